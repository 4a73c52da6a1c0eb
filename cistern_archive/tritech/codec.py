"""SeaNet packet codec: framing, validation, an incremental stream decoder and ``mtHeadData``.

Wire format (``../shared/protocols/tritech_micron.md`` §1.2; byte indices 0-based from the ``@``)::

    0      '@' (0x40)
    1..4   L as 4 ASCII hex digits (either case accepted, upper case emitted)
    5..6   L as u16 little-endian
    7      source node (SID)        0xFF from the PC, the head's node (2) in replies
    8      destination node (DID)   the head's node in commands, 0xFF in replies
    9      byte count               L - 5 (mod 256); 0 in mtHeadData (§1.4)
    10     message type             :class:`MessageType`
    11     sequence                 0x80 for a single-packet message
    12     node                     the head's node number
    13..   payload                  n = L - 8 bytes
    L+5    LF (0x0A)

Total length on the wire is ``L + 6 = n + 14``. There is no checksum, so a packet is accepted only when
the hex and binary lengths agree, the LF sits where the length says, and the byte count is consistent
(§1.3). A decoder never splits on ``@`` or LF, because both occur inside payloads; after any failure it
skips one byte past the bad ``@`` and searches again (§1.3 rule 7), so the next good packet is never lost.

Public API
----------
* :class:`MessageType` — message type IDs (§2).
* :class:`Packet` — one decoded frame, with its byte offset in the stream.
* :func:`encode_packet` / :meth:`Packet.to_bytes` — build a frame.
* :func:`decode_packet` — strict decode of exactly one frame from a buffer.
* :class:`StreamDecoder` — feed arbitrary chunks, get packets; reports skipped garbage as :class:`Discard`.
* :func:`iter_packets` — decode a whole byte string.
* :class:`HeadData`, :func:`decode_head_data`, :func:`encode_head_data` — ``mtHeadData`` (§9).
* :func:`bearing_to_rad` — Tritech bearing steps to the sonar-frame convention of
  :mod:`cistern_archive.core.scan`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from cistern_archive.core.errors import CisternError

__all__ = [
    "ADINTERVAL_S",
    "DEFAULT_SPEED_OF_SOUND",
    "Discard",
    "HEADER_LENGTH",
    "HeadData",
    "LF",
    "MAX_LENGTH",
    "MIN_LENGTH",
    "MessageType",
    "NODE_PC",
    "NODE_SONAR",
    "Packet",
    "PacketError",
    "SEQ_SINGLE",
    "STEPS_PER_REV",
    "StreamDecoder",
    "bearing_to_rad",
    "bin_length_m",
    "decode_head_data",
    "decode_packet",
    "encode_head_data",
    "encode_packet",
    "iter_packets",
    "rad_to_bearing",
]

SYNC = 0x40
"""The ``@`` that starts every packet."""
LF = 0x0A
"""The terminator byte."""
HEADER_LENGTH = 13
"""Bytes before the payload (``@``, hex length, binary length, SID, DID, count, type, seq, node)."""
MIN_LENGTH = 8
"""Smallest L (a packet without payload, 14 bytes on the wire)."""
MAX_LENGTH = 4096
"""Sanity cap on L (§1.3 rule 8): generous for 1500-bin 8-bit lines (L = 1539), small enough to resync fast."""
NODE_PC = 0xFF
NODE_SONAR = 0x02
SEQ_SINGLE = 0x80
STEPS_PER_REV = 6400
"""Bearing steps per revolution: 400 gradians x 16 (§7.4)."""
ADINTERVAL_S = 640e-9
"""Unit of ADInterval, seconds (§7.4)."""
DEFAULT_SPEED_OF_SOUND = 1500.0
"""Speed of sound used when none is given, m/s."""


class MessageType(IntEnum):
    """SeaNet message type IDs (§2)."""

    NULL = 0
    VERSION_DATA = 1
    HEAD_DATA = 2
    SPECT_DATA = 3
    ALIVE = 4
    PRG_ACK = 5
    BB_USER_DATA = 6
    TEST_DATA = 7
    AUX_DATA = 8
    ADC_DATA = 9
    ADC_REQ = 10
    LAN_STATUS = 13
    SET_TIME = 14
    TIMEOUT = 15
    REBOOT = 16
    PERFORMANCE_DATA = 17
    HEAD_COMMAND = 19
    ERASE_SECTOR = 20
    PROG_BLOCK = 21
    COPY_BOOT_BLK = 22
    SEND_VERSION = 23
    SEND_BB_USER = 24
    SEND_DATA = 25
    SEND_PERFORMANCE_DATA = 26
    SEND_FPGA_VERSION = 56
    FPGA_VERSION_DATA = 57
    FPGA_CAL_DATA = 63
    STOP_ALIVES = 66
    RESET_TO_DEFAULTS = 70


class PacketError(CisternError):
    """A frame or a message payload is malformed.

    Parameters
    ----------
    message : str
        What is wrong.
    offset : int, optional
        Stream offset of the packet's ``@`` (or of the bad byte).
    """

    def __init__(self, message: str, offset: int | None = None):
        self.offset = offset
        where = f"byte offset {offset}: " if offset is not None else ""
        super().__init__(f"{where}{message}")


def _type_name(msg_type: int) -> str:
    try:
        return "mt" + "".join(part.title() for part in MessageType(msg_type).name.split("_"))
    except ValueError:
        return f"type {msg_type}"


@dataclass(frozen=True)
class Packet:
    """One SeaNet frame.

    Attributes
    ----------
    sid, did : int
        Source and destination node (index 7, 8).
    type : int
        Message type (index 10); compare with :class:`MessageType`.
    seq : int
        Sequence byte (index 11): bit 7 = last packet, bits 0-6 = packet number.
    node : int
        Node byte (index 12).
    payload : bytes
        Bytes 13 .. L+4 (everything between the node byte and the LF).
    offset : int
        Byte offset of the ``@`` in the stream it was decoded from (-1 when built in memory).
    byte_count : int
        The byte-count field (index 9) as received.
    """

    sid: int
    did: int
    type: int
    seq: int
    node: int
    payload: bytes
    offset: int = -1
    byte_count: int = -1

    @property
    def length(self) -> int:
        """L, the value of the hex and binary length fields."""
        return len(self.payload) + MIN_LENGTH

    @property
    def total_length(self) -> int:
        """Bytes on the wire, ``L + 6``."""
        return len(self.payload) + 14

    @property
    def type_name(self) -> str:
        """SeaNet name of the message type, e.g. ``mtHeadData``."""
        return _type_name(self.type)

    def to_bytes(self) -> bytes:
        """Encode the packet again (the byte count is recomputed unless it was recorded)."""
        return encode_packet(self.type, self.payload, sid=self.sid, did=self.did, seq=self.seq, node=self.node,
                             byte_count=self.byte_count if self.byte_count >= 0 else None)


def expected_byte_count(msg_type: int, length: int) -> int:
    """The byte-count field a sender should write: 0 for ``mtHeadData`` (§1.4), else ``(L - 5) & 0xFF``."""
    return 0 if msg_type == MessageType.HEAD_DATA else (length - 5) & 0xFF


def encode_packet(msg_type: int, payload: bytes = b"", *, sid: int = NODE_PC, did: int = NODE_SONAR,
                  node: int = NODE_SONAR, seq: int = SEQ_SINGLE, byte_count: int | None = None) -> bytes:
    """Build one SeaNet frame.

    Parameters
    ----------
    msg_type : int
        Message type (:class:`MessageType`).
    payload : bytes
        Bytes after the node byte (index 13 on), without the LF.
    sid, did, node, seq : int
        Header bytes; the defaults are a PC-to-head command (SID 0xFF, DID 2, node 2, seq 0x80, §3).
        For a head reply use ``sid=2, did=0xFF``.
    byte_count : int, optional
        Override of index 9; by default :func:`expected_byte_count`.

    Returns
    -------
    bytes
        ``len(payload) + 14`` bytes, ``@`` first, LF last.

    Raises
    ------
    ValueError
        A header byte is outside 0..255 or the payload exceeds :data:`MAX_LENGTH`.
    """
    length = len(payload) + MIN_LENGTH
    if length > MAX_LENGTH:
        raise ValueError(f"payload of {len(payload)} bytes exceeds the {MAX_LENGTH - MIN_LENGTH}-byte cap")
    count = expected_byte_count(msg_type, length) if byte_count is None else byte_count
    for name, value in (("sid", sid), ("did", did), ("node", node), ("seq", seq), ("type", msg_type),
                        ("byte_count", count)):
        if not 0 <= int(value) <= 255:
            raise ValueError(f"{name} must be a byte, got {value}")
    head = b"@%04X" % length + struct.pack("<HBBBBBB", length, sid, did, count, int(msg_type), seq, node)
    return head + bytes(payload) + b"\n"


def _parse_hex4(raw: bytes | bytearray) -> int | None:
    """Value of 4 ASCII hex digits, or None if any is not a hex digit."""
    value = 0
    for ch in raw:
        if 0x30 <= ch <= 0x39:
            digit = ch - 0x30
        elif 0x41 <= ch <= 0x46:
            digit = ch - 0x37
        elif 0x61 <= ch <= 0x66:
            digit = ch - 0x57
        else:
            return None
        value = value * 16 + digit
    return value


def _check_header(buf: bytes | bytearray, pos: int) -> tuple[int | None, str]:
    """Validate the 7 length bytes at ``buf[pos]``: ``(L, "")`` or ``(None, reason)``."""
    hex_len = _parse_hex4(buf[pos + 1:pos + 5])
    if hex_len is None:
        return None, "hex length is not 4 hex digits"
    bin_len = buf[pos + 5] | (buf[pos + 6] << 8)
    if hex_len != bin_len:
        return None, f"hex length {hex_len} != binary length {bin_len}"
    if not MIN_LENGTH <= hex_len <= MAX_LENGTH:
        return None, f"length {hex_len} outside {MIN_LENGTH}..{MAX_LENGTH}"
    return hex_len, ""


def _check_body(buf: bytes | bytearray, pos: int, length: int, strict_byte_count: bool) -> str:
    """Validate terminator and byte count of a complete frame; ``""`` when good."""
    if buf[pos + length + 5] != LF:
        return f"no LF at the end of a {length + 6}-byte frame (found 0x{buf[pos + length + 5]:02X})"
    if strict_byte_count:
        count = buf[pos + 9]
        msg_type = buf[pos + 10]
        if count != (length - 5) & 0xFF and not (msg_type == MessageType.HEAD_DATA and count == 0):
            return f"byte count {count} does not match length {length} ({_type_name(msg_type)})"
    return ""


def _make_packet(buf: bytes | bytearray, pos: int, length: int, offset: int) -> Packet:
    return Packet(sid=buf[pos + 7], did=buf[pos + 8], type=buf[pos + 10], seq=buf[pos + 11], node=buf[pos + 12],
                  payload=bytes(buf[pos + HEADER_LENGTH:pos + length + 5]), offset=offset,
                  byte_count=buf[pos + 9])


def decode_packet(data: bytes | bytearray, *, offset: int = 0, strict_byte_count: bool = True) -> Packet:
    """Decode exactly one frame that starts at ``data[0]``.

    Parameters
    ----------
    data : bytes
        At least one whole frame; bytes after it are ignored.
    offset : int
        Stream offset of ``data[0]``, recorded in the packet and in errors.
    strict_byte_count : bool
        Check the byte-count field (§1.3 rule 5).

    Raises
    ------
    PacketError
        The bytes do not start with a valid frame.
    """
    if len(data) < 7:
        raise PacketError(f"truncated header: {len(data)} of 7 length bytes", offset)
    if data[0] != SYNC:
        raise PacketError(f"expected '@', found 0x{data[0]:02X}", offset)
    length, reason = _check_header(data, 0)
    if length is None:
        raise PacketError(reason, offset)
    if len(data) < length + 6:
        raise PacketError(f"truncated packet: {len(data)} of {length + 6} bytes", offset)
    reason = _check_body(data, 0, length, strict_byte_count)
    if reason:
        raise PacketError(reason, offset)
    return _make_packet(data, 0, length, offset)


@dataclass(frozen=True)
class Discard:
    """Bytes a :class:`StreamDecoder` skipped.

    Attributes
    ----------
    offset : int
        Stream offset of the first skipped byte.
    length : int
        Number of bytes skipped.
    reason : str
        Why (the failed check of the ``@`` at ``offset``, or "no '@'" for bytes between packets).
    """

    offset: int
    length: int
    reason: str

    def __str__(self) -> str:
        return f"byte offset {self.offset}: skipped {self.length} byte(s): {self.reason}"


@dataclass
class StreamDecoder:
    """Incremental SeaNet decoder: feed byte chunks of any size, get whole validated packets.

    The decoder keeps at most one partial frame (bounded by :data:`MAX_LENGTH`). A false ``@`` whose hex
    and binary lengths happen to agree holds output back until its claimed length has arrived (at most
    ``MAX_LENGTH + 6`` bytes), then is rejected and the bytes after it are searched again, so no good
    packet is lost; :meth:`finish` does the same at the end of a stream. Skipped bytes are
    reported as :class:`Discard` records in :attr:`discards` (drain them with :meth:`take_discards`);
    contiguous skipped bytes are merged into one record, whose reason is the first failed check (or
    "no '@'" when the bytes held no ``@``).

    Parameters
    ----------
    strict_byte_count : bool
        Reject frames whose byte-count field is inconsistent (§1.3 rule 5).
    start_offset : int
        Stream offset of the first byte fed (packet offsets count from here).

    Examples
    --------
    >>> dec = StreamDecoder()
    >>> [p.type_name for p in dec.feed(b"xx" + encode_packet(MessageType.SEND_VERSION))]
    ['mtSendVersion']
    >>> dec.take_discards()
    [Discard(offset=0, length=2, reason="no '@'")]
    """

    strict_byte_count: bool = True
    start_offset: int = 0
    discards: list[Discard] = field(default_factory=list)
    packets_decoded: int = 0
    bytes_fed: int = 0

    def __post_init__(self) -> None:
        self._buf = bytearray()
        self._base = self.start_offset  # stream offset of self._buf[0]

    @property
    def pending(self) -> int:
        """Bytes buffered but not yet part of a decoded packet or a discard."""
        return len(self._buf)

    @property
    def stream_offset(self) -> int:
        """Stream offset of the next byte to be fed."""
        return self._base + len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Packet]:
        """Append ``data`` and return every packet completed by it, in stream order."""
        self._buf += data
        self.bytes_fed += len(data)
        return list(self._drain(final=False))

    def __call__(self, data: bytes | bytearray | memoryview) -> Iterator[Packet]:
        """Alias of :meth:`feed` returning an iterator."""
        return iter(self.feed(data))

    def finish(self) -> list[Packet]:
        """Signal the end of the stream.

        A candidate frame that cannot complete (the stream ended first) is abandoned one byte at a time,
        so a good packet hidden inside a false frame's claimed length is still returned. Whatever remains
        is reported as a discard ("truncated").
        """
        return list(self._drain(final=True))

    def take_discards(self) -> list[Discard]:
        """Return and clear the discard records."""
        out, self.discards = self.discards, []
        return out

    def _discard(self, start: int, stop: int, reason: str) -> None:
        if stop <= start:
            return
        offset = self._base + start
        last = self.discards[-1] if self.discards else None
        if last is not None and last.offset + last.length == offset:
            keep = reason if last.reason == "no '@'" else last.reason
            self.discards[-1] = Discard(last.offset, last.length + stop - start, keep)
        else:
            self.discards.append(Discard(offset, stop - start, reason))

    def _drain(self, final: bool) -> Iterator[Packet]:
        buf = self._buf
        pos = 0
        n = len(buf)
        try:
            while pos < n:
                at = buf.find(b"@", pos)
                if at < 0:
                    self._discard(pos, n, "no '@'")
                    pos = n
                    break
                self._discard(pos, at, "no '@'")
                pos = at
                if n - pos < 7:
                    if final:
                        self._discard(pos, pos + 1, f"truncated: stream ends {n - pos} byte(s) after '@'")
                        pos += 1
                        continue
                    break
                length, reason = _check_header(buf, pos)
                if length is None:
                    self._discard(pos, pos + 1, reason)
                    pos += 1
                    continue
                if n - pos < length + 6:
                    if final:
                        self._discard(pos, pos + 1, f"truncated: {n - pos} of {length + 6} bytes of a frame")
                        pos += 1
                        continue
                    break
                reason = _check_body(buf, pos, length, self.strict_byte_count)
                if reason:
                    self._discard(pos, pos + 1, reason)
                    pos += 1
                    continue
                packet = _make_packet(buf, pos, length, self._base + pos)
                pos += length + 6
                self.packets_decoded += 1
                yield packet
        finally:
            del buf[:pos]
            self._base += pos


def iter_packets(data: bytes | bytearray, *, start_offset: int = 0, strict_byte_count: bool = True,
                 discards: list[Discard] | None = None) -> Iterator[Packet]:
    """Decode every packet of a complete byte string (feeds it once and finishes).

    Parameters
    ----------
    data : bytes
        The stream.
    start_offset : int
        Offset of ``data[0]``.
    strict_byte_count : bool
        See :class:`StreamDecoder`.
    discards : list, optional
        Receives the :class:`Discard` records.
    """
    dec = StreamDecoder(strict_byte_count=strict_byte_count, start_offset=start_offset)
    yield from dec.feed(data)
    yield from dec.finish()
    if discards is not None:
        discards.extend(dec.take_discards())


# --------------------------------------------------------------------------------------------------
# Angles
# --------------------------------------------------------------------------------------------------

def bearing_to_rad(steps: np.ndarray | int | float, *, ahead: int = 3200) -> np.ndarray | float:
    """Convert Tritech bearings to sonar-frame angles.

    Tritech counts 1/16 gradian steps (6400 per revolution) **clockwise** seen from above, with
    ``ahead`` (3200 by the SeaKing convention, §7.4 and §13) pointing forward. The sonar frame of
    :mod:`cistern_archive.core.scan` is counter-clockwise from forward, so::

        theta = -(steps - ahead) * 2 pi / 6400,   wrapped to [-pi, pi)

    3200 -> 0, 1600 (90 deg left) -> +pi/2, 4800 (90 deg right) -> -pi/2, 0 (astern) -> -pi.
    """
    theta = -(np.asarray(steps, dtype=np.float64) - ahead) * (2 * np.pi / STEPS_PER_REV)
    wrapped = (theta + np.pi) % (2 * np.pi) - np.pi
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def rad_to_bearing(theta: np.ndarray | float, *, ahead: int = 3200) -> np.ndarray | int:
    """Inverse of :func:`bearing_to_rad`, rounded to whole steps in 0..6399."""
    steps = np.rint(ahead - np.asarray(theta, dtype=np.float64) * STEPS_PER_REV / (2 * np.pi)).astype(np.int64)
    steps %= STEPS_PER_REV
    return int(steps) if np.ndim(steps) == 0 else steps


# --------------------------------------------------------------------------------------------------
# mtHeadData
# --------------------------------------------------------------------------------------------------

# Payload layout of mtHeadData from TotalByteCount (packet index 13) to Dbytes (index 42..43), §9.1.
_HEAD_FMT = struct.Struct("<HBBBHHIBHBBHHHHBHH")
HEAD_DATA_HEADER = _HEAD_FMT.size  # 31 bytes before the bin data
assert HEAD_DATA_HEADER == 31

HDCTRL_ADC8ON = 0x0001
HDCTRL_CONT = 0x0002
HDCTRL_SCANRIGHT = 0x0004
HDCTRL_INVERT = 0x0008
HDCTRL_MOTOFF = 0x0010
HDCTRL_TXOFF = 0x0020
HDCTRL_CHAN2 = 0x0080
HDCTRL_RAW = 0x0100
HDCTRL_HASMOT = 0x0200
HDCTRL_APPLYOFFSET = 0x0400
HDCTRL_PINGPONG = 0x0800
HDCTRL_STARELLIM = 0x1000
HDCTRL_REPLYASL = 0x2000

STATUS_HDPWRLOSS = 0x01
STATUS_MOTERR = 0x02
STATUS_ADC8 = 0x10

RANGE_UNITS = ("m", "ft", "fathom", "yd")


class HdCtrlFlags:
    """The HdCtrl bits (§5) read from an ``hd_ctrl`` attribute; shared by head data and head commands."""

    hd_ctrl: int

    @property
    def adc8on(self) -> bool:
        """True for one byte per bin (HdCtrl bit 0)."""
        return bool(self.hd_ctrl & HDCTRL_ADC8ON)

    @property
    def continuous(self) -> bool:
        """Continuous 360° rotation (HdCtrl ``cont``) rather than a sector between the limits."""
        return bool(self.hd_ctrl & HDCTRL_CONT)

    @property
    def scan_right(self) -> bool:
        """Bearing increases (clockwise) while scanning (HdCtrl ``scanright``)."""
        return bool(self.hd_ctrl & HDCTRL_SCANRIGHT)

    @property
    def inverted(self) -> bool:
        """Head mounted upside-down (HdCtrl ``invert``)."""
        return bool(self.hd_ctrl & HDCTRL_INVERT)


@dataclass(frozen=True, eq=False)
class HeadData(HdCtrlFlags):
    """A decoded ``mtHeadData`` scan line (§9.1; field indices are packet indices).

    Attributes
    ----------
    total_byte_count : int
        Index 13..14, ``Dbytes + 31``.
    device_type : int
        Index 15 (0x11 on a Micron DST).
    head_status : int
        Index 16: bit 0 HdPwrLoss, bit 1 MotErr, bit 4 8-bit data.
    sweep_code : int
        Index 17: 0 scanning, 1 at left limit, 2 at right limit, 5 at centre.
    hd_ctrl : int
        Index 18..19, the active control word (§7.3).
    range_scale_raw : int
        Index 20..21: low 14 bits range x 10, top 2 bits unit code.
    txn : int
        Index 22..25.
    gain : int
        Index 26, IGain 0..210.
    slope : int
        Index 27..28.
    ad_span, ad_low : int
        Index 29, 30 (255 x dB / 80).
    heading_offset : int
        Index 31..32, 1/16 gradian.
    ad_interval : int
        Index 33..34, sampling interval in 640 ns units.
    left_limit, right_limit : int
        Index 35..36, 37..38, 1/16 gradian.
    step_size : int
        Index 39, 1/16 gradian.
    bearing : int
        Index 40..41, 0..6399 in 1/16 gradian, clockwise.
    dbytes : int
        Index 42..43, number of data bytes.
    bins : ndarray of uint8
        Bin amplitudes, 0..255 (8-bit) or 0..15 (4-bit, unpacked).
    """

    total_byte_count: int
    device_type: int
    head_status: int
    sweep_code: int
    hd_ctrl: int
    range_scale_raw: int
    txn: int
    gain: int
    slope: int
    ad_span: int
    ad_low: int
    heading_offset: int
    ad_interval: int
    left_limit: int
    right_limit: int
    step_size: int
    bearing: int
    dbytes: int
    bins: np.ndarray

    @property
    def full_scale(self) -> int:
        """Largest bin value: 255 in 8-bit mode, 15 in 4-bit mode."""
        return 255 if self.adc8on else 15

    @property
    def n_bins(self) -> int:
        return int(self.bins.shape[0])

    @property
    def range_scale(self) -> float:
        """Range setting in :attr:`range_unit` (informational only: geometry comes from ADInterval)."""
        return (self.range_scale_raw & 0x3FFF) / 10.0

    @property
    def range_unit(self) -> str:
        return RANGE_UNITS[self.range_scale_raw >> 14]

    @property
    def motor_error(self) -> bool:
        return bool(self.head_status & STATUS_MOTERR)

    @property
    def power_loss(self) -> bool:
        return bool(self.head_status & STATUS_HDPWRLOSS)

    def bearing_rad(self, *, ahead: int = 3200) -> float:
        """Sonar-frame bearing of this line (CCW from forward, radians).

        :func:`bearing_to_rad` of :attr:`bearing`, mirrored when the head is mounted upside-down
        (HdCtrl ``invert``): the transducer then turns the other way seen from above.
        """
        theta = float(bearing_to_rad(self.bearing, ahead=ahead))
        return -theta if self.inverted and theta != -math.pi else theta

    def bin_time_s(self) -> float:
        """Two-way travel time per bin, ``ADInterval x 640 ns`` (§7.4)."""
        return self.ad_interval * ADINTERVAL_S

    def bin_size_m(self, speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> float:
        """Bin length ``c x ADInterval x 640 ns / 2`` in metres (§7.4).

        Parameters
        ----------
        speed_of_sound : float
            Sound speed in the water, m/s (1500 by default; fresh cistern water is nearer 1480).
        """
        return bin_length_m(self.ad_interval, speed_of_sound)

    def span_m(self, speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> float:
        """Range covered by the line, ``NBins x bin size``."""
        return self.n_bins * self.bin_size_m(speed_of_sound)

    def settings(self) -> dict[str, int | float | str | bool]:
        """The head's echoed settings as a JSON-serialisable dict."""
        return {
            "device_type": self.device_type, "hd_ctrl": self.hd_ctrl, "adc8on": self.adc8on,
            "continuous": self.continuous, "scan_right": self.scan_right, "inverted": self.inverted,
            "range_scale": self.range_scale, "range_unit": self.range_unit, "gain": self.gain,
            "slope": self.slope, "ad_span": self.ad_span, "ad_low": self.ad_low,
            "heading_offset": self.heading_offset, "ad_interval": self.ad_interval,
            "left_limit": self.left_limit, "right_limit": self.right_limit, "step_size": self.step_size,
            "n_bins": self.n_bins,
        }


def unpack_nibbles(data: bytes | np.ndarray, *, high_nibble_first: bool = True) -> np.ndarray:
    """Unpack 4-bit bins, two per byte (§9.2; high nibble = nearer bin by default)."""
    raw = np.frombuffer(bytes(data), dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    out = np.empty(raw.size * 2, dtype=np.uint8)
    hi, lo = raw >> 4, raw & 0x0F
    out[0::2], out[1::2] = (hi, lo) if high_nibble_first else (lo, hi)
    return out


def pack_nibbles(bins: np.ndarray, *, high_nibble_first: bool = True) -> bytes:
    """Inverse of :func:`unpack_nibbles` (an odd count is padded with one 0 bin)."""
    values = np.asarray(bins, dtype=np.uint8)
    if values.size % 2:
        values = np.append(values, np.uint8(0))
    if np.any(values > 15):
        raise ValueError("4-bit bins must be 0..15")
    first, second = values[0::2], values[1::2]
    hi, lo = (first, second) if high_nibble_first else (second, first)
    return ((hi << 4) | lo).astype(np.uint8).tobytes()


def decode_head_data(packet: Packet | bytes, *, high_nibble_first: bool = True, offset: int | None = None,
                     check_total: bool = True) -> HeadData:
    """Decode an ``mtHeadData`` packet (or its payload) into :class:`HeadData`.

    Parameters
    ----------
    packet : Packet or bytes
        The packet, or its payload (index 13 to just before the LF).
    high_nibble_first : bool
        Nibble order of 4-bit data (§9.2, §13).
    offset : int, optional
        Stream offset for error messages (default: the packet's).
    check_total : bool
        Require ``TotalByteCount == Dbytes + 31 == len(payload)`` (§9.1, rock's checks).

    Raises
    ------
    PacketError
        Wrong type, payload too short, or inconsistent counts.
    """
    if isinstance(packet, Packet):
        if packet.type != MessageType.HEAD_DATA:
            raise PacketError(f"expected mtHeadData, got {packet.type_name}", packet.offset)
        payload = packet.payload
        offset = packet.offset if offset is None else offset
    else:
        payload = bytes(packet)
    if len(payload) < HEAD_DATA_HEADER:
        raise PacketError(f"mtHeadData payload of {len(payload)} bytes is shorter than its "
                          f"{HEAD_DATA_HEADER}-byte header", offset)
    (total, device_type, status, sweep, hd_ctrl, range_raw, txn, gain, slope, span, low, heading_offset,
     ad_interval, left, right, step, bearing, dbytes) = _HEAD_FMT.unpack_from(payload)
    available = len(payload) - HEAD_DATA_HEADER
    if dbytes > available:
        raise PacketError(f"mtHeadData Dbytes {dbytes} exceeds the {available} data bytes present", offset)
    if check_total and (total != dbytes + HEAD_DATA_HEADER or dbytes != available):
        raise PacketError(f"mtHeadData counts disagree: TotalByteCount {total}, Dbytes {dbytes}, "
                          f"{available} data bytes", offset)
    raw = np.frombuffer(payload, dtype=np.uint8, count=dbytes, offset=HEAD_DATA_HEADER)
    bins = raw.copy() if hd_ctrl & HDCTRL_ADC8ON else unpack_nibbles(raw, high_nibble_first=high_nibble_first)
    bins.setflags(write=False)
    return HeadData(total, device_type, status, sweep, hd_ctrl, range_raw, txn, gain, slope, span, low,
                    heading_offset, ad_interval, left, right, step, bearing, dbytes, bins)


def encode_head_data(head: HeadData, *, high_nibble_first: bool = True, sid: int = NODE_SONAR,
                     did: int = NODE_PC, node: int = NODE_SONAR) -> bytes:
    """Build a whole ``mtHeadData`` frame from :class:`HeadData` (byte count 0, §1.4).

    ``total_byte_count`` and ``dbytes`` are recomputed from the bins; the other fields are written as given.
    """
    data = (np.asarray(head.bins, dtype=np.uint8).tobytes() if head.adc8on
            else pack_nibbles(head.bins, high_nibble_first=high_nibble_first))
    header = _HEAD_FMT.pack(len(data) + HEAD_DATA_HEADER, head.device_type, head.head_status, head.sweep_code,
                            head.hd_ctrl, head.range_scale_raw, head.txn, head.gain, head.slope, head.ad_span,
                            head.ad_low, head.heading_offset, head.ad_interval, head.left_limit,
                            head.right_limit, head.step_size, head.bearing, len(data))
    return encode_packet(MessageType.HEAD_DATA, header + data, sid=sid, did=did, node=node)


def bin_length_m(ad_interval: int, speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> float:
    """Bin length of an ADInterval: ``c x ADInterval x 640 ns / 2`` in metres (§7.4)."""
    return speed_of_sound * ad_interval * ADINTERVAL_S / 2.0


def ad_interval_for(range_m: float, n_bins: int, speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> int:
    """ADInterval for a wanted range and bin count: ``round(2 R / N / c / 640 ns)``, at least 5 (§7.4)."""
    if range_m <= 0 or n_bins <= 0 or not math.isfinite(range_m):
        raise ValueError(f"range {range_m} m and bins {n_bins} must be positive")
    return max(5, int(round(2.0 * range_m / n_bins / speed_of_sound / ADINTERVAL_S)))
