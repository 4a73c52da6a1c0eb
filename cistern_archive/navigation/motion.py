"""Motion compensation: every echo moved into the vehicle's body frame at its scan's reference time.

A mechanically scanned sonar on a moving vehicle takes a revolution over many seconds (13.8 s in the
Girona marina, 2.6 m of travel). Echo ``e`` of beam ``b`` at range ``r`` was measured at the beam's
time ``t_b`` from the pose ``P(t_b)``; in the body frame at the reference time ``t_ref`` it lies at

    ``q_e = P(t_ref)^-1 P(t_b) (r cos(beta_b), r sin(beta_b))``

with ``beta_b`` the beam's bearing in the body frame (Hernández et al. 2009, the MSISpIC
"scan forming" step; here with the dead-reckoned poses of :class:`~cistern_archive.navigation.track.Track`).
The sonar's timestamps are shifted by ``clock_offset_s`` onto the navigation clock first.
"""

from __future__ import annotations

import numpy as np

from cistern_archive.navigation.track import Track
from cistern_archive.sonar.scan import RangeScan, Scan


def scan_echoes(scan: Scan, *, threshold: float = 0.5, min_range_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Every echo of a scan: beam index and range of each bin at or above ``threshold`` (0–1 scale).

    Unlike a segmentation that keeps one range per beam, this keeps every bin above the threshold (a
    beam through a pontoon sees the pontoon and the quay behind it).

    Returns
    -------
    beam : ndarray of int, shape (N,)
    range_m : ndarray, shape (N,)
        Bin centres.
    """
    beam, bins = np.nonzero(scan.normalised() >= threshold)
    ranges = scan.bin_centres_m[bins]
    keep = ranges >= min_range_m
    return beam[keep], ranges[keep]


def body_points(bearings_rad: np.ndarray, ranges_m: np.ndarray) -> np.ndarray:
    """(N, 2) echo positions in the body frame from bearings and ranges."""
    return np.column_stack([ranges_m * np.cos(bearings_rad), ranges_m * np.sin(bearings_rad)])


def transform_points(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (N, 2) given in the frames of poses (N, 3) or one pose (3,), expressed in the parent frame."""
    poses = np.broadcast_to(np.asarray(poses, dtype=np.float64), (len(points), 3))
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.column_stack([poses[:, 0] + c * points[:, 0] - s * points[:, 1],
                            poses[:, 1] + s * points[:, 0] + c * points[:, 1]])


def inverse_transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (N, 2) of the parent frame expressed in the frame of ``pose`` (3,)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = points[:, 0] - pose[0], points[:, 1] - pose[1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy])


def compensate(points_body: np.ndarray, echo_times_s: np.ndarray, track: Track, reference_time_s: float,
               *, clock_offset_s: float = 0.0) -> np.ndarray:
    """Move echoes from their own body frames into the body frame at ``reference_time_s`` (module
    docstring); ``echo_times_s`` and ``reference_time_s`` are on the sonar clock."""
    poses = track.pose_at(np.asarray(echo_times_s, dtype=np.float64) + clock_offset_s)
    world = transform_points(poses, np.asarray(points_body, dtype=np.float64).reshape(-1, 2))
    return inverse_transform_points(track.pose_at(reference_time_s + clock_offset_s), world)


def compensated_range_scan(scan: Scan, track: Track, *, clock_offset_s: float = 0.0, threshold: float = 0.5,
                           min_range_m: float = 0.0) -> tuple[RangeScan, float]:
    """A scan's echoes, motion compensated to its mid-revolution time, as a :class:`RangeScan`.

    Every echo becomes one entry (bearing and range of the compensated point, so bearings repeat);
    ``yaw_rad`` is the dead-reckoned heading at the reference time. Returns the scan and that time
    (sonar clock).

    Raises
    ------
    ValueError
        The scan has no per-beam times.
    """
    if scan.beam_times_s is None:
        raise ValueError(f"scan {scan.station or '?'} has no per-beam times; motion compensation needs them")
    beam, ranges = scan_echoes(scan, threshold=threshold, min_range_m=min_range_m)
    times = scan.beam_times_s
    reference = 0.5 * (float(times.min()) + float(times.max()))
    points = compensate(body_points(scan.bearings_rad[beam], ranges), times[beam], track, reference,
                        clock_offset_s=clock_offset_s)
    yaw = float(track.pose_at(reference + clock_offset_s)[2])
    range_scan = RangeScan(bearings_rad=np.arctan2(points[:, 1], points[:, 0]), ranges_m=np.hypot(points[:, 0], points[:, 1]),
                           yaw_rad=yaw, depth_m=scan.depth_m, max_range_m=scan.max_range_m,
                           bin_size_m=scan.bin_size_m, beam_width_rad=scan.beam_width_rad, station=scan.station)
    return range_scan, reference
