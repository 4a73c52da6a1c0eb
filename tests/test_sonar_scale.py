"""Matchers' lengths scale to the sonar: a site five times larger, scanned at a 50 m range with bins five
times coarser, matches with the same defaults as the cistern it was drawn from."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cistern_archive.grid.polygon import polygon_scan, rectangle
from cistern_archive.pipeline.contracts import MatchGuess
from cistern_plugins.correlative import CorrelativeMatcher, CorrelativeParams
from cistern_plugins.guided_correlative import GuidedCorrelativeMatcher, GuidedCorrelativeParams
from cistern_plugins.icp import ICPMatcher, ICPParams
from cistern_plugins.particle_icp import ParticleICPMatcher, ParticleICPParams
from cistern_plugins.pf_pairwise.params import PFParams
from cistern_plugins.registration import length_unit

ROOM = [
    np.array([[0, 0], [9.0, 0], [9.0, 3.6], [4.0, 3.6], [4.0, 6.0], [0, 6.0]], float),
    rectangle(0.5, 0.5, centre=(6.8, 1.4)),
]
A_XY, B_XY = np.array([1.6, 1.5]), np.array([2.9, 2.2])
MATCHERS = [(ICPMatcher, ICPParams), (ParticleICPMatcher, ParticleICPParams),
            (CorrelativeMatcher, CorrelativeParams), (GuidedCorrelativeMatcher, GuidedCorrelativeParams)]


def pair(scale: float):
    """Two scans of ROOM enlarged ``scale`` times: range, bins and range noise enlarged alike."""
    room = [p * scale for p in ROOM]

    def scan(xy, seed):
        return polygon_scan(room, tuple(xy * scale), 0.0, rng=np.random.default_rng(seed), n_beams=400,
                            max_range_m=10.0 * scale, bin_size_m=0.05 * scale, range_noise_m=0.02 * scale)

    return scan(A_XY, 1), scan(B_XY, 2)


def guess(scale: float) -> MatchGuess:
    dx, dy = (B_XY - A_XY) * scale
    return MatchGuess(dx + 0.1 * scale, dy - 0.1 * scale, 0.0, 0.3 * scale)


class _Sonar:
    def __init__(self, bin_size_m: float, max_range_m: float):
        self.bin_size_m, self.max_range_m = bin_size_m, max_range_m


def test_the_length_unit_is_the_coarsest_ratio_and_never_below_one():
    assert length_unit(_Sonar(0.04, 8.0), _Sonar(0.08, 10.0)) == 1.0  # the calibration settings
    assert length_unit(_Sonar(0.02, 5.0)) == 1.0  # finer settings keep the limits as set
    assert length_unit(_Sonar(0.1, 50.0)) == pytest.approx(5.0)  # the marina's Miniking: its range decides
    assert length_unit(_Sonar(0.16, 10.0), _Sonar(0.04, 8.0)) == pytest.approx(2.0)  # coarser bins of one scan
    assert length_unit() == 1.0
    assert length_unit(_Sonar(0.04, math.inf), _Sonar(math.nan, 20.0)) == pytest.approx(2.0)  # unknowns count 1


def test_every_length_is_scaled_nested_sections_too_and_nothing_else():
    miniking = _Sonar(0.1, 50.0)
    p = PFParams().for_scans(miniking)
    assert p.map.cell_m == pytest.approx(5 * PFParams().map.cell_m)
    assert p.verify.fit.inlier_distance_m == pytest.approx(5 * PFParams().verify.fit.inlier_distance_m)
    assert p.filter.l_init_m == pytest.approx(5 * PFParams().filter.l_init_m)
    assert p.filter.n_particles == PFParams().filter.n_particles  # counts,
    assert p.filter.sigma_n_theta_deg == PFParams().filter.sigma_n_theta_deg  # angles and
    assert p.verify.fit.min_inlier_ratio == PFParams().verify.fit.min_inlier_ratio  # ratios are not lengths
    icp = ICPParams()
    assert icp.for_scans(_Sonar(0.04, 8.0)) is icp  # unit 1: the very parameters
    assert icp.model_copy(update={"scale_to_sonar": False}).for_scans(miniking).inlier_distance_m == 0.15
    kept = PFParams.model_validate({"verify": {"fit": {"scale_to_sonar": False}}}).for_scans(miniking)
    assert kept.verify.fit.inlier_distance_m == PFParams().verify.fit.inlier_distance_m  # a section kept in metres
    assert kept.verify.step_m == pytest.approx(5 * PFParams().verify.step_m)


@pytest.mark.parametrize("matcher, params", MATCHERS)
def test_a_site_five_times_larger_matches_as_the_one_it_was_drawn_from(matcher, params):
    """The pair of a 9 m chamber and the same pair at 45 m with a 50 m sonar (bins and noise five times
    coarser): with the defaults, the same verdict and an estimate five times the other."""
    (small_ref, small_mov), (large_ref, large_mov) = pair(1.0), pair(5.0)
    small = matcher().match(small_ref, small_mov, params(), rng=np.random.default_rng(0), guess=guess(1.0))
    large = matcher().match(large_ref, large_mov, params(), rng=np.random.default_rng(0), guess=guess(5.0))
    assert small.converged and large.converged, (small.reason, large.reason)
    assert math.hypot(small.dx_m - (B_XY - A_XY)[0], small.dy_m - (B_XY - A_XY)[1]) < 0.05
    np.testing.assert_allclose([large.dx_m, large.dy_m], [5 * small.dx_m, 5 * small.dy_m], atol=5e-3)
    assert large.dyaw_rad == pytest.approx(small.dyaw_rad, abs=1e-4)


def test_guided_correlative_defaults_are_the_miniking_sizes_at_its_length_unit():
    """The marina's survey names no lengths: at the Miniking's unit (5) the defaults are the window,
    lattices, likelihood width and second-peak distance it was sized with in metres."""
    p = GuidedCorrelativeParams().for_scans(_Sonar(0.1, 50.0))
    sizes = (p.radius_m, p.coarse_m, p.fine_m, p.sigma_m, p.ambiguity_distance_m, p.min_sigma_m)
    np.testing.assert_allclose(sizes, (3.0, 0.2, 0.1, 0.3, 2.0, 0.1), rtol=1e-12)
