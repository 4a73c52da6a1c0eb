"""The site's wall surface from the evidence: the boundary of the water the sonar saw, kept only where
walls were seen.

The paper isosurfaces the evidence volume (Sec. III-E). Cutting the occupancy probability at a level
above "unknown" wraps every occupied cell, so ghost echoes beyond the walls stand as posts and the
edges of beams that passed through a gap become tentacles. Here, per depth slice (McVicker et al.
Sec. III-D):

1. **water** is the observed free space (occupancy below ``free_below``), opened with a disc of
   ``open_m`` so that the thin wedges of single beams that slipped past a wall are cut off, and kept
   only where it is connected to a placed station of that slice: the water the vehicle was in;
2. **walls seen** are the occupied cells (above ``occupied_above``) within ``support_m`` of that water.
   Occupied cells elsewhere (behind a seen wall, or isolated in unknown space: multipath, fish, the
   tether) support nothing and leave no trace in the model; unknown space is neither wall nor water;
3. the surface is the zero set of the signed distance to the water (metres, positive outside), moved
   out by ``wall_offset_m`` (free cells end where the echo's cell begins);
4. several slices: the signed distances are interpolated linearly in depth, so a wall moves smoothly
   from one slice's outline to the next (a bell widens); one slice is extruded ``extend_m`` above and
   below (the paper's extrusion along z). The model spans the slices only: above the shallowest and
   below the deepest slice nothing was seen;
5. the surface is cut with :func:`skimage.measure.marching_cubes`; triangles at an edge of the water
   farther than ``max_gap_m / 2`` from every wall seen (marked per slice, interpolated in depth like
   the walls) are dropped: a gap in the walls narrower than ``max_gap_m`` is closed, a wider one (or
   the unseen end of a gallery) stays open rather than being invented. A gap in one slice whose
   neighbouring slices saw a wall there is closed too (:func:`seen_beside`).

The mesh is in the map frame, metres, z up (``z = -depth``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage

from cistern_archive.grid.volume import common_lattice, interpolate_layers, resample
from cistern_archive.core.grids import EvidenceGrid, MapResult
from cistern_archive.core.poses import Poses


class SurfaceParams(BaseModel):
    """How the wall surface is made from the evidence grids (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    free_below: float = Field(0.4, gt=0, lt=0.5, description="a cell is observed water below this occupancy")
    occupied_above: float = Field(0.6, gt=0.5, lt=1, description="a cell is a wall echo above this occupancy")
    open_m: float = Field(0.15, ge=0, description="radius of the opening that cuts single-beam wedges off the water")
    support_m: float = Field(0.15, gt=0, description="a wall echo supports the surface within this of the water")
    wall_offset_m: float = Field(0.025, description="the surface lies this far outside the last water cell")
    min_hole_m2: float = Field(0.1, ge=0, description="holes in the water smaller than this are filled")
    min_piece_m2: float = Field(0.25, ge=0, description="mesh pieces with less surface than this are dropped")
    max_gap_m: float = Field(0.6, ge=0, description="gaps in the seen walls narrower than this are closed")
    dz_m: float = Field(0.1, gt=0, description="vertical spacing of the volume's layers")
    extend_m: float = Field(1.0, ge=0, description="extrusion above and below a single slice")
    depth_interpolation: Literal["linear", "pchip"] = Field(
        "pchip", description="how the walls run between depth slices")
    slice_tolerance_m: float = Field(0.8, gt=0, description="stations this close in depth belong to a slice "
                                     "(a slice gathers the stations of an uneven floor; a bell's lie 1 m apart)")
    smooth_iterations: int = Field(20, ge=0, description="Taubin smoothing passes of the mesh")
    max_faces: int = Field(40_000, ge=100, description="decimate the mesh down to this many triangles")


@dataclass(frozen=True, eq=False)
class SurfaceMesh:
    """A triangle mesh of the walls.

    Attributes
    ----------
    points : ndarray, shape (N, 3), float64
        Map frame, metres, z up (``z = -depth``).
    triangles : ndarray, shape (M, 3), int64
    slice_depths_m : tuple of float
        Depths of the evidence grids it was made from.
    depth_range_m : tuple of float
        (shallowest, deepest) depth the model spans.
    """

    points: np.ndarray
    triangles: np.ndarray
    slice_depths_m: tuple[float, ...]
    depth_range_m: tuple[float, float]

    @property
    def n_triangles(self) -> int:
        return int(len(self.triangles))

    def triangle_areas(self) -> np.ndarray:
        a, b, c = (self.points[self.triangles[:, k]] for k in range(3))
        return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)

    def to_pyvista(self):
        """The mesh as a :class:`pyvista.PolyData` with the point array ``depth_m``."""
        import pyvista  # deferred: VTK loads in a second; only meshing needs it

        cells = np.column_stack([np.full(len(self.triangles), 3), self.triangles]).astype(np.int64).ravel()
        mesh = pyvista.PolyData(np.asarray(self.points, dtype=np.float64), cells)
        mesh.point_data["depth_m"] = (-mesh.points[:, 2]).astype(np.float32)
        return mesh


def _disc(radius_cells: int) -> np.ndarray:
    r = np.arange(-radius_cells, radius_cells + 1)
    return (r[:, None] ** 2 + r[None, :] ** 2) <= radius_cells ** 2


def slice_stations(grid: EvidenceGrid, poses: Poses, depths_m: Sequence[float], tolerance_m: float) -> np.ndarray:
    """Map-frame positions of the placed stations of this slice (all placed ones when none is within
    ``tolerance_m`` of its depth)."""
    placed = np.asarray(poses.placed, dtype=bool)
    near = placed & (np.abs(np.asarray(depths_m, dtype=float) - grid.depth_m) <= tolerance_m)
    pick = near if near.any() else placed
    return np.asarray(poses.xy_m, dtype=float)[pick]


def water_and_walls(probability: np.ndarray, cell_m: float, station_cells: np.ndarray,
                    params: SurfaceParams) -> tuple[np.ndarray, np.ndarray]:
    """The water the vehicle was in and the wall echoes that bound it (boolean masks of one slice)."""
    free = probability < params.free_below
    radius = int(round(params.open_m / cell_m))
    opened = ndimage.binary_opening(free, structure=_disc(radius)) if radius > 0 else free
    labels, _ = ndimage.label(opened)
    h, w = free.shape
    inside = [(r, c) for r, c in station_cells if 0 <= r < h and 0 <= c < w]
    keep = {int(labels[r, c]) for r, c in inside} - {0}
    if not keep:  # a station on a wall cell or outside the grid: the components nearest to the stations
        if not opened.any():
            return np.zeros_like(free), np.zeros_like(free)
        _, (rr, cc) = ndimage.distance_transform_edt(~opened, return_indices=True)
        keep = {int(labels[rr[r, c], cc[r, c]]) for r, c in station_cells.clip([0, 0], [h - 1, w - 1])}
    water = fill_small_holes(np.isin(labels, sorted(keep)), params.min_hole_m2 / cell_m ** 2)
    occupied = probability > params.occupied_above
    walls = occupied & (ndimage.distance_transform_edt(~water) * cell_m <= params.support_m)
    return water, walls


def slice_waters(grids: Sequence[EvidenceGrid], poses: Poses, depths_m: Sequence[float], params: SurfaceParams
                 ) -> tuple[EvidenceGrid, list[tuple[np.ndarray, np.ndarray]]]:
    """Every slice's water and walls (:func:`water_and_walls`) on the slices' common lattice, and an
    empty grid that carries that lattice."""
    origin, cell, shape = common_lattice(grids)
    lattice = EvidenceGrid(np.zeros(shape, dtype=np.float32), origin, cell, 0.0)
    pieces = []
    for grid in grids:
        stations = lattice.cell_of(slice_stations(grid, poses, depths_m, params.slice_tolerance_m))
        pieces.append(water_and_walls(resample(grid, origin, cell, shape), cell, stations, params))
    return lattice, pieces


def fill_small_holes(water: np.ndarray, max_cells: float) -> np.ndarray:
    """The water with its enclosed holes of fewer than ``max_cells`` cells filled: speckle and single
    ghost echoes inside the water would otherwise stand in the model as posts (a pillar is larger)."""
    holes, n = ndimage.label(~water)
    if n == 0:
        return water
    sizes = np.bincount(holes.ravel(), minlength=n + 1)
    border = np.unique(np.concatenate([holes[0], holes[-1], holes[:, 0], holes[:, -1]]))
    small = sizes < max_cells
    small[0] = False
    small[border] = False
    return water | small[holes]


def signed_distance(water: np.ndarray, cell_m: float) -> np.ndarray:
    """Metres from every cell centre to the water's edge: positive outside the water, negative inside."""
    if not water.any():
        return np.full(water.shape, 1e3, dtype=np.float32)
    outside = ndimage.distance_transform_edt(~water) * cell_m
    inside = ndimage.distance_transform_edt(water) * cell_m
    return (outside - inside + np.where(water, 0.5, -0.5) * cell_m).astype(np.float32)


def unseen_edges(water: np.ndarray, walls: np.ndarray, cell_m: float, reach_m: float) -> np.ndarray:
    """1 near the edges of the water that no wall seen supports (farther than ``reach_m`` from every
    wall echo: the water just ends in unknown space), 0 elsewhere; float32 for interpolation in depth."""
    edge = water & ~ndimage.binary_erosion(water, border_value=1)
    far = ndimage.distance_transform_edt(~walls) * cell_m > reach_m if walls.any() else np.ones_like(water)
    unseen = edge & far
    if not unseen.any():
        return np.zeros(water.shape, dtype=np.float32)
    return (ndimage.distance_transform_edt(~unseen) <= 2.0).astype(np.float32)


def seen_beside(unseen: np.ndarray) -> np.ndarray:
    """The unseen edges of (S, H, W) slices kept only where a neighbouring slice in depth leaves that
    place unseen too: a wall seen above and below a slice's gap bounds the water between them, so the
    model closes it rather than open a hole an archaeologist would read as a passage. One slice is
    unchanged (nothing beside it)."""
    if len(unseen) < 2:
        return unseen
    above = np.concatenate([unseen[1:2], unseen[:-1]])  # slice k - 1 (the first slice: the one below it)
    below = np.concatenate([unseen[1:], unseen[-2:-1]])  # slice k + 1 (the last slice: the one above it)
    return np.minimum(unseen, np.maximum(above, below))


def _layers(slice_depths: np.ndarray, params: SurfaceParams) -> np.ndarray:
    if len(slice_depths) == 1:
        top = max(0.0, slice_depths[0] - params.extend_m)
        bottom = slice_depths[0] + params.extend_m
    else:
        top, bottom = float(slice_depths[0]), float(slice_depths[-1])
    n = max(2, int(round((bottom - top) / params.dz_m)) + 1)
    return np.linspace(top, bottom, n)


def wall_surface(map_result: MapResult, poses: Poses, depths_m: Sequence[float],
                 params: SurfaceParams | None = None) -> SurfaceMesh | None:
    """The wall surface of a site (see the module docstring).

    Parameters
    ----------
    map_result : MapResult
        The mapper's depth slices.
    poses : Poses
        The placed stations (the water they were in is the water that counts).
    depths_m : sequence of float
        Depth of every scan (to give each slice its stations).
    params : SurfaceParams, optional

    Returns
    -------
    SurfaceMesh or None
        ``None`` when no wall was seen next to the water of any slice.
    """
    from skimage.measure import marching_cubes

    params = params or SurfaceParams()
    grids = sorted(map_result.grids, key=lambda g: g.depth_m)
    if not grids or not np.asarray(poses.placed).any():
        return None
    lattice, pieces = slice_waters(grids, poses, depths_m, params)
    origin, cell = lattice.origin_xy_m, lattice.cell_m
    if not any(walls.any() for _, walls in pieces):
        return None
    sdf = [signed_distance(water, cell) - params.wall_offset_m for water, _ in pieces]
    unseen = [unseen_edges(water, walls, cell, params.max_gap_m / 2.0) for water, walls in pieces]
    slice_depths = np.array([g.depth_m for g in grids])
    slice_depths, first = np.unique(slice_depths, return_index=True)
    sdf = np.stack([sdf[k] for k in first])
    unseen = seen_beside(np.stack([unseen[k] for k in first]))
    layers = _layers(slice_depths, params)
    volume = across_depth(sdf, slice_depths, layers, params.depth_interpolation)
    unseen_layers = interpolate_layers(unseen, slice_depths, layers)
    pad = ((0, 0), (1, 1), (1, 1))
    volume = np.pad(volume, pad, mode="constant", constant_values=1e3)
    if not (volume < 0).any():
        return None
    dz = float(layers[1] - layers[0])
    verts, faces, _, _ = marching_cubes(volume, level=0.0, spacing=(dz, cell, cell), allow_degenerate=False)
    depth = layers[0] + verts[:, 0]
    x = origin[0] + verts[:, 2] - cell + 0.5 * cell
    y = origin[1] + verts[:, 1] - cell + 0.5 * cell
    points = np.column_stack([x, y, -depth])
    faces = _supported(faces, verts, unseen_layers, cell, dz)
    if len(faces) == 0:
        return None
    points, faces = _compact(points, faces)
    points, faces = _smooth_and_decimate(points, faces, params)
    return SurfaceMesh(points=points, triangles=faces, slice_depths_m=tuple(float(d) for d in slice_depths),
                       depth_range_m=(float(layers[0]), float(layers[-1])))


def across_depth(slices: np.ndarray, slice_depths: np.ndarray, layers: np.ndarray, method: str) -> np.ndarray:
    """The signed distances of (S, H, W) slices at the layer depths: linear between neighbouring
    slices, or (``pchip``) a shape-preserving cubic through all of them (Fritsch & Carlson 1980), so
    that a bell's wall curves through its slices rather than bending at each one; one or two slices
    are always linear."""
    if method == "linear" or len(slice_depths) < 3:
        return interpolate_layers(slices, slice_depths, layers)
    from scipy.interpolate import PchipInterpolator

    inside = np.clip(layers, slice_depths[0], slice_depths[-1])
    return PchipInterpolator(slice_depths, slices, axis=0)(inside).astype(np.float32)


def _supported(faces: np.ndarray, verts: np.ndarray, unseen: np.ndarray, cell: float, dz: float) -> np.ndarray:
    """The triangles whose centroid is not at an unseen edge of the water (``unseen``, interpolated in
    depth on the unpadded lattice, below one half)."""
    centroid = verts[faces].mean(axis=1)
    k = np.clip(np.rint(centroid[:, 0] / dz).astype(int), 0, unseen.shape[0] - 1)
    r = np.clip(np.floor(centroid[:, 1] / cell).astype(int) - 1, 0, unseen.shape[1] - 1)
    c = np.clip(np.floor(centroid[:, 2] / cell).astype(int) - 1, 0, unseen.shape[2] - 1)
    return faces[unseen[k, r, c] < 0.5]


def _compact(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used, inverse = np.unique(faces.ravel(), return_inverse=True)
    return points[used], inverse.reshape(faces.shape).astype(np.int64)


def _smooth_and_decimate(points: np.ndarray, faces: np.ndarray, params: SurfaceParams) -> tuple[np.ndarray, np.ndarray]:
    """Taubin smoothing (no shrinkage) and quadric decimation, with VTK through pyvista."""
    import pyvista  # deferred: VTK loads in a second; only meshing needs it

    cells = np.column_stack([np.full(len(faces), 3), faces]).astype(np.int64).ravel()
    mesh = pyvista.PolyData(np.asarray(points, dtype=np.float64), cells)
    if params.smooth_iterations:
        mesh = mesh.smooth_taubin(n_iter=params.smooth_iterations, pass_band=0.1, boundary_smoothing=False)
    if params.min_piece_m2 > 0:
        mesh = _drop_small_pieces(mesh, params.min_piece_m2)
    if mesh.n_cells > params.max_faces:
        mesh = mesh.decimate(1.0 - params.max_faces / mesh.n_cells, volume_preservation=True)
    mesh = mesh.triangulate()
    triangles = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 4)[:, 1:]
    return np.asarray(mesh.points, dtype=np.float64), triangles


def _drop_small_pieces(mesh, min_area_m2: float):
    """Remove connected pieces of the mesh with less than ``min_area_m2`` of surface."""
    labelled = mesh.connectivity("all")
    regions = np.asarray(labelled.cell_data["RegionId"])
    areas = np.asarray(labelled.compute_cell_sizes(length=False, volume=False).cell_data["Area"])
    per_region = np.bincount(regions, weights=areas)
    keep = np.flatnonzero(per_region >= min_area_m2)
    if len(keep) == len(per_region):
        return mesh
    kept = labelled.extract_cells(np.flatnonzero(np.isin(regions, keep))).extract_surface(algorithm="dataset_surface")
    kept.clear_data()
    return kept
