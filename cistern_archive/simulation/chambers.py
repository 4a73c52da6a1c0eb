"""Random multi-chamber cisterns for the physical sonar simulator, with known truth.

A site is one to three chambers in a row, each joined to the next by a straight tunnel, under one
closed wall outline, scanned by an ROV that visits its stations in order (one chamber after another,
through each tunnel). Everything is drawn from one seeded generator, so a seed gives the same spec.

Geometry, in the site's own frame before a random rotation of the whole site:

* **Chambers**: ``x`` extent and ``y`` extent each 2.5–8 m. A chamber is a ``"polygon"`` (a box whose
  floor and ceiling walls are jittered polylines, with some corners cut off) or a ``"round"`` chamber
  (its floor and ceiling walls follow an ellipse that meets straight end walls). Its end walls
  (``x = x0`` and ``x = x1``) are straight, so that a tunnel can meet them square.
* **Tunnels**: 0.8–1.2 m wide and 1–2.5 m long, from the east end wall of one chamber to the west end
  wall of the next, at a height that both end walls hold with 0.25 m of wall either side.
* **The outline** walks every chamber's floor wall west to east, the last chamber's east wall, every
  ceiling wall east to west and the first chamber's west wall, stepping through each tunnel both ways.
  Chambers and tunnels occupy disjoint ``x`` intervals and each wall is ``x``-monotone, so the outline
  is a simple counter-clockwise polygon.

Stations (6–12): one in each tunnel (its middle third) or in one of its openings (0.5 m inside a
chamber, on the tunnel's axis), the others spread over the chambers by area (at least one each), some
0.45–0.8 m from a wall, the rest farther in, at least 0.8 m apart (less when many share a small
chamber). They are ordered as an ROV visits them: through each chamber from its westernmost station
always on to the nearest, the tunnel's station between two chambers; each heads towards the next with
20° of jitter. Echoes are Micron-like (the simulator's speckle, multipath ghosts, spikes, ring-down and
vehicle echo, on by default; walls of roughness 0.03–0.3; range 6, 8 or 10 m in 4 cm bins, 0.9°
steps); the compass has a bias of up to ±2° and 2° of noise. The records carry the true poses
(``truth``), as the demo specs' records do. :class:`GeneratorSettings` changes the tunnels' length and
width, how a tunnel is surveyed, the compass, the clutter and the sonar (its bin, its step and any other
setting of the simulator), the stations' depths and the order the record lists them in, stands
pillars in the chambers, and draws a whole site larger, heard as well (``scale``, :func:`scaled_spec`),
for studies of sites unlike these.

>>> cistern = random_cistern(np.random.default_rng(1), index=0)   # doctest: +SKIP
>>> site = simulate_site(cistern.spec)                            # doctest: +SKIP
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator

from cistern_archive.simulation.output import write_site
from cistern_archive.simulation.simulator import simulate_site
from cistern_archive.simulation.spec import EffectsSpec, SimulationSpec, SonarSpec, load_spec
from cistern_archive.sonar.geometry import contains, edges_of

ROOM_M = (2.5, 8.0)
TUNNEL_WIDTH_M = (0.8, 1.2)
TUNNEL_LENGTH_M = (1.0, 2.5)
STATIONS = (6, 12)
WALL_MARGIN_M = 0.25
NEAR_WALL_M = (0.45, 0.8)
MIN_SPACING_M = 0.8
OPENING_INSET_M = 0.5
PILLAR_CLEARANCE_M = 0.8
COMPASS_BIAS_DEG = 2.0
COMPASS_SIGMA_DEG = 2.0
YAW_JITTER_DEG = 20.0
MULTIPATH_FRACTION = (0.04, 0.10)
BIN_M = 0.04
STEP_DEG = 0.9


class GeneratorSettings(BaseModel):
    """What the generator draws from, where a study wants other sites than the defaults (module
    docstring): ``benchmarks/sites.py --random N --generator JSON``. The defaults give the same sites,
    draw for draw, as a generator without settings.

    ``tunnel_station_spacing_m`` changes how tunnels are surveyed: unset, each tunnel has one station,
    in it or in one of its openings; set, each has a station in both openings and inside one every
    ``tunnel_station_spacing_m`` or less.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    tunnel_length_m: tuple[float, float] = Field(TUNNEL_LENGTH_M, description="range of a tunnel's length")
    tunnel_width_m: tuple[float, float] = Field(TUNNEL_WIDTH_M, description="range of a tunnel's width")
    tunnel_station_spacing_m: float | None = Field(None, gt=0, description="stations along a tunnel (above)")
    compass_bias_deg: float = Field(COMPASS_BIAS_DEG, ge=0, description="a site's compass bias is drawn from ±this")
    compass_sigma_deg: float = Field(COMPASS_SIGMA_DEG, ge=0, description="compass noise per scan")
    multipath_fraction: tuple[float, float] = Field(MULTIPATH_FRACTION, description="range of the share of beams with a ghost")
    spike_rate: float | None = Field(None, ge=0, description="isolated spikes per beam (unset: the simulator's default)")
    bin_m: float = Field(BIN_M, gt=0, description="the sonar's range bin")
    step_deg: float = Field(STEP_DEG, gt=0, description="the sonar head's step between beams")
    sonar: dict[str, float] = Field(default_factory=dict,
                                    description="other settings of the sonar (SimulationSpec's sonar), e.g. beam_width_deg")
    effects: dict[str, float] = Field(default_factory=dict,
                                      description="other effects (SimulationSpec's effects), e.g. speckle_looks")
    segmentation: dict[str, float | bool | str] = Field(
        default_factory=dict, description="other settings of the records' segmentation, e.g. faint_walls")
    station_depth_jitter_m: float = Field(0.05, ge=0, description="each station's depth is the site's survey "
                                          "depth ± this (kept 0.3 m off the surface and the floor)")
    return_to_start: bool = Field(False, description="the vehicle comes back to the first chamber, where it "
                                  "was launched, and records one more station there (``r1``) last")
    pillars: tuple[int, int] = Field((0, 0), description="range of the number of free-standing pillars in "
                                     "each chamber (rock left to hold the roof)")
    pillar_size_m: tuple[float, float] = Field((0.4, 1.0), description="range of a pillar's width")
    station_order: Literal["visit", "label", "shuffled"] = Field(
        "visit", description="the order the record lists its stations in: as visited, sorted by label, or "
                             "shuffled; the scans' times keep the order of the visits")
    scale: float = Field(1.0, gt=0, description="every length of the site this many times as large, heard as "
                         "well at every place (scaled_spec): the same site at another size, surveyed at a "
                         "longer range with coarser bins")

    @model_validator(mode="after")
    def _ranges_ordered(self) -> "GeneratorSettings":
        for name in ("tunnel_length_m", "tunnel_width_m", "multipath_fraction", "pillars", "pillar_size_m"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f"{name} must be (low, high) with 0 <= low <= high, got ({lo}, {hi})")
        return self


@dataclass(frozen=True)
class Chamber:
    """One chamber in the site's own frame: its floor (south) and ceiling (north) walls, west to east.

    ``floor[0]`` and ``ceiling[0]`` are the ends of the west wall (``x = x0``), ``floor[-1]`` and
    ``ceiling[-1]`` those of the east wall (``x = x1``).
    """

    kind: str
    floor: np.ndarray
    ceiling: np.ndarray

    @property
    def x0(self) -> float:
        return float(self.floor[0, 0])

    @property
    def x1(self) -> float:
        return float(self.floor[-1, 0])

    def ring(self) -> np.ndarray:
        """The chamber alone as a closed counter-clockwise ring."""
        return np.vstack([self.floor, self.ceiling[::-1]])

    def extent_m(self) -> tuple[float, float]:
        """Bounding-box size (x, y) of the chamber."""
        ring = self.ring()
        return float(np.ptp(ring[:, 0])), float(np.ptp(ring[:, 1]))

    def span(self, end: int) -> tuple[float, float]:
        """Straight part of the west (``end=0``) or east (``end=-1``) wall: (y_low, y_high)."""
        return float(self.floor[end, 1]), float(self.ceiling[end, 1])

    def shifted(self, dx: float, dy: float) -> "Chamber":
        return Chamber(self.kind, self.floor + [dx, dy], self.ceiling + [dx, dy])


@dataclass(frozen=True)
class Tunnel:
    """A straight tunnel along x from ``x0`` to ``x1``, centred on ``y``, ``width_m`` wide."""

    x0: float
    x1: float
    y: float
    width_m: float


@dataclass(frozen=True)
class Layout:
    """Chambers and tunnels of a site in its own frame, and the rotation placing it in the map frame."""

    chambers: list[Chamber]
    tunnels: list[Tunnel]
    rotation_rad: float = 0.0
    outline: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @functools.cached_property
    def site_ring(self) -> np.ndarray:
        """The closed wall outline in the site's own frame (:func:`outline`; ``outline`` is the map frame's)."""
        return outline(self.chambers, self.tunnels)

    def to_map(self, points: np.ndarray) -> np.ndarray:
        """Points (N, 2) of the site's frame in the map frame (rotated about the origin)."""
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        return np.asarray(points, dtype=np.float64) @ np.array([[c, s], [-s, c]])


def _jittered_chain(rng: np.random.Generator, length: float, y: float, amplitude: float) -> np.ndarray:
    """Interior vertices of a floor or ceiling wall: 1–3 points between the end walls, jittered in y."""
    n = int(rng.integers(1, 4))
    xs = np.sort(rng.uniform(0.15 * length, 0.85 * length, n))
    return np.column_stack([xs, y + rng.uniform(-amplitude, amplitude, n)])


def polygon_chamber(rng: np.random.Generator, length: float, height: float) -> Chamber:
    """A box ``length`` x ``height`` with jittered floor and ceiling walls and some corners cut off."""
    amplitude = min(0.25, 0.06 * height)
    cut = [float(rng.uniform(0.3, min(0.8, 0.15 * height))) if rng.random() < 0.5 else 0.0 for _ in range(4)]
    floor = [[0.0, cut[0]]] + ([[cut[0], 0.0]] if cut[0] else [])
    floor += _jittered_chain(rng, length, 0.0, amplitude).tolist()
    floor += ([[length - cut[1], 0.0]] if cut[1] else []) + [[length, cut[1]]]
    ceiling = [[0.0, height - cut[2]]] + ([[cut[2], height]] if cut[2] else [])
    ceiling += _jittered_chain(rng, length, height, amplitude).tolist()
    ceiling += ([[length - cut[3], height]] if cut[3] else []) + [[length, height - cut[3]]]
    return Chamber("polygon", np.array(floor), np.array(ceiling))


def round_chamber(rng: np.random.Generator, length: float, height: float) -> Chamber:
    """A chamber whose floor and ceiling walls follow an ellipse meeting straight end walls of half height
    ``s`` (at least 0.9 m, so that a tunnel fits)."""
    half = height / 2.0
    s = min(half, max(0.9, float(rng.uniform(0.45, 0.7)) * half))
    u = np.linspace(-1.0, 1.0, 9)
    dy = half * np.sqrt(1.0 - (1.0 - (s / half) ** 2) * u**2)
    xs = (u + 1.0) * length / 2.0
    return Chamber("round", np.column_stack([xs, half - dy]), np.column_stack([xs, half + dy]))


def random_chamber(rng: np.random.Generator) -> Chamber:
    """A chamber of either kind whose bounding box is 2.5–8 m each way (redrawn until it is)."""
    while True:
        length, height = rng.uniform(3.0, 7.5, 2)
        make = polygon_chamber if rng.random() < 0.6 else round_chamber
        chamber = make(rng, float(length), float(height))
        if all(ROOM_M[0] <= e <= ROOM_M[1] for e in chamber.extent_m()):
            return chamber


def _tunnel_height(rng: np.random.Generator, span: tuple[float, float], width: float) -> float:
    lo, hi = span[0] + WALL_MARGIN_M + width / 2, span[1] - WALL_MARGIN_M - width / 2
    if hi < lo:
        raise ValueError(f"an end wall of {span[1] - span[0]:.2f} m cannot hold a {width:.2f} m tunnel")
    return float(rng.uniform(lo, hi))


def random_layout(rng: np.random.Generator, n_chambers: int, settings: GeneratorSettings | None = None) -> Layout:
    """``n_chambers`` chambers in a row joined by tunnels (module docstring), rotated at random."""
    settings = settings or GeneratorSettings()
    chambers = [random_chamber(rng)]
    tunnels = []
    for _ in range(n_chambers - 1):
        width = float(rng.uniform(*settings.tunnel_width_m))
        length = float(rng.uniform(*settings.tunnel_length_m))
        west = chambers[-1]
        y = _tunnel_height(rng, west.span(-1), width)
        east = random_chamber(rng)
        y_in_east = _tunnel_height(rng, east.span(0), width)
        east = east.shifted(west.x1 + length, y - y_in_east)
        tunnels.append(Tunnel(west.x1, east.x0, y, width))
        chambers.append(east)
    layout = Layout(chambers, tunnels, float(rng.uniform(0.0, 2.0 * math.pi)))
    return replace(layout, outline=layout.to_map(outline(chambers, tunnels)))


def outline(chambers: list[Chamber], tunnels: list[Tunnel]) -> np.ndarray:
    """The closed counter-clockwise wall outline of chambers joined by tunnels (site frame)."""
    points: list[np.ndarray] = []
    for k, chamber in enumerate(chambers):
        points += list(chamber.floor)
        if k < len(tunnels):
            t = tunnels[k]
            points += [np.array([t.x0, t.y - t.width_m / 2]), np.array([t.x1, t.y - t.width_m / 2])]
    for k in range(len(chambers) - 1, -1, -1):
        points += list(chambers[k].ceiling[::-1])
        if k > 0:
            t = tunnels[k - 1]
            points += [np.array([t.x1, t.y + t.width_m / 2]), np.array([t.x0, t.y + t.width_m / 2])]
    ring = np.array(points, dtype=np.float64)
    keep = np.hypot(*(ring - np.roll(ring, 1, axis=0)).T) > 1e-9
    return ring[keep]


def wall_distance(points: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """Distance from each point (N, 2) to the nearest edge of ``ring``."""
    a, b = edges_of([ring])
    e = b - a
    p = np.asarray(points, dtype=np.float64)[:, None, :]
    t = np.clip(((p - a) * e).sum(-1) / np.maximum((e * e).sum(-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * e), axis=-1).min(axis=1)


def pillar_ring(rng: np.random.Generator, centre: np.ndarray, size: float) -> np.ndarray:
    """A pillar ``size`` wide about ``centre`` (counter-clockwise): a square turned at random, or a round
    one (12 sides)."""
    if rng.random() < 0.5:
        angles = float(rng.uniform(0.0, math.pi / 2)) + np.arange(4) * (math.pi / 2)
        radius = size / math.sqrt(2.0)
    else:
        angles = np.arange(12) * (math.pi / 6)
        radius = size / 2.0
    return np.asarray(centre, dtype=np.float64) + radius * np.column_stack([np.cos(angles), np.sin(angles)])


def random_pillars(rng: np.random.Generator, layout: Layout, settings: GeneratorSettings) -> list[np.ndarray]:
    """Free-standing pillars (site frame), ``settings.pillars`` per chamber as far as they fit: each
    ``PILLAR_CLEARANCE_M`` or more from every wall and other pillar, and clear of the tunnels' mouths
    (as far from a chamber's end walls as from its other walls, plus the opening stations' inset)."""
    site_ring = layout.site_ring
    pillars: list[tuple[np.ndarray, float, np.ndarray]] = []
    for chamber in layout.chambers:
        ring = chamber.ring()
        wanted = int(rng.integers(settings.pillars[0], settings.pillars[1] + 1))
        here = 0
        for _ in range(400):
            if here == wanted:
                break
            size = float(rng.uniform(*settings.pillar_size_m))
            centre = rng.uniform(ring.min(axis=0), ring.max(axis=0))
            reach = size / math.sqrt(2.0) + PILLAR_CLEARANCE_M
            if (not contains([ring], centre[None])[0] or wall_distance(centre[None], site_ring)[0] < reach
                    or min(centre[0] - chamber.x0, chamber.x1 - centre[0]) < reach + OPENING_INSET_M
                    or any(np.hypot(*(centre - c)) < reach + r for c, r, _ in pillars)):
                continue
            pillars.append((centre, size / math.sqrt(2.0), pillar_ring(rng, centre, size)))
            here += 1
    return [ring for _, _, ring in pillars]


@dataclass(frozen=True)
class Station:
    """A planned station in the site's frame: label, position and where it is."""

    name: str
    xy: np.ndarray
    place: str  # "chamber", "near-wall", "tunnel" or "opening"


def _chamber_stations(rng: np.random.Generator, chamber: Chamber, site_ring: np.ndarray, n: int,
                      prefix: str, taken: list[np.ndarray], pillars: Sequence[np.ndarray] = (),
                      sharing: int = 0) -> list[Station]:
    """``n`` stations inside ``chamber``, outside its ``pillars``, some near a wall (or a pillar), apart by
    MIN_SPACING_M (less when many stations share a small chamber: half the side of the area each would
    have, ``sharing`` of them placed there already)."""
    ring = chamber.ring()
    spacing = min(MIN_SPACING_M, 0.5 * math.sqrt(abs(_area(ring)) / (n + sharing)))
    lo, hi = ring.min(axis=0), ring.max(axis=0)
    found: list[tuple[np.ndarray, str]] = []
    for _ in range(4000):
        if len(found) == n:
            break
        near = rng.random() < 0.4
        p = rng.uniform(lo, hi)
        clearance = min(float(wall_distance(p[None], wall)[0]) for wall in [site_ring, *pillars])
        wanted = NEAR_WALL_M[0] <= clearance <= NEAR_WALL_M[1] if near else clearance > NEAR_WALL_M[1]
        if not wanted or not contains([ring], p[None])[0] or any(contains([pillar], p[None])[0] for pillar in pillars):
            continue
        if any(np.hypot(*(p - q)) < spacing for q in taken + [f for f, _ in found]):
            continue
        found.append((p, "near-wall" if near else "chamber"))
    if len(found) < n:
        raise ValueError(f"could not place {n} stations in a {chamber.extent_m()} m chamber")
    order = visiting_order(np.array([p for p, _ in found]))
    return [Station(f"{prefix}{k + 1}", found[i][0], found[i][1]) for k, i in enumerate(order)]


def return_station(rng: np.random.Generator, layout: Layout, planned: list[Station],
                   pillars: Sequence[np.ndarray]) -> Station:
    """The station ``r1`` in the first chamber, apart from every planned station as far as the first
    chamber's own stations are from each other where it has no room at ``MIN_SPACING_M``."""
    taken = [s.xy for s in planned]
    first = layout.chambers[0]
    try:
        return _chamber_stations(rng, first, layout.site_ring, 1, "r", taken, pillars)[0]
    except ValueError:  # a small chamber full of stations
        inside = int(contains([first.ring()], np.array(taken)).sum())
        return _chamber_stations(rng, first, layout.site_ring, 1, "r", taken, pillars, sharing=inside)[0]


def visiting_order(points: np.ndarray) -> list[int]:
    """The order an ROV crossing a chamber west to east visits ``points`` (N, 2, site frame): from the
    westernmost, always on to the nearest not yet visited."""
    left = list(range(len(points)))
    order = [min(left, key=lambda k: points[k, 0])]
    left.remove(order[0])
    while left:
        nearest = min(left, key=lambda k: float(np.hypot(*(points[k] - points[order[-1]]))))
        order.append(nearest)
        left.remove(nearest)
    return order


def _connector(rng: np.random.Generator, tunnel: Tunnel, index: int) -> Station:
    """The station joining two chambers: in the tunnel's middle third, or in one of its openings."""
    choice = rng.random()
    if choice < 0.5:
        x = tunnel.x0 + (tunnel.x1 - tunnel.x0) * float(rng.uniform(1 / 3, 2 / 3))
        return Station(f"t{index + 1}", np.array([x, tunnel.y]), "tunnel")
    x = tunnel.x0 - OPENING_INSET_M if choice < 0.75 else tunnel.x1 + OPENING_INSET_M
    return Station(f"o{index + 1}", np.array([x, tunnel.y]), "opening")


def _tunnel_survey(tunnel: Tunnel, index: int, spacing_m: float) -> list[Station]:
    """The stations of a tunnel surveyed along its length: one in each opening and, inside, one every
    ``spacing_m`` or less, evenly spread (``t<k>a``, ``t<k>b`` …, between ``o<k>`` and ``p<k>``)."""
    inside = max(1, math.ceil((tunnel.x1 - tunnel.x0) / spacing_m) - 1)
    xs = [tunnel.x0 + (tunnel.x1 - tunnel.x0) * (q + 1) / (inside + 1) for q in range(inside)]
    stations = [Station(f"o{index + 1}", np.array([tunnel.x0 - OPENING_INSET_M, tunnel.y]), "opening")]
    stations += [Station(f"t{index + 1}{chr(ord('a') + q)}", np.array([x, tunnel.y]), "tunnel") for q, x in enumerate(xs)]
    return stations + [Station(f"p{index + 1}", np.array([tunnel.x1 + OPENING_INSET_M, tunnel.y]), "opening")]


def station_counts(rng: np.random.Generator, chambers: list[Chamber], n_stations: int) -> list[int]:
    """Stations per chamber: one each, the rest drawn in proportion to the chambers' areas."""
    spare = n_stations - (len(chambers) - 1) - len(chambers)
    if spare < 0:
        raise ValueError(f"{n_stations} stations cannot cover {len(chambers)} chambers and their tunnels")
    areas = np.array([abs(_area(c.ring())) for c in chambers])
    return (1 + rng.multinomial(spare, areas / areas.sum())).tolist()


def _area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def plan_stations(rng: np.random.Generator, layout: Layout, n_stations: int,
                  settings: GeneratorSettings | None = None, pillars: Sequence[np.ndarray] = ()) -> list[Station]:
    """Stations in visiting order (module docstring), in the site's frame, clear of the ``pillars``;
    ``n_stations`` counts one station per tunnel, however many ``settings.tunnel_station_spacing_m`` puts
    there."""
    spacing = (settings or GeneratorSettings()).tunnel_station_spacing_m
    site_ring = layout.site_ring
    counts = station_counts(rng, layout.chambers, n_stations)
    connectors = [[_connector(rng, tunnel, k)] if spacing is None else _tunnel_survey(tunnel, k, spacing)
                  for k, tunnel in enumerate(layout.tunnels)]
    stations: list[Station] = []
    for k, (chamber, n) in enumerate(zip(layout.chambers, counts)):
        if k > 0:
            stations += connectors[k - 1]
        taken = [s.xy for s in stations] + [s.xy for tunnel in connectors[k:] for s in tunnel]
        stations += _chamber_stations(rng, chamber, site_ring, n, "abc"[k], taken, pillars)
    return stations


def headings(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Map-frame yaw (rad) of each station: towards the next one, with YAW_JITTER_DEG of jitter."""
    step = np.diff(points, axis=0)
    towards = np.arctan2(step[:, 1], step[:, 0])
    towards = np.append(towards, towards[-1])
    return towards + math.radians(YAW_JITTER_DEG) * rng.standard_normal(len(points))


def _round(value: float, digits: int = 3) -> float:
    return float(round(float(value), digits))


@dataclass(frozen=True)
class GeneratedCistern:
    """A random cistern: its validated simulator spec, its layout and its stations (spec order)."""

    spec: SimulationSpec
    layout: Layout
    stations: list[Station]

    @property
    def chambers(self) -> int:
        return len(self.layout.chambers)


def station_depth(depth: float, water_depth: float, jitter_m: float, rng: np.random.Generator) -> float:
    """A station's depth: the survey depth ± ``jitter_m``, 0.3 m or more below the surface and above the floor."""
    return float(np.clip(depth + rng.uniform(-jitter_m, jitter_m), 0.3, water_depth - 0.3))


def listing_order(planned: list[Station], order: str, rng: np.random.Generator) -> list[int]:
    """Indices of the visited stations in the order the record lists them (``GeneratorSettings.station_order``).
    A shuffle draws from a generator spawned off ``rng``, so every other draw, of this site and the next,
    is as in the visiting order."""
    if order == "label":
        return sorted(range(len(planned)), key=lambda k: planned[k].name)
    if order == "shuffled":
        return [int(k) for k in rng.spawn(1)[0].permutation(len(planned))]
    return list(range(len(planned)))


def random_cistern(rng: np.random.Generator, index: int = 0, *, chambers: int | None = None,
                   stations: int | None = None, settings: GeneratorSettings | None = None) -> GeneratedCistern:
    """A random multi-chamber cistern (module docstring).

    Parameters
    ----------
    rng : numpy.random.Generator
        The only source of randomness: equal generator states give equal specs.
    index : int
        Names the site (``cistern-<index>``).
    chambers, stations : int, optional
        Fix the number of chambers (1–3) or stations (6–12) instead of drawing them.
    settings : GeneratorSettings, optional
        What the draws range over (the defaults otherwise).
    """
    settings = settings or GeneratorSettings()
    n_chambers = int(chambers if chambers is not None else rng.integers(1, 4))
    n_stations = int(stations if stations is not None else rng.integers(STATIONS[0], STATIONS[1] + 1))
    if not 1 <= n_chambers <= 3 or not STATIONS[0] <= n_stations <= STATIONS[1]:
        raise ValueError(f"chambers must be 1-3 and stations {STATIONS[0]}-{STATIONS[1]}, "
                         f"got {n_chambers} and {n_stations}")
    layout = random_layout(rng, n_chambers, settings)
    # pillars draw from a generator of their own, so that without them every draw is as before
    pillars = random_pillars(rng.spawn(1)[0], layout, settings) if settings.pillars[1] > 0 else []
    planned = plan_stations(rng, layout, n_stations, settings, pillars)
    xy = layout.to_map(np.array([s.xy for s in planned]))
    yaws = headings(xy, rng)
    returned = rng.spawn(1)[0] if settings.return_to_start else None  # its draws: a generator of its own
    back = None
    if returned is not None:
        back = return_station(returned, layout, planned, pillars)
        planned.append(back)
        xy = np.vstack([xy, layout.to_map(back.xy[None])])
        yaws = np.append(yaws, headings(xy[-2:], returned)[-1])
    frame = planned[0].name  # the reference probe's frame: the first station visited, however listed
    listed = listing_order(planned, settings.station_order, rng)
    planned, xy, yaws = [planned[k] for k in listed], xy[listed], yaws[listed]
    visits = listed if settings.station_order != "visit" else [None] * len(listed)
    depth = float(rng.uniform(1.0, 1.6))
    range_m = float(rng.choice([6.0, 8.0, 10.0]))
    first = layout.chambers[0]
    centre = layout.to_map(np.array([[0.5 * (first.x0 + first.x1), 0.5 * (first.span(0)[0] + first.span(0)[1])]]))
    site_seed = int(rng.integers(0, 2**31))
    water_depth = _round(depth + rng.uniform(0.8, 1.5), 2)
    spec = {
        "id": f"cistern-{index:03d}",
        "name": f"Random {n_chambers}-chamber cistern {index:03d}",
        "description": (f"{n_chambers} chamber(s) "
                        f"({', '.join('%.1f x %.1f m' % c.extent_m() for c in layout.chambers)}) joined by "
                        f"tunnels {', '.join('%.2f' % t.width_m for t in layout.tunnels) or '(none)'} m wide; "
                        f"{n_stations} stations ({', '.join(s.place for s in planned)})"
                        + (f"; {len(pillars)} pillar(s)." if pillars else ".")),
        "location": {"place": "simulated", "redact": True},
        "seed": site_seed,
        "site": {"water_depth_m": water_depth,
                 "levels": [{"depth_m": 0.0, "walls": {"polygon": [[_round(x), _round(y)] for x, y in layout.outline]},
                             **({"islands": [{"polygon": [[_round(x), _round(y)] for x, y in layout.to_map(pillar)]}
                                             for pillar in pillars]} if pillars else {}),
                             "wall_roughness": _round(rng.uniform(0.03, 0.3))}]},
        "sonar": {"range_m": range_m, "bins": int(round(range_m / settings.bin_m)), "step_deg": settings.step_deg,
                  **settings.sonar},
        "effects": {"compass_bias_deg": _round(rng.uniform(-settings.compass_bias_deg, settings.compass_bias_deg), 2),
                    "compass_sigma_deg": settings.compass_sigma_deg,
                    "multipath_fraction": _round(rng.uniform(*settings.multipath_fraction)),
                    **({} if settings.spike_rate is None else {"spike_rate": settings.spike_rate}),
                    **settings.effects},
        "segmentation": {"min_range_m": 0.4, **settings.segmentation},
        "stations": [
            {"name": s.name, "x_m": _round(p[0]), "y_m": _round(p[1]), "yaw_deg": _round(math.degrees(yaw), 2),
             "depth_m": _round(station_depth(depth, water_depth, settings.station_depth_jitter_m,
                                             returned if s is back else rng)),
             **({} if visit is None else {"visit": visit})}
            for s, p, yaw, visit in zip(planned, xy, yaws, visits)
        ],
        "references": [{
            "name": "width", "kind": "truth",
            "measure": {"frame": frame, "inside": [_round(centre[0, 0]), _round(centre[0, 1])],
                        "direction_deg": _round(math.degrees(layout.rotation_rad) + 90.0, 2),
                        "repeats": 5, "spacing_m": 0.2},
        }],
    }
    if settings.scale != 1.0:
        spec = scaled_spec(spec, settings.scale)
    return GeneratedCistern(SimulationSpec.model_validate(spec), layout, planned)


def scaled_spec(spec: dict, scale: float) -> dict:
    """A random cistern's spec ``scale`` times as large in every length, heard as well at every place.

    Its walls, pillars and depths, its stations and reference probe, the sonar's range (with as many
    bins, so each is ``scale`` times as long), pulse and TVG knee, and the extra path of its ghosts are
    multiplied by ``scale``; absorption is divided by it, so an echo loses as much on its way as it did.
    Spreading still grows with ``log10(scale)``: the receiver's noise is lowered by the spreading's
    ``n_s log10(scale)`` and every level set after the TVG (background, floor, the vehicle's own echoes,
    the A/D window's low end) moves with the echoes by ``(n_t - n_s) log10(scale)``, so each bin's counts
    at a place ``scale`` times as far are drawn as at the original place. The vehicle's own echoes keep
    their ranges, the beam its angles, the compass its noise. Whatever a site so drawn is placed worse
    than the original is owed to lengths fixed in metres somewhere in the pipeline.
    """
    sonar_spec, effects_spec = SonarSpec(**spec["sonar"]), EffectsSpec(**spec["effects"])
    decades = math.log10(scale)
    shift = (sonar_spec.tvg_exponent - sonar_spec.spreading_exponent) * decades

    def ring(shape: dict) -> dict:
        return {"polygon": [[_round(scale * x), _round(scale * y)] for x, y in shape["polygon"]]}

    def level(given: dict) -> dict:
        islands = {"islands": [ring(i) for i in given["islands"]]} if "islands" in given else {}
        return {**given, "walls": ring(given["walls"]), **islands}

    site = {**spec["site"], "levels": [level(given) for given in spec["site"]["levels"]],
            "water_depth_m": _round(scale * spec["site"]["water_depth_m"], 2)}
    sonar = {**spec["sonar"], "range_m": _round(scale * sonar_spec.range_m),
             "pulse_length_m": _round(scale * sonar_spec.pulse_length_m, 4),
             "tvg_min_range_m": _round(scale * sonar_spec.tvg_min_range_m, 4),
             "absorption_db_per_m": sonar_spec.absorption_db_per_m / scale,
             "tvg_absorption_db_per_m": sonar_spec.tvg_absorption_db_per_m / scale,
             "ad_low_db": sonar_spec.ad_low_db + shift}
    effects = {**spec["effects"],
               "multipath_extra_m": tuple(_round(scale * v) for v in effects_spec.multipath_extra_m),
               "noise_db": effects_spec.noise_db - sonar_spec.spreading_exponent * decades,
               **{name: getattr(effects_spec, name) + shift
                  for name in ("background_db", "floor_db", "self_echo_db", "near_field_db", "vehicle_echo_db")}}
    stations = [{**s, "x_m": _round(scale * s["x_m"]), "y_m": _round(scale * s["y_m"]),
                 "depth_m": _round(scale * s["depth_m"])} for s in spec["stations"]]
    references = [{**r, "measure": {**r["measure"], "inside": [_round(scale * v) for v in r["measure"]["inside"]],
                                    "spacing_m": _round(scale * r["measure"]["spacing_m"])}}
                  for r in spec["references"]]
    return {**spec, "site": site, "sonar": sonar, "effects": effects, "stations": stations, "references": references}


def random_cisterns(n: int, seed: int, settings: GeneratorSettings | None = None) -> list[GeneratedCistern]:
    """``n`` random cisterns from one seed (``cistern-000`` …), drawn with ``settings``."""
    rng = np.random.default_rng(seed)
    return [random_cistern(rng, k, settings=settings) for k in range(n)]


def write_specs(cisterns: list[GeneratedCistern], root: Path) -> list[Path]:
    """Write each cistern's spec to ``root/specs/<id>.yaml`` (a catalog root for
    :func:`simulate_into`); return the spec paths."""
    paths = []
    for cistern in cisterns:
        path = Path(root) / "specs" / f"{cistern.spec.id}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        body = yaml.safe_dump(cistern.spec.model_dump(mode="json", exclude_none=True), sort_keys=False, width=100)
        path.write_text(f"# A random {cistern.chambers}-chamber cistern of cistern_archive.simulation.chambers.\n"
                        + body, encoding="utf-8")
        paths.append(path)
    return paths


def simulate_into(spec_path: Path, root: Path) -> Path:
    """Simulate the spec at ``spec_path`` into the catalog ``root`` (scans, truth, ``sites/<id>.yaml``),
    as ``cistern-archive simulate SPEC --out ROOT --record-dir sites`` does; return the record's path."""
    return write_site(simulate_site(load_spec(spec_path)), Path(root), spec_path=spec_path, record_dir="sites")
