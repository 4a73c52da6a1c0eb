"""Helpers that write small catalogs for tests."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cistern_archive.sonar.interchange import write_scan
from cistern_archive.core.scan import Scan


def ring_scan(station: str = "S1", radius_m: float = 2.0) -> Scan:
    """A 200-beam scan of a circular wall ``radius_m`` away: enough to validate and segment."""
    bearings = np.linspace(-math.pi, math.pi, 200, endpoint=False)
    intensities = np.zeros((200, 100), dtype=np.uint8)
    intensities[:, int(radius_m / 0.05)] = 200
    intensities[:, int(radius_m / 0.05) + 1] = 120
    return Scan(bearings_rad=bearings, intensities=intensities, full_scale=255, bin_size_m=0.05, station=station)


RECORD = """\
id: test-site
name: Test site
scans:
  - file: data/s1.npz
    station: S1
    depth_m: 1.0
  - file: data/s2.npz
    station: S2
    depth_m: 1.0
references:
  - name: width
    value_m: 4.0
    kind: truth
"""


def write_catalog(root: Path, record_text: str = RECORD, name: str = "test-site.yaml") -> Path:
    """Write a catalog with two scan files and one record; returns the record path."""
    (root / "data").mkdir(parents=True, exist_ok=True)
    for station in ("s1", "s2"):
        write_scan(ring_scan(station.upper()), root / "data" / f"{station}.npz")
    path = root / name
    path.write_text(record_text, encoding="utf-8")
    return path
