"""A link's impairments, seeded and named: what `aspod proxy` does to a live session and the lock-step world to a
simulated one, frame by frame, with the same draws for the same seed.

The report's two telemetry links set the vocabulary: the radio modem's signal "will fade occasionally
(throughout the month) due to sunspots", and the photonic link needs "a direct line of sight", which
anything in the way blocks. So a link here has

* **pacing**: bytes leave at the line's baud rate, 10 bits a byte (8N1);
* **latency** and **jitter**: each frame is delayed by `latency_ms` plus a uniform draw in `[0,
  jitter_ms]`, never overtaking the frame before it (a serial link keeps order);
* **bit errors** (`ber`, per bit, on every byte of the frame and its delimiters), **drops** and
  **duplicates** (per frame);
* **outages**, when everything is lost: **fades** and **blockages**, either at random (starts a
  Poisson process with mean gap `fade_every_s`, durations exponential with mean `fade_s`; the
  same for `block_every_s`, `block_s`) or at given times (`fade=START+DURATION`, seconds since
  the link started). Outages are the link's, not a direction's: a fade takes both ways at once.

The unit is the frame (the bytes between two 0x00 delimiters), as on a packet radio: a frame is
delivered, damaged, doubled or lost whole, decided when its closing delimiter arrives. Each
direction draws from its own generator, seeded by the seed and the direction's name, in frame
order; the outages come from a third, in time. The same seed and the same frames at the same
times therefore meet the same fate in the proxy and in the lock-step world.

Presets (`Impairment.parse("radio")`; the report gives no figures, these are stated assumptions):
`clean`; `radio`: 20 ms latency, 10 ms jitter, BER 1e-5, a fade every 10 min on average, 30 s
long; `optical`: 1 ms latency, BER 1e-7, a blockage every 5 min on average, 5 s long.
"""
from __future__ import annotations

import bisect
import math
import random
from dataclasses import dataclass, field, fields, replace
from typing import Optional

from host_tools.sessions.segments import SegmentCutter

PRESETS: dict[str, dict] = {
    "clean": {},
    "radio": {"latency_ms": 20.0, "jitter_ms": 10.0, "ber": 1e-5, "fade_every_s": 600.0, "fade_s": 30.0},
    "optical": {"latency_ms": 1.0, "ber": 1e-7, "block_every_s": 300.0, "block_s": 5.0},
}
FADE, BLOCKAGE = "fade", "blockage"
KEPT_PAST_S = 120.0            # outages that ended this long before the latest question are forgotten
MIN_OUTAGE_EVERY_S = 0.1       # random outages' least mean gap: each is kept (KEPT_PAST_S) and looked through


@dataclass(frozen=True)
class Impairment:
    """What a link does to frames; `parse` reads it from a command line's words."""

    name: str = "clean"
    seed: int = 0
    baud: int = 0                 # 0: no pacing
    latency_ms: float = 0.0
    jitter_ms: float = 0.0
    ber: float = 0.0              # per bit
    drop: float = 0.0             # per frame
    dup: float = 0.0              # per frame
    fade_every_s: float = 0.0     # mean gap between random fades (0: none)
    fade_s: float = 0.0           # their mean duration
    block_every_s: float = 0.0
    block_s: float = 0.0
    fades: tuple[tuple[float, float], ...] = ()      # (start s, duration s) given
    blocks: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        for name in ("ber", "drop", "dup"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name}={getattr(self, name)}: a probability, within 0..1")
        for name in ("latency_ms", "jitter_ms", "fade_every_s", "fade_s", "block_every_s", "block_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}={value}: must be finite and >= 0")
        if self.baud < 0 or self.baud > 10_000_000:
            raise ValueError(f"baud={self.baud}: within 0 (no pacing)..10000000")
        for kind, every, mean in (("fade", self.fade_every_s, self.fade_s), ("block", self.block_every_s,
                                                                              self.block_s)):
            if every and not mean:
                raise ValueError(f"{kind}_every_s={every} needs a mean duration, {kind}_s")
            if 0 < every < MIN_OUTAGE_EVERY_S:
                raise ValueError(f"{kind}_every_s={every}: at least {MIN_OUTAGE_EVERY_S:g} s between {kind}s on "
                                 "average (or 0: none)")
        for start, duration in self.fades + self.blocks:
            if not (math.isfinite(start) and math.isfinite(duration) and start >= 0 and duration > 0):
                raise ValueError(f"an outage {start}+{duration}: start >= 0 and duration > 0, in seconds")

    @classmethod
    def parse(cls, text: str) -> "Impairment":
        """`PRESET[,key=value...]` or `key=value,...`: `radio`, `radio,seed=4,fade=60+30`, `ber=1e-5,drop=0.01`.

        Keys: seed, baud, latency_ms, jitter_ms, ber, drop, dup, fade_every_s, fade_s, block_every_s, block_s,
        fade=START+DURATION and block=START+DURATION (repeatable). ValueError names what is wrong."""
        words = [w.strip() for w in text.split(",") if w.strip()]
        if not words:
            raise ValueError("an empty impairment: give a preset (clean, radio, optical) or key=value pairs")
        values: dict = {}
        name = "custom"
        if "=" not in words[0]:
            name = words.pop(0)
            if name not in PRESETS:
                raise ValueError(f"no impairment preset {name!r}; there are {', '.join(PRESETS)}")
            values.update(PRESETS[name])
        types = {f.name: f.type for f in fields(cls)}
        fades, blocks = [], []
        given: dict[str, str] = {}
        for word in words:
            key, sep, value = word.partition("=")
            key = key.strip()
            if key in given and key not in ("fade", "block"):
                raise ValueError(f"{key} given twice ({given[key]}, {word}): give it once (a preset's value is "
                                 "overridden by giving the key after it)")
            given[key] = word
            try:
                if not sep:
                    raise ValueError
                if key in ("fade", "block"):
                    start, plus, duration = value.partition("+")
                    if not plus:
                        raise ValueError
                    (fades if key == "fade" else blocks).append((float(start), float(duration)))
                elif key in ("seed", "baud"):
                    values[key] = int(value)
                elif key in types and key not in ("name", "fades", "blocks"):
                    values[key] = float(value)
                else:
                    raise KeyError(key)
            except KeyError:
                raise ValueError(f"{word}: no such impairment; keys: seed, baud, latency_ms, jitter_ms, ber, drop, "
                                 "dup, fade_every_s, fade_s, block_every_s, block_s, fade=START+S, block=START+S") \
                    from None
            except ValueError:
                form = "START+DURATION, in seconds" if key in ("fade", "block") else "NUMBER"
                raise ValueError(f"{word}: write {key}={form}") from None
        return cls(name=name, fades=tuple(fades), blocks=tuple(blocks), **values)

    def with_seed(self, seed: int) -> "Impairment":
        return replace(self, seed=seed)

    def describe(self) -> str:
        parts = [self.name, f"seed {self.seed}"]
        if self.baud:
            parts.append(f"{self.baud} baud")
        if self.latency_ms or self.jitter_ms:
            parts.append(f"latency {self.latency_ms:g}+{self.jitter_ms:g} ms")
        for key in ("ber", "drop", "dup"):
            if getattr(self, key):
                parts.append(f"{key} {getattr(self, key):g}")
        if self.fade_every_s:
            parts.append(f"fades every {self.fade_every_s:g} s for {self.fade_s:g} s")
        if self.block_every_s:
            parts.append(f"blockages every {self.block_every_s:g} s for {self.block_s:g} s")
        parts += [f"fade {s:g}+{d:g} s" for s, d in self.fades] + [f"blockage {s:g}+{d:g} s" for s, d in self.blocks]
        return ", ".join(parts)


class Outages:
    """When the link is out, and why: the given windows and the random ones, drawn lazily in time."""

    def __init__(self, spec: Impairment) -> None:
        self._spec = spec
        self._rng = random.Random(f"{spec.seed}/outages")
        self._windows: list[tuple[float, float, str]] = sorted(
            [(s, s + d, FADE) for s, d in spec.fades] + [(s, s + d, BLOCKAGE) for s, d in spec.blocks])
        self._drawn_to = {FADE: 0.0, BLOCKAGE: 0.0}

    def _draw_until(self, t: float) -> None:
        for kind, every, mean in ((FADE, self._spec.fade_every_s, self._spec.fade_s),
                                  (BLOCKAGE, self._spec.block_every_s, self._spec.block_s)):
            while every and self._drawn_to[kind] <= t:
                start = self._drawn_to[kind] + self._rng.expovariate(1.0 / every)
                end = start + self._rng.expovariate(1.0 / mean)
                bisect.insort(self._windows, (start, end, kind))
                self._drawn_to[kind] = end

    def at(self, t: float) -> Optional[str]:
        """FADE or BLOCKAGE if the link is out at `t` (seconds since it started), else None."""
        self._draw_until(t)
        while self._windows and self._windows[0][1] < t - KEPT_PAST_S:
            self._windows.pop(0)
        for start, end, kind in self._windows:
            if start > t:
                break
            if t < end:
                return kind
        return None

    def windows(self, until_s: float) -> list[tuple[float, float, str]]:
        """The outages that start before `until_s` (for a report or a test)."""
        self._draw_until(until_s)
        return [w for w in self._windows if w[0] < until_s]


@dataclass
class Fate:
    """What became of one frame: its bytes as sent, what arrives (b"" if lost), why."""
    sent: bytes
    delivered: bytes
    lost: str = ""                 # "", "drop", FADE or BLOCKAGE
    bits_flipped: int = 0
    duplicated: bool = False
    due_s: float = 0.0

    def describe(self) -> str:
        if self.lost:
            return f"lost ({self.lost})"
        notes = [f"{self.bits_flipped} bit(s) flipped"] if self.bits_flipped else []
        if self.duplicated:
            notes.append("duplicated")
        return ", ".join(notes)


@dataclass
class LineStats:
    frames: int = 0
    dropped: int = 0
    faded: int = 0
    blocked: int = 0
    duplicated: int = 0
    bits_flipped: int = 0
    bytes_in: int = 0
    bytes_out: int = 0


class ImpairedLine:
    """One direction: `send(data, now)` takes bytes as they are written, `receive(now)` gives what has arrived.

    Bytes are cut into frames as they come (`SegmentCutter`); an unfinished frame waits (at most one frame's
    worth, like a receiver; a longer run goes on cut to that length when its delimiter comes). Times are seconds since the link
    started, on whatever clock the caller keeps (the wall clock in the proxy, the simulated one in lock-step).
    """

    def __init__(self, spec: Impairment, direction: str, outages: Outages) -> None:
        self.spec = spec
        self.outages = outages
        self._rng = random.Random(f"{spec.seed}/{direction}")
        self._cutter = SegmentCutter()
        self._queue: list[tuple[float, bytes]] = []        # (due, bytes), due non-decreasing
        self._last_due = 0.0
        self.held_bytes = 0                                 # the bytes in `_queue`
        self.stats = LineStats()

    def send(self, data: bytes, now: float) -> list[Fate]:
        """Take written bytes; the fates of the frames they complete."""
        self.stats.bytes_in += len(data)
        return [self._decide(b"\x00" + segment + b"\x00", now) for segment, _ in self._cutter.feed(data)]

    def restart(self) -> int:
        """Forget the unfinished frame and the frames not yet delivered: their writer is gone (another client took
        the line); the next one's bytes neither finish its half frame nor wait behind its backlog (as the paced
        UART drops what it held of a client that left). Returns the bytes forgotten."""
        self._cutter.reset()
        forgotten, self.held_bytes = self.held_bytes, 0
        self._queue.clear()
        return forgotten

    def _decide(self, frame: bytes, now: float) -> Fate:
        spec, rng, stats = self.spec, self._rng, self.stats
        stats.frames += 1
        # the draws depend on the frame's length and place in the stream only, never on an outage: a fade does not
        # shift the fates of the frames after it
        drop, dup, jitter = rng.random(), rng.random(), rng.random()
        flips = _binomial(rng, len(frame) * 8, spec.ber)
        positions = [rng.randrange(len(frame) * 8) for _ in range(flips)]
        fate = Fate(frame, b"")
        outage = self.outages.at(now)
        if outage is not None:
            fate.lost = outage
            if outage == FADE:
                stats.faded += 1
            else:
                stats.blocked += 1
            return fate
        if drop < spec.drop:
            fate.lost = "drop"
            stats.dropped += 1
            return fate
        out = bytearray(frame)
        for bit in positions:
            out[bit // 8] ^= 1 << (bit % 8)
        fate.bits_flipped = flips
        stats.bits_flipped += flips
        fate.duplicated = dup < spec.dup
        stats.duplicated += fate.duplicated
        fate.delivered = bytes(out) * (2 if fate.duplicated else 1)
        due = max(self._last_due, now + (spec.latency_ms + jitter * spec.jitter_ms) / 1e3)
        if spec.baud:
            due += len(fate.delivered) * 10 / spec.baud
        self._last_due = fate.due_s = due
        self._queue.append((due, fate.delivered))
        self.held_bytes += len(fate.delivered)
        return fate

    def receive(self, now: float) -> bytes:
        """The bytes due by `now`."""
        n = 0
        while n < len(self._queue) and self._queue[n][0] <= now:
            n += 1
        if not n:
            return b""
        out = b"".join(data for _, data in self._queue[:n])
        del self._queue[:n]
        self.held_bytes -= len(out)
        self.stats.bytes_out += len(out)
        return out

    def next_due_s(self) -> float:
        return self._queue[0][0] if self._queue else math.inf

    @property
    def in_flight(self) -> int:
        return len(self._queue)


@dataclass
class ImpairedLink:
    """Both directions of one link, sharing its outages."""
    spec: Impairment
    outages: Outages = field(init=False)
    to_controller: ImpairedLine = field(init=False)
    to_host: ImpairedLine = field(init=False)

    def __post_init__(self) -> None:
        self.outages = Outages(self.spec)
        self.to_controller = ImpairedLine(self.spec, "to_controller", self.outages)
        self.to_host = ImpairedLine(self.spec, "to_host", self.outages)

    def next_due_s(self) -> float:
        return min(self.to_controller.next_due_s(), self.to_host.next_due_s())


def _binomial(rng: random.Random, n: int, p: float) -> int:
    """A binomial draw (n trials of probability p) by the geometric gaps between successes: cheap for small p."""
    if p <= 0.0:
        return 0
    if p >= 1.0:
        return n
    log_q = math.log1p(-p)
    count, position = 0, -1
    while True:
        position += 1 + int(math.log(1.0 - rng.random()) / log_q)
        if position >= n:
            return count
        count += 1
