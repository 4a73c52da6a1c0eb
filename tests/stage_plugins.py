"""Small third-party-style plugins used by the registry tests (imported through entry points)."""

from __future__ import annotations

import numpy as np

from cistern_archive.pipeline.contracts import GuidedLocalizer, GuidedMatcher, MatchResult, StageParams


class CompassOnlyMatcher:
    """Claims no translation and never converges: a valid, honest, useless matcher."""

    name = "compass-only"

    class Params(StageParams):
        scale: float = 1.0

    def match(self, reference, moving, params, *, rng: np.random.Generator) -> MatchResult:
        return MatchResult(i=-1, j=-1, dx_m=0.0, dy_m=0.0, dyaw_rad=0.0, weight=0.0, converged=False,
                           iterations=0, seconds=0.0, reason="compass-only matcher estimates no translation")


class NoMethodMatcher:
    name = "no-method"

    class Params(StageParams):
        pass


class RequiredParamsMatcher(CompassOnlyMatcher):
    name = "required-params"

    class Params(StageParams):
        mandatory: int


class WrongGuessMatcher(CompassOnlyMatcher, GuidedMatcher):
    """Declares GuidedMatcher but takes ``guess`` by position only."""

    name = "wrong-guess"

    def match(self, reference, moving, params, guess, /, *, rng):  # noqa: D102
        return super().match(reference, moving, params, rng=rng)


class NoGuessMatcher(CompassOnlyMatcher, GuidedMatcher):
    """Declares GuidedMatcher but its match takes no ``guess``."""

    name = "no-guess"


class ShortGuidedLocalizer(GuidedLocalizer):
    """Declares GuidedLocalizer but its guided_pairs forgets the parameters."""

    name = "short-guided"

    class Params(StageParams):
        pass

    def pairs(self, n_scans, params):
        return []

    def localize(self, scans, matches, params, *, ties=()):
        raise NotImplementedError

    def guided_pairs(self, scans, matches):
        return []


class NoTiesLocalizer:
    """A localizer written before ties were typed input: ``localize`` takes no ``ties``."""

    name = "no-ties"

    class Params(StageParams):
        pass

    def pairs(self, n_scans, params):
        return []

    def localize(self, scans, matches, params):
        raise NotImplementedError


class ExtraRequiredLocalizer(NoTiesLocalizer):
    """``localize`` wants a parameter the runner never passes."""

    name = "extra-required"

    def localize(self, scans, matches, params, depth, *, ties=()):
        raise NotImplementedError
