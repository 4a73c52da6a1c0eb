"""The messages of a Micron DST conversation other than the head command (§4-6, §8-9).

Framing and the direction helpers (:func:`~.codec.reply`, :func:`~.codec.command`) live in
:mod:`cistern_archive.tritech.codec`; this module adds the payloads a driver and a head exchange
(``../shared/protocols/tritech_micron.md``, section numbers below refer to it):

==================  =========  ===========================================  ================
message             direction  here                                         total bytes
==================  =========  ===========================================  ================
mtAlive             head→PC    :class:`Alive`                               22 (§4)
mtVersionData       head→PC    :class:`VersionData`                         25 (§5)
mtBBUserData        head→PC    :class:`BBUserData`                          264 (§6)
mtHeadCommand       PC→head    :mod:`~.head_command`                        66 / 82 / 31 / 15 (§7)
mtSendData          PC→head    :class:`SendData`                            18 (§8)
mtHeadData          head→PC    :class:`~.head_data.HeadData` (8/4-bit)      45 + Dbytes (§9)
mtSendVersion,      PC→head    :func:`~.codec.command`                      14 (§2.1)
mtSendBBUser,
mtReBoot,
mtStopAlives
==================  =========  ===========================================  ================

:func:`decode_message` dispatches a packet to its typed message; :func:`head_data_for` builds the line a
head configured with a command sends. The scan settings a user gives are :mod:`~.settings`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntFlag

import numpy as np

from cistern_archive.tritech.head_command import (
    DEVICE_TYPE_DST,
    GainCommand,
    HeadCommand,
    ReverseCommand,
    decode_head_command,
)
from cistern_archive.tritech.codec import (
    command,
    expect_payload,
    reply,
    NODE_SONAR,
    STEPS_PER_REV,
    MessageType,
    Packet,
    PacketError,
)
from cistern_archive.tritech.head_data import (
    STATUS_ADC8,
    HeadData,
    decode_head_data,
)

__all__ = [
    "Alive",
    "BBUserData",
    "HeadInf",
    "Message",
    "SendData",
    "VersionData",
    "decode_message",
    "head_data_for",
    "time_of_day_ms",
]

def time_of_day_ms(unix_s: float) -> int:
    """Milliseconds since UTC midnight, the clock mtSendData carries (§8)."""
    return int(round((unix_s % 86400.0) * 1000.0)) % 86_400_000


# ------------------------------------------------------------------------------------------------
# mtAlive (§4)
# ------------------------------------------------------------------------------------------------

class HeadInf(IntFlag):
    """The HeadInf bit field of mtAlive (§4; bit 0 = InCentre ... bit 7 = SentCfg, §13)."""

    IN_CENTRE = 0x01
    CENTRED = 0x02
    MOTORING = 0x04
    MOTOR_ON = 0x08
    DIR = 0x10
    IN_SCAN = 0x20
    NO_PARAMS = 0x40
    SENT_CFG = 0x80


_ALIVE = struct.Struct("<BIHB")


@dataclass(frozen=True)
class Alive:
    """mtAlive: the head's periodic status (22 bytes, §4).

    Attributes
    ----------
    will_send : int
        Index 13; 0 once the head has parameters (libminiking).
    head_time_ms : int
        Index 14..17, the head clock in ms.
    motor_position : int
        Index 18..19, transducer bearing in 1/16 gradian.
    head_inf : HeadInf
        Index 20.
    """

    will_send: int
    head_time_ms: int
    motor_position: int
    head_inf: HeadInf

    @property
    def no_params(self) -> bool:
        return bool(self.head_inf & HeadInf.NO_PARAMS)

    @property
    def sent_cfg(self) -> bool:
        return bool(self.head_inf & HeadInf.SENT_CFG)

    @property
    def params_loaded(self) -> bool:
        """The head reports valid mtHeadCommand parameters ('params received': NoParams = 0, §11.1 step 6)."""
        return not self.no_params

    def encode(self, *, node: int = NODE_SONAR) -> bytes:
        payload = _ALIVE.pack(self.will_send, self.head_time_ms & 0xFFFFFFFF, self.motor_position,
                              int(self.head_inf))
        return reply(MessageType.ALIVE, payload, node=node)

    @classmethod
    def decode(cls, packet: Packet) -> "Alive":
        will_send, head_time, position, inf = _ALIVE.unpack(expect_payload(packet, MessageType.ALIVE, _ALIVE.size))
        return cls(will_send, head_time, position, HeadInf(inf))


# ------------------------------------------------------------------------------------------------
# mtVersionData (§5)
# ------------------------------------------------------------------------------------------------

_VERSION = struct.Struct("<BBHIHB")


@dataclass(frozen=True)
class VersionData:
    """mtVersionData (25 bytes, §5): frequency/CPU code, board type, serial, program length and checksum."""

    frequency_code: int
    board: int
    serial: int
    program_length: int
    checksum: int
    node: int = NODE_SONAR

    def encode(self) -> bytes:
        payload = _VERSION.pack(self.frequency_code, self.board, self.serial, self.program_length, self.checksum,
                                self.node)
        return reply(MessageType.VERSION_DATA, payload, node=self.node)

    @classmethod
    def decode(cls, packet: Packet) -> "VersionData":
        return cls(*_VERSION.unpack(expect_payload(packet, MessageType.VERSION_DATA, _VERSION.size)))


# ------------------------------------------------------------------------------------------------
# mtBBUserData (§6)
# ------------------------------------------------------------------------------------------------

BB_USER_PAYLOAD = 250
"""Payload of the DST/MiniKing mtBBUserData (264 bytes on the wire)."""
_BB_DST_INDEX = 19 - 13
_BB_DUPLEX_DST_INDEX = 146 - 13
_BB_DUPLEX_OLD_INDEX = 99 - 13


@dataclass(frozen=True)
class BBUserData:
    """mtBBUserData, the head's non-volatile user block (§6); only the fields drivers use are decoded.

    Attributes
    ----------
    raw : bytes
        The whole payload (packet index 13 up to the LF).
    """

    raw: bytes

    @property
    def is_dst(self) -> bool:
        """Packet index 19 == 15 marks a DST head (ENSTA, [L])."""
        return len(self.raw) > _BB_DST_INDEX and self.raw[_BB_DST_INDEX] == 15

    @property
    def half_duplex(self) -> bool:
        """Packet index 146 on a DST (99 on older heads): 1 = half duplex (one scan line per mtSendData)."""
        index = _BB_DUPLEX_DST_INDEX if self.is_dst else _BB_DUPLEX_OLD_INDEX
        return len(self.raw) > index and self.raw[index] == 1

    @property
    def replies_per_request(self) -> int:
        """Scan lines one mtSendData yields: 1 in half duplex, 2 in full duplex (§11.3)."""
        return 1 if self.half_duplex else 2

    @classmethod
    def build(cls, *, half_duplex: bool, dst: bool = True) -> "BBUserData":
        """The block an emulated head reports (zeros but the DST marker and the duplex flag, §6)."""
        raw = bytearray(BB_USER_PAYLOAD)
        if dst:
            raw[_BB_DST_INDEX] = 15
        raw[_BB_DUPLEX_DST_INDEX if dst else _BB_DUPLEX_OLD_INDEX] = 1 if half_duplex else 0
        return cls(bytes(raw))

    def encode(self, *, node: int = NODE_SONAR) -> bytes:
        return reply(MessageType.BB_USER_DATA, self.raw, node=node)

    @classmethod
    def decode(cls, packet: Packet) -> "BBUserData":
        payload = expect_payload(packet, MessageType.BB_USER_DATA)
        if len(payload) not in (BB_USER_PAYLOAD, 175 - 14):
            raise PacketError(f"mtBBUserData payload is {len(payload)} bytes, expected 250 or 161", packet.offset)
        return cls(payload)


# ------------------------------------------------------------------------------------------------
# mtSendData (§8)
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SendData:
    """mtSendData (18 bytes, §8): the PC's time of day in ms; the head answers with 1 or 2 mtHeadData."""

    time_ms: int = 0

    def encode(self, *, node: int = NODE_SONAR) -> bytes:
        return command(MessageType.SEND_DATA, struct.pack("<I", self.time_ms & 0xFFFFFFFF), node=node)

    @classmethod
    def decode(cls, packet: Packet) -> "SendData":
        return cls(struct.unpack("<I", expect_payload(packet, MessageType.SEND_DATA, 4))[0])


# ------------------------------------------------------------------------------------------------
# mtHeadData built from a command (what a head echoes, §9.1, §11.5)
# ------------------------------------------------------------------------------------------------

def head_data_for(cmd: HeadCommand, bearing: int, bins: np.ndarray, *, sweep_code: int = 0,
                  head_status: int | None = None, gain: int | None = None) -> HeadData:
    """The scan line a head configured with ``cmd`` sends at ``bearing`` (§9.1, §11.5).

    Parameters
    ----------
    cmd : HeadCommand
        The active command; HdCtrl, range, ADSpan/ADLow, ADInterval, limits and step are echoed.
    bearing : int
        Transducer bearing, 0..6399.
    bins : ndarray
        ``cmd.n_bins`` values, 0..255 (8-bit) or 0..15 (4-bit).
    sweep_code, head_status, gain : int
        Index 17, 16 and 26; HeadStatus defaults to the 8-bit flag when adc8on.
    """
    values = np.asarray(bins, dtype=np.uint8)
    if values.shape != (cmd.n_bins,):
        raise ValueError(f"expected {cmd.n_bins} bins, got shape {values.shape}")
    status = (STATUS_ADC8 if cmd.adc8on else 0) if head_status is None else head_status
    dbytes = cmd.n_bins if cmd.adc8on else (cmd.n_bins + 1) // 2
    return HeadData(total_byte_count=dbytes + 31, device_type=DEVICE_TYPE_DST, head_status=status,
                    sweep_code=sweep_code, hd_ctrl=cmd.hd_ctrl, range_scale_raw=cmd.range_scale, txn=cmd.txn[0],
                    gain=cmd.igain[0] if gain is None else gain, slope=cmd.slope[0], ad_span=cmd.ad_span,
                    ad_low=cmd.ad_low, heading_offset=0, ad_interval=cmd.ad_interval, left_limit=cmd.left_limit,
                    right_limit=cmd.right_limit, step_size=cmd.step_size, bearing=bearing % STEPS_PER_REV,
                    dbytes=dbytes, bins=values)


# ------------------------------------------------------------------------------------------------
# Dispatch
# ------------------------------------------------------------------------------------------------

Message = Alive | VersionData | BBUserData | HeadData | HeadCommand | GainCommand | ReverseCommand | SendData | Packet


def decode_message(packet: Packet, *, high_nibble_first: bool = True) -> Message:
    """The typed message of a packet; types without a decoder here are returned as the packet itself.

    Raises
    ------
    PacketError
        A known type whose payload is malformed (the error names the stream offset).
    """
    kind = packet.type
    if kind == MessageType.HEAD_DATA:
        return decode_head_data(packet, high_nibble_first=high_nibble_first)
    if kind == MessageType.ALIVE:
        return Alive.decode(packet)
    if kind == MessageType.VERSION_DATA:
        return VersionData.decode(packet)
    if kind == MessageType.BB_USER_DATA:
        return BBUserData.decode(packet)
    if kind == MessageType.HEAD_COMMAND:
        return decode_head_command(packet)
    if kind == MessageType.SEND_DATA:
        return SendData.decode(packet)
    return packet


