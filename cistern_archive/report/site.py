"""One site's report: figures, 3D model, arrays, tables and ``index.html`` in the site folder.

:func:`render_site` works from whatever a :class:`~cistern_archive.pipeline.results.SiteBuild` holds,
so a failed build still gets a page (its error, stage and input, and the arrays it reached).
Every file name is fixed or derived from a title; nothing depends on the clock unless
``SOURCE_DATE_EPOCH`` is set, so the same build gives the same bytes. The report only renders: it
writes the files it returns and never ``result.json``, which the caller writes afterwards with the
returned artifacts (:func:`cistern_archive.pipeline.runner.write_site_result`).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from cistern_archive.core.errors import CisternError
from cistern_archive.core.files import write_text_atomic
from cistern_archive.pipeline import export
from cistern_archive.pipeline.results import SiteBuild, SiteResult
from cistern_archive.pipeline.runner import RESULT_FILE
from cistern_archive.report import figures as fig
from cistern_archive.report import geotiff, maps, pdf, plan, track
from cistern_archive.report.config import ReportConfig
from cistern_archive.report.downloads import download_rows
from cistern_archive.report.files import build_time_from_env
from cistern_archive.report.html import render_site_page
from cistern_archive.report.model_section import build_model
from cistern_archive.report.page import page_context


def station_labels(build: SiteBuild) -> list[str]:
    """A label per scan: the station of the result, of the raw or the segmented scan, else its index."""
    n = max(len(build.result.scans), len(build.raw_scans), len(build.range_scans),
            0 if build.poses is None else len(build.poses.placed))
    labels = []
    for k in range(n):
        label = ""
        if k < len(build.result.scans):
            label = build.result.scans[k].id
        if not label and k < len(build.raw_scans):
            label = build.raw_scans[k].station
        if not label and k < len(build.range_scans):
            label = build.range_scans[k].station
        labels.append(label or f"scan {k}")
    return labels


def write_grid_files(build: SiteBuild, site_dir: Path) -> dict[str, str]:
    """``grid.npz`` and the grid images with ``grids.csv`` (:mod:`cistern_archive.pipeline.export`)."""
    if build.map_result is None or not build.map_result.grids:
        return {}
    grids = build.map_result.grids
    export.write_npz(site_dir / export.GRID_NPZ, grids)
    return {"grid": export.GRID_NPZ, **export.write_grid_pngs(grids, site_dir)}


# ------------------------------------------------------------------------------------------ figures
MAX_MAP_LABELS = 20
"""A map labels at most this many stations (a survey's hundreds of revolutions: every n-th one)."""


def _scan_depth(build: SiteBuild) -> float | None:
    depths = [s.depth_m for s in build.range_scans] or [s.depth_m for s in build.result.scans]
    return float(np.median(depths)) if depths else None


def _truth_offset(result: SiteResult, i: int, j: int) -> tuple[float, float] | None:
    scans = result.scans
    if not (0 <= i < len(scans) and 0 <= j < len(scans)):
        return None
    a, b = scans[i], scans[j]
    if None in (a.truth_x_m, a.truth_y_m, b.truth_x_m, b.truth_y_m):
        return None
    return (b.truth_x_m - a.truth_x_m, b.truth_y_m - a.truth_y_m)


def draw_figures(build: SiteBuild, labels: list[str], site_dir: Path, config: ReportConfig) -> dict[str, Any]:
    """Every matplotlib figure of the page; returns ``map``, ``slices``, ``probes``, ``thumbnail``,
    ``pairs`` (list) and ``fans`` (list) entries for what could be drawn."""
    out: dict[str, Any] = {"pairs": [], "pair_keys": {}, "fans": [], "pairs_not_drawn": 0, "fans_not_drawn": 0}
    grids = build.map_result.grids if build.map_result is not None else ()
    grid = maps.choose_slice(grids, _scan_depth(build)) if grids else None
    if grid is not None or build.poses is not None:
        out["map"] = maps.map_figure(site_dir / "map.png", grid, build.poses, build.matches, labels,
                                     dpi=config.dpi, label_every=max(1, -(-len(labels) // MAX_MAP_LABELS)),
                                     station_depths_m=[s.depth_m for s in build.result.scans])
    if grid is not None:
        maps.thumbnail(site_dir / "thumbnail.png", grid, build.poses, width_px=config.thumbnail_px)
        out["thumbnail"] = "thumbnail.png"
    if build.track is not None:
        out["track"] = track.track_figures(site_dir, build.track, dpi=config.dpi)
    if len(grids) > 1:
        out["slices"] = maps.slices_figure(site_dir / "slices.png", grids, dpi=config.dpi)
    if grids and build.table is not None and any(r.probe_lines for r in build.table.rows):
        out["probes"] = maps.probe_figure(site_dir / "probes.png", grids, build.table, dpi=config.dpi)
    matches = sorted(build.matches, key=lambda m: (m.i, m.j))
    drawn_matches = matches[: config.max_pair_figures]
    out["pairs"] = fig.pair_figures(
        site_dir, drawn_matches,
        [build.range_scans[m.i] if 0 <= m.i < len(build.range_scans) else None for m in drawn_matches],
        labels, truths=[_truth_offset(build.result, m.i, m.j) for m in drawn_matches],
        per_figure=config.pairs_per_figure, dpi=config.dpi)
    out["pair_keys"] = {(m.i, m.j): [f.key for f, chunk in out["pairs"] if k in chunk]
                        for k, m in enumerate(drawn_matches)}
    out["pairs"] = [f for f, _ in out["pairs"]]
    out["pairs_not_drawn"] = max(0, len(matches) - config.max_pair_figures)
    scans = build.raw_scans[: config.max_fan_figures]
    if scans:
        ranged = [build.range_scans[k] if k < len(build.range_scans) else None for k in range(len(scans))]
        out["fans"] = [fig.fan_montage(site_dir / "fans.png", scans, ranged, dpi=config.dpi)]
    out["fans_not_drawn"] = max(0, len(build.raw_scans) - config.max_fan_figures)
    return out


def render_site(build: SiteBuild, site_dir: Path, *, config: ReportConfig | None = None) -> dict[str, str]:
    """Write a site's report into ``site_dir``.

    Parameters
    ----------
    build : SiteBuild
        A successful or failed build; missing parts are reported as missing.
    site_dir : Path
        An existing folder (the caller publishes it atomically).
    config : ReportConfig, keyword-only, optional

    Returns
    -------
    dict
        Artifact name → path relative to ``site_dir`` of every file written: ``page`` (``index.html``),
        ``grid``, ``grid-png-<k>``, ``grids-csv``, ``map``, ``thumbnail``, ``mesh-ply``, ``mesh-gltf``,
        ``render-<view>``, the CSV tables and the figures. The page links ``result.json``
        (:data:`~cistern_archive.pipeline.runner.RESULT_FILE`), which is not among them: the caller writes
        it with these artifacts.
    """
    config = config or ReportConfig()
    site_dir = Path(site_dir)
    if not site_dir.is_dir():
        raise CisternError(f"{site_dir}: the site folder does not exist")
    labels = station_labels(build)
    artifacts: dict[str, str] = {}
    artifacts.update(write_grid_files(build, site_dir))
    drawn = draw_figures(build, labels, site_dir, config)
    for key in ("map", "slices", "probes"):
        if key in drawn:
            artifacts[key] = drawn[key].file
    if "thumbnail" in drawn:
        artifacts["thumbnail"] = drawn["thumbnail"]
    for f in drawn.get("track", []) + drawn["pairs"] + drawn["fans"]:
        artifacts[Path(f.file).stem] = f.file
    model = build_model(build, site_dir, config)
    artifacts.update(model.files)
    artifacts.update(write_plan(build, site_dir))
    if build.map_result is not None and build.map_result.grids and geotiff.georeferenced(build.record):
        location = build.record.location
        tif, world = geotiff.write_geotiff(site_dir / "grid.tif", build.map_result, location.latitude,
                                           location.longitude)
        artifacts.update({"grid-tif": tif.name, "grid-tfw": world.name})
    artifacts.update(export.write_tables(build.result, site_dir))
    artifacts["page"] = "index.html"
    if config.pdf and pdf.chromium_path() is not None:
        artifacts["report-pdf"] = "report.pdf"

    def write_page(artifacts: dict[str, str]) -> dict[str, str]:
        artifacts = dict(sorted(artifacts.items()))
        downloads = download_rows({**artifacts, "result": RESULT_FILE}, site_dir)
        context = page_context(build, labels, drawn, model, downloads, site_dir)
        write_text_atomic(site_dir / "index.html", render_site_page(**context))
        return artifacts

    artifacts = write_page(artifacts)
    if "report-pdf" in artifacts and pdf.print_pdf(site_dir / "index.html", site_dir / "report.pdf",
                                                   when=build_time_from_env()):
        artifacts = write_page({k: v for k, v in artifacts.items() if k != "report-pdf"})
    return artifacts


def write_plan(build: SiteBuild, site_dir: Path) -> dict[str, str]:
    """``plan.dxf`` and ``plan.svg``: the wall outline at every mapped depth (:mod:`cistern_archive.report.plan`)."""
    if build.mesh is None:
        return {}
    outlines = plan.outlines(build.mesh)
    if not outlines:
        return {}
    return {"plan-dxf": plan.write_dxf(site_dir / "plan.dxf", outlines).name,
            "plan-svg": plan.write_svg(site_dir / "plan.svg", outlines, title=f"{build.record.name}: plan").name}


IMG_SRC = re.compile(r'<img[^>]+src="([^"]+)"')


def page_bytes(page: Path) -> int:
    """Size of an HTML page plus every local image it shows."""
    html = page.read_text(encoding="utf-8")
    sources = sorted(set(IMG_SRC.findall(html)))
    return page.stat().st_size + sum((page.parent / s).stat().st_size for s in sources if "://" not in s)
