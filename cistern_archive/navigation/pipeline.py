"""The marina survey end to end: dead reckoning, calibration, clock, compensated scans, matches, graph.

Steps (each a function below, driven by :func:`run_survey`):

1. dead reckoning from the DVL and the MTi (:mod:`.track`), calibrated on DGPS of the first
   ``calibration_window_s`` only (:mod:`.calibration`);
2. the sonar-to-navigation clock offset, the candidate with the best consecutive-scan overlap
   (:mod:`.conventions`), then, when ``mount_offsets_deg`` lists corrections to try (none by default),
   the sonar's mount angle, the best overlap of revolutions ``mount_gap`` apart around the reader's
   nominal mount; both estimated on the first half of the key frames only;
3. every key frame read by the ``marina-pcd`` reader and motion compensated to its mid time
   (:mod:`.motion`);
4. matching through the plugin registry, as the runner does (:func:`cistern_archive.pipeline.runner.match_rounds`):
   the localizer's consecutive pairs with the dead-reckoned guess, then its loop-closure candidates;
5. the ``nav-graph`` localizer, and the corrected continuous track (:mod:`.correction`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import Field, model_validator

from cistern_archive.catalog.models import SurveySettings

from cistern_archive.navigation.calibration import Calibration, fit_start_calibration
from cistern_archive.navigation.conventions import Convention, Revolution, best_of, peak_of
from cistern_archive.navigation.correction import corrected_positions
from cistern_archive.navigation.motion import compensated_range_scan
from cistern_archive.navigation.survey import MarinaSurvey
from cistern_archive.navigation.track import Track
from cistern_archive.pipeline.contracts import MatchGuess, MatchResult, Poses
from cistern_archive.pipeline.registry import Registry, default_registry
from cistern_archive.pipeline.runner import localize, match_pair, match_rounds, resolve_stage
from cistern_archive.sonar.readers import read_file
from cistern_archive.sonar.readers.pcd import read_points
from cistern_archive.core.scan import RangeScan, Scan, wrap_angle
from cistern_archive.sonar import marina


class SurveyConfig(SurveySettings):
    """Settings of :func:`run_survey`: a site record's survey settings (:class:`SurveySettings`) with the
    matcher and the localizer (a record's ``pipeline`` stages) and the seed."""

    matcher: str = "guided-correlative"
    matcher_params: dict = Field(default_factory=lambda: {"yaw_window_deg": 2.0})
    localizer: str = "nav-graph"
    localizer_params: dict = Field(default_factory=lambda: {"consecutive": False, "loop_min_gap": 5, "loop_per_scan": 2,
                                                            "compass_sigma_deg": 8.0})
    seed: int = 20040825

    @model_validator(mode="after")
    def _disjoint_submaps(self) -> "SurveyConfig":
        """Scans matched as loops must not share revolutions: a submap matched with itself is no evidence."""
        gap = self.localizer_params.get("loop_min_gap", 10)
        if self.localizer == "nav-graph" and gap <= 2 * self.submap_neighbours:
            raise ValueError(f"loop_min_gap {gap} must exceed twice submap_neighbours ({self.submap_neighbours}): "
                             "loop candidates would share revolutions")
        if self.localizer_params.get("consecutive", True) and self.localizer == "nav-graph" and self.submap_neighbours:
            raise ValueError("consecutive matches of submaps share revolutions; set localizer_params.consecutive "
                             "to false or submap_neighbours to 0")
        return self


@dataclass
class SurveyRun:
    """Everything :func:`run_survey` measured."""

    raw_track: Track
    calibration: Calibration
    track: Track
    clock_offset_s: float
    clock_scores: list[tuple[float, float]]
    mount_offset_deg: float
    mount_scores: list[tuple[float, float]]
    frames: list[int]
    scans: list[RangeScan]
    matches: list[MatchResult]
    poses: Poses
    timings_s: dict[str, float] = field(default_factory=dict)

    def positions_at(self, times: np.ndarray) -> np.ndarray:
        """The corrected track at ``times`` (navigation clock)."""
        placed = np.flatnonzero(self.poses.placed)
        node_times = np.array([self.scans[k].time_s for k in placed])
        node_poses = np.column_stack([self.poses.xy_m[placed], self.poses.yaw_rad[placed]])
        return corrected_positions(self.track, node_times, node_poses, times)

    @property
    def calibration_end_s(self) -> float:
        """End of the DGPS window the dead reckoning was calibrated on (navigation clock): the errors are
        evaluated at the fixes after it."""
        return self.calibration.end_s

    @property
    def span_s(self) -> tuple[float, float]:
        """Navigation-clock times of the first and last placed scan."""
        times = [s.time_s for s, ok in zip(self.scans, self.poses.placed) if ok]
        return min(times), max(times)


def usable_frames(survey: MarinaSurvey, track: Track, offset_s: float) -> list[int]:
    """Key frames whose whole revolution lies inside the dead-reckoned track."""
    frames = []
    for k in sorted(survey.keyframes):
        begin, end = survey.keyframes[k]
        if begin + offset_s >= track.time[0] and end + offset_s <= track.time[-1]:
            frames.append(k)
    return frames


def first_half_revolutions(survey: MarinaSurvey, frames: list[int], stride: int, gap: int) -> dict[int, Revolution]:
    """Every ``stride``-th key frame of the first half of ``frames`` and those ``gap`` after it."""
    first_half = frames[: len(frames) // 2]
    chosen = set(first_half[::stride])
    chosen |= {k + gap for k in chosen if k + gap in first_half}
    return {k: Revolution(read_points(survey.pcd_dir / f"pclKeyFrame{k}.pcd")[0], survey.keyframe_beam_times(k))
            for k in sorted(chosen)}


def estimate_clock_offset(survey: MarinaSurvey, track: Track, frames: list[int], config: SurveyConfig
                          ) -> tuple[float, list[tuple[float, float]]]:
    """The offset (added to sonar times) with the best consecutive overlap on the first half of ``frames``."""
    revolutions = first_half_revolutions(survey, frames, config.clock_stride, 1)
    best, scored = best_of(revolutions, track, [Convention(clock_offset_s=o) for o in config.clock_offsets_s])
    return best.clock_offset_s, [(c.clock_offset_s, s) for c, s in scored]


def estimate_mount_offset(survey: MarinaSurvey, track: Track, frames: list[int], clock_offset_s: float,
                          config: SurveyConfig) -> tuple[float, list[tuple[float, float]]]:
    """The correction (degrees, added to the reader's nominal sonar mount) with the best overlap of
    revolutions ``mount_gap`` apart on the first half of ``frames``, refined between the grid's samples
    (:func:`peak_of`); 0 when no candidates are configured.

    A mount error ``e`` rotates every echo about the vehicle, so a displacement measured by matching
    two scans comes out rotated by ``e`` against the odometry's: loop closures that span tens of metres
    then bend the track sideways (a 5° error is 2.6 m across a 30 m loop).
    """
    if not config.mount_offsets_deg:
        return 0.0, []
    revolutions = first_half_revolutions(survey, frames, config.clock_stride, config.mount_gap)
    candidates = [Convention(clock_offset_s=clock_offset_s, mount_deg=marina.SONAR_MOUNT_DEG + o)
                  for o in config.mount_offsets_deg]
    _, scored = best_of(revolutions, track, candidates, gap=config.mount_gap)
    offsets, scores = list(config.mount_offsets_deg), [score for _, score in scored]
    return peak_of(offsets, scores), list(zip(offsets, scores))


def compensated_scans(survey: MarinaSurvey, track: Track, frames: list[int], offset_s: float,
                      config: SurveyConfig, mount_offset_deg: float = 0.0) -> list[RangeScan]:
    """Every key frame read, its bearings turned by ``mount_offset_deg`` (:func:`remount`), and motion
    compensated (:func:`compensated_range_scan`), with the echoes of its ``submap_neighbours``
    revolutions on either side."""
    raw = [remount(read_file(survey.pcd_dir / f"pclKeyFrame{k}.pcd", "marina-pcd").scans[0], mount_offset_deg)
           .replace(station=f"kf{k}") for k in frames]
    w = config.submap_neighbours
    scans = []
    for q, scan in enumerate(raw):
        companions = raw[max(0, q - w):q] + raw[q + 1:q + 1 + w]
        range_scan, _ = compensated_range_scan(scan, track, clock_offset_s=offset_s, min_range_m=config.min_range_m,
                                               echo_position=config.echo_position, companions=companions)
        scans.append(range_scan)
    return scans


def remount(scan: Scan, offset_deg: float) -> Scan:
    """The scan with every body-frame bearing turned by ``offset_deg`` (a corrected sonar mount)."""
    if offset_deg == 0.0:
        return scan
    return scan.replace(bearings_rad=wrap_angle(scan.bearings_rad + math.radians(offset_deg)))


def odometry_guess(a: RangeScan, b: RangeScan, radius_m: float) -> MatchGuess:
    """The dead-reckoned ``p_b - p_a`` (map frame), no yaw correction, a ``±radius_m`` window."""
    return MatchGuess(float(b.odometry[0] - a.odometry[0]), float(b.odometry[1] - a.odometry[1]), 0.0, radius_m)


def run_survey(survey: MarinaSurvey, config: SurveyConfig = SurveyConfig(), registry: Registry | None = None) -> SurveyRun:
    """Run every step of the module docstring, with the plugins of ``registry`` (the installed ones by default)."""
    timings: dict[str, float] = {}
    start = time.perf_counter()
    raw = survey.dead_reckoning(heading=config.heading)
    fix_time, fixes = survey.dgps_xy()
    calibration = fit_start_calibration(raw, fix_time, fixes, window_s=config.calibration_window_s)
    track = survey.dead_reckoning(heading=config.heading, scale=calibration.scale,
                                  yaw_offset_rad=calibration.yaw_offset_rad)
    frames = usable_frames(survey, track, 0.0)
    if config.max_keyframes is not None:
        frames = frames[: config.max_keyframes]
    timings["dead_reckoning"] = time.perf_counter() - start
    offset, clock_scores = estimate_clock_offset(survey, track, frames, config)
    frames = [k for k in frames if k in set(usable_frames(survey, track, offset))]
    timings["clock"] = time.perf_counter() - start - sum(timings.values())
    mount, mount_scores = estimate_mount_offset(survey, track, frames, offset, config)
    timings["mount"] = time.perf_counter() - start - sum(timings.values())
    scans = compensated_scans(survey, track, frames, offset, config, mount)
    timings["scans"] = time.perf_counter() - start - sum(timings.values())
    registry = registry or default_registry()
    matcher = resolve_stage(registry, "matcher", config.matcher, config.matcher_params)
    localizer = resolve_stage(registry, "localizer", config.localizer, config.localizer_params)

    def run_pair(i: int, j: int, guess: MatchGuess | None) -> MatchResult:
        guess = guess or odometry_guess(scans[i], scans[j], config.consecutive_radius_m)
        return match_pair(matcher, scans, config.seed, i, j, guess)

    matches = match_rounds(scans, localizer, run_pair)
    timings["matching"] = time.perf_counter() - start - sum(timings.values())
    poses = localize(localizer, scans, matches)
    timings["localizer"] = time.perf_counter() - start - sum(timings.values())
    return SurveyRun(raw_track=raw, calibration=calibration, track=track, clock_offset_s=offset,
                     clock_scores=clock_scores, mount_offset_deg=mount, mount_scores=mount_scores, frames=frames,
                     scans=scans, matches=matches, poses=poses, timings_s=timings)


def data_root_default() -> Path:
    """``../shared/data/marina`` beside the repository."""
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "marina"
