"""Several processes opening one new archive index at once (two rebuilds sharing an empty archive)."""

from __future__ import annotations

import multiprocessing
import sqlite3
from pathlib import Path

import pytest

from cistern_archive.archive.index import Index

OPENERS = 16


def _open(path: str, barrier, errors) -> None:
    barrier.wait()
    try:
        with Index(Path(path)) as index:
            index.add_object("0" * 64, 1)
    except Exception as exc:  # reported to the parent, which asserts there were none
        errors.put(f"{type(exc).__name__}: {exc}")


@pytest.mark.parametrize("attempt", range(3))
def test_processes_opening_a_new_index_together_all_succeed(tmp_path, attempt):
    """Turning a new index to write-ahead logging needs exclusive access and SQLite's busy handler
    does not wait for it; every opener must still get a working index."""
    context = multiprocessing.get_context("fork")
    barrier, errors = context.Barrier(OPENERS), context.Queue()
    path = tmp_path / "index.sqlite"
    workers = [context.Process(target=_open, args=(str(path), barrier, errors)) for _ in range(OPENERS)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(timeout=120)
    found = []
    while not errors.empty():
        found.append(errors.get())
    assert found == [] and all(w.exitcode == 0 for w in workers), found
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert db.execute("SELECT count(*) FROM objects").fetchone()[0] == 1
    db.close()
