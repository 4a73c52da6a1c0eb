"""Dead reckoning of a vehicle from body-frame bottom velocity and heading, with covariance.

Frames: the map frame is ENU (x east, y north), yaw counter-clockwise from east (as in
:mod:`cistern_archive.core.scan`); the body frame is x forward, y to port. A body velocity ``v`` moves
the vehicle by ``R(yaw) v`` in the map frame.

Model (:func:`dead_reckon`): the heading samples (a compass, e.g. 10 Hz) set the integration grid;
the bottom velocity (e.g. a DVL at ~1.5 Hz, invalid pings removed) is linearly interpolated onto it,
multiplied by ``scale`` and rotated by ``yaw + yaw_offset``; positions are the trapezoidal integral.

Uncertainty (:meth:`Track.relative`): the pose of ``t1`` seen from ``t0`` has the covariance

* ``sigma_v**2 * tau * T`` on both axes — white velocity noise of each ping (``sigma_v``, m/s) held for
  the ping interval ``tau`` over the elapsed time ``T``;
* ``(sigma_scale * d)**2`` along the displacement ``d`` and ``(sigma_heading * d)**2`` across it — a
  scale factor error and a heading bias, both proportional to the distance travelled;
* ``2 * sigma_heading**2`` on the relative yaw (two compass readings).

The rotation of that covariance into ``t0``'s body frame makes it the noise of an odometry factor
``X_t0^-1 X_t1`` (:mod:`cistern_plugins.nav_graph`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cistern_archive.core.scan import wrap_angle


@dataclass(frozen=True)
class OdometryNoise:
    """Noise model of dead reckoning (see the module docstring).

    Attributes
    ----------
    sigma_v_mps : float
        Velocity noise of one ping.
    ping_interval_s : float
        How long one ping's velocity is held.
    sigma_scale : float
        Relative error of the velocity scale.
    sigma_heading_rad : float
        Heading error (bias over the segment and noise of one reading).
    """

    sigma_v_mps: float = 0.02
    ping_interval_s: float = 0.66
    sigma_scale: float = 0.03
    sigma_heading_rad: float = math.radians(3.0)


@dataclass(frozen=True, eq=False)
class Track:
    """A dead-reckoned trajectory.

    Attributes
    ----------
    time : ndarray, shape (N,)
        Sample times (s), increasing.
    xy_m : ndarray, shape (N, 2)
        Map-frame positions.
    yaw_rad : ndarray, shape (N,)
        Map-frame headings, unwrapped (continuous).
    distance_m : ndarray, shape (N,)
        Distance travelled since the first sample.
    noise : OdometryNoise
        The model of :meth:`relative`'s covariance.
    """

    time: np.ndarray
    xy_m: np.ndarray
    yaw_rad: np.ndarray
    distance_m: np.ndarray
    noise: OdometryNoise = OdometryNoise()

    def pose_at(self, t: float | np.ndarray) -> np.ndarray:
        """Interpolated ``(x, y, yaw)`` at time(s) ``t`` (clamped at the ends); shape (3,) or (M, 3)."""
        t = np.asarray(t, dtype=np.float64)
        out = np.stack([np.interp(t, self.time, self.xy_m[:, 0]), np.interp(t, self.time, self.xy_m[:, 1]),
                        np.interp(t, self.time, self.yaw_rad)], axis=-1)
        return out

    def relative(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """The pose at ``t1`` in the body frame at ``t0`` and its 3×3 covariance (module docstring)."""
        p0, p1 = self.pose_at(t0), self.pose_at(t1)
        delta = se2_between(p0, p1)
        d = float(abs(np.interp(t1, self.time, self.distance_m) - np.interp(t0, self.time, self.distance_m)))
        return delta, relative_covariance(delta, d, abs(t1 - t0), self.noise)


def relative_covariance(delta: np.ndarray, distance_m: float, elapsed_s: float, noise: OdometryNoise) -> np.ndarray:
    """3×3 covariance of a dead-reckoned relative pose ``delta`` after ``distance_m`` travelled in
    ``elapsed_s`` (module docstring), in the frame ``delta`` is given in."""
    white = noise.sigma_v_mps ** 2 * noise.ping_interval_s * elapsed_s
    along = math.atan2(delta[1], delta[0]) if np.hypot(delta[0], delta[1]) > 1e-9 else 0.0
    rot = _rot(along)
    cov = np.zeros((3, 3))
    cov[:2, :2] = (white + 1e-6) * np.eye(2) + rot @ np.diag([(noise.sigma_scale * distance_m) ** 2,
                                                              (noise.sigma_heading_rad * distance_m) ** 2]) @ rot.T
    cov[2, 2] = 2.0 * noise.sigma_heading_rad ** 2
    return cov


def _rot(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s], [s, c]])


def se2_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 b`` for SE(2) poses ``(x, y, yaw)``: b in the frame of a."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([c * dx + s * dy, -s * dx + c * dy, float(wrap_angle(b[2] - a[2]))])


def se2_compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a b`` for SE(2) poses ``(x, y, yaw)``: b given in the frame of a, returned in a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def dead_reckon(velocity_time: np.ndarray, body_velocity: np.ndarray, heading_time: np.ndarray,
                yaw_rad: np.ndarray, *, scale: float = 1.0, yaw_offset_rad: float = 0.0,
                start_xy: tuple[float, float] = (0.0, 0.0),
                noise: OdometryNoise = OdometryNoise()) -> Track:
    """Integrate body-frame velocities rotated by the heading (module docstring).

    Parameters
    ----------
    velocity_time : ndarray, shape (V,)
        Times of the valid velocity samples, increasing.
    body_velocity : ndarray, shape (V, 2)
        Forward and port velocity (m/s) in the body frame.
    heading_time, yaw_rad : ndarray, shape (H,)
        Heading samples: map-frame yaw (rad, CCW from east), increasing times.
    scale : float
        Factor applied to every velocity (the DVL scale calibration).
    yaw_offset_rad : float
        Added to every heading (the compass-to-body offset).
    start_xy : tuple of float
        Position at the first grid time.

    Returns
    -------
    Track
        Sampled at the heading times inside the velocity record.

    Raises
    ------
    ValueError
        Fewer than two velocity or heading samples, or no heading sample inside the velocity record.
    """
    vt = np.asarray(velocity_time, dtype=np.float64)
    v = np.asarray(body_velocity, dtype=np.float64).reshape(-1, 2)
    ht = np.asarray(heading_time, dtype=np.float64)
    if len(vt) < 2 or len(ht) < 2:
        raise ValueError("dead reckoning needs at least two velocity and two heading samples")
    grid = ht[(ht >= vt[0]) & (ht <= vt[-1])]
    if len(grid) < 2:
        raise ValueError("no heading samples inside the time span of the velocity samples")
    yaw = np.interp(grid, ht, np.unwrap(np.asarray(yaw_rad, dtype=np.float64))) + yaw_offset_rad
    vx = scale * np.interp(grid, vt, v[:, 0])
    vy = scale * np.interp(grid, vt, v[:, 1])
    ve = vx * np.cos(yaw) - vy * np.sin(yaw)
    vn = vx * np.sin(yaw) + vy * np.cos(yaw)
    dt = np.diff(grid)
    steps = np.column_stack([0.5 * (ve[1:] + ve[:-1]) * dt, 0.5 * (vn[1:] + vn[:-1]) * dt])
    xy = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)]) + np.asarray(start_xy, dtype=np.float64)
    distance = np.concatenate([[0.0], np.cumsum(np.hypot(steps[:, 0], steps[:, 1]))])
    return Track(time=grid, xy_m=xy, yaw_rad=yaw, distance_m=distance, noise=noise)
