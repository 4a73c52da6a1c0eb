"""``cistern-archive rebuild``: rebuild the catalog's reports (incrementally, in parallel, atomically)."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import typer

from cistern_archive.commands import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE
from cistern_archive.core.errors import CisternError, EnvironmentProblem


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


def running_stages(folder: Path) -> list[tuple[str, str]]:
    """``(site, stage)`` of every site a worker is building now, from the stage markers in ``folder``
    (``OUT/.progress``, see :class:`cistern_archive.service.worker.StageMarker`), sorted by site."""
    try:
        entries = sorted(p for p in folder.iterdir() if not p.name.startswith("."))
    except OSError:
        return []
    running = []
    for path in entries:
        try:
            running.append((path.name, path.read_text(encoding="utf-8").strip()))
        except OSError:  # finished between the listing and the read
            continue
    return running


def running_text(running: list[tuple[str, str]]) -> str:
    """``building lair-pool (match), bell-cistern (report)``, or empty when nothing runs."""
    return "building " + ", ".join(f"{site} ({stage})" for site, stage in running) if running else ""


class RichProgress:
    """A rich progress bar with one line per finished site and, under the bar, which site is in which
    stage now (on a terminal)."""

    def __init__(self, out: Path) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from cistern_archive.service.worker import PROGRESS_DIR

        self.console = Console(stderr=True)
        self.bar = Progress(TextColumn("[bold]rebuild"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                            TextColumn("{task.description}"), console=self.console, transient=False)
        self.task = None
        self.base = ""
        self.folder = out / PROGRESS_DIR
        self.stop_polling = threading.Event()
        self.poller = threading.Thread(target=self._poll, name="rebuild-progress", daemon=True)

    def start(self, total: int, skipped: int, executor: str) -> None:
        self.bar.start()
        self.base = f"{skipped} unchanged, on {executor}"
        self.task = self.bar.add_task(self.base, total=total, completed=skipped)
        self.poller.start()

    def _refresh(self) -> None:
        from rich.markup import escape

        running = running_text(running_stages(self.folder))
        self.bar.update(self.task, description=escape(f"{self.base}; {running}" if running else self.base))

    def _poll(self) -> None:
        while not self.stop_polling.wait(0.5):
            self._refresh()

    def site_done(self, outcome) -> None:
        from rich.markup import escape

        style = {"ok": "green", "partial": "yellow", "failed": "bold red"}.get(outcome.status, "")
        message = f"[{style}]{outcome.status}[/] {outcome.id} ({outcome.timings_s.get('wall', 0.0):.1f} s)"
        if outcome.reasons:
            message += f": {escape(outcome.reasons[0].splitlines()[0])}"
        self.bar.console.print(message, highlight=False)
        self.bar.advance(self.task)
        self._refresh()

    def stop(self) -> None:
        self.stop_polling.set()
        if self.poller.is_alive():
            self.poller.join(timeout=2.0)
        if self.task is not None:
            self.bar.update(self.task, description=self.base)
        self.bar.stop()


def print_dry_run(catalog: Path, out: Path, *, sites: list[str] | None, force: bool) -> int:
    """Print one line per site (skip, new or rebuild, and why) and the catalog's problems; the exit code
    (0, or 2 for catalog problems)."""
    from cistern_archive.service.dryrun import dry_run  # the service loads when a command runs, not at CLI start

    try:
        plan = dry_run(catalog, out, sites=sites, force=force)
    except CisternError as exc:
        typer.echo(f"error: {exc}", err=True)
        return EXIT_USAGE
    for problem in plan.catalog_problems:
        typer.echo(problem, err=True)
    for decision in plan.decisions:
        typer.echo(decision.line())
    counts = plan.counts()
    typer.echo(f"dry run: {counts['rebuild']} to rebuild, {counts['new']} new, {counts['skip']} unchanged; "
               "nothing written")
    return EXIT_USAGE if plan.catalog_problems else EXIT_OK


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
        dry_run: bool = typer.Option(False, "--dry-run", help="List what would be rebuilt and why; write nothing."),
    ) -> None:
        """Rebuild every changed site into OUT/<site-id>/, then OUT/index.html and OUT/summary.json.

        Exit codes: 0 every site ok or unchanged; 1 some site partial (a scan unplaced, two parts of the
        map joined imprecisely, or a dimension not measured) or failed; 2 usage or catalog error; 3 internal
        error; 130 interrupted.
        """
        from cistern_archive.service.rebuild import rebuild as run_rebuild

        if dry_run:
            raise typer.Exit(print_dry_run(catalog, out, sites=list(site) or None, force=force))
        progress = RichProgress(out) if sys.stderr.isatty() else PlainProgress()
        try:
            summary = run_rebuild(catalog, out, sites=list(site) or None, workers=workers, force=force,
                                  scheduler=scheduler, scheduler_file=scheduler_file, archive=archive,
                                  progress=progress)
        except KeyboardInterrupt:
            typer.echo(f"interrupted; see {out / 'summary.json'}", err=True)
            raise typer.Exit(EXIT_INTERRUPTED) from None
        except EnvironmentProblem as exc:  # a full or read-only disk, a damaged archive index
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(EXIT_INTERNAL) from None
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
