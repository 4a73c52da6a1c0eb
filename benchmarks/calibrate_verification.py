"""Fit the calibrated match verification (``plugins/cistern_plugins/verification.json``).

Draws simulated pairs on a tuning seed — pairs of random rooms and galleries
(:mod:`cistern_archive.simulation.pairs`, with both of its sonar models) and every pair up to three stations apart in random
multi-chamber cisterns (:mod:`cistern_archive.simulation.chambers`), all through the physical sonar
simulator and the pipeline's segmentation — runs the point matchers with every verification limit off
(so each reports the pose its search found), labels each pose against the truth — correct: within
0.10 m and 2°; wrong: more than 0.15 m or 3° off, or the two scans are of different sites; poses in
between are left out; a pose ``icp`` refuses for turning beyond ``max_turn_deg`` is left out too, as
no model is asked about it — and fits a logistic model of ``P(correct)`` on the fit statistics of
:func:`cistern_plugins.verification.features`. The acceptance threshold is the lowest probability at
which at most ``--false-match-rate`` of the wrong poses are accepted. The same is then measured on
pairs of a second seed (``--seed``), with 95 % Wilson intervals, and everything is printed; with
``--write`` the model is written where the matchers read it.

    python benchmarks/calibrate_verification.py --pairs 100 --sites 12 --tune-seed 101 --tune-seed 303 --seed 202 \
        --false-match-rate 0.02 --write --json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from cistern_archive.evaluation import in_compass_frame, wilson_interval
from cistern_archive.pipeline.registry import default_registry
from cistern_archive.pipeline.runner import match_pair, resolve_stage, segment_scan
from cistern_archive.simulation.pairs import PairSpec, SimulatedPair, simulated_pair
from cistern_plugins.alignment import ConvergenceThresholds
from cistern_plugins.icp import turned_too_far
from cistern_plugins.registration import ConvergenceParams, ReferenceModel
from cistern_plugins.verification import CALIBRATION_FILE, FEATURES, Calibration, calibration, features

MATCHERS = ("correlative", "icp")
OPEN_LIMITS = {"calibrated": False, "min_inliers": 3, "min_inlier_ratio": 0.0, "min_constraint": 0.0,
               "max_weak_std_m": 1e6, "max_violation_ratio": 1.0}
"""Every limit off: the matchers report the pose their search found."""


def draw_pairs(n: int, seed: int, segmentation: str | None) -> list[SimulatedPair]:
    """``n`` overlapping pairs (overlap 0.2–0.95, offsets up to 3 m) and ``n // 2`` pairs of two sites,
    for each sonar model: the physical simulator (with ``segmentation``) and ideal rays with range
    noise, multipath outliers and drop-outs (scans from other sonars, already segmented)."""
    rng = np.random.default_rng(seed)
    pairs: list[SimulatedPair] = []
    for sonar in ("simulator", "rays"):
        spec = PairSpec(sonar=sonar, segmentation=segmentation, max_offset_m=3.0)
        pairs += [simulated_pair(rng, spec=spec, overlap_range=(0.2, 0.95)) for _ in range(n)]
        pairs += [simulated_pair(rng, spec=spec, overlapping=False) for _ in range(n // 2)]
    return pairs


def site_pairs(n_sites: int, seed: int, max_gap: int = 3) -> list[SimulatedPair]:
    """Every ordered pair up to ``max_gap`` stations apart in ``n_sites`` random multi-chamber cisterns
    (:mod:`cistern_archive.simulation.chambers`): scans that look through tunnels and openings into the
    next chamber, as the pipeline meets them, segmented as the records' default does."""
    from cistern_archive.simulation.simulator import simulate_site
    from cistern_archive.simulation.chambers import random_cisterns

    out = []
    for cistern in random_cisterns(n_sites, seed):
        site = simulate_site(cistern.spec)
        scans = [segment_scan(s.scan, cistern.spec.segmentation) for s in site.scans]
        poses = [s.pose for s in site.scans]
        for i in range(len(scans)):
            for j in range(len(scans)):
                if i == j or abs(i - j) > max_gap:
                    continue
                err_i = scans[i].yaw_rad - poses[i].yaw_rad
                d = in_compass_frame(np.array([poses[j].x_m - poses[i].x_m, poses[j].y_m - poses[i].y_m]), err_i)
                dyaw = -((scans[j].yaw_rad - poses[j].yaw_rad) - err_i)
                out.append(SimulatedPair(scans[i], scans[j], float(d[0]), float(d[1]), float(dyaw), 1.0, 0.0))
    return out


def labelled_fits(pairs: list[SimulatedPair], matcher_names=MATCHERS) -> tuple[np.ndarray, np.ndarray]:
    """Features and labels (1 correct, 0 wrong) of the pose every matcher found on every pair."""
    registry = default_registry()
    models = [ReferenceModel(pair.reference) for pair in pairs]
    rows, labels = [], []
    for name in matcher_names:
        matcher = resolve_stage(registry, "matcher", name, OPEN_LIMITS)
        limits = matcher.params.limits()
        max_turn_deg = getattr(matcher.params, "max_turn_deg", 180.0)
        for k, pair in enumerate(pairs):
            result = match_pair(matcher, [pair.reference, pair.moving], k, 0, 1)
            if not np.isfinite([result.dx_m, result.dy_m, result.dyaw_rad]).all():
                continue
            if turned_too_far(result.dyaw_rad, max_turn_deg):
                continue  # refused before any verdict (icp's turn limit): no model is asked about it
            pose = np.array([result.dx_m, result.dy_m, result.dyaw_rad])
            err = math.hypot(pose[0] - pair.dx_m, pose[1] - pair.dy_m)
            err_deg = abs(math.degrees((pose[2] - pair.dyaw_rad + math.pi) % (2 * math.pi) - math.pi))
            if pair.overlap > 0 and err <= 0.10 and err_deg <= 2.0:
                label = 1
            elif pair.overlap == 0 or err > 0.15 or err_deg > 3.0:
                label = 0
            else:
                continue
            quality = models[k].assess_pair(pair.moving, pose, limits)
            rows.append(features(quality, limits))
            labels.append(label)
    return np.array(rows), np.array(labels)


def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1.0, iterations: int = 50) -> tuple[np.ndarray, float]:
    """Maximum-likelihood logistic regression with a small L2 penalty (Newton / IRLS) on standardised
    features; returns weights and bias in the original units."""
    mu, sd = x.mean(axis=0), x.std(axis=0) + 1e-9
    z = np.column_stack([np.ones(len(x)), (x - mu) / sd])
    beta = np.zeros(z.shape[1])
    penalty = l2 * np.eye(z.shape[1])
    penalty[0, 0] = 0.0
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(z @ beta, -50, 50)))
        grad = z.T @ (y - p) - penalty @ beta
        hess = (z * (p * (1 - p))[:, None]).T @ z + penalty
        step = np.linalg.solve(hess, grad)
        beta += step
        if np.abs(step).max() < 1e-8:
            break
    weights = beta[1:] / sd
    return weights, float(beta[0] - weights @ mu)


def threshold_for(probabilities: np.ndarray, labels: np.ndarray, false_match_rate: float) -> float:
    """The lowest threshold at which at most ``false_match_rate`` of the wrong poses are accepted."""
    wrong = np.sort(probabilities[labels == 0])[::-1]
    allowed = int(math.floor(false_match_rate * len(wrong)))
    return float(np.nextafter(wrong[allowed], 1.0)) if allowed < len(wrong) else 0.0


def rates(model: Calibration, x: np.ndarray, y: np.ndarray, passes: np.ndarray | None = None) -> dict:
    """Right and wrong fits the model accepts (and, with ``passes``, that also pass those tests)."""
    p = np.array([model.probability(f) for f in x])
    accepted = p >= model.threshold
    if passes is not None:
        accepted &= passes
    tp, pos = int((accepted & (y == 1)).sum()), int((y == 1).sum())
    fp, neg = int((accepted & (y == 0)).sum()), int((y == 0).sum())
    return {"correct_accepted": tp, "correct": pos, "accept_rate": tp / pos if pos else None,
            "accept_rate_ci95": wilson_interval(tp, pos), "wrong_accepted": fp, "wrong": neg,
            "false_match_rate": fp / neg if neg else None, "false_match_rate_ci95": wilson_interval(fp, neg)}


def hard_limit_rates(model: Calibration, x: np.ndarray, y: np.ndarray, max_weak_std_m: float,
                     limits: ConvergenceThresholds) -> dict:
    """The rates of :func:`rates` once the hard limits a matcher applies besides the model are applied
    too (``min_inliers``, ``min_constraint``) with ``max_weak_std_m`` as the weak-direction limit."""
    d = limits.inlier_distance_m
    column = {name: k for k, name in enumerate(FEATURES)}
    weak = d * 10.0 ** x[:, column["log_weak_std"]]
    inliers = 10.0 ** x[:, column["log_inliers"]]
    constraint = x[:, column["constraint"]]
    hard = (weak <= max_weak_std_m) & (inliers >= limits.min_inliers - 0.5) & (constraint >= limits.min_constraint)
    return rates(model, x, y, hard)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=100, help="overlapping pairs per seed (and half as many without)")
    ap.add_argument("--sites", type=int, default=12, help="random multi-chamber cisterns per seed")
    ap.add_argument("--tune-seed", type=int, action="append", default=[],
                    help="seed of the pairs the model is fitted on (repeatable; default 101)")
    ap.add_argument("--seed", type=int, default=202, help="the seed the rates are reported on")
    ap.add_argument("--false-match-rate", type=float, default=0.02)
    ap.add_argument("--segmentation", default=None, help="segmentation method (default: the records' default)")
    ap.add_argument("--write", action="store_true", help=f"write the model to {CALIBRATION_FILE.name}")
    ap.add_argument("--weak-std-limit", type=float, action="append", default=[],
                    help="also report the rates with this weak-direction limit (m) and the other hard limits "
                         "of the matchers' defaults (repeatable)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    tune_seeds = args.tune_seed or [101]
    if args.seed in tune_seeds:
        ap.error("--seed must differ from every --tune-seed")
    x_tune, y_tune = labelled_fits([pair for seed in tune_seeds for pair in
                                    draw_pairs(args.pairs, seed, args.segmentation) + site_pairs(args.sites, seed)])
    weights, bias = fit_logistic(x_tune, y_tune)
    probe = Calibration(tuple(weights), bias, 0.5, args.false_match_rate, {})
    p_tune = np.array([probe.probability(f) for f in x_tune])
    threshold = threshold_for(p_tune, y_tune, args.false_match_rate)
    command = (f"python benchmarks/calibrate_verification.py --pairs {args.pairs} --sites {args.sites} "
               + "".join(f"--tune-seed {seed} " for seed in tune_seeds)
               + f"--seed {args.seed} --false-match-rate {args.false_match_rate}"
               + (f" --segmentation {args.segmentation}" if args.segmentation else "") + " --write")
    model = Calibration(tuple(float(w) for w in weights), bias, threshold, args.false_match_rate,
                        {"command": command, "tune_seeds": tune_seeds, "matchers": list(MATCHERS),
                         "segmentation": args.segmentation or "records' default",
                         "tune_correct": int((y_tune == 1).sum()), "tune_wrong": int((y_tune == 0).sum())})
    x_test, y_test = labelled_fits(draw_pairs(args.pairs, args.seed, args.segmentation) + site_pairs(args.sites, args.seed))
    out = {"model": model.to_json(), "tune": rates(model, x_tune, y_tune), "test": rates(model, x_test, y_test),
           "seconds": round(time.perf_counter() - t0, 1)}
    in_use = calibration()
    out["tune, model in use"] = rates(in_use, x_tune, y_tune)
    out["test, model in use"] = rates(in_use, x_test, y_test)
    defaults = ConvergenceParams().limits()
    for limit in args.weak_std_limit:
        for name, (x, y) in (("tune", (x_tune, y_tune)), ("test", (x_test, y_test))):
            out[f"{name} weak std <= {limit:g} m"] = hard_limit_rates(model, x, y, limit, defaults)
            out[f"{name}, model in use, weak std <= {limit:g} m"] = hard_limit_rates(in_use, x, y, limit, defaults)
    for name in [key for key in out if key.startswith(("tune", "test"))]:
        r = out[name]
        lo, hi = r["false_match_rate_ci95"]
        alo, ahi = r["accept_rate_ci95"]
        print(f"{name}: correct accepted {r['correct_accepted']}/{r['correct']} "
              f"({100 * r['accept_rate']:.1f} %, 95 % CI {100 * alo:.1f}–{100 * ahi:.1f}); wrong accepted "
              f"{r['wrong_accepted']}/{r['wrong']} ({100 * r['false_match_rate']:.2f} %, CI {100 * lo:.2f}–{100 * hi:.2f})")
    print("weights", dict(zip(FEATURES, np.round(weights, 3))), "bias", round(bias, 3), "threshold", round(threshold, 3))
    if args.write:
        CALIBRATION_FILE.write_text(json.dumps(model.to_json(), indent=2, sort_keys=True) + "\n", encoding="utf-8")
        print(f"wrote {CALIBRATION_FILE}")
    if args.json:
        print(json.dumps(out, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
