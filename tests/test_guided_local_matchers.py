"""The local matchers (`icp`, `particle-icp`) take a localizer's guess: they start from it, and refuse an
estimate that slid out of its window."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cistern_archive.grid.polygon import polygon_scan, rectangle
from cistern_archive.pipeline.contracts import GuidedMatcher, MatchGuess
from cistern_archive.pipeline.registry import default_registry
from cistern_plugins.icp import ICPMatcher, ICPParams
from cistern_plugins.particle_icp import ParticleICPMatcher, ParticleICPParams
from cistern_plugins.registration import outside_window, start_pose, turn_from_start

# An L-shaped chamber with a pillar: the two stations lie 4.6 m apart, beyond the reach of a local fit
# started from the compass-aligned zero pose.
ROOM = [
    np.array([[0, 0], [9.0, 0], [9.0, 3.6], [4.0, 3.6], [4.0, 6.0], [0, 6.0]], float),
    rectangle(0.5, 0.5, centre=(6.8, 1.4)),
]
A_XY, B_XY = (1.6, 1.5), (6.1, 2.4)
TRUTH = (B_XY[0] - A_XY[0], B_XY[1] - A_XY[1])
MATCHERS = [(ICPMatcher, ICPParams), (ParticleICPMatcher, ParticleICPParams)]


def scan_at(xy, seed: int):
    return polygon_scan(ROOM, xy, 0.0, rng=np.random.default_rng(seed), n_beams=400, range_noise_m=0.02)


def error_m(result) -> float:
    return math.hypot(result.dx_m - TRUTH[0], result.dy_m - TRUTH[1])


@pytest.mark.parametrize("matcher, params", MATCHERS)
def test_both_local_matchers_declare_the_guided_capability(matcher, params):
    assert default_registry().load("matcher", matcher.name).has(GuidedMatcher)


@pytest.mark.parametrize("matcher, params", MATCHERS)
def test_a_guess_near_the_truth_is_matched_where_the_zero_start_is_not(matcher, params):
    a, b = scan_at(A_XY, 1), scan_at(B_XY, 2)
    unguided = matcher().match(a, b, params(), rng=np.random.default_rng(0))
    assert not (unguided.converged and error_m(unguided) < 0.1)  # beyond its reach from zero
    guess = MatchGuess(TRUTH[0] + 0.25, TRUTH[1] - 0.2, math.radians(2.0), 0.5)
    guided = matcher().match(a, b, params(), rng=np.random.default_rng(0), guess=guess)
    assert guided.converged, guided.reason
    assert error_m(guided) < 0.05


@pytest.mark.parametrize("matcher, params", MATCHERS)
def test_a_guess_far_from_the_truth_is_not_a_silent_success(matcher, params):
    """A guess 1.5 m off with a 0.4 m window: the local fit either slides out of the window towards the
    walls (refused, saying so) or settles on a wrong place that the shared verdict refuses."""
    a, b = scan_at(A_XY, 1), scan_at(B_XY, 2)
    guess = MatchGuess(TRUTH[0] - 1.5, TRUTH[1] + 0.3, 0.0, 0.4)
    result = matcher().match(a, b, params(), rng=np.random.default_rng(0), guess=guess)
    assert not result.converged and result.reason
    if "window" in result.reason:
        assert "left the ±0.4 m window around the guess" in result.reason


def test_the_guess_window_helpers():
    guess = MatchGuess(1.0, -2.0, 0.1, 0.5)
    np.testing.assert_array_equal(start_pose(None), np.zeros(3))
    np.testing.assert_allclose(start_pose(guess), [1.0, -2.0, 0.1])
    assert outside_window(np.array([1.4, -2.45, 0.0]), guess) == ""
    assert outside_window(np.array([1.6, -2.0, 0.0]), guess).startswith("estimate (1.60, -2.00) m left")
    assert outside_window(np.array([9.0, 9.0, 0.0]), None) == ""
    assert turn_from_start(np.array([0.0, 0.0, 0.1 + 2 * math.pi]), guess) == pytest.approx(0.0, abs=1e-12)
    assert turn_from_start(np.array([0.0, 0.0, -3.0]), None) == pytest.approx(-3.0)
