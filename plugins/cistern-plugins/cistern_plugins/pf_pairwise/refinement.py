"""Point-to-line refinement of a verified estimate (``refine``).

The likelihood field scores how many beams land on the sampled walls of ``m_i``; walls are sampled
densely near each sonar and sparsely far from it, so the score favours placements that bring the two
scans' dense parts together and converged estimates are short by a few centimetres
(``benchmarks/RESULTS.md``). Point-to-line distances do not depend on how densely a wall is sampled.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cistern_plugins.pf_pairwise.pair import ScanPair
from cistern_plugins.pf_pairwise.params import PFParams
from cistern_plugins.pf_pairwise.particle_filter import Outcome
from cistern_plugins.registration import fit_covariance, refine_point_to_line, transform


def refine_estimate(pair: ScanPair, estimate: tuple[float, float, float],
                    p: PFParams) -> tuple[tuple[float, float, float], np.ndarray | None]:
    """``estimate`` refined by trimmed point-to-line ICP of the moving scan's echoes against the
    reference scan's (:func:`~cistern_plugins.registration.refine_point_to_line`), with the covariance
    of the point-to-line fit (:func:`~cistern_plugins.registration.fit_covariance`, inliers within
    ``verify.fit.inlier_distance_m``: along a plain gallery it is long along the axis, which a pose graph
    needs to know); unchanged with no covariance when ``refine.method`` is ``"none"``, the scans have too
    few echoes, or the refinement moves farther than ``refine.max_shift_m``."""
    r = p.refine
    if r.method == "none" or pair.model.tree is None or len(pair.model.points) < 3:
        return estimate, None
    model = pair.model
    src = pair.moving_points
    if len(src) < 3:
        return estimate, None
    pose = refine_point_to_line(model, src, np.array(estimate), iterations=r.iterations,
                                correspondence_m=r.correspondence_m, trim_fraction=r.trim_fraction,
                                max_shift_m=r.max_shift_m)
    if pose is None:
        return estimate, None
    inlier_m = p.verify.fit.inlier_distance_m
    rms = model.assess(transform(src, pose), inlier_m).rms_m
    covariance = fit_covariance(model, src, pose, inlier_m, rms)
    return (float(pose[0]), float(pose[1]), float(pose[2])), covariance


def refine(outcome: Outcome, pair: ScanPair, p: PFParams) -> Outcome:
    """A converged outcome refined (:func:`refine_estimate`), reported with the fit's covariance when
    the refinement gave one and with the particles' otherwise; any other outcome unchanged."""
    if not outcome.converged:
        return outcome
    estimate, covariance = refine_estimate(pair, outcome.estimate, p)
    return replace(outcome, estimate=estimate, covariance=outcome.covariance if covariance is None else covariance)
