"""Reliable delivery, sans-IO: a go-back-N sender and an exactly-once receiver.

The host's commands and the controller's events both use them. The sender keeps
up to `window` frames in flight, retransmits on an RFC 6298 timer (Karn's rule: no
RTT sample from a retransmitted frame; the timeout doubles on each expiry), and
after `retry_limit` sends of one frame gives up: every frame not yet answered fails
and the channel is suspended, so nothing is ever lost silently. The receiver
accepts only the next sequence number; an earlier one is a duplicate (answered from
the reply cache, never executed again) and a later one is a gap (NAKed once, so the
sender goes back). Sequence numbers are 16-bit, compared in serial arithmetic.
"""
from __future__ import annotations

import enum
import math
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import Any, Optional

SEQ_MOD = 1 << 16
REPLY_CACHE_SIZE = 64       # a receiver answers a duplicate of any of its last this many sequence numbers
NOTHING_RECEIVED_ACK = SEQ_MOD - 1   # the ack (last in-order sequence number) before anything arrived: 0 - 1


def seq_delta(a: int, b: int) -> int:
    """Signed distance from b to a in 16-bit serial arithmetic (RFC 1982)."""
    d = (a - b) & 0xFFFF
    return d - SEQ_MOD if d >= 0x8000 else d


class RttEstimator:
    """RFC 6298 smoothed RTT and retransmission timeout, with configurable bounds."""

    def __init__(self, initial_rto_s: float = 1.0, min_rto_s: float = 0.05, max_rto_s: float = 4.0) -> None:
        self.srtt_s: Optional[float] = None
        self.rttvar_s = 0.0
        self.min_rto_s = min_rto_s
        self.max_rto_s = max_rto_s
        self.rto_s = initial_rto_s

    def sample(self, rtt_s: float) -> None:
        if self.srtt_s is None:
            self.srtt_s, self.rttvar_s = rtt_s, rtt_s / 2
        else:
            self.rttvar_s = 0.75 * self.rttvar_s + 0.25 * abs(self.srtt_s - rtt_s)
            self.srtt_s = 0.875 * self.srtt_s + 0.125 * rtt_s
        self.rto_s = min(self.max_rto_s, max(self.min_rto_s, self.srtt_s + 4 * self.rttvar_s))

    def back_off(self) -> None:
        self.rto_s = min(self.max_rto_s, self.rto_s * 2)


class Outcome(enum.Enum):
    PENDING = "pending"
    SUCCEEDED = "succeeded"   # answered OK
    REJECTED = "rejected"     # answered with a reason code
    FAILED = "failed"         # never answered: outcome unknown (link suspended, session reset)


@dataclass(eq=False)
class Pending:
    """One reliable frame until it is answered or given up."""

    msg_id: int
    payload: bytes
    context: Any = None
    seq: int = -1
    tries: int = 0
    first_sent_s: Optional[float] = None
    last_sent_s: Optional[float] = None
    due_s: Optional[float] = None


@dataclass
class ReliableSender:
    """Sends in order with a window; answers arrive through `answered` or `acked_through`."""

    window: int = 8                     # must not exceed the receiver's reply cache
    retry_limit: int = 8
    rtt: RttEstimator = field(default_factory=RttEstimator)
    in_order: bool = True               # False for the urgent class: no go-back on a gap
    next_seq: int = 0
    retransmits: int = 0
    suspended: bool = False
    _inflight: "OrderedDict[int, Pending]" = field(default_factory=OrderedDict)
    _waiting: deque = field(default_factory=deque)

    def submit(self, msg_id: int, payload: bytes, context: Any = None) -> Pending:
        item = Pending(msg_id, payload, context)
        self._waiting.append(item)
        return item

    @property
    def outstanding(self) -> int:
        return len(self._inflight) + len(self._waiting)

    @property
    def waiting(self) -> int:
        """Submitted, not sent yet (the window is full): no sequence number yet."""
        return len(self._waiting)

    @property
    def idle(self) -> bool:
        """Nothing to send, nothing in flight, not suspended: `due` has nothing, whenever it is asked."""
        return not (self.suspended or self._inflight or self._waiting)

    def in_flight_seqs(self) -> list[int]:
        """The sequence numbers sent and not yet answered, oldest first."""
        return list(self._inflight)

    def next_due_s(self) -> float:
        """When `due` may next return something: -inf if frames wait for the window (at once, or as
        soon as an answer opens it), the earliest retransmission timer, inf if nothing is in flight."""
        if self.suspended:
            return math.inf
        if self._waiting:
            return -math.inf
        if not self._inflight:       # most calls: both ends ask at every run of their link's task
            return math.inf
        return min([p.due_s for p in self._inflight.values() if p.due_s is not None], default=math.inf)

    def due(self, now: float, resend: bool = True) -> list[Pending]:
        """Frames to send now: new ones the window admits and (with `resend`) those whose timer expired.

        Returns [] once suspended; check `take_failed()` after calling.
        """
        if self.suspended or not (self._inflight or self._waiting):
            return []          # nothing in flight, nothing waiting (most calls: the link polls every 1 ms)
        out: list[Pending] = []
        expired = [p for p in self._inflight.values() if p.due_s is not None and now >= p.due_s] if resend else []
        if expired:
            if any(p.tries >= self.retry_limit for p in expired):
                self.suspended = True
                return []
            self.rtt.back_off()
            # go-back-N: from the oldest expired frame on, everything goes again
            first = expired[0].seq if self.in_order else None
            for p in self._inflight.values():
                if p in expired or (first is not None and seq_delta(p.seq, first) >= 0):
                    out.append(p)
        # the window bounds the span of sequence numbers in flight, not their count: a
        # command whose reply was lost stays in flight while later ones complete, and the
        # receiver's reply cache must still hold its answer when it is sent again
        while self._waiting and (not self._inflight
                                 or seq_delta(self.next_seq, next(iter(self._inflight))) < self.window):
            item = self._waiting.popleft()
            item.seq = self.next_seq
            self.next_seq = (self.next_seq + 1) % SEQ_MOD
            self._inflight[item.seq] = item
            out.append(item)
        for p in out:
            if p.tries:
                self.retransmits += 1
            p.tries += 1
            p.last_sent_s = now
            if p.first_sent_s is None:
                p.first_sent_s = now
            p.due_s = now + self.rtt.rto_s
        return out

    def answered(self, seq: int, now: float) -> Optional[Pending]:
        """The frame `seq` was answered; returns it (None if it was not in flight)."""
        item = self._inflight.pop(seq, None)
        if item is not None and item.tries == 1 and item.last_sent_s is not None:
            self.rtt.sample(now - item.last_sent_s)
        return item

    def acked_through(self, seq: int, now: float) -> list[Pending]:
        """Cumulative ack: everything in flight up to and including `seq` was received."""
        done = [p for s, p in self._inflight.items() if seq_delta(seq, s) >= 0]
        for p in done:
            self.answered(p.seq, now)
        return done

    def go_back(self, expected_seq: int, now: float) -> None:
        """A NAK says the receiver expects `expected_seq`: resend from there at once."""
        for s, p in self._inflight.items():
            if seq_delta(s, expected_seq) >= 0 and p.due_s is not None:
                p.due_s = min(p.due_s, now)

    def resume(self) -> None:
        """After a suspension: send everything unanswered again, from the same sequence numbers.

        The receiver still expects the first of them, so nothing is skipped or mistaken
        for a duplicate; each gets a fresh retry budget.
        """
        items = list(self._inflight.values()) + list(self._waiting)
        if self._inflight:
            self.next_seq = next(iter(self._inflight))
        for item in items:
            item.seq, item.tries, item.due_s = -1, 0, None
        self._inflight.clear()
        self._waiting = deque(items)
        self.suspended = False

    def take_failed(self) -> list[Pending]:
        """When suspended: everything not answered, in order; the sender is emptied."""
        failed = list(self._inflight.values()) + list(self._waiting)
        self._inflight.clear()
        self._waiting.clear()
        return failed


class Verdict(enum.Enum):
    NEW = "new"
    DUPLICATE = "duplicate"
    GAP = "gap"


@dataclass
class ReliableReceiver:
    """Accepts each sequence number once, in order; caches the replies for duplicates."""

    cache_size: int = REPLY_CACHE_SIZE
    in_order: bool = True
    expected: int = 0
    _replies: "OrderedDict[int, Any]" = field(default_factory=OrderedDict)
    _seen: "OrderedDict[int, None]" = field(default_factory=OrderedDict)  # for the unordered class
    _nak_sent_for: Optional[int] = None

    def classify(self, seq: int) -> Verdict:
        if not self.in_order:
            return Verdict.DUPLICATE if seq in self._seen else Verdict.NEW
        d = seq_delta(seq, self.expected)
        if d == 0:
            return Verdict.NEW
        return Verdict.GAP if d > 0 else Verdict.DUPLICATE

    def accept(self, seq: int, reply: Any) -> None:
        """Record that `seq` (classified NEW) was executed and answered with `reply`."""
        if self.in_order:
            self.expected = (seq + 1) % SEQ_MOD
            self._nak_sent_for = None
        else:
            self._seen[seq] = None
            while len(self._seen) > self.cache_size:
                self._seen.popitem(last=False)
        self._replies[seq] = reply
        while len(self._replies) > self.cache_size:
            self._replies.popitem(last=False)

    def cached_reply(self, seq: int) -> Any:
        return self._replies.get(seq)

    def should_nak_gap(self) -> bool:
        """NAK a gap once per expected value, so a burst of out-of-order frames costs one NAK."""
        if self._nak_sent_for == self.expected:
            return False
        self._nak_sent_for = self.expected
        return True

    @property
    def last_in_order(self) -> int:
        """The ack to send: the last sequence number accepted in order (NOTHING_RECEIVED_ACK before any)."""
        return (self.expected - 1) % SEQ_MOD
