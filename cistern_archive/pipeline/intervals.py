"""95 % intervals of the map's dimensions.

A dimension is the mean of ``n`` parallel probes drawn wall to wall in an evidence grid of cell size
``c``, between walls seen from scans whose placement the localizer may give an uncertainty for. Four
independent sources are combined in quadrature:

* **probe spread**: the standard error of the mean of the probes, ``t(0.975, n − 1) · s / √n`` (Student's
  t; a single probe has no spread to estimate and contributes nothing);
* **grid cell**: each wall is found to within one cell, a uniform error of width ``c`` per wall, so
  ``1.96 · c / √6`` for the two walls together;
* **pose**: the scans nearest to the two ends of the probes saw the two walls; when they differ, their
  position covariances (``Poses.covariance``, e.g. from the ``pose-graph`` localizer) projected on the
  probe direction add ``1.96 · √(uᵀ(Σ_a + Σ_b)u)``; one scan seeing both walls moves them together and
  adds nothing. Localizers without covariances (``wls``) add nothing here;
* **heading**: the map's north is the compasses', off by their common bias, and the record gives the
  probes from a station, so the map measures them turned by that bias about the station. The comparator
  measures them again turned 2° either way (``DimensionRow.heading_shift_m``, a compass bias of 2° taken
  as the 95 % bound) and the larger change is the term; it is small where the probes end on walls square
  to them and large where they end far from the station on oblique walls or beside a corner. A
  comparator that does not say adds nothing.

``ci95_m`` is the half-width: the dimension is shown as ``3.47 ± 0.06 m``. How often these intervals
hold the true value on simulated sites is measured by ``benchmarks/intervals.py``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import stats

from cistern_archive.pipeline.contracts import Poses

Z95 = 1.959963984540054


def spread_term(probes: Sequence[float]) -> float:
    """``t(0.975, n − 1) · s / √n`` of the probes (0 for fewer than two)."""
    n = len(probes)
    if n < 2:
        return 0.0
    return float(stats.t.ppf(0.975, n - 1) * np.std(probes, ddof=1) / math.sqrt(n))


def cell_term(cell_m: float) -> float:
    """``1.96 · c / √6``: two walls, each within a cell."""
    return Z95 * cell_m / math.sqrt(6.0)


def pose_term(lines: Sequence[tuple[float, float, float, float]], poses: Poses | None) -> float:
    """``1.96 · √(uᵀ(Σ_a + Σ_b)u)`` of the scans nearest to the two ends of the probe lines (0 without
    covariances, or when one scan is nearest to both ends)."""
    if poses is None or poses.covariance is None or not lines:
        return 0.0
    placed = np.flatnonzero(np.asarray(poses.placed, dtype=bool))
    if len(placed) == 0:
        return 0.0
    ends = np.asarray(lines, dtype=float)
    a, b = ends[:, :2].mean(axis=0), ends[:, 2:].mean(axis=0)
    xy = np.asarray(poses.xy_m, dtype=float)[placed]
    near_a = placed[int(np.argmin(np.linalg.norm(xy - a, axis=1)))]
    near_b = placed[int(np.argmin(np.linalg.norm(xy - b, axis=1)))]
    if near_a == near_b:
        return 0.0
    u = (b - a) / max(float(np.linalg.norm(b - a)), 1e-12)
    cov = np.asarray(poses.covariance, dtype=float)
    variance = float(u @ (cov[near_a, :2, :2] + cov[near_b, :2, :2]) @ u)
    return Z95 * math.sqrt(variance) if math.isfinite(variance) and variance > 0 else 0.0


def heading_term(heading_shift_m: float | None) -> float:
    """The change of the dimension under 2° of compass bias (0 when unknown or not finite: a probe that
    finds no wall once turned is flagged weak instead, :func:`cistern_archive.pipeline.status.weakness`)."""
    return heading_shift_m if heading_shift_m is not None and math.isfinite(heading_shift_m) else 0.0


def ci95_half_width(probes: Sequence[float], cell_m: float,
                    lines: Sequence[tuple[float, float, float, float]] = (), poses: Poses | None = None,
                    heading_shift_m: float | None = None) -> float:
    """Half-width of the 95 % interval of a dimension (see the module docstring)."""
    terms = (spread_term(probes), cell_term(cell_m), pose_term(lines, poses), heading_term(heading_shift_m))
    return float(math.sqrt(sum(term ** 2 for term in terms)))
