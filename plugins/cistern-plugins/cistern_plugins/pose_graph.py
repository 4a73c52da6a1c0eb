"""``pose-graph``: robust least squares over every converged pair in a sliding window (GTSAM).

McVicker et al. localise from neighbouring pairs only (eqs. 7–10) and name matching beyond neighbours
as future work. This localizer asks the matcher for every pair within ``window`` scans (both
directions, or one), and solves for all positions and yaw corrections at once.

Guided matching (``guided``, off by default): the neighbours are matched first
(:meth:`PoseGraphLocalizer.pairs`); their graph is solved, and every pair 2 to ``window`` apart is then
matched with a :class:`~cistern_archive.pipeline.contracts.MatchGuess`, the relative pose of the two
scans in that solution and a ``±guess_radius_m`` window (:meth:`PoseGraphLocalizer.guided_pairs`), as
SLAM systems search for loop closures around their odometry; a pair whose scans the neighbours do not
join is matched without a guess. Measured on the demo ``water-gallery`` and on 20 synthetic galleries
it places no more scans and is no more accurate than matching every pair from scratch
(``benchmarks/RESULTS.md``): in the demo gallery scans two or more stations apart share too few echoes
to be matched either way, and in the synthetic ones the pairs converge without a guess.

Model: one ``Pose2`` variable per scan, ``X_k = (x_k, y_k, c_k)`` with ``(x_k, y_k)`` the map-frame
position and ``c_k`` the correction added to the compass yaw. A converged match ``(i, j)`` measures
``d_ij`` in scan i's compass frame and ``dyaw``; with i's correction ``c_i`` the map-frame
displacement is ``R(c_i) d_ij``, which is exactly GTSAM's ``BetweenFactorPose2`` measurement
``X_i^-1 X_j = (d_ij, dyaw)``. Each factor's noise is the match's covariance (or the default sigmas)
wrapped in a robust M-estimator (``huber`` or ``cauchy``), so a wrong match that slipped through is
down-weighted; the match covariance is floored at ``min_sigma_xy_m`` so that no single match is
trusted beyond the accuracy scan matching reaches on sonar data. The compass is trusted up to
``compass_sigma_deg`` (a prior on every ``c_k`` about the compasses' common frame,
:func:`cistern_plugins.factor_graph.add_compass_factors`; 2° by default, about twice a Micron-class
compass's noise, so that small yaw errors of the matches cannot accumulate along a chain of scans),
and the reference scan (in the largest group of scans
joined by converged matches, the one with most matches, lowest index on ties — cf. Table III) is
anchored at the origin. Levenberg–Marquardt solves the graph; then, for up to ``gate_rounds`` rounds,
the match whose squared Mahalanobis residual is largest is dropped if it exceeds ``gate_chi2``
(default: the 99.9 % quantile of chi-square with 3 degrees of freedom) and the graph is solved again —
robust losses soften a wrong match, the gate removes it; a scan whose only path was a dropped match
becomes unplaced. ``gtsam.Marginals`` gives each scan's 3×3 covariance, rotated into the map frame. Scans with no converged path to the reference are
returned unplaced with the reason.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from cistern_archive.pipeline.contracts import (GuidedLocalizer, MatchGuess, MatchResult, Poses, StageParams,
                                                VerticalTie)
from cistern_archive.core.scan import RangeScan
from cistern_plugins.factor_graph import Edge, GraphParams, poses_from_solution, solve_gated, spanning_tree


class PoseGraphParams(GraphParams):
    """Parameters of :class:`PoseGraphLocalizer` (plus the graph's, :class:`GraphParams`)."""

    window: int = Field(3, ge=1)
    directions: Literal["both", "one"] = "both"
    guided: bool = False
    guess_radius_m: float = Field(0.5, gt=0)


class PoseGraphLocalizer(GuidedLocalizer):
    """Sliding-window pose graph with robust factors and marginal covariances (the ``pose-graph`` localizer)."""

    name: ClassVar[str] = "pose-graph"
    Params: ClassVar[type[StageParams]] = PoseGraphParams

    def pairs(self, n_scans: int, params: StageParams) -> list[tuple[int, int]]:
        """Every pair within ``window`` scans of each other, nearest first; both directions unless ``one``.
        When ``guided``, only the neighbours (the rest come from :meth:`guided_pairs`)."""
        p = PoseGraphParams.of(params)
        return _pairs(n_scans, range(1, (1 if p.guided else p.window) + 1), p)

    def guided_pairs(self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
                     ties: Sequence[VerticalTie] = ()) -> list[tuple[int, int, MatchGuess | None]]:
        """The pairs 2 to ``window`` scans apart, each with the guess of the neighbours' solution (none
        when ``guided`` is off, as :meth:`pairs` then asked for them all)."""
        p = PoseGraphParams.of(params)
        if not p.guided:
            return []
        n = len(scans)
        good = _usable(matches, n)
        reference = _reference(n, good)
        solved = {}
        if reference >= 0:
            _, result, kept = _solve_gated(n, good, reference, p)
            solved = {k: result.atPose2(k) for k in spanning_tree(n, kept, reference)}
        out: list[tuple[int, int, MatchGuess | None]] = []
        for i, j in _pairs(n, range(2, p.window + 1), p):
            guess = None
            if i in solved and j in solved:
                rel = solved[i].between(solved[j])
                guess = MatchGuess(rel.x(), rel.y(), rel.theta(), p.guess_radius_m)
            out.append((i, j, guess))
        return out

    def localize(self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
                 ties: Sequence[VerticalTie] = ()) -> Poses:
        """Place every scan connected to the reference by converged matches. The vertical ``ties`` are not used: this
        localizer places the scans of one depth level."""
        p = PoseGraphParams.of(params)
        n = len(scans)
        good = _usable(matches, n)
        reference = _reference(n, good)
        yaw = np.array([s.yaw_rad for s in scans], dtype=np.float64)
        if reference < 0:
            reasons = tuple("no converged match" for _ in range(n))
            return Poses(np.full((n, 2), np.nan), yaw, np.zeros(n, bool), reasons, -1, None)
        graph, result, kept = _solve_gated(n, list(good), reference, p)
        placed = set(spanning_tree(n, kept, reference))
        reasons = [f"no converged path of matches to reference scan {reference}"] * n
        return poses_from_solution(scans, graph, result, placed, reference, reasons)


def _pairs(n_scans: int, gaps: range, p: PoseGraphParams) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for gap in gaps:
        for i in range(n_scans - gap):
            out.append((i, i + gap))
            if p.directions == "both":
                out.append((i + gap, i))
    return out


def _usable(matches: Sequence[MatchResult], n: int) -> list[MatchResult]:
    """The converged matches between two distinct scans of the site with a finite estimate."""
    return [m for m in matches if m.converged and 0 <= m.i < n and 0 <= m.j < n and m.i != m.j
            and np.isfinite([m.dx_m, m.dy_m, m.dyaw_rad]).all()]


def _solve_gated(n: int, good: list[MatchResult], reference: int, p: PoseGraphParams):
    """Solve, then drop the worst match while its squared Mahalanobis residual exceeds the gate."""
    noise = p.noise()
    return solve_gated(n, [Edge.of_match(m, noise) for m in good], reference, noise, p.gate_chi2, p.gate_rounds)


def _reference(n: int, good: Sequence[MatchResult]) -> int:
    """In the largest group of scans joined by converged matches, the scan with most converged matches
    (lowest index on ties); -1 when there are none."""
    if not good:
        return 0 if n == 1 else -1
    counts = np.zeros(n, dtype=int)
    parent = list(range(n))

    def find(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for m in good:
        counts[m.i] += 1
        counts[m.j] += 1
        parent[find(m.i)] = find(m.j)
    roots = np.array([find(k) for k in range(n)])
    sizes = np.bincount(roots, minlength=n)
    largest = roots == roots[np.argmax(np.where(counts > 0, sizes[roots], 0))]
    return int(np.argmax(np.where(largest, counts, -1)))
