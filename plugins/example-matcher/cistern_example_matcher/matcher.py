"""``example-grid``: brute-force grid search over translation and yaw.

Every pose on a grid (``±search_m`` at ``step_m``, ``±search_deg`` at ``step_deg``) is scored by the
share of the moving scan's echoes that fall near a reference echo, read from a distance field of the
reference scan; "near" is widened by the grid's own coarseness (half a step in translation plus the
arc half a yaw step sweeps at the median range). The ``candidates`` best poses are then searched again
on grids five times finer around them with the tolerance ``inlier_m``, and the best of those wins. The match is reported converged only when that share reaches ``min_inlier_ratio``.
At most ``max_points`` echoes (evenly spaced) are scored, to bound the time.
"""

from __future__ import annotations

import math
import time
from typing import ClassVar

import numpy as np
from pydantic import Field
from scipy import ndimage

from cistern_archive.pipeline.contracts import MatchResult, StageParams
from cistern_archive.core.scan import RangeScan


class GridSearchParams(StageParams):
    """Parameters; every field has a default and unknown keys are refused (``StageParams``)."""

    search_m: float = Field(2.5, gt=0)
    step_m: float = Field(0.15, gt=0)
    search_deg: float = Field(24.0, ge=0)
    step_deg: float = Field(3.0, gt=0)
    cell_m: float = Field(0.05, gt=0)
    inlier_m: float = Field(0.12, gt=0)
    min_inlier_ratio: float = Field(0.6, ge=0, le=1)
    max_points: int = Field(60, ge=10)
    candidates: int = Field(8, ge=1)


class DistanceField:
    """Distance from any point to the nearest reference echo, sampled on a grid."""

    def __init__(self, points: np.ndarray, cell_m: float, margin_m: float):
        self.cell = cell_m
        self.origin = points.min(axis=0) - margin_m
        size = np.ceil((points.max(axis=0) + margin_m - self.origin) / cell_m).astype(int) + 1
        empty = np.ones((size[1], size[0]), dtype=bool)
        ij = np.floor((points - self.origin) / cell_m).astype(int)
        empty[ij[:, 1], ij[:, 0]] = False
        self.field = ndimage.distance_transform_edt(empty) * cell_m

    def lookup(self, points: np.ndarray) -> np.ndarray:
        """Distances of points (..., 2); ``inf`` outside the grid."""
        ij = np.floor((points - self.origin) / self.cell).astype(int)
        h, w = self.field.shape
        inside = (ij[..., 0] >= 0) & (ij[..., 0] < w) & (ij[..., 1] >= 0) & (ij[..., 1] < h)
        values = self.field[np.clip(ij[..., 1], 0, h - 1), np.clip(ij[..., 0], 0, w - 1)]
        return np.where(inside, values, np.inf)


def _scores(dfield: DistanceField, points: np.ndarray, poses: np.ndarray, inlier_m: float) -> np.ndarray:
    """Share of points within ``inlier_m`` of the reference for every pose (K, 3)."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = c * points[:, 0] - s * points[:, 1] + poses[:, 0, None]
    y = s * points[:, 0] + c * points[:, 1] + poses[:, 1, None]
    return (dfield.lookup(np.stack([x, y], axis=-1)) <= inlier_m).mean(axis=1)


def _grid(centre: np.ndarray, half_m: float, step_m: float, half_rad: float, step_rad: float) -> np.ndarray:
    t = np.arange(-half_m, half_m + step_m / 2, step_m)
    a = np.arange(-half_rad, half_rad + step_rad / 2, step_rad) if half_rad > 0 else np.zeros(1)
    gx, gy, ga = np.meshgrid(t, t, a, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel(), ga.ravel()]) + centre


class GridSearchMatcher:
    """Brute-force grid-search matcher."""

    name: ClassVar[str] = "example-grid"
    Params: ClassVar[type[StageParams]] = GridSearchParams

    def match(self, reference: RangeScan, moving: RangeScan, params: StageParams, *,
              rng: np.random.Generator) -> MatchResult:
        """Locate ``moving`` in ``reference``'s frame (deterministic: ``rng`` is not needed)."""
        p = GridSearchParams.of(params)
        start = time.perf_counter()
        ref, mov = reference.points(), moving.points()
        if len(ref) < 10 or len(mov) < 10:
            return MatchResult(-1, -1, math.nan, math.nan, math.nan, 0.0, False, 0,
                               time.perf_counter() - start, f"too few echoes ({len(ref)}, {len(mov)})")
        dfield = DistanceField(ref, p.cell_m, p.search_m + 1.0)
        mov = mov[np.linspace(0, len(mov) - 1, min(p.max_points, len(mov))).astype(int)]
        coarse = _grid(np.zeros(3), p.search_m, p.step_m, math.radians(p.search_deg), math.radians(p.step_deg))
        reach = float(np.median(np.hypot(mov[:, 0], mov[:, 1])))
        loose = p.inlier_m + p.step_m / 2 + reach * math.radians(p.step_deg) / 2
        sc = _scores(dfield, mov, coarse, loose)
        top = np.argsort(-sc, kind="stable")[: p.candidates]
        fine = np.concatenate([_grid(coarse[k], p.step_m, p.step_m / 5, math.radians(p.step_deg),
                                     math.radians(p.step_deg) / 5) for k in top])
        fsc = _scores(dfield, mov, fine, p.inlier_m)
        pose, ratio = fine[int(np.argmax(fsc))], float(fsc.max())
        reason = ""
        if ratio < p.min_inlier_ratio:
            reason = f"only {100 * ratio:.0f} % of echoes fit (need {100 * p.min_inlier_ratio:.0f} %)"
        return MatchResult(-1, -1, float(pose[0]), float(pose[1]), float(pose[2]), ratio, not reason,
                           len(coarse) + len(fine), time.perf_counter() - start, reason)
