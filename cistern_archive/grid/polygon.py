"""Range scans ray cast inside polygons: known geometry for tests, conformance checks and benchmarks.

This is not the sonar simulator (which models intensities, speckle and the beam pattern); it produces
:class:`~cistern_archive.core.scan.RangeScan` objects directly, with optional Gaussian range noise,
dropped beams and spurious echoes, so that matchers and mappers can be checked against exact truth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cistern_archive.core.scan import RangeScan


def rectangle(width_m: float, length_m: float, *, centre: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Vertices (4, 2) of an axis-aligned rectangle, ``width_m`` along x and ``length_m`` along y."""
    cx, cy = centre
    hw, hl = width_m / 2, length_m / 2
    return np.array([[cx - hw, cy - hl], [cx + hw, cy - hl], [cx + hw, cy + hl], [cx - hw, cy + hl]])


def segments_of(polygons: Sequence[np.ndarray]) -> np.ndarray:
    """All edges (S, 4) as x0, y0, x1, y1 of closed polygons."""
    edges = []
    for poly in polygons:
        poly = np.asarray(poly, dtype=np.float64)
        edges.append(np.column_stack([poly, np.roll(poly, -1, axis=0)]))
    return np.concatenate(edges, axis=0)


def cast_rays(segments: np.ndarray, origin: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Distance from ``origin`` along each map-frame angle to the nearest segment (``inf`` if none)."""
    d = np.column_stack([np.cos(angles), np.sin(angles)])  # (A, 2)
    p = segments[:, :2] - origin  # (S, 2)
    e = segments[:, 2:] - segments[:, :2]  # (S, 2)
    denom = d[:, 0:1] * e[None, :, 1] - d[:, 1:2] * e[None, :, 0]  # (A, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (p[None, :, 0] * e[None, :, 1] - p[None, :, 1] * e[None, :, 0]) / denom
        u = (p[None, :, 0] * d[:, 1:2] - p[None, :, 1] * d[:, 0:1]) / denom
    hit = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
    t = np.where(hit, t, np.inf)
    return t.min(axis=1)


def polygon_scan(
    polygons: Sequence[np.ndarray],
    xy_m: tuple[float, float],
    yaw_rad: float,
    *,
    rng: np.random.Generator,
    n_beams: int = 200,
    max_range_m: float = 10.0,
    range_noise_m: float = 0.0,
    yaw_noise_rad: float = 0.0,
    dropout: float = 0.0,
    outliers: float = 0.0,
    bin_size_m: float = 0.05,
    beam_width_rad: float = math.radians(3.0),
    depth_m: float = 0.0,
    station: str = "",
) -> RangeScan:
    """A 360° range scan from ``xy_m`` inside the walls ``polygons``.

    Parameters
    ----------
    polygons : sequence of (K, 2) arrays
        Closed wall outlines in the map frame (the first is usually the site outline).
    xy_m, yaw_rad : tuple, float
        True sonar position and heading.
    rng : numpy.random.Generator
        Source of every random draw.
    n_beams : int
        Beams over one revolution.
    range_noise_m : float
        Standard deviation of Gaussian range noise.
    yaw_noise_rad : float
        Error of the recorded compass heading (added to ``yaw_rad`` in the returned scan).
    dropout : float
        Fraction of beams returned without an echo.
    outliers : float
        Fraction of beams given a uniform random range in front of the wall (multipath, fish, ROV tether).
    bin_size_m : float
        Ranges are quantised to bin centres of this size.
    """
    bearings = np.arange(n_beams) * (2 * np.pi / n_beams)
    true = cast_rays(segments_of(polygons), np.asarray(xy_m, dtype=np.float64), bearings + yaw_rad)
    ranges = true + rng.normal(0.0, range_noise_m, n_beams) if range_noise_m > 0 else true.copy()
    spurious = rng.random(n_beams) < outliers
    ranges[spurious] = rng.uniform(0.2, 1.0, int(spurious.sum())) * np.minimum(true[spurious], max_range_m)
    ranges = (np.floor(ranges / bin_size_m) + 0.5) * bin_size_m
    ranges[(ranges >= max_range_m) | ~np.isfinite(ranges) | (rng.random(n_beams) < dropout)] = np.nan
    return RangeScan(
        bearings_rad=bearings,
        ranges_m=ranges,
        yaw_rad=float(yaw_rad + yaw_noise_rad),
        depth_m=depth_m,
        max_range_m=max_range_m,
        bin_size_m=bin_size_m,
        beam_width_rad=beam_width_rad,
        station=station,
    )
