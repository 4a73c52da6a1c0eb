"""Preservation formats of a published build: open CSV tables, lossless PNG grids and a PLY mesh.

Everything a report shows is also written in a format that needs no software of this project to read.
The copies are made from the published site folder, not from a new build, with the writers of
:mod:`cistern_archive.pipeline.export`, so each is byte-identical to the report's download of the same
thing:

- ``dimensions.csv``, ``pairs.csv``, ``scans.csv`` — the tables of the site's ``result.json``;
- ``grid-<k>.png`` and ``grids.csv`` — every evidence-grid slice of ``grid.npz`` (black occupied,
  white free, grey unknown; north up) with its georeference;
- ``model.ply`` — the published 3D model (map frame, metres, z up), when the report exported one;
- ``raw-scans.csv`` and ``scans/<station>.csv`` — every raw scan (settings; bearing and intensities,
  one row per beam, one column per range bin), read from the raw inputs given.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np

from cistern_archive.catalog.loader import LoadedRecord
from cistern_archive.catalog.models import ScanRef
from cistern_archive.core.errors import CisternError
from cistern_archive.core.files import write_bytes_atomic
from cistern_archive.core.scan import Scan
from cistern_archive.pipeline import export
from cistern_archive.pipeline.results import SiteResult
from cistern_archive.pipeline.runner import RESULT_FILE, load_scan

MODEL_PLY = "model.ply"
RAW_SCANS_CSV = "raw-scans.csv"


def _precise(value: float | None) -> str:
    """A setting at full precision (the tables' 4 decimals would round a beam width in radians)."""
    return "" if value is None else f"{float(value):.12g}"


def _intensity_rows(scan: Scan) -> list[list[str | int | float]]:
    return [[f"{bearing:.6f}", *(int(v) if float(v).is_integer() else float(v) for v in row)]
            for bearing, row in zip(np.asarray(scan.bearings_rad), np.asarray(scan.intensities))]


def write_raw_scans(loaded: LoadedRecord, raw_root: Path, folder: Path) -> list[Path]:
    """``scans/<station>.csv`` (bearing + intensities) of every scan the record references, read from the
    copies of its inputs under ``raw_root``, and ``raw-scans.csv`` (one row per scan: its settings, or why
    it could not be read)."""
    from_raw = dataclasses.replace(loaded, root=raw_root)
    written, rows = [], []
    for ref in loaded.record.scans:
        try:
            scan = load_scan(from_raw, ref)
        except (CisternError, OSError, ValueError) as exc:
            rows.append([ref.station, ref.file, "", *[""] * 10, f"not readable: {exc}"])
            continue
        written.append(_write_scan(scan, ref, folder))
        rows.append([ref.station, ref.file, written[-1].relative_to(folder).as_posix(), len(scan.bearings_rad),
                     scan.intensities.shape[1], _precise(scan.bin_size_m), _precise(scan.start_range_m),
                     _precise(scan.full_scale), _precise(scan.yaw_rad), _precise(scan.depth_m),
                     _precise(scan.timestamp), scan.sonar_model, _precise(scan.beam_width_rad), ""])
    written.append(export.write_csv(folder / RAW_SCANS_CSV, [
        "station", "source_file", "csv", "beams", "bins", "bin_size_m", "start_range_m", "full_scale",
        "yaw_rad", "depth_m", "timestamp_unix_s", "sonar_model", "beam_width_rad", "problem"], rows))
    return written


def _write_scan(scan: Scan, ref: ScanRef, folder: Path) -> Path:
    path = folder / "scans" / f"{ref.station}.csv"  # the record's label: validated to name a file, unique
    header = ["bearing_rad"] + [f"bin_{b:04d}" for b in range(scan.intensities.shape[1])]
    return export.write_csv(path, header, _intensity_rows(scan))


def write_derived(site_dir: Path, folder: Path) -> list[Path]:
    """The tables, grid images and 3D model of the published site folder ``site_dir`` into ``folder``.

    Raises
    ------
    CisternError
        Naming the file, when the site's ``result.json`` or ``grid.npz`` cannot be read.
    """
    try:
        result = SiteResult.model_validate_json((site_dir / RESULT_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise CisternError(f"{site_dir / RESULT_FILE}: cannot read the published result ({exc})") from None
    names = list(export.write_tables(result, folder).values())
    if (site_dir / export.GRID_NPZ).is_file():
        names += export.write_grid_pngs(export.read_npz(site_dir / export.GRID_NPZ), folder).values()
    if (site_dir / MODEL_PLY).is_file():
        write_bytes_atomic(folder / MODEL_PLY, (site_dir / MODEL_PLY).read_bytes())
        names.append(MODEL_PLY)
    return [folder / name for name in names]


def write_preservation(site_dir: Path, loaded: LoadedRecord, raw_root: Path, folder: Path) -> list[Path]:
    """Every preservation file of a published site under ``folder`` (replaced when it exists).

    Parameters
    ----------
    site_dir : Path
        The published site folder (its ``result.json``, ``grid.npz`` and ``model.ply``).
    loaded : LoadedRecord
        The site's record, naming its scans.
    raw_root : Path
        Where the record's inputs are, at their catalog paths (the bag's ``raw/``).
    folder : Path
        The preservation folder to write.
    """
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    return write_derived(site_dir, folder) + write_raw_scans(loaded, raw_root, folder)

