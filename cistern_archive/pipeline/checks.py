"""The runner's checks of a matcher's output: usable numbers or a failed pair naming what was wrong."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from cistern_archive.pipeline.contracts import MatchGuess, MatchResult


def checked_match(result: MatchResult) -> MatchResult:
    """``result`` when every number in it is usable, else the same pair turned into a failure.

    A converged estimate must have a finite displacement, heading correction and weight, and its
    covariance (when given) must be a finite, symmetric, positive-definite 3 × 3 matrix; a confidence
    must lie in [0, 1]. A matcher that breaks this fails only its pair, with a reason naming what was
    wrong; a non-converged pair keeps its reason, and non-finite numbers never reach ``result.json``
    (:func:`assemble_result` writes them as ``null``). Alternatives with a non-finite pose or a radius
    that is not positive are dropped.
    """
    alternatives = tuple(a for a in result.alternatives if _usable_guess(a))
    if alternatives != result.alternatives:
        result = replace(result, alternatives=alternatives)
    problem = _match_problem(result)
    weight = float(result.weight) if math.isfinite(result.weight) else 0.0
    if not problem:
        tentative = result.tentative and not result.converged
        return result if (weight, tentative) == (result.weight, result.tentative) else \
            replace(result, weight=weight, tentative=tentative)
    reason = result.reason if not result.converged and result.reason else f"unusable matcher output: {problem}"
    return replace(result, converged=False, reason=reason, weight=weight, covariance=None, confidence=None,
                   tentative=False)


def _finite(value: object) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def _usable_guess(guess: MatchGuess) -> bool:
    return all(_finite(v) for v in (guess.dx_m, guess.dy_m, guess.dyaw_rad, guess.radius_m)) and guess.radius_m > 0


def _match_problem(result: MatchResult) -> str:
    values = {"dx_m": result.dx_m, "dy_m": result.dy_m, "dyaw_rad": result.dyaw_rad, "weight": result.weight}
    bad = [name for name, value in values.items() if not _finite(value)]
    if bad:
        return "non-finite " + ", ".join(bad)
    if result.confidence is not None and not 0.0 <= result.confidence <= 1.0:
        return f"confidence {result.confidence!r} outside [0, 1]"
    cov = result.covariance
    if cov is None:
        return ""
    cov = np.asarray(cov, dtype=np.float64)
    if cov.shape != (3, 3):
        return f"covariance of shape {cov.shape}, expected (3, 3)"
    if not np.isfinite(cov).all():
        return "covariance with non-finite entries"
    if not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-12):
        return "covariance not symmetric"
    if np.linalg.eigvalsh(0.5 * (cov + cov.T))[0] <= 0:
        return "covariance not positive definite"
    return ""


def checked_scale(scale: Any, n_scans: int) -> np.ndarray | None:
    """A mapper's echo scale as an array of ``n_scans`` finite shares in (0, 2], or ``None``; anything else
    is refused with what is wrong (the runner reports it as the map stage's failure)."""
    if scale is None:
        return None
    values = np.asarray(scale, dtype=float)
    if values.shape != (n_scans,):
        raise ValueError(f"echo scale has shape {values.shape}, expected one value per scan ({n_scans})")
    if not np.all(np.isfinite(values) & (values > 0) & (values <= 2)):
        raise ValueError(f"echo scale must be finite and within (0, 2], got {values.min()}…{values.max()}")
    return values
