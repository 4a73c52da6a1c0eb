"""Where site builds run: local worker processes (default) or a Dask distributed cluster.

Both executors take a function and a list of tasks and yield ``(task, result or exception)`` as each
finishes (``concurrent.futures.as_completed`` / ``distributed.as_completed``), so progress is reported
in completion order. One site is one task; a site's failure never cancels the others.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, TypeVar

from cistern_archive.core.errors import CisternError

T = TypeVar("T")
SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"
THREAD_LIMITS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS",
                 "VECLIB_MAXIMUM_THREADS", "NUMEXPR_MAX_THREADS", "VTK_SMP_MAX_THREADS")
MAX_ATTEMPTS = 2


class WorkerDied(RuntimeError):
    """The process building a site died (killed, out of memory, a crash in native code)."""


class LocalExecutor:
    """A pool of ``workers`` processes on this machine (started by a fork server, one thread each).

    Numeric libraries are limited to one thread per process (unless the environment already says
    otherwise), so ``N`` workers use ``N`` cores. A worker that dies breaks the pool: the pool is
    restarted and the unfinished sites are resubmitted, each at most :data:`MAX_ATTEMPTS` times.
    Workers die with the rebuild process however it ends
    (:func:`~cistern_archive.service.worker.die_with_parent`).
    """

    name = "local"

    def __init__(self, workers: int):
        if workers < 1:
            raise ValueError(f"--workers must be at least 1, got {workers}")
        self.workers = workers
        for var in THREAD_LIMITS:
            os.environ.setdefault(var, "1")
        method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
        self._context = multiprocessing.get_context(method)
        if method == "forkserver":
            self._context.set_forkserver_preload(["cistern_archive.service.worker"])
        self._pool: ProcessPoolExecutor | None = None

    def _new_pool(self) -> ProcessPoolExecutor:
        from cistern_archive.service.worker import die_with_parent  # deferred: the worker loads the report's VTK

        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=self._context,
                                         initializer=die_with_parent, initargs=(os.getpid(),))
        return self._pool

    def run(self, func: Callable[[T], Any], tasks: Sequence[T]) -> Iterator[tuple[T, Any]]:
        pending = list(tasks)
        attempts = {id(t): 0 for t in pending}
        while pending:
            pool = self._new_pool() if self._pool is None else self._pool
            futures = {}
            for task in pending:
                attempts[id(task)] += 1
                futures[pool.submit(func, task)] = task
            retry = []
            for future in as_completed(futures):
                task = futures[future]
                try:
                    yield task, future.result()
                except BrokenProcessPool:
                    if attempts[id(task)] >= MAX_ATTEMPTS:
                        yield task, WorkerDied(f"the worker process died {attempts[id(task)]} times while building it")
                    else:
                        retry.append(task)
                except Exception as exc:
                    yield task, exc
            if retry:
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._pool = None
            pending = retry

    def close(self, *, cancel: bool = False) -> None:
        """Shut the pool down; with ``cancel`` (an interrupt) stop the running builds at once.

        A stopped build leaves only its temporary folder (removed by the next rebuild); it never
        publishes after the rebuild has reported it unfinished.
        """
        if self._pool is None:
            return
        if cancel:
            for process in list((getattr(self._pool, "_processes", None) or {}).values()):
                process.terminate()
        self._pool.shutdown(wait=True, cancel_futures=cancel)
        self._pool = None


class DaskExecutor:
    """Sites as tasks on a Dask distributed cluster (``distributed.Client``).

    Parameters
    ----------
    address : str, optional
        Scheduler address (``tcp://host:8786``).
    scheduler_file : Path, optional
        A scheduler file written by ``dask scheduler --scheduler-file``.

    Workers must have this package (and the catalog's plugins) installed and see the catalog and
    output folders at the same paths (a shared file system).
    """

    name = "dask"

    def __init__(self, address: str | None = None, scheduler_file: Path | None = None, *, timeout: float = 30.0):
        from distributed import Client

        self.where = f"scheduler file {scheduler_file}" if scheduler_file is not None else str(address)
        try:
            if scheduler_file is not None:
                self.client = Client(scheduler_file=str(scheduler_file), timeout=timeout)
            else:
                self.client = Client(address, timeout=timeout)
        except (OSError, TimeoutError, ValueError) as exc:
            raise CisternError(f"cannot reach the Dask scheduler ({self.where}): {type(exc).__name__}: {exc}") from None
        info = self.client.scheduler_info()
        self.workers = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values())
        self.address = self.client.scheduler.address

    def run(self, func: Callable[[T], Any], tasks: Sequence[T]) -> Iterator[tuple[T, Any]]:
        from distributed import as_completed as dask_as_completed

        futures = {}
        for task in tasks:
            key = f"cistern-site-{getattr(task, 'site_id', 'task')}-{getattr(task, 'run_id', '')}"
            futures[self.client.submit(func, task, key=key, pure=False, retries=0)] = task
        try:
            for future in dask_as_completed(list(futures)):
                task = futures[future]
                try:
                    yield task, future.result()
                except Exception as exc:
                    yield task, exc
        finally:
            for future in futures:
                future.release()

    def close(self, *, cancel: bool = False) -> None:
        self.client.close()


def choose_executor(*, workers: int, scheduler: str | None = None,
                    scheduler_file: Path | None = None) -> LocalExecutor | DaskExecutor:
    """``--scheduler``, then ``--scheduler-file``, then ``$DASK_SCHEDULER_ADDRESS``; else local processes."""
    if scheduler:
        return DaskExecutor(address=scheduler)
    if scheduler_file is not None:
        return DaskExecutor(scheduler_file=scheduler_file)
    env = os.environ.get(SCHEDULER_ENV)
    if env:
        return DaskExecutor(address=env)
    return LocalExecutor(workers)
