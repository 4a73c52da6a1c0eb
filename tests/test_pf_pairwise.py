"""The particle-filter pair-wise matcher (paper Tables I–II, eqs. 3–6) on scans with known truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pydantic import ValidationError

from cistern_archive.grid.polygon import polygon_scan, rectangle
from cistern_archive.pipeline.contracts import Matcher, MatchResult
from cistern_archive.pipeline.registry import Registry
from cistern_archive.core.scan import RangeScan
from cistern_plugins.pf_pairwise import (
    PFPairwiseMatcher,
    PFParams,
    ScanPair,
    beam_score,
    crossing_fraction,
    fit_check,
    grid_modes,
    refine_estimate,
    select_beams,
    verify_unique,
)

ROOM = [
    np.array([[0, 0], [7.2, 0], [7.2, 3.6], [4.0, 3.6], [4.0, 5.0], [2.5, 5.0], [2.5, 3.6], [0, 3.6]], float),
    rectangle(0.4, 0.4, centre=(5.5, 1.2)),  # a pillar
]
A_XY, B_XY = (1.5, 1.8), (3.1, 2.2)


def scan_at(xy, yaw_deg=0.0, *, seed=0, polygons=ROOM, **kw) -> RangeScan:
    kw.setdefault("range_noise_m", 0.02)
    return polygon_scan(polygons, xy, math.radians(yaw_deg), rng=np.random.default_rng(seed), n_beams=200, **kw)


def match(a: RangeScan, b: RangeScan, seed: int = 0, **sections) -> MatchResult:
    return PFPairwiseMatcher().match(a, b, PFParams(**sections), rng=np.random.default_rng(seed))


def assert_not_silent(result: MatchResult) -> None:
    assert not result.converged
    assert result.reason
    if np.isfinite(result.dx_m):
        assert result.iterations > 0


def test_protocol_and_registry():
    assert isinstance(PFPairwiseMatcher(), Matcher)
    loaded = Registry().load("matcher", "pf-pairwise")
    assert loaded.instance.name == "pf-pairwise"
    params = loaded.validate_params({"filter": {"n_particles": 300, "measurement_model": "raycast"}})
    assert params.filter.n_particles == 300 and params.filter.measurement_model == "raycast"
    with pytest.raises(ValidationError):
        loaded.validate_params({"filter": {"n_particle": 300}})
    with pytest.raises(ValidationError):
        loaded.validate_params({"filter": {"measurement_model": "icp"}})
    with pytest.raises(ValidationError):
        loaded.validate_params({"history": {"snapshots": 3}, "beams": 100})


@pytest.mark.parametrize("flat, section", [({"n_particles": 300}, "filter.n_particles"),
                                           ({"verify_fit": False}, "verify.fit.enabled"),
                                           ({"refine": "none"}, "refine.method"),
                                           ({"map_occupied": "cone"}, "map.occupied")])
def test_a_key_of_the_flat_layout_names_its_section(flat, section):
    with pytest.raises(ValidationError, match=section.replace(".", r"\.")):
        PFParams(**flat)


def test_paper_constants_are_defaults():
    p = PFParams()
    assert p.map.cell_m == 0.05 and p.filter.n_particles == 500
    assert p.filter.chi_w == pytest.approx(2 / 7) and p.filter.chi_sigma == pytest.approx(2 / 5)


def test_eq3_eq4_score():
    """φ = exp(-d²/2σc²), σc = 2 r_c; +φ inside δmax, -(1-φ) outside."""
    p = PFParams(map={"cell_m": 0.05}, filter={"delta_max_m": 0.3})
    d = np.array([0.0, 0.1, 0.29, 0.31, 5.0])
    phi = np.exp(-(d**2) / (2 * 0.1**2))
    assert_allclose(beam_score(d, p), np.where(d < 0.3, phi, -(1 - phi)), rtol=1e-6)


@pytest.mark.parametrize("yaw_b", [0.0, 40.0])
def test_known_shift_recovered(yaw_b):
    a, b = scan_at(A_XY, 10.0, seed=1), scan_at(B_XY, yaw_b, seed=2)
    result = match(a, b)
    assert result.converged, result.reason
    assert_allclose([result.dx_m, result.dy_m], np.subtract(B_XY, A_XY), atol=0.05)
    assert abs(result.dyaw_rad) < math.radians(2.0)
    assert result.weight >= PFParams().filter.tau_pw
    assert result.covariance.shape == (3, 3)


def test_heading_correction_recovered():
    """A compass 3° off on the moving scan is corrected through θ."""
    a = scan_at(A_XY, seed=1)
    b = scan_at(B_XY, seed=2, yaw_noise_rad=math.radians(3.0))
    result = match(a, b, filter={"theta_init_std_deg": 3.0})
    assert result.converged, result.reason
    assert_allclose(result.dyaw_rad, math.radians(-3.0), atol=math.radians(1.0))
    assert_allclose([result.dx_m, result.dy_m], np.subtract(B_XY, A_XY), atol=0.06)


def test_raycast_model_recovers_the_shift():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    result = match(a, b, filter={"measurement_model": "raycast", "n_particles": 300, "init_oversample": 4})
    assert result.converged, result.reason
    assert_allclose([result.dx_m, result.dy_m], np.subtract(B_XY, A_XY), atol=0.06)


def test_history_is_recorded():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    result = match(a, b, history={"snapshots": 3, "particles": 50})
    h = result.history
    assert (h.weight_threshold.value, h.std_threshold.value) == (0.25, 0.05)  # tau_pw and r_c, eqs. 5-6
    assert (h.weight_threshold.label, h.std_threshold.label) == ("τ_pw", "r_c")
    assert h.weight_avg.shape == h.std_avg.shape == (result.iterations,)
    assert 1 <= len(h.snapshots) <= 3
    assert all(s.shape == (50, 4) for s in h.snapshots)
    assert h.snapshot_iterations[0] == 0 and h.snapshot_iterations[-1] == result.iterations - 1
    assert h.std_avg[-1] <= 0.05  # eq. 5 at convergence
    assert h.std_avg[0] > 1.0  # uniform start over L_init


def test_deterministic_for_a_seed():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    r1, r2 = match(a, b, seed=7), match(a, b, seed=7)
    assert (r1.dx_m, r1.dy_m, r1.iterations) == (r2.dx_m, r2.dy_m, r2.iterations)


def test_non_overlapping_scans_do_not_converge():
    other_room = [np.array([[20, 20], [22.5, 20], [23.5, 21.0], [22.0, 22.2], [20, 21.5]], float)]
    a = scan_at(A_XY, seed=1)
    b = scan_at((21.5, 21.0), seed=2, polygons=other_room)
    result = match(a, b)
    assert_not_silent(result)
    assert any(word in result.reason for word in ("tau_pw", "spread", "edge", "ambiguous", "walls"))


def test_pure_noise_scan_does_not_converge():
    a = scan_at(A_XY, seed=1)
    rng = np.random.default_rng(3)
    b = RangeScan(
        bearings_rad=a.bearings_rad, ranges_m=rng.uniform(0.2, 8.0, a.bearings_rad.size), yaw_rad=0.0,
        depth_m=0.0, max_range_m=10.0, bin_size_m=0.05, beam_width_rad=math.radians(3.0),
    )
    assert_not_silent(match(a, b))


@pytest.mark.parametrize("which", ["reference", "moving"])
def test_all_zero_scan_is_refused_with_reason(which):
    good = scan_at(A_XY, seed=1)
    empty = RangeScan(
        bearings_rad=good.bearings_rad, ranges_m=np.full(good.bearings_rad.size, np.nan), yaw_rad=0.0,
        depth_m=0.0, max_range_m=10.0, bin_size_m=0.05, beam_width_rad=math.radians(3.0),
    )
    a, b = (empty, good) if which == "reference" else (good, empty)
    result = match(a, b)
    assert_not_silent(result)
    assert f"{which} scan has no echoes" in result.reason
    assert math.isnan(result.dx_m) and math.isnan(result.dy_m)


def test_compass_off_30_degrees_is_not_a_silent_success():
    a = scan_at(A_XY, seed=1)
    b = scan_at(B_XY, seed=2, yaw_noise_rad=math.radians(30.0))
    result = match(a, b)
    if result.converged:  # only acceptable if it actually found the truth
        assert_allclose([result.dx_m, result.dy_m], np.subtract(B_XY, A_XY), atol=0.1)
        assert_allclose(result.dyaw_rad, math.radians(-30.0), atol=math.radians(3.0))
    else:
        assert_not_silent(result)
        assert not (abs(result.dx_m) < 1e-9 and abs(result.dy_m) < 1e-9)


def test_out_of_search_square_is_not_converged():
    """The truth 3.2 m away with L_init = 2 m: no particle can reach it; the filter must say so."""
    a, b = scan_at((1.0, 1.0), seed=1), scan_at((5.0, 2.5), seed=2)
    result = match(a, b, filter={"l_init_m": 2.0, "n_iterations": 40})
    if result.converged:
        assert_allclose([result.dx_m, result.dy_m], [4.0, 1.5], atol=0.1)
    else:
        assert_not_silent(result)


def test_shifted_resampling_is_available():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    result = match(a, b, filter={"resample_weighting": "shifted", "init_oversample": 1, "sigma_n_xy_m": 0.01,
                                 "n_iterations": 80})
    assert result.iterations >= 1
    if result.converged:  # the paper's weak selection settles ~0.1 m off here: why 'exponential' is default
        assert_allclose([result.dx_m, result.dy_m], np.subtract(B_XY, A_XY), atol=0.15)
    else:
        assert_not_silent(result)


def test_featureless_corridor_is_not_a_silent_success():
    """Parallel walls with no end in range: the along-axis offset cannot be observed."""
    corridor = [np.array([[-40, 0], [40, 0], [40, 1.4], [-40, 1.4]], float)]
    a = scan_at((0.0, 0.7), seed=1, polygons=corridor, max_range_m=6.0)
    b = scan_at((2.0, 0.7), seed=2, polygons=corridor, max_range_m=6.0)
    result = match(a, b)
    if result.converged:
        assert_allclose([result.dx_m, result.dy_m], [2.0, 0.0], atol=0.1)
    else:
        assert_not_silent(result)


def test_verification_can_be_switched_off():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    assert match(a, b, verify={"unique": False}).converged


def test_verification_reasons():
    """Edge of the search square, beams through walls, and a rival position are each reported."""
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    p = PFParams()
    model = PFPairwiseMatcher().likelihood_map(a, p)
    beams = select_beams(b, p.filter.max_beams)
    truth = (B_XY[0] - A_XY[0], B_XY[1] - A_XY[1], 0.0)
    assert crossing_fraction(model, beams, truth, p) < 0.05
    assert verify_unique(model, beams, truth, p) == ""
    wrong = (truth[0] + 1.0, truth[1] - 0.6, 0.0)  # next to a wall: many beams cross it
    assert crossing_fraction(model, beams, wrong, p) > p.verify.max_crossing
    assert "pass through walls" in verify_unique(model, beams, wrong, p)
    assert "edge" in verify_unique(model, beams, (3.99, 0.0, 0.0), p)


def test_grid_modes_include_the_true_offset():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    p = PFParams()
    modes = grid_modes(PFPairwiseMatcher().likelihood_map(a, p), select_beams(b, p.filter.max_beams), 0.0, p, 3)
    assert 1 <= len(modes) <= 3
    assert np.hypot(*np.subtract(modes[0], np.subtract(B_XY, A_XY))) <= 1.5 * p.verify.step_m
    gaps = [np.hypot(*np.subtract(m1, m2)) for k, m1 in enumerate(modes) for m2 in modes[k + 1:]]
    assert all(g > p.verify.ambiguity_radius_m for g in gaps)


def test_restarts_keep_a_good_match_and_report_failures():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    plain, restarted = match(a, b), match(a, b, filter={"restarts": 2})
    assert restarted.converged and (restarted.dx_m, restarted.dy_m) == (plain.dx_m, plain.dy_m)
    far_room = [np.array([[20, 20], [24, 20], [24, 23], [20, 23]], float)]
    c = scan_at((22.0, 21.5), seed=3, polygons=far_room)
    result = match(a, c, filter={"restarts": 2})
    assert_not_silent(result)
    assert "restarts" in result.reason


def test_fit_check_uses_the_shared_verdict():
    """The point matchers' verdict (inliers, inlier share, free space) judges a verified estimate."""
    pair = ScanPair(scan_at(A_XY, seed=1), scan_at(B_XY, seed=2))
    truth = (B_XY[0] - A_XY[0], B_XY[1] - A_XY[1], 0.0)
    assert fit_check(pair, truth, PFParams()) == ""
    far = fit_check(pair, (truth[0] + 3.0, truth[1] + 3.0, 0.0), PFParams())
    assert far.startswith("fit check:") and "inlier" in far
    off = PFParams(verify={"fit": {"enabled": False}})
    assert fit_check(pair, (truth[0] + 3.0, truth[1] + 3.0, 0.0), off) == ""


def test_partial_overlap_fit_must_respect_free_space():
    """Below ``partial_inlier_ratio`` the free-space limit ``partial_max_violation`` applies."""
    pair = ScanPair(scan_at(A_XY, seed=1), scan_at(B_XY, seed=2))
    truth = (B_XY[0] - A_XY[0], B_XY[1] - A_XY[1], 0.0)
    wrong = (truth[0] + 0.6, truth[1] - 0.4, 0.0)

    def fit(**limits) -> PFParams:
        return PFParams(verify={"fit": limits})

    loose = dict(min_inliers=3, min_inlier_ratio=0.0, max_violation_run_m=100.0)
    assert fit_check(pair, wrong, fit(**loose, partial_inlier_ratio=0.0)) == ""
    assert "in a row" in fit_check(pair, wrong, fit(min_inliers=3, min_inlier_ratio=0.0, partial_inlier_ratio=0.0))
    reason = fit_check(pair, wrong, fit(**loose, partial_inlier_ratio=1.0, partial_max_violation=0.0))
    assert "free space" in reason
    assert fit_check(pair, truth, fit(partial_inlier_ratio=1.0)) == ""


def test_fit_check_failure_is_reported_not_converged():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    assert match(a, b).converged
    result = match(a, b, verify={"fit": {"min_inliers": 10_000}})
    assert_not_silent(result)
    assert result.reason.startswith("fit check: only")


def test_refinement_pulls_an_estimate_onto_the_walls():
    """A verified estimate a few centimetres off is moved onto the reference's walls by point-to-line
    ICP; ``refine.method='none'`` keeps it, and a refinement moving farther than ``refine.max_shift_m`` is
    dropped."""
    pair = ScanPair(scan_at(A_XY, seed=1, range_noise_m=0.0), scan_at(B_XY, seed=2, range_noise_m=0.0))
    truth = np.array([B_XY[0] - A_XY[0], B_XY[1] - A_XY[1], 0.0])
    off = tuple(truth + [0.04, -0.03, math.radians(0.5)])
    refined, covariance = refine_estimate(pair, off, PFParams())
    assert np.hypot(*(np.array(refined[:2]) - truth[:2])) < 0.01 < np.hypot(*(np.array(off[:2]) - truth[:2]))
    assert covariance.shape == (3, 3)
    assert refine_estimate(pair, off, PFParams(refine={"method": "none"})) == (off, None)
    assert refine_estimate(pair, off, PFParams(refine={"max_shift_m": 0.01})) == (off, None)


def test_converged_matches_are_refined():
    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    refined, plain = match(a, b), match(a, b, refine={"method": "none"})
    assert refined.converged and plain.converged
    err = [math.hypot(r.dx_m - (B_XY[0] - A_XY[0]), r.dy_m - (B_XY[1] - A_XY[1])) for r in (refined, plain)]
    assert err[0] < 0.03 and err[0] != err[1]


def test_a_guess_narrows_the_search_to_its_window():
    from cistern_archive.pipeline.contracts import MatchGuess

    a, b = scan_at(A_XY, seed=1), scan_at(B_XY, seed=2)
    truth = (B_XY[0] - A_XY[0], B_XY[1] - A_XY[1])
    near = PFPairwiseMatcher().match(a, b, PFParams(), rng=np.random.default_rng(0),
                                     guess=MatchGuess(truth[0] + 0.2, truth[1] - 0.1, 0.0, 0.5))
    assert near.converged, near.reason
    assert math.hypot(near.dx_m - truth[0], near.dy_m - truth[1]) < 0.05
    away = PFPairwiseMatcher().match(a, b, PFParams(), rng=np.random.default_rng(0),
                                     guess=MatchGuess(truth[0] + 1.5, truth[1] + 1.5, 0.0, 0.4))
    assert_not_silent(away)
    assert math.hypot(away.dx_m - truth[0], away.dy_m - truth[1]) > 1.0  # it searched the guess's window
