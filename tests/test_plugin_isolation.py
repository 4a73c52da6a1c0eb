"""A third-party matcher is used by a record; a plugin that raises at import fails only its own site."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "plugins" / "example-matcher"


def install_dist(site: Path, name: str, version: str, package: str, entry_points: str) -> None:
    """Write ``package`` and the ``.dist-info`` an installer writes (METADATA + entry_points.txt)."""
    info = site / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(entry_points)
    (info / "RECORD").write_text("")
    assert (site / package).exists()


def pool_record(bundled: Path, catalog: Path, site_id: str, matcher: str | None) -> None:
    text = (bundled / "sites" / "lair-pool.yaml").read_text()
    text = text.replace("id: lair-pool", f"id: {site_id}")
    if matcher is not None:
        text += f"pipeline:\n  matcher:\n    plugin: {matcher}\n"
    (catalog / "sites").mkdir(parents=True, exist_ok=True)
    (catalog / "sites" / f"{site_id}.yaml").write_text(text)


@pytest.mark.slow
def test_third_party_matcher_is_used_and_a_broken_one_fails_only_its_site(bundled_catalog, tmp_path):
    site = tmp_path / "site-packages"
    shutil.copytree(EXAMPLE / "cistern_example_matcher", site / "cistern_example_matcher")
    install_dist(site, "cistern-example-matcher", "0.1.0", "cistern_example_matcher",
                 "[cistern_archive.matchers]\nexample-grid = cistern_example_matcher.matcher:GridSearchMatcher\n")
    (site / "cistern_broken_matcher.py").write_text('raise ImportError("needs libfoo, which is not installed")\n')
    install_dist(site, "cistern-broken-matcher", "9.9", "cistern_broken_matcher.py",
                 "[cistern_archive.matchers]\nbroken = cistern_broken_matcher:Matcher\n")

    catalog = tmp_path / "catalog"
    shutil.copytree(bundled_catalog / "data" / "lair-pool", catalog / "data" / "lair-pool")
    shutil.copytree(bundled_catalog / "specs", catalog / "specs")
    pool_record(bundled_catalog, catalog, "pool-builtin", None)
    pool_record(bundled_catalog, catalog, "pool-third-party", "example-grid")
    pool_record(bundled_catalog, catalog, "pool-broken", "broken")

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), *filter(None, sys.path)])}
    listing = subprocess.run([sys.executable, "-m", "cistern_archive", "plugins", "--json"], env=env,
                             capture_output=True, text=True, timeout=120)
    rows = {r["name"]: r for r in json.loads(listing.stdout)["plugins"] if r["stage"] == "matcher"}
    assert rows["example-grid"]["status"] == "ok"
    assert rows["example-grid"]["distribution"] == "cistern-example-matcher"
    assert rows["broken"]["status"] == "error"
    assert "needs libfoo" in rows["broken"]["error"]

    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "cistern_archive", "rebuild", "--catalog", str(catalog),
                          "--out", str(out), "--archive", str(tmp_path / "archive")],
                         env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 1, run.stdout + run.stderr
    summary = {s["id"]: s for s in json.loads((out / "summary.json").read_text())["sites"]}
    assert summary["pool-builtin"]["status"] == "ok"
    assert summary["pool-third-party"]["status"] == "ok"
    assert summary["pool-broken"]["status"] == "failed"
    assert "needs libfoo" in summary["pool-broken"]["error"]
    result = json.loads((out / "pool-third-party" / "result.json").read_text())
    matcher = next(p for p in result["provenance"]["plugins"] if p["stage"] == "matcher")
    assert matcher["plugin"] == "example-grid"
    assert matcher["distribution"] == "cistern-example-matcher"
    assert (out / "pool-third-party" / "index.html").is_file()
