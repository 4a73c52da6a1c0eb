"""Byte-for-byte reproducible writers for the files of a report.

The same inputs give the same bytes:

* PNG: matplotlib figures are saved without the ``Software`` text chunk and without a timestamp; raster
  arrays go through Pillow with no text chunks at all.
* NPZ: :func:`numpy.savez_compressed` stamps every zip member with the wall clock; :func:`write_npz`
  writes the zip itself with a fixed member time (1980-01-01, the earliest a zip file can hold).
* CSV: fixed float formatting, ``\\n`` line endings, sorted where order is not meaningful.
* Build time: only from ``SOURCE_DATE_EPOCH`` (https://reproducible-builds.org/specs/source-date-epoch/).
"""

from __future__ import annotations

import csv
import datetime as dt
import math
import os
import re
import unicodedata
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cistern_archive.grid.export import npz_bytes


def build_time_from_env(environ: Mapping[str, str] | None = None) -> dt.datetime | None:
    """The build time given by ``SOURCE_DATE_EPOCH`` (UTC), or ``None`` when it is not set.

    Raises
    ------
    ValueError
        When the variable is set but is not an integer number of seconds.
    """
    value = (os.environ if environ is None else environ).get("SOURCE_DATE_EPOCH", "").strip()
    if not value:
        return None
    try:
        seconds = int(value)
    except ValueError as exc:
        raise ValueError(f"SOURCE_DATE_EPOCH={value!r} is not an integer number of seconds") from exc
    return dt.datetime.fromtimestamp(seconds, tz=dt.timezone.utc)


def format_time(when: dt.datetime | None) -> str:
    """ISO 8601 in UTC to the second (``2026-01-31T12:00:00Z``), or an empty string."""
    if when is None:
        return ""
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.timezone.utc)
    return when.astimezone(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def slug(title: str) -> str:
    """A stable HTML id / file stem derived from a title: ASCII, lower case, hyphen separated."""
    text = unicodedata.normalize("NFKD", title).encode("ascii", "ignore").decode("ascii").lower()
    text = re.sub(r"[^a-z0-9]+", "-", text).strip("-")
    return text or "item"


def unique_slugs(titles: Sequence[str]) -> list[str]:
    """:func:`slug` of every title, with ``-2``, ``-3`` … appended to repeats (in order of appearance)."""
    seen: dict[str, int] = {}
    out = []
    for title in titles:
        base = slug(title)
        seen[base] = seen.get(base, 0) + 1
        out.append(base if seen[base] == 1 else f"{base}-{seen[base]}")
    return out


def write_png(path: Path, image: np.ndarray) -> Path:
    """Write an (H, W) or (H, W, 3|4) uint8 array as a PNG without any metadata chunk."""
    from PIL import Image

    array = np.ascontiguousarray(image)
    if array.dtype != np.uint8:
        raise TypeError(f"{path}: PNG data must be uint8, got {array.dtype}")
    Image.fromarray(array).save(path, format="PNG", optimize=False, compress_level=6)
    return path


def save_figure(figure: Any, path: Path, *, dpi: int, tight: bool = True) -> Path:
    """Save a matplotlib figure as a PNG with no ``Software`` chunk (nothing time- or host-dependent).

    With ``tight`` the canvas is fitted to what was drawn, so that no legend or label outside the
    axes is cut off (and no empty margin is kept); the thumbnail keeps its fixed size."""
    extra = {"bbox_inches": "tight", "pad_inches": 0.12} if tight else {}
    figure.savefig(path, format="png", dpi=dpi, metadata={"Software": None}, facecolor=figure.get_facecolor(),
                   **extra)
    return path


def write_npz(path: Path, arrays: Mapping[str, np.ndarray]) -> Path:
    """A compressed ``.npz`` readable by :func:`numpy.load`, identical for identical arrays.

    Members are written in sorted name order with a fixed timestamp and fixed permissions
    (:func:`cistern_archive.grid.export.npz_bytes`).
    """
    path.write_bytes(npz_bytes(dict(arrays)))
    return path


def format_number(value: float | None, digits: int = 3) -> str:
    """Fixed-point text of a number; empty for ``None`` and NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return f"{value:.{digits}f}"


def write_csv(path: Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> Path:
    """A CSV file with ``\\n`` line endings; floats with 4 decimals, ``None``/NaN as empty cells."""

    def cell(value: Any) -> Any:
        if isinstance(value, float):
            return format_number(value, 4)
        return "" if value is None else value

    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(header)
        for row in rows:
            writer.writerow([cell(value) for value in row])
    return path
