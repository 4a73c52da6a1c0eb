"""The open interchange format: one scan per ``.npz`` file.

A ``.npz`` (a zip of ``.npy`` arrays, readable by numpy and by any zip + npy reader) holding:

==================  ========================  ==============================================
name                dtype / shape             meaning
==================  ========================  ==============================================
``bearings_rad``    float64 (A,)              beam bearings, sonar frame, CCW from forward
``intensities``     device dtype (A, B)       echo intensities, 0 .. ``full_scale``
``metadata``        uint8 (N,)                UTF-8 JSON object (see below)
``beam_times_s``    float64 (A,)              schema version 2 only: time of every beam (Unix s)
==================  ========================  ==============================================

Schema version 2 adds ``beam_times_s`` for scans taken from a moving vehicle; a scan without beam times
is written as version 1, byte for byte as before, and both versions are read.

``metadata`` keys: ``schema`` (``"cistern-archive/scan"``), ``schema_version`` (1), ``full_scale``,
``bin_size_m``, ``start_range_m``, ``yaw_rad``, ``depth_m``, ``timestamp`` (Unix seconds or null),
``sonar_model``, ``beam_width_rad``, ``station``, ``settings`` (object). Floats are written with
``repr`` precision, so a round trip is exact. Files are zip-deflated like ``np.savez_compressed`` output,
but with fixed member timestamps so equal scans give equal bytes; they are written to a temporary
sibling and renamed into place.

Reading checks a file from its headers before anything is decompressed or allocated
(:func:`check_npz`): each member's declared size in the zip directory and the shape and dtype in its
``.npy`` header must agree and stay within :data:`MAX_ARRAY_BYTES` (a 2 MB zip can declare gigabytes
of zeros). Metadata numbers must be finite and a scan must have at least one beam and one bin.
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
import zlib
from pathlib import Path

import numpy as np

from cistern_archive.core.errors import ReaderError
from cistern_archive.core.files import atomic_file
from cistern_archive.core.scan import Scan

SCHEMA = "cistern-archive/scan"
SCHEMA_VERSION = 2
"""The newest version written; :data:`READABLE_VERSIONS` are read."""
READABLE_VERSIONS = (1, 2)


def scan_schema_version(scan: Scan) -> int:
    """2 when the scan has per-beam times, else 1 (the oldest version that holds the scan)."""
    return 2 if scan.beam_times_s is not None else 1
MAX_ARRAY_BYTES = 256 << 20
"""Largest array a scan may hold (a 360° Micron scan is well under 1 MiB)."""
MAX_METADATA_BYTES = 1 << 20
NUMERIC_METADATA = ("full_scale", "bin_size_m", "start_range_m", "yaw_rad", "depth_m", "beam_width_rad")
MEMBERS = ("bearings_rad", "intensities", "metadata")


def scan_metadata(scan: Scan) -> dict:
    return {
        "schema": SCHEMA,
        "schema_version": scan_schema_version(scan),
        "full_scale": float(scan.full_scale),
        "bin_size_m": float(scan.bin_size_m),
        "start_range_m": float(scan.start_range_m),
        "yaw_rad": float(scan.yaw_rad),
        "depth_m": float(scan.depth_m),
        "timestamp": None if math.isnan(scan.timestamp) else float(scan.timestamp),
        "sonar_model": scan.sonar_model,
        "beam_width_rad": float(scan.beam_width_rad),
        "station": scan.station,
        "settings": scan.settings,
    }


def write_scan(scan: Scan, path: str | os.PathLike) -> Path:
    """Write ``scan`` to ``path`` atomically (temporary sibling, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = json.dumps(scan_metadata(scan), sort_keys=True, allow_nan=False).encode("utf-8")
    arrays = {
        "bearings_rad": np.asarray(scan.bearings_rad, dtype=np.float64),
        "intensities": np.asarray(scan.intensities),
        "metadata": np.frombuffer(meta, dtype=np.uint8),
    }
    if scan.beam_times_s is not None:
        arrays["beam_times_s"] = np.asarray(scan.beam_times_s, dtype=np.float64)
    with atomic_file(path, binary=True) as handle:
        _write_npz_deterministic(handle, arrays)
    return path


def _write_npz_deterministic(handle, arrays: dict[str, np.ndarray]) -> None:
    """Like ``np.savez_compressed`` but with fixed zip timestamps, so equal scans give equal bytes."""
    with zipfile.ZipFile(handle, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, array in arrays.items():
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.ascontiguousarray(array), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, buffer.getvalue())


def _npy_header(archive: zipfile.ZipFile, name: str, path: Path) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype of one member, from its ``.npy`` header, checked against the zip's declared size."""
    info = archive.getinfo(f"{name}.npy")
    if info.file_size > MAX_ARRAY_BYTES + 65536:
        raise ReaderError(str(path), f"{name}.npy declares {info.file_size} bytes uncompressed; a scan's arrays "
                                     f"are at most {MAX_ARRAY_BYTES} bytes")
    with archive.open(info) as member:
        try:
            version = np.lib.format.read_magic(member)
            reader = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = reader(member)
        except (ValueError, TypeError, SyntaxError, EOFError) as exc:
            raise ReaderError(str(path), f"{name}.npy: bad .npy header: {exc}") from None
        header_bytes = member.tell()
    if dtype.hasobject:
        raise ReaderError(str(path), f"{name}.npy holds Python objects; only numeric arrays are read")
    nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if nbytes > MAX_ARRAY_BYTES:
        raise ReaderError(str(path), f"{name}.npy header claims shape {shape} of {dtype} ({nbytes} bytes); a "
                                     f"scan's arrays are at most {MAX_ARRAY_BYTES} bytes")
    if header_bytes + nbytes != info.file_size:
        raise ReaderError(str(path), f"{name}.npy header claims shape {shape} of {dtype} ({nbytes} bytes) but "
                                     f"the member holds {info.file_size - header_bytes} bytes of data")
    return shape, dtype


def check_npz(path: str | os.PathLike) -> None:
    """Check an interchange file from its zip directory and ``.npy`` headers only (nothing is decompressed
    beyond the headers, nothing large is allocated).

    Raises
    ------
    ReaderError
        A missing member, a malformed or oversized header, shapes that do not fit together, no beams.
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            missing = [m for m in MEMBERS if f"{m}.npy" not in names]
            if missing:
                raise ReaderError(str(path), f"not a cistern-archive scan: missing arrays {missing}")
            shapes = {m: _npy_header(archive, m, path) for m in MEMBERS}
            times = _npy_header(archive, "beam_times_s", path) if "beam_times_s.npy" in names else None
    except (OSError, zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError, zlib.error) as exc:
        raise ReaderError(str(path), f"unreadable .npz: {type(exc).__name__}: {exc}") from None
    (bearings, _), (intensities, dtype), (metadata, meta_dtype) = (shapes[m] for m in MEMBERS)
    if len(bearings) != 1 or len(intensities) != 2 or intensities[0] != bearings[0]:
        raise ReaderError(str(path), f"bearings_rad {bearings} and intensities {intensities} must be (A,) and "
                                     "(A, B)")
    if bearings[0] == 0 or intensities[1] == 0:
        raise ReaderError(str(path), f"the scan has no data: {bearings[0]} beams of {intensities[1]} bins")
    if dtype.kind not in "uif":
        raise ReaderError(str(path), f"intensities have dtype {dtype}; expected integers or floats")
    if times is not None and (times[0] != bearings or times[1].kind != "f"):
        raise ReaderError(str(path), f"beam_times_s {times[0]} of {times[1]} must be float times, one per beam "
                                     f"{bearings}")
    if len(metadata) != 1 or meta_dtype != np.uint8 or metadata[0] > MAX_METADATA_BYTES:
        raise ReaderError(str(path), f"metadata must be at most {MAX_METADATA_BYTES} uint8 bytes, got shape "
                                     f"{metadata} of {meta_dtype}")


def _check_metadata_numbers(meta: dict, path: Path) -> None:
    for key in NUMERIC_METADATA:
        value = meta.get(key)
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ReaderError(str(path), f"metadata {key} is {value!r}; expected a finite number")
    timestamp = meta.get("timestamp")
    if timestamp is not None and (isinstance(timestamp, bool) or not isinstance(timestamp, (int, float))
                                  or not math.isfinite(timestamp)):
        raise ReaderError(str(path), f"metadata timestamp is {timestamp!r}; expected Unix seconds or null")


def read_scan(path: str | os.PathLike) -> Scan:
    """Read a scan written by :func:`write_scan`.

    Raises
    ------
    ReaderError
        Naming the file and what is missing or wrong.
    """
    path = Path(path)
    check_npz(path)
    try:
        with open(path, "rb") as handle, np.load(handle, allow_pickle=False) as data:
            missing = {"bearings_rad", "intensities", "metadata"} - set(data.files)
            if missing:
                raise ReaderError(str(path), f"not a cistern-archive scan: missing arrays {sorted(missing)}")
            bearings = data["bearings_rad"]
            intensities = data["intensities"]
            meta_bytes = data["metadata"].tobytes()
            beam_times = data["beam_times_s"] if "beam_times_s" in data.files else None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ReaderError(str(path), f"unreadable .npz: {exc}") from None
    try:
        meta = json.loads(meta_bytes.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReaderError(str(path), f"metadata is not UTF-8 JSON: {exc}") from None
    if not isinstance(meta, dict):
        raise ReaderError(str(path), f"metadata is a JSON {type(meta).__name__}, expected an object")
    if meta.get("schema") != SCHEMA:
        raise ReaderError(str(path), f"metadata schema is {meta.get('schema')!r}, expected {SCHEMA!r}")
    version = meta.get("schema_version")
    if version not in READABLE_VERSIONS:
        raise ReaderError(str(path), f"unsupported schema_version {version!r}; this version reads "
                          f"{', '.join(map(str, READABLE_VERSIONS))}")
    if (beam_times is not None) != (version == 2):
        raise ReaderError(str(path), "schema_version 2 needs the array beam_times_s and version 1 has none; "
                          f"this file is version {version} {'with' if beam_times is not None else 'without'} it")
    if not np.all(np.isfinite(bearings)):
        raise ReaderError(str(path), "bearings_rad contains NaN or infinite values")
    _check_metadata_numbers(meta, path)
    timestamp = meta.get("timestamp")
    try:
        return Scan(
            bearings_rad=bearings,
            intensities=intensities,
            full_scale=meta["full_scale"],
            bin_size_m=meta["bin_size_m"],
            start_range_m=meta["start_range_m"],
            yaw_rad=meta["yaw_rad"],
            depth_m=meta["depth_m"],
            timestamp=float("nan") if timestamp is None else float(timestamp),
            sonar_model=meta["sonar_model"],
            beam_width_rad=meta["beam_width_rad"],
            station=meta["station"],
            settings=meta.get("settings", {}),
            beam_times_s=beam_times,
        )
    except KeyError as exc:
        raise ReaderError(str(path), f"metadata lacks {exc.args[0]!r}") from None
    except ValueError as exc:
        raise ReaderError(str(path), str(exc)) from None
