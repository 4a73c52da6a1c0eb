"""``correlative``: multi-resolution correlative scan matching (Olson 2009; Hess et al. 2016, Cartographer).

The reference scan is rasterised into a likelihood grid: every cell holds
``exp(-d^2 / (2 sigma^2))`` with ``d`` the distance to the nearest reference echo (a Euclidean distance
transform), minus ``free_space_penalty`` in cells the reference sonar saw empty (closer than its echo
on that bearing by more than ``free_space_margin_m``; the negative evidence of an occupancy-grid
match, like the δmax feedback of McVicker et al. eq. 4). A pose's score is the mean grid value under the moving scan's points. The search is
exhaustive over a window of translations (``±search_m``) and yaw corrections (``±search_deg``), so it
needs no initial guess, and exact: branch and bound over a pyramid of max-pooled grids (level ``h``
holds the maximum over the ``2^h × 2^h`` cells a translation node covers, Hess et al. Sec. IV-C), so a
node's score at level ``h`` bounds every pose below it. The search is breadth-first and vectorised:
at each level every surviving node is split into four children and nodes whose bound falls below the
pruning threshold are dropped; the threshold is the best exact score found so far (by a greedy descent
from the best node) times ``ambiguity_ratio``, so every pose within that ratio of the optimum survives
to the finest level and the runner-up peak is known exactly.

A best pose at the first or last yaw of the window is no peak: the optimum may lie beyond it (a compass
thrown off by iron fittings, or a pair of scans whose compasses disagree more than a Micron-class
compass's noise). A search without a guess is then repeated with the yaw window doubled, up to
``max_search_deg``, and refused if its best still lies on the edge. A search around a guess keeps its
window (``guess_search_deg``): the guess's heading comes from a solution of the site. Either way the
refinement below may not turn the pose out of the window the search covered by more than one of its yaw
steps: that pose was never scored against its rivals (on the bell cistern such a match, its guess's
window ±6°, came out turned 17° from the truth).

Convergence is honest on five counts: the best score reaches ``min_score``; the best heading lies inside
the yaw window, and the refined one stays in it (above); no pose farther than
``ambiguity_distance_m`` from the best (at any yaw) scores within ``ambiguity_ratio`` of it (Olson's
ambiguity test). The reason names which kind of ambiguity it is: a second peak, separated from the
best by a valley (on the straight path between them the score, maximised over nearby yaws, drops
below ``valley_ratio`` of the best), or a ridge — one elongated peak, as a gallery seen along its axis
gives, whose position along the ridge is unknown to at least ``ambiguity_distance_m``; and the refined placement passes the shared test
of :mod:`cistern_plugins.alignment`. The winning pose is refined to sub-cell accuracy by a few
point-to-line ICP iterations, as Cartographer refines its correlative estimate with a local solver; the
refined pose is kept only where it scores at least what the lattice can cost the optimum (the
likelihood's fall over half a cell): on pairs that share a few walls the point-to-line fit can slide
onto another fit, turned by up to 6° and 0.1 m off, which the search's score measures lower.
The result's ``iterations`` counts the finest-level poses that survived the pruning and ``weight`` is
the best score.

A room that looks alike turned (a round or elliptical chamber, a bell) gives many headings whose best
poses score within a few per cent of each other, and the highest of them is then the noise's choice: on
generated bell-shaped cisterns the matches came out turned 3–15° from the truth, for compasses good to
2°. Where the poses scoring within ``flat_heading_share`` of the best span more than
``flat_heading_span_deg`` of heading, the walls do not fix it, and the pose among them whose heading lies
nearest the compass's (or the guess's) is taken and refined instead; its score is the weight.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import ClassVar

import numpy as np
from pydantic import Field
from scipy import ndimage

from cistern_archive.pipeline.contracts import GuidedMatcher, MatchGuess, MatchResult, StageParams
from cistern_archive.core.scan import RangeScan, wrap_angle
from cistern_plugins.content_cache import ContentCache, scans_digest
from cistern_plugins.registration import (
    ConvergenceParams,
    FreeSpace,
    ReferenceModel,
    compose,
    fit_covariance,
    judge,
    match_confidence,
    refine_point_to_line,
    scan_points,
    tentative_fit,
    too_few_points,
    transform,
)


class CorrelativeParams(ConvergenceParams):
    """Parameters of :class:`CorrelativeMatcher` (plus the limits of :class:`ConvergenceParams`)."""

    resolution_m: float = Field(0.05, gt=0)
    sigma_m: float = Field(0.08, gt=0)
    search_m: float | None = Field(None, gt=0, description="half-width of the global search square; default: "
                                   "the smaller sonar range of the pair, at most max_search_m")
    max_search_m: float = Field(6.0, gt=0, description="cap of the default global search square")
    search_deg: float = Field(12.0, ge=0, le=180, description="yaw window of a global search: six times a "
                              "Micron-class compass's 2° noise")
    guess_search_deg: float = Field(6.0, ge=0, le=180, description="yaw window around a guess's heading")
    max_search_deg: float = Field(48.0, ge=0, le=180, description="a search without a guess whose best "
                                  "heading lies on the edge of its yaw window is repeated with the window "
                                  "doubled, up to this")
    levels: int = Field(5, ge=1, le=8)
    min_score: float = Field(0.08, ge=0, le=1)
    ambiguity_ratio: float = Field(0.9, gt=0, le=1)
    ambiguity_distance_m: float = Field(0.5, gt=0)
    valley_ratio: float = Field(0.8, gt=0, le=1)
    refine_iterations: int = Field(30, ge=0)
    free_space_penalty: float = Field(1.0, ge=0)
    flat_heading_share: float = Field(0.05, ge=0, lt=1, description="poses scoring within this share of the "
                                      "best are equally good (0: the best is always taken)")
    flat_heading_span_deg: float = Field(4.0, ge=0, description="where equally good poses span more heading "
                                         "than this (twice a Micron-class compass's noise), the walls do not "
                                         "fix the heading: the one nearest the compass, or the guess, is taken")


class LikelihoodPyramid:
    """The likelihood grid of a reference scan and its max-pooled levels.

    ``level[h][r, c]`` is the maximum of the base grid over rows ``r .. r + 2^h - 1`` and columns
    ``c .. c + 2^h - 1``, so a lookup at a node's corner bounds all translations in the node.
    """

    def __init__(self, points: np.ndarray, resolution_m: float, sigma_m: float, margin_m: float, levels: int,
                 free: FreeSpace | None = None, free_margin_m: float = 0.3, penalty: float = 0.0):
        self.resolution = resolution_m
        lo = points.min(axis=0) - margin_m
        hi = points.max(axis=0) + margin_m
        shape = np.ceil((hi - lo) / resolution_m).astype(int) + 1
        self.origin = lo
        occupied = np.ones((shape[1], shape[0]), dtype=bool)
        cells = np.floor((points - lo) / resolution_m).astype(int)
        occupied[cells[:, 1], cells[:, 0]] = False
        dist = ndimage.distance_transform_edt(occupied) * resolution_m
        base = np.exp(-0.5 * (dist / sigma_m) ** 2).astype(np.float32)
        if free is not None and penalty > 0:
            rows, cols = np.mgrid[0 : shape[1], 0 : shape[0]]
            centres = np.column_stack([cols.ravel(), rows.ravel()]) * resolution_m + lo + resolution_m / 2
            bad = free.in_free_space(centres, free_margin_m).reshape(base.shape)
            base[bad] -= np.float32(penalty)
        self.levels = [base]
        for h in range(1, levels):
            step = 2 ** (h - 1)
            prev = np.pad(self.levels[-1], ((0, step), (0, step)))
            pooled = np.maximum(np.maximum(prev[:-step, :-step], prev[step:, :-step]),
                                np.maximum(prev[:-step, step:], prev[step:, step:]))
            self.levels.append(pooled)

    def cells(self, points: np.ndarray) -> np.ndarray:
        """Integer (col, row) of points, shape (..., 2)."""
        return np.floor((points - self.origin) / self.resolution).astype(np.int64)

    def padded(self, window_cells: int) -> "PaddedPyramid":
        """The levels with a zero border wide enough for every lookup of a ``±window_cells`` search."""
        return PaddedPyramid(self, window_cells)

    def score(self, level: int, point_cells: np.ndarray, offsets: np.ndarray, angle_idx: np.ndarray) -> np.ndarray:
        """Mean grid value of level ``level`` under rotated points shifted by cell offsets.

        ``point_cells`` is (R, N, 2) for R rotations; ``offsets`` (K, 2) cell shifts and ``angle_idx`` (K,)
        rotation index of each node. Out-of-grid points count 0.
        """
        grid = self.levels[level]
        h, w = grid.shape
        c = point_cells[angle_idx] + offsets[:, None, :]  # (K, N, 2)
        inside = (c[..., 0] >= 0) & (c[..., 0] < w) & (c[..., 1] >= 0) & (c[..., 1] < h)
        vals = np.where(inside, grid[np.clip(c[..., 1], 0, h - 1), np.clip(c[..., 0], 0, w - 1)], 0.0)
        return vals.mean(axis=1)


class PaddedPyramid:
    """A :class:`LikelihoodPyramid` with every level framed by zeros, flattened, so that a search of
    ``±window_cells`` scores points by one gather of flat indices (no bounds tests): a point's cell is
    clamped to just beyond the reach of any offset, where the frame is zero, which keeps every score
    exact (out-of-grid points count 0)."""

    def __init__(self, pyramid: LikelihoodPyramid, window_cells: int):
        self.base = pyramid
        self.pad = 2 * window_cells + 2
        h, w = pyramid.levels[0].shape
        self.shape = (h + 2 * self.pad, w + 2 * self.pad)
        self.flat = [np.pad(level, self.pad).ravel() for level in pyramid.levels]
        self.window = window_cells

    def point_index(self, point_cells: np.ndarray) -> np.ndarray:
        """Flat indices (R, N) of rotated points' cells, clamped into the zero frame."""
        h, w = self.base.levels[0].shape
        reach = self.window + 1
        col = np.clip(point_cells[..., 0], -reach, w - 1 + reach) + self.pad
        row = np.clip(point_cells[..., 1], -reach, h - 1 + reach) + self.pad
        return (row * self.shape[1] + col).astype(np.int64)

    def score(self, level: int, point_index: np.ndarray, offsets: np.ndarray, angle_idx: np.ndarray) -> np.ndarray:
        """As :meth:`LikelihoodPyramid.score`, on flat indices from :meth:`point_index`."""
        shift = offsets[:, 1] * self.shape[1] + offsets[:, 0]
        vals = self.flat[level][point_index[angle_idx] + shift[:, None]]
        return vals.sum(axis=1, dtype=np.float64) / point_index.shape[1]


def _angles(points: np.ndarray, search_deg: float, resolution_m: float) -> np.ndarray:
    """Yaw candidates within ``±search_deg``: the step moves the farthest point by at most one cell
    (Hess et al. eq. 7)."""
    if search_deg == 0:
        return np.zeros(1)
    d_max = max(float(np.percentile(np.hypot(points[:, 0], points[:, 1]), 95)), resolution_m)
    step = math.acos(max(-1.0, 1 - resolution_m**2 / (2 * d_max**2)))
    n = int(math.ceil(math.radians(search_deg) / step))
    return np.arange(-n, n + 1) * step


def branch_and_bound(pyr: LikelihoodPyramid, points: np.ndarray, angles: np.ndarray, window_cells: int,
                     ambiguity_ratio: float, floor: float = -np.inf) -> tuple[np.ndarray, np.ndarray]:
    """All finest-level candidates within ``ambiguity_ratio`` of the optimum and above ``floor``:
    (K, 3) [col, row, angle idx] offsets and their exact scores, best first (empty when none)."""
    top = len(pyr.levels) - 1
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    rotated = np.stack([c * points[:, 0] - s * points[:, 1], s * points[:, 0] + c * points[:, 1]], axis=-1)
    fast = pyr.padded(window_cells)
    point_cells = fast.point_index(pyr.cells(rotated))
    step = 2**top
    span = np.arange(-window_cells, window_cells + 1, step)
    gx, gy, ga = np.meshgrid(span, span, np.arange(len(angles)), indexing="ij")
    nodes = np.column_stack([gx.ravel(), gy.ravel(), ga.ravel()])
    bounds = fast.score(top, point_cells, nodes[:, :2], nodes[:, 2])
    best = _greedy_descent(fast, point_cells, nodes[np.argmax(bounds)], top, window_cells)
    for level in range(top, 0, -1):
        keep = bounds >= max(_threshold(best, ambiguity_ratio), floor)
        nodes = nodes[keep]
        if len(nodes) == 0:
            return np.zeros((0, 3), dtype=np.int64), np.zeros(0)
        half = 2 ** (level - 1)
        kids = np.concatenate([nodes + [dx, dy, 0] for dx in (0, half) for dy in (0, half)])
        kids = kids[(np.abs(kids[:, 0]) <= window_cells) & (np.abs(kids[:, 1]) <= window_cells)]
        nodes = kids
        bounds = fast.score(level - 1, point_cells, nodes[:, :2], nodes[:, 2])
        if level - 1 > 0:
            best = max(best, _greedy_descent(fast, point_cells, nodes[np.argmax(bounds)], level - 1, window_cells))
        else:
            best = max(best, float(bounds.max()))
    keep = bounds >= max(_threshold(best, ambiguity_ratio), floor)
    order = np.argsort(-bounds[keep], kind="stable")
    return nodes[keep][order], bounds[keep][order]


def yaw_search(pyr: LikelihoodPyramid, points: np.ndarray, window_cells: int, half_deg: float, p: CorrelativeParams,
               *, widen: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, bool]:
    """:func:`branch_and_bound` over ``±half_deg`` of yaw; with ``widen``, again over a window twice as wide
    (up to ``max_search_deg``) while the best lies on the window's edge (module docstring). Returns the
    nodes and scores, the yaws searched, the last half-width and, with ``widen``, whether the best still
    lies on its edge (without, a search around a guess keeps its window whatever its best)."""
    while True:
        angles = _angles(points, half_deg, p.resolution_m)
        nodes, scores = branch_and_bound(pyr, points, angles, window_cells, p.ambiguity_ratio,
                                         floor=p.ambiguity_ratio * p.min_score)
        edge = widen and len(nodes) > 0 and at_yaw_edge(nodes[0], angles)
        if not (edge and half_deg < p.max_search_deg):
            return nodes, scores, angles, half_deg, edge
        half_deg = min(2.0 * half_deg, p.max_search_deg)


def nearest_heading_first(nodes: np.ndarray, scores: np.ndarray, angles: np.ndarray, share: float,
                          span_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """The search's nodes and scores (best first) with, first, the node whose heading lies nearest the
    search's centre among those scoring within ``share`` of the best, where their headings span more than
    ``span_rad``; else as they are (module docstring: a room that looks alike turned)."""
    if share <= 0 or len(angles) < 2 or len(nodes) < 2:
        return nodes, scores
    near = np.flatnonzero(scores >= scores[0] - share * abs(scores[0]))
    yaws = angles[nodes[near, 2]]
    if np.ptp(yaws) <= span_rad:
        return nodes, scores
    k = int(near[np.argmin(np.abs(yaws))])
    order = np.concatenate([[k], np.delete(np.arange(len(nodes)), k)])
    return nodes[order], scores[order]


def yaw_step(angles: np.ndarray) -> float:
    """The step between the yaws of a search (0 for one yaw)."""
    return float(angles[1] - angles[0]) if len(angles) > 1 else 0.0


def at_yaw_edge(node: np.ndarray, angles: np.ndarray) -> bool:
    """Whether a search node lies at the first or last yaw of a window of several."""
    return len(angles) > 1 and int(node[2]) in (0, len(angles) - 1)


def _threshold(best: float, ratio: float) -> float:
    """Pruning threshold: ``ratio`` of the best score, measured below it (scores may be negative)."""
    return best - (1.0 - ratio) * abs(best)


def _greedy_descent(pyr: "PaddedPyramid", point_cells: np.ndarray, node: np.ndarray, level: int,
                    window_cells: int) -> float:
    """Exact score of the leaf reached by always taking the best child: a lower bound of the optimum."""
    node = node.copy()
    for lv in range(level, 0, -1):
        half = 2 ** (lv - 1)
        kids = np.array([node + [dx, dy, 0] for dx in (0, half) for dy in (0, half)])
        kids = kids[(np.abs(kids[:, 0]) <= window_cells) & (np.abs(kids[:, 1]) <= window_cells)]
        sc = pyr.score(lv - 1, point_cells, kids[:, :2], kids[:, 2])
        node = kids[int(np.argmax(sc))]
    return float(pyr.score(0, point_cells, node[None, :2], node[None, 2])[0])


class CorrelativeMatcher(GuidedMatcher):
    """Exhaustive multi-resolution correlative matcher with branch and bound (the ``correlative`` matcher)."""

    name: ClassVar[str] = "correlative"
    Params: ClassVar[type[StageParams]] = CorrelativeParams

    def match(self, reference: RangeScan, moving: RangeScan, params: StageParams, *,
              rng: np.random.Generator, guess: MatchGuess | None = None) -> MatchResult:
        """Locate ``moving`` in ``reference``'s frame; the search is deterministic, ``rng`` is unused.

        Without a ``guess`` the search covers ``±search_m`` around the origin and ``±search_deg`` of yaw;
        with one, ``±guess.radius_m`` around the guessed offset and ``±guess_search_deg`` around its
        heading (the ambiguity test then only sees rivals inside that window).
        """
        p = CorrelativeParams.of(params).for_scans(reference, moving)
        start = time.perf_counter()
        why = too_few_points(reference, moving, p.min_points)
        if why:
            return MatchResult.no_estimate(why, seconds=time.perf_counter() - start)
        model = ReferenceModel(reference)
        centre = np.zeros(3) if guess is None else np.array([guess.dx_m, guess.dy_m, guess.dyaw_rad])
        half_m = search_half_width(reference, moving, p) if guess is None else guess.radius_m
        thin = thinned(scan_points(moving), 2 * p.resolution_m)
        src = transform(thin, centre)
        pyr = reference_pyramid(reference, model, p, half_m + 4 * p.sigma_m)
        window = int(math.ceil(half_m / p.resolution_m))
        half_deg = p.search_deg if guess is None else p.guess_search_deg
        nodes, scores, angles, half_deg, edge = yaw_search(pyr, src, window, half_deg, p, widen=guess is None)
        if len(nodes) == 0:
            reason = f"no pose in the window scores {p.ambiguity_ratio * p.min_score:.2f} or more"
            return MatchResult.no_estimate(reason, seconds=time.perf_counter() - start)
        nodes, scores = nearest_heading_first(nodes, scores, angles, p.flat_heading_share,
                                              math.radians(p.flat_heading_span_deg))
        delta = np.array([nodes[0, 0] * p.resolution_m, nodes[0, 1] * p.resolution_m, angles[nodes[0, 2]]])
        best = compose(delta, centre)
        reason = ""
        if scores[0] < p.min_score:
            reason = f"best correlation score {scores[0]:.2f} < {p.min_score:.2f}"
        elif edge:
            reason = (f"the best heading lies on the edge of the ±{half_deg:.0f}° search: the optimum may lie "
                      "beyond it")
        rival = _rival(nodes, scores, angles, p, pyr, src)
        ambiguous = not reason and rival is not None
        if ambiguous:
            kind = "a ridge: a pose" if rival[3] else "a second peak"
            reason = (f"ambiguous, {kind} {rival[0]:.2f} m / {rival[1]:.1f}° away scores "
                      f"{rival[2]:.2f} against the best {scores[0]:.2f}")
        pose = best
        iterations = len(nodes)
        raw = scan_points(moving)
        if p.refine_iterations:
            refined = refine_point_to_line(model, raw, best, iterations=p.refine_iterations,
                                           correspondence_m=p.inlier_distance_m + 2 * p.sigma_m, trim_fraction=0.8,
                                           max_shift_m=4 * p.resolution_m)
            pose = refined if refined is not None and keeps_score(pyr, thin, best, refined, p) else best
        turned = abs(wrap_angle(pose[2] - centre[2]))
        if not reason and turned > math.radians(half_deg) + yaw_step(angles):
            reason = (f"the refinement turned the heading {math.degrees(turned):.1f}° from the search's centre, "
                      f"beyond its ±{half_deg:.0f}° window")
        quality = model.assess_pair(moving, pose, p.limits())
        fit = judge(quality, p.limits())
        tentative = (ambiguous or not reason) and (not fit or tentative_fit(quality, p.limits()))
        reason = reason or fit
        confidence = match_confidence(quality, p.limits())
        cov = fit_covariance(model, raw, pose, p.inlier_distance_m, quality.rms_m)
        result = _result(pose, float(scores[0]), not reason, reason, iterations, start, cov, confidence)
        if ambiguous:
            result = replace(result, alternatives=rival_guesses(nodes, angles, centre, p))
        return replace(result, tentative=tentative) if tentative else result


PYRAMIDS = ContentCache(size=4)
"""Likelihood pyramids of recent reference scans: a site's pairs share their references (every pair of
one round asked of the same scan), and a pyramid costs more than the search it serves."""


def reference_pyramid(reference: RangeScan, model: ReferenceModel, p: CorrelativeParams,
                      margin_m: float) -> LikelihoodPyramid:
    """The likelihood pyramid of ``reference`` for a search ``margin_m`` wide (kept in :data:`PYRAMIDS`)."""
    key = (scans_digest([reference]), margin_m, p.resolution_m, p.sigma_m, p.levels, p.free_space_margin_m,
           p.free_space_penalty)
    return PYRAMIDS.get(key, lambda: LikelihoodPyramid(model.points, p.resolution_m, p.sigma_m, margin_m, p.levels,
                                                       model.free, p.free_space_margin_m, p.free_space_penalty))


def pose_score(pyr: LikelihoodPyramid, points: np.ndarray, pose: np.ndarray) -> float:
    """The search's score of one pose: the mean likelihood under ``points`` (the moving scan's, in its
    own frame) placed by ``pose``."""
    cells = pyr.cells(transform(points, pose))[None]
    return float(pyr.score(0, cells, np.zeros((1, 2), dtype=np.int64), np.zeros(1, dtype=np.int64))[0])


def keeps_score(pyr: LikelihoodPyramid, points: np.ndarray, searched: np.ndarray, refined: np.ndarray,
                p: CorrelativeParams) -> bool:
    """Whether the refined pose scores at least what the search's optimum can lose to its lattice: the
    likelihood's fall over half a cell, ``exp(-(resolution / 2)^2 / (2 sigma^2))`` of the searched
    pose's score (module docstring). A refinement that loses more has left the search's peak for
    another fit of the point-to-line objective (a few walls of a partial overlap, matched to the wrong
    ones within the correspondence distance)."""
    fall = math.exp(-0.5 * (p.resolution_m / (2 * p.sigma_m)) ** 2)
    before = pose_score(pyr, points, searched)
    return pose_score(pyr, points, refined) >= before - (1.0 - fall) * abs(before)


def thinned(points: np.ndarray, cell_m: float) -> np.ndarray:
    """One point per ``cell_m`` square (the first in beam order): the search scores walls, not how densely
    the sonar happened to sample them near itself, and costs less."""
    if len(points) == 0:
        return points
    keys = np.floor(points / cell_m).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def search_half_width(reference: RangeScan, moving: RangeScan, p: CorrelativeParams) -> float:
    """Half-width of the global search square: ``search_m``, or the smaller sonar range of the pair
    (two stations farther apart than that rarely share walls) capped at ``max_search_m``."""
    if p.search_m is not None:
        return p.search_m
    return float(min(reference.max_range_m, moving.max_range_m, p.max_search_m))


def _rival(nodes: np.ndarray, scores: np.ndarray, angles: np.ndarray, p: CorrelativeParams,
           pyr: LikelihoodPyramid, points: np.ndarray):
    """The best far rival, as (distance m, angle deg, score, joined by a ridge), or ``None``."""
    d = np.hypot(nodes[:, 0] - nodes[0, 0], nodes[:, 1] - nodes[0, 1]) * p.resolution_m
    da = np.degrees(np.abs(angles[nodes[:, 2]] - angles[nodes[0, 2]]))
    far = np.flatnonzero(d > p.ambiguity_distance_m)
    if len(far) == 0:
        return None
    k = far[0]
    ridge = valley(pyr, points, angles, nodes[0], nodes[k]) >= p.valley_ratio * scores[0]
    return float(d[k]), float(da[k]), float(scores[k]), ridge


def rival_guesses(nodes: np.ndarray, angles: np.ndarray, centre: np.ndarray, p: CorrelativeParams,
                  limit: int = 3) -> tuple[MatchGuess, ...]:
    """Up to ``limit`` rival peaks of an ambiguous search (``MatchResult.alternatives``): among the nodes
    within ``ambiguity_ratio`` of the best (best first), each farther than ``ambiguity_distance_m`` from
    the estimate and from every better rival kept, as a guess of that half-width."""
    kept: list[np.ndarray] = [nodes[0]]
    out = []
    for node in nodes[1:]:
        if all(math.hypot(*(node[:2] - k[:2])) * p.resolution_m > p.ambiguity_distance_m for k in kept):
            kept.append(node)
            pose = compose(np.array([node[0] * p.resolution_m, node[1] * p.resolution_m, angles[node[2]]]), centre)
            out.append(MatchGuess(float(pose[0]), float(pose[1]), float(pose[2]), p.ambiguity_distance_m))
            if len(out) == limit:
                break
    return tuple(out)


def valley(pyr: LikelihoodPyramid, points: np.ndarray, angles: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Lowest score on the straight path between nodes ``a`` and ``b`` (each path point scored at the
    best yaw within two steps of the yaws of ``a`` and ``b``)."""
    lo = max(0, min(a[2], b[2]) - 2)
    hi = min(len(angles), max(a[2], b[2]) + 3)
    sub = angles[lo:hi]
    c, s = np.cos(sub)[:, None], np.sin(sub)[:, None]
    cells = pyr.cells(np.stack([c * points[:, 0] - s * points[:, 1], s * points[:, 0] + c * points[:, 1]], axis=-1))
    n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1])))
    t = np.linspace(0.0, 1.0, max(n, 2) + 1)[1:-1]
    path = np.rint(a[:2] + t[:, None] * (b[:2] - a[:2])).astype(np.int64)
    offsets = np.repeat(path, len(sub), axis=0)
    idx = np.tile(np.arange(len(sub)), len(path))
    sc = pyr.score(0, cells, offsets, idx).reshape(len(path), len(sub)).max(axis=1)
    return float(sc.min()) if len(sc) else float("inf")


def _result(pose: np.ndarray, score: float, converged: bool, reason: str, iterations: int, start: float,
            covariance: np.ndarray | None = None, confidence: float | None = None) -> MatchResult:
    return MatchResult(i=-1, j=-1, dx_m=float(pose[0]), dy_m=float(pose[1]), dyaw_rad=float(pose[2]),
                       weight=score, converged=converged, iterations=iterations,
                       seconds=time.perf_counter() - start, reason=reason, covariance=covariance,
                       confidence=confidence)
