"""What a comparator returns: each reference dimension measured in the map."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


HEADING_TURN_DEG = 2.0
"""The turn of the whole map a dimension is checked against: the map's north is the compasses', and a
compass bias of a degree or two is common (the simulated sites draw theirs from ±2°). The record gives a
probe as an offset from a station, so the map places it turned by that bias about the station: a probe
whose ends lie far from it, on walls oblique to it or beside a corner or an opening, measures elsewhere
than the team did."""


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
    heading_shift_m: float = float("nan")
    """How much ``map_m`` changes when the probes turn by :data:`HEADING_TURN_DEG` either way about the
    station they are given from (``nan`` when the comparator does not say)."""

    @property
    def probe_std_m(self) -> float:
        return float(np.std(self.probes, ddof=1)) if len(self.probes) > 1 else float("nan")



@dataclass(frozen=True)
class DimensionTable:
    """All measured dimensions of a site plus summary statistics (e.g. the paper's percent difference)."""

    rows: tuple[DimensionRow, ...]
    stats: dict[str, float] = field(default_factory=dict)
