"""The simulated LAIR pool (McVicker et al., Sec. IV) over many seeds, beside the paper's numbers.

Each seed re-simulates the four scans of ``catalog/specs/lair-pool.yaml`` (a Micron-like head with
speckle, multipath, spikes, the vehicle's own echo and a biased, noisy compass) into a temporary catalog
(the simulator's writer, as ``cistern-archive simulate`` does) and builds that site record with the
pipeline runner (:func:`cistern_archive.pipeline.runner.build_site`, no rendering): segmentation,
the localizer's pairs (both rounds), matcher, localizer, mapper and comparator with the record's
references (10 probes each). ``--STAGE NAME`` runs another plugin for that stage than the record's (e.g.
``--matcher pf-pairwise --localizer wls``, the pipeline of the paper); ``--STAGE-param`` overrides a stage's parameters in the record (a dotted key such as
``filter.n_particles=300`` sets one field of a parameter section).
The site time is the runner's, without configuring and loading the scans.

Usage::

    .venv/bin/python benchmarks/pool.py [--seeds 20] [--json] [--STAGE NAME] [--STAGE-param key=value ...]

A pair counts as a success when it converged within 0.10 m of the truth displacement expressed in the
reference scan's compass frame (the map is drawn with the measured compass, so a common compass bias
rotates every estimate alike and is not an error of the matcher).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from cistern_archive.catalog.loader import load_record  # noqa: E402
from cistern_archive.catalog.models import StageChoice  # noqa: E402
from cistern_archive.evaluation import in_compass_frame  # noqa: E402
from cistern_archive.pipeline.contracts import STAGES  # noqa: E402
from cistern_archive.pipeline.registry import default_registry  # noqa: E402
from cistern_archive.pipeline.runner import build_site  # noqa: E402
from cistern_archive.simulation.output import write_site  # noqa: E402
from cistern_archive.simulation.simulator import simulate_site  # noqa: E402
from cistern_archive.simulation.spec import load_spec  # noqa: E402

PAPER = {
    "width_error_m": 3.47 - 3.61,
    "length_error_m": 7.27 - 7.21,
    "percent_difference": 3.30,
    "probe_std_width_m": 0.119,
    "probe_std_length_m": 0.060,
}
TARGETS = {
    "median_abs_width_error_m": 0.05,
    "median_abs_length_error_m": 0.05,
    "percent_difference": 1.0,
    "probe_std_width_m": 0.05,
    "probe_std_length_m": 0.05,
    "median_pair_seconds": 0.1,
    "median_site_seconds": 5.0,
}


def parse_value(text: str) -> object:
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def parse_overrides(items: list[str]) -> dict[str, object]:
    """``KEY=VALUE`` items as a parameter dict; a dotted key (``filter.n_particles=300``) nests."""
    out: dict[str, object] = {}
    for item in items:
        key, _, value = item.partition("=")
        *sections, field = key.split(".")
        target = out
        for section in sections:
            target = target.setdefault(section, {})
        target[field] = parse_value(value)
    return out


def merged(params: dict, overrides: dict) -> dict:
    """``params`` with ``overrides`` laid over it, section by section."""
    out = dict(params)
    for key, value in overrides.items():
        out[key] = merged(out.get(key) or {}, value) if isinstance(value, dict) else value
    return out


def expected_displacement(sim, i: int, j: int) -> np.ndarray:
    """Truth ``p_j - p_i`` rotated into scan i's measured-compass frame."""
    a, b = sim.scans[i], sim.scans[j]
    d = np.array([b.pose.x_m - a.pose.x_m, b.pose.y_m - a.pose.y_m])
    return in_compass_frame(d, a.scan.yaw_rad - a.pose.yaw_rad)


def seed_record(seed: int, spec, root: Path, overrides: dict[str, dict], plugins: dict[str, str] | None = None):
    """The pool simulated with ``seed`` as a site record in the catalog ``root``, with the stage
    parameter ``overrides`` (and ``plugins``, stage → plugin name, instead of the record's, each with its
    own defaults); returns the loaded record and the simulation (for its truth)."""
    sim = simulate_site(spec.model_copy(update={"seed": seed}))
    loaded = load_record(write_site(sim, root, record_dir="sites"), root)
    record = default_registry().resolve(loaded.record)
    pipeline = record.pipeline
    pipeline = pipeline.model_copy(update={stage: StageChoice(plugin=name) for stage, name in (plugins or {}).items()})
    stages = {stage: getattr(pipeline, stage).model_copy(
        update={"params": merged(getattr(pipeline, stage).params, overrides[stage])}) for stage in overrides}
    record = record.model_copy(update={"pipeline": pipeline.model_copy(update=stages)})
    return replace(loaded, record=record), sim


def run_seed(seed: int, spec, overrides: dict[str, dict], root: Path, plugins: dict[str, str] | None = None) -> dict:
    """Build one seed's pool with the pipeline runner (:func:`build_site`) and score it."""
    loaded, sim = seed_record(seed, spec, root / f"seed-{seed}", overrides, plugins)
    build = build_site(loaded)
    if build.result.status != "ok":
        raise SystemExit(f"seed {seed}: the build failed: {build.result.error}")
    timings = build.result.timings_s
    site_seconds = sum(v for k, v in timings.items() if k not in ("total", "configure", "load"))
    table, matches = build.table, build.matches
    rows = {(r.name, r.reference_kind): r for r in table.rows}
    ok = []
    for m in matches:
        if abs(m.i - m.j) != 1:
            continue
        err = float(np.hypot(*(np.array([m.dx_m, m.dy_m]) - expected_displacement(sim, m.i, m.j))))
        ok.append(bool(m.converged and err <= 0.10))
    return {
        "seed": seed,
        "width_error_m": rows[("width", "truth")].diff_m,
        "length_error_m": rows[("length", "truth")].diff_m,
        "percent_difference": table.stats.get("percent_difference", float("nan")),
        "probe_std_width_m": table.stats.get("probe_std_width_m", float("nan")),
        "probe_std_length_m": table.stats.get("probe_std_length_m", float("nan")),
        "mosaic_width_diff_m": rows[("width", "mosaic")].diff_m,
        "mosaic_length_diff_m": rows[("length", "mosaic")].diff_m,
        "pair_ok": ok,
        "pair_seconds": [m.seconds for m in matches],
        "placed": int(build.poses.placed.sum()),
        "site_seconds": site_seconds,
        "params": {p.stage: p.params for p in build.result.provenance.plugins},
    }


def summarise(runs: list[dict]) -> dict:
    def med(key: str) -> float:
        return float(statistics.median(r[key] for r in runs))

    def worst(key: str) -> float:
        return float(max(abs(r[key]) for r in runs))

    pair_ok = [ok for r in runs for ok in r["pair_ok"]]
    return {
        "seeds": len(runs),
        "median_abs_width_error_m": float(statistics.median(abs(r["width_error_m"]) for r in runs)),
        "worst_abs_width_error_m": worst("width_error_m"),
        "median_abs_length_error_m": float(statistics.median(abs(r["length_error_m"]) for r in runs)),
        "worst_abs_length_error_m": worst("length_error_m"),
        "median_width_error_m": med("width_error_m"),
        "median_length_error_m": med("length_error_m"),
        "percent_difference": med("percent_difference"),
        "worst_percent_difference": worst("percent_difference"),
        "probe_std_width_m": med("probe_std_width_m"),
        "probe_std_length_m": med("probe_std_length_m"),
        "median_abs_mosaic_width_diff_m": float(statistics.median(abs(r["mosaic_width_diff_m"]) for r in runs)),
        "median_abs_mosaic_length_diff_m": float(statistics.median(abs(r["mosaic_length_diff_m"]) for r in runs)),
        "pair_success_rate": sum(pair_ok) / len(pair_ok) if pair_ok else float("nan"),
        "scans_placed_fraction": sum(r["placed"] for r in runs) / (4 * len(runs)),
        "median_pair_seconds": float(statistics.median(s for r in runs for s in r["pair_seconds"])),
        "median_site_seconds": med("site_seconds"),
        "worst_site_seconds": float(max(r["site_seconds"] for r in runs)),
    }


def print_table(summary: dict) -> None:
    lines = [
        ("|width error| median / worst (m)", f"{summary['median_abs_width_error_m']:.3f} / {summary['worst_abs_width_error_m']:.3f}",
         f"{abs(PAPER['width_error_m']):.3f}", "<= 0.05"),
        ("|length error| median / worst (m)", f"{summary['median_abs_length_error_m']:.3f} / {summary['worst_abs_length_error_m']:.3f}",
         f"{abs(PAPER['length_error_m']):.3f}", "<= 0.05"),
        ("percent difference median / worst (%)", f"{summary['percent_difference']:.2f} / {summary['worst_percent_difference']:.2f}",
         f"{PAPER['percent_difference']:.2f}", "<= 1"),
        ("probe std width (m)", f"{summary['probe_std_width_m']:.3f}", f"{PAPER['probe_std_width_m']:.3f}", "<= 0.05"),
        ("probe std length (m)", f"{summary['probe_std_length_m']:.3f}", f"{PAPER['probe_std_length_m']:.3f}", "<= 0.05"),
        ("neighbour pairs within 0.10 m", f"{100 * summary['pair_success_rate']:.1f} %", "-", ">= 95 %"),
        ("median time per pair (s)", f"{summary['median_pair_seconds']:.3f}", "-", "<= 0.1"),
        ("median / worst site time (s)", f"{summary['median_site_seconds']:.2f} / {summary['worst_site_seconds']:.2f}", "-", "<= 5"),
    ]
    print(f"{'metric':42s} {'measured':>18s} {'paper':>8s} {'target':>9s}")
    for name, value, paper, target in lines:
        print(f"{name:42s} {value:>18s} {paper:>8s} {target:>9s}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    for stage in STAGES:
        parser.add_argument(f"--{stage}", metavar="NAME", help=f"{stage} plugin to use instead of the record's")
        parser.add_argument(f"--{stage}-param", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args(argv)

    spec = load_spec(ROOT / "catalog" / "specs" / "lair-pool.yaml")
    overrides = {stage: parse_overrides(getattr(args, f"{stage}_param")) for stage in STAGES}
    with tempfile.TemporaryDirectory(prefix="pool-") as tmp:
        plugins = {stage: getattr(args, stage) for stage in STAGES if getattr(args, stage)}
        runs = [run_seed(seed, spec, overrides, Path(tmp), plugins)
                for seed in range(args.first_seed, args.first_seed + args.seeds)]
    summary = summarise(runs)
    summary["params"] = runs[0]["params"]
    print_table(summary)
    if args.json:
        print(json.dumps(summary, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
