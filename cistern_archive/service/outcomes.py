"""A site's outcome in a rebuild: the archive's ``build`` and ``publish`` events and the run log's line."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cistern_archive.archive.repository import Archive
from cistern_archive.service.runlog import RunLog
from cistern_archive.service.summary import SiteOutcome
from cistern_archive.service.worker import SiteTask


def outcome_of(task: SiteTask, result: Any) -> SiteOutcome:
    """What a worker returned as a :class:`SiteOutcome` (an exception or a stray value: a failed site)."""
    if isinstance(result, SiteOutcome):
        return result
    message = f"{type(result).__name__}: {result}" if isinstance(result, BaseException) else repr(result)
    return SiteOutcome(id=task.site_id, status="failed", error=f"worker: {message}", build_key=task.build_key)


def file_size(path: Path) -> int:
    """Size of a published file in bytes, -1 when it cannot be read."""
    try:
        return path.stat().st_size
    except OSError:
        return -1


BUILD_EVENT_OUTCOME = {"ok": "success", "partial": "partial", "failed": "failure", "skipped": "skipped"}


def record_outcome(archive: Archive, run_id: str, outcome: SiteOutcome, out: Path) -> None:
    """``build`` event, and for a published site its artifacts and a ``publish`` event."""
    index = archive.index
    with index.transaction():
        index.add_event("build", agent=archive.agent, outcome=BUILD_EVENT_OUTCOME[outcome.status],
                        run_id=run_id, site_id=outcome.id,
                        detail={"build_key": outcome.build_key, "error": outcome.error, "worker": outcome.worker,
                                "seconds": outcome.timings_s.get("wall")})
        if outcome.artifacts:
            for path, sha256 in outcome.artifacts.items():
                index.add_artifact(run_id, outcome.id, path, sha256, file_size(out / outcome.id / path))
            index.add_event("publish", agent=archive.agent, outcome="success", run_id=run_id, site_id=outcome.id,
                            detail={"folder": outcome.id, "files": len(outcome.artifacts),
                                    "build_key": outcome.build_key})


def log_outcome(log: RunLog, outcome: SiteOutcome) -> None:
    """One line per site in the run log; a failure with its detail, a partial site with its reasons."""
    seconds = outcome.timings_s.get("wall")
    took = f" in {seconds:.2f} s" if seconds is not None else ""
    line = f"site {outcome.id}: {outcome.status}{took} (key {outcome.build_key[:12]}, worker {outcome.worker})"
    if outcome.status == "failed":
        log.write(f"{line}: {outcome.error}\n{outcome.detail}".rstrip(), "ERROR")
    elif outcome.status == "partial":
        log.write(f"{line}: {'; '.join(outcome.reasons)}", "WARN")
    else:
        log.write(line)
