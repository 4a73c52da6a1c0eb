"""Rebuilds on a real Dask cluster on loopback give the same results as local worker processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cistern_archive.service.executors import DaskExecutor, LocalExecutor, choose_executor
from cistern_archive.service.rebuild import rebuild
from service_helpers import CLI, FAST_REPORT, comparable_result, make_catalog

SITES = ["cistern-000", "cistern-001"]
DASK = Path(sys.executable).with_name("dask")


@pytest.fixture(scope="module")
def catalog(tmp_path_factory) -> Path:
    return make_catalog(tmp_path_factory.mktemp("template") / "catalog")


@pytest.fixture(scope="module")
def local_run(catalog, tmp_path_factory) -> Path:
    """The reference: the catalog built by local worker processes."""
    out = tmp_path_factory.mktemp("local") / "site"
    summary = rebuild(catalog, out, workers=2, report_config=FAST_REPORT)
    assert [s.status for s in summary.sites] == ["ok", "ok"]
    return out


def _science(path: Path) -> dict:
    """The result without timings and without the list of report files (the command renders the full
    report, the reference run a light one)."""
    data = comparable_result(path)
    data.pop("artifacts", None)
    return data


def _assert_same_results(out: Path, reference: Path, sites: list[str] = SITES) -> None:
    for site in sites:
        assert _science(out / site / "result.json") == _science(reference / site / "result.json")


def test_local_cluster_gives_the_local_results(catalog, local_run, tmp_path):
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        summary = rebuild(catalog, tmp_path / "site", scheduler=cluster.scheduler_address,
                          report_config=FAST_REPORT)
    assert summary.executor == f"dask {cluster.scheduler_address}" and summary.workers == 2
    assert [s.status for s in summary.sites] == ["ok", "ok"]
    assert all(s.worker and not s.worker.endswith(f":{os.getpid()}") for s in summary.sites)
    _assert_same_results(tmp_path / "site", local_run)


def _wait_for(path: Path, seconds: float) -> None:
    deadline = time.monotonic() + seconds
    while not path.is_file():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{path} did not appear within {seconds} s")
        time.sleep(0.1)


@pytest.mark.slow
def test_dask_scheduler_and_worker_processes(catalog, local_run, tmp_path):
    scheduler_file = tmp_path / "scheduler.json"
    logs = [open(tmp_path / name, "w") for name in ("scheduler.log", "worker.log")]
    scheduler = subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                  "--scheduler-file", str(scheduler_file)], stdout=logs[0], stderr=subprocess.STDOUT)
    worker = None
    try:
        _wait_for(scheduler_file, 60)
        worker = subprocess.Popen([str(DASK), "worker", "--scheduler-file", str(scheduler_file), "--host",
                                   "127.0.0.1", "--nworkers", "2", "--nthreads", "1", "--no-dashboard"],
                                  stdout=logs[1], stderr=subprocess.STDOUT)
        from distributed import Client

        with Client(scheduler_file=str(scheduler_file), timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
            address = client.scheduler.address
        out = tmp_path / "site"
        run = subprocess.run([*CLI, "rebuild", "--catalog", str(catalog), "--out", str(out),
                              "--scheduler-file", str(scheduler_file)], capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr
        summary = json.loads((out / "summary.json").read_text())
        assert summary["executor"] == f"dask {address}" and summary["workers"] == 2
        _assert_same_results(out, local_run)

        env = {**os.environ, "DASK_SCHEDULER_ADDRESS": address}
        again = subprocess.run([*CLI, "rebuild", "--catalog", str(catalog), "--out", str(tmp_path / "env"),
                                "--site", "cistern-001"], capture_output=True, text=True, timeout=600, env=env)
        assert again.returncode == 0, again.stderr
        assert json.loads((tmp_path / "env" / "summary.json").read_text())["executor"] == f"dask {address}"
        _assert_same_results(tmp_path / "env", local_run, ["cistern-001"])
    finally:
        for process in (worker, scheduler):
            if process is not None:
                process.terminate()
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()
        for handle in logs:
            handle.close()


def test_executor_choice(monkeypatch):
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)
    local = choose_executor(workers=3)
    assert isinstance(local, LocalExecutor) and local.workers == 3
    local.close()
    with pytest.raises(ValueError, match="at least 1"):
        LocalExecutor(0)
    assert DaskExecutor.name == "dask"
