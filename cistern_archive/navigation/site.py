"""A survey record built into a site: the survey pipeline, the evidence grid, the tracks against DGPS.

:func:`build_survey_site` is the moving-vehicle counterpart of
:func:`cistern_archive.pipeline.runner.build_site`: it returns the same
:class:`~cistern_archive.pipeline.results.SiteBuild` (poses of the key frames, their pairs, the
mapper's evidence grid; no reference dimensions) plus a
:class:`~cistern_archive.core.tracks.TrackComparison`, so the report renders it like any site. Steps:

1. ``configure``: the record's stages resolved (matcher, localizer, mapper; the installed defaults
   where it names none) and the survey settings checked with them (:class:`SurveyConfig`);
2. ``load``: the dataset's logs (:func:`~cistern_archive.navigation.survey.load_marina_survey`);
3. ``survey``: dead reckoning, clock, compensated key frames, matches and poses
   (:func:`~cistern_archive.navigation.pipeline.run_survey`; its own steps are the ``survey_*`` entries
   of ``timings_s``);
4. ``map``: the mapper over the placed key frames;
5. ``track``: dead reckoning as logged, calibrated dead reckoning and the corrected track against the
   DGPS fixes between the first and the last placed key frame, summarised over those after the
   calibration window (:func:`evaluate_track`).

A failure of a step is recorded like a stage failure of a cistern (``result.failure``); it never raises.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from cistern_archive.catalog.loader import SURVEY_INPUTS, LoadedRecord
from cistern_archive.catalog.models import SiteRecord, Survey
from cistern_archive.core.errors import StageError
from cistern_archive.core.tracks import EstimatedTrack, PublishedRow, TrackComparison
from cistern_archive.navigation.accuracy import evaluate_track, independent_after
from cistern_archive.navigation.pipeline import SurveyConfig, SurveyRun, run_survey, usable_frames
from cistern_archive.navigation.survey import MarinaSurvey, load_marina_survey
from cistern_archive.pipeline.assemble import assemble_result
from cistern_archive.pipeline.registry import Registry, default_registry
from cistern_archive.pipeline.results import SiteBuild, SiteResult
from cistern_archive.pipeline.runner import StageTimer, record_failure, resolve_stages, run_stage
from cistern_archive.sonar.marina import KEYFRAME_CLOUD

T = TypeVar("T")

SURVEY_STAGES = ("matcher", "localizer", "mapper")
"""The record's stages a survey uses (it has no reference dimensions for a comparator)."""


def survey_config(record: SiteRecord) -> SurveyConfig:
    """The survey settings of a resolved ``record`` with its matcher, localizer and seed.

    Raises
    ------
    ValueError
        The settings and the stages do not fit together (:class:`SurveyConfig`'s checks).
    """
    pipeline = record.pipeline
    return SurveyConfig(**record.survey.settings.model_dump(), matcher=pipeline.matcher.plugin,
                        matcher_params=dict(pipeline.matcher.params), localizer=pipeline.localizer.plugin,
                        localizer_params=dict(pipeline.localizer.params), seed=record.seed)


def track_comparison(survey: MarinaSurvey, run: SurveyRun, spec: Survey, config: SurveyConfig) -> TrackComparison:
    """Dead reckoning as logged (the DVL's own compass, no calibration: the published dead-reckoning
    row's sensors), calibrated dead reckoning and the corrected track at the DGPS fixes of the run's span,
    summarised over the fixes after the calibration window (:func:`evaluate_track`)."""
    fix_time, fixes = survey.dgps_xy()
    start, end = run.span_s
    after = independent_after(fix_time, start, end, run.calibration_end_s)
    estimates: dict[str, Callable] = {
        "dead reckoning, DVL compass as logged": lambda t, tr=survey.dead_reckoning(heading="dvl"): tr.pose_at(t)[:, :2],
        f"dead reckoning, calibrated on the first {config.calibration_window_s:g} s of DGPS":
            lambda t: run.track.pose_at(t)[:, :2],
        f"pipeline ({config.matcher} + {config.localizer})": run.positions_at,
    }
    truth = fixes[(fix_time >= start) & (fix_time <= end)]
    tracks, times = [], None
    for name, position_at in estimates.items():
        row = evaluate_track(position_at, fix_time, fixes, start=start, end=end, evaluated_from=after)
        times = row["time"]
        tracks.append(EstimatedTrack(name=name, xy_m=position_at(times), start_aligned_errors_m=row["start_aligned_errors"],
                                     rigid_errors_m=row["rigid_errors"], evaluated=row["evaluated"]))
    published = spec.published
    return TrackComparison(
        time_s=times, fixes_xy_m=truth, tracks=tuple(tracks),
        published=tuple(PublishedRow(r.method, r.mean_m, r.sd_m, r.max_m) for r in published.rows) if published else (),
        published_source=published.source if published else "",
        calibration_end_s=run.calibration_end_s,
        revolutions=len(run.scans), revolutions_available=len(usable_frames(survey, run.track, run.clock_offset_s)),
        clock_offset_s=float(run.clock_offset_s))


def build_survey_site(loaded: LoadedRecord, *, registry: Registry | None = None,
                      on_stage: Callable[[str], None] | None = None) -> SiteBuild:
    """Build a survey record (the steps of the module docstring); never raises for a step's failure.

    Returns
    -------
    SiteBuild
        As :func:`~cistern_archive.pipeline.runner.build_site`, with ``track`` and ``scan_files`` (the
        key frames' point clouds) set when the build got that far.
    """
    record = loaded.record
    registry = registry or default_registry()
    build = SiteBuild(result=SiteResult(site_id=record.id, name=record.name, status="ok"), record=record)
    timer = StageTimer(on_stage)
    stages: dict = {}
    label = str(loaded.path)
    try:
        with timer.stage("configure"):
            stages = {k: v for k, v in run_stage("configure", label, lambda: resolve_stages(record, registry)).items()
                      if k in SURVEY_STAGES}
            build.record = run_stage("configure", label, lambda: registry.resolve(record))
            config = run_stage("configure", label, lambda: survey_config(build.record))
        root = loaded.survey_root()
        with timer.stage("load"):
            survey = run_stage("load", str(root), lambda: load_marina_survey(root))
        if on_stage is not None:
            on_stage("survey")  # timed by its own steps, the survey_* entries below
        run = run_stage("survey", f"{len(survey.keyframes)} key frames", lambda: run_survey(survey, config, registry))
        timer.timings.update({f"survey_{k}": round(v, 6) for k, v in run.timings_s.items()})
        build.range_scans, build.matches, build.poses = list(run.scans), list(run.matches), run.poses
        build.scan_files = [SURVEY_INPUTS + KEYFRAME_CLOUD.format(frame=k) for k in run.frames]
        mapper = stages["mapper"]
        with timer.stage("map"):
            build.map_result = run_stage("map", f"{int(run.poses.placed.sum())} placed key frames",
                                         lambda: mapper.instance.build(build.range_scans, build.poses, mapper.params))
        with timer.stage("track"):
            build.track = run_stage("track", "DGPS fixes", lambda: track_comparison(survey, run, record.survey, config))
    except StageError as exc:
        record_failure(build, exc)
    build.result = assemble_result(build, loaded, [s.provenance(n) for n, s in stages.items()], timer.timings)
    return build
