"""The entry-point registry: lazy listing, contract checks, failure tolerance, provenance."""

from __future__ import annotations

import importlib.metadata as md
import sys

import pytest

from cistern_archive.core.errors import PluginError
from cistern_archive.catalog.models import PipelineSpec, StageChoice
from cistern_archive.pipeline.registry import DEFAULTS_GROUP, GROUPS, Registry


def entry(name: str, value: str, stage: str = "matcher") -> md.EntryPoint:
    return md.EntryPoint(name=name, value=value, group=GROUPS[stage])


@pytest.fixture()
def registry() -> Registry:
    return Registry({
        "matcher": [
            entry("compass-only", "stage_plugins:CompassOnlyMatcher"),
            entry("broken", "broken_plugin:Matcher"),
            entry("no-method", "stage_plugins:NoMethodMatcher"),
            entry("required-params", "stage_plugins:RequiredParamsMatcher"),
        ],
    })


def test_listing_does_not_import(registry):
    sys.modules.pop("broken_plugin", None)
    assert registry.names("matcher") == ["broken", "compass-only", "no-method", "required-params"]
    assert "broken_plugin" not in sys.modules
    assert registry.info("matcher", "broken").distribution == "unknown"


def test_load_checks_the_protocol_and_keeps_the_instance(registry):
    plugin = registry.load("matcher", "compass-only")
    assert plugin.instance.name == "compass-only"
    assert registry.load("matcher", "compass-only") is plugin
    assert registry.check_params("matcher", "compass-only", {"scale": 2}).scale == 2.0


def test_import_failure_is_recorded_and_others_still_load(registry):
    with pytest.raises(PluginError, match="failed to load: ImportError: this plugin needs a library"):
        registry.load("matcher", "broken")
    assert ("matcher", "broken") in registry.errors
    with pytest.raises(PluginError, match="failed to load"):  # remembered, not retried
        registry.load("matcher", "broken")
    registry.load_all()
    assert set(registry.errors) == {("matcher", "broken"), ("matcher", "no-method"), ("matcher", "required-params")}
    assert registry.load("matcher", "compass-only").instance is not None


def test_contract_violations_are_named(registry):
    with pytest.raises(PluginError, match=r"does not implement Matcher: missing \['match'\]"):
        registry.load("matcher", "no-method")
    with pytest.raises(PluginError, match="Params must have defaults"):
        registry.load("matcher", "required-params")


def test_unknown_names_and_stages(registry):
    with pytest.raises(PluginError, match="unknown matcher plugin 'nope'; installed: broken, compass-only"):
        registry.load("matcher", "nope")
    with pytest.raises(PluginError, match="unknown stage 'painter'"):
        registry.load("painter", "x")


def test_bad_params_name_the_field(registry):
    with pytest.raises(PluginError, match="bad params: scale: Input should be a valid number"):
        registry.check_params("matcher", "compass-only", {"scale": "big"})
    with pytest.raises(PluginError, match="colour: unknown parameter"):
        registry.check_params("matcher", "compass-only", {"colour": 1})


def test_installed_builtins_carry_provenance():
    registry = Registry()
    info = registry.info("matcher", "pf-pairwise")
    assert info.distribution == "cistern-plugins"
    assert info.provenance()["plugin"] == "pf-pairwise"
    assert set(GROUPS) == {"matcher", "localizer", "mapper", "comparator"}
    for stage in GROUPS:
        assert registry.names(stage), f"no built-in {stage} registered"


def default_entry(stage: str, value: str) -> md.EntryPoint:
    return md.EntryPoint(name=stage, value=value, group=DEFAULTS_GROUP)


def test_defaults_come_from_a_declaring_distribution():
    matchers = {"matcher": [entry("compass-only", "stage_plugins:CompassOnlyMatcher")]}
    registry = Registry(matchers, defaults=[default_entry("matcher", "stage_plugins:CompassOnlyMatcher")])
    assert registry.default("matcher") == "compass-only"
    record_pipeline = PipelineSpec()
    assert registry.choice(record_pipeline, "matcher") == StageChoice(plugin="compass-only")
    named = PipelineSpec(matcher=StageChoice(plugin="other", params={"a": 1}))
    assert registry.choice(named, "matcher").plugin == "other"


def test_missing_unknown_and_conflicting_defaults_are_named():
    matchers = {"matcher": [entry("compass-only", "stage_plugins:CompassOnlyMatcher")]}
    with pytest.raises(PluginError, match="no default matcher: no installed distribution declares one"):
        Registry(matchers, defaults=[]).default("matcher")
    with pytest.raises(PluginError, match="is not an installed matcher plugin"):
        Registry(matchers, defaults=[default_entry("matcher", "elsewhere:Matcher")]).default("matcher")
    rival = [default_entry("matcher", "stage_plugins:CompassOnlyMatcher"), default_entry("matcher", "x:Y")]
    with pytest.raises(PluginError, match="conflicting default matchers"):
        Registry(matchers, defaults=rival).default("matcher")


def test_installed_defaults_name_one_plugin_per_stage():
    registry = Registry()
    for stage in GROUPS:
        assert registry.default(stage) in registry.names(stage)


SIGNATURES = Registry({
    "matcher": [entry("wrong-guess", "stage_plugins:WrongGuessMatcher"),
                entry("no-guess", "stage_plugins:NoGuessMatcher")],
    "localizer": [entry(name, f"stage_plugins:{cls}", "localizer") for name, cls in (
        ("short-guided", "ShortGuidedLocalizer"), ("no-ties", "NoTiesLocalizer"),
        ("extra-required", "ExtraRequiredLocalizer"))],
})


@pytest.mark.parametrize("stage, name, message", [
    ("matcher", "wrong-guess", "matcher plugin 'wrong-guess': match() of GuidedMatcher takes parameter 'guess' "
                               "by position only; the runner passes it by name"),
    ("matcher", "no-guess", "matcher plugin 'no-guess': match() of GuidedMatcher does not take the keyword "
                            "parameter 'guess'"),
    ("localizer", "short-guided", "localizer plugin 'short-guided': guided_pairs() of GuidedLocalizer takes 2 "
                                  "positional parameter(s), the runner passes 3 (scans, matches, params): "
                                  "parameter 'params' is missing"),
    ("localizer", "no-ties", "localizer plugin 'no-ties': localize() of Localizer does not take the keyword "
                             "parameter 'ties'"),
    ("localizer", "extra-required", "localizer plugin 'extra-required': localize() of Localizer has parameter "
                                    "'depth' without a default, which the runner never passes"),
])
def test_a_wrong_method_signature_is_refused_at_load_naming_plugin_method_and_parameter(stage, name, message):
    with pytest.raises(PluginError) as caught:
        SIGNATURES.load(stage, name)
    assert str(caught.value) == message
    assert SIGNATURES.errors[(stage, name)] == message


def test_capabilities_are_recorded_at_load():
    from cistern_archive.pipeline.contracts import GuidedLocalizer, GuidedMatcher

    registry = Registry()
    assert registry.load("matcher", "correlative").capabilities == {GuidedMatcher}  # declared by subclassing
    assert registry.load("matcher", "pf-pairwise").has(GuidedMatcher)  # structurally: match takes guess
    for local in ("icp", "particle-icp"):  # declared by subclassing: they start from the guess
        assert registry.load("matcher", local).capabilities == {GuidedMatcher}
    plain = Registry({"matcher": [entry("compass-only", "stage_plugins:CompassOnlyMatcher")]})
    assert not plain.load("matcher", "compass-only").capabilities
    assert registry.load("localizer", "site-graph").has(GuidedLocalizer)
    assert not registry.load("localizer", "wls").capabilities
