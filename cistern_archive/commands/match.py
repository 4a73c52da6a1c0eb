"""``cistern-archive match A B``: run one pair-wise match and print the result."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from cistern_archive.commands import EXIT_OK
from cistern_archive.pipeline.results import finite_or_none


def match_files(reference: Path, moving: Path, *, matcher: str | None, params: dict, seed: int,
                segmentation: str, min_range_m: float) -> dict:
    """Read two scan files, segment them, match ``moving`` against ``reference``; a JSON-able dict.

    ``matcher`` ``None`` is the installed default matcher.
    """
    from cistern_archive.catalog.models import Segmentation
    from cistern_archive.pipeline.registry import default_registry
    from cistern_archive.pipeline.runner import match_pair, resolve_stage, segment_scan
    from cistern_archive.sonar.readers import read_scans

    registry = default_registry()
    matcher = matcher or registry.default("matcher")
    stage = resolve_stage(registry, "matcher", matcher, params)
    settings = Segmentation(method=segmentation, min_range_m=min_range_m)
    scan_a, scan_b = (segment_scan(read_scans(path)[0], settings) for path in (reference, moving))
    result = match_pair(stage, [scan_a, scan_b], seed, 0, 1)
    return {
        "matcher": matcher,
        "reference": str(reference),
        "moving": str(moving),
        "dx_m": finite_or_none(result.dx_m),
        "dy_m": finite_or_none(result.dy_m),
        "dyaw_rad": finite_or_none(result.dyaw_rad),
        "weight": finite_or_none(result.weight),
        "confidence": finite_or_none(result.confidence),
        "converged": bool(result.converged),
        "iterations": int(result.iterations),
        "seconds": round(result.seconds, 6),
        "reason": result.reason,
    }


def _describe(out: dict) -> str:
    """One line for a terminal: the estimate (or that there is none), the verdict and the effort."""
    state = "converged" if out["converged"] else f"not converged ({out['reason']})"
    if out["dx_m"] is None:
        where = "no estimate"
    else:
        where = (f"dx={out['dx_m']:+.3f} m dy={out['dy_m']:+.3f} m "
                 f"dyaw={np.degrees(out['dyaw_rad'] or 0.0):+.2f} deg weight={out['weight']}")
    return f"{where} {state} after {out['iterations']} iterations, {out['seconds']:.3f} s"


def register(app: typer.Typer) -> None:
    @app.command("match")
    def match(
        reference: Path = typer.Argument(..., exists=True, dir_okay=False, help="Reference scan file (i)."),
        moving: Path = typer.Argument(..., exists=True, dir_okay=False, help="Scan to locate (j)."),
        matcher: str = typer.Option("", "--matcher", show_default=False,
                                    help="Matcher plugin name (default: the installed default matcher)."),
        params: str = typer.Option("{}", "--params", help="Matcher parameters as a JSON object."),
        seed: int = typer.Option(0, "--seed", help="Random seed."),
        segmentation: str = typer.Option("paper", "--segmentation", help="Beam segmentation: paper, cfar or shadow."),
        min_range: float = typer.Option(0.4, "--min-range", min=0.0,
                                        help="Blank echoes nearer than this (m): the head's ring-down and the vehicle."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON object."),
    ) -> None:
        """Locate MOVING in the frame of REFERENCE: p_moving - p_reference."""
        try:
            parsed = json.loads(params)
        except json.JSONDecodeError as exc:
            raise typer.BadParameter(f"--params is not JSON: {exc}") from None
        if not isinstance(parsed, dict):
            raise typer.BadParameter("--params must be a JSON object")
        out = match_files(reference, moving, matcher=matcher or None, params=parsed, seed=seed, segmentation=segmentation,
                          min_range_m=min_range)
        if as_json:
            typer.echo(json.dumps(out, allow_nan=False))
        else:
            typer.echo(_describe(out))
        raise typer.Exit(EXIT_OK)
