"""The content-addressed archive: ingest, the SQLite index, provenance events and fixity checks."""

from __future__ import annotations

import hashlib
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from cistern_archive import __version__
from cistern_archive.archive import Archive, default_archive_dir, verify_archive
from cistern_archive.archive.index import EVENT_TYPES

CLI = [sys.executable, "-m", "cistern_archive"]


def _raw(tmp_path: Path, name: str, data: bytes) -> Path:
    path = tmp_path / "raw" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def _snapshot(path: Path) -> tuple[bytes, int, int]:
    info = path.stat()
    return path.read_bytes(), info.st_mode, info.st_mtime_ns


def test_ingest_stores_a_read_only_copy_under_its_digest_and_leaves_the_source_untouched(tmp_path):
    data = b"\x00\x01sonar bytes" * 1000
    source = _raw(tmp_path, "scan.bin", data)
    before = _snapshot(source)
    with Archive(tmp_path / "archive") as archive:
        item = archive.ingest(source, site_id="pool", role="scan", relative_path="data/pool/scan.bin")
        stored = archive.store.path_of(item.sha256)
        events = archive.index.events(site_id="pool")
    assert item.sha256 == hashlib.sha256(data).hexdigest()
    assert stored == tmp_path / "archive" / "objects" / item.sha256[:2] / item.sha256[2:]
    assert stored.read_bytes() == data
    assert stat.S_IMODE(stored.stat().st_mode) & 0o222 == 0, "stored objects are read-only"
    assert _snapshot(source) == before
    assert [e["type"] for e in events] == ["digest", "ingest"]
    assert {e["agent"] for e in events} == {f"cistern-archive {__version__}"}
    assert not list((tmp_path / "archive" / "tmp").iterdir())


def test_unchanged_files_reuse_their_digest_and_new_versions_keep_the_old_object(tmp_path):
    source = _raw(tmp_path, "scan.bin", b"version 1")
    with Archive(tmp_path / "archive") as archive:
        first = archive.ingest(source, site_id="pool")
        again = archive.ingest(source, site_id="pool")
        assert (first.stored, first.digested) == (True, True)
        assert (again.stored, again.digested) == (False, False)
        source.write_bytes(b"version 2, longer")
        second = archive.ingest(source, site_id="pool")
        assert second.stored and second.sha256 != first.sha256
        assert archive.store.path_of(first.sha256).read_bytes() == b"version 1"
        assert len(archive.index.objects()) == 2
        assert [row["sha256"] for row in archive.index.site_inputs("pool")] == [second.sha256]
        copy = _raw(tmp_path, "copy.bin", b"version 1")
        duplicate = archive.ingest(copy, site_id="other")
        assert duplicate.sha256 == first.sha256 and not duplicate.stored
        assert len(archive.index.objects()) == 2


def test_index_records_runs_artifacts_and_only_known_event_types(tmp_path):
    with Archive(tmp_path / "archive") as archive:
        archive.index.start_run("r1", catalog="c", out="o", executor="local", agent=archive.agent)
        archive.index.add_artifact("r1", "pool", "index.html", "ab" * 32, 10)
        archive.index.finish_run("r1", "ok", {"ok": 1})
        assert archive.index.runs()[0]["status"] == "ok"
        assert [a["path"] for a in archive.index.artifacts("pool")] == ["index.html"]
        with pytest.raises(ValueError, match="unknown event type"):
            archive.index.add_event("delete", agent=archive.agent, outcome="success")
    assert set(EVENT_TYPES) == {"ingest", "digest", "build", "publish", "fixity"}


def test_verify_finds_a_flipped_byte_and_a_missing_object(tmp_path):
    sources = [_raw(tmp_path, f"f{k}.bin", bytes([k]) * (100 + k)) for k in range(3)]
    with Archive(tmp_path / "archive") as archive:
        items = [archive.ingest(s) for s in sources]
        assert verify_archive(archive).ok
        flipped = archive.store.path_of(items[0].sha256)
        os.chmod(flipped, 0o644)
        raw = bytearray(flipped.read_bytes())
        raw[50] ^= 0x01
        flipped.write_bytes(bytes(raw))
        archive.store.path_of(items[1].sha256).unlink()
        report = verify_archive(archive)
        fixity = archive.index.events(type="fixity")
    assert not report.ok and report.checked == 3
    kinds = {p.sha256: p.kind for p in report.problems}
    assert kinds == {items[0].sha256: "mismatch", items[1].sha256: "missing"}
    assert sum(e["outcome"] == "failure" for e in fixity) == 2


def test_ingest_and_verify_commands(tmp_path):
    source = _raw(tmp_path, "scan.bin", b"ping" * 64)
    archive = tmp_path / "archive"
    run = subprocess.run([*CLI, "ingest", str(source), "--site", "pool", "--archive", str(archive)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    digest = hashlib.sha256(source.read_bytes()).hexdigest()
    assert digest in run.stdout
    ok = subprocess.run([*CLI, "verify", "--archive", str(archive)], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    obj = archive / "objects" / digest[:2] / digest[2:]
    os.chmod(obj, 0o644)
    obj.write_bytes(b"pong" + obj.read_bytes()[4:])
    bad = subprocess.run([*CLI, "verify", "--archive", str(archive)], capture_output=True, text=True)
    assert bad.returncode == 1
    assert "mismatch" in bad.stderr and digest[2:] in bad.stderr


def test_default_archive_location(tmp_path, monkeypatch):
    monkeypatch.delenv("CISTERN_ARCHIVE", raising=False)
    assert default_archive_dir(tmp_path / "catalog") == tmp_path.resolve() / ".archive"
    monkeypatch.setenv("CISTERN_ARCHIVE", str(tmp_path / "elsewhere"))
    assert default_archive_dir(tmp_path / "catalog") == tmp_path / "elsewhere"
