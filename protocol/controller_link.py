"""The controller's end of the link: handshake, exactly-once commands, reliable events, watchdog.

The application (firmware_py/comms.py) gives a `handler(msg, urgent, now) -> reply`
that executes one command and returns its reply message; the link calls it at
most once per sequence number, in order for the command class and at once for the
urgent class, and answers duplicates from the reply cache. `on_link_lost(now)` is
called when a session has seen no valid frame for `link_timeout_s`.

Handshake answers are bounded, because a Hello signed with the handshake key can be
recorded and played back at any rate (docs/protocol_security.md):

- a Hello must echo a fresh cookie: one without is answered only with a `HelloCookie`, made
  statelessly from its nonce and the time (`auth.hello_cookie`, valid 4 to 8 s), at most
  `COOKIE_RATE_PER_S` a second, `MAX_WAITING_COOKIES` waiting; the nonce given fewest cookies so
  far goes first and the one given most leaves when the list is full (ties broken by a keyed
  hash the attacker cannot predict), so recordings played back again lose to a new host; a
  recorded Hello's cookie is stale by then, so recordings never wait for a session;
- a Hello whose nonce already opened a session that a host adopted is a replay: counted,
  never answered (the last `COMPLETED_MEMORY` such nonces are remembered);
- the Hellos to answer wait in a short list, one per nonce (`MAX_WAITING_HELLOS`); a nonce
  answered less than `HELLO_REANSWER_S` ago is not answered again;
- answers go out at most `LinkConfig.hello_rate_per_s` a second (`HELLO_BURST` at once),
  after the session's own frames (commands' replies and events), and the nonce answered
  least often so far goes first, so a host that has not been answered yet is not starved
  by a few recorded Hellos played back over and over;
- a pending session is made when its first HelloReply goes out and is not evicted for
  another within `PENDING_MIN_LIFE_S`, so a host that got its answer has time to adopt it;
  answering its Hello again does not extend that, so recordings played back cannot hold
  the places for ever.

A session ends with the host's `Close` (`close_session`, called by the controller's handler):
no more telemetry, heartbeats or watchdog; the session stays only for the host's last
acknowledgements and a repeated Close (its cached `Closed`), and is forgotten when every
event is acknowledged or after the link timeout (the linger). Other commands in it are
refused (`SESSION_CLOSED`). The controller's handshake NAKs (with no session) are signed
with a key bound to its identity (`auth.nak_key`, `controller_id` in HelloReply), so that
another controller holding the same key cannot end this one's session.

Events survive fades and new sessions: those a session did not acknowledge are offered
again in the next one, behind an `EventsCarriedOver` event that says how many of them an
earlier host was sent (it may have seen them, its acknowledgement lost) and how many were
lost for want of room (`MAX_UNDELIVERED_EVENTS`).
"""
from __future__ import annotations

import hmac
import itertools
import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable, Optional

from protocol import auth
from protocol.errors import ParseError
from protocol.framing import Frame
from protocol.link import (HELLO_ID, HELLO_REPLY_ID, NAK_ID, PRIO_HEARTBEAT, PRIO_RELIABLE, PRIO_TELEMETRY, PRIO_URGENT,
                           LinkConfig, LinkEndpoint, LinkState, Session, TokenBucket, _Outgoing)
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.reasons import Reason
from protocol.reliable import SEQ_MOD, Pending, ReliableReceiver, ReliableSender, RttEstimator, Verdict
from protocol.schema import Message, MsgClass, Schema

CommandHandler = Callable[[Message, bool, float], Message]
MAX_PENDING_SESSIONS = 8
PENDING_MIN_LIFE_S = 2.0      # a pending session is kept at least this long after it was made (answered)
MAX_WAITING_HELLOS = 4        # Hellos waiting for an answer (one per nonce)
HELLO_REANSWER_S = 0.5        # a nonce is answered at most once in this long (a host resends after 1 s)
HELLO_BURST = 2               # HelloReplies at once before `hello_rate_per_s` holds
HELLO_MEMORY = 256            # nonces answered, with how often (the least often answered goes first)
COMPLETED_MEMORY = 256        # nonces of adopted sessions: a Hello bearing one is a replay
MAX_UNDELIVERED_EVENTS = 64   # events kept for the next session
VOUCH_KEY_OR_RECORDING, VOUCH_KEY, VOUCH_LIVE_SESSION = 1, 2, 3     # `vouch`: what a frame proves of its sender
COOKIE_EPOCH_S = 4.0          # a cookie is valid in the slot of this length it was made in and the next one
COOKIE_RATE_PER_S = 64.0      # HelloCookie answers a second (a flood at the whole line rate is about 180 Hellos)
COOKIE_BURST = 8
MAX_WAITING_COOKIES = 8       # Hellos waiting for a HelloCookie, one per nonce
COOKIE_MEMORY = 1024          # nonces given cookies, with how often (the least often goes first, the most often leaves)
CARRIED_OVER = SCHEMA["EventsCarriedOver"]


@dataclass
class _Hello:
    """A Hello waiting for its answer."""

    host_nonce: bytes
    result: Reason
    order: int                # arrival order, for ties


@dataclass
class _Pending:
    session: Session
    made_s: float             # when it was made, at its first HelloReply


class ControllerLink(LinkEndpoint):
    is_controller = True

    def __init__(self, psk: bytes, handler: CommandHandler, config: Optional[LinkConfig] = None,
                 schema: Schema = SCHEMA, nonce_source: Callable[[], bytes] = auth.new_nonce,
                 on_link_lost: Callable[[float], None] = lambda now: None,
                 on_session: Callable[[float], None] = lambda now: None,
                 controller_id: Optional[bytes] = None) -> None:
        super().__init__(psk, config, schema, nonce_source)
        # who this controller is (HelloReply): given, or new at each start; its handshake NAKs are bound to it
        self.controller_id = controller_id if controller_id is not None else self._nonce()[:auth.CONTROLLER_ID_BYTES]
        if len(self.controller_id) != auth.CONTROLLER_ID_BYTES:
            raise ValueError(f"controller_id must be {auth.CONTROLLER_ID_BYTES} bytes")
        self._nak_tx = auth.nak_key(psk, self.controller_id)
        self._cookie_secret = self._nonce()
        self._cookies: "OrderedDict[bytes, tuple[int, bytes]]" = OrderedDict()   # waiting: nonce -> (order, tie)
        self._cookied: "OrderedDict[bytes, int]" = OrderedDict()      # nonce -> cookies given it
        self._cookie_answers = TokenBucket(COOKIE_RATE_PER_S, COOKIE_BURST)
        self._closing_since: Optional[float] = None     # CLOSING: when the linger began (None: at the next poll)
        self._seen_s = 0.0                               # the link's time at its last feed or poll (`vouch`)
        self._handler = handler
        self._on_link_lost = on_link_lost
        self._on_session = on_session
        self._pending: "OrderedDict[bytes, _Pending]" = OrderedDict()
        self._waiting: "OrderedDict[bytes, _Hello]" = OrderedDict()
        self._answered: "OrderedDict[bytes, tuple[int, float]]" = OrderedDict()   # nonce -> (answers, last)
        self._completed: "OrderedDict[bytes, None]" = OrderedDict()
        self._hello_answers = TokenBucket(self.config.hello_rate_per_s, HELLO_BURST)
        self._arrivals = itertools.count()
        self._before_hellos = self._queues[:PRIO_HEARTBEAT]
        self._after_hellos = self._queues[PRIO_HEARTBEAT:]
        self._after_hellos_no_telemetry = self._queues[PRIO_HEARTBEAT:PRIO_TELEMETRY]
        self._undelivered: list[Pending] = []    # events for the next session; context True: offered already
        self._events_dropped = 0
        self.link_lost = False
        self.commands_executed = 0
        self._new_channels()

    def _new_channels(self) -> None:
        cfg = self.config
        self._commands = ReliableReceiver()
        self._urgent = ReliableReceiver(in_order=False)
        self._events = ReliableSender(window=cfg.window, retry_limit=cfg.retry_limit,
                                      rtt=RttEstimator(cfg.initial_rto_s, cfg.min_rto_s, cfg.max_rto_s))

    # ---- handshake ----
    def _handle_handshake(self, frame: Frame, now: float) -> None:
        if frame.msg_id != HELLO_ID:
            self._refuse(frame, Reason.WRONG_DIRECTION, now)
            return
        try:
            hello = self.schema.decode(frame.msg_id, frame.payload)
        except ParseError as exc:
            self._refuse(frame, exc.reason, now)
            return
        nonce = hello.host_nonce
        if nonce in self._completed:          # its session was adopted: only a recording sends it again
            self.stats.replays += 1
            self.stats.count(Reason.REPLAY)
            return
        if not self._cookie_fresh(nonce, hello.cookie, now):
            self._offer_cookie(nonce)
            return
        answered = self._answered.get(nonce)
        if nonce in self._waiting or (answered is not None and now - answered[1] < HELLO_REANSWER_S):
            self.stats.hellos_dropped += 1
            return
        result = Reason.OK
        if hello.protocol_version != PROTOCOL_VERSION:
            result = Reason.UNSUPPORTED_VERSION
        elif hello.schema_hash != self.schema.hash:
            result = Reason.SCHEMA_MISMATCH
        if result is not Reason.OK:
            self.stats.rejected += 1
            self.stats.count(result)
        self._waiting[nonce] = _Hello(nonce, result, next(self._arrivals))
        if len(self._waiting) > MAX_WAITING_HELLOS:   # the one that deserves an answer least waits no more
            del self._waiting[max(self._waiting.values(), key=self._hello_rank).host_nonce]
            self.stats.hellos_dropped += 1
        self.on_work()

    def _cookie_fresh(self, host_nonce: bytes, cookie: bytes, now: float) -> bool:
        """Whether `cookie` is the one this controller gave `host_nonce` in this time slot or the last."""
        epoch = math.floor(now / COOKIE_EPOCH_S)
        return any(hmac.compare_digest(cookie, auth.hello_cookie(self._cookie_secret, host_nonce, e))
                   for e in (epoch, epoch - 1))

    def _offer_cookie(self, host_nonce: bytes) -> None:
        """Queue a HelloCookie for `host_nonce` (once while it waits); when the list is full, the nonce given most
        cookies so far leaves it (a tie: by a keyed hash of the nonce, which no one outside can predict)."""
        if host_nonce in self._cookies:
            return
        tie = hmac.digest(self._cookie_secret, b"tie" + host_nonce, "sha256")[:4]
        self._cookies[host_nonce] = (next(self._arrivals), tie)
        if len(self._cookies) > MAX_WAITING_COOKIES:
            del self._cookies[max(self._cookies, key=lambda n: (self._cookied.get(n, 0), self._cookies[n][1]))]
            self.stats.hellos_dropped += 1
        self.on_work()

    def _answer_cookie(self, now: float) -> Optional[bytes]:
        """The HelloCookie to send now, signed, to the nonce given fewest so far (then the first come); None if
        none waits or the rate says not yet."""
        if not self._cookies or not self._cookie_answers.take(now):
            return None
        host_nonce = min(self._cookies, key=lambda n: (self._cookied.get(n, 0), self._cookies[n][0]))
        del self._cookies[host_nonce]
        self._cookied[host_nonce] = self._cookied.pop(host_nonce, 0) + 1
        if len(self._cookied) > COOKIE_MEMORY:
            self._cookied.popitem(last=False)
        spec = SCHEMA["HelloCookie"]
        cookie = auth.hello_cookie(self._cookie_secret, host_nonce, math.floor(now / COOKIE_EPOCH_S))
        return self._sign(_Outgoing(MsgClass.LINK, 0, spec.id, spec.encode(spec.type(host_nonce, cookie)),
                                    handshake=True), now)

    def vouch(self, frame: Frame) -> int:
        """What a frame seen on a connection that does not hold the line yet says of its sender, for a port that
        admits connections (host_tools/worlds/ports.py `TcpServerPort`); nothing changes here. 3: a new frame of the
        live session (its host); 2: a new frame of a pending session, or a Hello with a fresh cookie (a host that
        holds the key now); 1: a Hello that verifies (the key, or a recording of it); 0: nothing. At the time of
        the link's last `feed` or `poll`."""
        if frame.counter is None:
            return 0
        session = self.session
        if session is not None and frame.counter > session.rx_counter and frame.verify(session.keys.rx):
            return VOUCH_LIVE_SESSION
        if frame.msg_id == HELLO_ID:
            if not frame.verify(self._handshake.rx):
                return 0
            try:
                hello = self.schema.decode(frame.msg_id, frame.payload)
            except ParseError:
                return VOUCH_KEY_OR_RECORDING
            fresh = hello.host_nonce not in self._completed and \
                self._cookie_fresh(hello.host_nonce, hello.cookie, self._seen_s)
            return VOUCH_KEY if fresh else VOUCH_KEY_OR_RECORDING
        if any(frame.counter > p.session.rx_counter and frame.verify(p.session.keys.rx)
               for p in self._pending.values()):
            return VOUCH_KEY
        return 0

    def feed(self, data: bytes, now: float) -> None:
        self._seen_s = now
        super().feed(data, now)

    def _handshake_tx_key(self, msg_id: int):
        return self._nak_tx if msg_id == NAK_ID else self._handshake.tx

    def _hello_rank(self, hello: _Hello) -> tuple[int, int]:
        """Who is answered first: the nonce answered least often, then the earliest."""
        answered = self._answered.get(hello.host_nonce)
        return (answered[0] if answered else 0, hello.order)

    def _answer_hello(self, now: float) -> Optional[bytes]:
        """The HelloReply to send now, signed; None if none may go yet (rate, pending sessions)."""
        ready = [h for h in self._waiting.values() if self._may_answer_s(h) <= now]
        if not ready or not self._hello_answers.take(now):
            return None
        hello = min(ready, key=self._hello_rank)
        controller_nonce = bytes(auth.NONCE_BYTES)
        if hello.result is Reason.OK:
            controller_nonce = self._pending_for(hello.host_nonce, now).session.controller_nonce
        del self._waiting[hello.host_nonce]
        count = self._answered.pop(hello.host_nonce, (0, now))[0]
        self._answered[hello.host_nonce] = (count + 1, now)
        if len(self._answered) > HELLO_MEMORY:
            self._answered.popitem(last=False)
        reply = SCHEMA["HelloReply"].type(
            int(hello.result), PROTOCOL_VERSION, self.schema.hash, hello.host_nonce, controller_nonce,
            int(self.config.link_timeout_s * 1000), int(self.config.heartbeat_s * 1000), self.controller_id)
        return self._sign(_Outgoing(MsgClass.LINK, 0, HELLO_REPLY_ID, SCHEMA["HelloReply"].encode(reply),
                                    handshake=True), now)

    def _may_answer_s(self, hello: _Hello) -> float:
        """When `hello` may be answered, tokens aside: at once (-inf) for a refusal, or if its pending session
        exists or a place is free; else when the oldest pending session will have had `PENDING_MIN_LIFE_S`
        (its host had time to adopt it) and may give way."""
        if hello.result is not Reason.OK or hello.host_nonce in self._pending or \
                len(self._pending) < MAX_PENDING_SESSIONS:
            return -math.inf
        return next(iter(self._pending.values())).made_s + PENDING_MIN_LIFE_S

    def _pending_for(self, host_nonce: bytes, now: float) -> _Pending:
        """The pending session to answer `host_nonce` with (a Hello sent again gets the same one), made if
        needed in the place of the oldest (`_may_answer_s` said it may give way)."""
        pending = self._pending.get(host_nonce)
        if pending is None:
            if len(self._pending) >= MAX_PENDING_SESSIONS:
                self._pending.popitem(last=False)
            nonce = self._nonce()
            pending = _Pending(Session(auth.session_keys(self._psk, host_nonce, nonce, True), host_nonce, nonce), now)
            self._pending[host_nonce] = pending
        return pending

    def _hellos_ready_s(self) -> float:
        """When a waiting Hello may next be answered, with a HelloReply or a HelloCookie (inf: none waits)."""
        ready = self._cookie_answers.ready_s() if self._cookies else math.inf
        if not self._waiting:
            return ready
        return min(ready, max(self._hello_answers.ready_s(),
                              min(self._may_answer_s(h) for h in self._waiting.values())))

    def take_frame(self, now: float, telemetry: bool = True) -> Optional[bytes]:
        """`LinkEndpoint.take_frame`, with the answers to Hellos after the session's replies and events."""
        wire = self._take_from(self._before_hellos, now)
        if wire is None and self._waiting:
            wire = self._answer_hello(now)
        if wire is None and self._cookies:
            wire = self._answer_cookie(now)
        if wire is None:
            wire = self._take_from(self._after_hellos if telemetry else self._after_hellos_no_telemetry, now)
        return wire

    def _session_for(self, frame: Frame) -> Optional[Session]:
        session = super()._session_for(frame)
        if session is not None:
            return session
        for nonce, pending in self._pending.items():
            if frame.verify(pending.session.keys.rx):
                self._promote(nonce, pending.session)
                return pending.session
        return None

    def _promote(self, nonce: bytes, session: Session) -> None:
        """The host proved it holds the pending session's key: it becomes the session."""
        if self.session is not None:
            self._undelivered.extend(self._events.take_failed())
        del self._pending[nonce]
        self._waiting.pop(nonce, None)
        self._answered.pop(nonce, None)
        self._completed[nonce] = None
        if len(self._completed) > COMPLETED_MEMORY:
            self._completed.popitem(last=False)
        self.session = session
        self.state = LinkState.UP
        self._closing_since = None
        self._new_channels()
        self._carry_over_events()
        self._next_heartbeat_s = None
        self._on_session(self.last_valid_rx_s or 0.0)

    def _keep_undelivered(self) -> None:
        """Keep the newest `MAX_UNDELIVERED_EVENTS`; count the others as dropped."""
        excess = len(self._undelivered) - MAX_UNDELIVERED_EVENTS
        if excess > 0:
            del self._undelivered[:excess]
            self._events_dropped += excess

    def _carry_over_events(self) -> None:
        """Offer the new session the events the old one left, behind an `EventsCarriedOver` if any of them was
        offered before (sent at least once, in that session or an earlier one) or some were dropped."""
        items = []
        for item in self._undelivered:
            if item.msg_id == CARRIED_OVER.id:    # an earlier marker never acknowledged: a new one replaces it
                self._events_dropped += CARRIED_OVER.decode(item.payload).dropped
            else:
                items.append(item)
        self._undelivered = items
        self._keep_undelivered()
        offered = max((i + 1 for i, item in enumerate(self._undelivered)
                       if item.context or item.first_sent_s is not None), default=0)
        if offered or self._events_dropped:
            marker = CARRIED_OVER.type(min(offered, 0xFFFF), min(self._events_dropped, 0xFFFF))
            self._events.submit(CARRIED_OVER.id, CARRIED_OVER.encode(marker))
        for i, item in enumerate(self._undelivered):
            self._events.submit(item.msg_id, item.payload, context=i < offered)
        self._undelivered = []
        self._events_dropped = 0

    # ---- session frames ----
    def _peer_acked(self, ack: int, now: float) -> None:
        self._events.acked_through(ack, now)

    def _handle(self, frame: Frame, spec, now: float) -> None:
        cls = frame.cls
        if cls == MsgClass.LINK:
            self._handle_link(frame, spec, now)
            return
        receiver = self._commands if cls == MsgClass.COMMAND else self._urgent
        prio = PRIO_RELIABLE if cls == MsgClass.COMMAND else PRIO_URGENT
        verdict = receiver.classify(frame.seq)
        if verdict is not Verdict.DUPLICATE and self.state is LinkState.CLOSING:
            self._refuse(frame, Reason.SESSION_CLOSED, now, expected=receiver.expected)   # its Close came first
            return
        if verdict is Verdict.GAP:
            if receiver.should_nak_gap():
                self._refuse(frame, Reason.SEQUENCE_GAP, now, expected=receiver.expected)
            return
        if verdict is Verdict.DUPLICATE:
            cached = receiver.cached_reply(frame.seq)
            if cached is None:
                self.stats.stale_duplicates += 1
                self._refuse(frame, Reason.REPLAY, now, expected=receiver.expected)
            else:
                self._queue(prio, cls, frame.seq, *cached)
            return
        try:
            msg = spec.decode(frame.payload)
        except ParseError as exc:
            self.stats.rejected += 1
            self.stats.count(exc.reason)
            reply = SCHEMA["Result"].type(int(exc.reason))
        else:
            reply = self._handler(msg, cls == MsgClass.URGENT, now)
            self.commands_executed += 1
        encoded = (reply.spec.id, reply.spec.encode(reply))
        receiver.accept(frame.seq, encoded)
        self._queue(prio, cls, frame.seq, *encoded)

    def _handle_link(self, frame: Frame, spec, now: float) -> None:
        if spec.name == "Heartbeat" or spec.name == "Nak":
            try:
                msg = spec.decode(frame.payload)
            except ParseError as exc:
                self._refuse(frame, exc.reason, now)
                return
            if spec.name == "Heartbeat":
                self.peer_stats = msg
            else:
                self.stats.naks_rx += 1
                if msg.refused_class == MsgClass.EVENT and msg.reason == Reason.SEQUENCE_GAP:
                    self._events.go_back(msg.expected_seq, now)

    def _ack_value(self) -> int:
        return self._commands.last_in_order

    @property
    def quiet(self) -> bool:
        return self.link_lost   # nobody is listening: do not fill the line with heartbeats

    # ---- the session's end ----
    @property
    def last_event_seq(self) -> int:
        """The sequence number the last event submitted in this session has or will have."""
        return (self._events.next_seq + self._events.waiting - 1) % SEQ_MOD

    def close_session(self) -> None:
        """The host's Close was executed: the session says nothing more of its own (no telemetry, heartbeats or
        watchdog) and lingers, for the host's last acknowledgements and a repeated Close, until every event is
        acknowledged or the link timeout has passed (from the next `poll`); then it is forgotten."""
        if self.session is not None:
            self.state = LinkState.CLOSING
            self.link_lost = False               # its host just spoke (the Close): its events go out
            self._closing_since = None
            for periodic in self._after_hellos:      # heartbeats and telemetry queued before the Close: not sent
                periodic.clear()

    def _linger_over(self, now: float) -> bool:
        if self._closing_since is None:
            self._closing_since = now
        replies_out = not (self._queues[PRIO_URGENT] or self._queues[PRIO_RELIABLE])
        return (replies_out and self._events.outstanding == 0) or now - self._closing_since >= self.config.link_timeout_s

    def _forget_session(self) -> None:
        """The closed session is gone: the events its host did not acknowledge wait for the next one."""
        self._undelivered.extend(self._events.take_failed())
        self._keep_undelivered()
        self.session = None
        self.state = LinkState.NO_SESSION
        self._closing_since = None
        self._new_channels()

    # ---- events and timers ----
    def send_telemetry(self, msg: Message) -> None:
        if self.state is not LinkState.CLOSING:
            super().send_telemetry(msg)

    def send_event(self, msg: Message) -> None:
        """Queue an event for reliable delivery (kept across sessions until delivered)."""
        spec = msg.spec
        if self.session is None:
            self._undelivered.append(Pending(spec.id, spec.encode(msg)))
            self._keep_undelivered()
            return
        self._events.submit(spec.id, spec.encode(msg))
        self.on_work()

    def next_timer_s(self) -> float:
        """`LinkEndpoint.next_timer_s` with the events' timers and the link watchdog."""
        timer = super().next_timer_s()
        if self._waiting or self._cookies:
            timer = min(timer, self._hellos_ready_s())
        if self.session is None:
            return timer
        if self._events.suspended:
            return -math.inf
        if not self.link_lost:
            timer = min(timer, self._events.next_due_s())
        elif self._events.waiting:   # the link is lost: new events still go out once, nothing is resent (`poll`)
            timer = -math.inf
        if self.state is LinkState.CLOSING:
            return -math.inf if self._closing_since is None else \
                min(timer, self._closing_since + self.config.link_timeout_s)
        if self.last_valid_rx_s is not None and not self.link_lost:
            timer = min(timer, self.last_valid_rx_s + self.config.link_timeout_s)
        return timer

    def poll(self, now: float) -> None:
        self._seen_s = now
        super().poll(now)
        if self.session is None:
            return
        if self.state is not LinkState.CLOSING:
            self._watch(now)
        # While the link is lost no event is resent: nobody listens, and a new host on the line (a new connection)
        # could not verify them under this session's key. A new event still goes out once (the StateChanged to
        # the safe state, into the silence, in case the host hears it); the rest go when this session's host is
        # heard again, or, if another session is adopted first, are carried over to it (rule 7).
        for item in self._events.due(now, resend=not self.link_lost):
            self._queue(PRIO_RELIABLE, MsgClass.EVENT, item.seq, item.msg_id, item.payload)
        if self._events.suspended:
            self._events.resume()   # events are never dropped: keep offering them, in order
            self.stats.event_resumes += 1
        self.stats.retransmits = self._events.retransmits
        if self._events.rtt.srtt_s is not None:
            self.stats.srtt_us = int(self._events.rtt.srtt_s * 1e6)
        if self.state is LinkState.CLOSING and self._linger_over(now):
            self._forget_session()

    def _watch(self, now: float) -> None:
        """The link watchdog: lost after `link_timeout_s` without a valid frame (`on_link_lost`), back at the next."""
        if self.last_valid_rx_s is not None and now - self.last_valid_rx_s > self.config.link_timeout_s:
            if not self.link_lost:
                self.link_lost = True
                self._on_link_lost(now)
        elif self.link_lost:
            self.link_lost = False
