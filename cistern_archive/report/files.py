"""Byte-for-byte reproducible writers for the files of a report.

The same inputs give the same bytes:

* PNG: matplotlib figures are saved without the ``Software`` text chunk and without a timestamp; raster
  arrays go through Pillow with no text chunks at all.
* ``grid.npz``, the grid PNGs and the CSV tables: :mod:`cistern_archive.pipeline.export`.
* Build time: only from ``SOURCE_DATE_EPOCH`` (https://reproducible-builds.org/specs/source-date-epoch/).
"""

from __future__ import annotations

import datetime as dt
import os
import re
import unicodedata
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np


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
