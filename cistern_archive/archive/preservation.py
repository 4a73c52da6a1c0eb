"""Preservation formats of a built site: open CSV tables, lossless PNG grids and a PLY mesh.

Everything a report shows is also written in a format that needs no software of this project to read:
scans as CSV (one row per beam, one column per range bin), poses, pairs and dimensions as CSV, each
evidence-grid slice as an 8-bit grayscale PNG with its georeference in ``grids.csv``, and the 3D
model as a binary PLY.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from cistern_archive.pipeline.results import SiteBuild


def _write_csv(path: Path, header: list[str], rows: list[list]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(header)
        writer.writerows(["" if v is None or (isinstance(v, float) and math.isnan(v)) else v for v in row]
                         for row in rows)
    return path


def write_scans(build: SiteBuild, folder: Path) -> list[Path]:
    """``scans.csv`` (one row per scan: settings) and ``scans/<station>.csv`` (bearing + intensities)."""
    written = []
    rows = []
    for k, scan in enumerate(build.raw_scans):
        ref = build.record.scans[k]
        name = f"scans/{ref.station}.csv"  # the record's label: validated to name a file, unique in the site
        bins = scan.intensities.shape[1]
        header = ["bearing_rad"] + [f"bin_{b:04d}" for b in range(bins)]
        table = [[f"{bearing:.6f}", *(int(v) if float(v).is_integer() else float(v) for v in row)]
                 for bearing, row in zip(np.asarray(scan.bearings_rad), np.asarray(scan.intensities))]
        written.append(_write_csv(folder / name, header, table))
        rows.append([ref.station, ref.file, name, len(scan.bearings_rad), bins, scan.bin_size_m, scan.start_range_m,
                     scan.full_scale, scan.yaw_rad, scan.depth_m, scan.timestamp, scan.sonar_model,
                     scan.beam_width_rad])
    written.append(_write_csv(folder / "scans.csv", [
        "station", "source_file", "csv", "beams", "bins", "bin_size_m", "start_range_m", "full_scale",
        "yaw_rad", "depth_m", "timestamp_unix_s", "sonar_model", "beam_width_rad"], rows))
    return written


def write_tables(build: SiteBuild, folder: Path) -> list[Path]:
    """``poses.csv``, ``pairs.csv`` and ``dimensions.csv`` from the site result."""
    result = build.result
    return [
        _write_csv(folder / "poses.csv", ["index", "station", "file", "x_m", "y_m", "yaw_rad", "depth_m", "placed",
                                          "sigma_x_m", "sigma_y_m", "reason"],
                   [[s.index, s.id, s.file, s.x_m, s.y_m, s.yaw_rad, s.depth_m, s.placed, s.sigma_x_m, s.sigma_y_m,
                     s.reason] for s in result.scans]),
        _write_csv(folder / "pairs.csv", ["i", "j", "dx_m", "dy_m", "dyaw_rad", "weight", "converged", "iterations",
                                          "reason"],
                   [[p.i, p.j, p.dx_m, p.dy_m, p.dyaw_rad, p.weight, p.converged, p.iterations, p.reason]
                    for p in result.pairs]),
        _write_csv(folder / "dimensions.csv", ["name", "reference_kind", "reference_m", "map_m", "diff_m", "depth_m",
                                               "probe_std_m", "probes_m"],
                   [[d.name, d.reference_kind, d.reference_m, d.map_m, d.diff_m, d.depth_m, d.probe_std_m,
                     " ".join(f"{p:.4f}" for p in d.probes_m)] for d in result.dimensions]),
    ]


def write_grids(build: SiteBuild, folder: Path) -> list[Path]:
    """One PNG per depth slice (255 occupied, 0 free, 128 unknown; north up) and ``grids.csv``."""
    from cistern_archive.grid.export import write_png

    if build.map_result is None:
        return []
    written, rows = [], []
    for k, grid in enumerate(build.map_result.grids):
        name = f"grids/slice-{k:02d}.png"
        written.append(write_png(folder / name, grid))
        h, w = grid.log_odds.shape
        rows.append([name, grid.depth_m, grid.origin_xy_m[0], grid.origin_xy_m[1], grid.cell_m, w, h])
    written.append(_write_csv(folder / "grids.csv", ["png", "depth_m", "origin_x_m", "origin_y_m", "cell_m",
                                                     "width_cells", "height_cells"], rows))
    return written


def write_mesh(build: SiteBuild, folder: Path) -> list[Path]:
    """``model.ply``: the pipeline's wall surface (map frame, metres, z up)."""
    from cistern_archive.report.model3d import export_ply, render_mesh

    if build.mesh is None:
        return []
    return [export_ply(render_mesh(build.mesh), folder / "model.ply")]


def write_preservation(build: SiteBuild, folder: Path) -> list[Path]:
    """Every preservation file of a built site under ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    written = write_scans(build, folder) + write_tables(build, folder)
    return written + write_grids(build, folder) + write_mesh(build, folder)
