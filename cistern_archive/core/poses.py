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
    group_links : tuple of (int, int)
        Pairs of scans whose groups the localizer joined by fitting the groups as wholes, where no match
        of any two of their scans could (``site-graph``'s group fits); each pair is the two scans that
        lie nearest each other across the join.
    group_link_radius95_m : tuple of float
        For each group link, the radius (m) within which the second scan's position relative to the first
        lies with 95 % probability, from the localizer's joint covariance (``nan`` when it estimates none):
        how well the join places the two groups against each other.
    """

    xy_m: np.ndarray
    yaw_rad: np.ndarray
    placed: np.ndarray
    reasons: tuple[str, ...]
    reference: int
    covariance: np.ndarray | None = None
    group_links: tuple[tuple[int, int], ...] = ()
    group_link_radius95_m: tuple[float, ...] = ()
