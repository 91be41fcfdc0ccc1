"""The controller's end of the link: handshake, exactly-once commands, reliable events, watchdog.

The application (firmware_py/comms.py) gives a `handler(msg, urgent, now) -> reply`
that executes one command and returns its reply message; the link calls it at
most once per sequence number, in order for the command class and at once for the
urgent class, and answers duplicates from the reply cache. `on_link_lost(now)` is
called when a session has seen no valid frame for `link_timeout_s`.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from typing import Callable, Optional

from protocol import auth
from protocol.errors import ParseError
from protocol.framing import Frame
from protocol.link import (HELLO_ID, PRIO_RELIABLE, PRIO_URGENT, LinkConfig, LinkEndpoint, LinkState, Session)
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.reasons import Reason
from protocol.reliable import Pending, ReliableReceiver, ReliableSender, RttEstimator, Verdict
from protocol.schema import Message, MsgClass, Schema

CommandHandler = Callable[[Message, bool, float], Message]
MAX_PENDING_SESSIONS = 4
MAX_UNDELIVERED_EVENTS = 64


class ControllerLink(LinkEndpoint):
    is_controller = True

    def __init__(self, psk: bytes, handler: CommandHandler, config: Optional[LinkConfig] = None,
                 schema: Schema = SCHEMA, nonce_source: Callable[[], bytes] = auth.new_nonce,
                 on_link_lost: Callable[[float], None] = lambda now: None,
                 on_session: Callable[[float], None] = lambda now: None) -> None:
        super().__init__(psk, config, schema, nonce_source)
        self._handler = handler
        self._on_link_lost = on_link_lost
        self._on_session = on_session
        self._pending: "OrderedDict[bytes, Session]" = OrderedDict()
        self._undelivered: list[Pending] = []
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
        result = Reason.OK
        if hello.protocol_version != PROTOCOL_VERSION:
            result = Reason.UNSUPPORTED_VERSION
        elif hello.schema_hash != self.schema.hash:
            result = Reason.SCHEMA_MISMATCH
        controller_nonce = bytes(auth.NONCE_BYTES)
        if result is Reason.OK:
            pending = self._pending.get(hello.host_nonce)
            if pending is None:   # a retransmitted Hello gets the same answer
                nonce = self._nonce()
                pending = Session(auth.session_keys(self._psk, hello.host_nonce, nonce, True),
                                  hello.host_nonce, nonce)
                self._pending[hello.host_nonce] = pending
                while len(self._pending) > MAX_PENDING_SESSIONS:
                    self._pending.popitem(last=False)
            controller_nonce = pending.controller_nonce
        else:
            self.stats.rejected += 1
            self.stats.count(result)
        reply = SCHEMA["HelloReply"].type(
            int(result), PROTOCOL_VERSION, self.schema.hash, hello.host_nonce, controller_nonce,
            int(self.config.link_timeout_s * 1000), int(self.config.heartbeat_s * 1000))
        self._queue(PRIO_URGENT, MsgClass.LINK, 0, SCHEMA["HelloReply"].id,
                    SCHEMA["HelloReply"].encode(reply), handshake=True)

    def _session_for(self, frame: Frame) -> Optional[Session]:
        session = super()._session_for(frame)
        if session is not None:
            return session
        for nonce, pending in self._pending.items():
            if frame.verify(pending.keys.rx):
                self._promote(nonce, pending)
                return pending
        return None

    def _promote(self, nonce: bytes, session: Session) -> None:
        """The host proved it holds the pending session's key: it becomes the session."""
        if self.session is not None:
            self._undelivered.extend(self._events.take_failed())
        del self._pending[nonce]
        self.session = session
        self.state = LinkState.UP
        self._new_channels()
        for item in self._undelivered[-MAX_UNDELIVERED_EVENTS:]:
            self._events.submit(item.msg_id, item.payload)
        self._undelivered = []
        self._next_heartbeat_s = None
        self._on_session(self.last_valid_rx_s or 0.0)

    # ---- session frames ----
    def _handle(self, frame: Frame, spec, now: float) -> None:
        for _ in self._events.acked_through(frame.ack, now):
            pass
        cls = frame.cls
        if cls == MsgClass.LINK:
            self._handle_link(frame, spec, now)
            return
        receiver = self._commands if cls == MsgClass.COMMAND else self._urgent
        prio = PRIO_RELIABLE if cls == MsgClass.COMMAND else PRIO_URGENT
        verdict = receiver.classify(frame.seq)
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

    # ---- events and timers ----
    def send_event(self, msg: Message) -> None:
        """Queue an event for reliable delivery (kept across sessions until delivered)."""
        spec = msg.spec
        if self.session is None:
            self._undelivered.append(Pending(spec.id, spec.encode(msg)))
            del self._undelivered[:-MAX_UNDELIVERED_EVENTS]
            return
        self._events.submit(spec.id, spec.encode(msg))
        self.on_work()

    def next_timer_s(self) -> float:
        """`LinkEndpoint.next_timer_s` with the events' timers and the link watchdog."""
        timer = super().next_timer_s()
        if self.session is None:
            return timer
        if self._events.suspended:
            return -math.inf
        timer = min(timer, self._events.next_due_s())
        if self.last_valid_rx_s is not None and not self.link_lost:
            timer = min(timer, self.last_valid_rx_s + self.config.link_timeout_s)
        return timer

    def poll(self, now: float) -> None:
        super().poll(now)
        if self.session is None:
            return
        for item in self._events.due(now):
            self._queue(PRIO_RELIABLE, MsgClass.EVENT, item.seq, item.msg_id, item.payload)
        if self._events.suspended:
            self._events.resume()   # events are never dropped: keep offering them, in order
            self.stats.event_resumes += 1
        self.stats.retransmits = self._events.retransmits
        if self._events.rtt.srtt_s is not None:
            self.stats.srtt_us = int(self._events.rtt.srtt_s * 1e6)
        if self.last_valid_rx_s is not None and now - self.last_valid_rx_s > self.config.link_timeout_s:
            if not self.link_lost:
                self.link_lost = True
                self._on_link_lost(now)
        elif self.link_lost:
            self.link_lost = False
