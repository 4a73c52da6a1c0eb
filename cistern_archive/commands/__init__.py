"""One module per CLI command; each defines ``register(app)`` adding its command to the typer app.

A command imports its implementation inside the command function (each such import marked
``# deferred``): the CLI loads every command module to build its help, and ``cistern-archive --help``
should not wait for the numerical, rendering and archive libraries that one command needs.
"""

from cistern_archive.core.exitcodes import (  # noqa: F401  (the commands' exit codes)
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_SITES_FAILED,
    EXIT_USAGE,
)

COMMAND_MODULES = (
    "rebuild",
    "validate",
    "config",
    "plugins",
    "match",
    "inspect",
    "simulate",
    "ingest",
    "verify",
    "repair",
    "export",
    "emulate",
    "acquire",
    "survey",
)
