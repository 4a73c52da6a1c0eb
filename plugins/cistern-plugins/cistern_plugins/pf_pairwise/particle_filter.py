"""The particle filter of Table II: propagate, weigh (eqs. 3–4), average (eqs. 5–6), resample.

A particle is ``[x, y, θ]``: the position of the moving scan's sonar in the reference scan's frame and
a correction ``θ`` to its compass heading. :func:`run_filter` runs the filter from a set of particles
until eqs. 5–6 are met or ``n_iterations`` pass, and returns an :class:`Outcome` that verification and
refinement then judge and improve.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from cistern_archive.pipeline.contracts import MatchHistory, MatchResult
from cistern_plugins.pf_pairwise.history import ParticleHistory
from cistern_plugins.pf_pairwise.likelihood import Beams, LikelihoodMap, weigh
from cistern_plugins.pf_pairwise.params import PFParams
from cistern_plugins.pf_pairwise.window import SearchWindow


@dataclass(frozen=True, eq=False)
class Outcome:
    """One run of the filter: the estimate ``(dx, dy, θ)``, whether it converged (and passed the checks
    so far) and why not, the final weight average ``w_μ``, and the estimate's covariance."""

    estimate: tuple[float, float, float]
    weight: float
    converged: bool
    iterations: int
    reason: str
    covariance: np.ndarray | None
    history: MatchHistory

    def rejected(self, reason: str) -> "Outcome":
        """This outcome, not converged when ``reason`` is not empty."""
        return replace(self, converged=not reason, reason=reason)

    def result(self, seconds: float) -> MatchResult:
        """As the matcher's result (``i = j = -1``)."""
        dx, dy, theta = self.estimate
        return MatchResult(
            i=-1, j=-1, dx_m=dx, dy_m=dy, dyaw_rad=theta, weight=self.weight, converged=self.converged,
            iterations=self.iterations, seconds=seconds, reason=self.reason, covariance=self.covariance,
            history=self.history,
        )


def uniform_particles(n: int, p: PFParams, rng: np.random.Generator, window: SearchWindow) -> np.ndarray:
    """Table II, line 1: uniform in the search square (the L_init × L_init square around the origin
    without a guess); θ around the window's heading (the compass difference without a guess)."""
    xy = rng.uniform(-window.half_m, window.half_m, size=(n, 2)) + np.array([window.x_m, window.y_m])
    theta = rng.normal(window.theta_rad, math.radians(p.filter.theta_init_std_deg), size=(n, 1))
    return np.hstack([xy, theta])


def particles_around(xy: tuple[float, float], spread_m: float, p: PFParams, rng: np.random.Generator,
                     window: SearchWindow) -> np.ndarray:
    """``n_particles`` normal around ``xy`` (std ``spread_m``), θ around the window's heading: a restart."""
    cloud = np.array(xy) + rng.normal(0.0, spread_m, size=(p.filter.n_particles, 2))
    theta = rng.normal(window.theta_rad, math.radians(p.filter.theta_init_std_deg), size=(p.filter.n_particles, 1))
    return np.hstack([cloud, theta])


def run_filter(model: LikelihoodMap, beams: Beams, p: PFParams, rng: np.random.Generator,
               particles: np.ndarray) -> Outcome:
    """Table II from ``particles``: propagate (σn), weigh, average (eqs. 5–6), resample, until
    ``σ_p,μ ≤ r_c`` and ``w_μ ≥ tau_pw`` or ``n_iterations``. The estimate is the particles' mean
    position and circular mean θ after the last resampling, the covariance theirs."""
    f = p.filter
    noise = np.array([f.sigma_n_xy_m, f.sigma_n_xy_m, math.radians(f.sigma_n_theta_deg)])
    history = ParticleHistory(p)
    w_avg = s_avg = float("nan")
    converged = False
    iteration = 0
    w = np.zeros(len(particles))
    for iteration in range(f.n_iterations):
        if iteration > 0:
            particles = particles + rng.normal(0.0, 1.0, particles.shape) * noise
        w = weigh(model, beams, particles, p)
        w_now, s_now = float(w.mean()), spread(particles)
        if iteration == 0:
            w_avg, s_avg = w_now, s_now
        else:
            w_avg = f.chi_w * w_now + (1.0 - f.chi_w) * w_avg
            s_avg = f.chi_sigma * s_now + (1.0 - f.chi_sigma) * s_avg
        history.record(iteration, w_avg, s_avg, particles, w)
        keep = low_variance(resample_probabilities(w, p), f.n_particles, rng)
        particles, w = particles[keep], w[keep]
        if s_avg <= p.map.cell_m and w_avg >= f.tau_pw:
            converged = True
            break
    iterations = iteration + 1
    theta = math.atan2(float(np.sin(particles[:, 2]).mean()), float(np.cos(particles[:, 2]).mean()))
    return Outcome(
        estimate=(float(particles[:, 0].mean()), float(particles[:, 1].mean()), theta), weight=w_avg,
        converged=converged, iterations=iterations,
        reason="" if converged else not_converged(w_avg, s_avg, iterations, p),
        covariance=np.cov(particles.T), history=history.finish(iteration, particles, w),
    )


def low_variance(probabilities: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn by systematic (low-variance) resampling (Thrun et al. 2005, Table 4.4)."""
    cumulative = np.cumsum(probabilities)
    cumulative /= cumulative[-1]
    points = (rng.random() + np.arange(n)) / n
    return np.minimum(np.searchsorted(cumulative, points, side="right"), probabilities.size - 1)


def resample_probabilities(w: np.ndarray, p: PFParams) -> np.ndarray:
    """Unnormalised resampling probabilities: ``w - min w`` (``"shifted"``, the paper's "proportional
    to its weight" made non-negative) or ``exp(sharpness (w - max w))`` (``"exponential"``)."""
    if p.filter.resample_weighting == "shifted":
        shifted = w - w.min()
        total = shifted.sum()
        return shifted if total > 0 else np.ones_like(w)
    return np.exp(p.filter.sharpness * (w - w.max()))


def spread(particles: np.ndarray) -> float:
    """σ_p of eq. 5: the larger of the x and y standard deviations."""
    return float(max(particles[:, 0].std(), particles[:, 1].std()))


def not_converged(w_avg: float, s_avg: float, iterations: int, p: PFParams) -> str:
    """Which of eqs. 5–6 failed after ``iterations``."""
    problems = []
    if w_avg < p.filter.tau_pw:
        problems.append(
            f"weight average {w_avg:.3f} below tau_pw={p.filter.tau_pw:g} (too few beams agree with the map: "
            "the scans may not overlap, or the compass is off)"
        )
    if s_avg > p.map.cell_m:
        problems.append(
            f"particle spread {s_avg:.3f} m above r_c={p.map.cell_m:g} m (position ambiguous)"
        )
    return f"not converged after {iterations} iterations: " + "; ".join(problems)
