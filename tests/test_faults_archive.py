"""Faults of the archive and of the rebuild's environment: damaged, missing and unindexed objects, a deleted
or corrupt index, read-only and full disks, junk inputs, another site's bag, a crash between a publish and
the index, no catalog at all. After each: no traceback reaches the user, every good site still builds,
``verify`` exits 0 after ``repair`` (or the next rebuild), and no byte of a raw input or an earlier report
is lost."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import stat
import threading
from pathlib import Path

import bagit
import pytest

from cistern_archive.archive import Archive, verify_archive
from cistern_archive.archive.digest import file_sha256
from cistern_archive.archive.store import ObjectStore
from cistern_archive.service.rebuild import rebuild
from fault_helpers import can_mount, fill, free, guard, one_line_error, remount, run_cli, small_disk  # noqa: F401
from service_helpers import FAST_REPORT, copy_built, make_catalog, report_is_complete

SITES = ["cistern-000", "cistern-001"]


@pytest.fixture(scope="module")
def built_once(tmp_path_factory) -> tuple[Path, Path]:
    """Built with the command line's report settings, so that its later rebuilds find the sites current."""
    root = tmp_path_factory.mktemp("faults-archive")
    catalog = make_catalog(root / "catalog")
    summary = rebuild(catalog, root / "site", workers=2)
    assert [s.status for s in summary.sites] == ["ok", "ok"]
    return catalog, root / "site"


@pytest.fixture()
def built(built_once, tmp_path, guard) -> tuple[Path, Path, Path]:
    """A catalog, its published reports and its archive (``.archive`` beside them), copied for one test and
    watched: no raw input and no earlier report may be lost."""
    catalog, out = copy_built(built_once, tmp_path)
    shutil.copytree(built_once[0].parent / ".archive", tmp_path / ".archive", dirs_exist_ok=True)
    guard.watch_raw(catalog)
    guard.watch_reports(out)
    return catalog, out, tmp_path / ".archive"


def _rebuild_cli(catalog: Path, out: Path, *extra: str):
    return run_cli("rebuild", "--catalog", str(catalog), "--out", str(out), *extra)


def _verify(archive: Path, code: int = 0):
    run = run_cli("verify", "--archive", str(archive))
    assert run.returncode == code, run.stdout + run.stderr
    return run


def _object_of(archive: Path, site: str, relative: str) -> tuple[str, Path]:
    with Archive(archive) as store:
        row = next(r for r in store.index.site_inputs(site) if r["relative_path"] == relative)
        return row["sha256"], store.store.path_of(row["sha256"])


def _flip(path: Path, at: int = 100) -> None:
    os.chmod(path, 0o644)
    data = bytearray(path.read_bytes())
    data[at] ^= 0x01
    path.write_bytes(bytes(data))
    os.chmod(path, 0o444)


def _all_good(catalog: Path, out: Path, archive: Path, guard) -> None:
    """The end state of every fault: the sites build (or are current), verify passes, nothing was lost."""
    summary = rebuild(catalog, out, archive=archive)
    assert summary.exit_code == 0, [s.error for s in summary.sites]
    for site in SITES:
        assert report_is_complete(out / site)
    with Archive(archive) as store:
        report = verify_archive(store)
    assert report.ok, [str(p) for p in report.problems]
    assert guard.check() == []


# ------------------------------------------------------------------------------------ defect 1
def test_export_never_replaces_another_sites_bag(built, tmp_path):
    catalog, out, _ = built
    other = tmp_path / "bags" / "other"
    other.mkdir(parents=True)
    (other / "findings.txt").write_text("the other site's deposit")
    bagit.make_bag(str(other), bag_info={"External-Identifier": "cistern-0001"})  # starts with cistern-000
    before = {p.relative_to(other): p.read_bytes() for p in other.rglob("*") if p.is_file()}
    run = run_cli("export", "cistern-000", "--bag", str(other), "--catalog", str(catalog), "--out", str(out))
    one_line_error(run, code=2, naming="is not a bag of site 'cistern-000'")
    assert {p.relative_to(other): p.read_bytes() for p in other.rglob("*") if p.is_file()} == before


# ------------------------------------------------------------------------------------ defect 2
def test_a_damaged_object_is_restored_by_the_next_rebuild_from_the_intact_original(built, guard):
    catalog, out, archive = built
    digest, obj = _object_of(archive, "cistern-000", "data/cistern-000/s1.npz")
    _flip(obj)
    run = _verify(archive, 1)
    assert "mismatch" in run.stderr and digest in run.stderr
    run = _rebuild_cli(catalog, out)
    assert run.returncode == 0, run.stderr
    assert file_sha256(obj)[0] == digest
    with Archive(archive) as store:
        repaired = [json.loads(e["detail"]) for e in store.index.events(type="ingest") if e["sha256"] == digest]
        failures = [e for e in store.index.events(type="fixity") if e["sha256"] == digest and e["outcome"] == "failure"]
    assert any("repaired" in d and d["repaired"].startswith("damaged") for d in repaired) and failures
    recovered = json.loads((out / "summary.json").read_text())["recovered"]
    assert any(line.startswith("cistern-000: restored the archived copy of data/cistern-000/s1.npz")
               for line in recovered), recovered
    _all_good(catalog, out, archive, guard)


def test_ingest_of_the_intact_original_repairs_a_damaged_object(built, guard):
    catalog, out, archive = built
    digest, obj = _object_of(archive, "cistern-001", "data/cistern-001/s2.npz")
    _flip(obj, at=40)
    run = run_cli("ingest", str(catalog / "data" / "cistern-001" / "s2.npz"), "--archive", str(archive))
    assert run.returncode == 0 and "repaired the archived copy" in run.stdout, run.stdout + run.stderr
    assert file_sha256(obj)[0] == digest
    _all_good(catalog, out, archive, guard)


def test_a_damaged_object_is_never_copied_out(tmp_path):
    from cistern_archive.archive.store import DamagedObject

    source = tmp_path / "scan.bin"
    source.write_bytes(b"sonar" * 1000)
    store = ObjectStore(tmp_path / "archive")
    stored = store.put(source)
    _flip(store.path_of(stored.sha256))
    with pytest.raises(DamagedObject, match="damaged.*repair"):
        store.copy_out(stored.sha256, tmp_path / "bag" / "scan.bin")
    assert not (tmp_path / "bag" / "scan.bin").exists()


def test_an_input_that_changed_after_archiving_fails_only_its_site(built, guard):
    """The worker checks what it reads against the digests the build key was computed from."""
    from cistern_archive.service.worker import SiteTask, run_site

    catalog, out, _ = built
    record = catalog / "sites" / "cistern-000.yaml"
    bad = {"inputs": {"data/cistern-000/s1.npz": "0" * 64}}
    task = SiteTask(site_id="cistern-000", record_path=str(record), catalog_root=str(catalog), out=str(out),
                    build_key="k", key_material=bad, run_id="r", report_config=FAST_REPORT)
    outcome = run_site(task)
    assert outcome.status == "failed" and "s1.npz: sha256 is" in outcome.error and "0" * 64 in outcome.error
    assert guard.check() == []


def test_repair_restores_damaged_and_missing_objects_from_the_catalog(built, guard):
    catalog, out, archive = built
    damaged, obj = _object_of(archive, "cistern-000", "data/cistern-000/s2.npz")
    missing, gone = _object_of(archive, "cistern-001", "sites/cistern-001.yaml")
    _flip(obj)
    gone.unlink()
    _verify(archive, 1)
    run = run_cli("repair", "--catalog", str(catalog), "--archive", str(archive))
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"restored mismatch object {damaged}" in run.stdout and f"restored missing object {missing}" in run.stdout
    assert file_sha256(obj)[0] == damaged and file_sha256(gone)[0] == missing
    assert stat.S_IMODE(gone.stat().st_mode) & 0o222 == 0
    with Archive(archive) as store:
        restored = {e["sha256"] for e in store.index.events(type="ingest") if "repaired" in e["detail"]}
    assert {damaged, missing} <= restored
    _all_good(catalog, out, archive, guard)


def test_repair_says_what_it_cannot_restore(tmp_path):
    source = tmp_path / "only-copy.bin"
    source.write_bytes(b"unique bytes")
    with Archive(tmp_path / "archive") as store:
        item = store.ingest(source)
    source.unlink()
    _flip(tmp_path / "archive" / "objects" / item.sha256[:2] / item.sha256[2:], at=3)
    run = run_cli("repair", "--archive", str(tmp_path / "archive"), "--catalog", str(tmp_path / "none"))
    assert run.returncode == 1 and "NOT REPAIRED" in run.stderr and item.sha256 in run.stderr


# ------------------------------------------------------------------------------------ defect 4
def test_a_deleted_index_is_healed_by_the_next_rebuild(built, guard):
    catalog, out, archive = built
    for name in ("index.sqlite", "index.sqlite-wal", "index.sqlite-shm"):
        (archive / name).unlink(missing_ok=True)
    run = _verify(archive, 1)
    assert "unindexed" in run.stderr
    _all_good(catalog, out, archive, guard)


def test_an_object_stored_without_its_index_row_is_healed(built, guard):
    """A crash between ``store.put`` and the index commit, or a second process racing the first."""
    catalog, out, archive = built
    stray = catalog.parent / "stray.bin"
    stray.write_bytes(b"stored, never indexed")
    ObjectStore(archive).put(stray)
    _verify(archive, 1)
    new_scan = catalog / "data" / "cistern-000" / "s1.npz"
    with Archive(archive) as store:  # an object of a catalog input whose index row is gone
        digest = file_sha256(new_scan)[0]
        store.index.db.execute("PRAGMA foreign_keys=OFF")
        store.index.db.execute("DELETE FROM objects WHERE sha256 = ?", (digest,))
        store.index.db.execute("DELETE FROM inputs WHERE sha256 = ?", (digest,))
    _all_good(catalog, out, archive, guard)
    with Archive(archive) as store:
        assert store.index.has_object(digest) and store.index.has_object(file_sha256(stray)[0])


def test_a_corrupt_index_gives_one_line_then_repair_sets_it_aside(built, guard):
    catalog, out, archive = built
    for name in ("index.sqlite-wal", "index.sqlite-shm"):
        (archive / name).unlink(missing_ok=True)
    garbage = b"this is not an SQLite database " * 200
    (archive / "index.sqlite").write_bytes(garbage)
    run = run_cli("verify", "--archive", str(archive))
    assert run.returncode == 1 and "index.sqlite" in run.stderr and "repair" in run.stderr
    one_line_error(_rebuild_cli(catalog, out), code=3, naming="index.sqlite")
    one_line_error(run_cli("ingest", str(catalog / "sites" / "cistern-000.yaml"), "--archive", str(archive)),
                   code=3, naming="index.sqlite")
    run = run_cli("repair", "--catalog", str(catalog), "--archive", str(archive))
    assert run.returncode == 0, run.stdout + run.stderr
    kept = list(archive.glob("index.sqlite.damaged-*"))
    assert len(kept) == 1 and kept[0].read_bytes() == garbage
    _all_good(catalog, out, archive, guard)


# ------------------------------------------------------------------------------------ defect 5
def test_cleaning_tmp_spares_an_object_another_process_is_writing(tmp_path):
    fifo = tmp_path / "slow-source"
    os.mkfifo(fifo)
    payload = b"a slow recording" * 1000
    import hashlib

    digest = hashlib.sha256(payload).hexdigest()
    writer = ObjectStore(tmp_path / "archive")
    result: dict = {}

    def put() -> None:
        try:
            result["stored"] = writer.put(fifo, digest)
        except Exception as exc:  # noqa: BLE001 - reported below
            result["error"] = exc

    thread = threading.Thread(target=put)
    thread.start()
    with open(fifo, "wb") as feed:  # the writer has opened its temporary file and waits for data
        feed.write(payload[:100])
        feed.flush()
        assert any((tmp_path / "archive" / "tmp").iterdir())
        assert ObjectStore(tmp_path / "archive").clean_tmp() == 0  # another rebuild starting meanwhile
        feed.write(payload[100:])
    thread.join(30)
    assert "error" not in result, result.get("error")
    assert writer.path_of(digest).read_bytes() == payload


def test_cleaning_tmp_removes_leftovers_of_dead_processes(tmp_path):
    store = ObjectStore(tmp_path / "archive")
    import socket

    dead = store.tmp / f"obj-{socket.gethostname()}-{2 ** 22 + 12345}-abcd1234"
    dead.write_bytes(b"half")
    old_style = store.tmp / "obj-k3j4h5"
    old_style.write_bytes(b"half")
    assert store.clean_tmp() == 2 and not any(store.tmp.iterdir())


# ----------------------------------------------------------------------------------- defect 11
needs_mount = pytest.mark.skipif(not can_mount(), reason="needs root to mount a small tmpfs")


@contextlib.contextmanager
def _out_on_small_disk(out: Path, disk: Path, guard):
    """A copy of the published reports on a small tmpfs of their own, watched by ``guard``."""
    with small_disk(disk, "8m"):
        shutil.copytree(out, disk / "site", symlinks=True)
        guard.watch_reports(disk / "site")
        yield disk / "site"


@needs_mount
def test_a_read_only_out_gives_one_line_and_nothing_changes(built, tmp_path, guard):
    catalog, out, archive = built
    disk = tmp_path / "ro"
    with _out_on_small_disk(out, disk, guard) as site:
        remount(disk, "ro")
        one_line_error(_rebuild_cli(catalog, site, "--force"), code=3, naming=str(site))
        remount(disk, "rw")
        _all_good(catalog, site, archive, guard)


@needs_mount
def test_a_full_disk_when_the_lock_is_written_gives_one_line(built, tmp_path, guard):
    catalog, out, archive = built
    disk = tmp_path / "full-out"
    with _out_on_small_disk(out, disk, guard) as site:
        fill(disk)
        one_line_error(_rebuild_cli(catalog, site, "--force"), code=3, naming=".rebuild.lock")
        free(disk)
        _all_good(catalog, site, archive, guard)


@needs_mount
def test_a_read_only_archive_gives_one_line_and_nothing_is_published(built, tmp_path, guard):
    catalog, out, archive = built
    disk = tmp_path / "ro-archive"
    with small_disk(disk, "16m"):
        shutil.copytree(archive, disk / "archive")
        remount(disk, "ro")
        before = {site: (out / site / "build.json").read_bytes() for site in SITES}
        one_line_error(_rebuild_cli(catalog, out, "--force", "--archive", str(disk / "archive")), code=3,
                       naming=str(disk / "archive"))
        assert {site: (out / site / "build.json").read_bytes() for site in SITES} == before
        remount(disk, "rw")
        _all_good(catalog, out, disk / "archive", guard)


@needs_mount
def test_a_full_disk_in_the_archive_gives_one_line_and_leaves_no_partial_object(built, tmp_path, guard):
    catalog, out, _ = built
    disk = tmp_path / "full-archive"
    with small_disk(disk, "4m"):
        fill(disk)
        one_line_error(_rebuild_cli(catalog, out, "--archive", str(disk / "archive")), code=3,
                       naming=str(disk / "archive"))
        tmp = disk / "archive" / "tmp"
        assert not tmp.exists() or not any(tmp.iterdir())
        free(disk)
        _all_good(catalog, out, disk / "archive", guard)


@needs_mount
def test_a_full_disk_while_an_object_is_copied_leaves_neither_a_partial_object_nor_an_index_row(tmp_path):
    from cistern_archive.core.errors import EnvironmentProblem

    source = tmp_path / "long-recording.bin"
    source.write_bytes(os.urandom(6_000_000))
    before = file_sha256(source)
    disk = tmp_path / "small"
    with small_disk(disk, "4m"):
        with Archive(disk / "archive") as store:
            with pytest.raises(EnvironmentProblem, match=r"cannot write to the archive .*long-recording.bin"):
                store.ingest(source, site_id="pool")
            assert list(store.store.tmp.iterdir()) == [] and store.store.iter_digests() == []
            assert store.index.objects() == [] and store.index.site_inputs("pool") == []
    assert file_sha256(source) == before


# ----------------------------------------------------------------------------------- defect 12
def test_a_junk_scan_fails_its_site_without_being_archived(built, guard):
    catalog, out, archive = built
    junk = catalog / "data" / "cistern-000" / "s1.npz"
    junk.chmod(0o644)
    junk.write_bytes(os.urandom(3_000_000))
    guard.watch_raw(catalog)
    run = _rebuild_cli(catalog, out)
    assert run.returncode == 1 and "FAILED cistern-000" in run.stderr and "s1.npz" in run.stderr
    assert report_is_complete(out / "cistern-000")  # its failure report, naming the file
    assert not ObjectStore(archive).has(file_sha256(junk)[0])
    assert report_is_complete(out / "cistern-001")
    _verify(archive, 0)
    assert guard.check() == []


def test_summary_json_is_as_readable_as_every_other_output(built):
    catalog, out, _ = built
    assert rebuild(catalog, out).exit_code == 0
    for name in ("summary.json", "index.html"):
        assert stat.S_IMODE((out / name).stat().st_mode) == 0o644, name


def test_a_crash_between_a_publish_and_the_index_write_rerenders_the_index(built, guard):
    catalog, out, archive = built
    stale_index, stale_summary = (out / "index.html").read_bytes(), (out / "summary.json").read_bytes()
    record = catalog / "sites" / "cistern-000.yaml"
    record.write_text(record.read_text().replace("name: Generated cistern 000", "name: Renamed cistern"))
    guard.watch_raw(catalog)
    assert rebuild(catalog, out).exit_code == 0  # publishes cistern-000 ...
    (out / "index.html").write_bytes(stale_index)  # ... and crashes before the index and summary
    (out / "summary.json").write_bytes(stale_summary)
    assert rebuild(catalog, out).exit_code == 0
    assert "Renamed cistern" in (out / "index.html").read_text()
    log = (out / json.loads((out / "summary.json").read_text())["log"]).read_text()
    assert "index unchanged" not in log
    _all_good(catalog, out, archive, guard)


# --------------------------------------------------------------------------------------- also
def test_rebuild_without_a_catalog_writes_nothing(tmp_path):
    run = run_cli("rebuild", cwd=tmp_path)
    one_line_error(run, code=2, naming="catalog")
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "catalog").mkdir()
    one_line_error(run_cli("rebuild", cwd=tmp_path), code=2, naming="no site records")
    assert [p.name for p in tmp_path.iterdir()] == ["catalog"]


def test_verify_and_ingest_find_the_archive_rebuild_uses(built, tmp_path, monkeypatch):
    catalog, out, archive = built
    monkeypatch.delenv("CISTERN_ARCHIVE", raising=False)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    run = run_cli("verify", "--catalog", str(catalog), cwd=elsewhere)
    assert run.returncode == 0 and str(archive.resolve()) in run.stdout, run.stdout + run.stderr
    run = run_cli("ingest", str(catalog / "sites" / "cistern-000.yaml"), "--catalog", str(catalog), cwd=elsewhere)
    assert run.returncode == 0 and "already archived" in run.stdout and str(archive.resolve()) in run.stdout
    assert list(elsewhere.iterdir()) == []


# ------------------------------------------------------------------------------------ defect 8
def test_bad_records_fail_alone_and_every_good_site_still_builds(built, tmp_path, guard):
    catalog, out, archive = built
    good = (catalog / "sites" / "cistern-000.yaml").read_text()
    bad = {
        "nan-depth.yaml": good.replace("id: cistern-000", "id: nan-depth").replace("depth_m: ", "depth_m: .nan #", 1),
        "deep.yaml": good.replace("id: cistern-000", "id: deep-nesting") + "description: " + "[" * 5000 + "]" * 5000,
        "newline.yaml": good.replace("id: cistern-000", 'id: "newline-id\\n"'),
    }
    for name, text in bad.items():
        (catalog / "sites" / name).write_text(text)
    outside = tmp_path / "outside.yaml"
    outside.write_text(good.replace("id: cistern-000", "id: from-outside"))
    (catalog / "sites" / "linked.yaml").symlink_to(outside)
    run = _rebuild_cli(catalog, out)
    assert run.returncode == 2, run.stdout + run.stderr
    for name in [*bad, "linked.yaml"]:
        assert any(line.startswith(f"{catalog / 'sites' / name}:") for line in run.stderr.splitlines()), name
    assert "0 failed, 2 unchanged" in run.stdout
    for site in SITES:
        assert report_is_complete(out / site)
    assert sorted(p.name for p in out.iterdir() if p.is_dir() and not p.name.startswith(".")) == ["cistern-000",
                                                                                             "cistern-001", "logs"]
    assert guard.check() == []
