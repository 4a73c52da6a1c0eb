"""``cistern-archive ingest``: add raw files to the content-addressed archive."""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_OK, EXIT_USAGE


def register(app: typer.Typer) -> None:
    @app.command("ingest")
    def ingest(
        files: list[Path] = typer.Argument(..., help="Raw files to archive (never modified)."),
        site: str | None = typer.Option(None, "--site", help="Site id the files belong to."),
        archive: Path | None = typer.Option(None, "--archive",
                                            help="Archive folder (default: $CISTERN_ARCHIVE, else ./.archive)."),
    ) -> None:
        """Store a read-only copy of each file under its SHA-256 and record the ingest."""
        from cistern_archive.archive import Archive, default_archive_dir

        missing = [f for f in files if not f.is_file()]
        for path in missing:
            typer.echo(f"error: {path}: not a file", err=True)
        if missing:
            raise typer.Exit(EXIT_USAGE)
        root = archive or default_archive_dir()
        with Archive(root) as store:
            for path in files:
                item = store.ingest(path, site_id=site, role="input")
                state = "stored" if item.stored else "already archived"
                typer.echo(f"{item.sha256}  {path}  ({item.size} bytes, {state})")
        typer.echo(f"archive: {root}")
        raise typer.Exit(EXIT_OK)
