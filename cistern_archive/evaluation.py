"""Accuracy of placed scans against known truth (simulated sites).

The map frame is compass aligned, so a compass bias rotates the whole map and the choice of reference
scan translates it. Position errors are therefore measured after the least-squares rigid alignment
(rotation + translation, Umeyama 1991 without scale) of the estimated positions onto the true ones:
the usual absolute trajectory error of SLAM evaluations.
"""

from __future__ import annotations

import numpy as np

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


def position_errors(result: SiteResult) -> np.ndarray:
    """Distance (m) between each placed scan and its true position after rigid alignment.

    Returns an empty array when fewer than two placed scans have truth.
    """
    pairs = [((s.x_m, s.y_m), (s.truth_x_m, s.truth_y_m)) for s in result.scans
             if s.placed and s.truth_x_m is not None and s.x_m is not None]
    if len(pairs) < 2:
        return np.zeros(0)
    estimated = np.array([p[0] for p in pairs])
    truth = np.array([p[1] for p in pairs])
    rotation, translation = align_rigid_2d(estimated, truth)
    return np.linalg.norm(estimated @ rotation.T + translation - truth, axis=1)
