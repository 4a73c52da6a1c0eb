"""Repair of an archive: restore damaged or missing objects from their originals, index stray objects,
replace a damaged index.

Nothing is ever deleted: a damaged ``index.sqlite`` is renamed ``index.sqlite.damaged-<UTC time>``
(with its ``-wal``/``-shm`` files) before a new one is made from the objects on disk, and a damaged
object is replaced only by a file whose SHA-256 equals the object's name. Candidate originals are the
paths the index recorded for the digest and every file under the catalog. Each restored object gets a
``fixity`` failure and an ``ingest`` event with ``"repaired"``.
"""

from __future__ import annotations

import datetime as dt
import os
from dataclasses import dataclass, field
from pathlib import Path

from cistern_archive.archive.digest import file_sha256
from cistern_archive.archive.fixity import FixityReport, verify_archive
from cistern_archive.archive.index import DamagedIndex
from cistern_archive.archive.repository import INDEX_NAME, Archive
from cistern_archive.archive.store import DamagedObject


@dataclass
class RepairReport:
    """What :func:`repair_archive` did and what it could not do."""

    actions: list[str] = field(default_factory=list)
    unrepaired: list[str] = field(default_factory=list)
    after: FixityReport | None = None

    @property
    def ok(self) -> bool:
        return not self.unrepaired and self.after is not None and self.after.ok


def set_aside_index(root: Path) -> Path:
    """Rename a damaged ``index.sqlite`` (and its journal files) out of the way; return its new name."""
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ")
    kept = root / f"{INDEX_NAME}.damaged-{stamp}"
    for suffix in ("", "-wal", "-shm"):
        path = root / f"{INDEX_NAME}{suffix}"
        if path.exists():
            os.replace(path, root / f"{kept.name}{suffix}")
    return kept


def open_or_replace_index(root: Path, report: RepairReport) -> Archive:
    """The archive at ``root``; a damaged index is set aside first and a new one created."""
    archive = None
    try:
        archive = Archive(root)
        check = archive.index.db.execute("PRAGMA quick_check").fetchone()[0]
        if check != "ok":
            raise DamagedIndex(f"{root / INDEX_NAME}: archive index is damaged: {check}")
        return archive
    except DamagedIndex as exc:
        if archive is not None:
            archive.close()
        kept = set_aside_index(root)
        report.actions.append(f"set aside the damaged index as {kept.name} ({exc})")
        return Archive(root)


def catalog_digests(catalog: Path | None) -> dict[str, list[Path]]:
    """``{sha256: [files]}`` of every file under the catalog (the originals an object may be restored from)."""
    found: dict[str, list[Path]] = {}
    if catalog is None or not catalog.is_dir():
        return found
    for path in sorted(p for p in catalog.rglob("*") if p.is_file() and not p.is_symlink()):
        try:
            found.setdefault(file_sha256(path)[0], []).append(path)
        except OSError:
            continue
    return found


def _restore(archive: Archive, sha256: str, damage: str, candidates: list[Path]) -> str | None:
    """Restore one object from the first candidate with its digest; the path used, or None."""
    for source in candidates:
        try:
            stored = archive.store.restore(source, sha256)
        except (DamagedObject, OSError):
            continue
        with archive.index.transaction():
            archive.index.add_event("fixity", agent=archive.agent, outcome="failure", sha256=sha256, detail=damage)
            if not archive.index.has_object(sha256):
                archive.index.add_object(sha256, stored.size)
            archive.index.add_event("ingest", agent=archive.agent, outcome="success", sha256=sha256,
                                    detail={"source": str(source), "size": stored.size, "repaired": damage})
        return str(source)
    return None


def repair_archive(root: Path, catalog: Path | None = None) -> RepairReport:
    """Bring the archive at ``root`` back to a state where ``verify`` finds nothing.

    Parameters
    ----------
    root : Path
        The archive folder.
    catalog : Path, optional
        A catalog whose files may be the originals of damaged or missing objects.

    Returns
    -------
    RepairReport
        ``actions`` taken, objects left ``unrepaired`` (no original with their digest was found), and
        the fixity check made afterwards.
    """
    report = RepairReport()
    with open_or_replace_index(Path(root), report) as archive:
        report.actions += archive.index_strays()
        before = verify_archive(archive)
        from_catalog = catalog_digests(catalog) if before.problems else {}
        for problem in before.problems:
            candidates = [Path(p) for p in archive.index.sources_of(problem.sha256)]
            candidates += [p for p in from_catalog.get(problem.sha256, []) if p not in candidates]
            used = _restore(archive, problem.sha256, f"{problem.kind}: {problem.detail}", candidates)
            if used is None:
                report.unrepaired.append(f"{problem}; no original with sha256 {problem.sha256} was found")
            else:
                report.actions.append(f"restored {problem.kind} object {problem.sha256} from {used}")
        report.after = verify_archive(archive)
    return report
