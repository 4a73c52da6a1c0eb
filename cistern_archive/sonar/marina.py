"""Loaders of the Girona "abandoned marina" navigation logs (Ribas et al. 2008 dataset).

Files (see ``../shared/data/README.md``):

* ``_*_DGPS.log`` / ``GTData.csv``: log time (Unix s), latitude ``ddmm.mmmm``, longitude ``dddmm.mmmm``,
  status, altitude, geoid altitude, true course, magnetic course, speed (kn, km/h).
* ``dgps_local_EN_m.csv``: log time, east, north (m, origin at the first fix), status.
* ``_*_DVL.log``: log time, device date (wrong), water and bottom velocities (cm/s) …; only the columns up
  to heading/pitch/roll are trusted. ``dvlData.csv``: log time, bottom velocity x/y/z (m/s), three
  ranges, heading, pitch, roll (radians).
* ``_*_MTi.log``: log time, roll, pitch, yaw (degrees; yaw is a compass heading in ±180, clockwise from
  north), three rates, three accelerations.
* ``keyFrameTimeStamps.csv``: key frame number, begin and end time of its sonar revolution.

Frames of the derived point clouds (``pclKeyFrameN.pcd``), each fixed by the evidence quoted. The
measure (:mod:`cistern_archive.navigation.conventions`): place the echoes of consecutive revolutions
k and k+1 in the map by dead reckoning (calibrated, each echo at the pose of its beam's time) and
count the fraction of echoes of k+1 within 0.4 m of an echo of k; key frames 20–120 in steps of 4
and their successors. ``benchmarks/marina.py --conventions`` prints the table (RESULTS.md, "Girona
marina"); the measured conventions score 0.643, and

* **Mirror** (:data:`PCD_MIRRORED`): the clouds' y axis points to starboard; not mirrored: 0.088.
* **Beam order** (:data:`PCD_FIRST_BEAM_DEG`): beam ``j`` of a revolution (row ``j`` of the
  revolution's 200 rows in ``_IS_timestamps.log``) lies at ``-j * 1.8°`` in the cloud's own angles,
  i.e. at ``+j * 1.8°`` counter-clockwise once un-mirrored; clockwise order: 0.210, first beam at
  90°: 0.259; one time for the whole revolution (no motion compensation): 0.360.
* **Mount** (:data:`SONAR_MOUNT_DEG`): the sonar's zero bearing points 240° counter-clockwise from
  the DVL's x axis (216°: 0.509, 264°: 0.555). On a finer grid the overlap peaks near 245° (242°:
  0.650, 244°: 0.655, 246°: 0.654, 248°: 0.648), and revolutions three apart, which see the mount
  more sharply, peak near 244.5° (240°: 0.474, 244°: 0.500, 246°: 0.495); the issue's −114° is 246°.
  The reader keeps 240° as the nominal mount; the survey pipeline estimates the correction on the
  first half of each run (:func:`cistern_archive.navigation.pipeline.estimate_mount_offset`).
* **Compass offset** (:data:`MTI_COMPASS_OFFSET_DEG`): body heading = MTi yaw − 22°, the offset that
  best fits dead reckoning to the first 300 s of DGPS (−22.55°; the DVL's own compass reads about 4°
  lower still). A constant compass offset turns the whole dead-reckoned track rigidly, so the overlap
  above cannot see it; the DGPS can.
* **Clock** (:data:`SONAR_CLOCK_OFFSET_S`): the sonar's log clock runs 0.75 s behind the navigation
  logs: an echo logged at ``t`` was measured at navigation time ``t + 0.75 s`` (0 s: 0.568,
  −0.75 s: 0.476; the survey pipeline estimates it again on the first half of each run,
  :func:`cistern_archive.navigation.pipeline.estimate_clock_offset`).

Every loader returns a :class:`NavTable` of named float64 columns sorted by time, and raises
:class:`~cistern_archive.core.errors.ReaderError` naming the file and line of a malformed row.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cistern_archive.core.errors import ReaderError


PCD_MIRRORED = True
PCD_FIRST_BEAM_DEG = 0.0
SONAR_MOUNT_DEG = 240.0
MTI_COMPASS_OFFSET_DEG = -22.0
SONAR_CLOCK_OFFSET_S = 0.75


@dataclass(frozen=True)
class NavTable:
    """Columns of a navigation log, all of equal length, rows sorted by ``time``."""

    columns: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    @property
    def time(self) -> np.ndarray:
        return self.columns["time"]

    def between(self, start: float, end: float) -> "NavTable":
        """Rows with ``start <= time <= end``."""
        mask = (self.time >= start) & (self.time <= end)
        return NavTable({k: v[mask] for k, v in self.columns.items()})

    def interp(self, name: str, t: float | np.ndarray) -> float | np.ndarray:
        """Linear interpolation of a column at time(s) ``t`` (clamped at the ends)."""
        return np.interp(t, self.time, self.columns[name])


def _rows(path: Path, sep: str | None, skip_header: bool) -> list[tuple[int, list[str]]]:
    try:
        text = path.read_text(encoding="latin-1")
    except OSError as exc:
        raise ReaderError(str(path), f"cannot read: {exc.strerror or exc}") from exc
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped[0] in "%#":
            continue
        if skip_header and not rows and not (stripped[0].isdigit() or stripped[0] in "+-."):
            continue
        fields = [f for f in (stripped.split(sep) if sep else stripped.split()) if f.strip() != ""]
        rows.append((lineno, fields))
    return rows


def load_table(path: str | os.PathLike, names: list[str], *, sep: str | None = None,
               columns: list[int] | None = None, skip_header: bool = True) -> NavTable:
    """Load a numeric table.

    Parameters
    ----------
    path : path-like
        The file.
    names : list of str
        Names of the columns kept (the first must be ``"time"``).
    sep : str, optional
        Field separator (whitespace when None).
    columns : list of int, optional
        Indices of the kept columns (default: the first ``len(names)``).
    skip_header : bool
        Skip a leading non-numeric line (a CSV header).

    Raises
    ------
    ReaderError
        A row has too few fields, a non-numeric or non-finite value, or the file has no rows.
    """
    path = Path(path)
    cols = columns if columns is not None else list(range(len(names)))
    values = []
    for lineno, fields in _rows(path, sep, skip_header):
        if len(fields) <= max(cols):
            raise ReaderError(str(path), f"line {lineno}: {len(fields)} fields, need {max(cols) + 1}")
        try:
            row = [float(fields[c]) for c in cols]
        except ValueError as exc:
            raise ReaderError(str(path), f"line {lineno}: {exc}") from exc
        if not all(math.isfinite(v) for v in row):
            raise ReaderError(str(path), f"line {lineno}: NaN or infinite value")
        values.append(row)
    if not values:
        raise ReaderError(str(path), "no data rows")
    arr = np.array(values, dtype=np.float64)
    order = np.argsort(arr[:, 0], kind="stable")
    return NavTable({name: arr[order, i] for i, name in enumerate(names)})


def ddmm_to_deg(value: np.ndarray) -> np.ndarray:
    """Convert NMEA ``(d)ddmm.mmmm`` to decimal degrees."""
    value = np.asarray(value, dtype=np.float64)
    deg = np.trunc(value / 100.0)
    return deg + (value - deg * 100.0) / 60.0


_DGPS = ["time", "lat_ddmm", "lon_ddmm", "status", "altitude_m", "geoid_altitude_m", "true_course_deg",
         "magnetic_course_deg", "speed_kn", "speed_kmh"]


def load_dgps(path: str | os.PathLike) -> NavTable:
    """DGPS fixes from ``_*_DGPS.log`` or ``GTData.csv``, with added ``lat_deg`` and ``lon_deg``."""
    path = Path(path)
    table = load_table(path, _DGPS, sep="," if path.suffix.lower() == ".csv" else None)
    cols = dict(table.columns)
    cols["lat_deg"] = ddmm_to_deg(cols["lat_ddmm"])
    cols["lon_deg"] = ddmm_to_deg(cols["lon_ddmm"])
    return NavTable(cols)


def load_gt(path: str | os.PathLike) -> NavTable:
    """The ground-truth track ``GTData.csv`` (the DGPS fixes; same columns as :func:`load_dgps`)."""
    return load_dgps(path)


def load_dgps_local(path: str | os.PathLike) -> NavTable:
    """``dgps_local_EN_m.csv``: time, east_m, north_m, status."""
    return load_table(path, ["time", "east_m", "north_m", "status"], sep=",")


def load_dvl(path: str | os.PathLike) -> NavTable:
    """DVL data: ``dvlData.csv`` (m/s, radians) or the raw ``_*_DVL.log`` (converted to m/s, radians).

    Columns: time, bottom_vx, bottom_vy, bottom_vz (m/s), range1..3 (m), heading, pitch, roll (rad), and
    ``bottom_status`` (1 for a valid bottom track; ``dvlData.csv`` holds only valid rows, the raw log
    also the 84 pings with status 0, whose velocities are garbage, up to 4.6 m/s).
    """
    path = Path(path)
    names = ["time", "bottom_vx", "bottom_vy", "bottom_vz", "range1", "range2", "range3", "heading_rad",
             "pitch_rad", "roll_rad"]
    if path.suffix.lower() == ".csv":
        table = load_table(path, names, sep=",")
        return NavTable({**table.columns, "bottom_status": np.ones(len(table))})
    raw = load_table(path, names + ["bottom_status"], columns=[0, 11, 12, 13, 15, 16, 17, 22, 23, 24, 14])
    cols = dict(raw.columns)
    for k in ("bottom_vx", "bottom_vy", "bottom_vz"):
        cols[k] = cols[k] / 100.0
    for k in ("heading_rad", "pitch_rad", "roll_rad"):
        cols[k] = np.radians(cols[k])
    return NavTable(cols)


def load_mti(path: str | os.PathLike) -> NavTable:
    """``_*_MTi.log``: time, roll_deg, pitch_deg, yaw_deg (compass, ±180), rates (rad/s), accelerations."""
    names = ["time", "roll_deg", "pitch_deg", "yaw_deg", "rate_x", "rate_y", "rate_z", "acc_x", "acc_y", "acc_z"]
    return load_table(path, names)


def load_keyframe_times(path: str | os.PathLike) -> dict[int, tuple[float, float]]:
    """``keyFrameTimeStamps.csv`` as ``{key frame: (begin, end)}``."""
    table = load_table(path, ["time", "begin", "end"], sep=",")
    return {int(k): (float(b), float(e)) for k, b, e in zip(table["time"], table["begin"], table["end"])}


def load_beam_times(path: str | os.PathLike) -> NavTable:
    """``_*_IS_timestamps.log``: one row per sonar beam, ``time`` (log clock, Unix s) and ``sensor_ms``
    (the sonar's own clock, milliseconds of the UTC day)."""
    return load_table(path, ["time", "sensor_ms"])


def revolution_beam_times(beam_times: np.ndarray, begin: float, beams: int = 200) -> np.ndarray | None:
    """The ``beams`` consecutive beam times starting at a revolution's ``begin`` time (the first beam
    at or after it, within 50 ms), or None when the log has no such run."""
    start = int(np.searchsorted(beam_times, begin - 1e-3))
    if start + beams > len(beam_times) or abs(beam_times[start] - begin) > 0.05:
        return None
    return np.array(beam_times[start:start + beams], dtype=np.float64)


def mean_heading_deg(table: NavTable, start: float, end: float, column: str = "yaw_deg") -> float | None:
    """Circular mean of a compass-heading column over [start, end] (nearest sample when none inside)."""
    if len(table) == 0:
        return None
    part = table.between(start, end)
    values = part[column] if len(part) else np.array([table[column][np.argmin(np.abs(table.time - start))]])
    rad = np.radians(values)
    return math.degrees(math.atan2(np.sin(rad).mean(), np.cos(rad).mean())) % 360.0


DATASET_LOGS = ("*_DVL.log", "*_MTi.log", "dgps_local_EN_m.csv", "*_IS_timestamps.log")
"""The logs a marina survey reads, as glob patterns inside its folder (the first match of each is read)."""
KEYFRAME_TABLE = "derived_tim_pcd/keyFrameTimeStamps.csv"
KEYFRAME_CLOUD = "derived_tim_pcd/pclKeyFrame{frame}.pcd"


def dataset_problems(root: str | os.PathLike) -> list[str]:
    """What is missing or unreadable in a marina dataset folder: each log of :data:`DATASET_LOGS`, the
    key-frame table (parsed) and the point cloud of every key frame it lists; ``[]`` when complete."""
    root = Path(root)
    if not root.is_dir():
        return [f"{root}: the survey's data folder does not exist (or is not a folder)"]
    problems = [f"{root}: no file matching {pattern!r}" for pattern in DATASET_LOGS
                if not any(p.is_file() for p in root.glob(pattern))]
    table = root / KEYFRAME_TABLE
    if not table.is_file():
        return problems + [f"{table}: the key-frame time table is missing"]
    try:
        frames = load_keyframe_times(table)
    except ReaderError as exc:
        return problems + [str(exc)]
    if not frames:
        problems.append(f"{table}: lists no key frame")
    missing = [k for k in sorted(frames) if not (root / KEYFRAME_CLOUD.format(frame=k)).is_file()]
    if missing:
        shown = ", ".join(str(k) for k in missing[:5]) + (" …" if len(missing) > 5 else "")
        problems.append(f"{root / 'derived_tim_pcd'}: no point cloud for {len(missing)} key frame(s) of "
                        f"{KEYFRAME_TABLE} ({shown})")
    return problems


def dataset_files(root: str | os.PathLike) -> list[str]:
    """Every file a marina survey reads, as POSIX paths relative to ``root``, sorted.

    Raises
    ------
    ReaderError
        The folder is incomplete (:func:`dataset_problems`).
    """
    root = Path(root)
    problems = dataset_problems(root)
    if problems:
        raise ReaderError(str(root), "; ".join(problems))
    files = [sorted(p for p in root.glob(pattern) if p.is_file())[0] for pattern in DATASET_LOGS]
    files.append(root / KEYFRAME_TABLE)
    files += [root / KEYFRAME_CLOUD.format(frame=k) for k in load_keyframe_times(root / KEYFRAME_TABLE)]
    return sorted({p.relative_to(root).as_posix() for p in files})
