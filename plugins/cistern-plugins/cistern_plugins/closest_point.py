"""Iterative closest point on two scans' echoes: the iteration, the point-to-line refinement that the
search matchers end with, and the covariance of a point-to-line fit.

Part of the public registration API (:mod:`cistern_plugins.registration`); the ``icp`` matcher is this
iteration started from the compass-aligned zero pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cistern_archive.core.scan import wrap_angle
from cistern_plugins.alignment import (
    ReferenceModel,
    compose,
    covariance_from_fit,
    estimate_normals,
    kabsch_2d,
    parallel_walls,
    point_to_line_step,
    rotate,
    transform,
)


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
        pose[2] = wrap_angle(pose[2])
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


def fit_covariance(model: ReferenceModel, src: np.ndarray, pose: np.ndarray, inlier_distance_m: float,
                   rms_m: float) -> np.ndarray | None:
    """Covariance of (x, y, theta) from the point-to-line inliers of the moving points ``src`` placed by
    ``pose``, or ``None``. θ turns the moving scan about its own sonar (``pose[:2]``), as the pose-graph
    factors do, so the lever arms are the placed points' offsets from it.

    An inlier counts only where its own wall runs alike the reference wall it lies on
    (:func:`~cistern_plugins.alignment.parallel_walls`). A moving point near a corner of the reference,
    on a wall that meets the reference's wall across it, holds nothing along that wall's normal: a
    station inside a tunnel, matched to a chamber's station, lays the ends of the tunnel's side walls on
    the chamber's wall beside the mouth, and those points made a match that had slid 0.42 m along the
    tunnel look held to ±0.011 m along it (random cisterns, seed 116 ``cistern-009``; ±0.27 m without
    them, ``benchmarks/RESULTS.md``).
    """
    moved = transform(src, pose)
    dist, idx = model.tree.query(moved, k=1)
    inl = dist <= inlier_distance_m
    if inl.sum() >= 3:
        own = rotate(estimate_normals(src, cKDTree(src)), pose[2])
        inl[inl] = parallel_walls(own[inl], model.normals[idx[inl]])
    if inl.sum() < 3:
        return None
    return covariance_from_fit(moved[inl] - np.asarray(pose[:2]), model.normals[idx[inl]], rms_m)
