"""The mosaic comparator: probes, automatic width/length, the paper's percent difference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cistern_archive.catalog.models import Probe, ReferenceDimension
from cistern_archive.grid.polygon import polygon_scan, rectangle
from cistern_archive.pipeline.contracts import Comparator, DimensionRow, EvidenceGrid, MapResult, Poses
from cistern_archive.pipeline.registry import Registry
from cistern_plugins.evidence_grid import EvidenceGridMapper, GridParams
from cistern_plugins.mosaic import MosaicComparator, MosaicParams, percent_difference, table_stats

W, L = 3.61, 7.21


def pool_map(angle_deg: float = 0.0, offset=(0.0, 0.0), seed=0):
    """Map of a W × L pool (length along x, rotated by ``angle_deg``), four scans at known poses."""
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    corners = rectangle(L, W, centre=(L / 2, W / 2)) @ rot.T + offset
    stations = np.array([[1.25, 1.7], [2.85, 1.95], [4.45, 1.6], [6.05, 1.85]]) @ rot.T + offset
    rng = np.random.default_rng(seed)
    scans = [polygon_scan([corners], xy, 0.2 * k, rng=rng, n_beams=400, range_noise_m=0.01)
             for k, xy in enumerate(stations)]
    # the map frame has the first station at the origin
    xy = stations - stations[0]
    poses = Poses(xy_m=xy, yaw_rad=np.array([s.yaw_rad for s in scans]), placed=np.ones(4, bool),
                  reasons=("",) * 4, reference=0)
    map_scans = [s for s in scans]
    return EvidenceGridMapper().build(map_scans, poses, GridParams()), poses


def refs(frame="s1", kinds=("truth",), **probe):
    inside = probe.pop("inside", (2.35, 0.1))
    out = []
    for kind in kinds:
        out.append(ReferenceDimension(name="width", value_m=W, kind=kind, measure=Probe(
            frame=frame, inside=inside, direction_deg=90.0, repeats=10, spacing_m=0.5, **probe)))
        out.append(ReferenceDimension(name="length", value_m=L, kind=kind, measure=Probe(
            frame=frame, inside=inside, direction_deg=0.0, repeats=10, spacing_m=0.25, **probe)))
    return out


STATIONS = {"s1": 0, "s2": 1, "s3": 2, "s4": 3}


@pytest.fixture(scope="module")
def pool():
    return pool_map()


def test_protocol_and_registry():
    assert isinstance(MosaicComparator(), Comparator)
    assert Registry().load("comparator", "mosaic").instance.name == "mosaic"


def test_probe_measures_width_and_length(pool):
    map_result, poses = pool
    table = MosaicComparator().compare(map_result, poses, refs(), STATIONS, MosaicParams(edge="centre"))
    width, length = table.rows
    assert width.map_m == pytest.approx(W, abs=0.05)
    assert length.map_m == pytest.approx(L, abs=0.05)
    assert width.diff_m == pytest.approx(width.map_m - W)
    assert len(width.probes) == 10 and len(width.probe_lines) == 10
    assert width.probe_std_m < 0.05
    assert table.stats["percent_difference"] < 1.0
    assert set(table.stats) >= {"probe_std_width_m", "probe_std_length_m", "max_abs_diff_m"}


def test_inner_edge_is_shorter_by_about_a_cell(pool):
    map_result, poses = pool
    inner = MosaicComparator().compare(map_result, poses, refs(), STATIONS, MosaicParams(edge="inner"))
    centre = MosaicComparator().compare(map_result, poses, refs(), STATIONS, MosaicParams(edge="centre"))
    for a, b in zip(inner.rows, centre.rows):
        assert b.map_m - a.map_m == pytest.approx(0.05, abs=1e-9)


def test_frame_of_another_station(pool):
    """The same probe expressed from station s3 (offset by s3 - s1) measures the same thing."""
    map_result, poses = pool
    offset = np.array([4.45 - 1.25, 1.6 - 1.7])
    from_s3 = refs(frame="s3", inside=tuple(np.array([2.35, 0.1]) - offset))
    a = MosaicComparator().compare(map_result, poses, refs(), STATIONS, MosaicParams())
    b = MosaicComparator().compare(map_result, poses, from_s3, STATIONS, MosaicParams())
    assert [r.map_m for r in a.rows] == pytest.approx([r.map_m for r in b.rows], abs=1e-9)


def test_map_frame_probe(pool):
    map_result, poses = pool
    table = MosaicComparator().compare(map_result, poses, refs(frame=None), STATIONS, MosaicParams(edge="centre"))
    assert table.rows[0].map_m == pytest.approx(W, abs=0.05)


def test_unplaced_frame_station_gives_a_note(pool):
    map_result, poses = pool
    unplaced = Poses(xy_m=poses.xy_m.copy(), yaw_rad=poses.yaw_rad, placed=np.array([False, True, True, True]),
                     reasons=("no converged path", "", "", ""), reference=1)
    table = MosaicComparator().compare(map_result, unplaced, refs(), STATIONS, MosaicParams())
    assert math.isnan(table.rows[0].map_m) and "unplaced" in table.rows[0].note
    assert "percent_difference" not in table.stats


@pytest.mark.parametrize("angle", [0.0, 30.0])
def test_auto_width_and_length(angle):
    map_result, poses = pool_map(angle)
    auto = [
        ReferenceDimension(name="width", value_m=W, kind="truth", measure=Probe(method="auto-width", repeats=5)),
        ReferenceDimension(name="length", value_m=L, kind="truth", measure=Probe(method="auto-length", repeats=5)),
    ]
    table = MosaicComparator().compare(map_result, poses, auto, STATIONS, MosaicParams(edge="centre"))
    width, length = table.rows
    assert width.map_m == pytest.approx(W, abs=0.1)
    assert length.map_m == pytest.approx(L, abs=0.1)


def test_empty_map_and_open_probe():
    empty = MapResult(grids=())
    poses = Poses(xy_m=np.zeros((4, 2)), yaw_rad=np.zeros(4), placed=np.ones(4, bool), reasons=("",) * 4, reference=0)
    table = MosaicComparator().compare(empty, poses, refs(), STATIONS, MosaicParams())
    assert all(math.isnan(r.map_m) and r.note for r in table.rows)
    lo = np.zeros((20, 20), np.float32)
    lo[:, 0] = 4.0  # only one wall: every probe is open on one side
    grid = MapResult(grids=(EvidenceGrid(lo, (-0.5, -0.5), 0.05, 0.0),))
    table = MosaicComparator().compare(grid, poses, refs(frame=None, inside=(0.0, 0.0)), STATIONS, MosaicParams())
    assert math.isnan(table.rows[1].map_m) and "no wall" in table.rows[1].note


def test_percent_difference_formula():
    # the paper's rounded figures: 3.47 x 7.27 against 3.61 x 7.21
    assert percent_difference(3.47 / 7.27, 3.61 / 7.21) == pytest.approx(4.78, abs=0.01)
    rows = (
        DimensionRow("width", 3.5, 3.61, "truth", -0.11, probes=(3.4, 3.6)),
        DimensionRow("length", 7.2, 7.21, "truth", -0.01, probes=(7.2, 7.2)),
        DimensionRow("width", 3.5, 3.4, "mosaic", 0.1),
    )
    stats = table_stats(rows)
    assert stats["percent_difference"] == pytest.approx(percent_difference(3.5 / 7.2, 3.61 / 7.21))
    assert stats["probe_std_width_m"] == pytest.approx(np.std([3.4, 3.6], ddof=1))
    assert stats["max_abs_diff_m"] == pytest.approx(0.11)


def test_probe_through_a_gap_is_dropped_with_a_note():
    lo = np.zeros((60, 120), np.float32)  # 3 m x 6 m, cells 0.05 m
    lo[5, :] = 4.0
    lo[45, :] = 4.0
    lo[55, :] = 4.0  # a second wall beyond the first
    lo[45, 60] = 0.0  # a one-cell gap in the upper wall
    grid = MapResult(grids=(EvidenceGrid(lo, (0.0, 0.0), 0.05, 0.0),))
    poses = Poses(xy_m=np.zeros((4, 2)), yaw_rad=np.zeros(4), placed=np.ones(4, bool), reasons=("",) * 4, reference=0)
    ref = [ReferenceDimension(name="width", value_m=2.0, kind="truth", measure=Probe(
        inside=(3.025, 1.25), direction_deg=90.0, repeats=5, spacing_m=0.1))]
    (row,) = MosaicComparator().compare(grid, poses, ref, STATIONS, MosaicParams(edge="inner")).rows
    assert row.map_m == pytest.approx(2.0 - 0.05, abs=1e-6)
    assert len(row.probes) == len(row.probe_lines) < 5
    assert "outliers" in row.note
    (raw,) = MosaicComparator().compare(grid, poses, ref, STATIONS, MosaicParams(edge="inner", reject_outliers=False)).rows
    assert raw.map_m > row.map_m


def test_heading_check_is_small_on_square_walls_and_large_where_a_turn_runs_the_probe_into_a_wall(pool):
    """Turning a pool's probes 2° about their station barely changes them (walls square to the probes); a
    length probe 0.1 m from the side wall runs into it when turned (7.2 m × tan 2° = 0.25 m across)."""
    map_result, poses = pool
    square = MosaicComparator().compare(map_result, poses, refs(), STATIONS, MosaicParams())
    assert all(0 <= row.heading_shift_m < 0.05 for row in square.rows)
    hugging = [ReferenceDimension(name="length along the wall", value_m=L, kind="truth", measure=Probe(
        frame="s1", inside=(L / 2 - 1.25, W - 0.1 - 1.7), direction_deg=0.0, repeats=1))]
    row = MosaicComparator().compare(map_result, poses, hugging, STATIONS, MosaicParams()).rows[0]
    assert abs(row.map_m - L) < 0.1 and row.heading_shift_m > 1.0
