"""Simulated sites through the real pipeline, scored against their truth poses.

Two sources of sites:

* the demo catalog (default): every record in ``catalog/sites/*.yaml`` that has ``truth`` poses;
* ``--random N --seed S``: N random multi-chamber cisterns of :mod:`cistern_archive.simulation.chambers`
  (one to three chambers of 2.5–8 m joined by 0.8–1.2 m tunnels, 6–12 stations, Micron-like echoes,
  ±2° compass bias and 2° noise), written as a temporary catalog (specs, then scans, ``truth.json`` and
  records by the simulator's writer, as ``cistern-archive simulate`` does) and built from there.
  ``--generator JSON`` draws them with other settings
  (:class:`~cistern_archive.simulation.chambers.GeneratorSettings`: longer tunnels, tunnels surveyed
  with a station every metre or two, another compass, more clutter, the whole site larger:
  ``{"scale": 3.0}``).

Each site is built by the pipeline runner (:func:`cistern_archive.pipeline.runner.build_site`) with the
record's plugins (the defaults unless the record names others, or ``--localizer`` and ``--matcher``),
and scored:

* scans placed / scans;
* position error of the placed scans after the rigid alignment of all of them onto the truth
  (:func:`cistern_archive.evaluation.position_errors`) and, for the demo table, in the reference scan's
  compass frame without alignment (truth offsets rotated by its compass error);
* pairs the pipeline matched with at least 50 % overlap (visible-area overlap on the true walls,
  :func:`cistern_archive.sonar.geometry.overlap_fraction`) and those among them that converged within
  0.10 m of the truth displacement (in the reference scan's compass frame); ``eligible_pairs`` counts
  only neighbouring pairs, ``pairs_ge50`` every matched pair;
* pairs sharing ≥ 50 % of their wall: the same, but on the share of wall the two stations both see
  (:func:`~cistern_archive.sonar.geometry.shared_wall_fraction`) instead of the share of water: two stations in
  chambers that look at each other through a tunnel share much water and little wall, and no matcher can
  align walls it was not shown (``--details`` and the table, not the last line);
* rejected correct pairs: matched pairs with ≥ 50 % overlap reported not converged whose estimate was
  nevertheless within 0.10 m (what a better verification would keep);
* false convergences: matched pairs reported converged that are more than 0.10 m off, and among them
  those whose scans do not overlap at all;
* far pairs: pairs of one site with less than 20 % overlap, which the benchmark asks the site's matcher
  about directly (:func:`cistern_archive.pipeline.runner.match_pair`, no guess: what a localizer that
  proposes every pair within reach would ask); any it reports converged is a match to be refused;
* silent wrong sites: sites whose status is ``ok`` with a placed scan more than 0.25 m off after
  alignment;
* joins of groups (``Poses.group_links``, the fits of groups as wholes): whether each join's 95 %
  half-width (``group_link_ci95_m`` of ``result.json``) holds the true position of its two stations
  relative to each other, after the rigid alignment of the placed scans (``--details`` and the table);
* the whole-site time.

Pairs of scans at different depth levels (where the true walls at their two depths lie more than
``WALL_CHANGE_M`` apart; without a simulation spec, depths more than ``LEVEL_TOLERANCE_M`` apart, the
mapper's default slice tolerance) see different wall outlines in a site whose walls change with depth;
their overlap is undefined (``nan``), so they count neither as pairs with ≥ 50 % overlap nor as pairs
without overlap. They are reported apart (``cross_level_pairs``, ``cross_level_converged``); the
localizer joins depth levels through the record's vertical ties (``ScanRef.below``). Stations at
different depths of a site whose walls are the same at every depth are pairs like any other.

With ``--random`` the last line of ``--json`` is exactly ``{"sites", "scans", "placed", "pairs_ge50",
"pairs_ge50_ok", "far_pairs", "far_pairs_converged", "median_aligned_error_m", "max_aligned_error_m",
"silent_wrong_sites"}``; ``--details FILE`` writes everything else (per site, per chamber count, 95 %
Wilson intervals). Without ``--random`` the last line is the demo summary with ``per_site``.

Usage::

    .venv/bin/python benchmarks/sites.py [--catalog catalog] [--site ID ...] [--json]
    .venv/bin/python benchmarks/sites.py --random 40 --seed 1 [--workers 2] [--json] [--details out.json]
        [--generator '{"tunnel_length_m": [2, 4], "tunnel_station_spacing_m": 1.5}']
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from itertools import combinations
from pathlib import Path

import numpy as np
from pydantic import ValidationError
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parents[1]
LEVEL_TOLERANCE_M = 0.25
WALL_CHANGE_M = 0.05
OK_PAIR_M = 0.10
WRONG_SCAN_M = 0.25
FAR_OVERLAP = 0.20
RANDOM_KEYS = ("sites", "scans", "placed", "pairs_ge50", "pairs_ge50_ok", "far_pairs", "far_pairs_converged",
               "median_aligned_error_m", "max_aligned_error_m", "silent_wrong_sites")

from cistern_archive.catalog.loader import load_record, record_paths  # noqa: E402
from cistern_archive.catalog.models import StageChoice  # noqa: E402
from cistern_archive.evaluation import aligned_positions, in_compass_frame, position_errors as aligned_errors  # noqa: E402
from cistern_archive.evaluation import reference_frame_errors, strict_json, wilson_interval  # noqa: E402
from cistern_archive.pipeline.registry import default_registry  # noqa: E402
from cistern_archive.pipeline.runner import build_site, match_pair, record_ties, resolve_stages  # noqa: E402
from cistern_archive.sonar.geometry import interpolate_slice, overlap_fraction, shared_wall_fraction  # noqa: E402
from cistern_archive.simulation.chambers import GeneratorSettings, random_cisterns, simulate_into, write_specs  # noqa: E402
from cistern_archive.simulation.spec import load_spec  # noqa: E402
from cistern_plugins.registration import ConvergenceParams, ReferenceModel  # noqa: E402


def with_stage(loaded, stage: str, name: str | None = None, params: dict | None = None):
    """The record with another plugin for ``stage`` and/or more parameters (a ``None`` name keeps the
    record's plugin and adds ``params`` to its own), or unchanged."""
    if name is None and not params:
        return loaded
    current = default_registry().choice(loaded.record.pipeline, stage)
    kept = current.params if name is None or name == current.plugin else {}
    choice = StageChoice(plugin=name or current.plugin, params={**kept, **(params or {})})
    pipeline = loaded.record.pipeline.model_copy(update={stage: choice})
    return replace(loaded, record=loaded.record.model_copy(update={"pipeline": pipeline}))


def walls_differ(levels, depth_a: float, depth_b: float) -> bool:
    """Whether the site's true walls at two depths differ by more than ``WALL_CHANGE_M`` (vertex by vertex
    where both are interpolated from rings of one shape, else whenever they are not the same rings)."""
    a, b = interpolate_slice(levels, depth_a), interpolate_slice(levels, depth_b)
    if len(a) != len(b) or any(np.shape(ra) != np.shape(rb) for ra, rb in zip(a, b)):
        return True
    return any(np.hypot(*(np.asarray(ra) - np.asarray(rb)).T).max(initial=0.0) > WALL_CHANGE_M for ra, rb in zip(a, b))


class SiteTruth:
    """The truth of one built site: true positions, compass errors, and pair overlaps (cached)."""

    def __init__(self, record, scans, catalog: Path) -> None:
        truth = {t.station: t for t in record.truth}
        stations = [s.station for s in record.scans]
        self.xy = np.array([[truth[s].x_m, truth[s].y_m] for s in stations])
        self.compass_err = [scans[k].yaw_rad - math.radians(truth[s].yaw_deg) for k, s in enumerate(stations)]
        self.scans = scans
        self.spec = load_spec(catalog / record.simulation) if record.simulation else None
        self.max_range = record.sonar.range_m or max(s.max_range_m for s in scans)
        self._measures: dict[tuple[str, int, int], float] = {}

    def cross_level(self, i: int, j: int) -> bool:
        """Whether scans ``i`` and ``j`` see different walls: their true wall outlines at their two depths
        lie more than ``WALL_CHANGE_M`` apart somewhere (without a spec: depths more than
        ``LEVEL_TOLERANCE_M`` apart)."""
        di, dj = self.scans[i].depth_m, self.scans[j].depth_m
        if self.spec is None:
            return abs(di - dj) > LEVEL_TOLERANCE_M
        return walls_differ(self.spec.site.slices(), di, dj)

    def overlap(self, i: int, j: int) -> float:
        """Visible-area overlap of scans ``i`` and ``j`` (``nan`` without a spec or across levels)."""
        return self._pair_measure(overlap_fraction, i, j)

    def shared_wall(self, i: int, j: int) -> float:
        """Shared-wall fraction of scans ``i`` and ``j`` (:func:`~cistern_archive.sonar.geometry.shared_wall_fraction`;
        ``nan`` without a spec or across levels)."""
        return self._pair_measure(shared_wall_fraction, i, j)

    def _pair_measure(self, measure, i: int, j: int) -> float:
        """``measure(xy_i, xy_j, rings, max_range)`` on the true walls at the pair's mean depth, cached."""
        key = (measure.__name__, min(i, j), max(i, j))
        if key not in self._measures:
            if self.spec is None or self.cross_level(i, j):
                self._measures[key] = float("nan")
            else:
                depth = 0.5 * (self.scans[i].depth_m + self.scans[j].depth_m)
                rings = interpolate_slice(self.spec.site.slices(), depth)
                self._measures[key] = measure(self.xy[i], self.xy[j], rings, self.max_range)
        return self._measures[key]

    def true_pose(self, i: int, j: int) -> np.ndarray:
        """Where scan ``j`` truly lies in scan ``i``'s compass frame: displacement and yaw correction."""
        offset = in_compass_frame(self.xy[j] - self.xy[i], self.compass_err[i])
        return np.array([offset[0], offset[1], self.compass_err[i] - self.compass_err[j]])

    def displacement_error(self, i: int, j: int, dx_m: float, dy_m: float) -> float:
        """Distance (m) of an estimated displacement of ``j`` in ``i``'s frame from the truth."""
        expected = self.true_pose(i, j)
        return float(np.hypot(dx_m - expected[0], dy_m - expected[1]))

    def pair_error(self, match) -> float:
        """Distance (m) of a match's estimate from the truth displacement in scan i's compass frame."""
        return self.displacement_error(match.i, match.j, match.dx_m, match.dy_m)


def shared_wall_pairs(truth: SiteTruth, scans) -> list[tuple[int, int]]:
    """The pairs (one depth level, within sonar range) that share at least the verification's
    ``min_inliers`` wall points at their true relative pose (:meth:`ReferenceModel.assess_pair`, with
    the limits scaled to the pair's sonar as the matchers scale them): a pair below that minimum cannot
    pass any built-in matcher's verification, whatever it estimates."""
    params = ConvergenceParams()
    models: dict[int, ReferenceModel] = {}
    out = []
    for a, b in combinations(range(len(scans)), 2):
        reach = min(scans[a].max_range_m, scans[b].max_range_m)
        if truth.cross_level(a, b) or np.hypot(*(truth.xy[b] - truth.xy[a])) > reach:
            continue
        if a not in models:
            models[a] = ReferenceModel(scans[a])
        limits = params.for_scans(scans[a], scans[b]).limits()
        if models[a].assess_pair(scans[b], truth.true_pose(a, b), limits).inliers >= limits.min_inliers:
            out.append((a, b))
    return out


def placeable_scans(record, n: int, shared: list[tuple[int, int]]) -> int:
    """The most scans any localizer could place from pair-wise matches: the largest group that the
    ``shared`` pairs (:func:`shared_wall_pairs`) and the record's vertical ties join. So ``placed /
    placeable`` separates what the matching misses from what the site's stations never shared."""
    if n == 0:
        return 0
    index = record.station_index()
    links = [(index[t.lower], index[t.upper]) for t in record_ties(record) if t.lower in index and t.upper in index]
    links += list(shared)
    rows, cols = (np.array([link[k] for link in links], dtype=np.int64) for k in (0, 1))
    graph = coo_matrix((np.ones(len(links)), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return int(np.bincount(labels).max())


def break_pairs(build, truth: SiteTruth, shared: list[tuple[int, int]]) -> list[dict]:
    """The pairs that could have joined an unplaced scan to the placed ones (a :func:`shared_wall_pairs`
    pair with one scan placed and one not), each with what the matching made of it: whether it was
    asked, the best error of its estimates (either direction) and whether the truth was among the
    rival places the matcher reported (``MatchResult.alternatives``, within 0.25 m)."""
    placed = build.poses.placed if build.poses is not None else np.zeros(len(build.range_scans), bool)
    by_pair: dict[frozenset, list] = {}
    for m in build.matches:
        by_pair.setdefault(frozenset((m.i, m.j)), []).append(m)
    rows = []
    for a, b in shared:
        if placed[a] == placed[b]:
            continue
        matches = by_pair.get(frozenset((a, b)), [])
        errors = [truth.pair_error(m) for m in matches if math.isfinite(m.dx_m) and math.isfinite(m.dy_m)]
        rivals = [truth.displacement_error(m.i, m.j, r.dx_m, r.dy_m) for m in matches for r in m.alternatives]
        rows.append({"i": a, "j": b, "asked": bool(matches), "best_error_m": min(errors, default=float("nan")),
                     "truth_among_rivals": any(e <= WRONG_SCAN_M for e in rivals)})
    return rows


def far_pair_scores(loaded, build, truth: SiteTruth, limit: int) -> list[dict]:
    """Ask the site's matcher directly about up to ``limit`` pairs with < 20 % overlap (drawn with the
    site's seed); one row per pair with whether it converged and how far off it is."""
    record = loaded.record
    far = [(i, j) for i, j in combinations(range(len(build.range_scans)), 2)
           if truth.overlap(i, j) < FAR_OVERLAP]
    if len(far) > limit:
        pick = np.random.default_rng([record.seed, 20]).choice(len(far), size=limit, replace=False)
        far = [far[k] for k in sorted(pick)]
    matcher = resolve_stages(record, default_registry())["matcher"]
    rows = []
    for i, j in far:
        m = match_pair(matcher, build.range_scans, record.seed, i, j)
        finite = all(math.isfinite(v) for v in (m.dx_m, m.dy_m))
        rows.append({"i": i, "j": j, "overlap": truth.overlap(i, j), "converged": bool(m.converged),
                     "error_m": truth.pair_error(m) if finite else float("nan"), "seconds": m.seconds})
    return rows


def score_site(path: Path, catalog: Path, localizer=None, far_limit: int = 0, matcher=None) -> dict | None:
    """Build one site with the runner and score it against its truth (module docstring); ``localizer``
    and ``matcher`` are each ``(name, params)`` (:func:`with_stage`: a ``None`` name keeps the record's
    plugin and adds the params to its own)."""
    name, params = localizer or (None, {})
    matcher_name, matcher_params = matcher or (None, {})
    loaded = with_stage(with_stage(load_record(path, catalog), "localizer", name, params), "matcher",
                        matcher_name, matcher_params)
    record = loaded.record
    if not record.truth:
        return None
    t0 = time.perf_counter()
    build = build_site(loaded)
    return score_build(loaded, build, catalog, time.perf_counter() - t0, far_limit)


def score_build(loaded, build, catalog: Path, seconds: float, far_limit: int = 0) -> dict:
    """The figures of :func:`score_site` for a site already built (``seconds`` its build time)."""
    record = loaded.record
    scans = build.range_scans
    if len(scans) < len(record.scans):  # the build failed before every scan was segmented
        return failed_row(record, build, seconds)
    truth = SiteTruth(record, scans, catalog)
    shared = shared_wall_pairs(truth, scans)
    pairs = []
    for m in build.matches:
        estimate_err = truth.pair_error(m) if math.isfinite(m.dx_m) and math.isfinite(m.dy_m) else float("nan")
        err = estimate_err if m.converged else float("nan")
        neighbour = abs(m.i - m.j) == 1
        pairs.append({"i": m.i, "j": m.j, "converged": m.converged, "error_m": err, "estimate_error_m": estimate_err,
                      "overlap": truth.overlap(m.i, m.j), "shared_wall": truth.shared_wall(m.i, m.j),
                      "neighbour": neighbour, "seconds": m.seconds, "reason": m.reason})
    poses = build.poses
    position_errors = reference_frame_errors(poses, truth.xy, truth.compass_err) if poses is not None else []
    aligned = aligned_errors(build.result)
    ge50 = [p for p in pairs if p["overlap"] >= 0.5]
    wall50 = [p for p in pairs if p["shared_wall"] >= 0.5]
    eligible = [p for p in ge50 if p["neighbour"]]
    good = [p for p in eligible if right(p)]
    false_conv = [p for p in pairs if p["converged"] and p["error_m"] > OK_PAIR_M]
    cross_level = [m for m in build.matches if truth.cross_level(m.i, m.j)]
    far = far_pair_scores(loaded, build, truth, far_limit) if far_limit > 0 else []
    max_aligned = float(np.max(aligned)) if len(aligned) else float("nan")
    return {
        "site": record.id,
        "status": build.result.status,
        "failure": build.result.error,
        "scans": len(scans),
        "placed": int(poses.placed.sum()) if poses is not None else 0,
        "placeable": placeable_scans(record, len(scans), shared),
        "break_pairs": break_pairs(build, truth, shared),
        "median_position_error_m": statistics.median(position_errors) if position_errors else float("nan"),
        "max_position_error_m": max(position_errors) if position_errors else float("nan"),
        "aligned_errors_m": [float(e) for e in aligned],
        "median_aligned_error_m": float(np.median(aligned)) if len(aligned) else float("nan"),
        "max_aligned_error_m": max_aligned,
        "silent_wrong": bool(build.result.status == "ok" and max_aligned > WRONG_SCAN_M),
        "group_links": join_errors(poses, truth),
        "wrong_scans": int(sum(e > WRONG_SCAN_M for e in aligned)),
        "eligible_pairs": len(eligible),
        "eligible_pairs_ok": len(good),
        "pairs_ge50": len(ge50),
        "pairs_ge50_ok": sum(map(right, ge50)),
        "pairs_wall50": len(wall50),
        "pairs_wall50_ok": sum(map(right, wall50)),
        "pairs_ge50_rejected_reasons": [p["reason"][:120] for p in ge50 if not p["converged"]],
        "pairs_ge50_rejected_correct": sum(1 for p in ge50 if not p["converged"] and p["estimate_error_m"] <= OK_PAIR_M),
        "pairs": len(pairs),
        "pairs_converged": sum(p["converged"] for p in pairs),
        "false_convergences": len(false_conv),
        "false_convergences_no_overlap": sum(1 for p in false_conv if p["overlap"] == 0.0),
        "worst_false_convergence_m": max((p["error_m"] for p in false_conv), default=float("nan")),
        "far_pairs": len(far),
        "far_pairs_converged": sum(p["converged"] for p in far),
        "far_pairs_converged_errors_m": [p["error_m"] for p in far if p["converged"]],
        "cross_level_pairs": len(cross_level),
        "cross_level_converged": sum(1 for m in cross_level if m.converged),
        "median_pair_seconds": statistics.median(p["seconds"] for p in pairs) if pairs else float("nan"),
        "site_seconds": seconds,
        "unplaced_reasons": [r for r in (poses.reasons if poses is not None else ()) if r][:3],
    }


def join_errors(poses, truth: SiteTruth) -> list[dict]:
    """Each join of groups (:attr:`~cistern_archive.core.poses.Poses.group_links`): its stations, how far
    the second lies from where it belongs relative to the first after the rigid alignment of the placed
    scans onto the truth, and the join's 95 % radius (the site's ``group_link_ci95_m``)."""
    if poses is None or not poses.group_links:
        return []
    placed = np.flatnonzero(poses.placed)
    aligned = dict(zip(placed, aligned_positions(np.asarray(poses.xy_m)[placed], truth.xy[placed])))
    stations = [s.station for s in truth.scans]
    return [{"stations": [stations[i], stations[j]], "ci95_m": radius,
             "error_m": float(np.hypot(*((aligned[j] - aligned[i]) - (truth.xy[j] - truth.xy[i]))))}
            for (i, j), radius in zip(poses.group_links, poses.group_link_radius95_m)]


def right(pair: dict) -> bool:
    """Whether a scored pair converged within ``OK_PAIR_M`` of the truth."""
    return bool(pair["converged"] and pair["error_m"] <= OK_PAIR_M)


def failed_row(record, build, seconds: float) -> dict:
    """The row of a site whose build stopped before its scans were segmented: nothing placed."""
    nan = float("nan")
    row = {key: 0 for key in ("placed", "placeable", "wrong_scans", "eligible_pairs", "eligible_pairs_ok", "pairs_ge50", "pairs_ge50_ok",
                              "pairs_wall50", "pairs_wall50_ok",
                              "pairs", "pairs_converged", "false_convergences", "false_convergences_no_overlap",
                              "far_pairs", "far_pairs_converged", "cross_level_pairs", "cross_level_converged")}
    row.update({key: nan for key in ("median_position_error_m", "max_position_error_m", "median_aligned_error_m",
                                     "max_aligned_error_m", "worst_false_convergence_m", "median_pair_seconds")})
    row.update(site=record.id, status=build.result.status, failure=build.result.error, scans=len(record.scans),
               aligned_errors_m=[], pairs_ge50_rejected_correct=0, silent_wrong=False, pairs_ge50_rejected_reasons=[],
               far_pairs_converged_errors_m=[], site_seconds=seconds, unplaced_reasons=[build.result.error or ""],
               break_pairs=[], group_links=[])
    return row


def demo_summary(rows: list[dict]) -> dict:
    """The summary of the demo catalog (its historical format)."""
    eligible = sum(r["eligible_pairs"] for r in rows)
    return {
        "sites": len(rows),
        "scans": sum(r["scans"] for r in rows),
        "scans_placed": sum(r["placed"] for r in rows),
        "pair_success_rate": sum(r["eligible_pairs_ok"] for r in rows) / eligible if eligible else float("nan"),
        "false_convergences": sum(r["false_convergences"] for r in rows),
        "false_convergences_no_overlap": sum(r["false_convergences_no_overlap"] for r in rows),
        "median_position_error_m": statistics.median(r["median_position_error_m"] for r in rows) if rows else None,
        "max_position_error_m": max((r["max_position_error_m"] for r in rows), default=None),
        "per_site": rows,
    }


def random_summary(rows: list[dict]) -> dict:
    """The ten numbers of the ``--random`` interface (module docstring) over ``rows``."""
    errors = [e for r in rows for e in r["aligned_errors_m"]]
    return {
        "sites": len(rows),
        "scans": sum(r["scans"] for r in rows),
        "placed": sum(r["placed"] for r in rows),
        "pairs_ge50": sum(r["pairs_ge50"] for r in rows),
        "pairs_ge50_ok": sum(r["pairs_ge50_ok"] for r in rows),
        "far_pairs": sum(r["far_pairs"] for r in rows),
        "far_pairs_converged": sum(r["far_pairs_converged"] for r in rows),
        "median_aligned_error_m": float(np.median(errors)) if errors else float("nan"),
        "max_aligned_error_m": float(np.max(errors)) if errors else float("nan"),
        "silent_wrong_sites": sum(r["silent_wrong"] for r in rows),
        "placeable": sum(r["placeable"] for r in rows),
        "wrong_sites": sum(r["wrong_scans"] > 0 for r in rows),
        "wrong_scans": sum(r["wrong_scans"] for r in rows),
        "break_pairs": sum(len(r["break_pairs"]) for r in rows),
        "break_pairs_asked": sum(p["asked"] for r in rows for p in r["break_pairs"]),
        "break_pairs_estimated_right": sum(p["best_error_m"] <= OK_PAIR_M for r in rows for p in r["break_pairs"]),
        "break_pairs_truth_among_rivals": sum(p["truth_among_rivals"] for r in rows for p in r["break_pairs"]),
        "pairs_wall50": sum(r["pairs_wall50"] for r in rows),
        "pairs_wall50_ok": sum(r["pairs_wall50_ok"] for r in rows),
        "pairs_ge50_rejected": sum(len(r["pairs_ge50_rejected_reasons"]) for r in rows),
        "pairs_ge50_rejected_correct": sum(r["pairs_ge50_rejected_correct"] for r in rows),
        "joins": sum(len(r["group_links"]) for r in rows),
        "joins_within_ci95": sum(j["error_m"] <= j["ci95_m"] for r in rows for j in r["group_links"]),
    }


RATES = (("scans placed", "placed", "scans"), ("pairs >=50% within 0.10 m", "pairs_ge50_ok", "pairs_ge50"),
         ("pairs sharing >=50% of their wall within 0.10 m", "pairs_wall50_ok", "pairs_wall50"),
         ("far pairs converged", "far_pairs_converged", "far_pairs"), ("silent wrong sites", "silent_wrong_sites", "sites"),
         ("joins within their 95 % interval", "joins_within_ci95", "joins"))


def rates(summary: dict) -> dict:
    """Each rate of :data:`RATES` with its 95 % Wilson interval."""
    out = {}
    for _, num, den in RATES:
        k, n = summary[num], summary[den]
        out[num] = {"k": k, "n": n, "rate": k / n if n else float("nan"), "ci95": list(wilson_interval(k, n))}
    return out


def rate_cell(rate: dict) -> str:
    if not rate["n"]:
        return "–"
    lo, hi = rate["ci95"]
    return f"{100 * rate['rate']:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] ({rate['k']}/{rate['n']})"


def breakdown_table(groups: dict[str, dict]) -> str:
    """Rates with 95 % Wilson intervals per group, as a Markdown table."""
    head = "| sites | " + " | ".join(name for name, _, _ in RATES) + " | median / max aligned error (m) |"
    lines = [head, "|" + "---|" * (len(RATES) + 2)]
    for label, summary in groups.items():
        r = rates(summary)
        lines.append(f"| {label} ({summary['sites']}) | " + " | ".join(rate_cell(r[num]) for _, num, _ in RATES)
                     + f" | {summary['median_aligned_error_m']:.3f} / {summary['max_aligned_error_m']:.3f} |")
    return "\n".join(lines)


def print_rows(rows: list[dict]) -> None:
    print(f"{'site':16s} {'placed':>8s} {'pos err med/max (m)':>20s} {'aligned med/max':>16s} "
          f"{'>=50% ok':>9s} {'false':>5s} {'far conv':>8s} {'site s':>7s}")
    for r in rows:
        print(f"{r['site']:16s} {r['placed']:>3d}/{r['scans']:<4d} "
              f"{r['median_position_error_m']:>9.3f}/{r['max_position_error_m']:<9.3f} "
              f"{r['median_aligned_error_m']:>7.3f}/{r['max_aligned_error_m']:<7.3f} "
              f"{r['pairs_ge50_ok']:>4d}/{r['pairs_ge50']:<4d} {r['false_convergences']:>5d} "
              f"{r['far_pairs_converged']:>3d}/{r['far_pairs']:<4d} {r['site_seconds']:>7.1f}"
              + ("" if r["status"] == "ok" else f"  {r['status']}: {(r['failure'] or '')[:80]}"))
        for reason in r["unplaced_reasons"]:
            print(f"    unplaced: {reason[:150]}")


def demo_main(args) -> int:
    rows = []
    for path in record_paths(args.catalog):
        if args.site and path.stem not in args.site:
            continue
        row = score_site(path, args.catalog, (args.localizer, args.localizer_params),
                         matcher=(args.matcher, args.matcher_params))
        if row is not None:
            rows.append(row)
    print_rows(rows)
    summary = demo_summary(rows)
    eligible = sum(r["eligible_pairs"] for r in rows)
    print(f"neighbour pairs with >=50% overlap within 0.10 m: {100 * summary['pair_success_rate']:.1f} % of "
          f"{eligible}; false convergences: {summary['false_convergences']} "
          f"({summary['false_convergences_no_overlap']} without overlap)")
    if args.json:
        print(json.dumps(summary, sort_keys=True, default=float))
    return 0


def _random_site(job: tuple[Path, Path, tuple[str | None, dict], int, tuple[str | None, dict]]) -> dict:
    """Simulate one random site into the temporary catalog, build it and score it (one worker's job)."""
    spec_path, catalog, localizer, far_limit, matcher = job
    start = time.perf_counter()
    record_path = simulate_into(spec_path, catalog)
    simulated = time.perf_counter() - start
    row = score_site(record_path, catalog, localizer, far_limit, matcher)
    row["simulation_seconds"] = simulated
    return row


def random_main(args) -> int:
    if args.generator != GeneratorSettings():
        print(f"generator settings: {args.generator.model_dump_json(exclude_defaults=True)}")
    try:
        cisterns = random_cisterns(args.random, args.seed, args.generator)
    except ValueError as exc:  # settings the generator cannot draw a site from
        print(f"error: --generator {args.generator.model_dump_json(exclude_defaults=True)}: {exc}", file=sys.stderr)
        return 2
    chambers = {c.spec.id: c.chambers for c in cisterns}
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="random-cisterns-") as tmp:
        catalog = Path(tmp)
        jobs = [(path, catalog, (args.localizer, args.localizer_params), args.far_pairs,
                 (args.matcher, args.matcher_params))
                for path in write_specs(cisterns, catalog)]
        if args.workers > 1:
            with ProcessPoolExecutor(max_workers=args.workers) as pool:
                rows = list(pool.map(_random_site, jobs))
        else:
            rows = [_random_site(job) for job in jobs]
    wall = time.perf_counter() - start
    for row in rows:
        row["chambers"] = chambers[row["site"]]
    print_rows(rows)
    groups = {"all": random_summary(rows)}
    for n in sorted(set(chambers.values())):
        groups[f"{n} chamber{'s' if n > 1 else ''}"] = random_summary([r for r in rows if r["chambers"] == n])
    print(breakdown_table(groups))
    everything = groups["all"]
    for label, group in groups.items():
        print(f"{label}: {group['placeable']} of {group['scans']} scans placeable from pair-wise matches (a chain "
              f"of pairs sharing enough wall at the truth), {group['placed']} placed")
    print(f"pairs that could join an unplaced scan to the placed ones: {everything['break_pairs']}, asked "
          f"{everything['break_pairs_asked']}, an estimate within {OK_PAIR_M:.2f} m "
          f"{everything['break_pairs_estimated_right']}, the truth among the matcher's rival places "
          f"{everything['break_pairs_truth_among_rivals']}")
    print(f"sites with a placed scan more than {WRONG_SCAN_M:.2f} m off after alignment, whatever their status: "
          f"{everything['wrong_sites']} ({everything['wrong_scans']} scans; reported ok: "
          f"{everything['silent_wrong_sites']})")
    print(f"joins of groups whose 95 % interval holds the truth: {everything['joins_within_ci95']} of "
          f"{everything['joins']}")
    print(f"pairs with >=50% overlap rejected: {everything['pairs_ge50_rejected']}, of which "
          f"{everything['pairs_ge50_rejected_correct']} with an estimate within 0.10 m")
    failed = [r["site"] for r in rows if r["status"] == "failed"]
    partial = [r["site"] for r in rows if r["status"] == "partial"]
    per_site = wall / len(rows) if rows else float("nan")
    print(f"{len(rows)} sites in {wall:.1f} s ({per_site:.1f} s per site with {args.workers} worker(s); "
          f"median build {statistics.median(r['site_seconds'] for r in rows):.1f} s); "
          f"partial: {len(partial)}; failed: {', '.join(failed) or 'none'}")
    if args.details:
        details = {"seed": args.seed, "workers": args.workers, "wall_seconds": wall, "far_pairs_per_site": args.far_pairs,
                   "groups": {k: {**v, "rates": rates(v)} for k, v in groups.items()}, "per_site": rows}
        Path(args.details).write_text(json.dumps(strict_json(details), indent=1, allow_nan=False) + "\n")
    if args.json:
        print(json.dumps(strict_json({k: groups["all"][k] for k in RANDOM_KEYS}), allow_nan=False))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--catalog", type=Path, default=ROOT / "catalog")
    parser.add_argument("--site", action="append", default=[], help="only these site ids (demo catalog)")
    parser.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    parser.add_argument("--localizer", help="use this localizer plugin instead of the records' own")
    parser.add_argument("--localizer-params", type=json.loads, default={},
                        help='localizer parameters as JSON, e.g. \'{"bridge_confidence": 0.8}\'')
    parser.add_argument("--matcher", help="use this matcher plugin instead of the records' own")
    parser.add_argument("--matcher-params", type=json.loads, default={},
                        help="parameters added to the records' matcher's (or --matcher's), as JSON")
    parser.add_argument("--random", type=int, metavar="N", help="N random multi-chamber cisterns instead of the catalog")
    parser.add_argument("--seed", type=int, default=1, help="seed of the random cisterns")
    parser.add_argument("--workers", type=int, default=1, help="sites built in parallel (--random)")
    parser.add_argument("--far-pairs", type=int, default=12, metavar="K",
                        help="far pairs (< 20 %% overlap) asked of the matcher per site (--random)")
    parser.add_argument("--details", type=Path, help="write per-site and per-chamber-count results here (--random)")
    parser.add_argument("--generator", default="{}", metavar="JSON",
                        help="settings of the random cisterns (cistern_archive.simulation.chambers.GeneratorSettings) "
                             'as JSON, e.g. \'{"tunnel_length_m": [2, 4], "tunnel_station_spacing_m": 1.5}\' (--random)')
    args = parser.parse_args(argv)
    try:
        args.generator = GeneratorSettings.model_validate_json(args.generator)
    except ValidationError as exc:
        parser.error(f"--generator: {exc}")
    if args.random is not None:
        if args.random < 1 or args.workers < 1 or args.far_pairs < 0:
            parser.error("--random and --workers must be at least 1, --far-pairs at least 0")
        return random_main(args)
    return demo_main(args)


if __name__ == "__main__":
    sys.exit(main())
