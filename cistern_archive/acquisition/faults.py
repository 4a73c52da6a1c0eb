"""Faults an emulated head can inject into its byte stream (for the driver's robustness tests)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FaultInjector", "FaultPlan"]

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
