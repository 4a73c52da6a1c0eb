"""Pydantic models of a site record (one YAML file per site in ``catalog/``).

Every model refuses unknown fields. Paths are relative to the catalog root and may not leave it.
See the README's "Catalog format" for an annotated example.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from pathlib import PurePosixPath
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

SLUG = re.compile(r"[a-z0-9]+(?:-[a-z0-9]+)*")
"""Site ids (matched whole with ``fullmatch``: a trailing newline is not part of a slug)."""
STATION = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9._-]{0,62}[A-Za-z0-9])?")
"""Station labels: they name files (``data/<site>/<station>.seanet``, ``scans/<station>.csv``), so no
path separators, no leading dot, no white space, at most 64 characters."""

class Strict(BaseModel):
    # NaN and inf are refused in every float field: they cannot be hashed into a build key (canonical
    # JSON) and no measurement of a site is infinite.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def check_slug(value: str) -> str:
    """Refuse a site id that is not a slug (the whole string: ``fullmatch``)."""
    if not SLUG.fullmatch(value):
        raise ValueError(f"id {value!r} must be a slug: lower-case letters, digits and single hyphens")
    return value


def check_station(value: str) -> str:
    """Refuse a station label that could not safely name a file inside the site's folder."""
    if not STATION.fullmatch(value):
        raise ValueError(f"station label {value!r} must be 1-64 letters, digits, '.', '_' or '-', "
                         "starting and ending with a letter or digit (it names files)")
    return value


def check_json_value(value: Any, where: str = "params") -> Any:
    """Refuse values that have no exact JSON form (NaN, inf, bytes, dates, non-string keys)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{where}: {value!r} is not a finite number")
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise ValueError(f"{where}: key {key!r} is not a string")
            check_json_value(item, f"{where}.{key}")
    elif isinstance(value, list):
        for k, item in enumerate(value):
            check_json_value(item, f"{where}[{k}]")
    elif not (value is None or isinstance(value, (str, int, float, bool))):
        raise ValueError(f"{where}: a {type(value).__name__} value has no JSON form")
    return value


def check_relative_path(value: str) -> str:
    """Refuse absolute paths and paths with ``..`` (they would leave the catalog root)."""
    path = PurePosixPath(value.replace("\\", "/"))
    if not value.strip():
        raise ValueError("path is empty")
    if path.is_absolute() or re.match(r"^[A-Za-z]:", value):
        raise ValueError(f"path {value!r} is absolute; give it relative to the catalog root")
    if ".." in path.parts:
        raise ValueError(f"path {value!r} leaves the catalog root")
    return str(path)


class Expedition(Strict):
    name: str
    date: dt.date | None = None
    team: list[str] = Field(default_factory=list)


class Location(Strict):
    """Where the site is. ``redact: true`` keeps exact coordinates out of public reports."""

    place: str = ""
    latitude: float | None = Field(default=None, ge=-90, le=90)
    longitude: float | None = Field(default=None, ge=-180, le=180)
    redact: bool = True


class SonarSettings(Strict):
    model: str = "Tritech Micron DST"
    frequency_khz: float | None = Field(default=None, gt=0)
    range_m: float | None = Field(default=None, gt=0)
    bins: int | None = Field(default=None, gt=0)
    step_deg: float | None = Field(default=None, gt=0)
    beam_width_deg: float = Field(default=3.0, gt=0, lt=90)
    vertical_beam_width_deg: float | None = Field(default=None, gt=0, lt=90,
                                                  description="the beam's width in elevation; not given: a "
                                                  "Micron's 35° is assumed")
    gain: float | None = Field(default=None, ge=0)


class Segmentation(Strict):
    """Beam segmentation settings (:mod:`cistern_archive.sonar.segmentation`).

    ``paper`` is McVicker et al. Sec. III-B exactly; ``cfar`` and ``shadow`` are the alternatives
    compared in ``benchmarks/segmentation.py``. ``shadow`` is the default: on simulated sites with truth it
    puts the most beams on the wall and the fewest on reverberation, ghosts and ring-down.
    """

    method: Literal["paper", "cfar", "shadow"] = "shadow"
    threshold: float = Field(default=50.0, ge=0, le=255)
    min_range_m: float = Field(default=0.0, ge=0)
    faint_walls: Literal["auto", "on", "off"] = Field(default="auto", description=(
        "shadow method: also take faint wall echoes that cast a shadow as deep as most of their height and "
        "that both neighbouring beams confirm, for heads whose time-varying gain rises more slowly than the "
        "spreading loss (e.g. 20 log R), whose distant walls come back faint; 'auto': on where a site's wall "
        "echoes fall off with range as through such a gain (decided per site when it is built)"))


class ScanRef(Strict):
    """One stationary scan of the site."""

    file: str
    format: str | None = None
    station: str
    yaw_deg: float | None = Field(default=None, description="compass heading override, degrees from north")
    depth_m: float | None = None
    time: dt.datetime | None = None
    index: int = Field(default=0, ge=0, description="which scan of a multi-scan file")
    below: str | None = Field(
        default=None,
        description="station this scan was taken directly below: the vehicle descended vertically from "
        "it, so both share one horizontal position (a field note; a localizer may use it as a tie)",
    )

    @field_validator("file")
    @classmethod
    def _relative(cls, value: str) -> str:
        return check_relative_path(value)

    @field_validator("station")
    @classmethod
    def _station(cls, value: str) -> str:
        return check_station(value)


class Probe(Strict):
    """How to measure a dimension in the map: from a point inside the site, along a direction, to the
    first wall on each side; ``repeats`` parallel probes ``spacing_m`` apart (the paper's 10 probes)."""

    method: Literal["probe", "auto-width", "auto-length"] = "probe"
    frame: str | None = Field(default=None, description="station label whose frame the probe is in")
    inside: tuple[float, float] = (0.0, 0.0)
    direction_deg: float = 0.0
    repeats: int = Field(default=1, ge=1, le=100)
    spacing_m: float = Field(default=0.2, ge=0)
    depth_m: float | None = None


class ReferenceDimension(Strict):
    """A dimension known from a tape measure (``truth``) or from the team's sonar mosaic (``mosaic``)."""

    name: str
    value_m: float = Field(gt=0)
    kind: Literal["mosaic", "truth"]
    measure: Probe = Field(default_factory=Probe)


class StageChoice(Strict):
    plugin: str
    params: dict[str, Any] = Field(default_factory=dict)

    @field_validator("params")
    @classmethod
    def _json_params(cls, value: dict[str, Any]) -> dict[str, Any]:
        return check_json_value(value)


class PipelineSpec(Strict):
    """The plugin of each stage; a stage left out (``None``) gets the installed default.

    The defaults come from the plugin registry (entry-point group ``cistern_archive.defaults``), never
    from the catalog: ``Registry.resolve`` fills them in, and ``record.json`` holds the resolved record.
    """

    matcher: StageChoice | None = None
    localizer: StageChoice | None = None
    mapper: StageChoice | None = None
    comparator: StageChoice | None = None


class SurveySettings(Strict):
    """How a moving survey is processed (:mod:`cistern_archive.navigation.pipeline`; lengths in metres,
    times in seconds). The matcher and the localizer are the record's ``pipeline`` stages."""

    heading: Literal["mti", "dvl"] = Field("mti", description="compass the dead reckoning turns by")
    calibration_window_s: float = Field(300.0, gt=0, description="DGPS used to calibrate, from its start")
    clock_offsets_s: list[float] = Field(default_factory=lambda: [-1.0, -0.5, 0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0],
                                         min_length=1, description="sonar clock offsets tried")
    clock_stride: int = Field(2, ge=1, description="every n-th key frame scores the clock offsets and mounts")
    mount_offsets_deg: list[float] = Field(default_factory=list,
                                           description="corrections of the sonar's nominal mount angle tried "
                                                       "(degrees, e.g. -10 to 10 in steps of 2; empty, the "
                                                       "default: keep the nominal mount)")
    mount_gap: int = Field(3, ge=1, description="revolutions apart of the scans that score the mount")
    min_range_m: float = Field(1.0, ge=0)
    echo_position: Literal["leading", "centre", "bins"] = "leading"
    submap_neighbours: int = Field(2, ge=0, description="revolutions on either side merged into a key frame")
    consecutive_radius_m: float = Field(1.5, gt=0, description="search radius around the odometry's guess")
    max_keyframes: int | None = Field(None, ge=2, description="only the first N usable revolutions")


class PublishedResult(Strict):
    """One published result on the same data: a method's position error mean / SD / max (m)."""

    method: str = Field(min_length=1)
    mean_m: float = Field(ge=0)
    sd_m: float = Field(ge=0)
    max_m: float = Field(ge=0)


class PublishedComparison(Strict):
    """A published table the survey's errors are shown beside, and where it was published."""

    source: str = Field(min_length=1, description="the citation (authors, venue, year, table)")
    rows: list[PublishedResult] = Field(min_length=1)


class Survey(Strict):
    """A moving-vehicle survey: a dataset folder of navigation logs and sonar revolutions.

    ``data`` is the folder, absolute or relative to the catalog root; unlike scan files it may lie
    outside the catalog (a shared recording is not copied into it).
    """

    kind: Literal["marina"] = Field(description="the dataset's layout (marina: the Girona marina logs)")
    data: str
    settings: SurveySettings = Field(default_factory=SurveySettings)
    published: PublishedComparison | None = None

    @field_validator("data")
    @classmethod
    def _data(cls, value: str) -> str:
        if not value.strip():
            raise ValueError("data folder is empty")
        return value


class TruthPose(Strict):
    station: str
    x_m: float
    y_m: float
    yaw_deg: float = 0.0


class SiteRecord(Strict):
    """A site of the catalog."""

    schema_version: Literal[1] = 1
    id: str
    name: str
    description: str = ""
    expedition: Expedition | None = None
    location: Location = Field(default_factory=Location)
    sonar: SonarSettings = Field(default_factory=SonarSettings)
    segmentation: Segmentation = Field(default_factory=Segmentation)
    scans: list[ScanRef] = Field(default_factory=list, description="stationary scans (or a survey)")
    survey: Survey | None = Field(default=None, description="a moving-vehicle survey (or scans)")
    references: list[ReferenceDimension] = Field(default_factory=list)
    pipeline: PipelineSpec = Field(default_factory=PipelineSpec)
    seed: int = Field(default=0, ge=0)
    truth: list[TruthPose] = Field(default_factory=list, description="true station poses (simulated sites)")
    simulation: str | None = Field(default=None, description="simulator spec this site was made from")

    @field_validator("id")
    @classmethod
    def _slug(cls, value: str) -> str:
        return check_slug(value)

    @field_validator("simulation")
    @classmethod
    def _sim_path(cls, value: str | None) -> str | None:
        return None if value is None else check_relative_path(value)

    @model_validator(mode="after")
    def _unique_stations(self) -> "SiteRecord":
        if bool(self.scans) == (self.survey is not None):
            raise ValueError("a site record needs either scans (stationary stations) or a survey (a moving "
                             "vehicle), not " + ("both" if self.scans else "neither"))
        seen: set[str] = set()
        for scan in self.scans:
            if scan.station in seen:
                raise ValueError(f"station {scan.station!r} appears twice")
            seen.add(scan.station)
        for scan in self.scans:
            if scan.below is not None and (scan.below not in seen or scan.below == scan.station):
                raise ValueError(f"scan {scan.station!r}: below {scan.below!r} is not another station")
        for ref in self.references:
            if ref.measure.frame is not None and ref.measure.frame not in seen:
                raise ValueError(f"reference {ref.name!r}: frame {ref.measure.frame!r} is not a station")
        return self

    def public(self) -> "SiteRecord":
        """The record as it may be published: without coordinates when ``location.redact`` asks for it
        (a site's exact position stays in the catalog and the archive, never in a published folder)."""
        if not self.location.redact or (self.location.latitude is None and self.location.longitude is None):
            return self
        return self.model_copy(update={"location": self.location.model_copy(update={"latitude": None,
                                                                                     "longitude": None})})

    def station_index(self) -> dict[str, int]:
        return {scan.station: k for k, scan in enumerate(self.scans)}
