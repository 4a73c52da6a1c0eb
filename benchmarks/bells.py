"""Generated bell-shaped cisterns through the real pipeline: 3D models and dimensions on leaning walls.

``--random N`` bells (:mod:`cistern_archive.simulation.bells`, seeded by ``--seed``) are simulated,
built by the runner with their records' pipeline (``--mapper-params``, ``--localizer-params`` and
``--matcher-params`` add parameters to those stages', e.g. ``--mapper-params '{"lobe_correction":
false}'``), and scored: the 3D model as ``benchmarks/model3d.py`` scores it (surface distances, share
outside the true walls), the scans' aligned errors as ``benchmarks/sites.py`` does, and every truth
dimension (length and width at each scanned depth): the map's value minus the truth, and whether its
95 % interval holds the truth.

Usage::

    .venv/bin/python benchmarks/bells.py --random 12 --seed 1 [--workers 2] [--vertical] \
        [--mapper-params JSON] [--localizer-params JSON] [--matcher-params JSON] [--json]

``--vertical`` builds wells with vertical walls, scanned the same way: the control, on which a
correction for leaning walls should change nothing.

The last line of ``--json`` is ``{"seed", "sites", "median_surface_m", "p95_surface_m",
"outside_area_fraction", "dimension_bias_m", "dimension_abs_m", "dimensions", "covered", "pairs_ge50",
"pairs_ge50_ok", "false_convergences", "median_aligned_error_m", "max_aligned_error_m", ...}``: medians
over the sites of each model figure, the dimensions' mean signed and mean absolute error, the pairs with
≥ 50 % overlap and those within 0.10 m, the converged pairs more than 0.10 m off (as
``benchmarks/sites.py`` counts them), and the aligned errors of every placed scan of every site.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

import model3d  # noqa: E402
import sites  # noqa: E402
from cistern_archive.catalog.loader import load_record  # noqa: E402
from cistern_archive.pipeline.runner import build_site  # noqa: E402
from cistern_archive.simulation.bells import write_bell_catalog  # noqa: E402
from cistern_archive.simulation.spec import load_spec  # noqa: E402

MODEL_KEYS = ("median_surface_m", "p95_surface_m", "outside_area_fraction")


def score_bell(path: Path, catalog: Path, params: dict[str, dict]) -> dict:
    """Build one generated bell (``params``: stage → parameters added to the record's) and score its
    model, its scans and its dimensions."""
    loaded = load_record(path, catalog)
    for stage, values in params.items():
        loaded = sites.with_stage(loaded, stage, None, values)
    start = time.perf_counter()
    build = build_site(loaded)
    seconds = time.perf_counter() - start
    row = sites.score_build(loaded, build, catalog, seconds)
    model = model3d.score(build, load_spec(loaded.resolve(loaded.record.simulation)))
    dimensions = [{"name": d.name, "error_m": d.map_m - d.reference_m,
                   "covered": d.ci95_m is not None and abs(d.map_m - d.reference_m) <= d.ci95_m}
                  for d in build.result.dimensions if d.reference_kind == "truth" and d.map_m is not None]
    return {"site": loaded.record.id, "status": build.result.status, "placed": row["placed"], "scans": row["scans"],
            "median_aligned_error_m": row["median_aligned_error_m"], **{k: model[k] for k in MODEL_KEYS},
            "pairs_ge50": row["pairs_ge50"], "pairs_ge50_ok": row["pairs_ge50_ok"],
            "false_convergences": row["false_convergences"], "aligned_errors_m": row["aligned_errors_m"],
            "dimensions": dimensions, "seconds": round(seconds, 2)}


def summary(rows: list[dict]) -> dict:
    """Medians over the sites, and the dimensions' errors pooled."""
    scored = [r for r in rows if r["median_surface_m"] is not None]
    dims = [d for r in rows for d in r["dimensions"]]
    aligned = [e for r in rows for e in r["aligned_errors_m"]]
    out = {"sites": len(rows), "meshed": len(scored),
           **{k: statistics.median(r[k] for r in scored) if scored else None for k in MODEL_KEYS},
           "dimensions": len(dims), "covered": sum(d["covered"] for d in dims),
           "dimension_bias_m": statistics.fmean(d["error_m"] for d in dims) if dims else None,
           "dimension_abs_m": statistics.fmean(abs(d["error_m"]) for d in dims) if dims else None,
           "placed": sum(r["placed"] for r in rows), "scans": sum(r["scans"] for r in rows),
           **{k: sum(r[k] for r in rows) for k in ("pairs_ge50", "pairs_ge50_ok", "false_convergences")},
           "median_aligned_error_m": statistics.median(aligned) if aligned else None,
           "max_aligned_error_m": max(aligned) if aligned else None}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--random", type=int, default=12, help="generated bells")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--workers", type=int, default=1, help="sites built in parallel")
    parser.add_argument("--mapper-params", type=json.loads, default={}, help="mapper parameters as JSON")
    parser.add_argument("--vertical", action="store_true", help="wells with vertical walls instead (the control)")
    parser.add_argument("--localizer-params", type=json.loads, default={}, help="localizer parameters as JSON")
    parser.add_argument("--matcher-params", type=json.loads, default={}, help="matcher parameters as JSON")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON on the last line")
    args = parser.parse_args(argv)
    if args.random < 1 or args.workers < 1:
        parser.error("--random and --workers must be at least 1")
    with tempfile.TemporaryDirectory(prefix="bells-") as folder:
        catalog = Path(folder)
        paths = write_bell_catalog(catalog, args.random, seed=args.seed, vertical=args.vertical)
        params = {"mapper": args.mapper_params, "localizer": args.localizer_params, "matcher": args.matcher_params}
        jobs = [(path, catalog, params) for path in paths]
        if args.workers > 1:
            with ProcessPoolExecutor(max_workers=args.workers) as pool:
                rows = list(pool.map(score_bell, *zip(*jobs)))
        else:
            rows = [score_bell(*job) for job in jobs]
    print(f"{'site':<10} {'status':<8} placed  aligned med  model med/p95 (m)  outside  dimensions (map - truth, m)")
    for r in rows:
        model = ("—" if r["median_surface_m"] is None
                 else f"{r['median_surface_m']:.3f}/{r['p95_surface_m']:.3f}  {100 * r['outside_area_fraction']:5.1f} %")
        dims = " ".join(f"{d['error_m']:+.3f}{'' if d['covered'] else '!'}" for d in r["dimensions"])
        print(f"{r['site']:<10} {r['status']:<8} {r['placed']:>2}/{r['scans']:<3} {r['median_aligned_error_m']:10.3f}   "
              f"{model}  {dims}")
    total = summary(rows)
    print(f"medians over {total['meshed']} meshed of {total['sites']} sites: model {total['median_surface_m']:.3f} / "
          f"{total['p95_surface_m']:.3f} m, outside {100 * total['outside_area_fraction']:.1f} %; "
          f"{total['dimensions']} dimensions: mean error {total['dimension_bias_m']:+.3f} m, mean |error| "
          f"{total['dimension_abs_m']:.3f} m, {total['covered']} within their 95 % interval ('!' marks the others)")
    if args.json:
        print(json.dumps({"seed": args.seed, "params": params, **total, "rows": rows}, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
