"""The survey's order: the scans as they were recorded, whatever order the record lists them in.

Localizers chain scans by their order: the paper's WLS matches neighbours (McVicker et al. Table I), the
pose graph every pair within a window, and the site graph trusts the survey's chain more than a loop
closure and fits groups of scans as wholes only where the survey visited them one after the other. A
catalog may list its stations in another order — sorted by label, or as the team wrote them up. Where
every scan has a time of its own, the survey's order is the order of those times; otherwise it is the
order of the list. The runner hands every localizer its scans and matches in that order through
:class:`SurveyOrder` (:func:`cistern_archive.pipeline.runner.match_rounds` and
:func:`~cistern_archive.pipeline.runner.localize`) and takes its pairs and poses back into the record's
order, so no localizer, built-in or third-party, needs to know.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from cistern_archive.core.matches import MatchResult
from cistern_archive.core.poses import Poses
from cistern_archive.core.scan import RangeScan
from cistern_archive.pipeline.status import label_indices


def recording_order(scans: Sequence[RangeScan]) -> tuple[int, ...] | None:
    """The scans' indices in the order they were recorded, or ``None`` when that is the order given (or
    cannot be told: a scan without a time, or two scans with the same time)."""
    times = [float(s.time_s) for s in scans]
    if len(times) < 2 or not all(math.isfinite(t) for t in times) or len(set(times)) < len(times):
        return None
    order = tuple(sorted(range(len(times)), key=times.__getitem__))
    return None if order == tuple(range(len(times))) else order


class SurveyOrder:
    """Scans renumbered into the order they were recorded (:func:`recording_order`): ``scans`` and
    :meth:`matches` in that order, :meth:`pairs_back` and :meth:`poses_back` in the record's again. Where
    the record lists the scans as recorded, every method hands its input back unchanged."""

    def __init__(self, scans: Sequence[RangeScan]):
        self.order = recording_order(scans)
        if self.order is None:
            self.scans = list(scans)
            return
        self.scans = [scans[k] for k in self.order]
        self.rank = np.empty(len(self.order), dtype=np.int64)
        self.rank[list(self.order)] = np.arange(len(self.order))

    def matches(self, matches: Sequence[MatchResult]) -> list[MatchResult]:
        """``matches`` with their scan indices in the survey's order (an index of no scan stays as it is,
        for the localizer to pass over)."""
        if self.order is None:
            return list(matches)
        return [replace(m, i=self.place(m.i), j=self.place(m.j)) for m in matches]

    def place(self, k: int) -> int:
        """Scan ``k``'s place in the survey's order (``k`` itself where the record lists the scans as
        recorded, or for an index of no scan)."""
        if self.order is None:
            return k
        return int(self.rank[k]) if 0 <= k < len(self.rank) else k

    def pairs_back(self, pairs: Sequence[tuple]) -> list[tuple]:
        """Pairs ``(i, j, …)`` of the survey's order with the record's indices."""
        if self.order is None:
            return list(pairs)
        return [(self.order[i], self.order[j], *rest) for i, j, *rest in pairs]

    def poses_back(self, poses: Poses) -> Poses:
        """Poses of the survey's order in the record's; scan indices in their reasons (``scan 3``,
        ``(3,4)``) are given as station labels (:func:`~cistern_archive.pipeline.status.label_indices`),
        as they would mean other scans in the record's order."""
        if self.order is None:
            return poses
        to_record = np.asarray(self.order)
        labels = [s.station for s in self.scans]

        def back(values: np.ndarray) -> np.ndarray:
            out = np.empty_like(values)
            out[to_record] = values
            return out

        return replace(
            poses, xy_m=back(poses.xy_m), yaw_rad=back(poses.yaw_rad), placed=back(poses.placed),
            reasons=tuple(back(np.array([label_indices(r, labels) for r in poses.reasons], dtype=object))),
            reference=int(to_record[poses.reference]) if poses.reference >= 0 else -1,
            covariance=None if poses.covariance is None else back(poses.covariance),
            group_links=tuple((int(to_record[i]), int(to_record[j])) for i, j in poses.group_links),
        )
