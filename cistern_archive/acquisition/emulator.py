"""A software Micron DST head speaking SeaNet on a pseudo-terminal or a TCP port.

Three layers, each usable on its own:

* :class:`~cistern_archive.acquisition.echoes.SimulatedEcho` — what the head hears: one revolution of scan lines from the sonar model of
  :mod:`cistern_archive.simulation.simulator`, for the head's current range, bins and step, from a station in
  a catalog site (``SimulatedEcho.from_catalog``) or inside any polygon (``SimulatedEcho.from_polygon``).
* :class:`EmulatedHead` — the head's state machine of ``../shared/protocols/tritech_micron.md`` §11.5,
  without I/O: ``handle(packet, now)`` and ``poll(now)`` return the bytes to send.
* :class:`~cistern_archive.acquisition.emulator_server.EmulatorServer` — the wire: a thread that moves
  bytes between a pty (raw mode) or a TCP client and the head, through
  :class:`~cistern_archive.acquisition.faults.FaultInjector` (seeded dropped and flipped bytes, garbage
  bursts). Stalls and a reboot mid-scan are head behaviours driven by the same ``FaultPlan``.

Conventions the emulator documents (§9.2, §13): 4-bit bins are packed high nibble first; bearing 3200 is
ahead and bearings increase clockwise; an 8-bit intensity ``v`` becomes the 4-bit value ``v >> 4``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cistern_archive.acquisition.echoes import SimulatedEcho
from cistern_archive.acquisition.faults import FaultPlan
from cistern_archive.tritech.codec import DEFAULT_SPEED_OF_SOUND, STEPS_PER_REV, MessageType, Packet, PacketError
from cistern_archive.tritech.head_data import HDCTRL_STARELLIM, encode_head_data
from cistern_archive.tritech.messages import Alive, BBUserData, HeadInf, VersionData, head_data_for
from cistern_archive.tritech.codec import reply
from cistern_archive.tritech.settings import reversed_command, with_gain
from cistern_archive.tritech.head_command import GainCommand, HeadCommand, ReverseCommand, decode_head_command

__all__ = [
    "EmulatedHead",
]

AHEAD = 3200


# ------------------------------------------------------------------------------------------------
# The head
# ------------------------------------------------------------------------------------------------

@dataclass
class HeadTiming:
    """Emulated times, seconds.

    Attributes
    ----------
    alive_period : float
        mtAlive period (§11.4: about 1 s).
    boot : float
        Silence after power-on or mtReBoot before the first mtAlive (§11.4: a few seconds on a real head).
    realtime : bool
        Delay each scan line by the acoustic two-way time plus its serial transmission at 115200 baud
        (§11.4); false answers at once (fast tests).
    """

    alive_period: float = 1.0
    boot: float = 1.5
    realtime: bool = True

    def line_delay(self, cmd: HeadCommand, line_bytes: int,
                   speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> float:
        """Two-way time to the end of the line plus the line's serial time (8N1 at 115200 baud)."""
        if not self.realtime:
            return 0.0
        acoustic = 2.0 * cmd.n_bins * cmd.bin_size_m(speed_of_sound) / speed_of_sound
        return acoustic + line_bytes * 10.0 / 115200.0


class EmulatedHead:
    """The SeaNet state machine of a Micron DST (§11.5), clocked by the caller.

    Parameters
    ----------
    echo : SimulatedEcho
        The geometry the head sees.
    rng : numpy.random.Generator
        Drives the sonar model's noise (speckle, ghosts, spikes).
    faults : FaultPlan
        Stalls and the spontaneous reboot (byte faults are applied on the wire by :class:`FaultInjector`).
    timing : HeadTiming
    half_duplex : bool
        One scan line per mtSendData; false sends two (full duplex, §11.3).
    """

    def __init__(self, echo: SimulatedEcho, rng: np.random.Generator, *, faults: FaultPlan = FaultPlan(),
                 timing: HeadTiming | None = None, half_duplex: bool = False, node: int = 2,
                 keep_history: bool = False):
        self.echo = echo
        self.rng = rng
        self.faults = faults
        self.timing = HeadTiming() if timing is None else timing
        self.half_duplex = half_duplex
        self.node = node
        self.lines_sent = 0
        self.reboots = 0
        self.stalled_until: float | None = None
        self._glitched = False
        self._stall_done = False
        self._queue: list[tuple[float, bytes]] = []
        self.history: list[tuple[int, np.ndarray]] | None = [] if keep_history else None
        """(bearing, bins) of every scan line sent, when ``keep_history`` (for checking a recording)."""
        self._power_on(0.0, boot=0.0)

    # state ---------------------------------------------------------------------------------------

    def _power_on(self, now: float, *, boot: float | None = None) -> None:
        self.booted_at = now
        self.ready_at = now + (self.timing.boot if boot is None else boot)
        self.alives = True
        self.next_alive = self.ready_at
        self.sent_cfg = False
        self.cmd: HeadCommand | None = None
        self.bearing = AHEAD
        self.sector_dir = 1
        self.stalled_until = None
        self._queue = []
        self._table: np.ndarray | None = None
        self._table_lines = 0

    def head_inf(self) -> HeadInf:
        inf = HeadInf.CENTRED | HeadInf.MOTOR_ON
        if self.cmd is None:
            inf |= HeadInf.NO_PARAMS
        else:
            inf |= HeadInf.IN_SCAN
            if self.cmd.scan_right:
                inf |= HeadInf.DIR
        if self.sent_cfg:
            inf |= HeadInf.SENT_CFG
        return inf

    def alive(self, now: float) -> bytes:
        ms = int((now - self.booted_at) * 1000.0)
        return Alive(0 if self.cmd is not None else 1, ms, self.bearing, self.head_inf()).encode(node=self.node)

    # events --------------------------------------------------------------------------------------

    def handle(self, packet: Packet, now: float) -> list[bytes]:
        """React to one packet from the PC; returns what to send now (delayed replies come from :meth:`poll`)."""
        if now < self.ready_at or packet.did not in (self.node, 0xFF):
            return []
        kind = packet.type
        if kind == MessageType.REBOOT:
            self.reboots += 1
            self._power_on(now)
            return []
        if kind == MessageType.STOP_ALIVES:
            self.alives = False
            return []
        if kind == MessageType.SEND_VERSION:
            return [VersionData(3, 1, 0x1234, 0x00012345, 0xBEEF, self.node).encode()]
        if kind == MessageType.SEND_BB_USER:
            self.sent_cfg = True
            return [BBUserData.build(half_duplex=self.half_duplex).encode(node=self.node),
                    reply(MessageType.FPGA_CAL_DATA, bytes(16), node=self.node),
                    reply(MessageType.FPGA_VERSION_DATA, bytes(12), node=self.node)]
        if kind == MessageType.HEAD_COMMAND:
            return self._head_command(packet, now)
        if kind == MessageType.SEND_DATA:
            self._send_data(now)
        return []

    def _head_command(self, packet: Packet, now: float) -> list[bytes]:
        try:
            cmd = decode_head_command(packet)
        except PacketError:
            return []
        if isinstance(cmd, HeadCommand):
            if cmd.n_bins < 1 or cmd.ad_interval < 1 or cmd.step_size < 1:
                return []
            changed = self.cmd is None or (cmd.n_bins, cmd.ad_interval, cmd.step_size) != (
                self.cmd.n_bins, self.cmd.ad_interval, self.cmd.step_size)
            self.cmd = cmd
            if changed:
                self._table = None
            if not cmd.continuous or cmd.hd_ctrl & HDCTRL_STARELLIM:
                self.bearing = cmd.left_limit % STEPS_PER_REV
                self.sector_dir = 1 if cmd.scan_right else -1
            self.next_alive = now + self.timing.alive_period
            return [self.alive(now)]
        if self.cmd is None:
            return []
        self.cmd = with_gain(self.cmd, cmd) if isinstance(cmd, GainCommand) else reversed_command(self.cmd)
        if isinstance(cmd, ReverseCommand):
            self.sector_dir = -self.sector_dir
        return []

    def _send_data(self, now: float) -> None:
        if self.cmd is None:
            return  # §11.5: no parameters, no reply
        if self.stalled_until is not None:
            if now < self.stalled_until:
                return
            self.stalled_until = None
        due = now
        for _ in range(1 if self.half_duplex else 2):
            if self._fault_before_line(now):
                return
            line = self._next_line()
            due += self.timing.line_delay(self.cmd, len(line))
            self._queue.append((due, line))

    def _fault_before_line(self, now: float) -> bool:
        plan = self.faults
        if plan.reboot_at and not self._glitched and self.lines_sent >= plan.reboot_at:
            self._glitched = True
            self.reboots += 1
            self._power_on(now)
            return True
        if plan.stall_at and not self._stall_done and self.lines_sent >= plan.stall_at:
            self._stall_done = True
            self.stalled_until = now + plan.stall_s if plan.stall_s > 0 else math.inf
            return True
        return self.stalled_until is not None

    def _next_line(self) -> bytes:
        cmd = self.cmd
        assert cmd is not None
        if self._table is None or self._table_lines >= self._table.shape[0]:
            self._table = self.echo.revolution(cmd, self.rng)
            self._table_lines = 0
        offset = (self.bearing - AHEAD) % STEPS_PER_REV
        if cmd.inverted:  # the head turns the other way seen from above
            offset = (-offset) % STEPS_PER_REV
        row = int(round(offset / (STEPS_PER_REV / self._table.shape[0]))) % self._table.shape[0]
        values = self._table[row]
        bins = values if cmd.adc8on else (values >> 4)
        data = head_data_for(cmd, self.bearing, bins, sweep_code=self._sweep_code(cmd))
        if self.history is not None:
            self.history.append((self.bearing, data.bins))
        self._move(cmd)
        self.lines_sent += 1
        self._table_lines += 1
        return encode_head_data(data, sid=self.node, node=self.node)

    def _sweep_code(self, cmd: HeadCommand) -> int:
        """SweepCode of the current bearing (1 at the left limit, 2 at the right, in sector mode)."""
        if cmd.continuous:
            return 0
        if self.bearing == cmd.left_limit % STEPS_PER_REV:
            return 1
        if self.bearing == cmd.right_limit % STEPS_PER_REV:
            return 2
        return 0

    def _move(self, cmd: HeadCommand) -> None:
        if cmd.hd_ctrl & HDCTRL_STARELLIM:
            return
        sign = 1 if cmd.scan_right else -1
        if cmd.continuous:
            self.bearing = (self.bearing + sign * cmd.step_size) % STEPS_PER_REV
            return
        left, right = cmd.left_limit % STEPS_PER_REV, cmd.right_limit % STEPS_PER_REV
        width = (right - left) % STEPS_PER_REV or STEPS_PER_REV
        pos = (self.bearing - left) % STEPS_PER_REV
        pos += self.sector_dir * cmd.step_size
        if pos >= width:
            pos, self.sector_dir = width, -1
        elif pos <= 0:
            pos, self.sector_dir = 0, 1
        self.bearing = (left + pos) % STEPS_PER_REV

    def poll(self, now: float) -> list[bytes]:
        """Bytes due by ``now``: delayed scan lines and periodic mtAlive."""
        out: list[bytes] = []
        if now < self.ready_at:
            return out
        while self._queue and self._queue[0][0] <= now:
            out.append(self._queue.pop(0)[1])
        if self.alives and now >= self.next_alive:
            out.append(self.alive(now))
            self.next_alive = now + self.timing.alive_period
        return out

    def next_event(self, now: float) -> float:
        """Seconds until :meth:`poll` may have something to send."""
        times = [self.ready_at] if now < self.ready_at else []
        if self._queue:
            times.append(self._queue[0][0])
        if self.alives:
            times.append(max(self.next_alive, self.ready_at))
        return max(0.0, min(times) - now) if times else 1.0
