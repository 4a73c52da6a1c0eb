"""The joined groups checked again once they are whole (step 2 of :mod:`cistern_plugins.site_graph`).

The wall check judges a join when it is made (:meth:`~cistern_plugins.site_groups.WallCheck.conflict`),
between the groups as they are then — often one scan joined to a group of three. Two look-alike chambers
joined through an opening show it: the station in the next chamber, matched with the station in the
opening, fits the first chamber's walls as well as its own, and laid onto the first chamber it puts a
little of its walls into the water the first chamber's sonars saw, and they theirs into its water — both
ways, for every pair. Over three pairs the wall check cannot weigh that (right joins of three pairs reach
2.2–2.4 % under heavy multipath, :data:`~cistern_plugins.site_groups.TWO_WAY_PAIRS`); once the rest of the
chamber and the stations beyond it have joined the moved scan, the same join holds many more pairs, and
the median over them tells.

So when every join is made, each group is split in two every way the survey allows — a run of stations
visited one after another against the rest of the group (a chamber, or a chamber and what lies beyond it,
entered once) — and each split is judged over the pairs of its two parts that share walls: where five or
more such pairs put a median of more than :data:`SETTLED_TWO_WAY_SHARE` of their wall points into each
other's water both ways, one such split is cut. A look-alike join displaces everything placed through
it, so the split cut is the one that parts the most pairs in conflict (the stations beyond a look-alike
chamber, placed through it, go with it). The smaller part leaves the group (and so is not placed, with
the reason), every match across the cut is rejected, and the groups left are judged again. A part
that its own matches do not hold together is never cut off, nor left behind.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from cistern_plugins.factor_graph import spanning_tree
from cistern_plugins.site_groups import (
    TWO_WAY_PAIRS,
    Graph,
    JoinPair,
    WallCheck,
    sharing_pairs,
    two_way_share,
)

SETTLED_TWO_WAY_SHARE = 0.008
"""Median two-way share (:func:`~cistern_plugins.site_groups.two_way_share`) over the pairs of the two parts
of a split that share walls (:data:`~cistern_plugins.site_groups.TWO_WAY_PAIRS` or more), above which the
split is cut. Set between right and wrong groups judged so on the tuning seeds (``benchmarks/wall_tests.py``,
``settled`` figures; ``benchmarks/RESULTS.md``, "2026-12-05 (session 9)")."""


@dataclass(frozen=True)
class Split:
    """A group split into a run of stations visited one after another and the rest, with the pairs of
    the two parts that share walls and their median two-way share."""

    run: list[int]
    rest: list[int]
    sharing: list[JoinPair]
    share: float

    @property
    def conflicts(self) -> int:
        """How many of the pairs put more than :data:`SETTLED_TWO_WAY_SHARE` of their walls into each other's
        water both ways."""
        return sum(p.quality.violation_min > SETTLED_TWO_WAY_SHARE for p in self.sharing)


def runs_of(members: Sequence[int]) -> Iterator[tuple[list[int], list[int]]]:
    """Every split of a group's scans (indexed in the survey's order) into a run of consecutive members
    and the rest, each part non-empty."""
    for start in range(len(members)):
        for stop in range(start + 1, len(members) + 1):
            if stop - start < len(members):
                yield list(members[start:stop]), list(members[:start]) + list(members[stop:])


def held_together(part: Sequence[int], graph: Graph) -> bool:
    """Whether the accepted edges and ties among a part's scans join all of them."""
    inside = set(part)
    links = [e for e in list(graph.edges) + list(graph.ties) if e.i in inside and e.j in inside]
    return inside <= set(spanning_tree(len(graph.group), links, part[0]))


def pair_quality(walls: WallCheck, graph: Graph, a: int, b: int, known: dict[tuple[int, int], list[JoinPair]]
                 ) -> list[JoinPair]:
    """The assessment of scans ``a`` and ``b`` at the graph's poses, both ways (:meth:`~cistern_plugins.
    site_groups.WallCheck.assess_sides`; empty when they are not at one level within range), kept in
    ``known`` for the other splits."""
    key = (min(a, b), max(a, b))
    if key not in known:
        known[key] = walls.assess_sides([key[0]], graph.pose, [key[1]], graph.pose)
    return known[key]


def settled_splits(walls: WallCheck, graph: Graph, known: dict[tuple[int, int], list[JoinPair]]) -> list[Split]:
    """Every split of every group (:func:`runs_of`) with enough pairs sharing walls to be judged."""
    out = []
    for g in sorted(set(graph.group)):
        for run, rest in runs_of(graph.members(g)):
            pairs = [q for a in run for b in rest for q in pair_quality(walls, graph, a, b, known)]
            sharing = sharing_pairs(pairs, walls.limits)
            if len(sharing) >= TWO_WAY_PAIRS:
                out.append(Split(run, rest, sharing, two_way_share(sharing)))
    return out


def run_name(walls: WallCheck, split: Split) -> str:
    """The split's run of stations by its first and last labels (``b1 … c2``)."""
    run = [walls.label(k) for k in split.run]
    return run[0] if len(run) == 1 else f"{run[0]} … {run[-1]}"


def cut_reason(walls: WallCheck, split: Split) -> str:
    """Why the smaller part of a cut split is not placed with the rest."""
    named = run_name(walls, split)
    return (f"the stations {named}, visited one after another, and the rest of their group put walls into water "
            f"both ways once placed together: over {len(split.sharing)} pairs of stations, a median "
            f"{100 * split.share:.1f} % of each sonar's wall points fall in the water the other saw (at most "
            f"{100 * SETTLED_TWO_WAY_SHARE:.1f} %), as a look-alike chamber laid onto another; the smaller part "
            "is left unplaced")


def recheck_groups(graph: Graph, walls: WallCheck) -> dict[frozenset[int], str]:
    """Judge every group again (module docstring) and cut the split over the limit that parts the most
    pairs in conflict, among those whose two parts their own edges hold together, until none is left: the
    smaller part (the one without the earliest scan, between equals) becomes a group of its own, the
    edges across the cut leave ``graph.edges`` (rejected as joining the two parts) and its scans keep
    the reason in ``graph.cut``. Returns the reason of a match for every pair of scans across a
    cut."""
    across: dict[frozenset[int], str] = {}
    known: dict[tuple[int, int], list[JoinPair]] = {}
    while True:
        over = [s for s in settled_splits(walls, graph, known) if s.share > SETTLED_TWO_WAY_SHARE
                and held_together(s.run, graph) and held_together(s.rest, graph)]
        if not over:
            return across
        split = max(over, key=lambda s: (s.conflicts, s.share, -min(s.run)))
        why = cut_reason(walls, split)
        across_why = (f"joins the stations {run_name(walls, split)} to the rest of their group; placed together, "
                      "the two put walls into each other's water (a look-alike chamber)")
        keep, cut = sorted((split.run, split.rest), key=lambda part: (len(part), -min(part)), reverse=True)
        for part in (keep, cut):
            for k in part:
                graph.group[k] = min(part)
        graph.fitted = [f for f in graph.fitted if graph.group[f[0]] == graph.group[f[1]]]
        for e in graph.edges:
            if graph.group[e.i] != graph.group[e.j]:
                graph.rejected[(e.i, e.j)] = across_why
        graph.edges = [e for e in graph.edges if graph.group[e.i] == graph.group[e.j]]
        for k in cut:
            graph.cut[k] = why
        across.update({frozenset((a, b)): across_why for a in keep for b in cut})
