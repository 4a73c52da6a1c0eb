"""Whole-catalog validation: schema, referenced files, plugin names and their parameters.

Every problem reads ``file:line: field: message``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from cistern_archive.catalog.loader import LoadedRecord, format_loc, load_record, record_paths
from cistern_archive.core.errors import CatalogError, PluginError
from cistern_archive.pipeline.contracts import STAGES
from cistern_archive.pipeline.registry import Registry, default_registry
from cistern_archive.sonar import marina


@dataclass
class CatalogReport:
    """The records that passed and every problem found."""

    records: list[LoadedRecord] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def check_files(loaded: LoadedRecord) -> list[str]:
    """Problems with the files a record references: missing, not a file, or resolving outside the root."""
    problems = []
    record = loaded.record
    refs = [(("scans", k, "file"), scan.file) for k, scan in enumerate(record.scans)]
    if record.simulation:
        refs.append((("simulation",), record.simulation))
    for loc, relative in refs:
        resolved = loaded.resolve(relative)
        where = f"{loaded.path}:{loaded.line_of(*loc)}: {format_loc(loc)}"
        if not resolved.is_relative_to(loaded.root):
            problems.append(f"{where}: {relative!r} resolves outside the catalog root (symbolic link?)")
        elif not resolved.exists():
            problems.append(f"{where}: file {relative!r} not found under {loaded.root}")
        elif not resolved.is_file():
            problems.append(f"{where}: {relative!r} is not a file")
    return problems + check_survey(loaded)


SURVEY_CHECKS = {"marina": marina.dataset_problems}
"""Survey kind → the check of its data folder (a list of problems naming the file)."""


def check_survey(loaded: LoadedRecord) -> list[str]:
    """Problems with a survey record's data folder and the files its kind reads (none without a survey)."""
    survey = loaded.record.survey
    if survey is None:
        return []
    where = f"{loaded.path}:{loaded.line_of('survey', 'data')}: survey.data"
    return [f"{where}: {problem}" for problem in SURVEY_CHECKS[survey.kind](loaded.survey_root())]


def check_plugins(loaded: LoadedRecord, registry: Registry, *, load_errors: bool = True) -> list[str]:
    """Problems with the record's pipeline: unknown plugins, plugins that fail to load, bad params.

    With ``load_errors=False`` an installed plugin that fails to import is not counted as a problem of
    the record (the nightly rebuild then fails only the sites that use it, naming the plugin).
    """
    problems = []
    for stage in STAGES:
        try:
            choice = registry.choice(loaded.record.pipeline, stage)
        except PluginError as exc:
            problems.append(f"{loaded.path}:{loaded.line_of('pipeline')}: pipeline.{stage}: {exc}")
            continue
        installed = choice.plugin in registry.names(stage)
        try:
            registry.load(stage, choice.plugin)
        except PluginError as exc:
            if installed and not load_errors:
                continue
            line = loaded.line_of("pipeline", stage, "plugin")
            problems.append(f"{loaded.path}:{line}: pipeline.{stage}.plugin: {exc}")
            continue
        try:
            registry.check_params(stage, choice.plugin, choice.params)
        except PluginError as exc:
            line = loaded.line_of("pipeline", stage, "params")
            problems.append(f"{loaded.path}:{line}: pipeline.{stage}.params: {exc}")
    return problems


def validate_record(path: Path, root: Path, registry: Registry | None = None, *,
                    plugin_load_errors: bool = True) -> LoadedRecord:
    """Load one record and check everything; raise :class:`CatalogError` listing every problem."""
    registry = registry or default_registry()
    loaded = load_record(path, root)
    problems = check_files(loaded) + check_plugins(loaded, registry, load_errors=plugin_load_errors)
    if problems:
        raise CatalogError(problems)
    return loaded


def validate_catalog(catalog: Path, registry: Registry | None = None, *,
                     plugin_load_errors: bool = True) -> CatalogReport:
    """Validate every record under ``catalog``; site ids must be unique.

    ``plugin_load_errors=False`` accepts records whose (installed) plugin fails to import; see
    :func:`check_plugins`.
    """
    registry = registry or default_registry()
    report = CatalogReport()
    paths = record_paths(catalog)
    if not catalog.is_dir():
        report.problems.append(f"{catalog}:1: (catalog): not a directory")
        return report
    if not paths:
        report.problems.append(f"{catalog}:1: (catalog): no site records (*.yaml) found")
    seen: dict[str, Path] = {}
    for path in paths:
        try:
            loaded = validate_record(path, catalog, registry, plugin_load_errors=plugin_load_errors)
        except CatalogError as exc:
            report.problems.extend(exc.problems)
            continue
        site_id = loaded.record.id
        if site_id in seen:
            report.problems.append(
                f"{path}:{loaded.line_of('id')}: id: site id {site_id!r} is already used by {seen[site_id]}"
            )
            continue
        seen[site_id] = path
        report.records.append(loaded)
    return report


def find_site(catalog: Path, site_id: str, registry: Registry | None = None) -> LoadedRecord:
    """The valid record of ``site_id`` in ``catalog`` (plugins and parameters checked).

    Raises
    ------
    CatalogError
        No valid record has this id: the problems of the record files named after the site (the record
        is invalid) or, when there are none, the ids of the valid records.
    """
    report = validate_catalog(Path(catalog), registry)
    for loaded in report.records:
        if loaded.record.id == site_id:
            return loaded
    own = [p for p in report.problems if Path(p.split(":", 1)[0]).stem == site_id]
    if own:
        raise CatalogError(own + [f"{catalog}: the record of site {site_id!r} is invalid"])
    known = ", ".join(sorted(r.record.id for r in report.records)) or "none"
    raise CatalogError([f"{catalog}: no valid site record with id {site_id!r} (valid: {known})"])
