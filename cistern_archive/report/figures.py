"""The report's figures, drawn with matplotlib's Agg canvas (no display, no pyplot state).

* the evidence grid with the scan stations and the pair links (converged or not, line width by weight);
* per pair, the particle filter's convergence (the exponential weight and std averages of eqs. 5–6
  over the iterations) and its particles over the reference map, like the paper's Fig. 6 (the
  reference station in yellow, particles green to white as their weight grows);
* raw and segmented scan fans (:func:`cistern_archive.sonar.fan.fan_png`);
* the probe lines of each measured dimension over the grid (the paper's 10 probes, Sec. IV);
* the index thumbnail and a one-pixel-per-cell PNG of every slice.

Every function writes one PNG with :func:`cistern_archive.report.files.save_figure` (no metadata) and
returns a :class:`FigureFile` with the title, alt text and caption the page shows.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib import rcParams
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import LinearSegmentedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from cistern_archive.pipeline.contracts import DimensionTable, EvidenceGrid, HistoryThreshold, MatchResult, Poses
from cistern_archive.report.files import save_figure, write_png
from cistern_archive.core.scan import RangeScan, Scan

rcParams["svg.hashsalt"] = "cistern-archive"

PARTICLES = LinearSegmentedColormap.from_list("particles", ["#0b6623", "#3cb043", "#ffffff"])
GRID_CMAP = "gray_r"
LINK_OK, LINK_BAD = "#1b7837", "#c51b7d"
DIMENSION_COLOURS = ("#e66101", "#5e3c99", "#1a9641", "#d7191c", "#2b83ba", "#a6611a")


@dataclass(frozen=True)
class FigureFile:
    """A figure written beside the page."""

    key: str
    file: str
    title: str
    alt: str
    caption: str = ""


def _figure(width_in: float, height_in: float, dpi: int, **margins: float) -> Figure:
    """A figure on its own Agg canvas with fixed margins (fractions of the figure; a constraint
    solver would cost more than the drawing)."""
    figure = Figure(figsize=(width_in, height_in), dpi=dpi)
    FigureCanvasAgg(figure)
    figure.subplots_adjust(**{"left": 0.1, "right": 0.95, "bottom": 0.1, "top": 0.92, **margins})
    return figure


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
    return _figure(width, height, dpi, left=0.9 / width, right=(0.9 + plot_w) / width, bottom=0.55 / height,
                   top=1 - 0.35 / height)


def map_figure(
    path: Path,
    grid: EvidenceGrid | None,
    poses: Poses | None,
    matches: Sequence[MatchResult],
    labels: Sequence[str],
    *,
    dpi: int,
) -> FigureFile:
    """The evidence grid with stations and pair links.

    Links join placed stations: solid green for converged matches, dashed magenta for the others, the
    width growing with the match weight (relative to the largest weight of the site).
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
    if poses is not None and placed:
        xy = poses.xy_m[placed]
        ref = poses.reference
        ax.scatter(xy[:, 0], xy[:, 1], s=60, c="#2166ac", edgecolors="white", linewidths=1.0, zorder=3)
        if 0 <= ref < len(poses.placed) and poses.placed[ref]:
            ax.scatter([poses.xy_m[ref, 0]], [poses.xy_m[ref, 1]], s=140, marker="*", c="#ffd92f",
                       edgecolors="black", linewidths=0.8, zorder=4)
        x0, x1 = ax.get_xlim() if grid is None else grid.extent_m[:2]
        for xy_k, text in stacked_labels(poses.xy_m[placed], [labels[k] for k in placed],
                                         tolerance_m=0.015 * max(abs(x1 - x0), 1.0)):
            ax.annotate(text, xy_k, xytext=(6, 6), textcoords="offset points", fontsize=9,
                        color="#08306b", fontweight="bold", zorder=5)
    handles = [Line2D([], [], color=LINK_OK, lw=2.5, label="converged match"),
               Line2D([], [], color=LINK_BAD, lw=1.5, ls="--", label="not converged"),
               Line2D([], [], marker="o", ls="", mfc="#2166ac", mec="white", ms=8, label="scan station"),
               Line2D([], [], marker="*", ls="", mfc="#ffd92f", mec="black", ms=12, label="reference scan")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    depth = "" if grid is None else f" at depth {grid.depth_m:.2f} m"
    ax.set_title(f"Evidence grid{depth}", fontsize=11)
    save_figure(fig, path, dpi=dpi)
    unplaced = [labels[k] for k in range(len(labels)) if poses is None or not poses.placed[k]]
    caption = (
        f"Occupancy probability (black occupied, white free, grey unknown){depth}; "
        f"{len(placed)} of {len(labels)} scans placed"
        + (f" (not placed: {', '.join(unplaced)})" if unplaced else "")
        + "; lines are pair matches, solid when converged, wider for larger weights."
    )
    return FigureFile("map", path.name, "Map with scan stations and pair links",
                      f"Top-down evidence grid map{depth} with {len(placed)} scan stations and "
                      f"{len(matches)} pair-match links", caption)


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


def history_thresholds(matches: Sequence[MatchResult]) -> tuple[list[HistoryThreshold], list[HistoryThreshold]]:
    """The distinct weight and spread thresholds the matches' histories carry (in order of first use):
    the matcher says which lines its iteration is judged by, the report only draws them."""
    weight: list[HistoryThreshold] = []
    spread: list[HistoryThreshold] = []
    for match in matches:
        hist = match.history
        if hist is None:
            continue
        for line, seen in ((hist.weight_threshold, weight), (hist.std_threshold, spread)):
            if line is not None and line not in seen:
                seen.append(line)
    return weight, spread


def _must(lines: Sequence[HistoryThreshold], side: str) -> str:
    """", which must end above τ_pw" for the thresholds drawn, or nothing without one."""
    return f", which must end {side} {' or '.join(line.label for line in lines)}" if lines else ""


def _threshold_lines(ax, lines: Sequence[HistoryThreshold]) -> None:
    for line in lines:
        ax.axhline(line.value, color="black", ls=":", lw=1.0)
        ax.annotate(line.label, (0.01, line.value), xycoords=("axes fraction", "data"), xytext=(2, 2),
                    textcoords="offset points", fontsize=8)


def _pair_title(ax, match: MatchResult, labels: Sequence[str]) -> None:
    name_i, name_j = labels[match.i], labels[match.j]
    suffix = "" if match.converged else " (not converged)"
    ax.set_title(f"{name_j} in {name_i}{suffix}", fontsize=8, color=LINK_OK if match.converged else LINK_BAD)


def _grid_axes(n: int, dpi: int, *, cols: int = 4, panel_in: float = 2.5):
    rows = max(1, math.ceil(n / cols))
    width, height = cols * panel_in + 0.6, rows * (panel_in * 0.92) + 0.3
    fig = _figure(width, height, dpi, left=0.5 / width, right=1 - 0.35 / width, bottom=0.35 / height,
                  top=1 - 0.3 / height, wspace=0.55, hspace=0.5)
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    for ax in axes[n:]:
        ax.set_axis_off()
    return fig, axes[:n]


def convergence_figure(
    path: Path, matches: Sequence[MatchResult], labels: Sequence[str], *, dpi: int
) -> Figure:
    """The weight average of eq. 6 (left) and the position-std average of eq. 5 (right) of every pair
    over the iterations, one line per pair: converged pairs in green, the others dashed magenta and
    named at their last iteration; the thresholds the histories carry (e.g. τ_pw and r_c of eqs. 5–6)
    dotted."""
    weight_lines, spread_lines = history_thresholds(matches)
    fig = _figure(10.0, 3.8, dpi, left=0.07, right=0.98, bottom=0.14, top=0.9, wspace=0.22)
    left, right = fig.subplots(1, 2)
    name_failures = sum(1 for m in matches if not m.converged) <= 8
    for match in sorted(matches, key=lambda m: (m.converged, m.i, m.j), reverse=True):
        hist = match.history
        if hist is None or not len(hist.weight_avg):
            continue
        it = np.arange(1, len(hist.weight_avg) + 1)
        style = dict(color=LINK_OK, lw=1.0, alpha=0.6) if match.converged else dict(color=LINK_BAD, lw=1.4, ls="--")
        left.plot(it, hist.weight_avg, **style)
        right.plot(it, hist.std_avg, **style)
        if not match.converged and name_failures:
            name = f"{labels[match.j]} in {labels[match.i]}"
            left.annotate(name, (it[-1], hist.weight_avg[-1]), xytext=(3, 0), textcoords="offset points",
                          fontsize=7, color=LINK_BAD, va="center")
    _threshold_lines(left, weight_lines)
    _threshold_lines(right, spread_lines)
    right.set_yscale("log")
    left.set_title("Weight average (eq. 6)", fontsize=10)
    right.set_title("Position std average (eq. 5), metres", fontsize=10)
    for ax in (left, right):
        ax.set_xlabel("iteration")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    left.legend(handles=[Line2D([], [], color=LINK_OK, lw=1.5, label="converged"),
                         Line2D([], [], color=LINK_BAD, lw=1.5, ls="--", label="not converged")],
                fontsize=8, loc="lower right")
    save_figure(fig, path, dpi=dpi)
    return fig


def _scale_bar(ax, span_m: float, colour: str = "white") -> None:
    """A round-length bar in the lower-left corner of a panel without tick labels."""
    from cistern_archive.report.model3d import nice_length

    length = nice_length(span_m)
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    x, y = x0 + 0.06 * (x1 - x0), y0 + 0.07 * (y1 - y0)
    ax.plot([x, x + length], [y, y], color=colour, lw=2)
    ax.text(x + length / 2, y + 0.03 * (y1 - y0), f"{length:g} m", color=colour, fontsize=6.5, ha="center",
            va="bottom")


def particles_montage(
    path: Path,
    matches: Sequence[MatchResult],
    references: Sequence[RangeScan | None],
    labels: Sequence[str],
    *,
    truths: Sequence[tuple[float, float] | None],
    dpi: int,
) -> Figure:
    """One small panel per pair, like the paper's Fig. 6: in the reference station's frame (compass
    aligned), the reference echoes (grey), the reference station (yellow star), the particle snapshots
    from the first (faint) to the last (green to white by weight), the estimate (red cross) and, for
    simulated sites, the true position (cyan ring)."""
    fig, axes = _grid_axes(len(matches), dpi)
    for ax, match, reference, truth in zip(axes, matches, references, truths):
        _pair_title(ax, match, labels)
        ax.set_facecolor("#111111")
        ax.set_xticks([])
        ax.set_yticks([])
        reach = 1.0
        if reference is not None:
            pts = reference.points()
            ax.plot(pts[:, 0], pts[:, 1], ".", ms=1.2, color="#9e9e9e")
            if len(pts):
                reach = max(reach, float(np.max(np.abs(pts))))
        snaps = match.history.snapshots if match.history is not None else ()
        for k, snap in enumerate(snaps):
            snap = np.asarray(snap)
            if snap.size == 0:
                continue
            order = np.argsort(snap[:, 3], kind="stable")
            ax.scatter(snap[order, 0], snap[order, 1], c=snap[order, 3], cmap=PARTICLES, s=3,
                       alpha=0.25 + 0.75 * (k + 1) / len(snaps), linewidths=0, zorder=2)
        ax.scatter([0], [0], marker="*", s=70, c="#ffd92f", edgecolors="black", linewidths=0.5, zorder=4)
        if truth is not None:
            reach = max(reach, abs(truth[0]) + 0.5, abs(truth[1]) + 0.5)
            ax.scatter([truth[0]], [truth[1]], s=40, facecolors="none", edgecolors="#00e5ff", lw=1.2, zorder=4)
        if math.isfinite(match.dx_m) and math.isfinite(match.dy_m):
            ax.scatter([match.dx_m], [match.dy_m], marker="x", s=36, c="#ff1744", lw=1.5, zorder=5)
            reach = max(reach, abs(match.dx_m) + 0.5, abs(match.dy_m) + 0.5)
        reach *= 1.1
        ax.set_xlim(-reach, reach)
        ax.set_ylim(-reach, reach)
        ax.set_aspect("equal")
        _scale_bar(ax, 2 * reach)
    save_figure(fig, path, dpi=dpi)
    return fig


def pair_figures(
    out_dir: Path,
    matches: Sequence[MatchResult],
    references: Sequence[RangeScan | None],
    labels: Sequence[str],
    *,
    truths: Sequence[tuple[float, float] | None],
    per_figure: int,
    dpi: int,
) -> list[tuple[FigureFile, list[int]]]:
    """The convergence of every pair in one figure, and particle montages of ``per_figure`` pairs each.

    Returns
    -------
    list of (FigureFile, list of int)
        Each figure and the positions in ``matches`` of the pairs it shows.
    """
    if not matches:
        return []
    out: list[tuple[FigureFile, list[int]]] = []
    conv = out_dir / "pairs-convergence.png"
    convergence_figure(conv, matches, labels, dpi=dpi)
    weight, spread = history_thresholds(matches)
    failed = [f"{labels[m.j]} in {labels[m.i]}" for m in matches if not m.converged]
    out.append((FigureFile(
        "pairs-convergence", conv.name, "Convergence of the pair matches",
        f"Line charts of the particle filter's weight average and position spread over the iterations for "
        f"{len(matches)} pairs; {len(failed)} did not converge",
        f"One line per pair. Left: exponential average of the particle weights (eq. 6){_must(weight, 'above')}; "
        f"right: exponential average of the particles' position spread (eq. 5, log scale){_must(spread, 'below')}. "
        "Green: converged; dashed magenta: not converged, named 'moving in reference'"
        + (f" ({', '.join(failed)})" if failed else "") + ". The pair table gives each pair's numbers."),
        list(range(len(matches)))))
    n_parts = math.ceil(len(matches) / per_figure)
    for start in range(0, len(matches), per_figure):
        chunk = list(range(start, min(start + per_figure, len(matches))))
        part = start // per_figure + 1
        suffix = f" ({part} of {n_parts})" if n_parts > 1 else ""
        names = ", ".join(f"{labels[matches[k].j]} in {labels[matches[k].i]}" for k in chunk)
        parts = out_dir / f"pairs-particles-{part}.png"
        particles_montage(parts, [matches[k] for k in chunk], [references[k] for k in chunk], labels,
                          truths=[truths[k] for k in chunk], dpi=dpi)
        out.append((FigureFile(
            f"pairs-particles-{part}", parts.name, f"Particles of the pair matches{suffix}",
            f"Small multiples, one per pair ({names}): particles of the moving station over the reference "
            "station's echoes",
            "Like Fig. 6 of the paper, each panel is in the reference station's frame, north up, with its own "
            "scale bar: grey, the reference scan's echoes (its map m_i); yellow star, the reference station; "
            "dots, the moving station's particles from early (faint) to last, green to white as their weight "
            "grows; red cross, the estimate; cyan ring, the true position when the site is simulated. "
            "Magenta titles did not converge."), chunk))
    return out


def fan_montage(
    path: Path, scans: Sequence[Scan], ranged: Sequence[RangeScan | None], *, dpi: int, pixels: int = 260
) -> FigureFile:
    """One panel per scan: the raw intensities as a fan (sonar frame, forward up, like the head's own
    display; :func:`cistern_archive.sonar.fan.polar_to_cartesian`) with the segmented wall echoes of
    Sec. III-B over it (cyan dots)."""
    from cistern_archive.sonar.fan import polar_to_cartesian

    fig, axes = _grid_axes(len(scans), dpi)
    for ax, scan, ranges in zip(axes, scans, ranged):
        image, extent = polar_to_cartesian(scan.bearings_rad, scan.normalised(), scan.bin_size_m,
                                           scan.start_range_m, pixels=pixels)
        ax.set_facecolor("#101010")
        ax.imshow(image, cmap="inferno", vmin=0, vmax=1, extent=(-extent, extent, -extent, extent),
                  interpolation="nearest")
        if ranges is not None and ranges.valid.any():
            pts = ranges.points(yaw_rad=0.0)
            ax.plot(-pts[:, 1], pts[:, 0], ".", ms=1.0, color="#4fc3f7")
        ax.plot([0], [0], "+", color="white", ms=6)
        reach = extent
        if ranges is not None and ranges.valid.any():
            reach = min(extent, 1.25 * float(np.nanmax(ranges.ranges_m)) + 0.5)
        ax.set_xlim(-reach, reach)
        ax.set_ylim(-reach, reach)
        ax.set_title(scan.station or "scan", fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_aspect("equal")
        _scale_bar(ax, 2 * reach)
    save_figure(fig, path, dpi=dpi)
    names = ", ".join(s.station or "scan" for s in scans)
    beams = sorted({s.n_beams for s in scans})
    return FigureFile(
        "fans", path.name, "Raw scans with their segmented echoes",
        f"Sonar fans of the scans {names}: raw echo intensity with the segmented wall echoes as dots",
        "Each fan is one stationary 360° scan in the sonar's own frame, forward up, centred on the head "
        "(white cross), cropped to the farthest echo; the bar gives the scale. Colour is the raw echo intensity (dark weak, yellow strong); cyan dots are "
        f"the wall ranges the beam segmentation kept ({'/'.join(str(b) for b in beams)} beams per scan).")


def probe_figure(path: Path, grids: Sequence[EvidenceGrid], table: DimensionTable, *, dpi: int) -> FigureFile:
    """The probe lines of every dimension over the grid slice it was measured in."""
    rows = [r for r in table.rows if r.probe_lines]
    depths = sorted({choose_slice(grids, r.depth_m).depth_m for r in rows}) or [grids[0].depth_m]
    if len(depths) == 1:
        fig = _map_canvas(choose_slice(grids, depths[0]), dpi)
    else:
        width = 4.6 * len(depths) + 2.6
        fig = _figure(width, 5.8, dpi, left=0.8 / width, right=1 - 2.5 / width, bottom=0.09, top=0.93, wspace=0.3)
    axes = np.atleast_1d(fig.subplots(1, len(depths)))
    handles = []
    for ax, depth in zip(axes, depths):
        grid = choose_slice(grids, depth)
        _draw_grid(ax, grid)
        ax.set_title(f"Probes at depth {grid.depth_m:.2f} m", fontsize=10)
        for k, row in enumerate(table.rows):
            if not row.probe_lines or choose_slice(grids, row.depth_m).depth_m != depth:
                continue
            colour = DIMENSION_COLOURS[k % len(DIMENSION_COLOURS)]
            for x0, y0, x1, y1 in row.probe_lines:
                ax.plot([x0, x1], [y0, y1], color=colour, lw=1.2, alpha=0.9)
                ax.plot([x0, x1], [y0, y1], "|" if abs(y1 - y0) < abs(x1 - x0) else "_", color=colour, ms=6)
    for k, row in enumerate(table.rows):
        if row.probe_lines:
            handles.append(Line2D([], [], color=DIMENSION_COLOURS[k % len(DIMENSION_COLOURS)], lw=2,
                                  label=f"{row.name} ({row.reference_kind}): {row.map_m:.2f} m"))
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
    fig = _figure(3.2 * cols, 3.6 * rows, dpi, left=0.12, right=0.97, bottom=0.16, top=0.9, wspace=0.45,
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


def grid_png(path: Path, grid: EvidenceGrid) -> Path:
    """One pixel per cell, north up, black occupied, white free, grey unknown."""
    prob = grid.probability()
    image = np.round(255 * (1.0 - prob[::-1])).astype(np.uint8)
    return write_png(path, image)


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
