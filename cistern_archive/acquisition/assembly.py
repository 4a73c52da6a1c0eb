"""One 360° scan from a running head: lines assembled by bearing into a :class:`~cistern_archive.core.scan.Scan`.

:func:`collect_scan` asks a :class:`~cistern_archive.acquisition.driver.MicronDriver` for lines until
every bearing slot of one revolution is filled (or a limit is reached) and reports what is missing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cistern_archive.acquisition.driver import LinkError, MicronDriver
from cistern_archive.core.scan import Scan
from cistern_archive.tritech.codec import DEFAULT_SPEED_OF_SOUND, STEPS_PER_REV
from cistern_archive.tritech.head_data import HeadData

__all__ = ["ScanAssembler", "ScanCapture", "collect_scan"]

@dataclass(frozen=True, eq=False)
class ScanCapture:
    """The outcome of :func:`collect_scan`.

    Attributes
    ----------
    scan : Scan or None
        The assembled scan (None when no line arrived); ``scan.settings["partial"]`` says whether it is
        a full revolution.
    complete : bool
        Every bearing slot of one revolution was filled.
    missing : int
        Empty bearing slots.
    error : str
        Why collection stopped early ("" when complete).
    """

    scan: Scan | None
    complete: bool
    missing: int
    error: str = ""


@dataclass
class ScanAssembler:
    """Gathers scan lines into one revolution: one line per bearing slot of ``step`` (first line wins).

    A revolution is complete when every one of the ``6400 / step`` slots holds a line; lines lost to a
    corrupted packet or a reboot are filled on the next pass.

    SeaNet has no checksum (§1.3), so a bit flipped inside a header field can pass the framing checks.
    A line is therefore refused (and counted) when any echoed setting differs from the first line's
    (device type, HdCtrl, range scale, ADSpan, ADLow, ADInterval, step, limits, bin count) or when its
    bearing is not a whole number of steps from the first line's.
    """

    step: int
    speed_of_sound: float = DEFAULT_SPEED_OF_SOUND
    lines: dict[int, HeadData] = field(default_factory=dict)
    received: int = 0
    refused: int = 0
    first: HeadData | None = None
    started_at: float = math.nan

    @property
    def n_slots(self) -> int:
        return max(1, STEPS_PER_REV // self.step)

    @property
    def missing(self) -> int:
        return self.n_slots - len(self.lines)

    @property
    def complete(self) -> bool:
        return self.missing == 0

    def add(self, line: HeadData, at: float | None = None) -> bool:
        """Add a line; True when it filled a new slot."""
        self.received += 1
        if self.first is None:
            self.first = line
            self.started_at = time.time() if at is None else at
        elif _echo_key(line) != _echo_key(self.first) or (line.bearing - self.first.bearing) % self.step:
            self.refused += 1
            return False
        slot = int(round(line.bearing / self.step)) % self.n_slots
        if slot in self.lines:
            return False
        self.lines[slot] = line
        return True

    def build(self, *, station: str = "", depth_m: float = 0.0, yaw_rad: float = 0.0,
              extra: dict | None = None) -> Scan | None:
        """The :class:`Scan` so far (None before the first line), beams in scan order from the first line.

        Bearings are converted with :meth:`~cistern_archive.tritech.codec.HeadData.bearing_rad` (mirrored
        for an inverted head, the rule the SeaNet file readers use); the bin size comes from the echoed
        ADInterval (§7.4).
        """
        first = self.first
        if first is None:
            return None
        sign = 1 if first.scan_right else -1
        slot0 = int(round(first.bearing / self.step)) % self.n_slots
        order = sorted(self.lines, key=lambda s: (sign * (s - slot0)) % self.n_slots)
        chosen = [self.lines[s] for s in order]
        bearings = np.array([line.bearing_rad() for line in chosen], dtype=np.float64)
        intensities = np.stack([line.bins for line in chosen]).astype(np.uint8)
        settings = dict(first.settings())
        settings.update({"partial": not self.complete, "missing_beams": self.missing,
                         "lines_received": self.received, "lines_refused": self.refused,
                         "speed_of_sound_m_s": self.speed_of_sound})
        settings.update(extra or {})
        return Scan(bearings_rad=bearings, intensities=intensities, full_scale=float(first.full_scale),
                    bin_size_m=first.bin_size_m(self.speed_of_sound), start_range_m=0.0, yaw_rad=yaw_rad,
                    depth_m=depth_m, timestamp=self.started_at, sonar_model="Tritech Micron DST",
                    beam_width_rad=math.radians(3.0), station=station, settings=settings)


def _echo_key(line: HeadData) -> tuple:
    """The settings a head echoes in every line of one configuration (§9.1)."""
    return (line.device_type, line.hd_ctrl, line.range_scale_raw, line.ad_span, line.ad_low, line.ad_interval,
            line.step_size, line.left_limit, line.right_limit, line.dbytes, line.n_bins)


def collect_scan(driver: MicronDriver, *, station: str = "", depth_m: float = 0.0, yaw_rad: float = 0.0,
                 max_revolutions: float = 3.0, accept_missing: int = 0,
                 on_line: Callable[[ScanAssembler], None] | None = None, start: bool = True) -> ScanCapture:
    """Record one stationary 360° scan (the driver must be configured for continuous rotation).

    Parameters
    ----------
    driver : MicronDriver
        An open driver; started here unless ``start`` is false.
    station, depth_m, yaw_rad
        Stored in the scan (yaw is the map-frame heading, see :mod:`cistern_archive.core.scan`).
    max_revolutions : float
        Give up filling gaps after this many revolutions' worth of lines; the scan is then partial.
    accept_missing : int
        After one revolution's worth of lines, stop if at most this many bearings are still empty and
        count the scan as complete (its ``missing_beams`` says how many). 0 (default) fills every gap,
        which costs one more revolution whenever a line was lost.
    on_line : callable, optional
        Called after every line with the assembler (progress display).

    Returns
    -------
    ScanCapture
        Complete, or partial with the reason in ``error``. A :class:`LinkError` (start-up failure, link
        lost, head silent through its reboots) or a KeyboardInterrupt ends collection without raising:
        what was gathered is returned, and ``error`` is the link error's text or ``"interrupted"``.
    """
    if not driver.settings.continuous:
        raise ValueError("a 360-degree scan needs continuous rotation (HeadSettings.continuous = True)")
    assembler = ScanAssembler(step=driver.settings.step, speed_of_sound=driver.settings.speed_of_sound)
    limit = int(max_revolutions * assembler.n_slots)
    error = ""
    try:
        if start:
            driver.start()
        for line in driver.lines():
            assembler.add(line)
            if on_line is not None:
                on_line(assembler)
            if assembler.complete or (assembler.received >= assembler.n_slots
                                      and assembler.missing <= accept_missing):
                break
            if assembler.received >= limit:
                error = f"{assembler.missing} bearing slot(s) still empty after {assembler.received} lines"
                break
    except KeyboardInterrupt:
        error = "interrupted"
    except LinkError as exc:
        error = str(exc)
    complete = assembler.first is not None and assembler.missing <= accept_missing and error != "interrupted"
    extra = {"port": driver.port_name, "link": driver.stats.as_dict(), "partial": not complete}
    scan = assembler.build(station=station, depth_m=depth_m, yaw_rad=yaw_rad, extra=extra)
    return ScanCapture(scan=scan, complete=complete, missing=assembler.missing, error=error)
