"""``guided-correlative``: correlative scan matching in a window around an odometry guess.

For a sonar on a moving vehicle the dead-reckoned displacement between two revolutions is known to
a metre or two, so the search is not global (as the ``correlative`` matcher's) but a window around it,
which also keeps the search cheap at the 50 m range of a harbour sonar.

Model (Olson 2009, "Real-time correlative scan matching", Sec. III): the reference echoes are
rasterised into a likelihood grid ``L = exp(-d^2 / (2 sigma^2))``, ``d`` the distance to the nearest
reference echo (a Euclidean distance transform); a pose's score is the mean of ``L`` under the moving
echoes. Every echo counts, so a scan may hold several echoes per bearing (motion-compensated
point clouds). The search is exhaustive, coarse to fine: translations on a ``coarse_m`` lattice over
``±radius`` (the guess's, else ``radius_m``) times yaw corrections over ``±yaw_window_deg``, then a
``fine_m`` lattice over ``±coarse_m`` and finer yaws around the coarse optimum.

Uncertainty (Olson eq. 5–6): the coarse scores at the best yaw are turned into a distribution
``p ∝ exp((s - s_max) / temperature)``; its covariance, floored at ``min_sigma_m``, is the match's.

Honesty: the match converges only when the best score reaches ``min_score``, the optimum lies inside
the window (not on its edge), and no other local maximum farther than ``ambiguity_distance_m`` from it
scores above ``ambiguity_ratio`` times the best (a second peak). A ridge along a featureless quay is
one elongated peak: it passes, and its covariance says how little it knows along the ridge.
"""

from __future__ import annotations

import math
import time
from typing import ClassVar

import numpy as np
from pydantic import Field
from scipy import ndimage

from cistern_archive.pipeline.contracts import GuidedMatcher, MatchGuess, MatchResult, StageParams
from cistern_archive.core.scan import RangeScan
from cistern_plugins.registration import SonarScaled


class GuidedCorrelativeParams(SonarScaled):
    """Parameters of :class:`GuidedCorrelativeMatcher`. Lengths are written for the calibration sonar
    and sites (bins of 0.04–0.05 m, walls within 10 m) and scaled to each pair's
    (:meth:`~cistern_plugins.registration.SonarScaled.for_scans`): 2.3–4.9 times these for the
    Girona marina's clouds (their farther echoes 23–49 m off). At 5 they are the sizes this matcher
    had in metres for that survey's Miniking."""

    radius_m: float = Field(0.6, gt=0)
    yaw_window_deg: float = Field(3.0, ge=0, le=45)
    yaw_step_deg: float = Field(0.5, gt=0)
    coarse_m: float = Field(0.04, gt=0)
    fine_m: float = Field(0.02, gt=0)
    sigma_m: float = Field(0.06, gt=0)
    max_points: int = Field(800, ge=10)
    min_points: int = Field(50, ge=3)
    min_score: float = Field(0.25, ge=0, le=1)
    ambiguity_ratio: float = Field(0.9, gt=0, le=1)
    ambiguity_distance_m: float = Field(0.4, gt=0)
    temperature: float = Field(0.01, gt=0)
    min_sigma_m: float = Field(0.02, gt=0)
    min_sigma_deg: float = Field(0.5, gt=0)


class LikelihoodGrid:
    """``exp(-d^2 / 2 sigma^2)`` around a set of points, sampled on a square lattice."""

    def __init__(self, points: np.ndarray, cell_m: float, sigma_m: float, margin_m: float):
        self.cell = cell_m
        self.origin = points.min(axis=0) - margin_m
        shape = np.ceil((points.max(axis=0) + margin_m - self.origin) / cell_m).astype(int) + 1
        empty = np.ones((shape[1], shape[0]), dtype=bool)
        cells = np.floor((points - self.origin) / cell_m).astype(int)
        empty[cells[:, 1], cells[:, 0]] = False
        distance = ndimage.distance_transform_edt(empty) * cell_m
        self.values = np.exp(-0.5 * (distance / sigma_m) ** 2).astype(np.float32)

    def mean_under(self, points: np.ndarray) -> np.ndarray:
        """Mean value under ``points`` of shape (..., N, 2); points outside the grid count 0."""
        cells = np.floor((points - self.origin) / self.cell).astype(np.int64)
        h, w = self.values.shape
        inside = (cells[..., 0] >= 0) & (cells[..., 0] < w) & (cells[..., 1] >= 0) & (cells[..., 1] < h)
        values = self.values[np.clip(cells[..., 1], 0, h - 1), np.clip(cells[..., 0], 0, w - 1)]
        return np.where(inside, values, 0.0).mean(axis=-1)


def _rotate(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return points @ np.array([[c, s], [-s, c]])


def _search(grid: LikelihoodGrid, points: np.ndarray, centre: np.ndarray, radius_m: float,
            yaws: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scores (Y, T, T) of every yaw and translation ``centre + (i, j) * grid.cell`` and the offsets (T,).

    Translations are whole cells of ``grid``, so every score is a gather from the zero-padded grid.
    """
    n = int(math.ceil(radius_m / grid.cell))
    offsets = np.arange(-n, n + 1)
    padded = np.pad(grid.values, n)
    h, w = padded.shape
    gx, gy = np.meshgrid(offsets, offsets, indexing="ij")
    scores = np.empty((len(yaws), len(offsets), len(offsets)))
    for k, yaw in enumerate(yaws):
        cells = np.floor((_rotate(points, float(yaw)) + centre - grid.origin) / grid.cell).astype(np.int64) + n
        cols = cells[None, :, 0] + gx.reshape(-1, 1)
        rows = cells[None, :, 1] + gy.reshape(-1, 1)
        inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        values = padded[np.clip(rows, 0, h - 1), np.clip(cols, 0, w - 1)] * inside
        scores[k] = values.mean(axis=1).reshape(len(offsets), len(offsets))
    return scores, offsets * grid.cell


def _subsample(points: np.ndarray, limit: int) -> np.ndarray:
    """At most ``limit`` points, evenly spaced in the input order (deterministic)."""
    if len(points) <= limit:
        return points
    return points[np.linspace(0, len(points) - 1, limit).astype(int)]


def _covariance(scores: np.ndarray, offsets: np.ndarray, p: GuidedCorrelativeParams) -> np.ndarray:
    """Olson eqs. 5–6 over one yaw's translation scores, floored (see the module docstring)."""
    w = np.exp((scores - scores.max()) / p.temperature)
    w /= w.sum()
    gx, gy = np.meshgrid(offsets, offsets, indexing="ij")
    mx, my = float((w * gx).sum()), float((w * gy).sum())
    cxx = float((w * (gx - mx) ** 2).sum())
    cyy = float((w * (gy - my) ** 2).sum())
    cxy = float((w * (gx - mx) * (gy - my)).sum())
    cov = np.zeros((3, 3))
    cov[:2, :2] = np.array([[cxx, cxy], [cxy, cyy]]) + p.min_sigma_m ** 2 * np.eye(2)
    cov[2, 2] = math.radians(p.min_sigma_deg) ** 2
    return cov


def _ambiguity(scores: np.ndarray, offsets: np.ndarray, best_xy: np.ndarray, distance_m: float) -> float:
    """Best local maximum (over yaws; 3×3 neighbourhood) of the translations farther than ``distance_m``
    from ``best_xy``: a second peak. A single broad or elongated peak has none; its spread is in the
    covariance instead."""
    over_yaw = scores.max(axis=0)
    peaks = over_yaw >= ndimage.maximum_filter(over_yaw, size=3, mode="nearest")
    gx, gy = np.meshgrid(offsets, offsets, indexing="ij")
    far = peaks & (np.hypot(gx - best_xy[0], gy - best_xy[1]) > distance_m)
    return float(over_yaw[far].max()) if far.any() else 0.0


class GuidedCorrelativeMatcher(GuidedMatcher):
    """Coarse-to-fine correlative matching around a guess (the ``guided-correlative`` matcher)."""

    name: ClassVar[str] = "guided-correlative"
    needs_guess: ClassVar[bool] = True
    """Without a guess it searches a small window around zero displacement: benchmarks of global
    matching leave it out."""
    Params: ClassVar[type[StageParams]] = GuidedCorrelativeParams

    def match(self, reference: RangeScan, moving: RangeScan, params: StageParams, *, rng: np.random.Generator,
              guess: MatchGuess | None = None) -> MatchResult:
        """Locate ``moving`` relative to ``reference`` (map frame) around ``guess`` (zero when None);
        deterministic, ``rng`` is unused."""
        p = GuidedCorrelativeParams.of(params).for_scans(reference, moving)
        start = time.perf_counter()
        ref, mov = reference.points(), _subsample(moving.points(), p.max_points)
        if len(ref) < p.min_points or len(mov) < p.min_points:
            return MatchResult.no_estimate(f"too few echoes ({len(ref)} reference, {len(mov)} moving; "
                                           f"need {p.min_points})", seconds=time.perf_counter() - start)
        centre = np.array([guess.dx_m, guess.dy_m]) if guess is not None else np.zeros(2)
        yaw0 = guess.dyaw_rad if guess is not None else 0.0
        radius = guess.radius_m if guess is not None else p.radius_m
        margin = radius + 4 * p.sigma_m + p.fine_m
        lo, hi = mov.min(axis=0) + centre - margin, mov.max(axis=0) + centre + margin
        ref = ref[np.all((ref >= lo) & (ref <= hi), axis=1)]
        if len(ref) < p.min_points:
            return MatchResult.no_estimate(f"too few reference echoes ({len(ref)}) where the moving scan can lie",
                                           seconds=time.perf_counter() - start)
        coarse_grid = LikelihoodGrid(ref, p.coarse_m, p.sigma_m, margin)
        fine_grid = LikelihoodGrid(ref, p.fine_m, p.sigma_m, margin)
        half = math.radians(p.yaw_window_deg)
        n_yaw = int(math.ceil(half / math.radians(p.yaw_step_deg)))
        yaws = yaw0 + np.linspace(-half, half, 2 * n_yaw + 1) if n_yaw else np.array([yaw0])
        coarse, offsets = _search(coarse_grid, mov, centre, radius, yaws)
        k, i, j = np.unravel_index(int(np.argmax(coarse)), coarse.shape)
        best_xy = np.array([offsets[i], offsets[j]])
        second = _ambiguity(coarse, offsets, best_xy, p.ambiguity_distance_m)
        fine_yaws = yaws[k] + np.linspace(-1, 1, 5) * math.radians(p.yaw_step_deg) / 2
        fine, fine_offsets = _search(fine_grid, mov, centre + best_xy, p.coarse_m, fine_yaws)
        fk, fi, fj = np.unravel_index(int(np.argmax(fine)), fine.shape)
        translation = centre + best_xy + np.array([fine_offsets[fi], fine_offsets[fj]])
        best = float(fine.max())
        covariance = _covariance(coarse[k], offsets, p)
        reason = ""
        if best < p.min_score:
            reason = f"best score {best:.3f} below min_score {p.min_score}"
        elif max(abs(i - len(offsets) // 2), abs(j - len(offsets) // 2)) == len(offsets) // 2:
            reason = f"optimum on the edge of the ±{radius:.2f} m window"
        elif second > p.ambiguity_ratio * best:
            reason = (f"ambiguous: a second peak {p.ambiguity_distance_m} m or more away scores {second:.3f}, "
                      f"over {p.ambiguity_ratio} of the best {best:.3f}")
        return MatchResult(i=-1, j=-1, dx_m=float(translation[0]), dy_m=float(translation[1]),
                           dyaw_rad=float(fine_yaws[fk]), weight=best, converged=not reason,
                           iterations=int(coarse.size + fine.size), seconds=time.perf_counter() - start,
                           reason=reason, covariance=covariance, guess=guess)
