"""ICP matcher: recovers known shifts, both variants, honest flag."""

import numpy as np
import pytest

from cistern_archive.testing import simulated_pair
from cistern_plugins.icp import ICPMatcher, ICPParams


@pytest.mark.parametrize("variant", ["point-to-point", "point-to-line"])
def test_recovers_small_offset(variant):
    rng = np.random.default_rng(6)
    pair = simulated_pair(rng, overlap_range=(0.8, 1.0), offset_range_m=(0.1, 0.4), noise_m=0.02)
    res = ICPMatcher().match(pair.reference, pair.moving, ICPParams(variant=variant), rng=rng)
    assert res.converged, res.reason
    np.testing.assert_allclose([res.dx_m, res.dy_m], [pair.dx_m, pair.dy_m], atol=0.1)


def test_no_overlap_is_not_converged():
    rng = np.random.default_rng(4)
    flags = [ICPMatcher().match(p.reference, p.moving, ICPParams(), rng=rng).converged
             for p in (simulated_pair(rng, overlapping=False) for _ in range(10))]
    assert sum(flags) <= 1


def test_too_few_points_gives_reason():
    rng = np.random.default_rng(0)
    pair = simulated_pair(rng)
    empty = type(pair.moving)(pair.moving.bearings_rad, np.full_like(pair.moving.ranges_m, np.nan), 0.0, 0.0, 5.0,
                              0.05, 0.05)
    res = ICPMatcher().match(pair.reference, empty, ICPParams(), rng=rng)
    assert not res.converged and "too few echoes" in res.reason


def test_params_refuse_unknown_keys():
    with pytest.raises(ValueError):
        ICPParams(variant="point-to-plane")


def test_corridor_is_reported_degenerate():
    """Two scans of a straight featureless corridor: the along-axis shift is unobservable."""
    from cistern_archive.simulation.rays import Environment
    from cistern_archive.simulation.pairs import simulate_range_scan

    walls = np.array([[-50.0, -1.0, 50.0, -1.0], [-50.0, 1.0, 50.0, 1.0]])
    env = Environment(walls, "gallery", np.zeros((0, 2)))
    rng = np.random.default_rng(0)
    kw = dict(n_beams=200, max_range_m=6.0, noise_m=0.02, outlier_fraction=0.0, dropout_fraction=0.0, rng=rng)
    a = simulate_range_scan(env, np.array([0.0, 0.0]), 0.0, compass_yaw_rad=0.0, **kw)
    b = simulate_range_scan(env, np.array([0.8, 0.0]), 0.0, compass_yaw_rad=0.0, **kw)
    res = ICPMatcher().match(a, b, ICPParams(), rng=rng)
    assert not res.converged
    assert "constrain" in res.reason or "weakly" in res.reason


def test_a_fit_turned_beyond_the_compasses_is_refused():
    rng = np.random.default_rng(6)
    pair = simulated_pair(rng, overlap_range=(0.8, 1.0), offset_range_m=(0.1, 0.4), noise_m=0.02)
    turn_deg = abs(np.degrees(pair.dyaw_rad))
    assert turn_deg > 1.0  # the two compasses disagree
    found = ICPMatcher().match(pair.reference, pair.moving, ICPParams(), rng=rng)
    assert found.converged, found.reason
    limited = ICPMatcher().match(pair.reference, pair.moving, ICPParams(max_turn_deg=turn_deg / 2), rng=rng)
    assert not limited.converged and limited.reason.startswith("turned")
    assert (limited.dx_m, limited.dy_m) == (found.dx_m, found.dy_m)  # the estimate stays, refused


def test_turned_too_far_measures_the_turn_either_way_round():
    from cistern_plugins.icp import turned_too_far

    assert turned_too_far(np.radians(29.0), 30.0) == ""
    assert turned_too_far(np.radians(-29.0) + 2 * np.pi, 30.0) == ""
    assert "turned 179°" in turned_too_far(np.radians(-179.0), 30.0)
