"""Every installed matcher on the same simulated pairs, side by side.

Pairs come from :mod:`cistern_archive.testing.pairs` (ray-cast rooms and winding galleries, 200-beam
360° sweeps, range noise 2/5/10 cm, 5 % multipath outliers, 5 % drop-outs, compass error up to 20°).
They are drawn into buckets by overlap (20–30, 30–50, 50–70, 70–90 %) and initial offset (the true
translation a matcher must recover from a zero start: < 1 m or 1–2 m), plus ``no_overlap`` pairs from
two different sites. Every matcher sees exactly the same pairs.

Per bucket: success rate (converged, translation error ≤ 0.10 m, yaw error ≤ 2°), median and 95th
percentile translation error and median rotation error over converged pairs, median seconds, and the
false success rate (converged with no overlap, or with an error above 0.5 m).

External peers (the ``peers`` extra) are run when they import: Open3D's point-to-point ICP.

    python benchmarks/matchers.py --quick --json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from cistern_archive.pipeline.contracts import MatchResult
from cistern_archive.pipeline.registry import default_registry
from cistern_archive.errors import PluginError
from cistern_archive.sonar.scan import RangeScan
from cistern_archive.testing.pairs import SimulatedPair, simulated_pair
from cistern_archive.testing.scoring import score

OVERLAPS = {"20_30": (0.2, 0.3), "30_50": (0.3, 0.5), "50_70": (0.5, 0.7), "70_90": (0.7, 0.9)}
OFFSETS = {"lt_1m": (0.0, 1.0), "ge_1m": (1.0, 2.0)}


def draw_buckets(n: int, seed: int) -> dict[str, list[SimulatedPair]]:
    """``n`` pairs per bucket, all from one seeded generator."""
    rng = np.random.default_rng(seed)
    buckets: dict[str, list[SimulatedPair]] = {}
    for oname, orange in OVERLAPS.items():
        for fname, frange in OFFSETS.items():
            try:
                buckets[f"overlap_{oname}_offset_{fname}"] = [
                    simulated_pair(rng, overlap_range=orange, offset_range_m=frange) for _ in range(n)]
            except RuntimeError as exc:  # e.g. 20-30 % overlap is (nearly) impossible within 1 m
                print(f"bucket overlap_{oname}_offset_{fname} skipped: {exc}", file=sys.stderr)
    buckets["no_overlap"] = [simulated_pair(rng, overlapping=False) for _ in range(2 * n)]
    return buckets


class Open3DICP:
    """Open3D point-to-point ICP from the zero pose, converged when fitness ≥ 0.5 and inlier RMSE ≤ 0.1 m."""

    name = "open3d-icp"

    def __init__(self) -> None:
        import open3d as o3d  # noqa: F401  (import errors are reported by the caller)

        self.o3d = o3d

    def match(self, reference: RangeScan, moving: RangeScan) -> MatchResult:
        o3d = self.o3d
        start = time.perf_counter()
        clouds = []
        for scan in (moving, reference):
            pts = scan.points()
            pc = o3d.geometry.PointCloud()
            pc.points = o3d.utility.Vector3dVector(np.column_stack([pts, np.zeros(len(pts))]))
            clouds.append(pc)
        reg = o3d.pipelines.registration.registration_icp(
            clouds[0], clouds[1], 0.5, np.eye(4),
            o3d.pipelines.registration.TransformationEstimationPointToPoint(),
            o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=60))
        t = reg.transformation
        conv = bool(reg.fitness >= 0.5 and reg.inlier_rmse <= 0.1)
        return MatchResult(-1, -1, float(t[0, 3]), float(t[1, 3]), math.atan2(t[1, 0], t[0, 0]), float(reg.fitness),
                           conv, 60, time.perf_counter() - start, "" if conv else "low fitness")


def matchers() -> tuple[dict[str, object], dict[str, str]]:
    """Built-in and third-party matchers from the registry, plus the peers that import."""
    reg = default_registry()
    found: dict[str, object] = {}
    missing: dict[str, str] = {}
    for name in reg.names("matcher"):
        try:
            plugin = reg.load("matcher", name).instance
            found[name] = lambda ref, mov, k, p=plugin: p.match(ref, mov, p.Params(), rng=np.random.default_rng(k))
        except PluginError as exc:
            missing[name] = str(exc)
    try:
        peer = Open3DICP()
        found[peer.name] = lambda ref, mov, k, p=peer: p.match(ref, mov)
    except Exception as exc:  # an optional dependency may fail in any way
        missing["open3d-icp"] = f"{type(exc).__name__}: {exc}"
    return found, missing


def summarise(scores: list) -> dict[str, float]:
    conv = [s for s in scores if s.converged and math.isfinite(s.translation_error_m)]
    te = [s.translation_error_m for s in conv]
    re = [s.rotation_error_deg for s in conv]
    nan = float("nan")
    return {
        "n": len(scores),
        "success_rate": float(np.mean([s.success for s in scores])),
        "median_translation_error_m": float(np.median(te)) if te else nan,
        "p95_translation_error_m": float(np.percentile(te, 95)) if te else nan,
        "median_rotation_error_deg": float(np.median(re)) if re else nan,
        "median_seconds": float(np.median([s.seconds for s in scores])),
        "false_success_rate": float(np.mean([s.false_success for s in scores])),
    }


def run(n: int, seed: int) -> dict:
    buckets = draw_buckets(n, seed)
    found, missing = matchers()
    out: dict = {"matchers": {}, "unavailable": missing, "pairs_per_bucket": n, "seed": seed}
    for name, fn in found.items():
        per: dict[str, dict] = {}
        all_scores = []
        for bucket, pairs in buckets.items():
            scores = []
            for k, pr in enumerate(pairs):
                try:
                    res = fn(pr.reference, pr.moving, k)
                except Exception as exc:  # one failing plugin must not stop the comparison
                    out["unavailable"][name] = f"raised on {bucket} pair {k}: {type(exc).__name__}: {exc}"
                    break
                scores.append(score(res, pr))
            per[bucket] = summarise(scores) if scores else {}
            all_scores += scores
        n_blind = len(buckets["no_overlap"])
        per["all_overlapping"] = summarise(all_scores[: len(all_scores) - n_blind]) if all_scores else {}
        out["matchers"][name] = per
        print(f"{name:14s} done", file=sys.stderr)
    return out


def table(result: dict) -> str:
    rows = ["| matcher | bucket | success | median t (m) | p95 t (m) | median rot (°) | median s | false |",
            "|---|---|---|---|---|---|---|---|"]
    for name, per in result["matchers"].items():
        for bucket, v in per.items():
            if not v or bucket == "all_overlapping":
                continue
            rows.append(f"| {name} | {bucket} | {100 * v['success_rate']:.0f} % | {v['median_translation_error_m']:.3f} | "
                        f"{v['p95_translation_error_m']:.3f} | {v['median_rotation_error_deg']:.2f} | "
                        f"{v['median_seconds'] * 1000:.0f} ms | {100 * v['false_success_rate']:.0f} % |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 pairs per bucket (CI scale)")
    ap.add_argument("--pairs", type=int, default=12, help="pairs per bucket (no_overlap gets twice as many)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = ap.parse_args(argv)
    result = run(3 if args.quick else args.pairs, args.seed)
    print(table(result))
    for name, why in result["unavailable"].items():
        print(f"unavailable: {name}: {why}")
    if args.json:
        print(json.dumps(result, allow_nan=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
