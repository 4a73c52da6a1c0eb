"""How often the 95 % intervals of the map's dimensions hold the true value, on simulated sites.

Every truth dimension (tape-measure references of simulated sites, whose values are the simulator's
geometry) of the bundled demo catalog and of ``--synthetic N`` generated rectangular cisterns
(:func:`cistern_archive.simulation.synthetic.write_synthetic_catalog`, seeded) is built through the
pipeline; a dimension is covered when ``|map_m − reference_m| ≤ ci95_m``
(:mod:`cistern_archive.pipeline.intervals`). Unmeasured dimensions are counted apart.

Usage::

    .venv/bin/python benchmarks/intervals.py [--catalog catalog] [--synthetic 20] [--seed 3] [--json]

The last line of ``--json`` is ``{"nominal": 0.95, "coverage", "n", ...}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from cistern_archive.catalog.loader import load_record, record_paths  # noqa: E402
from cistern_archive.pipeline.runner import build_site  # noqa: E402
from cistern_archive.simulation.synthetic import write_synthetic_catalog  # noqa: E402


def truth_dimensions(catalog: Path) -> list[dict]:
    """One row per truth dimension of every simulated site of the catalog."""
    rows = []
    for path in record_paths(catalog):
        loaded = load_record(path, catalog)
        if loaded.record.simulation is None:
            continue
        build = build_site(loaded)
        for d in build.result.dimensions:
            if d.reference_kind != "truth":
                continue
            rows.append({"site": loaded.record.id, "name": d.name, "map_m": d.map_m, "reference_m": d.reference_m,
                         "ci95_m": d.ci95_m,
                         "covered": None if d.map_m is None or d.ci95_m is None
                         else bool(abs(d.map_m - d.reference_m) <= d.ci95_m)})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", type=Path, default=ROOT / "catalog")
    parser.add_argument("--synthetic", type=int, default=20, help="generated cisterns besides the catalog")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    rows = truth_dimensions(args.catalog)
    if args.synthetic:
        with tempfile.TemporaryDirectory(prefix="intervals-") as folder:
            write_synthetic_catalog(Path(folder), args.synthetic, seed=args.seed)
            rows += truth_dimensions(Path(folder))
    judged = [r for r in rows if r["covered"] is not None]
    coverage = float(np.mean([r["covered"] for r in judged])) if judged else None
    summary = {"nominal": 0.95, "coverage": None if coverage is None else round(coverage, 4), "n": len(judged),
               "unmeasured": len(rows) - len(judged),
               "median_ci95_m": round(float(np.median([r["ci95_m"] for r in judged])), 4) if judged else None,
               "missed": [f"{r['site']}: {r['name']}" for r in judged if not r["covered"]]}
    if not args.json:
        for r in rows:
            print(r)
    print(json.dumps(summary, sort_keys=True) if args.json else summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
