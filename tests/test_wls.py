"""Weighted-least-squares scan localisation (paper eqs. 7–10, Table III)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from cistern_archive.pipeline.contracts import Localizer, MatchResult, VerticalTie
from cistern_archive.pipeline.registry import Registry
from cistern_archive.core.scan import RangeScan
from cistern_plugins.wls import WLSLocalizer, WLSParams, combine, converged_measurements, estimates

TRUTH = np.array([[0.0, 0.0], [1.5, 0.2], [3.1, -0.1], [4.4, 0.5]])


def scans(n: int) -> list[RangeScan]:
    bearings = np.linspace(0, 2 * math.pi, 8, endpoint=False)
    return [
        RangeScan(bearings_rad=bearings, ranges_m=np.ones(8), yaw_rad=0.1 * k, depth_m=1.0, max_range_m=10.0,
                  bin_size_m=0.05, beam_width_rad=0.05, station=f"s{k}")
        for k in range(n)
    ]


def m(i, j, d=None, *, w=0.5, ok=True, dyaw=0.0, reason="") -> MatchResult:
    d = TRUTH[j] - TRUTH[i] if d is None else np.asarray(d, float)
    return MatchResult(i=i, j=j, dx_m=float(d[0]), dy_m=float(d[1]), dyaw_rad=dyaw, weight=w, converged=ok,
                       iterations=10, seconds=0.01, reason=reason if not ok else "")


def all_pairs(n: int = 4, **kw) -> list[MatchResult]:
    return [m(i, j, **kw) for i, j in WLSLocalizer().pairs(n, WLSParams())]


def test_protocol_and_registry():
    assert isinstance(WLSLocalizer(), Localizer)
    assert Registry().load("localizer", "wls").instance.name == "wls"


def test_pairs_neighbours_both_ways_then_third_scan():
    pairs = WLSLocalizer().pairs(4, WLSParams())
    assert pairs[:6] == [(0, 1), (1, 0), (1, 2), (2, 1), (2, 3), (3, 2)]
    assert set(pairs[6:]) == {(0, 2), (2, 0), (1, 3), (3, 1)}
    assert WLSLocalizer().pairs(4, WLSParams(third_scan=False)) == pairs[:6]
    assert WLSLocalizer().pairs(1, WLSParams()) == []


def test_exact_matches_give_exact_poses():
    poses = WLSLocalizer().localize(scans(4), all_pairs(), WLSParams())
    assert poses.reference == 0 and poses.placed.all()
    assert_allclose(poses.xy_m, TRUTH, atol=1e-12)
    assert poses.reasons == ("", "", "", "")
    assert_allclose(poses.yaw_rad, [0.0, 0.1, 0.2, 0.3])


def test_four_estimates_and_eq10_weighted_mean():
    """d_01 from z_01, -z_10, z_02 + z_21 and -(z_12 + z_20), weighted as documented."""
    ms = [m(0, 1, [1.0, 0.0], w=1.0), m(1, 0, [-1.2, 0.0], w=0.5),
          m(0, 2, [2.0, 0.0], w=1.0), m(2, 1, [-0.9, 0.0], w=1.0),
          m(1, 2, [1.1, 0.0], w=1.0), m(2, 0, [-2.1, 0.0], w=1.0)]
    z = converged_measurements(ms, 1e-3)
    est = estimates(0, 1, z, 3)
    assert len(est) == 4
    values = [e[0][0] for e in est]
    assert_allclose(values, [1.0, 1.2, 1.1, 1.0])
    weights = np.array([1.0, 0.5, 0.5, 0.5])  # a chain of two weight-1 links has weight 1/2
    assert_allclose([e[1] for e in est], weights)
    mean, total = combine(0, 1, z, 3)
    assert_allclose(mean[0], (weights * values).sum() / weights.sum())
    assert total == pytest.approx(weights.sum())


def test_reverse_only_pair_still_links():
    ms = [m(1, 0), m(1, 2), m(2, 1), m(2, 3)]
    poses = WLSLocalizer().localize(scans(4), ms, WLSParams(third_scan=False))
    assert poses.placed.all()
    assert_allclose(poses.xy_m, TRUTH, atol=1e-12)


def test_reference_is_first_scan_that_converges():
    ms = [m(0, 1, ok=False, reason="no overlap"), m(1, 0, ok=False, reason="no overlap"),
          m(1, 2), m(2, 1), m(2, 3), m(3, 2)]
    poses = WLSLocalizer().localize(scans(4), ms, WLSParams(third_scan=False))
    assert poses.reference == 1
    assert not poses.placed[0] and poses.placed[1:].all()
    assert_allclose(poses.xy_m[1:], TRUTH[1:] - TRUTH[1], atol=1e-12)
    assert np.isnan(poses.xy_m[0]).all()
    assert "no converged path to reference scan 1" in poses.reasons[0]
    assert "no overlap" in poses.reasons[0]


def test_broken_chain_leaves_the_rest_unplaced_but_global_bridges_it():
    ms = [m(0, 1), m(1, 0), m(1, 2, ok=False, reason="spread"), m(2, 1, ok=False, reason="spread"),
          m(2, 3), m(3, 2), m(1, 3), m(3, 1)]
    chain = WLSLocalizer().localize(scans(4), ms, WLSParams(solve="chain"))
    # the pseudo-measurement z_13 + z_32 still links 1 and 2 (eq. 7, n = 3)
    assert chain.placed.all()
    assert_allclose(chain.xy_m, TRUTH, atol=1e-12)
    ms_no_pseudo = [x for x in ms if (x.i, x.j) not in {(1, 3), (3, 1)}]
    broken = WLSLocalizer().localize(scans(4), ms_no_pseudo, WLSParams(solve="chain"))
    assert broken.placed.tolist() == [True, True, False, False]
    assert "no converged path" in broken.reasons[2]


def test_global_solve_averages_loop():
    noisy = all_pairs()
    noisy[0] = m(0, 1, TRUTH[1] + [0.1, 0.0])
    chain = WLSLocalizer().localize(scans(4), noisy, WLSParams(solve="chain"))
    glob = WLSLocalizer().localize(scans(4), noisy, WLSParams(solve="global"))
    assert glob.placed.all()
    assert np.abs(glob.xy_m - TRUTH).max() < np.abs(chain.xy_m - TRUTH).max() + 1e-12
    assert np.abs(glob.xy_m - TRUTH).max() < 0.1


def test_nothing_converged():
    ms = [m(i, j, ok=False, reason="pure noise") for i, j in WLSLocalizer().pairs(3, WLSParams())]
    poses = WLSLocalizer().localize(scans(3), ms, WLSParams())
    assert poses.reference == -1 and not poses.placed.any()
    assert all("no pair of scans converged" in r for r in poses.reasons)


def test_nan_and_nonpositive_weights_are_handled():
    ms = all_pairs()
    ms[0] = m(0, 1, w=-0.2)
    ms[1] = m(1, 0, [np.nan, 0.0])
    ms[1] = MatchResult(**{**ms[1].__dict__, "converged": True})
    poses = WLSLocalizer().localize(scans(4), ms, WLSParams())
    assert poses.placed.all()
    assert_allclose(poses.xy_m, TRUTH, atol=1e-9)


def test_heading_corrections_are_composed():
    """Scan 1's compass reads 10° high: z_12 is seen rotated by 10° in m_1, and z_01 says so."""
    e1 = math.radians(10.0)
    c, s = math.cos(e1), math.sin(e1)
    rot = np.array([[c, -s], [s, c]])
    ms = [m(0, 1, dyaw=-e1), m(1, 2, rot @ (TRUTH[2] - TRUTH[1]), dyaw=e1)]
    poses = WLSLocalizer().localize(scans(3), ms, WLSParams(third_scan=False))
    assert_allclose(poses.xy_m, TRUTH[:3], atol=1e-12)
    assert_allclose(poses.yaw_rad - np.array([0.0, 0.1, 0.2]), [0.0, -e1, 0.0], atol=1e-12)
    flat = WLSLocalizer().localize(scans(3), ms, WLSParams(third_scan=False, use_yaw=False))
    assert_allclose(flat.yaw_rad, [0.0, 0.1, 0.2])
    assert np.abs(flat.xy_m[2] - TRUTH[2]).max() > 0.05


def test_vertical_tie_joins_levels_and_overrides_their_match():
    """Scans 0-1 at one depth, 2-3 at another; scan 2 was taken below scan 1 (ScanRef.below)."""
    s = [RangeScan(bearings_rad=x.bearings_rad, ranges_m=x.ranges_m, yaw_rad=x.yaw_rad,
                   depth_m=1.0 if k < 2 else 3.0, max_range_m=10.0, bin_size_m=0.05, beam_width_rad=0.05,
                   station=x.station) for k, x in enumerate(scans(4))]
    truth = TRUTH.copy()
    truth[2] = truth[1]
    wrong = m(1, 2, [2.0, 2.0])  # a cross-level match converged to nonsense
    ms = [m(0, 1), m(1, 0), wrong, m(2, 3, truth[3] - truth[2]), m(3, 2, truth[2] - truth[3])]
    untied = WLSLocalizer().localize(s, ms[:2] + ms[3:], WLSParams(third_scan=False))
    assert untied.placed.tolist() == [True, True, False, False]
    tied = WLSLocalizer().localize(s, ms, WLSParams(third_scan=False), ties=[VerticalTie(lower="s2", upper="s1")])
    assert tied.placed.all()
    assert_allclose(tied.xy_m, truth, atol=1e-12)
    with pytest.raises(ValueError, match="no scan of station 'x9'"):
        WLSLocalizer().localize(s, ms, WLSParams(), ties=[VerticalTie(lower="s2", upper="x9")])


def test_runner_passes_the_records_vertical_ties(bundled_catalog):
    """The ties reach the localizer as typed input (``localize(..., ties=...)``), not through its params."""
    from cistern_archive.catalog.loader import load_record
    from cistern_archive.pipeline.runner import Stage, localize, record_ties

    record = load_record(bundled_catalog / "sites" / "bell-cistern.yaml", bundled_catalog).record
    ties = record_ties(record)
    assert [(t.lower, t.upper) for t in ties] == [(s.station, s.below) for s in record.scans if s.below]
    assert len(ties) == 2
    seen = []

    class Recording(WLSLocalizer):
        def localize(self, scans, matches, params, *, ties=()):
            seen.append(ties)
            return super().localize(scans, matches, params, ties=ties)

    poses = localize(Stage.of("localizer", Recording()), scans(2), [], ties=[])
    assert seen == [()] and not poses.placed.any()
    with pytest.raises(ValueError, match="no scan of station"):  # the bell's stations are not these scans
        localize(Stage.of("localizer", Recording()), scans(2), [], ties)
    assert seen[1] == ties
