"""What holds each placed scan in place: the converged matches its placement agrees with.

A scan joined to the map only by matches to stations recorded apart from it — a loop closure, such as a
last station back in the first chamber — rests on the one kind of join a look-alike chamber can mislead.
Where every station is placed, the localizer judged that join against the scans of every station (the
site graph refuses a lone scan laid into a look-alike chamber when two of that chamber's stations see
its walls cross their water); where some are unplaced, they could not, and the site's reasons say so
(:func:`cistern_archive.pipeline.status.loop_only_caveat`). On the random cisterns of five tuning runs
(``benchmarks/RESULTS.md``, "2026-12-05 (session 8)") four placed stations of ``partial`` sites were held
so: two misplaced (a return station 7.6 m off in a look-alike chamber, a station 1.75 m off) and two
right (a tunnel station held by the next chamber's, a station whose predecessor was unplaced).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cistern_archive.core.matches import MatchResult
from cistern_archive.core.poses import Poses
from cistern_archive.core.scan import RangeScan
from cistern_archive.pipeline.survey_order import SurveyOrder

AGREE_M = 0.3
"""A converged match holds its two scans in place when the solution puts them within this of the match's
displacement (the site graph's own cycle tolerance is 0.2 m plus the heading's share)."""


def holding_matches(matches: Sequence[MatchResult], poses: Poses, tolerance_m: float = AGREE_M) -> dict[int, set[int]]:
    """For each placed scan, the placed scans a converged match joins it to within ``tolerance_m`` of the
    solution (a match's displacement is the second scan's position minus the first's, in the map frame)."""
    xy = np.asarray(poses.xy_m, dtype=float)
    placed = np.asarray(poses.placed, dtype=bool)
    held: dict[int, set[int]] = {int(k): set() for k in np.flatnonzero(placed)}
    for m in matches:
        if not (m.converged and 0 <= m.i < len(placed) and 0 <= m.j < len(placed) and m.i != m.j
                and placed[m.i] and placed[m.j] and math.isfinite(m.dx_m) and math.isfinite(m.dy_m)):
            continue
        if math.hypot(*(xy[m.j] - xy[m.i] - (m.dx_m, m.dy_m))) <= tolerance_m:
            held[m.i].add(m.j)
            held[m.j].add(m.i)
    return held


def held_by_loops_only(scans: Sequence[RangeScan], matches: Sequence[MatchResult], poses: Poses
                       ) -> list[tuple[int, list[int]]]:
    """The placed scans whose every holding match (:func:`holding_matches`) joins them to a scan recorded
    two or more places away in the survey's order, each with those scans; scans held by no match (a fit
    of groups, a vertical tie) are not listed: their joins have reasons of their own."""
    survey = SurveyOrder(scans)
    return [(k, sorted(others)) for k, others in sorted(holding_matches(matches, poses).items())
            if others and all(abs(survey.place(k) - survey.place(j)) >= 2 for j in others)]
