"""Depth levels: which scans of a site lie at one depth, and so see the same walls.

A level is a run of depths, sorted, each within a tolerance of the next (single linkage). Stations that
landed on an uneven floor, each near the next in depth, share one level however far the shallowest lies
from the deepest; the levels of a bell-shaped cistern, scanned about 1 m apart, stay apart. The
localizer matches only scans of one level, and the mapper fuses each level into one grid.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def depth_levels(depths_m: Sequence[float], tolerance_m: float) -> tuple[int, ...]:
    """The depth level of each depth (module docstring), numbered from the shallowest; ``-1`` for an
    unknown (non-finite) depth.

    Parameters
    ----------
    depths_m : sequence of float
        One depth per scan, metres.
    tolerance_m : float
        A gap wider than this between consecutive sorted depths begins a new level.

    Returns
    -------
    tuple of int
        The level of each depth, in the order given.
    """
    depths = [float(d) for d in depths_m]
    order = sorted((d, k) for k, d in enumerate(depths) if math.isfinite(d))
    levels = [-1] * len(depths)
    level, last = -1, -math.inf
    for depth, k in order:
        if depth - last > tolerance_m:
            level += 1
        levels[k], last = level, depth
    return tuple(levels)
