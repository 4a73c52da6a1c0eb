"""``cistern-archive ingest``: add raw files to the content-addressed archive."""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_OK, EXIT_USAGE
from cistern_archive.commands.verify import archive_option, archive_root, catalog_option


def _state(item) -> str:
    if item.repaired:
        return f"repaired the archived copy, which was {item.repaired}"
    return "stored" if item.stored else "already archived"


def register(app: typer.Typer) -> None:
    @app.command("ingest")
    def ingest(
        files: list[Path] = typer.Argument(..., help="Raw files to archive (never modified)."),
        site: str | None = typer.Option(None, "--site", help="Site id the files belong to."),
        catalog: Path = catalog_option(),
        archive: Path | None = archive_option(),
    ) -> None:
        """Store a read-only copy of each file under its SHA-256 and record the ingest; a damaged archived
        copy with the same digest is restored."""
        from cistern_archive.archive import Archive  # deferred

        missing = [f for f in files if not f.is_file()]
        for path in missing:
            typer.echo(f"error: {path}: not a file", err=True)
        if missing:
            raise typer.Exit(EXIT_USAGE)
        root = archive_root(archive, catalog)
        with Archive(root) as store:
            for path in files:
                item = store.ingest(path, site_id=site, role="input")
                typer.echo(f"{item.sha256}  {path}  ({item.size} bytes, {_state(item)})")
        typer.echo(f"archive: {root}")
        raise typer.Exit(EXIT_OK)
