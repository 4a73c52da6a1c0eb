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
    model: bool = Field(default=True, description="render and export the 3D model (made by the pipeline's mesh step)")
    window_px: tuple[int, int] = (800, 600)
    viewer: bool = Field(default=True, description="the interactive 3D view (three.js, vendored) beside the renders")
    pdf: bool = Field(default=True, description="print the page to report.pdf with headless Chromium, when installed")
    max_page_bytes: int = Field(default=5_000_000, gt=0, description="budget of a site page with its images")
