"""The evidence a group of placed scans holds, for fitting one group to another
(:mod:`cistern_plugins.group_fit`): its wall points with the normal of their wall turned towards the
sonar that heard them, the water its sonars saw, and both rasterised per wall orientation as
likelihood fields with the free-space penalty.

Every length below is written for the calibration sonar (:mod:`cistern_plugins.sonar_scale`) and taken
``unit`` times as long for a site whose scans are (:func:`~cistern_plugins.sonar_scale.site_length_unit`):
a wall 15 m off at 0.12 m bins is traced, bordered and kept from a station as one 5 m off at 0.04 m
bins."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from cistern_archive.core.scan import RangeScan, wrap_angle
from cistern_plugins.alignment import (GRAZING_DEG, OPEN_SECTOR_DEG, FreeSpace, estimate_normals, rotate, scan_points,
                                       silent_water, transform)

ORIENTATIONS = 8
"""Wall orientations are binned in eighths of a turn for the search, in sixteenths for the refinement
(:class:`cistern_plugins.group_fit.FineScore`), where the grazing test below must be sharper."""
AGREE_DEG = 67.5
"""A point agrees with walls whose bin centres lie within this of its own bin's (normals within about
90°), so the two sides of one wall never agree."""
FREE_MARGIN_M = 0.3
"""Free space ends this far in front of a sonar's echo (as the correlative matcher's penalty does)."""
BORDER_M = 1.0
STATION_RADIUS_M = 0.3
"""No wall lies this close to a station: the vehicle floated there."""
TRACE_GAP_M = 0.3
"""Echoes of consecutive beams this close are one wall, traced between them (:func:`wall_trace`); so
are echoes farther apart that one wall met at up to ``90° - GRAZING_DEG`` of incidence gives
(``r * step / sin(GRAZING_DEG)``). An opening's jamb and the wall seen through it lie metres apart."""
WALL_END_REACH_M = 0.3
"""The farthest a wall is traced past its last echo (:func:`wall_ends`); 0 traces none."""
WALL_END_GAP_M = 1.0
"""A wall whose next beam would have met it farther than this past its last echo is not traced on: at
such grazing incidence its end is unknown."""
ON_WALL_M = 0.1
"""An echo lies on the wall of its beam-order neighbour when it is this close to that wall's line."""
TRACE_SPACING_M = 0.05
"""Points are laid at most this far apart along a traced wall: the refinement's cells, and the spacing
of echoes 3 m off at 0.9° steps. Not closer: a line sampled densely also covers the cells it only
grazes at a corner, and would score a diagonal wall higher than the same wall seen as echoes."""


class Cloud:
    """The walls and the water of a set of scans placed in one frame, with the lengths of the module taken
    ``unit`` times as long."""

    def __init__(self, scans: Sequence[RangeScan], poses: Sequence[np.ndarray], unit: float = 1.0):
        points, normals = [], []
        self.unit = unit
        self.frees: list[tuple[FreeSpace, np.ndarray]] = []
        for scan, pose in zip(scans, poses):
            p = scan_points(scan)
            n = facing_normals(p)
            ends, end_normals = wall_ends(scan, p, n, unit)
            p, n = wall_trace(p, n, unit)
            p, n = np.vstack([p, ends]), np.vstack([n, end_normals])
            points.append(transform(p, pose))
            normals.append(rotate(n, pose[2]) if len(n) else n)
            free = FreeSpace(silent_water(scan, math.radians(OPEN_SECTOR_DEG)))
            self.frees.append((free, np.asarray(pose, dtype=np.float64)))
        self.points = np.vstack(points) if points else np.zeros((0, 2))
        self.normals = np.vstack(normals) if normals else np.zeros((0, 2))
        self.turns = np.array([pose[2] for pose in poses], dtype=np.float64)

    def in_free_space(self, xy: np.ndarray, turn: float = 0.0, bins: int = ORIENTATIONS) -> np.ndarray:
        """Per orientation bin, the mask of points (this cloud's frame) that one of its sonars saw empty
        and would have heard a wall of that orientation at: a ray within ``GRAZING_DEG`` of a wall's
        plane may pass it unheard (as :meth:`FreeSpace.violations` skips such walls; any normal of the
        bin, half a bin from its centre, counts), shape (K, N). The bins are those of a frame turned by
        ``turn`` from this cloud's. Within ``STATION_RADIUS_M`` of a station every orientation counts: no
        wall stands where the vehicle floated."""
        out = np.zeros((bins, len(xy)), dtype=bool)
        centres = (np.arange(bins) + 0.5) * 2 * np.pi / bins - turn
        normals = np.column_stack([np.cos(centres), np.sin(centres)])
        for free, pose in self.frees:
            rel = xy - pose[:2]
            out[:, np.hypot(rel[:, 0], rel[:, 1]) < STATION_RADIUS_M * self.unit] = True
            seen = free.in_free_space(rotate(rel, -pose[2]), FREE_MARGIN_M * self.unit)
            if not seen.any():
                continue
            rays = rel[seen] / np.maximum(np.hypot(rel[seen, 0], rel[seen, 1]), 1e-9)[:, None]
            out[:, seen] |= np.abs(normals @ rays.T) >= math.sin(math.radians(GRAZING_DEG + 180.0 / bins))
        return out


def facing_normals(points: np.ndarray) -> np.ndarray:
    """Unit wall normals of a scan's points (relative to its sonar), turned towards the sonar."""
    if len(points) < 3:
        return np.zeros((len(points), 2))
    normals = estimate_normals(points, cKDTree(points))
    away = np.einsum("ij,ij->i", normals, points) > 0
    normals[away] *= -1
    return normals


def median_step(angles: np.ndarray) -> float:
    """The median step between consecutive angles (radians, each wrapped to half a turn)."""
    return float(np.median(np.abs(wrap_angle(np.diff(angles)))))


def runs(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Items laid in runs of ``counts[i]`` each: every item's run, and its place in the run from 1."""
    which = np.repeat(np.arange(len(counts)), counts)
    return which, np.arange(len(which)) - (np.cumsum(counts) - counts)[which] + 1


def wall_trace(points: np.ndarray, normals: np.ndarray, unit: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A scan's wall points (beam order) with the wall traced between consecutive echoes no farther
    apart than :data:`TRACE_GAP_M`, every :data:`TRACE_SPACING_M`, and their normals interpolated.

    The fits score walls by the cells they cover. Echoes lie a beam step apart, ``r * step`` face on
    and more obliquely: at the Micron's 1.8° steps a wall 5 m off is a point every 0.16 m or more,
    which covers one cell in two of the search's 0.1 m grid, at 0.9° steps every cell; traced, the same
    wall covers the same cells whatever the head's step. ``points`` are relative to their sonar; both
    lengths are taken ``unit`` times as long.
    """
    if len(points) < 2:
        return points, normals
    chord = np.diff(points, axis=0)
    length = np.hypot(chord[:, 0], chord[:, 1])
    step = median_step(np.arctan2(points[:, 1], points[:, 0]))
    reach = 0.5 * (np.hypot(*points[1:].T) + np.hypot(*points[:-1].T))
    joined = length <= np.maximum(TRACE_GAP_M * unit, reach * step / math.sin(math.radians(GRAZING_DEG)))
    steps = np.where(joined, np.floor(length / (TRACE_SPACING_M * unit)).astype(np.int64), 0)
    if not steps.any():
        return points, normals
    seg, place = runs(steps)
    t = place / (steps[seg] + 1)
    filled = points[seg] + t[:, None] * chord[seg]
    blend = (1 - t)[:, None] * normals[seg] + t[:, None] * normals[seg + 1]
    blend /= np.maximum(np.hypot(blend[:, 0], blend[:, 1]), 1e-9)[:, None]
    return np.vstack([points, filled]), np.vstack([normals, blend])


def wall_ends(scan: RangeScan, points: np.ndarray, normals: np.ndarray, unit: float = 1.0
              ) -> tuple[np.ndarray, np.ndarray]:
    """Each wall a scan heard traced on past its last echo, halfway to where the next beam would have met
    it, every :data:`TRACE_SPACING_M` (at most :data:`WALL_END_REACH_M`), with its normal.

    Where a wall ends (the jamb of an opening, the corner of a pillar, a tunnel's mouth seen down its
    length), the next beam passes beyond it: the wall ends somewhere between the last echo and that beam's
    crossing of the wall's line, a gap of ``r * step / sin(incidence)``. Traced only to the last echo,
    every end falls short by half that gap on average, most where the wall is met obliquely: a tunnel
    seen from the chamber at its mouth, whose far mouth both groups of a join see from opposite ends.
    Their fit, which scores how much wall the two lay on each other, then pulls them together by as
    much (0.17 m for a 3 m tunnel at 0.9° steps; joins on the random cisterns were a median 0.07 m short
    along the line between their stations, RESULTS.md "2026-12-06 (session 20)"). An end is traced only
    where the echo lies on a wall of two echoes or more (a lone echo may be a ghost or a spike), the next
    beam heard nothing or something beyond the wall's line (not a wall in front of it, which hides
    where this one goes on), and the gap is at most :data:`WALL_END_GAP_M`. ``points`` (beam order, as
    :func:`~cistern_plugins.alignment.scan_points` gives them) and their ``normals`` are relative to the
    sonar; the module's lengths are taken ``unit`` times as long."""
    valid = np.flatnonzero(scan.valid)
    if len(valid) < 2 or WALL_END_REACH_M <= 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    on_wall, end_gap, spacing = ON_WALL_M * unit, WALL_END_GAP_M * unit, TRACE_SPACING_M * unit
    bearings = scan.bearings_rad
    step = median_step(bearings)
    heard = np.full(len(bearings), np.inf)  # a beam that heard nothing passed every wall
    heard[valid] = scan.ranges_m[valid]
    rows = np.arange(len(valid))
    ends, end_normals = [], []
    for side in (-1, 1):  # the end each way round the sweep
        beam = (valid + side) % len(bearings)
        chord = points[(rows - side) % len(valid)] - points  # to the echo on the other side
        angle = bearings[beam] + scan.yaw_rad
        ray = np.column_stack([np.cos(angle), np.sin(angle)])
        facing = np.einsum("ij,ij->i", normals, ray)
        ok = ((np.abs(wrap_angle(bearings[beam] - bearings[valid])) <= 1.5 * step)  # a neighbour
              & (np.abs(np.einsum("ij,ij->i", normals, chord)) <= on_wall)  # a wall of two echoes
              & (np.hypot(chord[:, 0], chord[:, 1]) <= end_gap) & (facing < 0))
        t = np.einsum("ij,ij->i", normals, points) / np.where(ok, facing, -1.0)
        beyond = t[:, None] * ray - points  # from the last echo to the next beam's crossing of the wall
        gap = np.hypot(beyond[:, 0], beyond[:, 1])
        ok &= (heard[beam] > t + on_wall) & (gap > 0) & (gap <= end_gap)
        reach = np.minimum(0.5 * gap, WALL_END_REACH_M * unit)  # halfway to the crossing: where the end lies on average
        count = np.where(ok, np.floor_divide(reach, spacing), 0).astype(np.int64)
        which, place = runs(count)
        along = place * spacing
        ends.append(points[which] + along[:, None] * beyond[which] / gap[which, None])
        end_normals.append(normals[which])
    return np.vstack(ends), np.vstack(end_normals)


def orientation_bins(normals: np.ndarray, bins: int = ORIENTATIONS) -> np.ndarray:
    """The orientation bin (0 .. bins - 1) of each normal."""
    angle = np.mod(np.arctan2(normals[:, 1], normals[:, 0]), 2 * np.pi)
    return np.floor(angle / (2 * np.pi / bins)).astype(np.int64) % bins


class Raster:
    """A cloud rasterised on a grid of one frame: occupied cells per orientation bin, and per bin the
    likelihood field of the walls it agrees with, minus the free-space penalty where ``free`` (the cells
    the cloud's sonars saw empty, :meth:`Cloud.in_free_space`)."""

    def __init__(self, cloud: Cloud, lo: np.ndarray, shape: tuple[int, int], cell_m: float, sigma_m: float,
                 penalty: float, rotation: float = 0.0, bins: int = ORIENTATIONS):
        self.lo, self.shape, self.cell = np.asarray(lo, dtype=np.float64), shape, cell_m
        points, normals = cloud.points, cloud.normals
        if rotation:
            points, normals = rotate(points, rotation), rotate(normals, rotation)
        cells = np.floor((points - self.lo) / cell_m).astype(np.int64)
        inside = (cells >= 0).all(axis=1) & (cells[:, 0] < shape[1]) & (cells[:, 1] < shape[0])
        cells, which = cells[inside], orientation_bins(normals[inside], bins)
        self.occupied = np.zeros((bins, *shape), dtype=np.float64)
        self.occupied[which, cells[:, 1], cells[:, 0]] = 1.0
        rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
        centres = np.column_stack([cols.ravel(), rows.ravel()]) * cell_m + self.lo + cell_m / 2
        free = cloud.in_free_space(rotate(centres, -rotation) if rotation else centres, rotation, bins)
        free = free.reshape(bins, *shape)
        reach = int(round(AGREE_DEG / (360.0 / bins)))
        self.field = np.zeros((bins, *shape), dtype=np.float64)
        for k in range(bins):
            near = self.occupied[[(k + d) % bins for d in range(-reach, reach + 1)]].any(axis=0)
            if near.any():
                dist = ndimage.distance_transform_edt(~near) * cell_m
                self.field[k] = np.exp(-0.5 * (dist / sigma_m) ** 2)
            self.field[k][free[k]] -= penalty
        self.free = free

    def sample(self, points: np.ndarray, bins: np.ndarray, layer: np.ndarray | None = None) -> np.ndarray:
        """The field (or another ``layer`` of the raster's shape, such as ``free``) of each point's bin at
        the point, interpolated bilinearly (0 outside the grid)."""
        layer = self.field if layer is None else layer
        u = (points - self.lo) / self.cell - 0.5
        base = np.floor(u).astype(np.int64)
        frac = u - base
        out = np.zeros(u.shape[:-1])
        for dc, dr in ((0, 0), (1, 0), (0, 1), (1, 1)):
            cols, rows = base[..., 0] + dc, base[..., 1] + dr
            inside = (cols >= 0) & (rows >= 0) & (cols < self.shape[1]) & (rows < self.shape[0])
            weight = (frac[..., 0] if dc else 1 - frac[..., 0]) * (frac[..., 1] if dr else 1 - frac[..., 1])
            values = layer[np.broadcast_to(bins, rows.shape), np.where(inside, rows, 0), np.where(inside, cols, 0)]
            out += np.where(inside, weight * values, 0.0)
        return out


def bounds(points: np.ndarray, cell_m: float, unit: float = 1.0) -> tuple[np.ndarray, tuple[int, int]]:
    """Grid origin and shape (rows, cols) covering points with a border of ``BORDER_M * unit``."""
    lo = points.min(axis=0) - BORDER_M * unit
    hi = points.max(axis=0) + BORDER_M * unit
    size = np.ceil((hi - lo) / cell_m).astype(np.int64) + 1
    return lo, (int(size[1]), int(size[0]))


def cell_centres(raster: Raster) -> tuple[np.ndarray, np.ndarray]:
    """Centres of the occupied cells of a raster (its frame) and their bins."""
    bins, rows, cols = np.nonzero(raster.occupied)
    return np.column_stack([cols, rows]) * raster.cell + raster.lo + raster.cell / 2, bins


def wall_spread(cloud: Cloud) -> float:
    """How evenly a cloud's walls face every way: the smaller eigenvalue of the mean ``n n^T`` of its wall
    normals over the larger (1 for a round room, 0 for two parallel walls: a tunnel seen from inside)."""
    return moment_spread(cloud.normals.T @ cloud.normals, len(cloud.normals))


def normal_moment(scan: RangeScan, unit: float = 1.0) -> tuple[np.ndarray, int]:
    """The sum of ``n n^T`` over one scan's traced wall normals (in its own frame, traced at ``unit``) and
    their number: what :func:`placed_spread` adds up for a group of placed scans without building its
    :class:`Cloud`."""
    p = scan_points(scan)
    _, n = wall_trace(p, facing_normals(p), unit)
    return (n.T @ n if len(n) else np.zeros((2, 2))), len(n)


def placed_spread(moments: Sequence[tuple[np.ndarray, int]], turns: Sequence[float]) -> float:
    """:func:`wall_spread` of scans placed with the headings ``turns``, from their :func:`normal_moment`."""
    total, count = np.zeros((2, 2)), 0
    for (moment, n), turn in zip(moments, turns):
        c, s = math.cos(turn), math.sin(turn)
        r = np.array([[c, -s], [s, c]])
        total += r @ moment @ r.T
        count += n
    return moment_spread(total, count)


def moment_spread(moment: np.ndarray, count: int) -> float:
    """The smaller eigenvalue of ``moment / count`` over the larger (0 with fewer than three normals)."""
    if count < 3:
        return 0.0
    low, high = np.linalg.eigvalsh(moment / count)
    return float(low / high) if high > 0 else 0.0
