"""The "Track" section of a moving survey's page: its tracks over DGPS, the error over time, the table.

Everything here is drawn from a :class:`~cistern_archive.core.tracks.TrackComparison` the navigation
layer made; nothing is computed but the start alignment the errors already used. Errors are the
horizontal distance to each DGPS fix (Mallios et al. 2014, Table 2): *start-aligned* (the estimate
translated onto the fix where it starts) and *rigid* (after the best 2-D rotation and translation onto
the fixes after the calibration window, over which the table summarises the errors).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FuncFormatter

from cistern_archive.core.tracks import TrackComparison
from cistern_archive.report.canvas import FigureFile, new_figure
from cistern_archive.report.files import save_figure
from cistern_archive.report.html import number

TRACK_STYLES = (
    {"color": "#999999", "linestyle": "--", "linewidth": 1.2},
    {"color": "#e66101", "linestyle": "-", "linewidth": 1.4},
    {"color": "#2166ac", "linestyle": "-", "linewidth": 1.8},
)
"""Dead reckoning as logged, calibrated dead reckoning, the pipeline (in the order the tracks come)."""
CALIBRATION_COLOUR = "#fee08b"


def _style(k: int) -> dict[str, Any]:
    return TRACK_STYLES[min(k, len(TRACK_STYLES) - 1)]


def span_note(track: TrackComparison) -> str:
    """What part of the run was drawn, and why the published rows may not compare."""
    text = (f"{len(track.time_s)} DGPS fixes over {track.span_s:.0f} s, between the first and the last placed "
            f"revolution ({track.revolutions} revolutions")
    if track.partial:
        return text + (f" of the {track.revolutions_available} usable in the run). Only the start of the run was "
                       "processed, so these errors are not comparable to the published ones, which cover the whole run.")
    return text + ", the whole run)."


def calibration_note(track: TrackComparison) -> str:
    """Which fixes the dead reckoning was calibrated on, and that the table's errors leave them out (they
    are not independent of the estimates)."""
    if track.calibration_end_s is None:
        return ""
    inside = int(np.sum(track.time_s <= track.calibration_end_s))
    if not inside:
        return "No fix of the span lies in the calibration window."
    if inside == len(track.time_s):
        return ("Every fix of the span lies in the DGPS window the dead reckoning was calibrated on (compass offset "
                "and DVL scale): the errors count them all and are not independent of the calibrated tracks.")
    return (f"The first {inside} fixes of the span lie in the DGPS window the dead reckoning was calibrated on "
            "(compass offset and DVL scale); they are not independent of the calibrated tracks, so the errors "
            f"in the table are those at the {len(track.time_s) - inside} fixes after it.")


def tracks_figure(path: Path, track: TrackComparison, *, dpi: int) -> FigureFile:
    """DGPS and every estimate, start-aligned, east/north in metres, equal axes."""
    fixes = track.fixes_xy_m
    span = np.ptp(fixes, axis=0)
    aspect = float(np.clip((span[1] + 1.0) / (span[0] + 1.0), 0.4, 2.0))
    plot_w = 6.0 if aspect < 1 else 6.0 / aspect
    plot_h = plot_w * aspect
    width, height = plot_w + 1.0 + 3.0, plot_h + 0.9
    fig = new_figure(width, height, dpi, left=0.9 / width, right=(0.9 + plot_w) / width, bottom=0.6 / height,
                     top=1 - 0.35 / height)
    ax = fig.add_subplot()
    ax.plot(fixes[:, 0], fixes[:, 1], color="black", linewidth=2.6, label="DGPS", zorder=2)
    for k, estimate in enumerate(track.tracks):
        xy = estimate.start_aligned_xy(fixes)
        ax.plot(xy[:, 0], xy[:, 1], label=f"{estimate.name} (start-aligned)", zorder=3 + k, **_style(k))
        ax.plot(xy[-1, 0], xy[-1, 1], marker="s", markersize=5, color=_style(k)["color"], zorder=3 + k)
    ax.plot(fixes[0, 0], fixes[0, 1], marker="o", markersize=8, color="#1a9641", markeredgecolor="black", zorder=9,
            linestyle="")
    ax.plot(fixes[-1, 0], fixes[-1, 1], marker="s", markersize=7, color="black", zorder=9, linestyle="")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(True, color="#dddddd", linewidth=0.6)
    handles, _ = ax.get_legend_handles_labels()
    handles += [Line2D([], [], marker="o", ls="", mfc="#1a9641", mec="black", ms=8, label="start (all tracks)"),
                Line2D([], [], marker="s", ls="", mfc="black", mec="black", ms=6, label="end of each track")]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    ax.set_title("Tracks over DGPS, start-aligned", fontsize=11)
    save_figure(fig, path, dpi=dpi)
    names = ", ".join(t.name for t in track.tracks)
    caption = ("DGPS fixes (black, good to about 1 m) and each estimated track translated so that it starts on the "
               "first fix of the span (green dot); squares mark where each track ends. " + span_note(track))
    return FigureFile("track", path.name, "Tracks over DGPS", f"Map of the DGPS track with the start-aligned "
                      f"estimates: {names}", caption)


def error_figure(path: Path, track: TrackComparison, *, dpi: int) -> FigureFile:
    """Start-aligned error of every estimate against time, logarithmic, the calibration window shaded."""
    width, height = 9.0, 3.6
    fig = new_figure(width, height, dpi, left=0.8 / width, right=0.68, bottom=0.6 / height, top=1 - 0.35 / height)
    ax = fig.add_subplot()
    t = track.time_s - track.time_s[0]
    handles = []
    if track.calibration_end_s is not None and track.calibration_end_s > track.time_s[0]:
        end = min(track.calibration_end_s, track.time_s[-1]) - track.time_s[0]
        ax.axvspan(0.0, end, color=CALIBRATION_COLOUR, alpha=0.6, linewidth=0, zorder=0)
        handles.append(Patch(color=CALIBRATION_COLOUR, alpha=0.6, label="DGPS calibration window (not in the table)"))
    floor = 0.05
    for k, estimate in enumerate(track.tracks):
        errors = np.maximum(estimate.start_aligned_errors_m, floor)
        line, = ax.plot(t, errors, label=estimate.name, zorder=2 + k, **_style(k))
        handles.insert(k, line)
    ax.set_yscale("log")
    top = max(float(np.max(e.start_aligned_errors_m)) for e in track.tracks)
    ax.set_ylim(floor, max(top * 1.5, 1.0))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.set_xlim(0.0, max(float(t[-1]), 1.0))
    ax.set_xlabel("time since the first fix of the span (s)")
    ax.set_ylabel("start-aligned error (m)")
    ax.grid(True, which="major", color="#dddddd", linewidth=0.6)
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    ax.set_title("Position error against DGPS", fontsize=11)
    save_figure(fig, path, dpi=dpi)
    caption = (f"Distance from each start-aligned track to the DGPS fix at the same time, logarithmic scale "
               f"(errors below {floor:g} m, such as the zero at the first fix, drawn at {floor:g} m). "
               + calibration_note(track))
    return FigureFile("track-error", path.name, "Position error over time",
                      "Start-aligned position error of each track against time", caption.strip())


def track_figures(site_dir: Path, track: TrackComparison, *, dpi: int) -> list[FigureFile]:
    """Both figures of the section, written into ``site_dir``."""
    return [tracks_figure(site_dir / "track.png", track, dpi=dpi), error_figure(site_dir / "track_error.png", track, dpi=dpi)]


def _cells(stats) -> list[str]:
    return [number(stats.mean_m, 2), number(stats.sd_m, 2), number(stats.max_m, 2)]


def track_context(track: TrackComparison) -> dict[str, Any]:
    """The table rows (this build's tracks, then the published ones) and the notes, as strings."""
    rows = [{"name": t.name, "start": _cells(t.start_aligned), "rigid": _cells(t.rigid),
             "fixes": str(t.start_aligned.fixes), "published": False} for t in track.tracks]
    rows += [{"name": r.method, "start": [number(r.mean_m, 2), number(r.sd_m, 2), number(r.max_m, 2)],
              "rigid": ["", "", ""], "fixes": "", "published": True} for r in track.published]
    return {"rows": rows, "source": track.published_source, "span": span_note(track),
            "calibration": calibration_note(track), "partial": track.partial,
            "clock_offset": f"{track.clock_offset_s:+.2f} s"}
