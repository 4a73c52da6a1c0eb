"""Errors of an estimated track against DGPS fixes: start-aligned and after the best rigid alignment.

As in Mallios et al. 2014 (Table 2), the error is the horizontal distance between the estimate and
each DGPS fix (1 Hz). *Start-aligned*: the estimate is translated so that it starts at the first fix
evaluated (its heading stays the compass's). *Rigid*: the best 2-D rotation and translation of the
whole estimate onto the fixes (:func:`cistern_archive.evaluation.align_rigid_2d`) — the absolute
trajectory error of SLAM evaluations.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cistern_archive.core.tracks import ErrorSummary
from cistern_archive.evaluation import align_rigid_2d


def start_aligned_errors(estimate_xy: np.ndarray, fixes_xy: np.ndarray) -> np.ndarray:
    """Distances after translating the estimate onto the first fix. Both (N, 2), row i at fix i's time."""
    shifted = estimate_xy + (fixes_xy[0] - estimate_xy[0])
    return np.linalg.norm(shifted - fixes_xy, axis=1)


def rigid_errors(estimate_xy: np.ndarray, fixes_xy: np.ndarray) -> np.ndarray:
    """Distances after the least-squares rigid alignment of the estimate onto the fixes."""
    rotation, translation = align_rigid_2d(estimate_xy, fixes_xy)
    return np.linalg.norm(estimate_xy @ rotation.T + translation - fixes_xy, axis=1)


def fixes_within(fix_time: np.ndarray, start: float, end: float) -> np.ndarray:
    """Mask of the fixes inside ``[start, end]``."""
    return (fix_time >= start) & (fix_time <= end)


def evaluate_track(position_at: Callable[[np.ndarray], np.ndarray], fix_time: np.ndarray, fixes_xy: np.ndarray,
                   *, start: float, end: float) -> dict[str, object]:
    """Start-aligned and rigid errors of ``position_at(times) -> (N, 2)`` at the fixes in [start, end].

    Returns
    -------
    dict
        ``time`` and ``start_aligned_errors`` / ``rigid_errors`` arrays, ``start_aligned`` and ``rigid``
        :class:`ErrorSummary`.
    """
    mask = fixes_within(fix_time, start, end)
    times, truth = fix_time[mask], fixes_xy[mask]
    estimate = np.asarray(position_at(times), dtype=float)
    aligned, rigid = start_aligned_errors(estimate, truth), rigid_errors(estimate, truth)
    return {"time": times, "start_aligned_errors": aligned, "rigid_errors": rigid,
            "start_aligned": ErrorSummary.of(aligned), "rigid": ErrorSummary.of(rigid)}
