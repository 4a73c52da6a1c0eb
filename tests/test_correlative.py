"""Correlative matcher: exact branch and bound, large offsets without a guess, honest flag."""

import math
from dataclasses import replace

import numpy as np

from cistern_archive.core.scan import RangeScan
from cistern_archive.grid.polygon import polygon_scan
from cistern_archive.pipeline.contracts import MatchGuess
from cistern_archive.testing import simulated_pair
from cistern_plugins.registration import ReferenceModel, scan_points
from cistern_plugins.correlative import (CorrelativeMatcher, CorrelativeParams, LikelihoodPyramid, branch_and_bound,
                                        keeps_score, pose_score, reference_pyramid, thinned)


def test_large_offset_without_guess():
    rng = np.random.default_rng(11)
    pair = simulated_pair(rng, overlap_range=(0.6, 1.0), offset_range_m=(1.5, 2.0), noise_m=0.02)
    res = CorrelativeMatcher().match(pair.reference, pair.moving, CorrelativeParams(), rng=rng)
    assert res.converged, res.reason
    np.testing.assert_allclose([res.dx_m, res.dy_m], [pair.dx_m, pair.dy_m], atol=0.1)
    assert abs(math.degrees(res.dyaw_rad - pair.dyaw_rad)) < 2.0


def test_branch_and_bound_equals_exhaustive():
    rng = np.random.default_rng(5)
    pair = simulated_pair(rng, overlap_range=(0.6, 1.0), noise_m=0.02)
    ref, mov = scan_points(pair.reference), scan_points(pair.moving)[::4]
    pyr = LikelihoodPyramid(ref, 0.1, 0.1, 1.5, 3)
    angles = np.radians([-4.0, 0.0, 4.0])
    nodes, scores = branch_and_bound(pyr, mov, angles, 10, 0.999)
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    cells = pyr.cells(np.stack([c * mov[:, 0] - s * mov[:, 1], s * mov[:, 0] + c * mov[:, 1]], axis=-1))
    g = np.arange(-10, 11)
    gx, gy, ga = np.meshgrid(g, g, np.arange(3), indexing="ij")
    allnodes = np.column_stack([gx.ravel(), gy.ravel(), ga.ravel()])
    exhaustive = pyr.score(0, cells, allnodes[:, :2], allnodes[:, 2])
    assert math.isclose(float(scores[0]), float(exhaustive.max()), rel_tol=1e-6)


def test_no_overlap_is_not_converged():
    rng = np.random.default_rng(6)
    flags = [CorrelativeMatcher().match(p.reference, p.moving, CorrelativeParams(), rng=rng).converged
             for p in (simulated_pair(rng, overlapping=False) for _ in range(6))]
    assert not any(flags)


def test_ridge_is_not_a_rival_but_a_separate_peak_is():
    """A rival joined to the best by a high ridge is the same peak; one behind a valley is ambiguous."""
    from cistern_plugins.correlative import valley

    wall = np.column_stack([np.linspace(-3, 3, 121), np.zeros(121)])  # one long wall: a ridge along x
    pyr = LikelihoodPyramid(wall, 0.05, 0.08, 2.0, 1)
    angles = np.zeros(1)
    best, along, across = np.array([0, 0, 0]), np.array([20, 0, 0]), np.array([0, 20, 0])
    seg = wall[40:81]  # a 2 m piece of the wall, matched at several shifts along it
    assert valley(pyr, seg, angles, best, along) > 0.8
    assert valley(pyr, seg, angles, best, across) < 0.2


def _corridor_scan(x0: float) -> RangeScan:
    """A station at ``x = x0`` in a long corridor (walls at y = ±1 m, a cross wall at x = 8 m): seen
    from 5 m off, only the side walls are in range, so along the corridor every shift fits."""
    from cistern_archive.core.scan import RangeScan

    bearings = np.radians(np.arange(0.0, 360.0, 1.0))
    with np.errstate(divide="ignore"):
        to_side = np.where(np.abs(np.sin(bearings)) > 1e-9, 1.0 / np.abs(np.sin(bearings)), np.inf)
    ranges = np.where(to_side <= 4.0, to_side, np.nan)
    return RangeScan(bearings, ranges, 0.0, 1.0, 4.0, 0.05, math.radians(3.0), station=f"x{x0:g}")


def test_an_ambiguous_match_reports_its_rival_places_and_a_unique_one_none():
    rng = np.random.default_rng(3)
    res = CorrelativeMatcher().match(_corridor_scan(0.0), _corridor_scan(1.0), CorrelativeParams(), rng=rng)
    assert not res.converged and res.reason.startswith("ambiguous")
    assert 1 <= len(res.alternatives) <= 3
    for rival in res.alternatives:
        assert abs(rival.dy_m - res.dy_m) < 0.2  # along the corridor, not across it
        assert abs(rival.dx_m - res.dx_m) > CorrelativeParams().ambiguity_distance_m
        assert rival.radius_m == CorrelativeParams().ambiguity_distance_m
    # An L-shaped room seen from two stations 2 m apart: one place fits (a random room drawn here before
    # sat at the ambiguity ratio's edge, its rival at 0.90 of the best once free space is bounded by the
    # neighbouring beams at 1.8° steps).
    room = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [3.5, 4.0], [3.5, 5.0], [0.0, 5.0]])
    reference = polygon_scan([room], (1.5, 1.5), 0.0, rng=rng, n_beams=200, max_range_m=8.0, range_noise_m=0.02)
    moving = polygon_scan([room], (3.2, 2.6), 0.0, rng=rng, n_beams=200, max_range_m=8.0, range_noise_m=0.02)
    unique = CorrelativeMatcher().match(reference, moving, CorrelativeParams(), rng=rng)
    assert unique.converged and unique.alternatives == ()
    assert math.hypot(unique.dx_m - 1.7, unique.dy_m - 1.1) < 0.05


def test_a_reference_pyramid_is_built_once_and_changes_no_result():
    from cistern_plugins.correlative import PYRAMIDS

    rng = np.random.default_rng(11)
    pair = simulated_pair(rng, overlap_range=(0.6, 1.0), offset_range_m=(1.5, 2.0), noise_m=0.02)
    PYRAMIDS.items.clear()
    first = CorrelativeMatcher().match(pair.reference, pair.moving, CorrelativeParams(), rng=rng)
    assert len(PYRAMIDS.items) == 1
    PYRAMIDS.items.clear()
    fresh = CorrelativeMatcher().match(pair.reference, pair.moving, CorrelativeParams(), rng=rng)
    assert (first.dx_m, first.dy_m, first.dyaw_rad, first.weight) == (fresh.dx_m, fresh.dy_m, fresh.dyaw_rad, fresh.weight)
    again = CorrelativeMatcher().match(pair.reference, pair.moving, CorrelativeParams(), rng=rng)  # from the cache
    assert len(PYRAMIDS.items) == 1
    assert (again.dx_m, again.dy_m, again.weight) == (fresh.dx_m, fresh.dy_m, fresh.weight)
    moved = replace(pair.reference, ranges_m=pair.reference.ranges_m + 0.01)  # other echoes, another pyramid
    CorrelativeMatcher().match(moved, pair.moving, CorrelativeParams(), rng=rng)
    assert len(PYRAMIDS.items) == 2


def _compass_turned(correction_deg: float):
    """A well-posed pair whose moving compass is turned so that its true heading correction is
    ``correction_deg``: (pair, moving scan)."""
    pair = simulated_pair(np.random.default_rng(11), overlap_range=(0.6, 1.0), offset_range_m=(1.5, 2.0),
                          noise_m=0.02)
    turn = pair.dyaw_rad - math.radians(correction_deg)
    return pair, replace(pair.moving, yaw_rad=pair.moving.yaw_rad + turn)


def test_a_heading_beyond_the_yaw_window_is_searched_for_not_clamped_to_its_edge():
    """With the compass 25° off (beyond the ±12° window), the best pose of the first search lies on the
    window's edge: the search is widened and finds the heading; capped at 12° it refuses instead of
    converging on the edge."""
    pair, moving = _compass_turned(25.0)
    rng = np.random.default_rng(0)
    res = CorrelativeMatcher().match(pair.reference, moving, CorrelativeParams(), rng=rng)
    assert res.converged, res.reason
    assert abs(math.degrees(res.dyaw_rad) - 25.0) < 2.0
    np.testing.assert_allclose([res.dx_m, res.dy_m], [pair.dx_m, pair.dy_m], atol=0.1)
    capped = CorrelativeMatcher().match(pair.reference, moving, CorrelativeParams(max_search_deg=12.0), rng=rng)
    assert not capped.converged and "edge of the ±12° search" in capped.reason


def test_a_refinement_that_turns_the_heading_out_of_the_searched_window_is_refused():
    """Around a guess whose heading is 10° off, the ±6° search's best lies on its edge and the refinement
    turns it on, out of the window the search covered: a pose the search never scored, refused. A guess 2°
    off is matched."""
    pair, moving = _compass_turned(0.0)
    rng = np.random.default_rng(0)
    far = MatchGuess(pair.dx_m, pair.dy_m, math.radians(10.0), 0.5)
    res = CorrelativeMatcher().match(pair.reference, moving, CorrelativeParams(), rng=rng, guess=far)
    assert not res.converged and "beyond its ±6° window" in res.reason
    near = MatchGuess(pair.dx_m, pair.dy_m, math.radians(2.0), 0.5)
    ok = CorrelativeMatcher().match(pair.reference, moving, CorrelativeParams(), rng=rng, guess=near)
    assert ok.converged, ok.reason
    assert abs(math.degrees(ok.dyaw_rad)) < 2.0


def _round_room_pair(seed: int):
    """Two scans of a round room 5.2 m across, their compasses exact: the walls look alike at every heading."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2 * math.pi, 180, endpoint=False)
    room = [np.column_stack([2.6 * np.cos(t), 2.6 * np.sin(t)])]
    reference = polygon_scan(room, (-0.5, 0.2), 0.3, rng=rng, n_beams=400, range_noise_m=0.03, depth_m=1.0)
    moving = polygon_scan(room, (0.6, -0.3), 1.1, rng=rng, n_beams=400, range_noise_m=0.03, depth_m=1.0)
    return reference, moving


def test_a_room_that_looks_alike_turned_keeps_the_compass_heading():
    """In a round room every heading scores within a few per cent of the best, and the highest is the
    noise's choice (7.7° and 12° off here with ``flat_heading_share`` 0); among the equally good poses the
    one nearest the compass is taken, and the displacement comes out right with it."""
    for seed in (2, 5):
        reference, moving = _round_room_pair(seed)
        rng = np.random.default_rng(0)
        loose = CorrelativeMatcher().match(reference, moving, CorrelativeParams(flat_heading_share=0.0), rng=rng)
        assert abs(math.degrees(loose.dyaw_rad)) > 5.0
        res = CorrelativeMatcher().match(reference, moving, CorrelativeParams(), rng=rng)
        assert res.converged, res.reason
        assert abs(math.degrees(res.dyaw_rad)) < 2.0
        np.testing.assert_allclose([res.dx_m, res.dy_m], [1.1, -0.5], atol=0.03)


def test_equally_good_poses_give_way_to_the_one_nearest_the_centre_only_where_they_span_headings():
    from cistern_plugins.correlative import nearest_heading_first

    angles = np.radians(np.arange(-10.0, 11.0, 1.0))  # 21 yaws, index 10 the centre
    nodes = np.array([[0, 0, 2], [1, 0, 9], [5, 5, 10], [0, 1, 18]])
    scores = np.array([1.00, 0.97, 0.90, 0.96])
    first, ordered = nearest_heading_first(nodes, scores, angles, 0.05, math.radians(4.0))
    assert first[0].tolist() == [1, 0, 9] and ordered[0] == 0.97  # within 5 %, nearest the centre
    assert sorted(map(tuple, first.tolist())) == sorted(map(tuple, nodes.tolist()))
    narrow = nodes[:2], scores[:2]  # within 5 % but 7° apart only: kept as it is at a 10° span
    same, _ = nearest_heading_first(*narrow, angles, 0.05, math.radians(10.0))
    assert same[0].tolist() == [0, 0, 2]
    off, _ = nearest_heading_first(nodes, scores, angles, 0.0, math.radians(4.0))
    assert off[0].tolist() == [0, 0, 2]


def test_a_refinement_that_loses_the_search_score_keeps_the_searched_pose(bundled_catalog):
    """The bundled three-chamber cistern's b1 and o2 (o2 in the far tunnel's mouth, 5.2 m off, sharing
    a few walls of chamber b): around the site's guess the search's best pose lies 0.02 m from the truth,
    and point-to-line ICP from there slid onto another fit of those walls, turned 5.3° and 0.11 m off,
    which the search's own score puts a quarter lower. The searched pose is kept; it converges."""
    from cistern_archive.catalog.loader import load_record
    from cistern_archive.evaluation import in_compass_frame
    from cistern_archive.pipeline.runner import range_scans

    loaded = load_record(bundled_catalog / "sites" / "three-chambers.yaml", bundled_catalog)
    scans = {scan.station: scan for scan in range_scans(loaded)}
    reference, moving = scans["b1"], scans["o2"]
    truth = {t.station: t for t in loaded.record.truth}
    offset = np.array([truth["o2"].x_m - truth["b1"].x_m, truth["o2"].y_m - truth["b1"].y_m])
    guess = MatchGuess(5.132, -0.921, 0.004, 0.5)  # the site's guess for this pair (from its solution)
    res = CorrelativeMatcher().match(reference, moving, CorrelativeParams(), rng=np.random.default_rng(0), guess=guess)
    assert res.converged, res.reason
    expected = in_compass_frame(offset, reference.yaw_rad - math.radians(truth["b1"].yaw_deg))
    assert float(np.hypot(*(np.array([res.dx_m, res.dy_m]) - expected))) < 0.05
    p = CorrelativeParams().for_scans(reference, moving)
    pyr = reference_pyramid(reference, ReferenceModel(reference), p, 0.5 + 4 * p.sigma_m)
    points = thinned(scan_points(moving), 2 * p.resolution_m)
    slid = np.array([5.077, -0.829, math.radians(4.9)])  # where the refinement had taken it
    assert pose_score(pyr, points, slid) < 0.8 * pose_score(pyr, points, np.array([res.dx_m, res.dy_m, res.dyaw_rad]))
    assert not keeps_score(pyr, points, np.array([res.dx_m, res.dy_m, res.dyaw_rad]), slid, p)


def test_keeps_score_allows_what_the_lattice_can_cost_and_no_more():
    """A refinement within half a cell of the searched pose is kept (at most the likelihood's fall over half
    a cell is lost); one a cell off walls on both sides, or turned 3° off walls 3 m away, is not."""
    t = np.linspace(0.0, 3.0, 121)
    walls = np.concatenate([np.column_stack([t, np.zeros_like(t)]), np.column_stack([np.zeros_like(t), t]),
                            np.column_stack([t, np.full_like(t, 3.0)])])
    p = CorrelativeParams()
    pyr = LikelihoodPyramid(walls, p.resolution_m, p.sigma_m, 1.0, 1)
    at_walls = np.zeros(3)
    half_cell = np.array([p.resolution_m / 2, p.resolution_m / 2, 0.0])
    turned = np.array([0.0, 0.0, math.radians(3.0)])
    assert pose_score(pyr, walls, turned) < 0.9 * pose_score(pyr, walls, at_walls)
    assert keeps_score(pyr, walls, at_walls, half_cell, p)
    assert not keeps_score(pyr, walls, at_walls, turned, p)
    assert not keeps_score(pyr, walls, at_walls, 2 * half_cell, p)  # a cell off both walls: 12 % lower
    assert keeps_score(pyr, walls, turned, at_walls, p)  # a refinement that gains is always kept
