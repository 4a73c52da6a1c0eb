"""A wall seen from its two sides is not one wall: the inlier test of :mod:`cistern_plugins.alignment`."""

from __future__ import annotations

import numpy as np

from cistern_archive.grid.polygon import polygon_scan
from cistern_plugins.alignment import ConvergenceThresholds, ReferenceModel, seen_from_behind, verdict

# Two look-alike rooms, 0.6 m of rock between them: room A west, room B east.
ROOM_A = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]])
ROOM_B = ROOM_A + [4.6, 0.0]


def test_a_wall_point_is_behind_only_for_a_sonar_on_its_other_side():
    wall = np.array([[4.0, 1.5], [4.0, 1.0]])  # on A's east wall, reference sonar at the origin
    normals = np.array([[1.0, 0.0], [-1.0, 0.0]])  # the sign of a normal does not matter
    assert seen_from_behind(wall, normals, np.array([6.0, 1.5])).tolist() == [True, True]
    assert seen_from_behind(wall, normals, np.array([2.0, 2.5])).tolist() == [False, False]
    # a view along the wall's plane is not judged: the normal's error could flip the side
    assert seen_from_behind(wall, normals, np.array([4.3, 9.0])).tolist() == [False, False]


def test_two_rooms_laid_back_to_back_share_no_inliers():
    """The wrong match that sets two look-alike rooms side by side lays B's west wall onto A's east wall
    from behind: every point of it fits and none falls into water, yet it is refused; the right
    relative pose of two scans of one room loses no inlier to the test."""
    rng = np.random.default_rng(3)
    limits = ConvergenceThresholds()
    a = polygon_scan([ROOM_A], (2.0, 1.5), 0.0, rng=rng, n_beams=400, max_range_m=6.0)
    b = polygon_scan([ROOM_B], (6.6, 1.5), 0.0, rng=rng, n_beams=400, max_range_m=6.0)
    back_to_back = ReferenceModel(a).assess_pair(b, np.array([4.0, 0.0, 0.0]), limits)
    assert back_to_back.behind >= limits.min_inliers
    assert back_to_back.inliers < limits.min_inliers
    assert "opposite sides" in verdict(back_to_back, limits)
    same_room = polygon_scan([ROOM_A], (1.2, 1.0), 0.0, rng=rng, n_beams=400, max_range_m=6.0)
    right = ReferenceModel(a).assess_pair(same_room, np.array([-0.8, -0.5, 0.0]), limits)
    assert right.behind == 0 and verdict(right, limits) == ""
