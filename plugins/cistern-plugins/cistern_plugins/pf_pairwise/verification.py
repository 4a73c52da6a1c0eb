"""Whether a converged estimate can be trusted: unique in ``m_i`` (``verify``) and a fit of the echoes.

Eqs. 5–6 alone accept a filter that collapsed onto one of several equally good places (a straight
gallery, a symmetric room, a true offset outside the search square). :func:`verify_unique` rejects an
estimate on the edge of the searched square, one whose beams pass through walls of ``m_i``
(:func:`crossing_fraction`), and one with a rival position nearly as good on a coarse score grid
(:func:`grid_scores`). :func:`fit_check` then applies the point matchers' shared verdict to the
(refined) estimate.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from cistern_plugins.pf_pairwise.likelihood import Beams, LikelihoodMap
from cistern_plugins.pf_pairwise.pair import ScanPair
from cistern_plugins.pf_pairwise.params import PFParams
from cistern_plugins.pf_pairwise.particle_filter import Outcome
from cistern_plugins.pf_pairwise.window import SearchWindow
from cistern_plugins.registration import verdict


def verify(outcome: Outcome, model: LikelihoodMap, beams: Beams, p: PFParams, window: SearchWindow) -> Outcome:
    """A converged outcome rejected with the reason of :func:`verify_unique` (when ``verify.unique``)."""
    if not (outcome.converged and p.verify.unique):
        return outcome
    return outcome.rejected(verify_unique(model, beams, outcome.estimate, p, window))


def check_fit(outcome: Outcome, pair: ScanPair, p: PFParams) -> Outcome:
    """A converged outcome rejected with the reason of :func:`fit_check`."""
    if not outcome.converged:
        return outcome
    return outcome.rejected(fit_check(pair, outcome.estimate, p))


def grid_scores(model: LikelihoodMap, beams: Beams, theta: float, p: PFParams, window: SearchWindow,
                extra: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions of the search square on a ``verify.step_m`` grid (plus ``extra``, last) and their
    mean per-beam scores in the likelihood field smoothed to that step, the heading fixed at ``theta``."""
    beams = beams.subsample(p.verify.beams)
    axis = np.arange(-window.half_m, window.half_m + 1e-9, p.verify.step_m)
    gx, gy = np.meshgrid(axis + window.x_m, axis + window.y_m)
    cand = np.column_stack([gx.ravel(), gy.ravel()])
    if extra is not None:
        cand = np.vstack([cand, np.array(extra)[None, :]])
    c, s = math.cos(theta), math.sin(theta)
    ux = c * beams.cos - s * beams.sin
    uy = s * beams.cos + c * beams.sin
    flat = model.lookup.flat_index(cand[:, 0:1] + beams.ranges * ux, cand[:, 1:2] + beams.ranges * uy)
    return cand, model.coarse_flat[flat].mean(axis=1, dtype=np.float64)


def grid_modes(model: LikelihoodMap, beams: Beams, theta: float, p: PFParams, k: int,
               window: SearchWindow | None = None) -> list[tuple[float, float]]:
    """The ``k`` best-scoring grid positions of the search square (by default the ``L_init`` square), at
    least ``verify.ambiguity_radius_m`` apart and not on its edge (positive scores only)."""
    window = window or SearchWindow.initial(p)
    cand, score = grid_scores(model, beams, theta, p, window)
    score = np.where(window.offset(cand[:, 0], cand[:, 1]) <= window.half_m - p.verify.step_m, score, -np.inf)
    modes: list[tuple[float, float]] = []
    for _ in range(k):
        best = int(np.argmax(score))
        if not score[best] > 0:
            break
        modes.append((float(cand[best, 0]), float(cand[best, 1])))
        score = np.where(np.hypot(cand[:, 0] - cand[best, 0], cand[:, 1] - cand[best, 1]) > p.verify.ambiguity_radius_m,
                         score, -np.inf)
    return modes


def crossing_fraction(model: LikelihoodMap, beams: Beams, estimate: tuple[float, float, float], p: PFParams) -> float:
    """Share of the beams whose ray, cast from the estimate, meets a wall of ``m_i`` more than ``δmax``
    before the beam's own echo (the free space scan ``j`` saw is a wall in scan ``i``'s map)."""
    dx, dy, theta = estimate
    angle = np.arctan2(beams.sin, beams.cos) + theta
    hit = model.lookup.sphere_trace(np.full(angle.shape, dx), np.full(angle.shape, dy), angle, beams.ranges)
    return float(np.mean(np.isfinite(hit) & (hit < beams.ranges - p.filter.delta_max_m)))


def verify_unique(model: LikelihoodMap, beams: Beams, estimate: tuple[float, float, float], p: PFParams,
                  window: SearchWindow | None = None) -> str:
    """Why a converged estimate cannot be trusted ("" if it can).

    First, more than ``max_crossing`` of the beams may not cross a wall of ``m_i``
    (:func:`crossing_fraction`). Then, with the heading fixed at the estimate, every position of an
    ``L_init`` square (around the window's centre: the origin, or a guess) on a ``step_m`` grid is
    scored with the likelihood field smoothed to that step; the estimate is rejected when a position
    more than ``ambiguity_radius_m`` away scores at least ``ambiguity_ratio`` of the estimate's score,
    or when the estimate lies within one step of the edge of the searched square (``window``: the
    ``L_init`` square by default, the guess's window for a guided match).
    """
    v = p.verify
    dx, dy, theta = estimate
    window = window or SearchWindow.initial(p)
    if window.offset(dx, dy) > window.half_m - v.step_m:
        return f"estimate ({dx:.2f}, {dy:.2f}) m is at the edge of {window.describe()}"
    crossing = crossing_fraction(model, beams, estimate, p)
    if crossing > v.max_crossing:
        return (f"{100 * crossing:.0f} % of the beams pass through walls of the reference map before their "
                f"echo (more than max_crossing={v.max_crossing:g}): the scans contradict each other here")
    around = replace(window, half_m=max(window.half_m, 0.5 * p.filter.l_init_m))
    cand, score = grid_scores(model, beams, theta, p, around, extra=(dx, dy))
    near = np.hypot(cand[:-1, 0] - dx, cand[:-1, 1] - dy)
    best = max(float(score[-1]), float(score[:-1][near <= v.step_m].max(initial=-1.0)))
    far = near > v.ambiguity_radius_m
    if not far.any() or best <= 0:
        return "" if best > 0 else f"estimate scores {best:.3f} on the verification grid"
    k = int(np.argmax(np.where(far, score[:-1], -np.inf)))
    rival = float(score[k])
    if rival >= v.ambiguity_ratio * best:
        dist = math.hypot(cand[k, 0] - dx, cand[k, 1] - dy)
        return (f"ambiguous: a position {dist:.2f} m away ({cand[k, 0]:.2f}, {cand[k, 1]:.2f}) scores "
                f"{rival:.3f} against {best:.3f} at the estimate (repetitive or featureless walls)")
    return ""


def fit_check(pair: ScanPair, estimate: tuple[float, float, float], p: PFParams) -> str:
    """Why ``estimate`` fails the point matchers' shared verdict (:func:`~cistern_plugins.registration.verdict`),
    prefixed ``"fit check: "``; "" if it passes or ``verify.fit.enabled`` is off.

    With the defaults the inlier count and the inlier share (seen from both scans) apply to every
    estimate, and the free-space test (``partial_max_violation``) to those whose inlier share is below
    ``partial_inlier_ratio``; the corridor tests (``min_constraint``, ``max_weak_std_m``) and the general
    free-space limit (``max_violation_ratio``) are off, as :func:`verify_unique` judges ambiguity with the
    map itself and correct matches of segmented sonar scans can put a fifth of their wall points in the
    other scan's free space.
    """
    fit = p.verify.fit
    if not fit.enabled:
        return ""
    limits = fit.limits()
    quality = pair.model.assess_pair(pair.moving, np.array(estimate), limits)
    why = verdict(quality, limits)
    if not why and quality.inlier_ratio < fit.partial_inlier_ratio:
        why = verdict(quality, replace(limits, max_violation_ratio=fit.partial_max_violation))
    return f"fit check: {why}" if why else ""
