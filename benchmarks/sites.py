"""Every simulated demo site of the catalog through the pipeline, scored against its truth poses.

For each record in ``catalog/sites/*.yaml`` that has ``truth`` poses, the pipeline runner builds the site
with the record's plugins (the defaults: pf-pairwise, wls, evidence-grid, mosaic) and this script
reports:

* scans placed / scans;
* position error of the placed scans: the truth positions relative to the reference scan, rotated by the
  reference scan's compass error (the map is drawn in the measured-compass frame), against the placed
  positions — median and max;
* neighbour pairs with at least 50 % overlap (visible-area overlap from the site's simulator spec) that
  converged within 0.10 m of the truth displacement (in the moving pair's reference-scan compass frame);
* false convergences: pairs reported converged that are more than 0.10 m off, and among them those whose
  scans do not overlap at all;
* the whole-site time.

Pairs of scans at different depth levels (depths more than ``LEVEL_TOLERANCE_M`` apart, the mapper's
default slice tolerance) see different wall outlines in a site whose walls change with depth; their
overlap is undefined (``nan``), so they count neither as pairs with ≥ 50 % overlap nor as pairs without
overlap. They are reported apart (``cross_level_pairs``, ``cross_level_converged``); the localizer joins
depth levels through the record's vertical ties (``ScanRef.below``).

Usage::

    .venv/bin/python benchmarks/sites.py [--catalog catalog] [--site ID ...] [--json]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
LEVEL_TOLERANCE_M = 0.25

from cistern_archive.catalog.loader import load_record, record_paths  # noqa: E402
from cistern_archive.evaluation import in_compass_frame, position_errors as aligned_errors  # noqa: E402
from cistern_archive.evaluation import reference_frame_errors  # noqa: E402
from cistern_archive.catalog.models import StageChoice  # noqa: E402
from cistern_archive.pipeline.runner import build_site  # noqa: E402
from cistern_archive.sonar.geometry import interpolate_slice, overlap_fraction  # noqa: E402
from cistern_archive.sonar.simulator_spec import load_spec  # noqa: E402


def with_localizer(loaded, localizer: str | None):
    """The record with another localizer plugin (default parameters), or unchanged."""
    if localizer is None:
        return loaded
    pipeline = loaded.record.pipeline.model_copy(update={"localizer": StageChoice(plugin=localizer)})
    return replace(loaded, record=loaded.record.model_copy(update={"pipeline": pipeline}))


def score_site(path: Path, catalog: Path, localizer: str | None = None) -> dict | None:
    loaded = with_localizer(load_record(path, catalog), localizer)
    record = loaded.record
    if not record.truth:
        return None
    truth = {t.station: t for t in record.truth}
    stations = [s.station for s in record.scans]
    t0 = time.perf_counter()
    build = build_site(loaded)
    seconds = time.perf_counter() - t0
    scans = build.range_scans
    true_xy = np.array([[truth[s].x_m, truth[s].y_m] for s in stations])
    compass_err = [scans[k].yaw_rad - math.radians(truth[s].yaw_deg) for k, s in enumerate(stations)]
    spec = load_spec(catalog / record.simulation) if record.simulation else None
    max_range = record.sonar.range_m or max(s.max_range_m for s in scans)

    def overlap(i: int, j: int) -> float:
        if spec is None or abs(scans[i].depth_m - scans[j].depth_m) > LEVEL_TOLERANCE_M:
            return float("nan")
        rings = interpolate_slice(spec.site.slices(), 0.5 * (scans[i].depth_m + scans[j].depth_m))
        return overlap_fraction(true_xy[i], true_xy[j], rings, max_range)

    pairs = []
    for m in build.matches:
        expected = in_compass_frame(true_xy[m.j] - true_xy[m.i], compass_err[m.i])
        err = float(np.hypot(m.dx_m - expected[0], m.dy_m - expected[1])) if m.converged else float("nan")
        neighbour = abs(m.i - m.j) == 1
        ov = overlap(m.i, m.j) if (neighbour or m.converged) else float("nan")
        pairs.append({"i": m.i, "j": m.j, "converged": m.converged, "error_m": err, "overlap": ov,
                      "neighbour": neighbour, "seconds": m.seconds})
    poses = build.poses
    position_errors = reference_frame_errors(poses, true_xy, compass_err) if poses is not None else []
    aligned = aligned_errors(build.result)
    eligible = [p for p in pairs if p["neighbour"] and p["overlap"] >= 0.5]
    good = [p for p in eligible if p["converged"] and p["error_m"] <= 0.10]
    false_conv = [p for p in pairs if p["converged"] and p["error_m"] > 0.10]
    cross_level = [m for m in build.matches if abs(scans[m.i].depth_m - scans[m.j].depth_m) > LEVEL_TOLERANCE_M]
    return {
        "site": record.id,
        "status": build.result.status,
        "scans": len(scans),
        "placed": int(poses.placed.sum()) if poses is not None else 0,
        "median_position_error_m": statistics.median(position_errors) if position_errors else float("nan"),
        "max_position_error_m": max(position_errors) if position_errors else float("nan"),
        "median_aligned_error_m": float(np.median(aligned)) if len(aligned) else float("nan"),
        "max_aligned_error_m": float(np.max(aligned)) if len(aligned) else float("nan"),
        "eligible_pairs": len(eligible),
        "eligible_pairs_ok": len(good),
        "pairs": len(pairs),
        "pairs_converged": sum(p["converged"] for p in pairs),
        "false_convergences": len(false_conv),
        "false_convergences_no_overlap": sum(1 for p in false_conv if p["overlap"] == 0.0),
        "cross_level_pairs": len(cross_level),
        "cross_level_converged": sum(1 for m in cross_level if m.converged),
        "median_pair_seconds": statistics.median(p["seconds"] for p in pairs) if pairs else float("nan"),
        "site_seconds": seconds,
        "unplaced_reasons": [r for r in (poses.reasons if poses is not None else ()) if r][:3],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", type=Path, default=ROOT / "catalog")
    parser.add_argument("--site", action="append", default=[], help="only these site ids")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--localizer", help="use this localizer plugin instead of the records' own")
    args = parser.parse_args(argv)
    rows = []
    for path in record_paths(args.catalog):
        if args.site and path.stem not in args.site:
            continue
        row = score_site(path, args.catalog, args.localizer)
        if row is not None:
            rows.append(row)
    print(f"{'site':16s} {'placed':>8s} {'pos err med/max (m)':>20s} {'pairs>=50% ok':>14s} "
          f"{'false conv':>10s} {'pair s':>7s} {'site s':>7s}")
    for r in rows:
        print(f"{r['site']:16s} {r['placed']:>3d}/{r['scans']:<4d} "
              f"{r['median_position_error_m']:>9.3f}/{r['max_position_error_m']:<9.3f} "
              f"{r['eligible_pairs_ok']:>6d}/{r['eligible_pairs']:<7d} {r['false_convergences']:>10d} "
              f"{r['median_pair_seconds']:>7.3f} {r['site_seconds']:>7.1f}")
        for reason in r["unplaced_reasons"]:
            print(f"    unplaced: {reason[:150]}")
    eligible = sum(r["eligible_pairs"] for r in rows)
    summary = {
        "sites": len(rows),
        "scans": sum(r["scans"] for r in rows),
        "scans_placed": sum(r["placed"] for r in rows),
        "pair_success_rate": sum(r["eligible_pairs_ok"] for r in rows) / eligible if eligible else float("nan"),
        "false_convergences": sum(r["false_convergences"] for r in rows),
        "false_convergences_no_overlap": sum(r["false_convergences_no_overlap"] for r in rows),
        "median_position_error_m": statistics.median(r["median_position_error_m"] for r in rows) if rows else None,
        "max_position_error_m": max((r["max_position_error_m"] for r in rows), default=None),
        "per_site": rows,
    }
    print(f"pairs with >=50% overlap within 0.10 m: {100 * summary['pair_success_rate']:.1f} % of {eligible}; "
          f"false convergences: {summary['false_convergences']} "
          f"({summary['false_convergences_no_overlap']} without overlap)")
    if args.json:
        print(json.dumps(summary, sort_keys=True, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
