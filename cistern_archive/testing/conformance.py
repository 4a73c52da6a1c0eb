"""The matcher conformance suite: :func:`check_matcher`.

It runs a matcher plugin through the checks the pipeline relies on and prints a report:

1. **contract** — the object satisfies the :class:`~cistern_archive.pipeline.contracts.Matcher`
   Protocol with the registry's signature checks (and those of ``GuidedMatcher`` when it implements
   it), has a ``name``, a pydantic ``Params`` derived from ``StageParams`` whose fields all have
   defaults and which refuses unknown keys;
2. **result type** — ``match`` returns a :class:`~cistern_archive.pipeline.contracts.MatchResult` with
   finite ``seconds``, a bool ``converged``, a reason whenever it did not converge, and finite
   estimates whenever it did;
3. **determinism** — two runs with generators of the same seed give identical results;
4. **accuracy** — on ``n_pairs`` simulated pairs with known truth (overlap ≥ 50 %), the success rate
   reaches ``min_success_rate``;
5. **honesty** — on pairs from two different sites (no overlap) at most ``max_false_success_rate`` are
   reported converged;
6. **speed** — the median time per match is at most ``max_median_seconds``;
7. **guess** (a :class:`~cistern_archive.pipeline.contracts.GuidedMatcher` only) — given a guess near
   the truth (within ±0.2 m, ``±GUESS_RADIUS_M`` window) the overlapping pairs succeed at least as often
   as ``min_success_rate``, and given a guess whose window lies ``GUESS_MISS_M`` from the truth no
   estimate reported converged lies outside that window: a guided matcher searches the window it is
   given (a localizer relies on it to tell a loop closure from a look-alike place).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from typing import Any, TextIO

import numpy as np
from pydantic import BaseModel, ValidationError

from cistern_archive.core.errors import PluginError
from cistern_archive.pipeline.contracts import GuidedMatcher, Matcher, MatchGuess, MatchResult, StageParams
from cistern_archive.pipeline.registry import checked_plugin
from cistern_archive.simulation.pairs import SimulatedPair, simulated_pair
from cistern_archive.testing.scoring import PairScore, score


GUESS_RADIUS_M = 0.5
"""Half side of the window of the guesses the guess check gives."""
GUESS_MISS_M = 1.5
"""How far from the truth the guess check puts the centre of the window that misses it."""
GUESS_TOLERANCE_M = 0.05
"""How far past its window's edge a converged estimate may lie (a refinement's last step)."""


@dataclass(frozen=True)
class Check:
    """One conformance check: its name, whether it passed, and what was found."""

    name: str
    passed: bool
    detail: str


@dataclass
class ConformanceReport:
    """The outcome of :func:`check_matcher`."""

    plugin: str
    checks: list[Check] = field(default_factory=list)
    success_rate: float = math.nan
    false_success_rate: float = math.nan
    median_translation_error_m: float = math.nan
    median_rotation_error_deg: float = math.nan
    median_seconds: float = math.nan

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    def failures(self) -> list[Check]:
        return [c for c in self.checks if not c.passed]

    def format(self) -> str:
        lines = [f"conformance of matcher {self.plugin!r}: {'PASSED' if self.passed else 'FAILED'}"]
        lines += [f"  [{'ok' if c.passed else 'FAIL'}] {c.name}: {c.detail}" for c in self.checks]
        return "\n".join(lines)


def check_matcher(plugin: Any, *, n_pairs: int = 12, seed: int = 0, params: StageParams | None = None,
                  min_success_rate: float = 0.5, max_false_success_rate: float = 0.1,
                  max_median_seconds: float = 2.0, stream: TextIO | None = sys.stdout) -> ConformanceReport:
    """Run the conformance suite on a matcher (class or instance) and print the report to ``stream``.

    Parameters
    ----------
    plugin : object or class
        The matcher; a class is instantiated without arguments, as the registry does.
    n_pairs : int
        Overlapping pairs for the accuracy check (and half as many no-overlap pairs for honesty).
    seed : int
        Seed of the pairs and of the matcher's generators.
    params : StageParams, optional
        Parameters to run with; default ``plugin.Params()``.
    """
    instance = plugin() if isinstance(plugin, type) else plugin
    report = ConformanceReport(plugin=str(getattr(instance, "name", type(instance).__name__)))
    contract, capabilities = _check_contract(instance)
    report.checks.append(contract)
    if not contract.passed:
        return _emit(report, stream)
    p = params if params is not None else instance.Params()
    rng = np.random.default_rng(seed)
    pairs = [simulated_pair(rng, overlap_range=(0.5, 1.0)) for _ in range(n_pairs)]
    blind = [simulated_pair(rng, overlapping=False) for _ in range(max(2, n_pairs // 2))]
    results, errors = _run_all(instance, pairs + blind, p, seed)
    report.checks.append(_check_results(results, errors))
    if errors:
        return _emit(report, stream)
    report.checks.append(_check_determinism(instance, pairs[0], p, seed))
    scores = [score(r, pr) for r, pr in zip(results, pairs + blind)]
    _accuracy(report, scores[: len(pairs)], scores[len(pairs):], min_success_rate, max_false_success_rate)
    report.median_seconds = float(np.median([s.seconds for s in scores]))
    report.checks.append(Check("speed", report.median_seconds <= max_median_seconds,
                               f"median {report.median_seconds * 1000:.1f} ms per match (limit "
                               f"{max_median_seconds * 1000:.0f} ms)"))
    if GuidedMatcher in capabilities:  # the capability as the registry reads it
        report.checks.append(_check_guess(instance, pairs, p, seed, min_success_rate))
    return _emit(report, stream)


def _check_guess(instance: Any, pairs: list[SimulatedPair], p: StageParams, seed: int, min_success: float) -> Check:
    """Check 7 of the module docstring: guesses near the truth succeed, a window that misses the truth
    is searched and no farther."""
    rng = np.random.default_rng([seed, 7])
    near, outside = [], []
    for k, pr in enumerate(pairs):
        shift = rng.uniform(-0.2, 0.2, 2)
        guess = MatchGuess(pr.dx_m + shift[0], pr.dy_m + shift[1], pr.dyaw_rad, GUESS_RADIUS_M)
        result = instance.match(pr.reference, pr.moving, p, rng=np.random.default_rng([seed, k]), guess=guess)
        near.append(score(result, pr).success)
        turn = rng.uniform(0.0, 2.0 * math.pi)
        miss = MatchGuess(pr.dx_m + GUESS_MISS_M * math.cos(turn), pr.dy_m + GUESS_MISS_M * math.sin(turn),
                          pr.dyaw_rad, GUESS_RADIUS_M)
        result = instance.match(pr.reference, pr.moving, p, rng=np.random.default_rng([seed, k]), guess=miss)
        off = max(abs(result.dx_m - miss.dx_m), abs(result.dy_m - miss.dy_m))
        if result.converged and not off <= GUESS_RADIUS_M + GUESS_TOLERANCE_M:
            outside.append(f"pair {k}: ({result.dx_m:.2f}, {result.dy_m:.2f}) m, {off:.2f} m from the window's centre")
    rate = float(np.mean(near))
    passed = rate >= min_success and not outside
    detail = (f"success {100 * rate:.0f} % with a guess within 0.2 m of the truth (need {100 * min_success:.0f} %); "
              f"{len(outside)} of {len(pairs)} converged outside a ±{GUESS_RADIUS_M:g} m window "
              f"{GUESS_MISS_M:g} m from the truth")
    return Check("guess", passed, detail + (f" ({outside[0]})" if outside else ""))


def _emit(report: ConformanceReport, stream: TextIO | None) -> ConformanceReport:
    if stream is not None:
        print(report.format(), file=stream)
    return report


def _check_contract(instance: Any) -> tuple[Check, frozenset[type]]:
    """Check 1 of the module docstring, and the optional capabilities the registry finds."""
    problems = []
    capabilities: frozenset[type] = frozenset()
    if not isinstance(instance, Matcher):
        problems.append("does not implement the Matcher protocol (name, Params, match)")
    else:
        try:
            capabilities = checked_plugin("matcher", instance).capabilities  # as the registry checks at load
        except PluginError as exc:
            problems.append(str(exc))
    params = getattr(instance, "Params", None)
    if not (isinstance(params, type) and issubclass(params, BaseModel)):
        problems.append("Params is not a pydantic model class")
    else:
        if not issubclass(params, StageParams):
            problems.append("Params does not derive from StageParams")
        try:
            params()
        except ValidationError as exc:
            problems.append(f"Params fields need defaults: {exc.errors()[0]['loc']}")
        try:
            params(definitely_not_a_parameter=1)
            problems.append("Params accepts unknown keys (use extra='forbid')")
        except ValidationError:
            pass
    if not isinstance(getattr(instance, "name", None), str) or not instance.name:
        problems.append("name must be a non-empty string")
    return (Check("contract", not problems, "; ".join(problems) or "Protocol, name and Params are in order"),
            capabilities)


def _run_all(instance: Any, pairs: list[SimulatedPair], p: StageParams, seed: int) -> tuple[list[MatchResult], list[str]]:
    results, errors = [], []
    for k, pr in enumerate(pairs):
        try:
            results.append(instance.match(pr.reference, pr.moving, p, rng=np.random.default_rng([seed, k])))
        except Exception as exc:  # a plugin may raise anything; the report names it
            errors.append(f"pair {k}: {type(exc).__name__}: {exc}")
    return results, errors


def _check_results(results: list[Any], errors: list[str]) -> Check:
    if errors:
        return Check("result type", False, f"match raised on {len(errors)} pair(s); first: {errors[0]}")
    problems = []
    for k, r in enumerate(results):
        if not isinstance(r, MatchResult):
            problems.append(f"pair {k}: returned {type(r).__name__}, not MatchResult")
            continue
        if not isinstance(r.converged, (bool, np.bool_)):
            problems.append(f"pair {k}: converged is {type(r.converged).__name__}, not bool")
        if not math.isfinite(r.seconds) or r.seconds < 0:
            problems.append(f"pair {k}: seconds is {r.seconds}")
        if not r.converged and not r.reason:
            problems.append(f"pair {k}: not converged but no reason given")
        if r.converged and not all(math.isfinite(v) for v in (r.dx_m, r.dy_m, r.dyaw_rad)):
            problems.append(f"pair {k}: converged with a non-finite estimate")
    return Check("result type", not problems, "; ".join(problems[:3]) or f"{len(results)} valid MatchResults")


def _check_determinism(instance: Any, pair: SimulatedPair, p: StageParams, seed: int) -> Check:
    a = instance.match(pair.reference, pair.moving, p, rng=np.random.default_rng(seed))
    b = instance.match(pair.reference, pair.moving, p, rng=np.random.default_rng(seed))
    same = np.array_equal([a.dx_m, a.dy_m, a.dyaw_rad, a.converged], [b.dx_m, b.dy_m, b.dyaw_rad, b.converged],
                          equal_nan=True)
    return Check("determinism", bool(same), "equal seeds give equal results" if same else
                 f"equal seeds gave ({a.dx_m:.4f}, {a.dy_m:.4f}) and ({b.dx_m:.4f}, {b.dy_m:.4f})")


def _accuracy(report: ConformanceReport, overlapping: list[PairScore], blind: list[PairScore],
              min_success: float, max_false: float) -> None:
    report.success_rate = float(np.mean([s.success for s in overlapping]))
    conv = [s for s in overlapping if s.converged]
    report.median_translation_error_m = float(np.median([s.translation_error_m for s in conv])) if conv else math.nan
    report.median_rotation_error_deg = float(np.median([s.rotation_error_deg for s in conv])) if conv else math.nan
    report.false_success_rate = float(np.mean([s.false_success for s in blind + overlapping]))
    report.checks.append(Check(
        "accuracy", report.success_rate >= min_success,
        f"success {100 * report.success_rate:.0f} % on {len(overlapping)} pairs with ≥ 50 % overlap (need "
        f"{100 * min_success:.0f} %); median error {report.median_translation_error_m:.3f} m, "
        f"{report.median_rotation_error_deg:.2f}° over converged pairs"))
    false_blind = float(np.mean([s.false_success for s in blind]))
    report.checks.append(Check(
        "honesty", false_blind <= max_false,
        f"{100 * false_blind:.0f} % of {len(blind)} no-overlap pairs reported converged (limit {100 * max_false:.0f} %)"))
