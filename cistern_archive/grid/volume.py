"""Depth-slice evidence grids on one common lattice, and interpolation between slices in depth.

The paper maps one horizontal slice per site (Sec. III-D); sites scanned at several depths (bell-shaped
cisterns) give several slices at different extents. :func:`common_lattice` finds the one lattice that
covers them all, :func:`resample` puts a slice on it (unknown outside the slice), and
:func:`interpolate_layers` interpolates per-cell quantities linearly in depth (the wall surface of
:mod:`cistern_archive.grid.surface` interpolates signed distances to the water with it).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cistern_archive.core.grids import EvidenceGrid

UNKNOWN_PROBABILITY = 0.5


def common_lattice(grids: Sequence[EvidenceGrid]) -> tuple[tuple[float, float], float, tuple[int, int]]:
    """The smallest lattice, at the finest cell size, that covers every grid.

    Returns
    -------
    origin_xy_m, cell_m, (rows, cols)
    """
    if not grids:
        raise ValueError("no evidence grids to stack")
    cell = min(g.cell_m for g in grids)
    xmin = min(g.extent_m[0] for g in grids)
    xmax = max(g.extent_m[1] for g in grids)
    ymin = min(g.extent_m[2] for g in grids)
    ymax = max(g.extent_m[3] for g in grids)
    cols = max(1, int(np.ceil((xmax - xmin) / cell - 1e-9)))
    rows = max(1, int(np.ceil((ymax - ymin) / cell - 1e-9)))
    return (float(xmin), float(ymin)), float(cell), (rows, cols)


def resample(grid: EvidenceGrid, origin_xy_m: tuple[float, float], cell_m: float, shape: tuple[int, int]) -> np.ndarray:
    """Occupancy probability of ``grid`` at the cell centres of another lattice (nearest cell).

    Cells of the lattice that ``grid`` does not cover are unknown (0.5).
    """
    rows, cols = shape
    xs = origin_xy_m[0] + (np.arange(cols) + 0.5) * cell_m
    ys = origin_xy_m[1] + (np.arange(rows) + 0.5) * cell_m
    c = np.floor((xs - grid.origin_xy_m[0]) / grid.cell_m).astype(np.int64)
    r = np.floor((ys - grid.origin_xy_m[1]) / grid.cell_m).astype(np.int64)
    h, w = grid.log_odds.shape
    prob = grid.probability().astype(np.float32)
    out = np.full(shape, UNKNOWN_PROBABILITY, dtype=np.float32)
    rin = (r >= 0) & (r < h)
    cin = (c >= 0) & (c < w)
    out[np.ix_(rin, cin)] = prob[np.ix_(r[rin], c[cin])]
    return out


def interpolate_layers(slices: np.ndarray, slice_depths: np.ndarray, layers: np.ndarray) -> np.ndarray:
    """Linear interpolation in depth of (S, H, W) slices at the given layer depths (clamped at the ends)."""
    if len(slice_depths) == 1:
        return np.repeat(slices[:1], len(layers), axis=0).astype(np.float32)
    upper = np.clip(np.searchsorted(slice_depths, layers, side="right"), 1, len(slice_depths) - 1)
    lower = upper - 1
    span = slice_depths[upper] - slice_depths[lower]
    t = np.clip((layers - slice_depths[lower]) / span, 0.0, 1.0).astype(np.float32)
    t = t[:, None, None]
    return ((1 - t) * slices[lower] + t * slices[upper]).astype(np.float32)
