"""What a worker process does for one site: build, write, render, publish.

:func:`run_site` runs in a local worker process or on a Dask worker. It builds into a temporary
sibling of the site folder and publishes it with an atomic swap; any error (a full disk, a renderer
crash) discards the temporary folder and leaves the previously published report in place. A stage
failure is not an error here: the pipeline returns a failed result, whose report is published.

Two guards keep a worker from outliving or overtaking its rebuild:

- a local worker dies with the rebuild (:func:`die_with_parent`, the pool's initializer): the kernel
  sends it SIGKILL when its parent process exits (``prctl(PR_SET_PDEATHSIG)`` on Linux), and a thread
  polls the rebuild's pid in case the parent was only an intermediary (the fork server);
- right before the rename that publishes a site the worker checks that its rebuild still holds
  ``OUT/.rebuild.lock`` (:func:`~cistern_archive.service.lock.holds_lock`); otherwise the site fails
  and nothing is published.

The inputs the build reads are checked against the digests its build key was computed from, so a file
that changed (or decayed) after it was archived fails its site instead of being built silently.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import resource
import signal
import socket
import threading
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cistern_archive.archive.digest import file_sha256
from cistern_archive.archive.index import utc_now
from cistern_archive.core.errors import CisternError
from cistern_archive.core.files import write_text_atomic
from cistern_archive.service.lock import holds_lock, is_running
from cistern_archive.service.publish import discard, publish, staging_dir
from cistern_archive.service.summary import SiteOutcome

BUILD_INFO = "build.json"
PR_SET_PDEATHSIG = 1
PARENT_POLL_S = 0.5


class LostLock(CisternError):
    """The rebuild this worker builds for no longer holds the output folder's lock."""


class InputChanged(CisternError):
    """A file the site reads is not the one its build key (and the archive) recorded."""


def _set_parent_death_signal() -> None:
    """Ask the kernel for SIGKILL when the parent process exits (Linux; a no-op elsewhere)."""
    name = ctypes.util.find_library("c")
    if name is None:
        return
    try:
        ctypes.CDLL(name, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _watch_rebuild(pid: int) -> None:
    while True:
        time.sleep(PARENT_POLL_S)
        if not is_running(pid):
            os.kill(os.getpid(), signal.SIGKILL)


def die_with_parent(rebuild_pid: int) -> None:
    """Pool initializer: end this worker as soon as the rebuild process ``rebuild_pid`` is gone.

    Parameters
    ----------
    rebuild_pid : int
        The process running the rebuild (not necessarily this worker's parent: a fork server may be).
        It is polled every :data:`PARENT_POLL_S` seconds; a pid is not reused that fast.
    """
    _set_parent_death_signal()
    if not is_running(rebuild_pid):
        os.kill(os.getpid(), signal.SIGKILL)
    threading.Thread(target=_watch_rebuild, args=(rebuild_pid,), daemon=True, name="rebuild-watch").start()


def check_inputs(task: "SiteTask", loaded) -> None:
    """Refuse to build when the record or an input differs from what the build key was computed from.

    Raises
    ------
    InputChanged
        Naming the file and both digests.
    """
    record = task.key_material.get("record")
    if record is not None and loaded.record.model_dump(mode="json") != record:
        raise InputChanged(f"{task.record_path}: the record changed after it was archived; rebuild again")
    for relative, expected in (task.key_material.get("inputs") or {}).items():
        path = loaded.input_path(relative)
        actual = file_sha256(path)[0]
        if actual != expected:
            raise InputChanged(f"{path}: sha256 is {actual}, but {expected} was archived for this build; "
                               "the file changed or is damaged")


PROGRESS_DIR = ".progress"
"""``OUT/.progress/<site-id>`` holds the stage a worker is running for that site, while it runs."""


class StageMarker:
    """Writes the running stage of one site to ``OUT/.progress/<site-id>`` (renamed into place, so a
    reader never sees half a name) and removes it when the site is done. Best effort: a worker on
    another host whose ``OUT`` is not shared just shows nothing."""

    def __init__(self, out: Path, site_id: str) -> None:
        self.path = out / PROGRESS_DIR / site_id

    def __call__(self, stage: str) -> None:
        try:
            write_text_atomic(self.path, stage)
        except OSError:
            pass

    def clear(self) -> None:
        """Remove the marker, and the folder when no other site is running."""
        try:
            self.path.unlink(missing_ok=True)
            self.path.parent.rmdir()
        except OSError:  # absent, or another worker's marker is still there
            pass


@dataclass(frozen=True)
class SiteTask:
    """Everything a worker needs to build one site (plain values, cheap to pickle)."""

    site_id: str
    record_path: str
    catalog_root: str
    out: str
    build_key: str
    key_material: dict[str, Any]
    run_id: str
    report_config: dict[str, Any] | None = None


def build_time() -> str:
    """When the report was built: ``SOURCE_DATE_EPOCH`` when set (reproducible pages), else now (UTC)."""
    from cistern_archive.report.files import build_time_from_env, format_time

    pinned = build_time_from_env()
    return format_time(pinned) if pinned is not None else utc_now()


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, in MiB."""
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def manifest(folder: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``folder``, sorted."""
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    return {p.relative_to(folder).as_posix(): file_sha256(p)[0] for p in files}


def run_site(task: SiteTask) -> SiteOutcome:
    """Build one site and publish its report atomically; never raises for a failure of the site.

    Returns
    -------
    SiteOutcome
        ``ok``, ``partial`` or ``failed`` (with ``reasons``); on failure ``error`` says where, and the previous report (if any) is kept
        unless the failure was a pipeline stage (whose failure report is published).
    """
    from cistern_archive.catalog.loader import load_record
    from cistern_archive.core.files import write_json_atomic
    from cistern_archive.pipeline.runner import build_site, write_site_result
    from cistern_archive.report.config import ReportConfig
    from cistern_archive.report.site import render_site

    start, cpu_start = time.perf_counter(), time.process_time()
    timings: dict[str, float] = {}
    staged: Path | None = None
    out = Path(task.out)
    marker = StageMarker(out, task.site_id)
    try:
        staged = staging_dir(out, task.site_id)
        loaded = load_record(Path(task.record_path), Path(task.catalog_root))
        check_inputs(task, loaded)
        if loaded.record.survey is not None:
            from cistern_archive.navigation.site import build_survey_site

            build = build_survey_site(loaded, on_stage=marker)
        else:
            build = build_site(loaded, on_stage=marker)
        timings.update(build.result.timings_s)
        marker("report")
        tick = time.perf_counter()
        artifacts = render_site(build, staged, config=ReportConfig(**(task.report_config or {})))
        write_site_result(build, staged, artifacts)
        timings["report"] = round(time.perf_counter() - tick, 6)
        files = manifest(staged)
        write_json_atomic({"site_id": task.site_id, "build_key": task.build_key, "status": build.result.status,
                           "run_id": task.run_id, "built_at": build_time(), "files": files,
                           "key_material": task.key_material},
                          staged / BUILD_INFO)
        tick = time.perf_counter()
        if not holds_lock(out, task.run_id):
            raise LostLock(f"{out}: rebuild {task.run_id} no longer holds the lock; {task.site_id} not published")
        marker("publish")
        publish(staged, out / task.site_id)
        staged = None
        timings["publish"] = round(time.perf_counter() - tick, 6)
        status, error, reasons = build.result.status, build.result.error, list(build.result.status_reasons)
        detail = build.result.failure.traceback if build.result.failure else ""
    except Exception as exc:
        status, files, reasons = "failed", {}, []
        error = f"{type(exc).__name__}: {exc}"
        detail = traceback.format_exc(limit=12)
    finally:
        marker.clear()
        if staged is not None:
            discard(staged)
    timings["wall"] = round(time.perf_counter() - start, 6)
    timings["cpu"] = round(time.process_time() - cpu_start, 6)
    return SiteOutcome(id=task.site_id, status=status, reasons=reasons or ([error] if error else []),
                       report_status=status if files else None, error=error, build_key=task.build_key, timings_s=timings,
                       report=f"{task.site_id}/index.html" if files else None, worker=worker_name(),
                       peak_rss_mb=peak_rss_mb(), attempts=1, artifacts=files, detail=detail)
