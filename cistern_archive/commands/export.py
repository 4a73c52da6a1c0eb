"""``cistern-archive export SITE --bag DIR``: one BagIt bag for deposit with a data archive."""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_INTERNAL, EXIT_OK, EXIT_USAGE
from cistern_archive.core.errors import CisternError, EnvironmentProblem


def register(app: typer.Typer) -> None:
    @app.command("export")
    def export(
        site: str = typer.Argument(..., help="Site id."),
        bag: Path = typer.Option(..., "--bag", help="Bag folder to write (replaced if it is a bag of this site)."),
        catalog: Path = typer.Option(Path("catalog"), "--catalog", help="Catalog root folder."),
        out: Path = typer.Option(Path("site"), "--out", help="Rebuild output folder (its published build is packed)."),
        archive: Path | None = typer.Option(
            None, "--archive", help="Archive folder (default: $CISTERN_ARCHIVE, else .archive beside the catalog)."),
    ) -> None:
        """Pack the published build in an RFC 8493 bag: raw inputs, report, preservation formats, resolved
        configuration, provenance. Refused when the published build is not that of the current inputs."""
        from cistern_archive.service.export import export_bag

        try:
            result = export_bag(site, bag, catalog=catalog, out=out, archive=archive)
        except EnvironmentProblem as exc:  # a full or read-only disk, a damaged archive index
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(EXIT_INTERNAL) from None
        except CisternError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        typer.echo(f"{result.site_id}: {result.payload_files} payload file(s); report: {result.report_source}")
        typer.echo(str(result.path))
        raise typer.Exit(EXIT_OK)
