"""mtHeadCommand (PC→head, §7): the normal command that configures a scan, gain and scan-reverse.

Byte layout: ``../shared/protocols/tritech_micron.md`` §7.2-7.4. The user-facing, validated form is
:class:`cistern_archive.tritech.settings.HeadSettings`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from cistern_archive.tritech.codec import (
    DEFAULT_SPEED_OF_SOUND,
    NODE_SONAR,
    MessageType,
    Packet,
    PacketError,
    command,
    expect_payload,
)
from cistern_archive.tritech.head_data import HdCtrlFlags, bin_length_m

__all__ = ["DEVICE_TYPE_DST", "GainCommand", "HeadCommand", "ReverseCommand", "decode_head_command"]

DEVICE_TYPE_DST = 0x11
"""HdType / DeviceType of a Micron DST (§7.2, §13)."""

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
    payload = expect_payload(packet, MessageType.HEAD_COMMAND, at_least=1)
    variant = payload[0]
    if variant == V3B_GAIN:
        return GainCommand.from_payload(payload, packet.offset)
    if variant == V3B_REVERSE:
        if len(payload) != 1:
            raise PacketError(f"scan-reverse mtHeadCommand with {len(payload)} payload bytes", packet.offset)
        return ReverseCommand()
    return HeadCommand.from_payload(payload, packet.offset)
