"""The GTSAM factor graph the graph localizers (``pose-graph``, ``site-graph``) solve.

Model: one ``Pose2`` variable per scan, ``X_k = (x_k, y_k, c_k)`` with ``(x_k, y_k)`` the map-frame
position and ``c_k`` the correction added to the compass yaw. A converged match ``(i, j)`` measures
``d_ij`` in scan i's compass frame and ``dyaw``; with i's correction ``c_i`` the map-frame displacement
is ``R(c_i) d_ij``, which is exactly GTSAM's ``BetweenFactorPose2`` measurement ``X_i^-1 X_j = (d_ij,
dyaw)``. Each factor's noise is the match's covariance (floored at ``min_sigma_xy_m``, or default sigmas
when the matcher gives none), optionally wrapped in a robust M-estimator. Every correction ``c_k`` has a
prior of ``compass_sigma_deg`` about the compasses' common frame, itself a variable
(:func:`add_compass_factors`), and the reference scan is anchored at the origin. Levenberg–Marquardt
solves the graph; ``gtsam.Marginals`` gives each scan's covariance.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

from typing import Literal

import gtsam
import numpy as np
from pydantic import Field
from scipy.optimize import brentq

from cistern_archive.core.scan import wrap_angle
from cistern_archive.pipeline.contracts import MatchResult, Poses, StageParams
from cistern_archive.core.scan import RangeScan


@dataclass(frozen=True)
class GraphNoise:
    """Noise settings of the factor graph (see the module docstring)."""

    robust: str = "huber"
    robust_k: float = 1.345
    sigma_xy_m: float = 0.05
    sigma_yaw_deg: float = 1.0
    min_sigma_xy_m: float = 0.03
    compass_sigma_deg: float = 2.0
    max_iterations: int = 100


class GraphParams(StageParams):
    """The factor graph's noise and solver parameters, shared by the graph localizers."""

    robust: Literal["huber", "cauchy", "none"] = "huber"
    robust_k: float = Field(1.345, gt=0)
    sigma_xy_m: float = Field(0.05, gt=0)
    sigma_yaw_deg: float = Field(1.0, gt=0)
    min_sigma_xy_m: float = Field(0.03, gt=0)
    compass_sigma_deg: float = Field(2.0, gt=0)
    max_iterations: int = Field(100, ge=1)
    gate_chi2: float = Field(16.27, gt=0, description="99.9 % quantile of chi-square with 3 degrees of freedom")
    gate_rounds: int = Field(3, ge=0)

    def noise(self) -> GraphNoise:
        return GraphNoise(self.robust, self.robust_k, self.sigma_xy_m, self.sigma_yaw_deg, self.min_sigma_xy_m,
                          self.compass_sigma_deg, self.max_iterations)


@dataclass(frozen=True)
class Edge:
    """One relative-pose measurement between scans ``i`` and ``j``: ``X_i^-1 X_j = z``."""

    i: int
    j: int
    z: np.ndarray
    covariance: np.ndarray

    @classmethod
    def of_match(cls, m: MatchResult, noise: GraphNoise) -> "Edge":
        return cls(m.i, m.j, np.array([m.dx_m, m.dy_m, m.dyaw_rad], dtype=np.float64), match_covariance(m, noise))


def match_covariance(m: MatchResult, noise: GraphNoise) -> np.ndarray:
    """The covariance a match's factor gets: the matcher's own, floored, or the default sigmas."""
    if m.covariance is not None and np.isfinite(m.covariance).all():
        floor = np.diag([noise.min_sigma_xy_m**2] * 2 + [math.radians(0.2) ** 2])
        return 0.5 * (m.covariance + m.covariance.T) + floor
    return np.diag([noise.sigma_xy_m**2, noise.sigma_xy_m**2, math.radians(noise.sigma_yaw_deg) ** 2])


def spanning_tree(n: int, edges: Sequence[Edge], reference: int) -> dict[int, gtsam.Pose2]:
    """Initial poses by composing edges breadth-first from the reference."""
    adj: dict[int, list[tuple[int, gtsam.Pose2]]] = {k: [] for k in range(n)}
    for e in edges:
        z = gtsam.Pose2(*e.z)
        adj[e.i].append((e.j, z))
        adj[e.j].append((e.i, z.inverse()))
    poses = {reference: gtsam.Pose2(0.0, 0.0, 0.0)}
    queue = deque([reference])
    while queue:
        a = queue.popleft()
        for b, z in adj[a]:
            if b not in poses:
                poses[b] = poses[a].compose(z)
                queue.append(b)
    return poses


def _noise_model(e: Edge, noise: GraphNoise) -> gtsam.noiseModel.Base:
    base = gtsam.noiseModel.Gaussian.Covariance(e.covariance)
    if noise.robust == "none":
        return base
    est = (gtsam.noiseModel.mEstimator.Huber.Create(noise.robust_k) if noise.robust == "huber"
           else gtsam.noiseModel.mEstimator.Cauchy.Create(noise.robust_k))
    return gtsam.noiseModel.Robust.Create(est, base)


def solve(n: int, edges: Sequence[Edge], reference: int, noise: GraphNoise,
          initial: dict[int, gtsam.Pose2] | None = None) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict]:
    """Solve the graph of the scans the edges join to ``reference``; returns (graph, values, initial)."""
    initial = spanning_tree(n, edges, reference) if initial is None else initial
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    anchor = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-6]))
    graph.add(gtsam.PriorFactorPose2(reference, gtsam.Pose2(0, 0, 0), anchor))
    add_compass_factors(graph, values, sorted(initial), noise)
    for k, pose in sorted(initial.items()):
        values.insert(k, pose)
    for e in edges:
        if e.i in initial and e.j in initial:
            graph.add(gtsam.BetweenFactorPose2(e.i, e.j, gtsam.Pose2(*e.z), _noise_model(e, noise)))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(noise.max_iterations)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, lm).optimize()
    return graph, result, initial


COMPASS_FRAME = gtsam.symbol("c", 0)
"""Key of the compass frame's turn against the map frame (:func:`add_compass_factors`)."""


def add_compass_factors(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: Sequence[int],
                        noise: GraphNoise) -> None:
    """The compass as a prior on every scan's heading correction ``c_k``, against one common frame.

    Every compass reading has ``compass_sigma_deg`` of noise about the true heading plus a bias the
    scans share; the map frame is the reference scan's compass frame, so the reference's own error is
    in every other scan's correction. A prior ``c_k ~ N(0, sigma)`` would treat that one reading as
    exact and pull a loosely joined part of the site (a group joined along a tunnel) round towards it.
    Instead one more variable ``F`` (:data:`COMPASS_FRAME`) is the turn of the compasses' common frame
    against the map, and each scan, the reference included, has ``c_k - F ~ N(0, sigma)``: a
    ``BetweenFactorPose2(F, X_k)`` whose position part is free (10 km).
    """
    sigma = math.radians(noise.compass_sigma_deg)
    compass = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e4, 1e4, sigma]))
    values.insert(COMPASS_FRAME, gtsam.Pose2(0.0, 0.0, 0.0))
    graph.add(gtsam.PriorFactorPose2(COMPASS_FRAME, gtsam.Pose2(0.0, 0.0, 0.0),
                                     gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 1.0, math.pi]))))
    for k in keys:
        graph.add(gtsam.BetweenFactorPose2(COMPASS_FRAME, k, gtsam.Pose2(0.0, 0.0, 0.0), compass))


def chi2(e: Edge, values: gtsam.Values) -> float:
    """Squared Mahalanobis distance of an edge from a solution (without the robust loss)."""
    rel = values.atPose2(e.i).between(values.atPose2(e.j))
    err = np.array([rel.x() - e.z[0], rel.y() - e.z[1], wrap_angle(rel.theta() - e.z[2])])
    return float(err @ np.linalg.solve(e.covariance, err))


def solve_gated(n: int, edges: list[Edge], reference: int, noise: GraphNoise, gate_chi2: float,
                gate_rounds: int, keep: frozenset[int] = frozenset()):
    """Solve, then drop the worst edge while its squared Mahalanobis residual exceeds ``gate_chi2``
    (edges whose index is in ``keep`` are never dropped); returns (graph, values, edges kept)."""
    for _ in range(gate_rounds + 1):
        graph, result, initial = solve(n, edges, reference, noise)
        scores = [chi2(e, result) if k not in keep and e.i in initial and e.j in initial else 0.0
                  for k, e in enumerate(edges)]
        worst = int(np.argmax(scores)) if scores else -1
        if worst < 0 or scores[worst] <= gate_chi2 or len(edges) <= 1:
            break
        edges = edges[:worst] + edges[worst + 1:]
        keep = frozenset(k if k < worst else k - 1 for k in keep if k != worst)
    return graph, result, edges


def poses_from_solution(scans: Sequence[RangeScan], graph: gtsam.NonlinearFactorGraph, result: gtsam.Values,
                        placed_keys: set[int], reference: int, reasons: Sequence[str],
                        links: Sequence[tuple[int, int]] = ()) -> Poses:
    """:class:`Poses` of the solved scans, with marginal covariances rotated into the map frame; ``links``
    become :attr:`Poses.group_links`, each with its :func:`relative_radius95_m`."""
    n = len(scans)
    yaw = np.array([s.yaw_rad for s in scans], dtype=np.float64)
    placed = np.array([k in placed_keys for k in range(n)])
    xy = np.full((n, 2), np.nan)
    cov = np.full((n, 3, 3), np.nan)
    marginals = gtsam.Marginals(graph, result)
    for k in sorted(placed_keys):
        pose = result.atPose2(k)
        xy[k] = (pose.x(), pose.y())
        yaw[k] = yaw[k] + pose.theta()
        rot = np.eye(3)
        c, s = math.cos(pose.theta()), math.sin(pose.theta())
        rot[:2, :2] = [[c, -s], [s, c]]
        cov[k] = rot @ marginals.marginalCovariance(k) @ rot.T
    radii = tuple(relative_radius95_m(marginals, result, i, j) for i, j in links)
    return Poses(xy, yaw, placed, tuple("" if placed[k] else reasons[k] for k in range(n)), reference, cov,
                 group_links=tuple(links), group_link_radius95_m=radii)


def relative_radius95_m(marginals: gtsam.Marginals, result: gtsam.Values, i: int, j: int) -> float:
    """Radius (m) within which scan ``j``'s position relative to scan ``i`` lies with 95 % probability,
    from the two scans' joint marginal covariance (:func:`radius95_m`).

    With ``T_i`` and ``T_j`` perturbed on the right by ``Exp(d_i)`` and ``Exp(d_j)``, their relative pose
    ``T_i^-1 T_j`` is perturbed by ``d_j - Ad(T_ij^-1) d_i`` (first order), whose covariance follows from
    the joint one. Unlike the marginals of the two scans, which grow with their distance from the
    reference scan, it measures how well the two are placed against each other.
    """
    joint = marginals.jointMarginalCovariance(gtsam.KeyVector([i, j]))
    full = np.block([[joint.at(i, i), joint.at(i, j)], [joint.at(j, i), joint.at(j, j)]])
    between = result.atPose2(i).between(result.atPose2(j))
    jacobian = np.hstack([-between.inverse().AdjointMap(), np.eye(3)])
    relative = jacobian @ full @ jacobian.T
    return radius95_m(relative[:2, :2])


def radius95_m(covariance: np.ndarray, probability: float = 0.95) -> float:
    """The radius of the circle about the mean that holds a 2-D Gaussian position error with
    ``probability``: ``1.96 σ`` along the least certain direction when the other is certain, up to
    ``2.45 σ`` when both are alike (the chi-square of two degrees of freedom).

    A join's error is a distance, not one coordinate: ``1.96 σ`` of its least certain direction held the
    error of 306 of 335 joins of random cisterns (91.3 %; ``benchmarks/RESULTS.md``, "2026-12-07 (session
    28) — a join's 95 % radius"). With ``λ1, λ2`` the covariance's eigenvalues, a direction ``θ`` of the
    standard normal plane reaches ``r`` at a squared radius ``r^2 / (λ1 cos^2 θ + λ2 sin^2 θ)``, chi-square
    with two degrees of freedom, so ``P(|e| <= r)`` is the mean over ``θ`` of
    ``1 - exp(-r^2 / (2 (λ1 cos^2 θ + λ2 sin^2 θ)))``. ``nan`` for a covariance that is not finite.
    """
    if not np.all(np.isfinite(covariance)):
        return math.nan
    lam = np.clip(np.linalg.eigvalsh(0.5 * (covariance + covariance.T)), 0.0, None)
    if lam[-1] <= 0:
        return 0.0
    theta = (np.arange(360) + 0.5) * (math.pi / 360)
    spread = lam[1] * np.cos(theta) ** 2 + lam[0] * np.sin(theta) ** 2

    def held(r: float) -> float:
        return float(np.mean(1.0 - np.exp(-r * r / (2.0 * spread)))) - probability

    top = math.sqrt(-2.0 * math.log(1.0 - probability) * lam[-1])  # both directions as uncertain
    return float(brentq(held, 0.0, top * 1.001))
