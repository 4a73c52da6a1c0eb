"""What each pipeline stage receives and returns.

Data flows one way: ``RangeScan`` → :class:`MatchResult` → :class:`Poses` → :class:`MapResult`
→ :class:`DimensionTable`. A stage plugin is an object with a ``name``, a pydantic ``Params`` model
(``extra="forbid"``) and the method(s) of its :class:`typing.Protocol` below, with their signatures
(checked at load, :mod:`cistern_archive.pipeline.signatures`). Optional capabilities are protocols of
their own (:data:`CAPABILITIES`: :class:`GuidedMatcher`, :class:`GuidedLocalizer`,
:class:`EchoScaleMapper`). Results are frozen dataclasses holding numpy arrays; the runner turns them
into the JSON ``SiteResult``.

Conventions
-----------
A match of the pair (i, j) estimates ``d_ij = p_j - p_i``: the position of scan j minus the position
of scan i, in the map frame (compass aligned), and ``dyaw_rad``, a correction to add to scan j's
compass yaw relative to scan i's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Literal, Protocol, Self, runtime_checkable

import numpy as np
from pydantic import BaseModel, ConfigDict

# The stages' input and output types live in the bottom layer; they are named here too, as the contract.
from cistern_archive.core.dimensions import DimensionRow, DimensionTable  # noqa: F401
from cistern_archive.core.grids import EvidenceGrid, MapResult  # noqa: F401
from cistern_archive.core.matches import HistoryThreshold, MatchGuess, MatchHistory, MatchResult  # noqa: F401
from cistern_archive.core.poses import Poses  # noqa: F401
from cistern_archive.core.scan import RangeScan

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


@dataclass(frozen=True)
class VerticalTie:
    """The scan of station ``lower`` was taken directly below the scan of station ``upper``: the
    vehicle descended vertically between them, so both share one horizontal position (a record's
    ``ScanRef.below``). The runner passes a site's ties to every localizer (:meth:`Localizer.localize`)."""

    lower: str
    upper: str


@runtime_checkable
class Matcher(Protocol):
    """Pair-wise scan matcher: locate ``moving`` in the frame of ``reference``."""

    name: ClassVar[str]
    Params: ClassVar[type[StageParams]]

    def match(
        self, reference: RangeScan, moving: RangeScan, params: StageParams, *, rng: np.random.Generator
    ) -> MatchResult:  # pragma: no cover - protocol
        """Return the estimate of ``p_moving - p_reference`` (with ``i = j = -1``; the runner sets them).

        A matcher that can search around a first estimate declares :class:`GuidedMatcher`.
        """
        ...


@runtime_checkable
class GuidedMatcher(Matcher, Protocol):
    """Optional capability of a matcher: search only the window a :class:`MatchGuess` gives.

    A matcher implements it by subclassing this protocol (``class MyMatcher(GuidedMatcher): ...``) or
    structurally, by taking ``guess`` in ``match``; the registry checks the signature of its ``match``
    at load (:func:`cistern_archive.pipeline.signatures.check_methods`) and the runner passes every
    pair's ``guess`` (``None`` when the localizer has none)."""

    def match(
        self, reference: RangeScan, moving: RangeScan, params: StageParams, *, rng: np.random.Generator,
        guess: MatchGuess | None = None,
    ) -> MatchResult:  # pragma: no cover - protocol
        """As :meth:`Matcher.match`; with a ``guess`` only its window is searched."""
        ...


@runtime_checkable
class Localizer(Protocol):
    """Turns pair-wise matches into one pose per scan.

    The runner hands a localizer the scans in the survey's order — as recorded, where every scan has a
    time of its own (:mod:`cistern_archive.pipeline.survey_order`) — so that neighbouring indices are
    consecutive stations; the indices of its pairs, of the matches it is given and of its poses are
    those of that order, and the runner maps them to the record's."""

    name: ClassVar[str]
    Params: ClassVar[type[StageParams]]

    def pairs(self, n_scans: int, params: StageParams) -> list[tuple[int, int]]:  # pragma: no cover
        """Directed pairs (i, j) the matcher must run on, in the order they should run.

        A localizer that works out further rounds of pairs from the matches so far declares
        :class:`GuidedLocalizer`.
        """
        ...

    def localize(
        self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
        ties: Sequence[VerticalTie] = (),
    ) -> Poses:  # pragma: no cover
        """Place every scan it can; ``ties`` are the record's vertical ties (:class:`VerticalTie`)."""
        ...


@runtime_checkable
class GuidedLocalizer(Localizer, Protocol):
    """Optional capability of a localizer: further rounds of pairs, worked out from a first solution.

    A localizer implements it by subclassing this protocol or structurally, by defining
    ``guided_pairs``; the registry checks the signature at load and the runner asks it round after
    round (:func:`cistern_archive.pipeline.runner.match_rounds`)."""

    def guided_pairs(
        self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
        ties: Sequence[VerticalTie] = (),
    ) -> list[tuple[int, int, MatchGuess | None]]:  # pragma: no cover
        """The next round of ``(i, j, guess)`` (``guess`` a :class:`MatchGuess` or ``None``) given the
        matches so far (none before the first round); an empty list ends the rounds."""
        ...


@runtime_checkable
class Mapper(Protocol):
    """Fuses located scans into evidence grids."""

    name: ClassVar[str]
    Params: ClassVar[type[StageParams]]

    def build(self, scans: Sequence[RangeScan], poses: Poses, params: StageParams) -> MapResult:  # pragma: no cover
        ...


@runtime_checkable
class EchoScaleMapper(Mapper, Protocol):
    """Optional capability of a mapper: tell how far each scan's echoes fall short of its walls.

    A sonar's echoes can come back short by a share of their range (a wide vertical beam on leaning
    walls: :func:`cistern_archive.grid.lobe.echo_scale`), and a match between two such scans is then short
    by the same share. The runner asks a mapper that implements this (by subclassing the protocol or by
    defining ``echo_scale``) once the scans are placed, lengthens every match by its two scans' scale and
    places them again (:func:`cistern_archive.pipeline.runner.localize_step`)."""

    def echo_scale(self, scans: Sequence[RangeScan], poses: Poses, params: StageParams
                   ) -> np.ndarray | None:  # pragma: no cover - protocol
        """Each scan's echo range over the range of its walls (1 where they agree), from the map of the
        scans placed by ``poses``; ``None`` where the mapper cannot tell (e.g. its correction is off)."""
        ...


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


CAPABILITIES: dict[str, tuple[type, ...]] = {
    "matcher": (GuidedMatcher,),
    "localizer": (GuidedLocalizer,),
    "mapper": (EchoScaleMapper,),
}
"""The optional capabilities of each stage: protocols a plugin declares by subclassing them."""

PROTOCOLS: dict[str, type] = {
    "matcher": Matcher,
    "localizer": Localizer,
    "mapper": Mapper,
    "comparator": Comparator,
}
