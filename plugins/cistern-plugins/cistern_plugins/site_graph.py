"""``site-graph``: every scan placed by a consistent set of matches, not by a chain of neighbours.

McVicker et al. localise from neighbouring pairs (eqs. 7–10): one rejected neighbour pair unplaces every
later scan, and one wrong pair that passed the matcher's test is averaged into the map. This localizer
builds a graph over the whole site instead, in three steps.

1. **Candidate pairs, in rounds** (:meth:`SiteGraphLocalizer.pairs`, :meth:`~SiteGraphLocalizer.guided_pairs`).
   The first round matches every pair up to ``first_gap`` stations apart, both ways. Each later round
   solves the graph of the matches so far and asks for (a) every pair of scans whose solved positions
   are within ``reach`` (the smaller of the two sonar ranges times ``reach_factor``) with a
   :class:`~cistern_archive.pipeline.contracts.MatchGuess` — loop closures proposed from a first solution,
   as SLAM systems search around their odometry — and (b) for each scan outside the largest group, a
   global match (no guess, both ways) with the nearest station of another group not tried yet, up to
   ``global_gap`` stations away, and (c) across a break between consecutive stations, the reverse
   match again around the inverse of a forward estimate that has no rival place
   (:func:`reverse_checks`).
   Scans at different depth levels are never matched: at different depths of a bell-shaped cistern the
   walls differ, and the record's vertical ties (``ties``) join the levels. A level is a run of depths
   each within ``level_tolerance_m`` of the next (:func:`~cistern_archive.core.levels.depth_levels`), so
   stations that landed on an uneven floor are matched with each other across the whole run.

2. **Consistent matches as a set** (:func:`consistent_edges`). Every converged match is an edge. An
   edge gains support from every cycle it closes consistently: the reverse match of the same pair that
   agrees with it, and every triangle of edges whose composition returns to the start within
   ``consistency_m`` and ``consistency_deg`` (cycle consistency, as in Zach et al., CVPR 2010, and the
   pairwise consistency of Mangelson et al., ICRA 2018, with cycles among the matches instead of
   odometry). Groups of scans are then merged greedily, largest consensus first: between two groups,
   the edges that agree on where one group lies in the other's frame form a cluster whose score is the
   sum of ``1 + support`` over its edges; the best cluster of all merges its two groups. An edge that
   disagrees with the merged geometry is rejected, with the distance by which it disagrees. A single
   match may join two groups when nothing contradicts it and it is evidence enough (below) — a scan is
   unplaced only when no consistent chain of matches reaches it. A *tentative* match (not converged,
   but refused only for a rival peak, a weak direction or a confidence below the threshold,
   ``MatchResult.tentative``) takes part only when a consistent cycle with a converged match
   corroborates it or it is part of a sequence link (below), and with its covariance inflated by
   ``tentative_variance_factor``.

   Which links may join two groups is a matter of evidence. A loop closure between stations far apart
   in the visiting order must be a converged match of confidence ``bridge_confidence`` or more: the
   scans of a look-alike chamber all match into the same wrong place, so agreeing bridges between two
   groups cannot vouch for each other. Consecutive stations are the survey's own chain — the diver sets
   each station within sight of the last one, as a SLAM system trusts its odometry more than a loop
   closure — so a *sequence link* joins two groups on less (consecutive in the order the scans were
   recorded: by their times where every scan has its own, else as the record lists them,
   :mod:`cistern_archive.pipeline.survey_order`): the match of consecutive stations ``i → j``
   and the independent match ``j → i`` (each converged or tentative) agree as a 2-cycle, and the more
   confident of the two reaches ``sequence_confidence``; or ``i → j`` converged and ``j → i`` gave no
   estimate at all (a reverse estimate that disagrees vetoes it). That is what a gallery's neighbour
   pairs look like: the walls fit, but a straight reach leaves the along-axis direction weak, which both
   the calibrated confidence (0.5–0.8) and the covariance already say. On the tuning seed of the random
   multi-chamber cisterns (``benchmarks/sites.py --random 12 --seed 2``) every one of the 134 converged
   matches between consecutive stations was within 0.3 m of the truth, against 9 of 82 converged loop
   closures 3.8–11.4 m off. So the survey's chain is built first and loop closures come second, in
   three tiers (each tier's best cluster merges before any of the next): sequence links with a converged
   match; then confident loop closures, which join two groups of several scans each only when they come
   from two stations on each side (a scan that fell for a look-alike place drags its whole group with
   it, whatever it was matched with; on the tuning seed this refused the two wrong chamber-to-chamber
   joins and no right one), and never join a group whose walls all run one way (a station inside a
   tunnel sees two parallel walls and the corners of its mouths, which a match lays as surely onto the
   mouth of any passage of that width: :func:`~cistern_plugins.site_groups.passage_only`) — such a group
   joins through its survey chain; then sequence links of tentative matches only. Every join must also
   leave the walls in place (:class:`WallCheck`): placed as the join would place them, no pair of the two
   groups' scans may lay a stretch of wall across the water the other saw (one chamber's opening onto
   a look-alike's solid wall), no two pairs may lay their walls back to back (two chambers side by side
   with no rock between them), and in the last two tiers the median share of wall points in the other
   scans' water must stay small (a look-alike chamber fits the scans it was matched with, not the
   others that see it from elsewhere); a refused join's matches are rejected with that reason.

   Groups that no match could join are then fitted as wholes (``group_fit``,
   :func:`~cistern_plugins.site_groups.join_by_fit`, :mod:`cistern_plugins.group_fit`). A station in a
   tunnel or at its mouth shares a few metres of wall with any single station beyond it, too little for
   a pair-wise match to tell the right place from a look-alike; the scans joined on each side of the
   break see much more together — every wall of their chamber and all the water in it. The fit searches
   every translation and a ±``group_yaw_window_deg`` heading window for the placement of one group in the
   other's frame that lays walls on walls seen from the same side, and no wall in water either group
   saw (open beams count as water); it joins two groups when its score reaches ``group_min_score`` and
   holds once refined on sharper fields (where the search's peak keeps less than 0.3 of its score there,
   every peak of the search is refined and the best of them there is the fit), no place 0.5 m away
   scores more than ``group_ambiguity_ratio`` of it (a place that lays more wall than the best into the
   water either group saw is judged at a heavier penalty: two chambers of one shape laid
   on each other is no rival), neither group is a tunnel seen
   from inside (two parallel walls fit every passage of their width), and the join passes the wall
   check. Only groups the survey visited one after the other are fitted (two of their stations at most
   ``group_max_gap`` places apart in the survey's order): across stations that neither group holds, a
   fit cannot tell the real join from a look-alike chamber, and on the tuning sites such joins laid
   chambers 7–10 m off (RESULTS.md "2026-12-04 (night)"). A station joined to its group only by links to
   stations visited three or more places before it, with other groups' stations visited in between, is
   not counted (:func:`~cistern_plugins.site_groups.joined_in_sequence`): a return to the first chamber
   is recorded right after the last chamber's station, not near it. The clearest accepted fit joins first, until
   none is left. Its edge carries the covariance of the fit's score, wide along a tunnel that both
   groups see end to end. When no fit is left, a passage seen from inside between two groups — the
   stations of a tunnel, visited one after another between a station of each (``group_passages``,
   :func:`~cistern_plugins.site_groups.join_through_passage`) — is fitted to each of the two: the
   passage alone fits every passage of its width, but only one place in each chamber beside it, so it
   joins a side only where it fits that side clearly and to within 0.15 m along any direction. Where it
   fits both, the far group, placed by the two fits, must pass the wall check; where it fits one, the
   passage joins that side's group (the wall check judging that join), and the group beyond, visited
   right after the passage, may then be fitted to the grown group as a whole. The rounds of fits then go on.

   Once every join is made, each group is judged again whole (:mod:`cistern_plugins.settled_groups`): a
   join judged when one scan of a look-alike chamber joined a group of three could not weigh the few
   per cent of walls each sonar put into the other's water; with the whole chamber joined it can. A run
   of stations visited one after another whose pairs with the rest of its group put walls into water
   both ways is cut off, the smaller part left unplaced with the reason. Every edge left over is then
   checked against the merged geometry as before.

3. **Robust least squares** (:mod:`cistern_plugins.factor_graph`): the accepted edges and the vertical
   ties in a GTSAM factor graph with a robust loss, the compass as a prior on every heading correction
   about the compasses' common frame (:func:`cistern_plugins.factor_graph.add_compass_factors`),
   and a χ² gate that drops the worst edge while its squared Mahalanobis residual exceeds ``gate_chi2``.
   When the gate cuts the reference station off (every edge of it contradicted by the others or by the
   compasses), the largest set of scans the kept edges still join is anchored on its first station and
   solved again: one bad station leaves itself unplaced, not the whole site.
   ``gtsam.Marginals`` gives each scan's covariance, and each join of groups the radius that holds its two
   scans' relative position with 95 % probability (``Poses.group_link_radius95_m``): how well the join
   places the two groups against each other.

Every length of these steps — the guided window, the cycle tolerance, the graph's default σ, the wall
check's limits, the group fits' cells, σ, separation and probes, the clouds' margins and traces — is
written for the calibration sites (walls within 10 m) and taken ``length_unit`` times as long: by
default the median over the site's scans of their farther echoes' range over 10 m
(:func:`~cistern_plugins.sonar_scale.site_length_unit`): random cisterns drawn three times as large
place 163 of their 170 scans, against 157 with these lengths in metres and 166 at their own size
(``benchmarks/RESULTS.md``, "2026-12-07 (session 24)"). The depth levels' tolerance and the ties' σ
belong to the vehicle and stay in metres.

Reasons name stations by their labels: an unplaced scan says which of its matches were rejected and why.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import gtsam
import numpy as np
from pydantic import Field, PrivateAttr

from cistern_archive.core.scan import wrap_angle
from cistern_archive.pipeline.contracts import (GuidedLocalizer, MatchGuess, MatchResult, Poses, StageParams,
                                                VerticalTie)
from cistern_archive.core.scan import RangeScan
from cistern_plugins.factor_graph import Edge, GraphParams, poses_from_solution, solve_gated
from cistern_plugins.factor_graph import spanning_tree
from cistern_plugins.group_clouds import normal_moment
from cistern_plugins.group_fit import GroupFitSettings
from cistern_plugins.settled_groups import recheck_groups
from cistern_plugins.sonar_scale import scaled_lengths, site_length_unit
from cistern_plugins.site_groups import (
    Graph,
    WallCheck,
    best_cluster,
    close_enough,
    cycle_support,
    join_by_fit,
    largest_group,
    merge_groups,
    same_level,
    scan_levels,
    unplaced_reason,
)
from cistern_plugins.wls import vertical_ties


class SiteGraphParams(GraphParams):
    """Parameters of :class:`SiteGraphLocalizer` (plus the graph's, :class:`GraphParams`)."""

    first_gap: int = Field(1, ge=1, description="first round: every pair up to this many stations apart")
    global_gap: int = Field(4, ge=1, description="unjoined scans: global matches up to this many stations away")
    reach_factor: float = Field(1.0, gt=0, description="loop candidates within this times the sonar range")
    guess_radius_m: float = Field(0.5, gt=0, description="half-width of a guided match's search window")
    level_tolerance_m: float = Field(0.8, ge=0, description="a gap in depth wider than this between the "
                                     "scans' depths, sorted, separates two depth levels, whose scans are not "
                                     "matched (the levels of a bell-shaped cistern lie about 1 m apart)")
    consistency_m: float = Field(0.2, gt=0, description="cycle closure tolerance in translation")
    consistency_deg: float = Field(3.0, gt=0, description="cycle closure tolerance in heading")
    tie_sigma_m: float = Field(0.02, gt=0, description="horizontal sigma of a vertical tie")
    bridge_confidence: float = Field(0.9, ge=0, le=1, description="least confidence of the match that joins "
                                     "two groups of scans (matches without a confidence always may)")
    tentative_variance_factor: float = Field(25.0, ge=1, description="a tentative match's covariance is "
                                             "inflated by this, so converged matches dominate where they exist")
    sequence_confidence: float = Field(0.5, ge=0, le=1, description="a pair of consecutive stations whose two "
                                       "matches agree joins two groups when the more confident of the two has "
                                       "at least this confidence (step 2 of the module docstring)")
    group_fit: bool = Field(True, description="join the groups no match could join by fitting them as wholes "
                            "(step 2 of the module docstring, cistern_plugins.group_fit)")
    group_passages: bool = Field(True, description="join the groups on either side of a passage seen from inside "
                                 "(a tunnel's stations, whose walls all run one way) by fitting the passage to each "
                                 "(cistern_plugins.site_groups.join_through_passage)")
    group_min_score: float = Field(30.0, ge=0, description="a group fit joins only with at least this score "
                                   "(cells of 0.1 m of agreeing wall, both ways)")
    group_ambiguity_ratio: float = Field(0.8, gt=0, le=1, description="a group fit joins only when no place "
                                         "0.5 m or more away scores more than this share of the best")
    group_free_penalty: float = Field(5.0, ge=0, description="what a wall point in the other group's water "
                                      "costs, against 1 for an agreeing one")
    group_yaw_window_deg: float = Field(6.0, ge=0, le=45, description="heading window of a group fit "
                                        "(three times a Micron-class compass's 2° noise)")
    group_max_gap: int = Field(1, ge=1, description="a group fit joins only groups with two stations at most "
                               "this many places apart in the survey's order (1: one visited right after the "
                               "other; step 2 of the module docstring)")
    length_unit: float | None = Field(None, gt=0, description="metres of the site per metre of every length "
                                      "of this localizer (its *_m parameters but the depth tolerance and the "
                                      "ties', the wall checks' and the group fits'), written for sites whose walls "
                                      "lie within 10 m; none: the median over the site's scans of their farther "
                                      "echoes' range (90th percentile) over 10 m, each at least 1; 1: metres as "
                                      "given")
    _site_unit: float = PrivateAttr(1.0)

    UNSCALED: ClassVar[tuple[str, ...]] = ("level_tolerance_m", "tie_sigma_m")
    """Lengths that belong to the vehicle, not to the site's size: how far apart the levels lie and how
    still the vehicle held its place while it descended."""

    @property
    def site_unit(self) -> float:
        """The unit these parameters' lengths are scaled to (:meth:`for_site`; 1 before)."""
        return self._site_unit

    def for_site(self, scans: Sequence[RangeScan]) -> "SiteGraphParams":
        """These parameters with their lengths scaled to the site of ``scans``: ``length_unit``, or
        :func:`~cistern_plugins.sonar_scale.site_length_unit` when it is none; themselves at unit 1.
        Called once per call of the localizer, on the parameters as configured."""
        unit = self.length_unit if self.length_unit is not None else site_length_unit(scans)
        if unit == 1.0:
            return self
        scaled = scaled_lengths(self, unit).model_copy(update={name: getattr(self, name) for name in self.UNSCALED})
        scaled._site_unit = unit
        return scaled

    def group_settings(self) -> GroupFitSettings:
        """The settings of :func:`cistern_plugins.group_fit.fit_groups`, at the site's unit."""
        return GroupFitSettings(min_score=self.group_min_score, ambiguity_ratio=self.group_ambiguity_ratio,
                                free_penalty=self.group_free_penalty, yaw_window_deg=self.group_yaw_window_deg,
                                compass_sigma_deg=self.compass_sigma_deg).at_unit(self.site_unit)


class SiteGraphLocalizer(GuidedLocalizer):
    """Site-wide graph of consistent matches, solved by robust least squares (the ``site-graph`` localizer)."""

    name: ClassVar[str] = "site-graph"
    Params: ClassVar[type[StageParams]] = SiteGraphParams

    def pairs(self, n_scans: int, params: StageParams) -> list[tuple[int, int]]:
        """None: every round, the first included, needs the scans' depths (:meth:`guided_pairs`)."""
        return []

    def first_pairs(self, scans: Sequence[RangeScan], p: SiteGraphParams) -> list[tuple[int, int, None]]:
        """First round: every pair of one depth level up to ``first_gap`` stations apart, nearest first,
        both ways, without a guess."""
        out: list[tuple[int, int, None]] = []
        levels = scan_levels(scans, p)
        for gap in range(1, p.first_gap + 1):
            for i in range(len(scans) - gap):
                if same_level(levels, i, i + gap):
                    out += [(i, i + gap, None), (i + gap, i, None)]
        return out

    def guided_pairs(self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
                     ties: Sequence[VerticalTie] = ()) -> list[tuple[int, int, MatchGuess | None]]:
        """The first round (:meth:`first_pairs`) when nothing was matched yet; then loop candidates
        within reach of the solution so far (with a guess) and global matches for the scans not yet
        joined to the rest (module docstring, step 1). The scans come in the survey's order
        (:mod:`cistern_archive.pipeline.survey_order`)."""
        p = SiteGraphParams.of(params).for_site(scans)
        n = len(scans)
        if not matches:
            return self.first_pairs(scans, p)
        graph = consistent_edges(scans, matches, p, ties)
        tried = {frozenset((m.i, m.j)) for m in matches}
        out: list[tuple[int, int, MatchGuess | None]] = []
        levels = scan_levels(scans, p)
        for i in range(n):
            for j in range(i + 1, n):
                if frozenset((i, j)) in tried or not same_level(levels, i, j):
                    continue
                if graph.group[i] == graph.group[j]:
                    rel = graph.pose[i].between(graph.pose[j])
                    reach = p.reach_factor * min(scans[i].max_range_m, scans[j].max_range_m)
                    if math.hypot(rel.x(), rel.y()) <= reach:
                        out.append((i, j, MatchGuess(rel.x(), rel.y(), rel.theta(), p.guess_radius_m)))
        return out + self.bridging_pairs(scans, graph, tried, p) + reverse_checks(graph, matches, p)

    def bridging_pairs(self, scans: Sequence[RangeScan], graph: "Graph", tried: set,
                       p: SiteGraphParams) -> list[tuple[int, int, None]]:
        """Global matches (both ways) for scans outside the largest group: for each, the untried pair of
        one depth level with the nearest station in another group, at most ``global_gap`` stations away.
        One pair per scan and round keeps the expensive global searches to the breaks of the chain."""
        main = largest_group(graph)
        out: list[tuple[int, int, None]] = []
        asked: set[frozenset] = set()
        levels = scan_levels(scans, p)
        for k in range(len(scans)):
            if graph.group[k] == main and len(graph.members(main)) > 1:
                continue
            for gap in range(1, p.global_gap + 1):
                options = [j for j in (k - gap, k + gap) if 0 <= j < len(scans) and graph.group[j] != graph.group[k]
                           and frozenset((k, j)) not in tried | asked and same_level(levels, k, j)]
                if options:
                    j = options[0]
                    asked.add(frozenset((k, j)))
                    out += [(min(k, j), max(k, j), None), (max(k, j), min(k, j), None)]
                    break
        return out

    def localize(self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
                 ties: Sequence[VerticalTie] = ()) -> Poses:
        """Place every scan a consistent chain of matches joins to the reference (module docstring); the
        scans come in the survey's order (:mod:`cistern_archive.pipeline.survey_order`)."""
        p = SiteGraphParams.of(params).for_site(scans)
        n = len(scans)
        graph = consistent_edges(scans, matches, p, ties)
        main = largest_group(graph)
        members = graph.members(main)
        reference = min(members) if members and (len(members) > 1 or n == 1) else -1
        labels = [s.station or str(k) for k, s in enumerate(scans)]
        if reference < 0:
            reasons = [unplaced_reason(k, -1, graph, matches, labels) for k in range(n)]
            yaw = np.array([s.yaw_rad for s in scans], dtype=np.float64)
            return Poses(np.full((n, 2), np.nan), yaw, np.zeros(n, bool), tuple(reasons), -1, None)
        edges = graph.ties + graph.edges
        keep = frozenset(range(len(graph.ties)))
        solved, result, kept = solve_gated(n, edges, reference, p.noise(), p.gate_chi2, p.gate_rounds, keep)
        placed = set(spanning_tree(n, kept, reference))
        largest = largest_component(n, kept)
        if len(largest) > len(placed):  # the gate cut the reference off: anchor the scans still joined
            reference = min(largest)
            solved, result, kept = solve_gated(n, kept, reference, p.noise(), p.gate_chi2, p.gate_rounds, keep)
            placed = set(spanning_tree(n, kept, reference))
        kept_ids = {id(e) for e in kept}
        for e in edges:
            if id(e) not in kept_ids:
                graph.rejected[(e.i, e.j)] = "dropped by the χ² gate of the site's least-squares fit"
        reasons = [unplaced_reason(k, reference, graph, matches, labels) for k in range(n)]
        links = [(i, j) for i, j in graph.fitted if i in placed and j in placed]
        return poses_from_solution(scans, solved, result, placed, reference, reasons, links)


def largest_component(n: int, edges: Sequence[Edge]) -> set[int]:
    """The scans of the largest set joined by ``edges`` (the lowest-numbered set among equals)."""
    seen: set[int] = set()
    best: set[int] = set()
    for k in range(n):
        if k not in seen:
            component = set(spanning_tree(n, edges, k))
            seen |= component
            if len(component) > len(best):
                best = component
    return best


def reverse_checks(graph: Graph, matches: Sequence[MatchResult], p: SiteGraphParams) -> list[tuple[int, int, MatchGuess]]:
    """Guided reverse matches across a break of the survey's chain: for consecutive stations ``i``, ``j``
    in different groups whose match ``i → j`` converged or is tentative, with no rival place
    (``MatchResult.alternatives`` empty), while ``j → i`` was matched only globally and disagrees with it
    (or gave no estimate), ``j → i`` again around the inverse of ``i → j``.
    A global search of a station that sees little (a tunnel's) finds a look-alike place as often as the
    right one; searched around the other direction's estimate, the reverse match confirms it — the
    two-match agreement a sequence link needs (step 2) — or does not. An estimate with rivals is not
    re-matched: around a look-alike place the reverse search agrees as readily as around the right one."""
    by_pair: dict[tuple[int, int], list[MatchResult]] = {}
    for m in matches:
        by_pair.setdefault((m.i, m.j), []).append(m)
    out = []
    for (i, j), forward in sorted(by_pair.items()):
        if abs(i - j) != 1 or graph.group[i] == graph.group[j]:
            continue
        reverse = by_pair.get((j, i), [])
        if any(m.guess is not None for m in reverse):
            continue
        for m in forward:
            if not (m.converged or m.tentative) or m.alternatives:
                continue
            z = gtsam.Pose2(m.dx_m, m.dy_m, m.dyaw_rad)
            if any(r.converged and close_enough(z.compose(gtsam.Pose2(r.dx_m, r.dy_m, r.dyaw_rad)), p, z) for r in reverse):
                continue
            back = z.inverse()
            out.append((j, i, MatchGuess(back.x(), back.y(), back.theta(), p.guess_radius_m)))
    return out


def match_edges(scans: Sequence[RangeScan], matches: Sequence[MatchResult],
                p: SiteGraphParams) -> tuple[list[Edge], list[bool], list[float | None]]:
    """The converged and the tentative matches between distinct scans of one depth level, as edges, and
    for each whether it converged and its confidence (the last one wins when a directed pair was
    matched twice)."""
    n = len(scans)
    noise = p.noise()
    levels = scan_levels(scans, p)
    out: dict[tuple[int, int], tuple[Edge, bool, float | None]] = {}
    for m in matches:
        if not ((m.converged or m.tentative) and 0 <= m.i < n and 0 <= m.j < n and m.i != m.j):
            continue
        if not np.isfinite([m.dx_m, m.dy_m, m.dyaw_rad]).all() or not same_level(levels, m.i, m.j):
            continue
        edge = Edge.of_match(m, noise)
        if not m.converged:
            edge = Edge(edge.i, edge.j, edge.z, edge.covariance * p.tentative_variance_factor)
        out[(m.i, m.j)] = (edge, bool(m.converged), m.confidence)
    return [e for e, _, _ in out.values()], [s for _, s, _ in out.values()], [c for _, _, c in out.values()]


def tie_edges(scans: Sequence[RangeScan], ties: Sequence[VerticalTie], p: SiteGraphParams) -> list[Edge]:
    """The record's vertical ties as edges of zero displacement."""
    cov = np.diag([p.tie_sigma_m**2, p.tie_sigma_m**2, math.radians(p.compass_sigma_deg) ** 2])
    return [Edge(a, b, np.zeros(3), cov) for a, b in vertical_ties(scans, ties)]


def consistent_edges(scans: Sequence[RangeScan], matches: Sequence[MatchResult], p: SiteGraphParams,
                     vertical: Sequence[VerticalTie] = ()) -> Graph:
    """Step 2 of the module docstring: cycle support, then greedy consensus merging of scan groups."""
    n = len(scans)
    edges, strong, confidence = match_edges(scans, matches, p)
    confident = [c is None or c >= p.bridge_confidence for c in confidence]
    sequence = sequence_links(edges, strong, confidence, p)
    ties = tie_edges(scans, vertical, p)
    support = cycle_support(edges, strong, p)
    graph = Graph(edges=[], ties=ties, group=list(range(n)), pose=[gtsam.Pose2() for _ in range(n)])
    for t in ties:
        merge_groups(graph, t.i, t.j, gtsam.Pose2(*t.z))
    pending = [k for k in range(len(edges)) if strong[k] or support[k] > 0 or sequence[k]]
    for k in range(len(edges)):
        if not (strong[k] or support[k] > 0 or sequence[k]):
            graph.rejected[(edges[k].i, edges[k].j)] = "not converged, and no converged match corroborates it"
    loops = [s and c for s, c in zip(strong, confident)]
    tiers = (([s and c for s, c in zip(sequence, strong)], False), (loops, True), (sequence, False))
    walls = WallCheck(scans, p)
    moments = [normal_moment(scan, p.site_unit) for scan in scans]
    while True:
        best, tier = None, 0
        for tier, (bridges, loop_closures) in enumerate(tiers):
            best = best_cluster(graph, scans, edges, support, bridges, pending, p, loop_closures, moments)
            if best is not None:
                break
        if best is None:
            break
        members, (i, j, z) = best
        why = walls.conflict(graph, i, j, z, shares_too=tier > 0)
        if why:
            for k in members:
                graph.rejected[(edges[k].i, edges[k].j)] = why
            pending = [k for k in pending if k not in members]
            continue
        merge_groups(graph, i, j, z)
        graph.edges += [edges[k] for k in members]
        pending = [k for k in pending if k not in members]
    if p.group_fit:
        graph.edges += join_by_fit(graph, scans, walls, p)
    cuts = recheck_groups(graph, walls)
    for k in pending:
        e = edges[k]
        if graph.group[e.i] != graph.group[e.j]:
            graph.rejected[(e.i, e.j)] = cuts.get(frozenset((e.i, e.j))) or (
                "converged, but no link strong enough joins its two stations' groups (a loop closure needs "
                f"confidence {p.bridge_confidence:.2f} or more and, between groups of several scans, two "
                "stations on each side, and joins no passage seen from inside: its walls fit every passage of "
                "its width)" if strong[k] else
                "not converged, and no converged match joins its two stations' groups")
            continue
        solved = graph.pose[e.i].between(graph.pose[e.j])
        residual = solved.between(gtsam.Pose2(*e.z))
        if close_enough(residual, p, solved):
            graph.edges.append(e)
        else:
            graph.rejected[(e.i, e.j)] = (f"inconsistent with the other matches of the site: "
                                          f"{math.hypot(residual.x(), residual.y()):.2f} m and "
                                          f"{math.degrees(abs(wrap_angle(residual.theta()))):.1f}° off")
    return graph


def sequence_links(edges: Sequence[Edge], strong: Sequence[bool], confidence: Sequence[float | None],
                   p: SiteGraphParams) -> list[bool]:
    """For every edge, whether it is a sequence link (module docstring, step 2): its scans are consecutive
    stations and either the reverse match of the pair agrees with it and the more confident of the two
    has at least ``sequence_confidence`` (without a confidence, a converged match counts as sure and a
    tentative one as not), or it converged and the reverse match gave no estimate to compare with."""
    by_pair: dict[tuple[int, int], list[int]] = {}
    for k, e in enumerate(edges):
        by_pair.setdefault((e.i, e.j), []).append(k)
    sure = [float(strong[k]) if c is None else c for k, c in enumerate(confidence)]
    out = [False] * len(edges)
    for k, e in enumerate(edges):
        if abs(e.i - e.j) != 1:
            continue
        z = gtsam.Pose2(*e.z)
        reverse = by_pair.get((e.j, e.i), [])
        if not reverse:
            out[k] = bool(strong[k])
        for k2 in reverse:
            if max(sure[k], sure[k2]) >= p.sequence_confidence and close_enough(z.compose(gtsam.Pose2(*edges[k2].z)), p, z):
                out[k] = True
    return out
