"""``icp``: iterative closest point, the baseline scan matcher both papers compare against.

Besl & McKay (1992) point-to-point ICP, or the point-to-line variant (Chen & Medioni 1992; Censi
2008) that Silver et al. list among ICP's refinements, started from the compass-aligned zero pose.
Outliers are rejected at every iteration by a correspondence distance gate and by trimming (keep the
best ``trim_fraction`` of the pairs, Chetverikov et al. 2002). The result is reported converged only
when the iteration settled *and* the final fit passes the shared test of
:mod:`cistern_plugins.alignment` (inliers, inlier ratio, two-direction constraint).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from cistern_archive.pipeline.contracts import MatchResult, StageParams
from cistern_archive.core.scan import RangeScan
from cistern_plugins.verification import judge, match_confidence
from cistern_plugins.alignment import (
    ConvergenceParams,
    ReferenceModel,
    compose,
    covariance_from_fit,
    kabsch_2d,
    point_to_line_step,
    scan_points,
    too_few_points,
    transform,
    wrap,
)


class ICPParams(ConvergenceParams):
    """Parameters of :class:`ICPMatcher` (plus the convergence limits of :class:`ConvergenceParams`)."""

    variant: Literal["point-to-point", "point-to-line"] = "point-to-line"
    max_iterations: int = Field(100, ge=1)
    max_correspondence_m: float = Field(1.0, gt=0)
    trim_fraction: float = Field(0.8, gt=0, le=1)
    tolerance_m: float = Field(1e-3, gt=0)


@dataclass(frozen=True)
class ICPOutcome:
    """Final pose of an ICP run and whether the iteration settled."""

    pose: np.ndarray
    iterations: int
    settled: bool


def run_icp(model: ReferenceModel, src: np.ndarray, pose0: np.ndarray, *, variant: str, max_iterations: int,
            max_correspondence_m: float, trim_fraction: float, tolerance_m: float) -> ICPOutcome:
    """Iterate closest-point matching from ``pose0``; returns the final pose (x, y, theta).

    Each iteration pairs every transformed moving point with its nearest reference point (k-d tree),
    drops pairs farther than ``max_correspondence_m`` and all but the closest ``trim_fraction``, and
    solves the point-to-point (closed form) or point-to-line (one Gauss-Newton step) update.
    """
    pose = np.asarray(pose0, dtype=np.float64).copy()
    recent: list[np.ndarray] = []
    for it in range(1, max_iterations + 1):
        moved = transform(src, pose)
        dist, idx = model.tree.query(moved, k=1, distance_upper_bound=max_correspondence_m)
        ok = np.isfinite(dist)
        if ok.sum() < 3:
            return ICPOutcome(pose, it, False)
        keep = np.flatnonzero(ok)
        n_keep = max(3, int(math.ceil(trim_fraction * len(keep))))
        keep = keep[np.argsort(dist[keep], kind="stable")[:n_keep]]
        if variant == "point-to-point":
            delta = kabsch_2d(moved[keep], model.points[idx[keep]])
        else:
            delta = point_to_line_step(moved[keep], model.points[idx[keep]], model.normals[idx[keep]])
        pose = compose(delta, pose)
        pose[2] = wrap(pose[2])
        if math.hypot(delta[0], delta[1]) < tolerance_m and abs(delta[2]) < tolerance_m / 10:
            return ICPOutcome(pose, it, True)
        recent = (recent + [pose.copy()])[-6:]
        if len(recent) == 6 and _cycling(np.array(recent), 10 * tolerance_m):
            return ICPOutcome(pose, it, True)
    return ICPOutcome(pose, max_iterations, False)


def refine_point_to_line(model: ReferenceModel, src: np.ndarray, pose: np.ndarray, *, iterations: int,
                         correspondence_m: float, trim_fraction: float, max_shift_m: float) -> np.ndarray | None:
    """``pose`` refined by trimmed point-to-line ICP (:func:`run_icp`), or ``None`` when the refinement
    moves it farther than ``max_shift_m`` (it slid away along a corridor or onto another wall).

    The search matchers (pf-pairwise, particle-icp, correlative) find the right basin on a coarse score;
    point-to-line distances to the reference's local wall lines then settle the pose without the pull a
    point score has towards where both scans sample their walls densely (``benchmarks/RESULTS.md``).
    """
    out = run_icp(model, src, np.asarray(pose, dtype=np.float64), variant="point-to-line",
                  max_iterations=iterations, max_correspondence_m=correspondence_m, trim_fraction=trim_fraction,
                  tolerance_m=1e-4)
    if math.hypot(out.pose[0] - pose[0], out.pose[1] - pose[1]) > max_shift_m:
        return None
    return out.pose


def _cycling(poses: np.ndarray, tolerance_m: float) -> bool:
    """Whether the last poses only hop between correspondence sets within ``tolerance_m`` (a settled
    oscillation, common with trimming on noisy scans)."""
    spread = poses.max(axis=0) - poses.min(axis=0)
    return bool(math.hypot(spread[0], spread[1]) < tolerance_m and spread[2] < tolerance_m / 10)


class ICPMatcher:
    """Point-to-point / point-to-line ICP with outlier rejection (the ``icp`` matcher)."""

    name: ClassVar[str] = "icp"
    Params: ClassVar[type[StageParams]] = ICPParams

    def match(self, reference: RangeScan, moving: RangeScan, params: StageParams, *,
              rng: np.random.Generator) -> MatchResult:
        """Locate ``moving`` in ``reference``'s frame; ``rng`` is unused (ICP is deterministic)."""
        p = ICPParams.of(params)
        start = time.perf_counter()
        why = too_few_points(reference, moving, p.min_points)
        if why:
            return MatchResult.no_estimate(why, seconds=time.perf_counter() - start)
        model = ReferenceModel(reference)
        src = scan_points(moving)
        out = run_icp(model, src, np.zeros(3), variant=p.variant, max_iterations=p.max_iterations,
                      max_correspondence_m=p.max_correspondence_m, trim_fraction=p.trim_fraction,
                      tolerance_m=p.tolerance_m)
        quality = model.assess_pair(moving, out.pose, p.limits())
        reason = "" if out.settled else f"did not settle in {p.max_iterations} iterations"
        reason = reason or judge(quality, p.limits())
        return MatchResult(
            i=-1, j=-1, dx_m=float(out.pose[0]), dy_m=float(out.pose[1]), dyaw_rad=float(out.pose[2]),
            weight=quality.inlier_ratio, converged=not reason, iterations=out.iterations,
            seconds=time.perf_counter() - start, reason=reason,
            covariance=fit_covariance(model, src, out.pose, p.inlier_distance_m, quality.rms_m),
            confidence=match_confidence(quality, p.limits()),
        )


def fit_covariance(model: ReferenceModel, src: np.ndarray, pose: np.ndarray, inlier_distance_m: float,
                   rms_m: float) -> np.ndarray | None:
    """Covariance of (x, y, theta) from the point-to-line inliers of the moving points ``src`` placed by
    ``pose``, or ``None``. θ turns the moving scan about its own sonar (``pose[:2]``), as the pose-graph
    factors do, so the lever arms are the placed points' offsets from it."""
    moved = transform(src, pose)
    dist, idx = model.tree.query(moved, k=1)
    inl = dist <= inlier_distance_m
    if inl.sum() < 3:
        return None
    return covariance_from_fit(moved[inl] - np.asarray(pose[:2]), model.normals[idx[inl]], rms_m)

