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

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from cistern_archive.archive.digest import file_sha256
from cistern_archive.archive.index import utc_now
from cistern_archive.archive.repository import Archive, default_archive_dir
from cistern_archive.catalog.loader import SURVEY_INPUTS, LoadedRecord, record_paths
from cistern_archive.core.errors import CatalogError, CisternError, EnvironmentProblem
from cistern_archive.pipeline.registry import Registry, default_registry
from cistern_archive.service.buildkey import BuildKey, build_key, code_version
from cistern_archive.service.executors import choose_executor
from cistern_archive.service.lock import RebuildLock
from cistern_archive.service.publish import recover
from cistern_archive.service.runlog import LOG_DIR, RunLog, new_run_id
from cistern_archive.service.summary import RebuildSummary, SiteOutcome
from cistern_archive.service.worker import BUILD_INFO, PROGRESS_DIR, SiteTask, run_site
from cistern_archive.sonar import marina

SUMMARY_NAME = "summary.json"


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


@dataclass(frozen=True)
class SitePlan:
    loaded: LoadedRecord
    key: BuildKey
    repairs: tuple[str, ...] = ()
    """Archived copies of the site's inputs that were damaged or missing and were restored."""

    @property
    def site_id(self) -> str:
        return self.loaded.record.id


def site_inputs(loaded: LoadedRecord) -> list[tuple[str, str]]:
    """``(role, path relative to the catalog root)`` of every file the record references."""
    record = loaded.record
    items = [("scan", scan.file) for scan in record.scans]
    if record.simulation:
        items.append(("simulation", record.simulation))
    if record.survey is not None:
        items += [("survey", SURVEY_INPUTS + name) for name in marina.dataset_files(loaded.survey_root())]
    return sorted(set(items), key=lambda item: item[1])


def unreadable_inputs(loaded: LoadedRecord) -> set[str]:
    """The record's scan files that are plainly not of their format, judged from their headers only.

    They are not copied into the archive (a junk file of any size would otherwise be kept for ever);
    the site's build then fails at its ``load`` stage naming the file and the problem.
    """
    from cistern_archive.core.errors import ReaderError
    from cistern_archive.sonar.readers import check_file

    refused = set()
    for scan in loaded.record.scans:
        try:
            check_file(loaded.resolve(scan.file), scan.format)
        except ReaderError:
            refused.add(scan.file)
    return refused


def plan_site(loaded: LoadedRecord, archive: Archive, registry: Registry, run_id: str | None,
              report_config: dict[str, Any] | None = None) -> SitePlan:
    """Archive the site's record and inputs (copies only new content) and compute its build key."""
    site_id = loaded.record.id
    record_rel = loaded.path.resolve().relative_to(loaded.root).as_posix()
    refused = unreadable_inputs(loaded)
    items = [archive.ingest(loaded.path, site_id=site_id, role="record", relative_path=record_rel, run_id=run_id)]
    digests = {}
    for role, relative in site_inputs(loaded):
        if relative in refused:
            digests[relative] = file_sha256(loaded.input_path(relative))[0]
            continue
        items.append(archive.ingest(loaded.input_path(relative), site_id=site_id, role=role, relative_path=relative,
                                    run_id=run_id))
        digests[relative] = items[-1].sha256
    archive.index.touch_site(site_id, loaded.record.name, record_rel)
    repairs = tuple(f"restored the archived copy of {item.relative_path} ({item.sha256[:12]}), which was "
                    f"{item.repaired}" for item in items if item.repaired)
    return SitePlan(loaded=loaded, key=build_key(loaded, digests, registry, report_config), repairs=repairs)


def plan_sites(selected: list[LoadedRecord], store: Archive, registry: Registry, run_id: str,
               report_config: dict[str, Any] | None, log: RunLog) -> tuple[list[SitePlan], list[SiteOutcome]]:
    """Plan every selected site; a site whose inputs cannot be read or archived fails alone.

    Raises
    ------
    EnvironmentProblem
        The archive itself cannot be written (a full or read-only disk): no site can be planned.
    """
    plans, failed = [], []
    for loaded in selected:
        try:
            plans.append(plan_site(loaded, store, registry, run_id, report_config))
        except EnvironmentProblem:
            raise
        except (CisternError, OSError, ValueError) as exc:
            message = str(exc) if isinstance(exc, CisternError) else f"{type(exc).__name__}: {exc}"
            outcome = SiteOutcome(id=loaded.record.id, status="failed", build_key="",
                                  error=f"archiving its inputs: {message}")
            failed.append(outcome)
            _record_outcome(store, run_id, outcome, Path("."))
            _log_outcome(log, outcome)
    return plans, failed


def published_build(site_dir: Path) -> dict[str, Any] | None:
    """The ``build.json`` of a published site, or None when absent or unreadable."""
    try:
        data = json.loads((site_dir / BUILD_INFO).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


CURRENT_STATUSES = ("ok", "partial")
"""Published statuses a build key can stand for: the same inputs give the same ``partial`` build
again, while a ``failed`` one may have failed for a reason outside its inputs and is retried."""


def is_current(site_dir: Path, key: str) -> bool:
    """Whether the published report was built with ``key``, ran to the end (``ok`` or ``partial``)
    and is complete on disk."""
    info = published_build(site_dir)
    if info is None or info.get("build_key") != key or info.get("status") not in CURRENT_STATUSES:
        return False
    files = info.get("files") or {}
    return bool(files) and all((site_dir / name).is_file() for name in files)


def select_sites(records: list[LoadedRecord], wanted: list[str] | None, problems: list[str]) -> list[LoadedRecord]:
    """The records to rebuild: all valid ones, or those named by ``--site`` (unknown names are refused)."""
    if not wanted:
        return records
    by_id = {loaded.record.id: loaded for loaded in records}
    unknown = [site for site in wanted if site not in by_id]
    if unknown:
        known = ", ".join(sorted(by_id)) or "none"
        raise CatalogError(problems + [f"--site {name}: no valid site record with this id (valid: {known})"
                                       for name in unknown])
    return [by_id[site] for site in dict.fromkeys(wanted)]


def _outcome(task: SiteTask, result: Any) -> SiteOutcome:
    if isinstance(result, SiteOutcome):
        return result
    message = f"{type(result).__name__}: {result}" if isinstance(result, BaseException) else repr(result)
    return SiteOutcome(id=task.site_id, status="failed", error=f"worker: {message}", build_key=task.build_key)


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return -1


BUILD_EVENT_OUTCOME = {"ok": "success", "partial": "partial", "failed": "failure", "skipped": "skipped"}


def _record_outcome(archive: Archive, run_id: str, outcome: SiteOutcome, out: Path) -> None:
    """``build`` event, and for a published site its artifacts and a ``publish`` event."""
    index = archive.index
    with index.transaction():
        index.add_event("build", agent=archive.agent, outcome=BUILD_EVENT_OUTCOME[outcome.status],
                        run_id=run_id, site_id=outcome.id,
                        detail={"build_key": outcome.build_key, "error": outcome.error, "worker": outcome.worker,
                                "seconds": outcome.timings_s.get("wall")})
        if outcome.artifacts:
            for path, sha256 in outcome.artifacts.items():
                index.add_artifact(run_id, outcome.id, path, sha256, _size(out / outcome.id / path))
            index.add_event("publish", agent=archive.agent, outcome="success", run_id=run_id, site_id=outcome.id,
                            detail={"folder": outcome.id, "files": len(outcome.artifacts),
                                    "build_key": outcome.build_key})


def _log_outcome(log: RunLog, outcome: SiteOutcome) -> None:
    seconds = outcome.timings_s.get("wall")
    took = f" in {seconds:.2f} s" if seconds is not None else ""
    line = f"site {outcome.id}: {outcome.status}{took} (key {outcome.build_key[:12]}, worker {outcome.worker})"
    if outcome.status == "failed":
        log.write(f"{line}: {outcome.error}\n{outcome.detail}".rstrip(), "ERROR")
    elif outcome.status == "partial":
        log.write(f"{line}: {'; '.join(outcome.reasons)}", "WARN")
    else:
        log.write(line)


def clear_progress(out: Path) -> None:
    """Remove the stage markers of the workers (``OUT/.progress``; any left by a killed rebuild)."""
    import shutil

    shutil.rmtree(out / PROGRESS_DIR, ignore_errors=True)


def published_sites(out: Path, site_ids: list[str]) -> list[str]:
    """The catalog's sites that have a published ``result.json``, sorted."""
    return sorted(site_id for site_id in site_ids if (out / site_id / "result.json").is_file())


def index_key(out: Path, sites: list[str], code: str) -> str:
    """A digest of what ``OUT/index.html`` shows: the code version and, per published site, its
    ``build.json`` (build key, run, build time, status)."""
    import hashlib

    from cistern_archive.service.buildkey import canonical_json

    shown = []
    for site_id in sites:
        info = published_build(out / site_id) or {}
        shown.append([site_id, *(info.get(k) for k in ("build_key", "run_id", "built_at", "status"))])
    return hashlib.sha256(canonical_json({"code_version": code, "sites": shown}).encode("utf-8")).hexdigest()


def index_is_current(out: Path, key: str) -> bool:
    """Whether ``OUT/index.html`` was rendered from exactly the published reports ``key`` describes
    (recorded in the previous ``summary.json``; a crash between a publish and the index write leaves an
    older key there, so the index is rendered again)."""
    if not (out / "index.html").is_file():
        return False
    try:
        previous = json.loads((out / SUMMARY_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(previous, dict) and previous.get("index_key") == key


def index_entries(out: Path, site_ids: list[str]):
    """One :class:`~cistern_archive.report.IndexEntry` per published site, in site-id order."""
    from cistern_archive.pipeline.results import SiteResult
    from cistern_archive.report.index import IndexEntry

    entries = []
    for site_id in sorted(site_ids):
        site_dir = out / site_id
        try:
            result = SiteResult.model_validate_json((site_dir / "result.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        built_at = (published_build(site_dir) or {}).get("built_at") or ""
        entries.append(IndexEntry.from_result(result, build_time=built_at))
    return entries


def write_index(out: Path, site_ids: list[str]) -> Path:
    """Render ``OUT/index.html`` for every published site of the catalog and move it into place atomically.

    The page is rendered in a temporary sibling folder whose entries link to the site folders, so that
    the renderer sees the thumbnails, and then renamed over the previous index.
    """
    import os
    import shutil
    import tempfile

    from cistern_archive.report.index import render_index

    staging = Path(tempfile.mkdtemp(prefix=".index.tmp-", dir=out))
    try:
        for site_id in site_ids:
            if (out / site_id).is_dir():
                (staging / site_id).symlink_to(out / site_id, target_is_directory=True)
        page = render_index(index_entries(out, site_ids), staging)
        os.replace(page, out / "index.html")
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out / "index.html"


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
            outcome = _outcome(task, result)
            done.add(task.site_id)
            summary.sites.append(outcome)
            _record_outcome(store, summary.run_id, outcome, out)
            _log_outcome(log, outcome)
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
