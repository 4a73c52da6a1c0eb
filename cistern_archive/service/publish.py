"""Atomic publication of a site folder.

A site is written into a temporary sibling ``OUT/.<site>.tmp-XXXX`` and then swapped with
``OUT/<site>`` in one step: ``renameat2(RENAME_EXCHANGE)`` on Linux, otherwise a rename of the old
folder to ``OUT/.<site>.old-XXXX`` followed by a rename of the new one into place. Readers see either
the whole previous report or the whole new one. :func:`recover` (run under the rebuild lock) finishes
or rolls back whatever a crash interrupted: temporary folders are removed, an ``.old`` folder whose
site folder is missing is moved back.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import shutil
import tempfile
from pathlib import Path

from cistern_archive.core.files import fsync_dir

TMP_MARK = ".tmp-"
OLD_MARK = ".old-"
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def staging_dir(out: Path, site_id: str) -> Path:
    """Create ``OUT/.<site>.tmp-XXXX`` (a sibling of the site folder, so the final rename is atomic)."""
    out.mkdir(parents=True, exist_ok=True)
    staged = Path(tempfile.mkdtemp(prefix=f".{site_id}{TMP_MARK}", dir=out))
    os.chmod(staged, 0o755)  # mkdtemp makes it private; the published report must be readable
    return staged


def _libc_renameat2():
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        func = ctypes.CDLL(name, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    func.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    func.restype = ctypes.c_int
    return func


_renameat2 = _libc_renameat2()


def exchange(a: Path, b: Path) -> bool:
    """Atomically swap two paths; False when the platform or file system cannot."""
    if _renameat2 is None:
        return False
    rc = _renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(a), None, str(b))


def sync_tree(folder: Path) -> None:
    """Make a freshly written folder world-readable (temporary files are created private) and flush
    every file, then the folders, to disk."""
    for root, dirs, files in os.walk(folder):
        for name in dirs:
            os.chmod(os.path.join(root, name), 0o755)
        for name in files:
            path = os.path.join(root, name)
            if os.stat(path).st_mode & 0o044 != 0o044:
                os.chmod(path, 0o644)
            fd = os.open(path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    for root, dirs, _ in os.walk(folder, topdown=False):
        for name in dirs:
            fsync_dir(Path(root) / name)
    fsync_dir(folder)


def publish(staged: Path, target: Path) -> None:
    """Replace ``target`` by ``staged`` atomically; ``staged`` must be a sibling of ``target``.

    Raises
    ------
    OSError
        When a rename fails; the previous ``target`` is then still in place.
    """
    sync_tree(staged)
    if not target.exists():
        os.rename(staged, target)
    elif exchange(staged, target):
        shutil.rmtree(staged)  # now holds the previous report
    else:
        old = Path(tempfile.mkdtemp(prefix=f".{target.name}{OLD_MARK}", dir=target.parent))
        os.rename(target, old / "site")
        try:
            os.rename(staged, target)
        except OSError:
            os.rename(old / "site", target)
            shutil.rmtree(old, ignore_errors=True)
            raise
        shutil.rmtree(old, ignore_errors=True)
    fsync_dir(target.parent)


def discard(staged: Path) -> None:
    shutil.rmtree(staged, ignore_errors=True)


def recover(out: Path) -> list[str]:
    """Clean up after an interrupted rebuild; return what was done (one line each).

    Must only run while holding the rebuild lock (no other rebuild is staging folders).
    """
    actions: list[str] = []
    if not out.is_dir():
        return actions
    for entry in sorted(out.iterdir()):
        if not (entry.name.startswith(".") and entry.is_dir()):
            continue
        if TMP_MARK in entry.name:
            shutil.rmtree(entry, ignore_errors=True)
            actions.append(f"removed unfinished {entry.name}")
        elif OLD_MARK in entry.name:
            site = entry.name[1:].split(OLD_MARK)[0]
            target, kept = out / site, entry / "site"
            if not target.exists() and kept.is_dir():
                os.rename(kept, target)
                actions.append(f"restored previous report of {site}")
            shutil.rmtree(entry, ignore_errors=True)
            actions.append(f"removed {entry.name}")
    return actions
