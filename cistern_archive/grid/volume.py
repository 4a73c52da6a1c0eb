"""Stacking depth-slice evidence grids into a 3-D occupancy volume.

The paper maps one horizontal slice per site and extrudes it along z by the depth sensor's reading
("extrapolated along the z-axis to fill in the gaps", Sec. III-D) before the isosurface of Sec. III-E.
Sites scanned at several depths (bell-shaped cisterns) give several slices. Interpolating occupancy
probability between two slices whose walls stand at different places would cross-fade two vertical
walls into a staircase; instead each slice becomes a signed distance to its occupied cells (negative in
observed free water, positive elsewhere), the distances are interpolated linearly in depth, so a wall
moves smoothly from one slice to the next, and the result is turned back into a wall indicator
(1 on the wall, 0.5 one cell away, 0 from two cells on). The outermost slices are extruded by
``extend_m`` above (never past the water surface) and below.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from scipy import ndimage

from cistern_archive.pipeline.contracts import EvidenceGrid, MapResult

UNKNOWN_PROBABILITY = 0.5


@dataclass(frozen=True, eq=False)
class Volume:
    """Occupancy probability on a regular lattice.

    Attributes
    ----------
    probability : ndarray, shape (D, H, W), float32
        Layer ``k``, row ``r``, column ``c`` is the voxel centred at
        ``x = origin_xy_m[0] + (c + 0.5) * cell_m``, ``y = origin_xy_m[1] + (r + 0.5) * cell_m``,
        ``depth = depths_m[k]``; 0.5 where nothing is known.
    origin_xy_m : tuple of float
        Map-frame position of the lower-left corner of cell (0, 0) of every layer.
    cell_m : float
        Horizontal cell size.
    depths_m : ndarray, shape (D,)
        Depth of every layer (positive down, increasing, evenly spaced).
    slice_depths_m : tuple of float
        Depths of the evidence grids the volume was built from.
    """

    probability: np.ndarray
    origin_xy_m: tuple[float, float]
    cell_m: float
    depths_m: np.ndarray
    slice_depths_m: tuple[float, ...]

    @property
    def dz_m(self) -> float:
        return float(self.depths_m[1] - self.depths_m[0]) if len(self.depths_m) > 1 else self.cell_m

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the lattice."""
        _, h, w = self.probability.shape
        x0, y0 = self.origin_xy_m
        return (x0, x0 + w * self.cell_m, y0, y0 + h * self.cell_m)


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


def layer_depths(slice_depths: Sequence[float], *, dz_m: float, extend_m: float) -> np.ndarray:
    """Evenly spaced layer depths from ``extend_m`` above the shallowest slice (not above the surface,
    depth 0) to ``extend_m`` below the deepest."""
    top = max(0.0, min(slice_depths) - extend_m)
    bottom = max(slice_depths) + extend_m
    n = max(2, int(round((bottom - top) / dz_m)) + 1)
    return np.linspace(top, bottom, n)


def stack_slices(map_result: MapResult, *, dz_m: float = 0.1, extend_m: float = 1.0) -> Volume:
    """Stack the mapper's depth slices into a :class:`Volume`.

    Parameters
    ----------
    map_result : MapResult
        One evidence grid per depth slice (any order; equal depths are averaged in probability).
    dz_m : float, keyword-only
        Layer spacing of the volume.
    extend_m : float, keyword-only
        How far the outermost slices are extruded above and below (the paper's z extrusion for a
        single slice; the vertical extent of the model when only one slice exists).

    Returns
    -------
    Volume
        With one slice, every layer is that slice's occupancy probability (the paper's extrusion).
        With several, every layer is the wall indicator of the depth-interpolated signed distance
        (see the module docstring); layers beyond the outermost slices repeat them.
    """
    if dz_m <= 0:
        raise ValueError(f"dz_m must be positive, got {dz_m}")
    grids = sorted(map_result.grids, key=lambda g: g.depth_m)
    origin, cell, shape = common_lattice(grids)
    depths = np.array([g.depth_m for g in grids], dtype=np.float64)
    slices = np.stack([resample(g, origin, cell, shape) for g in grids])
    unique_depths, inverse = np.unique(depths, return_inverse=True)
    merged = np.stack([slices[inverse == k].mean(axis=0) for k in range(len(unique_depths))])
    layers = layer_depths(unique_depths, dz_m=dz_m, extend_m=extend_m)
    if len(unique_depths) == 1:
        probability = np.repeat(merged[:1], len(layers), axis=0).astype(np.float32)
    else:
        distances = np.stack([signed_wall_distance(p) for p in merged])
        probability = wall_indicator(interpolate_layers(distances, unique_depths, layers))
    return Volume(
        probability=probability,
        origin_xy_m=origin,
        cell_m=cell,
        depths_m=layers,
        slice_depths_m=tuple(float(d) for d in unique_depths),
    )


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


def signed_wall_distance(probability: np.ndarray) -> np.ndarray:
    """Distance in cells from every cell to the nearest occupied cell (probability > 0.5), negative in
    free cells (< 0.5) and positive in unknown ones; 0 on the occupied cells."""
    occupied = probability > UNKNOWN_PROBABILITY
    if not occupied.any():
        return np.full(probability.shape, 1e3, dtype=np.float32)
    distance = ndimage.distance_transform_edt(~occupied).astype(np.float32)
    return np.where(probability < UNKNOWN_PROBABILITY, -distance, distance)


def wall_indicator(distance: np.ndarray) -> np.ndarray:
    """Map a signed distance in cells to a wall indicator in [0, 1]: 1 on the wall, 0.5 one cell away
    (the value of unknown space), 0 two or more cells away."""
    return (0.5 + 0.5 * np.clip(1.0 - np.abs(distance), -1.0, 1.0)).astype(np.float32)
