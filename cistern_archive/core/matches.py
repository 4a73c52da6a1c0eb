"""What a pair-wise scan matcher returns: the estimate of one directed pair, its search window and
its diagnostics (the matcher stage's output types)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HistoryThreshold:
    """A threshold a matcher's iteration is judged by, drawn as a line across its history.

    Attributes
    ----------
    value : float
        The threshold, in the units of the series it applies to.
    label : str
        Its name in the figure (e.g. ``"τ_pw"``).
    """

    value: float
    label: str


@dataclass(frozen=True, eq=False)
class MatchHistory:
    """Per-iteration diagnostics of an iterative matcher (for the report's convergence figures).

    The matcher that fills it also says which thresholds its iteration is judged by, so the report draws
    them without knowing the matcher or its parameters.

    Attributes
    ----------
    weight_avg : ndarray, shape (T,)
        The matcher's score after each iteration (McVicker et al.'s filter: the exponential average of
        the particle weights, eq. 6's left side).
    std_avg : ndarray, shape (T,)
        The spread of its estimate after each iteration, metres (McVicker et al.'s filter: the
        exponential average of the particle position std, eq. 5's left side).
    snapshots : tuple of ndarray
        A few particle sets, each (K, 4): x, y, theta, weight.
    snapshot_iterations : tuple of int
        The iteration each snapshot was taken at.
    weight_threshold, std_threshold : HistoryThreshold or None
        The line the score must reach and the one the spread must fall below, or ``None`` when the
        matcher has no such threshold.
    """

    weight_avg: np.ndarray
    std_avg: np.ndarray
    snapshots: tuple[np.ndarray, ...] = ()
    snapshot_iterations: tuple[int, ...] = ()
    weight_threshold: HistoryThreshold | None = None
    std_threshold: HistoryThreshold | None = None



@dataclass(frozen=True)
class MatchGuess:
    """Where a localizer expects scan ``j`` relative to scan ``i``, from the matches it already has.

    A matcher that accepts a ``guess`` searches the square ``±radius_m`` around ``(dx_m, dy_m)`` and the
    heading correction around ``dyaw_rad`` instead of its own wide window: the search window around an
    odometry estimate that SLAM systems use to match scans beyond neighbours (loop closures), here with
    the chain of neighbour matches as the odometry.

    Attributes
    ----------
    dx_m, dy_m, dyaw_rad : float
        Expected ``p_j - p_i`` (in scan i's compass frame) and heading correction of scan j.
    radius_m : float
        Half the side of the square to search.
    """

    dx_m: float
    dy_m: float
    dyaw_rad: float
    radius_m: float



@dataclass(frozen=True, eq=False)
class MatchResult:
    """The estimate of one directed pair: scan ``j`` located in scan ``i``'s map.

    Attributes
    ----------
    i, j : int
        Indices of the reference and the moving scan in the site's scan list.
    dx_m, dy_m : float
        ``p_j - p_i`` in the map frame.
    dyaw_rad : float
        Correction to scan j's yaw relative to scan i (0 when the compass is trusted).
    weight : float
        The converged weight ``w_mu`` (eq. 6) or the matcher's own score; larger is better.
    converged : bool
        Whether the matcher vouches for this estimate.
    iterations : int
        Iterations used.
    seconds : float
        Wall time of the match.
    reason : str
        Why it did not converge (empty when it did).
    covariance : ndarray or None, shape (3, 3)
        Uncertainty of (dx, dy, dyaw) when the matcher estimates it.
    history : MatchHistory or None
        Diagnostics for the report.
    guess : MatchGuess or None
        The window the matcher was asked to search (set by the runner; ``None`` for a global search).
    tentative : bool
        For a pair that did not converge: the estimate is still the matcher's best, refused only because
        it is not unique or not constrained enough on its own (a rival peak nearly as good, a corridor
        that leaves one direction weak). A localizer may use it where converged matches corroborate it
        (closing a consistent cycle with them), never alone.
    confidence : float or None
        The matcher's calibrated probability that a converged estimate is right (within the accuracy
        its verification is calibrated for), when it estimates one; localizers order and weigh
        matches by it.
    alternatives : tuple of MatchGuess
        Other places the matcher found nearly as good as its estimate (the rival peaks of an ambiguous
        search), best first, each with the half-width of its peak; empty when the estimate had no rival.
        A localizer can tell from it that an estimate is one of several look-alike places.
    """

    i: int
    j: int
    dx_m: float
    dy_m: float
    dyaw_rad: float
    weight: float
    converged: bool
    iterations: int
    seconds: float
    reason: str = ""
    covariance: np.ndarray | None = None
    history: MatchHistory | None = None
    guess: MatchGuess | None = None
    confidence: float | None = None
    tentative: bool = False
    alternatives: tuple[MatchGuess, ...] = ()

    @property
    def translation(self) -> np.ndarray:
        return np.array([self.dx_m, self.dy_m])

    @classmethod
    def no_estimate(cls, reason: str, *, seconds: float, weight: float = 0.0) -> "MatchResult":
        """A pair the matcher could not estimate at all: not converged, NaN displacement, ``reason``."""
        nan = float("nan")
        return cls(i=-1, j=-1, dx_m=nan, dy_m=nan, dyaw_rad=nan, weight=weight, converged=False, iterations=0,
                   seconds=seconds, reason=reason)


def lengthen_matches(matches: Sequence[MatchResult], scale: np.ndarray) -> list[MatchResult]:
    """Every match's displacement divided by the mean of its two scans' ``scale`` (scan ``k``'s echo range
    over the range of its walls): two scans whose echoes fall short by a share ``k`` of their range see
    the walls shrunk about their own positions, and their match is short by the same share. An estimate
    without a finite displacement stays as it is; heading, covariance and verdict are kept."""
    out = []
    for m in matches:
        k = 0.5 * (float(scale[m.i]) + float(scale[m.j]))
        out.append(m if k == 1.0 or not math.isfinite(m.dx_m) else
                   dataclasses.replace(m, dx_m=m.dx_m / k, dy_m=m.dy_m / k))
    return out
