"""Accuracy of placed scans against known truth (simulated sites).

The map frame is compass aligned, so a compass bias rotates the whole map and the choice of reference
scan translates it. Position errors are therefore measured after the least-squares rigid alignment
(rotation + translation, Umeyama 1991 without scale) of the estimated positions onto the true ones:
the usual absolute trajectory error of SLAM evaluations.

The benchmarks also report errors without alignment, in the frame the map is drawn in: truth offsets
rotated by the reference scan's compass error (:func:`in_compass_frame`, :func:`reference_frame_errors`).
"""

from __future__ import annotations

import math

import numpy as np

from cistern_archive.pipeline.contracts import Poses
from cistern_archive.pipeline.results import SiteResult


def align_rigid_2d(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation ``R`` (2×2) and translation ``t`` minimising ``sum |R @ s + t - q|^2``.

    Parameters
    ----------
    source, target : ndarray, shape (N, 2)
        Corresponding points; N ≥ 1 (with N = 1 the rotation is the identity).
    """
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    if len(source) < 2:
        return np.eye(2), mu_t - mu_s
    cov = (target - mu_t).T @ (source - mu_s)
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    rotation = u @ np.diag([1.0, d]) @ vt
    return rotation, mu_t - rotation @ mu_s


def scan_position_errors(result: SiteResult) -> dict[int, float]:
    """Position in ``result.scans`` → distance (m) between that placed scan and its true position after
    rigid alignment; only placed scans with truth appear, and none when fewer than two have it.
    """
    scans = {k: s for k, s in enumerate(result.scans)
             if s.placed and s.truth_x_m is not None and s.x_m is not None}
    errors = aligned_errors(np.array([(s.x_m, s.y_m) for s in scans.values()]).reshape(-1, 2),
                            np.array([(s.truth_x_m, s.truth_y_m) for s in scans.values()]).reshape(-1, 2))
    return {k: float(e) for k, e in zip(scans, errors)}


def aligned_positions(estimated_xy_m: np.ndarray, true_xy_m: np.ndarray) -> np.ndarray:
    """The estimated positions (N, 2) moved by the rigid alignment of all of them onto the true ones
    (:func:`align_rigid_2d`)."""
    estimated = np.asarray(estimated_xy_m, dtype=float)
    rotation, translation = align_rigid_2d(estimated, true_xy_m)
    return estimated @ rotation.T + translation


def aligned_errors(estimated_xy_m: np.ndarray, true_xy_m: np.ndarray) -> np.ndarray:
    """Distance (m) of each estimated position from its true one after the rigid alignment of all of
    them onto the truth (:func:`aligned_positions`); empty when there are fewer than two.

    Parameters
    ----------
    estimated_xy_m, true_xy_m : ndarray, shape (N, 2)
    """
    truth = np.asarray(true_xy_m, dtype=float)
    if len(truth) < 2:
        return np.zeros(0)
    return np.linalg.norm(aligned_positions(estimated_xy_m, truth) - truth, axis=1)


def position_errors(result: SiteResult) -> np.ndarray:
    """Distance (m) between each placed scan and its true position after rigid alignment.

    Returns an empty array when fewer than two placed scans have truth.
    """
    return np.array(list(scan_position_errors(result).values()), dtype=float)


def in_compass_frame(offset_xy_m: np.ndarray, compass_error_rad: float) -> np.ndarray:
    """A true offset (m, shape (2,)) as a scan with this compass error (measured − true yaw) sees it."""
    c, s = math.cos(compass_error_rad), math.sin(compass_error_rad)
    x, y = offset_xy_m
    return np.array([c * x - s * y, s * x + c * y])


def reference_frame_errors(poses: Poses, true_xy_m: np.ndarray, compass_error_rad: np.ndarray) -> list[float]:
    """Distance (m) between each placed scan and its true offset from the reference scan, expressed in the
    reference scan's compass frame (no alignment); empty when no scan is the reference.

    Parameters
    ----------
    poses : Poses
        The localizer's output.
    true_xy_m : ndarray, shape (N, 2)
        True station positions.
    compass_error_rad : array_like, shape (N,)
        Measured minus true yaw of every scan.
    """
    ref = poses.reference
    if ref < 0:
        return []
    errors = []
    for k in np.flatnonzero(poses.placed):
        expected = in_compass_frame(true_xy_m[k] - true_xy_m[ref], compass_error_rad[ref])
        errors.append(float(np.hypot(*(poses.xy_m[k] - expected))))
    return errors


WILSON_Z95 = 1.959963984540054


def wilson_interval(successes: int, trials: int, z: float = WILSON_Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial rate ``successes / trials`` (95 % for the default ``z``).

    Wilson (1927): the bounds ``(p + z²/2n ± z sqrt(p(1-p)/n + z²/4n²)) / (1 + z²/n)``; unlike the normal
    approximation it stays inside [0, 1] and is not empty at 0 or ``trials`` successes. ``(nan, nan)``
    when there are no trials.
    """
    if trials <= 0:
        return float("nan"), float("nan")
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must be within 0..{trials}, got {successes}")
    p = successes / trials
    z2 = z * z
    centre = p + z2 / (2 * trials)
    half = z * math.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials))
    scale = 1 + z2 / trials
    low = 0.0 if successes == 0 else max(0.0, (centre - half) / scale)
    high = 1.0 if successes == trials else min(1.0, (centre + half) / scale)
    return low, high


def strict_json(value):
    """The same structure with NaN and infinities as ``None`` (JSON ``null``), tuples as lists."""
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
