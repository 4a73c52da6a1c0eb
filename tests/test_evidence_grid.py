"""Inverse sonar model, tiled store, ray casting, exports and the evidence-grid mapper."""

from __future__ import annotations

import io
import math
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose

from cistern_archive.grid.evidence import SonarModel, dense_scan_map, scan_window
from cistern_archive.pipeline.export import grid_image, npz_bytes, png_bytes, read_npz, write_npz, write_png
from cistern_archive.grid.polygon import polygon_scan, rectangle
from cistern_archive.grid.raycast import OccupancyLookup, distance_field
from cistern_archive.grid.tiles import TiledGrid
from cistern_archive.pipeline.contracts import EvidenceGrid, Mapper, Poses
from cistern_archive.pipeline.registry import Registry
from cistern_archive.core.scan import RangeScan
from cistern_plugins.evidence_grid import EvidenceGridMapper, GridParams, depth_slices

BOX = [rectangle(4.0, 6.0, centre=(2.0, 3.0))]


def one_beam(range_m: float, bearing: float = 0.0, width_deg: float = 3.0) -> RangeScan:
    return RangeScan(bearings_rad=np.array([bearing]), ranges_m=np.array([range_m]), yaw_rad=0.0, depth_m=0.0,
                     max_range_m=5.0, bin_size_m=0.05, beam_width_rad=math.radians(width_deg))


def box_scans(positions, depth=1.0, seed=0):
    rng = np.random.default_rng(seed)
    return [polygon_scan(BOX, xy, 0.3 * k, rng=rng, n_beams=400, range_noise_m=0.01, depth_m=depth)
            for k, xy in enumerate(positions)]


def poses_for(positions, scans, placed=None) -> Poses:
    n = len(positions)
    placed = np.ones(n, bool) if placed is None else np.asarray(placed)
    xy = np.where(placed[:, None], np.asarray(positions, float), np.nan)
    return Poses(xy_m=xy, yaw_rad=np.array([s.yaw_rad for s in scans]), placed=placed,
                 reasons=tuple("" if p else "test" for p in placed), reference=0)


# ------------------------------------------------------------------------------ inverse model
def test_single_beam_free_then_occupied_then_untouched():
    model = SonarModel(l_occ=1.0, l_free=-0.5)
    m = dense_scan_map(one_beam(2.0), cell_m=0.05, model=model)
    rows, cols = m.log_odds.shape
    centre_row = rows // 2
    x = m.origin_xy_m[0] + (np.arange(cols) + 0.5) * 0.05
    line = m.log_odds[centre_row]
    assert np.all(line[(x > 1.0) & (x < 1.9)] == -0.5)
    assert np.all(line[(x > 1.98) & (x < 2.02)] == 1.0)
    assert np.all(line[x > 2.1] == 0.0)
    assert np.all(line[x < 0] == 0.0)  # behind the sonar: another bearing


def test_echoes_not_heard_from_the_station_mark_walls_only():
    """A moving vehicle's compensated cloud: the line from the station to an echo was no beam's, so its
    cells gain no free evidence; the echo's cells are occupied as before."""
    model = SonarModel(l_occ=1.0, l_free=-0.5)
    stationary = dense_scan_map(one_beam(2.0), cell_m=0.05, model=model).log_odds
    cloud = dense_scan_map(replace(one_beam(2.0), rays_from_station=False), cell_m=0.05, model=model).log_odds
    assert stationary.min() == -0.5 and cloud.min() == 0.0
    np.testing.assert_array_equal(cloud, np.maximum(stationary, 0.0))


def test_cone_width_is_respected():
    m = dense_scan_map(one_beam(3.0, width_deg=10.0), cell_m=0.05, model=SonarModel())
    occ = np.argwhere(m.log_odds > 0)
    ys = m.origin_xy_m[1] + (occ[:, 0] + 0.5) * 0.05
    half_arc = 3.0 * math.tan(math.radians(5.0))
    assert ys.max() == pytest.approx(half_arc, abs=0.06) and ys.min() == pytest.approx(-half_arc, abs=0.06)


def test_no_echo_frees_only_when_asked():
    empty = one_beam(float("nan"))
    assert scan_window(empty, (0, 0), 0.0, origin_xy_m=(0, 0), cell_m=0.05, model=SonarModel()) is None
    w = scan_window(empty, (0, 0), 0.0, origin_xy_m=(0, 0), cell_m=0.05, model=SonarModel(free_no_echo=True))
    assert w is not None and w.delta.max() == 0 and w.delta.min() < 0


def test_clamping():
    m = dense_scan_map(one_beam(1.0), cell_m=0.05, model=SonarModel(l_occ=10.0, clamp_max=3.0))
    assert m.log_odds.max() == pytest.approx(3.0)


# ------------------------------------------------------------------------------ tiles
def test_tiled_grid_equals_dense_accumulation():
    scans = box_scans([(1.0, 1.5), (3.0, 4.0)])
    model = SonarModel()
    tiled = TiledGrid(cell_m=0.05, tile=32)
    dense = np.zeros((400, 400), np.float32)  # cells -200..199 on both axes
    for s, xy in zip(scans, [(1.0, 1.5), (3.0, 4.0)]):
        w = scan_window(s, xy, s.yaw_rad, origin_xy_m=(0.0, 0.0), cell_m=0.05, model=model)
        tiled.add_window(w)
        dense[w.row0 + 200 : w.row0 + 200 + w.delta.shape[0], w.col0 + 200 : w.col0 + 200 + w.delta.shape[1]] += w.delta
    out, row0, col0 = tiled.to_dense()
    assert_allclose(out, dense[row0 + 200 : row0 + 200 + out.shape[0], col0 + 200 : col0 + 200 + out.shape[1]])
    assert np.count_nonzero(dense) == np.count_nonzero(out)


def test_tiles_allocated_only_where_touched():
    """A 40 m straight gallery: tiles cover the swept strip, not the square bounding box."""
    gallery = [np.array([[0, 0], [40, 0], [40, 1.5], [0, 1.5]], float)]
    rng = np.random.default_rng(0)
    xs = np.arange(1.0, 40.0, 2.5)
    scans = [polygon_scan(gallery, (x, 0.75), 0.0, rng=rng, n_beams=200, max_range_m=5.0) for x in xs]
    result = EvidenceGridMapper().build(scans, poses_for([(x, 0.75) for x in xs], scans), GridParams())
    grid = result.grids[0]
    assert grid.extent_m[1] - grid.extent_m[0] > 39.0
    dense_square = (40.0 / 0.05) ** 2 * 4
    assert result.stats["tile_bytes"] < 0.2 * dense_square


# ------------------------------------------------------------------------------ ray casting
def test_sphere_trace_matches_march():
    scan = box_scans([(2.0, 3.0)])[0]
    m = dense_scan_map(scan, cell_m=0.05, model=SonarModel())
    lookup = OccupancyLookup(m.occupied(0.6), m.origin_xy_m, m.cell_m)
    rng = np.random.default_rng(1)
    x0, y0 = rng.uniform(-1.5, 1.5, 500), rng.uniform(-2.5, 2.5, 500)
    angle = rng.uniform(-np.pi, np.pi, 500)
    a = lookup.march(x0, y0, angle, np.full(500, 20.0))
    b = lookup.sphere_trace(x0, y0, angle, np.full(500, 20.0))
    # the two sample the ray at different points, so a ray grazing a corner gap may differ
    assert (np.isnan(a) != np.isnan(b)).mean() <= 0.02
    ok = np.isfinite(a) & np.isfinite(b)
    assert ok.mean() > 0.9
    assert np.mean(np.abs(a[ok] - b[ok]) <= 0.05 + 1e-9) >= 0.98


def test_distance_field_metres():
    occ = np.zeros((5, 5), bool)
    occ[2, 2] = True
    d = distance_field(occ, 0.1)
    assert d[2, 2] == 0 and d[2, 4] == pytest.approx(0.2) and d[0, 0] == pytest.approx(math.hypot(0.2, 0.2))


# ------------------------------------------------------------------------------ mapper
def test_protocol_and_registry():
    assert isinstance(EvidenceGridMapper(), Mapper)
    assert Registry().load("mapper", "evidence-grid").instance.name == "evidence-grid"


def test_mapper_draws_the_walls_where_they_are():
    positions = [(1.0, 1.5), (3.0, 4.5), (2.0, 3.0)]
    scans = box_scans(positions)
    result = EvidenceGridMapper().build(scans, poses_for(positions, scans), GridParams())
    (grid,) = result.grids
    occ = grid.log_odds > 0.4
    rows, cols = np.nonzero(occ)
    x = grid.origin_xy_m[0] + (cols + 0.5) * grid.cell_m
    y = grid.origin_xy_m[1] + (rows + 0.5) * grid.cell_m
    on_wall = np.minimum.reduce([np.abs(x), np.abs(x - 4.0), np.abs(y), np.abs(y - 6.0)]) < 0.1
    assert on_wall.mean() > 0.97
    inside = grid.cell_of(np.array([[2.0, 3.0], [1.0, 5.0]]))
    assert np.all(grid.log_odds[inside[:, 0], inside[:, 1]] < 0)
    assert result.stats["scans_fused"] == 3


def test_stations_on_an_uneven_floor_make_one_slice_and_a_bells_levels_three():
    scan = box_scans([(1.0, 1.5)])[0]
    tolerance = GridParams().depth_tolerance_m
    floor = [replace(scan, depth_m=d) for d in (1.0, 1.6, 2.2, 2.8, 1.3)]  # 1.8 m end to end
    assert depth_slices(floor, [10, 11, 12, 13, 14], tolerance) == [[10, 14, 11, 12, 13]]
    bell = [replace(scan, depth_m=d) for d in (1.6, 2.6, 3.6, 1.57, 2.63)]
    assert depth_slices(bell, [10, 11, 12, 13, 14], tolerance) == [[13, 10], [11, 14], [12]]


def test_depth_slices_and_unplaced_scans():
    positions = [(1.0, 1.5), (3.0, 4.5), (2.0, 3.0), (1.5, 2.0)]
    scans = box_scans(positions[:2], depth=1.0) + box_scans(positions[2:], depth=2.0)
    assert depth_slices(scans, [0, 1, 2, 3], 0.25) == [[0, 1], [2, 3]]
    assert depth_slices(scans, [0, 1, 2, 3], 1.0) == [[0, 1, 2, 3]]
    result = EvidenceGridMapper().build(scans, poses_for(positions, scans, [True, True, False, True]), GridParams())
    assert [g.depth_m for g in result.grids] == [1.0, 2.0]
    assert result.stats["scans_fused"] == 3


def test_nothing_placed_gives_no_grid():
    scans = box_scans([(1.0, 1.5)])
    result = EvidenceGridMapper().build(scans, poses_for([(1.0, 1.5)], scans, [False]), GridParams())
    assert result.grids == ()


# ------------------------------------------------------------------------------ exports
def test_png_and_npz_are_deterministic_and_readable(tmp_path):
    from PIL import Image

    positions = [(1.0, 1.5), (3.0, 4.5)]
    scans = box_scans(positions)
    grids = EvidenceGridMapper().build(scans, poses_for(positions, scans), GridParams()).grids
    p1 = write_png(tmp_path / "a.png", grids[0])
    p2 = write_png(tmp_path / "b.png", grids[0])
    assert p1.read_bytes() == p2.read_bytes()
    with Image.open(io.BytesIO(p1.read_bytes())) as img:
        assert img.size == grids[0].log_odds.shape[::-1] and img.mode == "L"
        assert not img.info  # no metadata
        assert np.array_equal(np.asarray(img), grid_image(grids[0]))
    write_npz(tmp_path / "g.npz", grids)
    assert npz_bytes({"a": np.arange(3)}) == npz_bytes({"a": np.arange(3)})
    (back,) = read_npz(tmp_path / "g.npz")
    assert_allclose(back.log_odds, grids[0].log_odds)
    assert back.origin_xy_m == pytest.approx(grids[0].origin_xy_m) and back.cell_m == grids[0].cell_m


def test_read_npz_names_a_file_of_another_layout(tmp_path):
    from cistern_archive.core.errors import CisternError

    other = tmp_path / "other.npz"
    other.write_bytes(npz_bytes({"depths_m": np.array([1.5]), "log_odds_0": np.zeros((2, 2), np.float32)}))
    with pytest.raises(CisternError, match=r"other\.npz: not a grid archive of this layout \(missing cell_m"):
        read_npz(other)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(CisternError, match=r"junk\.npz: cannot read the grid archive"):
        read_npz(tmp_path / "junk.npz")


def test_png_refuses_bad_arrays():
    with pytest.raises(ValueError):
        png_bytes(np.zeros((2, 2), np.float32))


def test_grid_image_orientation():
    lo = np.zeros((2, 3), np.float32)
    lo[0, 0] = 4.0  # lower-left cell occupied
    lo[0, 2] = -4.0  # lower-right cell free
    img = grid_image(EvidenceGrid(lo, (0.0, 0.0), 0.05, 0.0))
    # north up; black occupied, white free, grey unknown (the map figure's polarity)
    assert img[1, 0] < 10 and img[1, 2] > 245 and img[0, 0] == 128 and img[1, 1] == 128
