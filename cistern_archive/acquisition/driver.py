"""A pyserial driver for a Tritech Micron DST, and the assembly of its scan lines into a 360° :class:`Scan`.

The conversation follows ``../shared/protocols/tritech_micron.md`` §11:

1. open the port (``serial.serial_for_url``: a device path, ``socket://host:port`` or ``loop://``) at
   115200 8N1 and flush it;
2. wait for mtAlive (§11.1 step 2);
3. mtSendVersion → mtVersionData, re-sent until it arrives (step 4);
4. mtSendBBUser → mtBBUserData, which gives the duplex mode, i.e. 1 or 2 scan lines per request (step 5);
5. mtHeadCommand (the DST's 0x01 form), re-sent on each mtAlive until the head reports
   'params received' (NoParams = 0, step 6);
6. streaming with **one outstanding mtSendData**: after a request, collect mtHeadData until the expected
   1 or 2 lines arrived or a quiet gap passed, then request again (§11.2, §11.3). A request without
   reply is re-sent after ``reply_timeout_s``; after ``max_retries`` consecutive silent requests the head
   is deemed stalled and rebooted (mtReBoot) and configured again; an mtAlive reporting NoParams, or a
   line flagging MotErr / HdPwrLoss, means the head lost its parameters and they are re-sent;
7. shutdown: mtStopAlives, then the port is closed.

Every byte received is handed to ``raw_sink`` before it is decoded, so a recording keeps the stream
exactly as it came off the wire, garbage included.
"""

from __future__ import annotations

import select
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import serial

from cistern_archive.core.errors import CisternError
from cistern_archive.tritech.codec import MessageType, Packet, PacketError
from cistern_archive.tritech.stream import StreamDecoder
from cistern_archive.tritech.head_data import HeadData, decode_head_data
from cistern_archive.tritech.messages import Alive, BBUserData, SendData, VersionData, time_of_day_ms
from cistern_archive.tritech.codec import command
from cistern_archive.tritech.settings import HeadSettings

__all__ = [
    "DriverConfig",
    "LinkError",
    "MicronDriver",
]

BAUD = 115200
ALIVE_GRACE_S = 2.5
"""How long to wait for an unprompted mtAlive (period about 1 s, §4) before rebooting the head."""


class LinkError(CisternError):
    """The head cannot be reached or stopped answering; names the port and what was being waited for."""

    def __init__(self, port: str, message: str):
        self.port = port
        super().__init__(f"{port}: {message}")


@dataclass(frozen=True)
class DriverConfig:
    """Timeouts (seconds) and retry limits of the conversation.

    Attributes
    ----------
    alive_timeout_s : float
        Wait for the first mtAlive (and for a rebooted head to come back; ENSTA allows 30 s).
    reply_timeout_s : float
        Wait for a reply before re-sending a request (McGill: 1 s).
    config_timeout_s : float
        Wait for 'params received' after mtHeadCommand (ENSTA: 10 s).
    max_retries : int
        Consecutive unanswered mtSendData before the head counts as stalled (McGill: 5).
    max_reboots : int
        Stall recoveries (mtReBoot) in a row without a scan line before giving up.
    quiet_gap_s : float, optional
        After one line of a full-duplex pair, how long to wait for the second (default: twice the
        expected line time, at least 0.1 s).
    high_nibble_first : bool
        Nibble order of 4-bit lines (§9.2).
    """

    alive_timeout_s: float = 30.0
    reply_timeout_s: float = 1.0
    config_timeout_s: float = 10.0
    max_retries: int = 5
    max_reboots: int = 3
    quiet_gap_s: float | None = None
    high_nibble_first: bool = True


@dataclass
class LinkStats:
    """Counters of one driver session (all JSON-serialisable)."""

    bytes_received: int = 0
    packets: int = 0
    discarded_bytes: int = 0
    lines: int = 0
    requests: int = 0
    timeouts: int = 0
    reboots: int = 0
    reconfigurations: int = 0
    bad_lines: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


class MicronDriver:
    """Talks to one Micron head.

    Parameters
    ----------
    port : str or serial.SerialBase
        A ``serial_for_url`` URL (device path, ``socket://host:port``, ``loop://``) or an open port.
    settings : HeadSettings
        What to configure.
    config : DriverConfig
        Timeouts and retries.
    raw_sink : callable, optional
        Called with every chunk of received bytes, before decoding.
    log : callable, optional
        Called with one-line status messages (start-up steps, retries, reboots).

    Examples
    --------
    >>> with MicronDriver("socket://127.0.0.1:4001", HeadSettings()) as head:   # doctest: +SKIP
    ...     capture = collect_scan(head)
    """

    def __init__(self, port: str | serial.SerialBase, settings: HeadSettings, *, config: DriverConfig | None = None,
                 raw_sink: Callable[[bytes], None] | None = None, log: Callable[[str], None] | None = None):
        self.settings = settings
        self.config = DriverConfig() if config is None else config
        self.raw_sink = raw_sink
        self.log = log or (lambda message: None)
        self.stats = LinkStats()
        self.version: VersionData | None = None
        self.bb_user: BBUserData | None = None
        self.last_alive: Alive | None = None
        self._port_arg = port
        self.port_name = port if isinstance(port, str) else str(getattr(port, "port", None) or port)
        self._serial: serial.SerialBase | None = None
        self._decoder = StreamDecoder()
        self._packets: deque[Packet] = deque()
        self._lost_params = False
        self._fd: int | None = None

    # port ----------------------------------------------------------------------------------------

    def open(self) -> "MicronDriver":
        """Open the port at 115200 8N1 and flush stale input (a port object given open is used as is)."""
        if self._serial is not None:
            return self
        try:
            if isinstance(self._port_arg, str):
                self._serial = serial.serial_for_url(self._port_arg, baudrate=BAUD, bytesize=8, parity="N",
                                                     stopbits=1, timeout=0.02, write_timeout=2.0)
                self._serial.reset_input_buffer()  # stale bytes of an earlier session
            else:
                self._serial = self._port_arg  # the caller's port: its buffered input is kept
                if not self._serial.is_open:
                    self._serial.open()
            self._fd = _waitable_fd(self._serial)
            if self._fd is not None:
                self._serial.timeout = 0  # reads return what is there; waiting is done with select
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(self.port_name, f"cannot open the port: {exc}") from None
        return self

    def close(self) -> None:
        """Stop the mtAlive stream (mtStopAlives) and close the port; never raises."""
        if self._serial is None:
            return
        try:
            self._write(command(MessageType.STOP_ALIVES))
            self._serial.flush()
        except LinkError:
            pass
        sock = getattr(self._serial, "_socket", None)
        try:
            self._serial.close()
        except (serial.SerialException, OSError):
            pass
        if sock is not None:
            sock.close()  # pyserial's socket:// skips close() when shutdown() fails on a dead link
        self._serial = None

    def __enter__(self) -> "MicronDriver":
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _write(self, data: bytes) -> None:
        if self._serial is None:
            raise LinkError(self.port_name, "the port is not open")
        try:
            self._serial.write(data)
        except (serial.SerialException, OSError) as exc:
            raise LinkError(self.port_name, f"link lost while writing: {exc}") from None

    def _fill(self, wait_s: float) -> None:
        """Wait up to ``wait_s`` for input, read everything available, decode it."""
        assert self._serial is not None
        try:
            if self._fd is not None:
                ready, _, _ = select.select([self._fd], [], [], max(0.0, wait_s))
                data = self._serial.read(65536) if ready else b""
            else:
                data = self._serial.read(max(1, min(self._serial.in_waiting, 65536)))
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(self.port_name, f"link lost while reading: {exc}") from None
        if not data:
            return
        self.stats.bytes_received += len(data)
        if self.raw_sink is not None:
            self.raw_sink(data)
        packets = self._decoder.feed(data)
        self.stats.discarded_bytes += sum(d.length for d in self._decoder.take_discards())
        self.stats.packets += len(packets)
        self._packets.extend(packets)

    def next_packet(self, timeout_s: float) -> Packet | None:
        """The next packet from the head, or None after ``timeout_s``; mtAlive is recorded on the way."""
        if self._serial is None:
            raise LinkError(self.port_name, "the port is not open")
        deadline = time.monotonic() + timeout_s
        while True:
            if self._packets:
                packet = self._packets.popleft()
                if packet.type == MessageType.ALIVE:
                    self._note_alive(packet)
                return packet
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self._fill(min(left, 0.05))

    def _note_alive(self, packet: Packet) -> None:
        try:
            self.last_alive = Alive.decode(packet)
        except PacketError:
            return
        if self.last_alive.no_params:
            self._lost_params = True

    def _wait_for(self, msg_type: int, timeout_s: float, *, what: str, resend: bytes | None = None,
                  resend_every_s: float = 1.0, accept: Callable[[Packet], bool] | None = None) -> Packet:
        """Read until a packet of ``msg_type`` (passing ``accept``) arrives, re-sending ``resend`` periodically."""
        deadline = time.monotonic() + timeout_s
        next_send = time.monotonic() + resend_every_s
        while True:
            now = time.monotonic()
            if now >= deadline:
                raise LinkError(self.port_name, f"no {what} within {timeout_s:g} s")
            if resend is not None and now >= next_send:
                self._write(resend)
                next_send = now + resend_every_s
            packet = self.next_packet(min(deadline, next_send if resend is not None else deadline) - now)
            if packet is not None and packet.type == msg_type and (accept is None or accept(packet)):
                return packet

    # start-up ------------------------------------------------------------------------------------

    def start(self) -> None:
        """The start-up and configuration sequence (§11.1 steps 2, 4-6).

        A head that was told mtStopAlives by an earlier session stays quiet; when no mtAlive comes within
        ``ALIVE_GRACE_S`` the head is rebooted, which restarts the stream (§11.5).
        """
        self.open()
        self.log("waiting for mtAlive")
        grace = min(ALIVE_GRACE_S, self.config.alive_timeout_s)
        try:
            self._wait_for(MessageType.ALIVE, grace, what="mtAlive")
        except LinkError:
            self.log("no mtAlive yet: mtReBoot")
            self._write(command(MessageType.REBOOT))
            self._wait_for(MessageType.ALIVE, self.config.alive_timeout_s,
                           what="mtAlive from the head (is it powered and wired, and is this the right port?)")
        self.handshake()

    def handshake(self) -> None:
        """mtSendVersion, mtSendBBUser, then :meth:`configure` (§11.1 steps 4-6)."""
        cfg = self.config
        self.log("mtSendVersion")
        packet = self._wait_for(MessageType.VERSION_DATA, cfg.config_timeout_s, what="mtVersionData",
                                resend=self._send(command(MessageType.SEND_VERSION)),
                                accept=_decodes(VersionData.decode))
        self.version = VersionData.decode(packet)
        self.log("mtSendBBUser")
        packet = self._wait_for(MessageType.BB_USER_DATA, cfg.config_timeout_s, what="mtBBUserData",
                                resend=self._send(command(MessageType.SEND_BB_USER)), resend_every_s=2.0,
                                accept=_decodes(BBUserData.decode))
        self.bb_user = BBUserData.decode(packet)
        self.configure()

    def _send(self, data: bytes) -> bytes:
        self._write(data)
        return data

    @property
    def replies_per_request(self) -> int:
        """1 in half duplex, 2 in full duplex (from mtBBUserData, §11.3); 1 before it is known."""
        return self.bb_user.replies_per_request if self.bb_user is not None else 1

    def configure(self) -> None:
        """Send mtHeadCommand until an mtAlive reports the parameters (NoParams = 0, §11.1 step 6)."""
        cmd = self.settings.head_command().encode()
        self.log("mtHeadCommand")
        self._lost_params = False
        self._wait_for(MessageType.ALIVE, self.config.config_timeout_s,
                       what="mtAlive reporting 'params received' after mtHeadCommand",
                       resend=self._send(cmd), resend_every_s=1.0,
                       accept=_alive_has_params)
        self._lost_params = False

    def reboot(self) -> None:
        """mtReBoot, wait for the head to come back, then the whole start-up sequence again."""
        self.stats.reboots += 1
        self.log("mtReBoot")
        self._write(command(MessageType.REBOOT))
        time.sleep(0.5)
        self._packets.clear()
        self._wait_for(MessageType.ALIVE, self.config.alive_timeout_s, what="mtAlive after mtReBoot")
        self.handshake()

    # streaming -----------------------------------------------------------------------------------

    def _quiet_gap(self) -> float:
        if self.config.quiet_gap_s is not None:
            return self.config.quiet_gap_s
        s = self.settings
        line_s = 2.0 * s.range_m / s.speed_of_sound + (45 + s.n_bins) * 10.0 / BAUD
        return max(0.1, 2.0 * line_s)

    def request(self) -> None:
        """Send one mtSendData (with the PC's time of day, §8)."""
        self.stats.requests += 1
        self._write(SendData(time_of_day_ms(time.time())).encode())

    def _collect_reply(self) -> list[HeadData]:
        """Lines answering the outstanding request: up to the expected count, or until a quiet gap."""
        expected = self.replies_per_request
        lines: list[HeadData] = []
        deadline = time.monotonic() + self.config.reply_timeout_s
        while len(lines) < expected:
            packet = self.next_packet(deadline - time.monotonic())
            if packet is None:
                break
            if packet.type != MessageType.HEAD_DATA:
                continue
            try:
                line = decode_head_data(packet, high_nibble_first=self.config.high_nibble_first)
            except PacketError:
                self.stats.bad_lines += 1
                continue
            if line.motor_error or line.power_loss:
                self._lost_params = True
            lines.append(line)
            deadline = time.monotonic() + self._quiet_gap()
        return lines

    def lines(self) -> Iterator[HeadData]:
        """Scan lines, forever, with one outstanding request; recovers from silence, stalls and resets.

        Raises
        ------
        LinkError
            The port failed, or the head stayed silent through ``max_reboots`` reboots.
        """
        silent = 0
        reboots_without_line = 0
        while True:
            if self._lost_params:
                self.stats.reconfigurations += 1
                if self.last_alive is not None and not self.last_alive.sent_cfg:
                    self.log("the head has reset: start-up sequence again")
                    self.handshake()
                else:
                    self.log("the head lost its parameters: configuring again")
                    self.configure()
            self.request()
            got = self._collect_reply()
            if got:
                silent = 0
                reboots_without_line = 0
                self.stats.lines += len(got)
                yield from got
                continue
            silent += 1
            self.stats.timeouts += 1
            if silent < self.config.max_retries:
                continue
            if reboots_without_line >= self.config.max_reboots:
                raise LinkError(self.port_name, f"no scan line after {self.stats.requests} requests: the head "
                                f"stayed silent through {reboots_without_line} reboot(s)")
            self.log(f"stall: {silent} requests unanswered; rebooting the head")
            silent = 0
            reboots_without_line += 1
            self.reboot()


def _waitable_fd(port: serial.SerialBase) -> int | None:
    """A file descriptor ``select`` can wait on (device, pty, ``socket://``), or None (e.g. ``loop://``)."""
    try:
        fd = port.fileno()
    except (AttributeError, NotImplementedError, OSError, serial.SerialException):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None


def _alive_has_params(packet: Packet) -> bool:
    try:
        return Alive.decode(packet).params_loaded
    except PacketError:
        return False


def _decodes(decoder: Callable[[Packet], object]) -> Callable[[Packet], bool]:
    def check(packet: Packet) -> bool:
        try:
            decoder(packet)
        except PacketError:
            return False
        return True
    return check
