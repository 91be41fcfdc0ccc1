"""The host's end of the link: handshake, commands with exactly one outcome each, events in.

`submit(msg, now)` returns a `CommandHandle` that ends in exactly one terminal
outcome: SUCCEEDED (answered OK), REJECTED (answered with a reason code) or FAILED
(never answered: the retry limit suspended the link, or the session was replaced;
the command may or may not have run, and the handle says so). Nothing is dropped
silently.

A controller that restarted answers the host's frames with `Nak(NO_SESSION)` signed with
the handshake key. Such a NAK could be recorded once and replayed forever, so while a
session is up the host acts on one (a new handshake) only if it echoes the tag of a frame
the host sent in this session (it keeps the last `SENT_TAGS`); any other is a replay,
counted and ignored.

The controller's handshake NAKs are signed with a key bound to its identity (`controller_id` in its
HelloReply, `auth.nak_key`): a NAK made by another controller that holds the key, for a frame copied to
it, does not verify here.

Every Hello is answered first with a `HelloCookie`, which the host echoes in a second Hello at once (the
controller answers only Hellos with a fresh cookie: recordings never wait for a session).

`close(now, why)` ends the session cleanly: a `Close` after every command already submitted; the
state is CLOSING until the controller's `Closed` and every event up to its `last_event_seq` have come,
then CLOSED (the last acknowledgement queued). A host that goes silent without a Close is a lost link
to the controller, latched as a fault.

Events come to `on_event(msg, now)` once each. An `EventsCarriedOver(count)` says that the
next `count` were sent to an earlier session, whose host may have seen them (its
acknowledgement lost); while `on_event` handles one of those,
`event_from_earlier_session` is True.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Callable, Optional

from protocol import auth
from protocol.errors import EncodeError, ParseError
from protocol.framing import Frame
from protocol.link import (HELLO_COOKIE_ID, HELLO_REPLY_ID, NAK_TAG_BYTES, PRIO_RELIABLE, PRIO_URGENT, LinkConfig, LinkEndpoint,
                           LinkState, Session)
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.reasons import Reason
from protocol.reliable import Outcome, Pending, ReliableReceiver, ReliableSender, RttEstimator, Verdict, seq_delta
from protocol.schema import Message, MessageSpec, MsgClass, Schema
from protocol.states import CloseWhy

SENT_TAGS = 64    # tags of the last frames sent in this session that a handshake NAK may echo


@dataclass(eq=False)
class CommandHandle:
    """One command from submission to its single terminal outcome."""

    msg: Message
    submitted_s: float
    outcome: Outcome = Outcome.PENDING
    reason: Reason = Reason.OK
    reply: Optional[Message] = None
    done_s: Optional[float] = None
    tries: int = 0
    detail: str = ""
    spec: Optional[MessageSpec] = None     # the command's spec (`msg.spec`; given where `msg` is None)

    def __post_init__(self) -> None:
        if self.spec is None and self.msg is not None:
            self.spec = self.msg.spec

    @property
    def done(self) -> bool:
        return self.outcome is not Outcome.PENDING

    @property
    def ok(self) -> bool:
        return self.outcome is Outcome.SUCCEEDED

    @property
    def latency_s(self) -> Optional[float]:
        return None if self.done_s is None else self.done_s - self.submitted_s

    def _finish(self, outcome: Outcome, reason: Reason, now: float, reply: Optional[Message] = None,
                detail: str = "") -> None:
        if self.done:   # exactly one terminal outcome
            return
        self.outcome, self.reason, self.reply, self.done_s, self.detail = outcome, reason, reply, now, detail

    def describe(self) -> str:
        if self.outcome is Outcome.SUCCEEDED:
            return f"{self.spec.name}: ok"
        if self.outcome is Outcome.PENDING:
            return f"{self.spec.name}: no outcome yet (still being retried)"
        why = self.reason.describe() if isinstance(self.reason, Reason) else str(self.reason)
        return f"{self.spec.name}: {self.outcome.value}: {why}{' (' + self.detail + ')' if self.detail else ''}"


@dataclass
class Refusal:
    reason: Reason
    detail: str


@dataclass
class HandshakeSeen:
    """What a connect attempt heard (to say why a handshake did not complete): handshake frames that verified
    under this key (answers to this host's Hellos, or to others'), and this host's cookies."""

    verified: int = 0          # HelloReply and HelloCookie frames that verified, whoever they answer
    for_others: int = 0        # ... of which answered another host's Hello
    cookies: int = 0           # HelloCookie answers to this host's nonce

    def why_not_up(self, hellos: int, auth_errors: int, bytes_rx: int) -> str:
        """Why a connect found no session, as far as the line shows it."""
        if bytes_rx == 0:
            return f"nothing came back to {hellos} Hello frame(s): no controller answers on this line"
        if self.verified == 0 and auth_errors:
            return (f"{auth_errors} frame(s) came and none verifies under this key: the two ends have different keys "
                    "(--key-file)")
        if self.cookies:
            return (f"the controller answered {self.cookies} of {hellos} Hello frame(s) with a cookie but not with a "
                    f"session ({self.for_others} answers to other hosts' Hellos seen): the line or the controller is "
                    "busy (a flood of Hellos?)")
        if self.for_others:
            return (f"the controller answered {self.for_others} other Hello(s) but none of this host's {hellos}: "
                    "the line is busy (a flood of recorded Hellos, or other hosts connecting)")
        return f"no answer to {hellos} Hello frame(s) (frames came, none a handshake answer)"


class HostLink(LinkEndpoint):
    is_controller = False

    def __init__(self, psk: bytes, config: Optional[LinkConfig] = None, schema: Schema = SCHEMA,
                 nonce_source: Callable[[], bytes] = auth.new_nonce,
                 on_telemetry: Callable[[Message, float], None] = lambda msg, now: None,
                 on_event: Callable[[Message, float], None] = lambda msg, now: None) -> None:
        super().__init__(psk, config, schema, nonce_source)
        self.on_telemetry = on_telemetry
        self.on_event = on_event
        self.refusal: Optional[Refusal] = None
        self.controller_info: Optional[Message] = None
        self.last_telemetry: Optional[Message] = None
        self.peer_stats_s: Optional[float] = None          # when the peer's last Heartbeat arrived
        self.sessions_started = 0
        self.handshake_seen = HandshakeSeen()
        self.closed: Optional[Message] = None             # the controller's Closed, once the close is answered
        self._close: Optional[CommandHandle] = None
        self._nak_rx = None                               # the key of this session's controller's handshake NAKs
        self._cookie = bytes(auth.COOKIE_BYTES)
        self._hello_nonce: Optional[bytes] = None
        self._hello_due_s: Optional[float] = None
        self._hello_tries = 0
        self._telemetry_expected: Optional[int] = None
        self._retransmits_before = 0
        self._sent_tags: deque[bytes] = deque(maxlen=SENT_TAGS)
        self.event_from_earlier_session = False   # while on_event runs: see the module's doc
        self._new_channels()

    def _new_channels(self) -> None:
        cfg = self.config
        self._commands = ReliableSender(window=cfg.window, retry_limit=cfg.retry_limit,
                                        rtt=RttEstimator(cfg.initial_rto_s, cfg.min_rto_s, cfg.max_rto_s))
        self._urgent = ReliableSender(window=cfg.window, retry_limit=cfg.retry_limit, in_order=False,
                                      rtt=self._commands.rtt)
        self._events = ReliableReceiver()
        self._earlier_events = 0     # events still to come that an earlier session was sent (EventsCarriedOver)

    # ---- handshake ----
    def connect(self, now: float) -> None:
        """Start (or restart) a session. Commands still outstanding fail with SESSION_RESET."""
        self._fail_all(Reason.SESSION_RESET, now, "a new session was started")
        self._retransmits_before += self._commands.retransmits + self._urgent.retransmits
        self._new_channels()
        self._sent_tags.clear()
        self.session = None
        self.refusal = None
        self.closed, self._close, self._nak_rx = None, None, None
        self.handshake_seen = HandshakeSeen()
        self.state = LinkState.CONNECTING
        self._hello_nonce = self._nonce()
        self._cookie = bytes(auth.COOKIE_BYTES)
        self._hello_tries = 0
        self._hello_due_s = now
        self.on_work()

    @property
    def hellos_sent(self) -> int:
        return self._hello_tries

    def _send_hello(self, now: float, count: bool = True) -> None:
        """Send the Hello (again); `count`: it uses up one of `hello_tries` (not the echo of a fresh cookie)."""
        self._hello_tries += count
        self._hello_due_s = now + self.config.initial_rto_s
        hello = SCHEMA["Hello"].type(PROTOCOL_VERSION, self.schema.hash, self._hello_nonce, self._cookie)
        self._queue(PRIO_URGENT, MsgClass.LINK, 0, SCHEMA["Hello"].id, SCHEMA["Hello"].encode(hello),
                    handshake=True)

    def _handle_handshake(self, frame: Frame, now: float) -> None:
        if frame.msg_id not in (HELLO_REPLY_ID, HELLO_COOKIE_ID):
            return
        reply = self._decode(frame)
        if reply is None:
            return
        self.handshake_seen.verified += 1
        if self.state is not LinkState.CONNECTING or reply.host_nonce != self._hello_nonce:
            self.handshake_seen.for_others += 1
            self.stats.replays += 1   # an answer to some other Hello: stale or replayed
            return
        if frame.msg_id == HELLO_COOKIE_ID:
            self.handshake_seen.cookies += 1
            if reply.cookie != self._cookie:
                self._cookie = reply.cookie
                self._send_hello(now, count=False)     # at once: the cookie is valid for seconds only
            return
        self.controller_info = reply
        self._hello_due_s = None
        if reply.result != Reason.OK:
            reason = Reason(reply.result) if reply.result in Reason._value2member_map_ else Reason.NO_SESSION
            detail = (f"host schema {self.schema.hash:016x}, controller schema {reply.schema_hash:016x}; "
                      f"host protocol v{PROTOCOL_VERSION}, controller v{reply.protocol_version}")
            self.refusal = Refusal(reason, detail)
            self.state = LinkState.REFUSED
            return
        self.session = Session(auth.session_keys(self._psk, reply.host_nonce, reply.controller_nonce, False),
                               reply.host_nonce, reply.controller_nonce)
        self._nak_rx = auth.nak_key(self._psk, reply.controller_id)
        self.state = LinkState.UP
        self.sessions_started += 1
        # speak at least three times within the controller's link timeout, whatever ours says
        self.heartbeat_s = min(self.config.heartbeat_s, max(0.01, reply.link_timeout_ms / 3000))
        self._next_heartbeat_s = None   # a heartbeat at once makes the controller adopt the session

    def _handle_handshake_nak(self, frame: Frame, now: float) -> None:
        """A NAK signed with the handshake key: the controller has no session of ours (it restarted).

        While up, believed only if it refuses a frame sent in this session (its tag is one of ours):
        anything else is a recorded NAK played back, which must not end a live session.
        """
        super()._handle_handshake_nak(frame, now)
        if self.state not in (LinkState.UP, LinkState.CLOSING):
            return
        nak = self._decode(frame)
        if nak is None:
            return
        if nak.reason != Reason.NO_SESSION or nak.refused_tag not in self._sent_tags:
            self.stats.replays += 1
            self.stats.count(Reason.REPLAY)
            return
        if self.state is LinkState.CLOSING:
            self._closed(now)       # the controller has forgotten the session (it closed it; the answer was lost)
        else:
            self.connect(now)

    def _verifies_handshake_nak(self, frame: Frame) -> bool:
        """Only this session's controller's handshake NAKs are believed (signed under its identity's key)."""
        return self._nak_rx is not None and frame.verify(self._nak_rx)

    def _sent_in_session(self, tag: bytes) -> None:
        self._sent_tags.append(tag[:NAK_TAG_BYTES])

    def _decode(self, frame: Frame) -> Optional[Message]:
        """The message in an authenticated frame; None (counted as rejected) if it does not decode."""
        try:
            return self.schema.decode(frame.msg_id, frame.payload)
        except ParseError:
            self.stats.rejected += 1
            return None

    # ---- commands ----
    def submit(self, msg: Message, now: float) -> CommandHandle:
        """Send a command or urgent request; its handle ends in exactly one outcome."""
        handle = CommandHandle(msg, now)
        spec = msg.spec
        if spec.cls not in (MsgClass.COMMAND, MsgClass.URGENT) or spec.reply is None:
            handle._finish(Outcome.REJECTED, Reason.WRONG_DIRECTION, now, detail=f"{spec.name} is not a command")
            return handle
        if self.state is not LinkState.UP:
            reason = Reason.LINK_SUSPENDED if self.state is LinkState.SUSPENDED else (
                Reason.SESSION_CLOSED if self.state in (LinkState.CLOSING, LinkState.CLOSED) else (
                    self.refusal.reason if self.refusal else Reason.NO_SESSION))
            handle._finish(Outcome.FAILED, reason, now, detail=f"link is {self.state.value}")
            return handle
        try:
            payload = spec.encode(msg)
        except EncodeError as exc:
            handle._finish(Outcome.REJECTED, Reason.OUT_OF_RANGE, now, detail=str(exc))
            return handle
        return self._send(handle, payload, now)

    def submit_payload(self, spec, payload: bytes, now: float) -> CommandHandle:
        """Send command `spec` with `payload` as given, unchecked, in sequence (a fuzzer's: host_tools/fuzz);
        its handle's message is None. Refused at once if `spec` is no command or the link is not up."""
        handle = CommandHandle(None, now, spec=spec)
        if spec.cls not in (MsgClass.COMMAND, MsgClass.URGENT) or spec.reply is None or self.state is not LinkState.UP:
            handle._finish(Outcome.FAILED, Reason.NO_SESSION, now, detail=f"{spec.name}: not a command, or link down")
            return handle
        return self._send(handle, payload, now)

    def _send(self, handle: CommandHandle, payload: bytes, now: float) -> CommandHandle:
        spec = handle.spec
        sender = self._commands if spec.cls == MsgClass.COMMAND else self._urgent
        sender.submit(spec.id, payload, handle)
        self._pump(now)
        return handle

    @property
    def outstanding(self) -> int:
        return self._commands.outstanding + self._urgent.outstanding

    def _pump(self, now: float) -> None:
        for sender, cls, prio in ((self._urgent, MsgClass.URGENT, PRIO_URGENT),
                                  (self._commands, MsgClass.COMMAND, PRIO_RELIABLE)):
            for item in sender.due(now):
                item.context.tries = item.tries
                self._queue(prio, cls, item.seq, item.msg_id, item.payload)
            if sender.suspended:
                self.state = LinkState.SUSPENDED
                self._fail_all(Reason.LINK_SUSPENDED, now, f"no answer after {self.config.retry_limit} sends")
                return

    def close(self, now: float, why: CloseWhy = CloseWhy.DONE) -> CommandHandle:
        """End the session cleanly: a Close after every command submitted before it (see the module's doc).
        Refused at once (its handle says why) if the link is not up."""
        handle = self.submit(SCHEMA["Close"].type(int(why)), now)
        if not handle.done:
            self._close = handle
            self.state = LinkState.CLOSING
        return handle

    def _check_closed(self, now: float) -> None:
        """CLOSING: done when the Close is answered and every event up to the session's last has come."""
        handle = self._close
        if handle is None or not handle.done:
            return
        if not handle.ok:
            if self.state is LinkState.CLOSING:        # refused: the session goes on (a retry limit suspends it)
                self.state = LinkState.UP
            return
        if seq_delta(self._events.last_in_order, handle.reply.last_event_seq) >= 0:
            self._closed(now)

    def _closed(self, now: float) -> None:
        self.closed = self._close.reply if self._close is not None and self._close.ok else None
        self.state = LinkState.CLOSED
        # no Ack of its own: every event up to the last was acknowledged as it came (`_event`), and a second Ack
        # would reach a controller that may have forgotten the session already and draw a Nak(NO_SESSION)
        self._fail_all(Reason.SESSION_CLOSED, now, "the session was closed")

    def abandon(self, now: float, detail: str) -> None:
        """The transport is gone: every outstanding command fails, and the link is suspended."""
        self.state = LinkState.SUSPENDED
        self._fail_all(Reason.LINK_SUSPENDED, now, detail)

    def _fail_all(self, reason: Reason, now: float, detail: str) -> None:
        for sender in (self._urgent, self._commands):
            for item in sender.take_failed():
                item.context._finish(Outcome.FAILED, reason, now, detail=detail)

    def _complete(self, item: Optional[Pending], frame: Frame, now: float) -> None:
        if item is None:
            return   # an answer to a retransmission that was already answered
        handle: CommandHandle = item.context
        try:
            reply = self.schema.decode(frame.msg_id, frame.payload)
        except ParseError as exc:
            handle._finish(Outcome.REJECTED, exc.reason, now, detail=f"unreadable reply: {exc.detail}")
            return
        result = reply[0] if reply.spec.fields and reply.spec.fields[0].name == "result" else Reason.OK
        expected = handle.spec.reply
        if reply.spec.name != expected and (reply.spec.name != "Result" or result == Reason.OK):
            # a command is answered by its own reply, or refused by a Result: anything else is the peer's error,
            # and taking it as the answer would hand the caller a message of the wrong shape
            handle._finish(Outcome.REJECTED, Reason.UNKNOWN_MESSAGE, now, reply,
                           detail=f"{reply.spec.name} in answer to {handle.spec.name}, which {expected} answers "
                                  f"(or a Result refusing it)")
            return
        if result == Reason.OK:
            handle._finish(Outcome.SUCCEEDED, Reason.OK, now, reply)
        else:
            reason = Reason(result) if result in Reason._value2member_map_ else Reason.UNKNOWN_MESSAGE
            handle._finish(Outcome.REJECTED, reason, now, reply)

    # ---- session frames ----
    def _handle(self, frame: Frame, spec, now: float) -> None:
        cls = frame.cls
        if cls == MsgClass.COMMAND:
            self._complete(self._commands.answered(frame.seq, now), frame, now)
        elif cls == MsgClass.URGENT:
            self._complete(self._urgent.answered(frame.seq, now), frame, now)
        elif cls == MsgClass.TELEMETRY:
            self._telemetry(frame, spec, now)
        elif cls == MsgClass.EVENT:
            self._event(frame, spec, now)
        else:
            self._link(frame, spec, now)
        if self.state is LinkState.CLOSING:
            self._check_closed(now)

    def _link(self, frame: Frame, spec, now: float) -> None:
        if spec.name not in ("Heartbeat", "Nak"):
            return
        msg = self._decode(frame)
        if msg is None:
            return
        if spec.name == "Heartbeat":
            self.peer_stats, self.peer_stats_s = msg, now
            return
        self.stats.naks_rx += 1
        if msg.reason == Reason.SESSION_CLOSED and self.state is LinkState.CLOSING:
            self._closed(now)
            return
        if msg.reason == Reason.SEQUENCE_GAP:
            sender = self._commands if msg.refused_class == MsgClass.COMMAND else None
            if sender is not None:
                sender.go_back(msg.expected_seq, now)

    def _telemetry(self, frame: Frame, spec, now: float) -> None:
        if self._telemetry_expected is not None:
            lost = (frame.seq - self._telemetry_expected) & 0xFFFF
            if lost < 0x8000:
                self.stats.telemetry_lost += lost
        self._telemetry_expected = (frame.seq + 1) & 0xFFFF
        msg = self._decode(frame)
        if msg is None:
            return
        self.last_telemetry = msg
        self.on_telemetry(msg, now)

    def _event(self, frame: Frame, spec, now: float) -> None:
        verdict = self._events.classify(frame.seq)
        if verdict is Verdict.GAP:
            if self._events.should_nak_gap():
                self._refuse(frame, Reason.SEQUENCE_GAP, now, expected=self._events.expected)
            return
        if verdict is Verdict.NEW:
            self._events.accept(frame.seq, None)
            earlier = self._earlier_events > 0 and spec.name != "EventsCarriedOver"
            self._earlier_events -= earlier
            msg = self._decode(frame)
            if msg is not None:
                if spec.name == "EventsCarriedOver":
                    self._earlier_events = msg.count
                self.event_from_earlier_session = earlier
                try:
                    self.on_event(msg, now)
                finally:
                    self.event_from_earlier_session = False
        self.send_message(SCHEMA["Ack"].type(), PRIO_RELIABLE)

    def _ack_value(self) -> int:
        return self._events.last_in_order

    # ---- timers ----
    def poll(self, now: float) -> None:
        super().poll(now)
        if self.state is LinkState.CONNECTING and self._hello_due_s is not None and now >= self._hello_due_s:
            if self._hello_tries >= self.config.hello_tries:
                self.state = LinkState.SUSPENDED
                self.refusal = Refusal(Reason.LINK_SUSPENDED, f"no answer to {self._hello_tries} Hello frames")
                self._hello_due_s = None
            else:
                self._send_hello(now)
        if self.state in (LinkState.UP, LinkState.CLOSING) and not (self._urgent.idle and self._commands.idle):
            self._pump(now)
        if self.state is LinkState.CLOSING:
            self._check_closed(now)
        self.stats.retransmits = self._retransmits_before + self._commands.retransmits + self._urgent.retransmits
        if self._commands.rtt.srtt_s is not None:
            self.stats.srtt_us = int(self._commands.rtt.srtt_s * 1e6)

    def next_timer_s(self) -> float:
        """`LinkEndpoint.next_timer_s` with the Hello's retry and the commands' timers."""
        timer = super().next_timer_s()
        if self.state is LinkState.CONNECTING and self._hello_due_s is not None:
            timer = min(timer, self._hello_due_s)
        if self.state in (LinkState.UP, LinkState.CLOSING):
            timer = min(timer, self._urgent.next_due_s(), self._commands.next_due_s())
        return timer

    @property
    def srtt_s(self) -> Optional[float]:
        return self._commands.rtt.srtt_s
