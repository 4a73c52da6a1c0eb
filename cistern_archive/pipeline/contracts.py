"""What each pipeline stage receives and returns.

Data flows one way: ``RangeScan`` → :class:`MatchResult` → :class:`Poses` → :class:`MapResult`
→ :class:`DimensionTable`. A stage plugin is an object with a ``name``, a pydantic ``Params`` model
(``extra="forbid"``) and the method(s) of its :class:`typing.Protocol` below. Results are frozen
dataclasses holding numpy arrays; the runner turns them into the JSON ``SiteResult``.

Conventions
-----------
A match of the pair (i, j) estimates ``d_ij = p_j - p_i``: the position of scan j minus the position
of scan i, in the map frame (compass aligned), and ``dyaw_rad``, a correction to add to scan j's
compass yaw relative to scan i's.
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, Literal, Protocol, Self, runtime_checkable

import numpy as np
from pydantic import BaseModel, ConfigDict

from cistern_archive.grid.evidence_grid import EvidenceGrid  # noqa: F401  (the mapper contract's output)
from cistern_archive.sonar.scan import RangeScan

if TYPE_CHECKING:  # pragma: no cover
    from cistern_archive.catalog.models import ReferenceDimension

STAGES = ("matcher", "localizer", "mapper", "comparator")
StageName = Literal["matcher", "localizer", "mapper", "comparator"]


class StageParams(BaseModel):
    """Base of every plugin's ``Params`` model: unknown keys are refused, values are frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @classmethod
    def of(cls, params: "StageParams") -> Self:
        """``params`` as this model: itself when it is one already, else validated from its fields."""
        return params if isinstance(params, cls) else cls.model_validate(params.model_dump())


# --------------------------------------------------------------------------------------- matcher
@dataclass(frozen=True, eq=False)
class MatchHistory:
    """Per-iteration diagnostics of an iterative matcher (for the report's convergence figures).

    Attributes
    ----------
    weight_avg : ndarray, shape (T,)
        Exponential average of the particle weights after each iteration (eq. 6's left side).
    std_avg : ndarray, shape (T,)
        Exponential average of the particle position std after each iteration (eq. 5's left side).
    snapshots : tuple of ndarray
        A few particle sets, each (K, 4): x, y, theta, weight.
    snapshot_iterations : tuple of int
        The iteration each snapshot was taken at.
    """

    weight_avg: np.ndarray
    std_avg: np.ndarray
    snapshots: tuple[np.ndarray, ...] = ()
    snapshot_iterations: tuple[int, ...] = ()


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

    @property
    def translation(self) -> np.ndarray:
        return np.array([self.dx_m, self.dy_m])

    @classmethod
    def no_estimate(cls, reason: str, *, seconds: float, weight: float = 0.0) -> "MatchResult":
        """A pair the matcher could not estimate at all: not converged, NaN displacement, ``reason``."""
        nan = float("nan")
        return cls(i=-1, j=-1, dx_m=nan, dy_m=nan, dyaw_rad=nan, weight=weight, converged=False, iterations=0,
                   seconds=seconds, reason=reason)


@runtime_checkable
class Matcher(Protocol):
    """Pair-wise scan matcher: locate ``moving`` in the frame of ``reference``."""

    name: ClassVar[str]
    Params: ClassVar[type[StageParams]]

    def match(
        self, reference: RangeScan, moving: RangeScan, params: StageParams, *, rng: np.random.Generator
    ) -> MatchResult:  # pragma: no cover - protocol
        """Return the estimate of ``p_moving - p_reference`` (with ``i = j = -1``; the runner sets them).

        A matcher may also take a keyword ``guess: MatchGuess | None = None`` (see :func:`accepts_guess`);
        with a guess it searches only the window the guess gives.
        """
        ...


def accepts_guess(matcher: object) -> bool:
    """Whether ``matcher.match`` takes the optional ``guess`` keyword (:class:`MatchGuess`)."""
    try:
        parameters = inspect.signature(matcher.match).parameters  # type: ignore[attr-defined]
    except (TypeError, ValueError, AttributeError):
        return False
    return "guess" in parameters


# ------------------------------------------------------------------------------------- localizer
@dataclass(frozen=True, eq=False)
class Poses:
    """One pose per scan, or the reason it could not be placed.

    Attributes
    ----------
    xy_m : ndarray, shape (N, 2)
        Positions in the map frame (the reference scan at the origin); ``nan`` for unplaced scans.
    yaw_rad : ndarray, shape (N,)
        Headings (compass plus any correction).
    placed : ndarray of bool, shape (N,)
    reasons : tuple of str
        For each unplaced scan, why; empty strings for placed scans.
    reference : int
        Index of the reference scan (Table III), -1 when nothing could be placed.
    covariance : ndarray or None, shape (N, 3, 3)
        Marginal uncertainty of (x, y, yaw) when the localizer estimates it.
    """

    xy_m: np.ndarray
    yaw_rad: np.ndarray
    placed: np.ndarray
    reasons: tuple[str, ...]
    reference: int
    covariance: np.ndarray | None = None


@runtime_checkable
class Localizer(Protocol):
    """Turns pair-wise matches into one pose per scan."""

    name: ClassVar[str]
    Params: ClassVar[type[StageParams]]

    def pairs(self, n_scans: int, params: StageParams) -> list[tuple[int, int]]:  # pragma: no cover
        """Directed pairs (i, j) the matcher must run on, in the order they should run.

        A localizer may also have ``guided_pairs(scans, matches, params)``, returning a second round of
        ``(i, j, guess)`` (``guess`` a :class:`MatchGuess` or ``None``) worked out from the first round's
        matches; the runner matches them too and passes both rounds to :meth:`localize`
        (:func:`cistern_archive.pipeline.runner.match_rounds`).
        """
        ...

    def localize(
        self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams
    ) -> Poses:  # pragma: no cover
        """Place every scan it can."""
        ...


# ---------------------------------------------------------------------------------------- mapper
@dataclass(frozen=True, eq=False)
class MapResult:
    """The mapper's output: one evidence grid per depth slice, shallowest first."""

    grids: tuple[EvidenceGrid, ...]
    stats: dict[str, float] = field(default_factory=dict)


@runtime_checkable
class Mapper(Protocol):
    """Fuses located scans into evidence grids."""

    name: ClassVar[str]
    Params: ClassVar[type[StageParams]]

    def build(self, scans: Sequence[RangeScan], poses: Poses, params: StageParams) -> MapResult:  # pragma: no cover
        ...


# ------------------------------------------------------------------------------------ comparator
@dataclass(frozen=True)
class DimensionRow:
    """One measured dimension against its reference (the paper's Table IV, one cell pair).

    ``probes`` are the individual probe measurements (m) whose mean is ``map_m``; ``probe_lines`` the
    map-frame segments (x0, y0, x1, y1) each probe measured, for the report's figure.
    """

    name: str
    map_m: float
    reference_m: float
    reference_kind: str
    diff_m: float
    depth_m: float = 0.0
    probes: tuple[float, ...] = ()
    probe_lines: tuple[tuple[float, float, float, float], ...] = ()
    note: str = ""

    @property
    def probe_std_m(self) -> float:
        return float(np.std(self.probes, ddof=1)) if len(self.probes) > 1 else float("nan")


@dataclass(frozen=True)
class DimensionTable:
    """All measured dimensions of a site plus summary statistics (e.g. the paper's percent difference)."""

    rows: tuple[DimensionRow, ...]
    stats: dict[str, float] = field(default_factory=dict)


@runtime_checkable
class Comparator(Protocol):
    """Measures the reference dimensions in the map."""

    name: ClassVar[str]
    Params: ClassVar[type[StageParams]]

    def compare(
        self,
        map_result: MapResult,
        poses: Poses,
        references: Sequence["ReferenceDimension"],
        station_index: dict[str, int],
        params: StageParams,
    ) -> DimensionTable:  # pragma: no cover
        """Measure each reference in the map. ``station_index`` maps station labels to scan indices
        so that probes given in a station's frame can be placed with ``poses``."""
        ...


PROTOCOLS: dict[str, type] = {
    "matcher": Matcher,
    "localizer": Localizer,
    "mapper": Mapper,
    "comparator": Comparator,
}
