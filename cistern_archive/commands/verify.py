"""``cistern-archive verify``: recompute the digest of every archived object."""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_OK, EXIT_SITES_FAILED, EXIT_USAGE


def register(app: typer.Typer) -> None:
    @app.command("verify")
    def verify(
        archive: Path | None = typer.Option(None, "--archive",
                                            help="Archive folder (default: $CISTERN_ARCHIVE, else ./.archive)."),
    ) -> None:
        """Check every stored object against its SHA-256; list each mismatch or missing object (exit 1)."""
        from cistern_archive.archive import Archive, default_archive_dir, verify_archive

        root = archive or default_archive_dir()
        if not (root / "index.sqlite").is_file():
            typer.echo(f"error: {root}: no archive here (index.sqlite missing)", err=True)
            raise typer.Exit(EXIT_USAGE)
        with Archive(root) as store:
            report = verify_archive(store)
        for problem in report.problems:
            typer.echo(f"{'warning' if problem.kind == 'unindexed' else 'FAILED'}: {problem}", err=True)
        failures = [p for p in report.problems if p.kind != "unindexed"]
        typer.echo(f"{report.checked} object(s) checked, {len(failures)} problem(s); archive: {root}")
        raise typer.Exit(EXIT_OK if report.ok else EXIT_SITES_FAILED)
