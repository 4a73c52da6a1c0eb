"""SeaNet packet codec: framing and validation of one packet.

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
* :func:`check_header`, :func:`check_body`, :func:`packet_at` — the checks a decoder applies (§1.3).

The incremental stream decoder is :mod:`cistern_archive.tritech.stream`; ``mtHeadData`` and bearings
are :mod:`cistern_archive.tritech.head_data`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum


from cistern_archive.core.errors import CisternError

__all__ = [
    "ADINTERVAL_S",
    "DEFAULT_SPEED_OF_SOUND",
    "HEADER_LENGTH",
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
    "check_body",
    "check_header",
    "command",
    "decode_packet",
    "encode_packet",
    "expect_payload",
    "packet_at",
    "reply",
    "type_name",
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


def type_name(msg_type: int) -> str:
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
        return type_name(self.type)

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


def check_header(buf: bytes | bytearray, pos: int) -> tuple[int | None, str]:
    """Validate the 7 length bytes at ``buf[pos]``: ``(L, "")`` or ``(None, reason)`` (§1.3 rules 1-3, 8)."""
    hex_len = _parse_hex4(buf[pos + 1:pos + 5])
    if hex_len is None:
        return None, "hex length is not 4 hex digits"
    bin_len = buf[pos + 5] | (buf[pos + 6] << 8)
    if hex_len != bin_len:
        return None, f"hex length {hex_len} != binary length {bin_len}"
    if not MIN_LENGTH <= hex_len <= MAX_LENGTH:
        return None, f"length {hex_len} outside {MIN_LENGTH}..{MAX_LENGTH}"
    return hex_len, ""


def check_body(buf: bytes | bytearray, pos: int, length: int, strict_byte_count: bool) -> str:
    """Validate terminator and byte count of a complete frame; ``""`` when good (§1.3 rules 4-5)."""
    if buf[pos + length + 5] != LF:
        return f"no LF at the end of a {length + 6}-byte frame (found 0x{buf[pos + length + 5]:02X})"
    if strict_byte_count:
        count = buf[pos + 9]
        msg_type = buf[pos + 10]
        if count != (length - 5) & 0xFF and not (msg_type == MessageType.HEAD_DATA and count == 0):
            return f"byte count {count} does not match length {length} ({type_name(msg_type)})"
    return ""


def packet_at(buf: bytes | bytearray, pos: int, length: int, offset: int) -> Packet:
    """The frame of length ``L = length`` at ``buf[pos]`` (already checked) as a :class:`Packet`."""
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
    length, reason = check_header(data, 0)
    if length is None:
        raise PacketError(reason, offset)
    if len(data) < length + 6:
        raise PacketError(f"truncated packet: {len(data)} of {length + 6} bytes", offset)
    reason = check_body(data, 0, length, strict_byte_count)
    if reason:
        raise PacketError(reason, offset)
    return packet_at(data, 0, length, offset)


# --------------------------------------------------------------------------------------------------
# Frames by direction (§3) and payload checks
# --------------------------------------------------------------------------------------------------

def expect_payload(packet: Packet, msg_type: MessageType, size: int | None = None, at_least: int | None = None) -> bytes:
    """The payload of ``packet`` after checking its type and length; PacketError names the offset."""
    if packet.type != msg_type:
        raise PacketError(f"expected {type_name(msg_type)}, got {packet.type_name}", packet.offset)
    payload = packet.payload
    if size is not None and len(payload) != size:
        raise PacketError(f"{packet.type_name} payload is {len(payload)} bytes, expected {size}", packet.offset)
    if at_least is not None and len(payload) < at_least:
        raise PacketError(f"{packet.type_name} payload is {len(payload)} bytes, expected at least {at_least}",
                          packet.offset)
    return payload


def reply(msg_type: int, payload: bytes = b"", *, node: int = NODE_SONAR) -> bytes:
    """A head-to-PC frame (SID = node, DID 0xFF, node byte = SID, §3)."""
    return encode_packet(msg_type, payload, sid=node, did=NODE_PC, node=node)


def command(msg_type: int, payload: bytes = b"", *, node: int = NODE_SONAR) -> bytes:
    """A PC-to-head frame (SID 0xFF, DID = node, node byte = node, §3); no payload gives the 14-byte
    commands of §2.1 (mtSendVersion, mtSendBBUser, mtReBoot, mtStopAlives)."""
    return encode_packet(msg_type, payload, sid=NODE_PC, did=node, node=node)
