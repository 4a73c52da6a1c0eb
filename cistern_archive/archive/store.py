"""Content-addressed object store: every file is kept once, under its SHA-256.

Layout: ``ROOT/objects/ab/cdef…`` where ``abcdef…`` is the hex digest. Objects are written to
``ROOT/tmp`` first, flushed to disk, made read-only and renamed into place, so a crash never leaves a
partial object under a digest name. The source file is only ever opened for reading.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path

from cistern_archive.archive.digest import CHUNK, file_sha256, is_sha256

READ_ONLY = stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH


@dataclass(frozen=True)
class StoredObject:
    """The result of :meth:`ObjectStore.put`."""

    sha256: str
    size: int
    created: bool


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


class ObjectStore:
    """Files addressed by their SHA-256 under ``root/objects``.

    Parameters
    ----------
    root : Path
        The archive folder (created when missing).
    """

    def __init__(self, root: Path):
        self.root = Path(root)
        self.objects = self.root / "objects"
        self.tmp = self.root / "tmp"
        self.objects.mkdir(parents=True, exist_ok=True)
        self.tmp.mkdir(parents=True, exist_ok=True)

    def path_of(self, sha256: str) -> Path:
        """Where the object with this digest lives (whether or not it exists)."""
        if not is_sha256(sha256):
            raise ValueError(f"not a sha256 digest: {sha256!r}")
        return self.objects / sha256[:2] / sha256[2:]

    def has(self, sha256: str) -> bool:
        return self.path_of(sha256).is_file()

    def put(self, source: Path, sha256: str | None = None) -> StoredObject:
        """Store a copy of ``source`` (read-only) unless an object with its digest exists.

        Parameters
        ----------
        source : Path
            File to store; opened read-only, never changed.
        sha256 : str, optional
            Its digest when already known; the copy is checked against it.

        Raises
        ------
        OSError
            When the copy changed while being stored (its digest differs from ``sha256``).
        """
        if sha256 is None:
            sha256, size = file_sha256(source)
        else:
            size = source.stat().st_size
        target = self.path_of(sha256)
        if target.is_file():
            return StoredObject(sha256=sha256, size=size, created=False)
        copied, copied_size, tmp_path = self._copy_to_tmp(source)
        try:
            if copied != sha256:
                raise OSError(f"{source}: content changed while it was being archived "
                              f"(expected sha256 {sha256}, copied {copied})")
            os.chmod(tmp_path, READ_ONLY)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp_path, target)
            fsync_dir(target.parent)
        finally:
            Path(tmp_path).unlink(missing_ok=True)
        return StoredObject(sha256=sha256, size=copied_size, created=True)

    def _copy_to_tmp(self, source: Path) -> tuple[str, int, str]:
        """Copy ``source`` into ``tmp/`` while hashing it; return (digest, size, temporary path)."""
        digest = hashlib.sha256()
        size = 0
        fd, tmp_path = tempfile.mkstemp(prefix="obj-", dir=self.tmp)
        try:
            with open(source, "rb") as src, os.fdopen(fd, "wb") as dst:
                while chunk := src.read(CHUNK):
                    digest.update(chunk)
                    dst.write(chunk)
                    size += len(chunk)
                dst.flush()
                os.fsync(dst.fileno())
        except BaseException:
            Path(tmp_path).unlink(missing_ok=True)
            raise
        return digest.hexdigest(), size, tmp_path

    def copy_out(self, sha256: str, target: Path) -> Path:
        """Copy an object to ``target`` (a writable copy; the stored object is untouched)."""
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(self.path_of(sha256), target)
        return target

    def iter_digests(self) -> list[str]:
        """Digests of every object file present on disk, sorted."""
        found = []
        for folder in sorted(self.objects.iterdir()) if self.objects.is_dir() else []:
            if folder.is_dir() and len(folder.name) == 2:
                found.extend(folder.name + p.name for p in folder.iterdir() if p.is_file())
        return sorted(d for d in found if is_sha256(d))

    def clean_tmp(self) -> int:
        """Remove leftovers of interrupted writes; returns how many were removed."""
        removed = 0
        for leftover in self.tmp.iterdir():
            if leftover.is_file():
                leftover.unlink(missing_ok=True)
                removed += 1
        return removed
