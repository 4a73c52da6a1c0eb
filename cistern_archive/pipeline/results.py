"""The JSON result of a site build (``result.json``) and the in-memory bundle the report renders.

:class:`SiteResult` is the stable, documented output; :class:`SiteBuild` carries it together with the
arrays (scans, grids, match histories) that figures need and JSON should not hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from cistern_archive.pipeline.contracts import DimensionTable, MapResult, MatchResult, Poses
from cistern_archive.pipeline.status import SiteStatus
from cistern_archive.core.scan import RangeScan, Scan
from cistern_archive.core.tracks import TrackComparison


def finite_or_none(value: float | None) -> float | None:
    """``value`` as a float, or ``None`` when it is missing or not finite (JSON has no NaN)."""
    return float(value) if value is not None and math.isfinite(value) else None

RESULT_SCHEMA_VERSION = 1


class Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ScanPose(Model):
    index: int
    id: str = Field(description="station label")
    file: str
    x_m: float | None
    y_m: float | None
    yaw_rad: float
    depth_m: float
    placed: bool
    reason: str = ""
    sigma_x_m: float | None = None
    sigma_y_m: float | None = None
    truth_x_m: float | None = None
    truth_y_m: float | None = None
    echo_scale: float | None = Field(None, description="the scan's echo range over the range of its walls, "
                                     "by which its matches were lengthened before it was placed (null: not "
                                     "estimated, as with walls at one depth)")


class PairResult(Model):
    i: int
    j: int
    dx_m: float | None
    """``None`` when the matcher reached no estimate (likewise ``dy_m``, ``dyaw_rad``)."""
    dy_m: float | None
    dyaw_rad: float | None
    weight: float
    converged: bool
    iterations: int
    seconds: float
    reason: str = ""
    confidence: float | None = None
    """The matcher's probability that the estimate is right (0..1), when it calibrates one."""
    tentative: bool = False
    """A non-converged best estimate a localizer may use where converged matches corroborate it."""
    guess: list[float] | None = None
    """``[dx_m, dy_m, dyaw_rad, radius_m]`` of the window the matcher searched (guided pairs only)."""
    alternatives: list[list[float]] = Field(default_factory=list)
    """``[dx_m, dy_m, dyaw_rad, radius_m]`` of each rival place the matcher found nearly as good."""


class DimensionResult(Model):
    name: str
    map_m: float | None
    ci95_m: float | None = Field(default=None, description="half-width of the 95 % interval of map_m "
                                                           "(cistern_archive.pipeline.intervals)")
    reference_m: float
    reference_kind: Literal["mosaic", "truth"]
    diff_m: float | None
    depth_m: float = 0.0
    probe_std_m: float | None = None
    probes_m: list[float] = Field(default_factory=list)
    probes_requested: int = Field(default=0, description="probes the record asked for (0: not known)")
    heading_shift_m: float | None = Field(default=None, description="how much map_m changes when its probes "
                                          "turn 2° about the station they are given from (a compass bias "
                                          "of the whole map; None: not checked)")
    weak: bool = Field(default=False, description="too few probes, too wide a spread, leaning walls or too "
                                                  "large a heading shift to trust (cistern_archive.pipeline.status)")
    weak_reason: str = ""
    note: str = ""


class PluginProvenance(Model):
    stage: str
    plugin: str
    distribution: str
    version: str
    params: dict[str, Any]


class Provenance(Model):
    software: str = "cistern-archive"
    code_version: str
    plugins: list[PluginProvenance]
    seeds: dict[str, int]
    record_file: str
    python: str
    numpy: str


class StageFailure(Model):
    stage: str
    input: str
    error: str
    traceback: str = ""


class TrackErrors(Model):
    """Errors of one estimated track at the DGPS fixes (m): start-aligned and after rigid alignment."""

    name: str
    start_aligned: dict[str, float | int]
    rigid: dict[str, float | int]


class TrackSummary(Model):
    """A moving survey's tracks against DGPS (:class:`~cistern_archive.core.tracks.TrackComparison`)."""

    fixes: int = Field(description="DGPS fixes of the span drawn; each track's errors count those after "
                                   "calibration_end_s (their own 'fixes')")
    span_s: float
    revolutions: int
    revolutions_available: int
    clock_offset_s: float
    calibration_end_s: float | None = None
    tracks: list[TrackErrors]
    published_source: str = ""
    published: list[dict[str, float | str]] = Field(default_factory=list)


class SiteResult(Model):
    """Everything a site build produced that fits in JSON."""

    schema_version: int = RESULT_SCHEMA_VERSION
    site_id: str
    name: str
    status: SiteStatus
    status_reasons: list[str] = Field(default_factory=list, description="why the status is not ok")
    scans: list[ScanPose] = Field(default_factory=list)
    pairs: list[PairResult] = Field(default_factory=list)
    group_links: list[tuple[str, str]] = Field(default_factory=list, description="stations whose groups of "
                                               "scans were joined by fitting the groups as wholes, not by a match")
    group_link_ci95_m: list[float | None] = Field(default_factory=list, description="for each group link, the "
                                                  "radius (m) within which its two stations' relative position "
                                                  "lies with 95 % probability")
    dimensions: list[DimensionResult] = Field(default_factory=list)
    dimension_stats: dict[str, float | None] = Field(default_factory=dict)
    map_stats: dict[str, float] = Field(default_factory=dict)
    reference_scan: int | None = None
    provenance: Provenance | None = None
    timings_s: dict[str, float] = Field(default_factory=dict)
    failure: StageFailure | None = None
    track: TrackSummary | None = Field(default=None, description="a moving survey's tracks against DGPS")
    artifacts: dict[str, str] = Field(default_factory=dict, description="name -> path relative to the site folder")

    @property
    def error(self) -> str | None:
        return None if self.failure is None else f"{self.failure.stage}: {self.failure.input}: {self.failure.error}"


@dataclass(eq=False)
class SiteBuild:
    """A built site: the JSON result plus the arrays behind it, for the report.

    Attributes that a failed build did not reach are ``None`` or empty.
    """

    result: SiteResult
    record: Any  # cistern_archive.catalog.models.SiteRecord
    raw_scans: list[Scan] = field(default_factory=list)
    range_scans: list[RangeScan] = field(default_factory=list)
    matches: list[MatchResult] = field(default_factory=list)
    poses: Poses | None = None
    map_result: MapResult | None = None
    table: DimensionTable | None = None
    mesh: Any = None  # cistern_archive.grid.surface.SurfaceMesh: the wall surface of the mesh step
    scan_files: list[str] = field(default_factory=list)
    """The input each scan was read from, when the record does not list its scans (a survey's revolutions)."""
    track: TrackComparison | None = None
    """A moving survey's tracks against ground truth."""
    echo_scale: np.ndarray | None = None
    """Each scan's echo range over the range of its walls, where the mapper told it and the matches were
    lengthened by it (:func:`~cistern_archive.pipeline.runner.localize_step`)."""


def track_summary(track: TrackComparison) -> TrackSummary:
    """The JSON summary of a track comparison (``result.json``)."""
    return TrackSummary(
        fixes=len(track.time_s), span_s=round(track.span_s, 3), revolutions=track.revolutions,
        revolutions_available=track.revolutions_available, clock_offset_s=track.clock_offset_s,
        calibration_end_s=track.calibration_end_s,
        tracks=[TrackErrors(name=t.name, start_aligned=t.start_aligned.as_dict(), rigid=t.rigid.as_dict())
                for t in track.tracks],
        published_source=track.published_source,
        published=[{"method": r.method, "mean_m": r.mean_m, "sd_m": r.sd_m, "max_m": r.max_m} for r in track.published])
