"""``rebuild --dry-run``: per site skip / new / rebuild with the inputs whose material changed; nothing written."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from cistern_archive.service.dryrun import changed_paths, dry_run
from service_helpers import CLI, FAST_REPORT, build_once, copy_built

SITES = ["cistern-000", "cistern-001"]


@pytest.fixture(scope="module")
def built_once(tmp_path_factory) -> tuple[Path, Path]:
    return build_once(tmp_path_factory)


@pytest.fixture()
def built(built_once, tmp_path) -> tuple[Path, Path]:
    return copy_built(built_once, tmp_path)


def _tree(root: Path) -> dict[str, tuple[bytes, int]]:
    return {str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def _decisions(catalog: Path, out: Path, **kwargs) -> dict[str, tuple[str, tuple[str, ...]]]:
    plan = dry_run(catalog, out, report_config=kwargs.pop("report_config", FAST_REPORT), **kwargs)
    return {d.site_id: (d.action, d.reasons) for d in plan.decisions}


def _writable(path: Path) -> Path:
    path.chmod(0o644)
    return path


def test_unchanged_sites_are_skipped_and_nothing_is_written(built):
    catalog, out = built
    before = _tree(catalog.parent)
    assert _decisions(catalog, out) == {site: ("skip", ("build key unchanged",)) for site in SITES}
    assert _tree(catalog.parent) == before
    assert not (out / ".rebuild.lock").exists()
    assert not (catalog.parent / ".archive").exists(), "the archive is not opened"


def test_each_changed_input_of_the_key_is_named(built):
    catalog, out = built
    record = _writable(catalog / "sites" / "cistern-001.yaml")
    record.write_text(record.read_text().replace("description: ", "description: Edited. ", 1))
    scan = _writable(catalog / "data" / "cistern-000" / "s1.npz")
    scan.write_bytes(scan.read_bytes() + b"\0")
    decisions = _decisions(catalog, out)
    action, reasons = decisions["cistern-001"]
    assert action == "rebuild" and len(reasons) == 1 and reasons[0].startswith("record description: ")
    action, reasons = decisions["cistern-000"]
    assert action == "rebuild"
    assert reasons == (reasons[0],) and reasons[0].startswith("input data/cistern-000/s1.npz changed (sha256 ")

    other = _decisions(catalog, out, sites=["cistern-000"], report_config={**FAST_REPORT, "dpi": 72})
    assert list(other) == ["cistern-000"]
    assert "report settings dpi: 50 → 72" in other["cistern-000"][1]


def test_plugin_params_code_version_and_plugin_source_are_named(built):
    catalog, out = built
    record = _writable(catalog / "sites" / "cistern-000.yaml")
    text = record.read_text()
    assert "pipeline:" not in text
    record.write_text(text + "pipeline:\n  mapper:\n    plugin: evidence-grid\n    params:\n      cell_m: 0.04\n")
    build_json = _writable(out / "cistern-001" / "build.json")
    info = json.loads(build_json.read_text())
    info["build_key"] = "0" * 64
    info["key_material"]["code_version"] = "0.0.1+src.000000000000"
    info["key_material"]["plugins"][0]["source"] = "0" * 64
    build_json.write_text(json.dumps(info))
    decisions = _decisions(catalog, out)
    action, reasons = decisions["cistern-000"]
    assert action == "rebuild"
    assert "mapper evidence-grid params cell_m: 0.05 → 0.04" in reasons
    assert any(r.startswith("record pipeline.mapper") for r in reasons)
    action, reasons = decisions["cistern-001"]
    assert action == "rebuild"
    matcher = info["key_material"]["plugins"][0]["plugin"]
    assert reasons[0] == f"matcher {matcher}: plugin source files changed"
    assert reasons[1].startswith("code version 0.0.1+src.000000000000 → ")


def test_new_forced_and_failed_sites(built, tmp_path):
    catalog, out = built
    assert _decisions(catalog, tmp_path / "empty") == {site: ("new", ("no published report",)) for site in SITES}
    forced = _decisions(catalog, out, force=True)
    assert forced == {site: ("rebuild", ("forced (build key unchanged)",)) for site in SITES}
    build_json = _writable(out / "cistern-000" / "build.json")
    build_json.write_text(build_json.read_text().replace('"status": "ok"', '"status": "failed"'))
    assert _decisions(catalog, out)["cistern-000"] == (
        "rebuild", ("build key unchanged, but the published build failed",))


def test_changed_paths_names_leaves_added_and_removed_keys():
    old = {"a": 1, "b": {"c": [1, 2]}, "gone": "x"}
    new = {"a": 1, "b": {"c": [1, 3]}, "new": True}
    assert changed_paths(old, new) == ["b.c.1: 2 → 3", "gone removed (was 'x')", "new added (True)"]


def test_dry_run_command_lists_sites_and_leaves_everything_alone(built):
    catalog, out = built
    before = _tree(catalog.parent)
    run = subprocess.run([*CLI, "rebuild", "--catalog", str(catalog), "--out", str(out), "--dry-run"],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    # The command uses the default report settings, the published reports FAST_REPORT (and the code
    # version changes too when the sources were edited since the fixture built them).
    line = next(line for line in run.stdout.splitlines() if line.startswith("rebuild cistern-000: "))
    assert "report settings dpi removed (was 50)" in line
    assert "dry run: 2 to rebuild, 0 new, 0 unchanged; nothing written" in run.stdout
    assert _tree(catalog.parent) == before
    bad = subprocess.run([*CLI, "rebuild", "--catalog", str(catalog), "--out", str(out), "--dry-run",
                          "--site", "nowhere"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "--site nowhere" in bad.stderr and "Traceback" not in bad.stderr
