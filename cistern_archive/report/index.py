"""The catalog index: every site with its thumbnail, status, scans placed, last build and error, and
one table across sites of grid-versus-reference dimension differences (the paper's Table IV)."""

from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from cistern_archive import __version__
from cistern_archive.pipeline.results import DimensionResult, SiteResult
from cistern_archive.report.config import ReportConfig
from cistern_archive.report.files import build_time_from_env, format_time
from cistern_archive.report.html import render_index_page, signed

Status = Literal["ok", "failed", "skipped"]
STATUS_TEXT = {"ok": "built", "failed": "failed", "skipped": "skipped"}


@dataclass(frozen=True)
class IndexEntry:
    """One row of the catalog index.

    Attributes
    ----------
    site_id, name : str
    status : {"ok", "failed", "skipped"}
    scans_placed, scans_total : int
    build_time : str
        ISO 8601 UTC of the site's last build, or empty when unknown.
    error : str
        ``stage: input: error`` of a failed build, else empty.
    thumbnail : str or None
        Path of the thumbnail relative to the index's folder.
    page : str
        Link to the site page relative to the index's folder.
    dimensions : tuple of DimensionResult
    """

    site_id: str
    name: str
    status: Status
    scans_placed: int
    scans_total: int
    build_time: str = ""
    error: str = ""
    thumbnail: str | None = None
    page: str = ""
    dimensions: tuple[DimensionResult, ...] = field(default_factory=tuple)

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
            thumbnail=thumbnail,
            page=page or f"{result.site_id}/index.html",
            dimensions=tuple(result.dimensions),
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


def _preferred(dimensions: Sequence[DimensionResult]) -> dict[str, DimensionResult]:
    """One dimension per name: the one measured against a mosaic when both kinds exist (Table IV
    compares grid and mosaic), else the tape-measure one."""
    chosen: dict[str, DimensionResult] = {}
    for d in dimensions:
        if d.name not in chosen or (chosen[d.name].reference_kind != "mosaic" and d.reference_kind == "mosaic"):
            chosen[d.name] = d
    return chosen


def difference_table(entries: Sequence[IndexEntry]) -> tuple[list[str], list[dict]]:
    """Columns (dimension names in order of first appearance) and one row per site with dimensions.

    A cell is the signed difference map − reference in metres, marked † when the reference is a tape
    measure (``truth``) rather than a mosaic (a mosaic reference is preferred when a site has both);
    ``—`` when the site does not have that dimension or it could not be measured.
    """
    columns: list[str] = []
    for entry in entries:
        for d in entry.dimensions:
            if d.name not in columns:
                columns.append(d.name)
    rows = []
    for entry in entries:
        if not entry.dimensions:
            continue
        by_name = _preferred(entry.dimensions)
        cells = []
        for name in columns:
            d = by_name.get(name)
            if d is None or d.diff_m is None:
                cells.append("—")
            else:
                cells.append(signed(d.diff_m) + (" †" if d.reference_kind == "truth" else ""))
        rows.append({"name": entry.name, "page": entry.page, "cells": cells})
    return columns, rows


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
    )
    path = out_dir / "index.html"
    path.write_text(html, encoding="utf-8")
    return path
