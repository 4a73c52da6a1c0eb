"""``cistern-archive survey marina DATA --catalog CAT``: a moving-vehicle dataset as a catalog site.

Writes ``CAT/sites/girona-marina.yaml`` (:func:`cistern_archive.navigation.records.write_marina_record`);
the data stays in ``DATA``. Then ``cistern-archive rebuild --catalog CAT --out OUT --site girona-marina``.
"""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_OK, EXIT_USAGE


def register(app: typer.Typer) -> None:
    survey_app = typer.Typer(help="Turn a moving-vehicle survey's dataset into a catalog site.", no_args_is_help=True)
    app.add_typer(survey_app, name="survey")

    @survey_app.command("marina")
    def marina(
        data: Path = typer.Argument(..., help="The Girona marina dataset folder (its logs and derived_tim_pcd/)."),
        catalog: Path = typer.Option(Path("catalog"), "--catalog", help="Catalog root to write the record into."),
        keyframes: int | None = typer.Option(None, "--keyframes", min=2,
                                             help="Process only the first N usable revolutions (a quick build)."),
        site_id: str = typer.Option("girona-marina", "--id", help="Site id (and record file name)."),
        force: bool = typer.Option(False, "--force", help="Replace an existing record of this id."),
    ) -> None:
        """Write CATALOG/sites/<id>.yaml for the Girona marina survey at DATA (the data is not copied)."""
        from cistern_archive.core.errors import CatalogError, ReaderError  # deferred
        from cistern_archive.navigation.records import write_marina_record

        try:
            path = write_marina_record(data, catalog, keyframes=keyframes, site_id=site_id, overwrite=force)
        except (CatalogError, ReaderError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        except ValueError as exc:
            typer.echo(f"error: --id {site_id!r}: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        typer.echo(f"{site_id}: survey record -> {path}")
        typer.echo(f"build it with: cistern-archive rebuild --catalog {catalog} --out OUT --site {site_id}")
        raise typer.Exit(EXIT_OK)
