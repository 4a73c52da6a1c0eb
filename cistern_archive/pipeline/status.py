"""How far a site build can be trusted: the site's status and the dimensions flagged weak.

A site is

* ``ok`` when the pipeline ran to the end, every scan was placed and every reference dimension was
  measured;
* ``partial`` when it ran to the end but some scan is unplaced, some dimension could not be measured, or
  two parts of the map are placed against each other less precisely than :data:`MAX_JOIN_CI95_M` (joins
  of groups of scans fitted as wholes whose 95 % intervals are wider, alone or together: the map may be
  wrong by that much without any match being wrong, :func:`imprecise_joins`); the report shows what was
  reached, with the reasons;
* ``failed`` when a stage stopped the build, or no scan at all could be placed.

A measured dimension is *weak* when it rests on fewer than :data:`MIN_PROBE_FRACTION` of the probes the
record asked for, or when its probes spread (sample standard deviation) by more than
:data:`MAX_PROBE_STD_M`: the probes then cross different walls (gaps, sloping or irregular walls) and
their mean is not one wall-to-wall distance; or when, on a site mapped at several depths, its walls
lean more than :data:`MAX_WALL_LEAN_DEG` from the vertical; or when a compass bias of the whole map
(its probes turned 2° about the station they are given from) would change it by more than
:data:`MAX_HEADING_SHIFT_M`. Weak dimensions do not change the status; they are flagged in every table and
in ``result.json``.

Reasons speak of stations by their labels: :func:`label_indices` rewrites the 0-based scan indices that
stages use internally (``scan 3``, ``(3,4)``) into the record's station labels.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from itertools import groupby
from typing import Literal

from cistern_archive.core.dimensions import HEADING_TURN_DEG

SiteStatus = Literal["ok", "partial", "failed"]

MIN_PROBE_FRACTION = 0.5
"""A dimension measured on fewer than this share of its requested probes is weak."""
MAX_PROBE_STD_M = 0.20
"""A dimension whose probes spread by more than this (sample std, metres) is weak."""
MAX_WALL_LEAN_DEG = 30.0
"""A dimension whose walls lean more than this from the vertical (:func:`cistern_archive.grid.lean.wall_lean_deg`)
is weak: the sonar's wide vertical beam hears a leaning wall nearer than it is. On the bundled bell-shaped
cistern (a 35° vertical beam), before the mapper corrected echoes for the lean
(:mod:`cistern_archive.grid.lobe`), the dimensions between walls leaning 23–25° lay within their 95 %
intervals; the one between walls leaning 45° came out 0.30 m (7.8 %) short, outside its interval. The
correction rests on the lean read between the slices, so such a dimension stays weak."""

MAX_HEADING_SHIFT_M = MAX_PROBE_STD_M
"""A dimension that changes by more than this (0.20 m, the limit of the probes' spread) when its probes
turn 2° about the station they are given from
(:attr:`~cistern_archive.core.dimensions.DimensionRow.heading_shift_m`: a compass bias of the whole map)
is weak. On the bundled three-chamber cistern a length probed from a
station 13.6 m away came out 0.19 m (3.6 %) short, its probes on a corner, and turning them 2° changed it
by 0.94 m; probed from a station of its own chamber it came out 0.005 m off, and turning changed it by
0.012 m. The water gallery's first reach (probes ending on the diagonal wall of a bend) changes by
0.68 m; the other demo dimensions by 0.009–0.13 m."""

MAX_JOIN_CI95_M = 0.25
"""A join of two parts of the map whose 95 % radius (the distance within which the one lies from where it
belongs against the other with 95 % probability) exceeds this makes the site ``partial``. On random
three-chamber cisterns (``benchmarks/sites.py --random``) group fits along a tunnel seen end to end joined
scans 0.17–0.29 m from where they belong with a standard deviation of about 0.33 m along the tunnel, and
the site was otherwise ``ok``."""

_SCAN_INDEX = re.compile(r"\b(scans?|station index) (\d+)\b")
_PAIR_INDEX = re.compile(r"\((\d+), ?(\d+)\)(?!\s*m\b)")


def label_indices(text: str, labels: Sequence[str]) -> str:
    """``text`` with 0-based scan indices replaced by station labels.

    ``scan 3`` becomes ``scan w4`` and a pair ``(3,4)`` becomes ``(w4 → w5)`` when ``labels[3]`` is
    ``w4``; indices out of range are left as they are.

    Examples
    --------
    >>> label_indices("no converged path to reference scan 0: (0,1): not converged", ["s1", "s2"])
    'no converged path to reference scan s1: (s1 → s2): not converged'
    """
    def scan(match: re.Match) -> str:
        k = int(match.group(2))
        return f"{match.group(1)} {labels[k]}" if 0 <= k < len(labels) else match.group(0)

    def pair(match: re.Match) -> str:
        i, j = int(match.group(1)), int(match.group(2))
        if 0 <= i < len(labels) and 0 <= j < len(labels):
            return f"({labels[i]} → {labels[j]})"
        return match.group(0)

    return _PAIR_INDEX.sub(pair, _SCAN_INDEX.sub(scan, text))


def weakness(n_probes: int, n_requested: int, probe_std_m: float | None, wall_lean_deg: float | None = None,
             *, heading_shift_m: float | None = None) -> str:
    """Why a measured dimension is weak (see the module docstring), or ``""`` when it is not."""
    reasons = []
    if n_requested > 1 and n_probes < MIN_PROBE_FRACTION * n_requested:
        reasons.append(f"measured on {n_probes} of {n_requested} probes (fewer than half)")
    if probe_std_m is not None and math.isfinite(probe_std_m) and probe_std_m > MAX_PROBE_STD_M:
        reasons.append(f"probe spread {probe_std_m:.2f} m above {MAX_PROBE_STD_M:.2f} m")
    if wall_lean_deg is not None and wall_lean_deg > MAX_WALL_LEAN_DEG:
        reasons.append(f"its walls lean about {wall_lean_deg:.0f}° from the vertical "
                       f"(above {MAX_WALL_LEAN_DEG:.0f}°): "
                       "the sonar's tall vertical beam hears a leaning wall nearer than it is, by an amount "
                       "that depends on the lean")
    if heading_shift_m is not None and heading_shift_m > MAX_HEADING_SHIFT_M:
        change = f"{heading_shift_m:.2f} m" if math.isfinite(heading_shift_m) else "more than its probes can tell"
        reasons.append(f"{HEADING_TURN_DEG:.0f}° of compass bias would change it by {change}"
                       f" (above {MAX_HEADING_SHIFT_M:.2f} m): its probes, given from a station, end far from "
                       "it on walls oblique to them or beside a corner or an opening; give them from a station "
                       "nearer the walls measured")
    return "; ".join(reasons)


def site_status(*, failed_stage: str | None, scans_placed: Sequence[bool], labels: Sequence[str],
                unmeasured: Sequence[str], joins: Sequence[tuple[str, str, float | None]] = (),
                loop_only: Sequence[tuple[str, Sequence[str]]] = ()) -> tuple[SiteStatus, list[str]]:
    """The status of a site build and the reasons it is not ``ok``.

    Parameters
    ----------
    failed_stage : str or None
        ``stage: input: error`` of the stage that stopped the build, ``None`` when it ran to the end.
    scans_placed : sequence of bool
        One flag per scan of the record.
    labels : sequence of str
        Station label per scan.
    unmeasured : sequence of str
        Names of the reference dimensions that could not be measured, each with its reason.
    joins : sequence of (str, str, float or None)
        The stations of each join of groups fitted as wholes with its 95 % radius in metres
        (``None`` when the localizer gave none); :func:`imprecise_joins` says which are reasons.
    loop_only : sequence of (str, sequence of str)
        Placed stations held in place only by matches to stations recorded apart from them, each with
        those stations (:func:`cistern_archive.pipeline.support.held_by_loops_only`); where some station
        is unplaced, each is a caveat (:func:`loop_only_caveat`).

    Returns
    -------
    status : {"ok", "partial", "failed"}
    reasons : list of str
        One line per problem, naming stations by label; empty when ``ok``.
    """
    reasons: list[str] = []
    if failed_stage is not None:
        reasons.append(f"the build stopped at {failed_stage}")
    n_placed = sum(bool(p) for p in scans_placed)
    if scans_placed and n_placed == 0 and failed_stage is None:
        reasons.append(f"none of the {len(scans_placed)} scans could be placed")
    elif n_placed < len(scans_placed) and failed_stage is None:
        unplaced = [labels[k] for k, p in enumerate(scans_placed) if not p]
        reasons.append(f"{len(unplaced)} of {len(scans_placed)} scans not placed ({', '.join(unplaced)})"
                       + "".join(f". {hint}" for hint in chain_breaks(scans_placed, labels)))
        reasons += [loop_only_caveat(station, others) for station, others in loop_only]
    if failed_stage is None and n_placed > 0:
        reasons += [f"dimension not measured: {text}" for text in unmeasured]
        reasons += imprecise_joins(joins)
    if failed_stage is not None or (scans_placed and n_placed == 0):
        return "failed", reasons
    return ("partial" if reasons else "ok"), reasons


def chain_breaks(scans_placed: Sequence[bool], labels: Sequence[str]) -> list[str]:
    """Where the survey's chain breaks, as advice for the next dive: for every run of unplaced scans in
    the record's order (the order the stations were visited), the placed station next to it and what
    would join the run to the map.

    Examples
    --------
    >>> chain_breaks([True, True, False, False], ["a1", "a2", "b1", "b2"])
    ["The survey's chain breaks between a2 and b1: a station between them, in sight of both, could join b1–b2 to the map"]
    """
    hints = []
    k = 0
    for placed, run in groupby(scans_placed, key=bool):
        n = len(list(run))
        if not placed and (k > 0 or k + n < len(scans_placed)):  # a run with a placed station beside it
            first, last = labels[k], labels[k + n - 1]
            near, far = (labels[k - 1], first) if k > 0 else (last, labels[k + n])
            span = first if n == 1 else f"{first}–{last}"
            hint = (f"The survey's chain breaks between {near} and {far}: a station between them, in sight "
                    f"of both, could join {span} to the map")
            if k > 0 and k + n < len(scans_placed):
                hint += ". " + skipped_run_caveat(labels[k - 1], labels[k + n], span, several=n > 1)
            hints.append(hint)
        k += n
    return hints


def loop_only_caveat(station: str, others: Sequence[str]) -> str:
    """The caveat of a placed station that only loop closures hold, on a site with unplaced stations
    (:mod:`cistern_archive.pipeline.support`)."""
    return (f"{station} is held in place only by matches to {', '.join(others)}, recorded apart from it, and by "
            "none to a station recorded next to it: a loop closure that the unplaced stations cannot confirm; "
            f"where chambers look alike {station} may stand in another's place, so check it against the mosaic")


def skipped_run_caveat(before: str, after: str, span: str, *, several: bool = False) -> str:
    """The caveat of a run of unplaced stations with placed ones on both sides (:func:`chain_breaks`):
    the stations visited before and after it are on the map, so something other than the survey's chain
    joined them — a loop closure or a fit of groups as wholes, the joins a look-alike chamber can
    mislead, with the stations that could contradict them unplaced (``benchmarks/RESULTS.md``,
    "2026-12-04": on the report seed of the random cisterns, one such site had its first chamber laid
    8 m off onto the last)."""
    pronoun = "them" if several else "it"
    return (f"{before} and {after}, visited before and after {span}, are joined without {pronoun}, by a loop "
            "closure or a fit of groups as wholes that the unplaced stations cannot confirm: where chambers look "
            "alike, one part may stand in another's place, so check the parts on either side against the mosaic")


def imprecise_joins(joins: Sequence[tuple[str, str, float | None]]) -> list[str]:
    """The status reasons of joins of groups (stations and 95 % radius, see :func:`site_status`): each
    join wider than :data:`MAX_JOIN_CI95_M`; or, when none is, all of them together if their radii
    add up (root sum of squares, as independent errors of joins in series do) to more than it. Two scans
    of the map are never separated by more joins than there are, so that sum bounds how far any part of
    the map may be off against any other through its joins."""
    known = [(a, b, ci) for a, b, ci in joins if ci is not None]
    wide = [(a, b, ci) for a, b, ci in known if ci > MAX_JOIN_CI95_M]
    if wide:
        return [f"the groups of stations {a} and {b} are placed against each other only to ±{ci:.2f} m (95 %, "
                f"above {MAX_JOIN_CI95_M:.2f} m): {_JOIN_CONSEQUENCE}" for a, b, ci in wide]
    together = math.sqrt(sum(ci**2 for _, _, ci in known))
    if len(known) < 2 or together <= MAX_JOIN_CI95_M:
        return []
    stations = ", ".join(f"{a}–{b}" for a, b, _ in known)
    return [f"the joins of groups {stations} together place parts of the map against each other only to "
            f"±{together:.2f} m (95 %, above {MAX_JOIN_CI95_M:.2f} m): {_JOIN_CONSEQUENCE}"]


_JOIN_CONSEQUENCE = ("no match joins them, the fit of the groups as wholes leaves one direction uncertain, and parts "
                     "of the map may be misplaced by that much")
