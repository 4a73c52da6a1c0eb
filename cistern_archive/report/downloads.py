"""The page's Downloads section: every file of the site a reader may want, with its size."""

from __future__ import annotations

from pathlib import Path


def human_size(n_bytes: int) -> str:
    """A file size as a reader writes it: bytes, KiB or MiB."""
    if n_bytes < 1024:
        return f"{n_bytes} B"
    if n_bytes < 1024 ** 2:
        return f"{n_bytes / 1024:.1f} KiB"
    return f"{n_bytes / 1024 ** 2:.1f} MiB"


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
    ("grids-csv", "Grid images' georeference (CSV)", "depth, origin, cell size and size of every grid image"),
)


UNSIZED_DOWNLOADS = frozenset({"result", "report-pdf"})
"""Downloads whose size is not printed: ``result.json`` holds the build's timings, so its size changes
from build to build and would make the page differ while nothing else has; ``report.pdf`` is printed
from the finished page."""


def download_rows(artifacts: dict[str, str], site_dir: Path) -> list[dict[str, str]]:
    """One row (file, title, description, size) per artifact of :data:`DOWNLOADS`, then the grid images."""
    out = []
    for key, title, description in DOWNLOADS:
        if key in artifacts:
            size = "" if key in UNSIZED_DOWNLOADS else human_size((site_dir / artifacts[key]).stat().st_size)
            out.append({"file": artifacts[key], "title": title, "description": description, "size": size})
    for key in sorted(k for k in artifacts if k.startswith("grid-png-")):
        k = int(key.rsplit("-", 1)[1])
        out.append({"file": artifacts[key], "title": f"Grid image, slice {k + 1}",
                    "description": "one pixel per cell, north up: black occupied, white free, grey unknown "
                                   "(georeferenced by grids.csv)",
                    "size": human_size((site_dir / artifacts[key]).stat().st_size)})
    return out
