"""The window of a localizer's guess for the local matchers: where they start, and what they may return.

A :class:`~cistern_archive.pipeline.contracts.MatchGuess` says where the localizer's solution so far
(or the vehicle's odometry) puts scan ``j`` relative to scan ``i``: a square ``±radius_m`` around its
offset and a heading correction. A search matcher (``correlative``, ``pf-pairwise``) searches that
square; a local one (``icp``, ``particle-icp``) starts from the guess instead of the compass-aligned
zero pose, and an estimate that slid out of the square is refused — it settled on walls that the
solution places elsewhere, as a search confined to the square could not have.
"""

from __future__ import annotations

import numpy as np

from cistern_archive.core.scan import wrap_angle
from cistern_archive.pipeline.contracts import MatchGuess


def start_pose(guess: MatchGuess | None) -> np.ndarray:
    """The pose ``(x, y, theta)`` a local matcher starts from: the guess's offset and heading correction,
    or the compass-aligned zero pose without a guess."""
    if guess is None:
        return np.zeros(3)
    return np.array([guess.dx_m, guess.dy_m, guess.dyaw_rad], dtype=np.float64)


def outside_window(pose: np.ndarray, guess: MatchGuess | None) -> str:
    """Why an estimate is refused for lying outside the guess's square, or ``""`` (always without a
    guess)."""
    if guess is None:
        return ""
    off = max(abs(float(pose[0]) - guess.dx_m), abs(float(pose[1]) - guess.dy_m))
    if off <= guess.radius_m:
        return ""
    return (f"estimate ({pose[0]:.2f}, {pose[1]:.2f}) m left the ±{guess.radius_m:g} m window around the guess "
            f"({guess.dx_m:.2f}, {guess.dy_m:.2f}) by {off - guess.radius_m:.2f} m")


def turn_from_start(pose: np.ndarray, guess: MatchGuess | None) -> float:
    """The estimate's heading correction less the one it started from (:func:`start_pose`), wrapped."""
    return float(wrap_angle(float(pose[2]) - float(start_pose(guess)[2])))
