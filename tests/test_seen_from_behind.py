"""A wall seen from its two sides is not one wall: the inlier test of :mod:`cistern_plugins.alignment`."""

from __future__ import annotations

import numpy as np
import pytest

from cistern_archive.grid.polygon import polygon_scan
from cistern_plugins.alignment import ConvergenceThresholds, ReferenceModel, parallel_walls, seen_from_behind, verdict

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


# A chamber 6 x 5 m with a tunnel 0.8 m wide leaving its east wall; a station 0.5 m inside the tunnel
# hears the tunnel's walls end right at the chamber's wall beside the mouth.
MOUTH = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 2.1], [10.0, 2.1], [10.0, 2.9], [6.0, 2.9], [6.0, 5.0], [0.0, 5.0]])


@pytest.mark.parametrize("off_m", [0.0, 0.1])
def test_a_tunnel_meeting_a_chamber_wall_at_its_mouth_is_no_wall_seen_from_behind(off_m):
    """The tunnel's side walls end on the chamber's wall beside the mouth, and the station in the tunnel
    stands behind that wall: with the sonars' positions alone its wall points there look laid on the
    chamber's wall from behind, the more so when the join is a few centimetres off along the tunnel. The
    two walls meet across each other, as at a corner, not face to face."""
    rng = np.random.default_rng(1)
    in_tunnel = polygon_scan([MOUTH], (6.5, 2.5), 0.0, rng=rng, n_beams=400, max_range_m=5.0)
    in_chamber = polygon_scan([MOUTH], (3.0, 2.5), 0.0, rng=rng, n_beams=400, max_range_m=5.0)
    pose = np.array([-3.5 + off_m, 0.0, 0.0])  # the chamber's station in the tunnel's, off along the tunnel
    assert ReferenceModel(in_tunnel).assess_pair(in_chamber, pose, ConvergenceThresholds()).behind == 0


def test_only_walls_that_run_alike_are_two_faces_of_one_wall():
    along_x, along_y = np.array([[0.0, 1.0]]), np.array([[1.0, 0.0]])
    assert parallel_walls(along_x, -along_x).tolist() == [True]
    assert parallel_walls(along_x, along_y).tolist() == [False]
    tilted = np.array([[np.sin(np.radians(30)), np.cos(np.radians(30))]])
    assert parallel_walls(along_x, tilted).tolist() == [True]
