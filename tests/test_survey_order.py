"""The survey's order: scans listed out of the order they were recorded in are chained by their times,
by every localizer (the runner hands them the scans as recorded and takes their pairs and poses back)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from cistern_archive.core.matches import MatchResult
from cistern_archive.core.poses import Poses
from cistern_archive.core.scan import RangeScan
from cistern_archive.pipeline.registry import default_registry
from cistern_archive.pipeline.runner import localize, match_rounds, resolve_stage
from cistern_archive.pipeline.survey_order import SurveyOrder, recording_order

TRUTH = np.array([[0.0, 0.0], [1.5, 0.0], [3.0, 0.5], [4.5, 0.2], [6.0, 0.0]])
LISTED = [3, 0, 4, 1, 2]  # the record lists the stations s4, s1, s5, s2, s3; they were visited s1 … s5
TIMES = [30.0, 0.0, 40.0, 10.0, 20.0]
NEIGHBOURS_IN_TIME = {(0, 1), (1, 0), (1, 2), (2, 1), (2, 3), (3, 2), (3, 4), (4, 3)}


def _scans(times):
    return [RangeScan(np.zeros(3), np.ones(3), 0.0, 1.0, 5.0, 0.05, 0.05, station=f"s{v + 1}", time_s=t)
            for v, t in zip(LISTED, times)]


def _match(i, j, converged=True):
    d = TRUTH[LISTED[j]] - TRUTH[LISTED[i]]
    return MatchResult(i, j, float(d[0]), float(d[1]), 0.0, 1.0, converged, 1, 0.0,
                       reason="" if converged else "ambiguous, a second peak")


def test_the_recording_order_needs_a_time_of_its_own_for_every_scan():
    assert recording_order(_scans(TIMES)) == (1, 3, 4, 0, 2)
    assert recording_order(_scans([0.0, 10.0, 20.0, 30.0, 40.0])) is None  # listed as recorded
    assert recording_order(_scans([30.0, math.nan, 40.0, 10.0, 20.0])) is None
    assert recording_order(_scans([30.0, 10.0, 40.0, 10.0, 20.0])) is None


@pytest.mark.parametrize(("name", "params"), [("wls", {"third_scan": False}), ("pose-graph", {"window": 1}),
                                              ("site-graph", {})])
def test_every_localizer_chains_the_scans_as_recorded_and_places_them_in_the_records_order(name, params):
    stage = resolve_stage(default_registry(), "localizer", name, params)
    scans = _scans(TIMES)
    asked = []

    def run_pair(i, j, guess):
        asked.append((LISTED[i], LISTED[j]))
        return _match(i, j)

    matches = match_rounds(scans, stage, run_pair)
    assert set(asked[:len(NEIGHBOURS_IN_TIME)]) == NEIGHBOURS_IN_TIME  # the chain first (the site graph asks more)
    poses = localize(stage, scans, matches)
    assert poses.placed.all()
    first = LISTED.index(0)  # s1, where TRUTH starts
    np.testing.assert_allclose(poses.xy_m - poses.xy_m[first], TRUTH[LISTED], atol=1e-6)
    if name == "wls":  # it places along the chain only: without the times, s4 → s1 is the chain's first link
        assert not localize(stage, [replace(s, time_s=math.nan) for s in scans], matches).placed.all()


def test_a_survey_order_renumbers_matches_and_back():
    survey = SurveyOrder(_scans(TIMES))
    assert [s.station for s in survey.scans] == ["s1", "s2", "s3", "s4", "s5"]
    moved = survey.matches([_match(0, 1)])[0]
    assert (moved.i, moved.j) == (3, 0)
    assert survey.pairs_back([(3, 0, None)]) == [(0, 1, None)]
    stray = survey.matches([replace(_match(0, 1), i=-1, j=7)])[0]
    assert (stray.i, stray.j) == (-1, 7)  # an index of no scan is left for the localizer to pass over


def test_reasons_naming_scans_of_the_survey_order_come_back_as_station_labels():
    survey = SurveyOrder(_scans(TIMES))
    n = 5
    reasons = ("",) * 4 + ("no converged path to reference scan 0: (3,4): ambiguous",)
    solved = Poses(np.zeros((n, 2)), np.zeros(n), np.array([True] * 4 + [False]), reasons, 0)
    back = survey.poses_back(solved)
    assert back.reasons[2] == "no converged path to reference scan s1: (s4 → s5): ambiguous"  # s5 is listed third
    assert not back.placed[2] and back.reference == 1


def test_a_scan_held_only_by_matches_to_scans_recorded_apart_from_it_is_found():
    """s5 (recorded last) joined only to s1 and s2, a loop closure; s3 and s4 (recorded before it) joined
    to their neighbours in time; a match the solution disagrees with holds nothing."""
    from cistern_archive.pipeline.support import held_by_loops_only, holding_matches

    scans = _scans(TIMES)
    record = {f"s{v + 1}": k for k, v in enumerate(LISTED)}  # station -> index in the list
    xy = np.array([TRUTH[v] for v in LISTED])
    poses = Poses(xy, np.zeros(5), np.ones(5, dtype=bool), ("",) * 5, record["s1"])
    links = [("s1", "s2"), ("s2", "s3"), ("s3", "s4"), ("s5", "s1"), ("s2", "s5")]
    matches = [_match(record[a], record[b]) for a, b in links]
    wrong = _match(record["s4"], record["s5"])
    matches.append(replace(wrong, dx_m=wrong.dx_m + 1.0))  # 1 m off the solution: holds nothing
    assert holding_matches(matches, poses)[record["s5"]] == {record["s1"], record["s2"]}
    assert held_by_loops_only(scans, matches, poses) == [(record["s5"], sorted([record["s1"], record["s2"]]))]
    matches.append(_match(record["s4"], record["s5"]))  # now its predecessor in time holds it too
    assert held_by_loops_only(scans, matches, poses) == []
