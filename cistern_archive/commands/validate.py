"""``cistern-archive validate``: check every record, referenced file and plugin of a catalog."""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_OK, EXIT_USAGE


def register(app: typer.Typer) -> None:
    @app.command("validate")
    def validate(
        catalog: Path = typer.Option(Path("catalog"), "--catalog", help="Catalog root folder."),
    ) -> None:
        """Validate the catalog; print "file:line: field: message" for every problem (exit 2 if any)."""
        from cistern_archive.pipeline.validate import validate_catalog  # deferred

        report = validate_catalog(catalog)
        for problem in report.problems:
            typer.echo(problem, err=True)
        typer.echo(f"{len(report.records)} site record(s) valid, {len(report.problems)} problem(s)")
        raise typer.Exit(EXIT_OK if report.ok else EXIT_USAGE)
