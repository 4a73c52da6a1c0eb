"""Vectorised ray casting and distance fields over a boolean occupancy grid.

Two ray casts return the distance from a ray's start to the first occupied cell (``nan`` when the ray
leaves the grid or passes ``max_t`` without a hit):

* :meth:`OccupancyLookup.march` samples every ``step`` along every ray (the plain definition);
* :meth:`OccupancyLookup.sphere_trace` skips through open water by the distance field: from a sample
  whose cell is ``D`` from the nearest occupied cell centre, no occupied cell can start within
  ``D - sqrt(2) * cell`` (half a diagonal for the sample's offset in its cell, half for the target
  cell's extent), so the ray advances by ``max(D - sqrt(2) * cell, step)``. Near walls it degrades to
  the plain march, so both return the same first hit up to one ``step``.

The distance field is :func:`scipy.ndimage.distance_transform_edt` of the free cells, in metres.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

FAR_M = 1.0e6
"""Distance reported for cells with no occupied cell anywhere in the grid, and outside the grid."""


def distance_field(occupied: np.ndarray, cell_m: float) -> np.ndarray:
    """Euclidean distance (m, float32) from every cell centre to the nearest occupied cell centre."""
    if not np.any(occupied):
        return np.full(occupied.shape, FAR_M, dtype=np.float32)
    return (ndimage.distance_transform_edt(~occupied) * cell_m).astype(np.float32)


class OccupancyLookup:
    """Occupancy and distance field of one grid with fast point look-ups.

    Parameters
    ----------
    occupied : ndarray of bool, shape (H, W)
        Row ``r``, column ``c`` covers ``origin + (c, r) * cell_m`` (the EvidenceGrid convention).
    origin_xy_m : tuple of float
    cell_m : float
    """

    def __init__(self, occupied: np.ndarray, origin_xy_m: tuple[float, float], cell_m: float):
        self.shape = occupied.shape
        self.cell_m = float(cell_m)
        self.origin = (float(origin_xy_m[0]), float(origin_xy_m[1]))
        # One padding cell on every side: out-of-grid samples are clipped onto it.
        padded = np.zeros((self.shape[0] + 2, self.shape[1] + 2), dtype=bool)
        padded[1:-1, 1:-1] = occupied
        self.occupied_flat = padded.ravel()
        field = np.full(padded.shape, FAR_M, dtype=np.float32)
        field[1:-1, 1:-1] = distance_field(occupied, cell_m)
        self.distance_flat = field.ravel()
        self.width = padded.shape[1]
        self.any_occupied = bool(np.any(occupied))

    def flat_index(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index into the padded flat arrays of the cells containing (x, y); outside maps to the pad."""
        inv = 1.0 / self.cell_m
        col = np.floor((x - self.origin[0]) * inv).astype(np.int64) + 1
        row = np.floor((y - self.origin[1]) * inv).astype(np.int64) + 1
        outside = (col < 1) | (col > self.shape[1]) | (row < 1) | (row > self.shape[0])
        col = np.where(outside, 0, col)
        row = np.where(outside, 0, row)
        return row * self.width + col

    def march(
        self, x0: np.ndarray, y0: np.ndarray, angle: np.ndarray, max_t: np.ndarray, *, step: float | None = None
    ) -> np.ndarray:
        """First-hit distance along rays by sampling every ``step`` (default half a cell)."""
        step = 0.5 * self.cell_m if step is None else float(step)
        return self._cast(x0, y0, angle, max_t, step, use_field=False)

    def sphere_trace(
        self, x0: np.ndarray, y0: np.ndarray, angle: np.ndarray, max_t: np.ndarray, *, step: float | None = None
    ) -> np.ndarray:
        """First-hit distance along rays, skipping open water by the distance field."""
        step = 0.5 * self.cell_m if step is None else float(step)
        return self._cast(x0, y0, angle, max_t, step, use_field=True)

    def _cast(
        self, x0: np.ndarray, y0: np.ndarray, angle: np.ndarray, max_t: np.ndarray, step: float, use_field: bool
    ) -> np.ndarray:
        shape = np.broadcast(x0, y0, angle, max_t).shape
        x0 = np.broadcast_to(x0, shape).ravel()
        y0 = np.broadcast_to(y0, shape).ravel()
        ux = np.cos(np.broadcast_to(angle, shape).ravel())
        uy = np.sin(np.broadcast_to(angle, shape).ravel())
        t_max = np.broadcast_to(max_t, shape).ravel()
        result = np.full(x0.size, np.nan)
        if not self.any_occupied:
            return result.reshape(shape)
        active = np.flatnonzero(np.isfinite(t_max) & (t_max >= 0))
        t = np.zeros(active.size)
        slack = math.sqrt(2.0) * self.cell_m
        while active.size:
            px = x0[active] + t * ux[active]
            py = y0[active] + t * uy[active]
            flat = self.flat_index(px, py)
            hit = self.occupied_flat[flat]
            result[active[hit]] = t[hit]
            if use_field:
                advance = np.maximum(self.distance_flat[flat] - slack, step)
            else:
                advance = step
            t = t + advance
            keep = ~hit & (flat != 0) & (t <= t_max[active])
            active = active[keep]
            t = t[keep]
        return result.reshape(shape)
