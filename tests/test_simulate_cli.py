"""``cistern-archive simulate SPEC --out DIR``: scans, truth.json and a ready, valid site record."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cistern_archive.catalog.loader import load_record, record_paths
from cistern_archive.sonar.interchange import read_scan

CLI = [sys.executable, "-m", "cistern_archive"]
SPEC = """
id: tiny-room
name: Tiny room
seed: 5
site:
  water_depth_m: 2.0
  levels:
    - depth_m: 0.0
      walls: {rectangle: [0.0, 0.0, 3.0, 2.0]}
sonar: {range_m: 4.0, bins: 100, step_deg: 3.6}
stations:
  - {name: s1, x_m: 0.8, y_m: 1.0, yaw_deg: 10.0, depth_m: 1.0}
  - {name: s2, x_m: 2.2, y_m: 0.9, yaw_deg: -5.0, depth_m: 1.0}
references:
  - name: width
    kind: truth
    measure: {frame: s1, inside: [1.5, 1.0], direction_deg: 90.0, repeats: 4, spacing_m: 0.3}
  - name: width
    kind: mosaic
    error_sigma_m: 0.05
    measure: {frame: s1, inside: [1.5, 1.0], direction_deg: 90.0, repeats: 4, spacing_m: 0.3}
"""


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=120)


def test_simulate_writes_a_catalog(tmp_path: Path):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    done = run("simulate", str(spec), "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert "tiny-room: 2 scan(s)" in done.stdout
    [path] = record_paths(out)
    loaded = load_record(path, out)
    record = loaded.record
    assert record.id == "tiny-room" and record.simulation == "specs/tiny-room.yaml"
    assert (out / "specs" / "tiny-room.yaml").read_text() == SPEC
    assert [s.station for s in record.scans] == ["s1", "s2"]
    assert [(t.x_m, t.y_m, t.yaw_deg) for t in record.truth] == [(0.8, 1.0, 10.0), (2.2, 0.9, -5.0)]
    truth_width, mosaic_width = record.references
    assert truth_width.value_m == 2.0 and truth_width.kind == "truth"
    assert mosaic_width.kind == "mosaic" and abs(mosaic_width.value_m - 2.0) < 0.25
    assert truth_width.measure.inside == (0.7, 0.0)
    scan = read_scan(loaded.resolve(record.scans[0].file))
    assert scan.intensities.shape == (100, 100) and scan.station == "s1"
    truth = json.loads((out / "data" / "tiny-room" / "truth.json").read_text())
    assert truth["stations"][1]["station"] == "s2" and truth["levels"][0]["depth_m"] == 0.0
    assert np.isclose(truth["stations"][0]["measured_yaw_deg"], np.degrees(scan.yaw_rad))


def test_simulate_is_deterministic_and_honours_record_dir(tmp_path: Path):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(SPEC)
    for name in ("a", "b"):
        assert run("simulate", str(spec), "--out", str(tmp_path / name), "--record-dir", "sites").returncode == 0
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert Path("sites/tiny-room.yaml") in files and Path("data/tiny-room/s2.npz") in files
    for relative in files:
        assert (tmp_path / "a" / relative).read_bytes() == (tmp_path / "b" / relative).read_bytes(), relative


def test_ideal_switches_the_noise_off(tmp_path: Path):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(SPEC)
    assert run("simulate", str(spec), "--out", str(tmp_path / "o"), "--ideal").returncode == 0
    scan = read_scan(tmp_path / "o" / "data" / "tiny-room" / "s1.npz")
    assert scan.yaw_rad == pytest.approx(np.radians(10.0), abs=1e-12) and scan.depth_m == 1.0


def test_bad_spec_exits_2_naming_file_and_line(tmp_path: Path):
    spec = tmp_path / "bad.yaml"
    spec.write_text(SPEC.replace("bins: 100", "bins: -3"))
    done = run("simulate", str(spec), "--out", str(tmp_path / "o"))
    assert done.returncode == 2
    assert f"{spec}:10: sonar.bins" in done.stderr


def test_station_outside_exits_2(tmp_path: Path):
    spec = tmp_path / "out.yaml"
    spec.write_text(SPEC.replace("x_m: 2.2", "x_m: 9.0"))
    done = run("simulate", str(spec), "--out", str(tmp_path / "o"))
    assert done.returncode == 2 and "not in the water" in done.stderr


def test_missing_spec_exits_2(tmp_path: Path):
    done = run("simulate", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "o"))
    assert done.returncode == 2 and "nope.yaml" in done.stderr


def test_rerun_removes_scans_of_stations_that_are_gone(tmp_path: Path):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(SPEC)
    out = tmp_path / "o"
    assert run("simulate", str(spec), "--out", str(out)).returncode == 0
    fewer = SPEC.replace("  - {name: s2, x_m: 2.2, y_m: 0.9, yaw_deg: -5.0, depth_m: 1.0}\n", "")
    spec.write_text(fewer)
    assert run("simulate", str(spec), "--out", str(out)).returncode == 0
    assert sorted(p.name for p in (out / "data" / "tiny-room").iterdir()) == ["s1.npz", "truth.json"]
