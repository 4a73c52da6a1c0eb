"""Planning a rebuild: which sites to build, their inputs archived and their build keys, and whether a
published build is still current (steps 3–4 of :mod:`cistern_archive.service.rebuild`)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cistern_archive.archive.digest import file_sha256
from cistern_archive.archive.repository import Archive
from cistern_archive.catalog.loader import SURVEY_INPUTS, LoadedRecord
from cistern_archive.core.errors import CatalogError, CisternError, EnvironmentProblem, ReaderError
from cistern_archive.pipeline.registry import Registry
from cistern_archive.service.buildkey import BuildKey, build_key
from cistern_archive.service.outcomes import log_outcome, record_outcome
from cistern_archive.service.runlog import RunLog
from cistern_archive.service.summary import SiteOutcome
from cistern_archive.service.worker import BUILD_INFO
from cistern_archive.sonar import marina
from cistern_archive.sonar.readers import check_file


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
            record_outcome(store, run_id, outcome, Path("."))
            log_outcome(log, outcome)
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
