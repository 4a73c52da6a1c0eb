"""The nightly rebuild: validate, archive the inputs, skip unchanged sites, build the rest in workers,
publish atomically, write the index, ``summary.json`` and a run log.

Order of a rebuild of ``OUT``:

0. refuse a missing or empty catalog folder before anything is written;
1. take ``OUT/.rebuild.lock`` (refused while another rebuild runs; a stale lock is taken over; it names
   this run, which workers check before publishing) and clean up after any interrupted rebuild
   (:func:`~cistern_archive.service.publish.recover`);
2. validate the catalog; the valid records are built even when others have problems (exit code 2);
3. clean the archive's leftovers of dead processes and index objects stored without their index row;
   ingest every input of every selected site into the archive (re-checking the stored copies it relies
   on, restoring damaged ones from intact originals; scan files their reader refuses from the headers
   are not copied) and compute its build key; a site whose inputs cannot be read fails alone, an
   archive that cannot be written stops the rebuild (:class:`~cistern_archive.core.errors.EnvironmentProblem`);
4. skip the sites whose published ``build.json`` has the same key and status ``ok`` or ``partial``
   (unless ``force``; a ``failed`` site is always retried);
5. run :func:`~cistern_archive.service.worker.run_site` for the others on the chosen executor, in
   completion order, recording ``build`` and ``publish`` events and the published artifacts;
6. render ``OUT/index.html`` from every published site (kept when the published reports it shows are
   exactly those recorded with the previous index in ``summary.json``) and write ``OUT/summary.json``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Protocol

from cistern_archive.archive.index import utc_now
from cistern_archive.archive.repository import Archive, default_archive_dir
from cistern_archive.catalog.loader import record_paths
from cistern_archive.core.errors import CatalogError
from cistern_archive.pipeline.registry import Registry, default_registry
from cistern_archive.service.buildkey import code_version
from cistern_archive.service.executors import choose_executor
from cistern_archive.service.lock import RebuildLock
from cistern_archive.service.outcomes import log_outcome, outcome_of, record_outcome
from cistern_archive.service.publish import recover
from cistern_archive.service.runlog import LOG_DIR, RunLog, new_run_id
from cistern_archive.service.summary import SUMMARY_NAME, RebuildSummary, SiteOutcome
from cistern_archive.service.index_page import index_is_current, index_key, published_sites, write_index
from cistern_archive.service.planning import SitePlan, is_current, plan_sites, published_build, select_sites
from cistern_archive.service.worker import PROGRESS_DIR, SiteTask, run_site

class Progress(Protocol):
    """What a rebuild reports while it runs (the CLI draws bars or prints lines)."""

    def start(self, total: int, skipped: int, executor: str) -> None:  # pragma: no cover
        ...

    def site_done(self, outcome: SiteOutcome) -> None:  # pragma: no cover
        ...


class NullProgress:
    def start(self, total: int, skipped: int, executor: str) -> None:
        pass

    def site_done(self, outcome: SiteOutcome) -> None:
        pass


def clear_progress(out: Path) -> None:
    """Remove the stage markers of the workers (``OUT/.progress``; any left by a killed rebuild)."""
    import shutil

    shutil.rmtree(out / PROGRESS_DIR, ignore_errors=True)


def rebuild(
    catalog: Path,
    out: Path,
    *,
    sites: list[str] | None = None,
    workers: int = 1,
    force: bool = False,
    scheduler: str | None = None,
    scheduler_file: Path | None = None,
    archive: Path | None = None,
    progress: Progress | None = None,
    registry: Registry | None = None,
    report_config: dict[str, Any] | None = None,
) -> RebuildSummary:
    """Rebuild the catalog's reports into ``out``.

    Parameters
    ----------
    catalog, out : Path
        The catalog root and the output folder.
    sites : list of str, optional
        Only these site ids (all valid records when omitted).
    workers : int
        Local worker processes (ignored with a Dask scheduler).
    force : bool
        Rebuild sites whose build key did not change.
    scheduler, scheduler_file : optional
        Use the Dask cluster at this address / described by this file (also ``$DASK_SCHEDULER_ADDRESS``).
    archive : Path, optional
        The archive folder (:func:`~cistern_archive.archive.default_archive_dir` when omitted).
    progress : Progress, optional
        Receives the number of sites and each outcome as it completes.
    registry : Registry, optional
        The plugin registry (the installed plugins when omitted).
    report_config : dict, optional
        :class:`~cistern_archive.report.config.ReportConfig` fields to override (part of the build key).

    Returns
    -------
    RebuildSummary
        Also written to ``OUT/summary.json``; its ``exit_code`` is 0, 1 or 2.

    Raises
    ------
    RebuildLocked
        Another rebuild holds ``OUT``.
    CatalogError
        There is no catalog at ``catalog``, or ``--site`` names no valid record.
    EnvironmentProblem
        ``OUT`` or the archive cannot be written (a full or read-only disk) or the archive index is
        damaged; found while taking the lock or archiving, that is before any site is built.
    KeyboardInterrupt
        Re-raised after writing a summary marked ``interrupted`` (unfinished sites keep their previous
        report).
    """
    from cistern_archive.pipeline.validate import validate_catalog

    started = time.perf_counter()
    catalog, out = Path(catalog).resolve(), Path(out).resolve()
    require_catalog(catalog)
    archive_dir = Path(archive).resolve() if archive is not None else default_archive_dir(catalog)
    progress = progress or NullProgress()
    registry = registry or default_registry()
    run_id = new_run_id()
    with RebuildLock(out, run_id) as lock, RunLog(out / LOG_DIR / f"{run_id}.log") as log:
        summary = RebuildSummary(run_id=run_id, started_at=utc_now(), catalog=str(catalog), out=str(out),
                                 archive=str(archive_dir), executor="local", workers=workers, force=force,
                                 code_version=code_version(), stale_lock=lock.stale,
                                 log=f"{LOG_DIR}/{run_id}.log")
        log.write(f"rebuild {run_id}: catalog {catalog} -> {out}; archive {archive_dir}; {code_version()}")
        if lock.stale:
            log.write(f"took over a stale lock left by pid {lock.stale.get('pid')} (not running)", "WARN")
        summary.recovered = recover(out)
        clear_progress(out)
        for action in summary.recovered:
            log.write(f"recovery: {action}", "WARN")
        # A plugin that fails to import fails the sites that use it (exit 1), not the catalog (exit 2).
        report = validate_catalog(catalog, registry, plugin_load_errors=False)
        summary.catalog_problems = list(report.problems)
        for problem in report.problems:
            log.write(problem, "ERROR")
        selected = select_sites(report.records, sites, report.problems)
        with Archive(archive_dir) as store:
            _recover_archive(store, run_id, out, summary, log)
            plans, unplanned = plan_sites(selected, store, registry, run_id, report_config, log)
            summary.sites.extend(unplanned)
            for repair in (f"{p.site_id}: {r}" for p in plans for r in p.repairs):
                summary.recovered.append(repair)
                log.write(f"recovery: {repair}", "WARN")
            todo = [p for p in plans if force or not is_current(out / p.site_id, p.key.key)]
            skipped = [SiteOutcome(id=p.site_id, status="skipped", build_key=p.key.key,
                                   report=f"{p.site_id}/index.html",
                                   report_status=(published_build(out / p.site_id) or {}).get("status"))
                       for p in plans if p not in todo]
            summary.sites.extend(skipped)
            for outcome in skipped:
                log.write(f"site {outcome.id}: unchanged (key {outcome.build_key[:12]}), skipped")
            _execute(todo, summary, store, log, progress, out=out, catalog=catalog, workers=workers,
                     scheduler=scheduler, scheduler_file=scheduler_file, skipped=len(skipped),
                     report_config=report_config)
            clear_progress(out)
            summary.sites.sort(key=lambda s: s.id)
            summary.index_sites = published_sites(out, [loaded.record.id for loaded in report.records])
            summary.index_key = index_key(out, summary.index_sites, summary.code_version)
            if index_is_current(out, summary.index_key):
                log.write("index unchanged")
            else:
                write_index(out, summary.index_sites)
            summary.finished_at = utc_now()
            summary.seconds = round(time.perf_counter() - started, 3)
            store.index.finish_run(run_id, "interrupted" if summary.interrupted else
                                   ("ok" if summary.exit_code == 0 else "failed"), summary.counts(),
                                   executor=summary.executor)
        summary.write(out / SUMMARY_NAME)
        counts = summary.counts()
        log.write(f"done in {summary.seconds:.2f} s: {counts['ok']} ok, {counts['partial']} partial, "
                  f"{counts['failed']} failed, "
                  f"{counts['skipped']} skipped; exit code {130 if summary.interrupted else summary.exit_code}")
    if summary.interrupted:
        raise KeyboardInterrupt
    return summary


def require_catalog(catalog: Path) -> None:
    """Refuse, before anything is written, a catalog folder that is missing or holds no site records.

    Raises
    ------
    CatalogError
        Naming the folder.
    """
    if not catalog.is_dir():
        raise CatalogError([f"{catalog}:1: (catalog): not a directory; give the catalog with --catalog"])
    if not record_paths(catalog):
        raise CatalogError([f"{catalog}:1: (catalog): no site records (*.yaml here or in sites/); "
                            "give the catalog with --catalog"])


def _recover_archive(store: Archive, run_id: str, out: Path, summary: RebuildSummary, log: RunLog) -> None:
    """Clean up after interrupted rebuilds sharing the archive: temporary objects of dead processes,
    objects stored without their index row, runs into ``out`` that never finished."""
    store.store.clean_tmp()
    healed = store.index_strays(run_id=run_id)
    store.index.start_run(run_id, catalog=summary.catalog, out=str(out), executor="pending", agent=store.agent)
    abandoned = store.index.abandon_runs(str(out), keep=run_id)
    if abandoned:
        healed.append(f"marked {abandoned} unfinished earlier run(s) as abandoned")
    for action in healed:
        log.write(f"recovery: {action}", "WARN")
    summary.recovered.extend(healed)


def _fail_unfinished(tasks: list[SiteTask], done: set[str], summary: RebuildSummary, error: str) -> None:
    for task in tasks:
        if task.site_id not in done:
            summary.sites.append(SiteOutcome(id=task.site_id, status="failed", build_key=task.build_key, error=error))


def _execute(plans: list[SitePlan], summary: RebuildSummary, store: Archive, log: RunLog, progress: Progress, *,
             out: Path, catalog: Path, workers: int, scheduler: str | None, scheduler_file: Path | None,
             skipped: int, report_config: dict[str, Any] | None) -> None:
    # Longest first (the pair count grows with the square of the scans), so that no long site is left
    # to run alone at the end.
    ordered = sorted(plans, key=lambda p: (-len(p.loaded.record.scans), p.site_id))
    tasks = [SiteTask(site_id=p.site_id, record_path=str(p.loaded.path.resolve()), catalog_root=str(catalog),
                      out=str(out), build_key=p.key.key, key_material=p.key.material, run_id=summary.run_id,
                      report_config=report_config)
             for p in ordered]
    executor = choose_executor(workers=workers, scheduler=scheduler, scheduler_file=scheduler_file) if tasks else None
    if executor is not None:
        summary.executor = executor.name if executor.name == "local" else f"dask {executor.address}"
        summary.workers = executor.workers
    log.write(f"{len(tasks)} site(s) to build on {summary.executor} with {summary.workers} worker(s), "
              f"{skipped} unchanged")
    progress.start(len(tasks) + skipped, skipped, summary.executor)
    if executor is None:
        return
    done: set[str] = set()
    try:
        for task, result in executor.run(run_site, tasks):
            outcome = outcome_of(task, result)
            done.add(task.site_id)
            summary.sites.append(outcome)
            record_outcome(store, summary.run_id, outcome, out)
            log_outcome(log, outcome)
            progress.site_done(outcome)
    except KeyboardInterrupt:
        summary.interrupted = True
        executor.close(cancel=True)
        executor = None
        _fail_unfinished(tasks, done, summary, "interrupted; the previous report (if any) is kept")
        log.write("interrupted", "ERROR")
    except Exception as exc:  # the executor itself failed (e.g. the Dask scheduler went away)
        message = f"executor {summary.executor} failed: {type(exc).__name__}: {exc}"
        _fail_unfinished(tasks, done, summary, message + "; the previous report (if any) is kept")
        log.write(message, "ERROR")
    finally:
        if executor is not None:
            executor.close()
