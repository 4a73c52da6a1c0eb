"""How the two physical tests of the verification separate right placements from wrong ones.

The tests (:mod:`cistern_plugins.alignment`): a wall seen from its two sides is not one wall
(:func:`~cistern_plugins.alignment.seen_from_behind`, applied from ``BEHIND_SHARE`` of the inliers),
and no stretch of wall longer than ``max_violation_run_m`` may lie in the water another sonar saw
(:func:`~cistern_plugins.alignment.longest_run_m`). On random multi-chamber cisterns (the generator of
``benchmarks/sites.py --random``), each built by the runner with the default pipeline, this reports:

* ``truth_pairs``: every pair of one depth level within sonar range, assessed at its true relative pose
  (:meth:`~cistern_plugins.alignment.ReferenceModel.assess_pair`): the longest stretch, and how many
  pairs have points seen from behind, a quarter or more of them, and so with 25 points or more;
* ``matches``: every converged or tentative match, right (within 0.10 m) or wrong (more than 0.5 m
  off), with the stretch at its estimate;
* ``joins``: every join ``site-graph``'s wall check judged, at the poses it judged it, right (every pair
  within 0.3 m of the truth) or wrong (a pair more than 1 m off), with its longest stretch, how many of
  its pairs lay a stretch over the limit (and the second longest), its back-to-back count
  (:func:`back_to_back`), and how many pairs apart lay a stretch over ``CORROBORATED_RUN_M``
  (:func:`~cistern_plugins.site_groups.corroborated_runs`), and the second longest stretch among pairs that
  share no scan (what :data:`~cistern_plugins.site_groups.CORROBORATED_RUN_M` is set against), and the
  median two-way share of its pairs that share walls (:func:`two_way`, what
  :data:`~cistern_plugins.site_groups.TWO_WAY_SHARE` is set against). The wall check is observed, not
  changed: each call is recorded and passed on;
* ``settled``: every split of a group that the final check judged (five or more pairs sharing walls;
  :func:`~cistern_plugins.settled_groups.settled_splits`), right (every pair of the two parts within 0.3 m
  of the truth) or wrong (every pair more than 1 m off), with its median two-way share: what
  :data:`~cistern_plugins.settled_groups.SETTLED_TWO_WAY_SHARE` is set against.

Usage::

    .venv/bin/python benchmarks/wall_tests.py [--random 24] [--seeds 2,4] [--workers 2] [--json]

The numbers in ``benchmarks/RESULTS.md`` ("2026-12-02 (later)") come from the defaults.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from itertools import permutations
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import cistern_plugins.settled_groups as settled_groups  # noqa: E402
import cistern_plugins.site_groups as site_groups  # noqa: E402
from cistern_archive.catalog.loader import load_record  # noqa: E402
from cistern_archive.pipeline.runner import build_site  # noqa: E402
from cistern_archive.simulation.chambers import random_cisterns, simulate_into, write_specs  # noqa: E402
from cistern_plugins.alignment import ConvergenceThresholds, ReferenceModel  # noqa: E402
from sites import OK_PAIR_M, SiteTruth  # noqa: E402

WRONG_MATCH_M = 0.5
RIGHT_JOIN_M = 0.3
WRONG_JOIN_M = 1.0


class SplitRecorder:
    """Records every split of a group that ``site-graph``'s final check judges
    (:func:`~cistern_plugins.settled_groups.settled_splits`) and passes them on unchanged."""

    def __init__(self) -> None:
        self.splits: list[settled_groups.Split] = []
        original = settled_groups.settled_splits
        recorder = self

        def settled_splits(walls, graph, known):
            splits = original(walls, graph, known)
            recorder.splits += splits
            return splits

        settled_groups.settled_splits = settled_splits


class JoinRecorder:
    """Records the pairs of every join ``WallCheck`` judges (:meth:`~cistern_plugins.site_groups.WallCheck.assess_join`:
    their qualities and relative poses, with the join's lone scan, :func:`~cistern_plugins.site_groups.lone_scan`)
    and passes them on unchanged."""

    def __init__(self) -> None:
        self.calls: list[tuple[list[site_groups.JoinPair], int | None]] = []
        original = site_groups.WallCheck.assess_join
        recorder = self

        def assess_join(check, graph, i, j, z):
            pairs = original(check, graph, i, j, z)
            recorder.calls.append((pairs, site_groups.lone_scan(graph, i, j)))
            return pairs

        site_groups.WallCheck.assess_join = assess_join


def back_to_back(pairs: list[site_groups.JoinPair]) -> tuple[int, int]:
    """The most wall points one scan of a join lays on walls another saw from the other side, among the
    pairs that lay more so than from the same side (0 when none), and how many pairs of the join the wall
    check counts as laid back to back (:func:`~cistern_plugins.site_groups.laid_back_to_back`)."""
    limits = ConvergenceThresholds()
    backs = [p.quality.behind for p in pairs if p.quality.behind > p.quality.inliers]
    return max(backs, default=0), sum(site_groups.laid_back_to_back(p.quality, limits) for p in pairs)


def two_way(pairs: list[site_groups.JoinPair], limits: ConvergenceThresholds) -> tuple[int, float]:
    """How many pairs of a join share ``min_inliers`` wall points, and their median two-way share
    (:func:`~cistern_plugins.site_groups.two_way_share`): what :data:`~cistern_plugins.site_groups.TWO_WAY_SHARE`
    is set against."""
    sharing = site_groups.sharing_pairs(pairs, limits)
    return len(sharing), site_groups.two_way_share(sharing)


def split_errors(split, truth: SiteTruth) -> tuple[float, float]:
    """The least and the largest error (m, against the truth) of the relative positions of the scans the
    split parts, as the graph placed them."""
    errors = [truth.displacement_error(p.a, p.b, p.rel.x(), p.rel.y()) for p in split.sharing]
    return min(errors), max(errors)


def truth_pairs(scans, truth: SiteTruth) -> list[tuple[float, int, int]]:
    """(longest stretch, inliers, points seen from behind) of every pair at its true pose."""
    limits = ConvergenceThresholds()
    models = [ReferenceModel(s) for s in scans]
    out = []
    for a, b in permutations(range(len(scans)), 2):
        if truth.cross_level(a, b) or np.hypot(*(truth.xy[b] - truth.xy[a])) > min(scans[a].max_range_m, scans[b].max_range_m):
            continue
        q = models[a].assess_pair(scans[b], truth.true_pose(a, b), limits)
        out.append((q.violation_run_m, q.inliers, q.behind))
    return out


def one_site(job: tuple[int, int]) -> dict:
    """Simulate, build and measure site ``k`` of seed ``seed``."""
    seed, k = job
    recorder, split_recorder = JoinRecorder(), SplitRecorder()
    cistern = random_cisterns(k + 1, seed)[k]
    with tempfile.TemporaryDirectory(prefix="wall-tests-") as tmp:
        root = Path(tmp)
        loaded = load_record(simulate_into(write_specs([cistern], root)[0], root), root)
        build = build_site(loaded)
        scans = build.range_scans
        truth = SiteTruth(loaded.record, scans, root)
        limits = ConvergenceThresholds()
        models: dict[int, ReferenceModel] = {}
        matches = []
        for m in build.matches:
            if not (m.converged or m.tentative) or not math.isfinite(m.dx_m):
                continue
            model = models.setdefault(m.i, ReferenceModel(scans[m.i]))
            q = model.assess_pair(scans[m.j], np.array([m.dx_m, m.dy_m, m.dyaw_rad]), limits)
            matches.append((truth.pair_error(m), q.violation_run_m))
        joins = []
        for pairs, lone in recorder.calls:
            if pairs:
                errors = [truth.displacement_error(p.a, p.b, p.rel.x(), p.rel.y()) for p in pairs]
                runs = sorted((p.quality.violation_run_m for p in pairs), reverse=True)
                over = sum(r > limits.max_violation_run_m for r in runs)
                disjoint = [run for run, _, _ in site_groups.corroborated_runs(pairs, 0.0, lone)]  # longest first
                corroborated = sum(run > site_groups.CORROBORATED_RUN_M for run in disjoint)
                joins.append((max(errors), runs[0], *back_to_back(pairs), over, runs[1] if len(runs) > 1 else 0.0,
                              corroborated, disjoint[1] if len(disjoint) > 1 else 0.0, *two_way(pairs, limits)))
        splits = [(*split_errors(split, truth), split.share, len(split.sharing), split.conflicts)
                  for split in split_recorder.splits]
        return {"truth": truth_pairs(scans, truth), "matches": matches, "joins": joins, "splits": splits}


def summary(rows: list[dict]) -> dict:
    truth = np.array([t for r in rows for t in r["truth"]], dtype=float).reshape(-1, 3)
    matches = np.array([m for r in rows for m in r["matches"]], dtype=float).reshape(-1, 2)
    joins = np.array([j for r in rows for j in r["joins"]], dtype=float).reshape(-1, 10)
    splits = np.array([s for r in rows for s in r["splits"]], dtype=float).reshape(-1, 5)
    right_splits, wrong_splits = splits[splits[:, 1] <= RIGHT_JOIN_M], splits[splits[:, 0] > WRONG_JOIN_M]
    limit = ConvergenceThresholds().max_violation_run_m
    share = truth[:, 2] / np.maximum(truth[:, 1] + truth[:, 2], 1)
    right, wrong = matches[matches[:, 0] <= OK_PAIR_M], matches[matches[:, 0] > WRONG_MATCH_M]
    right_joins, wrong_joins = joins[joins[:, 0] <= RIGHT_JOIN_M], joins[joins[:, 0] > WRONG_JOIN_M]

    def top(values: np.ndarray) -> float | None:
        return round(float(values.max()), 3) if len(values) else None

    return {
        "truth_pairs": {"n": len(truth), "max_run_m": top(truth[:, 0]),
                        "q999_run_m": round(float(np.quantile(truth[:, 0], 0.999)), 3) if len(truth) else None,
                        "over_limit": int((truth[:, 0] > limit).sum()), "with_points_behind": int((truth[:, 2] > 0).sum()),
                        "behind_quarter": int((share >= 0.25).sum()),
                        "behind_quarter_25_points": int(((share >= 0.25) & (truth[:, 1] + truth[:, 2] >= 25)).sum())},
        "matches": {"right": len(right), "right_max_run_m": top(right[:, 1]), "wrong": len(wrong),
                    "wrong_median_run_m": round(float(np.median(wrong[:, 1])), 3) if len(wrong) else None,
                    "wrong_over_limit": int((wrong[:, 1] > limit).sum()), "wrong_max_run_m": top(wrong[:, 1])},
        "joins": {"right": len(right_joins), "right_max_run_m": top(right_joins[:, 1]), "wrong": len(wrong_joins),
                  "wrong_runs_m": sorted(round(float(v), 2) for v in wrong_joins[:, 1]),
                  "right_back_to_back": sorted((int(v), int(n)) for v, n in right_joins[:, 2:4] if v >= 10),
                  "wrong_back_to_back": sorted((int(v), int(n)) for v, n in wrong_joins[:, 2:4]),
                  "right_over_limit": sorted((int(n), round(float(second), 2)) for n, second in right_joins[:, 4:6] if n >= 1),
                  "wrong_over_limit": sorted((int(n), round(float(second), 2)) for n, second in wrong_joins[:, 4:6]),
                  "right_corroborated": sorted(int(n) for n in right_joins[:, 6] if n >= 1),
                  "wrong_corroborated": sorted(int(n) for n in wrong_joins[:, 6]),
                  "right_second_disjoint_max_m": top(right_joins[:, 7]),
                  "right_second_disjoint_q99_m": round(float(np.quantile(right_joins[:, 7], 0.99)), 3) if len(right_joins) else None,
                  "wrong_second_disjoint_m": sorted(round(float(v), 2) for v in wrong_joins[:, 7]),
                  "right_two_way_max": top(right_joins[right_joins[:, 8] >= site_groups.TWO_WAY_PAIRS, 9]),
                  "right_two_way_few_pairs_max": top(right_joins[(right_joins[:, 8] > 0)
                                                                 & (right_joins[:, 8] < site_groups.TWO_WAY_PAIRS), 9]),
                  "wrong_two_way": sorted((int(n), round(float(v), 4)) for n, v in wrong_joins[:, 8:10])},
        "settled": {"right": len(right_splits), "right_max_share": top(right_splits[:, 2]),
                    "right_q999_share": round(float(np.quantile(right_splits[:, 2], 0.999)), 4) if len(right_splits) else None,
                    "right_over_limit": int((right_splits[:, 2] > settled_groups.SETTLED_TWO_WAY_SHARE).sum()),
                    "wrong": len(wrong_splits),
                    "wrong_shares": sorted((int(n), round(float(v), 4)) for v, n in wrong_splits[:, 2:4])},
        "limit_m": limit,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--random", type=int, default=24, help="sites per seed")
    parser.add_argument("--seeds", default="2,4", help="comma-separated seeds of the site generator")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON on the last line")
    args = parser.parse_args(argv)
    jobs = [(int(s), k) for s in args.seeds.split(",") for k in range(args.random)]
    if args.workers > 1:
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            rows = list(pool.map(one_site, jobs))
    else:
        rows = [one_site(job) for job in jobs]
    figures = summary(rows)
    for key, value in figures.items():
        print(f"{key}: {value}")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
