"""Helpers of the fault-injection suites (``tests/test_faults*.py``).

:class:`DataGuard` takes a byte-for-byte snapshot of the raw inputs and of the published reports before
a fault and, after the fault and the recovery, counts what was lost: a raw file that is missing or
changed, a report folder that is neither its previous self nor a complete new report. Each count is
appended to ``$CISTERN_RELIABILITY_LOG`` (JSON lines) when that is set, for
``benchmarks/reliability.py``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from service_helpers import report_is_complete

CLI = [sys.executable, "-m", "cistern_archive"]
RELIABILITY_LOG = "CISTERN_RELIABILITY_LOG"
TRACEBACK = re.compile(r"Traceback \(most recent call last\)|^\s+File \".*\", line \d+", re.M)


def digest_tree(root: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``root`` (symbolic links not followed)."""
    if not root.is_dir():
        return {}
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and not p.is_symlink()}


@dataclass
class DataGuard:
    """Snapshots of raw inputs and published reports, compared after a fault."""

    case: str
    raw: dict[Path, dict[str, str]] = field(default_factory=dict)
    reports: dict[Path, dict[str, str]] = field(default_factory=dict)
    lost: list[str] = field(default_factory=list)
    checked: bool = False

    def watch_raw(self, root: Path) -> None:
        """Every file under ``root`` must survive byte for byte."""
        self.raw[root] = digest_tree(root)

    def watch_reports(self, out: Path) -> None:
        """Every published site folder under ``out`` must stay whole: its old bytes or a complete new report."""
        for site in sorted(p for p in out.iterdir() if (p / "build.json").is_file()):
            self.reports[site] = digest_tree(site)

    def check(self) -> list[str]:
        """What was lost (one line per file or report); also recorded for the reliability table."""
        lost = []
        for root, before in self.raw.items():
            after = digest_tree(root)
            lost += [f"{root / name}: {'changed' if name in after else 'missing'}"
                     for name, digest in before.items() if after.get(name) != digest]
        for site, before in self.reports.items():
            if digest_tree(site) != before and not (site.is_dir() and report_is_complete(site)):
                lost.append(f"{site}: report neither the previous one nor a complete new one")
        self.lost, self.checked = lost, True
        return lost

    def record(self) -> None:
        target = os.environ.get(RELIABILITY_LOG)
        if not target:
            return
        entry = {"case": self.case, "checked": self.checked, "lost": len(self.lost),
                 "raw_files": sum(len(v) for v in self.raw.values()), "reports": len(self.reports)}
        with open(target, "a", encoding="utf-8") as handle:
            handle.write(json.dumps(entry) + "\n")


def run_cli(*args: str, cwd: Path | None = None, timeout: float = 300, **kwargs) -> subprocess.CompletedProcess:
    """Run the command line; assert that no Python traceback reached the user."""
    run = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout, cwd=cwd, **kwargs)
    assert not TRACEBACK.search(run.stderr + run.stdout), f"a traceback reached the user:\n{run.stderr}"
    return run


def one_line_error(run: subprocess.CompletedProcess, *, code: int, naming: str) -> str:
    """The single ``error:`` line of a failed command, which must name ``naming``."""
    assert run.returncode == code, (run.returncode, run.stdout, run.stderr)
    errors = [line for line in run.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, run.stderr
    assert naming in errors[0], errors[0]
    return errors[0]


def can_mount() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0 and Path("/bin/mount").exists()


@contextlib.contextmanager
def small_disk(where: Path, size: str = "2m"):
    """A real small file system (tmpfs) mounted at ``where``; unmounted afterwards."""
    where.mkdir(parents=True, exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], check=True)
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


def remount(where: Path, mode: str) -> None:
    """Remount the tmpfs at ``where`` ``ro`` or ``rw``."""
    subprocess.run(["mount", "-o", f"remount,{mode}", str(where)], check=True)


FILLERS = (".filler", ".filler-tail")


def fill(folder: Path) -> None:
    """Fill the file system holding ``folder`` until it refuses another byte (see :func:`free`)."""
    for name, chunk in zip(FILLERS, (65536, 1)):
        with contextlib.suppress(OSError), open(folder / name, "wb") as handle:
            while True:
                handle.write(b"\0" * chunk)
                handle.flush()


def free(folder: Path) -> None:
    """Undo :func:`fill`."""
    for name in FILLERS:
        (folder / name).unlink(missing_ok=True)


@pytest.fixture()
def guard(request):
    """A :class:`DataGuard` for the test; its finding is recorded even when the test fails."""
    data_guard = DataGuard(case=request.node.nodeid)
    yield data_guard
    if not data_guard.checked:
        data_guard.check()
    data_guard.record()
