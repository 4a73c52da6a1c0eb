"""``cistern-archive simulate SPEC.yaml --out DIR``: simulate a site with known truth.

Writes the scans, ``truth.json`` and a ready site record under ``DIR`` (a catalog root); see
:mod:`cistern_archive.simulation.output` for the layout.
"""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_OK, EXIT_USAGE


def register(app: typer.Typer) -> None:
    @app.command("simulate")
    def simulate(
        specs: list[Path] = typer.Argument(..., help="Simulator spec(s) (YAML)."),
        out: Path = typer.Option(..., "--out", help="Catalog root to write into."),
        record_dir: str = typer.Option("", "--record-dir", help="Folder for the record under --out, e.g. sites."),
        ideal: bool = typer.Option(False, "--ideal", help="Switch every imperfection off (noise-free)."),
    ) -> None:
        """Simulate stationary scans of each spec's site; write scans, truth.json and a site record."""
        from cistern_archive.core.errors import CatalogError  # deferred
        from cistern_archive.simulation.output import write_site
        from cistern_archive.simulation.simulator import simulate_site
        from cistern_archive.simulation.spec import EffectsSpec, load_spec

        if record_dir and (Path(record_dir).is_absolute() or ".." in Path(record_dir).parts):
            typer.echo(f"error: --record-dir {record_dir!r} must be a folder inside --out", err=True)
            raise typer.Exit(EXIT_USAGE)
        for spec_path in specs:
            try:
                spec = load_spec(spec_path)
                site = simulate_site(spec, effects=EffectsSpec.ideal() if ideal else None)
            except CatalogError as exc:
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(EXIT_USAGE) from None
            except ValueError as exc:
                typer.echo(f"error: {spec_path}: {exc}", err=True)
                raise typer.Exit(EXIT_USAGE) from None
            record = write_site(site, out, spec_path=spec_path, record_dir=record_dir)
            typer.echo(f"{spec.id}: {len(site.scans)} scan(s) -> {record}")
        raise typer.Exit(EXIT_OK)
