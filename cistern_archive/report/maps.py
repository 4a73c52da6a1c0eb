"""The report's map figures, drawn over the evidence grid (occupancy probability, black occupied,
white free, grey unknown; matplotlib's ``gray_r``):

* the map with the scan stations and the pair links (converged or not, line width by weight);
* the depth slices as small multiples;
* the probe lines of each measured dimension over the grid (the paper's 10 probes, Sec. IV);
* the index thumbnail.

Every function writes one PNG with :func:`cistern_archive.report.files.save_figure` (no metadata).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib import patheffects
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from cistern_archive.core.dimensions import DimensionRow, DimensionTable
from cistern_archive.core.grids import EvidenceGrid
from cistern_archive.core.matches import MatchResult
from cistern_archive.core.poses import Poses
from cistern_archive.report.canvas import LINK_BAD, LINK_FIT, LINK_OK, FigureFile, new_figure
from cistern_archive.report.files import save_figure

GRID_CMAP = "gray_r"
MANY_STATIONS = 50
"""Above this many placed stations the map draws them as small dots."""
LABEL_HALO = [patheffects.withStroke(linewidth=2.5, foreground="white")]
"""A white outline around the station labels, so that they read over walls, links and markers."""
STATION_SPAN_M = 0.2
"""Placed stations spread over this much depth or more: the map's title and caption name their depths."""
DIMENSION_COLOURS = ("#e66101", "#5e3c99", "#1a9641", "#d7191c", "#2b83ba", "#a6611a")


def choose_slice(grids: Sequence[EvidenceGrid], depth_m: float | None) -> EvidenceGrid:
    """The slice nearest ``depth_m`` (the first when it is ``None``)."""
    if depth_m is None:
        return grids[0]
    return min(grids, key=lambda g: (abs(g.depth_m - depth_m), g.depth_m))


def _draw_grid(ax, grid: EvidenceGrid) -> None:
    ax.imshow(grid.probability(), cmap=GRID_CMAP, vmin=0.0, vmax=1.0, origin="lower", extent=grid.extent_m,
              interpolation="nearest")
    ax.set_xlabel("x, east (m)")
    ax.set_ylabel("y, north (m)")
    ax.set_aspect("equal")


def _map_canvas(grid: EvidenceGrid | None, dpi: int) -> Figure:
    """A figure whose plot area has the grid's aspect ratio, with room on the right for the legend."""
    aspect = 1.0
    if grid is not None:
        x0, x1, y0, y1 = grid.extent_m
        aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    plot_h = 5.0 if aspect >= 0.6 else 3.2
    plot_w = float(np.clip(plot_h / aspect, 2.5, 7.5))
    width, height = plot_w + 0.9 + 2.3, plot_h + 0.9
    return new_figure(width, height, dpi, left=0.9 / width, right=(0.9 + plot_w) / width, bottom=0.55 / height,
                   top=1 - 0.35 / height)


def map_figure(
    path: Path,
    grid: EvidenceGrid | None,
    poses: Poses | None,
    matches: Sequence[MatchResult],
    labels: Sequence[str],
    *,
    dpi: int,
    label_every: int = 1,
    station_depths_m: Sequence[float] = (),
) -> FigureFile:
    """The evidence grid with stations and pair links; every ``label_every``-th placed station (and the
    last) is labelled (a survey's hundreds of revolutions would bury the map under their labels).
    ``station_depths_m`` (one per scan): where the placed stations lie over a range of depths, the
    title and caption say which (the slice drawn is at one depth, the stations drawn are all of them).

    Links join placed stations: solid green for converged matches, dashed magenta for the others, the
    width growing with the match weight (relative to the largest weight of the site); dotted blue for
    the joins of groups of scans fitted as wholes (:attr:`Poses.group_links`).
    """
    fig = _map_canvas(grid, dpi)
    ax = fig.add_subplot()
    if grid is not None:
        _draw_grid(ax, grid)
    else:
        ax.set_xlabel("x, east (m)")
        ax.set_ylabel("y, north (m)")
        ax.set_aspect("equal")
    placed = [] if poses is None else [k for k in range(len(poses.placed)) if poses.placed[k]]
    if poses is not None and matches:
        weights = np.array([m.weight for m in matches], dtype=float)
        scale = float(np.nanmax(np.abs(weights))) if np.isfinite(weights).any() else 1.0
        for m in sorted(matches, key=lambda m: (m.converged, m.i, m.j)):
            if not (0 <= m.i < len(poses.placed) and 0 <= m.j < len(poses.placed)):
                continue
            if not (poses.placed[m.i] and poses.placed[m.j]):
                continue
            a, b = poses.xy_m[m.i], poses.xy_m[m.j]
            width = 0.8 + 3.0 * (abs(m.weight) / scale if scale > 0 and math.isfinite(m.weight) else 0.0)
            ax.plot([a[0], b[0]], [a[1], b[1]], color=LINK_OK if m.converged else LINK_BAD,
                    linestyle="-" if m.converged else "--", linewidth=width, alpha=0.85, zorder=2)
    fitted = [] if poses is None else [(i, j) for i, j in poses.group_links
                                       if 0 <= i < len(poses.placed) and 0 <= j < len(poses.placed)]
    for i, j in fitted:
        a, b = poses.xy_m[i], poses.xy_m[j]
        ax.plot([a[0], b[0]], [a[1], b[1]], color=LINK_FIT, linestyle=":", linewidth=3.0, zorder=2.5)
    if poses is not None and placed:
        xy = poses.xy_m[placed]
        ref = poses.reference
        dense = len(placed) > MANY_STATIONS  # a survey's revolutions: small dots that leave the walls visible
        ax.scatter(xy[:, 0], xy[:, 1], s=10 if dense else 60, c="#2166ac", edgecolors="white",
                   linewidths=0.3 if dense else 1.0, zorder=3)
        if 0 <= ref < len(poses.placed) and poses.placed[ref]:
            ax.scatter([poses.xy_m[ref, 0]], [poses.xy_m[ref, 1]], s=140, marker="*", c="#ffd92f",
                       edgecolors="black", linewidths=0.8, zorder=4)
        x0, x1 = ax.get_xlim() if grid is None else grid.extent_m[:2]
        named = [k for q, k in enumerate(placed) if q % label_every == 0 or q == len(placed) - 1]
        for xy_k, text in stacked_labels(poses.xy_m[named], [labels[k] for k in named],
                                         tolerance_m=0.015 * max(abs(x1 - x0), 1.0)):
            ax.annotate(text, xy_k, xytext=(8, 6), textcoords="offset points", fontsize=9,
                        color="#08306b", fontweight="bold", zorder=5, path_effects=LABEL_HALO)
    handles = [Line2D([], [], color=LINK_OK, lw=2.5, label="converged match"),
               Line2D([], [], color=LINK_BAD, lw=1.5, ls="--", label="not converged"),
               *([Line2D([], [], color=LINK_FIT, lw=2.5, ls=":", label="groups fitted as wholes")] if fitted else []),
               Line2D([], [], marker="o", ls="", mfc="#2166ac", mec="white", ms=8, label="scan station"),
               Line2D([], [], marker="*", ls="", mfc="#ffd92f", mec="black", ms=12, label="reference scan")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    depth = ("" if grid is None else f" at depth {grid.depth_m:.2f} m") + station_span(station_depths_m, placed)
    ax.set_title(f"Evidence grid{depth}", fontsize=11)
    save_figure(fig, path, dpi=dpi)
    unplaced = [labels[k] for k in range(len(labels)) if poses is None or not poses.placed[k]]
    caption = (
        f"Occupancy probability (black occupied, white free, grey unknown){depth}; "
        f"{len(placed)} of {len(labels)} scans placed"
        + (f" (not placed: {', '.join(unplaced)})" if unplaced else "")
        + "; lines are pair matches, solid when converged, wider for larger weights"
        + ("; dotted lines join groups of scans that no match could join, placed by fitting each group's walls "
           f"and water to the other's (less precise along a tunnel both groups see end to end: {join_precision(poses, labels)})"
           if fitted else "")
        + "."
    )
    return FigureFile("map", path.name, "Map with scan stations and pair links",
                      f"Top-down evidence grid map{depth} with {len(placed)} scan stations and "
                      f"{len(matches)} pair-match links", caption)


def station_span(depths_m: Sequence[float], placed: Sequence[int]) -> str:
    """`` (stations at 1.45–2.60 m)`` where the placed stations' depths span ``STATION_SPAN_M`` or more,
    else nothing."""
    depths = [depths_m[k] for k in placed if k < len(depths_m) and math.isfinite(depths_m[k])]
    if not depths or max(depths) - min(depths) < STATION_SPAN_M:
        return ""
    return f" (stations at {min(depths):.2f}–{max(depths):.2f} m)"


def join_precision(poses: Poses, labels: Sequence[str]) -> str:
    """Each group link as ``o1–b1 to ±0.66 m (95 %)``: the radius holding its two stations' relative
    position with 95 % probability."""
    radii = list(poses.group_link_radius95_m) + [math.nan] * len(poses.group_links)
    return ", ".join(f"{labels[i]}–{labels[j]}" + (f" to ±{radius:.2f} m (95 %)" if math.isfinite(radius) else "")
                     for (i, j), radius in zip(poses.group_links, radii))


def stacked_labels(xy: np.ndarray, labels: Sequence[str], *, tolerance_m: float) -> list[tuple[np.ndarray, str]]:
    """One label per place: stations closer than ``tolerance_m`` to an earlier one (scans taken above
    one another at several depths) share its label, ``d1a / d2a / d3a``, instead of overprinting it."""
    groups: list[tuple[np.ndarray, list[str]]] = []
    for point, label in zip(np.asarray(xy, dtype=float), labels):
        for anchor, names in groups:
            if float(np.hypot(*(point - anchor))) <= tolerance_m:
                names.append(label)
                break
        else:
            groups.append((point, [label]))
    return [(anchor, " / ".join(names)) for anchor, names in groups]


def probe_groups(rows: Sequence[DimensionRow]) -> list[tuple[list[DimensionRow], str]]:
    """The measured rows grouped by their probe lines (a dimension with a truth and a mosaic reference is
    one set of probes), each group with its legend label, in table order."""
    groups: dict[tuple, list[DimensionRow]] = {}
    for row in rows:
        if row.probe_lines:
            key = (row.depth_m, tuple(tuple(round(v, 4) for v in line) for line in row.probe_lines))
            groups.setdefault(key, []).append(row)
    labelled = []
    for members in groups.values():
        names = list(dict.fromkeys(r.name for r in members))
        kinds = ", ".join(r.reference_kind for r in members)
        labelled.append((members, f"{' / '.join(names)} ({kinds}): {members[0].map_m:.2f} m"))
    return labelled


def probe_figure(path: Path, grids: Sequence[EvidenceGrid], table: DimensionTable, *, dpi: int) -> FigureFile:
    """The probe lines of every dimension over the grid slice it was measured in (a dimension measured
    against a truth and a mosaic reference is drawn once, with both in its label)."""
    rows = [r for r in table.rows if r.probe_lines]
    depths = sorted({choose_slice(grids, r.depth_m).depth_m for r in rows}) or [grids[0].depth_m]
    if len(depths) == 1:
        fig = _map_canvas(choose_slice(grids, depths[0]), dpi)
    else:
        width = 4.6 * len(depths) + 2.6
        fig = new_figure(width, 5.8, dpi, left=0.8 / width, right=1 - 2.5 / width, bottom=0.09, top=0.93, wspace=0.3)
    axes = np.atleast_1d(fig.subplots(1, len(depths)))
    groups = probe_groups(rows)
    for ax, depth in zip(axes, depths):
        grid = choose_slice(grids, depth)
        _draw_grid(ax, grid)
        ax.set_title(f"Probes at depth {grid.depth_m:.2f} m", fontsize=10)
        for k, (members, _) in enumerate(groups):
            if choose_slice(grids, members[0].depth_m).depth_m != depth:
                continue
            colour = DIMENSION_COLOURS[k % len(DIMENSION_COLOURS)]
            for x0, y0, x1, y1 in members[0].probe_lines:
                ax.plot([x0, x1], [y0, y1], color=colour, lw=1.2, alpha=0.9)
                ax.plot([x0, x1], [y0, y1], "|" if abs(y1 - y0) < abs(x1 - x0) else "_", color=colour, ms=6)
    handles = [Line2D([], [], color=DIMENSION_COLOURS[k % len(DIMENSION_COLOURS)], lw=2, label=label)
               for k, (_, label) in enumerate(groups)]
    if handles:
        axes[-1].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    save_figure(fig, path, dpi=dpi)
    names = ", ".join(f"{r.name} ({len(r.probe_lines)})" for r in rows)
    return FigureFile("probes", path.name, "Probe lines of the measured dimensions",
                      f"Evidence grid with the probe lines used to measure {names or 'no dimension'}",
                      "Each line runs between the inner faces of two walls; a dimension's map value is the "
                      "mean of its probes (see the dimension table).")


def slices_figure(path: Path, grids: Sequence[EvidenceGrid], *, dpi: int) -> FigureFile:
    """Small multiples of every depth slice on a common extent."""
    n = len(grids)
    cols = min(n, 4)
    rows = math.ceil(n / cols)
    fig = new_figure(3.2 * cols, 3.6 * rows, dpi, left=0.12, right=0.97, bottom=0.16, top=0.9, wspace=0.45,
                  hspace=0.35)
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    xmin = min(g.extent_m[0] for g in grids)
    xmax = max(g.extent_m[1] for g in grids)
    ymin = min(g.extent_m[2] for g in grids)
    ymax = max(g.extent_m[3] for g in grids)
    for ax, grid in zip(axes, grids):
        _draw_grid(ax, grid)
        ax.set_xlim(xmin, xmax)
        ax.set_ylim(ymin, ymax)
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(f"depth {grid.depth_m:.2f} m", fontsize=9)
    for ax in axes[n:]:
        ax.set_axis_off()
    save_figure(fig, path, dpi=dpi)
    return FigureFile("slices", path.name, "Depth slices",
                      f"{n} evidence-grid slices from {grids[0].depth_m:.2f} m to {grids[-1].depth_m:.2f} m depth",
                      "The slices the 3D model interpolates between, shallowest first.")


def thumbnail(path: Path, grid: EvidenceGrid, poses: Poses | None, *, width_px: int) -> Path:
    """A small map for the catalog index (grid and stations, no axes)."""
    x0, x1, y0, y1 = grid.extent_m
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    width_in = width_px / 100
    height_in = float(np.clip(width_in * aspect, width_in * 0.5, width_in * 1.5))
    fig = Figure(figsize=(width_in, height_in), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.imshow(grid.probability(), cmap=GRID_CMAP, vmin=0, vmax=1, origin="lower", extent=grid.extent_m,
              interpolation="nearest")
    if poses is not None and poses.placed.any():
        xy = poses.xy_m[poses.placed]
        ax.scatter(xy[:, 0], xy[:, 1], s=36, c="#2166ac", edgecolors="white", linewidths=0.8)
    ax.set_aspect("equal")
    ax.set_axis_off()
    fig.set_facecolor("white")
    save_figure(fig, path, dpi=100, tight=False)
    return path
