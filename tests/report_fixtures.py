"""Synthetic site builds for the report tests and the report benchmark.

A rectangular pool (the paper's 3.61 m × 7.21 m) scanned from four stations: raw fans with a Gaussian
wall echo and speckle, segmented ranges, pair matches with particle-filter style histories, poses, one
or several evidence-grid slices and a dimension table measured with probe lines on the grid.
Everything is computed from the geometry with a seeded generator; nothing depends on the pipeline.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cistern_archive.catalog.models import SiteRecord
from cistern_archive.pipeline.contracts import (
    DimensionRow,
    DimensionTable,
    EvidenceGrid,
    HistoryThreshold,
    MapResult,
    MatchHistory,
    MatchResult,
    Poses,
)
from cistern_archive.pipeline.results import (
    PairResult,
    PluginProvenance,
    Provenance,
    ScanPose,
    SiteBuild,
    SiteResult,
    StageFailure,
)
from cistern_archive.grid.surface import wall_surface
from cistern_archive.pipeline.assemble import dimension_result
from cistern_archive.pipeline.status import site_status
from cistern_archive.core.scan import RangeScan, Scan

WIDTH_M, LENGTH_M = 3.61, 7.21
STATIONS_POOL = np.array([[1.0, 1.4], [2.6, 2.2], [1.1, 5.6], [2.5, 6.1]])
CELL_M = 0.05
LATITUDE, LONGITUDE = 35.88567, 14.40321


def rectangle_range(xy: np.ndarray, angles: np.ndarray, half: tuple[float, float], centre: tuple[float, float]) -> np.ndarray:
    """Distance from ``xy`` (inside) along each angle to the walls of an axis-aligned rectangle."""
    dx, dy = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(dx > 0, (centre[0] + half[0] - xy[0]) / dx, (centre[0] - half[0] - xy[0]) / dx)
        ty = np.where(dy > 0, (centre[1] + half[1] - xy[1]) / dy, (centre[1] - half[1] - xy[1]) / dy)
    return np.minimum(np.abs(tx), np.abs(ty))


def make_record(site_id: str, name: str, *, redact: bool = True, n_scans: int = 4) -> SiteRecord:
    return SiteRecord.model_validate({
        "id": site_id,
        "name": name,
        "description": "Rectangular pool used to validate the mapping (simulated for the report tests).",
        "expedition": {"name": "LAIR validation", "date": "2011-06-01", "team": ["A. Diver", "B. Pilot"]},
        "location": {"place": "San Luis Obispo", "latitude": LATITUDE, "longitude": LONGITUDE, "redact": redact},
        "sonar": {"frequency_khz": 675, "range_m": 10, "bins": 200, "step_deg": 0.9},
        "scans": [{"file": f"{site_id}/scan{k + 1}.npz", "station": f"S{k + 1}", "yaw_deg": 90.0, "depth_m": 1.5}
                  for k in range(n_scans)],
        "references": [
            {"name": "Width", "value_m": WIDTH_M, "kind": "truth",
             "measure": {"frame": "S1", "inside": [0.8, 2.0], "direction_deg": 0, "repeats": 10, "spacing_m": 0.3}},
            {"name": "Length", "value_m": LENGTH_M, "kind": "mosaic",
             "measure": {"frame": "S1", "inside": [0.8, 2.0], "direction_deg": 90, "repeats": 10, "spacing_m": 0.2}},
        ],
        "seed": 7,
    })


def make_scans(stations: np.ndarray, rng: np.random.Generator, *, half, centre, depth_m: float = 1.5):
    bearings = np.deg2rad(np.arange(0, 360, 0.9))
    bins, bin_size = 200, 0.05
    centres = (np.arange(bins) + 0.5) * bin_size
    raw, ranged = [], []
    for k, xy in enumerate(stations):
        truth = rectangle_range(xy, bearings, half, centre)
        noisy = truth + rng.normal(0, 0.03, len(truth))
        echo = 200 * np.exp(-0.5 * ((centres[None, :] - noisy[:, None]) / 0.06) ** 2)
        speckle = rng.gamma(1.5, 8.0, size=echo.shape) * (centres[None, :] < noisy[:, None] + 1.0)
        intensities = np.clip(echo + speckle, 0, 255).astype(np.uint8)
        station = f"S{k + 1}"
        raw.append(Scan(bearings, intensities, 255.0, bin_size, yaw_rad=0.0, depth_m=depth_m,
                        timestamp=1.3e9 + 600 * k, sonar_model="Tritech Micron DST", station=station))
        peak = centres[np.argmax(intensities, axis=1)]
        ranges = np.where(intensities.max(axis=1) > 50, peak, np.nan)
        ranged.append(RangeScan(bearings, ranges, 0.0, depth_m, bins * bin_size, bin_size, math.radians(3), station))
    return raw, ranged


def make_history(truth: np.ndarray, rng: np.random.Generator, *, converge: bool, iterations: int = 40) -> MatchHistory:
    """Particle clouds that contract on ``truth`` (or wander when ``converge`` is false), with the
    exponential averages of eqs. 5–6 (χσ = 2/5, χw = 2/7)."""
    particles = truth + rng.uniform(-2.5, 2.5, size=(300, 2))
    chi_s, chi_w = 2 / 5, 2 / 7
    std_avg, weight_avg, snapshots, snap_its = [], [], [], []
    s_avg = w_avg = None
    for t in range(iterations):
        dist = np.linalg.norm(particles - truth, axis=1)
        weight = 10 * np.exp(-(dist / 0.5) ** 2) if converge else 3 * rng.random(len(particles))
        std = float(np.mean(np.std(particles, axis=0)))
        s_avg = std if s_avg is None else chi_s * std + (1 - chi_s) * s_avg
        w_avg = float(weight.mean()) if w_avg is None else chi_w * float(weight.mean()) + (1 - chi_w) * w_avg
        std_avg.append(s_avg)
        weight_avg.append(w_avg)
        if t in (0, iterations // 4, iterations - 1):
            theta = rng.normal(0, 0.05, len(particles))
            snapshots.append(np.column_stack([particles, theta, weight]))
            snap_its.append(t)
        pull = 0.15 if converge else 0.0
        particles = particles + pull * (truth - particles) + rng.normal(0, 0.08 if converge else 0.3, particles.shape)
    return MatchHistory(np.array(weight_avg), np.array(std_avg), tuple(snapshots), tuple(snap_its),
                        weight_threshold=HistoryThreshold(6.0, "τ_pw"), std_threshold=HistoryThreshold(0.05, "r_c"))


def make_grid(half, centre, depth_m: float, *, origin_shift: np.ndarray) -> EvidenceGrid:
    """Walls occupied (+4), inside free (−2), outside unknown (0), in the map frame of station 1."""
    margin = 0.5
    x0, y0 = centre[0] - half[0] - margin, centre[1] - half[1] - margin
    w = int(np.ceil((2 * half[0] + 2 * margin) / CELL_M))
    h = int(np.ceil((2 * half[1] + 2 * margin) / CELL_M))
    xs = x0 + (np.arange(w) + 0.5) * CELL_M
    ys = y0 + (np.arange(h) + 0.5) * CELL_M
    gx, gy = np.meshgrid(xs, ys)
    ex = half[0] - np.abs(gx - centre[0])
    ey = half[1] - np.abs(gy - centre[1])
    inside = np.minimum(ex, ey)
    log_odds = np.zeros((h, w), dtype=np.float32)
    log_odds[inside > CELL_M] = -2.0
    log_odds[np.abs(inside) <= CELL_M] = 4.0
    return EvidenceGrid(log_odds, (float(x0 - origin_shift[0]), float(y0 - origin_shift[1])), CELL_M, depth_m)


def probe_row(name: str, grid: EvidenceGrid, reference: float, kind: str, *, axis: int, rng) -> DimensionRow:
    """Measure across the occupied walls of ``grid`` along x (axis 0) or y (axis 1) with 10 probes."""
    occ = grid.log_odds > 0
    x0, x1, y0, y1 = grid.extent_m
    probes, lines = [], []
    fractions = np.linspace(0.25, 0.75, 10)
    for f in fractions:
        if axis == 0:
            r = int(f * occ.shape[0])
            cols = np.flatnonzero(occ[r])
            a, b = cols.min(), cols.max()
            # inner faces of the walls, plus the sub-cell jitter of a real probe
            length = (b - a - 1) * grid.cell_m + rng.normal(0, 0.02)
            y = y0 + (r + 0.5) * grid.cell_m
            lines.append((x0 + (a + 1) * grid.cell_m, y, x0 + b * grid.cell_m, y))
        else:
            c = int(f * occ.shape[1])
            rows = np.flatnonzero(occ[:, c])
            a, b = rows.min(), rows.max()
            length = (b - a - 1) * grid.cell_m + rng.normal(0, 0.02)
            x = x0 + (c + 0.5) * grid.cell_m
            lines.append((x, y0 + (a + 1) * grid.cell_m, x, y0 + b * grid.cell_m))
        probes.append(float(length))
    mean = float(np.mean(probes))
    return DimensionRow(name, mean, reference, kind, mean - reference, grid.depth_m, tuple(probes), tuple(lines))


def make_site_build(
    *,
    site_id: str = "pool",
    name: str = "Swimming pool",
    seed: int = 0,
    slices: int = 1,
    unplaced: bool = False,
    failed: bool = False,
    redact: bool = True,
) -> SiteBuild:
    """A complete (or failed) synthetic :class:`SiteBuild`.

    Parameters
    ----------
    slices : int
        1 gives the paper's single slice; more give a bell-shaped site widening with depth.
    unplaced : bool
        The last scan's matches do not converge and it stays unplaced.
    failed : bool
        The build stops in the match stage: only the scans exist.
    """
    rng = np.random.default_rng(seed)
    half, centre = (WIDTH_M / 2, LENGTH_M / 2), (WIDTH_M / 2, LENGTH_M / 2)
    record = make_record(site_id, name, redact=redact)
    raw, ranged = make_scans(STATIONS_POOL, rng, half=half, centre=centre)
    origin = STATIONS_POOL[0]
    truth_d = STATIONS_POOL - origin
    n = len(raw)
    scans_json = [ScanPose(index=k, id=f"S{k + 1}", file=record.scans[k].file, x_m=None, y_m=None, yaw_rad=0.0,
                           depth_m=1.5, placed=False, reason="not reached") for k in range(n)]
    provenance = Provenance(
        code_version="0.1.0",
        plugins=[PluginProvenance(stage=s, plugin=p, distribution="cistern-plugins", version="0.1.0", params=prm)
                 for s, p, prm in [("matcher", "pf-pairwise", {"particles": 300, "tau_pw": 6.0}),
                                   ("localizer", "wls", {}), ("mapper", "evidence-grid", {"cell_m": CELL_M}),
                                   ("comparator", "mosaic", {})]],
        seeds={"site": 7},
        record_file=f"{site_id}.yaml",
        python="3.11.7",
        numpy=np.__version__,
    )
    if failed:
        result = SiteResult(
            site_id=site_id, name=name, status="failed", scans=scans_json, provenance=provenance,
            status_reasons=["the build stopped at match: pair (0, 2): ValueError: reference scan has no valid beams"],
            timings_s={"load": 0.12, "segment": 0.05, "match": 0.4},
            failure=StageFailure(stage="match", input=f"pair (0, 2): {record.scans[0].file} → {record.scans[2].file}",
                                 error="ValueError: reference scan has no valid beams",
                                 traceback="Traceback (most recent call last):\n  ...\nValueError: reference scan has no valid beams"),
        )
        return SiteBuild(result=result, record=record, raw_scans=raw, range_scans=ranged)

    matches = []
    for i in range(n):
        for j in range(i + 1, n):
            bad = unplaced and j == n - 1
            d = truth_d[j] - truth_d[i]
            hist = make_history(d, rng, converge=not bad)
            est = hist.snapshots[-1][:, :2].mean(axis=0)
            matches.append(MatchResult(i, j, float(est[0]), float(est[1]), 0.0,
                                       float(hist.weight_avg[-1]), not bad, len(hist.weight_avg), 0.2 + 0.01 * j,
                                       "weight average stayed below tau_pw" if bad else "", None, hist))
    placed = np.ones(n, dtype=bool)
    if unplaced:
        placed[-1] = False
    xy = truth_d + rng.normal(0, 0.03, truth_d.shape)
    xy[0] = 0.0
    xy[~placed] = np.nan
    reasons = tuple("" if p else "no converged match links it to the reference scan" for p in placed)
    poses = Poses(xy, np.zeros(n), placed, reasons, 0)
    grids = []
    depths = [1.5] if slices == 1 else list(np.linspace(1.0, 3.0, slices))
    for k, depth in enumerate(depths):
        grow = 0.25 * k
        grids.append(make_grid((half[0] + grow, half[1] + grow), centre, float(depth), origin_shift=origin))
    map_result = MapResult(tuple(grids), {"cells_occupied": float(sum((g.log_odds > 0).sum() for g in grids))})
    rows = (probe_row("Width", grids[0], WIDTH_M, "truth", axis=0, rng=rng),
            probe_row("Length", grids[0], LENGTH_M, "mosaic", axis=1, rng=rng))
    pd = abs((rows[0].map_m / rows[1].map_m) - (WIDTH_M / LENGTH_M)) / (WIDTH_M / LENGTH_M) * 100
    table = DimensionTable(rows, {"percent_difference": float(pd)})
    scans_json = [ScanPose(index=k, id=f"S{k + 1}", file=record.scans[k].file,
                           x_m=None if not placed[k] else float(xy[k, 0]), y_m=None if not placed[k] else float(xy[k, 1]),
                           yaw_rad=0.0, depth_m=1.5, placed=bool(placed[k]), reason=reasons[k],
                           truth_x_m=float(truth_d[k, 0]), truth_y_m=float(truth_d[k, 1])) for k in range(n)]
    labels = [s.id for s in scans_json]
    dimensions = [dimension_result(r, 10, labels, cell_m=CELL_M, poses=poses) for r in rows]
    status, status_reasons = site_status(failed_stage=None, scans_placed=list(placed), labels=labels, unmeasured=[])
    result = SiteResult(
        site_id=site_id, name=name, status=status, status_reasons=status_reasons, scans=scans_json,
        pairs=[PairResult(i=m.i, j=m.j, dx_m=m.dx_m, dy_m=m.dy_m, dyaw_rad=m.dyaw_rad, weight=m.weight,
                          converged=m.converged, iterations=m.iterations, seconds=m.seconds, reason=m.reason)
               for m in matches],
        dimensions=dimensions,
        dimension_stats=table.stats, map_stats=map_result.stats, reference_scan=0, provenance=provenance,
        timings_s={"load": 0.12, "segment": 0.05, "match": 2.4, "localize": 0.01, "map": 0.3, "compare": 0.02},
    )
    mesh = wall_surface(map_result, poses, [s.depth_m for s in ranged]) if slices == 1 else \
        wall_surface(map_result, poses, [float(d) for d in np.linspace(1.0, 3.0, n)])
    return SiteBuild(result=result, record=record, raw_scans=raw, range_scans=ranged, matches=matches,
                     poses=poses, map_result=map_result, table=table, mesh=mesh)


SITES = {
    "pool": dict(site_id="pool", name="Swimming pool"),
    "bell": dict(site_id="bell", name="Bell cistern", slices=3, unplaced=True, redact=False),
    "broken": dict(site_id="broken", name="Broken site", failed=True),
}


def render_catalog(root: Path) -> dict[str, dict[str, str]]:
    """Render the synthetic sites of :data:`SITES` and the index under ``root``; artifacts per site."""
    from cistern_archive.pipeline.runner import write_site_result
    from cistern_archive.report import IndexEntry, render_index, render_site

    artifacts = {}
    entries = []
    for key, kwargs in SITES.items():
        site_dir = root / key
        site_dir.mkdir(parents=True)
        build = make_site_build(**kwargs)
        artifacts[key] = render_site(build, site_dir)
        result = SiteResult.model_validate_json(write_site_result(build, site_dir, artifacts[key]).read_text())
        entries.append(IndexEntry.from_result(result, build_time="2024-01-01T00:00:00Z"))
    render_index(entries, root)
    return artifacts
