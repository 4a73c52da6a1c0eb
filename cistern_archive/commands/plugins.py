"""``cistern-archive plugins``: list installed stage plugins with provenance and load errors."""

from __future__ import annotations

import json

import typer

from cistern_archive.commands import EXIT_OK


def plugin_listing() -> list[dict]:
    """Every installed plugin, loaded to check it: stage, name, entry point, distribution, version, the
    optional capabilities it implements (``GuidedMatcher``, ``GuidedLocalizer``), status and error."""
    from cistern_archive.pipeline.registry import default_registry  # deferred

    registry = default_registry()
    registry.load_all()
    rows = []
    for info in registry.all_info():
        error = registry.errors.get((info.stage, info.name))
        capabilities = [] if error else sorted(c.__name__ for c in registry.load(info.stage, info.name).capabilities)
        rows.append({
            "stage": info.stage,
            "name": info.name,
            "entry_point": info.value,
            "distribution": info.distribution,
            "version": info.version,
            "capabilities": capabilities,
            "status": "error" if error else "ok",
            "error": error,
        })
    return rows


def register(app: typer.Typer) -> None:
    @app.command("plugins")
    def plugins(as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table.")) -> None:
        """List the installed matchers, localizers, mappers and comparators, and any that fail to load."""
        rows = plugin_listing()
        if as_json:
            typer.echo(json.dumps({"plugins": rows}, indent=2))
            raise typer.Exit(EXIT_OK)
        from rich.console import Console
        from rich.table import Table

        table = Table(title="Installed plugins")
        for column in ("stage", "name", "distribution", "version", "capabilities", "status"):
            table.add_column(column)
        for row in rows:
            status = "[green]ok[/]" if row["status"] == "ok" else "[red]error[/]"
            table.add_row(row["stage"], row["name"], row["distribution"], row["version"],
                          ", ".join(row["capabilities"]), status)
        console = Console()
        console.print(table)
        for row in rows:
            if row["error"]:
                console.print(f"[red]{row['stage']} {row['name']}[/]: {row['error']}", soft_wrap=True)
