"""The plugin author kit: pairs, scoring, check_matcher and the pytest fixtures."""

import io

import numpy as np

from cistern_archive.pipeline.contracts import MatchResult, StageParams
from cistern_archive.testing import check_matcher, pair_set, score, simulated_pair
from cistern_plugins.correlative import CorrelativeMatcher


def test_pairs_are_seeded_and_truthful():
    a, b = pair_set(3, 7), pair_set(3, 7)
    assert [p.dx_m for p in a] == [p.dx_m for p in b]
    pr = a[0]
    truth = MatchResult(-1, -1, pr.dx_m, pr.dy_m, pr.dyaw_rad, 1.0, True, 1, 0.0)
    assert score(truth, pr).success and not score(truth, pr).false_success


def test_overlap_bounds_are_respected():
    pr = simulated_pair(np.random.default_rng(1), overlap_range=(0.3, 0.5), offset_range_m=(1.0, 2.0))
    assert 0.3 <= pr.overlap <= 0.5 and 1.0 <= pr.offset_m <= 2.0


class _ZeroMatcher:
    """Always claims convergence at zero: the kit must catch it."""

    name = "zero"

    class Params(StageParams):
        pass

    def match(self, reference, moving, params, *, rng):
        return MatchResult(-1, -1, 0.0, 0.0, 0.0, 1.0, True, 1, 0.0)


class _NoDefaults:
    name = "nodefaults"

    class Params(StageParams):
        x: int

    def match(self, reference, moving, params, *, rng):  # pragma: no cover - never reached
        raise AssertionError


def test_check_matcher_flags_a_dishonest_matcher():
    out = io.StringIO()
    report = check_matcher(_ZeroMatcher, n_pairs=4, seed=0, stream=out)
    assert not report.passed
    failed = {c.name for c in report.failures()}
    assert {"accuracy", "honesty"} <= failed
    assert "FAILED" in out.getvalue()


def test_check_matcher_flags_params_without_defaults():
    report = check_matcher(_NoDefaults(), stream=None)
    assert [c.name for c in report.failures()] == ["contract"]


class _PositionalGuess(_ZeroMatcher):
    name = "positional-guess"

    def match(self, reference, moving, params, guess, /, *, rng):  # pragma: no cover - never reached
        raise AssertionError


def test_check_matcher_flags_a_wrong_signature_as_the_registry_would():
    report = check_matcher(_PositionalGuess(), stream=None)
    contract = next(c for c in report.checks if c.name == "contract")
    assert not contract.passed
    assert "match() of GuidedMatcher takes parameter 'guess' by position only" in contract.detail


def test_check_matcher_passes_a_real_matcher():
    report = check_matcher(CorrelativeMatcher(), n_pairs=4, seed=0, stream=None)
    assert report.passed, report.format()
    assert report.median_seconds > 0
    assert "0 of 4 converged outside" in next(c for c in report.checks if c.name == "guess").detail


class _IgnoresGuess(CorrelativeMatcher):
    """Declares the guided capability but searches its own wide window whatever the guess."""

    name = "ignores-guess"

    def match(self, reference, moving, params, *, rng, guess=None):
        return super().match(reference, moving, params, rng=rng)


def test_check_matcher_flags_a_guided_matcher_that_searches_beyond_its_window():
    report = check_matcher(_IgnoresGuess(), n_pairs=4, seed=0, stream=None)
    assert [c.name for c in report.failures()] == ["guess"]
    assert "converged outside a ±0.5 m window 1.5 m from the truth" in report.failures()[0].detail


def test_fixtures(simulated_pair, simulated_pairs, isolated_registry):
    assert simulated_pair.overlap >= 0.5
    assert len(simulated_pairs(2, seed=1)) == 2
    reg = isolated_registry(matchers={"correlative": "cistern_plugins.correlative:CorrelativeMatcher"})
    assert reg.names("matcher") == ["correlative"]
    assert reg.names("localizer") == []
    assert reg.load("matcher", "correlative").instance.name == "correlative"
