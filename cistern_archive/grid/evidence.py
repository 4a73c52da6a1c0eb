"""Log-odds inverse sonar model over the beam cone (evidence grids, paper Sec. III-D and Table III).

A cell is updated by every beam whose cone (``beam_width_rad`` wide, centred on the beam's bearing)
contains the cell centre. For a beam with an echo at range ``r``:

* cells closer than ``r - h`` are **free** (``l_free`` is added),
* cells within ``r ± h`` are **occupied** (``l_occ`` is added), with ``h = max(bin_size, cell) / 2``,
* cells farther than ``r + h`` are not touched (the wall hides them).

A beam with no echo adds ``l_free`` up to the sonar's range when ``free_no_echo`` is set (the beam saw
open water), and nothing otherwise. A scan whose echoes were not heard on beams from its station (a
moving vehicle's motion-compensated cloud, ``RangeScan.rays_from_station`` false) adds only its
echoes: the line from the station to an echo was no beam's, and carving it free cut the quay walls of
the Girona marina's map with spokes of water and left its walls a thin fringe. The log-odds of one scan
are summed over its beams (the standard independent-beam update, Thrun et al. 2005, ch. 9) and the
fused grid is clamped to ``[clamp_min, clamp_max]`` after every scan so that a cell can change its mind.

The update is computed cell-centrically: every cell of the scan's reach is visited once and tested
against the few beams whose bearing is within half a beam width of it, which vectorises over cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cistern_archive.core.scan import RangeScan


@dataclass(frozen=True)
class SonarModel:
    """Parameters of the inverse sonar model.

    Attributes
    ----------
    l_occ : float
        Log-odds added to a cell at the echo range (> 0).
    l_free : float
        Log-odds added to a cell in front of the echo (< 0).
    clamp_min, clamp_max : float
        Bounds of a fused cell's log-odds.
    free_no_echo : bool
        Whether beams without an echo free the cone up to the sonar's range.
    beam_width_rad : float or None
        Cone width; ``None`` uses each scan's own ``beam_width_rad``.
    occupied_width_rad : float or None
        Width of the part of the cone marked occupied at the echo range; ``None`` marks the whole cone
        (the classic model), ``0`` only the cells within half a cell of the beam's axis (the echo as a
        point: a wall seen at a grazing angle is not smeared across the cone into the open water).
    free_width_rad : float or None
        Width of the part of the cone marked free in front of the echo; ``None`` the whole cone. A
        narrow free cone keeps a wall seen at a grazing angle from being carved out by the edges of the
        cones of the beams that hit it a little farther on.
    """

    l_occ: float = 0.85
    l_free: float = -0.4
    clamp_min: float = -4.0
    clamp_max: float = 4.0
    free_no_echo: bool = False
    beam_width_rad: float | None = None
    occupied_width_rad: float | None = None
    free_width_rad: float | None = None


@dataclass(frozen=True, eq=False)
class ScanWindow:
    """The log-odds update of one scan over a rectangular block of cells.

    Attributes
    ----------
    row0, col0 : int
        Grid index of the block's first cell (the grid's cell ``(row0, col0)``).
    delta : ndarray, shape (H, W), float32
        Log-odds to add to the block.
    """

    row0: int
    col0: int
    delta: np.ndarray


def scan_reach_m(scan: RangeScan, model: SonarModel) -> float:
    """How far from the sonar one scan can change the grid (m)."""
    finite = scan.ranges_m[np.isfinite(scan.ranges_m)]
    reach = float(finite.max()) if finite.size else 0.0
    if model.free_no_echo and (finite.size < scan.ranges_m.size):
        reach = max(reach, float(scan.max_range_m))
    return reach + max(scan.bin_size_m, 0.0)


def _beam_window(bearings_sorted: np.ndarray, half_width: float) -> int:
    """Largest number of beams on one side of any bearing that can be within ``half_width`` of it."""
    n = bearings_sorted.size
    if n <= 1:
        return n
    extended = np.concatenate([bearings_sorted - 2 * np.pi, bearings_sorted, bearings_sorted + 2 * np.pi])
    lo = np.searchsorted(extended, bearings_sorted - half_width, side="left")
    hi = np.searchsorted(extended, bearings_sorted + half_width, side="right")
    return int(min(n, np.max(hi - lo) + 1))


def scan_window(
    scan: RangeScan,
    xy_m: tuple[float, float] | np.ndarray,
    yaw_rad: float,
    *,
    origin_xy_m: tuple[float, float],
    cell_m: float,
    model: SonarModel,
) -> ScanWindow | None:
    """Log-odds update of one scan placed at ``xy_m`` with heading ``yaw_rad``.

    Parameters
    ----------
    scan : RangeScan
        Bearings (sonar frame) and ranges; ``nan`` ranges are beams without an echo.
    xy_m : (2,) array_like
        Sonar position in the map frame.
    yaw_rad : float
        Heading in the map frame (beam ``b`` points at ``yaw_rad + bearings_rad[b]``).
    origin_xy_m : (2,) tuple
        Map-frame position of the grid's cell (0, 0) lower-left corner.
    cell_m : float
        Cell size.
    model : SonarModel
        Inverse sonar model.

    Returns
    -------
    ScanWindow or None
        ``None`` when the scan touches no cell (no echo and ``free_no_echo`` off).
    """
    reach = scan_reach_m(scan, model)
    if reach <= scan.bin_size_m or scan.bearings_rad.size == 0:
        return None
    x, y = float(xy_m[0]), float(xy_m[1])
    col0 = int(math.floor((x - reach - origin_xy_m[0]) / cell_m))
    row0 = int(math.floor((y - reach - origin_xy_m[1]) / cell_m))
    col1 = int(math.floor((x + reach - origin_xy_m[0]) / cell_m)) + 1
    row1 = int(math.floor((y + reach - origin_xy_m[1]) / cell_m)) + 1
    cx = origin_xy_m[0] + (np.arange(col0, col1) + 0.5) * cell_m - x
    cy = origin_xy_m[1] + (np.arange(row0, row1) + 0.5) * cell_m - y
    rho = np.hypot(cy[:, None], cx[None, :])
    bearing = np.arctan2(cy[:, None], cx[None, :]) - yaw_rad
    bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
    delta = _cone_update(scan, rho, bearing, reach, cell_m, model)
    if not np.any(delta):
        return None
    return ScanWindow(row0=row0, col0=col0, delta=delta)


def _cone_update(
    scan: RangeScan, rho: np.ndarray, bearing: np.ndarray, reach: float, cell_m: float, model: SonarModel
) -> np.ndarray:
    """Sum of the per-beam inverse-model updates at cells with polar coordinates (rho, bearing)."""
    width = scan.beam_width_rad if model.beam_width_rad is None else model.beam_width_rad
    half = 0.5 * float(width)
    b = (np.asarray(scan.bearings_rad) + np.pi) % (2 * np.pi) - np.pi
    order = np.argsort(b, kind="stable")
    b_sorted = b[order]
    r_sorted = np.asarray(scan.ranges_m)[order]
    n = b_sorted.size
    h = 0.5 * max(scan.bin_size_m, cell_m)
    inside = rho <= reach
    rho_in = rho[inside]
    bear_in = bearing[inside]
    out = np.zeros(rho_in.shape, dtype=np.float32)
    idx = np.searchsorted(b_sorted, bear_in)
    m = _beam_window(b_sorted, half)
    free_no_echo_limit = float(scan.max_range_m) if model.free_no_echo else -np.inf
    occ_half = _part_of_cone(model.occupied_width_rad, half, rho_in, cell_m)
    free_half = _part_of_cone(model.free_width_rad, half, rho_in, cell_m)
    if 2 * m + 1 >= n:
        candidates = (np.full(idx.shape, k) for k in range(n))
    else:
        candidates = ((idx + k) % n for k in range(-m, m + 1))
    for beam in candidates:
        diff = np.abs((bear_in - b_sorted[beam] + np.pi) % (2 * np.pi) - np.pi)
        r = r_sorted[beam]
        echo = np.isfinite(r)
        r_safe = np.where(echo, r, free_no_echo_limit)
        if scan.rays_from_station:  # else the line to the echo was no beam's (module docstring)
            free = (diff <= free_half) & (rho_in < np.where(echo, r_safe - h, r_safe))
            out += np.where(free, np.float32(model.l_free), np.float32(0.0))
        occ = (diff <= occ_half) & echo & (np.abs(rho_in - r_safe) <= h)
        out += np.where(occ, np.float32(model.l_occ), np.float32(0.0))
    delta = np.zeros(rho.shape, dtype=np.float32)
    delta[inside] = out
    return delta


def _part_of_cone(width: float | None, half: float, rho: np.ndarray, cell_m: float) -> np.ndarray | float:
    """Half-angle of the part of the cone a beam updates at each cell (at least half a cell wide)."""
    if width is None:
        return half
    return np.minimum(half, np.maximum(0.5 * width, 0.5 * cell_m / np.maximum(rho, 1e-6)))


@dataclass(frozen=True, eq=False)
class DenseMap:
    """A dense log-odds grid of one scan in its own map frame (the matcher's ``m_i``).

    Attributes
    ----------
    log_odds : ndarray, shape (H, W), float32
    origin_xy_m : tuple of float
        Lower-left corner of cell (0, 0), the scan's sonar being at the map origin.
    cell_m : float
    """

    log_odds: np.ndarray
    origin_xy_m: tuple[float, float]
    cell_m: float

    def occupied(self, probability_threshold: float) -> np.ndarray:
        """Cells whose occupancy probability exceeds ``probability_threshold`` (WEIGHT_THRESHOLD)."""
        p = np.clip(probability_threshold, 1e-6, 1 - 1e-6)
        return self.log_odds > np.float32(math.log(p / (1.0 - p)))


def dense_scan_map(scan: RangeScan, *, cell_m: float, model: SonarModel, margin_m: float = 0.0) -> DenseMap:
    """Evidence grid of a single scan with its sonar at the origin (Table I, line 2: ``construct.map``).

    The grid is compass aligned (beams point at ``scan.yaw_rad + bearing``), centred on the sonar and
    ``2 * (reach + margin_m)`` wide; clamped like a fused grid.
    """
    reach = scan_reach_m(scan, model) + margin_m
    n = max(1, int(math.ceil(reach / cell_m)))
    origin = (-n * cell_m, -n * cell_m)
    log_odds = np.zeros((2 * n, 2 * n), dtype=np.float32)
    window = scan_window(scan, (0.0, 0.0), scan.yaw_rad, origin_xy_m=origin, cell_m=cell_m, model=model)
    if window is not None:
        _add_window(log_odds, window)
    np.clip(log_odds, model.clamp_min, model.clamp_max, out=log_odds)
    return DenseMap(log_odds=log_odds, origin_xy_m=origin, cell_m=cell_m)


def _add_window(dense: np.ndarray, window: ScanWindow) -> None:
    """Add a window to a dense array whose cell (0, 0) is grid cell (0, 0), cropping what falls outside."""
    h, w = window.delta.shape
    r0, c0 = max(window.row0, 0), max(window.col0, 0)
    r1, c1 = min(window.row0 + h, dense.shape[0]), min(window.col0 + w, dense.shape[1])
    if r1 <= r0 or c1 <= c0:
        return
    dense[r0:r1, c0:c1] += window.delta[r0 - window.row0 : r1 - window.row0, c0 - window.col0 : c1 - window.col0]
