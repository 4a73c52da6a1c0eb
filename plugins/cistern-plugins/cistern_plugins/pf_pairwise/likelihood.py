"""The map ``m_i`` of the reference scan and the per-beam score of eqs. 3–4 against it.

:class:`LikelihoodMap` is ``m_i`` ready for weighting (Table I, line 2): the occupancy look-up for ray
casting and the likelihood field, the per-cell contribution precomputed once per map; :func:`weigh`
gives every particle's mean per-beam weight; :class:`MapCache` keeps the maps of the few pairs that
share a reference scan.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from cistern_archive.core.scan import RangeScan
from cistern_archive.grid.evidence import DenseMap, SonarModel, dense_scan_map
from cistern_archive.grid.raycast import FAR_M, OccupancyLookup
from cistern_plugins.pf_pairwise.params import PFParams


@dataclass(frozen=True, eq=False)
class Beams:
    """The moving scan's beams used for weighting: range and map-frame direction at θ = 0."""

    ranges: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    def subsample(self, n: int) -> "Beams":
        """At most ``n`` of the beams, evenly spread."""
        if self.ranges.size <= n:
            return self
        keep = np.linspace(0, self.ranges.size - 1, n).round().astype(np.int64)
        return Beams(ranges=self.ranges[keep], cos=self.cos[keep], sin=self.sin[keep])


def select_beams(scan: RangeScan, max_beams: int) -> Beams:
    """The beams of ``scan`` with an echo, at most ``max_beams`` of them (evenly subsampled)."""
    idx = np.flatnonzero(scan.valid)
    if idx.size > max_beams:
        idx = idx[np.linspace(0, idx.size - 1, max_beams).round().astype(np.int64)]
    angle = scan.yaw_rad + scan.bearings_rad[idx]
    return Beams(ranges=scan.ranges_m[idx], cos=np.cos(angle), sin=np.sin(angle))


@dataclass(frozen=True, eq=False)
class LikelihoodMap:
    """``m_i`` ready for weighting: occupancy look-up, the likelihood field at ``σc = 2 r_c``
    (``score_flat``), where ``m_i`` has evidence (``known_flat``), and the field smoothed to the
    ambiguity search's step (``coarse_flat``); flat arrays indexed by :meth:`OccupancyLookup.flat_index`."""

    dense: DenseMap
    lookup: OccupancyLookup
    score_flat: np.ndarray
    known_flat: np.ndarray
    coarse_flat: np.ndarray

    @classmethod
    def build(cls, reference: RangeScan, p: PFParams) -> "LikelihoodMap":
        """``m_i`` of Table I, line 2, from the reference scan alone (its sonar at the origin)."""
        sonar = SonarModel(
            l_occ=p.map.l_occ, l_free=p.map.l_free, free_no_echo=False,
            occupied_width_rad=occupied_width(reference, p.map.occupied),
            free_width_rad=occupied_width(reference, p.map.free),
        )
        dense = dense_scan_map(reference, cell_m=p.map.cell_m, model=sonar,
                               margin_m=p.filter.delta_max_m + p.map.cell_m)
        lookup = OccupancyLookup(dense.occupied(p.map.weight_threshold), dense.origin_xy_m, dense.cell_m)
        known = np.zeros((dense.log_odds.shape[0] + 2, dense.log_odds.shape[1] + 2), dtype=bool)
        known[1:-1, 1:-1] = dense.log_odds != 0
        known = known.ravel()

        def field(sigma_c: float) -> np.ndarray:
            score = beam_score(lookup.distance_flat, p, sigma_c)
            return np.where(known | (score > 0), score, np.float32(p.filter.unknown_score)).astype(np.float32)

        return cls(dense=dense, lookup=lookup, score_flat=field(2.0 * p.map.cell_m), known_flat=known,
                   coarse_flat=field(max(2.0 * p.map.cell_m, p.verify.step_m)))


class MapCache:
    """The last few maps built, keyed by the reference scan and the parameters that shape ``m_i``."""

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self._maps: OrderedDict[bytes, LikelihoodMap] = OrderedDict()

    def get(self, reference: RangeScan, p: PFParams) -> LikelihoodMap:
        """The map of ``reference`` (built on first use)."""
        key = _map_key(reference, p)
        if key in self._maps:
            self._maps.move_to_end(key)
            return self._maps[key]
        model = self._maps[key] = LikelihoodMap.build(reference, p)
        while len(self._maps) > self.size:
            self._maps.popitem(last=False)
        return model


def _map_key(scan: RangeScan, p: PFParams) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(scan.bearings_rad).tobytes())
    h.update(np.ascontiguousarray(scan.ranges_m).tobytes())
    h.update(repr((scan.yaw_rad, scan.bin_size_m, scan.beam_width_rad, scan.max_range_m)).encode())
    h.update(repr((p.map, p.filter.delta_max_m, p.filter.unknown_score, p.verify.step_m)).encode())
    return h.digest()


def occupied_width(scan: RangeScan, mode: str) -> float | None:
    """Angular width marked occupied around each echo in ``m_i`` (``None``: the whole beam cone)."""
    if mode == "cone":
        return None
    if mode == "axis" or scan.bearings_rad.size < 2:
        return 0.0
    b = np.sort((np.asarray(scan.bearings_rad) + np.pi) % (2 * np.pi) - np.pi)
    gaps = np.diff(np.append(b, b[0] + 2 * np.pi))
    return float(np.median(gaps[gaps > 1e-9])) if np.any(gaps > 1e-9) else 0.0


def beam_score(distance: np.ndarray, p: PFParams, sigma_c: float | None = None) -> np.ndarray:
    """Per-beam contribution of eqs. 3–4 as a function of ``|δs - δm|`` (float32): ``+φ`` inside
    ``δmax``, ``-(1 - φ)`` outside, ``φ = exp(-d² / 2σc²)`` with ``σc = 2 r_c`` by default."""
    sigma_c = 2.0 * p.map.cell_m if sigma_c is None else sigma_c
    d = distance.astype(np.float64)
    phi = np.exp(-(d * d) / (2.0 * sigma_c * sigma_c))
    return np.where(d < p.filter.delta_max_m, phi, -(1.0 - phi)).astype(np.float32)


def weigh(model: LikelihoodMap, beams: Beams, particles: np.ndarray, p: PFParams) -> np.ndarray:
    """Mean per-beam weight (eqs. 3–4) of every particle, shape (P,)."""
    f = p.filter
    x, y, th = particles[:, 0:1], particles[:, 1:2], particles[:, 2:3]
    c, s = np.cos(th), np.sin(th)
    ux = c * beams.cos - s * beams.sin  # (P, B) beam directions
    uy = s * beams.cos + c * beams.sin
    n_beams = beams.ranges.size
    if f.measurement_model == "distance-field":
        flat = model.lookup.flat_index(x + beams.ranges * ux, y + beams.ranges * uy)
        total = model.score_flat[flat].sum(axis=1, dtype=np.float64)
        if f.min_informative >= 1.0:
            return total / n_beams
        informative = (model.known_flat[flat] | (model.score_flat[flat] > 0)).sum(axis=1)
        return total / np.maximum(informative, f.min_informative * n_beams)
    angle = np.arctan2(uy, ux)
    hit = model.lookup.sphere_trace(x, y, angle, beams.ranges + f.delta_max_m)
    diff = np.where(np.isfinite(hit), np.abs(beams.ranges - hit), FAR_M)
    sigma_c = 2.0 * p.map.cell_m
    phi = np.exp(-(diff * diff) / (2.0 * sigma_c * sigma_c))
    score = np.where(diff < f.delta_max_m, phi, -(1.0 - phi))
    if f.unknown_score == -1.0 and f.min_informative >= 1.0:
        return score.mean(axis=1)
    end_known = model.known_flat[model.lookup.flat_index(x + beams.ranges * ux, y + beams.ranges * uy)]
    informative = np.isfinite(hit) | end_known
    score = np.where(informative, score, f.unknown_score)
    if f.min_informative >= 1.0:
        return score.mean(axis=1)
    return score.sum(axis=1) / np.maximum(informative.sum(axis=1), f.min_informative * n_beams)
