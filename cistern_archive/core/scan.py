"""The scan model shared by every reader, the simulator and the pipeline.

Frames and angles
-----------------
* The **map frame** is a local, right-handed, metric frame with x towards east and y towards north
  (ENU). Angles in it are counter-clockwise from +x, in radians.
* A scan's ``yaw_rad`` is the vehicle heading in the map frame (counter-clockwise from +x). A compass
  heading ``h`` (degrees clockwise from north) converts as ``yaw = radians(90 - h)``;
  :func:`yaw_from_compass_deg` does it.
* ``bearings_rad`` are beam directions in the **sonar frame**: counter-clockwise from the vehicle's
  forward axis, seen from above. A beam therefore points at ``yaw_rad + bearing`` in the map frame.
  Readers convert the device's own convention (Tritech heads count clockwise) into this one.
* Bin ``k`` of a beam covers ranges ``start_range_m + k * bin_size_m`` to ``+ bin_size_m``; its centre is
  reported by :attr:`Scan.bin_centres_m`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


def yaw_from_compass_deg(heading_deg: float) -> float:
    """Convert a compass heading (degrees clockwise from north) to a map-frame yaw (rad, CCW from east)."""
    return math.radians(90.0 - heading_deg)


def compass_deg_from_yaw(yaw_rad: float) -> float:
    """Inverse of :func:`yaw_from_compass_deg`, wrapped to [0, 360)."""
    return (90.0 - math.degrees(yaw_rad)) % 360.0


def wrap_angle(angle: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi if isinstance(angle, np.ndarray) else (
        (angle + math.pi) % (2 * math.pi) - math.pi
    )


VERTICAL_BEAM_WIDTH_RAD = math.radians(35.0)
"""A Micron-class head's beam width in elevation, where a scan does not say otherwise."""


@dataclass(frozen=True, eq=False)
class Scan:
    """One stationary sweep of a mechanically scanned imaging sonar.

    Attributes
    ----------
    bearings_rad : ndarray, shape (A,)
        Beam bearings in the sonar frame (see module docstring), in acquisition order.
    intensities : ndarray, shape (A, B)
        Echo intensities, one row per beam, in device units (0 .. ``full_scale``).
    full_scale : float
        The device's maximum intensity (255 for 8-bit data, 15 for 4-bit, 65535 for 16-bit).
    bin_size_m : float
        Length of one range bin.
    start_range_m : float
        Range at the start of bin 0.
    yaw_rad : float
        Vehicle heading in the map frame during the sweep (rad, CCW from east).
    depth_m : float
        Depth of the sonar head (positive down).
    timestamp : float
        Start time of the sweep, seconds since the Unix epoch (UTC); ``nan`` when unknown.
    sonar_model : str
        Device name, e.g. ``"Tritech Micron DST"``.
    beam_width_rad : float
        Horizontal beam width.
    vertical_beam_width_rad : float
        The beam's width in elevation (35° on a Micron, the default).
    station : str
        Station label (where the vehicle landed for this sweep).
    settings : dict
        Device settings as recorded (JSON-serialisable values only).
    beam_times_s : ndarray, shape (A,), or None
        Time of every beam (Unix s, UTC), for a sonar on a moving vehicle; ``None`` for a stationary
        sweep, whose beams all share :attr:`timestamp`.
    """

    bearings_rad: np.ndarray
    intensities: np.ndarray
    full_scale: float
    bin_size_m: float
    start_range_m: float = 0.0
    yaw_rad: float = 0.0
    depth_m: float = 0.0
    timestamp: float = float("nan")
    sonar_model: str = "unknown"
    beam_width_rad: float = math.radians(3.0)
    vertical_beam_width_rad: float = VERTICAL_BEAM_WIDTH_RAD
    station: str = ""
    settings: dict[str, Any] = field(default_factory=dict)
    beam_times_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        bearings = np.asarray(self.bearings_rad, dtype=np.float64)
        intensities = np.asarray(self.intensities)
        if self.beam_times_s is not None:
            times = np.asarray(self.beam_times_s, dtype=np.float64)
            if times.shape != bearings.shape:
                raise ValueError(f"beam_times_s must have one time per beam {bearings.shape}, got {times.shape}")
            if not np.all(np.isfinite(times)):
                raise ValueError("beam_times_s contains NaN or infinite values")
            times.setflags(write=False)
            object.__setattr__(self, "beam_times_s", times)
        if bearings.ndim != 1:
            raise ValueError(f"bearings_rad must be 1-D, got shape {bearings.shape}")
        if intensities.ndim != 2 or intensities.shape[0] != bearings.shape[0]:
            raise ValueError(
                f"intensities must be (beams, bins) = ({bearings.shape[0]}, B), got {intensities.shape}"
            )
        if not np.all(np.isfinite(bearings)):
            raise ValueError("bearings_rad contains NaN or infinite values")
        if not (self.bin_size_m > 0 and math.isfinite(self.bin_size_m)):
            raise ValueError(f"bin_size_m must be a positive finite number, got {self.bin_size_m}")
        if not (self.full_scale > 0):
            raise ValueError(f"full_scale must be positive, got {self.full_scale}")
        bearings.setflags(write=False)
        intensities.setflags(write=False)
        object.__setattr__(self, "bearings_rad", bearings)
        object.__setattr__(self, "intensities", intensities)

    @property
    def n_beams(self) -> int:
        return int(self.intensities.shape[0])

    @property
    def n_bins(self) -> int:
        return int(self.intensities.shape[1])

    @property
    def bin_centres_m(self) -> np.ndarray:
        """Range of the centre of every bin, shape (B,)."""
        return self.start_range_m + (np.arange(self.n_bins) + 0.5) * self.bin_size_m

    @property
    def max_range_m(self) -> float:
        return self.start_range_m + self.n_bins * self.bin_size_m

    def normalised(self) -> np.ndarray:
        """Intensities scaled to 0..1 by the device's full scale (float32)."""
        return (np.asarray(self.intensities, dtype=np.float32) / np.float32(self.full_scale)).clip(0, 1)

    def replace(self, **changes: Any) -> "Scan":
        """A copy with some fields changed."""
        values = {name: getattr(self, name) for name in self.__dataclass_fields__}
        values.update(changes)
        return Scan(**values)


@dataclass(frozen=True, eq=False)
class RangeScan:
    """A segmented scan: one range (or none) per beam; what matchers and mappers consume.

    Attributes
    ----------
    bearings_rad : ndarray, shape (A,)
        Beam bearings in the sonar frame.
    ranges_m : ndarray, shape (A,)
        Range to the wall echo of each beam; ``nan`` where the beam saw no wall.
    yaw_rad, depth_m : float
        Heading and depth, as in :class:`Scan`.
    max_range_m : float
        The sonar's range setting (beams with no echo saw free space up to here).
    bin_size_m, beam_width_rad : float
        Radial and angular resolution, used by inverse sensor models.
    station : str
        Station label.
    vertical_beam_width_rad : float
        The beam's width in elevation, as in :class:`Scan`.
    time_s : float
        Reference time (Unix s): when a stationary scan was recorded (its :attr:`Scan.timestamp`), or
        the time a moving vehicle's echoes are motion compensated to; ``nan`` when unknown.
    odometry : ndarray, shape (3,), or None
        Dead-reckoned ``(x, y, yaw)`` of the vehicle at ``time_s`` (map frame), for localizers that
        use navigation (``nav-graph``); ``None`` without navigation.
    detection_range_m : float
        How far the segmentation could tell a wall from the receiver's noise: beyond it the noise,
        lifted by the time-varying gain, passes the detection threshold by itself on most beams
        (:func:`cistern_archive.sonar.segmentation.noise_limited`), or where the range leaves too little
        water behind a wall to see its shadow (:func:`cistern_archive.sonar.segmentation.last_testable_bin`),
        so a beam that heard nothing there says nothing about walls. ``inf`` when it is not known.
    rays_from_station : bool
        Whether every echo was heard on a beam from the station, so that the water between the station
        and the echo was seen empty (a stationary scan). ``False`` for a cloud of echoes a moving
        vehicle heard from along its track, compensated into one frame
        (:func:`cistern_archive.navigation.motion.compensated_range_scan`): the line from the station to
        an echo was no beam's, and says nothing of the water on it.
    """

    bearings_rad: np.ndarray
    ranges_m: np.ndarray
    yaw_rad: float
    depth_m: float
    max_range_m: float
    bin_size_m: float
    beam_width_rad: float
    station: str = ""
    vertical_beam_width_rad: float = VERTICAL_BEAM_WIDTH_RAD
    time_s: float = float("nan")
    odometry: np.ndarray | None = None
    detection_range_m: float = float("inf")
    rays_from_station: bool = True

    def __post_init__(self) -> None:
        bearings = np.asarray(self.bearings_rad, dtype=np.float64)
        ranges = np.asarray(self.ranges_m, dtype=np.float64)
        if bearings.shape != ranges.shape or bearings.ndim != 1:
            raise ValueError(f"bearings {bearings.shape} and ranges {ranges.shape} must be equal 1-D shapes")
        bearings.setflags(write=False)
        ranges.setflags(write=False)
        object.__setattr__(self, "bearings_rad", bearings)
        object.__setattr__(self, "ranges_m", ranges)
        if self.odometry is not None:
            odometry = np.asarray(self.odometry, dtype=np.float64)
            if odometry.shape != (3,) or not np.all(np.isfinite(odometry)):
                raise ValueError(f"odometry must be three finite numbers (x, y, yaw), got {self.odometry!r}")
            odometry.setflags(write=False)
            object.__setattr__(self, "odometry", odometry)

    @property
    def valid(self) -> np.ndarray:
        """Mask of beams that have a range."""
        return np.isfinite(self.ranges_m)

    def points(self, *, yaw_rad: float | None = None) -> np.ndarray:
        """Echo positions relative to the sonar, rotated by ``yaw_rad`` (default: the scan's own yaw).

        Returns
        -------
        ndarray, shape (N, 2)
            x, y of every beam with a range, in metres; the map-frame orientation when ``yaw_rad`` is the
            heading, the sonar frame when it is 0.
        """
        yaw = self.yaw_rad if yaw_rad is None else yaw_rad
        mask = self.valid
        angles = self.bearings_rad[mask] + yaw
        r = self.ranges_m[mask]
        return np.column_stack([r * np.cos(angles), r * np.sin(angles)])
