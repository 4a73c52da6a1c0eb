"""Plane geometry of simulated sites: polygon rings, ray casting, depth slices, visibility.

A *site slice* is a list of closed rings (each an ``(K, 2)`` array of vertices in the map frame, metres,
x east, y north). The first ring is the outer wall; further rings are islands (pillars) inside it.
Rings are implicitly closed (the last vertex joins the first).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.path import Path as MplPath

Ring = np.ndarray
Slice = list[Ring]


def edges_of(rings: Sequence[Ring]) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points of every edge of every ring, shapes (E, 2) and (E, 2)."""
    starts = [np.asarray(r, dtype=np.float64) for r in rings]
    ends = [np.roll(r, -1, axis=0) for r in starts]
    return np.concatenate(starts), np.concatenate(ends)


def ray_cast(
    origin: np.ndarray, angles: np.ndarray, rings: Sequence[Ring], *, chunk: int = 4096
) -> tuple[np.ndarray, np.ndarray]:
    """Distance from ``origin`` along each map-frame angle to the first wall, and the incidence cosine.

    Parameters
    ----------
    origin : ndarray, shape (2,)
    angles : ndarray, shape (N,)
        Ray directions, radians CCW from +x.
    rings : sequence of (K, 2) arrays

    Returns
    -------
    ranges : ndarray, shape (N,)
        ``inf`` where a ray hits nothing.
    cos_incidence : ndarray, shape (N,)
        Cosine of the angle between the ray and the wall's normal at the hit (0 where nothing is hit).
    """
    origin = np.asarray(origin, dtype=np.float64)
    a, b = edges_of(rings)
    e = b - a
    e_len = np.hypot(e[:, 0], e[:, 1])
    ao = a - origin
    angles = np.asarray(angles, dtype=np.float64)
    ranges = np.full(angles.shape, np.inf)
    cosines = np.zeros(angles.shape)
    for lo in range(0, angles.size, chunk):
        d = np.column_stack([np.cos(angles[lo:lo + chunk]), np.sin(angles[lo:lo + chunk])])
        denom = d[:, 0:1] * e[None, :, 1] - d[:, 1:2] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ao[None, :, 0] * e[None, :, 1] - ao[None, :, 1] * e[None, :, 0]) / denom
            s = (ao[None, :, 0] * d[:, 1:2] - ao[None, :, 1] * d[:, 0:1]) / denom
        hit = (np.abs(denom) > 1e-12) & (t > 1e-9) & (s >= 0) & (s <= 1)
        t = np.where(hit, t, np.inf)
        best = np.argmin(t, axis=1)
        rows = np.arange(best.size)
        ranges[lo:lo + chunk] = t[rows, best]
        cosines[lo:lo + chunk] = np.where(
            np.isfinite(t[rows, best]), np.abs(denom[rows, best]) / e_len[best], 0.0
        )
    return ranges, cosines


def contains(rings: Sequence[Ring], points: np.ndarray) -> np.ndarray:
    """Which points lie in the water: inside the outer ring and outside every island."""
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    inside = MplPath(np.asarray(rings[0])).contains_points(points)
    for island in rings[1:]:
        inside &= ~MplPath(np.asarray(island)).contains_points(points)
    return inside


def ring_area(ring: Ring) -> float:
    """Unsigned area of a ring (shoelace formula)."""
    x, y = np.asarray(ring, dtype=np.float64).T
    return float(abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2.0)


def interpolate_slice(levels: Sequence[tuple[float, Slice]], depth_m: float) -> Slice:
    """The walls at ``depth_m`` of a site given as slices at several depths.

    Between two levels whose rings have equal vertex counts the vertices are interpolated linearly in
    depth; otherwise (or outside the range of levels) the nearest level is used.
    """
    ordered = sorted(levels, key=lambda item: item[0])
    depths = np.array([d for d, _ in ordered])
    if depth_m <= depths[0]:
        return ordered[0][1]
    if depth_m >= depths[-1]:
        return ordered[-1][1]
    upper = int(np.searchsorted(depths, depth_m))
    (d0, s0), (d1, s1) = ordered[upper - 1], ordered[upper]
    same = len(s0) == len(s1) and all(np.shape(r0) == np.shape(r1) for r0, r1 in zip(s0, s1))
    if not same:
        return s0 if depth_m - d0 <= d1 - depth_m else s1
    w = (depth_m - d0) / (d1 - d0)
    return [(1 - w) * np.asarray(r0) + w * np.asarray(r1) for r0, r1 in zip(s0, s1)]


def visibility_polygon(origin: np.ndarray, rings: Sequence[Ring], max_range_m: float, n_rays: int = 720) -> Ring:
    """The region seen from ``origin`` within ``max_range_m``, as a star-shaped ring of ``n_rays`` vertices."""
    angles = np.linspace(-np.pi, np.pi, n_rays, endpoint=False)
    ranges = _visible_ranges(np.asarray(origin, dtype=np.float64), rings, max_range_m, n_rays)
    return np.asarray(origin)[None, :] + ranges[:, None] * np.column_stack([np.cos(angles), np.sin(angles)])


def shared_wall_fraction(a: np.ndarray, b: np.ndarray, rings: Sequence[Ring], max_range_m: float,
                         n_rays: int = 720, tolerance_m: float = 0.05) -> float:
    """The smaller of the two shares of one station's visible wall that the other station sees too.

    A station's visible wall is where ``n_rays`` rays cast from it meet the walls within ``max_range_m``;
    the other station sees such a point when it lies within ``max_range_m`` of it and no wall stands in
    between (up to ``tolerance_m``). Unlike :func:`overlap_fraction`, which shares *water*, this shares
    the walls a matcher aligns: two chambers looking at each other through a tunnel share much of the
    water either sees and little wall.
    """
    stations = (np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    angles = np.linspace(-np.pi, np.pi, n_rays, endpoint=False)
    shares = []
    for here, there in (stations, stations[::-1]):
        ranges, _ = ray_cast(here, angles, rings)
        seen = ranges <= max_range_m
        if not seen.any():
            return 0.0
        walls = here + ranges[seen, None] * np.column_stack([np.cos(angles[seen]), np.sin(angles[seen])])
        offset = walls - there
        distance = np.hypot(offset[:, 0], offset[:, 1])
        first, _ = ray_cast(there, np.arctan2(offset[:, 1], offset[:, 0]), rings)
        shares.append(float(np.mean((distance <= max_range_m) & (first >= distance - tolerance_m))))
    return min(shares)


def _visible_ranges(origin: np.ndarray, rings: Sequence[Ring], max_range_m: float, n_rays: int) -> np.ndarray:
    angles = np.linspace(-np.pi, np.pi, n_rays, endpoint=False)
    ranges, _ = ray_cast(origin, angles, rings)
    return np.minimum(ranges, max_range_m)


def _seen(points: np.ndarray, origin: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """Which points lie in the star-shaped region ``ranges`` (one per ray, from -pi) around ``origin``."""
    d = points - origin
    n_rays = ranges.size
    index = np.round((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * n_rays).astype(np.int64) % n_rays
    return np.hypot(d[:, 0], d[:, 1]) <= ranges[index]


def overlap_fraction(
    a: np.ndarray, b: np.ndarray, rings: Sequence[Ring], max_range_m: float, cell_m: float = 0.05,
    n_rays: int = 720,
) -> float:
    """Shared fraction of the areas seen from stations ``a`` and ``b``: |Va ∩ Vb| / min(|Va|, |Vb|).

    The visible regions (star-shaped: ``n_rays`` rays cast from each station, cut at ``max_range_m``) are
    rasterised on a ``cell_m`` grid.
    """
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    ra = _visible_ranges(a, rings, max_range_m, n_rays)
    rb = _visible_ranges(b, rings, max_range_m, n_rays)
    lo = np.minimum(a - ra.max(), b - rb.max())
    hi = np.maximum(a + ra.max(), b + rb.max())
    xs = np.arange(lo[0], hi[0] + cell_m, cell_m)
    ys = np.arange(lo[1], hi[1] + cell_m, cell_m)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    in_a = _seen(grid, a, ra)
    in_b = _seen(grid, b, rb)
    smaller = min(int(in_a.sum()), int(in_b.sum()))
    return float((in_a & in_b).sum() / smaller) if smaller else 0.0
