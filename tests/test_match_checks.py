"""No NaN, ever: the runner turns bad matcher output into that pair's failure, and every built-in
matcher survives degenerate scans with an honest answer."""

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cistern_archive.pipeline.checks import checked_match
from cistern_archive.pipeline.contracts import MatchResult, StageParams
from cistern_archive.pipeline.registry import default_registry
from cistern_archive.pipeline.runner import Stage, match_pair, resolve_stage
from cistern_archive.core.scan import RangeScan

MATCHERS = ["pf-pairwise", "icp", "correlative", "particle-icp"]


def _result(**changes):
    values = dict(i=-1, j=-1, dx_m=1.0, dy_m=0.5, dyaw_rad=0.01, weight=0.8, converged=True, iterations=3,
                  seconds=0.01, covariance=np.diag([1e-3, 1e-3, 1e-5]))
    values.update(changes)
    return MatchResult(**values)


@pytest.mark.parametrize("changes, words", [
    ({"dx_m": float("nan")}, "non-finite dx_m"),
    ({"dyaw_rad": float("inf")}, "non-finite dyaw_rad"),
    ({"weight": float("nan")}, "non-finite weight"),
    ({"covariance": np.full((3, 3), np.nan)}, "non-finite"),
    ({"covariance": np.eye(2)}, "shape (2, 2)"),
    ({"covariance": np.array([[1.0, 0.5, 0], [0.0, 1, 0], [0, 0, 1]])}, "not symmetric"),
    ({"covariance": -np.eye(3)}, "not positive definite"),
    ({"confidence": 1.5}, "confidence"),
])
def test_bad_converged_output_becomes_a_failed_pair_with_a_reason(changes, words):
    checked = checked_match(_result(**changes))
    assert not checked.converged and not checked.tentative
    assert checked.reason.startswith("unusable matcher output") and words in checked.reason


def test_good_output_passes_unchanged_and_a_failure_keeps_its_own_reason():
    good = _result()
    assert checked_match(good) is good
    failed = checked_match(MatchResult.no_estimate("too few echoes", seconds=0.0))
    assert failed.reason == "too few echoes" and not failed.converged


def test_unusable_alternatives_are_dropped_and_usable_ones_kept():
    from cistern_archive.pipeline.contracts import MatchGuess

    good, nan, flat = MatchGuess(2.0, 1.0, 0.0, 0.5), MatchGuess(float("nan"), 1.0, 0.0, 0.5), MatchGuess(1.0, 1.0, 0.0, 0.0)
    checked = checked_match(_result(alternatives=(nan, good, flat)))
    assert checked.alternatives == (good,) and checked.converged


class _Degenerate:
    """A matcher that always claims convergence with NaN: the runner must contain it."""

    name = "nan-matcher"

    class Params(StageParams):
        pass

    def match(self, reference, moving, params, *, rng):
        return _result(dx_m=float("nan"))


def test_match_pair_contains_a_lying_matcher():
    scan = RangeScan(np.linspace(-np.pi, np.pi, 8, endpoint=False), np.ones(8), 0.0, 1.0, 5.0, 0.05, 0.05)
    result = match_pair(Stage.of("matcher", _Degenerate()), [scan, scan], 0, 0, 1)
    assert (result.i, result.j) == (0, 1) and not result.converged and "non-finite dx_m" in result.reason


def _scan(ranges, *, max_range=5.0):
    ranges = np.asarray(ranges, dtype=float)
    bearings = np.linspace(-np.pi, np.pi, len(ranges), endpoint=False) if len(ranges) else np.zeros(0)
    return RangeScan(bearings, ranges, 0.3, 1.0, max_range, 0.05, math.radians(3.0))


def _room(n=200):
    b = np.linspace(-np.pi, np.pi, n, endpoint=False)
    return np.minimum(2.0 / np.maximum(np.abs(np.cos(b)), 1e-9), 3.0 / np.maximum(np.abs(np.sin(b)), 1e-9))


DEGENERATE = {
    "empty": lambda: _scan([]),
    "one beam": lambda: _scan([2.0]),
    "no echo": lambda: _scan(np.full(200, np.nan)),
    "all at max range": lambda: _scan(np.full(200, 5.0)),
    "a circle": lambda: _scan(np.full(200, 2.0)),
    "room": lambda: _scan(_room()),
}


@pytest.mark.parametrize("name", MATCHERS)
@pytest.mark.parametrize("case", sorted(DEGENERATE))
def test_every_matcher_answers_degenerate_scans_honestly(name, case):
    """Each built-in matcher on degenerate scans (against itself and against a room): no exception,
    no NaN in a converged estimate, and the JSON of the checked result is strict."""
    registry = default_registry()
    matcher = resolve_stage(registry, "matcher", name, {"filter": {"n_particles": 100}} if name == "pf-pairwise" else {})
    for other in (DEGENERATE[case](), DEGENERATE["room"]()):
        result = match_pair(matcher, [other, DEGENERATE[case]()], 1, 0, 1)
        if result.converged:
            assert np.isfinite([result.dx_m, result.dy_m, result.dyaw_rad, result.weight]).all()
        elif case in ("empty", "one beam", "no echo"):
            assert result.reason
        finite = [v if v is None or math.isfinite(v) else None for v in (result.dx_m, result.dy_m, result.weight)]
        json.dumps(finite, allow_nan=False)
    if case in ("empty", "one beam", "no echo", "a circle"):
        assert not result.converged, f"{name} vouched for a match of a {case} scan: {result}"


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.one_of(st.floats(0.0, 8.0), st.just(float("nan"))), min_size=0, max_size=40))
def test_icp_and_correlative_never_return_unchecked_numbers(ranges):
    registry = default_registry()
    room = _scan(_room())
    for name in ("icp", "correlative"):
        result = match_pair(resolve_stage(registry, "matcher", name), [room, _scan(ranges)], 0, 0, 1)
        assert not result.converged or np.isfinite([result.dx_m, result.dy_m, result.dyaw_rad]).all()
