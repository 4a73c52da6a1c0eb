"""Run one site through the pipeline: record → scans → matches → poses → grids → dimension table.

The runner owns the order, the timing and the errors; the stages own the science. A failure is caught,
recorded with its stage and the input that caused it, and returned as a failed :class:`SiteResult`;
it never propagates to other sites.
"""

from __future__ import annotations

import math
import platform
import time
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from cistern_archive import __version__
from cistern_archive.catalog.loader import LoadedRecord
from cistern_archive.catalog.models import ScanRef, SiteRecord
from cistern_archive.core.errors import StageError
from cistern_archive.core.files import write_json_atomic
from cistern_archive.pipeline.contracts import (
    STAGES,
    DimensionRow,
    MatchGuess,
    MatchResult,
    Poses,
    StageParams,
    accepts_guess,
)
from cistern_archive.pipeline.registry import LoadedPlugin, Registry, default_registry
from cistern_archive.pipeline.results import (
    DimensionResult,
    PairResult,
    PluginProvenance,
    Provenance,
    ScanPose,
    SiteBuild,
    SiteResult,
    StageFailure,
    finite_or_none,
)
from cistern_archive.pipeline.intervals import ci95_half_width
from cistern_archive.pipeline.status import label_indices, site_status, weakness
from cistern_archive.sonar.readers import read_file
from cistern_archive.core.scan import RangeScan, Scan

T = TypeVar("T")

MAX_MATCH_ROUNDS = 6
"""Rounds of pair matching a localizer may ask for (:func:`match_rounds`)."""


@dataclass(frozen=True)
class Stage:
    """A resolved stage: the loaded plugin and its validated parameters."""

    plugin: LoadedPlugin
    params: StageParams

    @property
    def instance(self) -> Any:
        return self.plugin.instance

    def provenance(self, stage: str) -> PluginProvenance:
        info = self.plugin.info
        return PluginProvenance(
            stage=stage,
            plugin=info.name,
            distribution=info.distribution,
            version=info.version,
            params=self.params.model_dump(mode="json"),
        )


class _Timer:
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


def resolve_stages(record: SiteRecord, registry: Registry) -> dict[str, Stage]:
    """Load the record's plugin for every stage and validate its parameters."""
    stages = {}
    ties = {s.station: s.below for s in record.scans if s.below is not None}
    for stage in STAGES:
        choice = registry.choice(record.pipeline, stage)
        plugin = registry.load(stage, choice.plugin)
        params = dict(choice.params)
        if stage == "localizer" and ties and "below" in plugin.params_model.model_fields:
            params.setdefault("below", ties)  # the record's vertical ties (ScanRef.below)
        stages[stage] = Stage(plugin=plugin, params=registry.check_params(stage, choice.plugin, params))
    return stages


def load_scan(loaded: LoadedRecord, ref: ScanRef) -> Scan:
    """Read the scan a record references and apply the record's station, heading and depth."""
    result = read_file(loaded.resolve(ref.file), ref.format)
    if ref.index >= len(result.scans):
        raise ValueError(f"file holds {len(result.scans)} scan(s); index {ref.index} requested")
    scan = result.scans[ref.index]
    changes: dict[str, Any] = {"station": ref.station}
    if ref.yaw_deg is not None:
        changes["yaw_rad"] = math.radians(90.0 - ref.yaw_deg)
    if ref.depth_m is not None:
        changes["depth_m"] = ref.depth_m
    if ref.time is not None:
        changes["timestamp"] = ref.time.timestamp()
    return scan.replace(**changes)


def pair_rng(seed: int, i: int, j: int) -> np.random.Generator:
    """The generator of one directed pair: independent of the order pairs run in."""
    return np.random.default_rng([seed, i, j])


def _run(stage: str, input_label: str, func: Callable[[], T]) -> T:
    try:
        return func()
    except StageError:
        raise
    except Exception as exc:
        raise StageError(stage, input_label, f"{type(exc).__name__}: {exc}") from exc


def build_site(loaded: LoadedRecord, *, registry: Registry | None = None,
               on_stage: Callable[[str], None] | None = None) -> SiteBuild:
    """Run the whole pipeline for one site; never raises for a stage failure.

    ``on_stage(name)`` is called as each stage starts (the rebuild shows it on a terminal).

    Returns
    -------
    SiteBuild
        ``result.status`` is ``"ok"``, ``"partial"`` or ``"failed"`` (:func:`~cistern_archive.pipeline.status.site_status`,
        with ``result.status_reasons``; ``result.failure`` names the stage and the input that stopped a
        build); the arrays reached before a failure are kept for the report.
    """
    from cistern_archive.sonar.segmentation import segment

    registry = registry or default_registry()
    record = loaded.record
    timer = _Timer(on_stage)
    build = SiteBuild(result=SiteResult(site_id=record.id, name=record.name, status="ok"), record=record)
    stages: dict[str, Stage] = {}
    try:
        with timer.stage("configure"):
            stages = _run("configure", str(loaded.path), lambda: resolve_stages(record, registry))
            build.record = record = registry.resolve(record)  # record.json names every stage
        with timer.stage("load"):
            for ref in record.scans:
                build.raw_scans.append(_run("load", ref.file, lambda ref=ref: load_scan(loaded, ref)))
        with timer.stage("segment"):
            for ref, scan in zip(record.scans, build.raw_scans):
                build.range_scans.append(_run("segment", ref.file, lambda s=scan: segment(s, record.segmentation)))
        localizer, matcher = stages["localizer"], stages["matcher"]
        with timer.stage("match"):
            def run_pair(i: int, j: int, guess: MatchGuess | None) -> MatchResult:
                return _run("match", _pair_label(record, i, j),
                            lambda: match_pair(matcher.instance, matcher.params, build.range_scans, record.seed,
                                               i, j, guess))

            def plan(label: str, func: Callable[[], T]) -> T:
                return _run("match", label, func)

            build.matches.extend(match_rounds(build.range_scans, localizer.instance, localizer.params, run_pair,
                                              plan=plan))
        with timer.stage("localize"):
            build.poses = _run("localize", f"{len(build.matches)} matches",
                               lambda: localizer.instance.localize(build.range_scans, build.matches, localizer.params))
        mapper, comparator = stages["mapper"], stages["comparator"]
        with timer.stage("map"):
            build.map_result = _run("map", f"{int(build.poses.placed.sum())} placed scans",
                                    lambda: mapper.instance.build(build.range_scans, build.poses, mapper.params))
        with timer.stage("compare"):
            build.table = _run("compare", f"{len(record.references)} reference dimensions",
                               lambda: comparator.instance.compare(build.map_result, build.poses, record.references,
                                                                   record.station_index(), comparator.params))
        with timer.stage("mesh"):
            build.mesh = _run("mesh", f"{len(build.map_result.grids)} depth slices",
                              lambda: mesh_step(build))
    except StageError as exc:
        build.result.status = "failed"
        build.result.failure = StageFailure(
            stage=exc.stage, input=exc.input, error=exc.message,
            traceback="".join(traceback.format_exception(exc.__cause__ or exc)),
        )
    build.result = assemble_result(build, loaded, stages, timer.timings)
    return build


def mesh_step(build: SiteBuild):
    """The wall surface of the site from its evidence grids (:func:`cistern_archive.grid.surface.wall_surface`),
    or ``None`` when no wall was seen."""
    from cistern_archive.grid.surface import wall_surface

    return wall_surface(build.map_result, build.poses, [s.depth_m for s in build.range_scans])


def _pair_label(record: SiteRecord, i: int, j: int) -> str:
    stations = [s.station for s in record.scans]
    return f"pair {i}->{j} ({stations[i]} -> {stations[j]})"


def match_rounds(
    scans: Sequence[RangeScan], localizer: Any, localizer_params: StageParams,
    run_pair: Callable[[int, int, MatchGuess | None], MatchResult],
    *, plan: Callable[[str, Callable[[], Any]], Any] = lambda label, func: func(),
) -> list[MatchResult]:
    """Every match a localizer asks for: ``localizer.pairs`` first, then, when the localizer has
    ``guided_pairs``, the further rounds it works out from the matches so far (each pair with a
    :class:`MatchGuess` or ``None``), until it asks for no new pair or ``MAX_MATCH_ROUNDS`` rounds have
    run. ``run_pair(i, j, guess)`` matches one pair (e.g. with :func:`match_pair`); ``plan(label, func)``
    runs the localizer's own calls (the runner uses it to label a failure). A pair already matched is not
    matched again."""
    pairs = plan("pair list", lambda: localizer.pairs(len(scans), localizer_params))
    matches = [run_pair(i, j, None) for i, j in pairs]
    guided = getattr(localizer, "guided_pairs", None)
    if guided is None:
        return matches
    for round_no in range(2, MAX_MATCH_ROUNDS + 1):
        done = {(m.i, m.j) for m in matches}
        asked = plan(f"pair list of round {round_no}", lambda: guided(scans, list(matches), localizer_params))
        fresh = [(i, j, guess) for i, j, guess in asked if (i, j) not in done]
        if not fresh:
            break
        matches += [run_pair(i, j, guess) for i, j, guess in fresh]
    return matches


def match_pair(matcher: Any, params: StageParams, scans: Sequence[RangeScan], seed: int, i: int, j: int,
               guess: MatchGuess | None = None) -> MatchResult:
    """Match the directed pair ``(i, j)`` with its own seeded generator (:func:`pair_rng`) and the
    ``guess`` when the matcher takes one (:func:`~cistern_archive.pipeline.contracts.accepts_guess`;
    otherwise the pair is matched without it and recorded so); ``i``, ``j``, ``guess`` and a wall-clock
    time when the matcher reports none are set on the result."""
    start = time.perf_counter()
    extra = {"guess": guess} if guess is not None and accepts_guess(matcher) else {}
    result = matcher.match(scans[i], scans[j], params, rng=pair_rng(seed, i, j), **extra)
    if not isinstance(result, MatchResult):
        raise TypeError(f"matcher returned {type(result).__name__}, expected MatchResult")
    seconds = result.seconds if math.isfinite(result.seconds) and result.seconds > 0 else time.perf_counter() - start
    checked = checked_match(result)
    return MatchResult(**{**checked.__dict__, "i": i, "j": j, "seconds": seconds, "guess": extra.get("guess")})


def checked_match(result: MatchResult) -> MatchResult:
    """``result`` when every number in it is usable, else the same pair turned into a failure.

    A converged estimate must have a finite displacement, heading correction and weight, and its
    covariance (when given) must be a finite, symmetric, positive-definite 3 × 3 matrix; a confidence
    must lie in [0, 1]. A matcher that breaks this fails only its pair, with a reason naming what was
    wrong; a non-converged pair keeps its reason, and non-finite numbers never reach ``result.json``
    (:func:`assemble_result` writes them as ``null``).
    """
    problem = _match_problem(result)
    weight = float(result.weight) if math.isfinite(result.weight) else 0.0
    if not problem:
        tentative = result.tentative and not result.converged
        return result if (weight, tentative) == (result.weight, result.tentative) else \
            replace(result, weight=weight, tentative=tentative)
    reason = result.reason if not result.converged and result.reason else f"unusable matcher output: {problem}"
    return replace(result, converged=False, reason=reason, weight=weight, covariance=None, confidence=None,
                   tentative=False)


def _match_problem(result: MatchResult) -> str:
    values = {"dx_m": result.dx_m, "dy_m": result.dy_m, "dyaw_rad": result.dyaw_rad, "weight": result.weight}
    bad = [name for name, value in values.items() if not (isinstance(value, (int, float)) and math.isfinite(value))]
    if bad:
        return "non-finite " + ", ".join(bad)
    if result.confidence is not None and not 0.0 <= result.confidence <= 1.0:
        return f"confidence {result.confidence!r} outside [0, 1]"
    cov = result.covariance
    if cov is None:
        return ""
    cov = np.asarray(cov, dtype=np.float64)
    if cov.shape != (3, 3):
        return f"covariance of shape {cov.shape}, expected (3, 3)"
    if not np.isfinite(cov).all():
        return "covariance with non-finite entries"
    if not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-12):
        return "covariance not symmetric"
    if np.linalg.eigvalsh(0.5 * (cov + cov.T))[0] <= 0:
        return "covariance not positive definite"
    return ""


def assemble_result(build: SiteBuild, loaded: LoadedRecord, stages: dict[str, Stage],
                    timings: dict[str, float]) -> SiteResult:
    """Fill the JSON result from whatever the build reached."""
    record = loaded.record
    result = build.result.model_copy()
    truth = {t.station: t for t in record.truth}
    poses = build.poses
    labels = [ref.station for ref in record.scans]
    scans = []
    for k, ref in enumerate(record.scans):
        raw = build.raw_scans[k] if k < len(build.raw_scans) else None
        placed = bool(poses is not None and poses.placed[k])
        sigma = (None, None)
        if placed and poses.covariance is not None:
            sigma = (finite_or_none(math.sqrt(poses.covariance[k, 0, 0])),
                     finite_or_none(math.sqrt(poses.covariance[k, 1, 1])))
        t = truth.get(ref.station)
        scans.append(ScanPose(
            index=k, id=ref.station, file=ref.file,
            x_m=finite_or_none(poses.xy_m[k, 0]) if placed else None,
            y_m=finite_or_none(poses.xy_m[k, 1]) if placed else None,
            yaw_rad=float(poses.yaw_rad[k]) if poses is not None else (raw.yaw_rad if raw else 0.0),
            depth_m=raw.depth_m if raw else (ref.depth_m or 0.0),
            placed=placed,
            reason=label_indices(poses.reasons[k] if poses is not None else "not localized: " + (result.error or ""),
                                 labels),
            sigma_x_m=sigma[0], sigma_y_m=sigma[1],
            truth_x_m=t.x_m if t else None, truth_y_m=t.y_m if t else None,
        ))
    result.scans = scans
    result.reference_scan = poses.reference if poses is not None and poses.reference >= 0 else None
    result.pairs = [
        PairResult(i=m.i, j=m.j, dx_m=finite_or_none(m.dx_m), dy_m=finite_or_none(m.dy_m), dyaw_rad=finite_or_none(m.dyaw_rad),
                   weight=finite_or_none(m.weight) or 0.0, confidence=finite_or_none(m.confidence), tentative=m.tentative,
                   converged=m.converged, iterations=m.iterations, seconds=round(m.seconds, 6), reason=m.reason,
                   guess=None if m.guess is None else [m.guess.dx_m, m.guess.dy_m, m.guess.dyaw_rad, m.guess.radius_m])
        for m in build.matches
    ]
    if build.table is not None:
        result.dimensions = [dimension_result(row, _requested_probes(record, k, row), labels,
                                              cell_m=_cell_at(build, row.depth_m), poses=poses)
                             for k, row in enumerate(build.table.rows)]
        result.dimension_stats = {k: finite_or_none(v) for k, v in sorted(build.table.stats.items())}
    if build.map_result is not None:
        result.map_stats = {k: float(v) for k, v in sorted(build.map_result.stats.items())}
    result.status, result.status_reasons = site_status(
        failed_stage=result.error, scans_placed=[s.placed for s in scans], labels=labels,
        unmeasured=_unmeasured(record, result.dimensions) if build.table is not None else [])
    result.timings_s = dict(timings)
    result.timings_s["total"] = round(sum(timings.values()), 6)
    result.provenance = Provenance(
        code_version=__version__,
        plugins=[s.provenance(name) for name, s in stages.items()],
        seeds={"site": record.seed},
        record_file=str(loaded.path.relative_to(loaded.root)) if loaded.path.is_relative_to(loaded.root) else str(loaded.path),
        python=platform.python_version(),
        numpy=np.__version__,
    )
    return result


def _requested_probes(record: SiteRecord, k: int, row: DimensionRow) -> int:
    """How many probes the record asked for the ``k``-th row (by position when it matches the
    reference, else by name and kind; 0 when no reference matches)."""
    refs = record.references
    if k < len(refs) and refs[k].name == row.name and refs[k].kind == row.reference_kind:
        return refs[k].measure.repeats
    same = [r for r in refs if r.name == row.name and r.kind == row.reference_kind]
    return same[0].measure.repeats if same else 0


def dimension_result(row: DimensionRow, requested: int, labels: Sequence[str], *, cell_m: float | None = None,
                     poses: Poses | None = None) -> DimensionResult:
    """The JSON form of a comparator row, flagged weak (:func:`~cistern_archive.pipeline.status.weakness`)
    and with its 95 % interval (:func:`~cistern_archive.pipeline.intervals.ci95_half_width`, on a grid of
    ``cell_m``) when it is measured."""
    map_m, std = finite_or_none(row.map_m), finite_or_none(row.probe_std_m)
    weak = weakness(len(row.probes), requested, std) if map_m is not None else ""
    ci = None if map_m is None or cell_m is None else ci95_half_width(
        row.probes, cell_m, [line for line in row.probe_lines if line is not None], poses)
    return DimensionResult(name=row.name, map_m=map_m, ci95_m=ci, reference_m=row.reference_m,
                           reference_kind=row.reference_kind, diff_m=finite_or_none(row.diff_m),
                           depth_m=finite_or_none(row.depth_m) or 0.0, probe_std_m=std,
                           probes_m=[float(p) for p in row.probes], probes_requested=requested,
                           weak=bool(weak), weak_reason=weak, note=label_indices(row.note, labels))


def _cell_at(build: SiteBuild, depth_m: float) -> float | None:
    """Cell size of the slice nearest ``depth_m``."""
    grids = build.map_result.grids if build.map_result is not None else ()
    return min(grids, key=lambda g: abs(g.depth_m - depth_m)).cell_m if grids else None


def _unmeasured(record: SiteRecord, dimensions: Sequence[DimensionResult]) -> list[str]:
    """``name (kind): reason`` of every reference the table has no measured value for."""
    measured = {(d.name, d.reference_kind) for d in dimensions if d.map_m is not None}
    notes = {(d.name, d.reference_kind): d.note for d in dimensions}
    out = []
    for ref in record.references:
        if (ref.name, ref.kind) not in measured:
            note = notes.get((ref.name, ref.kind)) or "no wall found"
            out.append(f"{ref.name} ({ref.kind}): {note}")
    return out


RESULT_FILE = "result.json"
"""The site result's file in a site folder."""


def write_site_result(build: SiteBuild, site_dir: Path, artifacts: Mapping[str, str] | None = None) -> Path:
    """Write ``result.json`` (and the resolved record, ``record.json``) into ``site_dir``, once.

    Parameters
    ----------
    artifacts : mapping, optional
        Artifact name → path relative to ``site_dir`` of the files written beside it (the report's);
        ``result`` → ``result.json`` is added. Call this after everything else of the site is written.
    """
    site_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(build.record.model_dump(mode="json"), site_dir / "record.json")
    listed = dict(sorted({**(artifacts or {}), "result": RESULT_FILE}.items()))
    path = site_dir / RESULT_FILE
    write_json_atomic(build.result.model_copy(update={"artifacts": listed}).model_dump(mode="json"), path)
    return path
