"""Rigid 2-D alignment of range scans and the honest-convergence test shared by the point matchers.

Conventions follow :mod:`cistern_archive.pipeline.contracts`: a pose ``(x, y, theta)`` maps a moving
scan's points (map-oriented with its compass yaw, relative to its own station) into the reference
scan's frame as ``q = R(theta) p + (x, y)``; then ``(x, y)`` is ``p_moving - p_reference`` and ``theta``
the yaw correction of the moving scan.

The convergence test (:func:`assess_alignment`, :func:`verdict`) asks four questions of a final pose:
do enough moving points land on reference walls (inlier count and ratio among the points that fall
inside the reference sonar's range), do the matched walls constrain both translation directions (the
smaller eigenvalue of the point-to-line information matrix, per inlier, must reach ``min_constraint``
— a straight featureless corridor fails it — and the predicted standard deviation along the weakest
direction must stay below ``max_weak_std_m``), and is the placement physically possible: a wall point of one scan must not lie
in the free space the other sonar saw in front of its own echo on that bearing (the free-space
violation ratio, checked both ways, and no stretch of wall longer than ``max_violation_run_m`` in the
other's water or turned towards it where it heard nothing: :func:`longest_run_m`,
:meth:`FreeSpace.unheard_facing`), and a wall is not shared from behind (:func:`seen_from_behind`:
two look-alike rooms laid back to back). Two scans of different places can share many near points by
chance; they rarely avoid each other's free space.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from pydantic import Field

from cistern_archive.core.scan import wrap_angle
from cistern_archive.core.scan import RangeScan
from cistern_plugins.sonar_scale import SonarScaled


def scan_points(scan: RangeScan) -> np.ndarray:
    """Echo points of a scan, map-oriented by its compass yaw, relative to its station, shape (N, 2)."""
    return scan.points()


def transform(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Apply ``q = R(theta) p + t`` to points (N, 2); ``pose`` is (x, y, theta)."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return points @ np.array([[c, s], [-s, c]]) + pose[:2]


def transform_many(points: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Apply K poses (K, 3) to the same points (N, 2); returns (K, N, 2)."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = c * points[None, :, 0] - s * points[None, :, 1] + poses[:, 0, None]
    y = s * points[None, :, 0] + c * points[None, :, 1] + poses[:, 1, None]
    return np.stack([x, y], axis=-1)


def compose(delta: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """The pose that applies ``pose`` first and then ``delta`` (both in the reference frame)."""
    c, s = math.cos(delta[2]), math.sin(delta[2])
    t = np.array([c * pose[0] - s * pose[1], s * pose[0] + c * pose[1]]) + delta[:2]
    return np.array([t[0], t[1], pose[2] + delta[2]])


def kabsch_2d(src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted least-squares rigid transform (x, y, theta) taking ``src`` onto ``dst`` (Arun et al. 1987)."""
    w = np.ones(len(src)) if weights is None else weights
    w = w / w.sum()
    ms, md = w @ src, w @ dst
    a, b = src - ms, dst - md
    sxx = w @ (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])
    sxy = w @ (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    theta = math.atan2(sxy, sxx)
    c, s = math.cos(theta), math.sin(theta)
    t = md - np.array([c * ms[0] - s * ms[1], s * ms[0] + c * ms[1]])
    return np.array([t[0], t[1], theta])


def point_to_line_step(src: np.ndarray, dst: np.ndarray, normals: np.ndarray,
                       weights: np.ndarray | None = None) -> np.ndarray:
    """One linearised point-to-line step (Censi 2008 without the closed form): the small (x, y, theta)
    minimising ``sum w (n . (R p + t - q))^2``."""
    w = np.ones(len(src)) if weights is None else weights
    cross = src[:, 0] * normals[:, 1] - src[:, 1] * normals[:, 0]
    jac = np.column_stack([normals, cross])
    res = np.einsum("ij,ij->i", src - dst, normals)
    h = jac.T @ (jac * w[:, None]) + 1e-9 * np.eye(3)
    return -np.linalg.solve(h, jac.T @ (w * res))


def estimate_normals(points: np.ndarray, tree: cKDTree, k: int = 10) -> np.ndarray:
    """Unit wall normals of points from the principal axis of their ``k`` nearest neighbours."""
    k = min(k, len(points))
    _, idx = tree.query(points, k=k)
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    return vecs[:, :, 0]


def robust_error(distances: np.ndarray, kind: str, scale: float) -> np.ndarray:
    """Robust per-point error rho(d) for ``truncated`` (min(d, c)^2) or ``huber``, along the last axis."""
    if kind == "truncated":
        return np.minimum(distances, scale) ** 2
    if kind == "huber":
        return np.where(distances <= scale, distances**2, scale * (2 * distances - scale))
    raise ValueError(f"unknown robust error {kind!r}")


@dataclass(frozen=True)
class AlignmentQuality:
    """How well a moving scan, placed by a pose, fits the reference scan."""

    inliers: int
    candidates: int
    n_points: int
    rms_m: float
    constraint: float
    violation_ratio: float = 0.0
    violation_min: float = 0.0
    """The smaller of the two directions' violation ratios (``violation_ratio`` is the larger)."""
    behind: int = 0
    """Moving points on reference walls that the two sonars see from opposite sides, left out of the
    inliers (:data:`BEHIND_SHARE`)."""
    violation_run_m: float = 0.0
    """The longest stretch of one scan's wall (metres along its consecutive wall points) lying in the
    other scan's free space, the larger of the two directions (:func:`longest_run_m`)."""
    point_weight: float = 1.0
    """How many points at :data:`CALIBRATION_STEP_DEG` each point stands for (:func:`point_weight`)."""
    line_rms_m: float = math.inf
    """RMS of the inliers' distances to the reference wall's line (along its normal). ``rms_m`` is to
    the nearest reference *point*, and so also measures how far apart the reference's points lie (about
    ``s / sqrt(12)`` for points ``s`` apart): a scan of coarser steps reads rougher though its walls fit
    as well. The verification's statistics use this one."""

    @property
    def equivalent_inliers(self) -> float:
        """The inliers counted as points at :data:`CALIBRATION_STEP_DEG`: what the inlier limits and
        the calibrated verification were set on."""
        return self.inliers * self.point_weight

    @property
    def weak_std_m(self) -> float:
        """Predicted standard deviation of the translation along its weakest direction:
        ``rms / sqrt(lambda_min * inliers)`` (point-to-line Gauss-Newton, Censi 2007), with the
        point-to-line RMS (:attr:`line_rms_m`) and the inliers counted at :data:`CALIBRATION_STEP_DEG`
        (:attr:`equivalent_inliers`)."""
        info = self.constraint * self.equivalent_inliers
        return self.line_rms_m / math.sqrt(info) if info > 0 else math.inf

    @property
    def inlier_ratio(self) -> float:
        """Inliers among the moving points inside the reference sonar's range."""
        return self.inliers / self.candidates if self.candidates else 0.0


CALIBRATION_STEP_DEG = 0.9
"""The head's step between beams in the scans every count-based limit (``min_inliers``,
``max_weak_std_m``) and the calibrated verification were set on: the physical simulator's default."""


def point_weight(scan: RangeScan) -> float:
    """How many points at :data:`CALIBRATION_STEP_DEG` one point of ``scan`` stands for: its step
    between beams over that step, the step counted up to the beam's width.

    A stretch of wall yields a point per beam, so the same wall gives half the points at 1.8° steps and
    twice as many at 0.45°; the points of beams closer together than the beam is wide are not independent
    (the cones overlap), so what a count measures is the angle of wall seen. Counted raw, a match at
    1.8° steps falls under ``min_inliers`` and looks √2 less certain (:attr:`AlignmentQuality.weak_std_m`)
    than the same match at 0.9°. Beams farther apart than the beam's width see disjoint stretches: each
    such point stands for a beam width of wall, no more.
    """
    bearings = np.unique(np.mod(np.asarray(scan.bearings_rad, dtype=np.float64), 2 * np.pi))
    if len(bearings) < 2:
        return 1.0
    step = float(np.median(np.diff(bearings)))
    width = float(scan.beam_width_rad)
    if width > 0:
        step = min(step, width)
    return step / math.radians(CALIBRATION_STEP_DEG) if step > 0 else 1.0


@dataclass(frozen=True)
class ConvergenceThresholds:
    """Limits of :func:`verdict`; every matcher exposes them as parameters."""

    inlier_distance_m: float = 0.15
    min_inliers: int = 25
    min_inlier_ratio: float = 0.5
    min_constraint: float = 0.1
    max_violation_ratio: float = 0.09
    free_space_margin_m: float = 0.3
    max_weak_std_m: float = 0.03
    calibrated: bool = False
    max_violation_run_m: float = 0.75


class ConvergenceParams(SonarScaled):
    """The convergence limits every point matcher exposes (see :class:`ConvergenceThresholds`); their
    lengths are written for the calibration sonar and scaled to each pair's
    (:meth:`~cistern_plugins.sonar_scale.SonarScaled.for_scans`)."""

    inlier_distance_m: float = Field(0.15, gt=0)
    min_inliers: int = Field(25, ge=3)
    min_inlier_ratio: float = Field(0.5, ge=0, le=1)
    min_constraint: float = Field(0.03, ge=0)
    max_weak_std_m: float = Field(0.03, gt=0)
    max_violation_ratio: float = Field(0.09, ge=0, le=1)
    free_space_margin_m: float = Field(0.3, ge=0)
    min_points: int = Field(20, ge=3)
    max_violation_run_m: float = Field(0.75, gt=0, description="longest stretch of wall, in metres along one "
                                       "scan's consecutive wall points, that may lie in the other scan's free space")
    calibrated: bool = Field(True, description="judge a fit by the calibrated verification model "
                             "(cistern_plugins.verification) instead of the fixed ratio, constraint and "
                             "free-space limits; min_inliers still applies")

    def limits(self) -> ConvergenceThresholds:
        return ConvergenceThresholds(self.inlier_distance_m, self.min_inliers, self.min_inlier_ratio,
                                     self.min_constraint, self.max_violation_ratio, self.free_space_margin_m,
                                     self.max_weak_std_m, self.calibrated, self.max_violation_run_m)


def assess_alignment(ref_points: np.ndarray, tree: cKDTree, ref_normals: np.ndarray, moved: np.ndarray,
                     max_range_m: float, inlier_distance_m: float,
                     visible: np.ndarray | None = None, moving_origin: np.ndarray | None = None,
                     weight: float = 1.0, moved_normals: np.ndarray | None = None) -> AlignmentQuality:
    """Measure the fit of already transformed moving points ``moved`` against the reference points.

    The inlier share is taken over the *candidates*: the moving points within the reference sonar's
    range and, when ``visible`` is given, that it could have seen (not behind one of its own walls).
    With the moving sonar's position in the reference frame (``moving_origin``), a moving point on a
    reference wall that the two sonars see from opposite sides (:func:`seen_from_behind`) is no inlier;
    with the moving points' own wall normals (``moved_normals``, in the reference frame), only where the
    two walls run alike (:func:`parallel_walls`): the two faces of one wall, not a wall ending at another's
    corner. ``weight`` is the moving scan's :func:`point_weight`.
    """
    dist, idx = tree.query(moved, k=1)
    in_range = np.hypot(moved[:, 0], moved[:, 1]) <= max_range_m
    if visible is not None:
        in_range &= visible
    inlier = (dist <= inlier_distance_m) & in_range
    behind = 0
    if moving_origin is not None and inlier.any():
        hits = np.flatnonzero(inlier)
        behind_mask = seen_from_behind(ref_points[idx[hits]], ref_normals[idx[hits]], moving_origin)
        if moved_normals is not None:
            behind_mask &= parallel_walls(moved_normals[hits], ref_normals[idx[hits]])
        back = hits[behind_mask]
        if len(back) >= BEHIND_SHARE * len(hits):
            behind = len(back)
            inlier[back] = False
    n_in = int(inlier.sum())
    if n_in < 3:
        return AlignmentQuality(n_in, int(in_range.sum()), len(moved), float("inf"), 0.0, behind=behind,
                                point_weight=weight)
    nrm = ref_normals[idx[inlier]]
    info = nrm.T @ nrm / n_in
    constraint = float(np.linalg.eigvalsh(info)[0])
    rms = float(np.sqrt(np.mean(dist[inlier] ** 2)))
    across = np.einsum("ij,ij->i", moved[inlier] - ref_points[idx[inlier]], nrm)
    return AlignmentQuality(n_in, int(in_range.sum()), len(moved), rms, constraint, behind=behind, point_weight=weight,
                            line_rms_m=float(np.sqrt(np.mean(across ** 2))))


BEHIND_SHARE = 0.25
"""Share of the inliers seen from opposite sides of their walls (:func:`seen_from_behind`) from which
they count as none. At their true poses, 11 of the 2,706 same-level pairs of 48 random multi-chamber
cisterns (``benchmarks/wall_tests.py``) have a quarter or more so, at corners where a wall's normal is
ill-defined, none of them 25 points or more (149 and 17 while walls that meet across each other counted
too, :func:`parallel_walls`). A wall laid on another from behind has most of its inliers so."""


def seen_from_behind(wall: np.ndarray, normals: np.ndarray, moving_origin: np.ndarray) -> np.ndarray:
    """Mask of reference wall points (the reference sonar at the origin) that the moving sonar, at
    ``moving_origin``, would see from the other side of the wall.

    A sonar hears a wall's face only from the water in front of it: two sonars on opposite sides of a
    wall's tangent cannot have seen the same face. A wrong match that sets two look-alike chambers side
    by side lays one chamber's wall onto the other's from behind — every point fits and no wall falls
    into water, since each sonar's water lies on its own side. Rock between chambers is thicker than the
    inlier distance, so a right match does not pair the two faces of one wall; only a normal that is
    wrong, at a corner, makes a right pair look so (:data:`BEHIND_SHARE`), or a wall ending on another
    — a tunnel's side wall on the chamber's wall beside its mouth, which the station in the tunnel
    stands behind — where the moving scan's own wall runs across the reference's
    (:func:`parallel_walls`, which :func:`assess_alignment` applies when it has those normals). Views within
    ``GRAZING_DEG`` of the wall's plane, where a normal's error could flip the side, are not judged.
    """
    least = math.sin(math.radians(GRAZING_DEG))
    to_ref = -wall
    to_mov = np.asarray(moving_origin, dtype=np.float64)[None, :] - wall
    cos_ref = np.einsum("ij,ij->i", to_ref, normals) / np.maximum(np.hypot(to_ref[:, 0], to_ref[:, 1]), 1e-9)
    cos_mov = np.einsum("ij,ij->i", to_mov, normals) / np.maximum(np.hypot(to_mov[:, 0], to_mov[:, 1]), 1e-9)
    return (cos_ref * cos_mov < 0) & (np.abs(cos_ref) >= least) & (np.abs(cos_mov) >= least)


PARALLEL_DEG = 45.0
"""Two walls whose normals lie within this angle of each other (either sign) run alike; beyond it they
meet as at a corner (:func:`parallel_walls`)."""


def parallel_walls(normals: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Mask of points whose wall runs alike the other's (normals within :data:`PARALLEL_DEG`, either
    sign). Two look-alike chambers laid back to back lay a wall's two faces onto each other, and those
    run alike; a right join at a tunnel's mouth lays the tunnel's side walls on the chamber's wall beside
    the mouth only where they meet it at a corner, across it."""
    return np.abs(np.einsum("ij,ij->i", normals, other)) >= math.cos(math.radians(PARALLEL_DEG))


def hard_limits(quality: AlignmentQuality, limits: ConvergenceThresholds, *, ratio: bool = True) -> str:
    """The reason a fit fails the inlier count, the inlier share (with ``ratio``), one of the two
    corridor tests (``min_constraint``, ``max_weak_std_m``) or the stretch of wall in the other scan's
    water (``max_violation_run_m``), or an empty string."""
    if quality.equivalent_inliers < limits.min_inliers:
        behind = f"; {quality.behind} more on walls the two sonars see from opposite sides" if quality.behind else ""
        counted = "" if quality.point_weight == 1.0 else \
            f", {quality.equivalent_inliers:.0f} as points at {CALIBRATION_STEP_DEG}° steps"
        return f"only {quality.inliers} inlier points{counted} (< {limits.min_inliers}{behind})"
    if ratio and quality.inlier_ratio < limits.min_inlier_ratio:
        return f"inlier ratio {quality.inlier_ratio:.2f} < {limits.min_inlier_ratio:.2f}"
    if quality.constraint < limits.min_constraint:
        return f"walls constrain one direction only (constraint {quality.constraint:.3f} < {limits.min_constraint})"
    if quality.weak_std_m > limits.max_weak_std_m:
        return (f"weakly constrained: σ ≈ {quality.weak_std_m:.3f} m along the weakest direction "
                f"(> {limits.max_weak_std_m} m)")
    if quality.violation_run_m > limits.max_violation_run_m:
        return (f"{quality.violation_run_m:.2f} m of wall in a row fall in the other scan's free space "
                f"(> {limits.max_violation_run_m:.2f} m): one sonar sees water where the other sees a wall")
    return ""


def verdict(quality: AlignmentQuality, limits: ConvergenceThresholds) -> str:
    """Empty string when the fit passes every limit, else the reason it does not."""
    why = hard_limits(quality, limits)
    if why:
        return why
    if quality.violation_ratio > limits.max_violation_ratio:
        return (f"{100 * quality.violation_ratio:.0f} % of wall points fall in the other scan's free space "
                f"(> {100 * limits.max_violation_ratio:.0f} %)")
    return ""


GRAZING_DEG = 20.0
"""Rays within this angle of a wall's plane meet it at grazing incidence (:meth:`FreeSpace.violations`)."""
BLIND_RANGE_M = 0.7
"""Walls closer than this to a sonar may hide in its blanking range (:meth:`FreeSpace.shadowed`)."""
SHADOW_WIDTH_M = 0.1
"""Width of the wall each of those echoes stands for."""
OPEN_RANGE_SHARE = 0.75
"""A beam that heard no wall saw water out to this share of the sonar's range, where it says so at all
(:class:`FreeSpace`). Not to all of it: the last decimetres of a range hold no detections (the shadow
test needs water behind a wall), and a far wall met obliquely may answer too weakly to be segmented."""
RUN_GAP_STEPS = 3.0
"""Beams farther apart than this many median steps are not consecutive (:func:`silent_runs`)."""
OPEN_SECTOR_DEG = 20.0
"""A run of consecutive beams at least this wide that all heard nothing looked into open water: its
walls lie beyond what the sonar hears (a chamber larger than the range), not behind a few faint echoes."""


FACE_ON_DEG = 30.0
"""A wall met within this angle of its normal answers a sonar strongly (:meth:`FreeSpace.unheard_facing`):
a smooth wall's echo falls by some 15 dB towards grazing incidence, not near its normal."""
HEARD_SHARE = 0.75
"""Such a wall is heard surely within this share of :func:`open_water_m` (:meth:`FreeSpace.unheard_facing`),
itself three quarters of the range: a face-on wall within 0.56 of the range. (A half, tried first, left a
chamber laid 8.3 m off on its twin whose contradicting wall lay at 0.51 of the range;
``benchmarks/RESULTS.md``, "silence facing a wall".)"""


FLANK_REACH = 1.1
"""A wall facing a sonar on a beam that heard nothing, no farther than this many times the nearer of
the two echoes the sonar heard on either side of that beam, would have answered (:meth:`FreeSpace.unheard_facing`):
10 % farther costs its echo 1.7 dB of spreading loss (``40 log10 1.1``), and a wall met face-on answers
more strongly than the jambs of an opening, met obliquely, that flank it. The sonar's hearing is then
shown by the scan itself where the share of its range (``HEARD_SHARE``) assumes the least: a chamber laid
on its twin, its end wall across the other's tunnel mouth at 0.9 of a 6 m range, the mouth's jambs heard
at the same range on either side of 9° of silence (``benchmarks/RESULTS.md``, "the silence between two
echoes")."""


def open_water_m(scan: RangeScan) -> float:
    """How far a beam of ``scan`` that heard no wall saw water: ``OPEN_RANGE_SHARE`` of the range, and
    no farther than the scan's ``detection_range_m``, beyond which the receiver's noise hides walls
    (a long range setting in a small site)."""
    return min(OPEN_RANGE_SHARE * float(scan.max_range_m), float(scan.detection_range_m))


def answering_reach_m(scan: RangeScan, ranges: np.ndarray) -> np.ndarray:
    """On each beam of ``scan`` (``ranges``: its echoes sorted by bearing), how far a wall turned towards
    the sonar would surely have answered: ``HEARD_SHARE`` of :func:`open_water_m`, or, farther,
    ``FLANK_REACH`` times the nearer of the two echoes heard on either side of the beam
    (:func:`flanking_echoes`), no farther than the segmentation could tell a wall at all
    (``RangeScan.detection_range_m``) nor than the range."""
    reach = np.full(len(ranges), HEARD_SHARE * open_water_m(scan))
    if not np.isfinite(ranges).any():
        return reach
    before, after = flanking_echoes(ranges)
    detectable = min(float(scan.detection_range_m), float(scan.max_range_m))
    return np.maximum(reach, np.minimum(FLANK_REACH * np.minimum(ranges[before], ranges[after]), detectable))


class FreeSpace:
    """The free space one scan observed: on each map-frame bearing, nothing closer than its echo.

    A beam is a cone ``beam_width_rad`` wide, not a ray, and segmentation keeps one echo per beam: a
    wall that clips the edge of the cone (the jamb of an opening the beam looks through, a wall met at
    grazing incidence) may sit closer than the echo the beam reports. So the free range on a bearing is
    the *nearest* echo of every beam whose cone covers that bearing: free space eroded by the beam
    cone. Without this, correct matches of scans that look through an opening into the next chamber
    put 10–40 % of their wall points in each other's "free" space.

    A beam with no echo says nothing by default, even where a neighbour's cone covers its bearing: what
    its own axis, the most sensitive part of its lobe, did not hear, the edge of the neighbour's cone
    did not hear either (a far wall met obliquely answers too faintly), and the neighbour's echo may be
    a multipath ghost arriving after a direct echo nobody heard. Letting such a beam take its
    neighbours' water laid a right pair's walls 0.5–1 m "in water" (``benchmarks/RESULTS.md``,
    "2026-12-05 (session 4)"). What a neighbour's cone met may still hide what lies behind it on that
    bearing, so visibility (:meth:`visible`) keeps the cone's bound there (:func:`silent_water` gives
    silent beams ranges of their own). With ``open_sector_rad`` the beams of a run of silent beams that
    wide or wider saw water (:func:`silent_runs`), out to :func:`open_water_m`: a station in the
    corner of a chamber larger than its sonar's range hears the corner's two walls and nothing across
    the chamber, and that silence is what tells its corner from the corner of a smaller room, whose
    other walls would lie in it (:class:`ReferenceModel` judges every match so).

    A scan whose echoes were not heard on beams from its station (``RangeScan.rays_from_station`` off: a
    moving vehicle's motion-compensated cloud) shows no free space: every free-space test passes on it.
    """

    def __init__(self, scan: RangeScan, *, cone: bool = True, open_sector_rad: float | None = None):
        angles = np.mod(scan.bearings_rad + scan.yaw_rad, 2 * np.pi)
        order = np.argsort(angles, kind="stable")
        self.angles = angles[order]
        ranges = scan.ranges_m[order]
        step = 2 * np.pi / max(len(angles), 1)
        self.tolerance_rad = 1.5 * step
        heard = np.isfinite(ranges)
        reach = erosion_reach(self.angles, float(scan.beam_width_rad)) if cone and scan.beam_width_rad > 0 else 0.0
        self.ranges = _cone_minimum(self.angles, ranges, reach) if reach > 0 else ranges
        """On each bearing, the nearest echo of the beams whose cones reach it: what may hide a point
        (:meth:`visible`)."""
        free = self.ranges
        if open_sector_rad is not None:  # a wide silent run saw open water
            wide = silent_runs(self.angles, heard, open_sector_rad)
            if wide.any():
                heard = heard | wide
                free = np.where(wide, open_water_m(scan), ranges)
                free = _cone_minimum(self.angles, free, reach) if reach > 0 else free
        self.free_ranges = np.where(heard & scan.rays_from_station, free, np.nan)
        """The same on the bearings of beams that heard an echo, and of a wide run of beams that heard
        none out to :func:`open_water_m`; unknown on the others: how far the sonar saw water
        (:meth:`in_free_space`, :meth:`violation_mask`)."""
        self.silent = ~np.isfinite(ranges) & scan.rays_from_station
        """The beams that heard nothing (:meth:`unheard_facing`)."""
        self.answers_within_m = answering_reach_m(scan, ranges)
        """On each beam, how far a wall facing this sonar would surely have answered (:meth:`unheard_facing`)."""

    def violations(self, points: np.ndarray, margin_m: float,
                   normals: np.ndarray | None = None) -> tuple[int, int]:
        """(points in observed free space, points checked); ``points`` relative to the station.

        With the wall ``normals`` of the points (from the scan that saw them), a point whose wall this
        sonar would meet at grazing incidence — the ray within ``GRAZING_DEG`` of the wall's plane — is
        not checked: at grazing incidence the beam cone and the pulse smear the echo along the wall, so
        the sonar's "free" range there says nothing about that wall (the jambs of an opening the
        vehicle sits in, a wall seen edge-on through a doorway: walls seen from one side only).
        """
        bad, checked = self.violation_mask(points, margin_m, normals)
        return int(bad.sum()), int(checked.sum())

    def violation_mask(self, points: np.ndarray, margin_m: float,
                       normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The masks behind :meth:`violations`: points in observed free space, and points checked."""
        bad, checked = self._classify(points, margin_m)
        if normals is not None and len(points):
            rays = points / np.maximum(np.hypot(points[:, 0], points[:, 1]), 1e-9)[:, None]
            face_on = np.abs(np.einsum("ij,ij->i", rays, normals)) >= math.sin(math.radians(GRAZING_DEG))
            bad, checked = bad & face_on, checked & face_on
        shadowed = self.shadowed(points)
        return bad & ~shadowed, checked & ~shadowed

    def unheard_facing(self, points: np.ndarray, normals: np.ndarray, seen_from: np.ndarray) -> np.ndarray:
        """Mask of wall points (relative to this station) that face this sonar, within ``HEARD_SHARE``
        of its hearing (:func:`open_water_m`), on the bearing of a beam that heard nothing.

        ``normals`` are the points' wall normals and ``seen_from`` the station of the sonar that heard
        them (same frame): the face it heard is the one towards it. A beam that heard nothing says
        nothing of walls it would meet obliquely, from behind (the rock beside an opening it looks
        through) or far off (:class:`FreeSpace`); but a wall turned towards it, met within
        ``FACE_ON_DEG`` of its normal and within :func:`answering_reach_m` of it, answers. A stretch of such
        points is a wall laid where this sonar heard none: one chamber's opening set on the solid wall
        of a look-alike chamber, seen through the opening as silence (:meth:`ReferenceModel.assess_pair`).
        """
        if len(self.angles) == 0 or len(points) == 0:
            return np.zeros(len(points), dtype=bool)
        nearest, gap, r = self._nearest_beam(points)
        on_silent = self.silent[nearest] & (gap <= self.tolerance_rad)
        cos_here = np.einsum("ij,ij->i", -points, normals) / np.maximum(r, 1e-9)
        cos_hearer = np.einsum("ij,ij->i", np.asarray(seen_from, dtype=np.float64)[None, :] - points, normals)
        face_on = (np.abs(cos_here) >= math.cos(math.radians(FACE_ON_DEG))) & (cos_here * cos_hearer > 0)
        return on_silent & face_on & (r <= self.answers_within_m[nearest]) & ~self.shadowed(points)

    def shadowed(self, points: np.ndarray) -> np.ndarray:
        """Mask of points behind a wall (one of ``points`` itself) closer to this sonar than
        ``BLIND_RANGE_M``: a sonar that close to a wall — in a tunnel or an opening 1 m wide — hears
        nothing from it inside its blanking range and reports a farther echo on those bearings, so its
        "free" space there runs through rock. Such points are not checked."""
        r = np.hypot(points[:, 0], points[:, 1]) if len(points) else np.zeros(0)
        near = r < BLIND_RANGE_M
        if not near.any():
            return np.zeros(len(points), dtype=bool)
        a = np.arctan2(points[:, 1], points[:, 0])
        half = np.arctan2(0.5 * SHADOW_WIDTH_M, np.maximum(r[near], 1e-3))
        diff = np.abs(wrap_angle(a[:, None] - a[near][None, :]))
        return ((diff <= half[None, :]) & (r[:, None] > r[near][None, :] + 0.05)).any(axis=1)

    def visible(self, points: np.ndarray, tolerance_m: float) -> np.ndarray:
        """Mask of points (relative to the station) this sonar could have seen: not farther than its
        echo on their bearing by more than ``tolerance_m`` (a point behind one of its walls is hidden,
        neither evidence for a match nor against it — a scan that looks through an opening sees a
        chamber the other scan's sonar cannot)."""
        if len(self.angles) == 0 or len(points) == 0:
            return np.ones(len(points), dtype=bool)
        _, checked, r, r_echo = self._nearest(points, self.ranges)
        return ~(checked & (r > r_echo + tolerance_m))

    def in_free_space(self, points: np.ndarray, margin_m: float) -> np.ndarray:
        """Mask of points (relative to the station) the sonar saw empty."""
        return self._classify(points, margin_m)[0]

    def _classify(self, points: np.ndarray, margin_m: float) -> tuple[np.ndarray, np.ndarray]:
        if len(self.angles) == 0 or len(points) == 0:
            empty = np.zeros(len(points), dtype=bool)
            return empty, empty
        _, checked, r, r_echo = self._nearest(points, self.free_ranges)
        return checked & (r < r_echo - margin_m), checked

    def _nearest(self, points: np.ndarray, ranges: np.ndarray):
        """For every point: the nearest beam, whether it is within the bearing tolerance and ``ranges``
        holds a range on it, the point's range and that range."""
        nearest, gap, r = self._nearest_beam(points)
        r_echo = ranges[nearest]
        checked = (gap <= self.tolerance_rad) & np.isfinite(r_echo)
        return nearest, checked, r, r_echo

    def _nearest_beam(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For every point: the nearest beam, the bearing between them and the point's range."""
        a = np.mod(np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi)
        k = np.searchsorted(self.angles, a) % len(self.angles)
        km = (k - 1) % len(self.angles)
        dk = np.abs(wrap_angle(self.angles[k] - a))
        dkm = np.abs(wrap_angle(self.angles[km] - a))
        return np.where(dk <= dkm, k, km), np.minimum(dk, dkm), np.hypot(points[:, 0], points[:, 1])


def erosion_reach(angles: np.ndarray, beam_width_rad: float) -> float:
    """How far from a beam (radians) the beams lie whose echoes bound its free range: half the beam
    cone, and never so little that the beams next to it are left out.

    A point is looked up at its nearest beam, so its bearing is known to a step only; with steps as
    wide as half the cone or wider (1.8° steps under a 3° beam) the half cone would hold the beam
    alone, although the cones of the beams on either side cover bearings the point may have. The
    reach is then one and a half steps (as :attr:`FreeSpace.tolerance_rad`): the neighbours on either
    side, not the beams beyond them. The reach only bounds free space: a beam that heard nothing stays
    silent (:class:`FreeSpace`).

    Parameters
    ----------
    angles : ndarray
        The beams' bearings, sorted.
    beam_width_rad : float
        The cone's full width.
    """
    half_cone = 0.5 * beam_width_rad
    if len(angles) < 2 or half_cone <= 0:
        return half_cone
    step = float(np.median(np.diff(angles)))
    return max(half_cone, 1.5 * step)


def silent_runs(angles: np.ndarray, heard: np.ndarray, min_width_rad: float) -> np.ndarray:
    """Mask of the beams (``angles`` sorted in [0, 2π)) in a run of consecutive beams that heard nothing
    spanning ``min_width_rad`` or more, from the first beam of the run to the last (cyclically). Beams
    more than ``RUN_GAP_STEPS`` steps apart are not consecutive: the two ends of a sector scan do not
    join into one run. A scan that heard nothing at all has no such run: nothing tells open water from a
    sonar that failed."""
    n = len(angles)
    out = np.zeros(n, dtype=bool)
    if n < 2 or heard.all() or not heard.any():
        return out
    gaps = np.mod(np.diff(angles, append=angles[0] + 2 * np.pi), 2 * np.pi)  # gaps[k]: beam k to beam k + 1
    apart = gaps > RUN_GAP_STEPS * float(np.median(gaps))
    turn = (int(np.flatnonzero(heard)[-1]) + 1 + np.arange(n)) % n  # from just after a heard beam, once round
    silent, split, gap = ~heard[turn], apart[turn], gaps[turn]
    begins = silent & np.concatenate([[True], ~silent[:-1] | split[:-1]])
    run = np.cumsum(begins) - 1
    inner = silent & np.append(silent[1:] & ~split[:-1], False)  # the next beam is silent and of the same run
    width = np.bincount(run[silent], weights=np.where(inner, gap, 0.0)[silent])
    out[turn[silent]] = width[run[silent]] >= min_width_rad
    return out


def silent_water(scan: RangeScan, open_sector_rad: float) -> RangeScan:
    """``scan`` with every beam that heard nothing given the water it saw, as a range: a run of such
    beams ``open_sector_rad`` wide or wider (:func:`silent_runs`) out to :func:`open_water_m`, a narrower
    run out to the farther of the two echoes flanking it (a wall met at grazing incidence answers too
    faintly, and lies about where its heard stretches on either side point), no farther than
    :func:`open_water_m` either. A scan that heard nothing, or everything, is returned as it is."""
    angles = np.mod(scan.bearings_rad + scan.yaw_rad, 2 * np.pi)
    order = np.argsort(angles, kind="stable")
    ranges = scan.ranges_m[order]
    heard = np.isfinite(ranges)
    if heard.all() or not heard.any():
        return scan
    n = len(ranges)
    before, after = flanking_echoes(ranges)
    reach = open_water_m(scan)
    flanks = np.minimum(np.maximum(ranges[before], ranges[after]), reach)
    wide = silent_runs(angles[order], heard, open_sector_rad)
    filled = np.empty(n)
    filled[order] = np.where(heard, ranges, np.where(wide, reach, flanks))
    return replace(scan, ranges_m=filled)


def flanking_echoes(ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every beam of ``ranges`` (sorted by bearing, ``nan`` where a beam heard nothing, at least one
    heard), the index of the last beam up to it that heard an echo and of the next one from it,
    cyclically; a beam that heard one is its own on both sides."""
    n = len(ranges)
    heard = np.tile(np.isfinite(ranges), 2)
    index = np.arange(2 * n)  # two turns, to look round the end cyclically
    before = np.maximum.accumulate(np.where(heard, index, -1))[n:] % n
    after = np.minimum.accumulate(np.where(heard, index, 2 * n)[::-1])[::-1][:n] % n
    return before, after


def _cone_minimum(angles: np.ndarray, ranges: np.ndarray, half_cone_rad: float) -> np.ndarray:
    """For every beam (``angles`` sorted in [0, 2π)), the nearest finite echo among the beams within
    ``half_cone_rad`` of it (cyclically); ``nan`` where none of them has an echo."""
    n = len(angles)
    if n == 0:
        return ranges
    finite = np.where(np.isfinite(ranges), ranges, np.inf)
    wrapped = np.concatenate([angles - 2 * np.pi, angles, angles + 2 * np.pi])
    values = np.concatenate([finite, finite, finite])
    lo = np.searchsorted(wrapped, angles - half_cone_rad - 1e-12, side="left")
    hi = np.searchsorted(wrapped, angles + half_cone_rad + 1e-12, side="right")
    width = int((hi - lo).max())
    idx = np.clip(lo[:, None] + np.arange(width)[None, :], 0, len(values) - 1)
    window = np.where(idx < hi[:, None], values[idx], np.inf)
    out = window.min(axis=1)
    return np.where(np.isfinite(out), out, np.nan)


def inverse(pose: np.ndarray) -> np.ndarray:
    """The pose ``q -> R^T (q - t)``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    t = -np.array([c * pose[0] + s * pose[1], -s * pose[0] + c * pose[1]])
    return np.array([t[0], t[1], -pose[2]])


class ReferenceModel:
    """The reference scan's points with their k-d tree, normals and free space, built once per match."""

    def __init__(self, reference: RangeScan):
        self.points = scan_points(reference)
        self.max_range_m = float(reference.max_range_m)
        self.tree = cKDTree(self.points) if len(self.points) else None
        self.normals = estimate_normals(self.points, self.tree) if len(self.points) >= 3 else np.zeros((0, 2))
        self.free = FreeSpace(reference, open_sector_rad=math.radians(OPEN_SECTOR_DEG))
        self.weight = point_weight(reference)

    def assess(self, moved: np.ndarray, inlier_distance_m: float, weight: float = 1.0) -> AlignmentQuality:
        """Fit of transformed moving points (without the free-space check, see :meth:`assess_pair`);
        ``weight`` is the moving scan's :func:`point_weight`."""
        return assess_alignment(self.points, self.tree, self.normals, moved, self.max_range_m, inlier_distance_m,
                                weight=weight)

    def assess_pair(self, moving: RangeScan, pose: np.ndarray, limits: ConvergenceThresholds) -> AlignmentQuality:
        """Fit of the moving scan placed by ``pose``, checked both ways: when the reference-onto-moving
        inlier share is the smaller one it is used (with the smaller of the two inlier counts and
        constraints); the free-space violation ratio is the larger of the two directions, counted over
        the wall points each sonar could have seen face-on (:meth:`FreeSpace.violations`). The longest
        stretch of wall in the other's water counts too the wall points turned towards the other sonar
        on bearings where it heard nothing (:meth:`FreeSpace.unheard_facing`)."""
        src = scan_points(moving)
        moved = transform(src, pose)
        home = inverse(pose)
        mov_sonar, ref_sonar = np.asarray(pose[:2], dtype=np.float64), np.asarray(home[:2], dtype=np.float64)
        mov_tree = cKDTree(src) if len(src) >= 3 else None
        mov_normals = estimate_normals(src, mov_tree) if mov_tree is not None else None
        moved_normals = None if mov_normals is None else rotate(mov_normals, pose[2])
        back_normals = rotate(self.normals, -pose[2]) if len(self.normals) else None
        seen = self.free.visible(moved, limits.free_space_margin_m)
        q = assess_alignment(self.points, self.tree, self.normals, moved, self.max_range_m, limits.inlier_distance_m,
                             seen, moving_origin=mov_sonar, weight=point_weight(moving),
                             moved_normals=moved_normals)
        back = transform(self.points, home)
        mov_free = FreeSpace(moving, open_sector_rad=math.radians(OPEN_SECTOR_DEG))
        bad1, seen1 = self.free.violation_mask(moved, limits.free_space_margin_m, moved_normals)
        bad2, seen2 = mov_free.violation_mask(back, limits.free_space_margin_m, back_normals)
        n1, n2 = int(seen1.sum()), int(seen2.sum())
        ratios = (bad1.sum() / n1 if n1 else 0.0, bad2.sum() / n2 if n2 else 0.0)
        if moved_normals is not None and back_normals is not None:  # walls where the other heard none
            bad1 = bad1 | self.free.unheard_facing(moved, moved_normals, mov_sonar)
            bad2 = bad2 | mov_free.unheard_facing(back, back_normals, ref_sonar)
        gap = 2 * limits.inlier_distance_m
        run = max(longest_run_m(src, bad1, gap, viewer=ref_sonar),
                  longest_run_m(self.points, bad2, gap, viewer=mov_sonar))
        if mov_tree is not None:  # the same fit seen from the moving scan: the smaller inlier share counts
            rq = assess_alignment(src, mov_tree, mov_normals, back, float(moving.max_range_m), limits.inlier_distance_m,
                                  mov_free.visible(back, limits.free_space_margin_m),
                                  moving_origin=ref_sonar, weight=self.weight,
                                  moved_normals=back_normals)
            if rq.inlier_ratio < q.inlier_ratio:
                fewer = min((q, rq), key=lambda x: x.equivalent_inliers)
                q = AlignmentQuality(fewer.inliers, rq.candidates, q.n_points, q.rms_m, min(q.constraint, rq.constraint),
                                     behind=max(q.behind, rq.behind), point_weight=fewer.point_weight,
                                     line_rms_m=q.line_rms_m)
        return AlignmentQuality(q.inliers, q.candidates, q.n_points, q.rms_m, q.constraint, float(max(ratios)),
                                float(min(ratios)), q.behind, run, q.point_weight, q.line_rms_m)


def longest_run_m(points: np.ndarray, bad: np.ndarray, gap_m: float, viewer: np.ndarray | None = None) -> float:
    """The longest stretch, in metres along a scan's consecutive wall points (beam order), of points
    flagged ``bad``, neighbours no farther apart than ``gap_m`` (one wall, not a jump to another).

    Noise, a pose a few centimetres off and the corners of openings put scattered points of a right
    match into the other scan's free space; a wrong one lays a whole stretch of wall across the water
    another sonar saw — one chamber's opening onto the other's solid wall. On 240 random multi-chamber
    cisterns (``benchmarks/wall_tests.py --random 40``, seeds 2, 4–8) no pair at its true pose had a
    stretch longer than 0.29 m and no right join one longer than 0.30 m; a wrong join that set a
    chamber's opening on a solid wall had 1.76 m.

    With the position of the sonar whose water the points fall in (``viewer``, in the points' frame), a
    stretch that sonar would see edge-on — the chord between its ends within ``GRAZING_DEG`` of the ray
    to its middle — does not count: a sonar close to a wall, looking along it, hears little from it and
    reports a farther echo, so its "water" there runs along the wall. The per-point normals of
    :meth:`FreeSpace.violation_mask` already leave out such points where the wall is smooth; on a rough
    wall ten neighbours' normals scatter by more than the grazing angle, the stretch's chord does not (a
    right pair along a chamber's wall at its true pose laid 0.76 m so, seed 1 of the random cisterns).
    """
    if len(points) < 2:
        return 0.0
    steps = np.hypot(*np.diff(points, axis=0).T)
    link = bad[1:] & bad[:-1] & (steps <= gap_m)
    run_id = np.cumsum(np.concatenate([[True], ~link]))  # run of each point; a link joins i to i + 1
    totals = np.bincount(run_id[1:], weights=np.where(link, steps, 0.0), minlength=run_id[-1] + 1)
    if viewer is not None:
        totals[edge_on_runs(points, run_id, viewer)] = 0.0
    return float(totals.max())


def edge_on_runs(points: np.ndarray, run_id: np.ndarray, viewer: np.ndarray) -> np.ndarray:
    """Ids of the runs (``run_id`` of consecutive points) whose chord a sonar at ``viewer`` sees within
    ``GRAZING_DEG`` of its plane (:func:`longest_run_m`)."""
    ids = np.arange(run_id[-1] + 1)
    first = np.searchsorted(run_id, ids, side="left")
    last = np.searchsorted(run_id, ids, side="right") - 1
    real = first <= last
    chord = points[last[real]] - points[first[real]]
    ray = 0.5 * (points[last[real]] + points[first[real]]) - np.asarray(viewer, dtype=np.float64)[None, :]
    cross = np.abs(chord[:, 0] * ray[:, 1] - chord[:, 1] * ray[:, 0])
    norms = np.hypot(*chord.T) * np.hypot(*ray.T)
    grazing = (norms > 0) & (cross < math.sin(math.radians(GRAZING_DEG)) * norms)
    return ids[real][grazing]


def rotate(vectors: np.ndarray, angle: float) -> np.ndarray:
    """Vectors (N, 2) turned counter-clockwise by ``angle``."""
    c, s = math.cos(angle), math.sin(angle)
    return vectors @ np.array([[c, s], [-s, c]])


def too_few_points(reference: RangeScan, moving: RangeScan, minimum: int) -> str:
    """The reason a pair cannot be matched for lack of echoes, or an empty string."""
    n_ref, n_mov = int(reference.valid.sum()), int(moving.valid.sum())
    if n_ref < minimum or n_mov < minimum:
        return f"too few echoes: reference {n_ref}, moving {n_mov} (need {minimum})"
    return ""


def covariance_from_fit(src: np.ndarray, normals: np.ndarray, rms_m: float) -> np.ndarray:
    """Gauss-Newton covariance ``sigma^2 (J^T J)^-1`` of (x, y, theta) from point-to-line inliers."""
    cross = src[:, 0] * normals[:, 1] - src[:, 1] * normals[:, 0]
    jac = np.column_stack([normals, cross])
    sigma2 = max(rms_m, 0.01) ** 2
    return sigma2 * np.linalg.inv(jac.T @ jac + 1e-6 * np.eye(3))
