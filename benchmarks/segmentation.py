"""Beam segmentation: the paper's rule (Sec. III-B), the CFAR rule and the shadow rule, on simulated sites
with truth and on real recordings without it.

Simulated sites (the physical simulator, :mod:`cistern_archive.simulation.simulator`: reverberation through the
35° vertical lobe, multipath ghosts, speckle, spikes, ring-down and the vehicle's own echo), five families
and the bell-shaped cistern apart:

* ``demo``: every spec of ``catalog/specs`` re-simulated with other seeds; the bell-shaped cistern is
  reported apart (``bell``): its 35° lobe sees walls that lean in and out, so the wall at the sonar's depth
  (the truth used here) is not what the echo shows;
* ``chambers``: random sites of 2-3 rectangular chambers joined by tunnels 0.8-1.2 m wide
  (:func:`random_chambers`), 2 stations per chamber, so many beams look through an opening into the next
  chamber; water 2-4 m deep, ordinary floor reverberation;
* ``shallow``: the same kind of sites in 0.8-1.6 m of water with the head 0.15-0.4 m above the floor or
  below the surface and floor reverberation 3-9 dB stronger than the default, so the lobe meets the floor
  (or surface) within 0.5-1.4 m and reverberation fills most of every beam.
* ``speckle``: the ``chambers`` sites again under fully developed speckle (one look: exponentially
  distributed intensities, against the simulator's default of three looks), as a single-look head
  without averaging hears them; the near field's speckle then peaks above the shadow rule's first two
  tests on many beams.
* ``weak_tvg``: the ``chambers`` sites again through a head whose time-varying gain rises by 20 log R
  instead of the simulator's 35 log R (a common setting, and a gain law other simulators and heads
  may use): the echoes fall off with range by 15 dB a decade more, so distant walls stand 50-80 counts
  above the converter's floor.

Per beam the segmented range is compared with the true range along the beam's axis (``inf`` when the wall
is beyond the range setting): ``hit`` within ``TOL_BINS`` (2) bins; ``false`` walls are echoes more than
that from the wall: ``before`` it (reverberation, near field, spikes in the water), ``behind`` it (ghosts,
the smear of a far wall) or on a beam with no wall in range; ``missed``: no echo although the wall is in
range. ``score`` = hit - false - missed (fractions of all beams): a beam states either a wall at its
range or, with no echo, free water up to the range setting (:class:`~cistern_archive.core.scan.RangeScan`),
so a missed wall (free water through a wall) is as wrong as a false one. Four rules (``VARIANTS``): the
three methods with ``faint_walls`` off and ``faint``, the shadow rule with it on.

Seed sets: ``--set tune`` (random seeds 1..N, the demo specs with their catalog seed plus 3000) chose the
constants of ``shadow`` (``--tune`` runs the grid ``TUNE_GRID`` over them and prints it, best first);
``--set report`` (random seeds 1001..1000+N, the demo specs with their catalog seed plus 1000 and 2000)
is what ``RESULTS.md`` reports.

Real recordings (``../shared/data``, no truth): for every file, its full revolutions (when it holds two or
more of one setting) or else the sweeps of its most repeated sector setting are segmented with
``REAL_MIN_RANGE_M`` blanking (:func:`real_sweeps`), and

* ``echo``: fraction of beams with an echo;
* ``repeat``: consistency of consecutive sweeps of the stationary head: of the beams with an echo in
  one sweep and an echo on the nearest bearing (within half a step) of the next, the fraction within
  ``max(2 bins, 0.05 m)`` of each other; ``repeat_beyond_edge`` the same for the echoes beyond ``edge``
  (a rule that always marks the blanking edge repeats perfectly and finds nothing);
* ``edge``: fraction of echoes within 0.1 m beyond the blanking range (ring-down leaking past it);
* ``patch``: fraction of echoes within 0.1 m of the edge of the diffuse patch (the first range beyond the
  blanking where the across-beam median of the smoothed image falls below the threshold: the outer edge of
  the bottom reverberation around the head); ``null`` when there is no such patch.

``--figures DIR`` writes, for each recording and for one simulated site of each family, the raw fan beside
the points of every method (PNG).

Usage::

    .venv/bin/python benchmarks/segmentation.py [--set report] [--sites 8] [--figures DIR] [--json]
    .venv/bin/python benchmarks/segmentation.py --set tune --tune
"""

from __future__ import annotations

import argparse
import io
import itertools
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL_DATA = ROOT.parent / "shared" / "data"
TOL_BINS = 2
REAL_FILES = [
    "ping360/Sensor_Log_01__inside_base_dakhel_paygah.bin",
    "ping360/Sensor_Log_01__20200926-120409929.bin",
    "ping360/BIN__20240814-102337673.bin",
    "ping360/BIN__20240814-102841366.bin",
    "seanet/UdpHubLog_4001_2017_11_02_09_00_03.csv",
    "seanet/90degree_scan_target_moving_in.V4LOG",
]
REAL_MIN_RANGE_M = 0.5
EDGE_M = 0.1
REAL_ZOOM_M = {"UdpHubLog_4001_2017_11_02_09_00_03.csv": 15.0, "BIN__20240814-102337673.bin": 8.0,
               "BIN__20240814-102841366.bin": 8.0}
SEED_BASE = {"tune": 0, "report": 1000}
TUNE_GRID = {"SHADOW_LEAD_MARGIN": [10.0, 20.0, 35.0], "SHADOW_MARGIN": [50.0, 65.0, 80.0],
             "SHADOW_TRAIL_M": [0.4, 0.6, 0.8], "SHADOW_ECHO_M": [0.3]}

from cistern_archive.catalog.models import Segmentation  # noqa: E402
from cistern_archive.sonar import segmentation as seg  # noqa: E402
from cistern_archive.sonar.fan import polar_to_cartesian  # noqa: E402
from cistern_archive.simulation.simulator import simulate_site  # noqa: E402
from cistern_archive.simulation.spec import SimulationSpec, load_spec  # noqa: E402

VARIANTS = {**{method: {"method": method, "faint_walls": "off"} for method in seg.METHODS},
            "faint": {"method": "shadow", "faint_walls": "on"}}
"""The rules compared, scan by scan: each method with ``faint_walls`` off, and ``faint``, the shadow rule
with it on (:mod:`cistern_archive.sonar.segmentation`, step 3; a site's ``auto`` picks one of the two)."""
METHODS = tuple(VARIANTS)


# --- simulated sites -------------------------------------------------------------------------------

def _chamber_outline(rooms: list[tuple[float, float, float, float]], tunnels: list[tuple[float, float]]) -> list:
    """One polygon around rectangular rooms ``(x0, y0, x1, y1)`` left to right, joined by tunnels
    ``(y_centre, width)`` between consecutive rooms: bottom edge left to right, top edge back."""
    bottom, top = [], []
    for k, (x0, y0, x1, y1) in enumerate(rooms):
        if k > 0:
            yc, w = tunnels[k - 1]
            bottom.append((x0, yc - w / 2))
            top.append((x0, yc + w / 2))
        bottom += [(x0, y0), (x1, y0)]
        top += [(x0, y1), (x1, y1)]
        if k < len(rooms) - 1:
            yc, w = tunnels[k]
            bottom.append((x1, yc - w / 2))
            top.append((x1, yc + w / 2))
    return bottom + top[::-1]


def random_chambers(seed: int, shallow: bool) -> SimulationSpec:
    """A random site of 2-3 chambers joined by tunnels, two stations per chamber (see the module doc)."""
    rng = np.random.default_rng([seed, 12, int(shallow)])
    rooms, tunnels, x = [], [], 0.0
    for k in range(int(rng.integers(2, 4))):
        width, height = rng.uniform(2.5, 6.0), rng.uniform(2.5, 6.0)
        y0 = rng.uniform(-0.5, 0.5) - height / 2
        if k > 0:
            w = rng.uniform(0.8, 1.2)
            lo = max(rooms[-1][1], y0) + w / 2 + 0.3
            hi = min(rooms[-1][3], y0 + height) - w / 2 - 0.3
            tunnels.append((float(rng.uniform(lo, hi)) if hi > lo else 0.0, w))
            x += rng.uniform(0.6, 1.5)
        rooms.append((x, y0, x + width, y0 + height))
        x += width
    if shallow:
        water = rng.uniform(0.8, 1.6)
        floor_db = rng.uniform(-21.0, -15.0)
    else:
        water = rng.uniform(2.0, 4.0)
        floor_db = rng.uniform(-27.0, -21.0)
    stations = []
    for k, (x0, y0, x1, y1) in enumerate(rooms):
        for j in range(2):
            if shallow:
                gap = rng.uniform(0.15, 0.4)
                depth = water - gap if rng.random() < 0.7 else gap
            else:
                depth = rng.uniform(0.6, water - 0.4)
            stations.append({"name": f"r{k}s{j}", "x_m": float(rng.uniform(x0 + 0.6, x1 - 0.6)),
                             "y_m": float(rng.uniform(y0 + 0.6, y1 - 0.6)),
                             "yaw_deg": float(rng.uniform(-180, 180)), "depth_m": float(depth)})
    angle = rng.uniform(0, 2 * np.pi)
    rotation = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
    outline = np.asarray(_chamber_outline(rooms, tunnels)) @ rotation
    for station in stations:
        station["x_m"], station["y_m"] = (float(v) for v in np.array([station["x_m"], station["y_m"]]) @ rotation)
    return SimulationSpec.model_validate({
        "id": f"chambers-{seed}", "name": "random chambers", "seed": seed,
        "site": {"water_depth_m": float(water), "levels": [{"depth_m": 0.0, "walls": {
            "polygon": [tuple(map(float, v)) for v in outline]}}]},
        "sonar": {"range_m": 10.0, "bins": 250, "step_deg": float(rng.choice([0.9, 1.8]))},
        "effects": {"floor_db": float(floor_db)},
        "segmentation": {"threshold": 50, "min_range_m": 0.4},
        "stations": stations,
    })


def simulated_sets(which: str, n_sites: int) -> dict[str, list[tuple[SimulationSpec, list]]]:
    """The simulated scans of one seed set, by family: ``{family: [(spec, scans), ...]}``."""
    base = SEED_BASE[which]
    families: dict[str, list] = {"demo": [], "bell": [], "chambers": [], "shallow": [], "speckle": [],
                                 "weak_tvg": []}
    demo_seeds = [1000, 2000] if which == "report" else [3000]
    for spec_path in sorted((ROOT / "catalog" / "specs").glob("*.yaml")):
        spec0 = load_spec(spec_path)
        family = "bell" if len(spec0.site.levels) > 1 else "demo"
        for offset in demo_seeds:
            spec = spec0.model_copy(update={"seed": spec0.seed + offset})
            families[family].append((spec, simulate_site(spec).scans))
    for k in range(1, n_sites + 1):
        for family, shallow in (("chambers", False), ("shallow", True)):
            spec = random_chambers(base + k, shallow)
            families[family].append((spec, simulate_site(spec).scans))
        spec = one_look(random_chambers(base + k, False))
        families["speckle"].append((spec, simulate_site(spec).scans))
        spec = weak_tvg(random_chambers(base + k, False))
        families["weak_tvg"].append((spec, simulate_site(spec).scans))
    return families


WEAK_TVG_EXPONENT = 20.0
"""The ``weak_tvg`` family's time-varying gain, ``n log10 r`` (the simulator's default is 35)."""


def weak_tvg(spec: SimulationSpec) -> SimulationSpec:
    """The same site heard through a time-varying gain of ``WEAK_TVG_EXPONENT`` log R."""
    return spec.model_copy(update={"id": spec.id + "-weak-tvg",
                                   "sonar": spec.sonar.model_copy(update={"tvg_exponent": WEAK_TVG_EXPONENT})})


def one_look(spec: SimulationSpec) -> SimulationSpec:
    """The same site under fully developed speckle: one look, exponentially distributed intensities (the
    simulator's default is three looks)."""
    return spec.model_copy(update={"id": spec.id + "-one-look",
                                   "effects": spec.effects.model_copy(update={"speckle_looks": 1.0})})


def beam_outcomes(sim, settings: Segmentation) -> dict[str, np.ndarray]:
    """Per-beam outcome masks of one simulated scan (see the module docstring) and the errors."""
    ranges = seg.segment(sim.scan, settings).ranges_m
    truth = sim.truth_ranges_m
    tol = TOL_BINS * sim.scan.bin_size_m
    wall = np.isfinite(truth)
    echo = np.isfinite(ranges)
    error = np.where(wall & echo, ranges - np.where(wall, truth, 0.0), np.nan)
    return {
        "hit": wall & echo & (np.abs(np.nan_to_num(error)) <= tol),
        "one_bin": wall & echo & (np.abs(np.nan_to_num(error)) <= sim.scan.bin_size_m),
        "before": wall & echo & (np.nan_to_num(error) < -tol),
        "behind": wall & echo & (np.nan_to_num(error) > tol),
        "no_wall": ~wall & echo,
        "missed": wall & ~echo,
        "error": error,
    }


def summarise(outcomes: list[dict[str, np.ndarray]]) -> dict:
    """Fractions of all beams for each outcome, the score and the median |error| of the hits."""
    pooled = {key: np.concatenate([o[key] for o in outcomes]) for key in outcomes[0]}
    beams = pooled["hit"].size
    out = {"beams": int(beams)}
    for key in ("hit", "one_bin", "before", "behind", "no_wall", "missed"):
        out[key] = round(float(pooled[key].mean()), 4)
    out["false"] = round(out["before"] + out["behind"] + out["no_wall"], 4)
    out["score"] = round(out["hit"] - out["false"] - out["missed"], 4)
    hits = np.abs(pooled["error"][pooled["hit"]])
    out["median_abs_error_m"] = round(float(np.median(hits)), 4) if hits.size else None
    return out


def site_outcomes(spec: SimulationSpec, scans: list, method: str) -> list[dict[str, np.ndarray]]:
    """Beam outcomes of every scan of one site under ``method`` (the site's threshold and blanking)."""
    settings = spec.segmentation.model_copy(update=VARIANTS[method])
    return [beam_outcomes(sim, settings) for sim in scans]


def evaluate(families: dict[str, list], methods=METHODS) -> dict[str, dict[str, dict]]:
    """``{family: {method: summary}}``, plus ``all_vertical`` (every family but the bell) and, per family,
    ``best_sites``: on how many sites each method has the highest score (ties count for each)."""
    per_site = {f: [{m: site_outcomes(spec, scans, m) for m in methods} for spec, scans in sites]
                for f, sites in families.items()}
    result: dict[str, dict] = {}
    for family, sites in per_site.items():
        result[family] = {m: summarise([o for site in sites for o in site[m]]) for m in methods}
        scores = [{m: summarise(site[m])["score"] for m in methods} for site in sites]
        result[family]["best_sites"] = {m: sum(sc[m] == max(sc.values()) for sc in scores) for m in methods}
        result[family]["sites"] = len(sites)
    result["all_vertical"] = {
        m: summarise([o for f, sites in per_site.items() if f != "bell" for site in sites for o in site[m]])
        for m in methods}
    return result


def tune(families: dict[str, list]) -> list[dict]:
    """Score of ``shadow`` for every combination of ``TUNE_GRID`` (module constants set in turn)."""
    names = list(TUNE_GRID)
    saved = {name: getattr(seg, name) for name in names}
    rows = []
    try:
        for values in itertools.product(*TUNE_GRID.values()):
            for name, value in zip(names, values):
                setattr(seg, name, value)
            summary = summarise([beam_outcomes(sim, spec.segmentation.model_copy(update={"method": "shadow"}))
                                 for f in families if f != "bell" for spec, scans in families[f] for sim in scans])
            rows.append({**dict(zip(names, values)), **{k: summary[k] for k in ("hit", "false", "missed", "score")}})
    finally:
        for name, value in saved.items():
            setattr(seg, name, value)
    return sorted(rows, key=lambda r: -r["score"])


# --- real recordings ---------------------------------------------------------------------------------

def _group(scan) -> tuple:
    """Sweeps comparable with each other: equal bins, bin size, and full revolution or sector."""
    return (scan.n_bins, round(scan.bin_size_m, 6), bool(np.ptp(scan.bearings_rad) > 6.0))


def real_sweeps(path: Path) -> list:
    """The sweeps of one kind in the recording: its full revolutions if it holds two or more of one
    setting, else its most common sector (the head swept it again and again)."""
    from cistern_archive.sonar.readers import read_file

    scans = [s for s in read_file(path).scans if s.n_beams >= 8]
    counts = Counter(_group(s) for s in scans)
    full = [(n, g) for g, n in counts.items() if g[2] and n >= 2]
    if not counts:
        return []
    chosen = max(full)[1] if full else counts.most_common(1)[0][0]
    return [s for s in scans if _group(s) == chosen]


def patch_edge_m(scan, settings: Segmentation) -> float | None:
    """Outer edge of the diffuse patch around the head (module docstring), or ``None``."""
    values = seg._blank_near(scan, 0.0)
    smooth = seg._moving_average(values, 3, axis=1)
    far = scan.bin_centres_m >= settings.min_range_m
    peak = smooth[:, far].max() if smooth[:, far].size else 0.0
    if peak <= 0:
        return None
    profile = np.median(smooth, axis=0) * 255.0 / peak
    above = far & (profile > settings.threshold)
    if not above.any():
        return None
    first_above = int(np.argmax(above))
    below = np.flatnonzero(far & (profile <= settings.threshold) & (np.arange(profile.size) > first_above))
    return float(scan.bin_centres_m[below[0]]) if below.size else None


def _repeat_agreement(a, b, tol: float, beyond_m: float = 0.0) -> tuple[int, int]:
    """(agreeing, compared) echo pairs of two sweeps on nearest bearings within half a step, counting
    only pairs whose echoes are both farther than ``beyond_m``."""
    step = float(np.median(np.abs(np.diff(np.unwrap(a.bearings_rad))))) if a.bearings_rad.size > 1 else 0.0
    diff = np.abs(np.mod(a.bearings_rad[:, None] - b.bearings_rad[None, :] + np.pi, 2 * np.pi) - np.pi)
    nearest = np.argmin(diff, axis=1)
    close = diff[np.arange(diff.shape[0]), nearest] <= step / 2 + 1e-9
    ra, rb = a.ranges_m, b.ranges_m[nearest]
    both = close & (np.nan_to_num(ra) > beyond_m) & (np.nan_to_num(rb) > beyond_m)
    return int(np.count_nonzero(both & (np.abs(ra - rb) <= tol))), int(np.count_nonzero(both))


def real_metrics(sweeps: list, method: str) -> dict:
    """The honest no-truth measures of one method on the sweeps of one recording."""
    settings = Segmentation(**VARIANTS[method], min_range_m=REAL_MIN_RANGE_M)
    ranges = [seg.segment(s, settings) for s in sweeps]
    tol = max(TOL_BINS * sweeps[0].bin_size_m, 0.05)
    counts = np.zeros((2, 2), dtype=int)  # (all echoes, beyond the edge) x (agreeing, compared)
    for a, b in zip(ranges, ranges[1:]):
        counts[0] += _repeat_agreement(a, b, tol)
        counts[1] += _repeat_agreement(a, b, tol, beyond_m=REAL_MIN_RANGE_M + EDGE_M)
    echoes = np.concatenate([r.ranges_m[r.valid] for r in ranges])
    edges = [patch_edge_m(s, settings) for s in sweeps]
    at_patch = [np.abs(r.ranges_m[r.valid] - e) <= EDGE_M for r, e in zip(ranges, edges) if e is not None]
    return {
        "echo": round(float(np.mean([r.valid.mean() for r in ranges])), 4),
        "repeat": round(counts[0, 0] / counts[0, 1], 4) if counts[0, 1] else None,
        "repeat_beyond_edge": round(counts[1, 0] / counts[1, 1], 4) if counts[1, 1] else None,
        "edge": round(float(np.mean(echoes <= REAL_MIN_RANGE_M + EDGE_M)), 4) if echoes.size else None,
        "patch": round(float(np.concatenate(at_patch).mean()), 4) if at_patch and echoes.size else None,
        "median_range_m": round(float(np.median(echoes)), 3) if echoes.size else None,
    }


def real(figures: Path | None) -> dict:
    out: dict[str, dict] = {}
    if not REAL_DATA.is_dir():
        return out
    for relative in REAL_FILES:
        path = REAL_DATA / relative
        if not path.is_file():
            continue
        sweeps = real_sweeps(path)
        if not sweeps:
            continue
        first = sweeps[0]
        entry: dict = {"sweeps": len(sweeps), "beams": max(s.n_beams for s in sweeps), "bins": first.n_bins,
                       "bin_size_m": round(first.bin_size_m, 5)}
        for method in METHODS:
            entry[method] = real_metrics(sweeps, method)
        out[path.name] = entry
        if figures is not None:
            scan = max(sweeps, key=lambda s: s.n_beams)
            write_figure(figures / f"seg_{path.stem}.png", scan, path.name, REAL_MIN_RANGE_M, zoom_m=REAL_ZOOM_M.get(path.name))
    return out


# --- figures -------------------------------------------------------------------------------------------

def write_figure(target: Path, scan, title: str, min_range_m: float, truth: np.ndarray | None = None,
                 zoom_m: float | None = None) -> None:
    """Raw fan, then the echoes of each method over a dimmed fan (and the true walls if known), within
    ``zoom_m`` of the head (the whole range by default)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    extent = scan.max_range_m
    half = extent if zoom_m is None else min(zoom_m, extent)
    image, extent = polar_to_cartesian(scan.bearings_rad, scan.normalised(), scan.bin_size_m, scan.start_range_m,
                                       pixels=min(1600, int(300 * extent / half)))
    fig = Figure(figsize=(3.2 * (1 + len(METHODS)), 3.6), dpi=80, layout="constrained")
    FigureCanvasAgg(fig)
    fig.suptitle(f"{title} (blanking {min_range_m} m)")
    vmax = float(np.nanpercentile(image, 99.5)) or 1.0
    for k, method in enumerate(("raw",) + METHODS):
        ax = fig.add_subplot(1, 1 + len(METHODS), k + 1)
        ax.imshow(image, extent=(-extent, extent, -extent, extent), cmap="inferno", vmin=0, vmax=vmax,
                  alpha=1.0 if k == 0 else 0.45)
        ax.set_title(method if k else f"raw intensities (±{half:.1f} m)")
        ax.set_xlim(-half, half), ax.set_ylim(-half, half)
        ax.set_xticks([]), ax.set_yticks([])
        if truth is not None and k:
            ok = np.isfinite(truth)
            ax.scatter(-truth[ok] * np.sin(scan.bearings_rad[ok]), truth[ok] * np.cos(scan.bearings_rad[ok]),
                       s=1, c="#39d353", label="true wall")
        if k:
            settings = Segmentation(**VARIANTS[method], min_range_m=min_range_m)
            rs = seg.segment(scan, settings)
            ok = rs.valid
            ax.scatter(-rs.ranges_m[ok] * np.sin(rs.bearings_rad[ok]), rs.ranges_m[ok] * np.cos(rs.bearings_rad[ok]),
                       s=2, c="#3fa9f5", label="echo")
    target.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", metadata={"Software": None})
    target.write_bytes(buffer.getvalue())


def simulated_figures(families: dict[str, list], figures: Path) -> None:
    for family in ("chambers", "shallow", "speckle", "weak_tvg", "demo"):
        spec, scans = families[family][0]
        sim = scans[0]
        seen = sim.truth_ranges_m[np.isfinite(sim.truth_ranges_m)]
        write_figure(figures / f"seg_sim_{family}.png", sim.scan, f"simulated {family}: {spec.id} {sim.scan.station}",
                     spec.segmentation.min_range_m, truth=sim.truth_ranges_m,
                     zoom_m=1.15 * float(seen.max()) if seen.size else None)


# --- command line ------------------------------------------------------------------------------------

def print_table(result: dict) -> None:
    cols = ("hit", "one_bin", "before", "behind", "no_wall", "missed", "false", "score")
    print(f"{'family':13s} {'method':7s} {'beams':>6s} " + " ".join(f"{c:>7s}" for c in cols) + "  median|e|")
    for family, methods in result["simulated"].items():
        for method in METHODS:
            s = methods[method]
            print(f"{family:13s} {method:7s} {s['beams']:6d} " + " ".join(f"{s[c]:7.3f}" for c in cols)
                  + f"  {s['median_abs_error_m']}")
        if "best_sites" in methods:
            print(f"{family:13s} best score on {methods['best_sites']} of {methods['sites']} sites")
    for name, entry in result["real"].items():
        print(f"real {name} ({entry['sweeps']} sweeps of {entry['beams']} x {entry['bins']}):")
        for method in METHODS:
            print(f"    {method:7s} " + " ".join(f"{k} {v}" for k, v in entry[method].items()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", choices=sorted(SEED_BASE), default="report", help="seed set (module doc)")
    parser.add_argument("--sites", type=int, default=8, help="random sites per random family")
    parser.add_argument("--tune", action="store_true", help="grid over the shadow constants on this set")
    parser.add_argument("--no-real", action="store_true", help="skip the real recordings")
    parser.add_argument("--figures", type=Path, default=None, help="write PNG figures here")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    families = simulated_sets(args.set, args.sites)
    result: dict = {"set": args.set, "sites_per_family": args.sites, "tol_bins": TOL_BINS,
                    "scans": {f: sum(len(s) for _, s in v) for f, v in families.items()}}
    if args.tune:
        result["tune"] = tune(families)
    result["simulated"] = evaluate(families)
    result["real"] = {} if args.no_real else real(args.figures)
    if args.figures is not None:
        simulated_figures(families, args.figures)
    result["seconds"] = round(time.perf_counter() - start, 1)
    if args.json:
        print(json.dumps(result, sort_keys=True))
        return 0
    for row in result.get("tune", []):
        print("tune", row)
    print_table(result)
    print(f"scans {result['scans']}; {result['seconds']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
