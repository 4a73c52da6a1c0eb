"""``particle-icp``: particle scan matching weighted by ICP error (Silver, Bradley & Thayer).

Silver et al. (Sec. 4) weight each pose particle by the ICP error of the current scan against the
reference scan — the nearest-neighbour distances of the moving points, transformed by the particle,
to the reference points (here a ``scipy.spatial.cKDTree``) — and resample with probability inversely
related to that error. Following the paper's future work (Sec. 6), the squared distance is made
robust: ``truncated`` (``min(d, c)^2``) or ``huber``, so multipath outliers cannot dominate.

Steps (one directed pair; without a guess the prior is wide):

1. Draw ``initial_particles`` poses uniformly in ``±init_m`` (x, y) and ``±init_deg`` (yaw); with a
   localizer's guess (:class:`~cistern_archive.pipeline.contracts.MatchGuess`), in its square
   ``±radius_m`` around the guessed offset and ``±guess_init_deg`` around its heading correction.
2. Weight: mean robust error ``E_k`` of a random subset of ``n_points`` moving points; the weight is the
   Boltzmann factor ``exp(-(E_k - min E) / T)`` with ``T`` the median excess error, which keeps the
   paper's ordering (smaller error, larger weight) and is invariant to the scale of the error.
3. Resample ``particles`` poses (systematic resampling) and propagate them with Gaussian noise that
   shrinks each iteration (``sigma_m``, ``sigma_deg`` times ``anneal`` per iteration, down to the floors).
4. Stop when the particle spread is below ``converge_std_m`` / ``converge_std_deg`` or after
   ``iterations``. The estimate is the weighted mean of the final particles, refined (``refine``, by
   default) by point-to-line ICP unless that moves it more than ``refine_max_shift_m``: the mean
   nearest-neighbour error, like pf-pairwise's likelihood field, is lowest where both scans' densely
   sampled walls lie on each other, which shortens matches along a gallery by a few centimetres
   (``benchmarks/RESULTS.md``).

The converged flag is honest: the spread criterion must be met and the final placement must pass the
shared test of :mod:`cistern_plugins.registration` (inliers, inlier ratio, two-direction constraint,
free-space violations); with a guess, the estimate must also lie within its square
(:func:`~cistern_plugins.registration.outside_window`). The per-iteration weight and spread averages
and particle snapshots go into
:class:`~cistern_archive.pipeline.contracts.MatchHistory`.
"""

from __future__ import annotations

import math
import time
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from cistern_archive.pipeline.contracts import (GuidedMatcher, HistoryThreshold, MatchGuess, MatchHistory,
                                                MatchResult, StageParams)
from cistern_archive.core.scan import RangeScan
from cistern_plugins.registration import (
    ConvergenceParams,
    ReferenceModel,
    fit_covariance,
    judge,
    match_confidence,
    outside_window,
    refine_point_to_line,
    robust_error,
    scan_points,
    start_pose,
    too_few_points,
    transform_many,
)


class ParticleICPParams(ConvergenceParams):
    """Parameters of :class:`ParticleICPMatcher` (plus the limits of :class:`ConvergenceParams`)."""

    particles: int = Field(300, ge=10)
    initial_particles: int = Field(3000, ge=10)
    iterations: int = Field(40, ge=1)
    n_points: int = Field(80, ge=10)
    init_m: float = Field(2.5, gt=0)
    init_deg: float = Field(25.0, ge=0, le=180)
    guess_init_deg: float = Field(6.0, ge=0, le=180, description="with a guess: the initial yaw spread around "
                                  "its heading correction (its square replaces ±init_m)")
    robust: Literal["truncated", "huber"] = "truncated"
    robust_scale_m: float = Field(0.3, gt=0)
    sigma_m: float = Field(0.2, gt=0)
    sigma_deg: float = Field(3.0, ge=0)
    anneal: float = Field(0.85, gt=0, le=1)
    floor_m: float = Field(0.01, gt=0)
    floor_deg: float = Field(0.2, ge=0)
    converge_std_m: float = Field(0.03, gt=0)
    converge_std_deg: float = Field(0.7, gt=0)
    snapshots: int = Field(4, ge=0)
    refine: Literal["none", "point-to-line"] = "point-to-line"
    refine_iterations: int = Field(30, ge=1)
    refine_correspondence_m: float = Field(0.3, gt=0)
    refine_max_shift_m: float = Field(0.2, gt=0)


def icp_errors(model: ReferenceModel, points: np.ndarray, poses: np.ndarray, kind: str, scale: float) -> np.ndarray:
    """Mean robust nearest-neighbour error of ``points`` under each pose (K, 3) -> (K,) (Silver et al. Fig. 2)."""
    moved = transform_many(points, poses).reshape(-1, 2)
    dist, _ = model.tree.query(moved, k=1, distance_upper_bound=scale * 4)
    dist = np.minimum(dist, scale * 4).reshape(len(poses), len(points))
    return robust_error(dist, kind, scale).mean(axis=1)


def boltzmann(errors: np.ndarray) -> np.ndarray:
    """Normalised weights ``exp(-(E - min E) / T)``, ``T`` the median excess error."""
    excess = errors - errors.min()
    temp = max(float(np.median(excess)), 1e-9)
    w = np.exp(-excess / temp)
    return w / w.sum()


def systematic_resample(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``n`` draws, low-variance (systematic) resampling."""
    positions = (rng.random() + np.arange(n)) / n
    return np.minimum(np.searchsorted(np.cumsum(weights), positions), len(weights) - 1)


class ParticleICPMatcher(GuidedMatcher):
    """Particle filter over (x, y, yaw) weighted by robust ICP error (the ``particle-icp`` matcher)."""

    name: ClassVar[str] = "particle-icp"
    Params: ClassVar[type[StageParams]] = ParticleICPParams

    def match(self, reference: RangeScan, moving: RangeScan, params: StageParams, *,
              rng: np.random.Generator, guess: MatchGuess | None = None) -> MatchResult:
        """Locate ``moving`` in ``reference``'s frame, around the origin or in ``guess``'s window (module
        docstring, step 1); all randomness comes from ``rng``."""
        p = ParticleICPParams.of(params).for_scans(reference, moving)
        start = time.perf_counter()
        why = too_few_points(reference, moving, p.min_points)
        if why:
            return MatchResult.no_estimate(why, seconds=time.perf_counter() - start)
        model = ReferenceModel(reference)
        src = scan_points(moving)
        scale = (np.array([p.init_m, p.init_m, math.radians(p.init_deg)]) if guess is None
                 else np.array([guess.radius_m, guess.radius_m, math.radians(p.guess_init_deg)]))
        poses = start_pose(guess) + rng.uniform(-1, 1, (p.initial_particles, 3)) * scale
        sigma = np.array([p.sigma_m, p.sigma_m, math.radians(p.sigma_deg)])
        floor = np.array([p.floor_m, p.floor_m, math.radians(p.floor_deg)])
        weight_avg, std_avg, snaps, snap_its = [], [], [], []
        snap_at = set(np.linspace(0, p.iterations - 1, p.snapshots).astype(int).tolist()) if p.snapshots else set()
        settled, it = False, 0
        for it in range(1, p.iterations + 1):
            pts = src[rng.choice(len(src), size=min(p.n_points, len(src)), replace=False)]
            errors = icp_errors(model, pts, poses, p.robust, p.robust_scale_m)
            w = boltzmann(errors)
            spread = _spread(poses, w)
            weight_avg.append(float(np.exp(-errors.min() / p.robust_scale_m**2)))
            std_avg.append(float(math.hypot(spread[0], spread[1])))
            if it - 1 in snap_at:
                snaps.append(np.column_stack([poses, w]))
                snap_its.append(it)
            if it > 1 and spread[:2].max() <= p.converge_std_m and math.degrees(spread[2]) <= p.converge_std_deg:
                settled = True
                break
            idx = systematic_resample(w, p.particles, rng)
            noise = np.maximum(sigma * p.anneal ** (it - 1), floor)
            poses = poses[idx] + rng.normal(0.0, 1.0, (p.particles, 3)) * noise
        estimate = np.average(poses, axis=0, weights=w)
        if settled and p.refine == "point-to-line":
            refined = refine_point_to_line(model, src, estimate, iterations=p.refine_iterations,
                                           correspondence_m=p.refine_correspondence_m, trim_fraction=0.8,
                                           max_shift_m=p.refine_max_shift_m)
            estimate = estimate if refined is None else refined
        quality = model.assess_pair(moving, estimate, p.limits())
        reason = "" if settled else (
            f"particles did not converge in {p.iterations} iterations (spread {std_avg[-1]:.3f} m)")
        reason = reason or outside_window(estimate, guess) or judge(quality, p.limits())
        history = MatchHistory(np.array(weight_avg), np.array(std_avg), tuple(snaps), tuple(snap_its),
                               std_threshold=HistoryThreshold(p.converge_std_m, "converge_std_m (per axis)"))
        cov = np.cov(poses.T, aweights=w) if len(poses) > 3 else None
        fit_cov = fit_covariance(model, src, estimate, p.inlier_distance_m, quality.rms_m)
        if cov is not None and fit_cov is not None:
            cov = cov + fit_cov
        return MatchResult(
            i=-1, j=-1, dx_m=float(estimate[0]), dy_m=float(estimate[1]), dyaw_rad=float(estimate[2]),
            weight=quality.inlier_ratio, converged=not reason, iterations=it,
            seconds=time.perf_counter() - start, reason=reason, covariance=cov, history=history,
            confidence=match_confidence(quality, p.limits()),
        )


def _spread(poses: np.ndarray, w: np.ndarray) -> np.ndarray:
    mean = np.average(poses, axis=0, weights=w)
    return np.sqrt(np.average((poses - mean) ** 2, axis=0, weights=w))
