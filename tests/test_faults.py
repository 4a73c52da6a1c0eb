"""Fault tolerance of the service: the rebuild lock, atomic publication, recovery, write failures,
kill -9 in the middle of a rebuild."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from cistern_archive.service.lock import LOCK_NAME, RebuildLock, RebuildLocked
from cistern_archive.service.publish import exchange, publish, recover, staging_dir

REPO = Path(__file__).resolve().parents[1]


def _site(folder: Path, text: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "index.html").write_text(text)
    return folder


# ------------------------------------------------------------------------------------------ lock
def test_a_second_rebuild_lock_is_refused_with_a_clear_message(tmp_path):
    with RebuildLock(tmp_path) as held:
        assert held.stale is None
        with pytest.raises(RebuildLocked, match=rf"another rebuild is already writing .*pid {os.getpid()}"):
            with RebuildLock(tmp_path):
                pass
    assert not (tmp_path / LOCK_NAME).exists()
    with RebuildLock(tmp_path):
        pass


def test_a_lock_held_by_another_live_process_is_refused(tmp_path):
    code = textwrap.dedent(f"""
        import sys, time
        from pathlib import Path
        from cistern_archive.service.lock import RebuildLock
        with RebuildLock(Path({str(tmp_path)!r})):
            print("locked", flush=True)
            time.sleep(60)
    """)
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(RebuildLocked, match=f"pid {holder.pid}"):
            with RebuildLock(tmp_path):
                pass
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    with RebuildLock(tmp_path) as lock:  # the kernel released the flock; the file names a dead pid
        assert lock.stale is not None and lock.stale["pid"] == holder.pid


def test_a_stale_lock_file_of_a_dead_process_is_taken_over(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    pid = int(dead.stdout)
    import socket

    (tmp_path / LOCK_NAME).write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "started": "earlier"}))
    with RebuildLock(tmp_path) as lock:
        assert lock.stale["pid"] == pid
        assert json.loads((tmp_path / LOCK_NAME).read_text())["pid"] == os.getpid()


# --------------------------------------------------------------------------------------- publish
def test_publish_swaps_the_whole_folder(tmp_path):
    target = _site(tmp_path / "pool", "old")
    (target / "stale-figure.png").write_text("old figure")
    staged = staging_dir(tmp_path, "pool")
    _site(staged, "new")
    publish(staged, target)
    assert (target / "index.html").read_text() == "new"
    assert not (target / "stale-figure.png").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pool"]
    assert oct(target.stat().st_mode & 0o777) == oct(0o755)


def test_exchange_is_atomic_where_supported(tmp_path):
    a, b = _site(tmp_path / "a", "A"), _site(tmp_path / "b", "B")
    if not exchange(a, b):
        pytest.skip("renameat2(RENAME_EXCHANGE) not available here; publish falls back to two renames")
    assert (a / "index.html").read_text() == "B" and (b / "index.html").read_text() == "A"


def test_recover_removes_unfinished_folders_and_restores_an_interrupted_swap(tmp_path):
    _site(tmp_path / ".pool.tmp-abc123", "half written")
    _site(tmp_path / ".cave.old-xyz" / "site", "previous cave")
    _site(tmp_path / "well", "current well")
    _site(tmp_path / ".well.old-q" / "site", "older well")
    actions = recover(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cave", "well"]
    assert (tmp_path / "cave" / "index.html").read_text() == "previous cave"
    assert (tmp_path / "well" / "index.html").read_text() == "current well"
    assert any("restored previous report of cave" in a for a in actions)
