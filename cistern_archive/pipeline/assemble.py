"""The JSON result of a site (:class:`~cistern_archive.pipeline.results.SiteResult`) from whatever its
build reached: scan poses, pairs, the dimension table with intervals and weak flags, status, provenance."""

from __future__ import annotations

import math
import platform
from collections.abc import Mapping, Sequence

import numpy as np

from cistern_archive import __version__
from cistern_archive.catalog.loader import LoadedRecord
from cistern_archive.catalog.models import ScanRef, SiteRecord
from cistern_archive.core.grids import EvidenceGrid
from cistern_archive.grid.lean import wall_lean_deg
from cistern_archive.pipeline.contracts import DimensionRow, MatchGuess, Poses
from cistern_archive.pipeline.intervals import ci95_half_width
from cistern_archive.pipeline.results import (
    DimensionResult,
    PairResult,
    PluginProvenance,
    Provenance,
    ScanPose,
    SiteBuild,
    SiteResult,
    finite_or_none,
    track_summary,
)
from cistern_archive.pipeline.status import label_indices, site_status, weakness
from cistern_archive.pipeline.support import held_by_loops_only


def assemble_result(build: SiteBuild, loaded: LoadedRecord, plugins: Sequence[PluginProvenance],
                    timings: Mapping[str, float]) -> SiteResult:
    """Fill the JSON result from whatever the build reached; ``plugins`` are the resolved stages'
    provenance, ``timings`` the seconds each step took."""
    record = loaded.record
    result = build.result.model_copy()
    truth = {t.station: t for t in record.truth}
    poses = build.poses
    refs = scan_entries(build)
    labels = [ref.station for ref in refs]
    scans = []
    for k, ref in enumerate(refs):
        raw = build.raw_scans[k] if k < len(build.raw_scans) else None
        placed = bool(poses is not None and poses.placed[k])
        sigma = (None, None)
        if placed and poses.covariance is not None:
            sigma = (finite_or_none(math.sqrt(poses.covariance[k, 0, 0])),
                     finite_or_none(math.sqrt(poses.covariance[k, 1, 1])))
        t = truth.get(ref.station)
        scans.append(ScanPose(
            index=k, id=ref.station, file=ref.file,
            x_m=finite_or_none(poses.xy_m[k, 0]) if placed else None,
            y_m=finite_or_none(poses.xy_m[k, 1]) if placed else None,
            yaw_rad=float(poses.yaw_rad[k]) if poses is not None else (raw.yaw_rad if raw else 0.0),
            depth_m=raw.depth_m if raw else (ref.depth_m or 0.0),
            placed=placed,
            reason=label_indices(poses.reasons[k] if poses is not None else "not localized: " + (result.error or ""),
                                 labels),
            sigma_x_m=sigma[0], sigma_y_m=sigma[1],
            truth_x_m=t.x_m if t else None, truth_y_m=t.y_m if t else None,
            echo_scale=None if build.echo_scale is None else round(float(build.echo_scale[k]), 4),
        ))
    result.scans = scans
    result.reference_scan = poses.reference if poses is not None and poses.reference >= 0 else None
    links = [] if poses is None else [
        (labels[i], labels[j], _ci95(poses.group_link_radius95_m, n)) for n, (i, j) in enumerate(poses.group_links)
        if 0 <= i < len(labels) and 0 <= j < len(labels)]
    result.group_links = [(a, b) for a, b, _ in links]
    result.group_link_ci95_m = [ci for _, _, ci in links]
    result.pairs = [
        PairResult(i=m.i, j=m.j, dx_m=finite_or_none(m.dx_m), dy_m=finite_or_none(m.dy_m), dyaw_rad=finite_or_none(m.dyaw_rad),
                   weight=finite_or_none(m.weight) or 0.0, confidence=finite_or_none(m.confidence), tentative=m.tentative,
                   converged=m.converged, iterations=m.iterations, seconds=round(m.seconds, 6), reason=m.reason,
                   guess=None if m.guess is None else guess_row(m.guess), alternatives=[guess_row(a) for a in m.alternatives])
        for m in build.matches
    ]
    if build.table is not None:
        grids = build.map_result.grids if build.map_result is not None else ()
        result.dimensions = [dimension_result(row, _requested_probes(record, k, row), labels,
                                              cell_m=_cell_at(build, row.depth_m), poses=poses, grids=grids)
                             for k, row in enumerate(build.table.rows)]
        result.dimension_stats = {k: finite_or_none(v) for k, v in sorted(build.table.stats.items())}
    if build.map_result is not None:
        result.map_stats = {k: float(v) for k, v in sorted(build.map_result.stats.items())}
    loop_only = [] if poses is None or record.survey is not None else [  # a survey's navigation holds its scans
        (labels[k], [labels[j] for j in others])
        for k, others in held_by_loops_only(build.range_scans, build.matches, poses)]
    result.status, result.status_reasons = site_status(
        failed_stage=result.error, scans_placed=[s.placed for s in scans], labels=labels,
        unmeasured=_unmeasured(record, result.dimensions) if build.table is not None else [], joins=links,
        loop_only=loop_only)
    result.track = None if build.track is None else track_summary(build.track)
    result.timings_s = dict(timings)
    result.timings_s["total"] = round(sum(timings.values()), 6)
    result.provenance = Provenance(
        code_version=__version__,
        plugins=list(plugins),
        seeds={"site": record.seed},
        record_file=str(loaded.path.relative_to(loaded.root)) if loaded.path.is_relative_to(loaded.root) else str(loaded.path),
        python=platform.python_version(),
        numpy=np.__version__,
    )
    return result


def _ci95(radii: Sequence[float], n: int) -> float | None:
    """The 95 % radius (m) of the ``n``-th group link, ``None`` when unknown."""
    return finite_or_none(radii[n]) if n < len(radii) else None


def scan_entries(build: SiteBuild) -> list[ScanRef]:
    """The record's scans, or for a record that lists none (a survey) one entry per segmented scan,
    named by its station and the file of :attr:`SiteBuild.scan_files`."""
    if build.record.scans:
        return list(build.record.scans)
    return [ScanRef(file=file, station=scan.station, depth_m=scan.depth_m)
            for scan, file in zip(build.range_scans, build.scan_files)]


def _requested_probes(record: SiteRecord, k: int, row: DimensionRow) -> int:
    """How many probes the record asked for the ``k``-th row (by position when it matches the
    reference, else by name and kind; 0 when no reference matches)."""
    refs = record.references
    if k < len(refs) and refs[k].name == row.name and refs[k].kind == row.reference_kind:
        return refs[k].measure.repeats
    same = [r for r in refs if r.name == row.name and r.kind == row.reference_kind]
    return same[0].measure.repeats if same else 0


def dimension_result(row: DimensionRow, requested: int, labels: Sequence[str], *, cell_m: float | None = None,
                     poses: Poses | None = None, grids: Sequence[EvidenceGrid] = ()) -> DimensionResult:
    """The JSON form of a comparator row, flagged weak (:func:`~cistern_archive.pipeline.status.weakness`,
    with the lean of its walls between the depth slices ``grids`` and the comparator's heading check) and
    with its 95 % interval (:func:`~cistern_archive.pipeline.intervals.ci95_half_width`, on a grid of
    ``cell_m``) when it is measured."""
    map_m, std = finite_or_none(row.map_m), finite_or_none(row.probe_std_m)
    lines = [line for line in row.probe_lines if line is not None]
    shift = None if math.isnan(row.heading_shift_m) else row.heading_shift_m
    weak = "" if map_m is None else weakness(len(row.probes), requested, std,
                                             wall_lean_deg(grids, row.depth_m, lines), heading_shift_m=shift)
    ci = None if map_m is None or cell_m is None else ci95_half_width(row.probes, cell_m, lines, poses, shift)
    return DimensionResult(name=row.name, map_m=map_m, ci95_m=ci, reference_m=row.reference_m,
                           reference_kind=row.reference_kind, diff_m=finite_or_none(row.diff_m),
                           depth_m=finite_or_none(row.depth_m) or 0.0, probe_std_m=std,
                           probes_m=[float(p) for p in row.probes], probes_requested=requested,
                           heading_shift_m=finite_or_none(row.heading_shift_m),
                           weak=bool(weak), weak_reason=weak, note=label_indices(row.note, labels))


def _cell_at(build: SiteBuild, depth_m: float) -> float | None:
    """Cell size of the slice nearest ``depth_m``."""
    grids = build.map_result.grids if build.map_result is not None else ()
    return min(grids, key=lambda g: abs(g.depth_m - depth_m)).cell_m if grids else None


def _unmeasured(record: SiteRecord, dimensions: Sequence[DimensionResult]) -> list[str]:
    """``name (kind): reason`` of every reference the table has no measured value for."""
    measured = {(d.name, d.reference_kind) for d in dimensions if d.map_m is not None}
    notes = {(d.name, d.reference_kind): d.note for d in dimensions}
    out = []
    for ref in record.references:
        if (ref.name, ref.kind) not in measured:
            note = notes.get((ref.name, ref.kind)) or "no wall found"
            out.append(f"{ref.name} ({ref.kind}): {note}")
    return out


def guess_row(guess: MatchGuess) -> list[float]:
    """``[dx_m, dy_m, dyaw_rad, radius_m]`` of a search window (``result.json``)."""
    return [guess.dx_m, guess.dy_m, guess.dyaw_rad, guess.radius_m]
