"""A generated catalog of simulated rectangular cisterns, for the service's tests and benchmarks.

Each site is a rectangle of random size with two to four stations along its long axis and its true
width and length as references; the specs are written to ``ROOT/specs/`` and simulated with
:func:`cistern_archive.simulation.simulator.simulate_site` into ``ROOT/data/`` and ``ROOT/sites/``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from cistern_archive.simulation.output import generated_header, write_generated


def synthetic_spec(index: int, rng: np.random.Generator, *, stations: int | None = None) -> dict:
    """The simulator spec (as a mapping) of site ``index``."""
    length = float(np.round(rng.uniform(5.0, 9.0), 2))
    width = float(np.round(rng.uniform(2.5, 4.5), 2))
    n = int(stations if stations is not None else rng.integers(2, 5))
    spacing = min(1.6, 0.7 * length / max(n - 1, 1))
    xs = length / 2 + (np.arange(n) - (n - 1) / 2) * spacing
    station_list = []
    for k, x in enumerate(xs):
        station_list.append({
            "name": f"s{k + 1}",
            "x_m": float(np.round(x, 2)),
            "y_m": float(np.round(width / 2 + rng.uniform(-0.3, 0.3), 2)),
            "yaw_deg": float(np.round(rng.uniform(-20.0, 20.0) + 180.0 * rng.integers(0, 2), 1)),
            "depth_m": float(np.round(rng.uniform(1.0, 1.4), 2)),
        })
    inside = [float(np.round(length / 2, 2)), float(np.round(width / 2, 2))]  # site frame
    return {
        **generated_header(f"cistern-{index:03d}", f"Generated cistern {index:03d}",
                           f"Simulated rectangular cistern {length} m x {width} m with {n} stations.", rng),
        "site": {"water_depth_m": 2.0, "levels": [{"depth_m": 0.0, "walls": {"rectangle": [0.0, 0.0, length, width]}}]},
        "sonar": {"model": "Tritech Micron DST", "frequency_khz": 700, "range_m": 8.0, "bins": 200, "step_deg": 0.9,
                  "beam_width_deg": 3.0},
        "effects": {"compass_bias_deg": 2.0, "compass_sigma_deg": 1.0},
        "segmentation": {"method": "paper", "threshold": 50, "min_range_m": 0.4},
        "stations": station_list,
        "references": [
            {"name": "width", "kind": "truth", "value_m": width,
             "measure": {"frame": "s1", "inside": inside, "direction_deg": 90.0, "repeats": 5, "spacing_m": 0.3}},
            {"name": "length", "kind": "truth", "value_m": length,
             "measure": {"frame": "s1", "inside": inside, "direction_deg": 0.0, "repeats": 5, "spacing_m": 0.2}},
        ],
    }


def write_synthetic_catalog(root: Path, n_sites: int, *, seed: int = 0, stations: int | None = None) -> list[Path]:
    """Write ``n_sites`` simulated sites under the catalog root ``root``; return their record paths."""
    rng = np.random.default_rng(seed)
    return write_generated(root, (synthetic_spec(index, rng, stations=stations) for index in range(n_sites)))
