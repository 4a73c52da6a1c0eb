"""Lengths of a matcher's parameters scaled to the sonar that took the scans.

A matcher's lengths — the inlier distance, the free-space margin, the precision a fit must reach, a
likelihood's width, a search's lattice — are written for the sonars they were tuned, calibrated and
tested on: Micron-class heads at ranges up to 10 m with bins up to 0.08 m (:data:`CALIBRATION_RANGE_M`,
:data:`CALIBRATION_BIN_M`). A pair scanned with coarser bins or at a longer range sees its walls less
sharply: a wall's echo spreads over more range, the points a sonar lays along a wall lie farther apart
(one per beam: its range times the step), and a heading error moves a far wall farther. The same
limits in metres then refuse every right match of a 50 m harbour sonar with 0.1 m bins.

:func:`length_unit` is how many metres of a pair one metre of those limits is: the larger of the bin
ratio and the range ratio over both scans, and never less than 1 — finer settings keep the limits as
set, since they also carry the compass's noise and the chambers' shapes, which finer bins do not
change. :class:`SonarScaled` parameters multiply every length (a field named ``*_m``, in nested
sections too) by it before a match. Within the calibration settings the unit is exactly 1 and nothing
changes.
"""

from __future__ import annotations

import math
from typing import Self

from pydantic import BaseModel, Field

from cistern_archive.core.scan import RangeScan
from cistern_archive.pipeline.contracts import StageParams

CALIBRATION_BIN_M = 0.08
"""Coarsest range bin the built-in matchers' lengths were tested with. They were set on 0.04 m bins
(the physical simulator's 10 m over 250) and 0.05 m (the ideal-ray pairs); random multi-chamber sites
with 0.08 m bins match as well with them as with them scaled by 1.6, the bin ratio to 0.05 m
(``benchmarks/sites.py --random 40 --seed 2 --generator '{"bin_m": 0.08}'``: 338 and 337 of 347 scans
placed, 92.3 % and 91.8 % of the pairs with half their view shared within 0.10 m;
``benchmarks/RESULTS.md``): the inlier distance already spans two such bins."""
CALIBRATION_RANGE_M = 10.0
"""Longest range setting among those scans (the demo and random sites use 6, 8 and 10 m)."""


def length_unit(*scans: RangeScan, bin_m: float = CALIBRATION_BIN_M, range_m: float = CALIBRATION_RANGE_M) -> float:
    """Metres of these scans per metre of a limit written for the calibration sonar: the largest of 1
    and every scan's ``bin_size_m / bin_m`` and ``max_range_m / range_m`` (a ratio that is not a finite
    number, from a scan that does not know its range, counts as 1)."""
    ratios = [float(s.bin_size_m) / bin_m for s in scans] + [float(s.max_range_m) / range_m for s in scans]
    return max([1.0] + [r for r in ratios if math.isfinite(r)])


def scaled_lengths(model: BaseModel, unit: float) -> BaseModel:
    """A copy of ``model`` with every float field named ``*_m`` multiplied by ``unit``, in nested models
    too (but not in a nested :class:`SonarScaled` section whose ``scale_to_sonar`` is off); ``model``
    itself when ``unit`` is 1."""
    if unit == 1.0:
        return model
    update: dict[str, object] = {}
    for name, value in model:
        if isinstance(value, SonarScaled) and not value.scale_to_sonar:
            continue
        if isinstance(value, BaseModel):
            update[name] = scaled_lengths(value, unit)
        elif name.endswith("_m") and isinstance(value, float):
            update[name] = value * unit
    return model.model_copy(update=update)


class SonarScaled(StageParams):
    """Parameters whose lengths (fields named ``*_m``) are written for the calibration sonar and scaled
    to the scans of each match (:meth:`for_scans`)."""

    scale_to_sonar: bool = Field(True, description="multiply every length (a parameter named *_m) by the "
                                 "pair's length unit: the largest of 1, its bin over 0.08 m and its range "
                                 "over 10 m, the settings these lengths were set on; false: lengths in metres as given")

    def for_scans(self, *scans: RangeScan) -> Self:
        """These parameters with their lengths scaled to ``scans`` (:func:`length_unit`); themselves when
        ``scale_to_sonar`` is off or the unit is 1."""
        if not self.scale_to_sonar:
            return self
        return scaled_lengths(self, length_unit(*scans))  # type: ignore[return-value]
