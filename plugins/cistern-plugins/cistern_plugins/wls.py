"""Scan localisation by weighted least squares (McVicker et al., eqs. 7–10 and Table III).

For every neighbouring pair ``(i, j = i + 1)`` the matcher's converged estimates give up to four kinds
of measurement of ``d_ij = p_j - p_i`` (eq. 7):

1. ``z_ij`` (scan j located in scan i's map),
2. ``-z_ji`` (the reverse match; ``z_ji != -z_ij`` in general),
3. ``z_ik + z_kj`` for every third scan ``k`` with both matches converged,
4. ``-(z_jk + z_ki)`` likewise through the reverse matches.

A match also carries a heading correction (the matcher's θ), and ``z_kj`` is measured in scan k's
compass frame. The sums and negations above are therefore done as compositions of planar motions
(:func:`compose`, :func:`invert`), which reduce to the paper's plain sums when the corrections are zero;
positions are chained the same way, so a scan whose compass reads 2° off does not bend the rest of the
site by 2°.

Setting ``dS/dd_ij = 0`` (eq. 9) gives the weighted mean of eq. 10. Each direct measurement is
weighted by its converged weight ``w_mu`` (eq. 6). The paper derives the pseudo-measurements' weights
"from the first two in the same manner"; here a chained measurement gets ``w_a * w_b / (w_a + w_b)``,
the weight of a sum of two independent measurements whose variances are ``1 / w`` (so a chain is never
trusted more than its weaker link). Weights are floored at ``min_weight`` so that a converged match
with ``w_mu <= 0`` (possible when ``tau_pw <= 0``) still counts a little. The same weighted mean
is applied to the heading correction (third component).

Positions (Table III): the reference scan is the first scan (lowest index) that has a converged match
with another scan; it sits at the origin. ``solve="chain"`` places the other scans by adding the
``d_ij`` of neighbouring pairs outwards from the reference, as the paper does (a break in the chain
leaves the scans beyond it unplaced); ``solve="global"`` instead solves one least-squares problem over
every pair with an estimate (neighbours and, with ``third_scan``, the ``(i, i+2)`` pairs too), which can
bridge a failed neighbour pair. Scans without a path to the reference are unplaced with the reason.

Vertical ties
-------------
A scan recorded as taken ``below`` another station (the vehicle descended vertically between them,
:class:`cistern_archive.catalog.models.ScanRef`) gives a pseudo-measurement ``d = (0, 0, 0)`` of weight
``tie_weight`` between the two: the same horizontal position, the compasses trusted for the heading. It
replaces any match of that pair (scans at different depths of a bell-shaped cistern see different
outlines, so a match between them is not a measurement of their displacement) and joins the depth
levels, each of which is otherwise localised from its own matches. This is the record-level form of the
paper's manual alignment of depth levels ("manual mosaicking was used to align the scans in the third
dimension"). The pipeline runner passes the record's ties to :meth:`WLSLocalizer.localize`
(``ties``, :class:`~cistern_archive.pipeline.contracts.VerticalTie`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from cistern_archive.pipeline.contracts import MatchResult, Poses, StageParams, VerticalTie
from cistern_archive.core.scan import RangeScan


class WLSParams(StageParams):
    """Parameters of :class:`WLSLocalizer`."""

    third_scan: bool = Field(True, description="also match (i, i+2) pairs for the pseudo-measurements")
    max_gap: int = Field(2, ge=1, le=10, description="match every pair with |i - j| <= max_gap (needs third_scan)")
    solve: Literal["chain", "global"] = "chain"
    min_weight: float = Field(1e-3, gt=0, description="floor of a converged measurement's weight")
    use_yaw: bool = Field(True, description="apply the matcher's heading corrections")
    tie_weight: float = Field(10.0, gt=0, description="weight of a vertical tie (a converged match is ~0.3-0.9)")


Measurement = tuple[np.ndarray, float]
"""A measurement of (dx, dy, dyaw) and its weight."""


class WLSLocalizer:
    """Weighted-least-squares localiser (``wls``)."""

    name: ClassVar[str] = "wls"
    Params: ClassVar[type[StageParams]] = WLSParams

    def pairs(self, n_scans: int, params: StageParams) -> list[tuple[int, int]]:
        """Directed pairs: neighbours both ways (Table I), then the third-scan pairs up to ``max_gap``."""
        p = WLSParams.of(params)
        gaps = range(1, (p.max_gap if p.third_scan else 1) + 1)
        out: list[tuple[int, int]] = []
        for gap in gaps:
            for i in range(n_scans - gap):
                out += [(i, i + gap), (i + gap, i)]
        return out

    def localize(self, scans: Sequence[RangeScan], matches: Sequence[MatchResult], params: StageParams, *,
                 ties: Sequence[VerticalTie] = ()) -> Poses:
        """Eq. 10 for every neighbouring pair and the vertical ``ties``, then place the scans from the
        reference (Table III)."""
        p = WLSParams.of(params)
        n = len(scans)
        z = converged_measurements(matches, p.min_weight)
        reasons = _pair_reasons(matches)
        tied = vertical_ties(scans, ties)
        for a, b in tied:
            z[(a, b)] = z[(b, a)] = (np.zeros(3), p.tie_weight)
        edges = {(i, i + 1): combine(i, i + 1, z, n) for i in range(n - 1)}
        edges.update({(a, b): combine(a, b, z, n) for a, b in tied})
        if p.solve == "global":
            edges.update({(i, j): combine(i, j, z, n) for (i, j) in z if i < j and (i, j) not in edges})
        edges = {k: v for k, v in edges.items() if v is not None}
        if not p.use_yaw:
            edges = {k: (d * np.array([1.0, 1.0, 0.0]), w) for k, (d, w) in edges.items()}
        ref = next((k for k in range(n) if any(k in pair for pair in z)), -1)
        xy = np.full((n, 2), np.nan)
        yaw_corr = np.zeros(n)
        placed = np.zeros(n, dtype=bool)
        if ref >= 0:
            if p.solve == "chain":
                _chain(ref, edges, xy, yaw_corr, placed)
            else:
                _global(ref, edges, xy, yaw_corr, placed)
        yaw = np.array([s.yaw_rad for s in scans]) + np.where(placed, yaw_corr, 0.0)
        why = tuple("" if placed[k] else _unplaced_reason(k, ref, reasons) for k in range(n))
        return Poses(xy_m=xy, yaw_rad=yaw, placed=placed, reasons=why, reference=ref)


def vertical_ties(scans: Sequence[RangeScan], ties: Sequence[VerticalTie]) -> list[tuple[int, int]]:
    """Index pairs ``(min, max)`` of the scans joined by ``ties``, in the order of the ties' stations.

    Raises
    ------
    ValueError
        A station named in a tie is not one of the scans.
    """
    index = {s.station: k for k, s in enumerate(scans)}
    out = []
    for lower, upper in sorted((t.lower, t.upper) for t in ties):
        missing = [name for name in (lower, upper) if name not in index]
        if missing:
            raise ValueError(f"vertical tie {lower!r} below {upper!r}: no scan of station {missing[0]!r}")
        a, b = sorted((index[lower], index[upper]))
        if a != b:
            out.append((a, b))
    return out


def converged_measurements(matches: Sequence[MatchResult], min_weight: float) -> dict[tuple[int, int], Measurement]:
    """``z_ij`` and its weight for every converged directed match (the last one wins on repeats)."""
    out: dict[tuple[int, int], Measurement] = {}
    for m in matches:
        if m.converged and np.isfinite([m.dx_m, m.dy_m, m.dyaw_rad]).all():
            w = max(float(m.weight), min_weight) if np.isfinite(m.weight) else min_weight
            out[(m.i, m.j)] = (np.array([m.dx_m, m.dy_m, m.dyaw_rad]), w)
    return out


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``z_ik`` then ``z_kj`` → ``z_ij``: ``z_kj``'s translation is in scan k's compass frame, which is
    scan i's turned by ``z_ik``'s heading correction; with no heading corrections this is ``a + b``."""
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def invert(a: np.ndarray) -> np.ndarray:
    """``z_ji`` → an estimate of ``z_ij`` (``-z_ji`` when there is no heading correction)."""
    c, s = np.cos(-a[2]), np.sin(-a[2])
    return np.array([-(c * a[0] - s * a[1]), -(s * a[0] + c * a[1]), -a[2]])


def _series(a: Measurement, b: Measurement) -> Measurement:
    """The pseudo-measurement ``z_a ∘ z_b`` with the weight of a sum of independent terms."""
    (za, wa), (zb, wb) = a, b
    return compose(za, zb), wa * wb / (wa + wb)


def estimates(i: int, j: int, z: dict[tuple[int, int], Measurement], n: int) -> list[Measurement]:
    """The measurements of ``d_ij`` of eq. 7 (n = 1..4, every third scan ``k`` for n = 3, 4)."""
    out: list[Measurement] = []
    if (i, j) in z:
        out.append(z[(i, j)])
    if (j, i) in z:
        zji, wji = z[(j, i)]
        out.append((invert(zji), wji))
    for k in range(n):
        if k in (i, j):
            continue
        if (i, k) in z and (k, j) in z:
            out.append(_series(z[(i, k)], z[(k, j)]))
        if (j, k) in z and (k, i) in z:
            zji, w = _series(z[(j, k)], z[(k, i)])
            out.append((invert(zji), w))
    return out


def combine(i: int, j: int, z: dict[tuple[int, int], Measurement], n: int) -> Measurement | None:
    """Eq. 10: the weighted mean of the estimates of ``d_ij`` and the total weight (``None`` if none)."""
    est = estimates(i, j, z, n)
    if not est:
        return None
    values = np.array([e[0] for e in est])
    weights = np.array([e[1] for e in est])
    mean = (weights[:, None] * values).sum(axis=0) / weights.sum()
    mean[2] = np.arctan2(
        (weights * np.sin(values[:, 2])).sum(), (weights * np.cos(values[:, 2])).sum()
    )
    return mean, float(weights.sum())


def _neighbours(edges: dict[tuple[int, int], Measurement]) -> dict[int, list[tuple[int, np.ndarray]]]:
    adj: dict[int, list[tuple[int, np.ndarray]]] = {}
    for (i, j), (d, _) in sorted(edges.items()):
        adj.setdefault(i, []).append((j, d))
        adj.setdefault(j, []).append((i, invert(d)))
    return adj


def _chain(ref: int, edges: dict, xy: np.ndarray, yaw: np.ndarray, placed: np.ndarray) -> None:
    """Table III: positions by adding ``d_ij`` outwards from the reference (breadth first)."""
    adj = _neighbours(edges)
    xy[ref] = 0.0
    placed[ref] = True
    queue = deque([ref])
    while queue:
        a = queue.popleft()
        for b, d in adj.get(a, []):
            if not placed[b]:
                pose_b = compose(np.array([xy[a, 0], xy[a, 1], yaw[a]]), d)
                xy[b] = pose_b[:2]
                yaw[b] = pose_b[2]
                placed[b] = True
                queue.append(b)


def _global(ref: int, edges: dict, xy: np.ndarray, yaw: np.ndarray, placed: np.ndarray) -> None:
    """One weighted least-squares fit of all positions to all pair estimates, the reference fixed at 0."""
    _chain(ref, edges, xy, yaw, placed)  # the connected component and a starting point
    nodes = [k for k in range(len(placed)) if placed[k] and k != ref]
    if not nodes:
        return
    col = {k: c for c, k in enumerate(nodes)}
    rows, rhs, w = [], [], []
    for (i, j), (d, weight) in sorted(edges.items()):
        if not (placed[i] and placed[j]):
            continue
        row = np.zeros(len(nodes))
        if j in col:
            row[col[j]] += 1.0
        if i in col:
            row[col[i]] -= 1.0
        rows.append(row)
        rotated = compose(np.array([0.0, 0.0, yaw[i]]), d)
        rhs.append(np.array([rotated[0], rotated[1], d[2]]))
        w.append(np.sqrt(weight))
    a = np.array(rows) * np.array(w)[:, None]
    b = np.array(rhs) * np.array(w)[:, None]
    solution, *_ = np.linalg.lstsq(a, b, rcond=None)
    for k, c in col.items():
        xy[k] = solution[c, :2]
        yaw[k] = solution[c, 2]


def _pair_reasons(matches: Sequence[MatchResult]) -> dict[tuple[int, int], str]:
    return {(m.i, m.j): (m.reason or "not converged") for m in matches if not m.converged}


def _unplaced_reason(k: int, ref: int, reasons: dict[tuple[int, int], str]) -> str:
    if ref < 0:
        return "no pair of scans converged, so there is no reference scan"
    failed = [
        f"({a},{b}): {reasons[(a, b)]}"
        for a, b in ((k - 1, k), (k, k - 1), (k, k + 1), (k + 1, k))
        if (a, b) in reasons
    ]
    detail = "; ".join(failed) if failed else "its neighbours are unplaced"
    return f"no converged path to reference scan {ref}: {detail}"
