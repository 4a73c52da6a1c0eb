"""The free space one scan observed, eroded by the beam cone (:class:`cistern_plugins.alignment.FreeSpace`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cistern_archive.core.scan import RangeScan
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
