"""Evidence-grid storage: tiled sparse store vs a dense array vs OctoMap, time and memory.

Scene: an L-shaped water gallery, 40 m east then 40 m north, 1.5 m wide, one 200-beam scan every 2.5 m
(range 6 m), cells of 0.05 m — the case the issue names ("a 40 m gallery at 0.05 m cells").

* ``tiled``  — :class:`cistern_plugins.evidence_grid.EvidenceGridMapper` (64 × 64 tiles on touch);
* ``dense``  — the same per-scan updates added into one float32 array over the gallery's bounding box;
* ``octomap`` — ``octomap-python`` (optional; skipped when not installed): each scan inserted as a
  point cloud of its echoes (rays to the echo, free space along them) at the same resolution. OctoMap
  models the beam as a line, not a 3° cone, so it does less work per beam; its memory is
  ``OcTree.memoryUsage()`` (C++ allocations are invisible to tracemalloc).

Python allocations are measured with :mod:`tracemalloc` (peak during the build). Usage::

    .venv/bin/python benchmarks/grid_store.py [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tracemalloc

import numpy as np

from cistern_archive.grid.evidence import SonarModel, scan_window
from cistern_archive.grid.polygon import polygon_scan
from cistern_archive.pipeline.contracts import Poses
from cistern_plugins.evidence_grid import EvidenceGridMapper, GridParams

CELL = 0.05


def gallery():
    outline = np.array([[0, 0], [41.5, 0], [41.5, 41.5], [40, 41.5], [40, 1.5], [0, 1.5]], float)
    stations = [(x, 0.75) for x in np.arange(1.0, 40.0, 2.5)] + [(40.75, y) for y in np.arange(2.5, 41.0, 2.5)]
    rng = np.random.default_rng(0)
    scans = [polygon_scan([outline], xy, 0.0, rng=rng, n_beams=200, max_range_m=6.0, range_noise_m=0.02)
             for xy in stations]
    poses = Poses(xy_m=np.array(stations), yaw_rad=np.zeros(len(stations)), placed=np.ones(len(stations), bool),
                  reasons=("",) * len(stations), reference=0)
    return scans, poses


def measure(func):
    tracemalloc.start()
    t0 = time.perf_counter()
    out = func()
    seconds = time.perf_counter() - t0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return out, seconds, peak


def run_tiled(scans, poses):
    result, seconds, peak = measure(lambda: EvidenceGridMapper().build(scans, poses, GridParams(cell_m=CELL)))
    return {"seconds": seconds, "peak_python_bytes": peak, "store_bytes": int(result.stats["tile_bytes"]),
            "tiles": int(result.stats["tiles"]), "exported_grid_bytes": int(result.grids[0].log_odds.nbytes)}


def run_dense(scans, poses):
    model = SonarModel()

    def build():
        windows = [scan_window(s, poses.xy_m[k], poses.yaw_rad[k], origin_xy_m=(0.0, 0.0), cell_m=CELL, model=model)
                   for k, s in enumerate(scans)]
        r0 = min(w.row0 for w in windows)
        c0 = min(w.col0 for w in windows)
        r1 = max(w.row0 + w.delta.shape[0] for w in windows)
        c1 = max(w.col0 + w.delta.shape[1] for w in windows)
        dense = np.zeros((r1 - r0, c1 - c0), np.float32)
        for w in windows:
            dense[w.row0 - r0 : w.row0 - r0 + w.delta.shape[0], w.col0 - c0 : w.col0 - c0 + w.delta.shape[1]] += w.delta
            np.clip(dense, model.clamp_min, model.clamp_max, out=dense)
        return dense

    dense, seconds, peak = measure(build)
    return {"seconds": seconds, "peak_python_bytes": peak, "store_bytes": int(dense.nbytes), "shape": list(dense.shape)}


def run_octomap(scans, poses):
    try:
        import octomap
    except ImportError:
        return None
    tree = octomap.OcTree(CELL)
    clouds = []
    for k, s in enumerate(scans):
        pts = s.points(yaw_rad=float(poses.yaw_rad[k])) + poses.xy_m[k]
        clouds.append((np.column_stack([pts, np.zeros(len(pts))]).astype(np.float64),
                       np.array([poses.xy_m[k][0], poses.xy_m[k][1], 0.0])))
    t0 = time.perf_counter()
    per_scan = []
    for cloud, origin in clouds:
        t1 = time.perf_counter()
        tree.insertPointCloud(cloud, origin)
        per_scan.append(time.perf_counter() - t1)
    seconds = time.perf_counter() - t0
    return {"seconds": seconds, "median_scan_seconds": float(np.median(per_scan)),
            "store_bytes": int(tree.memoryUsage()), "leaf_nodes": int(tree.getNumLeafNodes())}


def one_scan_times(scans, poses):
    model = SonarModel()
    t = []
    for k, s in enumerate(scans):
        t0 = time.perf_counter()
        scan_window(s, poses.xy_m[k], poses.yaw_rad[k], origin_xy_m=(0.0, 0.0), cell_m=CELL, model=model)
        t.append(time.perf_counter() - t0)
    return float(np.median(t))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    scans, poses = gallery()
    out = {
        "scans": len(scans),
        "beams_per_scan": 200,
        "cell_m": CELL,
        "bbox_m": [41.5, 41.5],
        "tiled": run_tiled(scans, poses),
        "dense": run_dense(scans, poses),
        "octomap": run_octomap(scans, poses),
        "cone_update_median_scan_seconds": one_scan_times(scans, poses),
    }
    print(f"{len(scans)} scans of 200 beams, L-shaped gallery 40 m + 40 m, cells {CELL} m")
    for name in ("tiled", "dense", "octomap"):
        r = out[name]
        if r is None:
            print(f"{name:8s} not installed")
            continue
        peak = f"{r['peak_python_bytes'] / 1e6:8.2f} MB peak" if "peak_python_bytes" in r else " " * 16
        print(f"{name:8s} {r['seconds']:7.3f} s  store {r['store_bytes'] / 1e6:8.2f} MB  {peak}")
    print(f"cone inverse model, one scan: {1000 * out['cone_update_median_scan_seconds']:.1f} ms (median)")
    if out["octomap"]:
        print(f"octomap insertPointCloud, one scan: {1000 * out['octomap']['median_scan_seconds']:.2f} ms (median)")
    if args.json:
        print(json.dumps(out, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
