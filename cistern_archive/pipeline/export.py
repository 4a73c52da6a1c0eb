"""Open-format exports of a site build: ``grid.npz``, one PNG per grid slice, and the CSV tables.

This module is the one writer (and, for ``grid.npz``, reader) of these files. The report's downloads,
the archive's preservation copies and the BagIt export all write them here, so the same build gives the
same bytes wherever a file appears:

* ``grid.npz`` — every slice's ``log_odds_<k>`` (float32) with ``origin_xy_m`` (K, 2), ``cell_m`` (K,)
  and ``depth_m`` (K,); :func:`read_npz` reads it back into :class:`~cistern_archive.core.grids.EvidenceGrid`;
* ``grid-<k>.png`` — one pixel per cell, north up, 8-bit grayscale: **black occupied, white free, grey
  unknown** (:func:`grid_image`), with ``grids.csv`` giving each slice's georeference;
* ``dimensions.csv``, ``pairs.csv``, ``scans.csv`` — the result's tables (:data:`TABLES`).

Every file is deterministic: the PNG holds only IHDR, IDAT and IEND chunks, the ``.npz`` members carry a
fixed 1980-01-01 time, CSV floats have fixed decimals and ``\\n`` line endings. Files are written through
:mod:`cistern_archive.core.files` (a temporary sibling renamed into place).
"""

from __future__ import annotations

import csv
import io
import math
import os
import struct
import zipfile
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cistern_archive.core.errors import CisternError
from cistern_archive.core.files import write_bytes_atomic
from cistern_archive.core.grids import EvidenceGrid
from cistern_archive.core.scan import compass_deg_from_yaw
from cistern_archive.pipeline.results import DimensionResult, SiteResult

GRID_NPZ = "grid.npz"
GRIDS_CSV = "grids.csv"
UNKNOWN_GREY = 128
"""The grey of a cell no beam reached (log-odds exactly 0)."""


# ------------------------------------------------------------------------------------------ grid.npz
def npz_bytes(arrays: Mapping[str, np.ndarray]) -> bytes:
    """A compressed ``.npz`` (readable with :func:`numpy.load`), identical for identical arrays.

    Members are written in sorted name order with a fixed time and fixed permissions
    (:func:`numpy.savez_compressed` would stamp them with the wall clock).
    """
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(arrays):
            member = io.BytesIO()
            np.lib.format.write_array(member, np.asarray(arrays[name]), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, member.getvalue())
    return buffer.getvalue()


def write_npz(path: str | os.PathLike, grids: Sequence[EvidenceGrid]) -> Path:
    """Write every slice: ``log_odds_<k>`` (float32) plus ``origin_xy_m`` (K, 2), ``cell_m`` and ``depth_m`` (K,)."""
    arrays: dict[str, np.ndarray] = {
        f"log_odds_{k}": np.asarray(g.log_odds, dtype=np.float32) for k, g in enumerate(grids)
    }
    arrays["origin_xy_m"] = np.array([g.origin_xy_m for g in grids], dtype=np.float64).reshape(-1, 2)
    arrays["cell_m"] = np.array([g.cell_m for g in grids], dtype=np.float64)
    arrays["depth_m"] = np.array([g.depth_m for g in grids], dtype=np.float64)
    write_bytes_atomic(Path(path), npz_bytes(arrays))
    return Path(path)


def read_npz(path: str | os.PathLike) -> list[EvidenceGrid]:
    """Read back what :func:`write_npz` wrote.

    Raises
    ------
    CisternError
        Naming the file, when it is not a ``.npz`` or lacks an array of the layout above.
    """
    try:
        with np.load(path, allow_pickle=False) as data:
            n = int(data["cell_m"].size)
            return [
                EvidenceGrid(
                    log_odds=data[f"log_odds_{k}"],
                    origin_xy_m=(float(data["origin_xy_m"][k, 0]), float(data["origin_xy_m"][k, 1])),
                    cell_m=float(data["cell_m"][k]),
                    depth_m=float(data["depth_m"][k]),
                )
                for k in range(n)
            ]
    except KeyError as exc:
        raise CisternError(f"{path}: not a grid archive of this layout (missing {exc.args[0]})") from None
    except (OSError, ValueError, IndexError, zipfile.BadZipFile) as exc:
        raise CisternError(f"{path}: cannot read the grid archive ({exc})") from None


# ------------------------------------------------------------------------------------------ grid PNGs
def grid_image(grid: EvidenceGrid) -> np.ndarray:
    """Occupancy as uint8, north (+y) up: black (0) occupied, white (255) free, grey (128) unknown.

    The polarity is the map figure's (``gray_r``), so a slice reads the same in the report and in its
    download; a cell is unknown when its log-odds is exactly 0 (no beam reached it).
    """
    image = np.round(255.0 * (1.0 - grid.probability())).astype(np.uint8)
    image[np.asarray(grid.log_odds) == 0] = UNKNOWN_GREY
    return np.ascontiguousarray(image[::-1])


def png_bytes(image: np.ndarray) -> bytes:
    """Encode a 2-D uint8 array as a grayscale PNG without metadata."""
    image = np.asarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"png_bytes needs a 2-D uint8 array, got {image.dtype} {image.shape}")
    h, w = image.shape
    raw = b"".join(b"\x00" + image[r].tobytes() for r in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")


def write_png(path: str | os.PathLike, grid: EvidenceGrid) -> Path:
    """Write the grid's occupancy image (:func:`grid_image`) as a PNG."""
    write_bytes_atomic(Path(path), png_bytes(grid_image(grid)))
    return Path(path)


def grid_png_name(k: int) -> str:
    """File name of slice ``k``'s PNG."""
    return f"grid-{k}.png"


def write_grid_pngs(grids: Sequence[EvidenceGrid], folder: Path) -> dict[str, str]:
    """``grid-<k>.png`` of every slice and ``grids.csv`` (file, depth, origin, cell, size of each).

    Returns
    -------
    dict
        ``grid-png-<k>`` and ``grids-csv`` → file name in ``folder``.
    """
    files, rows = {}, []
    for k, grid in enumerate(grids):
        name = grid_png_name(k)
        write_png(folder / name, grid)
        files[f"grid-png-{k}"] = name
        h, w = grid.log_odds.shape
        rows.append([name, grid.depth_m, grid.origin_xy_m[0], grid.origin_xy_m[1], grid.cell_m, w, h])
    if grids:
        write_csv(folder / GRIDS_CSV, ["png", "depth_m", "origin_x_m", "origin_y_m", "cell_m", "width_cells",
                                       "height_cells"], rows)
        files["grids-csv"] = GRIDS_CSV
    return files


# ------------------------------------------------------------------------------------------ CSV tables
def format_number(value: float | None, digits: int = 3) -> str:
    """Fixed-point text of a number; empty for ``None`` and NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return f"{value:.{digits}f}"


def csv_bytes(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> bytes:
    """CSV text with ``\\n`` line endings: floats with 4 decimals, booleans as ``true``/``false``,
    ``None`` and NaN as empty cells."""

    def cell(value: Any) -> Any:
        if isinstance(value, bool):
            return str(value).lower()
        if isinstance(value, float):
            return format_number(value, 4)
        return "" if value is None else value

    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([cell(value) for value in row])
    return buffer.getvalue().encode("utf-8")


def write_csv(path: Path, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> Path:
    """Write :func:`csv_bytes` to ``path``."""
    write_bytes_atomic(path, csv_bytes(header, rows))
    return path


def _station(result: SiteResult, k: int) -> str:
    return result.scans[k].id if 0 <= k < len(result.scans) and result.scans[k].id else f"scan {k}"


def diff_percent(dimension: DimensionResult) -> float | None:
    """The map's signed difference from the reference as a percentage of the reference."""
    return None if dimension.diff_m is None else 100.0 * dimension.diff_m / dimension.reference_m


def dimensions_table(result: SiteResult) -> tuple[list[str], list[list[Any]]]:
    """Map against reference for every measured dimension; ``probes_m`` is ``;``-separated."""
    header = ["name", "reference_kind", "depth_m", "map_m", "ci95_m", "reference_m", "diff_m", "diff_percent",
              "probe_std_m", "n_probes", "probes_m"]
    rows = [[d.name, d.reference_kind, d.depth_m, d.map_m, d.ci95_m, d.reference_m, d.diff_m, diff_percent(d),
             d.probe_std_m, len(d.probes_m), ";".join(format_number(p, 4) for p in d.probes_m)]
            for d in result.dimensions]
    return header, rows


def pairs_table(result: SiteResult) -> tuple[list[str], list[list[Any]]]:
    """Every pair match, with the station labels of both scans."""
    header = ["i", "j", "station_i", "station_j", "dx_m", "dy_m", "dyaw_rad", "weight", "converged", "iterations",
              "reason"]
    rows = [[p.i, p.j, _station(result, p.i), _station(result, p.j), p.dx_m, p.dy_m, p.dyaw_rad, p.weight,
             p.converged, p.iterations, p.reason] for p in result.pairs]
    return header, rows


def scans_table(result: SiteResult) -> tuple[list[str], list[list[Any]]]:
    """Every scan, placed or not: position, its standard deviations, heading and depth, the reason it is
    unplaced and its echo scale (:attr:`~cistern_archive.pipeline.results.ScanPose.echo_scale`, empty where
    none was estimated)."""
    header = ["index", "station", "file", "placed", "x_m", "y_m", "sigma_x_m", "sigma_y_m", "yaw_rad",
              "heading_deg", "depth_m", "reason", "echo_scale"]
    rows = [[s.index, s.id, s.file, s.placed, s.x_m, s.y_m, s.sigma_x_m, s.sigma_y_m, s.yaw_rad,
             compass_deg_from_yaw(s.yaw_rad), s.depth_m, s.reason, s.echo_scale] for s in result.scans]
    return header, rows


TABLES: dict[str, tuple[str, Callable[[SiteResult], tuple[list[str], list[list[Any]]]]]] = {
    "dimensions-csv": ("dimensions.csv", dimensions_table),
    "pairs-csv": ("pairs.csv", pairs_table),
    "scans-csv": ("scans.csv", scans_table),
}
"""Artifact key → (file name, table of a result)."""


def write_tables(result: SiteResult, folder: Path) -> dict[str, str]:
    """Every table of :data:`TABLES` into ``folder``; returns artifact key → file name."""
    files = {}
    for key, (name, table) in TABLES.items():
        write_csv(folder / name, *table(result))
        files[key] = name
    return files
