"""Counts over a decoded session: frames, errors, round trips, retransmissions and losses per class.

What the figures mean (protocol/reliable.py and docs/protocol.md for the rules they follow):

* **round trip**: a reliable host frame (COMMAND or URGENT) is answered by a controller frame of the
  same class and sequence number; the time from the request's first transmission to the first
  answer. A retransmitted request is counted, not timed again (Karn's rule).
* **retransmissions**: a frame whose class and sequence number were already seen in its
  direction in the same session (a reliable sender going back, or a duplicating line).
* **telemetry lost**: gaps in the telemetry stream's sequence numbers (telemetry is never resent).
* **unanswered**: requests with no answer by the end of the capture.

A new session (a HelloReply that accepts) starts the numbering afresh. Whatever the capture's length, the counts
take bounded memory: round trips are kept as a `Spread` (count, least, most, and quantiles to within 1.1 %), and
the open requests and numbers seen as at most MAX_TRACKED each.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Optional

from protocol.reliable import seq_delta
from protocol.schema import Direction, MsgClass
from host_tools.sessions.decode import ARROW, MAC_BAD, DecodedFrame

RELIABLE_REQUESTS = (MsgClass.COMMAND, MsgClass.URGENT)


class Spread:
    """Samples (seconds, at least 0) summarized in bounded memory: how many, the least and the most exactly, and any
    quantile to within 1.1 %: a histogram of bins BINS_PER_DOUBLING to a doubling, from FLOOR_S (a nanosecond) up,
    so that a day's worth of round trips still takes a few thousand bins."""

    BINS_PER_DOUBLING = 64
    FLOOR_S = 1e-9

    def __init__(self) -> None:
        self.n = 0
        self.least = math.inf
        self.most = -math.inf
        self._bins: Counter = Counter()

    def add(self, value_s: float) -> None:
        self.n += 1
        self.least, self.most = min(self.least, value_s), max(self.most, value_s)
        self._bins[math.floor(math.log2(max(value_s, self.FLOOR_S)) * self.BINS_PER_DOUBLING)] += 1

    def quantile(self, q: float) -> float:
        """The sample of rank min(n - 1, int(q * n)) in sorted order, as the middle of its bin (within the least and
        the most)."""
        rank, seen = min(self.n - 1, int(q * self.n)), 0
        for index in sorted(self._bins):
            seen += self._bins[index]
            if seen > rank:
                middle = 2 ** ((index + 0.5) / self.BINS_PER_DOUBLING)
                return min(self.most, max(self.least, middle))
        return self.most


@dataclass
class SessionStats:
    frames: Counter = field(default_factory=Counter)           # (direction, class name) -> frames
    bytes: Counter = field(default_factory=Counter)            # direction -> bytes
    messages: Counter = field(default_factory=Counter)         # message name -> frames
    errors: Counter = field(default_factory=Counter)           # reason -> frames
    mac_failures: int = 0
    retransmissions: Counter = field(default_factory=Counter)  # (direction, class name) -> frames
    telemetry_lost: int = 0
    sessions: int = 0
    rtt_s: dict[str, Spread] = field(default_factory=lambda: {c.name: Spread() for c in RELIABLE_REQUESTS})
    first_s: Optional[float] = None
    last_s: Optional[float] = None
    _sent: dict[tuple[int, int], Optional[float]] = field(default_factory=dict, repr=False)
    _seen: set[tuple[Direction, int, int]] = field(default_factory=set, repr=False)
    _telemetry_seq: Optional[int] = field(default=None, repr=False)

    MAX_TRACKED = 4096     # open requests and seen numbers kept per session (seq numbers wrap at 65536)

    def add(self, d: DecodedFrame) -> None:
        self.first_s = d.time_s if self.first_s is None else self.first_s
        self.last_s = d.time_s
        self.bytes[d.direction] += d.size
        if d.frame is None:
            self.errors[d.error.split(":", 1)[0]] += 1
            return
        frame = d.frame
        self.frames[(d.direction, d.class_name)] += 1
        self.messages[d.name] += 1
        if d.error:
            self.errors[d.error.split(":", 1)[0]] += 1
        if d.mac == MAC_BAD:
            self.mac_failures += 1
            return
        if d.message is not None and d.message.spec.name == "HelloReply" and d.message.result == 0:
            self._new_session()
            return
        if frame.cls == MsgClass.LINK:
            return
        if frame.cls == MsgClass.TELEMETRY:
            if self._telemetry_seq is not None:
                gap = seq_delta(frame.seq, self._telemetry_seq) - 1
                if 0 < gap < 0x8000:
                    self.telemetry_lost += gap
            self._telemetry_seq = frame.seq
            return
        key = (d.direction, frame.cls, frame.seq)
        if key in self._seen:
            self.retransmissions[(d.direction, d.class_name)] += 1
        elif len(self._seen) < self.MAX_TRACKED:
            self._seen.add(key)
        if frame.cls in RELIABLE_REQUESTS:
            request = (frame.cls, frame.seq)
            if d.direction is Direction.TO_CONTROLLER:
                if request in self._sent:
                    self._sent[request] = None          # retransmitted: no RTT sample from it (Karn)
                elif len(self._sent) < self.MAX_TRACKED:
                    self._sent[request] = d.time_s
            elif request in self._sent:
                sent = self._sent.pop(request)
                if sent is not None:
                    self.rtt_s[MsgClass(frame.cls).name].add(d.time_s - sent)

    def _new_session(self) -> None:
        self.sessions += 1
        self._sent.clear()
        self._seen.clear()
        self._telemetry_seq = None

    @property
    def unanswered(self) -> int:
        return len(self._sent)

    def report(self) -> str:
        span = 0.0 if self.first_s is None else self.last_s - self.first_s
        lines = [f"span {span:.3f} s, {self.sessions} session(s) opened",
                 "frames:"]
        for (direction, cls), n in sorted(self.frames.items(), key=lambda kv: (kv[0][0].name, kv[0][1])):
            again = self.retransmissions.get((direction, cls), 0)
            lines.append(f"  {ARROW[direction]} {cls:<10} {n:7d}" + (f"  ({again} seen again)" if again else ""))
        for direction in (Direction.TO_CONTROLLER, Direction.TO_HOST):
            lines.append(f"  {ARROW[direction]} bytes      {self.bytes.get(direction, 0):7d}")
        lines.append(f"errors: {sum(self.errors.values())}"
                     + "".join(f"\n  {reason:<20} {n:7d}" for reason, n in sorted(self.errors.items())))
        lines.append(f"MAC failures: {self.mac_failures}")
        lines.append(f"telemetry frames lost (sequence gaps): {self.telemetry_lost}")
        lines.append(f"requests unanswered at the end: {self.unanswered}")
        for cls, spread in self.rtt_s.items():
            if spread.n:
                lines.append(f"round trip {cls}: n={spread.n} min {spread.least * 1e3:.2f} "
                             f"p50 {spread.quantile(0.5) * 1e3:.2f} p99 {spread.quantile(0.99) * 1e3:.2f} "
                             f"max {spread.most * 1e3:.2f} ms")
        lines.append("messages: " + ", ".join(f"{name} {n}" for name, n in sorted(self.messages.items())))
        return "\n".join(lines)

