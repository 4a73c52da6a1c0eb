"""Calibrated verification of a scan match: the probability that a fit is right, and the verdict.

The point matchers (``correlative``, ``icp``, ``particle-icp``) find a pose and then ask whether to
vouch for it. Fixed limits on single statistics (an inlier share of 0.5, 9 % of wall points in the
other scan's free space, a constraint eigenvalue) refuse correct matches of real echoes — scans that
look through an opening into the next chamber, reverberation rings, walls at grazing incidence — while
still letting some wrong ones through. Instead, a logistic model combines the statistics of the fit
(:class:`~cistern_plugins.alignment.AlignmentQuality`, both ways) into

    ``P(correct | fit) = 1 / (1 + exp(-(b + w · f)))``

with the features ``f`` of :func:`features`. Its weights and its acceptance threshold are fitted by
``benchmarks/calibrate_verification.py`` on simulated pairs of tuning seeds (correct: within 0.10 m and
2° of the truth; wrong: more than 0.15 m or 3° off, or scans of different sites; a pose ``icp`` refuses
for turning far from the compasses is no question for the model and is left out) and written to
``verification.json`` beside this module, with the seeds, the sample sizes and the false-match rate the
threshold was chosen for; the script reports the rates on another seed. The probability is reported as
the match's ``confidence`` and a fit whose confidence is below the threshold is refused with it as the
reason. Three limits stay hard: ``min_inliers`` (no model vouches for a handful of points), and the
two corridor tests — ``min_constraint``, the smaller eigenvalue of the wall-normal information per
inlier (0.03: with normals from ten neighbours, those of a straight corridor's noisy echoes alone reach
about 0.015–0.025), and
``max_weak_std_m``, the predicted standard deviation of the translation along its weakest direction
(a corridor seen without its ends slides along its axis however well its walls fit; at 0.03 m a
0.10 m error is more than three standard deviations away; 0.025 m refused right matches along the
demo gallery's reaches at the same false-match rate, benchmarks/RESULTS.md).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from cistern_plugins.alignment import AlignmentQuality, ConvergenceThresholds, hard_limits, verdict

CALIBRATION_FILE = Path(__file__).with_name("verification.json")
FEATURES = ("inlier_ratio", "violation_ratio", "violation_min", "log_weak_std", "rms_ratio", "log_inliers",
            "constraint")


def features(quality: AlignmentQuality, limits: ConvergenceThresholds) -> np.ndarray:
    """The model's inputs (:data:`FEATURES`): inlier share among the points the other sonar could see,
    the larger and the smaller of the two free-space violation shares (a sonar blind to a wall inside its
    blanking range violates one way only; two scans of different places violate both ways), log10 of
    the predicted weakest-direction std over the inlier distance, inlier RMS over the inlier distance,
    log10 of the inlier count (:attr:`~cistern_plugins.alignment.AlignmentQuality.equivalent_inliers`) and the
    constraint eigenvalue. Non-finite values are clipped to the range
    the model was fitted on."""
    d = limits.inlier_distance_m
    weak = quality.weak_std_m if math.isfinite(quality.weak_std_m) else 10.0 * d
    rms = quality.line_rms_m if math.isfinite(quality.line_rms_m) else d
    return np.array([
        quality.inlier_ratio,
        quality.violation_ratio,
        quality.violation_min,
        math.log10(min(max(weak / d, 1e-3), 10.0)),
        min(rms / d, 1.0),
        math.log10(max(quality.equivalent_inliers, 1)),
        min(quality.constraint, 0.5),
    ])


@dataclass(frozen=True)
class Calibration:
    """A fitted verification model (``verification.json``)."""

    weights: tuple[float, ...]
    bias: float
    threshold: float
    false_match_rate: float
    provenance: dict

    def probability(self, f: np.ndarray) -> float:
        z = self.bias + float(np.dot(self.weights, f))
        return float(1.0 / (1.0 + math.exp(-max(min(z, 50.0), -50.0))))

    def to_json(self) -> dict:
        return {"features": list(FEATURES), "weights": list(self.weights), "bias": self.bias,
                "threshold": self.threshold, "false_match_rate": self.false_match_rate,
                "provenance": self.provenance}


@lru_cache(maxsize=1)
def calibration() -> Calibration:
    """The model in ``verification.json``.

    Raises
    ------
    RuntimeError
        The file is missing or does not describe :data:`FEATURES` (re-run the calibration script).
    """
    try:
        data = json.loads(CALIBRATION_FILE.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RuntimeError(f"{CALIBRATION_FILE}: cannot read the verification model: {exc}") from exc
    if data.get("features") != list(FEATURES):
        raise RuntimeError(f"{CALIBRATION_FILE}: features {data.get('features')} are not {list(FEATURES)}; "
                           "re-run benchmarks/calibrate_verification.py")
    return Calibration(tuple(float(w) for w in data["weights"]), float(data["bias"]), float(data["threshold"]),
                       float(data["false_match_rate"]), dict(data.get("provenance", {})))


def match_confidence(quality: AlignmentQuality, limits: ConvergenceThresholds) -> float | None:
    """The calibrated probability that the fit is right, or ``None`` for the fixed limits."""
    if not limits.calibrated:
        return None
    return calibration().probability(features(quality, limits))


def judge(quality: AlignmentQuality, limits: ConvergenceThresholds) -> str:
    """Empty string when the fit is vouched for, else the reason it is not: the calibrated model when
    ``limits.calibrated``, else the fixed limits of :func:`~cistern_plugins.alignment.verdict`."""
    if not limits.calibrated:
        return verdict(quality, limits)
    why = hard_limits(quality, limits, ratio=False)
    if why:
        return why
    model = calibration()
    p = model.probability(features(quality, limits))
    if p < model.threshold:
        return (f"calibrated confidence {p:.2f} below {model.threshold:.2f} (inlier share {quality.inlier_ratio:.2f}, "
                f"{100 * quality.violation_ratio:.0f} % of wall points in the other scan's free space, "
                f"σ ≈ {quality.weak_std_m:.3f} m along the weakest direction)")
    return ""


TENTATIVE_CONFIDENCE = 0.3
"""Below the acceptance threshold but at least this confident, a fit is tentative (:func:`tentative_fit`)."""


def tentative_fit(quality: AlignmentQuality, limits: ConvergenceThresholds) -> bool:
    """Whether a refused fit is still worth offering as a *tentative* estimate (``MatchResult.tentative``):
    it has enough inliers, passes the corridor tests relaxed by a factor of two (half ``min_constraint``,
    twice ``max_weak_std_m``: good across a gallery, weak along it) and its calibrated confidence,
    though below the threshold, is at least :data:`TENTATIVE_CONFIDENCE`. A localizer uses it only where
    a consistent cycle of other matches corroborates it."""
    if not limits.calibrated or not judge(quality, limits):
        return False
    relaxed = replace(limits, min_constraint=limits.min_constraint / 2, max_weak_std_m=2 * limits.max_weak_std_m)
    why = judge(quality, relaxed)
    if not why:
        return True
    return why.startswith("calibrated confidence") and \
        calibration().probability(features(quality, limits)) >= TENTATIVE_CONFIDENCE
