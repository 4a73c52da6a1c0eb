"""The factor graph of the graph localizers (:mod:`cistern_plugins.factor_graph`): the compasses as
noisy readings about one common frame, the reference scan's included."""

import math

import numpy as np
import pytest

from cistern_plugins.factor_graph import COMPASS_FRAME, Edge, GraphNoise, solve


def _edge(i, j, dx, dy, dyaw_deg, sigma_m, sigma_deg):
    covariance = np.diag([sigma_m**2, sigma_m**2, math.radians(sigma_deg) ** 2])
    return Edge(i, j, np.array([dx, dy, math.radians(dyaw_deg)]), covariance)


def test_the_reference_compass_is_one_noisy_reading_among_the_others():
    """The reference's compass reads 3° off the others. Scan 1 is tied to it tightly, so its heading
    correction is -3°; scans 2 and 3, tied to each other tightly and to scan 1 with a heading the match
    hardly knows, take the compasses' common frame: the mean of what the four readings allow (-1.5°),
    not the reference's own reading (0°)."""
    edges = [_edge(0, 1, 2.0, 0.0, -3.0, 0.02, 0.1), _edge(2, 3, 2.0, 0.0, 0.0, 0.02, 0.1),
             _edge(1, 2, 2.0, 0.0, 0.0, 0.02, 30.0)]
    _, result, _ = solve(4, edges, 0, GraphNoise(robust="none", compass_sigma_deg=2.0))
    headings = [math.degrees(result.atPose2(k).theta()) for k in range(4)]
    assert headings[0] == pytest.approx(0.0, abs=1e-3)
    assert headings[1] == pytest.approx(-3.0, abs=0.05)
    assert headings[2] == pytest.approx(-1.5, abs=0.1) and headings[3] == pytest.approx(-1.5, abs=0.1)
    assert math.degrees(result.atPose2(COMPASS_FRAME).theta()) == pytest.approx(-1.5, abs=0.1)
