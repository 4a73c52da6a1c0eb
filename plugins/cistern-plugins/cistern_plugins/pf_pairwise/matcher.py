"""The ``pf-pairwise`` matcher: refuse → map → filter → verify → refine, restarted when asked."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from cistern_archive.core.scan import RangeScan
from cistern_archive.pipeline.contracts import MatchGuess, MatchResult, StageParams
from cistern_plugins.pf_pairwise.likelihood import Beams, LikelihoodMap, MapCache, select_beams
from cistern_plugins.pf_pairwise.pair import ScanPair
from cistern_plugins.pf_pairwise.params import PFParams
from cistern_plugins.pf_pairwise.particle_filter import Outcome, particles_around, run_filter, uniform_particles
from cistern_plugins.pf_pairwise.refinement import refine
from cistern_plugins.pf_pairwise.verification import check_fit, grid_modes, verify
from cistern_plugins.pf_pairwise.window import SearchWindow


@dataclass(frozen=True, eq=False)
class PairSearch:
    """Everything one pair's filters share: the map of the reference scan, the moving scan's beams,
    the window searched, the two scans' echoes and the parameters."""

    model: LikelihoodMap
    beams: Beams
    window: SearchWindow
    pair: ScanPair
    p: PFParams


class PFPairwiseMatcher:
    """Particle-filter pair-wise matcher (``pf-pairwise``)."""

    name: ClassVar[str] = "pf-pairwise"
    Params: ClassVar[type[StageParams]] = PFParams

    def __init__(self) -> None:
        self._maps = MapCache()

    def match(
        self, reference: RangeScan, moving: RangeScan, params: StageParams, *, rng: np.random.Generator,
        guess: MatchGuess | None = None,
    ) -> MatchResult:
        """Locate ``moving`` in the map of ``reference`` (Table II); ``i = j = -1``.

        Without a ``guess`` the particles start uniform in the ``L_init`` square around the origin;
        with one, in the square ``±guess.radius_m`` around the guessed offset, θ around its heading
        correction (:class:`SearchWindow`); verification still looks for rivals over an ``L_init``
        square around it (:func:`~cistern_plugins.pf_pairwise.verification.verify_unique`).
        """
        p = PFParams.of(params).for_scans(reference, moving)
        start = time.perf_counter()
        why = refuse(reference, moving, p)
        model = None if why else self.likelihood_map(reference, p)
        why = why or empty_map(model, p)
        if why:
            return MatchResult.no_estimate(why, seconds=time.perf_counter() - start, weight=float("nan"))
        search = PairSearch(model, select_beams(moving, p.filter.max_beams), SearchWindow.of(guess, p),
                            ScanPair(reference, moving), p)
        outcome = attempt(search, uniform_start(search, rng), rng)  # filter → verify → refine
        outcome = restart(search, outcome, rng)  # from the best grid positions, when asked and it failed
        return outcome.result(time.perf_counter() - start)

    def likelihood_map(self, reference: RangeScan, p: PFParams) -> LikelihoodMap:
        """``m_i`` of Table I line 2, cached for the few pairs that share a reference scan."""
        return self._maps.get(reference, p)


def attempt(search: PairSearch, particles: np.ndarray, rng: np.random.Generator) -> Outcome:
    """One filter from ``particles``, its estimate verified and refined: the filter (Table II), the
    uniqueness check in ``m_i``, the point-to-line refinement, then the fit check of the refined
    estimate (it judges the estimate that is reported)."""
    s, p = search, search.p
    outcome = run_filter(s.model, s.beams, p, rng, particles)
    outcome = verify(outcome, s.model, s.beams, p, s.window)
    outcome = refine(outcome, s.pair, p)
    return check_fit(outcome, s.pair, p)


def restart(search: PairSearch, first: Outcome, rng: np.random.Generator) -> Outcome:
    """``first`` if it converged or ``filter.restarts`` is 0; else the first of up to ``restarts``
    attempts started at the best positions of the coarse score grid (:func:`grid_modes`) that
    converges, or ``first`` with its reason when none does."""
    p = search.p
    if first.converged or p.filter.restarts == 0:
        return first
    for xy in grid_modes(search.model, search.beams, search.window.theta_rad, p, p.filter.restarts, search.window):
        outcome = attempt(search, particles_around(xy, p.verify.step_m / 2.0, p, rng, search.window), rng)
        if outcome.converged:
            return outcome
    return replace(first, reason=first.reason + f" (and after {p.filter.restarts} restarts)")


def uniform_start(search: PairSearch, rng: np.random.Generator) -> np.ndarray:
    """Table II, line 1: ``init_oversample`` × ``n_particles`` particles uniform in the window."""
    f = search.p.filter
    return uniform_particles(f.n_particles * f.init_oversample, search.p, rng, search.window)


def empty_map(model: LikelihoodMap, p: PFParams) -> str:
    """Why ``m_i`` cannot locate anything (empty string if it can)."""
    if model.lookup.any_occupied:
        return ""
    return f"map of the reference scan has no cell above weight_threshold={p.map.weight_threshold}"


def refuse(reference: RangeScan, moving: RangeScan, p: PFParams) -> str:
    """Why a pair cannot be matched at all (empty string if it can)."""
    for label, scan in (("reference", reference), ("moving", moving)):
        n = int(np.count_nonzero(scan.valid))
        if n == 0:
            return f"{label} scan has no echoes (every beam empty)"
        if n < p.filter.min_beams:
            return f"{label} scan has {n} echoes, fewer than min_beams={p.filter.min_beams}"
    return ""
