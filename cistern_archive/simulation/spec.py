"""The YAML simulator spec: a site's walls, the sonar, its imperfections, the stations and references.

A spec is validated by :class:`SimulationSpec` (unknown fields are refused). Coordinates are metres in the
site's map frame (x east, y north); yaws are map-frame degrees counter-clockwise from east; depths are
metres, positive down. See ``catalog/specs/*.yaml`` for annotated examples.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from cistern_archive.catalog.loader import parse_yaml, validation_problems
from cistern_archive.catalog.models import Location, Segmentation
from cistern_archive.core.errors import CatalogError
from cistern_archive.simulation.gallery import Recess, gallery_ring


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RecessSpec(_Strict):
    """A niche or blind side branch cut into one wall of a corridor (:mod:`cistern_archive.simulation.gallery`)."""

    reach: int = Field(ge=0, description="index of the corridor reach (segment of the centre line)")
    side: Literal["left", "right"] = Field(description="wall, seen travelling along the centre line")
    at_m: float = Field(ge=0, description="start, measured along the reach from its first point")
    length_m: float = Field(gt=0, description="extent along the reach")
    depth_m: float = Field(gt=0, description="how far it goes into the wall")


class RingSpec(_Strict):
    """One closed wall outline: exactly one of ``polygon``, ``rectangle``, ``ellipse`` or ``corridor``.

    ``corridor`` is a tunnel of constant ``width_m`` around a centre line (mitred at the bends); with
    ``widths`` (one per reach) its section steps between reaches, and ``recesses`` cut niches and blind
    side branches into its walls (:func:`cistern_archive.simulation.gallery.gallery_ring`).
    """

    polygon: list[tuple[float, float]] | None = Field(default=None, min_length=3)
    rectangle: tuple[float, float, float, float] | None = Field(
        default=None, description="x_min, y_min, x_max, y_max"
    )
    ellipse: tuple[float, float, float, float] | None = Field(
        default=None, description="centre x, centre y, semi-axis x, semi-axis y"
    )
    corridor: list[tuple[float, float]] | None = Field(default=None, min_length=2, description="centre line")
    width_m: float = Field(default=1.5, gt=0, description="width of a corridor")
    widths: list[float] | None = Field(default=None, description="width of each corridor reach (overrides width_m)")
    recesses: list[RecessSpec] = Field(default_factory=list, description="niches and side branches of a corridor")
    segments: int = Field(default=72, ge=8, le=2048, description="vertices of an ellipse")
    rotation_deg: float = 0.0

    @model_validator(mode="after")
    def _one_shape(self) -> "RingSpec":
        given = [name for name in ("polygon", "rectangle", "ellipse", "corridor") if getattr(self, name) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of polygon, rectangle, ellipse, corridor (got {given or 'none'})")
        if self.rectangle is not None:
            x0, y0, x1, y1 = self.rectangle
            if not (x1 > x0 and y1 > y0):
                raise ValueError("rectangle needs x_max > x_min and y_max > y_min")
        if self.ellipse is not None and min(self.ellipse[2:]) <= 0:
            raise ValueError("ellipse semi-axes must be positive")
        if (self.widths is not None or self.recesses) and self.corridor is None:
            raise ValueError("widths and recesses belong to a corridor")
        if self.widths is not None and (len(self.widths) != len(self.corridor) - 1 or min(self.widths) <= 0):
            raise ValueError(f"widths needs one positive width per reach ({len(self.corridor) - 1})")
        if self.corridor is not None and (self.widths is not None or self.recesses):
            self.vertices()  # a recess that does not fit its reach is refused here
        return self

    def vertices(self) -> np.ndarray:
        """The ring's vertices, shape (K, 2), counter-clockwise, rotated about the shape's centre."""
        if self.polygon is not None:
            ring = np.asarray(self.polygon, dtype=np.float64)
        elif self.corridor is not None and (self.widths is not None or self.recesses):
            reaches = len(self.corridor) - 1
            ring = gallery_ring(
                np.asarray(self.corridor, dtype=np.float64),
                self.widths if self.widths is not None else [self.width_m] * reaches,
                [Recess(r.reach, 1 if r.side == "left" else -1, r.at_m, r.length_m, r.depth_m)
                 for r in self.recesses],
            )
        elif self.corridor is not None:
            ring = corridor_ring(np.asarray(self.corridor, dtype=np.float64), self.width_m)
        elif self.rectangle is not None:
            x0, y0, x1, y1 = self.rectangle
            ring = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)
        else:
            cx, cy, ax, ay = self.ellipse  # type: ignore[misc]
            t = np.linspace(0.0, 2 * np.pi, self.segments, endpoint=False)
            ring = np.column_stack([cx + ax * np.cos(t), cy + ay * np.sin(t)])
        if self.rotation_deg:
            centre = ring.mean(axis=0)
            c, s = np.cos(np.radians(self.rotation_deg)), np.sin(np.radians(self.rotation_deg))
            ring = (ring - centre) @ np.array([[c, s], [-s, c]]) + centre
        return ring


def corridor_ring(centre: np.ndarray, width_m: float) -> np.ndarray:
    """The outline of a tunnel of ``width_m`` around a polyline, mitred at interior vertices.

    Returns
    -------
    ndarray, shape (2K, 2)
        Left side forwards, then right side backwards.
    """
    seg = np.diff(centre, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    if np.any(lengths <= 0):
        raise ValueError("corridor centre line has repeated points")
    tangents = seg / lengths[:, None]
    normals = np.column_stack([-tangents[:, 1], tangents[:, 0]])
    vertex_normals = np.vstack([normals[:1], normals[:-1] + normals[1:], normals[-1:]])
    vertex_normals /= np.hypot(vertex_normals[:, 0], vertex_normals[:, 1])[:, None]
    seg_normals = np.vstack([normals[:1], normals])
    scale = 1.0 / np.clip(np.sum(vertex_normals * seg_normals, axis=1), 0.3, None)
    offset = vertex_normals * (width_m / 2.0 * scale)[:, None]
    return np.vstack([centre + offset, (centre - offset)[::-1]])


class LevelSpec(_Strict):
    """The walls at one depth: the outer wall and optional islands (pillars).

    ``wall_roughness`` is the walls' diffuse backscatter at this depth (the isotropic term of the
    simulator's ``cos^2 + roughness`` model, :mod:`cistern_archive.simulation.simulator`); when given it
    replaces ``effects.wall_roughness`` and is interpolated linearly in depth between the levels that
    give it. Plastered or smooth ashlar walls: about 0.03 (grazing echoes ~15 dB below normal
    incidence); rough rock-cut walls with tool marks and joints: 0.2-0.5.
    """

    depth_m: float = Field(ge=0)
    walls: RingSpec
    islands: list[RingSpec] = Field(default_factory=list)
    wall_roughness: float | None = Field(default=None, ge=0, description="diffuse backscatter of the walls")

    def rings(self) -> list[np.ndarray]:
        return [self.walls.vertices()] + [island.vertices() for island in self.islands]


class SiteSpec(_Strict):
    """A 2-D site (one level) or a 3-D site (several levels; walls interpolate between levels)."""

    levels: list[LevelSpec] = Field(min_length=1)
    water_depth_m: float | None = Field(default=None, gt=0, description="floor depth, for the record")

    @model_validator(mode="after")
    def _distinct_depths(self) -> "SiteSpec":
        depths = [level.depth_m for level in self.levels]
        if len(set(depths)) != len(depths):
            raise ValueError(f"level depths must be distinct, got {depths}")
        return self

    def slices(self) -> list[tuple[float, list[np.ndarray]]]:
        return [(level.depth_m, level.rings()) for level in self.levels]

    def wall_roughness(self, depth_m: float, default: float) -> float:
        """The walls' diffuse backscatter at ``depth_m`` (``default`` if no level gives one)."""
        given = sorted((level.depth_m, level.wall_roughness) for level in self.levels
                       if level.wall_roughness is not None)
        if not given:
            return default
        return float(np.interp(depth_m, [d for d, _ in given], [r for _, r in given]))


class SonarSpec(_Strict):
    """A mechanically scanned imaging sonar (defaults: Tritech Micron DST class)."""

    model: str = "Tritech Micron DST"
    frequency_khz: float = Field(default=700.0, gt=0)
    range_m: float = Field(default=10.0, gt=0)
    bins: int = Field(default=250, ge=8, le=1500)
    step_deg: float = Field(default=0.9, gt=0, le=10)
    beam_width_deg: float = Field(default=3.0, gt=0, lt=45, description="one-way -3 dB, horizontal")
    vertical_beam_width_deg: float = Field(default=35.0, gt=0, lt=90, description="one-way -3 dB, vertical")
    pulse_length_m: float = Field(default=0.04, gt=0, description="c * tau / 2")
    sub_rays: int = Field(default=9, ge=1, le=63, description="rays across the horizontal beam pattern")
    vertical_rays: int = Field(default=13, ge=1, le=31, description="rays across the vertical beam pattern")
    ad_low_db: float = Field(default=-32.0, description="level mapped to intensity 0 (after TVG)")
    ad_span_db: float = Field(default=40.0, gt=0, description="level span mapped to 0..255")
    spreading_exponent: float = Field(default=40.0, ge=0, description="two-way spreading, n log10 r")
    absorption_db_per_m: float = Field(default=0.25, ge=0, description="one-way, at the sonar's frequency")
    tvg_exponent: float = Field(default=35.0, ge=0, description="time-varying gain n log10 r")
    tvg_absorption_db_per_m: float = Field(default=0.2, ge=0)
    tvg_min_range_m: float = Field(default=0.3, gt=0, description="TVG is held constant below this")


class EffectsSpec(_Strict):
    """The imperfections of real scans (set a value to 0 to switch its effect off)."""

    wall_roughness: float = Field(default=0.03, ge=0, description="diffuse floor of the cos^2 backscatter")
    speckle_looks: float = Field(default=3.0, ge=0, description="gamma speckle shape; 0 = no speckle")
    noise_db: float = Field(default=-63.0, description="receiver noise before TVG, at 1 m equivalent")
    background_db: float = Field(default=-33.0, description="water-column backscatter after TVG")
    floor_db: float = Field(default=-24.0, description="floor/surface reverberation through the vertical lobe")
    multipath_fraction: float = Field(default=0.06, ge=0, le=1)
    multipath_extra_m: tuple[float, float] = (0.3, 2.0)
    multipath_level_db: tuple[float, float] = (-9.0, 2.0)
    self_echo_db: float = Field(default=-3.0, description="ring-down level at zero range (after TVG)")
    self_echo_range_m: float = Field(default=0.05, ge=0, description="e-folding length of the ring-down")
    near_field_db: float = Field(default=-14.0, description="near-field reverberation at zero range")
    near_field_range_m: float = Field(default=0.35, ge=0, description="its e-folding length")
    vehicle_sector_deg: tuple[float, float] = Field(default=(180.0, 40.0), description="centre, width")
    vehicle_echo_range_m: tuple[float, float] = (0.22, 0.34)
    vehicle_echo_db: float = Field(default=-6.0)
    spike_rate: float = Field(default=0.004, ge=0, description="isolated spikes per beam")
    compass_bias_deg: float = 0.0
    compass_sigma_deg: float = Field(default=1.0, ge=0)
    depth_sigma_m: float = Field(default=0.02, ge=0)

    @classmethod
    def ideal(cls) -> "EffectsSpec":
        """No imperfections: a noise-free simulation of the same geometry."""
        return cls(
            wall_roughness=0.03, speckle_looks=0, noise_db=-200, background_db=-200, floor_db=-200,
            multipath_fraction=0, self_echo_db=-200, near_field_db=-200, vehicle_echo_db=-200, spike_rate=0, compass_bias_deg=0,
            compass_sigma_deg=0, depth_sigma_m=0,
        )


class StationSpec(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    x_m: float
    y_m: float
    yaw_deg: float = 0.0
    depth_m: float = Field(default=1.0, ge=0)
    below: str | None = Field(
        default=None,
        description="the team's note that the vehicle descended vertically from this earlier station "
        "(written to the record's scan as ``below``); give x_m, y_m with the descent's true drift",
    )
    visit: int | None = Field(
        default=None, ge=0,
        description="the station's place in the order the survey visited the stations, where the list "
        "gives them in another order: its scan is recorded ``visit`` × ``seconds_per_station`` after the "
        "start (default: its place in the list)",
    )


class RouteSpec(_Strict):
    """Stations placed along a polyline, each as far from the previous as the ``overlap`` allows (and at
    most ``max_spacing_m`` further along the route, if given).

    ``overlap`` is the shared fraction of the areas seen from two consecutive stations, |Va ∩ Vb| /
    min(|Va|, |Vb|), within the sonar's range. At every depth of ``depths`` the route is walked once.
    """

    waypoints: list[tuple[float, float]] = Field(min_length=2)
    depths: list[float] = Field(default_factory=lambda: [1.0], min_length=1)
    overlap: float = Field(default=0.6, gt=0, lt=1)
    step_m: float = Field(default=0.25, gt=0, description="search resolution along the route")
    max_spacing_m: float | None = Field(default=None, gt=0, description="longest hop along the route")
    yaw: Literal["along", "fixed"] = "along"
    yaw_deg: float = 0.0
    yaw_jitter_deg: float = Field(default=15.0, ge=0)
    prefix: str = Field(default="s", pattern=r"^[A-Za-z0-9_.-]*$")


class MeasureSpec(_Strict):
    """A probe in site coordinates; converted to the frame of station ``frame`` for the record."""

    frame: str | None = None
    inside: tuple[float, float]
    direction_deg: float = 0.0
    repeats: int = Field(default=10, ge=1, le=100)
    spacing_m: float = Field(default=0.2, ge=0)
    depth_m: float | None = None


class ReferenceSpec(_Strict):
    """A reference dimension. ``truth``: measured on the true walls when ``value_m`` is absent.
    ``mosaic``: ``value_m`` if given, else the truth perturbed by a seeded error of ``error_sigma_m``."""

    name: str
    kind: Literal["truth", "mosaic"]
    value_m: float | None = Field(default=None, gt=0)
    error_sigma_m: float = Field(default=0.05, ge=0)
    measure: MeasureSpec


class SimulationSpec(_Strict):
    """A simulated site."""

    schema_version: Literal[1] = 1
    id: str = Field(pattern=r"^[a-z0-9]+(?:-[a-z0-9]+)*$")
    name: str
    description: str = ""
    location: Location = Field(default_factory=lambda: Location(place="simulated"))
    seed: int = Field(default=0, ge=0)
    start_time: dt.datetime = dt.datetime(2012, 5, 1, 10, 0, tzinfo=dt.timezone.utc)
    seconds_per_station: float = Field(default=120.0, gt=0)
    site: SiteSpec
    sonar: SonarSpec = Field(default_factory=SonarSpec)
    effects: EffectsSpec = Field(default_factory=EffectsSpec)
    segmentation: Segmentation = Field(default_factory=Segmentation)
    stations: list[StationSpec] = Field(default_factory=list)
    routes: list[RouteSpec] = Field(default_factory=list)
    references: list[ReferenceSpec] = Field(default_factory=list)

    @model_validator(mode="after")
    def _has_stations(self) -> "SimulationSpec":
        if not self.stations and not self.routes:
            raise ValueError("give stations, routes, or both")
        names = [s.name for s in self.stations]
        if len(set(names)) != len(names):
            raise ValueError("station names must be unique")
        for k, station in enumerate(self.stations):
            if station.below is not None and station.below not in names[:k]:
                raise ValueError(f"station {station.name!r}: below {station.below!r} is not an earlier station")
        return self


def load_spec(path: str | Path) -> SimulationSpec:
    """Read and validate a simulator spec.

    Raises
    ------
    CatalogError
        ``file:line: field: message`` for malformed YAML or invalid fields.
    """
    path = Path(path)
    if not path.is_file():
        raise CatalogError([f"{path}: no such spec file"])
    data, lines = parse_yaml(path)
    if not isinstance(data, dict):
        raise CatalogError([f"{path}:1: (spec): expected a mapping of fields"])
    try:
        return SimulationSpec.model_validate(data)
    except ValidationError as exc:
        raise CatalogError(validation_problems(path, exc, lines)) from None
