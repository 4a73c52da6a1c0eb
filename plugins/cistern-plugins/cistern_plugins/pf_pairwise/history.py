"""What one run of the filter keeps for the report: the averages of eqs. 5–6 and a few particle clouds."""

from __future__ import annotations

import numpy as np

from cistern_archive.pipeline.contracts import HistoryThreshold, MatchHistory
from cistern_plugins.pf_pairwise.params import PFParams


class ParticleHistory:
    """Collects the per-iteration averages and a few particle snapshots (at iterations 0, 1, 2, 4, 8, ...
    and the last); :meth:`finish` keeps ``history.snapshots`` of them, evenly spread."""

    def __init__(self, p: PFParams):
        self.p = p
        self.weight: list[float] = []
        self.std: list[float] = []
        self.snaps: list[tuple[int, np.ndarray]] = []

    def record(self, iteration: int, w_avg: float, s_avg: float, particles: np.ndarray, w: np.ndarray) -> None:
        """The averages of ``iteration`` (and its particles, at a power of two)."""
        self.weight.append(w_avg)
        self.std.append(s_avg)
        if self.p.history.snapshots and (iteration & (iteration - 1)) == 0:
            self.snaps.append((iteration, self._snapshot(particles, w)))

    def _snapshot(self, particles: np.ndarray, w: np.ndarray) -> np.ndarray:
        k = min(len(particles), self.p.history.particles)
        idx = np.linspace(0, len(particles) - 1, k).round().astype(np.int64)
        return np.column_stack([particles[idx], w[idx]]).astype(np.float32)

    def finish(self, iteration: int, particles: np.ndarray, w: np.ndarray) -> MatchHistory:
        """The history, with the last iteration's particles and the thresholds of eqs. 5–6
        (``tau_pw`` on the weight average, ``r_c`` on the position std)."""
        thresholds = dict(weight_threshold=HistoryThreshold(self.p.filter.tau_pw, "τ_pw"),
                          std_threshold=HistoryThreshold(self.p.map.cell_m, "r_c"))
        if self.p.history.snapshots == 0:
            return MatchHistory(weight_avg=np.array(self.weight), std_avg=np.array(self.std), **thresholds)
        if not self.snaps or self.snaps[-1][0] != iteration:
            self.snaps.append((iteration, self._snapshot(particles, w)))
        n = min(self.p.history.snapshots, len(self.snaps))
        pick = sorted(set(np.linspace(0, len(self.snaps) - 1, n).round().astype(int).tolist()))
        chosen = [self.snaps[k] for k in pick]
        return MatchHistory(
            weight_avg=np.array(self.weight),
            std_avg=np.array(self.std),
            snapshots=tuple(s for _, s in chosen),
            snapshot_iterations=tuple(int(t) for t, _ in chosen),
            **thresholds,
        )
