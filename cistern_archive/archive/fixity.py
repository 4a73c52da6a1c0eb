"""Fixity check: recompute the digest of every stored object and compare it with its name."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cistern_archive.archive.digest import file_sha256
from cistern_archive.archive.repository import Archive


@dataclass(frozen=True)
class FixityProblem:
    """One object that failed its check."""

    sha256: str
    kind: str
    """``mismatch`` (content changed), ``missing`` (indexed but absent), ``size`` (length differs),
    ``unreadable`` or ``unindexed`` (present but unknown to the index)."""
    path: Path
    detail: str

    def __str__(self) -> str:
        return f"{self.path}: {self.kind}: {self.detail}"


@dataclass
class FixityReport:
    checked: int = 0
    problems: list[FixityProblem] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def verify_archive(archive: Archive, *, run_id: str | None = None) -> FixityReport:
    """Recompute every object's SHA-256; record one ``fixity`` event per object.

    Objects the index lists but the store lacks are ``missing``; objects on disk the index does not
    list are ``unindexed`` (an ingest interrupted between the two writes, a deleted index): a problem,
    healed by the next ``rebuild`` or by ``repair``.
    """
    report = FixityReport()
    indexed = {row["sha256"]: row["size"] for row in archive.index.objects()}
    on_disk = set(archive.store.iter_digests())
    events = []
    for sha256, size in sorted(indexed.items()):
        path = archive.store.path_of(sha256)
        report.checked += 1
        problem = _check(sha256, size, path, present=sha256 in on_disk)
        if problem is not None:
            report.problems.append(problem)
        events.append((sha256, "failure" if problem else "success", problem.kind if problem else "sha256 matches"))
    for sha256 in sorted(on_disk - set(indexed)):
        report.problems.append(FixityProblem(sha256, "unindexed", archive.store.path_of(sha256),
                                             "object present in the store but not in the index"))
    with archive.index.transaction():
        for sha256, outcome, detail in events:
            archive.index.add_event("fixity", agent=archive.agent, outcome=outcome, run_id=run_id, sha256=sha256,
                                    detail=detail)
    return report


def _check(sha256: str, size: int, path: Path, *, present: bool) -> FixityProblem | None:
    if not present:
        return FixityProblem(sha256, "missing", path, "object listed in the index is not in the store")
    try:
        actual, actual_size = file_sha256(path)
    except OSError as exc:
        return FixityProblem(sha256, "unreadable", path, f"{type(exc).__name__}: {exc}")
    if actual != sha256:
        return FixityProblem(sha256, "mismatch", path, f"sha256 is {actual}, expected {sha256}")
    if actual_size != size:
        return FixityProblem(sha256, "size", path, f"{actual_size} bytes, index says {size}")
    return None
