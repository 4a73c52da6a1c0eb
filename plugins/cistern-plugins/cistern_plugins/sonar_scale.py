"""Lengths of a matcher's parameters scaled to the sonar that took the scans.

A matcher's lengths — the inlier distance, the free-space margin, the precision a fit must reach, a
likelihood's width, a search's lattice — are written for the sonars and sites they were tuned,
calibrated and tested on: Micron-class heads with bins of 0.04–0.05 m in cisterns whose walls lie
within 10 m (:data:`CALIBRATION_BIN_M`, :data:`CALIBRATION_RANGE_M`). Coarser bins or farther walls
are seen less sharply: a wall's echo spreads over more range, the points a sonar lays along a wall lie
farther apart (one per beam: the wall's range times the step), and a heading error moves a far wall
farther. The same limits in metres then refuse every right match of a harbour sonar hearing quays
20–50 m off with 0.1 m bins.

:func:`length_unit` is how many metres of a pair one metre of those limits is: the largest of 1, each
scan's bin over :data:`CALIBRATION_BIN_M` and the range of its farther echoes (:func:`wall_range_m`)
over :data:`CALIBRATION_RANGE_M`. It is never less than 1 — finer settings and nearer walls keep the
limits as set, since they also carry the compass's noise and the chambers' shapes. It follows the
walls, not the range setting: a cistern scanned at 20 m instead of 10 m hears the same walls, and
lengths doubled there matched it worse (``benchmarks/RESULTS.md``). :class:`SonarScaled` parameters
multiply every length (a field named ``*_m``, in nested sections too) by it before a match. On every
scan with bins of 0.05 m or less at a range setting of 10 m or less the unit is exactly 1 and nothing
changes.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Self, TypeVar

import numpy as np
from pydantic import BaseModel, Field

from cistern_archive.core.scan import RangeScan
from cistern_archive.pipeline.contracts import StageParams

T = TypeVar("T")

CALIBRATION_BIN_M = 0.05
"""Coarsest range bin the built-in matchers' lengths were set on: 0.04 m (the physical simulator's 10 m
over 250) and 0.05 m (the ideal-ray pairs). Random cisterns drawn three times as large in every length
(``benchmarks/sites.py --random 20 --seed 2 --generator '{"scale": 3.0}'``, 0.12 m bins) matched
85.2 % of their pairs with half their view shared within 0.10 m with this reference against 76.7 %
with 0.08 m, and 87.1 % with every length tripled; random cisterns of the usual size with 0.08 m bins,
92.3 and 91.8 % unscaled and scaled by 1.6 (``--generator '{"bin_m": 0.08}'``, seed 2;
``benchmarks/RESULTS.md``)."""
CALIBRATION_RANGE_M = 10.0
"""Range of the farther echoes (:func:`wall_range_m`) up to which the lengths hold as set: the demo and
random cisterns' range settings (6, 8 and 10 m) bound it. The 347 scans of 40 random sites (seed 2)
scanned at a 20 m setting reach 8.7 m: those sites keep the limits as set."""
WALL_RANGE_PERCENTILE = 90.0
"""The percentile of a scan's echo ranges that :func:`wall_range_m` reports: the far walls a match has to
place, above the few ghosts and spikes beyond them."""


def wall_range_m(scan: RangeScan) -> float:
    """How far a scan's farther walls lie: the :data:`WALL_RANGE_PERCENTILE` of its echo ranges (0 without
    an echo)."""
    ranges = np.asarray(scan.ranges_m, dtype=np.float64)
    ranges = ranges[np.isfinite(ranges)]
    return float(np.percentile(ranges, WALL_RANGE_PERCENTILE)) if ranges.size else 0.0


def length_unit(*scans: RangeScan, bin_m: float = CALIBRATION_BIN_M, range_m: float = CALIBRATION_RANGE_M) -> float:
    """Metres of these scans per metre of a limit written for the calibration sonar: the largest of 1
    and every scan's ``bin_size_m / bin_m`` and ``wall_range_m(scan) / range_m`` (a bin that is not a
    finite number counts as 1)."""
    ratios = [float(s.bin_size_m) / bin_m for s in scans] + [wall_range_m(s) / range_m for s in scans]
    return max([1.0] + [r for r in ratios if math.isfinite(r)])


def site_length_unit(scans: Sequence[RangeScan], range_m: float = CALIBRATION_RANGE_M) -> float:
    """Metres of a site per metre of a length written for the calibration sites: the median over its
    scans of the range of each one's farther echoes (:func:`wall_range_m`) over ``range_m``, each at
    least 1 (1 without scans).

    A site's lengths — how much wall a join may lay across water, where a look-alike chamber's tunnel
    mouth lands on solid wall, a group fit's cells — are the size of its chambers and openings, so they
    follow its walls, not its bins: with the matchers' unit (coarser bins too), random cisterns of the
    usual size heard with 0.08 m bins at the usual pulse (``benchmarks/sites.py --random 40 --seed 2
    --generator '{"bin_m": 0.08}'``) let the wall check accept a look-alike chamber 6.6 m off, its
    stretch of wall across water allowed 1.2 m where the tunnels are 0.8–1.2 m wide. The median
    follows the site's usual scan, not the one that looked down the longest gallery."""
    units = [max(1.0, wall_range_m(s) / range_m) for s in scans]
    return float(np.median(units)) if units else 1.0


def scaled_lengths(model: T, unit: float) -> T:
    """A copy of ``model`` (a pydantic model or a dataclass) with every float field named ``*_m``
    multiplied by ``unit``, in nested models too (but not in a nested :class:`SonarScaled` section whose
    ``scale_to_sonar`` is off); ``model`` itself when ``unit`` is 1."""
    if unit == 1.0:
        return model
    if dataclasses.is_dataclass(model):
        return dataclasses.replace(model, **{f.name: getattr(model, f.name) * unit for f in dataclasses.fields(model)
                                             if f.name.endswith("_m") and isinstance(getattr(model, f.name), float)})
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
                                 "pair's length unit: the largest of 1, its bin over 0.05 m and the range of "
                                 "its farther echoes (90th percentile) over 10 m, the settings these lengths "
                                 "were set on; false: lengths in metres as given")

    def for_scans(self, *scans: RangeScan) -> Self:
        """These parameters with their lengths scaled to ``scans`` (:func:`length_unit`); themselves when
        ``scale_to_sonar`` is off or the unit is 1."""
        if not self.scale_to_sonar:
            return self
        return scaled_lengths(self, length_unit(*scans))
