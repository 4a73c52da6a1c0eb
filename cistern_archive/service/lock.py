"""A lock that lets one rebuild at a time write an output folder.

The lock file ``OUT/.rebuild.lock`` holds the owner's pid, host, process start time and command line.
It is taken with ``flock`` (released by the kernel when the owner dies, however it dies) and checked
against the recorded pid: a lock file whose owner is no longer running is stale and is taken over.
The file also names the owner's run id, so a worker can check that its rebuild still holds the lock
right before it publishes (:func:`holds_lock`): a worker that outlived its rebuild never publishes
over the next one.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any

import psutil

from cistern_archive.core.errors import CisternError, EnvironmentProblem

LOCK_NAME = ".rebuild.lock"


class RebuildLocked(CisternError):
    """Another rebuild is writing the same output folder."""


def process_start(pid: int) -> float | None:
    """When process ``pid`` started (seconds since the epoch), or None when it is not running."""
    try:
        return psutil.Process(pid).create_time()
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return None


def owner_alive(info: dict[str, Any]) -> bool:
    """Whether the process recorded in a lock file is still running (and is the same process)."""
    pid = info.get("pid")
    if not isinstance(pid, int) or info.get("host") != socket.gethostname():
        return isinstance(pid, int)  # another host's lock: assume alive, it cannot be checked from here
    started = process_start(pid)
    if started is None:
        return False
    recorded = info.get("process_start")
    return recorded is None or abs(float(recorded) - started) < 1.0


class RebuildLock:
    """Context manager holding ``OUT/.rebuild.lock``.

    Parameters
    ----------
    out : Path
        The output folder (created when missing).

    Attributes
    ----------
    stale : dict or None
        After entering: the record of a stale lock that was taken over (its owner had died).

    Raises
    ------
    RebuildLocked
        On entry, when a live process holds the lock; the message names it.
    """

    def __init__(self, out: Path, run_id: str | None = None):
        self.path = Path(out) / LOCK_NAME
        self.run_id = run_id
        self.stale: dict[str, Any] | None = None
        self._fd: int | None = None

    def __enter__(self) -> "RebuildLock":
        try:
            return self._take()
        except OSError as exc:  # a read-only or full disk: one line naming the lock file
            raise EnvironmentProblem(f"{self.path}: cannot take the rebuild lock: {exc.strerror or exc}") from None

    def _take(self) -> "RebuildLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(10):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                info = _read(fd)
                os.close(fd)
                raise RebuildLocked(self._refusal(info)) from None
            if _same_file(fd, self.path):
                break
            os.close(fd)  # the file was replaced between open and flock; try the new one
        else:  # pragma: no cover - needs ten consecutive races
            raise RebuildLocked(f"{self.path}: could not take the lock (it keeps being replaced)")
        previous = _read(fd)
        if previous:
            if owner_alive(previous):
                os.close(fd)
                raise RebuildLocked(self._refusal(previous))
            self.stale = previous
        try:
            _write(fd, {
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "process_start": process_start(os.getpid()),
                "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "command": " ".join(sys.argv),
                "run_id": self.run_id,
            })
        except OSError:
            os.close(fd)  # the flock goes with it; a later rebuild finds an empty or stale file
            raise
        self._fd = fd
        return self

    def _refusal(self, info: dict[str, Any]) -> str:
        who = f"pid {info.get('pid', '?')} on {info.get('host', '?')}, started {info.get('started', '?')}"
        return (f"another rebuild is already writing {self.path.parent} ({who}); wait for it to finish. "
                f"Lock file: {self.path}")

    def __exit__(self, *exc: object) -> None:
        if self._fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)
        finally:
            os.close(self._fd)
            self._fd = None


def holds_lock(out: Path, run_id: str) -> bool:
    """Whether the rebuild ``run_id`` still holds ``OUT/.rebuild.lock`` (its owner alive, its run id)."""
    try:
        fd = os.open(Path(out) / LOCK_NAME, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return False
    try:
        info = _read(fd)
    finally:
        os.close(fd)
    return info.get("run_id") == run_id and _running(info)


def _running(info: dict[str, Any]) -> bool:
    """Whether the pid in a lock record runs (a zombie does not). Unlike :func:`owner_alive` this does not
    compare start times, which move with the wall clock; the run id already names one rebuild."""
    pid = info.get("pid")
    if not isinstance(pid, int) or info.get("host") != socket.gethostname():
        return isinstance(pid, int)
    return is_running(pid)


def is_running(pid: int) -> bool:
    """Whether process ``pid`` exists and has not exited (a zombie waiting for its parent has)."""
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except (psutil.NoSuchProcess, psutil.AccessDenied):
        return False


def _same_file(fd: int, path: Path) -> bool:
    try:
        on_disk = path.stat()
    except FileNotFoundError:
        return False
    mine = os.fstat(fd)
    return (mine.st_dev, mine.st_ino) == (on_disk.st_dev, on_disk.st_ino)


def _read(fd: int) -> dict[str, Any]:
    os.lseek(fd, 0, os.SEEK_SET)
    raw = b""
    while chunk := os.read(fd, 65536):
        raw += chunk
    try:
        data = json.loads(raw.decode("utf-8")) if raw.strip() else {}
    except (UnicodeDecodeError, json.JSONDecodeError):
        data = {"unreadable": raw[:200].decode("utf-8", "replace")}
    return data if isinstance(data, dict) else {}


def _write(fd: int, info: dict[str, Any]) -> None:
    os.ftruncate(fd, 0)
    os.lseek(fd, 0, os.SEEK_SET)
    os.write(fd, (json.dumps(info, sort_keys=True) + "\n").encode("utf-8"))
    os.fsync(fd)
