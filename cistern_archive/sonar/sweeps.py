"""Split a stream of sonar beams into 360° scans and sector sweeps.

A mechanically scanned sonar reports one beam at a time. Readers collect the beams of a recording as
:class:`Beam` records and hand them to :func:`beams_to_scans`, which cuts the stream where

* the settings that shape a beam change (bin count, bin size, …: the ``key`` of a beam),
* the head reverses direction (the end of a sector sweep), or
* the rotation accumulated since the sweep's first beam completes a full revolution (the next beam
  would repeat the first bearing), so a continuous 360° recording becomes one scan per revolution, or
* consecutive bearings jump by more than ``max_step_rad`` (45° by default): a mechanical head never
  turns that far between two pings, so the stream was restarted or beams were lost.

Repeated bearings (zero increments) neither cut nor count as rotation.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cistern_archive.core.scan import Scan, wrap_angle

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, eq=False)
class Beam:
    """One beam as read from a recording.

    Attributes
    ----------
    bearing_rad : float
        Sonar-frame bearing (CCW from forward, see :mod:`cistern_archive.core.scan`).
    intensities : ndarray, shape (B,)
        Bin values in device units.
    timestamp : float
        Unix seconds, ``nan`` when unknown.
    key : hashable
        Everything that must be equal for beams to share a scan (bin count, bin size, full scale, …).
    """

    bearing_rad: float
    intensities: np.ndarray
    timestamp: float = float("nan")
    key: Hashable = None


MAX_STEP_RAD = math.radians(45.0)


def split_sweeps(bearings_rad: Sequence[float] | np.ndarray, keys: Sequence[Hashable] | None = None,
                 max_step_rad: float = MAX_STEP_RAD) -> list[slice]:
    """Index ranges of the sweeps of a beam stream.

    Parameters
    ----------
    bearings_rad : sequence of float
        Bearings in acquisition order.
    keys : sequence of hashable, optional
        Per-beam settings keys; a change of key starts a new sweep.
    max_step_rad : float
        Larger bearing jumps between consecutive beams start a new sweep.

    Returns
    -------
    list of slice
        Consecutive, non-overlapping ranges covering every beam.
    """
    b = np.asarray(bearings_rad, dtype=np.float64)
    n = b.shape[0]
    if n == 0:
        return []
    steps = wrap_angle(np.diff(b))
    cuts = [0]
    direction = 0.0
    turned = 0.0
    for i in range(1, n):
        d = float(steps[i - 1])
        if keys is not None and keys[i] != keys[i - 1]:
            cuts.append(i)
            direction, turned = 0.0, 0.0
            continue
        if d == 0.0:
            continue
        sign = math.copysign(1.0, d)
        if abs(d) > max_step_rad:
            cuts.append(i)
            direction, turned = 0.0, 0.0
            continue
        if direction and sign != direction:
            cuts.append(i)
            direction, turned = sign, 0.0
            continue
        direction = sign
        turned += abs(d)
        if turned >= TWO_PI - 0.5 * abs(d):
            cuts.append(i)
            turned = 0.0
    cuts.append(n)
    return [slice(a, z) for a, z in zip(cuts[:-1], cuts[1:]) if z > a]


@dataclass
class ScanTemplate:
    """Fields shared by every scan a reader builds from a beam stream (passed on to :class:`Scan`)."""

    full_scale: float
    bin_size_m: float
    start_range_m: float = 0.0
    yaw_rad: float = 0.0
    depth_m: float = 0.0
    sonar_model: str = "unknown"
    beam_width_rad: float = math.radians(3.0)
    settings: dict[str, Any] = field(default_factory=dict)


def beams_to_scans(beams: Sequence[Beam], template_for: Callable[[Beam, Sequence[Beam]], ScanTemplate]
                   ) -> list[Scan]:
    """Split beams into sweeps (:func:`split_sweeps`) and build one :class:`Scan` per sweep.

    Parameters
    ----------
    beams : sequence of Beam
        The recording's beams in order.
    template_for : callable
        ``template_for(first_beam, sweep_beams)`` gives the scan-level fields of a sweep (called once
        per sweep, so a reader can, e.g., average the heading over the sweep's time span).

    Returns
    -------
    list of Scan
        Scans in recording order; a scan's timestamp is that of its first beam with a known time.
    """
    slices = split_sweeps([bm.bearing_rad for bm in beams], [bm.key for bm in beams])
    scans = []
    for sl in slices:
        sweep = beams[sl]
        tpl = template_for(sweep[0], sweep)
        intensities = np.stack([bm.intensities for bm in sweep])
        times = [bm.timestamp for bm in sweep if math.isfinite(bm.timestamp)]
        settings = dict(tpl.settings)
        if times:
            settings.setdefault("end_timestamp", float(times[-1]))
        scans.append(Scan(
            bearings_rad=np.array([bm.bearing_rad for bm in sweep], dtype=np.float64),
            intensities=intensities, full_scale=tpl.full_scale, bin_size_m=tpl.bin_size_m,
            start_range_m=tpl.start_range_m, yaw_rad=tpl.yaw_rad, depth_m=tpl.depth_m,
            timestamp=float(times[0]) if times else float("nan"), sonar_model=tpl.sonar_model,
            beam_width_rad=tpl.beam_width_rad, settings=settings,
        ))
    return scans
