"""SHA-256 digests of files, read in chunks (never loads a whole recording into memory)."""

from __future__ import annotations

import hashlib
from pathlib import Path

CHUNK = 1 << 20
ALGORITHM = "sha256"


def file_sha256(path: Path) -> tuple[str, int]:
    """Hex SHA-256 and size in bytes of a file, opened read-only.

    Parameters
    ----------
    path : Path
        The file to digest; it is never modified.

    Returns
    -------
    tuple of (str, int)
        The lower-case hex digest and the number of bytes read.
    """
    digest = hashlib.sha256()
    size = 0
    with open(path, "rb") as handle:
        while chunk := handle.read(CHUNK):
            digest.update(chunk)
            size += len(chunk)
    return digest.hexdigest(), size


def is_sha256(text: str) -> bool:
    """Whether ``text`` looks like a lower-case hex SHA-256 digest."""
    return len(text) == 64 and all(c in "0123456789abcdef" for c in text)
