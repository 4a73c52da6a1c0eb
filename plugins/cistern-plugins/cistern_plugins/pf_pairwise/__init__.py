"""``pf-pairwise``: pair-wise scan matching with a particle filter (McVicker et al., Tables I–II, eqs. 3–6).

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
  ``filter.unknown_score`` instead of the penalty: ``-1`` reproduces the paper (every disagreeing beam is
  penalised, so a pair with 50 % overlap scores about ``0.5 * 0.85 - 0.5 = -0.08`` at the right
  place); the default ``0`` treats "no evidence" as neither agreement nor contradiction, so the weight
  at the right place is about the overlap fraction times the agreement, while beams that end in
  space ``m_i`` saw as free are still penalised.
* **Walls of m_i** – the inverse model marks the echo range occupied over ``map.occupied``: the whole
  beam cone (``"cone"``, the classic model), one beam step around the axis (``"step"``, default: walls
  stay contiguous but a wall seen at a grazing angle is not smeared across a 3° cone into open water,
  which in a 1.4 m gallery puts phantom walls in mid-channel), or the axis alone (``"axis"``).
* **δm** – ``filter.measurement_model="raycast"`` casts a ray from the particle along the beam to the first
  cell of ``m_i`` whose occupancy probability exceeds ``map.weight_threshold`` (sphere tracing over the
  distance field, which returns the same first hit as a half-cell march, see
  :mod:`cistern_archive.grid.raycast`). ``"distance-field"`` is the likelihood-field
  approximation: ``|δs - δm|`` is replaced by the distance from the beam's end point to the nearest
  occupied cell, so the per-cell contribution is precomputed once per map and a particle costs one
  look-up per beam. It ignores walls crossed before the echo; it is ~10× faster (see
  ``benchmarks/RESULTS.md``).
* **Resampling** – low-variance (systematic) resampling. ``filter.resample_weighting="shifted"`` draws with
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
The parameters come in sections, one per step (:mod:`~cistern_plugins.pf_pairwise.params`): ``filter``
(Table II and eqs. 3–6), ``map`` (``m_i``), ``verify``, ``refine`` and ``history``. The defaults are the
measured best (``benchmarks/RESULTS.md``); the paper's method is :meth:`PFParams.paper`
(:data:`PAPER_CONFIGURATION`: ``filter.measurement_model="raycast", filter.resample_weighting="shifted",
filter.init_oversample=1, filter.unknown_score=-1, map.occupied="cone", map.free="cone",
verify.unique=False, verify.fit.enabled=False, filter.restarts=0, refine.method="none"``, every beam).
The departures:

* ``filter.init_oversample`` – the first iteration weighs that many uniform samples per particle and
  keeps ``n_particles`` of them (a coarse search before the fine filter);
* ``filter.resample_weighting="exponential"``, ``filter.unknown_score=0`` and ``map.occupied="step"``
  (above);
* ``verify.unique`` – a converged estimate is checked before it is reported
  (:func:`~cistern_plugins.pf_pairwise.verification.verify_unique`): it may not sit on the edge of the
  search square, more than ``max_crossing`` of its beams may not pass through walls of ``m_i``, and no
  position farther than ``ambiguity_radius_m`` may score nearly as well. Eqs. 5–6 alone accept a filter
  that collapsed onto one of several equally good places.
* ``verify.fit`` – a verified estimate must also pass the convergence verdict the point matchers share
  (:func:`cistern_plugins.registration.verdict`,
  :func:`~cistern_plugins.pf_pairwise.verification.fit_check`): at least ``min_inliers`` echo points
  of either scan within ``inlier_distance_m`` of the other's and an inlier share of at least
  ``min_inlier_ratio`` (0.25) both ways; a fit whose inlier share is below ``partial_inlier_ratio``
  (0.5) may in addition put no more than ``partial_max_violation`` (20 %) of its wall points in the
  free space the other sonar saw. The likelihood field rewards the beams that land on walls and is
  blind to how few they are: without this check 2 of 60 pairs of scans of different sites converged
  (seed 1 of ``benchmarks/matchers.py``), all with inlier shares of 0.14–0.34. The corridor tests of
  the verdict (``min_constraint``, ``max_weak_std_m``) and its general free-space limit are off by
  default: the ambiguity search covers the first, and correct matches of segmented sonar scans put up
  to 22 % of their wall points in the other scan's free space (smeared echoes at grazing incidence).
* ``filter.min_informative < 1`` (off by default) normalises the weight by the beams that land where
  ``m_i`` has evidence instead of by all beams; ``map.free`` narrows the free-space cone of ``m_i``.
* ``refine.method="point-to-line"`` – a verified estimate is refined by trimmed point-to-line ICP of the
  two scans' echoes (pairs within ``refine.correspondence_m``, the closest ``refine.trim_fraction``
  kept) and reported with that fit's covariance, unless the refinement moves it more than
  ``refine.max_shift_m`` (see "Limits"); the fit check then judges the refined estimate.
* ``guess`` – a localizer may ask for a pair with a
  :class:`~cistern_archive.pipeline.contracts.MatchGuess`; the particles then start in the square
  ``±radius_m`` around it (:class:`SearchWindow`) and θ around its heading correction. The ambiguity
  search still covers an ``L_init`` square around the guess: a window as small as the guess's cannot
  hold a rival ``ambiguity_radius_m`` away, and a wrong match inside it would pass.
* ``filter.restarts > 0`` (off by default): when the filter from the uniform start fails (not converged
  or rejected by verification), up to that many filters are restarted around the best positions of the
  coarse score grid that verification uses
  (:func:`~cistern_plugins.pf_pairwise.verification.grid_modes`), and the first one that converges and
  verifies is reported. On the demo gallery it recovered one pair and let two more wrong ones through
  (``benchmarks/RESULTS.md``), so it stays off.

The steps are one module each: :mod:`~cistern_plugins.pf_pairwise.params` (the sections),
:mod:`~cistern_plugins.pf_pairwise.likelihood` (``m_i`` and eqs. 3–4),
:mod:`~cistern_plugins.pf_pairwise.particle_filter` (Table II, eqs. 5–6),
:mod:`~cistern_plugins.pf_pairwise.verification`, :mod:`~cistern_plugins.pf_pairwise.refinement`,
:mod:`~cistern_plugins.pf_pairwise.history` (what the report draws) and
:mod:`~cistern_plugins.pf_pairwise.matcher` (refuse → map → filter → verify → refine).

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

from cistern_plugins.pf_pairwise.likelihood import Beams, LikelihoodMap, beam_score, select_beams
from cistern_plugins.pf_pairwise.matcher import PFPairwiseMatcher
from cistern_plugins.pf_pairwise.pair import ScanPair
from cistern_plugins.pf_pairwise.params import MOVED, PAPER_CONFIGURATION, PFParams
from cistern_plugins.pf_pairwise.refinement import refine_estimate
from cistern_plugins.pf_pairwise.verification import crossing_fraction, fit_check, grid_modes, verify_unique
from cistern_plugins.pf_pairwise.window import SearchWindow

__all__ = [
    "MOVED",
    "PAPER_CONFIGURATION",
    "Beams",
    "LikelihoodMap",
    "PFPairwiseMatcher",
    "PFParams",
    "ScanPair",
    "SearchWindow",
    "beam_score",
    "crossing_fraction",
    "fit_check",
    "grid_modes",
    "refine_estimate",
    "select_beams",
    "verify_unique",
]
