"""Where one group of placed scans lies in another's frame: a global, two-sided search over the walls
and the water both groups saw (site-graph's join across a break of the survey's chain).

A station in a tunnel or at its mouth shares only a few metres of wall with any single station of the
next chamber, too little for a pair-wise match to tell the right place from a look-alike one. The
scans already joined on each side of the break see much more together: every wall of their chamber
and, as important, all the water in it. This module matches the two groups as wholes, as a SLAM
system matches a scan against a submap instead of against its last scan (Hess et al., ICRA 2016), with
a score that uses both kinds of evidence both ways:

* **walls that agree**: a wall point of one group on a wall of the other, *seen from the same side*
  (each point carries the normal of its wall turned towards the sonar that heard it; a wall is heard
  only from the water in front of it, so two look-alike chambers laid back to back share no wall);
* **walls in water**: a wall point of one group where a sonar of the other saw open water (its free
  space, :class:`~cistern_plugins.alignment.FreeSpace`) costs ``free_penalty`` times what an agreeing
  point gains. Such a conflict is near impossible when the placement is right, so it must outweigh
  agreement: with an even trade, one chamber laid inside another wins on the walls it happens to share.

The score of placing group B by ``T`` in group A's frame is::

    S(T) = sum_{b in B} L_A(T b) + sum_{a in A} L_B(T^-1 a)

over the occupied cells of each group (a wall seen by several stations counts once), with ``L_G`` the
likelihood field of group G's walls of matching orientation, ``exp(-d^2 / 2 sigma^2)``, minus
``free_penalty`` in G's free space and zero in space G never saw. Beams that heard no wall saw water
(:func:`~cistern_plugins.alignment.silent_water`): a run of them 20° wide or wider out to 0.75 of the
range, no farther than the receiver's noise let it hear, a narrower one out to the farther of the
echoes on either side (a wall met at grazing incidence answers too faintly); and no wall stands where a
vehicle floated. The compasses
add a prior on the turn between the two frames (:class:`CompassPrior`). For every yaw of the window
both sums are cross-correlations over all translations at once (FFT), as in the correlative matching
of Olson (ICRA 2009) with the second, reverse sum added; the best pose is then refined by a direct
local search of the same score on fields twice as fine with orientations twice as narrow
(:class:`FineScore`), polished by point-to-line ICP of walls seen from the same side, and given the
covariance of the score's curvature (:func:`score_covariance`).

A placement is accepted (:func:`accept`) when it is clearly best: its score reaches ``min_score`` (in
cells of wall, about ``cell_m`` of wall each) and keeps ``min_refined_share`` of it once refined (a
peak of the coarser search that the sharper refinement does not confirm is no peak; where it keeps less
than ``confirm_share``, every peak of the search is refined and the one that scores best there is the fit,
clearly best if it is not the search's own, :func:`choose_refined`), the best pose
farther than ``separation_m`` away scores at most ``ambiguity_ratio`` of it (a rival that lays more wall
than the best into water either group saw pays for it at a heavier penalty, :func:`credible_rival`: two
chambers of one shape laid on each other is no alternative to their true places), and neither group is a
tunnel seen from inside (two parallel walls fit every passage of their width,
:func:`~cistern_plugins.group_clouds.wall_spread`). site-graph then puts the join to its own wall check
(no stretch of wall across water, walls not in the water of the other scans) before it merges the
groups.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy import fft
from scipy.spatial import cKDTree

from cistern_archive.core.scan import RangeScan
from cistern_plugins.alignment import compose, point_to_line_step, rotate, transform
from cistern_plugins.group_clouds import BORDER_M, ORIENTATIONS, Cloud, Raster, bounds, cell_centres
from cistern_plugins.sonar_scale import scaled_lengths

SCORE_TEMPERATURE = 4.0
"""Cells of score per unit of log-likelihood when the score's curvature becomes a covariance."""
MAX_SIGMA = 5.0
"""The widest standard deviation a fit's covariance takes along any direction, in metres for a
translation and degrees for a turn (the score's curvature is floored there, so that a direction the
score cannot tell apart keeps a finite, wide sigma)."""
POLISH_TOLERANCE = 1.0
"""The point-to-line polish is kept unless it loses more than this (cells of wall) of the score."""


@dataclass(frozen=True)
class GroupFitSettings:
    """The search's settings (site-graph's ``group_*`` parameters).

    Its lengths (``cell_m``, ``sigma_m``, ``separation_m``) and the module's (the refinement's reach, the
    covariance's probes, :data:`PROFILE_FROM_M`, :data:`PROFILE_STEPS_M`, :data:`OUTLYING_M`, the clouds'
    border) are written for the calibration sonar; ``unit`` is how many metres of the site one of them
    is (:meth:`at_unit`, :func:`~cistern_plugins.sonar_scale.site_length_unit`). Scores count cells, so
    a site ``unit`` times as large scores as the calibration site did.
    """

    cell_m: float = 0.1
    sigma_m: float = 0.1
    yaw_window_deg: float = 6.0
    compass_sigma_deg: float = 2.0
    yaw_step_deg: float = 1.0
    free_penalty: float = 5.0
    min_score: float = 30.0
    min_spread: float = 0.1
    min_refined_share: float = 0.2
    confirm_share: float = 0.3
    ambiguity_ratio: float = 0.8
    separation_m: float = 0.5
    rivals: int = 4
    rival_free_penalty: float = 20.0
    unit: float = 1.0

    def at_unit(self, unit: float) -> "GroupFitSettings":
        """These settings with their lengths ``unit`` times as long (itself when ``unit`` is 1)."""
        if unit == 1.0:
            return self
        return replace(scaled_lengths(self, unit), unit=self.unit * unit)


@dataclass(frozen=True)
class GroupFit:
    """The best placement of group B in group A's frame and its rival.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        ``(x, y, theta)``: B's frame in A's frame (``q_A = R(theta) q_B + (x, y)``).
    score : float
        ``S`` at the refined pose, in coarse cells (module docstring), without the compass prior.
    rival : float
        The best coarse score of a pose farther than ``separation_m`` from the best, less what its walls
        in water cost beyond the best's (:func:`credible_rival`).
    best_coarse : float
        The best coarse score (the rival's yardstick).
    refined_rival : float
        Where the refinement kept less than ``confirm_share`` of the search's best score: the best refined
        score of the search's other peaks, judged as :meth:`Peak.credible` against the fit; else ``-inf``
        (not asked).
    chosen_by_refinement : bool
        The fit is another peak of the search than its best, chosen by its refined score
        (:func:`choose_refined`).
    covariance : ndarray, shape (3, 3)
        Of ``pose``, the turn about B's origin (:func:`score_covariance`).
    """

    pose: np.ndarray
    score: float
    rival: float
    best_coarse: float
    covariance: np.ndarray
    refined_rival: float = -math.inf
    chosen_by_refinement: bool = False


@dataclass(frozen=True)
class CompassPrior:
    """What the compasses say of the turn between two groups' frames: each frame is the compass frame of
    its scans less their mean heading correction, each compass reading with ``compass_sigma_deg`` of
    noise; as a penalty on the score in its own units (``SCORE_TEMPERATURE`` cells per unit of
    log-likelihood)."""

    mean: float
    sigma: float

    @classmethod
    def of(cls, a: Cloud, b: Cloud, s: GroupFitSettings) -> "CompassPrior":
        sigma = math.radians(s.compass_sigma_deg) * math.sqrt(1.0 / max(len(a.turns), 1) + 1.0 / max(len(b.turns), 1))
        return cls(float(np.mean(a.turns) - np.mean(b.turns)) if len(a.turns) and len(b.turns) else 0.0, sigma)

    def penalty(self, turn: np.ndarray) -> np.ndarray:
        return SCORE_TEMPERATURE * 0.5 * ((np.asarray(turn) - self.mean) / self.sigma) ** 2


def coarse_scores(a: Cloud, b: Cloud, s: GroupFitSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                                  tuple[int, int]]:
    """``S`` on the coarse grid of every yaw of the window: (scores (Y, H, W), yaws, A's grid origin,
    B's grid origin, A's grid shape); translation index ``k`` is ``t = k * cell + lo_A - lo_B``, with
    ``k`` from ``-(B's side - 1)`` to A's shape less one, negative ones wrapped."""
    lo_a, shape_a = bounds(a.points, s.cell_m, s.unit)
    reach = float(np.hypot(b.points[:, 0], b.points[:, 1]).max()) + BORDER_M * s.unit
    lo_b = np.array([-reach, -reach])
    side = int(math.ceil(2 * reach / s.cell_m)) + 1
    shape_b = (side, side)
    shape = (fft.next_fast_len(shape_a[0] + side), fft.next_fast_len(shape_a[1] + side, real=True))
    ra = Raster(a, lo_a, shape_a, s.cell_m, s.sigma_m, s.free_penalty)
    fa_field = fft.rfft2(ra.field, s=shape, axes=(1, 2))
    fa_occupied = fft.rfft2(ra.occupied, s=shape, axes=(1, 2))
    half = s.yaw_window_deg
    prior = CompassPrior.of(a, b, s)
    yaws = prior.mean + (np.radians(np.arange(-half, half + 1e-9, s.yaw_step_deg)) if s.yaw_step_deg > 0 else np.zeros(1))
    out = np.empty((len(yaws), *shape))
    for y, yaw in enumerate(yaws):
        rb = Raster(b, lo_b, shape_b, s.cell_m, s.sigma_m, s.free_penalty, rotation=float(yaw))
        spectrum = (fa_field * np.conj(fft.rfft2(rb.occupied, s=shape, axes=(1, 2)))
                    + fa_occupied * np.conj(fft.rfft2(rb.field, s=shape, axes=(1, 2)))).sum(axis=0)
        out[y] = fft.irfft2(spectrum, s=shape) - prior.penalty(yaw)
    return out, yaws, lo_a, lo_b, shape_a


def distinct_peaks(scores: np.ndarray, yaws: np.ndarray, lo_a: np.ndarray, lo_b: np.ndarray, shape_a: tuple[int, int],
                   s: GroupFitSettings, count: int = 2) -> list[tuple[float, np.ndarray]]:
    """The best ``count`` coarse poses at least ``separation_m`` apart (at any yaw), as (score, pose)."""
    work = scores.copy()
    shape = work.shape[1:]
    radius = int(math.ceil(s.separation_m / s.cell_m))
    out = []
    for _ in range(count):
        y, r, c = np.unravel_index(int(np.argmax(work)), work.shape)
        value = float(work[y, r, c])
        if not math.isfinite(value):
            break
        k = np.array([c if c < shape_a[1] else c - shape[1], r if r < shape_a[0] else r - shape[0]])
        out.append((value, np.array([*(k * s.cell_m + lo_a - lo_b), yaws[y]])))
        dr = (np.arange(shape[0]) - r + shape[0] // 2) % shape[0] - shape[0] // 2
        dc = (np.arange(shape[1]) - c + shape[1] // 2) % shape[1] - shape[1] // 2
        work[:, (np.abs(dr)[:, None] <= radius) & (np.abs(dc)[None, :] <= radius)] = -np.inf
    return out


class FineScore:
    """``S`` evaluated pose by pose on fields twice as fine as the search's, read bilinearly."""

    def __init__(self, a: Cloud, b: Cloud, s: GroupFitSettings):
        fine = 0.5 * s.cell_m
        lo_a, shape_a = bounds(a.points, fine, s.unit)
        lo_b, shape_b = bounds(b.points, fine, s.unit)
        self.ra = Raster(a, lo_a, shape_a, fine, 0.5 * s.sigma_m, s.free_penalty, bins=2 * ORIENTATIONS)
        self.rb = Raster(b, lo_b, shape_b, fine, 0.5 * s.sigma_m, s.free_penalty, bins=2 * ORIENTATIONS)
        self.pa, self.bins_a = cell_centres(self.ra)
        self.pb, self.bins_b = cell_centres(self.rb)
        self.prior = CompassPrior.of(a, b, s)

    def __call__(self, poses: np.ndarray, *, prior: bool = True) -> np.ndarray:
        """Scores of poses (M, 3), in coarse cells of wall (fine cells are half as long), less the
        compass prior's penalty unless ``prior`` is false."""
        return self.both_ways(poses, self.ra.field, self.rb.field) - (self.prior.penalty(poses[:, 2]) if prior else 0.0)

    def conflict(self, poses: np.ndarray) -> np.ndarray:
        """How much wall of either group lies where the other's sonars saw water, at poses (M, 3): cells
        of wall in the same units as the score (what the free-space penalty is paid on)."""
        return self.both_ways(poses, self.ra.free, self.rb.free)

    def both_ways(self, poses: np.ndarray, layer_a: np.ndarray, layer_b: np.ndarray) -> np.ndarray:
        """Half the sum, at each pose, of ``layer_a`` (A's raster) under B's wall cells placed by the pose
        and of ``layer_b`` under A's cells taken back into B's frame."""
        out = np.empty(len(poses))
        for lo in range(0, len(poses), 64):
            chunk = poses[lo:lo + 64]
            c, sn = np.cos(chunk[:, 2])[:, None], np.sin(chunk[:, 2])[:, None]
            bx = c * self.pb[None, :, 0] - sn * self.pb[None, :, 1] + chunk[:, 0, None]
            by = sn * self.pb[None, :, 0] + c * self.pb[None, :, 1] + chunk[:, 1, None]
            s1 = self.ra.sample(np.stack([bx, by], axis=-1), self.bins_b[None, :], layer_a).sum(axis=1)
            ax, ay = self.pa[None, :, 0] - chunk[:, 0, None], self.pa[None, :, 1] - chunk[:, 1, None]
            back = np.stack([c * ax + sn * ay, -sn * ax + c * ay], axis=-1)
            s2 = self.rb.sample(back, self.bins_a[None, :], layer_b).sum(axis=1)
            out[lo:lo + 64] = 0.5 * (s1 + s2)
        return out


def local_grid(pose: np.ndarray, step_m: float, turn_rad: float, half: int = 4, turns: int = 2) -> np.ndarray:
    """Poses around ``pose``: ``±half`` steps of ``step_m`` in x and y, ``±turns`` steps of ``turn_rad``."""
    d = np.arange(-half, half + 1) * step_m
    t = np.arange(-turns, turns + 1) * turn_rad
    dx, dy, dt = np.meshgrid(d, d, t, indexing="ij")
    return np.column_stack([pose[0] + dx.ravel(), pose[1] + dy.ravel(), pose[2] + dt.ravel()])


def refine(score: FineScore, pose: np.ndarray, s: GroupFitSettings) -> tuple[np.ndarray, float]:
    """The best pose of the fine score around a coarse one: ±2 coarse cells and ±1 yaw step, then a grid
    four times finer around the best of those; with its score."""
    for step, turn in ((0.5 * s.cell_m, 0.5 * s.yaw_step_deg), (0.125 * s.cell_m, 0.125 * s.yaw_step_deg)):
        grid = local_grid(pose, step, math.radians(turn))
        values = score(grid)
        k = int(np.argmax(values))
        pose, best = grid[k], float(values[k])
    return pose, best


REFINE_RADIUS_M = 0.3
"""The point-to-line polish pairs a wall point with walls of the other group this close."""


def refine_icp(a: Cloud, b: Cloud, pose: np.ndarray, *, iterations: int = 30, radius_m: float = REFINE_RADIUS_M,
               trim_fraction: float = 0.8) -> np.ndarray:
    """``pose`` polished by trimmed point-to-line ICP of B's walls onto A's walls seen from the same side
    (normals within 67.5°), as the correlative matcher polishes its grid estimate."""
    tree = cKDTree(a.points)
    agree = math.cos(math.radians(67.5))
    pose = np.asarray(pose, dtype=np.float64).copy()
    for _ in range(iterations):
        moved = transform(b.points, pose)
        turned = rotate(b.normals, pose[2])
        dist, idx = tree.query(moved, k=4, distance_upper_bound=radius_m)
        found = idx < len(a.points)
        safe = np.where(found, idx, 0)
        same = found & (np.einsum("ij,ikj->ik", turned, a.normals[safe]) > agree)
        first = np.argmax(same, axis=1)
        ok = same[np.arange(len(moved)), first]
        if ok.sum() < 10:
            break
        pick = safe[np.arange(len(moved)), first][ok]
        d = dist[np.arange(len(moved)), first][ok]
        keep = d <= np.quantile(d, trim_fraction)
        src, dst, normals = moved[ok][keep], a.points[pick][keep], a.normals[pick][keep]
        step = point_to_line_step(src, dst, normals)
        pose = compose(step, pose)
        if math.hypot(step[0], step[1]) < 1e-4 and abs(step[2]) < 1e-5:
            break
    return pose


@dataclass(frozen=True)
class Peak:
    """One peak of the search, refined: its coarse score and pose, its refined pose, its refined score
    without the compass prior (as :attr:`GroupFit.score`) and the wall it lays in water there
    (:meth:`FineScore.conflict`)."""

    coarse: float
    coarse_pose: np.ndarray
    pose: np.ndarray
    score: float
    conflict: float

    @classmethod
    def refined(cls, a: Cloud, b: Cloud, fine: FineScore, peak: tuple[float, np.ndarray], s: GroupFitSettings,
                polish: bool = True) -> "Peak":
        """``peak`` (coarse score, pose) refined on the fine fields (:func:`refine`) and, with ``polish``,
        by point-to-line ICP unless that loses more than :data:`POLISH_TOLERANCE` of the score."""
        pose, score = refine(fine, peak[1], s)
        if polish:
            polished = refine_icp(a, b, pose, radius_m=REFINE_RADIUS_M * s.unit)
            if float(fine(polished[None, :])[0]) >= score - POLISH_TOLERANCE:
                pose = polished
        return cls(peak[0], peak[1], pose, float(fine(pose[None, :], prior=False)[0]),
                   float(fine.conflict(pose[None, :])[0]))

    def excess_conflict(self, against: "Peak", s: GroupFitSettings) -> float:
        """``rival_free_penalty - free_penalty`` per cell of wall laid in water beyond what ``against``
        lays there."""
        return (s.rival_free_penalty - s.free_penalty) * max(0.0, self.conflict - against.conflict)

    def credible(self, against: "Peak", s: GroupFitSettings) -> float:
        """The refined score less :meth:`excess_conflict` (as :func:`credible_rival` judges a coarse
        score)."""
        return self.score - self.excess_conflict(against, s)


def fit_groups(a: Cloud, b: Cloud, s: GroupFitSettings) -> GroupFit | None:
    """The best placement of cloud ``b`` in ``a``'s frame and its rival, or ``None`` when either is empty.

    A peak of the search that keeps less than ``confirm_share`` of its score once refined may owe its
    rank to the coarse fields' blur; then every peak of the search is refined, and the one that scores
    best on the sharper fields, judged as :meth:`Peak.credible`, is the fit (:func:`choose_refined`)."""
    if len(a.points) < 3 or len(b.points) < 3:
        return None
    scores, yaws, lo_a, lo_b, shape_a = coarse_scores(a, b, s)
    peaks = distinct_peaks(scores, yaws, lo_a, lo_b, shape_a, s, count=1 + s.rivals)
    if not peaks:
        return None
    fine = FineScore(a, b, s)
    best = Peak.refined(a, b, fine, peaks[0], s)
    spread = outlying_spread(scores, lo_a - lo_b, shape_a, s, best.coarse_pose)
    if best.score < s.confirm_share * best.coarse:
        return choose_refined(a, b, fine, best, peaks[1:], s, spread)
    covariance = score_covariance(fine, best.pose, s.unit)
    covariance[:2, :2] += spread
    rivals = (Peak.refined(a, b, fine, rival, s, polish=False) for rival in peaks[1:])
    return GroupFit(pose=best.pose, score=best.score, rival=credible_rival(rivals, best, s), best_coarse=best.coarse,
                    covariance=covariance)


def choose_refined(a: Cloud, b: Cloud, fine: FineScore, best: Peak, rivals: Sequence[tuple[float, np.ndarray]],
                   s: GroupFitSettings, spread: np.ndarray) -> GroupFit:
    """The fit among the search's peaks (``best``, refined, and ``rivals``) that scores best once each is
    refined, judged as :meth:`Peak.credible` against ``best``; its :attr:`GroupFit.refined_rival` is the
    best of the others judged against it. ``spread`` is the search's :func:`outlying_spread` about
    ``best``, kept when ``best`` stays the fit; a peak chosen over it instead takes the spread of the other
    refined peaks about itself (:func:`refined_spread`), as the search's mass lies around a peak the
    refinement did not confirm.

    One lone station was laid 12 m off in a chamber that shared no wall with it, at a refined 13.6 of its
    search's 65, while two of the search's other peaks, refined, scored 17.1 and 17.6 (seed 125
    ``cistern-036``); a chamber's search peaked at 81 where, refined, it laid 43 cells of wall in water
    and scored −7.3, 6.3 m from the true place, whose peak scored 68 in the search and 49.3 refined
    (seed 128 ``cistern-018``)."""
    peaks = [best] + [Peak.refined(a, b, fine, rival, s, polish=False) for rival in rivals]
    k = max(range(len(peaks)), key=lambda n: peaks[n].credible(best, s))
    top, others = peaks[k], peaks[:k] + peaks[k + 1:]
    if k > 0:
        top = Peak.refined(a, b, fine, (top.coarse, top.coarse_pose), s)
        spread = refined_spread(top, others, s)
    covariance = score_covariance(fine, top.pose, s.unit)
    covariance[:2, :2] += spread
    rival = credible_rival(others, top, s)
    return GroupFit(pose=top.pose, score=top.score, rival=rival, best_coarse=top.coarse, covariance=covariance,
                    refined_rival=max((p.credible(top, s) for p in others), default=-math.inf),
                    chosen_by_refinement=k > 0)


def refined_spread(top: Peak, others: Sequence[Peak], s: GroupFitSettings) -> np.ndarray:
    """The translation covariance (2 × 2) the other refined peaks add to ``top``, as
    :func:`outlying_spread` reads the search's mass: each peak farther than :data:`OUTLYING_M` from it
    weighs ``exp((S - S_top) / SCORE_TEMPERATURE)`` with ``S`` judged as :meth:`Peak.credible`."""
    out = np.zeros((2, 2))
    total = 1.0
    for peak in others:
        weight = math.exp(min(0.0, peak.credible(top, s) - top.score) / SCORE_TEMPERATURE)
        total += weight
        t = peak.pose[:2] - top.pose[:2]
        if math.hypot(*t) > OUTLYING_M * s.unit:
            out += weight * np.outer(t, t)
    return out / total


def credible_rival(rivals: Iterable[Peak], best: Peak, s: GroupFitSettings) -> float:
    """The coarse score of the best rival place (``rivals``: the search's next peaks, best first,
    :func:`distinct_peaks`, each refined as a :class:`Peak`) once each pays for the walls it lays in water
    beyond what ``best`` lays there, at ``rival_free_penalty`` instead of the search's ``free_penalty``
    per cell (:meth:`Peak.excess_conflict`). Only rivals above ``ambiguity_ratio`` of the best could make
    the fit ambiguous; the first one under it keeps its coarse score unjudged, as every one after it would stay under it.

    The search's penalty keeps one chamber from being laid inside another on the walls they share, but
    two chambers of one shape laid on each other agree on every wall and conflict only where one's mouth
    meets the other's solid wall: on the tuning sites (seed 4 ``cistern-026``) such an overlay scored 233
    against the right place's 239, with 45 cells of wall in water against its 1.6, and the fit was
    refused as ambiguous. A place that puts walls where the other group's sonars saw water is
    no likely alternative; a rival that does not (another look-alike of the same quality) keeps its
    score. Each rival is refined (:func:`refine`), as the best is, so that both are judged at their own
    peaks; ``rivals`` may be a generator, so that only the rivals reached are refined. The best place
    itself is chosen as before: scoring every place at the heavier
    penalty, or choosing the best by it, accepted fewer right fits on the tuning seeds.
    """
    out = 0.0
    for peak in rivals:
        if peak.coarse <= s.ambiguity_ratio * best.coarse:
            return max(out, peak.coarse)
        out = max(out, peak.coarse - peak.excess_conflict(best, s))
    return out


def accept(fit: GroupFit | None, s: GroupFitSettings, spreads: tuple[float, float] = (1.0, 1.0)) -> str:
    """Empty when ``fit`` is clear enough to join two groups (module docstring), else why not.

    ``spreads`` are the two groups' :func:`wall_spread`: a group whose walls all run one way (a station
    inside a tunnel sees two parallel walls and little else) fits every passage of that width as well
    as its own, so it joins through its matches only."""
    if fit is None:
        return "no walls to match"
    if min(spreads) < s.min_spread:
        return (f"a group's walls all run one way (a tunnel seen from inside: spread {min(spreads):.2f} < "
                f"{s.min_spread:.2f}), which fits every passage of its width")
    if fit.best_coarse < s.min_score:
        return f"the two groups share too little wall: best score {fit.best_coarse:.0f} < {s.min_score:.0f}"
    if fit.score < s.min_refined_share * fit.best_coarse:
        return (f"the search's peak does not hold once refined: score {fit.score:.1f} against "
                f"{fit.best_coarse:.0f} in the search")
    if fit.chosen_by_refinement and fit.refined_rival > s.ambiguity_ratio * fit.score:
        return (f"ambiguous once refined: the search's peaks score {fit.score:.1f} and {fit.refined_rival:.1f} "
                f"on the sharper fields")
    if fit.refined_rival > fit.score:
        return (f"the search's peak does not hold once refined: score {fit.score:.1f} against "
                f"{fit.best_coarse:.0f} in the search, and another of its peaks scores {fit.refined_rival:.1f} "
                f"once refined")
    if fit.rival > s.ambiguity_ratio * fit.best_coarse:
        return (f"ambiguous: a place {s.separation_m:.1f} m or more away scores {fit.rival:.0f} against "
                f"the best {fit.best_coarse:.0f}")
    return ""


def score_covariance(score: FineScore, pose: np.ndarray, unit: float = 1.0) -> np.ndarray:
    """Covariance of a fit's pose from the curvature of its score (a Laplace approximation): a quadratic
    fitted to ``S`` over ±0.1 m and ±0.5° around ``pose``, read as a log-likelihood at
    ``SCORE_TEMPERATURE`` cells per unit. A direction the score cannot tell apart (along a tunnel seen
    from both ends) gets a wide sigma, up to :data:`MAX_SIGMA` (metres, degrees). The turn is about
    B's frame origin (``pose[:2]``), as ``pose`` turns B. Every length (the probes, :data:`MAX_SIGMA`'s
    metres, :data:`PROFILE_FROM_M`) is taken ``unit`` times as long."""
    d = np.arange(-2, 3) * 0.05 * unit
    t = np.radians(np.arange(-1, 2) * 0.5)
    dx, dy, dt = (v.ravel() for v in np.meshgrid(d, d, t, indexing="ij"))
    values = score(np.column_stack([pose[0] + dx, pose[1] + dy, pose[2] + dt]), prior=False)
    design = np.column_stack([np.ones_like(dx), dx, dy, dt, dx * dx, dy * dy, dt * dt, dx * dy, dx * dt, dy * dt])
    c = np.linalg.lstsq(design, values, rcond=None)[0]
    hessian = -np.array([[2 * c[4], c[7], c[8]], [c[7], 2 * c[5], c[9]], [c[8], c[9], 2 * c[6]]])
    scale = np.array([1.0 / unit, 1.0 / unit, 1.0 / math.radians(1.0)])  # units of length, degrees: comparable
    scaled = hessian / np.outer(scale, scale)
    vals, vecs = np.linalg.eigh(0.5 * (scaled + scaled.T))
    floor = SCORE_TEMPERATURE / MAX_SIGMA**2
    vals = np.maximum(vals, floor)
    for k in range(3):
        length = float(np.hypot(*vecs[:2, k]))
        if length > 0.9 and SCORE_TEMPERATURE / vals[k] > PROFILE_FROM_M**2:  # both in units of length
            sigma = profile_sigma(score, pose, vecs[:2, k] / length, unit) / unit
            vals[k] = max(vals[k], SCORE_TEMPERATURE / sigma**2)
    information = (vecs * vals) @ vecs.T * np.outer(scale, scale)
    cov = SCORE_TEMPERATURE * np.linalg.inv(information)
    return 0.5 * (cov + cov.T)


PROFILE_FROM_M = 0.2
"""A direction whose curvature leaves a sigma above this is read from the score's profile instead
(:func:`profile_sigma`)."""
PROFILE_STEPS_M = (0.2, 0.4, 0.8, 1.6, 3.2)


def profile_sigma(score: FineScore, pose: np.ndarray, direction: np.ndarray, unit: float = 1.0) -> float:
    """The sigma (m) of a fit along a direction its peak's curvature cannot resolve, from the score's
    profile along it.

    A tunnel seen from inside is flat over ±0.1 m along its axis, but its mouths and the chambers beyond
    make the score fall farther out. Stepping out both ways by :data:`PROFILE_STEPS_M`, the first step
    ``d`` at which the smaller of the two drops reaches half a unit of log-likelihood gives the sigma of
    a Gaussian falling so (``d * sqrt(T / (2 dS))``), but never less than the flat stretch before it
    (uniform over ``±d_prev``: ``d_prev / sqrt(3)``); :data:`MAX_SIGMA` when the score never falls. The
    steps and :data:`MAX_SIGMA` are taken ``unit`` times as long.
    """
    steps = np.asarray(PROFILE_STEPS_M) * unit
    most = MAX_SIGMA * unit
    offsets = np.concatenate([steps, -steps])[:, None] * np.asarray(direction)[None, :]
    probes = np.column_stack([pose[:2] + offsets, np.full(len(offsets), pose[2])])
    values = score(np.vstack([pose[None, :], probes]), prior=False)
    drops = values[0] - np.maximum(values[1:len(steps) + 1], values[len(steps) + 1:])
    flat = 0.0
    for d, drop in zip(steps, drops):
        if drop >= 0.5 * SCORE_TEMPERATURE:
            return min(most, max(d * math.sqrt(SCORE_TEMPERATURE / (2.0 * drop)), flat / math.sqrt(3.0)))
        flat = d
    return most


OUTLYING_M = 0.25
"""Coarse poses farther than this from the best are outside its peak (:func:`outlying_spread`): the
curvature's quadratic reads ±0.1 m, and a peak's cells fall off within two cells."""


def outlying_spread(scores: np.ndarray, offset: np.ndarray, shape_a: tuple[int, int], s: GroupFitSettings,
                    best: np.ndarray) -> np.ndarray:
    """The translation covariance (2 × 2) the search's other good places add to a fit's peak.

    The curvature of the score (:func:`score_covariance`) describes the peak itself; the coarse search
    may also score well elsewhere — a second peak under the ambiguity ratio, a ridge along a tunnel both
    groups see end to end. Read as a likelihood (``exp(S / SCORE_TEMPERATURE)``, as the curvature is),
    the whole search window gives the probability mass of each place; the mass farther than
    :data:`OUTLYING_M` from the best, with its squared offsets, is what the peak's own covariance leaves
    out (the correlative matcher's covariance of Olson, ICRA 2009, over the window, less the peak
    already counted).

    Parameters
    ----------
    scores : ndarray, shape (Y, H, W)
        The coarse scores (:func:`coarse_scores`) with translation ``k * cell + offset``.
    offset : ndarray, shape (2,)
        ``lo_A - lo_B``.
    shape_a : (int, int)
        A's grid shape (the wrap of negative indices).
    s : GroupFitSettings
    best : ndarray, shape (3,)
        The best coarse pose.
    """
    top = float(scores.max())
    yaw, rows, cols = np.nonzero(scores > top - SCORE_TEMPERATURE * math.log(1e4))
    h, w = scores.shape[1:]
    k = np.column_stack([np.where(cols < shape_a[1], cols, cols - w), np.where(rows < shape_a[0], rows, rows - h)])
    t = k * s.cell_m + offset - np.asarray(best[:2], dtype=np.float64)
    weight = np.exp((scores[yaw, rows, cols] - top) / SCORE_TEMPERATURE)
    far = np.hypot(t[:, 0], t[:, 1]) > OUTLYING_M * s.unit
    return (weight[far, None, None] * (t[far, :, None] * t[far, None, :])).sum(axis=0) / weight.sum()


def about(cov: np.ndarray, pose: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """A pose covariance with its turn about ``pose[:2]`` re-expressed with the turn about ``pivot``."""
    arm = np.asarray(pivot, dtype=np.float64) - np.asarray(pose[:2], dtype=np.float64)
    m = np.array([[1.0, 0.0, -arm[1]], [0.0, 1.0, arm[0]], [0.0, 0.0, 1.0]])
    return m @ cov @ m.T


def pose_key(poses: Sequence[np.ndarray]) -> bytes:
    """The exact poses of a group, as a cache key: a fit is reused only for the very same inputs, so a
    cached and a computed fit are the same bytes and rebuilds stay reproducible."""
    return np.ascontiguousarray(np.asarray(poses, dtype=np.float64)).tobytes()
