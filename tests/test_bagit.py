"""BagIt export: one valid RFC 8493 bag per site with raw inputs, preservation formats, report,
resolved configuration and provenance, packed from the published build (never rebuilt)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import bagit
import pytest

from cistern_archive.pipeline.export import read_npz, write_npz
from cistern_archive.service.export import NotPublished, export_bag
from cistern_archive.service.rebuild import rebuild
from service_helpers import CLI, FAST_REPORT, make_catalog

SITE = "cistern-001"
BAG_REPORT = {**FAST_REPORT, "model": True, "viewer": False}  # the bag's model.ply is the published one


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("bagit")
    catalog = make_catalog(root / "catalog")
    out = root / "site"
    summary = rebuild(catalog, out, workers=2, report_config=BAG_REPORT)
    assert [s.status for s in summary.sites] == ["ok", "ok"]
    return catalog, out


def test_export_writes_a_valid_bag_with_everything_a_depositor_needs(built, tmp_path, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    catalog, out = built
    result = export_bag(SITE, tmp_path / "bag", catalog=catalog, out=out)
    assert result.report_source.startswith("published report")
    bag = bagit.Bag(str(result.path))
    bag.validate()  # raises BagValidationError on any problem
    assert bag.info["External-Identifier"] == SITE
    assert bag.info["Bagging-Date"] == "2023-11-14"
    assert set(bag.algorithms) == {"sha256", "sha512"}
    data = result.path / "data"
    record = catalog / "sites" / f"{SITE}.yaml"
    assert (data / "raw" / "sites" / f"{SITE}.yaml").read_bytes() == record.read_bytes()
    for scan in sorted((catalog / "data" / SITE).glob("*.npz")):
        assert (data / "raw" / "data" / SITE / scan.name).read_bytes() == scan.read_bytes()
    assert (data / "raw" / "specs" / f"{SITE}.yaml").is_file()
    preservation = data / "preservation"
    header = (preservation / "scans" / "s1.csv").read_text().splitlines()[0].split(",")
    assert header[0] == "bearing_rad" and header[1] == "bin_0000"
    for name in ("raw-scans.csv", "scans.csv", "pairs.csv", "dimensions.csv", "grids.csv"):
        assert (preservation / name).is_file()
    raw_scans = (preservation / "raw-scans.csv").read_text().splitlines()
    assert len(raw_scans) == 3 and raw_scans[1].startswith("s1,") and raw_scans[1].endswith(",")  # no problem
    assert (preservation / "grid-0.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (preservation / "model.ply").read_bytes().startswith(b"ply")
    assert (data / "report" / "index.html").is_file()
    for export in ("plan.dxf", "plan.svg"):  # the CAD exports travel with the report
        assert (data / "report" / export).is_file(), export
    assert json.loads((data / "report" / "result.json").read_text())["site_id"] == SITE
    resolved = json.loads((data / "config" / "resolved.json").read_text())
    assert resolved["id"] == SITE and resolved["pipeline"]["matcher"]["params"]
    provenance = data / "provenance"
    assert json.loads((provenance / "build-key.json").read_text())["build_key"] == result.build_key
    events = {e["type"] for e in json.loads((provenance / "events.json").read_text())}
    assert {"ingest", "digest", "build", "publish"} <= events
    assert all(len(item["sha256"]) == 64 for item in json.loads((provenance / "inputs.json").read_text()))


def test_bag_preservation_and_report_carry_the_same_bytes(built, tmp_path):
    """One writer per format: the bag's preservation copies, its report and the published downloads
    are the same files, and grid.npz reads back into grids that write the same grid.npz."""
    catalog, out = built
    data = export_bag(SITE, tmp_path / "bag", catalog=catalog, out=out).path / "data"
    published = out / SITE
    same = ("dimensions.csv", "pairs.csv", "scans.csv", "grids.csv", "grid-0.png", "model.ply")
    for name in same:
        assert (published / name).is_file(), name
        assert (data / "preservation" / name).read_bytes() == (published / name).read_bytes(), name
        assert (data / "report" / name).read_bytes() == (published / name).read_bytes(), name
    for name in ("index.html", "result.json", "grid.npz", "build.json"):  # packed, not rebuilt
        assert (data / "report" / name).read_bytes() == (published / name).read_bytes(), name
    grids = read_npz(published / "grid.npz")
    assert grids and all(g.log_odds.ndim == 2 for g in grids)
    write_npz(tmp_path / "again.npz", grids)
    assert (tmp_path / "again.npz").read_bytes() == (published / "grid.npz").read_bytes()
    header = (published / "dimensions.csv").read_text().splitlines()[0]
    assert header == "name,reference_kind,depth_m,map_m,ci95_m,reference_m,diff_m,diff_percent,probe_std_m," \
                     "n_probes,probes_m"


def test_export_refuses_a_stale_or_missing_published_build(built, tmp_path):
    catalog, out = built
    changed = tmp_path / "catalog"
    shutil.copytree(catalog, changed)
    record = changed / "sites" / f"{SITE}.yaml"
    record.write_text(record.read_text().replace("name:", "name: Renamed", 1))
    archive = tmp_path / "archive"
    with pytest.raises(NotPublished, match=rf"^{SITE}: the published build in .* is stale.*run rebuild first"):
        export_bag(SITE, tmp_path / "bag", catalog=changed, out=out, archive=archive)
    with pytest.raises(NotPublished, match=rf"^{SITE}: no published build in .*run rebuild first"):
        export_bag(SITE, tmp_path / "bag", catalog=catalog, out=tmp_path / "empty", archive=archive)
    assert not (tmp_path / "bag").exists() and not list(tmp_path.glob(".bag.tmp-*"))


def test_a_damaged_bag_fails_validation_and_a_re_export_replaces_it(built, tmp_path):
    catalog, out = built
    path = export_bag(SITE, tmp_path / "bag", catalog=catalog, out=out).path
    scan = path / "data" / "raw" / "data" / SITE / "s1.npz"
    damaged = bytearray(scan.read_bytes())
    damaged[100] ^= 0xFF
    scan.write_bytes(bytes(damaged))
    with pytest.raises(bagit.BagValidationError):
        bagit.Bag(str(path)).validate()
    export_bag(SITE, tmp_path / "bag", catalog=catalog, out=out)
    bagit.Bag(str(path)).validate()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


@pytest.mark.slow
def test_export_command(built, tmp_path):
    catalog, out = built
    run = subprocess.run([*CLI, "export", SITE, "--bag", str(tmp_path / "bag"), "--catalog", str(catalog),
                          "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    bagit.Bag(str(tmp_path / "bag")).validate()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("keep me")
    refused = subprocess.run([*CLI, "export", SITE, "--bag", str(tmp_path / "other"), "--catalog", str(catalog),
                              "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2 and "is not a bag of site" in refused.stderr
    assert (tmp_path / "other" / "notes.txt").read_text() == "keep me"
    unknown = subprocess.run([*CLI, "export", "nowhere", "--bag", str(tmp_path / "x"), "--catalog", str(catalog),
                              "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert unknown.returncode == 2 and "nowhere" in unknown.stderr
