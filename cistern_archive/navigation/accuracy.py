"""Errors of an estimated track against DGPS fixes: start-aligned and after the best rigid alignment.

As in Mallios et al. 2014 (Table 2), the error is the horizontal distance between the estimate and
each DGPS fix (1 Hz). *Start-aligned*: the estimate is translated so that it starts at the fix where
the track starts (its heading stays the compass's). *Rigid*: the best 2-D rotation and translation of
the estimate onto the evaluated fixes (:func:`cistern_archive.evaluation.align_rigid_2d`) — the
absolute trajectory error of SLAM evaluations.

Fixes the estimate was calibrated on (a vehicle's first minutes at the surface) are not independent of
it: the errors are summarised, and the rigid alignment fitted, over the fixes after that window only
(``evaluated_from`` of :func:`evaluate_track`); the errors at every fix of the span are kept for the
figures.
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


def rigid_errors(estimate_xy: np.ndarray, fixes_xy: np.ndarray, fitted: np.ndarray | None = None) -> np.ndarray:
    """Distances after the least-squares rigid alignment of the estimate onto the fixes (onto the fixes
    of the mask ``fitted`` only, when given; the distances are those at every fix)."""
    fit = slice(None) if fitted is None else fitted
    rotation, translation = align_rigid_2d(estimate_xy[fit], fixes_xy[fit])
    return np.linalg.norm(estimate_xy @ rotation.T + translation - fixes_xy, axis=1)


def fixes_within(fix_time: np.ndarray, start: float, end: float) -> np.ndarray:
    """Mask of the fixes inside ``[start, end]``."""
    return (fix_time >= start) & (fix_time <= end)


def independent_after(fix_time: np.ndarray, start: float, end: float, calibration_end: float) -> float | None:
    """``evaluated_from`` for :func:`evaluate_track`: the calibration window's end, or ``None`` when no fix
    of the span [start, end] lies after it (a short run inside the window: its errors then count every
    fix and are not independent of a calibrated estimate, which the report says)."""
    return calibration_end if bool(np.any(fixes_within(fix_time, start, end) & (fix_time > calibration_end))) else None


def evaluate_track(position_at: Callable[[np.ndarray], np.ndarray], fix_time: np.ndarray, fixes_xy: np.ndarray,
                   *, start: float, end: float, evaluated_from: float | None = None) -> dict[str, object]:
    """Start-aligned and rigid errors of ``position_at(times) -> (N, 2)`` at the fixes in [start, end],
    summarised over those after ``evaluated_from`` (module docstring; all of them when it is ``None``).

    Returns
    -------
    dict
        ``time``, ``start_aligned_errors`` and ``rigid_errors`` at every fix of the span, ``evaluated``
        (the mask of the fixes summarised), and the ``start_aligned`` and ``rigid``
        :class:`ErrorSummary` over them.

    Raises
    ------
    ValueError
        No fix lies in the span after ``evaluated_from``.
    """
    mask = fixes_within(fix_time, start, end)
    times, truth = fix_time[mask], fixes_xy[mask]
    evaluated = times > evaluated_from if evaluated_from is not None else np.ones(len(times), dtype=bool)
    if not evaluated.any():
        raise ValueError("no DGPS fix to evaluate after the calibration window")
    estimate = np.asarray(position_at(times), dtype=float)
    aligned, rigid = start_aligned_errors(estimate, truth), rigid_errors(estimate, truth, evaluated)
    return {"time": times, "start_aligned_errors": aligned, "rigid_errors": rigid, "evaluated": evaluated,
            "start_aligned": ErrorSummary.of(aligned[evaluated]), "rigid": ErrorSummary.of(rigid[evaluated])}
