"""One module per CLI command; each defines ``register(app)`` adding its command to the typer app."""

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
)
