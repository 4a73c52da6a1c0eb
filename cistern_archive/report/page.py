"""What ``site.html.j2`` shows of one site, as plain strings, lists and dicts (:func:`page_context`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from cistern_archive import __version__
from cistern_archive.core.dimensions import HEADING_TURN_DEG
from cistern_archive.core.scan import compass_deg_from_yaw
from cistern_archive.evaluation import scan_position_errors
from cistern_archive.pipeline.export import diff_percent
from cistern_archive.pipeline.results import SiteBuild, SiteResult
from cistern_archive.pipeline.status import MAX_HEADING_SHIFT_M, MAX_PROBE_STD_M, MAX_WALL_LEAN_DEG
from cistern_archive.report import viewer
from cistern_archive.report.canvas import FigureFile
from cistern_archive.report.files import build_time_from_env, format_time, unique_slugs
from cistern_archive.report.html import STATUS_TEXT, number, probe_count, signed, with_interval
from cistern_archive.report.model_section import ModelOutcome
from cistern_archive.report.track import track_context

SECTION_TITLES = {
    "failure": "Build failed",
    "summary": "Summary",
    "map": "Map",
    "track": "Track",
    "model": "3D model",
    "dimensions": "Dimensions",
    "pairs": "Pair matches",
    "pair_figures": "Convergence and particles of each pair",
    "scans": "Scans",
    "fans": "Scan fans",
    "provenance": "Parameters and provenance",
    "downloads": "Downloads",
}
TOC = ("failure", "summary", "map", "track", "model", "dimensions", "pairs", "scans", "provenance", "downloads")



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
    if sonar.vertical_beam_width_deg is None:
        parts.append(f"beam width {sonar.beam_width_deg:g}°")
    else:
        parts.append(f"beam {sonar.beam_width_deg:g}° wide and {sonar.vertical_beam_width_deg:g}° tall")
    return ", ".join(parts)


def station_label(labels: list[str], k: int) -> str:
    """The label of scan ``k`` (``scan k`` when there is none)."""
    return labels[k] if 0 <= k < len(labels) else f"scan {k}"


def _figure_view(f: FigureFile, anchor: str, site_dir: Path) -> dict[str, Any]:
    from PIL import Image

    with Image.open(site_dir / f.file) as image:
        width, height = image.size
    return {"anchor": anchor, "file": f.file, "title": f.title, "alt": f.alt, "caption": f.caption,
            "width": width, "height": height}


def _dimension_rows(result: SiteResult) -> list[dict[str, str]]:
    rows = []
    for d in result.dimensions:
        rows.append({"name": d.name, "kind": d.reference_kind, "depth": number(d.depth_m, 2),
                     "map": with_interval(d.map_m, d.ci95_m), "reference": number(d.reference_m),
                     "diff": signed(d.diff_m), "percent": signed(diff_percent(d), 2),
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
    shown = {"failure": result.failure is not None, "track": build.track is not None}
    sections = [{"id": ids[key], "title": SECTION_TITLES[key]} for key in TOC if shown.get(key, True)]
    single = [(key, drawn[key]) for key in ("map", "slices", "probes") if key in drawn]
    all_figures = single + [("track", f) for f in drawn.get("track", [])] + [("pair", f) for f in drawn["pairs"]] + \
        [("fan", f) for f in drawn["fans"]] + [("view", f) for f in model.views]
    anchors = unique_slugs([f"figure {f.title}" for _, f in all_figures])
    views = {id(f): _figure_view(f, a, site_dir) for (_, f), a in zip(all_figures, anchors)}
    figures = {key: None for key in ("map", "slices", "probes")}
    figures.update({key: views[id(f)] for key, f in single})
    figure_anchor = {f.key: views[id(f)]["anchor"] for f in drawn["pairs"]}
    pair_anchor = {pair: figure_anchor[keys[-1]] for pair, keys in drawn["pair_keys"].items() if keys}
    pairs = [{"label": f"{station_label(labels, p.i)} → {station_label(labels, p.j)}",
              "dx": signed(p.dx_m), "dy": signed(p.dy_m),
              "dyaw": signed(None if p.dyaw_rad is None else math.degrees(p.dyaw_rad), 2),
              "weight": number(p.weight, 3),
              "converged": "yes" if p.converged else "no", "iterations": str(p.iterations),
              "reason": p.reason or "—",
              "figure": (p.i, p.j) in pair_anchor, "anchor": pair_anchor.get((p.i, p.j), "")}
             for p in sorted(result.pairs, key=lambda p: (p.i, p.j))]
    has_truth = any(s.truth_x_m is not None for s in result.scans)
    has_scale = any(s.echo_scale is not None for s in result.scans)
    errors = scan_position_errors(result)
    placed = []
    for k, s in enumerate(result.scans):
        if not s.placed:
            continue
        error = errors.get(k)
        placed.append({"id": s.id, "file": s.file, "x": signed(s.x_m), "y": signed(s.y_m),
                       "sx": number(s.sigma_x_m), "sy": number(s.sigma_y_m),
                       "heading": number(compass_deg_from_yaw(s.yaw_rad), 1), "depth": number(s.depth_m, 2),
                       "error": number(error), "scale": number(s.echo_scale, 3)})
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
        "lean_threshold": f"{MAX_WALL_LEAN_DEG:.0f}",
        "heading_threshold": f"{MAX_HEADING_SHIFT_M:.2f}",
        "heading_turn": f"{HEADING_TURN_DEG:.0f}",
        "ids": ids,
        "sections": sections,
        "location": location_text(build.record),
        "sonar": sonar_text(build.record),
        "placed_count": sum(1 for s in result.scans if s.placed),
        "reference_label": station_label(labels, reference) if reference is not None and reference >= 0 else "",
        "dimension_stats": _stat_rows(result.dimension_stats),
        "figures": figures,
        "views": [views[id(f)] for f in model.views],
        "viewer_scripts": viewer.script_sources() if "viewer-model" in model.files else [],
        "model_note": model.note,
        "model_missing": model.missing,
        "track": None if build.track is None else track_context(build.track),
        "track_figures": [views[id(f)] for f in drawn.get("track", [])],
        "dimensions": _dimension_rows(result),
        "pairs": pairs,
        "pair_figures": [views[id(f)] for f in drawn["pairs"]],
        "pairs_not_drawn": drawn["pairs_not_drawn"],
        "fan_figures": [views[id(f)] for f in drawn["fans"]],
        "fans_not_drawn": drawn["fans_not_drawn"],
        "placed": placed,
        "unplaced": unplaced,
        "has_truth": has_truth,
        "has_scale": has_scale,
        "plugins": plugins,
        "seeds": seeds,
        "downloads": downloads,
    }
