"""Scoring a matcher's result against a simulated pair's truth (shared by the conformance kit and the
matcher benchmark).

A **success** is a result reported converged whose translation error is at most 0.10 m and whose yaw
error is at most 2°. A **false success** is a result reported converged on a pair with no overlap, or
whose translation error exceeds 0.5 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cistern_archive.pipeline.contracts import MatchResult
from cistern_archive.simulation.pairs import SimulatedPair

SUCCESS_TRANSLATION_M = 0.10
SUCCESS_ROTATION_DEG = 2.0
FALSE_TRANSLATION_M = 0.5


@dataclass(frozen=True)
class PairScore:
    """Errors and verdicts of one result."""

    translation_error_m: float
    rotation_error_deg: float
    converged: bool
    success: bool
    false_success: bool
    seconds: float


def score(result: MatchResult, pair: SimulatedPair) -> PairScore:
    """Compare ``result`` with ``pair``'s truth (errors are ``inf`` for non-finite estimates or no overlap)."""
    finite = all(math.isfinite(v) for v in (result.dx_m, result.dy_m, result.dyaw_rad))
    if pair.overlap > 0 and finite:
        te = math.hypot(result.dx_m - pair.dx_m, result.dy_m - pair.dy_m)
        re = abs(math.degrees((result.dyaw_rad - pair.dyaw_rad + math.pi) % (2 * math.pi) - math.pi))
    else:
        te = re = math.inf
    conv = bool(result.converged)
    success = conv and te <= SUCCESS_TRANSLATION_M and re <= SUCCESS_ROTATION_DEG
    false = conv and (pair.overlap == 0 or te > FALSE_TRANSLATION_M)
    return PairScore(te, re, conv, success, false, float(result.seconds))
