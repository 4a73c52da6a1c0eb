"""The free space one scan observed, eroded by the beam cone (:class:`cistern_plugins.alignment.FreeSpace`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from cistern_archive.core.scan import RangeScan, wrap_angle
from cistern_plugins.alignment import FreeSpace, erosion_reach


def jamb_scan(step_deg: float, jamb_beam: int, *, beam_width_deg: float = 3.0) -> RangeScan:
    """A full turn in ``step_deg`` steps seeing a wall 5 m off, but for one beam that hears the jamb of
    an opening 1 m off."""
    bearings = np.radians(np.arange(0.0, 360.0, step_deg))
    ranges = np.full(len(bearings), 5.0)
    ranges[jamb_beam] = 1.0
    return RangeScan(bearings_rad=bearings, ranges_m=ranges, yaw_rad=0.0, depth_m=1.0, max_range_m=6.0,
                     bin_size_m=0.04, beam_width_rad=math.radians(beam_width_deg))


def point_at(bearing_deg: float, range_m: float) -> np.ndarray:
    b = math.radians(bearing_deg)
    return np.array([[range_m * math.cos(b), range_m * math.sin(b)]])


@pytest.mark.parametrize("step_deg", [0.9, 1.8])
def test_a_point_inside_the_jamb_beams_cone_is_not_free_whatever_the_step(step_deg):
    """A point 1.0° from the jamb's beam lies inside its 3° cone, so the sonar did not see it free
    however far the next beam reached. At 1.8° steps the point's nearest beam is the next one, whose
    own half cone (1.5°) does not reach the jamb's beam: the neighbours bound it all the same."""
    free = FreeSpace(jamb_scan(step_deg, jamb_beam=50))
    jamb_bearing = 50 * step_deg
    assert not free.in_free_space(point_at(jamb_bearing + 1.0, 2.0), margin_m=0.1)[0]
    assert free.in_free_space(point_at(jamb_bearing + 4.0, 2.0), margin_m=0.1)[0]


def test_a_beam_that_heard_nothing_gains_no_water_from_its_neighbours():
    """A beam with no echo (a far wall met obliquely, too faint to answer) between a beam that heard a
    wall 5 m off and beams that heard nothing: its neighbour's cone covers its bearing, but what its own
    axis did not hear, the cone's edge did not hear either, so a point 4 m off on its bearing is not
    free; on the neighbour's own bearing it is. The wall in the cone may still hide what lies behind
    it on that bearing: a point beyond it is not one the sonar could have seen."""
    for step_deg in (0.9, 1.8):
        bearings = np.radians(np.arange(0.0, 360.0, step_deg))
        ranges = np.full(len(bearings), np.nan)
        ranges[:40] = 5.0
        scan = RangeScan(bearings_rad=bearings, ranges_m=ranges, yaw_rad=0.0, depth_m=1.0, max_range_m=6.0,
                         bin_size_m=0.04, beam_width_rad=math.radians(3.0))
        free = FreeSpace(scan)
        assert free.in_free_space(point_at(39 * step_deg, 4.0), margin_m=0.1)[0]
        assert not free.in_free_space(point_at(40 * step_deg, 4.0), margin_m=0.1)[0]
        assert not free.violations(point_at(40 * step_deg, 4.0), margin_m=0.1)[1]
        assert not free.visible(point_at(40 * step_deg, 5.5), tolerance_m=0.1)[0]  # behind the wall in its cone
        assert free.visible(point_at(200.0, 5.5), tolerance_m=0.1)[0]


def test_the_reach_is_the_half_cone_unless_the_steps_are_wider():
    """At the simulator's 0.9° steps the reach is the 1.5° half cone, as it always was (the calibrated
    verification's features are unchanged); at 1.8° it is one and a half steps, the neighbours and no
    more; a cone of no width erodes nothing."""
    fine = np.radians(np.arange(0.0, 360.0, 0.9))
    coarse = np.radians(np.arange(0.0, 360.0, 1.8))
    assert erosion_reach(fine, math.radians(3.0)) == pytest.approx(math.radians(1.5))
    assert erosion_reach(coarse, math.radians(3.0)) == pytest.approx(math.radians(2.7))
    assert erosion_reach(coarse, 0.0) == 0.0


ROOM = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [3.5, 4.0], [3.5, 5.0], [0.0, 5.0]])


@pytest.mark.parametrize("seed", [0, 1])
def test_inliers_are_counted_as_points_at_the_calibration_step(seed):
    """The same match at 1.8° steps has half the inlier points of one at 0.9°; counted as points at the
    calibration's 0.9° it has as many, and the same predicted σ along its weakest direction (to the
    precision of the two scans' noise)."""
    from cistern_archive.grid.polygon import polygon_scan
    from cistern_plugins.alignment import ConvergenceThresholds, ReferenceModel

    rng = np.random.default_rng(seed)
    qualities = {}
    for beams in (400, 200):
        a = polygon_scan([ROOM], (1.5, 1.5), 0.0, rng=rng, n_beams=beams, max_range_m=8.0, range_noise_m=0.02)
        b = polygon_scan([ROOM], (4.0, 2.0), 0.0, rng=rng, n_beams=beams, max_range_m=8.0, range_noise_m=0.02)
        qualities[beams] = ReferenceModel(a).assess_pair(b, np.array([2.5, 0.5, 0.0]), ConvergenceThresholds())
    fine, coarse = qualities[400], qualities[200]
    assert fine.point_weight == pytest.approx(1.0) and coarse.point_weight == pytest.approx(2.0)
    assert coarse.inliers == pytest.approx(fine.inliers / 2, rel=0.1)
    assert coarse.equivalent_inliers == pytest.approx(fine.equivalent_inliers, rel=0.1)
    assert coarse.weak_std_m == pytest.approx(fine.weak_std_m, rel=0.2)
    assert coarse.line_rms_m <= coarse.rms_m


def sonar_scan(bearings_deg: np.ndarray, ranges_m: np.ndarray, *, yaw_rad: float = 0.0) -> RangeScan:
    """A scan of a 6 m head with a 3° beam from the origin: ``ranges_m`` (nan: no echo) on ``bearings_deg``."""
    return RangeScan(bearings_rad=np.radians(bearings_deg), ranges_m=ranges_m, yaw_rad=yaw_rad, depth_m=1.0,
                     max_range_m=6.0, bin_size_m=0.04, beam_width_rad=math.radians(3.0))


def silent_scan(heard_deg: tuple[float, float], *, step_deg: float = 0.9, range_m: float = 3.0) -> RangeScan:
    """A full turn hearing a wall ``range_m`` off on the bearings from ``heard_deg[0]`` up to
    ``heard_deg[1]`` (degrees, wrapping through 0) and nothing on the others."""
    bearings = np.arange(0.0, 360.0, step_deg)
    lo, hi = heard_deg
    heard = (np.mod(bearings - lo, 360.0) < np.mod(hi - lo, 360.0))
    ranges = np.where(heard, range_m, np.nan)
    return sonar_scan(bearings, ranges)


def test_a_wide_run_of_silent_beams_saw_open_water_out_to_a_share_of_the_range():
    """Walls heard on three quarters of the turn and a quarter silent (a corner of a chamber larger than
    the sonar's range): the silent quarter saw water out to ``OPEN_RANGE_SHARE`` of the 6 m range, and
    nothing about what lies beyond; on its edges the heard beams' cones still bound it. Only for the
    checks that ask for it (``open_sector_rad``): by default a silent beam says nothing."""
    from cistern_plugins.alignment import OPEN_RANGE_SHARE

    scan = silent_scan((270.0, 180.0))  # silent from 180° to 270°, across no wrap
    wide = FreeSpace(scan, open_sector_rad=math.radians(20.0))
    open_m = OPEN_RANGE_SHARE * 6.0
    assert wide.in_free_space(point_at(225.0, open_m - 0.5), margin_m=0.1)[0]
    assert not wide.in_free_space(point_at(225.0, open_m + 0.5), margin_m=0.1)[0]
    assert not wide.in_free_space(point_at(180.0, open_m - 0.5), margin_m=0.1)[0]  # in the cone of a heard beam
    assert not FreeSpace(scan).in_free_space(point_at(225.0, 2.0), margin_m=0.1)[0]
    assert wide.visible(point_at(225.0, 5.5), tolerance_m=0.1)[0]  # what may hide a point is unchanged


def test_a_silent_run_saw_water_no_farther_than_the_noise_lets_the_sonar_hear():
    """The same quarter silent with the range set to 20 m: beyond the scan's detection range (9 m) the
    receiver's noise hid any wall, so the silence there claims no water, whatever share of the range."""
    from cistern_plugins.alignment import open_water_m

    scan = dataclasses.replace(silent_scan((270.0, 180.0)), max_range_m=20.0, detection_range_m=9.0)
    assert open_water_m(scan) == 9.0
    assert open_water_m(dataclasses.replace(scan, detection_range_m=math.inf)) == 15.0
    wide = FreeSpace(scan, open_sector_rad=math.radians(20.0))
    assert wide.in_free_space(point_at(225.0, 8.5), margin_m=0.1)[0]
    assert not wide.in_free_space(point_at(225.0, 9.5), margin_m=0.1)[0]


def test_silent_beams_saw_water_to_the_farther_flank_of_a_narrow_run_and_far_in_a_wide_one():
    """:func:`~cistern_plugins.alignment.silent_water`: a few silent beams between echoes at 2 m and 4 m
    (a wall met at grazing incidence) saw water out to 4 m, not to 0.75 of the range; a run across the
    turn's start is one run; a wide run saw water out to :func:`open_water_m`, and no farther than the
    scan's detection range."""
    from cistern_plugins.alignment import silent_water

    bearings = np.arange(0.0, 360.0, 0.9)
    ranges = np.full(len(bearings), 3.0)
    ranges[[9, 13]] = 2.0, 4.0
    ranges[10:13] = np.nan  # silent between 2 m and 4 m
    ranges[[398, 1]] = 3.5, 2.5
    ranges[[399, 0]] = np.nan  # silent across the turn's start
    ranges[100:150] = np.nan  # 45° silent
    scan = sonar_scan(bearings, ranges, yaw_rad=0.4)
    filled = silent_water(scan, math.radians(20.0)).ranges_m
    assert np.all(filled[10:13] == 4.0)
    assert np.all(filled[[399, 0]] == 3.5)
    assert np.all(filled[100:150] == 4.5)
    assert np.all(silent_water(dataclasses.replace(scan, detection_range_m=3.8), math.radians(20.0)).ranges_m[10:13]
                  == 3.8)
    assert np.array_equal(np.isfinite(filled), np.ones(len(bearings), dtype=bool))


def test_a_group_sees_water_behind_silent_beams_no_farther_than_their_flanks_or_its_hearing():
    """A group's water (:class:`~cistern_plugins.group_clouds.Cloud`), with the range set to 20 m: a few
    silent beams (9°) between walls 3 m off claim water to 3 m, not 15 m through the rock; a wide silent
    run claims it out to 0.75 of the range, and no farther than where the receiver's noise began to
    hide walls."""
    from cistern_plugins.group_clouds import Cloud

    origin = np.zeros(3)
    few = dataclasses.replace(silent_scan((9.0, 0.0)), max_range_m=20.0)  # silent from 0° to 9°
    assert Cloud([few], [origin]).in_free_space(point_at(4.5, 2.5)).any()
    assert not Cloud([few], [origin]).in_free_space(point_at(4.5, 4.0)).any()
    wide = dataclasses.replace(silent_scan((270.0, 180.0)), max_range_m=20.0)
    assert Cloud([wide], [origin]).in_free_space(point_at(225.0, 12.0)).any()
    heard_to_9m = dataclasses.replace(wide, detection_range_m=9.0)
    assert Cloud([heard_to_9m], [origin]).in_free_space(point_at(225.0, 8.0)).any()
    assert not Cloud([heard_to_9m], [origin]).in_free_space(point_at(225.0, 12.0)).any()


def test_a_narrow_silent_run_or_a_scan_that_heard_nothing_says_nothing():
    """Ten silent beams (9°, a far wall met obliquely too faint to answer) claim no water, whether the
    run lies in the middle of the turn or across its start, nor do the silent ends of a sector scan, 200°
    apart across the bearings it never swept; a scan that heard nothing at all tells open water from a
    sonar that failed in no way, and claims none either."""
    for heard in ((99.0, 90.0), (9.0, 0.0)):  # silent 90°–99°, and 0°–9° across the wrap
        free = FreeSpace(silent_scan(heard), open_sector_rad=math.radians(20.0))
        assert not free.in_free_space(point_at(heard[1] + 4.5, 2.0), margin_m=0.1)[0]
    wrapped = FreeSpace(silent_scan((40.0, 330.0)), open_sector_rad=math.radians(20.0))  # 330°–40° silent
    assert wrapped.in_free_space(point_at(5.0, 2.0), margin_m=0.1)[0]
    sector = np.arange(100.0, 260.0, 0.9)  # a sector scan silent for 9° at either end: two runs, not one
    ends = np.where((sector < 109.0) | (sector > 251.0), np.nan, 3.0)
    scan = sonar_scan(sector, ends)
    assert not FreeSpace(scan, open_sector_rad=math.radians(10.0)).in_free_space(point_at(255.0, 2.0), 0.1)[0]
    bearings = np.arange(0.0, 360.0, 0.9)
    deaf = sonar_scan(bearings, np.full(len(bearings), np.nan))
    assert not FreeSpace(deaf, open_sector_rad=math.radians(20.0)).in_free_space(point_at(90.0, 2.0), 0.1)[0]


def test_a_corner_heard_alone_is_no_corner_of_a_smaller_room():
    """A station 1 m from the corner of a 14 m x 10 m chamber, its sonar reaching 6 m, hears the corner's
    two walls and nothing to the north-east. A 5 m x 4 m room's corner fits those walls exactly; laid
    there, that room's other two walls cross the water the first sonar saw in its silent quarter, and
    the fit is refused. A station of the same large chamber at its true place is not."""
    from cistern_archive.grid.polygon import polygon_scan
    from cistern_plugins.alignment import ConvergenceThresholds, ReferenceModel, hard_limits

    rng = np.random.default_rng(3)
    hall = np.array([[0.0, 0.0], [14.0, 0.0], [14.0, 10.0], [0.0, 10.0]])
    room = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 4.0], [0.0, 4.0]])
    corner = polygon_scan([hall], (1.0, 1.0), 0.0, rng=rng, n_beams=400, max_range_m=6.0, range_noise_m=0.01)
    small = polygon_scan([room], (2.5, 2.0), 0.0, rng=rng, n_beams=400, max_range_m=6.0, range_noise_m=0.01)
    same_hall = polygon_scan([hall], (3.0, 2.5), 0.0, rng=rng, n_beams=400, max_range_m=6.0, range_noise_m=0.01)
    limits = ConvergenceThresholds()
    model = ReferenceModel(corner)
    look_alike = model.assess_pair(small, np.array([1.5, 1.0, 0.0]), limits)
    assert look_alike.violation_run_m > limits.max_violation_run_m
    assert "free space" in hard_limits(look_alike, limits)
    right = model.assess_pair(same_hall, np.array([2.0, 1.5, 0.0]), limits)
    assert right.violation_run_m == 0.0 and hard_limits(right, limits) == ""


def test_a_cloud_gathered_along_a_track_shows_no_free_space():
    """The echoes of a moving vehicle compensated into one frame were heard from along its track, not
    on beams from the station: the line from the station to an echo says nothing of its water. Free
    space is then unknown everywhere (every free-space test passes); what lies behind an echo is still
    hidden from the station's view."""
    stationary = jamb_scan(0.9, jamb_beam=50)
    cloud = dataclasses.replace(stationary, rays_from_station=False)
    inside = point_at(200.0, 2.0)
    assert FreeSpace(stationary).in_free_space(inside, margin_m=0.1)[0]
    assert FreeSpace(stationary).violations(inside, margin_m=0.1) == (1, 1)
    assert not FreeSpace(cloud).in_free_space(inside, margin_m=0.1)[0]
    assert FreeSpace(cloud).violations(inside, margin_m=0.1) == (0, 0)
    assert not FreeSpace(cloud).visible(point_at(200.0, 5.5), tolerance_m=0.1)[0]


def opening_scan(walls_m: float = 3.0, max_range_m: float = 10.0) -> RangeScan:
    """A full turn at 0.9° steps hearing walls ``walls_m`` off, but for 15 beams about bearing 0 that
    heard nothing: an opening the sonar looks through."""
    bearings = np.radians(np.arange(0.0, 360.0, 0.9))
    ranges = np.full(len(bearings), walls_m)
    ranges[np.abs(wrap_angle(bearings)) <= math.radians(6.5)] = np.nan
    return RangeScan(bearings_rad=bearings, ranges_m=ranges, yaw_rad=0.0, depth_m=1.0, max_range_m=max_range_m,
                     bin_size_m=0.04, beam_width_rad=math.radians(3.0))


def wall_across(x_m: float, half_m: float = 0.15, n: int = 11) -> tuple[np.ndarray, np.ndarray]:
    """Points of a wall across bearing 0 at ``x_m``, and their (unsigned) normals."""
    points = np.column_stack([np.full(n, x_m), np.linspace(-half_m, half_m, n)])
    return points, np.tile([[1.0, 0.0]], (n, 1))


def test_a_wall_facing_the_sonar_where_it_heard_nothing_contradicts_the_pose():
    """Another sonar heard a wall 2 m off across the opening, from this sonar's side: turned towards this
    sonar, met head-on and well within its hearing, it would have answered."""
    free = FreeSpace(opening_scan())
    points, normals = wall_across(2.0)
    assert free.unheard_facing(points, normals, seen_from=np.array([1.0, 0.5])).all()


def test_silence_says_nothing_of_a_wall_from_behind_obliquely_far_or_on_a_heard_beam():
    """The back of that wall (the other sonar beyond it, as beside an opening the beam looks through),
    the same wall turned 60° from the ray, one beyond three quarters of its hearing, and one on beams that
    heard an echo are no contradiction."""
    free = FreeSpace(opening_scan())
    points, normals = wall_across(2.0)
    assert not free.unheard_facing(points, normals, seen_from=np.array([3.0, 0.0])).any()
    oblique = np.tile([[math.cos(math.radians(60.0)), math.sin(math.radians(60.0))]], (len(points), 1))
    assert not free.unheard_facing(points, oblique, seen_from=np.array([0.0, 0.0])).any()
    far, far_normals = wall_across(6.0)
    assert not free.unheard_facing(far, far_normals, seen_from=np.array([1.0, 0.0])).any()
    turned = points @ np.array([[0.0, 1.0], [-1.0, 0.0]])  # the same wall about bearing 90°: heard beams
    assert not free.unheard_facing(turned, normals @ np.array([[0.0, 1.0], [-1.0, 0.0]]),
                                   seen_from=np.array([0.0, 1.0])).any()


def test_silence_between_two_echoes_is_heard_as_far_as_they_are():
    """The opening's jambs heard 5.3 m off on either side of the silence, at 0.9 of a 6 m range: a wall
    across it at 5.4 m, facing the sonar, would have answered as they did, though it lies beyond the
    share of the range a silent beam vouches for by itself (``HEARD_SHARE`` of ``open_water_m``: 3.4 m).
    One 10 % farther than the jambs, or beyond where the segmentation could tell a wall at all
    (``detection_range_m``: the end of the range holds no shadow), says nothing."""
    scan = opening_scan(walls_m=5.3, max_range_m=6.0)
    behind = np.array([6.5, 0.0])  # the other sonar, beyond the wall in the twin chamber's frame
    for x_m, answers in ((5.4, True), (5.9, False)):
        points, normals = wall_across(x_m)
        assert FreeSpace(scan).unheard_facing(points, normals, seen_from=np.array([x_m - 0.5, 0.0])).all() == answers
        assert not FreeSpace(scan).unheard_facing(points, normals, seen_from=behind).any()
    points, normals = wall_across(5.4)
    deaf_end = dataclasses.replace(scan, detection_range_m=5.35)
    assert not FreeSpace(deaf_end).unheard_facing(points, normals, seen_from=np.array([4.9, 0.0])).any()
