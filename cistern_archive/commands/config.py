"""``cistern-archive config SITE``: print a site's resolved record, every default filled in.

The output is the record as the pipeline runs it and as ``record.json`` stores it
(:meth:`~cistern_archive.pipeline.registry.Registry.resolve`): every stage named, each with its
plugin's validated parameters, defaults included.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from cistern_archive.commands import EXIT_OK, EXIT_USAGE
from cistern_archive.core.errors import CatalogError, PluginError


def resolved_record(catalog: Path, site_id: str) -> dict[str, Any]:
    """The resolved record of ``site_id`` as JSON-able data.

    Raises
    ------
    CatalogError
        The catalog has no valid record of this id (the problems say why).
    PluginError
        A stage's plugin cannot be loaded or its parameters are refused.
    """
    # Imported when the command runs: the CLI starts (and prints --help) without the pipeline.
    from cistern_archive.pipeline.registry import default_registry
    from cistern_archive.pipeline.validate import find_site

    registry = default_registry()
    loaded = find_site(catalog, site_id, registry)
    return registry.resolve(loaded.record).model_dump(mode="json")


def as_yaml(data: dict[str, Any]) -> str:
    """``data`` as block YAML in the record's own key order (what a record file looks like)."""
    import yaml  # only this command writes YAML

    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, default_flow_style=False)


def register(app: typer.Typer) -> None:
    @app.command("config")
    def config(
        site: str = typer.Argument(..., help="Site id."),
        catalog: Path = typer.Option(Path("catalog"), "--catalog", help="Catalog root folder."),
        as_json: bool = typer.Option(False, "--json", help="Print JSON (the form of record.json) instead of YAML."),
    ) -> None:
        """Print SITE's record as the pipeline runs it: every stage named, every parameter with its default.

        Exit codes: 0 printed; 2 unknown site, invalid record or a plugin that cannot be loaded.
        """
        try:
            data = resolved_record(catalog, site)
        except CatalogError as exc:
            for problem in exc.problems:
                typer.echo(problem, err=True)
            raise typer.Exit(EXIT_USAGE) from None
        except PluginError as exc:
            typer.echo(f"error: site {site}: {exc}", err=True)
            raise typer.Exit(EXIT_USAGE) from None
        typer.echo(json.dumps(data, indent=2, allow_nan=False) if as_json else as_yaml(data).rstrip("\n"))
        raise typer.Exit(EXIT_OK)
