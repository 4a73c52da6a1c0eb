"""The console script: exit codes and the machine-readable outputs other tools rely on."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from catalog_helpers import RECORD, write_catalog


def run_cli(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cistern_archive", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


def test_version_and_help():
    from cistern_archive import __version__

    assert run_cli("--version").stdout.strip() == __version__
    help_text = run_cli("--help").stdout
    for command in ("rebuild", "validate", "plugins", "match", "inspect", "simulate"):
        assert command in help_text


def test_usage_errors_exit_2():
    assert run_cli("no-such-command").returncode == 2
    assert run_cli("match").returncode == 2


def test_validate_exit_codes(bundled_catalog, tmp_path):
    ok = run_cli("validate", "--catalog", str(bundled_catalog))
    assert ok.returncode == 0, ok.stderr
    write_catalog(tmp_path, RECORD.replace("kind: truth", "kind: guess"))
    bad = run_cli("validate", "--catalog", str(tmp_path))
    assert bad.returncode == 2
    assert "test-site.yaml:13: references[0].kind:" in bad.stderr


def test_plugins_json_lists_builtins_with_provenance():
    out = run_cli("plugins", "--json")
    assert out.returncode == 0, out.stderr
    rows = {(r["stage"], r["name"]): r for r in json.loads(out.stdout)["plugins"]}
    for key in (("matcher", "pf-pairwise"), ("localizer", "wls"), ("mapper", "evidence-grid"),
                ("comparator", "mosaic")):
        assert rows[key]["status"] == "ok", rows[key]
        assert rows[key]["distribution"] == "cistern-plugins"
    assert rows[("matcher", "correlative")]["capabilities"] == ["GuidedMatcher"]
    assert rows[("localizer", "site-graph")]["capabilities"] == ["GuidedLocalizer"]
    assert rows[("localizer", "wls")]["capabilities"] == []
    assert rows[("mapper", "evidence-grid")]["capabilities"] == ["EchoScaleMapper"]


@pytest.mark.parametrize("matcher", ["pf-pairwise"])
def test_match_prints_one_json_result(bundled_catalog, matcher):
    data = bundled_catalog / "data" / "lair-pool"
    out = run_cli("match", str(data / "s1.npz"), str(data / "s2.npz"), "--matcher", matcher, "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert {"dx_m", "dy_m", "dyaw_rad", "weight", "converged", "iterations", "seconds"} <= set(result)
    assert result["converged"] is True
    # Truth: s2 - s1 = (1.60, 0.25) m in the site frame; the map frame differs by the compass bias (~2 deg).
    assert abs(result["dx_m"] - 1.60) < 0.15 and abs(result["dy_m"] - 0.25) < 0.15


def test_match_refuses_bad_params(bundled_catalog):
    data = bundled_catalog / "data" / "lair-pool"
    out = run_cli("match", str(data / "s1.npz"), str(data / "s2.npz"), "--params", '{"bogus": 1}', "--json")
    assert out.returncode == 2
    assert "bogus: unknown parameter" in out.stderr
