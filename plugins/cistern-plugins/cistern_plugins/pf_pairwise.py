"""Pair-wise scan matching with a particle filter (McVicker et al., Tables I–II, eqs. 3–6).

Scan ``j`` (moving) is located in the evidence grid ``m_i`` built from scan ``i`` (reference) alone,
with scan ``i``'s sonar at the origin of a compass-aligned frame. A particle is ``[x, y, θ]``: the
position of scan ``j``'s sonar in that frame and a correction ``θ`` to scan ``j``'s compass heading,
so the measured compass difference is the centre of the θ distribution.

Decisions where the paper's text is ambiguous
---------------------------------------------
* **Eq. 3** – ``φ = exp(-(δs - δm)² / (2 σc²))`` with ``σc = 2 r_c`` (``a`` normalises the peak to 1).
* **Eq. 4** – every beam of scan ``j`` with an echo contributes ``+φ`` when ``|δs - δm| < δmax`` and
  ``-(1 - φ)`` otherwise (negative feedback); a beam whose ray finds no occupied cell counts as
  ``δm = ∞`` and so contributes ``-1``. The particle's weight is the **mean** of the contributions over
  the beams used, so it lies in ``[-1, 1]`` whatever the beam count: ``1`` means every beam lands on a
  wall of ``m_i``; ``0`` means as many beams agree as disagree. ``tau_pw`` (eq. 6) is in these units;
  the paper's 6.0 was a sum over the beams of its scans.
* **Unknown space** – ``m_i`` holds evidence only where scan ``i`` looked. A beam whose end point
  falls in a cell with no evidence at all (log-odds exactly 0) and that meets no wall contributes
  ``unknown_score`` instead of the penalty: ``-1`` reproduces the paper (every disagreeing beam is
  penalised, so a pair with 50 % overlap scores about ``0.5 * 0.85 - 0.5 = -0.08`` at the right
  place); the default ``0`` treats "no evidence" as neither agreement nor contradiction, so the weight
  at the right place is about the overlap fraction times the agreement, while beams that end in
  space ``m_i`` saw as free are still penalised.
* **Walls of m_i** – the inverse model marks the echo range occupied over ``map_occupied``: the whole
  beam cone (``"cone"``, the classic model), one beam step around the axis (``"step"``, default: walls
  stay contiguous but a wall seen at a grazing angle is not smeared across a 3° cone into open water,
  which in a 1.4 m gallery puts phantom walls in mid-channel), or the axis alone (``"axis"``).
* **δm** – ``measurement_model="raycast"`` casts a ray from the particle along the beam to the first
  cell of ``m_i`` whose occupancy probability exceeds ``weight_threshold`` (sphere tracing over the
  distance field, which returns the same first hit as a half-cell march, see
  :mod:`cistern_archive.grid.raycast`). ``measurement_model="distance-field"`` is the likelihood-field
  approximation: ``|δs - δm|`` is replaced by the distance from the beam's end point to the nearest
  occupied cell, so the per-cell contribution is precomputed once per map and a particle costs one
  look-up per beam. It ignores walls crossed before the echo; it is ~10× faster (see
  ``benchmarks/RESULTS.md``).
* **Resampling** – low-variance (systematic) resampling. ``resample_weighting="shifted"`` draws with
  probability proportional to ``w - min(w)`` (the paper's "proportional to its weight", made
  non-negative); ``"exponential"`` draws proportional to ``exp(sharpness * (w - max w))``, which
  concentrates faster on the same ranking.
* **Eqs. 5–6** – before resampling, ``σ_p`` is the larger of the standard deviations of the particles'
  x and y; ``w`` is the mean particle weight. Their exponential averages use ``chi_sigma`` and
  ``chi_w`` and start at the first iteration's values. Converged when ``σ_p,μ ≤ r_c`` and
  ``w_μ ≥ tau_pw``, otherwise after ``n_iterations`` the pair is reported not converged with the reason.
* **Output** – ``dx, dy`` is the mean particle position after the last resampling (``p_j - p_i``),
  ``dyaw`` the circular mean of θ, ``weight`` the final ``w_μ``, ``covariance`` the particles'
  covariance of (x, y, θ); a converged estimate is then refined (``refine``, below) and reported with
  the covariance of that fit.

Defaults and the paper
----------------------
The defaults are the measured best (``benchmarks/RESULTS.md``); the paper's method is
:meth:`PFParams.paper` (:data:`PAPER_CONFIGURATION`: ``measurement_model="raycast",
resample_weighting="shifted", init_oversample=1, unknown_score=-1, map_occupied="cone",
map_free="cone", verify=False, verify_fit=False, restarts=0, refine="none"``, every beam). The
departures:

* ``init_oversample`` – the first iteration weighs that many uniform samples per particle and keeps
  ``n_particles`` of them (a coarse search before the fine filter);
* ``resample_weighting="exponential"``, ``unknown_score=0`` and ``map_occupied="step"`` (above);
* ``verify`` – a converged estimate is checked before it is reported (:func:`verify_unique`): it may
  not sit on the edge of the search square, more than ``max_crossing`` of its beams may not pass
  through walls of ``m_i``, and no position farther than ``ambiguity_radius_m`` may score nearly as
  well. Eqs. 5–6 alone accept a filter that collapsed onto one of several equally good places.
* ``verify_fit`` – a verified estimate must also pass the convergence verdict the point matchers share
  (:func:`cistern_plugins.alignment.verdict`, :func:`fit_check`): at least ``min_inliers`` echo points
  of either scan within ``inlier_distance_m`` of the other's and an inlier share of at least
  ``min_inlier_ratio`` (0.25) both ways; a fit whose inlier share is below ``partial_inlier_ratio``
  (0.5) may in addition put no more than ``partial_max_violation`` (20 %) of its wall points in the
  free space the other sonar saw. The likelihood field rewards the beams that land on walls and is
  blind to how few they are: without this check 2 of 60 pairs of scans of different sites converged
  (seed 1 of ``benchmarks/matchers.py``), all with inlier shares of 0.14–0.34. The corridor tests of
  the verdict (``min_constraint``, ``max_weak_std_m``) and its general free-space limit are off by
  default: the ambiguity search covers the first, and correct matches of segmented sonar scans put up
  to 22 % of their wall points in the other scan's free space (smeared echoes at grazing incidence).
* ``min_informative < 1`` (off by default) normalises the weight by the beams that land where ``m_i``
  has evidence instead of by all beams; ``map_free`` narrows the free-space cone of ``m_i``.
* ``refine="point-to-line"`` – a verified estimate is refined by trimmed point-to-line ICP of the two
  scans' echoes (pairs within ``refine_correspondence_m``, the closest ``refine_trim_fraction`` kept)
  and reported with that fit's covariance, unless the refinement moves it more than
  ``refine_max_shift_m`` (see "Limits"); the fit check then judges the refined estimate.
* ``guess`` – a localizer may ask for a pair with a
  :class:`~cistern_archive.pipeline.contracts.MatchGuess`; the particles then start in the square
  ``±radius_m`` around it (:class:`SearchWindow`) and θ around its heading correction. The ambiguity
  search still covers an ``L_init`` square around the guess: a window as small as the guess's cannot
  hold a rival ``ambiguity_radius_m`` away, and a wrong match inside it would pass.
* ``restarts > 0`` (off by default): when the filter from the uniform start fails (not converged or
  rejected by verification), up to that many filters are restarted around the best positions of the
  coarse score grid that verification uses (:func:`grid_modes`), and the first one that converges and
  verifies is reported. On the demo gallery it recovered one pair and let two more wrong ones through
  (``benchmarks/RESULTS.md``), so it stays off.

Limits
------
Along a straight gallery with parallel side walls and no feature in range (no bend, end, niche or change
of section), every position along the axis explains the side walls equally well: the along-axis offset
is not observable from the scans, whatever the measurement model. The filter then either spreads along
the axis (eq. 5 not met) or collapses on one of the equally good positions, which verification rejects
as ambiguous (or, when the rival scores just under ``ambiguity_ratio``, lets through an estimate
decimetres to metres off). Closer stations do not cure this; features in range do (the last, plain
8 m of the demo ``water-gallery`` show it). Sloping walls seen through the 35° vertical lobe
(bell-shaped cisterns) return the leading edge of a smear whose range depends on the distance to the
wall, so two scans of one depth see slightly different outlines and their matches are biased by
0.1–0.3 m.

The likelihood field is also biased along a gallery, towards the reference scan. A scan samples a wall
at one echo per beam, densely near the sonar and sparsely where its beams graze the wall (every
``d Δφ / sin² α`` for a wall ``d`` away met at ``α``), and the score counts the moving scan's echoes
that land on the reference's sampled walls: moving the scans towards each other lays the dense parts
on each other and scores higher. On the demo ``water-gallery`` the converged neighbour matches were
3.9 cm short per 2 m step on average, and 2.6 cm short with the simulator's exact axial ranges in place
of the segmented echoes, so the bias is in the score, not in the echoes; it adds up along the gallery
(0.19 m median scan error after alignment). ``refine`` removes it: the verified estimate is refined by
point-to-line ICP, whose distances to the reference's local wall lines do not depend on how densely the
walls are sampled (−0.5 cm per step, 0.04 m median scan error; ``benchmarks/RESULTS.md``).
"""

from __future__ import annotations

import hashlib
import math
import time
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from cistern_archive.grid.evidence import DenseMap, SonarModel, dense_scan_map
from cistern_archive.grid.raycast import FAR_M, OccupancyLookup
from cistern_archive.pipeline.contracts import MatchGuess, MatchHistory, MatchResult, StageParams
from cistern_archive.core.scan import RangeScan
from cistern_plugins.alignment import ConvergenceParams, ReferenceModel, scan_points, transform, verdict
from cistern_plugins.icp import fit_covariance, refine_point_to_line


class PFParams(ConvergenceParams):
    """Parameters of :class:`PFPairwiseMatcher` (Tables I–II and Sec. IV of the paper), plus the limits
    of :class:`~cistern_plugins.alignment.ConvergenceParams` that ``verify_fit`` applies (``min_points``
    is not used: ``min_beams`` refuses scans with too few echoes)."""

    cell_m: float = Field(0.05, gt=0, description="map cell size r_c (m); sigma_c = 2 r_c")
    calibrated: bool = Field(False, description="verify_fit uses the fixed limits below, not the calibrated model")
    n_particles: int = Field(500, ge=10, le=100_000, description="Num_Particles")
    l_init_m: float = Field(8.0, gt=0, description="side of the uniform initial square L_init (m)")
    theta_init_std_deg: float = Field(2.0, ge=0, description="std of the initial heading correction (deg)")
    sigma_n_xy_m: float = Field(0.02, ge=0, description="propagation noise sigma_n of x and y (m)")
    sigma_n_theta_deg: float = Field(0.5, ge=0, description="propagation noise sigma_n of theta (deg)")
    delta_max_m: float = Field(0.3, gt=0, description="delta_max of eq. 4 (m)")
    weight_threshold: float = Field(0.6, gt=0, lt=1, description="WEIGHT_THRESHOLD: occupied probability")
    n_iterations: int = Field(60, ge=1, le=10_000, description="Num_Iterations")
    chi_w: float = Field(2.0 / 7.0, gt=0, le=1, description="smoothing of the weight average (eq. 6)")
    chi_sigma: float = Field(2.0 / 5.0, gt=0, le=1, description="smoothing of the std average (eq. 5)")
    tau_pw: float = Field(0.25, ge=-1, le=1, description="weight threshold of eq. 6 (mean per-beam units)")
    measurement_model: Literal["raycast", "distance-field"] = "distance-field"
    resample_weighting: Literal["shifted", "exponential"] = "exponential"
    sharpness: float = Field(40.0, gt=0, description="exponent scale of 'exponential' resampling")
    init_oversample: int = Field(4, ge=1, le=100, description="uniform samples weighed at start, per particle")
    max_beams: int = Field(200, ge=1, description="beams of the moving scan used (evenly subsampled)")
    min_beams: int = Field(10, ge=1, description="fewer echoes than this: not converged")
    verify: bool = Field(True, description="reject converged estimates that are ambiguous or on the search edge")
    verify_fit: bool = Field(
        True, description="reject converged estimates that fail the point matchers' shared fit verdict"
    )
    min_inlier_ratio: float = Field(0.25, ge=0, le=1, description="fit verdict: least inlier share, both ways")
    min_constraint: float = Field(0.0, ge=0, description="fit verdict: off (the ambiguity search does this)")
    max_weak_std_m: float = Field(1.0, gt=0, description="fit verdict: off (the ambiguity search does this)")
    max_violation_ratio: float = Field(1.0, ge=0, le=1, description="fit verdict: share of wall points in free space")
    partial_inlier_ratio: float = Field(
        0.5, ge=0, le=1, description="fit verdict: below this inlier share, partial_max_violation applies"
    )
    partial_max_violation: float = Field(
        0.2, ge=0, le=1, description="fit verdict: largest free-space violation ratio of a partial-overlap fit"
    )
    verify_step_m: float = Field(0.15, gt=0, description="grid step of the ambiguity search (m)")
    ambiguity_radius_m: float = Field(0.5, gt=0, description="alternatives farther than this count as other modes")
    ambiguity_ratio: float = Field(0.85, gt=0, le=1, description="an alternative scoring this share of the best is a rival")
    max_crossing: float = Field(0.1, ge=0, le=1, description="largest share of beams that may cross a wall of m_i")
    verify_beams: int = Field(100, ge=10, description="beams used by the ambiguity search (evenly subsampled)")
    restarts: int = Field(
        0, ge=0, le=10, description="filters restarted at the best-scoring grid positions when the first fails"
    )
    history_snapshots: int = Field(4, ge=0, le=50, description="particle snapshots kept for the report")
    snapshot_particles: int = Field(200, ge=1, description="particles kept per snapshot")
    map_l_occ: float = Field(0.85, gt=0, description="log-odds of an echo cell in m_i")
    map_l_free: float = Field(-0.4, lt=0, description="log-odds of a free cell in m_i")
    map_free: Literal["cone", "step", "axis"] = Field(
        "cone", description="part of the beam cone marked free in m_i in front of the echo"
    )
    min_informative: float = Field(
        1.0, gt=0, le=1, description="weight = sum over beams / max(informative beams, this share of beams)"
    )
    map_occupied: Literal["cone", "step", "axis"] = Field(
        "step", description="part of the beam cone marked occupied in m_i: all, one beam step, the axis"
    )
    unknown_score: float = Field(
        0.0, ge=-1, le=1, description="contribution of a beam whose end lies where m_i has no evidence (paper: -1)"
    )
    refine: Literal["none", "point-to-line"] = Field(
        "point-to-line", description="refine a verified estimate by point-to-line ICP of the two scans' echoes"
    )
    refine_iterations: int = Field(30, ge=1, description="most ICP iterations of the refinement")
    refine_correspondence_m: float = Field(0.3, gt=0, description="refinement: farthest paired echoes (m)")
    refine_trim_fraction: float = Field(0.8, gt=0, le=1, description="refinement: share of closest pairs kept")
    refine_max_shift_m: float = Field(
        0.2, gt=0, description="a refinement moving the estimate farther than this is discarded (m)"
    )

    @classmethod
    def paper(cls, **changes) -> "PFParams":
        """McVicker et al.'s filter exactly as written (:data:`PAPER_CONFIGURATION`), with ``changes``."""
        return cls(**{**PAPER_CONFIGURATION, **changes})


PAPER_CONFIGURATION = {
    "measurement_model": "raycast",
    "resample_weighting": "shifted",
    "init_oversample": 1,
    "unknown_score": -1.0,
    "map_occupied": "cone",
    "map_free": "cone",
    "min_informative": 1.0,
    "verify": False,
    "verify_fit": False,
    "restarts": 0,
    "refine": "none",
    "max_beams": 100_000,
    "cell_m": 0.05,
    "chi_w": 2.0 / 7.0,
    "chi_sigma": 2.0 / 5.0,
}
"""The paper's method (Tables I–II, eqs. 3–6): ray casting, proportional resampling, a uniform start,
every disagreeing beam penalised, cone walls, every beam, no verification and no refinement. ``tau_pw``
stays in this plugin's per-beam units (the paper's 6.0 was a sum over its beams)."""


@dataclass(frozen=True)
class SearchWindow:
    """The square of positions the filter searches: centre ``(x_m, y_m)``, half side ``half_m``, and the
    centre ``theta_rad`` of the heading correction's initial distribution."""

    x_m: float
    y_m: float
    half_m: float
    theta_rad: float = 0.0
    guided: bool = False

    @classmethod
    def initial(cls, p: PFParams) -> "SearchWindow":
        """The paper's ``L_init`` square around the reference sonar, θ around the compass difference."""
        return cls(0.0, 0.0, 0.5 * p.l_init_m)

    @classmethod
    def around(cls, guess: MatchGuess) -> "SearchWindow":
        return cls(guess.dx_m, guess.dy_m, guess.radius_m, guess.dyaw_rad, guided=True)

    def offset(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Chebyshev distance of positions from the centre (the square's 'radius' at them)."""
        return np.maximum(np.abs(np.asarray(x) - self.x_m), np.abs(np.asarray(y) - self.y_m))

    def describe(self) -> str:
        if not self.guided:
            return f"the {2 * self.half_m:g} m search square; the true offset may lie outside it (raise l_init_m)"
        return (f"the ±{self.half_m:g} m search window around the guess ({self.x_m:.2f}, {self.y_m:.2f}); "
                "the true offset may lie outside it")


@dataclass(frozen=True, eq=False)
class _Beams:
    """The moving scan's beams used for weighting: range and map-frame direction at θ = 0."""

    ranges: np.ndarray
    cos: np.ndarray
    sin: np.ndarray


@dataclass(frozen=True, eq=False)
class _MapModel:
    """``m_i`` ready for weighting: occupancy look-up and the precomputed likelihood field."""

    dense: DenseMap
    lookup: OccupancyLookup
    score_flat: np.ndarray
    known_flat: np.ndarray
    coarse_flat: np.ndarray


class PFPairwiseMatcher:
    """Particle-filter pair-wise matcher (``pf-pairwise``)."""

    name: ClassVar[str] = "pf-pairwise"
    Params: ClassVar[type[StageParams]] = PFParams

    def __init__(self) -> None:
        self._maps: OrderedDict[bytes, _MapModel] = OrderedDict()

    # ------------------------------------------------------------------------------------ API
    def match(
        self, reference: RangeScan, moving: RangeScan, params: StageParams, *, rng: np.random.Generator,
        guess: MatchGuess | None = None,
    ) -> MatchResult:
        """Locate ``moving`` in the map of ``reference`` (Table II); ``i = j = -1``.

        Without a ``guess`` the particles start uniform in the ``L_init`` square around the origin;
        with one, in the square ``±guess.radius_m`` around the guessed offset, θ around its heading
        correction (:class:`SearchWindow`); verification still looks for rivals over an ``L_init``
        square around it (:func:`verify_unique`).
        """
        p = PFParams.of(params)
        start = time.perf_counter()
        refusal = _refuse(reference, moving, p)
        if refusal:
            return MatchResult.no_estimate(refusal, seconds=time.perf_counter() - start, weight=float("nan"))
        model = self._map(reference, p)
        if not model.lookup.any_occupied:
            return MatchResult.no_estimate(
                f"map of the reference scan has no cell above weight_threshold={p.weight_threshold}",
                seconds=time.perf_counter() - start, weight=float("nan"),
            )
        beams = _select_beams(moving, p.max_beams)
        window = SearchWindow.around(guess) if guess is not None else SearchWindow.initial(p)
        return _run_filter(model, beams, p, rng, start, fit_check(reference, moving, p), window)

    # ------------------------------------------------------------------------------------ map
    def _map(self, reference: RangeScan, p: PFParams) -> _MapModel:
        """``m_i`` of Table I line 2, cached for the few pairs that share a reference scan."""
        key = _map_key(reference, p)
        if key in self._maps:
            self._maps.move_to_end(key)
            return self._maps[key]
        sonar = SonarModel(
            l_occ=p.map_l_occ, l_free=p.map_l_free, free_no_echo=False,
            occupied_width_rad=occupied_width(reference, p.map_occupied),
            free_width_rad=occupied_width(reference, p.map_free),
        )
        dense = dense_scan_map(reference, cell_m=p.cell_m, model=sonar, margin_m=p.delta_max_m + p.cell_m)
        lookup = OccupancyLookup(dense.occupied(p.weight_threshold), dense.origin_xy_m, dense.cell_m)
        known = np.zeros((dense.log_odds.shape[0] + 2, dense.log_odds.shape[1] + 2), dtype=bool)
        known[1:-1, 1:-1] = dense.log_odds != 0
        known = known.ravel()

        def field(sigma_c: float) -> np.ndarray:
            score = _score(lookup.distance_flat, p, sigma_c)
            return np.where(known | (score > 0), score, np.float32(p.unknown_score)).astype(np.float32)

        model = _MapModel(
            dense=dense, lookup=lookup, score_flat=field(2.0 * p.cell_m), known_flat=known,
            coarse_flat=field(max(2.0 * p.cell_m, p.verify_step_m)),
        )
        self._maps[key] = model
        while len(self._maps) > 4:
            self._maps.popitem(last=False)
        return model


# ------------------------------------------------------------------------------------ helpers
def _map_key(scan: RangeScan, p: PFParams) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(scan.bearings_rad).tobytes())
    h.update(np.ascontiguousarray(scan.ranges_m).tobytes())
    h.update(repr((scan.yaw_rad, scan.bin_size_m, scan.beam_width_rad, scan.max_range_m)).encode())
    h.update(repr((p.cell_m, p.weight_threshold, p.map_l_occ, p.map_l_free, p.delta_max_m,
                   p.map_occupied, p.map_free, p.unknown_score, p.verify_step_m)).encode())
    return h.digest()


def occupied_width(scan: RangeScan, mode: str) -> float | None:
    """Angular width marked occupied around each echo in ``m_i`` (``None``: the whole beam cone)."""
    if mode == "cone":
        return None
    if mode == "axis" or scan.bearings_rad.size < 2:
        return 0.0
    b = np.sort((np.asarray(scan.bearings_rad) + np.pi) % (2 * np.pi) - np.pi)
    gaps = np.diff(np.append(b, b[0] + 2 * np.pi))
    return float(np.median(gaps[gaps > 1e-9])) if np.any(gaps > 1e-9) else 0.0


def _score(distance: np.ndarray, p: PFParams, sigma_c: float | None = None) -> np.ndarray:
    """Per-beam contribution of eqs. 3–4 as a function of ``|δs - δm|`` (float32); σc = 2 r_c by default."""
    sigma_c = 2.0 * p.cell_m if sigma_c is None else sigma_c
    d = distance.astype(np.float64)
    phi = np.exp(-(d * d) / (2.0 * sigma_c * sigma_c))
    return np.where(d < p.delta_max_m, phi, -(1.0 - phi)).astype(np.float32)


def _refuse(reference: RangeScan, moving: RangeScan, p: PFParams) -> str:
    """Why a pair cannot be matched at all (empty string if it can)."""
    for label, scan in (("reference", reference), ("moving", moving)):
        n = int(np.count_nonzero(scan.valid))
        if n == 0:
            return f"{label} scan has no echoes (every beam empty)"
        if n < p.min_beams:
            return f"{label} scan has {n} echoes, fewer than min_beams={p.min_beams}"
    return ""


def _select_beams(scan: RangeScan, max_beams: int) -> _Beams:
    idx = np.flatnonzero(scan.valid)
    if idx.size > max_beams:
        idx = idx[np.linspace(0, idx.size - 1, max_beams).round().astype(np.int64)]
    angle = scan.yaw_rad + scan.bearings_rad[idx]
    return _Beams(ranges=scan.ranges_m[idx], cos=np.cos(angle), sin=np.sin(angle))


def _weigh(model: _MapModel, beams: _Beams, particles: np.ndarray, p: PFParams) -> np.ndarray:
    """Mean per-beam weight (eqs. 3–4) of every particle, shape (P,)."""
    x, y, th = particles[:, 0:1], particles[:, 1:2], particles[:, 2:3]
    c, s = np.cos(th), np.sin(th)
    ux = c * beams.cos - s * beams.sin  # (P, B) beam directions
    uy = s * beams.cos + c * beams.sin
    n_beams = beams.ranges.size
    if p.measurement_model == "distance-field":
        flat = model.lookup.flat_index(x + beams.ranges * ux, y + beams.ranges * uy)
        total = model.score_flat[flat].sum(axis=1, dtype=np.float64)
        if p.min_informative >= 1.0:
            return total / n_beams
        informative = (model.known_flat[flat] | (model.score_flat[flat] > 0)).sum(axis=1)
        return total / np.maximum(informative, p.min_informative * n_beams)
    angle = np.arctan2(uy, ux)
    hit = model.lookup.sphere_trace(x, y, angle, beams.ranges + p.delta_max_m)
    diff = np.where(np.isfinite(hit), np.abs(beams.ranges - hit), FAR_M)
    sigma_c = 2.0 * p.cell_m
    phi = np.exp(-(diff * diff) / (2.0 * sigma_c * sigma_c))
    score = np.where(diff < p.delta_max_m, phi, -(1.0 - phi))
    if p.unknown_score == -1.0 and p.min_informative >= 1.0:
        return score.mean(axis=1)
    end_known = model.known_flat[model.lookup.flat_index(x + beams.ranges * ux, y + beams.ranges * uy)]
    informative = np.isfinite(hit) | end_known
    score = np.where(informative, score, p.unknown_score)
    if p.min_informative >= 1.0:
        return score.mean(axis=1)
    return score.sum(axis=1) / np.maximum(informative.sum(axis=1), p.min_informative * n_beams)


def _low_variance(probabilities: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn by systematic (low-variance) resampling (Thrun et al. 2005, Table 4.4)."""
    cumulative = np.cumsum(probabilities)
    cumulative /= cumulative[-1]
    points = (rng.random() + np.arange(n)) / n
    return np.minimum(np.searchsorted(cumulative, points, side="right"), probabilities.size - 1)


def _resample_probabilities(w: np.ndarray, p: PFParams) -> np.ndarray:
    if p.resample_weighting == "shifted":
        shifted = w - w.min()
        total = shifted.sum()
        return shifted if total > 0 else np.ones_like(w)
    return np.exp(p.sharpness * (w - w.max()))


def _spread(particles: np.ndarray) -> float:
    """σ_p of eq. 5: the larger of the x and y standard deviations."""
    return float(max(particles[:, 0].std(), particles[:, 1].std()))


class _History:
    """Collects the per-iteration averages and a few particle snapshots."""

    def __init__(self, p: PFParams):
        self.p = p
        self.weight: list[float] = []
        self.std: list[float] = []
        self.snaps: list[tuple[int, np.ndarray]] = []

    def record(self, iteration: int, w_avg: float, s_avg: float, particles: np.ndarray, w: np.ndarray) -> None:
        self.weight.append(w_avg)
        self.std.append(s_avg)
        if self.p.history_snapshots and (iteration & (iteration - 1)) == 0:
            self.snaps.append((iteration, self._snapshot(particles, w)))

    def _snapshot(self, particles: np.ndarray, w: np.ndarray) -> np.ndarray:
        k = min(len(particles), self.p.snapshot_particles)
        idx = np.linspace(0, len(particles) - 1, k).round().astype(np.int64)
        return np.column_stack([particles[idx], w[idx]]).astype(np.float32)

    def finish(self, iteration: int, particles: np.ndarray, w: np.ndarray) -> MatchHistory:
        if self.p.history_snapshots == 0:
            return MatchHistory(weight_avg=np.array(self.weight), std_avg=np.array(self.std))
        if not self.snaps or self.snaps[-1][0] != iteration:
            self.snaps.append((iteration, self._snapshot(particles, w)))
        n = min(self.p.history_snapshots, len(self.snaps))
        pick = sorted(set(np.linspace(0, len(self.snaps) - 1, n).round().astype(int).tolist()))
        chosen = [self.snaps[k] for k in pick]
        return MatchHistory(
            weight_avg=np.array(self.weight),
            std_avg=np.array(self.std),
            snapshots=tuple(s for _, s in chosen),
            snapshot_iterations=tuple(int(t) for t, _ in chosen),
        )


def _initial_particles(n: int, p: PFParams, rng: np.random.Generator, window: SearchWindow) -> np.ndarray:
    """Uniform in the search square (the L_init × L_init square around the origin without a guess); θ
    around the window's heading (the compass difference without a guess)."""
    xy = rng.uniform(-window.half_m, window.half_m, size=(n, 2)) + np.array([window.x_m, window.y_m])
    theta = rng.normal(window.theta_rad, math.radians(p.theta_init_std_deg), size=(n, 1))
    return np.hstack([xy, theta])


@dataclass(frozen=True, eq=False)
class _Outcome:
    """One run of the filter: the estimate, whether it converged and verified, and why not."""

    estimate: tuple[float, float, float]
    weight: float
    converged: bool
    iterations: int
    reason: str
    covariance: np.ndarray
    history: MatchHistory


class PairFit:
    """The reference scan's points (built on first use) and what the filter's estimate is checked and
    refined with: :meth:`__call__` is the fit check of :func:`fit_check`, :meth:`refine` the
    point-to-line refinement of ``refine``."""

    def __init__(self, reference: RangeScan, moving: RangeScan, p: PFParams):
        self.reference, self.moving, self.p = reference, moving, p
        self._model: ReferenceModel | None = None

    @property
    def model(self) -> ReferenceModel:
        if self._model is None:
            self._model = ReferenceModel(self.reference)
        return self._model

    def __call__(self, estimate: tuple[float, float, float]) -> str:
        """Why ``estimate`` fails the shared verdict ("" if it passes, or if ``verify_fit`` is off)."""
        p = self.p
        if not p.verify_fit:
            return ""
        limits = p.limits()
        quality = self.model.assess_pair(self.moving, np.array(estimate), limits)
        why = verdict(quality, limits)
        if not why and quality.inlier_ratio < p.partial_inlier_ratio:
            why = verdict(quality, replace(limits, max_violation_ratio=p.partial_max_violation))
        return f"fit check: {why}" if why else ""

    def refine(self, estimate: tuple[float, float, float]) -> tuple[tuple[float, float, float], np.ndarray | None]:
        """``estimate`` refined by trimmed point-to-line ICP of the moving scan's echoes against the
        reference scan's (:func:`cistern_plugins.icp.refine_point_to_line`), with the covariance of the point-to-line
        fit (:func:`cistern_plugins.icp.fit_covariance`: along a plain gallery it is long along the
        axis, which a pose graph needs to know); unchanged with no covariance when ``refine`` is off,
        the scans have too few echoes, or the refinement moves farther than ``refine_max_shift_m``.

        The likelihood field scores how many beams land on the sampled walls of ``m_i``; walls are
        sampled densely near each sonar and sparsely far from it, so the score favours placements that
        bring the two scans' dense parts together and converged estimates are short by a few
        centimetres (``benchmarks/RESULTS.md``). Point-to-line distances do not depend on how densely
        a wall is sampled.
        """
        p = self.p
        if p.refine == "none" or self.model.tree is None or len(self.model.points) < 3:
            return estimate, None
        src = scan_points(self.moving)
        if len(src) < 3:
            return estimate, None
        pose = refine_point_to_line(self.model, src, np.array(estimate), iterations=p.refine_iterations,
                                    correspondence_m=p.refine_correspondence_m,
                                    trim_fraction=p.refine_trim_fraction, max_shift_m=p.refine_max_shift_m)
        if pose is None:
            return estimate, None
        rms = self.model.assess(transform(src, pose), p.inlier_distance_m).rms_m
        covariance = fit_covariance(self.model, src, pose, p.inlier_distance_m, rms)
        return (float(pose[0]), float(pose[1]), float(pose[2])), covariance


def fit_check(reference: RangeScan, moving: RangeScan, p: PFParams) -> PairFit:
    """The shared convergence verdict of the point matchers (:func:`cistern_plugins.alignment.verdict`)
    as a check of a verified estimate: calling the result gives why an estimate fails ("" if it passes,
    or if ``verify_fit`` is off).

    With the defaults the inlier count and the inlier share (seen from both scans) apply to every
    estimate, and the free-space test (``partial_max_violation``) to those whose inlier share is below
    ``partial_inlier_ratio``; the corridor tests (``min_constraint``, ``max_weak_std_m``) and the general
    free-space limit (``max_violation_ratio``) are off, as :func:`verify_unique` judges ambiguity with the
    map itself and correct matches of segmented sonar scans can put a fifth of their wall points in the
    other scan's free space. The reference's points, tree and free space are built on the first call.
    """
    return PairFit(reference, moving, p)


def _run_filter(
    model: _MapModel, beams: _Beams, p: PFParams, rng: np.random.Generator, start: float,
    check: PairFit, window: SearchWindow,
) -> MatchResult:
    """Table II from a uniform start; if it fails, up to ``restarts`` filters started at the best
    positions of the coarse score grid (:func:`grid_modes`). The first run that converges and passes
    :func:`verify_unique` and ``check`` (:func:`fit_check`) is reported; if none does, the first run and
    its reason."""
    first = _filter(model, beams, p, rng, _initial_particles(p.n_particles * p.init_oversample, p, rng, window),
                    check, window)
    outcome = first
    if not first.converged and p.restarts > 0 and first.iterations > 0:
        for x, y in grid_modes(model, beams, window.theta_rad, p, p.restarts, window):
            xy = np.array([x, y]) + rng.normal(0.0, p.verify_step_m / 2.0, size=(p.n_particles, 2))
            theta = rng.normal(window.theta_rad, math.radians(p.theta_init_std_deg), size=(p.n_particles, 1))
            attempt = _filter(model, beams, p, rng, np.hstack([xy, theta]), check, window)
            if attempt.converged:
                outcome = attempt
                break
    if not outcome.converged and p.restarts > 0 and first.iterations > 0:
        outcome = _Outcome(**{**first.__dict__, "reason": first.reason + f" (and after {p.restarts} restarts)"})
    dx, dy, theta = outcome.estimate
    return MatchResult(
        i=-1, j=-1, dx_m=dx, dy_m=dy, dyaw_rad=theta, weight=outcome.weight, converged=outcome.converged,
        iterations=outcome.iterations, seconds=time.perf_counter() - start, reason=outcome.reason,
        covariance=outcome.covariance, history=outcome.history,
    )


def _filter(model: _MapModel, beams: _Beams, p: PFParams, rng: np.random.Generator, particles: np.ndarray,
            check: PairFit, window: SearchWindow) -> _Outcome:
    """Table II: propagate, weigh, average (eqs. 5–6), resample, until converged or Num_Iterations;
    then :func:`verify_unique` if ``verify`` and ``check``."""
    noise = np.array([p.sigma_n_xy_m, p.sigma_n_xy_m, math.radians(p.sigma_n_theta_deg)])
    history = _History(p)
    w_avg = s_avg = float("nan")
    converged = False
    iteration = 0
    w = np.zeros(len(particles))
    for iteration in range(p.n_iterations):
        if iteration > 0:
            particles = particles + rng.normal(0.0, 1.0, particles.shape) * noise
        w = _weigh(model, beams, particles, p)
        w_now, s_now = float(w.mean()), _spread(particles)
        if iteration == 0:
            w_avg, s_avg = w_now, s_now
        else:
            w_avg = p.chi_w * w_now + (1.0 - p.chi_w) * w_avg
            s_avg = p.chi_sigma * s_now + (1.0 - p.chi_sigma) * s_avg
        history.record(iteration, w_avg, s_avg, particles, w)
        keep = _low_variance(_resample_probabilities(w, p), p.n_particles, rng)
        particles, w = particles[keep], w[keep]
        if s_avg <= p.cell_m and w_avg >= p.tau_pw:
            converged = True
            break
    iterations = iteration + 1
    reason = "" if converged else _why(w_avg, s_avg, iterations, p)
    theta = math.atan2(float(np.sin(particles[:, 2]).mean()), float(np.cos(particles[:, 2]).mean()))
    dx, dy = float(particles[:, 0].mean()), float(particles[:, 1].mean())
    if converged and p.verify:
        reason = verify_unique(model, beams, (dx, dy, theta), p, window)
        converged = not reason
    covariance = np.cov(particles.T)
    if converged:
        (dx, dy, theta), fit = check.refine((dx, dy, theta))
        covariance = covariance if fit is None else fit
        reason = check((dx, dy, theta))
        converged = not reason
    return _Outcome(
        estimate=(dx, dy, theta), weight=w_avg, converged=converged, iterations=iterations, reason=reason,
        covariance=covariance, history=history.finish(iteration, particles, w),
    )


def _grid_scores(model: _MapModel, beams: _Beams, theta: float, p: PFParams, window: SearchWindow,
                 extra: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions of the search square on a ``verify_step_m`` grid (plus ``extra``, last) and their
    mean per-beam scores in the likelihood field smoothed to that step, the heading fixed at ``theta``."""
    if beams.ranges.size > p.verify_beams:
        keep = np.linspace(0, beams.ranges.size - 1, p.verify_beams).round().astype(np.int64)
        beams = _Beams(ranges=beams.ranges[keep], cos=beams.cos[keep], sin=beams.sin[keep])
    axis = np.arange(-window.half_m, window.half_m + 1e-9, p.verify_step_m)
    gx, gy = np.meshgrid(axis + window.x_m, axis + window.y_m)
    cand = np.column_stack([gx.ravel(), gy.ravel()])
    if extra is not None:
        cand = np.vstack([cand, np.array(extra)[None, :]])
    c, s = math.cos(theta), math.sin(theta)
    ux = c * beams.cos - s * beams.sin
    uy = s * beams.cos + c * beams.sin
    flat = model.lookup.flat_index(cand[:, 0:1] + beams.ranges * ux, cand[:, 1:2] + beams.ranges * uy)
    return cand, model.coarse_flat[flat].mean(axis=1, dtype=np.float64)


def grid_modes(model: _MapModel, beams: _Beams, theta: float, p: PFParams, k: int,
               window: SearchWindow | None = None) -> list[tuple[float, float]]:
    """The ``k`` best-scoring grid positions of the search square (by default the ``L_init`` square), at
    least ``ambiguity_radius_m`` apart and not on its edge (positive scores only)."""
    window = window or SearchWindow.initial(p)
    cand, score = _grid_scores(model, beams, theta, p, window)
    score = np.where(window.offset(cand[:, 0], cand[:, 1]) <= window.half_m - p.verify_step_m, score, -np.inf)
    modes: list[tuple[float, float]] = []
    for _ in range(k):
        best = int(np.argmax(score))
        if not score[best] > 0:
            break
        modes.append((float(cand[best, 0]), float(cand[best, 1])))
        score = np.where(np.hypot(cand[:, 0] - cand[best, 0], cand[:, 1] - cand[best, 1]) > p.ambiguity_radius_m,
                         score, -np.inf)
    return modes


def crossing_fraction(model: _MapModel, beams: _Beams, estimate: tuple[float, float, float], p: PFParams) -> float:
    """Share of the beams whose ray, cast from the estimate, meets a wall of ``m_i`` more than ``δmax``
    before the beam's own echo (the free space scan ``j`` saw is a wall in scan ``i``'s map)."""
    dx, dy, theta = estimate
    angle = np.arctan2(beams.sin, beams.cos) + theta
    hit = model.lookup.sphere_trace(np.full(angle.shape, dx), np.full(angle.shape, dy), angle, beams.ranges)
    return float(np.mean(np.isfinite(hit) & (hit < beams.ranges - p.delta_max_m)))


def verify_unique(model: _MapModel, beams: _Beams, estimate: tuple[float, float, float], p: PFParams,
                  window: SearchWindow | None = None) -> str:
    """Why a converged estimate cannot be trusted ("" if it can).

    The particles can collapse onto one of several equally good places (a straight gallery, a
    symmetric room, a true offset outside the search square), and eqs. 5–6 cannot tell. First, more
    than ``max_crossing`` of the beams may not cross a wall of ``m_i`` (:func:`crossing_fraction`).
    Then, with the heading fixed at the estimate, every position of an ``L_init`` square (around the
    window's centre: the origin, or a guess) on a ``verify_step_m`` grid is scored with the likelihood
    field smoothed to that step; the estimate is rejected when a position more than
    ``ambiguity_radius_m`` away scores at least ``ambiguity_ratio`` of the estimate's score, or when the
    estimate lies within one step of the edge of the searched square (``window``: the ``L_init`` square
    by default, the guess's window for a guided match).
    """
    dx, dy, theta = estimate
    window = window or SearchWindow.initial(p)
    if window.offset(dx, dy) > window.half_m - p.verify_step_m:
        return f"estimate ({dx:.2f}, {dy:.2f}) m is at the edge of {window.describe()}"
    crossing = crossing_fraction(model, beams, estimate, p)
    if crossing > p.max_crossing:
        return (f"{100 * crossing:.0f} % of the beams pass through walls of the reference map before their "
                f"echo (more than max_crossing={p.max_crossing:g}): the scans contradict each other here")
    around = replace(window, half_m=max(window.half_m, 0.5 * p.l_init_m))
    cand, score = _grid_scores(model, beams, theta, p, around, extra=(dx, dy))
    best = max(float(score[-1]), float(score[:-1][np.hypot(cand[:-1, 0] - dx, cand[:-1, 1] - dy) <= p.verify_step_m].max(initial=-1.0)))
    far = np.hypot(cand[:-1, 0] - dx, cand[:-1, 1] - dy) > p.ambiguity_radius_m
    if not far.any() or best <= 0:
        return "" if best > 0 else f"estimate scores {best:.3f} on the verification grid"
    k = int(np.argmax(np.where(far, score[:-1], -np.inf)))
    rival = float(score[k])
    if rival >= p.ambiguity_ratio * best:
        dist = math.hypot(cand[k, 0] - dx, cand[k, 1] - dy)
        return (f"ambiguous: a position {dist:.2f} m away ({cand[k, 0]:.2f}, {cand[k, 1]:.2f}) scores "
                f"{rival:.3f} against {best:.3f} at the estimate (repetitive or featureless walls)")
    return ""


def _why(w_avg: float, s_avg: float, iterations: int, p: PFParams) -> str:
    problems = []
    if w_avg < p.tau_pw:
        problems.append(
            f"weight average {w_avg:.3f} below tau_pw={p.tau_pw:g} (too few beams agree with the map: "
            "the scans may not overlap, or the compass is off)"
        )
    if s_avg > p.cell_m:
        problems.append(
            f"particle spread {s_avg:.3f} m above r_c={p.cell_m:g} m (position ambiguous)"
        )
    return f"not converged after {iterations} iterations: " + "; ".join(problems)
