"""The Girona marina run against DGPS, side by side with the published table (Mallios et al. 2014, Table 2).

Rows (absolute position error at the 1 Hz DGPS fixes, metres, mean / SD / max):

* dead reckoning with the sensors as logged, no calibration: the DVL's bottom velocity rotated by the
  DVL's own compass (``dvl``), and by the raw MTi compass (``mti``);
* dead reckoning calibrated on the first 300 s of DGPS (compass offset and DVL scale,
  :mod:`cistern_archive.navigation.calibration`) — the odometry of the pipeline;
* the pipeline (:mod:`cistern_archive.navigation.pipeline`): motion-compensated revolutions, the
  ``guided-correlative`` matcher around the odometry's guess, the ``nav-graph`` localizer.

Every row is evaluated on the same fixes: those between the first and the last placed revolution (the
sonar starts 173 s before the navigation logs and stops 340 s before them) that lie after the DGPS
window the dead reckoning was calibrated on (its first 300 s: those fixes are not independent of the
estimates), start-aligned (on the fix where the track starts) and after the best rigid alignment, over
all of them and over their first and second halves; the parameters were chosen on the first half. The
same rows at every fix of the span, calibration window included (as the published rows cover the whole
run), follow as ``whole_span``. The sonar-to-navigation clock offset is estimated from the scans and
printed.

Usage::

    .venv/bin/python benchmarks/marina.py [--data DIR] [--keyframes N] [--figures DIR | --no-figures] [--config JSON] [--json]
    .venv/bin/python benchmarks/marina.py --conventions   # the cloud's frame conventions, measured

``--json`` prints, as its last line, ``{"dead_reckoning": {...}, "pipeline": {"start_aligned": {...},
"rigid": {...}}, "revolutions", "seconds", ...}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from cistern_archive.core.errors import CisternError  # noqa: E402
from cistern_archive.navigation.accuracy import evaluate_track, independent_after  # noqa: E402
from cistern_archive.navigation.calibration import fit_start_calibration  # noqa: E402
from cistern_archive.navigation.conventions import Convention, Revolution, consecutive_overlap  # noqa: E402
from cistern_archive.catalog.models import Survey  # noqa: E402
from cistern_archive.navigation.pipeline import SurveyConfig, data_root_default, run_survey  # noqa: E402
from cistern_archive.navigation.site import track_comparison  # noqa: E402
from cistern_archive.report.track import error_figure, tracks_figure  # noqa: E402
from cistern_archive.navigation.survey import load_marina_survey  # noqa: E402
from cistern_archive.sonar.readers.pcd import read_points  # noqa: E402

from cistern_archive.navigation.records import PUBLISHED_TABLE2 as PUBLISHED  # noqa: E402
from cistern_archive.sonar.marina import SONAR_MOUNT_DEG  # noqa: E402


def _rows(survey, run) -> tuple[dict[str, dict], dict[str, dict]]:
    """Every evaluated track: name → evaluation over the sonar span (:func:`evaluate_track`), at the fixes
    after the calibration window, and the same at all of them (as the published rows were evaluated)."""
    fix_time, fixes = survey.dgps_xy()
    start, end = run.span_s
    after = independent_after(fix_time, start, end, run.calibration_end_s)
    tracks = {
        "dead reckoning, DVL compass (as logged)": survey.dead_reckoning(heading="dvl"),
        "dead reckoning, MTi compass (as logged)": run.raw_track,
        "dead reckoning, calibrated (first 300 s)": run.track,
    }
    positions = {name: (lambda t, tr=tr: tr.pose_at(t)[:, :2]) for name, tr in tracks.items()}
    positions["pipeline (nav-graph)"] = run.positions_at
    return tuple({name: evaluate_track(at, fix_time, fixes, start=start, end=end, evaluated_from=evaluated_from)
                  for name, at in positions.items()} for evaluated_from in (after, None))


def _halves(row: dict) -> tuple[float, float]:
    """Start-aligned mean error over the first and the second half of the evaluated fixes."""
    errors = row["start_aligned_errors"][row["evaluated"]]
    half = len(errors) // 2
    return float(errors[:half].mean()), float(errors[half:].mean())


def _table(rows: dict[str, dict]) -> str:
    lines = ["| track | start-aligned mean / SD / max (m) | rigid mean / SD / max (m) | mean 1st half / 2nd half (m) |",
             "|---|---|---|---|"]
    for name, row in rows.items():
        a, r = row["start_aligned"], row["rigid"]
        h1, h2 = _halves(row)
        lines.append(f"| {name} | {a.mean_m:.2f} / {a.sd_m:.2f} / {a.max_m:.2f} | {r.mean_m:.2f} / {r.sd_m:.2f} / "
                     f"{r.max_m:.2f} | {h1:.2f} / {h2:.2f} |")
    for name, (mean, sd, mx) in PUBLISHED.items():
        lines.append(f"| published: {name} | {mean:.2f} / {sd:.2f} / {mx:.2f} | | |")
    return "\n".join(lines)


def along_track_bias(run) -> tuple[int, float, float] | None:
    """Converged consecutive matches: how many, and the median and mean of (match - dead reckoning)
    along the dead-reckoned displacement (negative: the match is short of it); None without any."""
    along = []
    for m in run.matches:
        if m.j != m.i + 1 or not m.converged:
            continue
        a, b = run.scans[m.i].odometry, run.scans[m.j].odometry
        step = b[:2] - a[:2]
        length = float(np.hypot(*step))
        if length > 0.5:
            along.append(float(np.dot([m.dx_m, m.dy_m], step) / length - length))
    return (len(along), float(np.median(along)), float(np.mean(along))) if along else None


def _figures(survey, run, config: SurveyConfig, data: Path, out: Path) -> list[Path]:
    """The report's Track figures (:mod:`cistern_archive.report.track`) of this run: the tracks over DGPS
    and the error over time, as a site page draws them."""
    track = track_comparison(survey, run, Survey(kind="marina", data=str(data)), config)
    out.mkdir(parents=True, exist_ok=True)
    drawn = (tracks_figure(out / "marina_tracks.png", track, dpi=110), error_figure(out / "marina_error.png", track, dpi=110))
    return [out / figure.file for figure in drawn]


CONVENTION_VARIANTS = {
    "measured (mirrored, +j·1.8° from 0°, mount 240°, clock +0.75 s, per-beam times)": {},
    "not mirrored": {"mirrored": False},
    "clockwise beam order": {"clockwise": True},
    "first beam at 90°": {"first_beam_deg": 90.0},
    "one time per revolution (no motion compensation)": {"per_beam_time": False},
    "mount 216°": {"mount_deg": 216.0},
    "mount 264°": {"mount_deg": 264.0},
    "clock 0 s": {"clock_offset_s": 0.0},
    "clock -0.75 s": {"clock_offset_s": -0.75},
}


def conventions_table(survey, frames: range) -> str:
    """Consecutive-overlap score of the measured cloud conventions and of each alternative
    (:mod:`cistern_archive.navigation.conventions`), on key frames ``frames`` and their successors."""
    raw = survey.dead_reckoning()
    fix_time, fixes = survey.dgps_xy()
    calibration = fit_start_calibration(raw, fix_time, fixes)
    track = survey.dead_reckoning(scale=calibration.scale, yaw_offset_rad=calibration.yaw_offset_rad)
    wanted = sorted(set(frames) | {k + 1 for k in frames})
    revolutions = {k: Revolution(read_points(survey.pcd_dir / f"pclKeyFrame{k}.pcd")[0], survey.keyframe_beam_times(k))
                   for k in wanted}
    lines = ["| convention | overlap |", "|---|---|"]
    for name, change in CONVENTION_VARIANTS.items():
        score = consecutive_overlap(revolutions, track, replace(Convention(), **change))
        lines.append(f"| {name} | {score:.3f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=data_root_default(), help="the marina data directory")
    parser.add_argument("--keyframes", type=int, default=None, help="only the first N usable revolutions")
    parser.add_argument("--figures", type=Path, default=ROOT / "benchmarks" / "figures")
    parser.add_argument("--no-figures", action="store_true")
    parser.add_argument("--config", default="{}", help="JSON overrides of SurveyConfig (tuning runs)")
    parser.add_argument("--conventions", action="store_true",
                        help="only measure the cloud's frame conventions against their alternatives")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON on the last line")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"marina data not found at {args.data}", file=sys.stderr)
        return 2
    if args.conventions:
        print(conventions_table(load_marina_survey(args.data), range(20, 121, 4)))
        return 0
    start, cpu_start = time.perf_counter(), time.process_time()
    try:
        survey = load_marina_survey(args.data)
        config = SurveyConfig.model_validate({**json.loads(args.config), "max_keyframes": args.keyframes})
        run = run_survey(survey, config)
    except (CisternError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    rows, whole = _rows(survey, run)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    consecutive = [m for m in run.matches if m.j == m.i + 1]
    loops = [m for m in run.matches if m.j != m.i + 1]
    evaluated = rows["pipeline (nav-graph)"]["evaluated"]
    print(f"errors at the {int(evaluated.sum())} DGPS fixes after the calibration window (the first "
          f"{int((~evaluated).sum())} fixes of the span lie in it):\n")
    print(_table(rows))
    print(f"\nthe same at all {len(evaluated)} fixes of the span (as the published rows were evaluated):\n")
    print(_table(whole))
    print(f"\nrevolutions: {len(run.scans)} placed {int(run.poses.placed.sum())}; matches: consecutive "
          f"{sum(m.converged for m in consecutive)}/{len(consecutive)}, loop candidates "
          f"{sum(m.converged for m in loops)}/{len(loops)} converged")
    bias = along_track_bias(run)
    if bias is not None:
        print(f"consecutive matches against dead reckoning, along track: {bias[0]} matches, median {bias[1]:+.2f} m, "
              f"mean {bias[2]:+.2f} m")
    print(f"calibration (first {run.calibration.window_s:.0f} s of DGPS): {run.calibration.as_dict()}")
    print("clock offset (added to sonar times), consecutive-overlap score: "
          + ", ".join(f"{o:+.2f} s: {s:.3f}" for o, s in run.clock_scores) + f" -> {run.clock_offset_s:+.2f} s")
    if run.mount_scores:
        print(f"sonar mount correction (added to {SONAR_MOUNT_DEG:.0f}°), overlap of revolutions "
              f"{config.mount_gap} apart: " + ", ".join(f"{o:+.0f}°: {s:.3f}" for o, s in run.mount_scores)
              + f" -> {run.mount_offset_deg:+.2f}°")
    print("timings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in run.timings_s.items()) + f", total {seconds:.1f} (CPU {cpu_seconds:.1f})")
    if not args.no_figures:
        for path in _figures(survey, run, config, args.data, args.figures):
            print(f"figure: {path}")
    if args.json:
        dr = rows["dead reckoning, DVL compass (as logged)"]
        pipe = rows["pipeline (nav-graph)"]
        print(json.dumps({
            "dead_reckoning": dr["start_aligned"].as_dict(),
            "pipeline": {"start_aligned": pipe["start_aligned"].as_dict(), "rigid": pipe["rigid"].as_dict()},
            "dead_reckoning_calibrated": rows["dead reckoning, calibrated (first 300 s)"]["start_aligned"].as_dict(),
            "pipeline_halves_mean_m": [round(v, 3) for v in _halves(pipe)],
            "whole_span": {"dead_reckoning": whole["dead reckoning, DVL compass (as logged)"]["start_aligned"].as_dict(),
                           "pipeline": {k: whole["pipeline (nav-graph)"][k].as_dict() for k in ("start_aligned", "rigid")}},
            "clock_offset_s": run.clock_offset_s,
            "mount_offset_deg": round(run.mount_offset_deg, 2),
            "revolutions": len(run.scans),
            "seconds": round(seconds, 1),
            "cpu_seconds": round(cpu_seconds, 1),
        }))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
