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

from collections.abc import Sequence

import numpy as np

from cistern_archive.navigation.track import Track
from cistern_archive.core.scan import RangeScan, Scan


def scan_echoes(scan: Scan, *, threshold: float = 0.5, min_range_m: float = 0.0, max_gap_bins: int = 2,
                position: str = "leading") -> tuple[np.ndarray, np.ndarray]:
    """Every echo of a scan: the beam index and range of each run of bins at or above ``threshold``.

    Unlike a segmentation that keeps one range per beam, every separate return of a beam is kept (a
    beam past a pontoon sees the pontoon and the quay behind it). Bins above the threshold that are
    at most ``max_gap_bins`` apart form one echo, placed at its ``"leading"`` edge (the first bin: the
    surface facing the sonar) or its ``"centre"``; ``"bins"`` keeps every bin as its own echo. A run is one echo, not one point per bin: a wall
    seen at 30 m lights a run of bins along the beam (pulse length and beam footprint), and runs of
    points radiating from the sonar would pull a scan matcher towards zero displacement.

    Returns
    -------
    beam : ndarray of int, shape (N,)
    range_m : ndarray, shape (N,)
        Bin centres (or run centres).
    """
    above = scan.normalised() >= threshold
    beam, bins = np.nonzero(above)
    if position == "bins":
        ranges = scan.bin_centres_m[bins]
        keep = ranges >= min_range_m
        return beam[keep], ranges[keep]
    if beam.size == 0:
        return beam, np.zeros(0)
    new = np.ones(beam.size, dtype=bool)
    new[1:] = (beam[1:] != beam[:-1]) | (bins[1:] - bins[:-1] > max_gap_bins)
    first = np.flatnonzero(new)
    last = np.append(first[1:], beam.size) - 1
    if position == "leading":
        centre_bin = bins[first].astype(np.float64)
    elif position == "centre":
        centre_bin = 0.5 * (bins[first] + bins[last])
    else:
        raise ValueError(f"position must be 'leading', 'centre' or 'bins', got {position!r}")
    ranges = scan.start_range_m + (centre_bin + 0.5) * scan.bin_size_m
    keep = ranges >= min_range_m
    return beam[first][keep], ranges[keep]


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
                           min_range_m: float = 0.0, echo_position: str = "leading",
                           companions: Sequence[Scan] = ()) -> tuple[RangeScan, float]:
    """A scan's echoes (:func:`scan_echoes` with ``echo_position``), motion compensated to its
    mid-revolution time, as a :class:`RangeScan`.

    Every echo becomes one entry (bearing and range of the compensated point, so bearings repeat);
    ``yaw_rad`` is the dead-reckoned heading at the reference time, ``time_s`` that time on the
    navigation clock and ``odometry`` the dead-reckoned pose there. The echoes of ``companions`` (e.g.
    the neighbouring revolutions) are compensated into the same reference frame and added: a local
    map, as dense as several revolutions, whose shape rests on dead reckoning over their span only.
    Returns the scan and the reference time on the sonar clock.

    Raises
    ------
    ValueError
        A scan has no per-beam times.
    """
    for item in (scan, *companions):
        if item.beam_times_s is None:
            raise ValueError(f"scan {item.station or '?'} has no per-beam times; motion compensation needs them")
    reference = 0.5 * (float(scan.beam_times_s.min()) + float(scan.beam_times_s.max()))
    parts = []
    for item in (scan, *companions):
        beam, ranges = scan_echoes(item, threshold=threshold, min_range_m=min_range_m, position=echo_position)
        parts.append(compensate(body_points(item.bearings_rad[beam], ranges), item.beam_times_s[beam], track,
                                reference, clock_offset_s=clock_offset_s))
    points = np.concatenate(parts)
    odometry = track.pose_at(reference + clock_offset_s)
    range_scan = RangeScan(bearings_rad=np.arctan2(points[:, 1], points[:, 0]), ranges_m=np.hypot(points[:, 0], points[:, 1]),
                           yaw_rad=float(odometry[2]), depth_m=scan.depth_m, max_range_m=scan.max_range_m,
                           bin_size_m=scan.bin_size_m, beam_width_rad=scan.beam_width_rad, station=scan.station,
                           time_s=reference + clock_offset_s, odometry=odometry, rays_from_station=False)
    return range_scan, reference
