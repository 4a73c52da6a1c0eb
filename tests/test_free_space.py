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


def test_the_reach_is_the_half_cone_unless_the_steps_are_wider():
    """At the simulator's 0.9° steps the reach is the 1.5° half cone, as it always was (the calibrated
    verification's features are unchanged); at 1.8° it is one and a half steps, the neighbours and no
    more; a cone of no width erodes nothing."""
    fine = np.radians(np.arange(0.0, 360.0, 0.9))
    coarse = np.radians(np.arange(0.0, 360.0, 1.8))
    assert erosion_reach(fine, math.radians(3.0)) == pytest.approx(math.radians(1.5))
    assert erosion_reach(coarse, math.radians(3.0)) == pytest.approx(math.radians(2.7))
    assert erosion_reach(coarse, 0.0) == 0.0
