"""The bundled demo sites: valid records, the sites the issue asks for, and bytes equal to a fresh run."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cistern_archive.catalog.loader import load_record
from cistern_archive.pipeline.validate import validate_catalog
from cistern_archive.sonar.geometry import overlap_fraction
from cistern_archive.sonar.interchange import read_scan
from cistern_archive.sonar.segmentation import segment
from cistern_archive.simulation.output import write_site
from cistern_archive.simulation.simulator import simulate_site
from cistern_archive.simulation.spec import load_spec

CATALOG = Path(__file__).resolve().parents[1] / "catalog"
SITES = ["bell-cistern", "gatto-pardo", "lair-pool", "mdina-site-8", "three-chambers", "water-gallery"]


def record(site: str):
    return load_record(CATALOG / "sites" / f"{site}.yaml", CATALOG).record


def truth(site: str) -> dict:
    return json.loads((CATALOG / "data" / site / "truth.json").read_text())


def test_bundled_catalog_validates():
    report = validate_catalog(CATALOG)
    assert report.ok, report.problems
    assert sorted(loaded.record.id for loaded in report.records) >= SITES


@pytest.mark.parametrize("site", SITES)
def test_committed_files_equal_a_fresh_simulation(site: str, tmp_path: Path):
    spec_path = CATALOG / "specs" / f"{site}.yaml"
    fresh = tmp_path / "catalog"
    (fresh / "specs").mkdir(parents=True)
    (fresh / "specs" / spec_path.name).write_bytes(spec_path.read_bytes())
    write_site(simulate_site(load_spec(spec_path)), fresh, spec_path=fresh / "specs" / spec_path.name,
               record_dir="sites")
    produced = sorted(p.relative_to(fresh) for p in fresh.rglob("*") if p.is_file())
    committed = sorted(p.relative_to(CATALOG) for p in (CATALOG / "data" / site).iterdir())
    assert sorted(p for p in produced if p.parts[0] == "data") == committed
    for relative in produced:
        assert (CATALOG / relative).read_bytes() == (fresh / relative).read_bytes(), f"{relative} differs"


@pytest.mark.parametrize("site", SITES)
def test_references_have_truth_and_mosaic_with_probes(site: str):
    rec = record(site)
    kinds = {ref.kind for ref in rec.references}
    assert kinds == {"truth", "mosaic"}
    for ref in rec.references:
        assert ref.measure.method == "probe" and ref.measure.frame in rec.station_index()
        assert ref.measure.repeats >= 5
    assert [t.station for t in rec.truth] == [s.station for s in rec.scans]
    assert rec.simulation == f"specs/{site}.yaml"


def test_data_is_small():
    sizes = [p.stat().st_size for p in (CATALOG / "data").rglob("*.npz")]
    assert max(sizes) < 64_000
    assert sum(p.stat().st_size for p in (CATALOG / "data").rglob("*") if p.is_file()) < 5_000_000


def test_pool_is_the_papers_pool():
    rec = record("lair-pool")
    assert len(rec.scans) == 4
    values = {(r.name, r.kind): r.value_m for r in rec.references}
    assert values[("width", "truth")] == 3.61 and values[("length", "truth")] == 7.21
    rings = truth("lair-pool")["levels"][0]["rings"][0]
    xs, ys = zip(*rings)
    assert (max(xs) - min(xs), max(ys) - min(ys)) == pytest.approx((7.21, 3.61))


def test_pool_scans_segment_to_the_walls():
    """The records' segmentation (the shadow rule) puts most beams within one bin of the true wall
    (committed files)."""
    rec = record("lair-pool")
    assert rec.segmentation.method == "shadow" and rec.segmentation.min_range_m == 0.4
    doc = truth("lair-pool")
    ring = np.asarray(doc["levels"][0]["rings"][0])
    from cistern_archive.sonar.geometry import ray_cast

    for ref, station in zip(rec.scans, doc["stations"]):
        scan = read_scan(CATALOG / ref.file)
        true_yaw = math.radians(station["yaw_deg"])
        expected, _ = ray_cast(np.array([station["x_m"], station["y_m"]]), true_yaw + scan.bearings_rad, [ring])
        ranges = segment(scan, rec.segmentation).ranges_m
        assert np.mean(np.abs(ranges - expected) <= scan.bin_size_m) > 0.7


def test_mdina_end_scans_barely_overlap():
    doc = truth("mdina-site-8")
    rings = [np.asarray(r) for r in doc["levels"][0]["rings"]]
    pos = {s["station"]: np.array([s["x_m"], s["y_m"]]) for s in doc["stations"]}
    names = [s["station"] for s in doc["stations"]]
    overlaps = {(a, b): overlap_fraction(pos[a], pos[b], rings, 10.0) for a, b in zip(names, names[1:])}
    assert overlap_fraction(pos["a3"], pos["b1"], rings, 10.0) < 0.3
    assert ("a3", "o1") in overlaps and ("o1", "b1") in overlaps  # the station in the opening joins them
    assert all(v >= 0.7 for v in overlaps.values())


def test_three_chambers_are_joined_by_tunnels_with_a_station_in_each_passage():
    spec = load_spec(CATALOG / "specs" / "three-chambers.yaml")
    rings = [np.asarray(r) for r in truth("three-chambers")["levels"][0]["rings"]]
    assert len(rings) == 1  # one closed outline
    pos = {s["station"]: np.array([s["x_m"], s["y_m"]]) for s in truth("three-chambers")["stations"]}
    names = [s.name for s in spec.stations]
    assert [n[0] for n in names] == list("aaatbbboccc")  # visiting order: A, tunnel, B, opening, C
    from cistern_archive.sonar.geometry import ray_cast

    for station, (x0, x1) in (("t1", (5.0, 6.5)), ("o2", (11.0, 12.2))):  # each tunnel, wall to wall
        across, _ = ray_cast(np.array([0.5 * (x0 + x1), pos[station][1]]), np.array([np.pi / 2, -np.pi / 2]), rings)
        assert 0.8 <= across.sum() <= 1.2
    assert spec.stations[3].x_m > 5.0 and spec.stations[3].x_m < 6.5  # t1 inside the first tunnel
    overlaps = [overlap_fraction(pos[a], pos[b], rings, 8.0) for a, b in zip(names, names[1:])]
    assert min(overlaps) >= 0.6  # every scan overlaps the next one well
    assert overlap_fraction(pos["a1"], pos["c3"], rings, 8.0) == 0.0
    assert overlap_fraction(pos["b3"], pos["c1"], rings, 8.0) < 0.5  # either side of tunnel 2


def test_bell_is_scanned_at_three_depths_with_changing_walls():
    rec = record("bell-cistern")
    depths = sorted({round(s.depth_m) for s in rec.scans})
    assert len(depths) == 3
    per_depth = [sum(1 for s in rec.scans if round(s.depth_m) == d) for d in depths]
    assert min(per_depth) >= 2
    levels = truth("bell-cistern")["levels"]
    spans = [np.ptp(np.asarray(level["rings"][0])[:, 0]) for level in levels]
    assert len(levels) >= 3 and spans[0] < spans[-1] / 3


def test_bell_levels_are_tied_by_vertical_descents():
    rec = record("bell-cistern")
    index = rec.station_index()
    xy = {t.station: np.array([t.x_m, t.y_m]) for t in rec.truth}
    ties = [(s.station, s.below) for s in rec.scans if s.below is not None]
    assert len(ties) == 2
    for lower, upper in ties:
        assert index[upper] == index[lower] - 1  # descended from the previous station
        assert rec.scans[index[lower]].depth_m > rec.scans[index[upper]].depth_m + 0.5
        assert 0.0 < np.hypot(*(xy[lower] - xy[upper])) < 0.1  # the descent drifts a few centimetres


def test_gallery_is_long_with_many_stations():
    rec = record("water-gallery")
    assert len(rec.scans) >= 12
    xy = np.array([[t.x_m, t.y_m] for t in rec.truth])
    assert np.sum(np.hypot(*np.diff(xy, axis=0).T)) >= 25.0
    ring = np.asarray(truth("water-gallery")["levels"][0]["rings"][0])
    assert np.ptp(ring[:, 0]) >= 30.0


def test_gallery_is_rough_with_features_and_overlapping_stations():
    spec = load_spec(CATALOG / "specs" / "water-gallery.yaml")
    level = spec.site.levels[0]
    assert level.wall_roughness is not None and level.wall_roughness >= 0.2
    assert len(level.walls.recesses) >= 5 and len(set(level.walls.widths)) >= 3
    assert max(r.depth_m for r in level.walls.recesses) >= 2.0  # a side branch
    rings = [np.asarray(r) for r in truth("water-gallery")["levels"][0]["rings"]]
    xy = [np.array([t.x_m, t.y_m]) for t in record("water-gallery").truth]
    assert all(overlap_fraction(a, b, rings, spec.sonar.range_m) >= 0.5 for a, b in zip(xy, xy[1:]))


def test_scan_below_must_name_another_station():
    from pydantic import ValidationError

    from cistern_archive.catalog.models import SiteRecord

    data = record("bell-cistern").model_dump(mode="json")
    data["scans"][3]["below"] = "nowhere"
    with pytest.raises(ValidationError, match="below 'nowhere' is not another station"):
        SiteRecord.model_validate(data)
    data["scans"][3]["below"] = data["scans"][3]["station"]
    with pytest.raises(ValidationError, match="is not another station"):
        SiteRecord.model_validate(data)
