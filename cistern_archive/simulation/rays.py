"""Wall geometry and ray casting for simulated scan pairs with known truth.

An environment is a set of wall segments ``(S, 4)``: x0, y0, x1, y1 in the map frame. Rays are cast
against every segment at once (vectorised over rays and segments); the nearest hit wins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Environment:
    """Walls of a simulated site and the free positions a vehicle may occupy.

    Attributes
    ----------
    walls : ndarray, shape (S, 4)
        Wall segments x0, y0, x1, y1 (m).
    kind : str
        ``"room"`` or ``"gallery"``.
    free_points : ndarray, shape (F, 2)
        Candidate station positions well inside the free space (at least 0.4 m from any wall).
    rings : tuple of ndarray
        The same walls as closed vertex rings (K, 2), the form :mod:`cistern_archive.simulation.simulator`
        takes.
    centre_line : ndarray or None, shape (V, 2)
        A gallery's centre line (``None`` for rooms).
    """

    walls: np.ndarray
    kind: str
    free_points: np.ndarray
    rings: tuple[np.ndarray, ...] = ()
    centre_line: np.ndarray | None = None


def cast_rays(origin: np.ndarray, angles: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """Distance from ``origin`` along each map-frame angle to the nearest wall (``inf`` on a miss).

    Parameters
    ----------
    origin : ndarray, shape (2,)
    angles : ndarray, shape (A,)
        Ray directions, counter-clockwise from +x (rad).
    walls : ndarray, shape (S, 4)

    Returns
    -------
    ndarray, shape (A,)
    """
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)[:, None, :]  # (A,1,2)
    a = walls[None, :, :2] - origin  # (1,S,2)
    e = (walls[:, 2:] - walls[:, :2])[None]  # (1,S,2)
    denom = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]  # (A,S)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (a[..., 0] * e[..., 1] - a[..., 1] * e[..., 0]) / denom
        u = (a[..., 0] * d[..., 1] - a[..., 1] * d[..., 0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= 0.0) & (u <= 1.0)
    t = np.where(hit, t, np.inf)
    return t.min(axis=1) if t.size else np.full(len(angles), np.inf)


def visible_from(origin: np.ndarray, points: np.ndarray, walls: np.ndarray, max_range_m: float,
                 tolerance_m: float = 0.05) -> np.ndarray:
    """Which wall points a sonar at ``origin`` would see (in range and not occluded)."""
    rel = points - origin
    dist = np.hypot(rel[:, 0], rel[:, 1])
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    first = cast_rays(origin, np.arctan2(rel[:, 1], rel[:, 0]), walls)
    return (dist <= max_range_m) & (first >= dist - tolerance_m)


def _polygon_walls(vertices: np.ndarray) -> np.ndarray:
    return np.column_stack([vertices, np.roll(vertices, -1, axis=0)])


def _box_walls(cx: float, cy: float, half: float, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    corners = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    rot = corners @ np.array([[c, s], [-s, c]]) + [cx, cy]
    return _polygon_walls(rot)


def _inside(points: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """Even-odd rule: a point is free when a ray from it crosses the walls an odd number of times."""
    out = np.zeros(len(points), dtype=bool)
    x0, y0, x1, y1 = walls.T
    for k, (px, py) in enumerate(points):
        cond = (y0 > py) != (y1 > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x0 + (py - y0) * (x1 - x0) / (y1 - y0)
        out[k] = np.count_nonzero(cond & (xc > px)) % 2 == 1
    return out


def _segment_distance(points: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """Distance from every point to its nearest wall segment."""
    a = walls[None, :, :2]
    e = walls[None, :, 2:] - a
    p = points[:, None, :]
    t = np.clip(((p - a) * e).sum(-1) / np.maximum((e * e).sum(-1), 1e-12), 0, 1)
    closest = a + t[..., None] * e
    return np.linalg.norm(p - closest, axis=-1).min(axis=1)


def _free_points(walls: np.ndarray, bounds: tuple[float, float, float, float], rng: np.random.Generator,
                 n: int = 400, clearance_m: float = 0.4) -> np.ndarray:
    x0, x1, y0, y1 = bounds
    cand = np.column_stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)])
    keep = _inside(cand, walls) & (_segment_distance(cand, walls) >= clearance_m)
    return cand[keep]


def random_room(rng: np.random.Generator) -> Environment:
    """An irregular cistern chamber: a star-shaped polygon with jittered radius and a few pillars."""
    n = int(rng.integers(9, 16))
    angles = np.sort(rng.uniform(0, 2 * np.pi, n))
    radius = rng.uniform(2.5, 6.0, n)
    outer = np.column_stack([radius * np.cos(angles), radius * np.sin(angles)])
    walls = [_polygon_walls(outer)]
    for _ in range(int(rng.integers(1, 4))):
        r = rng.uniform(0.5, 1.8)
        a = rng.uniform(0, 2 * np.pi)
        walls.append(_box_walls(r * np.cos(a), r * np.sin(a), rng.uniform(0.15, 0.35), rng.uniform(0, np.pi)))
    all_walls = np.concatenate(walls)
    free = _free_points(all_walls, (-6, 6, -6, 6), rng)
    return Environment(all_walls, "room", free, tuple(w[:, :2] for w in walls))


def random_gallery(rng: np.random.Generator, length_m: float = 24.0) -> Environment:
    """A winding gallery: a bent centre line, varying width, rectangular niches cut into the walls."""
    n_seg = max(3, int(length_m / 4))
    heading = 0.0
    pts = [np.zeros(2)]
    for _ in range(n_seg):
        heading += rng.uniform(-0.6, 0.6)
        pts.append(pts[-1] + rng.uniform(3.0, 5.0) * np.array([np.cos(heading), np.sin(heading)]))
    centre = np.array(pts)
    half = rng.uniform(0.9, 1.8, len(centre))
    left, right = [], []
    for k, c in enumerate(centre):
        if k == 0:
            t = centre[1] - centre[0]
        elif k == len(centre) - 1:
            t = centre[-1] - centre[-2]
        else:
            t = centre[k + 1] - centre[k - 1]
        t = t / np.linalg.norm(t)
        nrm = np.array([-t[1], t[0]])
        left.append(c + half[k] * nrm)
        right.append(c - half[k] * nrm)
        if 0 < k < len(centre) - 1 and rng.random() < 0.6:  # a niche after this vertex
            side = left if rng.random() < 0.5 else right
            sign = 1.0 if side is left else -1.0
            depth, width = rng.uniform(0.4, 1.0), rng.uniform(0.6, 1.2)
            nxt = centre[k + 1] - c
            nxt = nxt / np.linalg.norm(nxt)
            base = c + sign * half[k] * nrm + 0.8 * nxt
            side.extend([base, base + sign * depth * nrm, base + sign * depth * nrm + width * nxt, base + width * nxt])
    outline = np.array(left + right[::-1])
    walls = _polygon_walls(outline)
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    free = _free_points(walls, (lo[0], hi[0], lo[1], hi[1]), rng, n=800)
    return Environment(walls, "gallery", free, (outline,), centre)


def stations_along(line: np.ndarray, spacing_m: float) -> np.ndarray:
    """Points every ``spacing_m`` along a polyline (its first vertex included)."""
    seg = np.diff(line, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    at = np.arange(0.0, cum[-1], spacing_m)
    k = np.clip(np.searchsorted(cum, at, side="right") - 1, 0, len(seg) - 1)
    return line[k] + seg[k] * ((at - cum[k]) / lengths[k])[:, None]


def random_environment(rng: np.random.Generator) -> Environment:
    """A room or a gallery with equal probability."""
    return random_room(rng) if rng.random() < 0.5 else random_gallery(rng)
