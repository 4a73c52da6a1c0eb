"""The ``cistern-archive`` command-line app (typer).

Exit codes: 0 all sites built; 1 some sites failed (the others still built); 2 usage or catalog error;
3 internal error; 130 interrupted.
"""

from __future__ import annotations

import importlib
import inspect
import sys

import typer

from cistern_archive import __version__
from cistern_archive.commands import COMMAND_MODULES, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_USAGE
from cistern_archive.core.errors import CisternError, EnvironmentProblem, describe_os_error

app = typer.Typer(
    name="cistern-archive",
    help="Maps, 3D models and reports from stationary sonar scans of flooded archaeological sites.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(__version__)
        raise typer.Exit(0)


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", help="Print the version and exit.", is_eager=True,
                                 callback=_print_version),
) -> None:
    """Maps, 3D models and reports from stationary sonar scans of flooded archaeological sites."""


def _register_commands() -> None:
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"cistern_archive.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"cistern_archive.commands.{name}":
                continue
            raise
        module.register(app)


def _one_line_summaries() -> None:
    """Give every command the first paragraph of its docstring, on one line, as the summary in the
    command list: the rich help keeps a docstring's line breaks there, which splits a sentence across
    rows of the table."""
    for info in app.registered_commands:
        doc = info.help or (info.callback.__doc__ if info.callback else None)
        if info.short_help is None and doc:
            info.short_help = " ".join(inspect.cleandoc(doc).split("\n\n")[0].split())


_register_commands()
_one_line_summaries()


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script; maps exceptions to the documented exit codes."""
    try:
        code = app(args=argv, standalone_mode=False)
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        sys.exit(EXIT_INTERRUPTED)
    except SystemExit:
        raise
    except EnvironmentProblem as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_INTERNAL)
    except CisternError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_USAGE)
    except OSError as exc:  # a full or read-only disk, a vanished folder: the environment, not a bug
        typer.echo(f"error: {describe_os_error(exc)}", err=True)
        sys.exit(EXIT_INTERNAL)
    except Exception as exc:  # usage errors of the command-line parser, and anything unexpected
        names = {cls.__name__ for cls in type(exc).__mro__}
        if "Exit" in names:
            sys.exit(getattr(exc, "exit_code", 0))
        if "Abort" in names:
            typer.echo("interrupted", err=True)
            sys.exit(EXIT_INTERRUPTED)
        if "ClickException" in names:
            exc.show()
            sys.exit(EXIT_USAGE)
        import traceback

        traceback.print_exc()
        typer.echo(f"internal error: {type(exc).__name__}: {exc}", err=True)
        sys.exit(EXIT_INTERNAL)
    sys.exit(code if isinstance(code, int) else 0)
