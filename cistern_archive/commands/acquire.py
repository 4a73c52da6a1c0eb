"""``cistern-archive acquire``: record one stationary 360° scan from a Tritech Micron into the catalog.

Writes, in this order: the raw byte stream (``data/<site>/<station>.seanet``, fsynced as it arrives), the
decoded scan (``data/<site>/<station>.npz``), the site record (atomic, validated), the archive. Exit codes:
0 complete scan; 1 partial scan kept (or nothing received); 2 usage/catalog error; 130 interrupted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from cistern_archive.commands import EXIT_INTERRUPTED, EXIT_OK, EXIT_SITES_FAILED, EXIT_USAGE


def register(app: typer.Typer) -> None:
    @app.command("acquire")
    def acquire(
        catalog: Path = typer.Option(Path("catalog"), "--catalog", help="Catalog root."),
        port: str = typer.Option(..., "--port", help="Serial device, or socket://HOST:PORT, of the sonar head."),
        site: str = typer.Option(..., "--site", help="Id of the site record to extend."),
        station: str = typer.Option(..., "--station", help="Label of the new station."),
        depth: float = typer.Option(..., "--depth", help="Depth of the sonar head, metres (positive down)."),
        heading: float = typer.Option(..., "--heading", help="Compass heading, degrees clockwise from north."),
        range_m: Optional[float] = typer.Option(None, "--range",
                                                help="Range, metres (default: the record's sonar.range_m)."),
        bins: Optional[int] = typer.Option(None, "--bins", help="Bins per beam (default: the record's sonar.bins)."),
        step: Optional[int] = typer.Option(None, "--step", help="Motor step, 1/16 gradian: 4, 8, ..., 128."),
        gain: Optional[float] = typer.Option(None, "--gain", help="Gain, fraction 0..1."),
        accept_gaps: int = typer.Option(0, "--accept-gaps", min=0, help="Stop after one revolution if at most "
                                        "this many beams are missing (default: fill every gap)."),
        four_bit: bool = typer.Option(False, "--4bit", help="Ask for 4-bit bins (half the bytes)."),
        archive_dir: Optional[Path] = typer.Option(None, "--archive",
                                                   help="Archive folder (default: beside the catalog)."),
        no_archive: bool = typer.Option(False, "--no-archive", help="Do not add the files to the archive."),
        reply_timeout: float = typer.Option(1.0, "--reply-timeout", min=0.05, help="Seconds before a re-request."),
        alive_timeout: float = typer.Option(30.0, "--alive-timeout", min=0.1, help="Seconds to wait for the head."),
    ) -> None:
        """Record one stationary 360-degree scan: raw stream, interchange scan, site record, archive."""
        from pydantic import ValidationError
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from cistern_archive.core.errors import CatalogError  # deferred
        from cistern_archive.acquisition.session import acquire_scan, find_site, settings_for_record
        from cistern_archive.acquisition.driver import DriverConfig
        from cistern_archive.archive import catalog_store
        from cistern_archive.tritech.settings import HeadSettings

        console = Console(stderr=True)
        try:
            loaded = find_site(catalog, site)
            base = settings_for_record(loaded.record)
            changes = {k: v for k, v in (("range_m", range_m), ("n_bins", bins), ("step", step),
                                         ("gain", gain)) if v is not None}
            if four_bit:
                changes["bits"] = 4
            settings = HeadSettings.model_validate({**base.model_dump(), **changes})
        except CatalogError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        except ValidationError as exc:
            typer.echo(f"error: settings: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        config = DriverConfig(reply_timeout_s=reply_timeout, alive_timeout_s=alive_timeout)
        total = settings.beams_per_revolution()
        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[status]}"), TimeElapsedColumn(), console=console,
                      transient=False) as progress:
            task = progress.add_task(f"{site}/{station}", total=total, status="starting")

            def on_line(assembler) -> None:
                progress.update(task, completed=len(assembler.lines),
                                status=f"{assembler.received} lines, bearing {assembler.first.bearing}"
                                if assembler.first is not None else "")

            def log(message: str) -> None:
                progress.update(task, status=message)

            try:
                result = acquire_scan(catalog, port, site, station, depth_m=depth, heading_deg=heading,
                                      settings=settings, config=config,
                                      store=None if no_archive else catalog_store(catalog, archive_dir),
                                      accept_missing=accept_gaps, on_line=on_line,
                                      log=log)
            except CatalogError as exc:
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(EXIT_USAGE) from None
        if result.raw_path is not None:
            console.print(f"raw stream: {result.raw_path}")
        if result.scan_path is not None:
            console.print(f"scan: {result.scan_path} (station {result.station}, "
                          f"{result.capture.scan.n_beams} beams x {result.capture.scan.n_bins} bins)")
        if result.record_path is not None:
            console.print(f"record: {result.record_path}")
        if result.archived:
            console.print(f"archived: {', '.join(result.archived)}")
        for note in result.notes:
            console.print(f"note: {note}")
        if result.capture.error == "interrupted":
            raise typer.Exit(EXIT_INTERRUPTED)
        raise typer.Exit(EXIT_OK if result.capture.complete else EXIT_SITES_FAILED)
