"""The example plugin passes the cistern-archive conformance suite."""

from cistern_archive.testing import check_matcher
from cistern_example_matcher import GridSearchMatcher


def test_conformance():
    report = check_matcher(GridSearchMatcher, n_pairs=6, seed=1)
    assert report.passed, report.format()


def test_recovers_a_known_shift(simulated_pair):
    matcher = GridSearchMatcher()
    result = matcher.match(simulated_pair.reference, simulated_pair.moving, matcher.Params(), rng=None)
    assert result.converged, result.reason
    assert abs(result.dx_m - simulated_pair.dx_m) < 0.1
    assert abs(result.dy_m - simulated_pair.dy_m) < 0.1
