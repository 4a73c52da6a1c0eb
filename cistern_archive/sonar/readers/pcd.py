"""Reader of the marina's derived point clouds (``pclKeyFrameN.pcd``, PCD v0.7 ASCII, fields x y z).

Each file is one thresholded 2-D point cloud per 360° revolution of the marina's Miniking sonar
(200 beams of 1.8°, 0.1 m bins, 50 m range, ``_SETUP.log``), in the sonar frame (x forward, y left,
metres). The reader turns it back into a :class:`~cistern_archive.sonar.scan.Scan` grid:

* beam ``k`` has bearing ``k * 1.8°`` wrapped to [-180°, 180°) (CCW from forward), every point goes to
  the beam nearest ``atan2(y, x)`` and the bin ``floor(hypot(x, y) / 0.1 m)``;
* intensities are 1 where a point fell and 0 elsewhere (``full_scale`` 1): the processing that made the
  cloud already thresholded the echoes (README: bins smoothed, ramp subtracted, points above 45 kept).

Navigation: when ``keyFrameTimeStamps.csv`` lies beside the file, the scan's timestamp is its key frame's
begin time; when an ``*_MTi.log`` lies in the parent directory, the yaw is the circular mean of the MTi
compass yaw over the key frame (:mod:`cistern_archive.sonar.marina`). Depth is 0 (no depth log).
Rows with NaN or infinite coordinates, or beyond the 50 m range, are dropped with a warning naming the line.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from cistern_archive.errors import ReaderError
from cistern_archive.sonar import marina
from cistern_archive.sonar.readers import ReadResult, read_bytes, register_reader
from cistern_archive.sonar.scan import Scan, yaw_from_compass_deg

BEAMS = 200
STEP_RAD = 2.0 * math.pi / BEAMS
BIN_SIZE_M = 0.1
RANGE_M = 50.0
MINIKING_BEAM_WIDTH_RAD = math.radians(3.0)
_KEYFRAME = re.compile(r"(\d+)\.pcd$", re.IGNORECASE)


def _parse_header(lines: list[str], path: Path) -> tuple[dict[str, list[str]], int]:
    header: dict[str, list[str]] = {}
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        key, *values = stripped.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            return header, i + 1
    raise ReaderError(str(path), "no DATA line: not a PCD file or truncated header", record=len(lines))


def read_points(path: Path) -> tuple[np.ndarray, list[str]]:
    """The (N, 2) x, y points of an ASCII PCD with fields x y z, plus warnings naming bad lines."""
    try:
        text = read_bytes(path).decode("ascii")
    except UnicodeDecodeError as exc:
        raise ReaderError(str(path), "not an ASCII PCD file (binary data)", offset=exc.start) from exc
    lines = text.splitlines()
    header, start = _parse_header(lines, path)
    kind = (header.get("DATA") or [""])[0]
    if kind.lower() != "ascii":
        raise ReaderError(str(path), f"unsupported PCD DATA {kind!r}; only ascii",
                          record=start)
    fields = [f.lower() for f in header.get("FIELDS", [])]
    if "x" not in fields or "y" not in fields:
        raise ReaderError(str(path), f"PCD FIELDS {fields} lack x and y", record=1)
    ix, iy = fields.index("x"), fields.index("y")
    warnings: list[str] = []
    points = []
    for lineno, line in enumerate(lines[start:], start=start + 1):
        parts = line.split()
        if not parts:
            continue
        try:
            x, y = float(parts[ix]), float(parts[iy])
        except (ValueError, IndexError):
            warnings.append(f"{path}: line {lineno}: not a point ({line.strip()[:40]!r}); skipped")
            continue
        if not (math.isfinite(x) and math.isfinite(y)):
            warnings.append(f"{path}: line {lineno}: NaN or infinite coordinate; skipped")
            continue
        points.append((x, y))
    declared = (header.get("POINTS") or [None])[0]
    if declared is not None and declared.isdigit() and int(declared) != len(points) + len(warnings):
        warnings.append(f"{path}: header declares {declared} points, the file has {len(points) + len(warnings)}")
    return np.array(points, dtype=np.float64).reshape(-1, 2), warnings


def points_to_grid(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Bearings (200,), a (200, 500) 0/1 grid, and the number of points beyond :data:`RANGE_M`."""
    n_bins = int(round(RANGE_M / BIN_SIZE_M))
    grid = np.zeros((BEAMS, n_bins), dtype=np.uint8)
    ranges = np.hypot(points[:, 0], points[:, 1])
    theta = np.arctan2(points[:, 1], points[:, 0])
    beam = np.rint(theta / STEP_RAD).astype(np.int64) % BEAMS
    bins = np.floor(ranges / BIN_SIZE_M).astype(np.int64)
    inside = bins < n_bins
    grid[beam[inside], bins[inside]] = 1
    bearings = (np.arange(BEAMS) * STEP_RAD + math.pi) % (2 * math.pi) - math.pi
    return bearings, grid, int((~inside).sum())


def _navigation(path: Path, warnings: list[str]) -> tuple[float, float, dict]:
    """Timestamp, yaw and settings from the key-frame table and MTi log beside the file."""
    m = _KEYFRAME.search(path.name)
    stamps = path.parent / "keyFrameTimeStamps.csv"
    if m is None or not stamps.is_file():
        return float("nan"), 0.0, {}
    try:
        frames = marina.load_keyframe_times(stamps)
    except ReaderError as exc:
        warnings.append(f"{exc}; no timestamp")
        return float("nan"), 0.0, {}
    frame = int(m.group(1))
    if frame not in frames:
        warnings.append(f"{path}: key frame {frame} is not in {stamps.name}; no timestamp")
        return float("nan"), 0.0, {}
    begin, end = frames[frame]
    settings: dict = {"key_frame": frame, "end_timestamp": end}
    mti_logs = sorted(path.parent.parent.glob("*_MTi.log"))
    yaw = 0.0
    if mti_logs:
        try:
            heading = marina.mean_heading_deg(marina.load_mti(mti_logs[0]), begin, end)
        except ReaderError as exc:
            warnings.append(f"{exc}; yaw left at 0")
            heading = None
        if heading is not None:
            yaw = yaw_from_compass_deg(heading)
            settings["compass_heading_deg"] = heading
            settings["heading_source"] = mti_logs[0].name
    return begin, yaw, settings


def _sniff(path: Path) -> bool:
    try:
        with path.open("rb") as fh:
            return b"FIELDS" in fh.read(512)
    except OSError:
        return False


@register_reader("marina-pcd", (".pcd",), "Girona marina derived point cloud (one revolution per file)",
                 sniff=_sniff)
def read_pcd(path: Path) -> ReadResult:
    """Read one key-frame point cloud as a 200-beam scan (see the module docstring)."""
    points, warnings = read_points(path)
    if points.shape[0] == 0:
        raise ReaderError(str(path), "no valid points", record=0)
    bearings, grid, beyond = points_to_grid(points)
    if beyond:
        warnings.append(f"{path}: {beyond} point(s) beyond {RANGE_M} m dropped")
    timestamp, yaw, nav_settings = _navigation(path, warnings)
    settings = {"source": "marina derived point cloud", "points": int(points.shape[0]),
                "range_m": RANGE_M, "step_rad": STEP_RAD, **nav_settings}
    scan = Scan(bearings_rad=bearings, intensities=grid, full_scale=1.0, bin_size_m=BIN_SIZE_M,
                start_range_m=0.0, yaw_rad=yaw, depth_m=0.0, timestamp=timestamp,
                sonar_model="Tritech Miniking (marina, thresholded)", beam_width_rad=MINIKING_BEAM_WIDTH_RAD,
                settings=settings)
    return ReadResult(format="marina-pcd", scans=[scan], warnings=warnings)
