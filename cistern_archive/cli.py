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


def running_text(doc: str) -> str:
    """A docstring as help text: each paragraph on one line (the rich help keeps a docstring's line
    breaks, which split sentences in mid-line on the terminal), paragraphs apart as before."""
    return "\n\n".join(" ".join(paragraph.split()) for paragraph in inspect.cleandoc(doc).split("\n\n"))


def _help_as_running_text(typer_app: typer.Typer) -> None:
    """Give every command of ``typer_app`` and of its sub-apps its docstring as running text, and the
    first paragraph as its summary in the command list."""
    for info in typer_app.registered_commands:
        doc = info.help or (info.callback.__doc__ if info.callback else None)
        if doc:
            info.help = running_text(doc)
            info.short_help = info.short_help or info.help.split("\n\n")[0]
    for group in typer_app.registered_groups:
        if group.typer_instance is not None:
            _help_as_running_text(group.typer_instance)


_register_commands()
_help_as_running_text(app)


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
