"""``pose-graph``: robust least squares over every converged pair in a sliding window (GTSAM).

McVicker et al. localise from neighbouring pairs only (eqs. 7–10) and name matching beyond neighbours
as future work. This localizer asks the matcher for every pair within ``window`` scans (both
directions, or one), and solves for all positions and yaw corrections at once.

Model: one ``Pose2`` variable per scan, ``X_k = (x_k, y_k, c_k)`` with ``(x_k, y_k)`` the map-frame
position and ``c_k`` the correction added to the compass yaw. A converged match ``(i, j)`` measures
``d_ij`` in scan i's compass frame and ``dyaw``; with i's correction ``c_i`` the map-frame
displacement is ``R(c_i) d_ij``, which is exactly GTSAM's ``BetweenFactorPose2`` measurement
``X_i^-1 X_j = (d_ij, dyaw)``. Each factor's noise is the match's covariance (or the default sigmas)
wrapped in a robust M-estimator (``huber`` or ``cauchy``), so a wrong match that slipped through is
down-weighted. The compass is trusted up to ``compass_sigma_deg`` (a prior on every ``c_k``), and the
reference scan (the one with most converged matches, lowest index on ties, as in Table III) is
anchored at the origin. Levenberg–Marquardt solves the graph; ``gtsam.Marginals`` gives each scan's
3×3 covariance, rotated into the map frame. Scans with no converged path to the reference are
returned unplaced with the reason.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import ClassVar, Literal

import gtsam
import numpy as np
from pydantic import Field

from cistern_archive.pipeline.contracts import MatchResult, Poses, StageParams
from cistern_archive.sonar.scan import RangeScan


class PoseGraphParams(StageParams):
    """Parameters of :class:`PoseGraphLocalizer`."""

    window: int = Field(3, ge=1)
    directions: Literal["both", "one"] = "both"
    robust: Literal["huber", "cauchy", "none"] = "huber"
    robust_k: float = Field(1.345, gt=0)
    sigma_xy_m: float = Field(0.05, gt=0)
    sigma_yaw_deg: float = Field(1.0, gt=0)
    min_sigma_xy_m: float = Field(0.01, gt=0)
    compass_sigma_deg: float = Field(5.0, gt=0)
    max_iterations: int = Field(100, ge=1)


class PoseGraphLocalizer:
    """Sliding-window pose graph with robust factors and marginal covariances (the ``pose-graph`` localizer)."""

    name: ClassVar[str] = "pose-graph"
    Params: ClassVar[type[StageParams]] = PoseGraphParams

    def pairs(self, n_scans: int, params: StageParams) -> list[tuple[int, int]]:
        """Every pair within ``window`` scans of each other, nearest first; both directions unless ``one``."""
        p = _params(params)
        out: list[tuple[int, int]] = []
        for gap in range(1, p.window + 1):
            for i in range(n_scans - gap):
                out.append((i, i + gap))
                if p.directions == "both":
                    out.append((i + gap, i))
        return out

    def localize(self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams) -> Poses:
        """Place every scan connected to the reference by converged matches."""
        p = _params(params)
        n = len(scans)
        good = [m for m in matches if m.converged and 0 <= m.i < n and 0 <= m.j < n and m.i != m.j
                and np.isfinite([m.dx_m, m.dy_m, m.dyaw_rad]).all()]
        reference = _reference(n, good)
        yaw = np.array([s.yaw_rad for s in scans], dtype=np.float64)
        if reference < 0:
            reasons = tuple("no converged match" for _ in range(n))
            return Poses(np.full((n, 2), np.nan), yaw, np.zeros(n, bool), reasons, -1, None)
        initial = _spanning_tree(n, good, reference)
        placed = np.array([k in initial for k in range(n)])
        graph, values = _build_graph(good, initial, reference, p)
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, _lm(p)).optimize()
        marginals = gtsam.Marginals(graph, result)
        xy = np.full((n, 2), np.nan)
        cov = np.full((n, 3, 3), np.nan)
        out_yaw = yaw.copy()
        for k in range(n):
            if not placed[k]:
                continue
            pose = result.atPose2(k)
            xy[k] = (pose.x(), pose.y())
            out_yaw[k] = yaw[k] + pose.theta()
            rot = np.eye(3)
            c, s = math.cos(pose.theta()), math.sin(pose.theta())
            rot[:2, :2] = [[c, -s], [s, c]]
            cov[k] = rot @ marginals.marginalCovariance(k) @ rot.T
        reasons = tuple("" if placed[k] else f"no converged path of matches to reference scan {reference}"
                        for k in range(n))
        return Poses(xy, out_yaw, placed, reasons, reference, cov)


def _params(params: StageParams) -> PoseGraphParams:
    return params if isinstance(params, PoseGraphParams) else PoseGraphParams.model_validate(params.model_dump())


def _lm(p: PoseGraphParams) -> gtsam.LevenbergMarquardtParams:
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(p.max_iterations)
    return lm


def _reference(n: int, good: Sequence[MatchResult]) -> int:
    """The scan with most converged matches (lowest index on ties); -1 when there are none."""
    if not good:
        return 0 if n == 1 else -1
    counts = np.zeros(n, dtype=int)
    for m in good:
        counts[m.i] += 1
        counts[m.j] += 1
    return int(np.argmax(counts))


def _spanning_tree(n: int, good: Sequence[MatchResult], reference: int) -> dict[int, gtsam.Pose2]:
    """Initial poses by composing matches breadth-first from the reference."""
    adj: dict[int, list[tuple[int, gtsam.Pose2]]] = {k: [] for k in range(n)}
    for m in good:
        z = gtsam.Pose2(m.dx_m, m.dy_m, m.dyaw_rad)
        adj[m.i].append((m.j, z))
        adj[m.j].append((m.i, z.inverse()))
    poses = {reference: gtsam.Pose2(0.0, 0.0, 0.0)}
    queue = deque([reference])
    while queue:
        a = queue.popleft()
        for b, z in adj[a]:
            if b not in poses:
                poses[b] = poses[a].compose(z)
                queue.append(b)
    return poses


def _noise(m: MatchResult, p: PoseGraphParams) -> gtsam.noiseModel.Base:
    if m.covariance is not None and np.isfinite(m.covariance).all():
        cov = 0.5 * (m.covariance + m.covariance.T) + np.diag([p.min_sigma_xy_m**2] * 2 + [1e-6])
        base = gtsam.noiseModel.Gaussian.Covariance(cov)
    else:
        base = gtsam.noiseModel.Diagonal.Sigmas(np.array([p.sigma_xy_m, p.sigma_xy_m, math.radians(p.sigma_yaw_deg)]))
    if p.robust == "none":
        return base
    est = (gtsam.noiseModel.mEstimator.Huber.Create(p.robust_k) if p.robust == "huber"
           else gtsam.noiseModel.mEstimator.Cauchy.Create(p.robust_k))
    return gtsam.noiseModel.Robust.Create(est, base)


def _build_graph(good: Sequence[MatchResult], initial: dict[int, gtsam.Pose2], reference: int,
                 p: PoseGraphParams) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    anchor = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-6]))
    graph.add(gtsam.PriorFactorPose2(reference, gtsam.Pose2(0, 0, 0), anchor))
    compass = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e4, 1e4, math.radians(p.compass_sigma_deg)]))
    for k, pose in sorted(initial.items()):
        values.insert(k, pose)
        if k != reference:
            graph.add(gtsam.PriorFactorPose2(k, gtsam.Pose2(0, 0, 0), compass))
    for m in good:
        if m.i in initial and m.j in initial:
            graph.add(gtsam.BetweenFactorPose2(m.i, m.j, gtsam.Pose2(m.dx_m, m.dy_m, m.dyaw_rad), _noise(m, p)))
    return graph, values
