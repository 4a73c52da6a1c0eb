"""kill -9 of the rebuild: of its main process alone (its workers must die with it and never publish) and of
its whole process group at several points; two rebuilds into different outputs sharing one archive; a
worker whose rebuild lost the lock. Afterwards every report is whole, the next rebuild builds every site,
``verify`` passes and no byte of a raw input or an earlier report is lost."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import psutil
import pytest

from cistern_archive.archive import Archive, verify_archive
from cistern_archive.service.lock import RebuildLock
from cistern_archive.service.rebuild import rebuild
from fault_helpers import digest_tree, guard  # noqa: F401  (guard is a fixture)
from service_helpers import FAST_REPORT, copy_built, make_catalog, report_is_complete

SITES = ["cistern-000", "cistern-001", "cistern-002"]


@pytest.fixture(scope="module")
def built_once(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("faults-kill")
    catalog = make_catalog(root / "catalog", n_sites=3)
    summary = rebuild(catalog, root / "site", workers=2, report_config=FAST_REPORT)
    assert [s.status for s in summary.sites] == ["ok"] * 3
    return catalog, root / "site"


@pytest.fixture()
def built(built_once, tmp_path, guard) -> tuple[Path, Path]:
    catalog, out = copy_built(built_once, tmp_path)
    guard.watch_raw(catalog)
    guard.watch_reports(out)
    return catalog, out


def _start_rebuild(catalog: Path, out: Path, *, workers: int = 2, archive: Path | None = None,
                   force: bool = True) -> subprocess.Popen:
    code = textwrap.dedent(f"""
        from pathlib import Path
        from cistern_archive.service.rebuild import rebuild
        archive = {str(archive) if archive else None!r}
        summary = rebuild(Path({str(catalog)!r}), Path({str(out)!r}), workers={workers}, force={force},
                          archive=Path(archive) if archive else None, report_config={FAST_REPORT!r})
        raise SystemExit(summary.exit_code)
    """)
    return subprocess.Popen([sys.executable, "-c", code], start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


def _staging(out: Path) -> list[Path]:
    return [p for p in out.iterdir() if p.name.startswith(".") and ".tmp-" in p.name] if out.is_dir() else []


def _log_text(out: Path, runs_before: int) -> str:
    logs = sorted((out / "logs").iterdir()) if (out / "logs").is_dir() else []
    return logs[-1].read_text() if len(logs) > runs_before else ""


def _wait_for(condition, victim: subprocess.Popen, what: str, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline or victim.poll() is not None:
            os.killpg(victim.pid, signal.SIGKILL)
            pytest.fail(f"the rebuild never reached {what}")
        time.sleep(0.01)


def _alive(pids: list[int]) -> list[int]:
    alive = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                alive.append(pid)
        except psutil.NoSuchProcess:
            pass
    return alive


def _wait_gone(pids: list[int], timeout: float) -> list[int]:
    deadline = time.monotonic() + timeout
    alive = _alive(pids)
    while alive and time.monotonic() < deadline:
        time.sleep(0.05)
        alive = _alive(alive)
    return alive


def _recovers(catalog: Path, out: Path, guard, archive: Path | None = None) -> None:
    summary = rebuild(catalog, out, workers=2, archive=archive, report_config=FAST_REPORT)
    assert summary.exit_code == 0, [s.error for s in summary.sites]
    assert not _staging(out) and not (out / ".rebuild.lock").exists()
    for site in SITES:
        assert report_is_complete(out / site)
    with Archive(archive or catalog.parent / ".archive") as store:
        report = verify_archive(store)
        assert report.ok, [str(p) for p in report.problems]
        assert store.index.db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert guard.check() == []


# ------------------------------------------------------------------------------------ defect 3
def test_a_worker_dies_when_the_rebuild_process_is_gone(tmp_path):
    code = textwrap.dedent("""
        import os, sys, time, multiprocessing
        from cistern_archive.service.worker import die_with_parent
        def child(pid):
            die_with_parent(pid)
            print(os.getpid(), flush=True)
            time.sleep(120)
        if __name__ == "__main__":
            ctx = multiprocessing.get_context("spawn")
            worker = ctx.Process(target=child, args=(os.getpid(),))
            worker.start()
            time.sleep(120)
    """)
    script = tmp_path / "parent.py"
    script.write_text(code)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True,
                              start_new_session=True)
    try:
        child = int(parent.stdout.readline())
        parent.kill()
        parent.wait()
        assert _wait_gone([child], timeout=5) == [], "the worker outlived its rebuild"
    finally:
        os.killpg(parent.pid, signal.SIGKILL) if parent.poll() is None else None
        parent.stdout.close()


def test_a_worker_never_publishes_without_holding_the_lock(built, guard):
    from cistern_archive.service.worker import SiteTask, run_site

    catalog, out = built
    before = digest_tree(out / "cistern-000")
    with RebuildLock(out, "the-next-rebuild"):  # a later rebuild took over while this worker was building
        task = SiteTask(site_id="cistern-000", record_path=str(catalog / "sites" / "cistern-000.yaml"),
                        catalog_root=str(catalog), out=str(out), build_key="k", key_material={},
                        run_id="the-killed-rebuild", report_config=FAST_REPORT)
        outcome = run_site(task)
    assert outcome.status == "failed" and "no longer holds the lock" in outcome.error
    assert digest_tree(out / "cistern-000") == before and not _staging(out)
    assert guard.check() == []


@pytest.mark.slow
def test_kill_9_of_the_main_process_takes_its_workers_with_it(built, guard):
    catalog, out = built
    victim = _start_rebuild(catalog, out, workers=2)
    workers: list[int] = []
    try:
        _wait_for(lambda: len(_staging(out)) >= 2, victim, "two sites building at once")
        workers = [p.pid for p in psutil.Process(victim.pid).children(recursive=True)]
        assert workers
        os.kill(victim.pid, signal.SIGKILL)  # the main process only, as an OOM killer or `kill -9 PID` does
        victim.wait()
        assert _wait_gone(workers, timeout=5) == [], "workers outlived the rebuild"
        frozen = {site: digest_tree(out / site) for site in SITES}
        time.sleep(3)  # nothing may publish after the rebuild died
        assert {site: digest_tree(out / site) for site in SITES} == frozen
    finally:
        for pid in _alive(workers):  # only on failure: the workers this test started
            os.kill(pid, signal.SIGKILL)
        victim.stderr.close()
    _recovers(catalog, out, guard)


POINTS = {
    "lock taken": lambda out, log: (out / ".rebuild.lock").is_file(),
    "first site staged": lambda out, log: bool(_staging(out)),
    "first site published": lambda out, log: ": ok in " in log,
}


@pytest.mark.slow
@pytest.mark.parametrize("point", sorted(POINTS))
def test_kill_9_of_the_process_group_at_several_points(built, guard, point):
    catalog, out = built
    runs_before = len(list((out / "logs").iterdir()))
    victim = _start_rebuild(catalog, out, workers=2)
    try:
        _wait_for(lambda: POINTS[point](out, _log_text(out, runs_before)), victim, point)
    finally:
        os.killpg(victim.pid, signal.SIGKILL)
        victim.wait()
        victim.stderr.close()
    for site in SITES:  # straight after the crash every report is whole: the previous one or a new one
        assert report_is_complete(out / site)
    _recovers(catalog, out, guard)


@pytest.mark.slow
def test_two_rebuilds_into_different_outputs_share_one_archive(built_once, tmp_path, guard):
    catalog, _ = copy_built(built_once, tmp_path)
    guard.watch_raw(catalog)
    archive = tmp_path / "shared-archive"  # empty: both rebuilds store every object at the same time
    outs = [tmp_path / "out-a", tmp_path / "out-b"]
    for round_ in range(2):
        victims = [_start_rebuild(catalog, out, workers=1, archive=archive, force=round_ == 1) for out in outs]
        results = [(v.wait(timeout=300), v.stderr.read()) for v in victims]
        for victim in victims:
            victim.stderr.close()
        assert [code for code, _ in results] == [0, 0], results
        for out in outs:
            summary = json.loads((out / "summary.json").read_text())
            assert [s["status"] for s in summary["sites"]] == ["ok"] * 3
    with Archive(archive) as store:
        assert verify_archive(store).ok
        assert store.index.db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert guard.check() == []
