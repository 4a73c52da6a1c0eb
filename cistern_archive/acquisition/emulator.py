"""A software Micron DST head speaking SeaNet on a pseudo-terminal or a TCP port.

Three layers, each usable on its own:

* :class:`SimulatedEcho` — what the head hears: one revolution of scan lines from the sonar model of
  :mod:`cistern_archive.simulation.simulator`, for the head's current range, bins and step, from a station in
  a catalog site (:meth:`SimulatedEcho.from_catalog`) or inside any polygon (:meth:`SimulatedEcho.from_polygon`).
* :class:`EmulatedHead` — the head's state machine of ``../shared/protocols/tritech_micron.md`` §11.5,
  without I/O: ``handle(packet, now)`` and ``poll(now)`` return the bytes to send.
* :class:`EmulatorServer` — the wire: a thread that moves bytes between a pty (raw mode) or a TCP client
  and the head, through :class:`FaultInjector` (seeded dropped and flipped bytes, garbage bursts).
  Stalls and a reboot mid-scan are head behaviours driven by the same :class:`FaultPlan`.

Conventions the emulator documents (§9.2, §13): 4-bit bins are packed high nibble first; bearing 3200 is
ahead and bearings increase clockwise; an 8-bit intensity ``v`` becomes the 4-bit value ``v >> 4``.
"""

from __future__ import annotations

import errno
import math
import os
import select
import socket
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cistern_archive.core.errors import CatalogError
from cistern_archive.sonar.geometry import Slice, interpolate_slice
from cistern_archive.simulation.simulator import TruePose, simulate_scan, station_poses
from cistern_archive.simulation.spec import EffectsSpec, SonarSpec, load_spec
from cistern_archive.acquisition.session import find_site
from cistern_archive.tritech.codec import DEFAULT_SPEED_OF_SOUND, STEPS_PER_REV, MessageType, Packet, PacketError
from cistern_archive.tritech.stream import StreamDecoder
from cistern_archive.tritech.head_data import HDCTRL_STARELLIM, encode_head_data
from cistern_archive.tritech.messages import Alive, BBUserData, HeadInf, VersionData, head_data_for
from cistern_archive.tritech.codec import reply
from cistern_archive.tritech.settings import reversed_command, with_gain
from cistern_archive.tritech.head_command import GainCommand, HeadCommand, ReverseCommand, decode_head_command

__all__ = [
    "EmulatedHead",
    "EmulatorServer",
    "FaultInjector",
    "FaultPlan",
    "SimulatedEcho",
]

AHEAD = 3200
TYPICAL_IGAIN, TYPICAL_AD_LOW, TYPICAL_AD_SPAN = 84, 8, 81


# ------------------------------------------------------------------------------------------------
# Echoes
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SimulatedEcho:
    """The walls around one station and the sonar model that turns them into scan lines.

    Attributes
    ----------
    rings : list of (K, 2) arrays
        The walls at the station's depth, map frame.
    pose : TruePose
        The station (position, yaw, depth).
    sonar : SonarSpec
        Physical sonar model; range, bins and step are replaced by the head's configuration.
    effects : EffectsSpec
        Imperfections (speckle, ghosts, spikes...).
    water_depth_m : float, optional
        Floor depth, for floor reverberation.
    """

    rings: Slice
    pose: TruePose
    sonar: SonarSpec = field(default_factory=SonarSpec)
    effects: EffectsSpec = field(default_factory=EffectsSpec)
    water_depth_m: float | None = None

    @classmethod
    def from_polygon(cls, vertices: np.ndarray, *, x_m: float, y_m: float, yaw_deg: float = 0.0,
                     depth_m: float = 1.0, effects: EffectsSpec | None = None) -> "SimulatedEcho":
        """A station at (x, y) with heading ``yaw_deg`` (map frame, CCW from east) inside one polygon."""
        pose = TruePose("emulated", float(x_m), float(y_m), math.radians(yaw_deg), float(depth_m))
        return cls([np.asarray(vertices, dtype=np.float64)], pose,
                   effects=EffectsSpec() if effects is None else effects)

    @classmethod
    def from_catalog(cls, catalog: str | os.PathLike, site_id: str, station: str | None = None) -> "SimulatedEcho":
        """The simulated geometry of a catalog site, seen from one of its stations.

        Parameters
        ----------
        catalog : path
            Catalog root (records in it or in ``sites/``).
        site_id : str
            Record id; the record must name its simulator spec (``simulation:``).
        station : str, optional
            Station label of the spec; the first station when omitted.

        Raises
        ------
        CatalogError
            Unknown site, a site without a simulation spec, or an unknown station.
        """
        root = Path(catalog)
        loaded = find_site(root, site_id)
        if loaded.record.simulation is None:
            raise CatalogError([f"{loaded.path}: site {site_id!r} has no 'simulation' spec; the emulator echoes "
                                "simulated sites only"])
        spec = load_spec(loaded.resolve(loaded.record.simulation))
        poses = station_poses(spec)
        chosen = poses[0] if station is None else next((p for p in poses if p.station == station), None)
        if chosen is None:
            raise CatalogError([f"{loaded.path}: site {site_id!r} has no station {station!r}; "
                                f"stations: {', '.join(p.station for p in poses)}"])
        rings = interpolate_slice(spec.site.slices(), chosen.depth_m)
        return cls(rings, chosen, spec.sonar, spec.effects, spec.site.water_depth_m)

    def revolution(self, cmd: HeadCommand, rng: np.random.Generator,
                   speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> np.ndarray:
        """Intensities (0..255) of one revolution for the head's settings.

        Row ``k`` is the beam ``k x step`` clockwise from ahead (bearing ``3200 + k x step``), as
        :func:`~cistern_archive.simulation.simulator.beam_bearings` orders them.

        The spec's AD window is taken as the head's at the typical command (IGain 84, ADLow 8, ADSpan 81,
        §12.3); the command's departures from it move the window: ``+80/210 dB`` per IGain unit lowers the
        floor, ADLow and ADSpan shift and scale it at ``80/255 dB`` per unit (§7.4).
        """
        step = max(1, cmd.step_size)
        n_bins = max(1, cmd.n_bins)
        gain_db = (cmd.igain[0] - TYPICAL_IGAIN) * 80.0 / 210.0
        low_db = self.sonar.ad_low_db + (cmd.ad_low - TYPICAL_AD_LOW) * 80.0 / 255.0 - gain_db
        span_db = max(self.sonar.ad_span_db + (cmd.ad_span - TYPICAL_AD_SPAN) * 80.0 / 255.0, 1.0)
        sonar = self.sonar.model_copy(update={
            "range_m": max(n_bins * cmd.bin_size_m(speed_of_sound), 0.01),
            "bins": n_bins,
            "step_deg": step * 360.0 / STEPS_PER_REV,
            "ad_low_db": low_db,
            "ad_span_db": span_db,
        })
        simulated = simulate_scan(self.rings, self.pose, sonar, self.effects, rng, water_depth_m=self.water_depth_m)
        return np.asarray(simulated.scan.intensities)


# ------------------------------------------------------------------------------------------------
# Faults
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FaultPlan:
    """What goes wrong, seeded.

    Attributes
    ----------
    drop : float
        Probability that each byte the head sends is lost.
    flip : float
        Probability that each byte the head sends has one bit flipped.
    garbage : float
        Probability that a burst of 1..64 random bytes precedes a packet.
    stall_at : int
        After this many scan lines (0 = never) the head stops answering mtSendData.
    stall_s : float
        How long a stall lasts; 0 = until the head is rebooted.
    reboot_at : int
        After this many scan lines (0 = never) the head resets by itself once (a power glitch mid-scan).
    seed : int
        Seed of every random choice.
    """

    drop: float = 0.0
    flip: float = 0.0
    garbage: float = 0.0
    stall_at: int = 0
    stall_s: float = 0.0
    reboot_at: int = 0
    seed: int = 0

    @classmethod
    def parse(cls, text: str) -> "FaultPlan":
        """Parse ``"drop=0.001,flip=0.001,garbage=0.02,stall=150,stall_s=2,reboot=300,seed=7"``.

        Raises
        ------
        ValueError
            An unknown key or a bad value, naming it.
        """
        names = {"drop": "drop", "flip": "flip", "garbage": "garbage", "stall": "stall_at", "stall_at": "stall_at",
                 "stall_s": "stall_s", "reboot": "reboot_at", "reboot_at": "reboot_at", "seed": "seed"}
        values: dict[str, float | int] = {}
        for item in filter(None, (part.strip() for part in text.split(","))):
            key, sep, raw = item.partition("=")
            if not sep or key.strip() not in names:
                raise ValueError(f"fault {item!r}: expected KEY=VALUE with KEY one of {', '.join(sorted(names))}")
            name = names[key.strip()]
            try:
                values[name] = int(raw) if name in ("stall_at", "reboot_at", "seed") else float(raw)
            except ValueError:
                raise ValueError(f"fault {item!r}: {raw!r} is not a number") from None
        plan = cls(**values)  # type: ignore[arg-type]
        for name in ("drop", "flip", "garbage"):
            if not 0.0 <= getattr(plan, name) <= 1.0:
                raise ValueError(f"fault {name}={getattr(plan, name)} is not a probability")
        if plan.stall_at < 0 or plan.reboot_at < 0 or plan.stall_s < 0:
            raise ValueError("fault counts and durations must not be negative")
        return plan

    @property
    def corrupts_bytes(self) -> bool:
        return self.drop > 0 or self.flip > 0 or self.garbage > 0


class FaultInjector:
    """Applies a :class:`FaultPlan`'s byte faults to each outgoing packet (seeded)."""

    def __init__(self, plan: FaultPlan, rng: np.random.Generator):
        self.plan = plan
        self.rng = rng
        self.dropped = 0
        self.flipped = 0
        self.garbage_bytes = 0

    def __call__(self, data: bytes) -> bytes:
        plan = self.plan
        if not plan.corrupts_bytes or not data:
            return data
        out = bytearray()
        if plan.garbage > 0 and self.rng.random() < plan.garbage:
            burst = self.rng.integers(0, 256, size=int(self.rng.integers(1, 65)), dtype=np.uint8).tobytes()
            out += burst
            self.garbage_bytes += len(burst)
        buf = np.frombuffer(data, dtype=np.uint8).copy()
        if plan.flip > 0:
            flips = self.rng.random(buf.size) < plan.flip
            if flips.any():
                buf[flips] ^= (1 << self.rng.integers(0, 8, size=int(flips.sum()))).astype(np.uint8)
                self.flipped += int(flips.sum())
        if plan.drop > 0:
            keep = self.rng.random(buf.size) >= plan.drop
            self.dropped += int(buf.size - keep.sum())
            buf = buf[keep]
        out += buf.tobytes()
        return bytes(out)


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


# ------------------------------------------------------------------------------------------------
# The wire
# ------------------------------------------------------------------------------------------------

class EmulatorServer:
    """Serves an :class:`EmulatedHead` on a pty or a TCP port, in a background thread.

    Use :meth:`on_pty` or :meth:`on_tcp`, then :meth:`start` (or ``with``); :attr:`url` is what
    ``serial.serial_for_url`` opens (the pty path, or ``socket://127.0.0.1:PORT``). Output sent while no
    client listens is lost, as on a real serial line.
    """

    def __init__(self, head: EmulatedHead, injector: FaultInjector):
        self.head = head
        self.injector = injector
        self.url = ""
        self.bytes_in = 0
        self.bytes_out = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._listener: socket.socket | None = None
        self._client: socket.socket | None = None
        self._decoder = StreamDecoder()
        self._t0 = time.monotonic()
        self.error: BaseException | None = None

    @classmethod
    def on_pty(cls, head: EmulatedHead, injector: FaultInjector) -> "EmulatorServer":
        """A pseudo-terminal in raw mode; :attr:`url` is the slave's path (e.g. ``/dev/pts/3``)."""
        server = cls(head, injector)
        master, slave = os.openpty()
        tty.setraw(slave)
        tty.setraw(master)
        os.set_blocking(master, False)
        server._master, server._slave = master, slave
        server.url = os.ttyname(slave)
        return server

    @classmethod
    def on_tcp(cls, head: EmulatedHead, injector: FaultInjector, *, host: str = "127.0.0.1",
               port: int = 0) -> "EmulatorServer":
        """A TCP listener (one client at a time); :attr:`url` is ``socket://HOST:PORT``."""
        server = cls(head, injector)
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind((host, port))
        listener.listen(1)
        listener.setblocking(False)
        server._listener = listener
        server.url = f"socket://{host}:{listener.getsockname()[1]}"
        return server

    # lifecycle -----------------------------------------------------------------------------------

    def start(self) -> "EmulatorServer":
        self._thread = threading.Thread(target=self.serve_forever, name="sonar-head-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None
        for sock in (self._client, self._listener):
            if sock is not None:
                sock.close()
        self._client = self._listener = None

    def __enter__(self) -> "EmulatorServer":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def now(self) -> float:
        return time.monotonic() - self._t0

    def serve_forever(self) -> None:
        """Run until :meth:`stop` (or KeyboardInterrupt in the calling thread)."""
        try:
            while not self._stop.is_set():
                self._step(min(0.05, self.head.next_event(self.now())))
        except BaseException as exc:  # recorded for the caller; the thread must not die silently
            self.error = exc
            raise

    # I/O -----------------------------------------------------------------------------------------

    def _readable(self) -> list:
        if self._master is not None:
            return [self._master]
        assert self._listener is not None
        return [self._client if self._client is not None else self._listener]

    def _step(self, timeout: float) -> None:
        ready, _, _ = select.select(self._readable(), [], [], timeout)
        now = self.now()
        for source in ready:
            if source is self._listener:
                self._accept()
            else:
                self._receive(self._read(source), now)
        for data in self.head.poll(now):
            self._send(data)

    def _accept(self) -> None:
        assert self._listener is not None
        try:
            client, _ = self._listener.accept()
        except BlockingIOError:
            return
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._client = client
        self._decoder = StreamDecoder()

    def _read(self, source) -> bytes:
        try:
            if isinstance(source, socket.socket):
                data = source.recv(4096)
                if not data:
                    self._drop_client()
                return data
            return os.read(source, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as exc:
            if isinstance(source, socket.socket):
                self._drop_client()
                return b""
            if exc.errno == errno.EIO:
                return b""
            raise

    def _drop_client(self) -> None:
        if self._client is not None:
            self._client.close()
        self._client = None

    def _receive(self, data: bytes, now: float) -> None:
        self.bytes_in += len(data)
        for packet in self._decoder.feed(data):
            for out in self.head.handle(packet, now):
                self._send(out)
        self._decoder.take_discards()

    def _send(self, data: bytes) -> None:
        wire = self.injector(data)
        try:
            if self._master is not None:
                view = memoryview(wire)
                deadline = time.monotonic() + 0.05  # nobody reading: the rest is lost, as on a real line
                while view and time.monotonic() < deadline:
                    try:
                        view = view[os.write(self._master, view):]
                    except BlockingIOError:
                        if self._stop.wait(0.002):
                            return
                self.bytes_out += len(wire) - len(view)
            elif self._client is not None:
                self._client.sendall(wire)
                self.bytes_out += len(wire)
        except OSError:
            self._drop_client()


def build_emulator(echo: SimulatedEcho, *, faults: FaultPlan = FaultPlan(), tcp_port: int | None = None,
                   host: str = "127.0.0.1", timing: HeadTiming | None = None,
                   half_duplex: bool = False, keep_history: bool = False) -> EmulatorServer:
    """A ready (not yet started) emulator: pty when ``tcp_port`` is None, else TCP (0 = any free port).

    The head's noise and the wire's faults use two generators derived from ``faults.seed``.
    """
    head = EmulatedHead(echo, np.random.default_rng([faults.seed, 0]), faults=faults, timing=timing,
                        half_duplex=half_duplex, keep_history=keep_history)
    injector = FaultInjector(faults, np.random.default_rng([faults.seed, 1]))
    if tcp_port is None:
        return EmulatorServer.on_pty(head, injector)
    return EmulatorServer.on_tcp(head, injector, host=host, port=tcp_port)
