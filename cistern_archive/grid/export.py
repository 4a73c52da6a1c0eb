"""Deterministic exports of evidence grids: 8-bit grayscale PNG and a numeric ``.npz`` archive.

Both writers produce byte-identical files for identical grids: the PNG holds only IHDR, IDAT and IEND
chunks (no time or text metadata) and the ``.npz`` members carry a fixed 1980-01-01 timestamp. Files are
written to a temporary sibling and renamed into place.
"""

from __future__ import annotations

import io
import os
import struct
import zipfile
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cistern_archive.core.files import write_bytes_atomic
from cistern_archive.core.grids import EvidenceGrid


def grid_image(grid: EvidenceGrid) -> np.ndarray:
    """Occupancy as uint8 (255 = occupied, 0 = free, 128 = unknown), north (+y) up."""
    prob = grid.probability()
    img = np.round(255.0 * prob).astype(np.uint8)
    img[grid.log_odds == 0] = 128
    return np.ascontiguousarray(img[::-1])


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
    """Write the grid's occupancy image (see :func:`grid_image`) as a PNG."""
    write_bytes_atomic(Path(path), png_bytes(grid_image(grid)))
    return Path(path)


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """A deterministic, compressed ``.npz`` (readable with :func:`numpy.load`)."""
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
    """Write every slice: ``log_odds_<k>`` arrays plus ``origin_xy_m``, ``cell_m`` and ``depth_m`` (K,)."""
    arrays: dict[str, np.ndarray] = {
        f"log_odds_{k}": np.asarray(g.log_odds, dtype=np.float32) for k, g in enumerate(grids)
    }
    arrays["origin_xy_m"] = np.array([g.origin_xy_m for g in grids], dtype=np.float64).reshape(-1, 2)
    arrays["cell_m"] = np.array([g.cell_m for g in grids], dtype=np.float64)
    arrays["depth_m"] = np.array([g.depth_m for g in grids], dtype=np.float64)
    write_bytes_atomic(Path(path), npz_bytes(arrays))
    return Path(path)


def read_npz(path: str | os.PathLike) -> list[EvidenceGrid]:
    """Read back what :func:`write_npz` wrote."""
    with np.load(path, allow_pickle=False) as data:
        n = data["cell_m"].size
        return [
            EvidenceGrid(
                log_odds=data[f"log_odds_{k}"],
                origin_xy_m=(float(data["origin_xy_m"][k, 0]), float(data["origin_xy_m"][k, 1])),
                cell_m=float(data["cell_m"][k]),
                depth_m=float(data["depth_m"][k]),
            )
            for k in range(n)
        ]
