"""The catalog index: every site with its thumbnail, status (and why it is not ok), scans placed and last
build, and one table across sites with a row per site and dimension, the map against the tape-measured
truth and the mosaic (after the paper's Table IV), with the catalog's summary figures."""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from cistern_archive import __version__
from cistern_archive.core.dimensions import HEADING_TURN_DEG
from cistern_archive.pipeline.results import DimensionResult, SiteResult, TrackSummary
from cistern_archive.pipeline.status import MAX_HEADING_SHIFT_M, MAX_JOIN_CI95_M, MAX_PROBE_STD_M, MAX_WALL_LEAN_DEG
from cistern_archive.report.config import ReportConfig
from cistern_archive.report.files import build_time_from_env, format_time
from cistern_archive.report.html import STATUS_TEXT, number, probe_count, render_index_page, signed, with_interval

Status = Literal["ok", "partial", "failed", "skipped"]


@dataclass(frozen=True)
class IndexEntry:
    """One row of the catalog index.

    Attributes
    ----------
    site_id, name : str
    status : {"ok", "partial", "failed", "skipped"}
    scans_placed, scans_total : int
    build_time : str
        ISO 8601 UTC of the site's last build, or empty when unknown.
    error : str
        ``stage: input: error`` of a failed build, else empty.
    reasons : tuple of str
        Why the site is partial or failed (``status_reasons`` of its result).
    thumbnail : str or None
        Path of the thumbnail relative to the index's folder.
    page : str
        Link to the site page relative to the index's folder.
    dimensions : tuple of DimensionResult
    track : TrackSummary or None
        A moving survey's track errors against its ground truth (``result.json``'s ``track``).
    """

    site_id: str
    name: str
    status: Status
    scans_placed: int
    scans_total: int
    build_time: str = ""
    error: str = ""
    reasons: tuple[str, ...] = ()
    thumbnail: str | None = None
    page: str = ""
    dimensions: tuple[DimensionResult, ...] = field(default_factory=tuple)
    track: TrackSummary | None = None

    @classmethod
    def from_result(
        cls,
        result: SiteResult,
        *,
        thumbnail: str | None = None,
        build_time: dt.datetime | str | None = None,
        status: Status | None = None,
        page: str | None = None,
    ) -> "IndexEntry":
        """Build the entry of a site from its :class:`SiteResult`.

        ``thumbnail`` defaults to the result's ``thumbnail`` artifact (``<site-id>/thumbnail.png``);
        ``page`` to ``<site-id>/index.html``; ``status`` to the result's.
        """
        if thumbnail is None and "thumbnail" in result.artifacts:
            thumbnail = f"{result.site_id}/{result.artifacts['thumbnail']}"
        when = format_time(_parse_time(build_time)) if isinstance(build_time, str) else format_time(build_time)
        return cls(
            site_id=result.site_id,
            name=result.name,
            status=status or result.status,
            scans_placed=sum(1 for s in result.scans if s.placed),
            scans_total=len(result.scans),
            build_time=when,
            error=result.error or "",
            reasons=tuple(result.status_reasons),
            thumbnail=thumbnail,
            page=page or f"{result.site_id}/index.html",
            dimensions=tuple(result.dimensions),
            track=result.track,
        )


def _parse_time(text: str) -> dt.datetime | None:
    """An ISO 8601 time (``Z`` or an offset; naive means UTC), or ``None`` when empty or unreadable."""
    text = text.strip()
    if not text:
        return None
    try:
        return dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None


@dataclass(frozen=True)
class TableColumn:
    """One column of the cross-site dimension table: its key in a row, heading and explanation."""

    key: str
    heading: str
    explanation: str


TRUTH_COLUMNS = (
    TableColumn("truth", "Truth (m)", "the tape-measured reference"),
    TableColumn("truth_diff", "Map − truth (m)", "signed difference; positive when the map is larger"),
    TableColumn("truth_percent", "Map − truth (%)", "the same difference as a percentage of the truth"),
)
MOSAIC_COLUMNS = (
    TableColumn("mosaic", "Mosaic (m)", "the same dimension on the team's hand-made sonar mosaic"),
    TableColumn("mosaic_diff", "Map − mosaic (m)", "signed difference to the mosaic, as in Table IV of McVicker et al."),
)
COMMON_COLUMNS = (
    TableColumn("map", "Map (m)", "mean of the probe lines measured wall to wall in the evidence grid, "
                                  "± the half-width of its 95 % interval (probe spread, grid cell, where "
                                  "the localizer gives it the pose uncertainty of the scans that saw the walls, "
                                  f"and the map's heading: the probes turned {HEADING_TURN_DEG:.0f}° about their "
                                  "station)"),
)
TAIL_COLUMNS = (
    TableColumn("probes", "Probes", "probes the value rests on, of those the record asked for"),
    TableColumn("std", "Probe std (m)", "sample standard deviation of those probes"),
)


def _pairs(dimensions: Sequence[DimensionResult]) -> list[tuple[str, dict[str, DimensionResult]]]:
    """The dimensions of a site grouped by name, in order of first appearance: ``{kind: dimension}``."""
    grouped: dict[str, dict[str, DimensionResult]] = {}
    for d in dimensions:
        grouped.setdefault(d.name, {}).setdefault(d.reference_kind, d)
    return list(grouped.items())


def _percent(d: DimensionResult | None) -> float | None:
    return None if d is None or d.diff_m is None else 100.0 * d.diff_m / d.reference_m


def difference_table(entries: Sequence[IndexEntry]) -> tuple[list[TableColumn], list[dict]]:
    """The columns and one row per site and dimension of the cross-site table (after Table IV).

    A row shows the map's value once, measured against the tape-measured truth when the site has one
    and against the mosaic beside it; the truth or mosaic columns appear only when some site has that
    kind of reference. A dimension is flagged ``weak`` as in ``result.json``.
    """
    has = {kind: any(d.reference_kind == kind for e in entries for d in e.dimensions) for kind in ("truth", "mosaic")}
    columns = list(COMMON_COLUMNS) + (list(TRUTH_COLUMNS) if has["truth"] else []) + \
        (list(MOSAIC_COLUMNS) if has["mosaic"] else []) + list(TAIL_COLUMNS)
    rows = []
    for entry in entries:
        pairs = _pairs(entry.dimensions)
        for k, (name, kinds) in enumerate(pairs):
            truth, mosaic = kinds.get("truth"), kinds.get("mosaic")
            shown = truth or mosaic
            cells = {"map": with_interval(shown.map_m, shown.ci95_m), "truth": number(truth.reference_m) if truth else "—",
                     "truth_diff": signed(truth.diff_m) if truth else "—", "truth_percent": signed(_percent(truth), 2),
                     "mosaic": number(mosaic.reference_m) if mosaic else "—",
                     "mosaic_diff": signed(mosaic.diff_m) if mosaic else "—",
                     "probes": probe_count(shown), "std": number(shown.probe_std_m)}
            rows.append({"site": entry.name, "site_id": entry.site_id, "page": entry.page, "dimension": name,
                         "site_rows": len(pairs) if k == 0 else 0,
                         "weak": shown.weak, "weak_reason": shown.weak_reason,
                         "cells": [cells[c.key] for c in columns]})
    return columns, rows


def summary_figures(entries: Sequence[IndexEntry]) -> list[dict[str, str]]:
    """The catalog's summary figures, each with what it is: the median and largest absolute difference
    to the truth and to the mosaic over the measured dimensions, and how many dimensions are weak."""
    figures = []
    for kind, label in (("truth", "truth"), ("mosaic", "mosaic")):
        diffs = [abs(d.diff_m) for e in entries for d in e.dimensions if d.reference_kind == kind and d.diff_m is not None]
        if diffs:
            figures.append({"label": f"Map vs {label}", "value": f"median {number(float(np.median(diffs)))} m, "
                            f"largest {number(max(diffs))} m",
                            "explanation": f"absolute map − {label} difference over the {len(diffs)} dimensions "
                                           f"measured against a {label} reference"})
    shown = [d for e in entries for _, kinds in _pairs(e.dimensions) for d in [kinds.get("truth") or kinds.get("mosaic")]]
    if shown:
        weak = sum(1 for d in shown if d.weak)
        figures.append({"label": "Weak dimensions", "value": f"{weak} of {len(shown)}",
                        "explanation": "measured on fewer than half of their probes, with a probe spread "
                                       f"above {MAX_PROBE_STD_M:.2f} m, between walls leaning more than "
                                       f"{MAX_WALL_LEAN_DEG:.0f}° or changed by more than "
                                       f"{MAX_HEADING_SHIFT_M:.2f} m by {HEADING_TURN_DEG:.0f}° of compass bias: read them with "
                                       "care"})
    return figures


TRACK_COLUMNS = (
    TableColumn("mean", "Mean (m)", "mean horizontal distance to the DGPS fixes, the track started on the first fix"),
    TableColumn("sd", "SD (m)", "its standard deviation"),
    TableColumn("max", "Max (m)", "its largest value"),
    TableColumn("rigid", "Rigid mean (m)", "the mean after the best rigid 2-D alignment of the track onto "
                                           "those fixes (what remains once a start offset and heading are removed)"),
    TableColumn("fixes", "Fixes", "DGPS fixes the errors are measured at (those after the calibration window, "
                                  "where the run reaches past it)"),
)


def track_table(entries: Sequence[IndexEntry]) -> list[dict]:
    """One row per moving survey and estimated track (as on the survey's own page), then the published
    rows the record names for that run, marked as published."""
    rows = []
    for entry in entries:
        if entry.track is None:
            continue
        own = [{"name": t.name, "published": False,
                "cells": [number(t.start_aligned.get("mean_m")), number(t.start_aligned.get("sd_m")),
                          number(t.start_aligned.get("max_m")), number(t.rigid.get("mean_m")),
                          str(t.start_aligned.get("fixes", entry.track.fixes))]} for t in entry.track.tracks]
        published = [{"name": str(r["method"]), "published": True,
                      "cells": [number(r.get("mean_m")), number(r.get("sd_m")), number(r.get("max_m")), "—", "—"]}
                     for r in entry.track.published]
        for k, row in enumerate(own + published):
            rows.append({**row, "site": entry.name, "page": entry.page, "site_rows": len(own) + len(published) if k == 0 else 0})
    return rows


def render_index(
    entries: Sequence[IndexEntry],
    out_dir: Path,
    *,
    title: str = "Cistern archive",
    config: ReportConfig | None = None,
) -> Path:
    """Write ``out_dir/index.html`` for the given sites (in the given order).

    Thumbnails that do not exist under ``out_dir`` are left out rather than shown broken.
    """
    config = config or ReportConfig()
    out_dir = Path(out_dir)
    entries = [e if e.thumbnail is None or (out_dir / e.thumbnail).is_file()
               else IndexEntry(**{**e.__dict__, "thumbnail": None}) for e in entries]
    columns, rows = difference_table(entries)
    counts = {status: sum(1 for e in entries if e.status == status) for status in STATUS_TEXT}
    views = [{**e.__dict__, "status_text": STATUS_TEXT.get(e.status, e.status)} for e in entries]
    html = render_index_page(
        version=__version__,
        build_time=format_time(build_time_from_env()),
        title=title,
        entries=views,
        counts=counts,
        thumb_px=config.thumbnail_px // 2,
        diff_columns=columns,
        diff_rows=rows,
        summary_figures=summary_figures(entries),
        weak_threshold=f"{MAX_PROBE_STD_M:.2f}",
        lean_threshold=f"{MAX_WALL_LEAN_DEG:.0f}",
        heading_threshold=f"{MAX_HEADING_SHIFT_M:.2f}",
        heading_turn=f"{HEADING_TURN_DEG:.0f}",
        join_threshold=f"{MAX_JOIN_CI95_M:.2f}",
        track_columns=TRACK_COLUMNS,
        track_rows=track_table(entries),
        track_sources=sorted({e.track.published_source for e in entries if e.track and e.track.published_source}),
    )
    path = out_dir / "index.html"
    path.write_text(html, encoding="utf-8")
    return path
