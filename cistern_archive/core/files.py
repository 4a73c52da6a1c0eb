"""Atomic file writes: the one way every layer puts a file in place.

A file is written to a temporary sibling, flushed to disk, optionally checked, given its final mode and
renamed over the target, and the directory entry is flushed. A reader sees the old file or the new one,
never a half-written one; a failure (an exception, a full disk, a kill) leaves the old file untouched
and no temporary behind except after a kill, whose ``.<name>.*.tmp`` leftovers are ignored by readers.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

FILE_MODE = 0o644
"""Mode of a new file (``mkstemp`` would leave 0600, which other readers of a published site lack)."""


def fsync_dir(path: Path) -> None:
    """Flush a directory entry (a rename or a new file) to disk where the platform allows it."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextmanager
def atomic_file(path: str | os.PathLike, *, binary: bool = False, newline: str | None = "\n",
                validate: Callable[[Path], None] | None = None) -> Iterator[IO[Any]]:
    """Open a temporary sibling of ``path`` for writing; on success it replaces ``path``.

    Parameters
    ----------
    path : path-like
        The file to write. Its folder is created when missing.
    binary : bool
        Yield a binary handle instead of a UTF-8 text handle.
    newline : str or None
        Newline translation of a text handle (``"\\n"``: none on any platform).
    validate : callable, optional
        Called with the temporary file's path after it is flushed and before the rename; an exception
        it raises leaves ``path`` as it was.

    Notes
    -----
    An existing file's mode is kept; a new file gets :data:`FILE_MODE`.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        opened = os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline=newline)
        with opened as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        if validate is not None:
            validate(Path(tmp))
        os.chmod(tmp, target.stat().st_mode & 0o777 if target.exists() else FILE_MODE)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_dir(target.parent)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Put ``data`` at ``path`` atomically (see :func:`atomic_file`); returns the path."""
    with atomic_file(path, binary=True) as handle:
        handle.write(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str, *, newline: str | None = "\n",
                      validate: Callable[[Path], None] | None = None) -> Path:
    """Put UTF-8 ``text`` at ``path`` atomically (see :func:`atomic_file`); returns the path."""
    with atomic_file(path, newline=newline, validate=validate) as handle:
        handle.write(text)
    return Path(path)


def write_json_atomic(data: Any, path: str | os.PathLike) -> Path:
    """Write ``data`` as indented, key-sorted JSON (NaN refused) atomically; returns the path."""
    return write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True, allow_nan=False) + "\n")
