"""Entry-point plugin registry: lazy, typed, failure-tolerant, with provenance.

One entry-point group per stage (:data:`GROUPS`). Entry points are listed without importing them; a
plugin is imported only when a record asks for it, checked against its stage's Protocol, and kept.
A plugin that fails to import is remembered with its error and reported; it never breaks the sites
that do not use it. The built-in stages (``plugins/``) register through the same groups.
"""

from __future__ import annotations

import importlib.metadata as md
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel, ValidationError

from cistern_archive.catalog.models import PipelineSpec, SiteRecord, StageChoice
from cistern_archive.core.errors import PluginError
from cistern_archive.pipeline.contracts import PROTOCOLS, STAGES, StageParams
from cistern_archive.pipeline.signatures import check_methods, protocol_methods

GROUPS = {stage: f"cistern_archive.{stage}s" for stage in STAGES}
DEFAULTS_GROUP = "cistern_archive.defaults"
"""Entry points named after a stage whose value is one of that stage's plugin objects: the plugin a
record gets when it does not name one. The core names no plugin; a distribution declares its defaults."""


@dataclass(frozen=True)
class PluginInfo:
    """What is known about an installed plugin without importing it."""

    stage: str
    name: str
    value: str
    distribution: str
    version: str

    def provenance(self) -> dict[str, str]:
        return {"plugin": self.name, "distribution": self.distribution, "version": self.version}


@dataclass(frozen=True)
class LoadedPlugin:
    """An imported, checked plugin instance with its provenance and the optional capabilities it
    implements (:data:`~cistern_archive.pipeline.contracts.CAPABILITIES`, checked at load)."""

    info: PluginInfo
    instance: Any
    capabilities: frozenset[type] = frozenset()

    def has(self, capability: type) -> bool:
        """Whether the plugin implements ``capability`` (e.g. :class:`~cistern_archive.pipeline.contracts.GuidedMatcher`)."""
        return capability in self.capabilities

    @property
    def params_model(self) -> type[BaseModel]:
        return self.instance.Params

    def validate_params(self, params: dict[str, Any]) -> StageParams:
        """Validate a record's parameters with the plugin's ``Params`` model."""
        return self.instance.Params.model_validate(params)


class Registry:
    """The installed plugins of every stage.

    Parameters
    ----------
    entry_points : dict, optional
        ``{stage: [EntryPoint, ...]}`` to use instead of the installed distributions (tests use it to
        isolate the registry).
    """

    def __init__(self, entry_points: dict[str, list[md.EntryPoint]] | None = None,
                 defaults: list[md.EntryPoint] | None = None):
        if entry_points is None:
            entry_points = {stage: list(md.entry_points(group=group)) for stage, group in GROUPS.items()}
            if defaults is None:
                defaults = list(md.entry_points(group=DEFAULTS_GROUP))
        self._entry_points = {stage: {ep.name: ep for ep in eps} for stage, eps in entry_points.items()}
        self._defaults = list(defaults or [])
        self._loaded: dict[tuple[str, str], LoadedPlugin] = {}
        self.errors: dict[tuple[str, str], str] = {}

    # ---------------------------------------------------------------------------------- listing
    def names(self, stage: str) -> list[str]:
        return sorted(self._entry_points.get(stage, {}))

    def info(self, stage: str, name: str) -> PluginInfo:
        ep = self._entry_point(stage, name)
        dist = getattr(ep, "dist", None)
        return PluginInfo(
            stage=stage,
            name=name,
            value=ep.value,
            distribution=dist.name if dist is not None else "unknown",
            version=dist.version if dist is not None else "unknown",
        )

    def default(self, stage: str) -> str:
        """The name of the plugin a record gets for ``stage`` when it names none.

        Raises
        ------
        PluginError
            When no installed distribution declares a default for the stage, when its declared object is
            not one of the stage's plugins, or when two distributions declare different defaults.
        """
        declared = sorted({ep.value for ep in self._defaults if ep.name == stage})
        if not declared:
            raise PluginError(f"no default {stage}: no installed distribution declares one "
                              f"(entry-point group {DEFAULTS_GROUP}); name the {stage} in the record")
        if len(declared) > 1:
            raise PluginError(f"conflicting default {stage}s declared: {', '.join(declared)}; "
                              f"name the {stage} in the record")
        names = [name for name, ep in self._entry_points.get(stage, {}).items() if ep.value == declared[0]]
        if not names:
            raise PluginError(f"default {stage} {declared[0]} is not an installed {stage} plugin")
        return min(names)

    def choice(self, pipeline: PipelineSpec, stage: str) -> StageChoice:
        """The record's choice for ``stage``, or the installed default with default parameters."""
        named = getattr(pipeline, stage)
        return named if named is not None else StageChoice(plugin=self.default(stage))

    def resolve(self, record: SiteRecord) -> SiteRecord:
        """The record as it runs: every stage named, each with its plugin's validated parameters,
        defaults filled in (the form ``record.json`` stores and ``cistern-archive config`` prints).

        Raises
        ------
        PluginError
            A stage's plugin is unknown or fails to load, or its parameters are refused.
        """
        choices = {}
        for stage in STAGES:
            choice = self.choice(record.pipeline, stage)
            params = self.check_params(stage, choice.plugin, choice.params)
            choices[stage] = StageChoice(plugin=choice.plugin, params=params.model_dump(mode="json"))
        return record.model_copy(update={"pipeline": PipelineSpec(**choices)})

    def all_info(self) -> list[PluginInfo]:
        return [self.info(stage, name) for stage in STAGES for name in self.names(stage)]

    def _entry_point(self, stage: str, name: str) -> md.EntryPoint:
        if stage not in GROUPS:
            raise PluginError(f"unknown stage {stage!r}; stages are {', '.join(STAGES)}")
        try:
            return self._entry_points.get(stage, {})[name]
        except KeyError:
            known = ", ".join(self.names(stage)) or "none"
            raise PluginError(f"unknown {stage} plugin {name!r}; installed: {known}") from None

    # ---------------------------------------------------------------------------------- loading
    def load(self, stage: str, name: str) -> LoadedPlugin:
        """Import, instantiate and check a plugin (once); raise :class:`PluginError` on failure."""
        key = (stage, name)
        if key in self._loaded:
            return self._loaded[key]
        if key in self.errors:
            raise PluginError(self.errors[key])
        info = self.info(stage, name)
        try:
            obj = self._entry_point(stage, name).load()
            loaded = checked_plugin(stage, obj() if isinstance(obj, type) else obj, info)
        except PluginError as exc:
            self.errors[key] = str(exc)
            raise
        except Exception as exc:  # a third-party import can raise anything
            message = f"{stage} plugin {name!r} ({info.distribution} {info.version}) failed to load: "
            message += f"{type(exc).__name__}: {exc}"
            self.errors[key] = message
            raise PluginError(message) from exc
        self._loaded[key] = loaded
        return loaded

    def load_all(self) -> None:
        """Try to load every plugin (for ``cistern-archive plugins``); errors are kept in :attr:`errors`."""
        for stage in STAGES:
            for name in self.names(stage):
                try:
                    self.load(stage, name)
                except PluginError:
                    pass

    def check_params(self, stage: str, name: str, params: dict[str, Any]) -> StageParams:
        """Load the plugin and validate parameters; errors name the plugin and the field."""
        plugin = self.load(stage, name)
        try:
            return plugin.validate_params(params)
        except ValidationError as exc:
            details = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or '(params)'}: "
                + ("unknown parameter" if e["type"] == "extra_forbidden" else e["msg"])
                for e in exc.errors()
            )
            raise PluginError(f"{stage} plugin {name!r}: bad params: {details}") from None


def checked_plugin(stage: str, instance: Any, info: PluginInfo | None = None) -> LoadedPlugin:
    """``instance`` checked against its stage's protocol (members, method signatures, the capabilities
    it implements, a ``Params`` model with defaults for every field), as a :class:`LoadedPlugin`.

    ``info`` defaults to an unregistered plugin named after ``instance.name`` (benchmarks and tests run
    plugin objects that no entry point names).

    Raises
    ------
    PluginError
        Naming the plugin and what is wrong.
    """
    name = info.name if info is not None else str(getattr(instance, "name", type(instance).__name__))
    info = info or PluginInfo(stage=stage, name=name, value=f"{type(instance).__module__}:{type(instance).__name__}",
                              distribution="unregistered", version="unknown")
    protocol = PROTOCOLS[stage]
    if not isinstance(instance, protocol):
        missing = [m for m in ("name", "Params", *protocol_methods(protocol)) if not hasattr(instance, m)]
        raise PluginError(f"{stage} plugin {name!r} does not implement {protocol.__name__}: missing {missing}")
    capabilities = check_methods(stage, name, instance)
    params = getattr(instance, "Params", None)
    if not (isinstance(params, type) and issubclass(params, BaseModel)):
        raise PluginError(f"{stage} plugin {name!r}: Params must be a pydantic model class")
    try:
        params()
    except ValidationError as exc:
        raise PluginError(f"{stage} plugin {name!r}: Params must have defaults for every field: {exc}") from None
    return LoadedPlugin(info=info, instance=instance, capabilities=capabilities)


_default: Registry | None = None


def default_registry() -> Registry:
    """The process-wide registry of installed plugins (created on first use)."""
    global _default
    if _default is None:
        _default = Registry()
    return _default
