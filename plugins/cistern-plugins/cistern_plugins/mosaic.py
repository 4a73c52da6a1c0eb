"""Mosaic comparator: reference dimensions measured in the evidence grid (the paper's Table IV, Sec. IV).

Probe (``method="probe"``)
    From the probe's inside point, walk along ``+direction`` and ``-direction`` to the first occupied
    cell (log-odds above ``occupied_log_odds``) on each side; the measurement is the distance between the
    two walls, each taken at the first wall cell's inner edge (``edge="inner"``, default, the paper's
    count "from one inside edge to the other") or at the middle of that cell (``edge="centre"``). The
    inverse sonar model marks the cell that contains the echo, so with exact ranges the wall lies
    anywhere in that cell: the centre is then unbiased and the inner edge half a cell short per side
    (synthetic pools: −0.005 m vs −0.055 m mean width error). The simulated Micron's echoes come back
    about a centimetre long per side (the beam's off-axis rays travel farther), which the inner edge
    partly cancels: on the simulated pool ``inner`` measures 0.021 / 0.025 m median width / length
    error and ``centre`` 0.030 / 0.025 m (``benchmarks/RESULTS.md``). ``repeats``
    parallel probes are spaced ``spacing_m`` apart across the direction, centred on the inside point;
    the row's value is their mean and their spread is the paper's probe standard deviation. A probe
    that slips through a gap in a wall (the paper's "holes in the map") measures to the next wall
    beyond; with ``reject_outliers`` such probes (farther than ``max(outlier_min_m, 3 × 1.4826 × MAD)``
    from the probes' median) are dropped and the row's note says which.

    **Frames.** With ``frame`` naming a station, ``inside`` is an offset from that station's placed
    position along the map's axes (east, north) and ``direction_deg`` is counter-clockwise from east:
    the map frame is compass aligned, so a probe drawn on a station-centred, north-up sketch needs no
    rotation. ``frame_rotation="yaw"`` rotates both by the station's heading instead (a probe drawn in
    the vehicle's own frame). Without ``frame`` the point is in the map frame (the reference scan at 0).

    **Heading check.** The map's north is the compasses', off by their common bias, so the map places a
    probe turned by that bias about its station. Each probe is measured again turned by
    ``HEADING_TURN_DEG`` (2°) either way about its station (the map's origin without ``frame``), and the
    larger change of the value is the row's ``heading_shift_m``: small where the probes end on walls
    square to them, large where they end far from the station on oblique walls, at a corner or an
    opening (the report flags such a dimension weak, :func:`cistern_archive.pipeline.status.weakness`).

Automatic (``method="auto-width"`` / ``"auto-length"``)
    For rectangular sites: the principal axes of the occupied cells give the site's directions; the
    minor axis is the width, the major the length. The probes start at the centroid of the occupied
    cells and are repeated across the axis like a probe.

Statistics (``DimensionTable.stats``)
    ``percent_difference`` when ``truth`` references named ``width`` and ``length`` exist: the percent
    difference between the map's width/length ratio ``a`` and the true ratio ``b``,
    ``100 |a - b| / ((a + b) / 2)`` (the paper's PD; its reported 3.30 % is not reproducible from its
    rounded 3.47 m × 7.27 m, which give 4.78 %); ``probe_std_<name>_m`` per truth dimension (sample std
    of the probes, ddof = 1); ``max_abs_diff_m``, ``mean_abs_diff_m`` over the rows measured.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, ClassVar, Literal

import numpy as np
from pydantic import Field

from cistern_archive.core.dimensions import HEADING_TURN_DEG
from cistern_archive.pipeline.contracts import DimensionRow, DimensionTable, EvidenceGrid, MapResult, Poses, StageParams

if TYPE_CHECKING:  # pragma: no cover
    from cistern_archive.catalog.models import Probe, ReferenceDimension


class MosaicParams(StageParams):
    """Parameters of :class:`MosaicComparator`."""

    occupied_log_odds: float = Field(0.4, description="a cell is a wall above this log-odds")
    max_probe_m: float = Field(60.0, gt=0, description="give up a probe side after this distance")
    step_fraction: float = Field(0.1, gt=0, le=1, description="probe sampling step, in cells")
    frame_rotation: Literal["none", "yaw"] = "none"
    edge: Literal["inner", "centre", "centroid"] = "inner"
    reject_outliers: bool = Field(True, description="drop probes that passed through a gap in a wall")
    outlier_min_m: float = Field(0.15, ge=0, description="never call a probe within this of the median an outlier")


class MosaicComparator:
    """Grid-vs-reference dimension table (``mosaic``)."""

    name: ClassVar[str] = "mosaic"
    Params: ClassVar[type[StageParams]] = MosaicParams

    def compare(
        self,
        map_result: MapResult,
        poses: Poses,
        references: Sequence["ReferenceDimension"],
        station_index: dict[str, int],
        params: StageParams,
    ) -> DimensionTable:
        """Measure every reference in the map and summarise (see the module docstring)."""
        p = MosaicParams.of(params)
        rows = tuple(_measure(ref, map_result, poses, station_index, p) for ref in references)
        return DimensionTable(rows=rows, stats=table_stats(rows))


# ----------------------------------------------------------------------------------- measuring
def _row(
    ref: "ReferenceDimension", depth: float, probes: list[float], lines: list, note: str,
    p: MosaicParams | None = None,
) -> DimensionRow:
    keep = [k for k, v in enumerate(probes) if math.isfinite(v)]
    notes = [note] if note else []
    if len(keep) < len(probes):
        notes.append(f"{len(probes) - len(keep)} of {len(probes)} probes found no wall on one side")
    if p is not None and p.reject_outliers and len(keep) >= 3:
        values = np.array([probes[k] for k in keep])
        med = float(np.median(values))
        mad = float(np.median(np.abs(values - med)))
        inlier = np.abs(values - med) <= max(p.outlier_min_m, 3.0 * 1.4826 * mad)
        if not inlier.all():
            notes.append(f"{int((~inlier).sum())} of {len(probes)} probes dropped as outliers "
                         f"(through a gap in a wall): {', '.join(f'{v:.2f}' for v in values[~inlier])} m")
        keep = [k for k, ok in zip(keep, inlier) if ok]
    finite = [probes[k] for k in keep]
    value = float(np.mean(finite)) if finite else float("nan")
    return DimensionRow(
        name=ref.name, map_m=value, reference_m=float(ref.value_m), reference_kind=ref.kind,
        diff_m=value - float(ref.value_m), depth_m=depth, probes=tuple(finite),
        probe_lines=tuple(lines[k] for k in keep if k < len(lines)), note="; ".join(notes),
    )


def _measure(
    ref: "ReferenceDimension", map_result: MapResult, poses: Poses, station_index: dict[str, int], p: MosaicParams
) -> DimensionRow:
    probe = ref.measure
    grid = pick_grid(map_result, probe.depth_m)
    if grid is None or grid.log_odds.size == 0:
        return _row(ref, float("nan"), [], [], "the map is empty")
    occupied = grid.log_odds > p.occupied_log_odds
    pivot = None  # the station a probe is given from: automatic axes come from the map itself
    if probe.method == "probe":
        placed = probe_in_map(probe, poses, station_index, p.frame_rotation)
        if isinstance(placed, str):
            return _row(ref, grid.depth_m, [], [], placed)
        start, angle, pivot = placed
    else:
        axes = principal_axes(grid, occupied)
        if axes is None:
            return _row(ref, grid.depth_m, [], [], "too few occupied cells for automatic axes")
        start, major = axes
        angle = major if probe.method == "auto-length" else major + math.pi / 2
    values, lines = repeated_probes(grid, occupied, start, angle, probe.repeats, probe.spacing_m, p)
    row = _row(ref, grid.depth_m, values, lines, "", p)
    if pivot is None or not math.isfinite(row.map_m):
        return row
    return replace(row, heading_shift_m=heading_shift(ref, grid, occupied, pivot, start, angle, row.map_m, p))


def heading_shift(ref: "ReferenceDimension", grid: EvidenceGrid, occupied: np.ndarray, pivot: np.ndarray,
                  start: np.ndarray, angle: float, value: float, p: MosaicParams) -> float:
    """The larger change of ``value`` when the probes turn ``HEADING_TURN_DEG`` either way about
    ``pivot`` (``inf`` when a turned probe set finds no wall)."""
    changes = []
    for sign in (-1.0, 1.0):
        turned_start, turned_angle = turn_about(pivot, start, angle, sign * HEADING_TURN_DEG)
        values, _ = repeated_probes(grid, occupied, turned_start, turned_angle, ref.measure.repeats,
                                    ref.measure.spacing_m, p)
        turned = _row(ref, grid.depth_m, values, [], "", p).map_m
        changes.append(abs(turned - value) if math.isfinite(turned) else math.inf)
    return max(changes)


def turn_about(pivot: np.ndarray, start: np.ndarray, angle: float, turn_deg: float) -> tuple[np.ndarray, float]:
    """A probe's start point and direction (rad) turned by ``turn_deg`` about ``pivot``: where the map puts
    a probe given from the station at ``pivot`` when the map's heading is off by that much
    (:data:`~cistern_archive.core.dimensions.HEADING_TURN_DEG`)."""
    turn = math.radians(turn_deg)
    c, s = math.cos(turn), math.sin(turn)
    offset = np.asarray(start, dtype=np.float64) - pivot
    return pivot + np.array([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]]), angle + turn


def pick_grid(map_result: MapResult, depth_m: float | None) -> EvidenceGrid | None:
    """The slice nearest ``depth_m`` (the shallowest when no depth is given)."""
    if not map_result.grids:
        return None
    if depth_m is None:
        return map_result.grids[0]
    return min(map_result.grids, key=lambda g: abs(g.depth_m - depth_m))


def probe_in_map(
    probe: "Probe", poses: Poses, station_index: dict[str, int], rotation: str
) -> tuple[np.ndarray, float, np.ndarray] | str:
    """Map-frame start point and direction (rad) of a probe and the point it is given from (its frame
    station, or the map's origin), or why it cannot be placed."""
    inside = np.asarray(probe.inside, dtype=np.float64)
    angle = math.radians(probe.direction_deg)
    if probe.frame is None:
        return inside, angle, np.zeros(2)
    if probe.frame not in station_index:
        return f"probe frame {probe.frame!r} is not a station of the site"
    k = station_index[probe.frame]
    if not bool(poses.placed[k]):
        return f"probe frame station {probe.frame!r} (scan {k}) is unplaced: {poses.reasons[k]}"
    if rotation == "yaw":
        yaw = float(poses.yaw_rad[k])
        c, s = math.cos(yaw), math.sin(yaw)
        inside = np.array([c * inside[0] - s * inside[1], s * inside[0] + c * inside[1]])
        angle += yaw
    return poses.xy_m[k] + inside, angle, poses.xy_m[k]


def principal_axes(grid: EvidenceGrid, occupied: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Centroid and major-axis angle (rad) of the occupied cells."""
    rows, cols = np.nonzero(occupied)
    if rows.size < 10:
        return None
    xy = np.column_stack([
        grid.origin_xy_m[0] + (cols + 0.5) * grid.cell_m,
        grid.origin_xy_m[1] + (rows + 0.5) * grid.cell_m,
    ])
    centre = xy.mean(axis=0)
    cov = np.cov((xy - centre).T)
    evals, evecs = np.linalg.eigh(cov)
    major = evecs[:, int(np.argmax(evals))]
    return centre, math.atan2(major[1], major[0])


def repeated_probes(
    grid: EvidenceGrid, occupied: np.ndarray, start: np.ndarray, angle: float, repeats: int, spacing: float,
    p: MosaicParams,
) -> tuple[list[float], list[tuple[float, float, float, float] | None]]:
    """``repeats`` parallel wall-to-wall measurements centred on ``start`` (a line per probe, ``None``
    where the probe found no wall on one side)."""
    u = np.array([math.cos(angle), math.sin(angle)])
    normal = np.array([-u[1], u[0]])
    values, lines = [], []
    for k in range(repeats):
        origin = start + (k - (repeats - 1) / 2.0) * spacing * normal
        plus = wall_distance(grid, occupied, origin, u, p)
        minus = wall_distance(grid, occupied, origin, -u, p)
        values.append(plus + minus)
        if math.isfinite(plus + minus):
            a, b = origin - minus * u, origin + plus * u
            lines.append((float(a[0]), float(a[1]), float(b[0]), float(b[1])))
        else:
            lines.append(None)
    return values, lines


def wall_distance(grid: EvidenceGrid, occupied: np.ndarray, origin: np.ndarray, u: np.ndarray, p: MosaicParams) -> float:
    """Distance from ``origin`` along ``u`` to the inner edge of the first occupied cell (``inf`` if none).

    The ray is sampled every ``step_fraction`` cells; the first sample inside an occupied cell is then
    replaced by the exact distance at which the ray enters that cell's square (``edge="inner"``, the
    paper's count from inner edge to inner edge), plus half a cell (``"centre"``: the wall is taken at
    the middle of its first cell), or by the log-odds-weighted mean distance over the contiguous band
    of wall cells the probe crosses (``"centroid"``).
    """
    step = p.step_fraction * grid.cell_m
    t = np.arange(0.0, p.max_probe_m, step)
    pts = origin + t[:, None] * u
    rc = grid.cell_of(pts)
    h, w = occupied.shape
    inside = (rc[:, 0] >= 0) & (rc[:, 0] < h) & (rc[:, 1] >= 0) & (rc[:, 1] < w)
    last = np.flatnonzero(inside)
    if last.size == 0:
        return float("inf")
    n = last[-1] + 1
    rows, cols = rc[:n, 0].clip(0, h - 1), rc[:n, 1].clip(0, w - 1)
    wall = inside[:n] & occupied[rows, cols]
    hits = np.flatnonzero(wall)
    if hits.size == 0:
        return float("inf")
    first = hits[0]
    row, col = rc[first]
    inner = _entry_distance(grid, int(row), int(col), origin, u, float(t[first]))
    if p.edge == "inner":
        return inner
    if p.edge == "centre":
        return inner + 0.5 * grid.cell_m
    # centroid: log-odds-weighted mean position over the contiguous wall band the probe enters
    end = first + int(np.argmin(wall[first:])) if not wall[first:].all() else n
    band = slice(first, end)
    weight = grid.log_odds[rows[band], cols[band]].astype(np.float64) - p.occupied_log_odds
    return float((t[band] * weight).sum() / weight.sum())


def _entry_distance(grid: EvidenceGrid, row: int, col: int, origin: np.ndarray, u: np.ndarray, fallback: float) -> float:
    """Where the ray ``origin + t u`` enters the square of cell (row, col) (slab method)."""
    lo = np.array([grid.origin_xy_m[0] + col * grid.cell_m, grid.origin_xy_m[1] + row * grid.cell_m])
    hi = lo + grid.cell_m
    t_near = -np.inf
    for a in range(2):
        if abs(u[a]) < 1e-12:
            continue
        t0, t1 = (lo[a] - origin[a]) / u[a], (hi[a] - origin[a]) / u[a]
        t_near = max(t_near, min(t0, t1))
    return float(t_near) if np.isfinite(t_near) and t_near >= 0 else fallback


# ----------------------------------------------------------------------------------- summary
def table_stats(rows: Sequence[DimensionRow]) -> dict[str, float]:
    """Summary statistics of a dimension table (see the module docstring)."""
    stats: dict[str, float] = {}
    measured = [r for r in rows if math.isfinite(r.map_m)]
    if measured:
        diffs = np.abs([r.diff_m for r in measured])
        stats["max_abs_diff_m"] = float(diffs.max())
        stats["mean_abs_diff_m"] = float(diffs.mean())
    truth = {r.name: r for r in measured if r.reference_kind == "truth"}
    for name, row in sorted(truth.items()):
        if len(row.probes) > 1:
            stats[f"probe_std_{name}_m"] = row.probe_std_m
    if "width" in truth and "length" in truth:
        stats["percent_difference"] = percent_difference(
            truth["width"].map_m / truth["length"].map_m, truth["width"].reference_m / truth["length"].reference_m
        )
    return stats


def percent_difference(a: float, b: float) -> float:
    """``100 |a - b| / ((a + b) / 2)``."""
    return float(100.0 * abs(a - b) / ((a + b) / 2.0))
