"""Reader of the marina's derived point clouds (``pclKeyFrameN.pcd``, PCD v0.7 ASCII, fields x y z).

Each file is one thresholded 2-D point cloud per 360° revolution of the marina's Miniking sonar
(200 beams of 1.8°, 0.1 m bins, 50 m range, ``_SETUP.log``), in the sonar frame (x forward, y left,
metres). The reader turns it back into a :class:`~cistern_archive.core.scan.Scan` grid:

* the cloud is mirrored (y to starboard); row ``j`` of the grid is the ``j``-th beam of the revolution
  in acquisition order, at ``+j * 1.8°`` counter-clockwise in the sonar frame, and its bearing in the
  body (DVL) frame adds the sonar mount (:data:`~cistern_archive.sonar.marina.SONAR_MOUNT_DEG`). The
  evidence for each convention is in :mod:`cistern_archive.sonar.marina`;
* every point goes to its beam and the bin ``floor(hypot(x, y) / 0.1 m)``: every echo of a beam is
  kept, intensities are 1 where a point fell and 0 elsewhere (``full_scale`` 1): the processing that
  made the cloud already thresholded the echoes (README: bins smoothed, ramp subtracted, points above
  45 kept).

Navigation: when ``keyFrameTimeStamps.csv`` lies beside the file, the scan's timestamp is its key frame's
begin time and, with ``*_IS_timestamps.log`` in the parent directory, ``beam_times_s`` holds the log
time of each of its 200 beams (sonar clock; ``settings["sonar_clock_offset_s"]`` maps it onto the
navigation clock). When an ``*_MTi.log`` lies in the parent directory, the yaw is the circular mean of
the MTi compass yaw over the key frame plus the compass offset
(:data:`~cistern_archive.sonar.marina.MTI_COMPASS_OFFSET_DEG`): the heading of the body frame. Depth is
0 (no depth log). The logs are parsed once per process and cached while unchanged.
Rows with NaN or infinite coordinates, or beyond the 50 m range, are dropped with a warning naming the line.
"""

from __future__ import annotations

import functools
import math
import re
from pathlib import Path

import numpy as np

from cistern_archive.core.errors import ReaderError
from cistern_archive.sonar import marina
from cistern_archive.sonar.readers import ReadResult, header_check, read_bytes, register_reader
from cistern_archive.core.scan import Scan, yaw_from_compass_deg

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


def cloud_beams(points: np.ndarray, *, mirrored: bool = marina.PCD_MIRRORED,
                first_beam_deg: float = marina.PCD_FIRST_BEAM_DEG,
                clockwise: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Acquisition index (0..199), sonar-frame angle (rad, CCW) and range of every cloud point.

    The cloud's angle ``atan2(y, x)`` is negated when the cloud is mirrored (:data:`marina.PCD_MIRRORED`)
    to give the sonar's counter-clockwise angle; beam ``j`` lies at ``first_beam_deg + j * 1.8°``
    (``- j * 1.8°`` when the head turns ``clockwise``, a hypothesis the data rejects).
    """
    theta = np.arctan2(points[:, 1], points[:, 0])
    sonar_angle = -theta if mirrored else theta
    turn = -1.0 if clockwise else 1.0
    beam = np.rint(turn * (sonar_angle - math.radians(first_beam_deg)) / STEP_RAD).astype(np.int64) % BEAMS
    return beam, sonar_angle, np.hypot(points[:, 0], points[:, 1])


def beam_bearings(*, first_beam_deg: float = marina.PCD_FIRST_BEAM_DEG,
                  mount_deg: float = marina.SONAR_MOUNT_DEG) -> np.ndarray:
    """Body-frame bearing (rad, CCW from the DVL's x axis, wrapped to [-pi, pi)) of beams 0..199."""
    angles = math.radians(first_beam_deg + mount_deg) + np.arange(BEAMS) * STEP_RAD
    return (angles + math.pi) % (2 * math.pi) - math.pi


def points_to_grid(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Body-frame bearings (200,) in acquisition order, a (200, 500) 0/1 grid of every point, and the
    number of points beyond :data:`RANGE_M`."""
    n_bins = int(round(RANGE_M / BIN_SIZE_M))
    grid = np.zeros((BEAMS, n_bins), dtype=np.uint8)
    beam, _, ranges = cloud_beams(points)
    bins = np.floor(ranges / BIN_SIZE_M).astype(np.int64)
    inside = bins < n_bins
    grid[beam[inside], bins[inside]] = 1
    return beam_bearings(), grid, int((~inside).sum())


@functools.lru_cache(maxsize=4)
def _cached(loader, path: Path, stamp: tuple[int, int]):
    return loader(path)


def _load(loader, path: Path):
    """``loader(path)``, cached while the file's size and modification time stay the same."""
    stat = path.stat()
    return _cached(loader, path, (stat.st_size, stat.st_mtime_ns))


def _beam_times(path: Path, begin: float, warnings: list[str]) -> np.ndarray | None:
    """The 200 beam times of the revolution that begins at ``begin`` (``_IS_timestamps.log`` beside
    ``derived_tim_pcd``), or None with a warning."""
    logs = sorted(path.parent.parent.glob("*_IS_timestamps.log"))
    if not logs:
        return None
    try:
        times = _load(marina.load_beam_times, logs[0]).time
    except ReaderError as exc:
        warnings.append(f"{exc}; no beam times")
        return None
    beam_times = marina.revolution_beam_times(times, begin, BEAMS)
    if beam_times is None:
        warnings.append(f"{path}: no run of {BEAMS} beams at {begin:.3f} s in {logs[0].name}; no beam times")
    return beam_times


def _navigation(path: Path, warnings: list[str]) -> tuple[float, float, dict, np.ndarray | None]:
    """Timestamp, body yaw, settings and beam times from the key-frame table and logs beside the file."""
    m = _KEYFRAME.search(path.name)
    stamps = path.parent / "keyFrameTimeStamps.csv"
    if m is None or not stamps.is_file():
        return float("nan"), 0.0, {}, None
    try:
        frames = _load(marina.load_keyframe_times, stamps)
    except ReaderError as exc:
        warnings.append(f"{exc}; no timestamp")
        return float("nan"), 0.0, {}, None
    frame = int(m.group(1))
    if frame not in frames:
        warnings.append(f"{path}: key frame {frame} is not in {stamps.name}; no timestamp")
        return float("nan"), 0.0, {}, None
    begin, end = frames[frame]
    settings: dict = {"key_frame": frame, "end_timestamp": end}
    mti_logs = sorted(path.parent.parent.glob("*_MTi.log"))
    yaw = 0.0
    if mti_logs:
        try:
            heading = marina.mean_heading_deg(_load(marina.load_mti, mti_logs[0]), begin, end)
        except ReaderError as exc:
            warnings.append(f"{exc}; yaw left at 0")
            heading = None
        if heading is not None:
            yaw = yaw_from_compass_deg(heading + marina.MTI_COMPASS_OFFSET_DEG)
            settings["compass_heading_deg"] = heading
            settings["compass_offset_deg"] = marina.MTI_COMPASS_OFFSET_DEG
            settings["heading_source"] = mti_logs[0].name
    return begin, yaw, settings, _beam_times(path, begin, warnings)


def _sniff(path: Path) -> bool:
    try:
        with path.open("rb") as fh:
            return b"FIELDS" in fh.read(512)
    except OSError:
        return False


@register_reader("marina-pcd", (".pcd",), "Girona marina derived point cloud (one revolution per file)",
                 sniff=_sniff, check=header_check(_sniff, "a PCD point cloud: no FIELDS line in its first 512 bytes"))
def read_pcd(path: Path) -> ReadResult:
    """Read one key-frame point cloud as a 200-beam scan (see the module docstring)."""
    points, warnings = read_points(path)
    if points.shape[0] == 0:
        raise ReaderError(str(path), "no valid points", record=0)
    bearings, grid, beyond = points_to_grid(points)
    if beyond:
        warnings.append(f"{path}: {beyond} point(s) beyond {RANGE_M} m dropped")
    timestamp, yaw, nav_settings, beam_times = _navigation(path, warnings)
    settings = {"source": "marina derived point cloud", "points": int(points.shape[0]),
                "range_m": RANGE_M, "step_rad": STEP_RAD, "mirrored": marina.PCD_MIRRORED,
                "first_beam_deg": marina.PCD_FIRST_BEAM_DEG, "sonar_mount_deg": marina.SONAR_MOUNT_DEG,
                "sonar_clock_offset_s": marina.SONAR_CLOCK_OFFSET_S, **nav_settings}
    scan = Scan(bearings_rad=bearings, intensities=grid, full_scale=1.0, bin_size_m=BIN_SIZE_M,
                start_range_m=0.0, yaw_rad=yaw, depth_m=0.0, timestamp=timestamp,
                sonar_model="Tritech Miniking (marina, thresholded)", beam_width_rad=MINIKING_BEAM_WIDTH_RAD,
                settings=settings, beam_times_s=beam_times)
    return ReadResult(format="marina-pcd", scans=[scan], warnings=warnings)
