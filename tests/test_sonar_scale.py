"""Matchers' lengths scale to the sonar: a site five times larger, its walls five times farther and its bins
five times coarser, matches with the same defaults as the smaller one."""

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
from cistern_plugins.sonar_scale import site_length_unit

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
                            max_range_m=10.0 * scale, bin_size_m=0.04 * scale, range_noise_m=0.02 * scale)

    return scan(A_XY, 1), scan(B_XY, 2)


def guess(scale: float) -> MatchGuess:
    dx, dy = (B_XY - A_XY) * scale
    return MatchGuess(dx + 0.1 * scale, dy - 0.1 * scale, 0.0, 0.3 * scale)


class _Sonar:
    """What the length unit reads of a scan: its bin and its echo ranges."""

    def __init__(self, bin_size_m: float, *walls_m: float, max_range_m: float = 10.0):
        self.bin_size_m, self.max_range_m = bin_size_m, max_range_m
        self.ranges_m = np.array([*walls_m, np.nan])  # a beam that heard nothing does not count


def test_the_length_unit_follows_the_bins_and_the_walls_and_is_never_below_one():
    assert length_unit(_Sonar(0.04, 2.0, 8.0), _Sonar(0.05, 10.0)) == 1.0  # the calibration settings
    assert length_unit(_Sonar(0.02, 3.0)) == 1.0  # finer bins, nearer walls: the limits as set
    assert length_unit(_Sonar(0.1, 50.0, max_range_m=50.0)) == pytest.approx(5.0)  # quays 50 m off
    assert length_unit(_Sonar(0.04, 4.0, max_range_m=20.0)) == 1.0  # a long setting, the same near walls
    assert length_unit(_Sonar(0.16, 3.0), _Sonar(0.04, 3.0)) == pytest.approx(3.2)  # coarser bins of one scan
    assert length_unit(_Sonar(0.12, 12.0)) == pytest.approx(2.4)  # a cistern three times as large: its bins
    ghosts = _Sonar(0.04, *([20.0] * 95 + [80.0] * 5), max_range_m=100.0)
    assert length_unit(ghosts) == pytest.approx(2.0)  # the 90th percentile: walls, not the ghosts beyond
    assert length_unit() == 1.0 and length_unit(_Sonar(0.04)) == 1.0  # no scan, no echo
    assert length_unit(_Sonar(math.nan, 20.0)) == pytest.approx(2.0)  # a bin that is not a number counts 1


def test_a_site_unit_follows_the_walls_of_its_usual_scan_not_the_bins():
    assert site_length_unit([]) == 1.0
    assert site_length_unit([_Sonar(0.08, 6.0), _Sonar(0.08, 8.0)]) == 1.0  # coarser bins, the usual walls
    walls = [_Sonar(0.04, 15.0), _Sonar(0.04, 30.0, max_range_m=40.0), _Sonar(0.04, 60.0, max_range_m=80.0)]
    assert site_length_unit(walls) == pytest.approx(3.0)  # the median, not the farthest gallery
    assert site_length_unit([_Sonar(0.04, 4.0)] * 2 + walls[2:]) == 1.0


def test_every_length_is_scaled_nested_sections_too_and_nothing_else():
    miniking = _Sonar(0.1, 50.0, max_range_m=50.0)
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
    """A pair in an 18 m chamber and the same pair five times larger (walls, range, bins and noise): with
    the defaults, the same verdict and an estimate five times the other."""
    (small_ref, small_mov), (large_ref, large_mov) = pair(2.0), pair(10.0)
    assert length_unit(large_ref, large_mov) == pytest.approx(5 * length_unit(small_ref, small_mov))
    assert length_unit(small_ref, small_mov) > 1.0  # both beyond the calibration sites' walls
    small = matcher().match(small_ref, small_mov, params(), rng=np.random.default_rng(0), guess=guess(2.0))
    large = matcher().match(large_ref, large_mov, params(), rng=np.random.default_rng(0), guess=guess(10.0))
    assert small.converged and large.converged, (small.reason, large.reason)
    assert math.hypot(small.dx_m - 2 * (B_XY - A_XY)[0], small.dy_m - 2 * (B_XY - A_XY)[1]) < 0.1
    np.testing.assert_allclose([large.dx_m, large.dy_m], [5 * small.dx_m, 5 * small.dy_m], atol=1e-2)
    assert large.dyaw_rad == pytest.approx(small.dyaw_rad, abs=1e-4)


def test_guided_correlative_defaults_are_the_miniking_sizes_at_its_length_unit():
    """The marina's survey names no lengths: at unit 5 (quays 50 m off) the defaults are the window,
    lattices, likelihood width and second-peak distance the matcher had in metres for the Miniking."""
    p = GuidedCorrelativeParams().for_scans(_Sonar(0.1, 50.0, max_range_m=50.0))
    sizes = (p.radius_m, p.coarse_m, p.fine_m, p.sigma_m, p.ambiguity_distance_m, p.min_sigma_m)
    np.testing.assert_allclose(sizes, (3.0, 0.2, 0.1, 0.3, 2.0, 0.1), rtol=1e-12)
