"""``nav-graph``: a pose graph for surveys with navigation — odometry, compass, scan matches, calibration.

For scans taken from a moving vehicle (each :class:`~cistern_archive.core.scan.RangeScan` carries its
dead-reckoned ``odometry`` pose and ``time_s``; :func:`cistern_archive.navigation.motion.compensated_range_scan`),
GTSAM solves for one ``Pose2`` per scan, ``X_k = (x_k, y_k, theta_k)`` in the map frame, and the
calibration variables: the DVL scale ``s`` and the compass deviation
``delta(psi) = d0 + d1 sin(psi) + d2 cos(psi)`` (a constant offset and, with ``deviation``, the
heading-dependent one-cycle terms):

* **odometry** between consecutive scans: ``R(-theta_k)(p_{k+1} - p_k) = s t_k`` and
  ``theta_{k+1} - theta_k = phi_k``, with ``(t_k, phi_k)`` the dead-reckoned relative pose and its
  covariance from :class:`~cistern_archive.navigation.track.OdometryNoise` (white velocity noise, scale
  and heading errors proportional to the distance);
* **compass** on every scan: ``theta_k = psi_k + delta(psi_k)`` with ``psi_k`` the (calibrated)
  dead-reckoned heading, ``compass_sigma_deg``, a Huber kernel (the marina walls disturb the compass);
* **priors**: the first scan at its odometry pose (start alignment), ``s = 1 ± scale_sigma``,
  ``d0 = 0 ± offset_sigma_deg`` and ``d1, d2 = 0 ± deviation_sigma_deg`` (the surface calibration is
  the priors' mean);
* **scan matches** ``(i, j)``: the matched displacement and yaw correction, rotated into scan i's body
  frame, as ``X_i^-1 X_j`` (``BetweenFactorPose2``), with the match's covariance floored at
  ``min_match_sigma_m`` and a Cauchy kernel.

Pairs: :meth:`NavGraphLocalizer.pairs` asks for consecutive scans; :meth:`NavGraphLocalizer.guided_pairs`
proposes loop-closure candidates from the solution of the first round: for each scan, the earlier
scans at least ``loop_min_gap`` away whose solved positions lie within ``loop_radius_m`` (the nearest
``loop_per_scan``), each with a :class:`~cistern_archive.pipeline.contracts.MatchGuess` of their solved
relative pose and a window of ``loop_window_sigma`` standard deviations of the odometry between them
(clamped to ``[loop_window_min_m, loop_window_max_m]``). The runner asks again while new pairs come;
every round proposes the nearest earlier scans of the current solution, and the later rounds also look
for revisits around the solution of every match so far: each scan without a
converged match to a scan at least ``revisit_gap`` back, and with fewer than ``revisit_tries`` such
pairs tried, gets its ``revisit_per_scan`` nearest untried ones within ``loop_radius_m``. The first
round's solution is the odometry's, whose drift between two visits of a place (several metres) can
put the place outside the search window; the matches along the track remove most of that drift.

Ambiguity gate: after solving, the match whose squared Mahalanobis residual is largest is dropped while
it exceeds ``gate_chi2`` (up to ``gate_rounds`` times), then the graph is solved again — robust kernels
soften wrong matches, the gate removes them. Every scan with odometry is placed (the odometry chain joins
them all); scans without odometry are returned unplaced with the reason.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import ClassVar

import gtsam
import numpy as np
from pydantic import Field

from cistern_archive.navigation.track import OdometryNoise, relative_covariance, se2_between
from cistern_archive.pipeline.contracts import (GuidedLocalizer, MatchGuess, MatchResult, Poses, StageParams,
                                                VerticalTie)
from cistern_archive.core.scan import RangeScan, wrap_angle

SCALE_KEY = gtsam.symbol("s", 0)
OFFSET_KEY = gtsam.symbol("d", 0)


class NavGraphParams(StageParams):
    """Parameters of :class:`NavGraphLocalizer` (lengths in metres, angles in degrees)."""

    sigma_v_mps: float = Field(0.02, gt=0)
    ping_interval_s: float = Field(0.66, gt=0)
    sigma_scale: float = Field(0.03, gt=0)
    sigma_heading_deg: float = Field(3.0, gt=0)
    compass_sigma_deg: float = Field(4.0, gt=0)
    scale_sigma: float = Field(0.03, gt=0)
    offset_sigma_deg: float = Field(3.0, gt=0)
    estimate_calibration: bool = True
    deviation: bool = True
    deviation_sigma_deg: float = Field(3.0, gt=0)
    min_match_sigma_m: float = Field(0.3, gt=0)
    min_match_sigma_deg: float = Field(1.0, gt=0)
    cauchy_k: float = Field(1.0, gt=0)
    consecutive: bool = True
    loop_radius_m: float = Field(30.0, gt=0)
    loop_min_gap: int = Field(10, ge=2)
    loop_per_scan: int = Field(1, ge=0)
    loop_window_sigma: float = Field(3.0, gt=0)
    loop_window_min_m: float = Field(1.0, gt=0)
    loop_window_max_m: float = Field(5.0, gt=0)
    revisit_gap: int = Field(15, ge=2)
    revisit_per_scan: int = Field(0, ge=0, description="revisit candidates per scan in later rounds (0: none)")
    revisit_tries: int = Field(3, ge=1)
    gate_chi2: float = Field(16.27, gt=0)
    gate_rounds: int = Field(20, ge=0)
    max_iterations: int = Field(100, ge=1)

    def odometry_noise(self) -> OdometryNoise:
        return OdometryNoise(sigma_v_mps=self.sigma_v_mps, ping_interval_s=self.ping_interval_s,
                             sigma_scale=self.sigma_scale, sigma_heading_rad=math.radians(self.sigma_heading_deg))


def odometry_covariance(a: RangeScan, b: RangeScan, noise: OdometryNoise) -> tuple[np.ndarray, np.ndarray]:
    """Relative dead-reckoned pose of ``b`` in ``a``'s body frame and its covariance
    (:func:`~cistern_archive.navigation.track.relative_covariance`, with the straight-line distance)."""
    delta = se2_between(a.odometry, b.odometry)
    return delta, relative_covariance(delta, float(math.hypot(delta[0], delta[1])), abs(b.time_s - a.time_s), noise)


def _odometry_error(measured: np.ndarray):
    """Error function of the scaled odometry factor on ``(X_k, X_k+1, s)`` (module docstring)."""

    def error(factor: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        k0, k1, ks = factor.keys()
        a, b = values.atPose2(k0), values.atPose2(k1)
        scale = float(values.atVector(ks)[0])
        ca, sa = math.cos(a.theta()), math.sin(a.theta())
        dx, dy = b.x() - a.x(), b.y() - a.y()
        body = np.array([ca * dx + sa * dy, -sa * dx + ca * dy])
        err = np.array([body[0] - scale * measured[0], body[1] - scale * measured[1],
                        float(wrap_angle(b.theta() - a.theta() - measured[2]))])
        if jacobians is not None:
            rel = b.theta() - a.theta()
            cr, sr = math.cos(rel), math.sin(rel)
            jacobians[0] = np.array([[-1.0, 0.0, body[1]], [0.0, -1.0, -body[0]], [0.0, 0.0, -1.0]])
            jacobians[1] = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
            jacobians[2] = np.array([[-measured[0]], [-measured[1]], [0.0]])
        return err

    return error


def _compass_error(heading: float):
    """Error function of the compass factor on ``(X_k, d)``: ``theta_k - psi_k - deviation(psi_k)`` with
    ``deviation(psi) = d0 + d1 sin(psi) + d2 cos(psi)`` (:func:`deviation_terms`)."""
    terms = deviation_terms(heading)

    def error(factor: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        kx, kd = factor.keys()
        deviation = float(terms @ values.atVector(kd))
        err = np.array([float(wrap_angle(values.atPose2(kx).theta() - heading - deviation))])
        if jacobians is not None:
            jacobians[0] = np.array([[0.0, 0.0, 1.0]])
            jacobians[1] = -terms[None, :]
        return err

    return error


def deviation_terms(heading: float) -> np.ndarray:
    """``(1, sin psi, cos psi)``: the constant and one-cycle terms of a compass deviation (the classical
    ``A + B sin psi + C cos psi`` of a magnetic compass near iron, here the marina's steel walls)."""
    return np.array([1.0, math.sin(heading), math.cos(heading)])


def match_measurement(scan_i: RangeScan, scan_j: RangeScan, match: MatchResult,
                      p: NavGraphParams) -> tuple[gtsam.Pose2, np.ndarray]:
    """A match as ``X_i^-1 X_j`` in scan i's body frame, with its floored covariance."""
    c, s = math.cos(scan_i.yaw_rad), math.sin(scan_i.yaw_rad)
    rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    body = rot @ np.array([match.dx_m, match.dy_m, 0.0])
    dtheta = float(wrap_angle(scan_j.yaw_rad + match.dyaw_rad - scan_i.yaw_rad))
    cov = match.covariance if match.covariance is not None else np.diag([p.min_match_sigma_m ** 2] * 2 + [0.0])
    cov = rot @ np.asarray(cov, dtype=float) @ rot.T
    floor = np.diag([p.min_match_sigma_m ** 2, p.min_match_sigma_m ** 2, math.radians(p.min_match_sigma_deg) ** 2])
    return gtsam.Pose2(body[0], body[1], dtheta), cov + floor


def _usable(matches: Sequence[MatchResult], scans: Sequence[RangeScan]) -> list[MatchResult]:
    n = len(scans)
    return [m for m in matches if m.converged and 0 <= m.i < n and 0 <= m.j < n and m.i != m.j
            and scans[m.i].odometry is not None and scans[m.j].odometry is not None
            and all(math.isfinite(v) for v in (m.dx_m, m.dy_m, m.dyaw_rad))]


class _Graph:
    """The factor graph of one solve (module docstring)."""

    def __init__(self, scans: Sequence[RangeScan], nodes: list[int], matches: list[MatchResult], p: NavGraphParams):
        self.graph = gtsam.NonlinearFactorGraph()
        self.initial = gtsam.Values()
        for k in nodes:
            self.initial.insert(k, gtsam.Pose2(*scans[k].odometry))
        self.initial.insert(SCALE_KEY, np.array([1.0]))
        self.initial.insert(OFFSET_KEY, np.zeros(3))
        self._add_priors(scans[nodes[0]], nodes[0], p)
        self._add_navigation(scans, nodes, p)
        self._add_matches(scans, matches, p)

    def _add_priors(self, first: RangeScan, key: int, p: NavGraphParams) -> None:
        """The first scan at its odometry pose; the calibration variables at the surface calibration."""
        calibrate = p.estimate_calibration
        scale_sigma = p.scale_sigma if calibrate else 1e-6
        offset_sigma = math.radians(p.offset_sigma_deg) if calibrate else 1e-6
        deviation_sigma = math.radians(p.deviation_sigma_deg) if calibrate and p.deviation else 1e-6
        self.graph.add(gtsam.PriorFactorPose2(key, gtsam.Pose2(*first.odometry), gtsam.noiseModel.Diagonal.Sigmas(
            np.array([0.01, 0.01, math.radians(p.compass_sigma_deg)]))))
        self.graph.add(gtsam.PriorFactorVector(SCALE_KEY, np.array([1.0]), gtsam.noiseModel.Isotropic.Sigma(1, scale_sigma)))
        self.graph.add(gtsam.PriorFactorVector(OFFSET_KEY, np.zeros(3), gtsam.noiseModel.Diagonal.Sigmas(
            np.array([offset_sigma, deviation_sigma, deviation_sigma]))))

    def _add_navigation(self, scans: Sequence[RangeScan], nodes: list[int], p: NavGraphParams) -> None:
        """Scaled odometry between consecutive scans and a robust compass factor on each."""
        noise = p.odometry_noise()
        for a, b in zip(nodes[:-1], nodes[1:]):
            delta, cov = odometry_covariance(scans[a], scans[b], noise)
            self.graph.add(gtsam.CustomFactor(gtsam.noiseModel.Gaussian.Covariance(cov), [a, b, SCALE_KEY],
                                              _odometry_error(delta)))
        compass = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                                                 gtsam.noiseModel.Isotropic.Sigma(1, math.radians(p.compass_sigma_deg)))
        for k in nodes:
            self.graph.add(gtsam.CustomFactor(compass, [k, OFFSET_KEY], _compass_error(float(scans[k].odometry[2]))))

    def _add_matches(self, scans: Sequence[RangeScan], matches: list[MatchResult], p: NavGraphParams) -> None:
        """One Cauchy-robust ``BetweenFactorPose2`` per match."""
        cauchy = gtsam.noiseModel.mEstimator.Cauchy.Create(p.cauchy_k)
        for m in matches:
            measured, cov = match_measurement(scans[m.i], scans[m.j], m, p)
            model = gtsam.noiseModel.Robust.Create(cauchy, gtsam.noiseModel.Gaussian.Covariance(cov))
            self.graph.add(gtsam.BetweenFactorPose2(m.i, m.j, measured, model))

    def solve(self, p: NavGraphParams) -> gtsam.Values:
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(p.max_iterations)
        return gtsam.LevenbergMarquardtOptimizer(self.graph, self.initial, params).optimize()


def _mahalanobis(values: gtsam.Values, m: MatchResult, scans: Sequence[RangeScan], p: NavGraphParams) -> float:
    measured, cov = match_measurement(scans[m.i], scans[m.j], m, p)
    predicted = values.atPose2(m.i).between(values.atPose2(m.j))
    r = gtsam.Pose2.Logmap(measured.between(predicted))
    return float(r @ np.linalg.solve(cov, r))


def solve(scans: Sequence[RangeScan], matches: Sequence[MatchResult], p: NavGraphParams
          ) -> tuple[list[int], gtsam.Values, list[MatchResult], _Graph]:
    """Solve the gated graph: (nodes, solution, the matches kept, the final graph)."""
    nodes = [k for k, s in enumerate(scans) if s.odometry is not None]
    if not nodes:
        raise ValueError("no scan has odometry: nav-graph needs scans from a survey with navigation")
    kept = _usable(matches, scans)
    graph = _Graph(scans, nodes, kept, p)
    values = graph.solve(p)
    for _ in range(p.gate_rounds):
        if not kept:
            break
        residuals = [_mahalanobis(values, m, scans, p) for m in kept]
        worst = int(np.argmax(residuals))
        if residuals[worst] <= p.gate_chi2:
            break
        kept = kept[:worst] + kept[worst + 1:]
        graph = _Graph(scans, nodes, kept, p)
        values = graph.solve(p)
    return nodes, values, kept, graph


class NavGraphLocalizer(GuidedLocalizer):
    """Pose graph over odometry, compass and scan matches with calibration (the ``nav-graph`` localizer)."""

    name: ClassVar[str] = "nav-graph"
    Params: ClassVar[type[StageParams]] = NavGraphParams

    def pairs(self, n_scans: int, params: StageParams) -> list[tuple[int, int]]:
        """Consecutive scans (none when ``consecutive`` is off)."""
        p = NavGraphParams.of(params)
        return [(k, k + 1) for k in range(n_scans - 1)] if p.consecutive else []

    def guided_pairs(self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
                     ties: Sequence[VerticalTie] = ()) -> list[tuple[int, int, MatchGuess | None]]:
        """Loop-closure candidates from the solution of the matches so far (module docstring): every
        round proposes each scan's nearest earlier scans (pairs asked before are not matched again),
        later rounds the revisits too."""
        p = NavGraphParams.of(params)
        if p.loop_per_scan == 0:
            return []
        nodes, values, _, _ = solve(scans, matches, p)
        chosen = _nearest_earlier(nodes, values, p.loop_min_gap, p.loop_per_scan, p.loop_radius_m, set())
        if any(m.j - m.i >= p.loop_min_gap for m in matches):
            asked = set(chosen)
            chosen += [pair for pair in _revisits(nodes, values, matches, p) if pair not in asked]
        return [(nodes[a], nodes[b], _loop_guess(scans, nodes, values, a, b, p)) for a, b in chosen]

    def localize(self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
                 ties: Sequence[VerticalTie] = ()) -> Poses:
        """Place every scan with odometry; the calibration estimate is in :func:`calibration_of`. The vertical ``ties`` are not used: this
        localizer places the scans of one depth level."""
        p = NavGraphParams.of(params)
        n = len(scans)
        yaw = np.array([s.yaw_rad for s in scans], dtype=np.float64)
        xy = np.full((n, 2), np.nan)
        placed = np.zeros(n, dtype=bool)
        if not any(s.odometry is not None for s in scans):
            reasons = tuple("no odometry: nav-graph needs scans from a survey with navigation" for _ in range(n))
            return Poses(xy, yaw, placed, reasons, -1, None)
        nodes, values, _, graph = solve(scans, matches, p)
        marginals = gtsam.Marginals(graph.graph, values)
        cov = np.full((n, 3, 3), np.nan)
        for k in nodes:
            pose = values.atPose2(k)
            xy[k] = (pose.x(), pose.y())
            yaw[k] = pose.theta()
            placed[k] = True
            c, s = math.cos(pose.theta()), math.sin(pose.theta())
            rot = np.eye(3)
            rot[:2, :2] = [[c, -s], [s, c]]
            cov[k] = rot @ marginals.marginalCovariance(k) @ rot.T
        reasons = tuple("" if placed[k] else "no odometry for this scan" for k in range(n))
        return Poses(xy, yaw, placed, reasons, nodes[0], cov)


def _solved_xy(values: gtsam.Values, nodes: list[int]) -> np.ndarray:
    return np.array([[values.atPose2(k).x(), values.atPose2(k).y()] for k in nodes])


def _nearest_earlier(nodes: list[int], values: gtsam.Values, min_gap: int, per_scan: int, radius_m: float,
                     skip: set[tuple[int, int]], only: set[int] | None = None) -> list[tuple[int, int]]:
    """For each node ``b`` (those in ``only``, all when None), the ``per_scan`` nearest earlier nodes ``a``
    at least ``min_gap`` scans back whose solved positions lie within ``radius_m``, leaving out the
    scan pairs in ``skip``; as (a, b) indices into ``nodes``."""
    xy = _solved_xy(values, nodes)
    out = []
    for b_idx, j in enumerate(nodes):
        if only is not None and j not in only:
            continue
        earlier = [a for a in range(b_idx) if j - nodes[a] >= min_gap and (nodes[a], j) not in skip]
        if not earlier:
            continue
        dist = np.hypot(*(xy[earlier] - xy[b_idx]).T)
        order = [earlier[int(q)] for q in np.argsort(dist, kind="stable") if dist[q] <= radius_m]
        out += [(a_idx, b_idx) for a_idx in order[:per_scan]]
    return out


def _revisits(nodes: list[int], values: gtsam.Values, matches: Sequence[MatchResult],
              p: NavGraphParams) -> list[tuple[int, int]]:
    """Revisit candidates of a later round: for each scan without a converged match to a scan at least
    ``revisit_gap`` back and with fewer than ``revisit_tries`` such pairs tried, the ``revisit_per_scan``
    nearest untried ones within ``loop_radius_m`` of the current solution.

    The first round's candidates come from the odometry alone, whose drift between revisits (several
    metres) can exceed the search window; once the matches along the track have corrected it, the
    same places are found again within the window."""
    if p.revisit_per_scan == 0:
        return []
    tried = {(m.i, m.j) for m in matches}
    closed = {m.j for m in matches if m.converged and m.j - m.i >= p.revisit_gap}
    attempts = Counter(j for i, j in tried if j - i >= p.revisit_gap)
    open_scans = {j for j in nodes if j not in closed and attempts[j] < p.revisit_tries}
    return _nearest_earlier(nodes, values, p.revisit_gap, p.revisit_per_scan, p.loop_radius_m, tried, only=open_scans)


def _loop_guess(scans: Sequence[RangeScan], nodes: list[int], values: gtsam.Values, a_idx: int, b_idx: int,
                p: NavGraphParams) -> MatchGuess:
    """The solved relative pose of nodes ``a_idx`` → ``b_idx`` as a guess, its window ``loop_window_sigma``
    standard deviations of the odometry between them, clamped to ``[loop_window_min_m, loop_window_max_m]``."""
    noise = p.odometry_noise()
    i, j = nodes[a_idx], nodes[b_idx]
    pi, pj = values.atPose2(i), values.atPose2(j)
    travelled = sum(math.hypot(*se2_between(scans[nodes[q]].odometry, scans[nodes[q + 1]].odometry)[:2])
                    for q in range(a_idx, b_idx))
    sigma = math.hypot(noise.sigma_scale, noise.sigma_heading_rad) * travelled
    radius = min(max(p.loop_window_sigma * sigma, p.loop_window_min_m), p.loop_window_max_m)
    dyaw = float(wrap_angle((pj.theta() - pi.theta()) - (scans[j].yaw_rad - scans[i].yaw_rad)))
    return MatchGuess(pj.x() - pi.x(), pj.y() - pi.y(), dyaw, radius)


def calibration_of(values: gtsam.Values) -> dict[str, float]:
    """The graph's DVL scale and compass deviation ``A + B sin(psi) + C cos(psi)`` (degrees, added to the
    compass heading; ``psi`` the map-frame yaw)."""
    a, b, c = (-math.degrees(float(v)) for v in values.atVector(OFFSET_KEY))
    return {"dvl_scale": float(values.atVector(SCALE_KEY)[0]), "compass_offset_deg": a,
            "compass_deviation_sin_deg": b, "compass_deviation_cos_deg": c}
