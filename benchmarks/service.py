"""Benchmark of the archival service on a generated catalog of simulated sites.

Measures, in one run and on the same catalog:

- a full rebuild with 1 local worker and with 2 local workers (fresh output folders, side by side),
  and the speed-up between them (target >= 1.7x);
- a no-change rebuild with the ``cistern-archive rebuild`` command, interpreter start-up included
  (target <= 2 s), and the same call made in-process;
- the peak resident memory of every worker process (target <= 1 GB).

Usage::

    python benchmarks/service.py                 # 60 sites, full reports
    python benchmarks/service.py --sites 10 --report light --json

The benchmark runs on a frozen copy of the sources (``--live-sources`` to use the working tree), so
that edits made to the tree while it runs do not change the build keys between its measurements.

``--report light`` renders reports without the 3D model and the per-pair figures (for quick checks);
the targets are stated for the full report.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LIGHT_REPORT = {"model": False, "max_pair_figures": 0, "max_fan_figures": 0, "dpi": 50}
TARGETS = {"no_change_s": 2.0, "speedup": 1.7, "peak_worker_rss_mb": 1024.0}


def _timed_rebuild(catalog: Path, out: Path, archive: Path, *, workers: int, report: dict | None) -> dict:
    from cistern_archive.service.rebuild import rebuild

    start = time.perf_counter()
    summary = rebuild(catalog, out, workers=workers, archive=archive, report_config=report)
    seconds = time.perf_counter() - start
    counts = summary.counts()
    rss = [s.peak_rss_mb for s in summary.sites if s.peak_rss_mb is not None]
    site_wall = sum(s.timings_s.get("wall", 0.0) for s in summary.sites)
    site_cpu = sum(s.timings_s.get("cpu", 0.0) for s in summary.sites)
    return {"seconds": round(seconds, 3), "counts": counts, "exit_code": summary.exit_code,
            "sites_wall_s": round(site_wall, 3), "sites_cpu_s": round(site_cpu, 3),
            "busy_workers": round(site_wall / seconds, 3) if seconds > 0 else None,
            "workers_seen": len({s.worker for s in summary.sites if s.worker}),
            "peak_worker_rss_mb": max(rss) if rss else None, "code_version": summary.code_version,
            "failed": {s.id: s.error for s in summary.failed}}


def _warm_up(catalog: Path, archive: Path) -> None:
    """Archive every input once, so that neither timed run pays for the first copy into the archive."""
    from cistern_archive.archive import Archive
    from cistern_archive.pipeline.validate import validate_catalog
    from cistern_archive.pipeline.registry import default_registry
    from cistern_archive.service.planning import plan_site

    registry = default_registry()
    with Archive(archive) as store:
        for loaded in validate_catalog(catalog, registry).records:
            plan_site(loaded, store, registry, run_id=None)


def _fresh_code_version() -> str:
    code = "from cistern_archive.service.buildkey import code_version; print(code_version())"
    # Run outside the repository: the working directory would shadow a frozen copy of the sources.
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                          cwd=tempfile.gettempdir()).stdout.strip()


def run(n_sites: int, report_mode: str, workdir: Path) -> dict:
    from cistern_archive.simulation.synthetic import write_synthetic_catalog

    report = LIGHT_REPORT if report_mode == "light" else None
    catalog, archive = workdir / "catalog", workdir / "archive"
    start = time.perf_counter()
    write_synthetic_catalog(catalog, n_sites, seed=2024)
    generate_s = time.perf_counter() - start

    _warm_up(catalog, archive)
    one = _timed_rebuild(catalog, workdir / "out-1", archive, workers=1, report=report)
    two = _timed_rebuild(catalog, workdir / "out-2", archive, workers=2, report=report)
    in_process = _timed_rebuild(catalog, workdir / "out-2", archive, workers=2, report=report)

    cli: dict = {"seconds": None, "note": ""}
    if report is None and _fresh_code_version() == in_process["code_version"]:
        command = [str(Path(sys.executable).with_name("cistern-archive")), "rebuild", "--catalog", str(catalog),
                   "--out", str(workdir / "out-2"), "--archive", str(archive), "--workers", "2"]
        start = time.perf_counter()
        proc = subprocess.run(command, capture_output=True, text=True, cwd=workdir)
        cli["seconds"] = round(time.perf_counter() - start, 3)
        summary = json.loads((workdir / "out-2" / "summary.json").read_text())
        cli["skipped"] = sum(s["status"] == "skipped" for s in summary["sites"])
        cli["exit_code"] = proc.returncode
    elif report is not None:
        cli["note"] = "light reports are not reachable from the command; in-process figure only"
    else:
        cli["note"] = "package sources changed during the run; the command would rebuild, not measured"

    speedup = one["seconds"] / two["seconds"]
    peak = max(v for v in (one["peak_worker_rss_mb"], two["peak_worker_rss_mb"]) if v is not None)
    no_change = cli["seconds"] if cli["seconds"] is not None else in_process["seconds"]
    return {
        "benchmark": "service",
        "sites": n_sites,
        "report": report_mode,
        "cpu_count": os.cpu_count(),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "generate_catalog_s": round(generate_s, 3),
        "full_rebuild_1_worker": one,
        "full_rebuild_2_workers": two,
        "speedup_1_to_2_workers": round(speedup, 3),
        "no_change_rebuild_in_process": in_process,
        "no_change_rebuild_command": cli,
        "peak_worker_rss_mb": peak,
        "targets": TARGETS,
        "met": {
            "no_change_s": no_change <= TARGETS["no_change_s"] and in_process["counts"]["skipped"] == n_sites,
            "speedup": speedup >= TARGETS["speedup"],
            "peak_worker_rss_mb": peak <= TARGETS["peak_worker_rss_mb"],
        },
    }


FROZEN_ENV = "CISTERN_BENCH_FROZEN_SOURCES"


def freeze_sources(target: Path) -> Path:
    """Copy the package (its templates included) and the built-in plugins to ``target`` (excluding caches).

    Build keys cover the package sources; on a tree that is being edited, a frozen copy keeps the code
    version fixed for the whole benchmark (the main process, the workers and the command).
    """
    repo = Path(__file__).resolve().parents[1]
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(repo / "cistern_archive", target / "cistern_archive", ignore=ignore)
    shutil.copytree(repo / "plugins" / "cistern_plugins", target / "cistern_plugins", ignore=ignore)
    return target


def _rerun_frozen(argv: list[str]) -> int:
    snapshot = freeze_sources(Path(tempfile.mkdtemp(prefix="cistern-service-src-")))
    env = {**os.environ, FROZEN_ENV: str(snapshot),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(snapshot), os.environ.get("PYTHONPATH")]))}
    try:
        return subprocess.run([sys.executable, __file__, *argv], env=env).returncode
    finally:
        shutil.rmtree(snapshot, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--live-sources" not in argv and not os.environ.get(FROZEN_ENV):
        return _rerun_frozen(argv)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--live-sources", action="store_true",
                        help="use the working tree as it is (default: a frozen copy of the sources)")
    parser.add_argument("--sites", type=int, default=60, help="number of generated sites (default 60)")
    parser.add_argument("--report", choices=("full", "light"), default="full", help="report settings")
    parser.add_argument("--workdir", type=Path, default=None, help="keep the catalog and outputs here")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)
    os.environ.setdefault("SOURCE_DATE_EPOCH", "1700000000")
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="cistern-service-bench-"))
    try:
        result = run(args.sites, args.report, workdir)
    finally:
        if args.workdir is None:
            shutil.rmtree(workdir, ignore_errors=True)
    result["frozen_sources"] = bool(os.environ.get(FROZEN_ENV))
    if args.json:
        print(json.dumps(result, sort_keys=True))
    else:
        print(f"{result['sites']} sites, {result['report']} reports, load {result['load_average_1min']}")
        print(f"full rebuild, 1 worker : {result['full_rebuild_1_worker']['seconds']:.1f} s")
        print(f"full rebuild, 2 workers: {result['full_rebuild_2_workers']['seconds']:.1f} s "
              f"(speed-up {result['speedup_1_to_2_workers']:.2f}x, target >= {TARGETS['speedup']}x)")
        print(f"no-change rebuild: command {result['no_change_rebuild_command']['seconds']} s, in-process "
              f"{result['no_change_rebuild_in_process']['seconds']:.2f} s (target <= {TARGETS['no_change_s']} s)")
        print(f"peak worker memory: {result['peak_worker_rss_mb']:.0f} MiB "
              f"(target <= {TARGETS['peak_worker_rss_mb']:.0f})")
        print(f"targets met: {result['met']}")
    return 0 if all(result["met"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
