"""Small third-party-style plugins used by the registry tests (imported through entry points)."""

from __future__ import annotations

import numpy as np

from cistern_archive.pipeline.contracts import MatchResult, StageParams


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
