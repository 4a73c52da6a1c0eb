"""Write a simulated site as a catalog: scans (``.npz``), ``truth.json`` and a ready site record.

Layout under the output root ``OUT`` (which is a catalog root)::

    OUT/<record_dir>/<id>.yaml          the site record (SiteRecord), paths relative to OUT
    OUT/data/<id>/<station>.npz         one scan per station (cistern_archive.sonar.interchange)
    OUT/data/<id>/truth.json            true poses, walls per depth, true reference dimensions
    OUT/specs/<id>.yaml                 a copy of the spec, unless the spec already lives under OUT

``OUT/data/<id>/`` belongs to the simulation: ``.npz`` files left there by an earlier run of the same
spec that the new run does not write (e.g. a route now has fewer stations) are removed.

Truth poses in the record and in ``truth.json`` are in the site's map frame: x east, y north (m), yaw in
degrees counter-clockwise from east. Reference probes are given in the frame of a station: ``inside`` is
relative to that station's true position, axes east/north, ``direction_deg`` counter-clockwise from east.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import yaml

from cistern_archive.catalog.models import (
    PipelineSpec,
    Probe,
    ReferenceDimension,
    ScanRef,
    SiteRecord,
    SonarSettings,
    TruthPose,
)
from cistern_archive.core.files import write_text_atomic
from cistern_archive.sonar.geometry import interpolate_slice, ray_cast
from cistern_archive.sonar.interchange import write_scan
from cistern_archive.simulation.simulator import SimulatedSite, TruePose, simulate_site, station_rng
from cistern_archive.simulation.spec import MeasureSpec, ReferenceSpec, SimulationSpec, load_spec

TRUTH_SCHEMA = "cistern-archive/simulation-truth"


def probe_lengths(rings: list[np.ndarray], inside: tuple[float, float], direction_deg: float, repeats: int,
                  spacing_m: float) -> np.ndarray:
    """Wall-to-wall lengths along ``repeats`` parallel probes ``spacing_m`` apart, centred on ``inside``.

    Each probe goes through its point in both senses of ``direction_deg`` to the first wall.
    """
    theta = math.radians(direction_deg)
    normal = np.array([-math.sin(theta), math.cos(theta)])
    offsets = (np.arange(repeats) - (repeats - 1) / 2.0) * spacing_m
    lengths = []
    for offset in offsets:
        point = np.asarray(inside, dtype=np.float64) + offset * normal
        ranges, _ = ray_cast(point, np.array([theta, theta + math.pi]), rings)
        lengths.append(float(ranges.sum()))
    return np.array(lengths)


def _probe_depth(measure: MeasureSpec, poses: dict[str, TruePose]) -> float:
    if measure.depth_m is not None:
        return measure.depth_m
    if measure.frame is not None:
        return poses[measure.frame].depth_m
    return next(iter(poses.values())).depth_m


def reference_value(ref: ReferenceSpec, spec: SimulationSpec, poses: dict[str, TruePose], index: int) -> float:
    """The value a reference takes: given, measured on the true walls, or truth plus a mosaic error."""
    if ref.value_m is not None:
        return ref.value_m
    m = ref.measure
    rings = interpolate_slice(spec.site.slices(), _probe_depth(m, poses))
    truth = float(np.mean(probe_lengths(rings, m.inside, m.direction_deg, m.repeats, m.spacing_m)))
    if ref.kind == "truth":
        return round(truth, 3)
    error = ref.error_sigma_m * station_rng(spec.seed, 2, index).standard_normal()
    return round(truth + float(error), 3)


def _probe(measure: MeasureSpec, poses: dict[str, TruePose]) -> Probe:
    origin = (0.0, 0.0)
    if measure.frame is not None:
        if measure.frame not in poses:
            raise ValueError(f"reference probe frame {measure.frame!r} is not a station")
        origin = (poses[measure.frame].x_m, poses[measure.frame].y_m)
    inside = (round(measure.inside[0] - origin[0], 4), round(measure.inside[1] - origin[1], 4))
    return Probe(method="probe", frame=measure.frame, inside=inside, direction_deg=measure.direction_deg,
                 repeats=measure.repeats, spacing_m=measure.spacing_m, depth_m=measure.depth_m)


def build_record(site: SimulatedSite, scan_files: list[str], spec_ref: str | None) -> SiteRecord:
    """The site record of a simulated site (paths relative to the catalog root)."""
    spec = site.spec
    poses = {s.pose.station: s.pose for s in site.scans}
    below = {station.name: station.below for station in spec.stations}
    scans = [
        ScanRef(file=path, format="npz", station=s.pose.station, depth_m=round(s.scan.depth_m, 3),
                below=below.get(s.pose.station))
        for s, path in zip(site.scans, scan_files)
    ]
    references = [
        ReferenceDimension(name=ref.name, kind=ref.kind, value_m=reference_value(ref, spec, poses, k),
                           measure=_probe(ref.measure, poses))
        for k, ref in enumerate(spec.references)
    ]
    truth = [
        TruthPose(station=p.station, x_m=round(p.x_m, 4), y_m=round(p.y_m, 4),
                  yaw_deg=round(math.degrees(p.yaw_rad), 4))
        for p in poses.values()
    ]
    sonar = SonarSettings(
        model=spec.sonar.model, frequency_khz=spec.sonar.frequency_khz, range_m=spec.sonar.range_m,
        bins=spec.sonar.bins, step_deg=spec.sonar.step_deg, beam_width_deg=spec.sonar.beam_width_deg,
        vertical_beam_width_deg=spec.sonar.vertical_beam_width_deg,
    )
    return SiteRecord(
        id=spec.id, name=spec.name, description=spec.description.strip(), location=spec.location,
        sonar=sonar, segmentation=spec.segmentation, scans=scans, references=references,
        seed=spec.seed, truth=truth, simulation=spec_ref,
    )


def truth_document(site: SimulatedSite, record: SiteRecord, scan_files: list[str]) -> dict:
    """The ``truth.json`` content."""
    spec = site.spec
    return {
        "schema": TRUTH_SCHEMA,
        "schema_version": 1,
        "site": spec.id,
        "seed": spec.seed,
        "frame": "map frame: x east, y north (m); yaw degrees CCW from east; depth positive down",
        "stations": [
            {
                "station": s.pose.station,
                "file": path,
                "x_m": s.pose.x_m,
                "y_m": s.pose.y_m,
                "yaw_deg": math.degrees(s.pose.yaw_rad),
                "depth_m": s.pose.depth_m,
                "measured_yaw_deg": math.degrees(s.scan.yaw_rad),
                "measured_depth_m": s.scan.depth_m,
            }
            for s, path in zip(site.scans, scan_files)
        ],
        "levels": [
            {"depth_m": depth, "rings": [np.asarray(r).round(6).tolist() for r in rings]}
            for depth, rings in spec.site.slices()
        ],
        "references": [ref.model_dump(mode="json") for ref in record.references],
    }


def record_yaml(record: SiteRecord, spec_ref: str | None) -> str:
    """The record as YAML, with a header naming the spec it is generated from."""
    header = "# Generated by `cistern-archive simulate`"
    header += f" from {spec_ref}; regenerate rather than edit.\n" if spec_ref else "; regenerate rather than edit.\n"
    data = record.model_dump(mode="json", exclude_none=True)
    if record.pipeline == PipelineSpec():
        del data["pipeline"]
    body = yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=100)
    return header + body


def write_site(site: SimulatedSite, out: Path, *, spec_path: Path | None = None, record_dir: str = "") -> Path:
    """Write scans, truth and record under the catalog root ``out``; return the record's path.

    Parameters
    ----------
    site : SimulatedSite
    out : Path
        The catalog root to write into.
    spec_path : Path, optional
        The spec file; referenced by the record (copied to ``out/specs/`` when it is outside ``out``).
    record_dir : str
        Folder of the record under ``out`` (``""`` or ``"sites"``).
    """
    out = Path(out)
    spec_id = site.spec.id
    data_dir = out / "data" / spec_id
    scan_files = []
    for s in site.scans:
        relative = f"data/{spec_id}/{s.pose.station}.npz"
        write_scan(s.scan, out / relative)
        scan_files.append(relative)
    written = {Path(f).name for f in scan_files}
    for stale in sorted(data_dir.glob("*.npz")):
        if stale.name not in written:
            stale.unlink()
    spec_ref = None
    if spec_path is not None:
        spec_path = Path(spec_path).resolve()
        try:
            spec_ref = spec_path.relative_to(out.resolve()).as_posix()
        except ValueError:
            spec_ref = f"specs/{spec_id}.yaml"
            target = out / spec_ref
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(spec_path, target)
    record = build_record(site, scan_files, spec_ref)
    truth = truth_document(site, record, scan_files)
    write_text_atomic(data_dir / "truth.json", json.dumps(truth, indent=1, sort_keys=False) + "\n")
    record_path = out / record_dir / f"{spec_id}.yaml"
    write_text_atomic(record_path, record_yaml(record, spec_ref))
    return record_path


def generated_header(site_id: str, name: str, description: str, rng: np.random.Generator) -> dict:
    """The first fields of a generated site's spec (a mapping): schema, id, name, description, a
    redacted simulated location and a seed drawn from ``rng``."""
    return {"schema_version": 1, "id": site_id, "name": name, "description": description,
            "location": {"place": "simulated", "redact": True}, "seed": int(rng.integers(0, 2**31))}


def write_generated(root: Path, specs: Iterable[dict]) -> list[Path]:
    """Write each generated spec (a mapping) to ``ROOT/specs/<id>.yaml`` and simulate it into the catalog
    ``root`` (``data/``, ``sites/``); return the records' paths."""
    root = Path(root)
    (root / "specs").mkdir(parents=True, exist_ok=True)
    records = []
    for spec in specs:
        spec_path = root / "specs" / f"{spec['id']}.yaml"
        spec_path.write_text(yaml.safe_dump(spec, sort_keys=False), encoding="utf-8")
        records.append(write_site(simulate_site(load_spec(spec_path)), root, spec_path=spec_path, record_dir="sites"))
    return records
