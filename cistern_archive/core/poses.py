"""What a localizer returns: one pose per scan, or why the scan could not be placed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Poses:
    """One pose per scan, or the reason it could not be placed.

    Attributes
    ----------
    xy_m : ndarray, shape (N, 2)
        Positions in the map frame (the reference scan at the origin); ``nan`` for unplaced scans.
    yaw_rad : ndarray, shape (N,)
        Headings (compass plus any correction).
    placed : ndarray of bool, shape (N,)
    reasons : tuple of str
        For each unplaced scan, why; empty strings for placed scans.
    reference : int
        Index of the reference scan (Table III), -1 when nothing could be placed.
    covariance : ndarray or None, shape (N, 3, 3)
        Marginal uncertainty of (x, y, yaw) when the localizer estimates it.
    """

    xy_m: np.ndarray
    yaw_rad: np.ndarray
    placed: np.ndarray
    reasons: tuple[str, ...]
    reference: int
    covariance: np.ndarray | None = None
