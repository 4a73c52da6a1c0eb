"""The Girona marina run (../shared/data/marina): dead reckoning, frames, clock and the survey pipeline."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cistern_archive.navigation.accuracy import evaluate_track
from cistern_archive.navigation.calibration import fit_start_calibration
from cistern_archive.navigation.conventions import Convention, Revolution, consecutive_overlap
from cistern_archive.navigation.track import dead_reckon
from cistern_archive.sonar.readers.pcd import read_points

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def survey(shared_data: Path):
    from cistern_archive.navigation.survey import load_marina_survey

    root = shared_data / "marina"
    if not root.is_dir():
        pytest.skip(f"marina recordings not found at {root}")
    return load_marina_survey(root)


def _fixes(survey, track):
    fix_time, fixes = survey.dgps_xy()
    return evaluate_track(lambda t: track.pose_at(t)[:, :2], fix_time, fixes, start=track.time[0], end=track.time[-1])


def test_survey_logs(survey):
    assert len(survey.dvl) == 4961  # the 84 pings with bottom status 0 are dropped
    assert len(survey.keyframes) == 230 and len(survey.beam_time) == 46259
    times = survey.keyframe_beam_times(5)
    assert len(times) == 200 and times[0] == pytest.approx(survey.keyframes[5][0], abs=1e-3)


def test_dead_reckoning_as_logged_is_near_the_published_error(survey):
    """DVL velocity turned by the DVL's own compass, no calibration: the published 17.46 m mean ± 15 %."""
    stats = _fixes(survey, survey.dead_reckoning(heading="dvl"))["start_aligned"]
    assert abs(stats.mean_m - 17.46) < 0.15 * 17.46
    vt, v = survey.body_velocity()
    ht, yaw = survey.heading("dvl")
    starboard = dead_reckon(vt, v * [1.0, -1.0], ht, yaw)  # the other handedness of the DVL's y axis
    assert _fixes(survey, starboard)["start_aligned"].mean_m > 100.0


def test_start_calibration_fixes_the_mti_compass_offset(survey):
    fix_time, fixes = survey.dgps_xy()
    raw = survey.dead_reckoning(heading="mti")
    calibration = fit_start_calibration(raw, fix_time, fixes, window_s=300.0)
    assert calibration.as_dict()["compass_offset_deg"] == pytest.approx(-22.5, abs=1.5)
    assert 0.9 < calibration.scale < 1.05
    calibrated = survey.dead_reckoning(scale=calibration.scale, yaw_offset_rad=calibration.yaw_offset_rad)
    assert _fixes(survey, calibrated)["start_aligned"].mean_m < 0.5 * _fixes(survey, raw)["start_aligned"].mean_m


def test_cloud_frame_conventions_beat_the_alternatives(survey):
    """Mirror, beam order and clock offset (marina module docstring) on key frames 40-60."""
    track = survey.dead_reckoning(yaw_offset_rad=math.radians(22.5))
    revolutions = {k: Revolution(read_points(survey.pcd_dir / f"pclKeyFrame{k}.pcd")[0], survey.keyframe_beam_times(k))
                   for k in range(40, 61)}
    measured = consecutive_overlap(revolutions, track, Convention())
    for other in (Convention(mirrored=False), Convention(clockwise=True), Convention(per_beam_time=False),
                  Convention(clock_offset_s=-1.0), Convention(mount_deg=200.0)):
        assert consecutive_overlap(revolutions, track, other) < measured - 0.02, other


@pytest.mark.slow
def test_survey_pipeline_beats_calibrated_dead_reckoning_on_the_first_revolutions(survey):
    from cistern_archive.navigation.pipeline import SurveyConfig, run_survey

    run = run_survey(survey, SurveyConfig(max_keyframes=60))
    assert run.poses.placed.all() and 0.25 <= run.clock_offset_s <= 1.25
    assert sum(m.converged for m in run.matches) >= 5
    fix_time, fixes = survey.dgps_xy()
    start, end = run.span_s
    after = run.calibration_end_s
    pipeline = evaluate_track(run.positions_at, fix_time, fixes, start=start, end=end, evaluated_from=after)["start_aligned"]
    dead = evaluate_track(lambda t: run.track.pose_at(t)[:, :2], fix_time, fixes, start=start, end=end,
                          evaluated_from=after)["start_aligned"]
    assert pipeline.mean_m < dead.mean_m
    assert np.isfinite(pipeline.max_m)
