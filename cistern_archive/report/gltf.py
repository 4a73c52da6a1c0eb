"""A self-contained binary glTF 2.0 (``.glb``) writer for triangle meshes.

One mesh, one node, positions, normals, per-vertex colours and 32-bit indices in a single embedded
buffer: the file opens in any glTF viewer without side files. glTF is y-up and metric
(glTF 2.0 §3.4); the map frame (x east, y north, z up) maps to glTF as ``(x, z, -y)``. The writer uses
no clock and no random ids, so the same mesh gives the same bytes.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

GLB_MAGIC = 0x46546C67  # "glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
FLOAT, UNSIGNED_BYTE, UNSIGNED_INT = 5126, 5121, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * ((4 - len(data) % 4) % 4)


def map_to_gltf(points: np.ndarray) -> np.ndarray:
    """Map frame (x east, y north, z up) to glTF axes (x, y up, z towards the viewer = south)."""
    p = np.asarray(points, dtype=np.float64)
    return np.column_stack([p[:, 0], p[:, 2], -p[:, 1]])


def glb_bytes(
    points: np.ndarray,
    triangles: np.ndarray,
    *,
    normals: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    name: str = "model",
) -> bytes:
    """Encode a triangle mesh as a GLB file.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Vertices in the map frame (metres, z up).
    triangles : ndarray, shape (M, 3)
        Vertex indices.
    normals : ndarray, shape (N, 3), optional
        Unit vertex normals in the map frame.
    colors : ndarray, shape (N, 3) or (N, 4), uint8, optional
        Vertex colours (sRGB).
    name : str, keyword-only
        Name of the mesh and node.
    """
    pos = map_to_gltf(points).astype(np.float32)
    idx = np.asarray(triangles, dtype=np.uint32).reshape(-1)
    if len(pos) == 0 or len(idx) == 0:
        raise ValueError("cannot write an empty mesh as glTF")
    if idx.max() >= len(pos):
        raise ValueError(f"triangle index {int(idx.max())} out of range for {len(pos)} vertices")
    views: list[dict] = []
    accessors: list[dict] = []
    blob = b""

    def add(data: np.ndarray, component: int, kind: str, target: int, **extra) -> int:
        nonlocal blob
        raw = np.ascontiguousarray(data).tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(raw), "target": target})
        blob = _pad(blob + raw, b"\x00")
        count = data.shape[0] if kind != "SCALAR" else data.size
        accessors.append({"bufferView": len(views) - 1, "componentType": component, "count": int(count),
                          "type": kind, **extra})
        return len(accessors) - 1

    attributes = {
        "POSITION": add(pos, FLOAT, "VEC3", ARRAY_BUFFER,
                        min=[float(v) for v in pos.min(axis=0)], max=[float(v) for v in pos.max(axis=0)]),
    }
    if normals is not None:
        nrm = map_to_gltf(normals).astype(np.float32)
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(length > 0, nrm / np.where(length > 0, length, 1), np.array([0, 1, 0], np.float32))
        attributes["NORMAL"] = add(nrm.astype(np.float32), FLOAT, "VEC3", ARRAY_BUFFER)
    if colors is not None:
        col = np.asarray(colors, dtype=np.uint8)
        if col.shape[1] == 3:
            col = np.column_stack([col, np.full(len(col), 255, np.uint8)])
        attributes["COLOR_0"] = add(col, UNSIGNED_BYTE, "VEC4", ARRAY_BUFFER, normalized=True)
    indices = add(idx, UNSIGNED_INT, "SCALAR", ELEMENT_ARRAY_BUFFER)
    document = {
        "asset": {"version": "2.0", "generator": "cistern-archive"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{"attributes": attributes, "indices": indices, "mode": 4,
                                                   "material": 0}]}],
        "materials": [{"name": "wall", "doubleSided": True,
                       "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.0,
                                                "roughnessFactor": 0.9}}],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    text = _pad(json.dumps(document, separators=(",", ":"), sort_keys=True).encode("utf-8"), b" ")
    total = 12 + 8 + len(text) + 8 + len(blob)
    return b"".join([
        struct.pack("<III", GLB_MAGIC, 2, total),
        struct.pack("<II", len(text), CHUNK_JSON), text,
        struct.pack("<II", len(blob), CHUNK_BIN), blob,
    ])


def read_glb(data: bytes) -> tuple[dict, bytes]:
    """Split a GLB file into its JSON document and binary chunk (checks the header)."""
    magic, version, total = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2 or total != len(data):
        raise ValueError(f"not a glTF 2.0 binary file (magic {magic:#x}, version {version}, length {total})")
    json_len, json_type = struct.unpack_from("<II", data, 12)
    if json_type != CHUNK_JSON:
        raise ValueError("first GLB chunk is not JSON")
    document = json.loads(data[20:20 + json_len])
    bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
    if bin_type != CHUNK_BIN:
        raise ValueError("second GLB chunk is not BIN")
    start = 28 + json_len
    return document, data[start:start + bin_len]


def write_glb(path: Path, mesh, *, colormap: str, depth_range: tuple[float, float]) -> Path:
    """Write a :class:`pyvista.PolyData` triangle mesh (with ``depth_m``) as a GLB coloured by depth."""
    from matplotlib import colormaps

    triangles = mesh.triangulate().faces.reshape(-1, 4)[:, 1:]
    lo, hi = depth_range
    t = (np.asarray(mesh.point_data["depth_m"], dtype=np.float64) - lo) / max(hi - lo, 1e-9)
    colors = (colormaps[colormap](np.clip(t, 0, 1))[:, :3] * 255).round().astype(np.uint8)
    normals = mesh.point_data["Normals"] if "Normals" in mesh.point_data else None
    path.write_bytes(glb_bytes(mesh.points, triangles, normals=normals, colors=colors, name=path.stem))
    return path
