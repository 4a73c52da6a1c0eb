"""A demo site re-simulated with other vertical beam widths: how much of its error the vertical lobe makes.

The spec of one simulated demo site (default: the bell-shaped cistern) is simulated again with the
sonar's ``vertical_beam_width_deg`` set to each width asked for (everything else, the seed included,
unchanged), built by the runner and scored as ``benchmarks/sites.py`` scores the demo sites (pairs
with at least 50 % overlap within 0.10 m, converged pairs more than 0.10 m off, aligned scan errors)
and as ``benchmarks/model3d.py`` scores the 3D model (surface distances and the share outside the
true walls). On walls that lean over the vehicle a wide lobe hears the wall first from above, nearer
than where the lobe's axis meets it (``benchmarks/RESULTS.md``, "why the bell-shaped cistern misses").

Usage::

    .venv/bin/python benchmarks/lobe.py [--site bell-cistern] [--width 35 --width 4] [--json]

The last line of ``--json`` is ``{"site", "widths": {WIDTH: {"pairs_ge50", "pairs_ge50_ok",
"false_convergences", "median_aligned_error_m", "max_aligned_error_m", "median_surface_m",
"p95_surface_m", "outside_area_fraction"}}}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

import model3d  # noqa: E402
import sites  # noqa: E402
from cistern_archive.catalog.loader import load_record  # noqa: E402
from cistern_archive.pipeline.runner import build_site  # noqa: E402
from cistern_archive.simulation.chambers import simulate_into  # noqa: E402
from cistern_archive.simulation.spec import load_spec  # noqa: E402

PAIR_KEYS = ("pairs_ge50", "pairs_ge50_ok", "false_convergences", "median_aligned_error_m", "max_aligned_error_m")
MODEL_KEYS = ("median_surface_m", "p95_surface_m", "outside_area_fraction")


def with_vertical_beam(spec_path: Path, width_deg: float, out: Path) -> Path:
    """A copy of the spec at ``spec_path`` in ``out/specs`` with the sonar's vertical beam width set."""
    spec = yaml.safe_load(spec_path.read_text())
    spec.setdefault("sonar", {})["vertical_beam_width_deg"] = float(width_deg)
    target = out / "specs" / spec_path.name
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(yaml.safe_dump(spec, sort_keys=False))
    return target


def score_width(spec_path: Path, width_deg: float) -> dict:
    """Simulate, build and score the site with one vertical beam width."""
    with tempfile.TemporaryDirectory(prefix="lobe-") as tmp:
        catalog = Path(tmp)
        loaded = load_record(simulate_into(with_vertical_beam(spec_path, width_deg, catalog), catalog), catalog)
        start = time.perf_counter()
        build = build_site(loaded)
        row = sites.score_build(loaded, build, catalog, time.perf_counter() - start)
        model = model3d.score(build, load_spec(loaded.resolve(loaded.record.simulation)))
    return {**{k: row[k] for k in PAIR_KEYS}, **{k: model[k] for k in MODEL_KEYS}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", type=Path, default=ROOT.parent / "catalog")
    parser.add_argument("--site", default="bell-cistern", help="a simulated demo site (its spec in CATALOG/specs)")
    parser.add_argument("--width", type=float, action="append", help="vertical beam width, degrees (repeatable); "
                        "default 35 and 4")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON on the last line")
    args = parser.parse_args(argv)
    spec_path = args.catalog / "specs" / f"{args.site}.yaml"
    if not spec_path.is_file():
        parser.error(f"{spec_path}: no simulator spec for site {args.site!r}")
    widths = {f"{w:g}": score_width(spec_path, w) for w in (args.width or [35.0, 4.0])}
    print(f"{'vertical beam':>14}  pairs>=50% ok  false  aligned med/max (m)  model med/p95 (m)  outside")
    for width, r in widths.items():
        print(f"{width + '°':>14}  {r['pairs_ge50_ok']:>5}/{r['pairs_ge50']:<6}  {r['false_convergences']:>5}  "
              f"{r['median_aligned_error_m']:.3f}/{r['max_aligned_error_m']:.3f}        "
              f"{r['median_surface_m']:.3f}/{r['p95_surface_m']:.3f}        {100 * r['outside_area_fraction']:.1f} %")
    if args.json:
        print(json.dumps({"site": args.site, "widths": widths}, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
