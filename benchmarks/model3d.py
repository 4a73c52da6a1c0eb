"""The 3D model of every simulated demo site against the simulator's true wall surface.

For each record in the catalog with a simulator spec (``simulation:``) and truth poses, the pipeline
builds the site (its ``mesh`` step makes the wall surface, :mod:`cistern_archive.grid.surface`); the
mesh is moved from the map frame into the simulator's frame by the least-squares rigid alignment of the
placed stations onto their true positions (:func:`cistern_archive.evaluation.align_rigid_2d`), and
every triangle is scored at its centroid against the true walls at the centroid's depth
(:func:`cistern_archive.sonar.geometry.interpolate_slice`, the walls the simulator echoed):

* ``median_surface_m``, ``p95_surface_m``: area-weighted median and 95th percentile of the horizontal
  distance from the mesh to the true wall;
* ``outside_area_fraction``: share of the mesh area lying outside the true walls (in rock) by more than
  ``OUTSIDE_TOLERANCE_M``;
* ``area_m2``, ``triangles``, ``depth_range_m``, ``seconds`` (the mesh step).

Usage::

    .venv/bin/python benchmarks/model3d.py [--catalog catalog] [--site ID ...] [--json]

The last line of ``--json`` is ``{"sites": {ID: {"median_surface_m", "p95_surface_m",
"outside_area_fraction", ...}}}``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUTSIDE_TOLERANCE_M = 0.10

from cistern_archive.catalog.loader import load_record, record_paths  # noqa: E402
from cistern_archive.evaluation import align_rigid_2d  # noqa: E402
from cistern_archive.pipeline.runner import build_site  # noqa: E402
from cistern_archive.sonar.geometry import contains, edges_of, interpolate_slice  # noqa: E402
from cistern_archive.simulation.spec import load_spec  # noqa: E402


def distance_to_rings(points: np.ndarray, rings) -> np.ndarray:
    """Horizontal distance from each point (N, 2) to the nearest edge of the rings."""
    a, b = edges_of(rings)
    ab = b - a
    out = np.empty(len(points))
    for start in range(0, len(points), 2048):
        p = points[start:start + 2048, None, :]
        t = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
        out[start:start + 2048] = np.linalg.norm(p - (a + t[..., None] * ab), axis=-1).min(axis=1)
    return out


def weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> float:
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, q * cumulative[-1])])


def to_world(build, xy: np.ndarray) -> np.ndarray:
    """Map-frame points into the simulator's frame, by the rigid alignment of the placed stations."""
    truth = {t.station: (t.x_m, t.y_m) for t in build.record.truth}
    placed = [k for k, s in enumerate(build.result.scans) if s.placed and s.id in truth]
    source = np.array([[build.result.scans[k].x_m, build.result.scans[k].y_m] for k in placed])
    target = np.array([truth[build.result.scans[k].id] for k in placed])
    rotation, translation = align_rigid_2d(source, target)
    return xy @ rotation.T + translation


def score(build, spec) -> dict:
    """The figures of one site's mesh (see the module docstring)."""
    mesh = build.mesh
    if mesh is None:
        return {"median_surface_m": None, "p95_surface_m": None, "outside_area_fraction": None,
                "note": "no mesh"}
    centroids = mesh.points[mesh.triangles].mean(axis=1)
    areas = mesh.triangle_areas()
    world = to_world(build, centroids[:, :2])
    depths = -centroids[:, 2]
    levels = spec.site.slices()
    distance = np.empty(len(world))
    outside = np.zeros(len(world), dtype=bool)
    keys = np.round(depths / 0.05).astype(int)
    for key in np.unique(keys):
        pick = keys == key
        rings = interpolate_slice(levels, key * 0.05)
        distance[pick] = distance_to_rings(world[pick], rings)
        outside[pick] = ~contains(rings, world[pick]) & (distance[pick] > OUTSIDE_TOLERANCE_M)
    return {
        "median_surface_m": round(weighted_quantile(distance, areas, 0.5), 4),
        "p95_surface_m": round(weighted_quantile(distance, areas, 0.95), 4),
        "outside_area_fraction": round(float(areas[outside].sum() / areas.sum()), 4),
        "area_m2": round(float(areas.sum()), 2),
        "triangles": mesh.n_triangles,
        "depth_range_m": [round(d, 2) for d in mesh.depth_range_m],
        "seconds": build.result.timings_s.get("mesh"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", type=Path, default=ROOT / "catalog")
    parser.add_argument("--site", action="append", default=[], help="only this site id (repeatable)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON on the last line")
    args = parser.parse_args(argv)
    sites = {}
    for path in record_paths(args.catalog):
        loaded = load_record(path, args.catalog)
        record = loaded.record
        if record.simulation is None or not record.truth or (args.site and record.id not in args.site):
            continue
        build = build_site(loaded)
        sites[record.id] = score(build, load_spec(loaded.resolve(record.simulation)))
        if not args.json:
            print(record.id, sites[record.id])
    if args.json:
        print(json.dumps({"sites": sites}, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
