"""``cistern-archive repair``: restore damaged or missing archive objects from the catalog's originals."""

from __future__ import annotations

from pathlib import Path

import typer

from cistern_archive.commands import EXIT_OK, EXIT_SITES_FAILED
from cistern_archive.commands.verify import archive_option, catalog_option, existing_archive


def register(app: typer.Typer) -> None:
    @app.command("repair")
    def repair(
        catalog: Path = catalog_option(),
        archive: Path | None = archive_option(),
    ) -> None:
        """Restore damaged or missing objects from their originals, index stray objects, replace a damaged
        index (kept as index.sqlite.damaged-TIME); then check every object. Exit 1 when something could not
        be restored."""
        from cistern_archive.archive.repair import repair_archive  # deferred

        root = existing_archive(archive, catalog)
        report = repair_archive(root, catalog if catalog.is_dir() else None)
        for action in report.actions:
            typer.echo(f"repaired: {action}")
        for problem in report.unrepaired:
            typer.echo(f"NOT REPAIRED: {problem}", err=True)
        after = report.after
        typer.echo(f"{len(report.actions)} repair(s); {after.checked} object(s) checked, {len(after.problems)} "
                   f"problem(s) left; archive: {root}")
        raise typer.Exit(EXIT_OK if report.ok else EXIT_SITES_FAILED)
