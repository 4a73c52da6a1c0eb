"""Echo ranges on leaning walls corrected for the vertical lobe (cistern_archive.grid.lobe) in the mapper."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.testing import assert_allclose

from cistern_archive.core.matches import MatchResult, lengthen_matches
from cistern_archive.core.poses import Poses
from cistern_archive.grid.lobe import range_factor, slope_at_zero, smooth_along_wall
from cistern_archive.grid.polygon import polygon_scan, rectangle
from cistern_plugins.evidence_grid import EvidenceGridMapper, GridParams

LEAN = math.radians(40.0)
DETECTION = math.radians(3.0)


def test_range_factor_follows_the_geometry_of_the_lobe():
    assert_allclose(range_factor(np.array([0.0]), DETECTION), [1.0])
    # within the detection angle the wall's nearest point, at normal incidence, forms the echo
    assert_allclose(range_factor(np.array([math.radians(2.0)]), DETECTION), [1 / math.cos(math.radians(2.0))])
    assert_allclose(range_factor(np.array([LEAN, -LEAN]), DETECTION),
                    [math.cos(LEAN - DETECTION) / math.cos(LEAN)] * 2)


def test_the_slope_at_a_slice_is_the_parabola_through_its_neighbours():
    wall = lambda z: 0.8 * z - 0.3 * z ** 2  # noqa: E731  outward offset of the wall against depth
    slope = slope_at_zero([-1.0, 1.0], [np.array([wall(-1.0)]), np.array([wall(1.0)])])
    assert_allclose(slope, [0.8])
    one_side = slope_at_zero([1.0, np.float64(2.0)], [np.array([wall(1.0)]), np.array([np.nan])])
    assert_allclose(one_side, [wall(1.0)])  # the other slice sees no wall there: the chord to the one that does


def circle(radius: float, n: int = 180) -> np.ndarray:
    t = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return np.column_stack([radius * np.cos(t), radius * np.sin(t)])


def cone_radius(depth: float) -> float:
    """A room widening with depth, its walls leaning 40° from the vertical."""
    return 1.2 + (depth - 1.0) * math.tan(LEAN)


def cone_scans(seed: int = 0):
    """Three depths, two stations each, every echo as short as the lobe makes it on a 40° lean."""
    rng = np.random.default_rng(seed)
    shrink = 1.0 / float(range_factor(np.array([LEAN]), DETECTION)[0])
    scans, positions = [], []
    for depth in (1.5, 2.5, 3.5):
        for k, xy in enumerate(((0.0, 0.0), (0.3, -0.2))):
            scan = polygon_scan([circle(cone_radius(depth))], xy, 0.7 * k, rng=rng, n_beams=400,
                                range_noise_m=0.01, depth_m=depth)
            scans.append(dataclasses.replace(scan, ranges_m=scan.ranges_m * shrink))
            positions.append(xy)
    poses = Poses(xy_m=np.array(positions, dtype=float), yaw_rad=np.array([s.yaw_rad for s in scans]),
                  placed=np.ones(len(scans), bool), reasons=("",) * len(scans), reference=0)
    return scans, poses


def wall_radius(grid) -> float:
    """Median distance from the room's centre of a slice's wall cells."""
    rows, cols = np.nonzero(grid.probability() > 0.6)
    x = grid.origin_xy_m[0] + (cols + 0.5) * grid.cell_m
    y = grid.origin_xy_m[1] + (rows + 0.5) * grid.cell_m
    return float(np.median(np.hypot(x, y)))


def test_a_room_leaning_over_the_vehicle_is_mapped_out_to_its_walls():
    scans, poses = cone_scans()
    mapper = EvidenceGridMapper()
    plain = mapper.build(scans, poses, GridParams(lobe_correction=False))
    corrected = mapper.build(scans, poses, GridParams(lobe_detection_share=3.0 / 17.5))
    truth = [cone_radius(g.depth_m) for g in corrected.grids]
    short = [truth[k] - wall_radius(g) for k, g in enumerate(plain.grids)]
    assert min(short) > 0.06  # 4 % short at 1.6-3.3 m, as the lobe left them
    assert_allclose([wall_radius(g) for g in corrected.grids], truth, atol=0.03)
    assert 30.0 < corrected.stats["lobe_median_lean_deg"] < 50.0


def test_the_echo_scale_of_a_room_leaning_over_the_vehicle_is_its_echoes_shortening():
    """The mapper tells how far each scan's echoes fall short (``EchoScaleMapper``): on the 40° cone
    every echo is short by the same share, which it reads back from the first slices; the match between
    two such scans, short by that share, is lengthened back to the true displacement."""
    scans, poses = cone_scans()
    shrink = 1.0 / float(range_factor(np.array([LEAN]), DETECTION)[0])
    scale = EvidenceGridMapper().echo_scale(scans, poses, GridParams(lobe_detection_share=3.0 / 17.5))
    assert_allclose(scale, shrink, atol=0.01)
    assert EvidenceGridMapper().echo_scale(scans, poses, GridParams(lobe_correction=False)) is None
    true = poses.xy_m[1] - poses.xy_m[0]
    short = MatchResult(i=0, j=1, dx_m=shrink * true[0], dy_m=shrink * true[1], dyaw_rad=0.0, weight=1.0,
                        converged=True, iterations=1, seconds=0.0)
    (match,) = lengthen_matches([short], scale)
    assert_allclose([match.dx_m, match.dy_m], true, atol=0.005)
    assert match.converged and match.dyaw_rad == 0.0


def one_depth_site():
    rng = np.random.default_rng(1)
    box = [rectangle(4.0, 6.0, centre=(2.0, 3.0))]
    positions = [(1.5, 2.0), (2.5, 4.0)]
    scans = [polygon_scan(box, xy, 0.3 * k, rng=rng, n_beams=400, range_noise_m=0.01, depth_m=1.2)
             for k, xy in enumerate(positions)]
    poses = Poses(xy_m=np.array(positions), yaw_rad=np.array([s.yaw_rad for s in scans]), placed=np.ones(2, bool),
                  reasons=("", ""), reference=0)
    return scans, poses


def test_a_site_scanned_at_one_depth_is_mapped_as_before():
    scans, poses = one_depth_site()
    mapper = EvidenceGridMapper()
    on, off = mapper.build(scans, poses, GridParams()), mapper.build(scans, poses, GridParams(lobe_correction=False))
    assert np.array_equal(on.grids[0].log_odds, off.grids[0].log_odds)
    assert "lobe_corrected_echoes" not in on.stats
    assert mapper.echo_scale(scans, poses, GridParams()) is None


def test_the_correction_scales_with_the_vertical_beam():
    """A head with a narrow beam in elevation hears a leaning wall where its axis meets it."""
    scans, poses = cone_scans()
    narrow = [dataclasses.replace(s, vertical_beam_width_rad=math.radians(4.0)) for s in scans]
    mapper = EvidenceGridMapper()
    wide = mapper.build(scans, poses, GridParams())
    thin = mapper.build(narrow, poses, GridParams())
    plain = mapper.build(scans, poses, GridParams(lobe_correction=False))
    moved = [wall_radius(a) - wall_radius(b) for a, b in zip(wide.grids, plain.grids)]
    barely = [wall_radius(a) - wall_radius(b) for a, b in zip(thin.grids, plain.grids)]
    assert min(moved) > 0.05 and max(abs(m) for m in barely) < 0.3 * min(moved)


def test_echoes_on_a_leaning_wall_are_averaged_along_it_and_no_others():
    rng = np.random.default_rng(3)
    bearings = np.radians(np.arange(360.0))
    ranges = 2.0 + rng.normal(0.0, 0.1, 360)
    ranges[90:100] = 3.0  # another wall behind an opening
    lean = np.full(360, math.radians(40.0))
    lean[180:200] = math.radians(4.0)  # a vertical stretch: its echoes are sharp
    lean[300:305] = np.nan  # lean unknown
    smooth = smooth_along_wall(ranges, lean, bearings, math.radians(7.0))
    leaning = np.ones(360, bool)
    leaning[90:100] = leaning[180:200] = leaning[300:305] = False
    assert np.std(smooth[leaning] - 2.0) < 0.5 * np.std(ranges[leaning] - 2.0)
    assert_allclose(smooth[90:100], 3.0)  # averaged with the far wall's echoes only
    assert np.array_equal(smooth[180:200], ranges[180:200]) and np.array_equal(smooth[300:305], ranges[300:305])
    assert np.array_equal(smooth_along_wall(ranges, lean, bearings, 0.0), ranges)


def water_beyond(grid, radius: float, margin: float = 0.1) -> int:
    """Cells a slice holds as water more than ``margin`` beyond a round room's wall."""
    rows, cols = np.nonzero(grid.probability() < 0.4)
    x = grid.origin_xy_m[0] + (cols + 0.5) * grid.cell_m
    y = grid.origin_xy_m[1] + (rows + 0.5) * grid.cell_m
    return int(np.sum(np.hypot(x, y) > radius + margin))


def test_scattered_echoes_on_a_leaning_wall_do_not_carry_the_water_past_it():
    """The smeared echoes of a leaning wall scatter along it; averaged along the wall, the longest of
    them no longer carry the slice's water into the rock."""
    scans, poses = cone_scans()
    rng = np.random.default_rng(5)
    scattered = [dataclasses.replace(s, ranges_m=s.ranges_m + rng.normal(0.0, 0.12, s.ranges_m.shape)) for s in scans]
    mapper = EvidenceGridMapper()
    apart = mapper.build(scattered, poses, GridParams(lobe_smooth_deg=0.0))
    averaged = mapper.build(scattered, poses, GridParams())
    leak_apart = sum(water_beyond(g, cone_radius(g.depth_m)) for g in apart.grids)
    leak_averaged = sum(water_beyond(g, cone_radius(g.depth_m)) for g in averaged.grids)
    assert leak_averaged < 0.3 * leak_apart
    assert_allclose([wall_radius(g) for g in averaged.grids], [cone_radius(g.depth_m) for g in averaged.grids],
                    atol=0.04)
