"""The archive's SQLite index: sites, inputs, runs, artifacts and provenance events.

Events follow the preservation vocabulary: ``ingest`` (an object entered the store), ``digest`` (a
message digest was computed), ``build`` (a site was built), ``publish`` (a report was published) and
``fixity`` (a stored object was checked against its digest). Every event names its agent: the software
and its version.
"""

from __future__ import annotations

import datetime as dt
import json
import sqlite3
import time
from pathlib import Path
from typing import Any

from cistern_archive.core.errors import EnvironmentProblem

EVENT_TYPES = ("ingest", "digest", "build", "publish", "fixity")

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS objects (
    sha256 TEXT PRIMARY KEY,
    size INTEGER NOT NULL,
    stored_at TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS sites (
    id TEXT PRIMARY KEY,
    name TEXT NOT NULL DEFAULT '',
    record_path TEXT NOT NULL DEFAULT '',
    first_seen TEXT NOT NULL,
    last_seen TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS inputs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    site_id TEXT,
    role TEXT NOT NULL,
    source_path TEXT NOT NULL,
    relative_path TEXT NOT NULL,
    sha256 TEXT NOT NULL REFERENCES objects(sha256),
    size INTEGER NOT NULL,
    mtime_ns INTEGER NOT NULL,
    ingested_at TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS inputs_by_source ON inputs(source_path, id);
CREATE INDEX IF NOT EXISTS inputs_by_site ON inputs(site_id, id);
CREATE TABLE IF NOT EXISTS runs (
    id TEXT PRIMARY KEY,
    started_at TEXT NOT NULL,
    finished_at TEXT,
    status TEXT NOT NULL,
    catalog TEXT NOT NULL,
    out TEXT NOT NULL,
    executor TEXT NOT NULL,
    agent TEXT NOT NULL,
    counts TEXT NOT NULL DEFAULT '{}'
);
CREATE TABLE IF NOT EXISTS artifacts (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    run_id TEXT NOT NULL REFERENCES runs(id),
    site_id TEXT NOT NULL,
    path TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    size INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time TEXT NOT NULL,
    type TEXT NOT NULL CHECK (type IN ('ingest', 'digest', 'build', 'publish', 'fixity')),
    agent TEXT NOT NULL,
    outcome TEXT NOT NULL,
    run_id TEXT,
    site_id TEXT,
    sha256 TEXT,
    detail TEXT NOT NULL DEFAULT ''
);
"""

SCHEMA_VERSION = "1"


def utc_now() -> str:
    """The current UTC time as an ISO 8601 string (the index records real times)."""
    return dt.datetime.now(dt.timezone.utc).isoformat(timespec="milliseconds")


class DamagedIndex(EnvironmentProblem):
    """``index.sqlite`` is not a readable SQLite database (``cistern-archive repair`` replaces it)."""


class _GuardedConnection(sqlite3.Connection):
    """A connection whose database errors (a damaged file, a full or read-only disk) name the index file."""

    path = ""

    def _guard(self, call, *args):
        try:
            return call(*args)
        except (sqlite3.IntegrityError, sqlite3.ProgrammingError):
            raise
        except sqlite3.DatabaseError as exc:
            if "not a database" in str(exc) or "malformed" in str(exc):
                raise DamagedIndex(f"{self.path}: archive index is damaged: {exc}; "
                                   "run `cistern-archive repair`") from None
            raise EnvironmentProblem(f"{self.path}: archive index: {exc}") from None

    def execute(self, *args):  # type: ignore[override]
        return self._guard(super().execute, *args)

    def executescript(self, *args):  # type: ignore[override]
        return self._guard(super().executescript, *args)


WAL_BUDGET_S = 30.0
"""How long :func:`use_wal` keeps trying to turn a new index to write-ahead logging."""


def use_wal(db: sqlite3.Connection, path: Path, budget_s: float = WAL_BUDGET_S) -> None:
    """Put the index in write-ahead-log mode (a persistent property of the file).

    Converting the journal needs exclusive access, and SQLite does not run its busy handler for that
    pragma: two processes opening a new, shared archive at once get "database is locked" at once,
    whatever the connection's timeout. So the mode is read first (after the first open there is nothing
    to convert, and no lock is taken), and the conversion is retried with backoff within ``budget_s``;
    another process finishing it meanwhile counts as done.
    """
    deadline = time.monotonic() + budget_s
    pause = 0.01
    while True:
        try:
            if db.execute("PRAGMA journal_mode").fetchone()[0].lower() == "wal":
                return
            if db.execute("PRAGMA journal_mode=WAL").fetchone()[0].lower() == "wal":
                return
        except EnvironmentProblem as exc:
            if "locked" not in str(exc) or time.monotonic() >= deadline:
                raise
        else:
            if time.monotonic() >= deadline:
                raise EnvironmentProblem(f"{path}: archive index: cannot switch to write-ahead logging")
        time.sleep(pause)
        pause = min(2 * pause, 0.5)


class Index:
    """A connection to ``index.sqlite``; use as a context manager or call :meth:`close`.

    Parameters
    ----------
    path : Path
        The database file (created with its schema when missing).
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        try:
            self.db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, factory=_GuardedConnection)
        except sqlite3.Error as exc:
            raise EnvironmentProblem(f"{self.path}: cannot open the archive index: {exc}") from None
        self.db.path = str(self.path)
        self.db.row_factory = sqlite3.Row
        use_wal(self.db, self.path)
        self.db.execute("PRAGMA synchronous=NORMAL")
        self.db.execute("PRAGMA foreign_keys=ON")
        self.db.executescript(SCHEMA)
        self.db.execute("INSERT OR IGNORE INTO meta(key, value) VALUES ('schema_version', ?)", (SCHEMA_VERSION,))

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> "Index":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def transaction(self) -> "_Transaction":
        """``with index.transaction():`` groups statements into one atomic commit."""
        return _Transaction(self.db)

    # ------------------------------------------------------------------------------- objects
    def add_object(self, sha256: str, size: int) -> None:
        self.db.execute("INSERT OR IGNORE INTO objects(sha256, size, stored_at) VALUES (?, ?, ?)",
                        (sha256, size, utc_now()))

    def objects(self) -> list[sqlite3.Row]:
        return list(self.db.execute("SELECT sha256, size, stored_at FROM objects ORDER BY sha256"))

    def has_object(self, sha256: str) -> bool:
        return self.db.execute("SELECT 1 FROM objects WHERE sha256 = ?", (sha256,)).fetchone() is not None

    def sources_of(self, sha256: str) -> list[str]:
        """Every file path ever ingested with this digest, most recent first (candidates for a repair)."""
        return [row["source_path"] for row in self.db.execute(
            "SELECT source_path, MAX(id) AS last FROM inputs WHERE sha256 = ? GROUP BY source_path "
            "ORDER BY last DESC", (sha256,))]

    # --------------------------------------------------------------------------------- sites
    def touch_site(self, site_id: str, name: str = "", record_path: str = "") -> None:
        now = utc_now()
        self.db.execute(
            "INSERT INTO sites(id, name, record_path, first_seen, last_seen) VALUES (?, ?, ?, ?, ?) "
            "ON CONFLICT(id) DO UPDATE SET name=excluded.name, record_path=excluded.record_path, "
            "last_seen=excluded.last_seen",
            (site_id, name, record_path, now, now),
        )

    def sites(self) -> list[sqlite3.Row]:
        return list(self.db.execute("SELECT * FROM sites ORDER BY id"))

    # -------------------------------------------------------------------------------- inputs
    def latest_input(self, source_path: str) -> sqlite3.Row | None:
        """The most recent ingest of a file path (for the size/mtime digest cache)."""
        return self.db.execute(
            "SELECT * FROM inputs WHERE source_path = ? ORDER BY id DESC LIMIT 1", (source_path,)
        ).fetchone()

    def add_input(self, *, site_id: str | None, role: str, source_path: str, relative_path: str, sha256: str,
                  size: int, mtime_ns: int) -> None:
        self.db.execute(
            "INSERT INTO inputs(site_id, role, source_path, relative_path, sha256, size, mtime_ns, ingested_at) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (site_id, role, source_path, relative_path, sha256, size, mtime_ns, utc_now()),
        )

    def site_inputs(self, site_id: str) -> list[sqlite3.Row]:
        """The latest version of every input path of a site."""
        return list(self.db.execute(
            "SELECT * FROM inputs WHERE id IN (SELECT MAX(id) FROM inputs WHERE site_id = ? "
            "GROUP BY relative_path) ORDER BY relative_path", (site_id,)))

    # ---------------------------------------------------------------------------------- runs
    def start_run(self, run_id: str, *, catalog: str, out: str, executor: str, agent: str) -> None:
        self.db.execute(
            "INSERT INTO runs(id, started_at, status, catalog, out, executor, agent) "
            "VALUES (?, ?, 'running', ?, ?, ?, ?)",
            (run_id, utc_now(), catalog, out, executor, agent),
        )

    def finish_run(self, run_id: str, status: str, counts: dict[str, int], *, executor: str | None = None) -> None:
        self.db.execute("UPDATE runs SET finished_at = ?, status = ?, counts = ?, executor = COALESCE(?, executor) "
                        "WHERE id = ?", (utc_now(), status, json.dumps(counts, sort_keys=True), executor, run_id))

    def abandon_runs(self, out: str, keep: str) -> int:
        """Mark runs into ``out`` still ``running`` (their process died) as ``abandoned``; keep ``keep``."""
        cursor = self.db.execute("UPDATE runs SET status = 'abandoned' WHERE out = ? AND status = 'running' "
                                 "AND id != ?", (out, keep))
        return cursor.rowcount

    def runs(self) -> list[sqlite3.Row]:
        return list(self.db.execute("SELECT * FROM runs ORDER BY started_at, id"))

    def add_artifact(self, run_id: str, site_id: str, path: str, sha256: str, size: int) -> None:
        self.db.execute("INSERT INTO artifacts(run_id, site_id, path, sha256, size) VALUES (?, ?, ?, ?, ?)",
                        (run_id, site_id, path, sha256, size))

    def artifacts(self, site_id: str, run_id: str | None = None) -> list[sqlite3.Row]:
        if run_id is None:
            run_id_row = self.db.execute(
                "SELECT run_id FROM artifacts WHERE site_id = ? ORDER BY id DESC LIMIT 1", (site_id,)).fetchone()
            if run_id_row is None:
                return []
            run_id = run_id_row["run_id"]
        return list(self.db.execute("SELECT * FROM artifacts WHERE site_id = ? AND run_id = ? ORDER BY path",
                                    (site_id, run_id)))

    # -------------------------------------------------------------------------------- events
    def add_event(self, type: str, *, agent: str, outcome: str, run_id: str | None = None,
                  site_id: str | None = None, sha256: str | None = None, detail: str | dict[str, Any] = "") -> None:
        if type not in EVENT_TYPES:
            raise ValueError(f"unknown event type {type!r}; known: {', '.join(EVENT_TYPES)}")
        if not isinstance(detail, str):
            detail = json.dumps(detail, sort_keys=True)
        self.db.execute(
            "INSERT INTO events(time, type, agent, outcome, run_id, site_id, sha256, detail) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (utc_now(), type, agent, outcome, run_id, site_id, sha256, detail),
        )

    def events(self, *, type: str | None = None, site_id: str | None = None) -> list[sqlite3.Row]:
        query, args = "SELECT * FROM events WHERE 1=1", []
        if type is not None:
            query, args = query + " AND type = ?", args + [type]
        if site_id is not None:
            query, args = query + " AND site_id = ?", args + [site_id]
        return list(self.db.execute(query + " ORDER BY id", args))


class _Transaction:
    def __init__(self, db: sqlite3.Connection):
        self.db = db

    def __enter__(self) -> None:
        self.db.execute("BEGIN IMMEDIATE")

    def __exit__(self, exc_type: object, *rest: object) -> None:
        if exc_type is None:
            self.db.execute("COMMIT")
        elif self.db.in_transaction:
            self.db.execute("ROLLBACK")
