"""The survey's order: scans listed out of the order they were recorded in are chained by their times."""

import math
from dataclasses import replace

import numpy as np

from cistern_archive.core.matches import MatchResult
from cistern_archive.core.scan import RangeScan
from cistern_plugins.site_graph import SiteGraphLocalizer, SiteGraphParams
from cistern_plugins.survey_order import SurveyOrder, recording_order

TRUTH = np.array([[0.0, 0.0], [1.5, 0.0], [3.0, 0.5], [4.5, 0.2], [6.0, 0.0]])
LISTED = [3, 0, 4, 1, 2]  # the record lists the stations s4, s1, s5, s2, s3; they were visited s1 … s5


def _scans(times):
    return [RangeScan(np.zeros(3), np.ones(3), 0.0, 1.0, 5.0, 0.05, 0.05, station=f"s{v + 1}", time_s=t)
            for v, t in zip(LISTED, times)]


def _match(i, j, converged=True):
    d = TRUTH[LISTED[j]] - TRUTH[LISTED[i]]
    return MatchResult(i, j, float(d[0]), float(d[1]), 0.0, 1.0, converged, 1, 0.0,
                       reason="" if converged else "ambiguous, a second peak")


def test_the_recording_order_needs_a_time_of_its_own_for_every_scan():
    assert recording_order(_scans([30.0, 0.0, 40.0, 10.0, 20.0])) == (1, 3, 4, 0, 2)
    assert recording_order(_scans([0.0, 10.0, 20.0, 30.0, 40.0])) is None  # listed as recorded
    assert recording_order(_scans([30.0, math.nan, 40.0, 10.0, 20.0])) is None
    assert recording_order(_scans([30.0, 10.0, 40.0, 10.0, 20.0])) is None


def test_neighbours_in_time_are_matched_first_and_the_poses_come_back_in_the_records_order():
    loc, p = SiteGraphLocalizer(), SiteGraphParams()
    scans = _scans([30.0, 0.0, 40.0, 10.0, 20.0])
    first = loc.guided_pairs(scans, [], p)
    visited = {(LISTED[i], LISTED[j]) for i, j, _ in first}
    assert visited == {(0, 1), (1, 0), (1, 2), (2, 1), (2, 3), (3, 2), (3, 4), (4, 3)}
    poses = loc.localize(scans, [_match(i, j) for i, j, _ in first], p)
    assert poses.placed.all() and scans[poses.reference].station == "s1"
    np.testing.assert_allclose(poses.xy_m - poses.xy_m[poses.reference], TRUTH[LISTED], atol=1e-6)
    as_listed = loc.localize([replace(s, time_s=math.nan) for s in scans], [_match(i, j) for i, j, _ in first], p)
    assert not as_listed.placed.all()  # without the times, s4 → s1 and s1 → s5 are not the survey's chain


def test_a_survey_order_renumbers_matches_and_back():
    survey = SurveyOrder(_scans([30.0, 0.0, 40.0, 10.0, 20.0]))
    assert [s.station for s in survey.scans] == ["s1", "s2", "s3", "s4", "s5"]
    moved = survey.matches([_match(0, 1)])[0]
    assert (moved.i, moved.j) == (3, 0)
    assert survey.pairs_back([(3, 0, None)]) == [(0, 1, None)]
    stray = survey.matches([replace(_match(0, 1), i=-1, j=7)])[0]
    assert (stray.i, stray.j) == (-1, 7)  # an index of no scan is left for the localizer to pass over
