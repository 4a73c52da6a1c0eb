"""``cistern-archive inspect FILE``: read a recording and summarise its scans.

``--json`` prints ``{"format": ..., "file": ..., "scans": [{"beams", "bins", "bin_size_m",
"bearing_min_deg", "bearing_max_deg", ...}], "warnings": [...]}``. An unreadable file exits with
``EXIT_USAGE`` (2) and a message naming the file and the byte offset or record.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import typer

from cistern_archive.commands import EXIT_USAGE
from cistern_archive.core.errors import ReaderError
from cistern_archive.pipeline.results import finite_or_none
from cistern_archive.core.scan import Scan


def scan_summary(scan: Scan) -> dict:
    """The per-scan numbers ``inspect`` reports (JSON-serialisable; unknown values are null)."""
    degrees = np.degrees(scan.bearings_rad)
    return {
        "beams": scan.n_beams,
        "bins": scan.n_bins,
        "bin_size_m": finite_or_none(scan.bin_size_m),
        "start_range_m": finite_or_none(scan.start_range_m),
        "max_range_m": finite_or_none(scan.max_range_m),
        "bearing_min_deg": finite_or_none(degrees.min()) if degrees.size else None,
        "bearing_max_deg": finite_or_none(degrees.max()) if degrees.size else None,
        "full_scale": finite_or_none(scan.full_scale),
        "timestamp": finite_or_none(scan.timestamp),
        "yaw_deg": finite_or_none(math.degrees(scan.yaw_rad)),
        "depth_m": finite_or_none(scan.depth_m),
        "sonar_model": scan.sonar_model,
    }


def inspect_file(path: Path, fmt: str | None = None) -> dict:
    """Read ``path`` and return the ``inspect --json`` document; raises ReaderError when unreadable."""
    from cistern_archive.sonar.readers import read_file  # deferred

    result = read_file(path, fmt)
    return {"format": result.format, "file": str(path), "scans": [scan_summary(s) for s in result.scans],
            "warnings": list(result.warnings)}


def _text(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _print_table(doc: dict) -> None:
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    console = Console()
    table = Table(title=f"{doc['file']} ({doc['format']}, {len(doc['scans'])} scans)")
    for column in ("#", "beams", "bins", "bin size m", "max range m", "bearings deg", "full scale", "time"):
        table.add_column(column, justify="right")
    for i, s in enumerate(doc["scans"]):
        table.add_row(str(i), str(s["beams"]), str(s["bins"]), _text(s["bin_size_m"], ".5f"),
                      _text(s["max_range_m"], ".2f"),
                      f"{_text(s['bearing_min_deg'], '.1f')} .. {_text(s['bearing_max_deg'], '.1f')}",
                      _text(s["full_scale"], "g"), _text(s["timestamp"], ".3f"))
    console.print(table)
    for warning in doc["warnings"]:
        console.print(f"[yellow]warning:[/] {escape(warning)}", soft_wrap=True, highlight=False)


def register(app: typer.Typer) -> None:
    @app.command("inspect")
    def inspect(
        file: Path = typer.Argument(..., help="A sonar recording (V4LOG, raw SeaNet, UdpHubLog csv, Ping360 "
                                                "log, marina .pcd, interchange .npz)."),
        fmt: str = typer.Option(None, "--format", help="Reader to use (default: detected from the file)."),
        as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
    ) -> None:
        """Read a recording and list its scans: beams, bins, bin size and bearing span."""
        try:
            doc = inspect_file(file, fmt)
        except ReaderError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        if as_json:
            typer.echo(json.dumps(doc, indent=2, allow_nan=False))
        else:
            _print_table(doc)
