"""The page's 3D model section: the pipeline's wall surface (``SiteBuild.mesh``) exported as PLY and
GLB, the interactive viewer, and the off-screen renders when rendering works on this machine."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cistern_archive.pipeline.results import SiteBuild
from cistern_archive.report import model3d, offscreen, viewer
from cistern_archive.report.canvas import FigureFile
from cistern_archive.report.config import ReportConfig
from cistern_archive.report.gltf import write_glb


@dataclass
class ModelOutcome:
    """What the 3D step produced: rendered views, exported files, or why there is no model."""

    views: list[FigureFile] = field(default_factory=list)
    files: dict[str, str] = field(default_factory=dict)
    note: str = ""
    missing: str = ""


def build_model(build: SiteBuild, site_dir: Path, config: ReportConfig) -> ModelOutcome:
    """The pipeline's wall surface → PLY and GLB exports → off-screen renders (when rendering works here)."""
    if not config.model:
        return ModelOutcome(missing="The 3D model was not requested for this report.")
    if build.map_result is None or not build.map_result.grids:
        return ModelOutcome(missing="No 3D model: the build stopped before the mapping stage.")
    if build.mesh is None:
        return ModelOutcome(missing="No 3D model: no wall was seen next to the water the vehicle was in.")
    surface = build.mesh
    mesh = model3d.render_mesh(surface)
    depth_range = surface.depth_range_m
    files = {"mesh-ply": model3d.export_ply(mesh, site_dir / "model.ply").name,
             "mesh-gltf": write_glb(site_dir / "model.glb", mesh, colormap=model3d.COLORMAP,
                                    depth_range=depth_range).name}
    depths = surface.slice_depths_m
    note = (f"one slice at {depths[0]:.2f} m extruded vertically from {depth_range[0]:.2f} m to "
            f"{depth_range[1]:.2f} m, as in the paper" if len(depths) == 1 else
            f"{len(depths)} slices from {depths[0]:.2f} m to {depths[-1]:.2f} m, walls curved through them")
    note += f"; {surface.n_triangles} triangles"
    reason = offscreen.probe()
    if reason:
        if config.viewer:
            files.update(viewer.write_viewer(site_dir, site_dir / files["mesh-gltf"]))
        return ModelOutcome(files=files, note=note, missing=f"3D views not rendered: {reason}. The mesh is still "
                                                            "available under Downloads.")
    if config.viewer:
        files.update(viewer.write_viewer(site_dir, site_dir / files["mesh-gltf"]))
    rendered = model3d.render_views(mesh, site_dir, config, depth_range=depth_range)
    views = [FigureFile(f"model-{v.key}", rendered[v.key], v.title, v.alt, v.caption)
             for v in model3d.VIEWS if v.key in rendered]
    files.update({f"render-{v.key}": rendered[v.key] for v in model3d.VIEWS if v.key in rendered})
    return ModelOutcome(views=views, files=files, note=note)
