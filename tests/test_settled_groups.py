"""site-graph's final check of its groups (``cistern_plugins.settled_groups``): a look-alike chamber joined
through one link is cut off once the chamber is whole, and a right group is left as it is."""

import dataclasses

import gtsam
import numpy as np
import pytest

from cistern_archive.core.matches import MatchResult
from cistern_plugins import site_groups
from cistern_archive.grid.polygon import polygon_scan
from cistern_plugins.factor_graph import Edge
from cistern_plugins.settled_groups import SETTLED_TWO_WAY_SHARE, recheck_groups, runs_of, settled_splits
from cistern_plugins.site_graph import SiteGraphLocalizer, SiteGraphParams
from cistern_plugins.site_groups import Graph, WallCheck

from test_site_graph import niche_room

STATIONS = ["a1", "a2", "b1", "b2", "b3"]
XY = [(1.0, 1.5), (3.0, 1.5), (1.2, 1.2), (2.8, 1.6), (2.0, 2.2)]
"""Stations a1, a2 in one room and b1–b3 in another, each at these coordinates of its own room."""


def two_rooms(room_b):
    """Scans of a 4 m x 3 m room with niches at 0.5 and 2.6 m (a1, a2) and of ``room_b`` (b1–b3), visited
    in that order."""
    rooms = [niche_room([0.5, 2.6])] * 2 + [room_b] * 3
    return [dataclasses.replace(polygon_scan([rooms[k]], XY[k], 0.0, rng=np.random.default_rng(k), n_beams=400,
                                             max_range_m=6.0, range_noise_m=0.01), station=STATIONS[k])
            for k in range(5)]


def laid_on_first(scans):
    """One group with the second room laid exactly onto the first, joined by the link a2–b1 only."""
    pose = [gtsam.Pose2(x, y, 0.0) for x, y in XY]
    edges = [Edge(i, j, np.array([XY[j][0] - XY[i][0], XY[j][1] - XY[i][1], 0.0]), np.eye(3) * 1e-4)
             for i, j in ((0, 1), (1, 2), (2, 3), (3, 4))]
    return Graph(edges=edges, ties=[], group=[0] * 5, pose=pose)


def test_runs_are_every_stretch_of_the_survey_against_the_rest():
    splits = list(runs_of([0, 1, 3]))
    assert ([0], [1, 3]) in splits and ([1, 3], [0]) in splits and ([1], [0, 3]) in splits
    assert all(run and rest for run, rest in splits) and len(splits) == 5  # never the whole group


def test_a_look_alike_room_laid_on_the_first_is_cut_off_whole():
    """Rooms alike but for where their niches lie, the second laid onto the first by one link: over the
    six pairs of the two rooms each sonar puts walls into the other's water, so the smaller part (the
    first room's two stations) leaves the group, the link is rejected, and the reason names the run."""
    scans = two_rooms(niche_room([1.5, 3.2]))
    graph = laid_on_first(scans)
    walls = WallCheck(scans, SiteGraphParams())
    worst = max(settled_splits(walls, graph, {}), key=lambda s: s.conflicts)
    assert sorted(worst.run + worst.rest) == list(range(5)) and len(worst.sharing) == 6
    assert worst.share > SETTLED_TWO_WAY_SHARE
    across = recheck_groups(graph, walls)
    assert graph.group[0] == graph.group[1] != graph.group[2] == graph.group[3] == graph.group[4]
    assert [(e.i, e.j) for e in graph.edges] == [(0, 1), (2, 3), (3, 4)]
    why = graph.cut[0]
    assert "a1 … a2" in why and "look-alike chamber laid onto another" in why and graph.cut[1] == why
    assert graph.rejected[(1, 2)].startswith("joins the stations a1 … a2 to the rest of their group")
    assert set(across) == {frozenset((a, b)) for a in (0, 1) for b in (2, 3, 4)}


def test_a_room_laid_on_itself_stays_whole():
    scans = two_rooms(niche_room([0.5, 2.6]))
    graph = laid_on_first(scans)
    walls = WallCheck(scans, SiteGraphParams())
    assert max(s.share for s in settled_splits(walls, graph, {})) <= SETTLED_TWO_WAY_SHARE
    assert recheck_groups(graph, walls) == {} and set(graph.group) == {0} and len(graph.edges) == 4


def test_a_part_its_own_edges_do_not_hold_together_is_not_cut_off():
    """Each station of the second room joined to a2 alone: the second room's stations are held only by
    the first room's, so no split judged (five pairs sharing walls or more) has both parts held together
    by their own edges, and nothing is cut."""
    scans = two_rooms(niche_room([1.5, 3.2]))
    graph = laid_on_first(scans)
    graph.edges = [Edge(i, j, np.array([XY[j][0] - XY[i][0], XY[j][1] - XY[i][1], 0.0]), np.eye(3) * 1e-4)
                   for i, j in ((0, 1), (1, 2), (1, 3), (1, 4))]
    assert recheck_groups(graph, WallCheck(scans, SiteGraphParams())) == {}
    assert set(graph.group) == {0}


def match(i, j, scans_xy, *, dx=0.0):
    """A converged, confident match of scan ``j`` in scan ``i``'s frame at the given coordinates (plus ``dx``)."""
    (xi, yi), (xj, yj) = scans_xy[i], scans_xy[j]
    return MatchResult(i, j, xj - xi + dx, yj - yi, 0.0, 1.0, True, 10, 0.01, covariance=np.eye(3) * 1e-4,
                       confidence=0.95)


@pytest.mark.parametrize("look_alike", [True, False])
def test_localize_leaves_the_smaller_part_unplaced_with_the_reason(look_alike, monkeypatch):
    """Through the localizer: the survey's chain a1–a2–b1–b2–b3, every link matched both ways, the link
    a2–b1 laying the second room onto the first. Alike but for the niches, the two stations of the first
    room are left unplaced with the reason; alike in every wall, the five stations stay placed. The
    join of b1 alone onto the first room is refused at once, a1 and a2 each seeing its niche cross their
    water; with a lone scan's views counted as one (as before), the whole rooms are judged once joined
    and the smaller part is cut off."""
    scans = two_rooms(niche_room([1.5, 3.2] if look_alike else [0.5, 2.6]))
    matches = [m for i in range(4) for m in (match(i, i + 1, XY), match(i + 1, i, XY))]
    poses = SiteGraphLocalizer().localize(scans, matches, SiteGraphParams())
    if not look_alike:
        assert poses.placed.all()
        return
    assert poses.placed.tolist() == [False, False, True, True, True]
    assert "as one chamber's opening laid onto a look-alike's solid wall" in poses.reasons[0]
    monkeypatch.setattr(site_groups, "lone_scan", lambda *args: None)
    poses = SiteGraphLocalizer().localize(scans, matches, SiteGraphParams())
    assert poses.placed.tolist() == [False, False, True, True, True]
    assert poses.reasons[0].startswith("no consistent chain of matches to the reference station b1: the stations "
                                       "a1 … a2, visited one after another")
