"""Settings of the report: figure sizes, 3D model parameters and the size caps of a site page."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class ReportConfig(BaseModel):
    """How a site report is rendered.

    Every field has a default that keeps one site's report within the targets of the project
    (≤ 10 s to render, ≤ 5 MB of page and images).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    dpi: int = Field(default=100, ge=50, le=300, description="resolution of the matplotlib figures")
    thumbnail_px: int = Field(default=240, ge=64, le=800, description="width of the index thumbnail")
    max_pair_figures: int = Field(default=48, ge=0, description="pairs beyond this are listed but not drawn")
    pairs_per_figure: int = Field(default=16, ge=1, le=48, description="pairs per particle montage")
    max_fan_figures: int = Field(default=24, ge=0, description="scans beyond this are listed but not drawn")
    # 3D model
    model: bool = Field(default=True, description="build, render and export the 3D model")
    window_px: tuple[int, int] = (800, 600)
    dz_m: float = Field(default=0.1, gt=0, description="vertical spacing of the volume's layers")
    extend_m: float = Field(
        default=1.0, ge=0, description="height the outermost slices are extruded above and below"
    )
    iso_level: float = Field(default=0.6, gt=0, lt=1, description="occupancy probability of the isosurface")
    smooth_sigma_cells: float = Field(default=0.8, ge=0, description="Gaussian blur of the volume before meshing")
    min_blob_cells: int = Field(default=6, ge=0, description="occupied blobs smaller than this are not meshed")
    dilate_cells: int = Field(default=1, ge=0, le=5, description="horizontal dilation of walls before meshing")
    smooth_iterations: int = Field(default=20, ge=0, description="Taubin smoothing passes of the mesh")
    min_component_fraction: float = Field(
        default=0.01, ge=0, lt=1, description="drop mesh pieces with fewer triangles than this share"
    )
    max_faces: int = Field(default=25_000, ge=100, description="decimate the mesh down to this many triangles")
    max_page_bytes: int = Field(default=5_000_000, gt=0, description="budget of a site page with its images")
