"""What a comparator returns: each reference dimension measured in the map."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class DimensionRow:
    """One measured dimension against its reference (the paper's Table IV, one cell pair).

    ``probes`` are the individual probe measurements (m) whose mean is ``map_m``; ``probe_lines`` the
    map-frame segments (x0, y0, x1, y1) each probe measured, for the report's figure.
    """

    name: str
    map_m: float
    reference_m: float
    reference_kind: str
    diff_m: float
    depth_m: float = 0.0
    probes: tuple[float, ...] = ()
    probe_lines: tuple[tuple[float, float, float, float], ...] = ()
    note: str = ""

    @property
    def probe_std_m(self) -> float:
        return float(np.std(self.probes, ddof=1)) if len(self.probes) > 1 else float("nan")



@dataclass(frozen=True)
class DimensionTable:
    """All measured dimensions of a site plus summary statistics (e.g. the paper's percent difference)."""

    rows: tuple[DimensionRow, ...]
    stats: dict[str, float] = field(default_factory=dict)
