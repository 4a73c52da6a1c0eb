"""``cistern-archive verify``: recompute the digest of every archived object."""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_OK, EXIT_SITES_FAILED, EXIT_USAGE


def catalog_option():
    return typer.Option(Path("catalog"), "--catalog",
                        help="Catalog root; the default archive is .archive beside it, as for rebuild.")


def archive_option():
    return typer.Option(None, "--archive",
                        help="Archive folder (default: $CISTERN_ARCHIVE, else .archive beside the catalog).")


def archive_root(archive: Path | None, catalog: Path) -> Path:
    """``--archive``, else the archive ``rebuild --catalog CATALOG`` uses."""
    from cistern_archive.archive import default_archive_dir  # deferred

    return archive if archive is not None else default_archive_dir(catalog)


def existing_archive(archive: Path | None, catalog: Path) -> Path:
    """The archive folder, or exit 2 when there is no archive there (neither an index nor objects)."""
    root = archive_root(archive, catalog)
    if not ((root / "index.sqlite").is_file() or (root / "objects").is_dir()):
        typer.echo(f"error: {root}: no archive here (neither index.sqlite nor objects/)", err=True)
        raise typer.Exit(EXIT_USAGE)
    return root


def register(app: typer.Typer) -> None:
    @app.command("verify")
    def verify(
        catalog: Path = catalog_option(),
        archive: Path | None = archive_option(),
    ) -> None:
        """Check every stored object against its SHA-256; list each mismatch, missing or unindexed object
        (exit 1; `repair` restores them)."""
        from cistern_archive.archive import Archive, verify_archive  # deferred
        from cistern_archive.archive.index import DamagedIndex

        root = existing_archive(archive, catalog)
        try:
            with Archive(root) as store:
                report = verify_archive(store)
        except DamagedIndex as exc:  # a damaged index: a finding of the check, not a crash
            typer.echo(f"FAILED: {exc}", err=True)
            typer.echo(f"the archive index cannot be read; run `cistern-archive repair`; archive: {root}")
            raise typer.Exit(EXIT_SITES_FAILED) from None
        for problem in report.problems:
            typer.echo(f"FAILED: {problem}", err=True)
        hint = "; run `cistern-archive repair`" if report.problems else ""
        typer.echo(f"{report.checked} object(s) checked, {len(report.problems)} problem(s){hint}; archive: {root}")
        raise typer.Exit(EXIT_OK if report.ok else EXIT_SITES_FAILED)
