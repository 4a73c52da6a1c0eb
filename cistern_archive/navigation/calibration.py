"""Calibration of dead reckoning at the surface: DVL scale and compass offset from early DGPS fixes.

A vehicle that starts its mission at the surface sees DGPS for a while. Over that window a constant
compass offset ``delta`` and a DVL scale ``s`` turn the uncalibrated dead-reckoned track ``p(t)``
(started at the origin) into ``s R(delta) p(t)`` — exactly, since the offset rotates every increment
alike. The least-squares fit of that similarity onto the fixes ``q(t) - q(t_0)`` has a closed form:
with complex numbers ``z = sum(conj(p) q) / sum(|p|^2)``, ``s = |z|`` and ``delta = arg z``.
Only the fixes inside the window are used; everything after it is evaluated, never fitted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cistern_archive.navigation.track import Track


@dataclass(frozen=True)
class Calibration:
    """Compass offset (added to the map-frame yaw, rad), DVL scale, and the fit's support: the window's
    first time (``start_s``, navigation clock) and length, its fixes and the distance travelled in it."""

    yaw_offset_rad: float
    scale: float
    window_s: float
    fixes: int
    distance_m: float
    start_s: float

    @property
    def end_s(self) -> float:
        """The window's last time: every fix after it is independent of the calibration."""
        return self.start_s + self.window_s

    def as_dict(self) -> dict[str, float]:
        return {"compass_offset_deg": round(-math.degrees(self.yaw_offset_rad), 3), "dvl_scale": round(self.scale, 4),
                "window_s": self.window_s, "fixes": self.fixes, "distance_m": round(self.distance_m, 2)}


def fit_start_calibration(track: Track, fix_time: np.ndarray, fixes_xy: np.ndarray, *,
                          window_s: float = 300.0) -> Calibration:
    """Fit offset and scale of an uncalibrated ``track`` on the fixes of its first ``window_s`` seconds.

    Raises
    ------
    ValueError
        Fewer than two fixes in the window, or no motion in it.
    """
    start = max(float(fix_time[0]), float(track.time[0]))
    mask = (fix_time >= start) & (fix_time <= start + window_s) & (fix_time <= track.time[-1])
    if mask.sum() < 2:
        raise ValueError(f"calibration needs two DGPS fixes in the first {window_s} s of the track")
    estimate = track.pose_at(fix_time[mask])[:, :2]
    p = (estimate[:, 0] - estimate[0, 0]) + 1j * (estimate[:, 1] - estimate[0, 1])
    q = (fixes_xy[mask, 0] - fixes_xy[mask][0, 0]) + 1j * (fixes_xy[mask, 1] - fixes_xy[mask][0, 1])
    power = float(np.sum(np.abs(p) ** 2))
    if power < 1e-6:
        raise ValueError("the vehicle did not move during the calibration window")
    z = np.sum(np.conj(p) * q) / power
    distance = float(np.interp(start + window_s, track.time, track.distance_m) - np.interp(start, track.time, track.distance_m))
    return Calibration(yaw_offset_rad=float(np.angle(z)), scale=float(np.abs(z)), window_s=window_s,
                       fixes=int(mask.sum()), distance_m=distance, start_s=start)
