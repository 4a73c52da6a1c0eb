"""The Girona marina survey as one object: navigation logs, per-beam sonar times, key-frame echoes.

Files (``../shared/data/marina``, see its README): ``_*_DVL.log`` (bottom velocity, ~1.5 Hz),
``_*_MTi.log`` (10 Hz attitude), ``dgps_local_EN_m.csv`` (1 Hz DGPS, east/north metres),
``_*_IS_timestamps.log`` (one row per sonar beam) and ``derived_tim_pcd/`` (one point cloud per
revolution, ``keyFrameTimeStamps.csv``).

Conventions, each with the evidence that fixed it (measured by ``benchmarks/marina.py``):

* **DVL body frame**: x forward, y to port. Dead reckoning with the DVL's own compass and no
  calibration is 17.3 m mean error over the sonar's span (``benchmarks/marina.py``); with y to
  starboard it is over 100 m (``tests/test_marina.py``).
* **Heading**: the MTi yaw is a compass heading (clockwise from north, ±180°). The DVL compass reads
  about 26° less (README); the offset that best fits the first 300 s of DGPS is about −22°
  (:func:`cistern_archive.navigation.calibration.fit_start_calibration`), so the MTi yaw is used with
  a calibrated offset.
* **Beam times**: key frame ``k`` (1-based) is 200 consecutive rows of ``_IS_timestamps.log`` starting
  at the first row at or after its begin time (every key frame starts exactly 200 rows after the
  previous one).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cistern_archive.core.errors import ReaderError
from cistern_archive.navigation.track import OdometryNoise, Track, dead_reckon
from cistern_archive.sonar import marina

BEAMS_PER_REVOLUTION = 200


@dataclass(frozen=True, eq=False)
class MarinaSurvey:
    """Navigation and sonar timing of the marina run.

    Attributes
    ----------
    root : Path
        The data directory.
    dvl : NavTable
        Valid bottom-track pings only (status 1).
    mti : NavTable
        Attitude at 10 Hz.
    dgps : NavTable
        DGPS fixes (``time``, ``east_m``, ``north_m``).
    beam_time : ndarray, shape (B,)
        Log time of every sonar beam.
    keyframes : dict of int to (float, float)
        Key frame → begin, end time.
    """

    root: Path
    dvl: marina.NavTable
    mti: marina.NavTable
    dgps: marina.NavTable
    beam_time: np.ndarray
    keyframes: dict[int, tuple[float, float]]

    @property
    def pcd_dir(self) -> Path:
        return self.root / "derived_tim_pcd"

    def keyframe_beam_times(self, frame: int) -> np.ndarray:
        """Log times of the 200 beams of key frame ``frame``, in acquisition order."""
        begin, _ = self.keyframes[frame]
        times = marina.revolution_beam_times(self.beam_time, begin, BEAMS_PER_REVOLUTION)
        if times is None:
            raise ReaderError(str(self.root), f"key frame {frame}: no run of {BEAMS_PER_REVOLUTION} beam times "
                              f"starting at {begin:.3f} s in the IS timestamps log")
        return times

    def body_velocity(self) -> tuple[np.ndarray, np.ndarray]:
        """Times and (forward, port) bottom velocities of the valid pings."""
        return self.dvl.time, np.column_stack([self.dvl["bottom_vx"], self.dvl["bottom_vy"]])

    def heading(self, source: str = "mti") -> tuple[np.ndarray, np.ndarray]:
        """Times and map-frame yaw (rad) from the MTi (``"mti"``) or the DVL's compass (``"dvl"``)."""
        if source == "mti":
            return self.mti.time, np.radians(90.0 - self.mti["yaw_deg"])
        if source == "dvl":
            return self.dvl.time, math.pi / 2 - self.dvl["heading_rad"]
        raise ValueError(f"unknown heading source {source!r}; use 'mti' or 'dvl'")

    def dead_reckoning(self, *, heading: str = "mti", scale: float = 1.0, yaw_offset_rad: float = 0.0,
                       noise: OdometryNoise = OdometryNoise()) -> Track:
        """Dead reckoning from the DVL and the chosen compass (:func:`dead_reckon`)."""
        vt, v = self.body_velocity()
        ht, yaw = self.heading(heading)
        return dead_reckon(vt, v, ht, yaw, scale=scale, yaw_offset_rad=yaw_offset_rad, noise=noise)

    def dgps_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """DGPS fix times and (east, north) positions."""
        return self.dgps.time, np.column_stack([self.dgps["east_m"], self.dgps["north_m"]])


def _one(root: Path, pattern: str) -> Path:
    found = sorted(root.glob(pattern))
    if not found:
        raise ReaderError(str(root), f"no file matching {pattern!r}")
    return found[0]


def load_marina_survey(root: str | os.PathLike) -> MarinaSurvey:
    """Load the marina logs from ``root`` (the ``marina`` data directory).

    Raises
    ------
    ReaderError
        A file is missing or malformed (naming it and the line).
    """
    root = Path(root)
    dvl = marina.load_dvl(_one(root, "*_DVL.log"))
    valid = dvl["bottom_status"] == 1
    dvl = marina.NavTable({k: v[valid] for k, v in dvl.columns.items()})
    stamps = root / "derived_tim_pcd" / "keyFrameTimeStamps.csv"
    if not stamps.is_file():
        raise ReaderError(str(stamps), "key-frame time table not found")
    return MarinaSurvey(root=root, dvl=dvl, mti=marina.load_mti(_one(root, "*_MTi.log")),
                        dgps=marina.load_dgps_local(_one(root, "dgps_local_EN_m.csv")),
                        beam_time=marina.load_beam_times(_one(root, "*_IS_timestamps.log")).time,
                        keyframes=marina.load_keyframe_times(stamps))

