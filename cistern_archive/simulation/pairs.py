"""Simulated scan pairs with known truth, for conformance checks, tests and the matcher benchmark.

A pair is two :class:`~cistern_archive.core.scan.RangeScan` taken at two stations of one simulated
site (or of two different sites, for pairs with no overlap), with the true displacement
``d = p_moving - p_reference`` and the true yaw correction of the moving scan's compass.

Two sonar models (``PairSpec.sonar``):

* ``"simulator"``: the project's physical sonar simulator
  (:func:`cistern_archive.simulation.simulator.simulate_scan`: beam patterns, speckle, multipath ghosts,
  reverberation, 8-bit AD conversion) followed by the pipeline's beam segmentation
  (:func:`cistern_archive.sonar.segmentation.segment`, ``PairSpec.segmentation``), so matchers see the
  ranges they will see in a site build. ``noise_m`` then only labels the pair; the noise is the
  simulator's.
* ``"rays"`` (default): ideal rays with Gaussian range noise (``noise_m``), a fraction of multipath outliers (a
  uniformly random range before the wall, as Silver et al. simulate on ~10 % of readings) and
  drop-outs; fast, and the noise level is controlled exactly.

The reference compass is exact; the moving compass is off by ``yaw_error_rad``, so the true
correction is ``-yaw_error_rad``.

The overlap of a pair is the smaller of the two fractions of one scan's true wall points that the
other station sees (in range, not occluded).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cistern_archive.catalog.models import Segmentation
from cistern_archive.core.scan import RangeScan
from cistern_archive.simulation.rays import Environment, cast_rays, random_environment, visible_from
from cistern_archive.simulation.simulator import TruePose, simulate_scan
from cistern_archive.simulation.spec import EffectsSpec, SonarSpec
from cistern_archive.sonar.segmentation import segment


@dataclass(frozen=True, eq=False)
class SimulatedPair:
    """Two scans and the truth a matcher should recover.

    Attributes
    ----------
    reference, moving : RangeScan
    dx_m, dy_m : float
        True ``p_moving - p_reference`` in the map frame.
    dyaw_rad : float
        True correction to add to the moving scan's compass yaw.
    overlap : float
        Fraction of common wall (0 for pairs from different sites), see module docstring.
    noise_m : float
        Standard deviation of the range noise.
    """

    reference: RangeScan
    moving: RangeScan
    dx_m: float
    dy_m: float
    dyaw_rad: float
    overlap: float
    noise_m: float

    @property
    def offset_m(self) -> float:
        """Initial translation offset a matcher starting from zero must overcome."""
        return math.hypot(self.dx_m, self.dy_m)


def simulate_range_scan(env: Environment, position: np.ndarray, yaw_rad: float, *, compass_yaw_rad: float,
                        n_beams: int, max_range_m: float, noise_m: float, outlier_fraction: float,
                        dropout_fraction: float, rng: np.random.Generator, station: str = "") -> RangeScan:
    """Cast one 360° sweep from ``position`` with true heading ``yaw_rad``; record ``compass_yaw_rad``."""
    bearings = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    true = cast_rays(np.asarray(position, float), bearings + yaw_rad, env.walls)
    ranges = true + rng.normal(0.0, noise_m, n_beams) if noise_m > 0 else true.copy()
    outlier = rng.random(n_beams) < outlier_fraction
    ranges[outlier] = rng.uniform(0.3, 1.0, outlier.sum()) * np.minimum(true[outlier], max_range_m)
    ranges[(rng.random(n_beams) < dropout_fraction) | ~(true <= max_range_m) | (ranges <= 0)] = np.nan
    return RangeScan(bearings_rad=bearings, ranges_m=ranges, yaw_rad=float(compass_yaw_rad), depth_m=1.0,
                     max_range_m=max_range_m, bin_size_m=0.05, beam_width_rad=math.radians(3.0), station=station)


def simulate_sonar_scan(env: Environment, position: np.ndarray, yaw_rad: float, *, compass_yaw_rad: float,
                        max_range_m: float, step_deg: float, rng: np.random.Generator, station: str = "",
                        segmentation: str | None = None) -> RangeScan:
    """One sweep through the physical simulator and the pipeline's beam segmentation (``segmentation``:
    a :class:`~cistern_archive.catalog.models.Segmentation` method; default, the records' default)."""
    sonar = SonarSpec(range_m=max_range_m, bins=int(round(max_range_m / 0.04)), step_deg=step_deg,
                      sub_rays=5, vertical_rays=5)
    effects = EffectsSpec(compass_sigma_deg=0.0, compass_bias_deg=0.0, depth_sigma_m=0.0)
    pose = TruePose(station, float(position[0]), float(position[1]), float(yaw_rad), 1.0)
    sim = simulate_scan(list(env.rings), pose, sonar, effects, rng, water_depth_m=3.0)
    settings = Segmentation(min_range_m=0.4) if segmentation is None else \
        Segmentation(method=segmentation, min_range_m=0.4)
    rs = segment(sim.scan.replace(yaw_rad=float(compass_yaw_rad)), settings)
    return rs


def pair_overlap(env: Environment, p_ref: np.ndarray, p_mov: np.ndarray, max_range_m: float,
                 n_beams: int = 360) -> float:
    """The smaller of the two co-visible fractions of true wall points (see module docstring)."""
    angles = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    fractions = []
    for a, b in ((p_ref, p_mov), (p_mov, p_ref)):
        r = cast_rays(a, angles, env.walls)
        ok = r <= max_range_m
        if not ok.any():
            return 0.0
        pts = a + np.column_stack([r[ok] * np.cos(angles[ok]), r[ok] * np.sin(angles[ok])])
        fractions.append(float(visible_from(b, pts, env.walls, max_range_m).mean()))
    return min(fractions)


@dataclass(frozen=True)
class PairSpec:
    """How to draw pairs: ranges of the random quantities."""

    n_beams: int = 200
    max_range_m: tuple[float, float] = (2.5, 8.0)
    noise_levels_m: tuple[float, ...] = (0.02, 0.05, 0.10)
    outlier_fraction: float = 0.05
    dropout_fraction: float = 0.05
    max_offset_m: float = 2.0
    max_yaw_error_deg: float = 20.0
    sonar: str = "rays"
    segmentation: str | None = None
    """Segmentation method of the ``simulator`` sonar (``None``: the records' default)."""


def simulated_pair(rng: np.random.Generator, *, spec: PairSpec = PairSpec(), overlapping: bool = True,
                   noise_m: float | None = None, offset_range_m: tuple[float, float] | None = None,
                   overlap_range: tuple[float, float] | None = None, environment: Environment | None = None,
                   max_tries: int = 400) -> SimulatedPair:
    """Draw one pair.

    Parameters
    ----------
    rng : numpy.random.Generator
        The only source of randomness: equal seeds give equal pairs.
    overlapping : bool
        ``False`` draws the two scans in two different sites (overlap 0).
    noise_m : float, optional
        Range noise; default a random choice of ``spec.noise_levels_m``.
    offset_range_m : (float, float), optional
        Bounds on the true translation (default 0 .. ``spec.max_offset_m``).
    overlap_range : (float, float), optional
        Redraw until the overlap falls in these bounds (overlapping pairs only).
    """
    noise = float(rng.choice(spec.noise_levels_m)) if noise_m is None else float(noise_m)
    lo, hi = offset_range_m if offset_range_m is not None else (0.0, spec.max_offset_m)
    yaw_error = math.radians(float(rng.uniform(-spec.max_yaw_error_deg, spec.max_yaw_error_deg)))
    for _ in range(max_tries):
        max_range = float(rng.uniform(*spec.max_range_m))
        env = environment if environment is not None else random_environment(rng)
        if len(env.free_points) < 2:
            continue
        p_ref = env.free_points[rng.integers(len(env.free_points))]
        if overlapping:
            d = env.free_points - p_ref
            dist = np.hypot(d[:, 0], d[:, 1])
            ok = np.flatnonzero((dist >= lo) & (dist <= hi))
            if len(ok) == 0:
                continue
            p_mov = env.free_points[ok[rng.integers(len(ok))]]
            overlap = pair_overlap(env, p_ref, p_mov, max_range)
            if overlap_range is not None and not overlap_range[0] <= overlap <= overlap_range[1]:
                continue
            env_mov = env
        else:
            env_mov = random_environment(rng)
            if len(env_mov.free_points) == 0:
                continue
            p_mov = env_mov.free_points[rng.integers(len(env_mov.free_points))]
            overlap = 0.0
        yaw_ref = float(rng.uniform(-np.pi, np.pi))
        yaw_mov = float(rng.uniform(-np.pi, np.pi))
        if spec.sonar == "simulator":
            common = dict(max_range_m=max_range, step_deg=360.0 / spec.n_beams, rng=rng,
                          segmentation=spec.segmentation)
            ref = simulate_sonar_scan(env, p_ref, yaw_ref, compass_yaw_rad=yaw_ref, station="ref", **common)
            mov = simulate_sonar_scan(env_mov, p_mov, yaw_mov, compass_yaw_rad=yaw_mov + yaw_error, station="mov",
                                      **common)
        else:
            common = dict(n_beams=spec.n_beams, max_range_m=max_range, noise_m=noise,
                          outlier_fraction=spec.outlier_fraction, dropout_fraction=spec.dropout_fraction, rng=rng)
            ref = simulate_range_scan(env, p_ref, yaw_ref, compass_yaw_rad=yaw_ref, station="ref", **common)
            mov = simulate_range_scan(env_mov, p_mov, yaw_mov, compass_yaw_rad=yaw_mov + yaw_error, station="mov",
                                      **common)
        if ref.valid.sum() < 20 or mov.valid.sum() < 20:
            continue
        dx, dy = (p_mov - p_ref) if overlapping else rng.uniform(-hi, hi, 2)
        return SimulatedPair(ref, mov, float(dx), float(dy), -yaw_error, overlap, noise)
    raise RuntimeError(f"could not draw a pair with offset in [{lo}, {hi}] m and overlap in {overlap_range} "
                       f"after {max_tries} tries")


def pair_set(n: int, seed: int, *, spec: PairSpec = PairSpec(), no_overlap_fraction: float = 0.0) -> list[SimulatedPair]:
    """``n`` pairs from one seed; a fraction of them from two different sites."""
    rng = np.random.default_rng(seed)
    n_none = int(round(n * no_overlap_fraction))
    return [simulated_pair(rng, spec=spec, overlapping=k >= n_none) for k in range(n)]
