"""Build keys: one SHA-256 per site over everything its report depends on.

The key covers the canonical JSON of the validated record (so comments and key order in the YAML do not
matter), the digest of every input file, each stage's plugin (name, distribution, version, resolved
parameters with defaults, digest of its module source), the code version (package version plus a
digest of the package sources and report templates), non-default report settings and
``SOURCE_DATE_EPOCH`` (reports print it).
Two builds with the same key produce the same report, so an unchanged key means the site is skipped.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata as md
import importlib.util
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cistern_archive
from cistern_archive import __version__
from cistern_archive.catalog.loader import LoadedRecord
from cistern_archive.core.errors import PluginError
from cistern_archive.pipeline.contracts import STAGES
from cistern_archive.pipeline.registry import Registry

KEY_SCHEMA = 1
SOURCE_SUFFIXES = (".py", ".j2", ".html", ".css", ".js", ".json", ".yaml")


def canonical_json(data: Any) -> str:
    """JSON with sorted keys and no insignificant whitespace (the hashed form)."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def _hash_tree(digest: "hashlib._Hash", root: Path) -> None:
    for path in sorted(p for p in root.rglob("*") if p.is_file() and p.suffix in SOURCE_SUFFIXES
                       and "__pycache__" not in p.parts):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
        digest.update(b"\0")


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """``<package version>+src.<12 hex>``: the version plus a digest of the sources that shape a report.

    Hashes ``cistern_archive`` (its report templates included) and ``$CISTERN_ARCHIVE_TEMPLATES`` when
    set, so that a code change rebuilds every site even when the version number did not move. Plugins
    are hashed per stage, whatever distribution they come from (:func:`plugin_material`).
    """
    package = Path(cistern_archive.__file__).resolve().parent
    digest = hashlib.sha256()
    roots = [package]
    if os.environ.get("CISTERN_ARCHIVE_TEMPLATES"):
        roots.append(Path(os.environ["CISTERN_ARCHIVE_TEMPLATES"]))
    for root in roots:
        if root.is_dir():
            digest.update(root.name.encode())
            _hash_tree(digest, root)
    return f"{__version__}+src.{digest.hexdigest()[:12]}"


@functools.lru_cache(maxsize=None)
def distribution_digest(distribution: str, module: str) -> str:
    """SHA-256 of the source files of the distribution that provides ``module``.

    The files are those ``importlib.metadata`` lists for the distribution (a regular install). An
    editable install lists only a path hook, so then the whole top-level package of ``module`` is
    hashed. Either way a change to any file of the plugin's package (a shared helper, a data file it
    reads) changes the key, not only a change to the plugin's own module.
    """
    digest = hashlib.sha256()
    try:
        files = [f for f in (md.distribution(distribution).files or []) if f.suffix in SOURCE_SUFFIXES]
    except md.PackageNotFoundError:
        files = []
    sources = sorted((str(f), Path(str(f.locate()))) for f in files if "__pycache__" not in f.parts)
    sources = [(name, path) for name, path in sources if path.is_file()]
    if any(name.endswith(".py") for name, _ in sources):
        for name, path in sources:
            digest.update(name.encode() + b"\0" + path.read_bytes() + b"\0")
        return digest.hexdigest()
    try:
        spec = importlib.util.find_spec(module.split(".")[0])
    except (ImportError, ValueError):
        return "unknown"
    if spec is None:
        return "unknown"
    if spec.submodule_search_locations:
        _hash_tree(digest, Path(list(spec.submodule_search_locations)[0]))
    elif spec.origin and Path(spec.origin).is_file():
        digest.update(Path(spec.origin).read_bytes())
    else:
        return "unknown"
    return digest.hexdigest()


def plugin_material(loaded: LoadedRecord, registry: Registry) -> list[dict[str, Any]]:
    """Name, distribution, version, resolved params and source digest of each stage's plugin.

    Raises
    ------
    PluginError
        When a plugin is unknown (validation catches this first). A plugin that fails to import gives
        its error in place of the resolved parameters, so the key changes once it is fixed.
    """
    items = []
    for stage in STAGES:
        choice = registry.choice(loaded.record.pipeline, stage)
        info = registry.info(stage, choice.plugin)
        try:
            params = registry.check_params(stage, choice.plugin, choice.params).model_dump(mode="json")
        except PluginError as exc:  # an installed plugin that fails to import: its site will fail
            params = {"record_params": choice.params, "load_error": str(exc)}
        items.append({"stage": stage, "plugin": info.name, "distribution": info.distribution,
                      "version": info.version, "params": params,
                      "source": distribution_digest(info.distribution, info.value.split(":")[0])})
    return items


@dataclass(frozen=True)
class BuildKey:
    """A site's build key and the material it was computed from (stored beside the report)."""

    key: str
    material: dict[str, Any]


def build_key(loaded: LoadedRecord, input_digests: dict[str, str], registry: Registry,
              report_config: dict[str, Any] | None = None) -> BuildKey:
    """The build key of one site.

    Parameters
    ----------
    loaded : LoadedRecord
        The validated record.
    input_digests : dict
        ``{path relative to the catalog root: sha256}`` of every file the record references.
    registry : Registry
        Where the record's plugins are resolved.
    report_config : dict, optional
        Report settings that differ from the defaults.
    """
    material = {
        "schema": KEY_SCHEMA,
        "record": loaded.record.model_dump(mode="json"),
        "inputs": dict(sorted(input_digests.items())),
        "plugins": plugin_material(loaded, registry),
        "code_version": code_version(),
        "source_date_epoch": os.environ.get("SOURCE_DATE_EPOCH"),
        "report": dict(sorted((report_config or {}).items())),
    }
    key = hashlib.sha256(canonical_json(material).encode("utf-8")).hexdigest()
    return BuildKey(key=key, material=material)
