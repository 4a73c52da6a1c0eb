"""How far the walls at the ends of a measured dimension lean, read from the depth slices above and below.

A mechanically scanned sonar's beam is narrow across (3°) but wide in elevation (35° on a Micron): a wall
that leans over the vehicle answers first from above (or below) the sonar's depth, nearer than where
the beam's axis meets it, so a slice's walls come out short where the walls lean, and so does a
dimension measured between them (``benchmarks/RESULTS.md``, "why the bell-shaped cistern misses": a bell
whose walls lean 47° was mapped 0.30 m short across at that depth; the mapper now corrects the echoes
for the lean, :mod:`cistern_archive.grid.lobe`, and the lean read here still flags such a dimension as
resting on that correction). With slices at several depths, the
lean at each end of a probe line is the change of that end's wall position from the dimension's slice to
the nearest other slice, over the depth between them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cistern_archive.core.grids import EvidenceGrid

OCCUPIED_ABOVE = 0.6
"""A cell whose occupancy probability exceeds this is a wall (as the wall surface reads the grids)."""
MIN_SLICE_GAP_M = 0.3
"""Slices closer in depth than this are the same depth level."""
SEARCH_BEYOND_M = 2.0
"""How far past the dimension's own wall the other slice's wall is looked for."""


def first_wall_m(grid: EvidenceGrid, wall: np.ndarray, start: np.ndarray, direction: np.ndarray,
                 reach_m: float) -> float:
    """Distance from ``start`` along the unit ``direction`` to the first cell of ``grid`` that ``wall``
    (a boolean mask of its cells) marks, within ``reach_m`` (``nan`` when none)."""
    steps = np.arange(0.0, reach_m, grid.cell_m / 2)
    points = start[None, :] + steps[:, None] * direction[None, :]
    cells = grid.cell_of(points)
    rows, cols = grid.log_odds.shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < rows) & (cells[:, 1] >= 0) & (cells[:, 1] < cols)
    hit = np.zeros(len(points), dtype=bool)
    hit[inside] = wall[cells[inside, 0], cells[inside, 1]]
    return float(steps[np.argmax(hit)]) if hit.any() else float("nan")


def wall_lean_deg(grids: Sequence[EvidenceGrid], depth_m: float,
                  probe_lines: Sequence[tuple[float, float, float, float]]) -> float | None:
    """Median lean from the vertical (degrees) of the walls at the ends of ``probe_lines`` (map-frame
    segments measured on the slice at ``depth_m``), against the nearest slice at another depth; ``None``
    when there is no other slice or no wall on it along the probes.
    """
    others = [g for g in grids if abs(g.depth_m - depth_m) >= MIN_SLICE_GAP_M]
    if not others or not probe_lines:
        return None
    other = min(others, key=lambda g: (abs(g.depth_m - depth_m), g.depth_m))
    dz = abs(other.depth_m - depth_m)
    wall = other.probability() > OCCUPIED_ABOVE
    leans = []
    for x0, y0, x1, y1 in probe_lines:
        a, b = np.array([x0, y0], dtype=float), np.array([x1, y1], dtype=float)
        half = 0.5 * float(np.hypot(*(b - a)))
        if half <= 0:
            continue
        middle, along = 0.5 * (a + b), (b - a) / (2 * half)
        for direction in (along, -along):
            there = first_wall_m(other, wall, middle, direction, half + SEARCH_BEYOND_M)
            if math.isfinite(there):
                leans.append(math.degrees(math.atan2(abs(there - half), dz)))
    return float(np.median(leans)) if leans else None
