"""Particle-ICP matcher (Silver et al.): seeded determinism, accuracy, history, honest flag."""

import numpy as np

from cistern_archive.testing import simulated_pair
from cistern_plugins.particle_icp import ParticleICPMatcher, ParticleICPParams, icp_errors
from cistern_plugins.registration import ReferenceModel, scan_points


def _pair(seed=3):
    return simulated_pair(np.random.default_rng(seed), overlap_range=(0.7, 1.0), noise_m=0.02)


def test_recovers_shift_and_records_history():
    pair = _pair()
    res = ParticleICPMatcher().match(pair.reference, pair.moving, ParticleICPParams(), rng=np.random.default_rng(0))
    assert res.converged, res.reason
    np.testing.assert_allclose([res.dx_m, res.dy_m], [pair.dx_m, pair.dy_m], atol=0.1)
    assert res.history is not None and len(res.history.std_avg) == res.iterations


def test_same_seed_same_result():
    pair = _pair(4)
    m = ParticleICPMatcher()
    a = m.match(pair.reference, pair.moving, ParticleICPParams(), rng=np.random.default_rng(9))
    b = m.match(pair.reference, pair.moving, ParticleICPParams(), rng=np.random.default_rng(9))
    assert (a.dx_m, a.dy_m, a.dyaw_rad) == (b.dx_m, b.dy_m, b.dyaw_rad)


def test_truth_has_lowest_robust_error():
    pair = _pair(5)
    model = ReferenceModel(pair.reference)
    truth = np.array([pair.dx_m, pair.dy_m, pair.dyaw_rad])
    poses = np.vstack([truth, truth + [0.5, 0, 0], truth + [0, 0, 0.2]])
    err = icp_errors(model, scan_points(pair.moving), poses, "truncated", 0.3)
    assert np.argmin(err) == 0


def test_no_overlap_rarely_converges():
    rng = np.random.default_rng(8)
    flags = [ParticleICPMatcher().match(p.reference, p.moving, ParticleICPParams(), rng=rng).converged
             for p in (simulated_pair(rng, overlapping=False) for _ in range(5))]
    assert sum(flags) <= 1


def test_settled_estimates_are_refined_by_point_to_line_icp():
    pair = _pair(3)
    truth = np.array([pair.dx_m, pair.dy_m])
    m = ParticleICPMatcher()
    refined = m.match(pair.reference, pair.moving, ParticleICPParams(), rng=np.random.default_rng(0))
    plain = m.match(pair.reference, pair.moving, ParticleICPParams(refine="none"), rng=np.random.default_rng(0))
    assert refined.converged and plain.converged
    err = [np.hypot(*(np.array([r.dx_m, r.dy_m]) - truth)) for r in (refined, plain)]
    assert err[0] < 0.03 and err[0] != err[1]
