"""Evidence-grid mapper: placed scans fused into one log-odds grid per depth slice (Table III).

Each placed scan is moved to its pose and its inverse-sonar-model update (beam cone, free space before
the echo, echo band ``± max(bin, cell) / 2``, see :mod:`cistern_archive.grid.evidence`) is added to the
slice's :class:`~cistern_archive.grid.tiles.TiledGrid`, then the slice is clamped. Scans are grouped into
slices by depth level (:func:`~cistern_archive.core.levels.depth_levels`: sorted by depth, a scan joins
the current slice while it lies within ``depth_tolerance_m`` of the one before, so stations on an uneven
floor make one plan); a slice's depth is the mean of its scans' depths.
Where the slices lie at several depths, the echoes are corrected for the lean of their walls, read from
these first slices, and fused again (``lobe_*``, :mod:`cistern_archive.grid.lobe`: a tall vertical beam
hears a leaning wall nearer than it is). The mapper tells the runner by how much each scan's echoes fall
short there (:meth:`EvidenceGridMapper.echo_scale`, the ``EchoScaleMapper`` capability), so that the
matches between them, short by as much, are lengthened before the scans are placed for good.

Storage: the fused grid lives in fixed-size tiles allocated on touch (the paper used an octree); the
dense :class:`~cistern_archive.pipeline.contracts.EvidenceGrid` handed on is the non-zero bounding box
of the tiles. ``benchmarks/RESULTS.md`` compares time and memory with a dense array and OctoMap.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import numpy as np
from pydantic import Field

from cistern_archive.core.levels import depth_levels
from cistern_archive.grid.evidence import SonarModel, scan_window
from cistern_archive.grid.lobe import SAME_LEVEL_M, correct_for_lobe, echo_scale
from cistern_archive.grid.tiles import TiledGrid
from cistern_archive.pipeline.contracts import EchoScaleMapper, EvidenceGrid, MapResult, Poses, StageParams
from cistern_archive.core.scan import RangeScan


class GridParams(StageParams):
    """Parameters of :class:`EvidenceGridMapper`."""

    cell_m: float = Field(0.05, gt=0, description="cell size r_c (m)")
    l_occ: float = Field(0.85, gt=0, description="log-odds added at an echo")
    l_free: float = Field(-0.4, lt=0, description="log-odds added in front of an echo")
    clamp_min: float = Field(-4.0, lt=0)
    clamp_max: float = Field(4.0, gt=0)
    free_no_echo: bool = Field(False, description="beams without an echo free their cone to max range")
    beam_width_deg: float | None = Field(None, gt=0, lt=90, description="override the scans' beam width")
    depth_tolerance_m: float = Field(0.8, ge=0, description="a gap in depth wider than this between the "
                                     "scans' depths, sorted, begins a new slice (the levels of a bell-shaped "
                                     "cistern lie about 1 m apart)")
    tile_cells: int = Field(64, ge=8, le=1024, description="tile side in cells")
    pad_cells: int = Field(2, ge=0, description="unknown cells kept around the exported grid")
    lobe_correction: bool = Field(True, description="correct echo ranges on leaning walls for the vertical "
                                  "lobe where slices lie at several depths (cistern_archive.grid.lobe)")
    lobe_detection_share: float = Field(0.17, ge=0, le=1, description="elevation off the beam's axis, towards a "
                                        "leaning wall, at which its echo forms, as a share of the vertical "
                                        "beam's half width (0.17: 3° of a Micron's 35°)")
    lobe_max_lean_deg: float = Field(60.0, gt=0, lt=80, description="leans read from the slices are capped here")
    lobe_reach_m: float = Field(1.5, gt=0, description="another slice's wall farther than this from an echo "
                                "is not its wall")
    lobe_smooth_deg: float = Field(7.0, ge=0, le=45, description="corrected echoes on walls leaning 10° or "
                                   "more are averaged with those of their scan within this many degrees of "
                                   "bearing either side that hear the same wall (0: not averaged)")
    lobe_lengthen_matches: bool = Field(True, description="tell the runner each scan's echo scale on leaning "
                                        "walls, by which it lengthens the matches before placing the scans "
                                        "again (EchoScaleMapper; needs lobe_correction)")


class EvidenceGridMapper(EchoScaleMapper):
    """Log-odds evidence-grid mapper (``evidence-grid``)."""

    name: ClassVar[str] = "evidence-grid"
    Params: ClassVar[type[StageParams]] = GridParams

    def build(self, scans: Sequence[RangeScan], poses: Poses, params: StageParams) -> MapResult:
        """Fuse every placed scan into the grid of its depth slice; where the slices lie at several
        depths, fuse them again with their echoes corrected for the lean of their walls
        (:func:`cistern_archive.grid.lobe.correct_for_lobe`)."""
        p = GridParams.of(params)
        first = self.fuse(scans, poses, p)
        if not p.lobe_correction:
            return first
        corrected, leans = correct_for_lobe(scans, poses, first.grids, p.lobe_detection_share, p.lobe_max_lean_deg,
                                            p.lobe_reach_m, p.lobe_smooth_deg)
        if not leans.size:
            return first
        final = self.fuse(corrected, poses, p)
        stats = {**final.stats, "lobe_corrected_echoes": float(leans.size),
                 "lobe_median_lean_deg": float(np.median(leans))}
        return MapResult(grids=final.grids, stats=stats)

    def echo_scale(self, scans: Sequence[RangeScan], poses: Poses, params: StageParams) -> np.ndarray | None:
        """Each scan's echo range over the range of its leaning walls, read from the first slices as
        :meth:`build` reads the leans (:func:`cistern_archive.grid.lobe.echo_scale`); ``None`` with
        ``lobe_correction`` or ``lobe_lengthen_matches`` off, or the placed scans at one depth."""
        p = GridParams.of(params)
        depths = [scan.depth_m for scan, placed in zip(scans, poses.placed) if placed]
        if not (p.lobe_correction and p.lobe_lengthen_matches) or not depths or np.ptp(depths) < SAME_LEVEL_M:
            return None
        return echo_scale(scans, poses, self.fuse(scans, poses, p).grids, p.lobe_detection_share,
                          p.lobe_max_lean_deg, p.lobe_reach_m)

    @staticmethod
    def fuse(scans: Sequence[RangeScan], poses: Poses, p: GridParams) -> MapResult:
        """Every placed scan's inverse sonar model added to the tiled grid of its depth slice."""
        model = SonarModel(
            l_occ=p.l_occ, l_free=p.l_free, clamp_min=p.clamp_min, clamp_max=p.clamp_max,
            free_no_echo=p.free_no_echo,
            beam_width_rad=None if p.beam_width_deg is None else float(np.radians(p.beam_width_deg)),
        )
        placed = [k for k in range(len(scans)) if bool(poses.placed[k])]
        grids: list[EvidenceGrid] = []
        tile_bytes = 0
        n_tiles = 0
        for slice_scans in depth_slices([scans[k] for k in placed], placed, p.depth_tolerance_m):
            tiled = TiledGrid(cell_m=p.cell_m, tile=p.tile_cells)
            for k in slice_scans:
                window = scan_window(
                    scans[k], poses.xy_m[k], float(poses.yaw_rad[k]),
                    origin_xy_m=tiled.origin_xy_m, cell_m=p.cell_m, model=model,
                )
                if window is not None:
                    tiled.add_window(window)
                    tiled.clamp(p.clamp_min, p.clamp_max)
            tile_bytes += tiled.nbytes()
            n_tiles += len(tiled.tiles)
            dense, row0, col0 = tiled.to_dense(pad=p.pad_cells)
            depth = float(np.nanmean([scans[k].depth_m for k in slice_scans])) if any(
                np.isfinite(scans[k].depth_m) for k in slice_scans) else 0.0
            grids.append(
                EvidenceGrid(
                    log_odds=dense,
                    origin_xy_m=(col0 * p.cell_m, row0 * p.cell_m),
                    cell_m=p.cell_m,
                    depth_m=depth,
                )
            )
        stats = {
            "scans_fused": float(len(placed)),
            "slices": float(len(grids)),
            "tiles": float(n_tiles),
            "tile_bytes": float(tile_bytes),
        }
        return MapResult(grids=tuple(grids), stats=stats)


def depth_slices(scans: Sequence[RangeScan], indices: Sequence[int], tolerance_m: float) -> list[list[int]]:
    """Group scan indices into depth slices, shallowest first (see the module docstring); a scan of
    unknown depth counts as at 0 m."""
    depths = [float(s.depth_m) if np.isfinite(s.depth_m) else 0.0 for s in scans]
    levels = depth_levels(depths, tolerance_m)
    order = sorted(range(len(scans)), key=lambda k: (levels[k], depths[k], indices[k]))
    slices: list[list[int]] = [[] for _ in range(max(levels, default=-1) + 1)]
    for k in order:
        slices[levels[k]].append(indices[k])
    return slices
