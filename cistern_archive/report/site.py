"""One site's report: figures, 3D model, arrays, tables and ``index.html`` in the site folder.

:func:`render_site` works from whatever a :class:`~cistern_archive.pipeline.results.SiteBuild` holds,
so a failed build still gets a page (its error, stage and input, and the arrays it reached).
Every file name is fixed or derived from a title; nothing depends on the clock unless
``SOURCE_DATE_EPOCH`` is set, so the same build gives the same bytes.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from cistern_archive import __version__
from cistern_archive.core.errors import CisternError
from cistern_archive.evaluation import scan_position_errors
from cistern_archive.pipeline.results import SiteBuild, SiteResult
from cistern_archive.pipeline.status import MAX_PROBE_STD_M
from cistern_archive.report import figures as fig
from cistern_archive.report import geotiff, model3d, offscreen, pdf, plan, viewer
from cistern_archive.report.config import ReportConfig
from cistern_archive.report.files import (
    build_time_from_env,
    format_number,
    format_time,
    unique_slugs,
    write_csv,
    write_npz,
)
from cistern_archive.report.gltf import write_glb
from cistern_archive.report.html import STATUS_TEXT, number, probe_count, render_site_page, signed, with_interval
from cistern_archive.core.scan import compass_deg_from_yaw

SECTION_TITLES = {
    "failure": "Build failed",
    "summary": "Summary",
    "map": "Map",
    "model": "3D model",
    "dimensions": "Dimensions",
    "pairs": "Pair matches",
    "pair_figures": "Convergence and particles of each pair",
    "scans": "Scans",
    "fans": "Scan fans",
    "provenance": "Parameters and provenance",
    "downloads": "Downloads",
}
TOC = ("failure", "summary", "map", "model", "dimensions", "pairs", "scans", "provenance", "downloads")


@dataclass
class ModelOutcome:
    """What the 3D step produced: rendered views, exported files, or why there is no model."""

    views: list[fig.FigureFile] = field(default_factory=list)
    files: dict[str, str] = field(default_factory=dict)
    note: str = ""
    missing: str = ""


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


def location_text(record: Any) -> str:
    """The place, with coordinates only when the record does not ask to redact them."""
    location = getattr(record, "location", None)
    if location is None:
        return "not recorded"
    place = location.place or "place not recorded"
    if location.redact:
        return f"{place} (exact coordinates withheld to protect the site)"
    if location.latitude is None or location.longitude is None:
        return place
    lat = f"{abs(location.latitude):.5f}° {'N' if location.latitude >= 0 else 'S'}"
    lon = f"{abs(location.longitude):.5f}° {'E' if location.longitude >= 0 else 'W'}"
    return f"{place} ({lat}, {lon})"


def sonar_text(record: Any) -> str:
    sonar = getattr(record, "sonar", None)
    if sonar is None:
        return "not recorded"
    parts = [sonar.model]
    if sonar.frequency_khz:
        parts.append(f"{sonar.frequency_khz:g} kHz")
    if sonar.range_m:
        parts.append(f"range {sonar.range_m:g} m")
    if sonar.step_deg:
        parts.append(f"step {sonar.step_deg:g}°")
    parts.append(f"beam width {sonar.beam_width_deg:g}°")
    return ", ".join(parts)


def human_size(n_bytes: int) -> str:
    if n_bytes < 1024:
        return f"{n_bytes} B"
    if n_bytes < 1024 ** 2:
        return f"{n_bytes / 1024:.1f} KiB"
    return f"{n_bytes / 1024 ** 2:.1f} MiB"


# ------------------------------------------------------------------------------------------ arrays
def write_arrays(build: SiteBuild, site_dir: Path) -> dict[str, str]:
    """``grid.npz`` (every slice's log-odds, origin, cell and depth) and one PNG per slice."""
    files: dict[str, str] = {}
    if build.map_result is None or not build.map_result.grids:
        return files
    grids = build.map_result.grids
    arrays: dict[str, np.ndarray] = {"depths_m": np.array([g.depth_m for g in grids], dtype=np.float64)}
    for k, grid in enumerate(grids):
        arrays[f"log_odds_{k}"] = np.asarray(grid.log_odds, dtype=np.float32)
        arrays[f"origin_xy_m_{k}"] = np.asarray(grid.origin_xy_m, dtype=np.float64)
        arrays[f"cell_m_{k}"] = np.asarray(grid.cell_m, dtype=np.float64)
    write_npz(site_dir / "grid.npz", arrays)
    files["grid"] = "grid.npz"
    for k, grid in enumerate(grids):
        name = f"grid-{k}.png"
        fig.grid_png(site_dir / name, grid)
        files[f"grid-png-{k}"] = name
    return files


def write_tables(result: SiteResult, labels: list[str], site_dir: Path) -> dict[str, str]:
    """CSV files of the dimension, pair and scan tables."""
    write_csv(site_dir / "dimensions.csv",
              ["name", "reference_kind", "depth_m", "map_m", "ci95_m", "reference_m", "diff_m", "diff_percent",
               "probe_std_m", "n_probes", "probes_m"],
              [[d.name, d.reference_kind, d.depth_m, d.map_m, d.ci95_m, d.reference_m, d.diff_m,
                None if d.diff_m is None else 100.0 * d.diff_m / d.reference_m, d.probe_std_m, len(d.probes_m),
                ";".join(format_number(p, 4) for p in d.probes_m)] for d in result.dimensions])
    write_csv(site_dir / "pairs.csv",
              ["i", "j", "station_i", "station_j", "dx_m", "dy_m", "dyaw_rad", "weight", "converged",
               "iterations", "reason"],
              [[p.i, p.j, _label(labels, p.i), _label(labels, p.j), p.dx_m, p.dy_m, p.dyaw_rad, p.weight,
                str(p.converged).lower(), p.iterations, p.reason] for p in result.pairs])
    write_csv(site_dir / "scans.csv",
              ["index", "station", "file", "placed", "x_m", "y_m", "sigma_x_m", "sigma_y_m", "yaw_rad",
               "heading_deg", "depth_m", "reason"],
              [[s.index, s.id, s.file, str(s.placed).lower(), s.x_m, s.y_m, s.sigma_x_m, s.sigma_y_m, s.yaw_rad,
                compass_deg_from_yaw(s.yaw_rad), s.depth_m, s.reason] for s in result.scans])
    return {"dimensions-csv": "dimensions.csv", "pairs-csv": "pairs.csv", "scans-csv": "scans.csv"}


def _label(labels: list[str], k: int) -> str:
    return labels[k] if 0 <= k < len(labels) else f"scan {k}"


# ------------------------------------------------------------------------------------------ figures
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
    grid = fig.choose_slice(grids, _scan_depth(build)) if grids else None
    if grid is not None or build.poses is not None:
        out["map"] = fig.map_figure(site_dir / "map.png", grid, build.poses, build.matches, labels, dpi=config.dpi)
    if grid is not None:
        fig.thumbnail(site_dir / "thumbnail.png", grid, build.poses, width_px=config.thumbnail_px)
        out["thumbnail"] = "thumbnail.png"
    if len(grids) > 1:
        out["slices"] = fig.slices_figure(site_dir / "slices.png", grids, dpi=config.dpi)
    if grids and build.table is not None and any(r.probe_lines for r in build.table.rows):
        out["probes"] = fig.probe_figure(site_dir / "probes.png", grids, build.table, dpi=config.dpi)
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
    views = [fig.FigureFile(f"model-{v.key}", rendered[v.key], v.title, v.alt, v.caption)
             for v in model3d.VIEWS if v.key in rendered]
    files.update({f"render-{v.key}": rendered[v.key] for v in model3d.VIEWS if v.key in rendered})
    return ModelOutcome(views=views, files=files, note=note)


# ------------------------------------------------------------------------------------------ page
def _figure_view(f: fig.FigureFile, anchor: str, site_dir: Path) -> dict[str, Any]:
    from PIL import Image

    with Image.open(site_dir / f.file) as image:
        width, height = image.size
    return {"anchor": anchor, "file": f.file, "title": f.title, "alt": f.alt, "caption": f.caption,
            "width": width, "height": height}


def _dimension_rows(result: SiteResult) -> list[dict[str, str]]:
    rows = []
    for d in result.dimensions:
        percent = None if d.diff_m is None else 100.0 * d.diff_m / d.reference_m
        rows.append({"name": d.name, "kind": d.reference_kind, "depth": number(d.depth_m, 2), "map": with_interval(d.map_m, d.ci95_m),
                     "reference": number(d.reference_m), "diff": signed(d.diff_m), "percent": signed(percent, 2),
                     "std": number(d.probe_std_m), "probes": probe_count(d), "weak": d.weak,
                     "note": "; ".join(n for n in (d.weak_reason and f"weak: {d.weak_reason}", d.note) if n)})
    return rows


STAT_EXPLANATIONS = {
    "percent_difference": "the paper's percent difference (Sec. IV) between the map's width/length ratio a and "
                          "the true ratio b, 100 |a − b| / ((a + b) / 2): how far the map's shape is from the "
                          "truth, whatever its scale (not the per-dimension column of the table)",
    "max_abs_diff_m": "largest |map − reference| over the rows of the table, truth and mosaic",
    "mean_abs_diff_m": "mean |map − reference| over the rows of the table, truth and mosaic",
}


def stat_explanation(key: str) -> str:
    """What a summary statistic of the comparator is (``probe_std_<name>_m`` and the fixed keys)."""
    if key in STAT_EXPLANATIONS:
        return STAT_EXPLANATIONS[key]
    if key.startswith("probe_std_") and key.endswith("_m"):
        return f"sample standard deviation of the probes of '{key[len('probe_std_'):-2].replace('_', ' ')}' (truth)"
    return ""


def _stat_rows(stats: dict[str, float | None]) -> list[dict[str, str]]:
    rows = []
    for key in sorted(stats):
        value = stats[key]
        label = key.replace("_", " ").capitalize()
        if key.endswith("_m"):
            label = label[:-2] + " (m)"
        if "percent" in key or key.endswith("_pct"):
            text = "—" if value is None else f"{number(value, 2)} %"
            label = label.replace(" pct", "")
        else:
            text = number(value, 3)
        rows.append({"label": label, "value": text, "explanation": stat_explanation(key)})
    return rows


def parameter_text(value: Any) -> str:
    """A parameter value as a reader writes it: numbers and words as they are, lists comma-separated,
    mappings as ``key: value`` pairs (a mapping inside one in parentheses)."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, dict):
        return "; ".join(f"{k}: ({parameter_text(v)})" if isinstance(v, dict) and v else f"{k}: {parameter_text(v)}"
                         for k, v in sorted(value.items())) or "none"
    if isinstance(value, list | tuple):
        return ", ".join(parameter_text(v) for v in value) or "none"
    return "none" if value is None else str(value)


def parameter_items(params: dict[str, Any]) -> list[dict[str, str]]:
    """``[{"key", "value"}]`` of a plugin's parameters, sorted by name."""
    return [{"key": key, "value": parameter_text(params[key])} for key in sorted(params)]


def page_context(build: SiteBuild, labels: list[str], drawn: dict[str, Any], model: ModelOutcome,
                 downloads: list[dict[str, str]], site_dir: Path) -> dict[str, Any]:
    """Everything ``site.html.j2`` shows, as plain strings, lists and dicts."""
    result = build.result
    ids = dict(zip(SECTION_TITLES, unique_slugs(list(SECTION_TITLES.values()))))
    sections = [{"id": ids[key], "title": SECTION_TITLES[key]} for key in TOC
                if key != "failure" or result.failure is not None]
    single = [(key, drawn[key]) for key in ("map", "slices", "probes") if key in drawn]
    all_figures = single + [("pair", f) for f in drawn["pairs"]] + [("fan", f) for f in drawn["fans"]] + \
        [("view", f) for f in model.views]
    anchors = unique_slugs([f"figure {f.title}" for _, f in all_figures])
    views = {id(f): _figure_view(f, a, site_dir) for (_, f), a in zip(all_figures, anchors)}
    figures = {key: None for key in ("map", "slices", "probes")}
    figures.update({key: views[id(f)] for key, f in single})
    figure_anchor = {f.key: views[id(f)]["anchor"] for f in drawn["pairs"]}
    pair_anchor = {pair: figure_anchor[keys[-1]] for pair, keys in drawn["pair_keys"].items() if keys}
    pairs = [{"label": f"{_label(labels, p.i)} → {_label(labels, p.j)}", "dx": signed(p.dx_m), "dy": signed(p.dy_m),
              "dyaw": signed(None if p.dyaw_rad is None else math.degrees(p.dyaw_rad), 2), "weight": number(p.weight, 3),
              "converged": "yes" if p.converged else "no", "iterations": str(p.iterations),
              "reason": p.reason or "—",
              "figure": (p.i, p.j) in pair_anchor, "anchor": pair_anchor.get((p.i, p.j), "")}
             for p in sorted(result.pairs, key=lambda p: (p.i, p.j))]
    has_truth = any(s.truth_x_m is not None for s in result.scans)
    errors = scan_position_errors(result)
    placed = []
    for k, s in enumerate(result.scans):
        if not s.placed:
            continue
        error = errors.get(k)
        placed.append({"id": s.id, "file": s.file, "x": signed(s.x_m), "y": signed(s.y_m),
                       "sx": number(s.sigma_x_m), "sy": number(s.sigma_y_m),
                       "heading": number(compass_deg_from_yaw(s.yaw_rad), 1), "depth": number(s.depth_m, 2),
                       "error": number(error)})
    unplaced = [{"id": s.id, "file": s.file, "reason": s.reason or "not reached"} for s in result.scans if not s.placed]
    provenance = result.provenance
    plugins = [] if provenance is None else [
        {"stage": p.stage, "plugin": p.plugin, "distribution": p.distribution, "version": p.version,
         "params": parameter_items(p.params)}
        for p in provenance.plugins]
    seeds = [] if provenance is None else sorted(provenance.seeds.items())
    reference = result.reference_scan
    status_text = STATUS_TEXT.get(result.status, result.status)
    return {
        "version": __version__,
        "build_time": format_time(build_time_from_env()),
        "result": result,
        "record": build.record,
        "status_text": status_text,
        "weak_threshold": f"{MAX_PROBE_STD_M:.2f}",
        "ids": ids,
        "sections": sections,
        "location": location_text(build.record),
        "sonar": sonar_text(build.record),
        "placed_count": sum(1 for s in result.scans if s.placed),
        "reference_label": _label(labels, reference) if reference is not None and reference >= 0 else "",
        "dimension_stats": _stat_rows(result.dimension_stats),
        "figures": figures,
        "views": [views[id(f)] for f in model.views],
        "viewer_scripts": viewer.script_sources() if "viewer-model" in model.files else [],
        "model_note": model.note,
        "model_missing": model.missing,
        "dimensions": _dimension_rows(result),
        "pairs": pairs,
        "pair_figures": [views[id(f)] for f in drawn["pairs"]],
        "pairs_not_drawn": drawn["pairs_not_drawn"],
        "fan_figures": [views[id(f)] for f in drawn["fans"]],
        "fans_not_drawn": drawn["fans_not_drawn"],
        "placed": placed,
        "unplaced": unplaced,
        "has_truth": has_truth,
        "plugins": plugins,
        "seeds": seeds,
        "downloads": downloads,
    }


DOWNLOADS = (
    ("grid", "Evidence grids", "log-odds of every depth slice with origin, cell size and depth (NumPy .npz)"),
    ("mesh-ply", "3D model (PLY)", "triangle mesh, map frame in metres, z up"),
    ("mesh-gltf", "3D model (glTF binary)", "self-contained .glb coloured by depth, for any glTF viewer"),
    ("grid-tif", "Evidence grid (GeoTIFF)", "occupancy per depth slice in its UTM zone (WGS 84), for GIS"),
    ("grid-tfw", "World file of the GeoTIFF", "the same georeferencing for software that reads world files"),
    ("plan-dxf", "Plan (DXF)", "wall outline at every mapped depth, one layer per depth, metres, for CAD"),
    ("plan-svg", "Plan (SVG)", "the same outlines north up with a scale bar and north arrow, for print"),
    ("report-pdf", "Report (PDF)", "this page printed, for the archive"),
    ("result", "Result (JSON)", "the site's result.json: poses, pairs, dimensions, provenance, timings"),
    ("dimensions-csv", "Dimension table (CSV)", "map vs reference for every measured dimension"),
    ("pairs-csv", "Pair table (CSV)", "every pair match"),
    ("scans-csv", "Scan table (CSV)", "every scan, placed or not"),
)


UNSIZED_DOWNLOADS = frozenset({"result", "report-pdf"})
"""Downloads whose size is not printed: ``result.json`` holds the build's timings, so its size changes
from build to build and would make the page differ while nothing else has; ``report.pdf`` is printed
from the finished page."""


def _downloads(artifacts: dict[str, str], site_dir: Path) -> list[dict[str, str]]:
    out = []
    for key, title, description in DOWNLOADS:
        if key in artifacts:
            size = "" if key in UNSIZED_DOWNLOADS else human_size((site_dir / artifacts[key]).stat().st_size)
            out.append({"file": artifacts[key], "title": title, "description": description, "size": size})
    for key in sorted(k for k in artifacts if k.startswith("grid-png-")):
        k = int(key.rsplit("-", 1)[1])
        out.append({"file": artifacts[key], "title": f"Grid image, slice {k + 1}",
                    "description": "one pixel per cell, north up: black occupied, white free, grey unknown",
                    "size": human_size((site_dir / artifacts[key]).stat().st_size)})
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
        Artifact name → path relative to ``site_dir``: ``page`` (``index.html``), ``result``
        (``result.json``, written here with these artifacts), ``grid``, ``grid-png-<k>``, ``map``,
        ``thumbnail``, ``mesh-ply``, ``mesh-gltf``, ``render-<view>``, the CSV tables and the figures.
    """
    config = config or ReportConfig()
    site_dir = Path(site_dir)
    if not site_dir.is_dir():
        raise CisternError(f"{site_dir}: the site folder does not exist")
    labels = station_labels(build)
    artifacts: dict[str, str] = {}
    artifacts.update(write_arrays(build, site_dir))
    drawn = draw_figures(build, labels, site_dir, config)
    for key in ("map", "slices", "probes"):
        if key in drawn:
            artifacts[key] = drawn[key].file
    if "thumbnail" in drawn:
        artifacts["thumbnail"] = drawn["thumbnail"]
    for f in drawn["pairs"] + drawn["fans"]:
        artifacts[Path(f.file).stem] = f.file
    model = build_model(build, site_dir, config)
    artifacts.update(model.files)
    artifacts.update(write_plan(build, site_dir))
    if build.map_result is not None and build.map_result.grids and geotiff.georeferenced(build.record):
        location = build.record.location
        tif, world = geotiff.write_geotiff(site_dir / "grid.tif", build.map_result, location.latitude,
                                           location.longitude)
        artifacts.update({"grid-tif": tif.name, "grid-tfw": world.name})
    artifacts.update(write_tables(build.result, labels, site_dir))
    artifacts["result"] = "result.json"
    artifacts["page"] = "index.html"
    if config.pdf and pdf.chromium_path() is not None:
        artifacts["report-pdf"] = "report.pdf"

    def write_page(artifacts: dict[str, str]) -> dict[str, str]:
        artifacts = dict(sorted(artifacts.items()))
        result = build.result.model_copy(update={"artifacts": artifacts})
        (site_dir / "result.json").write_text(result.model_dump_json(indent=2) + "\n", encoding="utf-8")
        context = page_context(replace(build, result=result), labels, drawn, model,
                               _downloads(artifacts, site_dir), site_dir)
        (site_dir / "index.html").write_text(render_site_page(**context), encoding="utf-8")
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
