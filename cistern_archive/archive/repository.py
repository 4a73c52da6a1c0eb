"""The archive: an object store plus its index, and the operations the service performs on them.

Raw inputs are ingested by copy: the archive keeps its own read-only copy of every version of every
input and never opens the originals for writing. Digests of unchanged files (same path, size and
modification time as their last ingest) are taken from the index instead of being recomputed;
``verify`` recomputes every stored object's digest.

An ingest always checks the stored object it relies on: a damaged or missing object is restored from
the file being ingested when that file has the object's digest (a ``fixity`` failure and an ``ingest``
event with ``"repaired"`` are recorded), and an object found on disk without its index row (a crash
between the copy and the index commit, a deleted index) is indexed again. Storing an object and
indexing it are therefore one recoverable step.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cistern_archive import __version__
from cistern_archive.archive.digest import file_sha256
from cistern_archive.archive.index import Index
from cistern_archive.archive.store import ObjectStore

ARCHIVE_ENV = "CISTERN_ARCHIVE"
INDEX_NAME = "index.sqlite"


def agent() -> str:
    """The agent recorded with every event: this software and its version."""
    return f"cistern-archive {__version__}"


def default_archive_dir(catalog: Path | None = None) -> Path:
    """Where the archive lives when no ``--archive`` is given.

    ``$CISTERN_ARCHIVE`` when set; otherwise ``.archive`` beside the catalog folder (for the bundled
    ``catalog/`` that is ``.archive`` at the repository root), or in the working directory.
    The archive is kept out of the published site folder: it holds raw data that reports may redact.
    """
    env = os.environ.get(ARCHIVE_ENV)
    if env:
        return Path(env)
    if catalog is not None:
        return Path(catalog).resolve().parent / ".archive"
    return Path(".archive")


@dataclass(frozen=True)
class IngestedInput:
    """One input file as the archive knows it."""

    source: Path
    relative_path: str
    role: str
    sha256: str
    size: int
    stored: bool
    """True when this call added a new object to the store."""
    digested: bool
    """True when the digest was computed (not taken from the index)."""
    repaired: str | None = None
    """What was wrong with the stored object when this ingest restored it (``missing``, ``damaged: …``)."""


class Archive:
    """Content-addressed store and SQLite index under one folder.

    Parameters
    ----------
    root : Path
        The archive folder; created (with ``objects/``, ``tmp/`` and ``index.sqlite``) when missing.
    """

    def __init__(self, root: Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.store = ObjectStore(self.root)
        self.index = Index(self.root / INDEX_NAME)
        self.agent = agent()

    def close(self) -> None:
        self.index.close()

    def __enter__(self) -> "Archive":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def ingest(self, source: Path, *, site_id: str | None = None, role: str = "input",
               relative_path: str | None = None, run_id: str | None = None) -> IngestedInput:
        """Add a file to the archive (a no-op apart from the index when it is already there).

        Parameters
        ----------
        source : Path
            The raw file; only read.
        site_id : str, optional
            The site it belongs to.
        role : str
            ``scan``, ``record``, ``simulation`` or ``input``.
        relative_path : str, optional
            Its path inside the catalog (the name used in exports); the file name when omitted.
        run_id : str, optional
            The rebuild that ingested it.
        """
        source = Path(source).resolve()
        info = source.stat()
        relative_path = relative_path or source.name
        cached = self.index.latest_input(str(source))
        digested = False
        if cached is not None and cached["size"] == info.st_size and cached["mtime_ns"] == info.st_mtime_ns:
            sha256, size = cached["sha256"], cached["size"]
        else:
            (sha256, size), digested = file_sha256(source), True
        damage = self.store.damage(sha256)
        if damage is not None and not digested:  # the cached digest is only trusted with an intact object
            (sha256, size), digested = file_sha256(source), True
            damage = self.store.damage(sha256)
        expected = self.index.has_object(sha256)
        repaired = damage if damage is not None and (expected or damage != "missing") else None
        stored = None
        if damage is not None:
            stored = self.store.restore(source, sha256) if repaired else self.store.put(source, sha256)
        with self.index.transaction():
            if digested:
                self.index.add_event("digest", agent=self.agent, outcome="success", run_id=run_id, site_id=site_id,
                                     sha256=sha256, detail={"algorithm": "sha256", "source": str(source)})
            if repaired:
                self.index.add_event("fixity", agent=self.agent, outcome="failure", run_id=run_id, site_id=site_id,
                                     sha256=sha256, detail=repaired)
            if not expected:
                self.index.add_object(sha256, size)
            if stored is not None or not expected:
                detail: dict[str, Any] = {"source": str(source), "size": size}
                if repaired:
                    detail["repaired"] = repaired
                elif stored is None:
                    detail["indexed"] = "the object was in the store without its index row"
                self.index.add_event("ingest", agent=self.agent, outcome="success", run_id=run_id, site_id=site_id,
                                     sha256=sha256, detail=detail)
            changed = (cached is None or cached["sha256"] != sha256 or cached["site_id"] != site_id
                       or cached["relative_path"] != relative_path or cached["mtime_ns"] != info.st_mtime_ns)
            if changed:
                if site_id is not None:
                    self.index.touch_site(site_id)
                self.index.add_input(site_id=site_id, role=role, source_path=str(source),
                                     relative_path=relative_path, sha256=sha256, size=size,
                                     mtime_ns=info.st_mtime_ns)
        return IngestedInput(source=source, relative_path=relative_path, role=role, sha256=sha256, size=size,
                             stored=stored is not None and stored.created and not repaired, digested=digested,
                             repaired=repaired)

    def index_strays(self, *, run_id: str | None = None) -> list[str]:
        """Index every object found in the store without its index row whose bytes match its digest.

        Returns
        -------
        list of str
            One line per object indexed (damaged strays are left for ``verify`` and ``repair``).
        """
        indexed = {row["sha256"] for row in self.index.objects()}
        healed = []
        for sha256 in self.store.iter_digests():
            if sha256 in indexed or self.store.damage(sha256) is not None:
                continue
            size = self.store.path_of(sha256).stat().st_size
            with self.index.transaction():
                self.index.add_object(sha256, size)
                self.index.add_event("ingest", agent=self.agent, outcome="success", run_id=run_id, sha256=sha256,
                                     detail={"size": size, "indexed": "the object was in the store without its "
                                                                      "index row"})
            healed.append(f"indexed object {sha256} (in the store without its index row)")
        return healed


def catalog_store(catalog: str | os.PathLike, archive_dir: str | os.PathLike | None = None
                  ) -> Callable[[str, list[tuple[Path, str]]], list[str]]:
    """A function that ingests a site's new catalog files into the archive (acquisition's ``store``).

    Parameters
    ----------
    catalog : path
        The catalog root the files are in (their archive paths are relative to it).
    archive_dir : path, optional
        The archive (default: :func:`default_archive_dir` of the catalog).

    Returns
    -------
    callable
        ``store(site_id, [(path, role), ...])`` returning the catalog-relative paths it ingested.
    """
    root = Path(catalog)
    where = Path(archive_dir) if archive_dir is not None else default_archive_dir(root)

    def store(site_id: str, files: list[tuple[Path, str]]) -> list[str]:
        done: list[str] = []
        with Archive(where) as archive:
            for path, role in files:
                relative = path.resolve().relative_to(root.resolve()).as_posix()
                archive.ingest(path, site_id=site_id, role=role, relative_path=relative)
                done.append(relative)
        return done

    return store

