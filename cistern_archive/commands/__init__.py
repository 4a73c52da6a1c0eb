"""One module per CLI command; each defines ``register(app)`` adding its command to the typer app."""

EXIT_OK = 0
EXIT_SITES_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130

COMMAND_MODULES = (
    "rebuild",
    "validate",
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
