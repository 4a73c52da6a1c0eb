"""The stretch of wall one scan lays in another's water (:func:`cistern_plugins.alignment.longest_run_m`)."""

from __future__ import annotations

import numpy as np

from cistern_plugins.alignment import longest_run_m


def rough_wall(rng: np.random.Generator, start: float, stop: float, y: float, roughness: float) -> np.ndarray:
    """Points every 2 cm along ``y = const`` from ``x = start`` to ``stop``, jittered across by ``roughness``."""
    xs = np.arange(start, stop + 1e-9, 0.02)
    return np.column_stack([xs, y + rng.uniform(-roughness, roughness, len(xs))])


def test_the_longest_stretch_is_measured_along_consecutive_flagged_points():
    wall = rough_wall(np.random.default_rng(0), 1.0, 3.0, 0.5, 0.0)
    bad = np.ones(len(wall), dtype=bool)
    bad[40] = False  # 0.78 m west of an unflagged point, 1.18 m east of it
    assert abs(longest_run_m(wall, bad, 0.3) - 1.18) < 1e-9
    bad[70] = False
    assert abs(longest_run_m(wall, bad, 0.3) - 0.78) < 1e-9
    assert longest_run_m(wall, np.zeros(len(wall), dtype=bool), 0.3) == 0.0


def test_a_stretch_the_other_sonar_sees_edge_on_is_no_evidence_of_water():
    """A sonar close to a rough wall, looking along it, hears a farther echo there; the wall it did not
    hear is not laid across its water. Seen face on, the same stretch counts in full, as it does without
    the sonar's position."""
    wall = rough_wall(np.random.default_rng(1), 1.0, 3.0, 0.5, 0.05)
    bad = np.ones(len(wall), dtype=bool)
    along = longest_run_m(wall, bad, 0.3, viewer=np.array([-0.5, 0.3]))
    face_on = longest_run_m(wall, bad, 0.3, viewer=np.array([2.0, -2.0]))
    assert along == 0.0
    assert face_on > 2.0  # the jitter lengthens the path along the points
    assert face_on == longest_run_m(wall, bad, 0.3)
