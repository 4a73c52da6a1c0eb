"""Echo ranges on leaning walls, corrected for the sonar's wide vertical lobe.

A mechanically scanned sonar's beam is narrow across (3°) but wide in elevation (35° on a Micron). On a
vertical wall the echo forms where the beam's axis meets it. On a wall that leans by ``α`` from the
vertical towards the vehicle above (a bell widening with depth) or below, the rays a little off the axis
towards the lean meet it nearer, the nearer the steeper, and the wall's echo, spread over the slant
ranges of the whole lobe, peaks before the axis's range: every echo on such a wall is short by a share
that grows with the lean (about 4.6 % at 40–50° on the bell, ``benchmarks/RESULTS.md``, "2026-12-05
(session 2)"), and the slice's walls come out inside the true ones.

If the segmented echo forms at the elevation ``β`` off the axis towards the lean, a share of the half
width of the vertical beam (``detection_share``: the beam pattern scales with its width),
a wall at horizontal distance ``R`` at the sonar's depth, leaning by ``α ≥ β`` in the beam's plane, is
met at the slant range ``r = R cos α / cos(α − β)``; so ``R = r cos(α − β) / cos α``, and ``R = r / cos α``
where ``α < β`` (the nearest point of the wall, met at normal incidence, lies within the angle).

The lean is read from the map itself, where a site was scanned at several depths: the first maps of the
depth slices give the water each slice saw (as :mod:`cistern_archive.grid.surface` reads it), and at
every echo the outward offset of the other slices' walls from this slice's wall, against depth, is fitted
by a parabola through this slice and the two nearest others (a straight line with one other), whose
slope at the slice's depth is ``tan α``. Where another slice's wall lies farther than ``reach_m`` from
the echo (not the same wall, or not seen) the echo is not corrected; the lean is capped at
``max_lean_deg``. One depth slice: nothing changes.

A leaning wall's echo is smeared over the slant ranges of the whole lobe, and where its peak forms
within the smear varies from ping to ping: on the bell the ranges scatter with an interquartile range of
0.17–0.23 m against 0.03 m on vertical walls (``benchmarks/RESULTS.md``, "2026-12-05 (session 2)").
The water each slice sees ends at the longest of its echoes, so that scatter pushes the walls out in
places and pulls them in elsewhere. Each corrected echo on a wall leaning ``SMOOTH_MIN_LEAN_DEG`` or more
is therefore replaced by the mean of the corrected echoes of its scan within a few degrees of bearing
that hear the same wall (:func:`smooth_along_wall`), as a wall is continuous over the few centimetres
between neighbouring beams where the scatter is not.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence

import numpy as np

from cistern_archive.core.grids import EvidenceGrid
from cistern_archive.core.poses import Poses
from cistern_archive.core.scan import RangeScan, wrap_angle
from cistern_archive.grid.surface import SurfaceParams, signed_distance, slice_waters

SAME_LEVEL_M = 0.3
"""Slices closer in depth than this are one depth level."""

SMOOTH_MIN_LEAN_DEG = 10.0
"""Echoes on walls leaning less than this are not smoothed (:func:`smooth_along_wall`): there the echo is
sharp, and the leans read on vertical walls are noise below it."""

SAME_WALL_M = 0.3
"""Neighbouring echoes whose ranges differ by more than this hear another wall (:func:`smooth_along_wall`)."""

SMOOTH_ROWS = 256
"""Echoes averaged at a time by :func:`smooth_along_wall`."""

MIN_SCALE_ECHOES = 20
"""A scan's echo scale (:func:`echo_scale`) is read from at least this many echoes with a known lean."""


def range_factor(lean_rad: np.ndarray, detection_rad: float) -> np.ndarray:
    """``R / r``: the horizontal distance of the wall at the sonar's depth over the echo's range, for
    walls leaning by ``lean_rad`` (see the module docstring)."""
    lean = np.abs(np.asarray(lean_rad, dtype=float))
    return np.cos(np.maximum(lean - detection_rad, 0.0)) / np.cos(lean)


@dataclasses.dataclass(frozen=True)
class SliceWater:
    """The water one depth slice saw, as a signed distance on the slices' common lattice (metres,
    positive outside the water)."""

    depth_m: float
    signed_m: np.ndarray


def signed_waters(grids: Sequence[EvidenceGrid], poses: Poses, depths_m: Sequence[float]
                  ) -> tuple[EvidenceGrid, list[SliceWater]]:
    """Every slice's water as the wall surface reads it (:func:`~cistern_archive.grid.surface.slice_waters`),
    as signed distances on one lattice, and the empty grid that carries the lattice."""
    lattice, pieces = slice_waters(grids, poses, depths_m, SurfaceParams())
    return lattice, [SliceWater(float(grid.depth_m), signed_distance(water, lattice.cell_m))
                     for grid, (water, _) in zip(grids, pieces)]


def slope_at_zero(dz: Sequence[float], offsets: Sequence[np.ndarray]) -> np.ndarray:
    """The slope at 0 of the curve through ``(0, 0)`` and ``(dz[k], offsets[k])``: a line with one other
    point, a parabola with two (where one of the two is ``nan`` the line through the other)."""
    if len(dz) == 1:
        return offsets[0] / dz[0]
    (z1, z2), (w1, w2) = dz[:2], offsets[:2]
    parabola = (w1 * z2 ** 2 - w2 * z1 ** 2) / (z1 * z2 * (z2 - z1))
    return np.where(np.isfinite(parabola), parabola, np.where(np.isfinite(w1), w1 / z1, w2 / z2))


def echo_lean(scan: RangeScan, xy_m: np.ndarray, yaw_rad: float, lattice: EvidenceGrid,
              waters: Sequence[SliceWater], reach_m: float) -> np.ndarray:
    """The lean from the vertical (radians, ≥ 0) of the wall at every beam's echo; ``nan`` where it
    cannot be read (no echo, outside the lattice, no other slice's wall within ``reach_m``)."""
    lean = np.full(scan.ranges_m.shape, np.nan)
    own = min(waters, key=lambda w: abs(w.depth_m - scan.depth_m))
    others = sorted((w for w in waters if abs(w.depth_m - own.depth_m) >= SAME_LEVEL_M),
                    key=lambda w: abs(w.depth_m - own.depth_m))[:2]
    echo = scan.valid
    if not others or not echo.any():
        return lean
    cells = lattice.cell_of(np.asarray(xy_m, dtype=float)[None, :] + scan.points(yaw_rad=yaw_rad))
    rows, cols = lattice.log_odds.shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < rows) & (cells[:, 1] >= 0) & (cells[:, 1] < cols)
    r, c = np.clip(cells[:, 0], 0, rows - 1), np.clip(cells[:, 1], 0, cols - 1)
    offsets = []
    for other in others:
        outward = own.signed_m[r, c] - other.signed_m[r, c]  # how far the other slice's wall lies beyond
        offsets.append(np.where(inside & (np.abs(outward) < reach_m), outward, np.nan))
    slope = slope_at_zero([w.depth_m - own.depth_m for w in others], offsets)
    lean[echo] = np.arctan(np.abs(slope))
    return lean


def smooth_along_wall(ranges_m: np.ndarray, lean_rad: np.ndarray, bearings_rad: np.ndarray, window_rad: float,
                      min_lean_rad: float = math.radians(SMOOTH_MIN_LEAN_DEG), same_wall_m: float = SAME_WALL_M
                      ) -> np.ndarray:
    """Each echo on a wall leaning at least ``min_lean_rad`` replaced by the mean range of the echoes on
    such walls within ``window_rad`` of its bearing (either side, across north) whose ranges lie within
    ``same_wall_m`` of its own; every other beam, and everything with ``window_rad`` 0, as it was."""
    ranges = np.asarray(ranges_m, dtype=float)
    leaning = np.isfinite(ranges) & (np.nan_to_num(np.asarray(lean_rad, dtype=float)) >= min_lean_rad)
    if window_rad <= 0 or not leaning.any():
        return ranges
    idx = np.flatnonzero(leaning)
    r, b = ranges[idx], np.asarray(bearings_rad, dtype=float)[idx]
    out = ranges.copy()
    for start in range(0, idx.size, SMOOTH_ROWS):  # rows at a time: memory grows with the beams, not their square
        rows = slice(start, start + SMOOTH_ROWS)
        apart = np.abs(wrap_angle(b[rows, None] - b[None, :]))
        together = ((apart <= window_rad) & (np.abs(r[rows, None] - r[None, :]) < same_wall_m)).astype(float)
        out[idx[rows]] = together @ r / together.sum(axis=1)
    return out


def correct_for_lobe(scans: Sequence[RangeScan], poses: Poses, grids: Sequence[EvidenceGrid],
                     detection_share: float, max_lean_deg: float, reach_m: float, smooth_deg: float = 0.0
                     ) -> tuple[list[RangeScan], np.ndarray]:
    """Every placed scan with its echo ranges corrected for the lean of their walls (module docstring).

    Parameters
    ----------
    scans, poses : the mapper's input; unplaced scans are returned unchanged.
    grids : the first maps of the depth slices (corrected only when they lie at two depths or more).
    detection_share : elevation off the beam's axis, towards the lean, at which the echo forms (``β``), as
        a share of the half width of each scan's vertical beam.
    max_lean_deg : the lean is capped here.
    reach_m : other slices' walls farther than this from an echo are not its wall.
    smooth_deg : the corrected echoes on leaning walls are averaged over this many degrees of bearing
        either side (:func:`smooth_along_wall`); 0 leaves them apart.

    Returns
    -------
    scans : list of RangeScan
    leans_deg : ndarray
        The lean read at every corrected echo (degrees), for the map's statistics.
    """
    out, leans = [], []
    for scan, factor, lean in echo_factors(scans, poses, grids, detection_share, max_lean_deg, reach_m):
        if factor is None:
            out.append(scan)
            continue
        ranges = smooth_along_wall(scan.ranges_m * factor, lean, scan.bearings_rad, math.radians(smooth_deg))
        out.append(dataclasses.replace(scan, ranges_m=ranges))
        leans.append(np.degrees(lean[np.isfinite(lean)]))
    return out, np.concatenate(leans) if leans else np.zeros(0)


def echo_factors(scans: Sequence[RangeScan], poses: Poses, grids: Sequence[EvidenceGrid], detection_share: float,
                 max_lean_deg: float, reach_m: float) -> Iterator[tuple[RangeScan, np.ndarray | None, np.ndarray | None]]:
    """Every scan with ``R / r`` at each of its beams (1 where the lean is unknown) and the lean read at
    each (radians, capped; ``nan`` where unknown), or ``None`` twice for an unplaced scan or where the
    slices lie at one depth (parameters as :func:`correct_for_lobe`)."""
    if not grids or np.ptp([g.depth_m for g in grids]) < SAME_LEVEL_M:
        yield from ((scan, None, None) for scan in scans)
        return
    lattice, waters = signed_waters(grids, poses, [s.depth_m for s in scans])
    cap = math.radians(max_lean_deg)
    for k, scan in enumerate(scans):
        if not bool(poses.placed[k]):
            yield scan, None, None
            continue
        lean = echo_lean(scan, poses.xy_m[k], float(poses.yaw_rad[k]), lattice, waters, reach_m)
        known = np.isfinite(lean)
        detection = detection_share * scan.vertical_beam_width_rad / 2
        factor = np.where(known, range_factor(np.minimum(np.nan_to_num(lean), cap), detection), 1.0)
        yield scan, factor, np.where(known, np.minimum(lean, cap), np.nan)


def echo_scale(scans: Sequence[RangeScan], poses: Poses, grids: Sequence[EvidenceGrid], detection_share: float,
               max_lean_deg: float, reach_m: float, min_echoes: int = MIN_SCALE_ECHOES) -> np.ndarray:
    """Each scan's echo range over the range of its walls, ``r / R``: the median over its echoes whose lean
    could be read, 1 for a scan with fewer than ``min_echoes`` of them, an unplaced one, or slices at one
    depth (parameters as :func:`correct_for_lobe`).

    Scan matching aligns the echoes of two scans as they are. Where every echo of both falls short of
    its wall by the same share, ``r = k R``, each scan sees the walls shrunk by ``k`` about its own
    position, and the rigid displacement between two such views is ``k`` times the true one: a match on
    leaning walls is short along the line between the two stations by ``(1 − k)`` of its length
    (:func:`cistern_archive.core.matches.lengthen_matches` undoes it)."""
    scale = np.ones(len(scans))
    for k, (_, factor, lean) in enumerate(echo_factors(scans, poses, grids, detection_share, max_lean_deg, reach_m)):
        if lean is None:
            continue
        known = np.isfinite(lean)
        if known.sum() >= min_echoes:
            scale[k] = float(np.median(1.0 / factor[known]))
    return scale
