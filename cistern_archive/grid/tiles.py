"""A sparse 2-D log-odds store: fixed-size square tiles allocated when first touched.

A 40 m gallery mapped at 0.05 m cells spans 800 × 800 cells or more in its bounding box, most of it
rock that no beam ever reaches; a dense float32 array of the box is cheap for one gallery but grows with
the square of the site's extent, while the tiles that beams touch grow with the area swept. The store
keeps ``{(tile_row, tile_col): ndarray (T, T) float32}``; indices are signed so the map can grow in
every direction from the reference scan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cistern_archive.grid.evidence import ScanWindow


@dataclass
class TiledGrid:
    """Log-odds grid made of ``tile`` × ``tile`` blocks.

    Attributes
    ----------
    cell_m : float
        Cell size; cell ``(row, col)`` covers ``(col, row) * cell_m`` to ``+ cell_m`` in the map frame.
    tile : int
        Cells per tile side.
    tiles : dict
        ``(tile_row, tile_col) -> float32 array (tile, tile)``.
    """

    cell_m: float
    tile: int = 64
    tiles: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)

    @property
    def origin_xy_m(self) -> tuple[float, float]:
        """Map position of cell (0, 0): the map origin (cells are indexed from it)."""
        return (0.0, 0.0)

    def nbytes(self) -> int:
        """Memory held by the tile arrays."""
        return sum(t.nbytes for t in self.tiles.values())

    def add_window(self, window: ScanWindow) -> None:
        """Add a scan's log-odds block; tiles whose part of the block is all zero are not allocated."""
        t = self.tile
        h, w = window.delta.shape
        r_end, c_end = window.row0 + h, window.col0 + w
        for tr in range(math.floor(window.row0 / t), math.floor((r_end - 1) / t) + 1):
            r0, r1 = max(tr * t, window.row0), min((tr + 1) * t, r_end)
            for tc in range(math.floor(window.col0 / t), math.floor((c_end - 1) / t) + 1):
                c0, c1 = max(tc * t, window.col0), min((tc + 1) * t, c_end)
                block = window.delta[r0 - window.row0 : r1 - window.row0, c0 - window.col0 : c1 - window.col0]
                if not block.any():
                    continue
                tile = self.tiles.get((tr, tc))
                if tile is None:
                    tile = self.tiles[(tr, tc)] = np.zeros((t, t), dtype=np.float32)
                tile[r0 - tr * t : r1 - tr * t, c0 - tc * t : c1 - tc * t] += block

    def clamp(self, low: float, high: float) -> None:
        """Clamp every allocated cell to ``[low, high]``."""
        for tile in self.tiles.values():
            np.clip(tile, low, high, out=tile)

    def bounds(self) -> tuple[int, int, int, int] | None:
        """(row0, row1, col0, col1), end-exclusive, of the allocated cells that are not 0."""
        if not self.tiles:
            return None
        t = self.tile
        rows, cols = [], []
        for (tr, tc), tile in self.tiles.items():
            nz_r = np.flatnonzero(tile.any(axis=1))
            nz_c = np.flatnonzero(tile.any(axis=0))
            if nz_r.size:
                rows += [tr * t + nz_r[0], tr * t + nz_r[-1] + 1]
                cols += [tc * t + nz_c[0], tc * t + nz_c[-1] + 1]
        if not rows:
            return None
        return min(rows), max(rows), min(cols), max(cols)

    def to_dense(self, pad: int = 0) -> tuple[np.ndarray, int, int]:
        """The non-zero bounding box as one dense array, plus the grid index of its cell (0, 0).

        Returns
        -------
        (array (H, W) float32, row0, col0)
        """
        b = self.bounds()
        if b is None:
            return np.zeros((0, 0), dtype=np.float32), 0, 0
        row0, row1, col0, col1 = b[0] - pad, b[1] + pad, b[2] - pad, b[3] + pad
        out = np.zeros((row1 - row0, col1 - col0), dtype=np.float32)
        t = self.tile
        for (tr, tc), tile in self.tiles.items():
            r0, c0 = tr * t, tc * t
            rr0, rr1 = max(r0, row0), min(r0 + t, row1)
            cc0, cc1 = max(c0, col0), min(c0 + t, col1)
            if rr1 > rr0 and cc1 > cc0:
                out[rr0 - row0 : rr1 - row0, cc0 - col0 : cc1 - col0] = tile[rr0 - r0 : rr1 - r0, cc0 - c0 : cc1 - c0]
        return out, row0, col0
