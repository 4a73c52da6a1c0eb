"""Pose-graph localizer: window pairs, robust to a wrong match, marginals, unplaced scans."""

import numpy as np
import pytest

from cistern_archive.pipeline.contracts import MatchResult
from cistern_archive.core.scan import RangeScan
from cistern_plugins.pose_graph import PoseGraphLocalizer, PoseGraphParams

TRUTH = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.5], [3.0, 0.2], [4.0, 0.0]])


def _scans(n):
    return [RangeScan(np.zeros(3), np.ones(3), 0.0, 1.0, 5.0, 0.05, 0.05) for _ in range(n)]


def _matches(pairs, rng, sigma=0.02):
    return [MatchResult(i, j, *(TRUTH[j] - TRUTH[i] + rng.normal(0, sigma, 2)), 0.0, 1.0, True, 1, 0.0)
            for i, j in pairs]


def test_pairs_window_and_directions():
    loc = PoseGraphLocalizer()
    one = PoseGraphParams(window=2, directions="one")
    assert loc.pairs(4, one) == [(0, 1), (1, 2), (2, 3), (0, 2), (1, 3)]
    assert loc.guided_pairs(_scans(4), [], one) == []
    assert len(loc.pairs(4, PoseGraphParams(window=2))) == 10


def test_guided_pairs_take_their_guess_from_the_neighbours():
    """Guided: neighbours first, then the pairs up to ``window`` apart with the neighbours' solution as
    the guess; pairs the neighbours do not join get no guess."""
    loc, p = PoseGraphLocalizer(), PoseGraphParams(window=3, directions="one", guided=True, guess_radius_m=0.4)
    assert loc.pairs(5, p) == [(0, 1), (1, 2), (2, 3), (3, 4)]
    neighbours = _matches([(0, 1), (1, 2), (2, 3)], np.random.default_rng(1), sigma=0.0)
    second = loc.guided_pairs(_scans(5), neighbours, p)
    assert [(i, j) for i, j, _ in second] == [(0, 2), (1, 3), (2, 4), (0, 3), (1, 4)]
    for i, j, guess in second:
        if 4 in (i, j):
            assert guess is None
        else:
            assert guess.radius_m == 0.4
            np.testing.assert_allclose([guess.dx_m, guess.dy_m, guess.dyaw_rad], [*(TRUTH[j] - TRUTH[i]), 0.0],
                                       atol=1e-6)


def test_recovers_positions_despite_a_wrong_match():
    loc, p = PoseGraphLocalizer(), PoseGraphParams(window=3)
    ms = _matches(loc.pairs(5, p), np.random.default_rng(0))
    ms.append(MatchResult(0, 2, 5.0, -4.0, 0.0, 1.0, True, 1, 0.0))
    poses = loc.localize(_scans(5), ms, p)
    assert poses.placed.all()
    xy = poses.xy_m - poses.xy_m[0]
    np.testing.assert_allclose(xy, TRUTH, atol=0.08)
    assert poses.covariance.shape == (5, 3, 3)
    assert np.all(np.linalg.eigvalsh(poses.covariance[1]) > 0)


def test_disconnected_scan_is_unplaced_with_reason():
    loc, p = PoseGraphLocalizer(), PoseGraphParams(window=1)
    ms = _matches([(0, 1), (1, 2)], np.random.default_rng(1))
    poses = loc.localize(_scans(4), ms, p)
    assert not poses.placed[3] and "no converged path" in poses.reasons[3]
    assert np.isnan(poses.xy_m[3]).all()


def test_reference_is_in_the_largest_group():
    """A dense pair of scans must not win over a longer chain."""
    loc, p = PoseGraphLocalizer(), PoseGraphParams(window=1)
    rng = np.random.default_rng(2)
    chain = _matches([(0, 1), (1, 2), (2, 3)], rng)
    dense = [MatchResult(5, 6, 1.0, 0.0, 0.0, 1.0, True, 1, 0.0) for _ in range(6)]
    poses = loc.localize(_scans(7), chain + dense, p)
    assert poses.placed[:4].all() and not poses.placed[5:].any() and not poses.placed[4]


def test_relative_radius_is_the_uncertainty_of_one_scan_against_another_not_against_the_reference():
    """A chain 0 → 1 → 2 whose links are uncertain by 0.1 m along and 0.2 m across: scan 2 against scan 1
    is uncertain by exactly its link's (0.1 m, 0.2 m) however far the chain has drifted from the reference,
    and against the reference by more (the two links, and scan 1's turn swinging the second)."""
    import gtsam

    from cistern_plugins.factor_graph import radius95_m, relative_radius95_m

    graph = gtsam.NonlinearFactorGraph()
    link = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.2, 0.01]))
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-4))))
    graph.add(gtsam.BetweenFactorPose2(0, 1, gtsam.Pose2(1.0, 0.0, 0.5), link))
    graph.add(gtsam.BetweenFactorPose2(1, 2, gtsam.Pose2(1.0, 0.0, 0.0), link))
    values = gtsam.Values()
    for k, pose in enumerate((gtsam.Pose2(), gtsam.Pose2(1.0, 0.0, 0.5), gtsam.Pose2(1.9, 0.5, 0.5))):
        values.insert(k, pose)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    marginals = gtsam.Marginals(graph, result)
    assert relative_radius95_m(marginals, result, 1, 2) == pytest.approx(radius95_m(np.diag([0.01, 0.04])), rel=1e-3)
    assert relative_radius95_m(marginals, result, 0, 2) > 0.5


def test_the_95_percent_radius_holds_95_percent_of_a_2d_error():
    """``1.96 σ`` of the least certain direction when the other is certain, ``2.45 σ`` when both are
    alike, and in between the radius that 95 % of drawn errors fall within."""
    from cistern_plugins.factor_graph import radius95_m

    assert radius95_m(np.diag([1e-12, 0.04])) == pytest.approx(1.96 * 0.2, rel=1e-3)
    assert radius95_m(np.diag([0.04, 0.04])) == pytest.approx(2.4477 * 0.2, rel=1e-3)
    assert np.isnan(radius95_m(np.full((2, 2), np.nan))) and radius95_m(np.zeros((2, 2))) == 0.0
    cov = np.array([[0.02, 0.01], [0.01, 0.03]])
    errors = np.random.default_rng(3).multivariate_normal([0.0, 0.0], cov, size=200_000)
    assert np.quantile(np.hypot(errors[:, 0], errors[:, 1]), 0.95) == pytest.approx(radius95_m(cov), rel=0.01)
