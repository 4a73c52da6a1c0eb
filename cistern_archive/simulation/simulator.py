"""A physically plausible mechanically scanned imaging sonar in simulated sites with known truth.

The model of one stationary 360° scan (all levels in dB re an arbitrary source level):

* **Beam**: the head steps ``step_deg`` clockwise (seen from above), so bearings in the sonar frame
  (counter-clockwise, see :mod:`cistern_archive.core.scan`) decrease. Each beam is ``sub_rays`` x
  ``vertical_rays`` rays across Gaussian two-way patterns (the square of one-way patterns whose -3 dB
  widths are ``beam_width_deg`` horizontally and ``vertical_beam_width_deg`` vertically). A ray at elevation ``e``
  meets the wall at the horizontal distance ``h`` where the walls of the depth ``d + h tan e`` are
  (walls change with depth in 3-D sites: found by fixed-point iteration over interpolated slices,
  :mod:`cistern_archive.sonar.geometry`), at slant range ``h / cos e``; rays reaching the floor or the
  surface first give no wall echo. Elevations are stratified: each beam draws its own elevation within
  each of the ``vertical_rays`` cells, so sloping walls smear smoothly instead of in rings. Vertical walls therefore give a sharp leading edge with a short tail,
  and sloping (bell-shaped) walls a longer smear.
* **Echo** of a ray hitting a wall at range ``r`` with incidence cosine ``c``:
  ``BS(c) - n_s log10 r - 2 a r`` with backscatter ``BS = 10 log10(c^2 + roughness)`` (Lambert-like), two-way
  spreading ``n_s`` (40) and absorption ``a`` dB/m one way. The two terms of ``BS`` are two scales of
  a wall's relief: ``c^2`` is Lambert's law, the diffuse echo of relief of the order of the wavelength
  (2 mm at 700 kHz), which falls to nothing at grazing incidence; ``roughness`` stands for relief much
  larger than the wavelength (tool marks, joints, spalls, encrustation), whose facets and edges face the
  head at any incidence, so it does not fall with incidence. A plastered or smooth ashlar wall
  (``roughness`` ≈ 0.03) returns grazing echoes ~15 dB below normal incidence, so a long gallery's side
  walls fade a few metres from the head; a rough rock-cut wall (0.2–0.5) returns them 4–8 dB below.
  ``effects.wall_roughness`` sets it for a site, a level's ``wall_roughness`` per depth
  (:class:`~cistern_archive.simulation.spec.LevelSpec`). The compressed (matched-filter) pulse puts the
  echo in range as a Gaussian of standard deviation ``pulse_length_m / 2`` centred on ``r``; its energy is
  integrated over each bin (**bin quantisation**).
* **Time-varying gain**: ``+ n_t log10 max(r, r_min) + 2 a_t r``; ``n_t`` and ``a_t`` need not equal
  ``n_s`` and ``a`` (by default far walls come back a few dB weaker, as on real heads).
* **Receiver noise** is added before the TVG, so it grows with range after it; **water-column
  backscatter** is a constant level after the TVG (volume reverberation, roughly compensated by it);
  **near-field reverberation** decays exponentially from the head; **floor and surface
  reverberation** enters through the vertical lobe beyond the slant range where the lobe's edge meets the
  floor or the surface.
* **Speckle**: every bin's echo and reverberation power is multiplied by a unit-mean gamma variate with
  ``speckle_looks`` degrees of freedom; noise is exponential.
* **Multipath ghosts**: on a fraction of beams a copy of the direct echo arrives ``multipath_extra_m``
  later with a level offset drawn from ``multipath_level_db`` (it may be stronger than the direct echo).
* **The vehicle's own echo**: transducer ring-down at zero range on every beam, and the vehicle's body in
  a sector of bearings (behind the head by default) a few decimetres away.
* **AD conversion** as on a Tritech head: ``255 (L - ADLow) / ADSpan`` clipped to 0..255 and truncated
  to 8 bits, so the water between walls is mostly exact zeros.
* **Random spikes**: isolated one-bin interference spikes.
* **Navigation**: the compass reads the true yaw plus a bias and Gaussian noise; the depth sensor the
  true depth plus Gaussian noise. The vehicle is stationary during a scan.

Everything random is drawn from a ``numpy.random.Generator`` passed in; :func:`simulate_site` derives one
per station from the spec's seed, so a spec always produces the same bytes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from cistern_archive.sonar.geometry import Slice, interpolate_slice, ray_cast
from cistern_archive.core.scan import Scan, wrap_angle
from cistern_archive.simulation.spec import EffectsSpec, SimulationSpec, SonarSpec
from cistern_archive.simulation.stations import TruePose, plan_route, station_poses, station_rng

__all__ = [
    "FULL_SCALE", "SimulatedScan", "SimulatedSite", "TruePose", "beam_bearings", "lobe_hits", "plan_route",
    "simulate_scan", "simulate_site", "station_poses", "station_rng",
]

FULL_SCALE = 255


@dataclass(frozen=True, eq=False)
class SimulatedScan:
    """A simulated scan with its truth.

    Attributes
    ----------
    scan : Scan
        What the sonar, compass and depth sensor report.
    pose : TruePose
        Where it really was.
    truth_ranges_m : ndarray, shape (A,)
        Range along each beam's axis to the true wall (``inf`` beyond the range setting or no wall).
    """

    scan: Scan
    pose: TruePose
    truth_ranges_m: np.ndarray


@dataclass(frozen=True, eq=False)
class SimulatedSite:
    """All scans of a spec, in station order."""

    spec: SimulationSpec
    scans: list[SimulatedScan]


def _db_to_power(db: np.ndarray | float) -> np.ndarray | float:
    return np.power(10.0, np.asarray(db) / 10.0)


def beam_bearings(sonar: SonarSpec) -> np.ndarray:
    """Bearings of one clockwise revolution in the sonar frame (CCW from forward), acquisition order."""
    n_beams = int(round(360.0 / sonar.step_deg))
    return np.asarray(wrap_angle(-np.arange(n_beams) * math.radians(360.0 / n_beams)))


def _lobe(width_deg: float, rays: int, span: float) -> tuple[np.ndarray, np.ndarray]:
    """Ray offsets (rad) across ``+-span x width`` and their two-way Gaussian weights (summing to 1).

    ``width_deg`` is the one-way -3 dB width; the two-way pattern is the one-way pattern squared.
    """
    width = math.radians(width_deg)
    if rays == 1:
        return np.zeros(1), np.ones(1)
    offsets = np.linspace(-span * width, span * width, rays)
    weights = np.exp(-8.0 * math.log(2.0) * (offsets / width) ** 2)
    return offsets, weights / weights.sum()


def _pattern(sonar: SonarSpec) -> tuple[np.ndarray, np.ndarray]:
    """Sub-ray angular offsets (rad) and weights across the horizontal lobe (``beam_width_deg``)."""
    return _lobe(sonar.beam_width_deg, sonar.sub_rays, 1.0)


def _vertical_pattern(sonar: SonarSpec) -> tuple[np.ndarray, np.ndarray]:
    """Elevation offsets (rad) and weights across the vertical lobe (``vertical_beam_width_deg``)."""
    return _lobe(sonar.vertical_beam_width_deg, sonar.vertical_rays, 0.75)


DEPTH_STEP_M = 0.05


def lobe_hits(
    rings: Slice, levels: list[tuple[float, Slice]] | None, origin: np.ndarray, angles: np.ndarray,
    depth_m: float, elevation: np.ndarray | float, water_depth_m: float | None, *, iterations: int = 5,
    level_hits: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Slant range and incidence cosine of rays at ``elevation`` (rad, positive down) to the walls.

    Parameters
    ----------
    rings : Slice
        The walls at the sonar's depth.
    levels : list of (depth, Slice), optional
        The site's levels when walls change with depth; ``None`` for vertical walls.
    origin, angles, depth_m :
        Where the head is and the rays' map-frame directions.
    elevation : float or ndarray, shape angles.shape
        Ray elevation below the horizontal.
    water_depth_m : float, optional
        Rays meeting the floor (or the surface, depth 0) before a wall return ``inf``.
    level_hits : (ndarray, ndarray), optional
        ``ray_cast(origin, angles, rings)`` if already computed.

    Returns
    -------
    slant_m, cos_incidence : ndarray, shape angles.shape
    """
    horizontal, cosines = ray_cast(origin, angles, rings) if level_hits is None else (
        level_hits[0].copy(), level_hits[1].copy())
    elevation = np.broadcast_to(np.asarray(elevation, dtype=np.float64), horizontal.shape)
    tan_e = np.tan(elevation)
    if levels is not None and len(levels) > 1 and np.any(elevation != 0.0):
        for _ in range(iterations):
            depth = depth_m + np.where(np.isfinite(horizontal), horizontal, 0.0) * tan_e
            quantised = np.round(np.clip(depth, 0.0, None) / DEPTH_STEP_M) * DEPTH_STEP_M
            for value in np.unique(quantised):
                pick = quantised == value
                horizontal[pick], cosines[pick] = ray_cast(origin, angles[pick], interpolate_slice(levels, value))
    hit_depth = depth_m + horizontal * tan_e
    ok = np.isfinite(horizontal) & (hit_depth >= 0.0)
    if water_depth_m is not None:
        ok &= hit_depth <= water_depth_m
    slant = np.where(ok, horizontal / np.cos(elevation), np.inf)
    return slant, np.where(ok, cosines * np.cos(elevation), 0.0)


def _bin_fractions(ranges: np.ndarray, edges: np.ndarray, sigma: float) -> np.ndarray:
    """Fraction of a Gaussian pulse centred on each range falling in each bin, shape ranges.shape + (B,)."""
    cdf = ndtr((edges - ranges[..., None]) / sigma)
    return np.diff(cdf, axis=-1)


def _echo_profiles(
    ranges: np.ndarray, cosines: np.ndarray, weights: np.ndarray, sonar: SonarSpec, effects: EffectsSpec,
    edges: np.ndarray,
) -> np.ndarray:
    """Pre-TVG echo power per beam and bin from sub-rays, shape (A, B).

    Each sub-ray's pulse is spread over the bins within 4 standard deviations of its range (the rest of
    a Gaussian is below 1e-4 of it).
    """
    n_beams, n_rays = ranges.shape
    n_bins = edges.size - 1
    bin_size = edges[1] - edges[0]
    sigma = sonar.pulse_length_m / 2.0
    hit = np.isfinite(ranges) & (ranges < edges[-1] + 4 * sigma)
    beam_idx = np.broadcast_to(np.arange(n_beams)[:, None], ranges.shape)[hit]
    r = ranges[hit]
    backscatter = cosines[hit] ** 2 + effects.wall_roughness
    loss_db = sonar.spreading_exponent * np.log10(np.maximum(r, 1e-3)) + 2.0 * sonar.absorption_db_per_m * r
    power = np.broadcast_to(weights[None, :], ranges.shape)[hit] * backscatter * _db_to_power(-loss_db)
    reach = int(math.ceil(4 * sigma / bin_size)) + 1
    first = np.floor(r / bin_size).astype(np.int64) - reach
    out = np.zeros(n_beams * n_bins)
    for step in range(2 * reach + 1):
        k = first + step
        ok = (k >= 0) & (k < n_bins)
        lo = (edges[0] + k[ok] * bin_size - r[ok]) / sigma
        fraction = ndtr(lo + bin_size / sigma) - ndtr(lo)
        np.add.at(out, beam_idx[ok] * n_bins + k[ok], power[ok] * fraction)
    return out.reshape(n_beams, n_bins)


def _tvg_gain(centres: np.ndarray, sonar: SonarSpec) -> np.ndarray:
    r = np.maximum(centres, sonar.tvg_min_range_m)
    return _db_to_power(sonar.tvg_exponent * np.log10(r) + 2.0 * sonar.tvg_absorption_db_per_m * centres)


def _ghosts(
    axial_ranges: np.ndarray, axial_cos: np.ndarray, sonar: SonarSpec, effects: EffectsSpec, edges: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Pre-TVG power of multipath ghosts, shape (A, B)."""
    n_beams = axial_ranges.size
    chosen = (rng.random(n_beams) < effects.multipath_fraction) & np.isfinite(axial_ranges)
    extra = rng.uniform(*effects.multipath_extra_m, size=n_beams)
    offset_db = rng.uniform(*effects.multipath_level_db, size=n_beams)
    ghost_r = np.where(chosen, axial_ranges + extra, edges[-1] * 10.0)
    backscatter = axial_cos**2 + effects.wall_roughness
    loss_db = (sonar.spreading_exponent * np.log10(np.maximum(ghost_r, 1e-3))
               + 2.0 * sonar.absorption_db_per_m * ghost_r)
    power = np.where(chosen, backscatter * _db_to_power(offset_db - loss_db), 0.0)
    return power[:, None] * _bin_fractions(ghost_r, edges, sonar.pulse_length_m / 2.0)


def _self_echo(bearings: np.ndarray, centres: np.ndarray, effects: EffectsSpec, pulse_m: float) -> np.ndarray:
    """Post-TVG power of the ring-down, the near-field reverberation and the vehicle's body, (A, B)."""
    ring = np.zeros(centres.shape)
    if effects.self_echo_range_m > 0:
        ring = ring + _db_to_power(effects.self_echo_db) * np.exp(-centres / effects.self_echo_range_m)
    if effects.near_field_range_m > 0:
        ring = ring + _db_to_power(effects.near_field_db) * np.exp(-centres / effects.near_field_range_m)
    out = np.broadcast_to(ring, (bearings.size, centres.size)).copy()
    centre, width = (math.radians(v) for v in effects.vehicle_sector_deg)
    delta = np.abs(np.asarray(wrap_angle(bearings - centre)))
    in_sector = delta <= width / 2
    if in_sector.any() and width > 0:
        lo, hi = effects.vehicle_echo_range_m
        body_r = lo + (hi - lo) * (delta[in_sector] / (width / 2)) ** 2
        sigma = max(pulse_m, 0.02)
        bump = np.exp(-0.5 * ((centres[None, :] - body_r[:, None]) / sigma) ** 2)
        out[in_sector] += _db_to_power(effects.vehicle_echo_db) * bump
    return out


def _reverberation(
    centres: np.ndarray, wall_ranges: np.ndarray, depth_m: float, water_depth_m: float | None,
    sonar: SonarSpec, effects: EffectsSpec,
) -> np.ndarray:
    """Post-TVG floor/surface reverberation seen through the vertical lobe, up to each beam's wall."""
    half = math.radians(sonar.vertical_beam_width_deg / 2.0)
    heights = [depth_m] if depth_m > 0 else []
    if water_depth_m is not None and water_depth_m > depth_m:
        heights.append(water_depth_m - depth_m)
    if not heights:
        return np.zeros((wall_ranges.size, centres.size))
    onset = min(heights) / math.sin(half)
    ramp = np.clip((centres - onset) / max(onset, 0.1), 0.0, 1.0)
    level = _db_to_power(effects.floor_db) * ramp
    before_wall = centres[None, :] < np.where(np.isfinite(wall_ranges), wall_ranges, np.inf)[:, None]
    return level[None, :] * before_wall


def simulate_scan(
    rings: Slice,
    pose: TruePose,
    sonar: SonarSpec,
    effects: EffectsSpec,
    rng: np.random.Generator,
    *,
    timestamp: float = float("nan"),
    water_depth_m: float | None = None,
    levels: list[tuple[float, Slice]] | None = None,
) -> SimulatedScan:
    """Simulate one stationary 360° scan (model in the module docstring).

    Parameters
    ----------
    rings : list of (K, 2) arrays
        The walls at the sonar's depth.
    pose : TruePose
        The true pose of the sonar head.
    sonar, effects : SonarSpec, EffectsSpec
    rng : numpy.random.Generator
        Source of every random draw.
    timestamp : float
        Start of the sweep (Unix seconds).
    water_depth_m : float, optional
        Floor depth, for floor reverberation and for the vertical lobe.
    levels : list of (depth, Slice), optional
        The site's levels, when its walls change with depth (the vertical lobe sees other depths).

    Returns
    -------
    SimulatedScan
    """
    bearings = beam_bearings(sonar)
    bin_size = sonar.range_m / sonar.bins
    edges = np.arange(sonar.bins + 1) * bin_size
    centres = edges[:-1] + bin_size / 2
    offsets, weights = _pattern(sonar)
    elevations, v_weights = _vertical_pattern(sonar)
    origin = np.array([pose.x_m, pose.y_m])
    beam_angles = pose.yaw_rad + bearings
    ray_angles = (beam_angles[:, None] + offsets[None, :]).ravel()
    level_hits = ray_cast(origin, ray_angles, rings)
    cell = (elevations[1] - elevations[0]) if elevations.size > 1 else 0.0
    slant, cos_inc = [], []
    for elevation in elevations:
        jitter = rng.uniform(-cell / 2, cell / 2, size=bearings.size) if cell else np.zeros(bearings.size)
        per_ray = np.repeat(elevation + jitter, offsets.size)
        r, c = lobe_hits(rings, levels, origin, ray_angles, pose.depth_m, per_ray, water_depth_m,
                         level_hits=level_hits)
        slant.append(r.reshape(bearings.size, offsets.size))
        cos_inc.append(c.reshape(bearings.size, offsets.size))
    ranges = np.concatenate(slant, axis=1)
    cosines = np.concatenate(cos_inc, axis=1)
    weights = (v_weights[:, None] * weights[None, :]).ravel()
    axial_r, axial_c = ray_cast(origin, beam_angles, rings)

    echo = _echo_profiles(ranges, cosines, weights, sonar, effects, edges)
    echo += _ghosts(axial_r, axial_c, sonar, effects, edges, rng)
    tvg = _tvg_gain(centres, sonar)
    signal = echo * tvg[None, :]
    signal += _self_echo(bearings, centres, effects, sonar.pulse_length_m)
    signal += _reverberation(centres, axial_r, pose.depth_m, water_depth_m, sonar, effects)
    if effects.speckle_looks > 0:
        signal *= rng.gamma(effects.speckle_looks, 1.0 / effects.speckle_looks, size=signal.shape)
    noise_power = _db_to_power(effects.noise_db) * tvg + _db_to_power(effects.background_db)
    noise = noise_power[None, :] * rng.exponential(1.0, size=signal.shape)
    level_db = 10.0 * np.log10(signal + noise + 1e-30)
    counts = np.floor(FULL_SCALE * (level_db - sonar.ad_low_db) / sonar.ad_span_db)
    intensities = np.clip(counts, 0, FULL_SCALE).astype(np.uint8)
    _add_spikes(intensities, effects.spike_rate, rng)

    measured_yaw = pose.yaw_rad + math.radians(
        effects.compass_bias_deg + effects.compass_sigma_deg * rng.standard_normal()
    )
    measured_depth = pose.depth_m + effects.depth_sigma_m * rng.standard_normal()
    scan = Scan(
        bearings_rad=bearings,
        intensities=intensities,
        full_scale=FULL_SCALE,
        bin_size_m=bin_size,
        start_range_m=0.0,
        yaw_rad=float(wrap_angle(measured_yaw)),
        depth_m=float(max(measured_depth, 0.0)),
        timestamp=timestamp,
        sonar_model=sonar.model,
        beam_width_rad=math.radians(sonar.beam_width_deg),
        station=pose.station,
        settings={
            "simulated": True,
            "frequency_khz": sonar.frequency_khz,
            "range_m": sonar.range_m,
            "bins": sonar.bins,
            "step_deg": 360.0 / bearings.size,
            "ad_low_db": sonar.ad_low_db,
            "ad_span_db": sonar.ad_span_db,
        },
    )
    truth = np.where(axial_r <= sonar.range_m, axial_r, np.inf)
    return SimulatedScan(scan=scan, pose=pose, truth_ranges_m=truth)


def _add_spikes(intensities: np.ndarray, rate: float, rng: np.random.Generator) -> None:
    """Isolated one-bin interference spikes, in place."""
    n_beams, n_bins = intensities.shape
    count = int(rng.poisson(rate * n_beams)) if rate > 0 else 0
    if count:
        beams = rng.integers(0, n_beams, size=count)
        bins = rng.integers(0, n_bins, size=count)
        intensities[beams, bins] = rng.integers(120, FULL_SCALE + 1, size=count).astype(np.uint8)


def simulate_site(spec: SimulationSpec, *, effects: EffectsSpec | None = None) -> SimulatedSite:
    """Simulate every station of ``spec`` (deterministic in ``spec.seed``).

    Parameters
    ----------
    spec : SimulationSpec
    effects : EffectsSpec, optional
        Override the spec's imperfections (e.g. :meth:`EffectsSpec.ideal` for a noise-free run).
    """
    effects = spec.effects if effects is None else effects
    start = spec.start_time.timestamp()
    slices = spec.site.slices()
    scans = []
    visits = [s.visit for s in spec.stations]
    for k, pose in enumerate(station_poses(spec)):
        visit = visits[k] if k < len(visits) and visits[k] is not None else k
        rings = interpolate_slice(slices, pose.depth_m)
        roughness = spec.site.wall_roughness(pose.depth_m, effects.wall_roughness)
        walls = effects if roughness == effects.wall_roughness else effects.model_copy(
            update={"wall_roughness": roughness})
        scans.append(simulate_scan(
            rings, pose, spec.sonar, walls, station_rng(spec.seed, 1, k),
            timestamp=start + visit * spec.seconds_per_station, water_depth_m=spec.site.water_depth_m,
            levels=slices if len(spec.site.levels) > 1 else None,
        ))
    return SimulatedSite(spec=spec, scans=scans)
