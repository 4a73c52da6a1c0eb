"""Outlines of galleries: a tunnel around a centre line whose width may step from one reach to the next,
with rectangular recesses (niches, blind side branches) cut into either wall.

Maltese water galleries are rock-cut tunnels with bends, changes of section and niches or short side
branches; these are what a scan matcher can lock onto along an otherwise featureless corridor. The
outline is built side by side: each reach's wall is its centre line offset by half the reach's width;
at a bend the walls of consecutive reaches meet at the intersection of their offset lines (a mitre),
and where two consecutive reaches are collinear with different widths the wall steps across. A recess
on reach ``k`` starts ``at_m`` along it, runs ``length_m`` along it and goes ``depth_m`` into the wall.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Recess:
    """A rectangular recess in one wall of reach ``segment`` (``side`` +1 left, -1 right of travel)."""

    segment: int
    side: int
    at_m: float
    length_m: float
    depth_m: float


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def _junction(vertex: np.ndarray, t1: np.ndarray, o1: np.ndarray, t2: np.ndarray, o2: np.ndarray) -> list[np.ndarray]:
    """Where the wall of the reach before ``vertex`` (offset ``o1``) meets the wall after it (``o2``)."""
    p1, p2 = vertex + o1, vertex + o2
    denom = _cross(t1, t2)
    if abs(denom) < 1e-9:
        return [p1] if np.allclose(p1, p2) else [p1, p2]
    a = _cross(p2 - p1, t2) / denom
    return [p1 + a * t1]


def gallery_ring(centre: np.ndarray, widths: Sequence[float], recesses: Sequence[Recess] = ()) -> np.ndarray:
    """The outline of a gallery (see the module docstring).

    Parameters
    ----------
    centre : ndarray, shape (K, 2)
        Centre line, K >= 2 distinct consecutive points.
    widths : sequence of float, length K - 1
        Width of each reach.
    recesses : sequence of Recess

    Returns
    -------
    ndarray, shape (M, 2)
        Left wall forwards, then right wall backwards (the vertex order of
        :func:`cistern_archive.simulation.spec.corridor_ring`).

    Raises
    ------
    ValueError
        Wrong number of widths, repeated centre points, or a recess outside its reach.
    """
    centre = np.asarray(centre, dtype=np.float64)
    seg = np.diff(centre, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    if len(widths) != len(seg):
        raise ValueError(f"gallery has {len(seg)} reaches but {len(widths)} widths")
    if np.any(lengths <= 0):
        raise ValueError("gallery centre line has repeated points")
    tangents = seg / lengths[:, None]
    normals = np.column_stack([-tangents[:, 1], tangents[:, 0]])
    for r in recesses:
        if not 0 <= r.segment < len(seg) or r.at_m < 0 or r.at_m + r.length_m > lengths[r.segment] + 1e-9:
            raise ValueError(f"recess {r} does not fit on its reach (reach lengths {np.round(lengths, 3).tolist()})")
    sides = []
    for side in (1, -1):
        offsets = [side * w / 2.0 * n for w, n in zip(widths, normals)]
        points = [centre[0] + offsets[0]]
        for k in range(len(seg)):
            if k > 0:
                points += _junction(centre[k], tangents[k - 1], offsets[k - 1], tangents[k], offsets[k])
            for r in sorted((r for r in recesses if r.segment == k and r.side == side), key=lambda r: r.at_m):
                a = centre[k] + offsets[k] + r.at_m * tangents[k]
                b = a + r.length_m * tangents[k]
                push = side * r.depth_m * normals[k]
                points += [a, a + push, b + push, b]
        points.append(centre[-1] + offsets[-1])
        sides.append(np.array(points))
    return np.vstack([sides[0], sides[1][::-1]])
