"""Head settings: the user-facing, validated description of a scan (range, bins, gain, step, sector,
direction, 8/4-bit) and its translation to and from the DST's 0x01 mtHeadCommand (§7.2-7.4).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, model_validator

from cistern_archive.tritech.codec import DEFAULT_SPEED_OF_SOUND, STEPS_PER_REV
from cistern_archive.tritech.head_command import DEVICE_TYPE_DST, GainCommand, HeadCommand
from cistern_archive.tritech.head_data import (
    HDCTRL_ADC8ON,
    HDCTRL_CONT,
    HDCTRL_HASMOT,
    HDCTRL_INVERT,
    HDCTRL_RAW,
    HDCTRL_REPLYASL,
    HDCTRL_SCANRIGHT,
    ad_interval_for,
    bin_length_m,
)

__all__ = ["STEP_SIZES", "HeadSettings", "deg_to_steps", "reversed_command", "settings_from_command",
           "steps_to_deg", "with_gain"]

HDCTRL_BASE = HDCTRL_RAW | HDCTRL_HASMOT | HDCTRL_REPLYASL
"""raw | hasmot | ReplyASL, always set for an imaging sonar (§7.3): 0x2300."""
IGAIN_MAX = 210
"""IGain of 100 % (80 dB), §7.4."""

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
