"""Run one site through the pipeline: record → scans → matches → poses → grids → dimension table → mesh.

The runner owns the order, the timing and the errors; the stages own the science. :func:`build_site`
runs the named steps of :data:`STEPS` in order, each timed and labelled; a failure is caught, recorded
with its step and the input that caused it, and returned as a failed :class:`SiteResult`; it never
propagates to other sites. Benchmarks, commands and the navigation pipeline call the same functions
(:func:`range_scans`, :func:`match_pair`, :func:`match_rounds`, :func:`localize`), never copies of them.
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from cistern_archive.catalog.loader import LoadedRecord
from cistern_archive.catalog.models import ScanRef, Segmentation, SiteRecord
from cistern_archive.core.errors import StageError
from cistern_archive.core.files import write_json_atomic
from cistern_archive.core.matches import lengthen_matches
from cistern_archive.core.scan import RangeScan, Scan
from cistern_archive.pipeline.assemble import assemble_result
from cistern_archive.pipeline.checks import checked_match, checked_scale
from cistern_archive.pipeline.contracts import (
    STAGES,
    EchoScaleMapper,
    GuidedLocalizer,
    GuidedMatcher,
    MatchGuess,
    MatchResult,
    Poses,
    StageParams,
    VerticalTie,
)
from cistern_archive.pipeline.registry import LoadedPlugin, Registry, checked_plugin, default_registry
from cistern_archive.pipeline.results import PluginProvenance, SiteBuild, SiteResult, StageFailure
from cistern_archive.pipeline.survey_order import SurveyOrder
from cistern_archive.sonar.readers import read_file

T = TypeVar("T")

MAX_MATCH_ROUNDS = 6
"""Rounds of pair matching a localizer may ask for (:func:`match_rounds`)."""


@dataclass(frozen=True)
class Stage:
    """A resolved stage: the loaded plugin and its validated parameters."""

    plugin: LoadedPlugin
    params: StageParams

    @classmethod
    def of(cls, stage: str, instance: Any, params: StageParams | dict | None = None) -> "Stage":
        """A plugin object no entry point names (checked as the registry checks one) with ``params``
        (validated by its ``Params``; its defaults when ``None``)."""
        plugin = checked_plugin(stage, instance)
        if not isinstance(params, StageParams):
            params = plugin.instance.Params.model_validate(params or {})
        return cls(plugin=plugin, params=params)

    @property
    def instance(self) -> Any:
        return self.plugin.instance

    def provenance(self, stage: str) -> PluginProvenance:
        info = self.plugin.info
        return PluginProvenance(stage=stage, plugin=info.name, distribution=info.distribution,
                                version=info.version, params=self.params.model_dump(mode="json"))


def resolve_stage(registry: Registry, stage: str, name: str, params: dict[str, Any] | None = None) -> Stage:
    """Load the plugin ``name`` of ``stage`` and validate ``params`` with it."""
    return Stage(plugin=registry.load(stage, name), params=registry.check_params(stage, name, params or {}))


def resolve_stages(record: SiteRecord, registry: Registry) -> dict[str, Stage]:
    """Load the record's plugin for every stage (the installed default where it names none) and
    validate its parameters."""
    stages = {}
    for stage in STAGES:
        choice = registry.choice(record.pipeline, stage)
        stages[stage] = resolve_stage(registry, stage, choice.plugin, choice.params)
    return stages


def record_ties(record: SiteRecord) -> tuple[VerticalTie, ...]:
    """The record's vertical ties (``ScanRef.below``), in scan order."""
    return tuple(VerticalTie(lower=s.station, upper=s.below) for s in record.scans if s.below is not None)


def load_scan(loaded: LoadedRecord, ref: ScanRef) -> Scan:
    """Read the scan a record references and apply the record's station, heading and depth, and its
    sonar's vertical beam width."""
    result = read_file(loaded.resolve(ref.file), ref.format)
    if ref.index >= len(result.scans):
        raise ValueError(f"file holds {len(result.scans)} scan(s); index {ref.index} requested")
    scan = result.scans[ref.index]
    changes: dict[str, Any] = {"station": ref.station}
    if loaded.record.sonar.vertical_beam_width_deg is not None:
        changes["vertical_beam_width_rad"] = math.radians(loaded.record.sonar.vertical_beam_width_deg)
    if ref.yaw_deg is not None:
        changes["yaw_rad"] = math.radians(90.0 - ref.yaw_deg)
    if ref.depth_m is not None:
        changes["depth_m"] = ref.depth_m
    if ref.time is not None:
        changes["timestamp"] = ref.time.timestamp()
    return scan.replace(**changes)


def segment_scan(scan: Scan, settings: Segmentation) -> RangeScan:
    """One range per beam (:func:`cistern_archive.sonar.segmentation.segment` with ``settings``)."""
    from cistern_archive.sonar.segmentation import segment  # scipy: deferred until a scan is segmented

    return segment(scan, settings)


def range_scans(loaded: LoadedRecord) -> list[RangeScan]:
    """The record's scans, read and segmented as :func:`build_site` does (its ``load`` and ``segment``)."""
    raw = [load_scan(loaded, ref) for ref in loaded.record.scans]
    settings = site_segmentation(raw, loaded.record.segmentation)
    return [segment_scan(scan, settings) for scan in raw]


def pair_rng(seed: int, i: int, j: int) -> np.random.Generator:
    """The generator of one directed pair: independent of the order pairs run in."""
    return np.random.default_rng([seed, i, j])


def match_pair(matcher: Stage, scans: Sequence[RangeScan], seed: int, i: int, j: int,
               guess: MatchGuess | None = None) -> MatchResult:
    """Match the directed pair ``(i, j)`` with its own seeded generator (:func:`pair_rng`).

    A :class:`~cistern_archive.pipeline.contracts.GuidedMatcher` gets the ``guess``; any other matcher
    matches the pair without it (recorded so). ``i``, ``j``, the guess used and a wall-clock time when
    the matcher reports none are set on the result, and unusable numbers turn it into a failed pair
    (:func:`~cistern_archive.pipeline.checks.checked_match`).
    """
    start = time.perf_counter()
    guided = matcher.plugin.has(GuidedMatcher)
    extra = {"guess": guess} if guided else {}
    result = matcher.instance.match(scans[i], scans[j], matcher.params, rng=pair_rng(seed, i, j), **extra)
    if not isinstance(result, MatchResult):
        raise TypeError(f"matcher returned {type(result).__name__}, expected MatchResult")
    seconds = result.seconds if math.isfinite(result.seconds) and result.seconds > 0 else time.perf_counter() - start
    checked = checked_match(result)
    return MatchResult(**{**checked.__dict__, "i": i, "j": j, "seconds": seconds,
                          "guess": guess if guided else None})


def match_rounds(
    scans: Sequence[RangeScan], localizer: Stage, run_pair: Callable[[int, int, MatchGuess | None], MatchResult],
    *, ties: Sequence[VerticalTie] = (), plan: Callable[[str, Callable[[], Any]], Any] = lambda label, func: func(),
) -> list[MatchResult]:
    """Every match a localizer asks for: ``localizer.pairs`` first, then, for a
    :class:`~cistern_archive.pipeline.contracts.GuidedLocalizer`, the further rounds it works out from
    the matches so far (each pair with a :class:`MatchGuess` or ``None``), until it asks for no new
    pair or ``MAX_MATCH_ROUNDS`` rounds have run. ``run_pair(i, j, guess)`` matches one pair (e.g. with
    :func:`match_pair`); ``plan(label, func)`` runs the localizer's own calls (the runner uses it to
    label a failure). A pair is matched at most once without a guess and once with one: a
    global match may be followed by a guided one, but a pair asked again is not matched again.

    The localizer sees the scans in the survey's order (:class:`~cistern_archive.pipeline.survey_order.SurveyOrder`:
    as recorded, where every scan has a time); the pairs it asks for are run, and returned, with the
    record's indices."""
    params = localizer.params
    survey = SurveyOrder(scans)
    pairs = survey.pairs_back(plan("pair list", lambda: localizer.instance.pairs(len(scans), params)))
    matches = [run_pair(i, j, None) for i, j in pairs]
    if not localizer.plugin.has(GuidedLocalizer):
        return matches
    matched, guided = set(pairs), set()
    for round_no in range(2, MAX_MATCH_ROUNDS + 1):
        asked = survey.pairs_back(plan(f"pair list of round {round_no}", lambda: localizer.instance.guided_pairs(
            survey.scans, survey.matches(matches), params, ties=tuple(ties))))
        fresh: dict[tuple[int, int], MatchGuess | None] = {}
        for i, j, guess in asked:
            if (i, j) not in fresh and (i, j) not in (matched if guess is None else guided):
                fresh[(i, j)] = guess
        if not fresh:
            break
        matched.update(fresh)
        guided.update(pair for pair, guess in fresh.items() if guess is not None)
        matches += [run_pair(i, j, guess) for (i, j), guess in fresh.items()]
    return matches


def localize(localizer: Stage, scans: Sequence[RangeScan], matches: Sequence[MatchResult],
             ties: Sequence[VerticalTie] = ()) -> Poses:
    """One pose per scan (or the reason it is unplaced) from the matches and the vertical ``ties``, in the
    record's order; the localizer sees the survey's (:class:`~cistern_archive.pipeline.survey_order.SurveyOrder`)."""
    survey = SurveyOrder(scans)
    return survey.poses_back(localizer.instance.localize(survey.scans, survey.matches(matches), localizer.params,
                                                         ties=tuple(ties)))


@dataclass
class SiteRun:
    """What the steps of one build share: the record, its resolved stages and the build so far."""

    loaded: LoadedRecord
    registry: Registry
    build: SiteBuild
    stages: dict[str, Stage] = field(default_factory=dict)

    @property
    def record(self) -> SiteRecord:
        return self.build.record

    def pair_label(self, i: int, j: int) -> str:
        stations = [s.station for s in self.record.scans]
        return f"pair {i}->{j} ({stations[i]} -> {stations[j]})"


def run_stage(stage: str, input_label: str, func: Callable[[], T]) -> T:
    """``func()``, with any failure turned into a :class:`StageError` naming the stage and its input."""
    try:
        return func()
    except StageError:
        raise
    except Exception as exc:
        raise StageError(stage, input_label, f"{type(exc).__name__}: {exc}") from exc


def configure_step(run: SiteRun) -> None:
    """Resolve every stage's plugin and parameters; the build's record names every stage (``record.json``)."""
    run.stages = run_stage("configure", str(run.loaded.path), lambda: resolve_stages(run.loaded.record, run.registry))
    run.build.record = run_stage("configure", str(run.loaded.path), lambda: run.registry.resolve(run.loaded.record))


def load_step(run: SiteRun) -> None:
    """Read every scan the record references."""
    for ref in run.record.scans:
        run.build.raw_scans.append(run_stage("load", ref.file, lambda ref=ref: load_scan(run.loaded, ref)))


def site_segmentation(scans: Sequence[Scan], settings: Segmentation) -> Segmentation:
    """The record's segmentation with what it leaves to the site decided from its scans
    (:func:`cistern_archive.sonar.segmentation.site_segmentation`: ``faint_walls: auto``)."""
    from cistern_archive.sonar.segmentation import site_segmentation as decide  # scipy: deferred

    return decide(scans, settings)


def segment_step(run: SiteRun) -> None:
    """One range per beam of every scan, with the record's segmentation as decided for this site (the
    build's record, written as ``record.json``, says what was decided)."""
    settings = run_stage("segment", f"{len(run.build.raw_scans)} scans",
                         lambda: site_segmentation(run.build.raw_scans, run.record.segmentation))
    run.build.record = run.build.record.model_copy(update={"segmentation": settings})
    for ref, scan in zip(run.record.scans, run.build.raw_scans):
        run.build.range_scans.append(run_stage("segment", ref.file, lambda s=scan: segment_scan(s, settings)))


def match_step(run: SiteRun) -> None:
    """Every pair the localizer asks for, round after round (:func:`match_rounds`)."""
    matcher, scans, seed = run.stages["matcher"], run.build.range_scans, run.record.seed

    def run_pair(i: int, j: int, guess: MatchGuess | None) -> MatchResult:
        return run_stage("match", run.pair_label(i, j), lambda: match_pair(matcher, scans, seed, i, j, guess))

    run.build.matches.extend(match_rounds(scans, run.stages["localizer"], run_pair, ties=record_ties(run.record),
                                          plan=lambda label, func: run_stage("match", label, func)))


def localize_step(run: SiteRun) -> None:
    """Place the scans (:func:`localize`) with the record's vertical ties. Where the mapper tells that
    the echoes of placed scans fall short of their walls (an
    :class:`~cistern_archive.pipeline.contracts.EchoScaleMapper`), every match is lengthened by its two
    scans' scale (:func:`~cistern_archive.core.matches.lengthen_matches`: matched echoes short by a share
    of their range make the match short by as much) and the scans are placed again from those matches,
    which the build keeps (the scans stay as segmented: the mapper corrects each echo for the lean of
    its own wall)."""
    build, localizer, mapper, ties = run.build, run.stages["localizer"], run.stages["mapper"], record_ties(run.record)
    build.poses = run_stage("localize", f"{len(build.matches)} matches", lambda: localize(
        localizer, build.range_scans, build.matches, ties))
    if not mapper.plugin.has(EchoScaleMapper) or not build.poses.placed.any():
        return
    scale = run_stage("map", f"echo scale of {int(build.poses.placed.sum())} placed scans", lambda: checked_scale(
        mapper.instance.echo_scale(build.range_scans, build.poses, mapper.params), len(build.range_scans)))
    if scale is None or np.all(scale == 1.0):
        return
    build.echo_scale = scale
    build.matches = lengthen_matches(build.matches, scale)
    build.poses = run_stage("localize", f"{len(build.matches)} matches lengthened by their echo scale",
                            lambda: localize(localizer, build.range_scans, build.matches, ties))


def map_step(run: SiteRun) -> None:
    """Fuse the placed scans into evidence grids."""
    build, mapper = run.build, run.stages["mapper"]
    build.map_result = run_stage("map", f"{int(build.poses.placed.sum())} placed scans",
                            lambda: mapper.instance.build(build.range_scans, build.poses, mapper.params))


def compare_step(run: SiteRun) -> None:
    """Measure the record's reference dimensions in the map."""
    build, comparator, record = run.build, run.stages["comparator"], run.record
    build.table = run_stage("compare", f"{len(record.references)} reference dimensions",
                       lambda: comparator.instance.compare(build.map_result, build.poses, record.references,
                                                           record.station_index(), comparator.params))


def mesh_step(run: SiteRun) -> None:
    """The wall surface of the site from its evidence grids (:func:`cistern_archive.grid.surface.wall_surface`),
    or ``None`` when no wall was seen."""
    from cistern_archive.grid.surface import wall_surface  # scikit-image: deferred until a site is meshed

    build = run.build
    build.mesh = run_stage("mesh", f"{len(build.map_result.grids)} depth slices", lambda: wall_surface(
        build.map_result, build.poses, [s.depth_m for s in build.range_scans]))


STEPS: tuple[tuple[str, Callable[[SiteRun], None]], ...] = (
    ("configure", configure_step),
    ("load", load_step),
    ("segment", segment_step),
    ("match", match_step),
    ("localize", localize_step),
    ("map", map_step),
    ("compare", compare_step),
    ("mesh", mesh_step),
)
"""The steps of :func:`build_site`, in order (the names are the keys of ``result.timings_s``)."""


class StageTimer:
    """Seconds per named step (``result.timings_s``), announcing each step to ``on_stage`` as it starts."""

    def __init__(self, on_stage: Callable[[str], None] | None = None) -> None:
        self.timings: dict[str, float] = {}
        self.on_stage = on_stage

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        if self.on_stage is not None:
            self.on_stage(name)
        start = time.perf_counter()
        try:
            yield
        finally:
            self.timings[name] = round(self.timings.get(name, 0.0) + time.perf_counter() - start, 6)


def record_failure(build: SiteBuild, exc: StageError) -> None:
    """Mark ``build`` failed at the stage and input ``exc`` names, with the traceback of its cause."""
    build.result.status = "failed"
    build.result.failure = StageFailure(stage=exc.stage, input=exc.input, error=exc.message,
                                        traceback="".join(traceback.format_exception(exc.__cause__ or exc)))


def build_site(loaded: LoadedRecord, *, registry: Registry | None = None,
               on_stage: Callable[[str], None] | None = None) -> SiteBuild:
    """Run the whole pipeline for one site (the steps of :data:`STEPS`); never raises for a stage failure.

    ``on_stage(name)`` is called as each step starts (the rebuild shows it on a terminal).

    Returns
    -------
    SiteBuild
        ``result.status`` is ``"ok"``, ``"partial"`` or ``"failed"`` (:func:`~cistern_archive.pipeline.status.site_status`,
        with ``result.status_reasons``; ``result.failure`` names the stage and the input that stopped a
        build); the arrays reached before a failure are kept for the report.
    """
    record = loaded.record
    build = SiteBuild(result=SiteResult(site_id=record.id, name=record.name, status="ok"), record=record)
    run = SiteRun(loaded=loaded, registry=registry or default_registry(), build=build)
    timer = StageTimer(on_stage)
    try:
        for name, step in STEPS:
            with timer.stage(name):
                step(run)
    except StageError as exc:
        record_failure(build, exc)
    build.result = assemble_result(build, loaded, [s.provenance(n) for n, s in run.stages.items()], timer.timings)
    return build


RESULT_FILE = "result.json"
"""The site result's file in a site folder."""


def write_site_result(build: SiteBuild, site_dir: Path, artifacts: Mapping[str, str] | None = None) -> Path:
    """Write ``result.json`` (and the resolved record, ``record.json``, redacted as the record asks:
    :meth:`~cistern_archive.catalog.models.SiteRecord.public`) into ``site_dir``, once.

    Parameters
    ----------
    artifacts : mapping, optional
        Artifact name → path relative to ``site_dir`` of the files written beside it (the report's);
        ``result`` → ``result.json`` is added. Call this after everything else of the site is written.
    """
    site_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(build.record.public().model_dump(mode="json"), site_dir / "record.json")
    listed = dict(sorted({**(artifacts or {}), "result": RESULT_FILE}.items()))
    path = site_dir / RESULT_FILE
    write_json_atomic(build.result.model_copy(update={"artifacts": listed}).model_dump(mode="json"), path)
    return path
