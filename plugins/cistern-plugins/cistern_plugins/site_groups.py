"""The groups of site-graph's consensus: cycle support, sequence-link order, the consistent clusters that
join two groups, the wall check that refuses a join putting walls into water, and the reasons of the
scans left apart (steps 1–2 of :mod:`cistern_plugins.site_graph`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import gtsam
import numpy as np

from cistern_archive.core.levels import depth_levels
from cistern_archive.core.matches import MatchResult
from cistern_archive.core.scan import RangeScan, wrap_angle
from cistern_plugins.alignment import AlignmentQuality, ConvergenceThresholds, ReferenceModel
from cistern_plugins.factor_graph import Edge
from cistern_plugins.group_clouds import Cloud, placed_spread, wall_spread
from cistern_plugins.content_cache import ContentCache, scans_digest
from cistern_plugins.group_fit import GroupFit, about, accept, fit_groups, pose_key
from cistern_plugins.sonar_scale import scaled_lengths

if TYPE_CHECKING:  # pragma: no cover
    from cistern_plugins.site_graph import SiteGraphParams


def pose_array(pose: gtsam.Pose2) -> np.ndarray:
    """``(x, y, theta)`` of a pose, as the alignment helpers take it."""
    return np.array([pose.x(), pose.y(), pose.theta()])


def scan_levels(scans: Sequence[RangeScan], p: SiteGraphParams) -> tuple[int, ...]:
    """The depth level of each scan (:func:`~cistern_archive.core.levels.depth_levels`; ``-1`` for a scan
    of unknown depth): only scans of one level see the same walls and may be matched."""
    return depth_levels([s.depth_m for s in scans], p.level_tolerance_m)


def same_level(levels: Sequence[int], i: int, j: int) -> bool:
    """Whether scans ``i`` and ``j`` lie at one depth level of ``levels`` (:func:`scan_levels`); a scan of
    unknown depth counts as on every level."""
    return levels[i] == levels[j] or -1 in (levels[i], levels[j])


@dataclass
class Graph:
    """Where the consensus left the site: accepted edges, groups, poses within each group, and why
    each rejected match was rejected."""

    edges: list[Edge]
    ties: list[Edge]
    group: list[int]
    pose: list[gtsam.Pose2]
    rejected: dict[tuple[int, int], str] = field(default_factory=dict)
    unjoined: dict[int, str] = field(default_factory=dict)
    """Why the group fit did not join a scan's group to the reference's (by scan)."""
    cut: dict[int, str] = field(default_factory=dict)
    """Why a scan was cut off its group once the group was whole (by scan;
    :mod:`cistern_plugins.settled_groups`): said first of an unplaced scan."""
    fitted: list[tuple[int, int]] = field(default_factory=list)
    """The scans of each join by a group fit (the edge's two ends)."""

    def members(self, g: int) -> list[int]:
        return [k for k, h in enumerate(self.group) if h == g]


def cycle_support(edges: Sequence[Edge], strong: Sequence[bool], p: SiteGraphParams) -> list[int]:
    """For every edge, how many consistent cycles it closes: an agreeing reverse match and every
    consistent triangle of edges (module docstring, step 2). A tentative edge (``strong`` false) counts
    only the cycles in which another edge is a converged match: tentative matches cannot vouch for each
    other (two matches of a scan pair that both fell for the same look-alike place agree too)."""
    rel: dict[tuple[int, int], list[tuple[int, gtsam.Pose2]]] = {}
    for k, e in enumerate(edges):
        z = gtsam.Pose2(*e.z)
        rel.setdefault((e.i, e.j), []).append((k, z))
        rel.setdefault((e.j, e.i), []).append((k, z.inverse()))
    support = [0] * len(edges)

    def credit(cycle: Sequence[int]) -> None:
        for k in cycle:
            if strong[k] or any(strong[k2] for k2 in cycle if k2 != k):
                support[k] += 1

    for k, e in enumerate(edges):
        z = gtsam.Pose2(*e.z)
        for k2, back in rel.get((e.i, e.j), []):
            if k2 > k and close_enough(z.between(back), p, z):
                credit((k, k2))
    nodes = sorted({a for a, _ in rel})
    for a in nodes:
        for b in nodes:
            if b <= a or (a, b) not in rel:
                continue
            for c in nodes:
                if c <= b or (b, c) not in rel or (a, c) not in rel:
                    continue
                for kab, zab in rel[(a, b)]:
                    for kbc, zbc in rel[(b, c)]:
                        for kac, zac in rel[(a, c)]:
                            if len({kab, kbc, kac}) == 3 and close_enough(zab.compose(zbc).between(zac), p, zac):
                                credit((kab, kbc, kac))
    return support


def close_enough(residual: gtsam.Pose2, p: SiteGraphParams, span: gtsam.Pose2) -> bool:
    """Whether a cycle's residual motion is within tolerance; the heading tolerance's lever arm over the
    span of the cycle is allowed in translation."""
    lever = math.hypot(span.x(), span.y()) * math.sin(math.radians(p.consistency_deg))
    return (math.hypot(residual.x(), residual.y()) <= p.consistency_m + lever
            and abs(wrap_angle(residual.theta())) <= math.radians(p.consistency_deg))


def frame_offset(graph: Graph, e: Edge) -> gtsam.Pose2:
    """Where edge ``e`` puts the group of ``e.j`` in the frame of the group of ``e.i``."""
    return graph.pose[e.i].compose(gtsam.Pose2(*e.z)).compose(graph.pose[e.j].inverse())


def best_cluster(graph: Graph, scans: Sequence[RangeScan], edges: Sequence[Edge], support: Sequence[int],
                  bridges: Sequence[bool], pending: Sequence[int], p: SiteGraphParams, loop_closures: bool,
                  moments: Sequence[tuple[np.ndarray, int]]):
    """The largest-consensus cluster of pending edges between two groups that holds at least one edge
    allowed to join two groups (``bridges``: confident loop closures, or sequence links), as (edge
    indices, (i, j, z)) ready for :func:`_merge`, or ``None`` when there is none. Other matches never
    join two groups on their own: every scan of a look-alike chamber matches into the same wrong place,
    so such bridges to one group corroborate each other. With ``loop_closures``, a cluster that joins
    two groups of several scans each (at the depth level of the other group: :func:`several_each_side`)
    must hold bridges from two stations on each side (:func:`seen_from_two_stations`), and neither group
    may be a passage seen from inside (:func:`passage_only`, from the scans' ``moments``): it waits until
    its own survey chain has joined it to more."""
    by_pair: dict[tuple[int, int], list[tuple[int, gtsam.Pose2]]] = {}
    for k in pending:
        e = edges[k]
        gi, gj = graph.group[e.i], graph.group[e.j]
        if gi == gj:
            continue
        offset = frame_offset(graph, e)
        key, offset = ((gi, gj), offset) if gi < gj else ((gj, gi), offset.inverse())
        by_pair.setdefault(key, []).append((k, offset))
    best, best_score = None, -1.0
    for (ga, gb), items in sorted(by_pair.items()):
        if loop_closures and any(passage_only(graph, moments, g, p) for g in (ga, gb)):
            continue
        for k, offset in items:
            members = [k2 for k2, o2 in items if close_enough(offset.between(o2), p, offset)]
            if not any(bridges[k2] for k2 in members):
                continue
            if loop_closures and several_each_side(graph, scans, ga, gb, p) \
                    and not seen_from_two_stations(graph, [edges[k2] for k2 in members if bridges[k2]], ga):
                continue
            score = sum(1 + support[k2] for k2 in members)
            if score > best_score:
                best_score = score
                best = (members, ga, gb, offset)
    if best is None:
        return None
    members, ga, gb, offset = best
    anchor_a = graph.members(ga)[0]
    anchor_b = graph.members(gb)[0]
    z = graph.pose[anchor_a].inverse().compose(offset).compose(graph.pose[anchor_b])
    return members, (anchor_a, anchor_b, z)


BACK_TO_BACK_PAIRS = 2
"""Pairs of scans of a join laying their walls back to back (:meth:`WallCheck.conflict`) from which the
join is refused. A wrong join that sets two chambers side by side does so for every pair of scans that
sees the common wall; a right one can do so for one pair, where a wall's normal at a corner, seen far off
and at a glance, points the wrong way. Over the 1,926 judgements of right joins and 23 of wrong ones on
40 random cisterns of each of seeds 2 and 4 (``benchmarks/wall_tests.py --random 40 --seeds 2,4``), no
right join has such a pair, and the wrong joins with such points have 2 and 31 (51 and 136 points).
While a tunnel's side walls ending on a chamber's wall beside its mouth counted as laid on it from
behind (:func:`~cistern_plugins.alignment.parallel_walls`), right joins had up to 44 such points, and a
join placed a few centimetres off along the tunnel could have two such pairs and be refused."""

TWO_WAY_SHARE = 0.02
"""Median share, over the pairs of a join that share ``min_inliers`` or more wall points (at least
:data:`TWO_WAY_PAIRS` of them), of the wall points each sonar of a pair puts into the other's water, the
smaller of the two directions (``AlignmentQuality.violation_min``), from which the join is refused. A
right join leaves stray points in water one way (a wall seen edge-on, a view through an opening); two
look-alike chambers laid one onto the other a little off put walls into water both ways for nearly every
pair. Over the 218 right joins with five such pairs or more judged on 40 random cisterns of each of
seeds 2 and 4 this median was at most 0.3 %; the wrong join of that kind (4.5 m off, 9–24 pairs with
220–280 inliers and stretches of 0.4–0.7 m, under the run limit) had 2.9–3.1 %."""
TWO_WAY_PAIRS = 5
"""A median over fewer pairs is not "nearly every pair": with three pairs, right joins reached 0.7 %
on those seeds, and 2.2–2.4 % on the same sites drawn with 20 % multipath echoes."""


CORROBORATED_RUN_M = 0.22
"""A stretch of wall in a row across another scan's water that counts towards a corroborated conflict
(:func:`corroborated_runs`). One chamber's tunnel mouth (0.8–1.2 m wide) laid onto a look-alike's solid
wall shows, from each scan that looks through the mouth, as a stretch shorter than the opening (the
beams' cones eat its edges, a slanting view sees part of it): under the single-pair limit
``max_violation_run_m`` (0.75 m), which must stay above what one pair's noise gives, but seen from several
stations apart. Set between what right and wrong joins show from their second pair sharing no scan
with the first (``benchmarks/wall_tests.py --random 40 --seeds 2,4`` and ``--seeds 5,6,7,8``: 5,819
judgements of right joins, at most 0.18 m; 40 of wrong ones, 0 or 0.27–0.66 m)."""
CORROBORATED_PAIRS = 2
"""Pairs of a join, no two sharing a scan, each laying more than :data:`CORROBORATED_RUN_M` of wall in a
row across the other's water, from which the join is refused. Over the joins judged on 40 random
cisterns of each of seeds 2, 4–8 (the same runs), no right join had two such pairs (17 had one); 30 of
the 40 judgements of wrong ones had two to four, among them a middle chamber laid onto the first, 8.5 m
off, that every other test let through. At their true poses, the 14,038 pairs of those sites within
range lay at most 0.29 m, and 99.9 % of them at most 0.22 m (``benchmarks/RESULTS.md``,
"2026-12-05 (session 4)")."""


def corroborated_runs(pairs: Sequence[JoinPair], min_run_m: float, lone: int | None = None
                      ) -> list[tuple[float, int, int]]:
    """The pairs of a join that lay more than ``min_run_m`` of wall in a row across the other's water,
    longest first, no two sharing a scan (a scan with one odd beam conflicts with every scan of the other
    group; independent views of the same conflict do not share one): ``(run, a, b)`` each. A join of a
    ``lone`` scan (a group of one) has no second scan on its side: there the views are the other
    group's scans, each of which sees the lone scan's walls from its own place, and only they must differ."""
    chosen: list[tuple[float, int, int]] = []
    used: set[int] = set()
    for run, a, b in sorted(((p.quality.violation_run_m, p.a, p.b) for p in pairs), reverse=True):
        if run <= min_run_m:
            break
        if not ({a, b} - {lone}) & used:
            chosen.append((run, a, b))
            used |= {a, b} - {lone}
    return chosen


def lone_scan(graph: Graph, i: int, j: int) -> int | None:
    """The scan of the join of ``j``'s group into ``i``'s that is a group by itself (``j`` first), or
    ``None``: :func:`corroborated_runs` counts the views of a lone scan's walls by the other group's scans."""
    return next((k for k in (j, i) if len(graph.members(graph.group[k])) == 1), None)


def sharing_pairs(pairs: Sequence[JoinPair], limits: ConvergenceThresholds) -> list[JoinPair]:
    """The pairs that share ``min_inliers`` or more wall points (as many points at the calibration's step)."""
    return [p for p in pairs if p.quality.equivalent_inliers >= limits.min_inliers]


def two_way_share(sharing: Sequence[JoinPair]) -> float:
    """The median, over pairs, of the share of wall points each sonar of a pair puts into the other's water,
    the smaller of the two directions (``AlignmentQuality.violation_min``); 0 without pairs."""
    return float(np.median([p.quality.violation_min for p in sharing])) if sharing else 0.0


def laid_back_to_back(q: AlignmentQuality, limits: ConvergenceThresholds) -> bool:
    """Whether a pair of scans lays ``min_inliers`` or more wall points on walls the other sonar saw from
    the other side, more than it lays on walls seen from the same side (:meth:`WallCheck.conflict`)."""
    return q.behind * q.point_weight >= limits.min_inliers and q.behind > q.inliers


class JoinPair(NamedTuple):
    """One pair of scans across a join, as the join would place them: scan ``b`` (moved group) assessed
    against scan ``a`` at their relative pose ``rel``."""

    quality: AlignmentQuality
    a: int
    b: int
    rel: gtsam.Pose2


def wall_limits(unit: float) -> ConvergenceThresholds:
    """The fixed verification limits the wall check judges a join by, their lengths (``*_m``) taken
    ``unit`` times as long (the site's :func:`~cistern_plugins.sonar_scale.site_length_unit`)."""
    return scaled_lengths(ConvergenceThresholds(), unit)


class WallCheck:
    """Whether joining two groups would put the walls one group's sonars saw into the water the other
    group's sonars saw (module docstring, step 2): every pair of scans of the two groups at one depth
    level and within sonar range, placed as the merge would place them, is assessed both ways
    (:meth:`~cistern_plugins.alignment.ReferenceModel.assess_pair`); among the pairs that would share
    walls (``min_inliers`` inliers or more), the median free-space violation share must not exceed
    ``max_violation_ratio`` (the fixed verification limits, their lengths at the site's unit:
    :func:`wall_limits`). A look-alike chamber fits the scans it was matched with, not the others that see
    it from elsewhere."""

    def __init__(self, scans: Sequence[RangeScan], p: SiteGraphParams):
        self.scans, self.p = scans, p
        self.levels = scan_levels(scans, p)
        self.limits = wall_limits(p.site_unit)
        self.corroborated_run_m = CORROBORATED_RUN_M * p.site_unit
        self.models: dict[int, ReferenceModel] = {}

    def model(self, k: int) -> ReferenceModel:
        if k not in self.models:
            self.models[k] = ReferenceModel(self.scans[k])
        return self.models[k]

    def label(self, k: int) -> str:
        """Scan ``k``'s station label (its index when it has none)."""
        return self.scans[k].station or str(k)

    def assess_join(self, graph: Graph, i: int, j: int, z: gtsam.Pose2) -> list[JoinPair]:
        """Every pair of scans of the two groups at one depth level and within sonar range, placed as the
        merge of ``j``'s group into ``i``'s by ``z`` would place them, assessed both ways
        (:meth:`~cistern_plugins.alignment.ReferenceModel.assess_pair`)."""
        offset = graph.pose[i].compose(z).compose(graph.pose[j].inverse())
        moved = {b: offset.compose(graph.pose[b]) for b in graph.members(graph.group[j])}
        return self.assess_sides(graph.members(graph.group[i]), graph.pose, list(moved), moved)

    def assess_sides(self, side_a: Sequence[int], poses_a, side_b: Sequence[int], poses_b) -> list[JoinPair]:
        """Every pair of a scan of ``side_a`` and one of ``side_b`` at one depth level and within sonar
        range, at their poses (``poses_a[k]``, ``poses_b[k]``), assessed both ways."""
        pairs = []
        for a in side_a:
            for b in side_b:
                sa, sb = self.scans[a], self.scans[b]
                rel = poses_a[a].between(poses_b[b])
                if same_level(self.levels, a, b) and math.hypot(rel.x(), rel.y()) <= min(sa.max_range_m, sb.max_range_m):
                    pairs.append(JoinPair(self.model(a).assess_pair(sb, pose_array(rel), self.limits), a, b, rel))
        return pairs

    def conflict(self, graph: Graph, i: int, j: int, z: gtsam.Pose2, *, shares_too: bool = True) -> str:
        """Empty when the merge of ``j``'s group into ``i``'s (:func:`_merge`) leaves the walls in place,
        else the reason, naming the stations of the worst pair. These tests: no pair of the two groups
        lays a stretch of wall longer than ``max_violation_run_m`` across the other's water (one
        chamber's opening onto the other's solid wall, :func:`~cistern_plugins.alignment.longest_run_m`),
        nor do :data:`CORROBORATED_PAIRS` pairs apart lay shorter ones (:func:`corroborated_runs`);
        the pairs that share ``min_inliers`` or more wall points do not put walls into each other's water
        both ways (:data:`TWO_WAY_SHARE`: a look-alike chamber laid a little off);
        fewer than :data:`BACK_TO_BACK_PAIRS` pairs lay ``min_inliers`` or more wall points onto walls the
        other sonar saw from the other side, more than they lay on walls seen from the same side (two
        chambers back to back, the group form of :func:`~cistern_plugins.alignment.seen_from_behind`);
        and, with ``shares_too``, the median violation share stays within ``max_violation_ratio``."""
        pairs = self.assess_join(graph, i, j, z)
        runs = [(q.violation_run_m, a, b) for q, a, b, _ in pairs]
        backs = [(q.behind, q.inliers, a, b) for q, a, b, _ in pairs if laid_back_to_back(q, self.limits)]
        sharing = sharing_pairs(pairs, self.limits)
        shares = [(q.violation_ratio, a, b) for q, a, b, _ in sharing]
        run, a, b = max(runs, default=(0.0, -1, -1))
        if run > self.limits.max_violation_run_m:
            return (f"joining its groups would lay {run:.2f} m of wall in a row across the water other scans saw "
                    f"({self.label(a)} – {self.label(b)}; at most {self.limits.max_violation_run_m:.2f} m)")
        least = self.corroborated_run_m
        corroborated = corroborated_runs(pairs, least, lone_scan(graph, i, j))
        if len(corroborated) >= CORROBORATED_PAIRS:
            seen = ", ".join(f"{self.label(a)} – {self.label(b)} {run:.2f} m" for run, a, b in corroborated)
            return (f"joining its groups would lay wall across the water other scans saw, from {len(corroborated)} "
                    f"pairs of stations apart ({seen}; {CORROBORATED_PAIRS} or more over {least:.2f} m): "
                    "as one chamber's opening laid onto a look-alike's solid wall")
        both_ways = two_way_share(sharing) if len(sharing) >= TWO_WAY_PAIRS else 0.0
        if both_ways > TWO_WAY_SHARE:
            return (f"joining its groups would put walls into water both ways: over {len(sharing)} pairs, a median "
                    f"{100 * both_ways:.1f} % of each sonar's wall points fall in the water the other saw "
                    f"(at most {100 * TWO_WAY_SHARE:.0f} %), as a look-alike chamber laid a little off")
        if len(backs) >= BACK_TO_BACK_PAIRS:
            behind, front, a, b = max(backs)
            return (f"joining its groups would lay walls back to back: {behind} of {self.label(b)}'s wall points fall "
                    f"on walls {self.label(a)} saw from the other side ({front} from the same side), as two chambers "
                    "side by side with no rock between them")
        if not shares or not shares_too:
            return ""
        median = float(np.median([v for v, _, _ in shares]))
        if median <= self.limits.max_violation_ratio:
            return ""
        worst, a, b = max(shares)
        return (f"joining its groups would put walls into water other scans saw: a median {100 * median:.0f} % "
                f"of wall points in the other scan's free space over {len(shares)} pairs "
                f"(worst {self.label(a)} – {self.label(b)}, {100 * worst:.0f} %)")


PASSAGE_MIN_NORMALS = 20
"""Fewer traced wall normals than this say nothing about which way a group's walls run."""


def passage_only(graph: Graph, moments: Sequence[tuple[np.ndarray, int]], g: int, p: SiteGraphParams) -> bool:
    """Whether the walls of group ``g`` all run one way (:func:`~cistern_plugins.group_clouds.placed_spread`
    below the group fit's ``min_spread``): a station inside a tunnel sees two parallel walls and the
    corners of its mouths, which fit the mouth of every passage of that width in the site as well as its
    own, however sure the match — as the group fit, such a group joins through its sequence links only."""
    members = graph.members(g)
    if sum(moments[k][1] for k in members) < PASSAGE_MIN_NORMALS:
        return False
    spread = placed_spread([moments[k] for k in members], [graph.pose[k].theta() for k in members])
    return spread < p.group_settings().min_spread


def several_each_side(graph: Graph, scans: Sequence[RangeScan], ga: int, gb: int, p: SiteGraphParams) -> bool:
    """Whether each of two groups has at least two scans that could be matched with the other group (at
    the depth level of one of its scans): only then can loop closures come from two stations a side."""
    a, b = graph.members(ga), graph.members(gb)
    levels = scan_levels(scans, p)

    def matchable(here: list[int], there: list[int]) -> int:
        return sum(any(same_level(levels, k, m) for m in there) for k in here)

    return matchable(a, b) > 1 and matchable(b, a) > 1


def seen_from_two_stations(graph: Graph, bridges: Sequence[Edge], g: int) -> bool:
    """Whether the loop closures between group ``g`` and another come from two stations on each side: a
    scan that fell for a look-alike place drags its whole group with it, whichever stations of the other
    group it was matched with; a second station on each side is harder to fool."""
    here = {e.i if graph.group[e.i] == g else e.j for e in bridges}
    there = {e.j if graph.group[e.i] == g else e.i for e in bridges}
    return len(here) >= 2 and len(there) >= 2


def merge_groups(graph: Graph, i: int, j: int, z: gtsam.Pose2) -> None:
    """Join the group of ``j`` to the group of ``i`` so that ``X_i^-1 X_j = z``."""
    gi, gj = graph.group[i], graph.group[j]
    if gi == gj:
        return
    offset = graph.pose[i].compose(z).compose(graph.pose[j].inverse())
    for k in graph.members(gj):
        graph.pose[k] = offset.compose(graph.pose[k])
        graph.group[k] = gi


def largest_group(graph: Graph) -> int:
    """The group with most scans (the one of the lowest scan index on ties)."""
    sizes: dict[int, int] = {}
    for g in graph.group:
        sizes[g] = sizes.get(g, 0) + 1
    return max(sizes, key=lambda g: (sizes[g], -min(graph.members(g))))


FITS = ContentCache()
"""Group fits already computed (site-graph solves the same groups again in every round)."""


def level_members(graph: Graph, levels: Sequence[int], g: int, depth_of: int) -> list[int]:
    """The scans of group ``g`` at the depth level of scan ``depth_of`` (``levels``: :func:`scan_levels`)."""
    return [k for k in graph.members(g) if same_level(levels, k, depth_of)]


def group_fit(scans: Sequence[RangeScan], graph: Graph, a: list[int], b: list[int], p: SiteGraphParams,
              digest: str) -> tuple[GroupFit | None, tuple[float, float]]:
    """The fit of the scans ``b`` (one group) in the frame of the scans ``a`` (another) and the two
    groups' :func:`~cistern_plugins.group_clouds.wall_spread`, cached: the clouds are built only when
    the pair was not fitted before."""
    poses_a, poses_b = [pose_array(graph.pose[k]) for k in a], [pose_array(graph.pose[k]) for k in b]

    def compute() -> tuple[GroupFit | None, tuple[float, float]]:
        cloud_a = Cloud([scans[k] for k in a], poses_a, p.site_unit)
        cloud_b = Cloud([scans[k] for k in b], poses_b, p.site_unit)
        return fit_groups(cloud_a, cloud_b, p.group_settings()), (wall_spread(cloud_a), wall_spread(cloud_b))

    key = (digest, tuple(a), pose_key(poses_a), tuple(b), pose_key(poses_b), p.group_settings())
    return FITS.get(key, compute)


def group_edge(graph: Graph, a: list[int], b: list[int], fit: GroupFit) -> Edge:
    """The fit as an edge between the two scans of the groups that lie nearest each other once placed,
    with the fit's covariance turned into that edge's frame."""
    t = gtsam.Pose2(*fit.pose)
    placed = {k: t.compose(graph.pose[k]) for k in b}
    i, j = min(((i, j) for i in a for j in b),
               key=lambda ij: math.hypot(graph.pose[ij[0]].x() - placed[ij[1]].x(), graph.pose[ij[0]].y() - placed[ij[1]].y()))
    z = graph.pose[i].between(placed[j])
    cov = about(fit.covariance, fit.pose, np.array([placed[j].x(), placed[j].y()]))
    c, s = math.cos(graph.pose[i].theta()), math.sin(graph.pose[i].theta())
    into_i = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # A's frame to scan i's: R(-theta_i)
    return Edge(i, j, pose_array(z), into_i @ cov @ into_i.T)


def survey_gap(a: Sequence[int], b: Sequence[int]) -> int:
    """How many places apart in the survey's order the nearest two stations of two groups were visited
    (scans are indexed in that order): 1 when one was visited right after the other."""
    return min(abs(i - j) for i in a for j in b)


RETURN_PLACES = 3
"""A station whose every link joins it to stations visited this many places or more before it, with
stations of other groups visited in between, came back to them (:func:`joined_in_sequence`). Two places
back is the survey's chain skipping one station whose own matches failed (a station in a tunnel): the
vehicle passed there, and the skipped station lies between."""


def joined_in_sequence(graph: Graph, k: int) -> bool:
    """Whether station ``k`` stands where the survey's chain left it: alone in its group, or joined to it
    by a link (a match, a fit or a vertical tie) with a station visited at most two places before it, or
    after it, or with an earlier one such that every station visited in between belongs to its group
    too (the survey never left the group's chamber, only its matches with the stations just before it
    failed). A station whose every link joins it to stations visited ``RETURN_PLACES`` or more places
    before it, with stations of other groups visited in between, came back to them — a return to the
    first chamber at the end of a survey — through passages the survey did not record, so the station
    visited just before it need not be near it, and a group fit may not count the two as visited one
    after the other."""
    links = [(e.i, e.j) for e in (*graph.edges, *graph.ties)] + graph.fitted
    ends = [j if i == k else i for i, j in links if k in (i, j)]
    if not ends or max(ends) > k - RETURN_PLACES:
        return True
    own = graph.group[k]
    return all(graph.group[m] == own for m in range(max(ends) + 1, k))


def far_apart_reason(gap: int, max_gap: int) -> str:
    """Why two groups visited ``gap`` places apart are not fitted as wholes (:func:`join_by_fit`)."""
    between = gap - 1
    allowed = ("the survey visited one right after the other" if max_gap == 1
               else f"the survey visited them at most {max_gap} places apart")
    return (f"the survey visited {between} station{'s' if between != 1 else ''} between them that neither group "
            "holds; without those a fit of the groups as wholes cannot tell the real join from a look-alike "
            f"chamber (groups are fitted only where {allowed})")


def join_by_fit(graph: Graph, scans: Sequence[RangeScan], walls: WallCheck, p: SiteGraphParams) -> list[Edge]:
    """Join groups that no match could join by fitting them as wholes (:mod:`cistern_plugins.group_fit`):
    each round, every pair of groups at one depth level that the survey visited at most ``group_max_gap``
    places apart (:func:`survey_gap`, over the stations :func:`joined_in_sequence`) is fitted and the
    clearest accepted fit that passes the wall check merges its two groups; until no fit joins two
    groups; when none does, a passage between two groups joins them (:func:`join_through_passage`), and
    the rounds go on. Returns the edges added (one per join, two for a passage); the reasons of the fits
    refused are kept in ``graph.unjoined`` for every scan outside the largest group."""
    digest = scans_digest(scans)
    added: list[Edge] = []
    far_said: list[int] = []
    while True:
        for k in far_said:  # a round after a join may fit groups a round before kept apart
            graph.unjoined.pop(k, None)
        groups = sorted(set(graph.group))
        if len(groups) < 2:
            return added
        members = {g: graph.members(g) for g in groups}
        anchors = {g: [k for k in members[g] if joined_in_sequence(graph, k)] for g in groups}
        candidates, far_apart = [], []
        for x, ga in enumerate(groups):
            for gb in groups[x + 1:]:
                big, small = (ga, gb) if len(members[ga]) >= len(members[gb]) else (gb, ga)
                gap = survey_gap(anchors[big], anchors[small])
                if gap > p.group_max_gap:
                    why = (f"not fitted as a group with {walls.label(members[big][0])}'s group: "
                           f"{far_apart_reason(gap, p.group_max_gap)}")
                    far_apart += [(k, why) for k in members[small]]
                    continue
                probe = members[small][0]
                a, b = level_members(graph, walls.levels, big, probe), level_members(graph, walls.levels, small, probe)
                if not a or not b:
                    continue
                fit, spreads = group_fit(scans, graph, a, b, p, digest)
                why = accept(fit, p.group_settings(), spreads)
                if why:
                    for k in members[small]:
                        graph.unjoined.setdefault(k, f"fitted as a group with {walls.label(a[0])}'s group: {why}")
                    continue
                candidates.append((fit.score, a, b, fit))
        far_said = [k for k, _ in far_apart if k not in graph.unjoined]
        for k, why in far_apart:  # said only of scans no fit gave a reason for
            graph.unjoined.setdefault(k, why)
        for _, a, b, fit in sorted(candidates, key=lambda c: -c[0]):
            edge = group_edge(graph, a, b, fit)
            why = merge_checked(graph, walls, [edge])
            if why:
                for k in b:
                    graph.unjoined.setdefault(k, f"fitted as a group with {walls.label(a[0])}'s group, but {why}")
                continue
            note_fitted(graph, [edge])
            added.append(edge)
            break
        else:
            bridged = join_through_passage(graph, scans, walls, p, digest) if p.group_passages else []
            if not bridged:
                return added
            added += bridged


def note_fitted(graph: Graph, edges: Sequence[Edge]) -> None:
    """Record joins just made by fits: their edges' two scans in ``graph.fitted``, and no reason left why
    the scans of the joined group stand apart."""
    graph.fitted += [(e.i, e.j) for e in edges]
    for k in graph.members(graph.group[edges[0].i]):
        graph.unjoined.pop(k, None)


PASSAGE_FIT_SIGMA_M = 0.15
"""The largest standard deviation (m) a passage's fit to a group may leave along any direction: a tunnel
whose ends its stations do not hear fits anywhere along itself (the fit's covariance then says so, up to
``MAX_SIGMA``), and a group placed through it would be placed by that much."""


def loose_along(fit: GroupFit, unit: float = 1.0) -> str:
    """Why a passage's fit leaves its place too loose along some direction (looser than
    :data:`PASSAGE_FIT_SIGMA_M` times the site's ``unit``), or empty."""
    sigma = float(np.sqrt(np.linalg.eigvalsh(fit.covariance[:2, :2]).max()))
    most = PASSAGE_FIT_SIGMA_M * unit
    if sigma <= most:
        return ""
    return f"it fits within ±{sigma:.2f} m along one direction only (σ > {most:.2f} m)"


def join_through_passage(graph: Graph, scans: Sequence[RangeScan], walls: WallCheck, p: SiteGraphParams,
                         digest: str) -> list[Edge]:
    """Join the groups on either side of a passage seen from inside through the passage itself: a group
    of stations visited one after the other whose walls all run one way (a tunnel's), between a station
    of one group and the next station of another, is fitted as a whole to each (:func:`passage_edges`);
    where both fits hold they place the far group in the near one's frame, where one holds the passage
    joins that side alone, and the wall check judges either as any join (:func:`merge_checked`). Returns
    the edges of the first join made (two, or one for a side alone; none when no passage joins a group).
    A passage tried and refused says why in ``graph.unjoined`` for its stations (more precisely than the
    fits of groups, which refuse any passage seen from inside)."""
    for g in sorted(set(graph.group)):
        edges, why = passage_edges(graph, scans, walls, p, digest, g)
        if edges:
            joined = merge_checked(graph, walls, edges)
            if not joined:
                note_fitted(graph, edges)
                return edges
            why = (f"fitted as a passage between the groups on either side, but {joined}" if len(edges) == 2 else
                   f"{why}; fitted as a passage to the other side's group, but {joined}")
        if why:
            for k in graph.members(g):
                graph.unjoined[k] = why
    return []


def passage_edges(graph: Graph, scans: Sequence[RangeScan], walls: WallCheck, p: SiteGraphParams, digest: str,
                  g: int) -> tuple[list[Edge], str]:
    """The edges of group ``g``'s fits (:func:`group_fit`) to the groups of the stations visited just
    before and just after it, when ``g`` is a passage seen from inside (its walls run one way) between
    two groups, for each side it fits clearly (:func:`~cistern_plugins.group_fit.accept`, but for its
    own spread) and to within :data:`PASSAGE_FIT_SIGMA_M`; and why a side did not fit (empty when ``g``
    is no passage between two groups, or fits both). On its own a passage fits every passage of its
    width; beside a chamber visited right before or after it only at one place. A passage that fits one
    side only joins that side's group: the group beyond may then be fitted to it as a whole, visited
    right after it (:func:`join_by_fit`)."""
    members = graph.members(g)
    lo, hi = min(members), max(members)
    if hi - lo + 1 != len(members) or lo == 0 or hi == len(scans) - 1:
        return [], ""
    sides = (graph.group[lo - 1], graph.group[hi + 1])
    if sides[0] == sides[1]:
        return [], ""
    s = p.group_settings()
    edges, refused = [], []
    for side in sides:
        a, b = level_members(graph, walls.levels, side, lo), level_members(graph, walls.levels, g, lo)
        if not a or not b:
            return [], ""
        fit, spreads = group_fit(scans, graph, a, b, p, digest)
        if spreads[1] >= s.min_spread:
            return [], ""
        why = accept(fit, s, (spreads[0], 1.0)) or loose_along(fit, s.unit)
        if why:
            refused.append(f"fitted as a passage to {walls.label(a[0])}'s group: {why}")
        else:
            edges.append(group_edge(graph, a, b, fit))
    return edges, "; ".join(refused)


def merge_checked(graph: Graph, walls: WallCheck, edges: Sequence[Edge]) -> str:
    """Merge the groups of each edge in turn, each judged by the wall check as the ones before left the
    groups; on a refusal the graph is left as it was and the wall check's reason returned (empty when
    every edge merged)."""
    saved = (list(graph.group), list(graph.pose))
    for edge in edges:
        z = gtsam.Pose2(*edge.z)
        why = walls.conflict(graph, edge.i, edge.j, z)
        if why:
            graph.group[:], graph.pose[:] = saved
            return why
        merge_groups(graph, edge.i, edge.j, z)
    return ""


def unplaced_reason(k: int, reference: int, graph: Graph, matches: Sequence[MatchResult], labels: Sequence[str]) -> str:
    """Why scan ``k`` is not placed, naming stations: its matches with the placed part of the site and
    what became of each (the first three), and why no group fit joined it."""
    if reference >= 0 and graph.group[k] == graph.group[reference]:
        return ("its only consistent matches were dropped by the least-squares fit's χ² gate; "
                f"no chain of matches joins it to the reference station {labels[reference]}")
    target = f"the reference station {labels[reference]}" if reference >= 0 else "any other station"
    notes = []
    for m in matches:
        if k not in (m.i, m.j) or not (0 <= m.i < len(labels) and 0 <= m.j < len(labels)):
            continue
        pair = f"{labels[m.i]} → {labels[m.j]}"
        if m.converged:
            why = graph.rejected.get((m.i, m.j), "joins it only to stations that are themselves unplaced")
        else:
            why = m.reason or "not converged"
        notes.append(f"{pair}: {why}")
    detail = "; ".join(notes[:3]) + (f"; and {len(notes) - 3} more" if len(notes) > 3 else "")
    if k in graph.unjoined:
        detail = "; ".join(filter(None, (detail, graph.unjoined[k])))
    cut = f": {graph.cut[k]}" if k in graph.cut else ""
    return f"no consistent chain of matches to {target}{cut}" + (f" ({detail})" if detail else " (no pair was matched)")
