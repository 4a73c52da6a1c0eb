"""Depth levels: single linkage of the scans' depths."""

import math

from cistern_archive.core.levels import depth_levels


def test_an_uneven_floor_is_one_level_however_far_its_ends_lie_apart():
    assert depth_levels([1.0, 1.7, 2.4, 3.1, 1.35], 0.8) == (0, 0, 0, 0, 0)  # 2.1 m end to end, 0.7 m steps


def test_levels_a_gap_wider_than_the_tolerance_apart_are_numbered_from_the_shallowest():
    assert depth_levels([3.6, 1.6, 2.6, 1.57, 2.61, 3.63], 0.8) == (2, 0, 1, 0, 1, 2)  # a bell's three levels
    assert depth_levels([1.0, 1.9], 0.8) == (0, 1)
    assert depth_levels([1.0, 1.8], 0.8) == (0, 0)  # the tolerance itself still joins


def test_unknown_depths_have_no_level():
    assert depth_levels([math.nan, 1.0, math.inf, 1.2], 0.5) == (-1, 0, -1, 0)
    assert depth_levels([], 0.5) == ()
