"""Readers of recorded sonar files, registered by format name.

``read_scans(path, fmt=None)`` returns every 360° scan (or sector sweep) of a file as a list of
:class:`~cistern_archive.core.scan.Scan`. A reader never modifies its input file.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from cistern_archive.core.errors import ReaderError
from cistern_archive.core.scan import Scan


@dataclass(frozen=True)
class ReadResult:
    """Scans read from one file plus warnings that name the record or byte offset they concern."""

    format: str
    scans: list[Scan]
    warnings: list[str]


ReaderFunc = Callable[[Path], ReadResult]


@dataclass(frozen=True)
class ReaderSpec:
    name: str
    suffixes: tuple[str, ...]
    read: ReaderFunc
    description: str = ""
    sniff: Callable[[Path], bool] | None = None
    """Optional content check used when several readers claim the same suffix."""
    check: Callable[[Path], None] | None = None
    """Optional cheap check of a file's headers (raises :class:`ReaderError`), run before it is archived."""


READERS: dict[str, ReaderSpec] = {}


def register_reader(name: str, suffixes: tuple[str, ...], description: str = "",
                    sniff: Callable[[Path], bool] | None = None, check: Callable[[Path], None] | None = None):
    """Decorator: register ``func(path) -> ReadResult`` as the reader of format ``name``.

    ``sniff(path) -> bool`` (optional) tells whether a file's content is this format; it decides between
    readers that share a suffix (e.g. ``.bin``). ``check(path)`` (optional) refuses, from the headers
    only, a file this reader would refuse (see :func:`check_file`).
    """

    def decorate(func: ReaderFunc) -> ReaderFunc:
        READERS[name] = ReaderSpec(name=name, suffixes=tuple(s.lower() for s in suffixes), read=func,
                                   description=description, sniff=sniff, check=check)
        return func

    return decorate


def header_check(sniff: Callable[[Path], bool], expected: str) -> Callable[[Path], None]:
    """A ``check`` for :func:`register_reader` from a format's ``sniff``: refuses a file whose first
    bytes are not ``expected`` (read from the head of the file only, whatever its size)."""

    def check(path: Path) -> None:
        if not sniff(path):
            raise ReaderError(str(path), f"not {expected}")

    return check


def read_bytes(path: Path) -> bytes:
    """The whole file, or a :class:`ReaderError` naming it when it cannot be read."""
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ReaderError(str(path), f"cannot read: {exc.strerror or exc}") from exc


def detect_format(path: Path) -> str:
    """Pick a reader by the file's suffix (or name pattern)."""
    _load_builtin_readers()
    name = path.name.lower()
    candidates = [spec for spec in READERS.values() if any(name.endswith(suffix) for suffix in spec.suffixes)]
    if len(candidates) > 1:
        for spec in candidates:
            if spec.sniff is not None and spec.sniff(path):
                return spec.name
    if candidates:
        return candidates[0].name
    raise ReaderError(str(path), f"no reader for this file type; known formats: {', '.join(sorted(READERS))}")


def read_file(path: str | os.PathLike, fmt: str | None = None) -> ReadResult:
    """Read every scan of a file with the reader of ``fmt`` (detected from the name when omitted)."""
    _load_builtin_readers()
    path = Path(path)
    if not path.is_file():
        raise ReaderError(str(path), "file not found")
    fmt = fmt or detect_format(path)
    if fmt not in READERS:
        raise ReaderError(str(path), f"unknown format {fmt!r}; known formats: {', '.join(sorted(READERS))}")
    return READERS[fmt].read(path)


def check_file(path: str | os.PathLike, fmt: str | None = None) -> None:
    """A cheap look at a file's headers (no full read): refuses files that are plainly not of their format.

    The nightly rebuild calls it before archiving a scan, so that a junk file (of any size) is reported
    without being copied into the archive. Formats without a header check pass.

    Raises
    ------
    ReaderError
        Naming the file and what is wrong.
    """
    _load_builtin_readers()
    path = Path(path)
    fmt = fmt or detect_format(path)
    if fmt not in READERS:
        raise ReaderError(str(path), f"unknown format {fmt!r}; known formats: {', '.join(sorted(READERS))}")
    if READERS[fmt].check is not None:
        READERS[fmt].check(path)


def read_scans(path: str | os.PathLike, fmt: str | None = None) -> list[Scan]:
    return read_file(path, fmt).scans


_loaded = False


def _load_builtin_readers() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    from cistern_archive.sonar.readers import npz, pcd, ping360, seanet  # noqa: F401  (each registers itself)
