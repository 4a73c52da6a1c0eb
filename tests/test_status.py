"""Honest status: ok only when every scan is placed and every dimension measured; weak dimensions;
station labels in reasons; the rebuild's summary and exit code."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import pytest

import numpy as np

from cistern_archive.core.grids import EvidenceGrid
from cistern_archive.grid.lean import wall_lean_deg
from cistern_archive.pipeline.status import (MAX_HEADING_SHIFT_M, MAX_JOIN_CI95_M, MAX_PROBE_STD_M,
                                             MAX_WALL_LEAN_DEG, chain_breaks, label_indices, site_status,
                                             skipped_run_caveat, weakness)
from service_helpers import CLI, make_catalog


def test_ok_only_when_every_scan_is_placed_and_every_dimension_measured():
    labels = ["s1", "s2", "s3"]
    assert site_status(failed_stage=None, scans_placed=[True] * 3, labels=labels, unmeasured=[]) == ("ok", [])
    status, reasons = site_status(failed_stage=None, scans_placed=[True, False, True], labels=labels, unmeasured=[])
    assert status == "partial" and reasons == [
        "1 of 3 scans not placed (s2). The survey's chain breaks between s1 and s2: a station between them, "
        "in sight of both, could join s2 to the map. " + skipped_run_caveat("s1", "s3", "s2")]
    status, reasons = site_status(failed_stage=None, scans_placed=[True] * 3, labels=labels,
                                  unmeasured=["width (truth): the map is empty"])
    assert status == "partial" and reasons == ["dimension not measured: width (truth): the map is empty"]


def test_each_break_of_the_survey_chain_is_named_at_the_placed_station_next_to_it():
    labels = ["a1", "a2", "t1", "b1", "b2", "c1"]
    hints = chain_breaks([False, True, True, False, False, True], labels)
    assert [h.split(":")[0] for h in hints] == ["The survey's chain breaks between a1 and a2",
                                                "The survey's chain breaks between t1 and b1"]
    assert "could join b1–b2 to the map" in hints[1]
    assert "could join" in hints[0] and "joined without" not in hints[0]  # nothing placed before a1


def test_a_run_of_unplaced_stations_between_placed_ones_warns_that_its_two_sides_are_joined_unconfirmed():
    """The first and the last chamber placed, the middle one not: what joined the two sides skipped the
    stations that could have told a look-alike from the right place, and the reason says so."""
    labels = ["a1", "o1", "b1", "b2", "t2", "c1"]
    (hint,) = chain_breaks([True, True, False, False, True, True], labels)
    assert hint.startswith("The survey's chain breaks between o1 and b1")
    assert "o1 and t2, visited before and after b1–b2, are joined without them" in hint
    assert "check the parts on either side against the mosaic" in hint
    (end,) = chain_breaks([True, True, True, True, False, False], labels)
    assert "joined without" not in end
    assert chain_breaks([True] * 3, labels[:3]) == [] and chain_breaks([False] * 3, labels[:3]) == []


def test_a_join_of_groups_placed_less_precisely_than_the_limit_makes_the_site_partial():
    """Every scan placed, but two parts of the map joined by a group fit to within ±0.66 m only: the map
    may be wrong by that much without any match being wrong, so the site is not ``ok``."""
    labels = ["a1", "o1", "b1"]
    precise = [("o1", "b1", MAX_JOIN_CI95_M - 0.01), ("a1", "o1", None)]
    assert site_status(failed_stage=None, scans_placed=[True] * 3, labels=labels, unmeasured=[], joins=precise) == ("ok", [])
    status, reasons = site_status(failed_stage=None, scans_placed=[True] * 3, labels=labels, unmeasured=[],
                                  joins=[("o1", "b1", 0.659)])
    assert status == "partial"
    assert reasons[0].startswith("the groups of stations o1 and b1 are placed against each other only to ±0.66 m")


def test_joins_each_precise_enough_but_not_together_make_the_site_partial():
    """Two joins in series, ±0.18 and ±0.22 m: each under the limit, together ±0.29 m (a scan two joins
    away came out 0.36 m off so)."""
    labels = ["a1", "o1", "b1", "o2", "c1"]
    status, reasons = site_status(failed_stage=None, scans_placed=[True] * 5, labels=labels, unmeasured=[],
                                  joins=[("o1", "b1", 0.18), ("b1", "o2", 0.22)])
    assert status == "partial"
    assert reasons == [reasons[0]] and "o1–b1, b1–o2 together place parts of the map" in reasons[0]
    assert "±0.28 m" in reasons[0]
    assert site_status(failed_stage=None, scans_placed=[True] * 5, labels=labels, unmeasured=[],
                       joins=[("o1", "b1", 0.1), ("b1", "o2", 0.1)])[0] == "ok"


def test_nothing_placed_or_a_stopped_stage_is_failed():
    status, reasons = site_status(failed_stage=None, scans_placed=[False, False], labels=["a", "b"],
                                  unmeasured=["width (truth): the map is empty"])
    assert status == "failed" and reasons == ["none of the 2 scans could be placed"]
    status, reasons = site_status(failed_stage="load: a.npz: bad file", scans_placed=[False, False],
                                  labels=["a", "b"], unmeasured=[])
    assert status == "failed" and reasons == ["the build stopped at load: a.npz: bad file"]


def test_weak_when_fewer_than_half_the_probes_or_a_wide_spread():
    assert weakness(10, 10, 0.05) == ""
    assert weakness(5, 10, 0.05) == ""  # half is enough
    assert "2 of 10 probes" in weakness(2, 10, 0.05)
    assert f"above {MAX_PROBE_STD_M:.2f} m" in weakness(10, 10, MAX_PROBE_STD_M + 0.01)
    assert weakness(1, 1, None) == ""  # a single requested probe has no spread to judge


def test_weak_when_a_compass_bias_of_the_map_would_change_it():
    assert weakness(10, 10, 0.05, heading_shift_m=MAX_HEADING_SHIFT_M - 0.01) == ""
    far = weakness(10, 10, 0.05, heading_shift_m=0.94)
    assert "2° of compass bias would change it by 0.94 m" in far
    assert "more than its probes can tell" in weakness(10, 10, 0.05, heading_shift_m=math.inf)


def _room(half_width_m: float, depth_m: float) -> EvidenceGrid:
    """A slice of a square room centred on the origin: walls (log-odds +4) at ``±half_width_m``, water inside."""
    cell = 0.05
    n = 200  # 10 m square from (-5, -5)
    centres = -5.0 + (np.arange(n) + 0.5) * cell
    x, y = np.meshgrid(centres, centres)
    reach = np.maximum(np.abs(x), np.abs(y))
    log_odds = np.where(reach < half_width_m, -4.0, np.where(reach < half_width_m + 2 * cell, 4.0, 0.0))
    return EvidenceGrid(log_odds.astype(np.float32), (-5.0, -5.0), cell, depth_m)


def test_walls_leaning_between_depth_slices_make_a_dimension_weak():
    probe = [(-2.0, 0.3, 2.0, 0.3)]  # wall to wall across the slice at 1 m
    leaning = [_room(2.0, 1.0), _room(3.0, 2.0)]  # each wall 1 m farther out 1 m deeper: 45°
    assert abs(wall_lean_deg(leaning, 1.0, probe) - 45.0) < 3.0
    upright = [_room(2.0, 1.0), _room(2.0, 2.0)]
    assert wall_lean_deg(upright, 1.0, probe) < 3.0
    assert wall_lean_deg(leaning[:1], 1.0, probe) is None  # one depth: nothing to compare with
    assert "lean about 45°" in weakness(10, 10, 0.05, 45.0)
    assert weakness(10, 10, 0.05, MAX_WALL_LEAN_DEG - 1) == ""


def test_reasons_name_stations_not_indices():
    labels = ["w1", "w2", "w3"]
    text = ("no converged path to reference scan 0: (1,2): ambiguous: a position 1.56 m away (1.85, -0.10); "
            "probe frame station 's2' (scan 1) is unplaced; scan 7 of another list")
    assert label_indices(text, labels) == (
        "no converged path to reference scan w1: (w2 → w3): ambiguous: a position 1.56 m away (1.85, -0.10); "
        "probe frame station 's2' (scan w2) is unplaced; scan 7 of another list")


@pytest.fixture(scope="module")
def partial_catalog(tmp_path_factory) -> Path:
    """Two generated cisterns; the second asks for a dimension whose probe starts far outside it."""
    root = make_catalog(tmp_path_factory.mktemp("status") / "catalog")
    record = root / "sites" / "cistern-001.yaml"
    text = record.read_text()
    assert "references:\n" in text
    record.write_text(text.replace("references:\n", "references:\n- name: far wall\n  value_m: 3.0\n  kind: truth\n"
                                   "  measure: {frame: s1, inside: [400.0, 400.0], direction_deg: 0.0, repeats: 4}\n",
                                   1))
    return root


def test_rebuild_reports_partial_sites_and_exits_1(partial_catalog, tmp_path):
    out = tmp_path / "site"
    run = subprocess.run(CLI + ["rebuild", "--catalog", str(partial_catalog), "--out", str(out), "--archive",
                                str(tmp_path / "archive")], capture_output=True, text=True, timeout=300)
    assert run.returncode == 1, run.stderr
    assert "PARTIAL cistern-001: dimension not measured: far wall (truth)" in run.stderr
    summary = json.loads((out / "summary.json").read_text())
    statuses = {s["id"]: (s["status"], s["report_status"]) for s in summary["sites"]}
    assert statuses == {"cistern-000": ("ok", "ok"), "cistern-001": ("partial", "partial")}
    result = json.loads((out / "cistern-001" / "result.json").read_text())
    assert result["status"] == "partial" and result["status_reasons"]
    far = next(d for d in result["dimensions"] if d["name"] == "far wall")
    assert far["map_m"] is None and far["probes_requested"] == 4 and not far["weak"]
    page = (out / "cistern-001" / "index.html").read_text()
    assert 'badge badge-partial">partial<' in page and 'id="status-reasons"' in page
    index = (out / "index.html").read_text()
    assert "1 ok, 1 partial, 0 failed" in index
    # unchanged partial sites are not rebuilt: the same inputs give the same partial build
    again = subprocess.run(CLI + ["rebuild", "--catalog", str(partial_catalog), "--out", str(out), "--archive",
                                  str(tmp_path / "archive")], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert {s["id"]: (s["status"], s["report_status"]) for s in summary["sites"]} == {
        "cistern-000": ("skipped", "ok"), "cistern-001": ("skipped", "partial")}


def test_workers_mark_their_running_stage_for_the_terminal(tmp_path):
    from cistern_archive.commands.rebuild import running_stages, running_text
    from cistern_archive.service.worker import PROGRESS_DIR, StageMarker

    first, second = StageMarker(tmp_path, "well-b"), StageMarker(tmp_path, "cistern-a")
    first("match")
    second("load")
    second("report")
    assert running_stages(tmp_path / PROGRESS_DIR) == [("cistern-a", "report"), ("well-b", "match")]
    assert running_text(running_stages(tmp_path / PROGRESS_DIR)) == "building cistern-a (report), well-b (match)"
    first.clear()
    second.clear()
    assert running_stages(tmp_path / PROGRESS_DIR) == [] and running_text([]) == ""
    assert running_stages(tmp_path / "absent") == []


def test_build_site_announces_each_stage(partial_catalog):
    from cistern_archive.catalog.loader import load_record
    from cistern_archive.pipeline.runner import build_site

    stages: list[str] = []
    build_site(load_record(partial_catalog / "sites" / "cistern-000.yaml", partial_catalog), on_stage=stages.append)
    assert stages == ["configure", "load", "segment", "match", "localize", "map", "compare", "mesh"]


def test_a_probe_given_far_from_its_chamber_is_weak_and_one_given_nearby_is_right():
    """The bundled three-chamber cistern's chamber C length, probed from c1 (its own chamber) as the record
    gives it, and from a1, 13.6 m west: there the map's compass bias (2°) moves the probes onto a corner."""
    import dataclasses

    from cistern_archive.catalog.loader import load_record
    from cistern_archive.pipeline.runner import build_site

    catalog = Path(__file__).resolve().parents[1] / "catalog"
    loaded = load_record(catalog / "sites" / "three-chambers.yaml", catalog)
    truth = {s["station"]: (s["x_m"], s["y_m"]) for s in json.loads(
        (catalog / "data" / "three-chambers" / "truth.json").read_text())["stations"]}
    c1, a1 = np.array(truth["c1"]), np.array(truth["a1"])

    def length(record):
        rows = build_site(dataclasses.replace(loaded, record=record)).result.dimensions
        return next(d for d in rows if d.name == "length" and d.reference_kind == "truth")

    near = length(loaded.record)
    assert not near.weak and abs(near.map_m - near.reference_m) < 0.05
    far_refs = [r.model_copy(update={"measure": r.measure.model_copy(update={
        "frame": "a1", "inside": tuple(np.round(np.array(r.measure.inside) + c1 - a1, 3))})})
        if r.name == "length" else r for r in loaded.record.references]
    far = length(loaded.record.model_copy(update={"references": far_refs}))
    assert far.weak and "2° of compass bias would change it" in far.weak_reason
    assert abs(far.map_m - far.reference_m) > abs(near.map_m - near.reference_m)


def test_a_station_held_only_by_loop_closures_is_a_caveat_only_where_some_station_is_unplaced():
    held = [("r1", ["b1", "b2"])]
    status, reasons = site_status(failed_stage=None, scans_placed=[False, True, True, True], unmeasured=[],
                                  labels=["a1", "b1", "b2", "r1"], loop_only=held)
    assert status == "partial" and any(r.startswith("r1 is held in place only by matches to b1, b2") for r in reasons)
    status, reasons = site_status(failed_stage=None, scans_placed=[True] * 4, unmeasured=[],
                                  labels=["a1", "b1", "b2", "r1"], loop_only=held)
    assert status == "ok" and reasons == []
