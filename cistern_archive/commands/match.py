"""``cistern-archive match A B``: run one pair-wise match and print the result."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import typer

from cistern_archive.commands import EXIT_OK


def match_files(reference: Path, moving: Path, *, matcher: str, params: dict, seed: int,
                segmentation: str, min_range_m: float) -> dict:
    """Read two scan files, segment them, match ``moving`` against ``reference``; a JSON-able dict."""
    from cistern_archive.catalog.models import Segmentation
    from cistern_archive.pipeline.registry import default_registry
    from cistern_archive.pipeline.runner import pair_rng
    from cistern_archive.sonar.readers import read_scans
    from cistern_archive.sonar.segmentation import segment

    registry = default_registry()
    plugin = registry.load("matcher", matcher)
    checked = registry.check_params("matcher", matcher, params)
    settings = Segmentation(method=segmentation, min_range_m=min_range_m)
    scan_a, scan_b = (segment(read_scans(path)[0], settings) for path in (reference, moving))
    start = time.perf_counter()
    result = plugin.instance.match(scan_a, scan_b, checked, rng=pair_rng(seed, 0, 1))
    seconds = time.perf_counter() - start
    return {
        "matcher": matcher,
        "reference": str(reference),
        "moving": str(moving),
        "dx_m": float(result.dx_m),
        "dy_m": float(result.dy_m),
        "dyaw_rad": float(result.dyaw_rad),
        "weight": float(result.weight) if np.isfinite(result.weight) else None,
        "converged": bool(result.converged),
        "iterations": int(result.iterations),
        "seconds": round(seconds, 6),
        "reason": result.reason,
    }


def register(app: typer.Typer) -> None:
    @app.command("match")
    def match(
        reference: Path = typer.Argument(..., exists=True, dir_okay=False, help="Reference scan file (i)."),
        moving: Path = typer.Argument(..., exists=True, dir_okay=False, help="Scan to locate (j)."),
        matcher: str = typer.Option("pf-pairwise", "--matcher", help="Matcher plugin name."),
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
        out = match_files(reference, moving, matcher=matcher, params=parsed, seed=seed, segmentation=segmentation,
                          min_range_m=min_range)
        if as_json:
            typer.echo(json.dumps(out))
        else:
            state = "converged" if out["converged"] else f"not converged ({out['reason']})"
            typer.echo(f"dx={out['dx_m']:+.3f} m dy={out['dy_m']:+.3f} m dyaw={np.degrees(out['dyaw_rad']):+.2f} deg "
                       f"weight={out['weight']} {state} after {out['iterations']} iterations, {out['seconds']:.3f} s")
        raise typer.Exit(EXIT_OK)
