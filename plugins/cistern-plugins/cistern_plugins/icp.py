"""``icp``: iterative closest point, the baseline scan matcher both papers compare against.

Besl & McKay (1992) point-to-point ICP, or the point-to-line variant (Chen & Medioni 1992; Censi
2008) that Silver et al. list among ICP's refinements, started from the compass-aligned zero pose, or
from a localizer's guess (:class:`~cistern_archive.pipeline.contracts.MatchGuess`: loop closures around
the solution so far, a moving vehicle's dead-reckoned displacement); an estimate that slides out of the
guess's square is refused (:func:`~cistern_plugins.registration.outside_window`).
Outliers are rejected at every iteration by a correspondence distance gate and by trimming (keep the
best ``trim_fraction`` of the pairs, Chetverikov et al. 2002). The result is reported converged only
when the iteration settled *and* the final fit passes the shared verdict of
:mod:`cistern_plugins.registration` (inliers, inlier ratio, two-direction constraint). The iteration
itself is :func:`cistern_plugins.registration.run_icp`. A fit turned more than ``max_turn_deg`` from the
start (the compasses' headings, or the guess's) is refused whatever its verdict: started from the
compasses' headings, ICP settles in a rectangular or round chamber as well on the pose turned half a
revolution, whose walls fit exactly.
"""

from __future__ import annotations

import math
import time
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from cistern_archive.pipeline.contracts import GuidedMatcher, MatchGuess, MatchResult, StageParams
from cistern_archive.core.scan import RangeScan, wrap_angle
from cistern_plugins.registration import (
    AlignmentQuality,
    ConvergenceParams,
    ReferenceModel,
    fit_covariance,
    judge,
    match_confidence,
    outside_window,
    run_icp,
    scan_points,
    start_pose,
    too_few_points,
    turn_from_start,
)


class ICPParams(ConvergenceParams):
    """Parameters of :class:`ICPMatcher` (plus the convergence limits of :class:`ConvergenceParams`)."""

    variant: Literal["point-to-point", "point-to-line"] = "point-to-line"
    max_iterations: int = Field(100, ge=1)
    max_correspondence_m: float = Field(1.0, gt=0)
    trim_fraction: float = Field(0.8, gt=0, le=1)
    tolerance_m: float = Field(1e-3, gt=0)
    max_turn_deg: float = Field(
        30.0, gt=0, le=180, description="largest rotation from the start (compass-aligned, or a guess's "
        "heading) a fit may end with: two scans' compasses disagree by a few degrees, so a fit turned "
        "further (a symmetric chamber fitting itself turned half a revolution) is refused")


def turned_too_far(dyaw_rad: float, max_turn_deg: float) -> str:
    """The reason a fit turned more than ``max_turn_deg`` from its start (``dyaw_rad``: the turn from the
    compass-aligned start or the guess's heading) is refused, or ``""``."""
    turn = abs(math.degrees(wrap_angle(dyaw_rad)))
    if turn <= max_turn_deg:
        return ""
    return (f"turned {turn:.0f}° from its start (the compass headings, or the guess's; more than "
            f"{max_turn_deg:g}°): a symmetric chamber fits itself turned round")


def icp_verdict(dyaw_rad: float, quality: AlignmentQuality, params: ICPParams) -> str:
    """Why a settled ICP fit is refused, or ``""``: its turn from its start, then the shared verdict
    (:func:`~cistern_plugins.registration.judge`)."""
    return turned_too_far(dyaw_rad, params.max_turn_deg) or judge(quality, params.limits())


class ICPMatcher(GuidedMatcher):
    """Point-to-point / point-to-line ICP with outlier rejection (the ``icp`` matcher)."""

    name: ClassVar[str] = "icp"
    Params: ClassVar[type[StageParams]] = ICPParams

    def match(self, reference: RangeScan, moving: RangeScan, params: StageParams, *,
              rng: np.random.Generator, guess: MatchGuess | None = None) -> MatchResult:
        """Locate ``moving`` in ``reference``'s frame, from the compass-aligned zero pose or from ``guess``
        (then an estimate outside its square is refused); ``rng`` is unused (ICP is deterministic)."""
        p = ICPParams.of(params).for_scans(reference, moving)
        start = time.perf_counter()
        why = too_few_points(reference, moving, p.min_points)
        if why:
            return MatchResult.no_estimate(why, seconds=time.perf_counter() - start)
        model = ReferenceModel(reference)
        src = scan_points(moving)
        out = run_icp(model, src, start_pose(guess), variant=p.variant, max_iterations=p.max_iterations,
                      max_correspondence_m=p.max_correspondence_m, trim_fraction=p.trim_fraction,
                      tolerance_m=p.tolerance_m)
        quality = model.assess_pair(moving, out.pose, p.limits())
        reason = "" if out.settled else f"did not settle in {p.max_iterations} iterations"
        reason = (reason or outside_window(out.pose, guess)
                  or icp_verdict(turn_from_start(out.pose, guess), quality, p))
        return MatchResult(
            i=-1, j=-1, dx_m=float(out.pose[0]), dy_m=float(out.pose[1]), dyaw_rad=float(out.pose[2]),
            weight=quality.inlier_ratio, converged=not reason, iterations=out.iterations,
            seconds=time.perf_counter() - start, reason=reason,
            covariance=fit_covariance(model, src, out.pose, p.inlier_distance_m, quality.rms_m),
            confidence=match_confidence(quality, p.limits()),
        )
