"""``mtHeadData`` (one sonar line: bearing, range settings and bins, §9) and Tritech bearings.

Byte layout and flags: ``../shared/protocols/tritech_micron.md`` §5, §7.4 and §9.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from cistern_archive.tritech.codec import (
    ADINTERVAL_S,
    DEFAULT_SPEED_OF_SOUND,
    NODE_PC,
    NODE_SONAR,
    STEPS_PER_REV,
    MessageType,
    Packet,
    PacketError,
    encode_packet,
)

__all__ = ["HeadData", "bearing_to_rad", "bin_length_m", "decode_head_data", "encode_head_data",
           "rad_to_bearing"]


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
