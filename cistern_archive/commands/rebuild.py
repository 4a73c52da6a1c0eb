"""``cistern-archive rebuild``: rebuild the catalog's reports (incrementally, in parallel, atomically)."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from cistern_archive.commands import EXIT_INTERRUPTED, EXIT_USAGE
from cistern_archive.errors import CisternError


class PlainProgress:
    """One log line per site (when the output is not a terminal, e.g. the nightly job's log)."""

    def __init__(self) -> None:
        self.total = 0
        self.done = 0

    def start(self, total: int, skipped: int, executor: str) -> None:
        self.total, self.done = total, skipped
        typer.echo(f"{total} site(s): {skipped} unchanged, {total - skipped} to build on {executor}")

    def site_done(self, outcome) -> None:
        self.done += 1
        seconds = outcome.timings_s.get("wall", 0.0)
        line = f"[{self.done}/{self.total}] {outcome.id}: {outcome.status} ({seconds:.1f} s)"
        if outcome.reasons:
            line += f": {outcome.reasons[0].splitlines()[0]}"
        typer.echo(line)


class RichProgress:
    """A rich progress bar with one line per finished site (on a terminal)."""

    def __init__(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.console = Console(stderr=True)
        self.bar = Progress(TextColumn("[bold]rebuild"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                            TextColumn("{task.description}"), console=self.console, transient=False)
        self.task = None

    def start(self, total: int, skipped: int, executor: str) -> None:
        self.bar.start()
        self.task = self.bar.add_task(f"{skipped} unchanged, building on {executor}", total=total,
                                      completed=skipped)

    def site_done(self, outcome) -> None:
        from rich.markup import escape

        style = {"ok": "green", "partial": "yellow", "failed": "bold red"}.get(outcome.status, "")
        message = f"[{style}]{outcome.status}[/] {outcome.id} ({outcome.timings_s.get('wall', 0.0):.1f} s)"
        if outcome.reasons:
            message += f": {escape(outcome.reasons[0].splitlines()[0])}"
        self.bar.console.print(message, highlight=False)
        self.bar.advance(self.task)

    def stop(self) -> None:
        self.bar.stop()


def register(app: typer.Typer) -> None:
    @app.command("rebuild")
    def rebuild(
        catalog: Path = typer.Option(Path("catalog"), "--catalog", help="Catalog root folder."),
        out: Path = typer.Option(Path("site"), "--out", help="Output folder of the reports."),
        site: list[str] = typer.Option([], "--site", help="Rebuild only this site id (repeatable)."),
        workers: int = typer.Option(1, "--workers", min=1, help="Local worker processes."),
        force: bool = typer.Option(False, "--force", help="Rebuild sites even when nothing changed."),
        scheduler: str | None = typer.Option(None, "--scheduler", help="Dask scheduler address (tcp://host:port)."),
        scheduler_file: Path | None = typer.Option(None, "--scheduler-file", help="Dask scheduler file."),
        archive: Path | None = typer.Option(
            None, "--archive", help="Archive folder (default: $CISTERN_ARCHIVE, else .archive beside the catalog)."),
    ) -> None:
        """Rebuild every changed site into OUT/<site-id>/, then OUT/index.html and OUT/summary.json.

        Exit codes: 0 every site ok or unchanged; 1 some site partial (a scan unplaced or a dimension
        not measured) or failed; 2 usage or catalog error; 3 internal error; 130 interrupted.
        """
        from cistern_archive.service.rebuild import rebuild as run_rebuild

        progress = RichProgress() if sys.stderr.isatty() else PlainProgress()
        try:
            summary = run_rebuild(catalog, out, sites=list(site) or None, workers=workers, force=force,
                                  scheduler=scheduler, scheduler_file=scheduler_file, archive=archive,
                                  progress=progress)
        except KeyboardInterrupt:
            typer.echo(f"interrupted; see {out / 'summary.json'}", err=True)
            raise typer.Exit(EXIT_INTERRUPTED) from None
        except CisternError as exc:  # a locked output folder, an unknown --site, an unreachable scheduler
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        finally:
            if isinstance(progress, RichProgress):
                progress.stop()
        for problem in summary.catalog_problems:
            typer.echo(problem, err=True)
        for site_outcome in summary.not_ok:
            typer.echo(f"{site_outcome.status.upper()} {site_outcome.id}: {'; '.join(site_outcome.reasons)}", err=True)
        counts = summary.counts()
        typer.echo(f"{counts['ok']} ok, {counts['partial']} partial, {counts['failed']} failed, "
                   f"{counts['skipped']} unchanged "
                   f"in {summary.seconds:.2f} s; log {out / summary.log}")
        typer.echo(str((out / "index.html").resolve()))
        raise typer.Exit(summary.exit_code)
