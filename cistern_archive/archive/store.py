"""Content-addressed object store: every file is kept once, under its SHA-256.

Layout: ``ROOT/objects/ab/cdef…`` where ``abcdef…`` is the hex digest. Objects are written to
``ROOT/tmp`` first, flushed to disk, made read-only and renamed into place, so a crash never leaves a
partial object under a digest name. The source file is only ever opened for reading.

Several processes may share one store (two rebuilds into different output folders): a temporary file
is named after its host and process, and :meth:`ObjectStore.clean_tmp` removes only those of processes
of this host that are no longer running. Every read of an object for a build or an export checks its
digest (:meth:`ObjectStore.copy_out`, :meth:`ObjectStore.damage`); a damaged object is replaced only by
a copy whose digest matches its name (:meth:`ObjectStore.restore`).
"""

from __future__ import annotations

import hashlib
import os
import socket
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path

import psutil

from cistern_archive.archive.digest import CHUNK, file_sha256, is_sha256
from cistern_archive.core.errors import CisternError, EnvironmentProblem
from cistern_archive.core.files import fsync_dir

READ_ONLY = stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH
TMP_PREFIX = "obj-"


class DamagedObject(CisternError):
    """A stored object's bytes no longer match its digest (or it is missing)."""


def _tmp_prefix() -> str:
    return f"{TMP_PREFIX}{socket.gethostname()}-{os.getpid()}-"


def _writer_alive(name: str) -> bool:
    """Whether the process that created temporary file ``name`` may still be writing it."""
    host, _, rest = name[len(TMP_PREFIX):].rpartition("-")[0].rpartition("-")
    if not name.startswith(TMP_PREFIX) or not rest.isdigit():
        return False  # not named by this module (an older version): nobody is writing it
    if host != socket.gethostname():
        return True  # another machine sharing the store: its processes cannot be checked from here
    return psutil.pid_exists(int(rest))


@dataclass(frozen=True)
class StoredObject:
    """The result of :meth:`ObjectStore.put`."""

    sha256: str
    size: int
    created: bool


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
        return self._store(source, sha256)

    def restore(self, source: Path, sha256: str) -> StoredObject:
        """Replace a damaged or missing object by a copy of ``source``, whose digest must be ``sha256``.

        Raises
        ------
        DamagedObject
            When ``source`` does not have that digest (the damaged object is then left as it was).
        """
        return self._store(source, sha256)

    def _store(self, source: Path, sha256: str) -> StoredObject:
        copied, copied_size, tmp_path = self._copy_to_tmp(source)
        target = self.path_of(sha256)
        try:
            if copied != sha256:
                raise DamagedObject(f"{source}: its content is not object {sha256} (sha256 {copied}); it "
                                    "changed while being archived, or it is not the original")
            try:
                os.chmod(tmp_path, READ_ONLY)
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(tmp_path, target)
                fsync_dir(target.parent)
            except OSError as exc:
                raise EnvironmentProblem(f"{target}: cannot store the archive object: "
                                         f"{exc.strerror or exc}") from None
        finally:
            Path(tmp_path).unlink(missing_ok=True)
        return StoredObject(sha256=sha256, size=copied_size, created=True)

    def _copy_to_tmp(self, source: Path) -> tuple[str, int, str]:
        """Copy ``source`` into ``tmp/`` while hashing it; return (digest, size, temporary path).

        Raises
        ------
        EnvironmentProblem
            The archive cannot be written (a full or read-only disk); nothing is left in ``tmp/``.
        OSError
            ``source`` cannot be read.
        """
        digest = hashlib.sha256()
        size = 0
        try:
            fd, tmp_path = tempfile.mkstemp(prefix=_tmp_prefix(), dir=self.tmp)
        except OSError as exc:
            raise EnvironmentProblem(f"{self.tmp}: cannot write to the archive: {exc.strerror or exc}") from None
        try:
            with open(source, "rb") as src, os.fdopen(fd, "wb") as dst:
                while chunk := src.read(CHUNK):
                    digest.update(chunk)
                    try:
                        dst.write(chunk)
                    except OSError as exc:
                        raise EnvironmentProblem(f"{self.tmp}: cannot write to the archive while storing "
                                                 f"{source}: {exc.strerror or exc}") from None
                    size += len(chunk)
                try:
                    dst.flush()
                    os.fsync(dst.fileno())
                except OSError as exc:
                    raise EnvironmentProblem(f"{self.tmp}: cannot write to the archive while storing "
                                             f"{source}: {exc.strerror or exc}") from None
        except BaseException:
            Path(tmp_path).unlink(missing_ok=True)
            raise
        return digest.hexdigest(), size, tmp_path

    def damage(self, sha256: str) -> str | None:
        """What is wrong with a stored object (``missing``, ``unreadable: …``, ``sha256 is …``), or None."""
        path = self.path_of(sha256)
        if not path.is_file():
            return "missing"
        try:
            actual, _ = file_sha256(path)
        except OSError as exc:
            return f"unreadable: {exc.strerror or exc}"
        return None if actual == sha256 else f"damaged: its sha256 is now {actual}"

    def copy_out(self, sha256: str, target: Path) -> Path:
        """Copy an object to ``target`` (a writable copy; the stored object is untouched), checking its digest.

        Raises
        ------
        DamagedObject
            The object is missing or its bytes do not match its digest; ``target`` is not written.
        """
        target.parent.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha256()
        try:
            with open(self.path_of(sha256), "rb") as src, open(target, "wb") as dst:
                while chunk := src.read(CHUNK):
                    digest.update(chunk)
                    dst.write(chunk)
        except FileNotFoundError:
            raise DamagedObject(f"{self.path_of(sha256)}: archive object is missing; "
                                "run `cistern-archive repair`") from None
        if digest.hexdigest() != sha256:
            target.unlink(missing_ok=True)
            raise DamagedObject(f"{self.path_of(sha256)}: archive object is damaged (its sha256 is now "
                                f"{digest.hexdigest()}); run `cistern-archive repair`")
        return target

    def iter_digests(self) -> list[str]:
        """Digests of every object file present on disk, sorted."""
        found = []
        for folder in sorted(self.objects.iterdir()) if self.objects.is_dir() else []:
            if folder.is_dir() and len(folder.name) == 2:
                found.extend(folder.name + p.name for p in folder.iterdir() if p.is_file())
        return sorted(d for d in found if is_sha256(d))

    def clean_tmp(self) -> int:
        """Remove leftovers of interrupted writes (of processes no longer running); returns how many."""
        removed = 0
        for leftover in self.tmp.iterdir():
            if leftover.is_file() and not _writer_alive(leftover.name):
                leftover.unlink(missing_ok=True)
                removed += 1
        return removed
