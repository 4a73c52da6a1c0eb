"""Small simulated catalogs for the emulator, driver and acquisition tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from cistern_archive.simulation.output import write_site
from cistern_archive.simulation.simulator import simulate_site
from cistern_archive.simulation.spec import load_spec

SPEC = """\
# A 6 m x 4 m pool with three stations (a tiny stand-in for the LAIR pool).
schema_version: 1
id: pool
name: Test pool
seed: 11
site:
  water_depth_m: 1.6
  levels:
    - depth_m: 0.0
      walls:
        rectangle: [0.0, 0.0, 6.0, 4.0]
sonar:
  range_m: 6.0
  bins: 120
  step_deg: 1.8
stations:
  - {name: a, x_m: 1.5, y_m: 1.8, yaw_deg: 10.0, depth_m: 1.0}
  - {name: b, x_m: 3.0, y_m: 2.1, yaw_deg: -5.0, depth_m: 1.0}
  - {name: c, x_m: 4.5, y_m: 1.9, yaw_deg: 3.0, depth_m: 1.0}
"""


def make_catalog(root: Path, spec_text: str, stations: tuple[str, ...]) -> Path:
    """Write a spec, simulate it and write a catalog under ``root`` whose record holds only ``stations``.

    The other stations of the spec are left for a test to acquire through the emulator.
    """
    root.mkdir(parents=True, exist_ok=True)
    spec_path = root / "specs" / "site.yaml"
    spec_path.parent.mkdir(parents=True, exist_ok=True)
    spec_path.write_text(spec_text, encoding="utf-8")
    site = simulate_site(load_spec(spec_path))
    keep = [s for s in site.scans if s.pose.station in stations]
    write_site(type(site)(spec=site.spec, scans=keep), root, spec_path=spec_path, record_dir="sites")
    return root


def make_tiny_catalog(root: Path, *, stations: tuple[str, ...] = ("a", "c")) -> Path:
    """The 6 m x 4 m pool with stations ``a`` and ``c`` in its record (``b`` left to acquire)."""
    return make_catalog(root, SPEC, stations)


@pytest.fixture
def tiny_catalog(tmp_path: Path) -> Path:
    return make_tiny_catalog(tmp_path / "catalog")
