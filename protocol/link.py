"""The link endpoint both ends share, sans-IO: bytes and `now` in, frames out.

`LinkEndpoint.feed(data, now)` takes whatever arrived on the wire; `poll(now)` runs
the timers; `take_frame(now)` hands the transport the next frame to send (signed at
that moment, so counters increase in wire order whatever the queue priorities).
`ControllerLink` (protocol/controller_link.py) and `HostLink` (protocol/host_link.py)
add what each role does with the frames that check out.

A received frame goes through: frame finder -> COBS/CRC/header (framing.py) ->
key selection -> MAC -> counter (replay) -> direction/class -> the role's handler.
Nothing before the MAC and counter checks changes any state except the error
counters. Bad frames are answered with a NAK and a reason where that is safe:
never for CRC or framing errors (nothing in them can be trusted) and never for
replays (a duplicating link makes them in the normal course), and at most
`nak_rate_per_s` a second for the rest, so garbage cannot make the controller flood
the link. A NAK echoes the start of the refused frame's MAC tag (`refused_tag`): tags
differ in every session, so a host can tell a NAK of a frame it sent from a recorded one.
"""
from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass, field, fields
from typing import Callable, Optional

from protocol import auth
from protocol.errors import ParseError
from protocol.framing import COUNTER_MAX, Frame, FrameReceiver, encode_signed
from protocol.messages import SCHEMA
from protocol.reliable import NOTHING_RECEIVED_ACK, REPLY_CACHE_SIZE
from protocol.reasons import Reason
from protocol.schema import Direction, Message, MsgClass, Schema

HELLO_ID = SCHEMA["Hello"].id
HELLO_REPLY_ID = SCHEMA["HelloReply"].id
HELLO_COOKIE_ID = SCHEMA["HelloCookie"].id
NAK_ID = SCHEMA["Nak"].id
HANDSHAKE_IDS = frozenset({HELLO_ID, HELLO_REPLY_ID, HELLO_COOKIE_ID})
NAK_TAG_BYTES = SCHEMA["Nak"].fields[-1].text_size    # how much of the refused frame's tag a NAK echoes

# Transmit priorities: lower goes first.
PRIO_URGENT, PRIO_RELIABLE, PRIO_HEARTBEAT, PRIO_TELEMETRY = range(4)


@dataclass
class LinkConfig:
    """Timing and sizes of one end of the link; checked when built."""

    heartbeat_s: float = 1.0
    link_timeout_s: float = 3.0          # controller: safe state after this long with no valid frame
    window: int = 8                      # reliable frames in flight
    retry_limit: int = 8                 # sends of one reliable frame before giving up
    initial_rto_s: float = 1.0
    min_rto_s: float = 0.05
    max_rto_s: float = 2.0
    hello_tries: int = 5
    nak_rate_per_s: float = 10.0         # answers to unauthenticated or malformed frames
    hello_rate_per_s: float = 4.0        # controller: HelloReplies a second, to all hosts together
    telemetry_backlog: int = 2           # telemetry frames queued before the oldest is dropped

    def __post_init__(self) -> None:
        checks = [
            (0.01 <= self.heartbeat_s <= 60, "heartbeat_s must be within 0.01..60 s"),
            (0.05 <= self.link_timeout_s <= 3600, "link_timeout_s must be within 0.05..3600 s"),
            (self.link_timeout_s > self.heartbeat_s, "link_timeout_s must exceed heartbeat_s"),
            (1 <= self.window <= REPLY_CACHE_SIZE, f"window must be within 1..{REPLY_CACHE_SIZE} (the reply cache)"),
            (1 <= self.retry_limit <= 100, "retry_limit must be within 1..100"),
            (0 < self.min_rto_s <= self.initial_rto_s <= self.max_rto_s, "need 0 < min_rto <= initial_rto <= max_rto"),
            (1 <= self.hello_tries <= 100, "hello_tries must be within 1..100"),
            (self.nak_rate_per_s >= 0, "nak_rate_per_s must be >= 0"),
            (0.1 <= self.hello_rate_per_s <= 1000, "hello_rate_per_s must be within 0.1..1000"),
            (1 <= self.telemetry_backlog <= 64, "telemetry_backlog must be within 1..64"),
        ]
        for ok, why in checks:
            if not ok:
                raise ValueError(f"LinkConfig: {why}")


class TokenBucket:
    """At most `rate_per_s` a second on average and `burst` at once, on the `now` it is given."""

    def __init__(self, rate_per_s: float, burst: float) -> None:
        self.rate_per_s = rate_per_s
        self.burst = burst
        self.tokens = burst
        self._refilled_s: Optional[float] = None

    def _refill(self, now: float) -> None:
        if self._refilled_s is not None:
            self.tokens = min(self.burst, self.tokens + (now - self._refilled_s) * self.rate_per_s)
        self._refilled_s = now

    def take(self, now: float) -> bool:
        """Spend a token if there is one."""
        self._refill(now)
        if self.tokens < 1:
            return False
        self.tokens -= 1
        return True

    def ready_s(self) -> float:
        """When a token will be there (-inf: now)."""
        if self.tokens >= 1 or self._refilled_s is None:
            return -math.inf
        return self._refilled_s + (1 - self.tokens) / self.rate_per_s if self.rate_per_s > 0 else math.inf


@dataclass
class LinkStats:
    """What one end counts; a subset travels in every Heartbeat."""

    frames_rx: int = 0
    frames_tx: int = 0
    bytes_rx: int = 0
    bytes_tx: int = 0
    crc_errors: int = 0        # BAD_CRC and BAD_FRAME, oversize segments included
    auth_errors: int = 0       # UNAUTHENTICATED, BAD_MAC, REPLAY
    rejected: int = 0          # authenticated but refused with a reason
    naks_tx: int = 0
    naks_rx: int = 0
    retransmits: int = 0
    srtt_us: int = 0
    replays: int = 0
    event_resumes: int = 0      # times the event sender hit its retry limit and started over
    stale_duplicates: int = 0   # a duplicate older than the reply cache (a sender outside its window)
    telemetry_dropped: int = 0  # queued telemetry dropped because the wire was busy
    telemetry_lost: int = 0     # host: gaps in the telemetry sequence
    hellos_dropped: int = 0     # controller: Hellos not answered (answered < 0.5 s ago, or others deserved it more)
    reasons: dict = field(default_factory=dict)  # Reason -> count of every refusal

    def count(self, reason: Reason) -> None:
        self.reasons[reason] = self.reasons.get(reason, 0) + 1

    def heartbeat_fields(self) -> dict:
        return {name: getattr(self, name) & 0xFFFFFFFF for name in _HEARTBEAT_STATS}


_HEARTBEAT_STATS = tuple(f.name for f in fields(LinkStats) if f.name in {f.name for f in SCHEMA["Heartbeat"].fields})


class LinkState(enum.Enum):
    NO_SESSION = "no session"
    CONNECTING = "connecting"
    UP = "up"
    REFUSED = "refused"        # the controller refused the handshake (schema or version)
    SUSPENDED = "suspended"    # host: retry limit reached; reconnect to go on
    CLOSING = "closing"        # a Close was sent (host) or executed (controller): the session's last words
    CLOSED = "closed"          # host: the controller answered the Close and every event of the session came


@dataclass
class Session:
    keys: auth.DirectionKeys
    host_nonce: bytes
    controller_nonce: bytes
    tx_counter: int = 0
    rx_counter: int = -1


@dataclass
class _Outgoing:
    cls: int
    seq: int
    msg_id: int
    payload: bytes
    handshake: bool = False


class LinkEndpoint:
    """What both ends share: keys, counters, the transmit queues and the receive path."""

    is_controller = False

    def __init__(self, psk: bytes, config: Optional[LinkConfig] = None, schema: Schema = SCHEMA,
                 nonce_source: Callable[[], bytes] = auth.new_nonce) -> None:
        if len(psk) < auth.MIN_KEY_BYTES:
            raise ValueError(f"pre-shared key must be at least {auth.MIN_KEY_BYTES} bytes")
        self.config = config or LinkConfig()
        self.schema = schema
        self.stats = LinkStats()
        self.peer_stats: Optional[Message] = None       # the peer's last Heartbeat
        self._psk = psk
        self._nonce = nonce_source
        self._handshake = auth.handshake_keys(psk, self.is_controller)
        self._handshake_tx_counter = 0
        self.session: Optional[Session] = None
        self.state = LinkState.NO_SESSION
        self._rx = FrameReceiver()
        self._receivable = schema.receivable(Direction.TO_CONTROLLER if self.is_controller else Direction.TO_HOST)
        self._queues: list[deque[_Outgoing]] = [deque() for _ in range(4)]
        self._telemetry_seq = 0
        self._next_heartbeat_s: Optional[float] = None
        self.heartbeat_s = self.config.heartbeat_s
        self._naks = TokenBucket(self.config.nak_rate_per_s, self.config.nak_rate_per_s)
        self.last_valid_rx_s: Optional[float] = None
        self.started_s: Optional[float] = None
        # Called when the link has work for its transport that no timer announces: a frame queued,
        # an event or a connection to start. A transport that sleeps until `next_timer_s` wakes on it.
        self.on_work: Callable[[], None] = lambda: None

    # ---- receive path ----
    def feed(self, data: bytes, now: float) -> None:
        """Process bytes from the wire. Never raises for any content of `data`."""
        if self.started_s is None:
            self.started_s = now
        self.stats.bytes_rx += len(data)
        overflows = self._rx.overflows
        for item in self._rx.feed(data):
            if isinstance(item, ParseError):
                self._frame_error(item, now)
            else:
                self._receive(item, now)
        self.stats.crc_errors += self._rx.overflows - overflows

    def _frame_error(self, err: ParseError, now: float) -> None:
        self.stats.count(err.reason)
        if err.reason in (Reason.BAD_CRC, Reason.BAD_FRAME):
            self.stats.crc_errors += 1
        else:
            # CRC was right, so the header can be believed enough to say why
            self.stats.rejected += 1
            self._nak_if_allowed(err.reason, None, now)

    def _receive(self, frame: Frame, now: float) -> None:
        if frame.counter is None:
            self._auth_error(Reason.UNAUTHENTICATED, frame, now)
            return
        if frame.msg_id in HANDSHAKE_IDS:
            if not frame.verify(self._handshake.rx):
                self._auth_error(Reason.BAD_MAC, frame, now)
                return
            self._accepted(frame, now, alive=False)   # no counter check: a replay must not feed the watchdog
            self._handle_handshake(frame, now)
            return
        session = self._session_for(frame)
        if session is None:
            if frame.msg_id == NAK_ID and self._verifies_handshake_nak(frame):
                self._accepted(frame, now, alive=False)
                self._handle_handshake_nak(frame, now)
                return
            self._auth_error(Reason.NO_SESSION if self.session is None else Reason.BAD_MAC, frame, now)
            return
        if frame.counter <= session.rx_counter:
            self.stats.auth_errors += 1
            self.stats.replays += 1
            self.stats.count(Reason.REPLAY)
            return
        session.rx_counter = frame.counter
        self._accepted(frame, now)
        self._peer_acked(frame.ack, now)     # the ack of every session frame that checks out, refused or not
        spec = self._receivable.get((frame.msg_id, frame.cls))
        if spec is None:
            known = frame.msg_id in self.schema.by_id
            self._refuse(frame, Reason.WRONG_DIRECTION if known else Reason.UNKNOWN_MESSAGE, now)
            return
        self._handle(frame, spec, now)

    def _accepted(self, frame: Frame, now: float, alive: bool = True) -> None:
        """Count a frame that checked out; `alive`: it also proves the peer is there (the watchdog)."""
        self.stats.frames_rx += 1
        if alive:
            self.last_valid_rx_s = now

    def _session_for(self, frame: Frame) -> Optional[Session]:
        """The session whose key verifies `frame` (the controller also tries pending ones)."""
        if self.session is not None and frame.verify(self.session.keys.rx):
            return self.session
        return None

    def _auth_error(self, reason: Reason, frame: Frame, now: float) -> None:
        self.stats.auth_errors += 1
        self.stats.count(reason)
        if frame.msg_id != NAK_ID:   # never answer a NAK with a NAK: two ends would ping-pong
            self._nak_if_allowed(reason, frame, now)

    def _refuse(self, frame: Frame, reason: Reason, now: float, expected: int = 0) -> None:
        """An authenticated frame refused: always answered."""
        self.stats.rejected += 1
        self.stats.count(reason)
        self._send_nak(reason, frame, expected)

    def _nak_if_allowed(self, reason: Reason, frame: Optional[Frame], now: float) -> None:
        if self._naks.take(now):
            self._send_nak(reason, frame, 0)

    def _send_nak(self, reason: Reason, frame: Optional[Frame], expected: int) -> None:
        """NAK `frame` (None: a frame too broken to name) with `reason`, echoing its tag."""
        self.stats.naks_tx += 1
        if frame is None:
            nak = SCHEMA["Nak"].type(int(reason), 0, 0, 0, expected, bytes(NAK_TAG_BYTES))
        else:
            nak = SCHEMA["Nak"].type(int(reason), frame.cls & 0xFF, frame.seq, frame.msg_id, expected,
                                     frame.tag[:NAK_TAG_BYTES].ljust(NAK_TAG_BYTES, b"\x00"))
        payload = SCHEMA["Nak"].encode(nak)
        self._queue(PRIO_URGENT, MsgClass.LINK, 0, NAK_ID, payload, handshake=self.session is None)

    # ---- role hooks ----
    def _handle_handshake(self, frame: Frame, now: float) -> None:
        raise NotImplementedError

    def _verifies_handshake_nak(self, frame: Frame) -> bool:
        """Whether a NAK outside any session is signed by a peer this end believes (the host: its controller)."""
        return frame.verify(self._handshake.rx)

    def _handle_handshake_nak(self, frame: Frame, now: float) -> None:
        self.stats.naks_rx += 1

    def _handle(self, frame: Frame, spec, now: float) -> None:
        raise NotImplementedError

    def _peer_acked(self, ack: int, now: float) -> None:
        """A session frame that passed the MAC and counter checks carried `ack` (the controller: its events),
        whatever is then done with the frame: the ack says what its sender received, which a refusal of the
        frame itself does not change."""

    def _ack_value(self) -> int:
        raise NotImplementedError

    # ---- transmit path ----
    def _queue(self, prio: int, cls: int, seq: int, msg_id: int, payload: bytes, handshake: bool = False) -> None:
        q = self._queues[prio]
        q.append(_Outgoing(int(cls), seq, msg_id, payload, handshake))
        if prio == PRIO_TELEMETRY and len(q) > self.config.telemetry_backlog:
            q.popleft()
            self.stats.telemetry_dropped += 1
        self.on_work()

    def send_message(self, msg: Message, prio: int, seq: int = 0) -> None:
        spec = msg.spec
        self._queue(prio, spec.cls, seq, spec.id, spec.encode(msg))

    def send_telemetry(self, msg: Message) -> None:
        """Queue a telemetry frame (unreliable; dropped, and counted, if the wire is backed up)."""
        if self.session is None:
            return
        self._telemetry_seq = (self._telemetry_seq + 1) & 0xFFFF
        self.send_message(msg, PRIO_TELEMETRY, self._telemetry_seq)

    @property
    def tx_backlog(self) -> int:
        return sum(len(q) for q in self._queues)

    def take_frame(self, now: float, telemetry: bool = True) -> Optional[bytes]:
        """The next frame for the wire, signed now; None when nothing is queued.

        With `telemetry=False` telemetry frames stay queued (the caller keeps the
        line free for a reply that is about to be due).
        """
        return self._take_from(self._queues if telemetry else self._queues[:PRIO_TELEMETRY], now)

    def _take_from(self, queues: list[deque[_Outgoing]], now: float) -> Optional[bytes]:
        """The first frame of the first of `queues` that has one, signed now."""
        for q in queues:
            while q:
                wire = self._sign(q.popleft(), now)
                if wire is not None:
                    return wire
        return None

    def _sign(self, out: _Outgoing, now: float) -> Optional[bytes]:
        """`out` signed for the wire and counted; None if the session it was meant for is gone."""
        if out.handshake:
            self._handshake_tx_counter += 1
            key, counter = self._handshake_tx_key(out.msg_id), self._handshake_tx_counter
        elif self.session is not None and self.session.tx_counter < COUNTER_MAX:
            self.session.tx_counter += 1
            key, counter = self.session.keys.tx, self.session.tx_counter
        else:
            return None
        # a handshake frame belongs to no session: it acknowledges nothing (the new session's numbers start afresh)
        ack = NOTHING_RECEIVED_ACK if out.handshake else self._ack_value()
        wire, tag = encode_signed(out.cls, out.seq, ack, out.msg_id, out.payload, key, counter)
        if not out.handshake:
            self._sent_in_session(tag)
            if out.cls != MsgClass.TELEMETRY and self._next_heartbeat_s is not None:
                # any session frame the peer must act on proves the link alive: the heartbeat waits (not an
                # answer to some other host's Hello, which the peer does not see as ours)
                self._next_heartbeat_s = now + self.heartbeat_s
        self.stats.frames_tx += 1
        self.stats.bytes_tx += len(wire)
        return wire

    def _handshake_tx_key(self, msg_id: int):
        """The key a frame sent outside any session is signed with."""
        return self._handshake.tx

    def _sent_in_session(self, tag: bytes) -> None:
        """A frame signed with the session key went out with `tag` (the host remembers the last few)."""

    def take_all(self, now: float) -> bytes:
        chunks = []
        while (wire := self.take_frame(now)) is not None:
            chunks.append(wire)
        return b"".join(chunks)

    # ---- timers ----
    def poll(self, now: float) -> None:
        if self.started_s is None:
            self.started_s = now
        if self.session is not None and self.state is LinkState.UP and not self.quiet:
            if self._next_heartbeat_s is None or now >= self._next_heartbeat_s:
                self._next_heartbeat_s = now + self.heartbeat_s
                self.send_message(self.heartbeat(now), PRIO_HEARTBEAT)

    def next_timer_s(self) -> float:
        """The earliest time at which `poll` may have something to do.

        Never later than that, possibly earlier (a transport polling then finds nothing to do);
        -inf: poll now; inf: nothing until a frame arrives or `on_work` is called. For a
        transport that sleeps between frames rather than polling every period.
        """
        if self.started_s is None:
            return -math.inf
        if self.session is not None and self.state is LinkState.UP and not self.quiet:
            return -math.inf if self._next_heartbeat_s is None else self._next_heartbeat_s
        return math.inf

    @property
    def quiet(self) -> bool:
        """True while periodic frames (heartbeats, telemetry) should not be sent."""
        return False

    def uptime_ms(self, now: float) -> int:
        return int((now - (self.started_s if self.started_s is not None else now)) * 1000) & 0xFFFFFFFF

    def heartbeat(self, now: float) -> Message:
        return SCHEMA["Heartbeat"].type(uptime_ms=self.uptime_ms(now), **self.heartbeat_stats())

    def heartbeat_stats(self) -> dict:
        return self.stats.heartbeat_fields()
