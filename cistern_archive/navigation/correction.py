"""A continuous track from a pose graph's solution at the scans and dead reckoning in between.

The graph solves the poses ``X_k`` at the scans' reference times ``t_k``; the dead-reckoned pose there
is ``D(t_k)``. The correction ``C_k = X_k D(t_k)^-1`` (SE(2)) is interpolated linearly in
``(x, y, theta)`` between consecutive scans and held beyond the first and last, and the corrected pose
at any time is ``C(t) D(t)``: the dead-reckoned motion between scans, bent onto the solved poses.
"""

from __future__ import annotations

import numpy as np

from cistern_archive.navigation.track import Track, se2_compose


def se2_inverse(pose: np.ndarray) -> np.ndarray:
    """``pose^-1`` for ``(x, y, yaw)``."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.array([-(c * pose[0] + s * pose[1]), s * pose[0] - c * pose[1], -pose[2]])


def corrected_positions(track: Track, node_times: np.ndarray, node_poses: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Corrected (x, y) at ``times`` (module docstring). ``node_times`` (K,) increasing, ``node_poses`` (K, 3)."""
    node_times = np.asarray(node_times, dtype=float)
    corrections = np.array([se2_compose(pose, se2_inverse(track.pose_at(t)))
                            for t, pose in zip(node_times, np.asarray(node_poses, dtype=float))])
    corrections[:, 2] = np.unwrap(corrections[:, 2])
    c = np.column_stack([np.interp(times, node_times, corrections[:, q]) for q in range(3)])
    dead = track.pose_at(np.asarray(times, dtype=float))
    return np.array([se2_compose(ck, dk)[:2] for ck, dk in zip(c, dead)])
