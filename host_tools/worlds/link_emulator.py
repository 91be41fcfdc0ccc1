"""A lossy line between host and controller: bit errors, drops, duplicates, fades.

Seeded, so a run repeats exactly. It acts on whole writes (one or more frames
handed over at once), as a radio modem would on its packets, plus independent bit
errors on every byte. A fade (the report blames sunspots for radio fades) is a
Gilbert-Elliott two-state channel: once in a fade, everything is lost until it ends.
"""
from __future__ import annotations

import random
from dataclasses import dataclass, field


@dataclass
class LineFaults:
    bit_error_rate: float = 0.0      # per bit
    drop_rate: float = 0.0           # per write
    duplicate_rate: float = 0.0      # per write
    fade_start_rate: float = 0.0     # per write, chance a fade begins
    fade_end_rate: float = 0.2       # per write while fading, chance it ends

    def __post_init__(self) -> None:
        for name in ("bit_error_rate", "drop_rate", "duplicate_rate", "fade_start_rate", "fade_end_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"LineFaults.{name} must be a probability in 0..1")


@dataclass
class LossyLine:
    """One direction of a lossy line: `transfer(data) -> what arrives`."""

    faults: LineFaults
    rng: random.Random = field(default_factory=lambda: random.Random(0))
    fading: bool = False
    writes: int = 0
    dropped: int = 0
    duplicated: int = 0
    bits_flipped: int = 0
    faded: int = 0

    def transfer(self, data: bytes) -> bytes:
        if not data:
            return data
        self.writes += 1
        f, rng = self.faults, self.rng
        if self.fading:
            if rng.random() < f.fade_end_rate:
                self.fading = False
        elif rng.random() < f.fade_start_rate:
            self.fading = True
        if self.fading:
            self.faded += 1
            return b""
        if rng.random() < f.drop_rate:
            self.dropped += 1
            return b""
        out = bytearray(data)
        if f.bit_error_rate > 0:
            nbits = len(out) * 8
            # number of flips ~ binomial; draw positions directly
            flips = sum(1 for _ in range(nbits) if rng.random() < f.bit_error_rate) if nbits < 64 else \
                _binomial(rng, nbits, f.bit_error_rate)
            for _ in range(flips):
                bit = rng.randrange(nbits)
                out[bit // 8] ^= 1 << (bit % 8)
            self.bits_flipped += flips
        if rng.random() < f.duplicate_rate:
            self.duplicated += 1
            return bytes(out) * 2
        return bytes(out)


def _binomial(rng: random.Random, n: int, p: float) -> int:
    """Binomial draw by inversion over the geometric gaps between successes."""
    if p <= 0:
        return 0
    import math
    count, position = 0, -1
    log_q = math.log1p(-p) if p < 1 else float("-inf")
    while True:
        if log_q == float("-inf"):
            return n
        position += 1 + int(math.log(1.0 - rng.random()) / log_q)
        if position >= n:
            return count
        count += 1
