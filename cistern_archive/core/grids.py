"""What a mapper returns: log-odds evidence grids, one per depth slice."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class EvidenceGrid:
    """A 2-D log-odds evidence grid of one depth slice.

    Attributes
    ----------
    log_odds : ndarray, shape (H, W), float32
        Row ``r``, column ``c`` is the cell whose lower-left corner is
        ``origin_xy_m + (c, r) * cell_m``; 0 means unknown, > 0 occupied, < 0 free.
    origin_xy_m : tuple of float
        Map-frame position of the lower-left corner of cell (0, 0).
    cell_m : float
        Cell size r_c.
    depth_m : float
        Depth of the slice.
    """

    log_odds: np.ndarray
    origin_xy_m: tuple[float, float]
    cell_m: float
    depth_m: float

    def probability(self) -> np.ndarray:
        """Occupancy probability of every cell."""
        return 1.0 / (1.0 + np.exp(-self.log_odds.astype(np.float64)))

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """Integer (row, col) of map-frame points, shape (..., 2); may fall outside the grid."""
        xy = np.asarray(xy, dtype=np.float64)
        col = np.floor((xy[..., 0] - self.origin_xy_m[0]) / self.cell_m).astype(np.int64)
        row = np.floor((xy[..., 1] - self.origin_xy_m[1]) / self.cell_m).astype(np.int64)
        return np.stack([row, col], axis=-1)

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the grid in the map frame."""
        h, w = self.log_odds.shape
        x0, y0 = self.origin_xy_m
        return (x0, x0 + w * self.cell_m, y0, y0 + h * self.cell_m)


@dataclass(frozen=True, eq=False)
class MapResult:
    """The mapper's output: one evidence grid per depth slice, shallowest first."""

    grids: tuple[EvidenceGrid, ...]
    stats: dict[str, float] = field(default_factory=dict)
