"""``rebuild --dry-run``: what a rebuild would do to each site, and why, without doing any of it.

Every selected site gets its build key from the catalog as it is now (the record, the digests of its
input files read in place, its plugins, the code version, the report settings;
:func:`~cistern_archive.service.buildkey.build_key`), and that key's material is compared with the
material stored beside the published report (``build.json``). Nothing is written: no lock is taken, the
archive is not opened, no report is touched.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from cistern_archive.archive.digest import file_sha256
from cistern_archive.catalog.loader import LoadedRecord
from cistern_archive.pipeline.registry import Registry, default_registry
from cistern_archive.pipeline.validate import validate_catalog
from cistern_archive.service.buildkey import build_key
from cistern_archive.service.rebuild import require_catalog
from cistern_archive.service.planning import CURRENT_STATUSES, is_current, published_build, select_sites, site_inputs

Action = Literal["skip", "new", "rebuild"]
SHOWN_CHARS = 60
"""Longer values are shortened in a change's description."""


@dataclass(frozen=True)
class SiteDecision:
    """What a rebuild would do with one site: ``skip`` (key unchanged), ``new`` (never published) or
    ``rebuild``, with the reasons (the inputs of the build key whose material changed)."""

    site_id: str
    action: Action
    build_key: str
    reasons: tuple[str, ...] = ()

    def line(self) -> str:
        """``rebuild cistern-000: input sites/a.npz changed (…); code version …``."""
        head = f"{self.action:7s} {self.site_id}"
        return f"{head}: {'; '.join(self.reasons)}" if self.reasons else head


@dataclass
class DryRun:
    """The decisions for every selected site, and the catalog's problems (sites a rebuild would not build)."""

    decisions: list[SiteDecision] = field(default_factory=list)
    catalog_problems: list[str] = field(default_factory=list)

    def counts(self) -> dict[str, int]:
        return {action: sum(d.action == action for d in self.decisions) for action in ("skip", "new", "rebuild")}


def shown(value: Any) -> str:
    """A value for a one-line description, shortened to :data:`SHOWN_CHARS`."""
    text = repr(value)
    return text if len(text) <= SHOWN_CHARS else text[: SHOWN_CHARS - 1] + "…"


def changed_paths(old: Any, new: Any, prefix: str = "") -> list[str]:
    """``path: old → new`` of every leaf that differs between two JSON values (dotted paths, list
    indices as numbers; ``added`` / ``removed`` for keys present on one side only)."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in sorted(set(old) | set(new), key=str):
            path = f"{prefix}.{key}" if prefix else str(key)
            if key not in old:
                out.append(f"{path} added ({shown(new[key])})")
            elif key not in new:
                out.append(f"{path} removed (was {shown(old[key])})")
            else:
                out += changed_paths(old[key], new[key], path)
        return out
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        return [c for k, (a, b) in enumerate(zip(old, new)) for c in changed_paths(a, b, f"{prefix}.{k}")]
    return [] if old == new else [f"{prefix or 'value'}: {shown(old)} → {shown(new)}"]


def input_changes(old: dict[str, str], new: dict[str, str]) -> list[str]:
    """Which input files of the record changed content, appeared or are no longer read."""
    out = []
    for path in sorted(set(old) | set(new)):
        if path not in old:
            out.append(f"input {path} added")
        elif path not in new:
            out.append(f"input {path} no longer read")
        elif old[path] != new[path]:
            out.append(f"input {path} changed (sha256 {old[path][:12]} → {new[path][:12]})")
    return out


def plugin_changes(old: list[dict[str, Any]], new: list[dict[str, Any]]) -> list[str]:
    """Per stage: another plugin, or the same plugin with other parameters, version or source files."""
    before = {item.get("stage"): item for item in old}
    out = []
    for item in new:
        stage, previous = item["stage"], before.get(item["stage"])
        if previous is None:
            out.append(f"{stage}: no stored plugin")
        elif previous.get("plugin") != item["plugin"]:
            out.append(f"{stage} plugin {previous.get('plugin')} → {item['plugin']}")
        else:
            name = f"{stage} {item['plugin']}"
            if previous.get("distribution") != item["distribution"] or previous.get("version") != item["version"]:
                out.append(f"{name}: {previous.get('distribution')} {previous.get('version')} → "
                           f"{item['distribution']} {item['version']}")
            out += [f"{name} params {c}" for c in changed_paths(previous.get("params"), item["params"])]
            if previous.get("source") != item["source"]:
                out.append(f"{name}: plugin source files changed")
    return out


def material_changes(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """Why two build keys differ: each part of the key material that changed (module docstring)."""
    out = [f"record {c}" for c in changed_paths(old.get("record"), new["record"])]
    out += input_changes(old.get("inputs") or {}, new["inputs"])
    out += plugin_changes(old.get("plugins") or [], new["plugins"])
    if old.get("code_version") != new["code_version"]:
        out.append(f"code version {old.get('code_version')} → {new['code_version']}")
    out += [f"report settings {c}" for c in changed_paths(old.get("report") or {}, new["report"])]
    if old.get("source_date_epoch") != new["source_date_epoch"]:
        out.append(f"SOURCE_DATE_EPOCH {old.get('source_date_epoch')} → {new['source_date_epoch']}")
    if old.get("schema") != new["schema"]:
        out.append(f"build key schema {old.get('schema')} → {new['schema']}")
    return out


def input_digests(loaded: LoadedRecord) -> dict[str, str]:
    """``{path relative to the catalog root: sha256}`` of the record's input files, read in place."""
    return {relative: file_sha256(loaded.input_path(relative))[0] for _, relative in site_inputs(loaded)}


def decide(loaded: LoadedRecord, site_dir: Path, registry: Registry, report_config: dict[str, Any] | None,
           force: bool = False) -> SiteDecision:
    """What a rebuild would do with one site, and why (see :class:`SiteDecision`)."""
    site_id = loaded.record.id
    try:
        key = build_key(loaded, input_digests(loaded), registry, report_config)
    except OSError as exc:
        return SiteDecision(site_id, "rebuild", "", (f"an input cannot be read ({exc}); the site would fail",))
    published = published_build(site_dir)
    if published is None:
        return SiteDecision(site_id, "new", key.key, ("no published report",))
    current = is_current(site_dir, key.key)
    if current and not force:
        return SiteDecision(site_id, "skip", key.key, ("build key unchanged",))
    if current:
        return SiteDecision(site_id, "rebuild", key.key, ("forced (build key unchanged)",))
    if published.get("build_key") == key.key:
        status = published.get("status")
        why = (f"the published build {status}" if status not in CURRENT_STATUSES
               else "published files are missing")
        return SiteDecision(site_id, "rebuild", key.key, (f"build key unchanged, but {why}",))
    stored = published.get("key_material")
    if not isinstance(stored, dict):
        return SiteDecision(site_id, "rebuild", key.key, ("build key changed (no key material stored with it)",))
    reasons = material_changes(stored, key.material) or ["build key changed"]
    return SiteDecision(site_id, "rebuild", key.key, tuple(reasons))


def dry_run(catalog: Path, out: Path, *, sites: list[str] | None = None, force: bool = False,
            registry: Registry | None = None, report_config: dict[str, Any] | None = None) -> DryRun:
    """What :func:`~cistern_archive.service.rebuild.rebuild` with the same arguments would build, and why.

    Raises
    ------
    CatalogError
        There is no catalog at ``catalog``, or ``sites`` names no valid record.
    """
    catalog, out = Path(catalog).resolve(), Path(out).resolve()
    require_catalog(catalog)
    registry = registry or default_registry()
    report = validate_catalog(catalog, registry, plugin_load_errors=False)
    selected = select_sites(report.records, sites, report.problems)
    decisions = [decide(loaded, out / loaded.record.id, registry, report_config, force) for loaded in selected]
    return DryRun(decisions=sorted(decisions, key=lambda d: d.site_id), catalog_problems=list(report.problems))
