"""The one jinja2 environment of the report and thin keyword-only render helpers.

Templates are package data (``cistern_archive/report/templates/``, which the repository's top-level
``templates/`` links to), so a wheel install renders as an editable one; ``CISTERN_ARCHIVE_TEMPLATES``
points elsewhere (a site's own styling). The environment is created once per folder and cached;
autoescaping is on for every template; undefined variables raise.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

import jinja2

from cistern_archive.core.errors import CisternError
from cistern_archive.pipeline.export import format_number

TEMPLATES_ENV = "CISTERN_ARCHIVE_TEMPLATES"
STATUS_TEXT = {"ok": "ok", "partial": "partial", "failed": "failed", "skipped": "skipped"}
"""Badge text of each status (:mod:`cistern_archive.pipeline.status`; ``skipped`` is the rebuild's)."""
REQUIRED = ("base.html.j2", "site.html.j2", "index.html.j2", "macros.html.j2", "style.css")


def templates_dir() -> Path:
    """The folder holding the report templates.

    Raises
    ------
    CisternError
        When neither ``$CISTERN_ARCHIVE_TEMPLATES`` nor the package's ``templates/`` holds them.
    """
    candidates = []
    if os.environ.get(TEMPLATES_ENV):
        candidates.append(Path(os.environ[TEMPLATES_ENV]))
    candidates.append(Path(__file__).resolve().parent / "templates")
    for folder in candidates:
        if all((folder / name).is_file() for name in REQUIRED):
            return folder
    tried = ", ".join(str(c) for c in candidates)
    raise CisternError(f"report templates not found (looked in {tried}; need {', '.join(REQUIRED)})")


def signed(value: float | None, digits: int = 3) -> str:
    """``+0.012`` / ``−0.026`` (true minus sign), empty for missing values."""
    text = format_number(value, digits)
    if not text:
        return "—"
    return ("+" + text if not text.startswith("-") else "\u2212" + text[1:]) if float(text) != 0 else text.lstrip("-")


def number(value: float | None, digits: int = 3) -> str:
    """Fixed-point number with a true minus sign, ``—`` when missing."""
    text = format_number(value, digits)
    if not text:
        return "—"
    return "\u2212" + text[1:] if text.startswith("-") and float(text) != 0 else text.lstrip("-")


def with_interval(value: float | None, ci95: float | None, digits: int = 3) -> str:
    """``3.470 ± 0.060``: a value with the half-width of its 95 % interval (just the value without one)."""
    text = number(value, digits)
    return text if ci95 is None or value is None else f"{text} ± {number(ci95, digits)}"


def probe_count(dimension: Any) -> str:
    """``8 of 10``: the probes a dimension's value rests on, of those the record asked for
    (a :class:`~cistern_archive.pipeline.results.DimensionResult`)."""
    used, asked = len(dimension.probes_m), dimension.probes_requested
    return f"{used} of {asked}" if asked else str(used)


@functools.lru_cache(maxsize=4)
def environment(folder: str) -> jinja2.Environment:
    """The cached environment for one template folder (autoescape on, strict undefined)."""
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(folder),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=False,
        lstrip_blocks=False,
        keep_trailing_newline=True,
    )
    env.filters["signed"] = signed
    env.filters["number"] = number
    return env


def _render(name: str, context: dict[str, Any]) -> str:
    return environment(str(templates_dir())).get_template(name).render(**context)


def render_site_page(**context: Any) -> str:
    """Render ``site.html.j2`` (see :func:`cistern_archive.report.site.page_context` for the names)."""
    return _render("site.html.j2", context)


def render_index_page(**context: Any) -> str:
    """Render ``index.html.j2`` (see :func:`cistern_archive.report.index.index_context`)."""
    return _render("index.html.j2", context)
