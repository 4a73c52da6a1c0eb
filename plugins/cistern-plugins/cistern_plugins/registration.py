"""The registration helpers the built-in matchers share: the stable API a third-party matcher may use.

Everything a matcher plugin may import from ``cistern_plugins`` is named here; the built-in matchers
import their shared helpers through this module too, and the modules behind it
(:mod:`~cistern_plugins.alignment`, :mod:`~cistern_plugins.verification`,
:mod:`~cistern_plugins.closest_point`, :mod:`~cistern_plugins.guess_window`,
:mod:`~cistern_plugins.sonar_scale`) may change their insides as long as these names keep their
signatures and meaning. Anything else in ``cistern_plugins`` (a matcher's own functions, a name with a
leading underscore) is an implementation detail.

Conventions (as :mod:`cistern_archive.pipeline.contracts`): a scan's points are map-oriented with its
compass yaw and relative to its own station; a pose ``(x, y, theta)`` places the moving scan's points in
the reference scan's frame as ``q = R(theta) p + (x, y)``, so ``(x, y)`` is ``p_moving - p_reference`` and
``theta`` the moving scan's yaw correction.

Geometry
    :func:`scan_points` (a scan's echoes as (N, 2) points), :func:`transform`, :func:`transform_many`,
    :func:`compose`, :func:`inverse`, :func:`rotate`, :func:`robust_error` (truncated or Huber error
    of distances); angles wrap with :func:`cistern_archive.core.scan.wrap_angle`.
The reference scan
    :class:`ReferenceModel`: its points, k-d tree, normals and free space, built once per match;
    ``assess(moved, inlier_distance_m)`` and ``assess_pair(moving, pose, limits)`` give an
    :class:`AlignmentQuality` (inliers, inlier share, rms, wall-normal constraint, free-space violations,
    both ways). :class:`FreeSpace` is the space a sonar saw empty in front of its echoes.
The verdict on a fit
    :class:`ConvergenceParams` (the limits as pydantic fields a matcher's ``Params`` can inherit; its
    ``limits()`` gives :class:`ConvergenceThresholds`); :class:`SonarScaled` (parameters whose lengths,
    the fields named ``*_m``, are written for the calibration sonar: ``p.for_scans(reference, moving)``
    scales them by the pair's :func:`length_unit`, its bin over 0.05 m or the range of its farther
    echoes over 10 m, at least 1; every built-in matcher's parameters are so); :func:`too_few_points`
    (refuse a pair before matching); :func:`verdict` (the fixed limits: inliers, inlier share, two-direction constraint,
    free space); :func:`judge` (the calibrated model when ``limits.calibrated``, else :func:`verdict`),
    :func:`match_confidence` (the calibrated probability that the fit is right, for
    ``MatchResult.confidence``) and :func:`tentative_fit` (whether a refused fit may be offered as
    ``MatchResult.tentative``).
Point-to-line ICP
    :func:`run_icp` (trimmed point-to-point or point-to-line ICP from a starting pose, an
    :class:`ICPOutcome`); :func:`refine_point_to_line` (polish a search matcher's estimate without the
    along-gallery pull of a point score; ``None`` when it slides farther than allowed) and
    :func:`fit_covariance` (the 3 × 3 covariance of a point-to-line fit, for ``MatchResult.covariance``).
A localizer's guess (:class:`~cistern_archive.pipeline.contracts.MatchGuess`), for a local matcher
    :func:`start_pose` (the guess's pose, or the compass-aligned zero), :func:`outside_window` (refuse an
    estimate that slid out of the guess's square) and :func:`turn_from_start` (the heading correction
    less the guess's).

Example: the end of a search matcher::

    from cistern_plugins.registration import (ReferenceModel, fit_covariance, judge, match_confidence,
                                              refine_point_to_line, scan_points)

    p = p.for_scans(reference, moving)  # lengths scaled to the pair's sonar
    model, src = ReferenceModel(reference), scan_points(moving)
    pose = refine_point_to_line(model, src, pose, iterations=30, correspondence_m=0.3,
                                trim_fraction=0.8, max_shift_m=0.2) or pose
    quality = model.assess_pair(moving, pose, p.limits())
    reason = judge(quality, p.limits())
    covariance = fit_covariance(model, src, pose, p.inlier_distance_m, quality.rms_m)
"""

from __future__ import annotations

from cistern_plugins.alignment import (
    AlignmentQuality,
    ConvergenceParams,
    ConvergenceThresholds,
    FreeSpace,
    ReferenceModel,
    compose,
    inverse,
    robust_error,
    rotate,
    scan_points,
    too_few_points,
    transform,
    transform_many,
    verdict,
)
from cistern_plugins.closest_point import ICPOutcome, fit_covariance, refine_point_to_line, run_icp
from cistern_plugins.guess_window import outside_window, start_pose, turn_from_start
from cistern_plugins.sonar_scale import SonarScaled, length_unit, wall_range_m
from cistern_plugins.verification import judge, match_confidence, tentative_fit

__all__ = [
    "AlignmentQuality",
    "ConvergenceParams",
    "ConvergenceThresholds",
    "FreeSpace",
    "ICPOutcome",
    "ReferenceModel",
    "SonarScaled",
    "compose",
    "fit_covariance",
    "inverse",
    "judge",
    "length_unit",
    "match_confidence",
    "outside_window",
    "refine_point_to_line",
    "robust_error",
    "rotate",
    "run_icp",
    "scan_points",
    "start_pose",
    "tentative_fit",
    "too_few_points",
    "transform",
    "transform_many",
    "turn_from_start",
    "verdict",
    "wall_range_m",
]
