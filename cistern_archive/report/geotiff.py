"""``grid.tif``: the evidence grid for GIS, written only for a georeferenced, unredacted site.

The map frame is local metres, x east and y north (compass aligned), with the reference scan at the
origin; the record's ``location.latitude`` / ``longitude`` are taken as the reference scan's position.
That point is projected to its UTM zone (WGS 84) and the grid laid on it: one band of occupancy
probability per depth slice (float32, 0 free … 1 occupied, ``nan`` unknown), north up, with the CRS and
geotransform in the file and a world file ``grid.tfw`` beside it. A redacted site (``location.redact``,
the default) or one without coordinates gets no GeoTIFF, since its position must not leave the archive.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cistern_archive.grid.volume import UNKNOWN_PROBABILITY, common_lattice, resample
from cistern_archive.pipeline.contracts import MapResult


def georeferenced(record) -> bool:
    """Whether the record gives coordinates it lets the reports publish."""
    location = getattr(record, "location", None)
    return bool(location is not None and not location.redact and location.latitude is not None
                and location.longitude is not None)


def utm_crs(latitude: float, longitude: float) -> str:
    """``EPSG:326ZZ`` (north) or ``EPSG:327ZZ`` (south): the WGS 84 UTM zone of a point."""
    zone = int((longitude + 180.0) // 6.0) % 60 + 1
    return f"EPSG:{32600 + zone if latitude >= 0 else 32700 + zone}"


def write_geotiff(path: Path, map_result: MapResult, latitude: float, longitude: float) -> list[Path]:
    """Write ``path`` (GeoTIFF) and its world file; returns both paths."""
    import rasterio
    from affine import Affine
    from rasterio.warp import transform

    crs = utm_crs(latitude, longitude)
    (east,), (north,) = transform("EPSG:4326", crs, [longitude], [latitude])
    grids = sorted(map_result.grids, key=lambda g: g.depth_m)
    origin, cell, (rows, cols) = common_lattice(grids)
    bands = []
    for grid in grids:
        probability = resample(grid, origin, cell, (rows, cols)).astype(np.float32)
        probability[probability == UNKNOWN_PROBABILITY] = np.nan  # log-odds 0, or outside the slice
        bands.append(probability[::-1])  # north up
    west, top = east + origin[0], north + origin[1] + rows * cell
    geotransform = Affine(cell, 0.0, west, 0.0, -cell, top)  # north up
    with rasterio.open(path, "w", driver="GTiff", width=cols, height=rows, count=len(bands), dtype="float32",
                       crs=crs, transform=geotransform, nodata=np.nan, compress="deflate") as out:
        for k, (band, grid) in enumerate(zip(bands, grids), start=1):
            out.write(band, k)
            out.set_band_description(k, f"occupancy probability at depth {grid.depth_m:.2f} m")
    world = path.with_suffix(".tfw")
    world.write_text("\n".join(f"{v:.6f}" for v in (cell, 0.0, 0.0, -cell, west + cell / 2, top - cell / 2)) + "\n",
                     encoding="ascii")
    return [path, world]

