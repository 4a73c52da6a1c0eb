"""Generated bell-shaped cisterns: walls that lean over the vehicle, scanned at several depths.

Each site is a neck of 0.4-0.8 m radius at 0.3 m depth widening through elliptical levels 1 m apart
(4-5.5 m of water): the lean of the walls from the vertical is steepest under the neck (30-60°) and
falls level by level (by a factor of 0.55-0.9), the shape of the Maltese bell cisterns (McVicker et
al., Sec. III-A). It is scanned at two or three depths about
1 m apart, three stations per depth; the vehicle descends vertically from the last station of one
depth to the first of the next (a ``below`` tie, 3 cm of drift). The true length and width of every
scanned depth are its references. Specs are written to ``ROOT/specs/`` and simulated into
``ROOT/data/`` and ``ROOT/sites/`` as :mod:`cistern_archive.simulation.synthetic` does. With
``vertical`` the same sites have vertical walls (wells scanned at several depths: the control).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cistern_archive.simulation.output import generated_header, write_generated

LEVEL_STEP_M = 1.0
"""Depth between the levels that define the walls."""


def bell_levels(rng: np.random.Generator, vertical: bool = False
                ) -> tuple[list[dict], list[tuple[float, float, float]]]:
    """The spec's levels and, per level, ``(depth, semi-major, semi-minor)`` of its ellipse (``vertical``:
    a well of one ellipse, its semi-major axis 1.8-3 m, at every depth)."""
    neck = float(rng.uniform(1.8, 3.0) if vertical else rng.uniform(0.4, 0.8))
    ratio = float(rng.uniform(0.8, 0.95))
    rotation = float(rng.uniform(0.0, 180.0))
    floor = float(rng.uniform(4.0, 5.5))
    lean = 0.0 if vertical else math.radians(rng.uniform(30.0, 60.0))
    depths = [0.3] + [float(d) for d in np.arange(1.0, floor, LEVEL_STEP_M)] + [floor]
    shape, radius = [], neck
    for k, depth in enumerate(depths):
        if k:
            radius += (depth - depths[k - 1]) * math.tan(lean)
            lean *= float(rng.uniform(0.55, 0.9))
        shape.append((float(depth), radius, radius * ratio))
    levels = [{"depth_m": round(d, 2), "walls": {"ellipse": [0.0, 0.0, round(float(a), 3), round(float(b), 3)], "segments": 96,
                                                  "rotation_deg": round(rotation, 1)}} for d, a, b in shape]
    return levels, shape


def _radius_at(shape: list[tuple[float, float, float]], depth: float) -> float:
    """The semi-minor axis (the narrower) of the walls at ``depth``, linear between levels."""
    return float(np.interp(depth, [s[0] for s in shape], [s[2] for s in shape]))


def bell_stations(rng: np.random.Generator, shape: list[tuple[float, float, float]]) -> list[dict]:
    """Three stations per scanned depth, the first of each depth below the last of the one above."""
    floor = shape[-1][0]
    top = float(rng.uniform(1.5, 2.0))
    depths = [d for d in np.arange(top, floor - 0.7, LEVEL_STEP_M)][:3]
    stations: list[dict] = []
    for level, depth in enumerate(depths):
        reach = 0.55 * _radius_at(shape, depth)
        for k in range(3):
            if level and k == 0:
                above = stations[-1]
                x, y = above["x_m"] + rng.normal(0, 0.03), above["y_m"] + rng.normal(0, 0.03)
            else:
                angle, r = rng.uniform(0, 2 * math.pi), reach * math.sqrt(rng.uniform(0.2, 1.0))
                x, y = r * math.cos(angle), r * math.sin(angle)
            station = {"name": f"d{level + 1}{'abc'[k]}", "x_m": round(float(x), 2), "y_m": round(float(y), 2),
                       "yaw_deg": round(float(rng.uniform(-180, 180)), 1), "depth_m": round(float(depth), 2)}
            if level and k == 0:
                station["below"] = stations[-1]["name"]
            stations.append(station)
    return stations


def bell_spec(index: int, rng: np.random.Generator, vertical: bool = False) -> dict:
    """The simulator spec (as a mapping) of generated bell ``index`` (``vertical``: a well with vertical
    walls, scanned the same way)."""
    levels, shape = bell_levels(rng, vertical)
    stations = bell_stations(rng, shape)
    rotation = levels[0]["walls"]["rotation_deg"]
    references = []
    for station in stations:
        if station["name"].endswith("a"):
            for name, turn in (("length", 0.0), ("width", 90.0)):
                references.append({"name": f"{name} at {station['depth_m']:.1f} m", "kind": "truth",
                                   "measure": {"frame": station["name"], "inside": [0.0, 0.0],
                                               "direction_deg": round(rotation + turn, 1), "repeats": 10,
                                               "spacing_m": 0.1, "depth_m": station["depth_m"]}})
    floor = shape[-1][0]
    return {
        **generated_header(f"bell-{index:03d}", f"Generated bell-shaped cistern {index:03d}",
                           f"Simulated bell-shaped cistern {floor:.1f} m deep, base {2 * shape[-1][1]:.1f} m across.",
                           rng),
        "site": {"water_depth_m": round(floor, 2), "levels": levels},
        "segmentation": {"method": "shadow", "threshold": 50, "min_range_m": 0.4},
        "sonar": {"range_m": 6.0, "bins": 150, "step_deg": 0.9},
        "effects": {"compass_bias_deg": round(float(rng.uniform(-3, 3)), 1)},
        "stations": stations,
        "references": references,
    }


def write_bell_catalog(root: Path, n_sites: int, *, seed: int = 0, vertical: bool = False) -> list[Path]:
    """Write ``n_sites`` simulated bell-shaped cisterns (``vertical``: wells with vertical walls) under the
    catalog root ``root``; return their record paths."""
    rng = np.random.default_rng(seed)
    return write_generated(root, (bell_spec(index, rng, vertical) for index in range(n_sites)))
