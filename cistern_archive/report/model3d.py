"""The 3D model of a site as the report shows it: the pipeline's wall surface, rendered and exported.

The surface itself is made from the evidence by the pipeline's mesh step
(:func:`cistern_archive.grid.surface.wall_surface`, ``SiteBuild.mesh``); this module only renders it
off screen from fixed views and writes the PLY. Mesh coordinates are the map frame in metres with
z up (``z = -depth``); the point array ``depth_m`` holds the depth the renders are coloured by.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cistern_archive.report import offscreen
from cistern_archive.report.config import ReportConfig
from cistern_archive.report.files import write_png

COLORMAP = "viridis"


@dataclass(frozen=True)
class View:
    """One fixed camera of the renders."""

    key: str
    title: str
    alt: str
    caption: str


VIEWS = (
    View("top", "Top view", "The 3D model seen from above, walls coloured by depth",
         "Plan view from above, north up, orthographic: the scale bar holds everywhere."),
    View("oblique-ne", "Oblique view from the north-east", "The 3D model seen obliquely from the north-east",
         "Perspective view from above the north-east corner; the scale bar lies on the floor in front."),
    View("oblique-sw", "Oblique view from the south-west", "The 3D model seen obliquely from the south-west",
         "Perspective view from above the south-west corner; the scale bar lies on the floor in front."),
    View("section", "Vertical section",
         "The 3D model cut by a vertical plane through its centre along its longer axis, seen from the side",
         "The far half of the model behind a vertical cut along its longer axis, orthographic, seen from "
         "the side: the wall profile with depth."),
)


def render_mesh(surface):
    """The pipeline's :class:`~cistern_archive.grid.surface.SurfaceMesh` as a pyvista mesh with
    ``depth_m`` and point normals, for rendering and export."""
    mesh = surface.to_pyvista()
    return mesh.compute_normals(cell_normals=False, point_normals=True, split_vertices=False,
                                auto_orient_normals=False)


def nice_length(span_m: float) -> float:
    """A round scale-bar length (1, 2 or 5 × 10^k) of about a quarter of ``span_m``."""
    target = max(span_m / 4.0, 1e-3)
    power = 10.0 ** np.floor(np.log10(target))
    for step in (5.0, 2.0, 1.0):
        if step * power <= target:
            return float(step * power)
    return float(power)


def _camera(view: str, bounds: tuple[float, ...]) -> tuple[tuple[float, float, float], ...]:
    """Position, focal point and view-up of a fixed view."""
    x0, x1, y0, y1, z0, z1 = bounds
    centre = ((x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2)
    radius = max(x1 - x0, y1 - y0, z1 - z0, 1e-3)
    cx, cy, cz = centre
    if view == "top":
        return (cx, cy, cz + 3 * radius), centre, (0.0, 1.0, 0.0)
    if view == "oblique-ne":
        return (cx + 1.6 * radius, cy + 1.6 * radius, cz + 1.4 * radius), centre, (0.0, 0.0, 1.0)
    if view == "oblique-sw":
        return (cx - 1.6 * radius, cy - 1.6 * radius, cz + 1.4 * radius), centre, (0.0, 0.0, 1.0)
    # section: cut along the longer horizontal axis, look at the cut face
    if (x1 - x0) >= (y1 - y0):
        return (cx, cy - 3 * radius, cz), centre, (0.0, 0.0, 1.0)
    return (cx + 3 * radius, cy, cz), centre, (0.0, 0.0, 1.0)


def _section(mesh):
    """The half of the mesh behind the vertical plane through its centre, along the longer axis."""
    x0, x1, y0, y1, _, _ = mesh.bounds
    centre = ((x0 + x1) / 2, (y0 + y1) / 2, 0.0)
    if (x1 - x0) >= (y1 - y0):
        return mesh.clip(normal=(0.0, -1.0, 0.0), origin=centre)
    return mesh.clip(normal=(1.0, 0.0, 0.0), origin=centre)


def scale_bar(view: str, bounds: tuple[float, ...], length: float) -> tuple[np.ndarray, np.ndarray]:
    """End points of the scale bar: along the model's bottom edge nearest the camera, just outside it
    (along y for a section seen from +x)."""
    x0, x1, y0, y1, z0, z1 = bounds
    margin = 0.08 * max(x1 - x0, y1 - y0, 1e-3)
    if view == "top":
        a, b = (x0, y0 - margin, z1), (x0 + length, y0 - margin, z1)
    elif view == "oblique-ne":
        a, b = (x1 - length, y1 + margin, z0), (x1, y1 + margin, z0)
    elif view == "oblique-sw":
        a, b = (x0, y0 - margin, z0), (x0 + length, y0 - margin, z0)
    elif (x1 - x0) >= (y1 - y0):
        a, b = (x0, (y0 + y1) / 2, z0 - margin), (x0 + length, (y0 + y1) / 2, z0 - margin)
    else:
        a, b = ((x0 + x1) / 2, y0, z0 - margin), ((x0 + x1) / 2, y0 + length, z0 - margin)
    return np.asarray(a, dtype=float), np.asarray(b, dtype=float)


def label_offset(view: str, bounds: tuple[float, ...]) -> np.ndarray:
    """Shift of the scale bar's label away from the model, so that it does not sit on the bar."""
    x0, x1, y0, y1, _, _ = bounds
    step = 0.06 * max(x1 - x0, y1 - y0, 1e-3)
    return {"top": np.array([0.0, -step, 0.0]), "oblique-ne": np.array([0.0, step, 0.0]),
            "oblique-sw": np.array([0.0, -step, 0.0])}.get(view, np.array([0.0, 0.0, -step]))


def depth_annotations(depth_range: tuple[float, float], n: int = 5) -> dict[float, str]:
    """Colour-bar labels: ``n`` depths from the shallowest (top of the bar) to the deepest, placed at
    their elevation (``-depth``), the scalar the renders are coloured by."""
    return {float(-d): f"{round(float(d), 1) + 0.0:.1f}" for d in np.linspace(depth_range[0], depth_range[1], n)}


PLAN_COLOUR = "#303030"
"""Colour of the walls' footprint in the top view."""
PLAN_LINE_PX = 3.0
"""Width of the footprint's lines in the top view (pixels): flattened, a vertical wall is a line."""


def plan_footprint(mesh):
    """The mesh flattened onto a plane just below its lowest point (the top view's plan of the walls,
    drawn as lines: a flattened vertical wall has no area)."""
    flat = mesh.copy(deep=True)
    z0 = float(mesh.bounds[4]) - 0.01 * max(float(mesh.bounds[5] - mesh.bounds[4]), 1.0)
    points = np.array(flat.points, dtype=np.float64)
    points[:, 2] = z0
    flat.points = points
    return flat


def render_views(mesh, out_dir: Path, config: ReportConfig, *, depth_range: tuple[float, float]) -> dict[str, str]:
    """Render :data:`VIEWS` off screen into ``out_dir/model-<view>.png``.

    One plotter renders every view: the model (or its section) coloured by depth with a depth colour
    bar, and a black scale bar of a round length with its label.

    Returns
    -------
    dict
        View key → file name.
    """
    import pyvista  # deferred: VTK loads in a second and picks its OpenGL window at import

    offscreen.configure()
    files: dict[str, str] = {}
    bounds = tuple(float(v) for v in mesh.bounds)
    length = nice_length(max(bounds[1] - bounds[0], bounds[3] - bounds[2]))
    section = _section(mesh)
    if section.n_points == 0:
        section = mesh
    for shown in (mesh, section):
        shown.point_data["elevation_m"] = -np.asarray(shown.point_data["depth_m"], dtype=np.float32)
    plotter = pyvista.Plotter(off_screen=True, window_size=list(config.window_px))
    try:
        plotter.set_background("white")
        # Coloured by elevation so that the bar runs the model's way (shallow at the top), labelled in depth.
        style = dict(scalars="elevation_m", cmap=COLORMAP + "_r", clim=(-depth_range[1], -depth_range[0]),
                     smooth_shading=True, specular=0.2)
        bar = dict(title="Depth (m)", color="black", vertical=True, n_labels=0, position_x=0.86,
                   position_y=0.12, width=0.07, height=0.76, title_font_size=22, label_font_size=18)
        whole = plotter.add_mesh(mesh, scalar_bar_args=bar, annotations=depth_annotations(depth_range), **style)
        cut = plotter.add_mesh(section, show_scalar_bar=False, **style)
        # Seen from straight above, a vertical wall is edge-on and all but vanishes: the walls' footprint,
        # flattened below the model in dark grey, shows them as a plan does (a sloping wall still shows
        # its own colours, which hide the footprint beneath).
        footprint = plotter.add_mesh(plan_footprint(mesh), color=PLAN_COLOUR, style="wireframe", line_width=PLAN_LINE_PX,
                                   lighting=False, show_scalar_bar=False)
        for view in VIEWS:
            plotter.suppress_rendering = True
            whole.SetVisibility(view.key != "section")
            cut.SetVisibility(view.key == "section")
            footprint.SetVisibility(view.key == "top")
            a, b = scale_bar(view.key, bounds, length)
            plotter.add_mesh(pyvista.Line(a, b), color="black", line_width=5, name="scale-bar")
            plotter.add_point_labels(
                [(a + b) / 2 + label_offset(view.key, bounds)], [f"{length:g} m"], name="scale-label", font_size=20, text_color="black",
                shape=None, show_points=False, always_visible=True, justification_horizontal="center",
            )
            position, focal, up = _camera(view.key, bounds)
            plotter.camera_position = [position, focal, up]
            plotter.camera.parallel_projection = view.key in ("top", "section")
            plotter.reset_camera()
            plotter.camera.zoom(1.1 if view.key.startswith("oblique") else 0.95)
            plotter.suppress_rendering = False
            plotter.render()
            image = plotter.screenshot(return_img=True)
            name = f"model-{view.key}.png"
            write_png(out_dir / name, np.asarray(image, dtype=np.uint8))
            files[view.key] = name
    finally:
        plotter.close()
    return files


def export_ply(mesh, path: Path) -> Path:
    """Binary PLY of the mesh (map frame, metres, z up)."""
    mesh.save(str(path), binary=True)
    return path
