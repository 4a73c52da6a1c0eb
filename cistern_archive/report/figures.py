"""The report's pair and scan figures, drawn with matplotlib's Agg canvas (no display, no pyplot state).

* per pair, the particle filter's convergence (the exponential weight and std averages of eqs. 5–6
  over the iterations) and its particles over the reference map, like the paper's Fig. 6 (the
  reference station in yellow, particles green to white as their weight grows);
* raw and segmented scan fans (:func:`cistern_archive.sonar.fan.polar_to_cartesian`).

The figures drawn over the evidence grid are in :mod:`cistern_archive.report.maps`. Every function
writes one PNG with :func:`cistern_archive.report.files.save_figure` (no metadata); the page records it
as a :class:`~cistern_archive.report.canvas.FigureFile` with the title, alt text and caption it shows.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.colors import LinearSegmentedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from cistern_archive.core.matches import HistoryThreshold, MatchResult
from cistern_archive.core.scan import RangeScan, Scan
from cistern_archive.report.canvas import LINK_BAD, LINK_OK, FigureFile
from cistern_archive.report.canvas import new_figure as _figure
from cistern_archive.report.files import save_figure

PARTICLES = LinearSegmentedColormap.from_list("particles", ["#0b6623", "#3cb043", "#ffffff"])


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
            "grows; red cross, the estimate (lengthened by the two scans' echo scale where the scan table "
            "gives one, so it lies beyond the particles' last place); cyan ring, the true position when the "
            "site is simulated. "
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


