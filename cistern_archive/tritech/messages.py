"""The messages of a Micron DST conversation, and the typed settings that build its head command.

Framing, validation and ``mtHeadData`` live in :mod:`cistern_archive.tritech.codec`; this module adds the
payloads of the other messages a driver and a head exchange (``../shared/protocols/tritech_micron.md``,
section numbers below refer to it):

==================  =========  ===========================================  ================
message             direction  here                                         total bytes
==================  =========  ===========================================  ================
mtAlive             head→PC    :class:`Alive`                               22 (§4)
mtVersionData       head→PC    :class:`VersionData`                         25 (§5)
mtBBUserData        head→PC    :class:`BBUserData`                          264 (§6)
mtHeadCommand       PC→head    :class:`HeadCommand` (0x01 / 0x1D),          66 / 82 (§7)
                               :class:`GainCommand` (0x1E),                 31
                               :class:`ReverseCommand` (0x0F)               15
mtSendData          PC→head    :class:`SendData`                            18 (§8)
mtHeadData          head→PC    :class:`~.codec.HeadData` (8- and 4-bit)     45 + Dbytes (§9)
mtSendVersion,      PC→head    :func:`command`                              14 (§2.1)
mtSendBBUser,
mtReBoot,
mtStopAlives
==================  =========  ===========================================  ================

:class:`HeadSettings` is the user-facing, validated description of a scan (range, bins, gain, step,
sector, direction, 8/4-bit); :meth:`HeadSettings.head_command` turns it into the DST's 0x01 command,
with ADInterval from §7.4.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, replace
from enum import IntFlag
from typing import Literal, get_args

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from cistern_archive.tritech.codec import (
    bin_length_m,
    HdCtrlFlags,
    DEFAULT_SPEED_OF_SOUND,
    HDCTRL_ADC8ON,
    HDCTRL_CONT,
    HDCTRL_HASMOT,
    HDCTRL_INVERT,
    HDCTRL_RAW,
    HDCTRL_REPLYASL,
    HDCTRL_SCANRIGHT,
    NODE_PC,
    NODE_SONAR,
    STATUS_ADC8,
    STEPS_PER_REV,
    HeadData,
    MessageType,
    Packet,
    PacketError,
    _type_name,
    ad_interval_for,
    decode_head_data,
    encode_packet,
)

__all__ = [
    "Alive",
    "BBUserData",
    "GainCommand",
    "HeadCommand",
    "HeadInf",
    "HeadSettings",
    "Message",
    "ReverseCommand",
    "SendData",
    "VersionData",
    "command",
    "decode_message",
    "head_data_for",
    "reply",
    "time_of_day_ms",
]

HDCTRL_BASE = HDCTRL_RAW | HDCTRL_HASMOT | HDCTRL_REPLYASL
"""raw | hasmot | ReplyASL, always set for an imaging sonar (§7.3): 0x2300."""
IGAIN_MAX = 210
"""IGain of 100 % (80 dB), §7.4."""
DEVICE_TYPE_DST = 0x11
"""HdType / DeviceType of a Micron DST (§7.2, §13)."""


def _expect(packet: Packet, msg_type: MessageType, size: int | None = None, at_least: int | None = None) -> bytes:
    """The payload of ``packet`` after checking its type and length; PacketError names the offset."""
    if packet.type != msg_type:
        raise PacketError(f"expected {_type_name(msg_type)}, got {packet.type_name}", packet.offset)
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
        will_send, head_time, position, inf = _ALIVE.unpack(_expect(packet, MessageType.ALIVE, _ALIVE.size))
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
        return cls(*_VERSION.unpack(_expect(packet, MessageType.VERSION_DATA, _VERSION.size)))


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
        payload = _expect(packet, MessageType.BB_USER_DATA)
        if len(payload) not in (BB_USER_PAYLOAD, 175 - 14):
            raise PacketError(f"mtBBUserData payload is {len(payload)} bytes, expected 250 or 161", packet.offset)
        return cls(payload)


# ------------------------------------------------------------------------------------------------
# mtHeadCommand (§7)
# ------------------------------------------------------------------------------------------------

V3B_NORMAL = 0x01
V3B_DUAL = 0x1D
V3B_GAIN = 0x1E
V3B_REVERSE = 0x0F
# Packet index 14..64 of the normal command (§7.2): HdCtrl .. ScanZ.
_HEAD_CMD = struct.Struct("<HB4IHHHHBBBBHHBBHHHHHBBH")
# The 16-byte V3B block (§7.2): ADSpan x2, ADLow x2, IGain x2, set-point x2, Slope x2, slope delay x2.
_V3B = struct.Struct("<8B4H")
assert _HEAD_CMD.size == 51 and _V3B.size == 16


@dataclass(frozen=True)
class HeadCommand(HdCtrlFlags):
    """The normal mtHeadCommand (V3BParams 0x01, 66 bytes; or 0x1D + V3B block, 82 bytes), §7.2.

    Field names follow the sheet; angles are 1/16 gradian, ``ad_interval`` is in 640 ns units,
    ``lockout`` in µs, ``range_scale`` is range x 10 with the unit code in the top 2 bits.
    """

    hd_ctrl: int
    hd_type: int = DEVICE_TYPE_DST
    txn: tuple[int, int] = (0, 0)
    rxn: tuple[int, int] = (0, 0)
    tx_pulse_len: int = 0
    range_scale: int = 100
    left_limit: int = 2400
    right_limit: int = 4000
    ad_span: int = 81
    ad_low: int = 8
    igain: tuple[int, int] = (84, 84)
    slope: tuple[int, int] = (0, 0)
    mo_time: int = 25
    step_size: int = 16
    ad_interval: int = 104
    n_bins: int = 200
    max_ad_buf: int = 1000
    lockout: int = 100
    minor_axis: int = 1600
    major_axis: int = 1
    ctl2: int = 0
    scan_z: int = 0
    v3b_block: bytes | None = None

    @property
    def variant(self) -> int:
        """0x01 (single channel, the DST's form) or 0x1D (with the V3B block)."""
        return V3B_NORMAL if self.v3b_block is None else V3B_DUAL

    def bin_size_m(self, speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> float:
        """``c x ADInterval x 640 ns / 2`` (§7.4)."""
        return bin_length_m(self.ad_interval, speed_of_sound)

    def payload(self) -> bytes:
        body = _HEAD_CMD.pack(self.hd_ctrl, self.hd_type, *self.txn, *self.rxn, self.tx_pulse_len, self.range_scale,
                              self.left_limit, self.right_limit, self.ad_span, self.ad_low, *self.igain, *self.slope,
                              self.mo_time, self.step_size, self.ad_interval, self.n_bins, self.max_ad_buf,
                              self.lockout, self.minor_axis, self.major_axis, self.ctl2, self.scan_z)
        if self.v3b_block is None:
            return bytes([V3B_NORMAL]) + body
        if len(self.v3b_block) != _V3B.size:
            raise ValueError(f"the V3B block is 16 bytes, got {len(self.v3b_block)}")
        return bytes([V3B_DUAL]) + body + bytes(self.v3b_block)

    def encode(self, *, node: int = NODE_SONAR) -> bytes:
        """The whole frame: 66 bytes for 0x01, 82 for 0x1D."""
        return command(MessageType.HEAD_COMMAND, self.payload(), node=node)

    @classmethod
    def from_payload(cls, payload: bytes, offset: int = -1) -> "HeadCommand":
        variant = payload[0] if payload else None
        expected = {V3B_NORMAL: 52, V3B_DUAL: 68}.get(variant)  # type: ignore[arg-type]
        if expected is None or len(payload) != expected:
            raise PacketError(f"not a normal mtHeadCommand: V3BParams {variant!r}, payload {len(payload)} bytes",
                              offset)
        f = _HEAD_CMD.unpack_from(payload, 1)
        return cls(hd_ctrl=f[0], hd_type=f[1], txn=(f[2], f[3]), rxn=(f[4], f[5]), tx_pulse_len=f[6],
                   range_scale=f[7], left_limit=f[8], right_limit=f[9], ad_span=f[10], ad_low=f[11],
                   igain=(f[12], f[13]), slope=(f[14], f[15]), mo_time=f[16], step_size=f[17], ad_interval=f[18],
                   n_bins=f[19], max_ad_buf=f[20], lockout=f[21], minor_axis=f[22], major_axis=f[23], ctl2=f[24],
                   scan_z=f[25], v3b_block=bytes(payload[52:]) if variant == V3B_DUAL else None)


@dataclass(frozen=True)
class GainCommand:
    """The reduced gain-only mtHeadCommand (0x1E, 31 bytes, §7.2): the 16 bytes of the V3B block."""

    ad_span: tuple[int, int]
    ad_low: tuple[int, int]
    igain: tuple[int, int]
    set_point: tuple[int, int] = (0, 0)
    slope: tuple[int, int] = (0, 0)
    slope_delay: tuple[int, int] = (0, 0)

    def payload(self) -> bytes:
        return bytes([V3B_GAIN]) + _V3B.pack(*self.ad_span, *self.ad_low, *self.igain, *self.set_point,
                                             *self.slope, *self.slope_delay)

    def encode(self, *, node: int = NODE_SONAR) -> bytes:
        return command(MessageType.HEAD_COMMAND, self.payload(), node=node)

    @classmethod
    def from_payload(cls, payload: bytes, offset: int = -1) -> "GainCommand":
        if len(payload) != 17 or payload[0] != V3B_GAIN:
            raise PacketError(f"not a gain-only mtHeadCommand ({len(payload)} payload bytes)", offset)
        v = _V3B.unpack_from(payload, 1)
        return cls(v[0:2], v[2:4], v[4:6], v[6:8], v[8:10], v[10:12])


@dataclass(frozen=True)
class ReverseCommand:
    """The scan-reverse mtHeadCommand (0x0F, 15 bytes, §7.2)."""

    def encode(self, *, node: int = NODE_SONAR) -> bytes:
        return command(MessageType.HEAD_COMMAND, bytes([V3B_REVERSE]), node=node)


def decode_head_command(packet: Packet) -> HeadCommand | GainCommand | ReverseCommand:
    """Any of the four mtHeadCommand variants (§7.1)."""
    payload = _expect(packet, MessageType.HEAD_COMMAND, at_least=1)
    variant = payload[0]
    if variant == V3B_GAIN:
        return GainCommand.from_payload(payload, packet.offset)
    if variant == V3B_REVERSE:
        if len(payload) != 1:
            raise PacketError(f"scan-reverse mtHeadCommand with {len(payload)} payload bytes", packet.offset)
        return ReverseCommand()
    return HeadCommand.from_payload(payload, packet.offset)


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
        return cls(struct.unpack("<I", _expect(packet, MessageType.SEND_DATA, 4))[0])


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


# ------------------------------------------------------------------------------------------------
# Settings
# ------------------------------------------------------------------------------------------------

StepSize = Literal[4, 8, 16, 32, 64, 128]
STEP_SIZES: tuple[int, ...] = get_args(StepSize)


class HeadSettings(BaseModel):
    """What to ask the head for; builds the DST's 0x01 mtHeadCommand (§7.2-7.4).

    Angles (``step``, ``left_limit``, ``right_limit``) are Tritech bearing steps of 1/16 gradian
    (6400 per revolution, 3200 = ahead, increasing clockwise). The sector limits only matter when
    ``continuous`` is false.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    range_m: float = Field(10.0, gt=0, le=300, description="wanted range, metres")
    n_bins: int = Field(200, ge=2, le=1500, description="range bins per scan line")
    gain: float = Field(0.4, ge=0, le=1, description="initial gain as a fraction of full (IGain = gain x 210)")
    step: StepSize = Field(16, description="motor step per ping, 1/16 gradian (16 = 0.9 deg)")
    continuous: bool = Field(True, description="rotate 360 deg; false scans the sector between the limits")
    left_limit: int = Field(2400, ge=0, lt=STEPS_PER_REV)
    right_limit: int = Field(4000, ge=0, lt=STEPS_PER_REV)
    direction: Literal["right", "left"] = Field("right", description="right = clockwise (bearing increases)")
    bits: Literal[8, 4] = Field(8, description="8-bit bins, or 4-bit bins packed two per byte")
    inverted: bool = Field(False, description="head mounted upside-down")
    speed_of_sound: float = Field(DEFAULT_SPEED_OF_SOUND, gt=1000, lt=2000, description="m/s")
    ad_span: int = Field(81, ge=1, le=255, description="255 x span_dB / 80")
    ad_low: int = Field(8, ge=0, le=255, description="255 x low_dB / 80")
    slope: int = Field(0, ge=0, le=65535)
    mo_time: int = Field(25, ge=1, le=255, description="motor step delay, 10 us units")
    max_ad_buf: int = Field(1000, ge=1, le=1000)
    lockout_us: int = Field(100, ge=0, le=65535)

    @model_validator(mode="after")
    def _consistent(self) -> "HeadSettings":
        if self.bits == 4 and self.n_bins % 2:
            raise ValueError("4-bit data packs two bins per byte: n_bins must be even")
        interval = self.ad_interval()
        if interval > 1500:
            raise ValueError(f"ADInterval {interval} exceeds 1500: too few bins for {self.range_m} m")
        if round(self.range_m * 10) > 0x3FFF:
            raise ValueError("range_m x 10 must fit in 14 bits")
        return self

    def ad_interval(self) -> int:
        """``round((2 R / N) / c / 640 ns)``, at least 5 (§7.4; see :func:`~.codec.ad_interval_for`)."""
        return ad_interval_for(self.range_m, self.n_bins, self.speed_of_sound)

    def bin_size_m(self) -> float:
        """The bin length the head will actually use, ``c x ADInterval x 640 ns / 2`` (§7.4)."""
        return bin_length_m(self.ad_interval(), self.speed_of_sound)

    def hd_ctrl(self) -> int:
        """The HdCtrl word (§7.3): 0x2300 plus adc8on, cont, scanright, invert."""
        word = HDCTRL_BASE
        if self.bits == 8:
            word |= HDCTRL_ADC8ON
        if self.continuous:
            word |= HDCTRL_CONT
        if self.direction == "right":
            word |= HDCTRL_SCANRIGHT
        if self.inverted:
            word |= HDCTRL_INVERT
        return word

    def igain(self) -> int:
        """IGain 0..210 (§7.4)."""
        return int(round(self.gain * IGAIN_MAX))

    def beams_per_revolution(self) -> int:
        return STEPS_PER_REV // self.step

    def head_command(self) -> HeadCommand:
        """The 66-byte 0x01 command a Micron DST takes (§7.1, example §12.3)."""
        gain = self.igain()
        return HeadCommand(
            hd_ctrl=self.hd_ctrl(), hd_type=DEVICE_TYPE_DST, range_scale=int(round(self.range_m * 10)),
            left_limit=self.left_limit, right_limit=self.right_limit, ad_span=self.ad_span, ad_low=self.ad_low,
            igain=(gain, gain), slope=(self.slope, self.slope), mo_time=self.mo_time, step_size=self.step,
            ad_interval=self.ad_interval(), n_bins=self.n_bins, max_ad_buf=self.max_ad_buf,
            lockout=self.lockout_us, minor_axis=1600, major_axis=1,
        )

    def as_record(self) -> dict[str, int | float | str | bool]:
        """JSON-serialisable settings plus the derived ADInterval and bin size."""
        out: dict[str, int | float | str | bool] = dict(self.model_dump())
        out["ad_interval"] = self.ad_interval()
        out["bin_size_m"] = self.bin_size_m()
        out["hd_ctrl"] = self.hd_ctrl()
        return out


def settings_from_command(cmd: HeadCommand, speed_of_sound: float = DEFAULT_SPEED_OF_SOUND) -> HeadSettings:
    """The :class:`HeadSettings` closest to a received command (range from ADInterval, §7.4)."""
    step = cmd.step_size if cmd.step_size in STEP_SIZES else 16
    range_m = cmd.n_bins * bin_length_m(cmd.ad_interval, speed_of_sound)
    return HeadSettings(
        range_m=max(range_m, 0.01), n_bins=max(2, cmd.n_bins), gain=min(1.0, cmd.igain[0] / IGAIN_MAX),
        step=step, continuous=cmd.continuous, left_limit=cmd.left_limit % STEPS_PER_REV,
        right_limit=cmd.right_limit % STEPS_PER_REV, direction="right" if cmd.scan_right else "left",
        bits=8 if cmd.adc8on else 4, inverted=cmd.inverted, speed_of_sound=speed_of_sound,
        ad_span=max(1, cmd.ad_span), ad_low=cmd.ad_low,
    )


def with_gain(cmd: HeadCommand, gain: GainCommand) -> HeadCommand:
    """``cmd`` after a 0x1E gain-only command (§7.2)."""
    return replace(cmd, ad_span=gain.ad_span[0], ad_low=gain.ad_low[0], igain=gain.igain, slope=gain.slope)


def reversed_command(cmd: HeadCommand) -> HeadCommand:
    """``cmd`` after a 0x0F scan-reverse command: the scanright bit flipped."""
    return replace(cmd, hd_ctrl=cmd.hd_ctrl ^ HDCTRL_SCANRIGHT)


def steps_to_deg(steps: float) -> float:
    """1/16 gradian steps to degrees (x 360/6400)."""
    return steps * 360.0 / STEPS_PER_REV


def deg_to_steps(deg: float) -> int:
    """Degrees to whole 1/16 gradian steps."""
    return int(round(deg * STEPS_PER_REV / 360.0)) % STEPS_PER_REV

