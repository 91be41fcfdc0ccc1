"""`aspod conform --host`: the other side. conform plays a controller (`PlayedController`), a host implementation
connects to it and does its work, and every frame each way is kept (`HostWatch`); when the host has gone, its frames
are judged against the same rules of docs/protocol.md as the controller's are (`HOST_CHECKS`).

The watch sees the host's bytes before the controller's link does, so it knows the keys the link knows at that
moment: the handshake key, the live session's and the pending ones' (a host's first frame under a new session key
is what adopts it). Each check reads the timeline and raises `Fail` or `Skip` as the controller's checks do.

Two things a well-behaved controller would not do are done once each, to see the host's answer to them: the reply to
the host's command 1 in its first session is dropped (the host must resend it, signed again, and take the cached
reply), and when that resend has been answered, two `Nak(NO_SESSION)` a recording or another controller could make
are sent (one under another controller's NAK key echoing a tag the host sent, one under this controller's NAK key
echoing a tag it never sent): the host must ignore both and keep its session.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Callable, Optional

from protocol import auth
from protocol.errors import ParseError
from protocol.framing import Frame, FrameReceiver, decode_frame, encode_frame
from protocol.link import HELLO_ID, NAK_ID, NAK_TAG_BYTES, LinkConfig
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.reliable import NOTHING_RECEIVED_ACK, seq_delta
from protocol.schema import Message, MsgClass
from timebase import Clock

from host_tools.conform.checks import CLASSES, CLIENT, CLOSING, SESSIONS, SHOULD, Check, Fail, Skip, expect
from host_tools.conform.controller import PlayedController
from host_tools.conform.runner import FAIL, PASS, SKIP, Result

EVENT_ACK_S = 1.0     # the controller's first retransmission timeout: an event not acknowledged by then goes again
SETTLE_S = 0.5        # after the host's session ends, its last frames are awaited this long
DROPPED_SEQ = 1       # the reply to the host's command of this number, in its first session, is dropped once
RESEND_SLACK_S = 0.5  # a resend is due within the longest retransmission timeout and this


@dataclass
class Seen:
    """A frame on the line: when, which way (`from_host`), the frame (None: it did not decode, `error` says why),
    the key it verified under (`handshake`, `session N` for the N-th session the host opened, None), its message."""

    time_s: float
    from_host: bool
    frame: Optional[Frame]
    error: Optional[ParseError] = None
    key: Optional[str] = None
    session: int = -1
    msg: Optional[Message] = None
    dropped: bool = False          # a frame conform made and never sent (the reply the host must ask for again)

    @property
    def name(self) -> str:
        return self.msg.spec.name if self.msg is not None else "?"


@dataclass
class HostWatch:
    played: PlayedController
    seen: list[Seen] = field(default_factory=list)
    sessions: dict[bytes, int] = field(default_factory=dict)       # host nonce -> session number
    dropped: Optional[Seen] = None          # the reply dropped on purpose
    forged_at: Optional[float] = None       # when the two NAKs the host must ignore went out
    _dropping: Optional[bytes] = None
    _rx: FrameReceiver = field(default_factory=FrameReceiver)

    def __post_init__(self) -> None:
        self.played.on_bytes_in = self.bytes_in
        self.played.on_frame_out = self.frame_out
        self.played.drop = lambda wire, now: wire is self._dropping

    def _session_keys(self) -> list[tuple[int, object, bytes]]:
        """(number, rx key, host nonce) of the live session and the pending ones."""
        link = self.played.link
        out = []
        live = link.session
        if live is not None:
            out.append((self._number(live.host_nonce), live.keys.rx, live.host_nonce))
        for nonce, pending in link._pending.items():
            out.append((self._number(nonce), pending.session.keys.rx, nonce))
        return out

    def _number(self, nonce: bytes) -> int:
        return self.sessions.setdefault(nonce, len(self.sessions))

    def bytes_in(self, data: bytes, now: float) -> None:
        for item in self._rx.feed(data):
            if isinstance(item, ParseError):
                self.seen.append(Seen(now, True, None, item))
                continue
            seen = Seen(now, True, item, msg=_decode(item))
            if item.msg_id == HELLO_ID and item.verify(self.played.link._handshake.rx):
                seen.key = "handshake"
            else:
                for number, key, _ in self._session_keys():
                    if item.verify(key):
                        seen.key, seen.session = f"session {number}", number
                        break
            self.seen.append(seen)

    def frame_out(self, wire: bytes, now: float) -> None:
        frame = decode_frame(wire[1:-1])
        seen = Seen(now, False, frame, msg=_decode(frame))
        live = self.played.link.session
        if live is not None and frame.verify(live.keys.tx):
            seen.session = self._number(live.host_nonce)
            seen.key = f"session {seen.session}"
        if seen.session == 0 and frame.cls == MsgClass.COMMAND and frame.seq == DROPPED_SEQ:
            if self.dropped is None:
                seen.dropped, self.dropped, self._dropping = True, seen, wire
            elif self.forged_at is None:
                self._forge_no_session(now)
        self.seen.append(seen)

    def _forge_no_session(self, now: float) -> None:
        """Two NO_SESSION NAKs the host must not believe: another controller's (its NAK key under another identity)
        echoing a tag the host sent, and this controller's echoing a tag the host never sent."""
        link = self.played.link
        sent = [s.frame.tag[:NAK_TAG_BYTES] for s in self.host(0)]
        unsent = os.urandom(NAK_TAG_BYTES)
        while unsent in sent:
            unsent = os.urandom(NAK_TAG_BYTES)
        other_id = bytes(b ^ 0xFF for b in link.controller_id)
        for key, tag in ((auth.nak_key(self.played.psk, other_id), sent[-1]),
                         (auth.nak_key(self.played.psk, link.controller_id), unsent)):
            nak = SCHEMA["Nak"].type(int(Reason.NO_SESSION), MsgClass.COMMAND, DROPPED_SEQ, 0, 0, tag)
            link._handshake_tx_counter += 1
            self.played.injected.append(encode_frame(MsgClass.LINK, 0, NOTHING_RECEIVED_ACK, NAK_ID,
                                                     SCHEMA["Nak"].encode(nak), key, link._handshake_tx_counter))
        self.forged_at = now

    # ---- views of the timeline ----
    def host(self, session: Optional[int] = None) -> list[Seen]:
        return [s for s in self.seen if s.from_host and (session is None or s.session == session)]

    def to_host(self, session: int) -> list[Seen]:
        return [s for s in self.seen if not s.from_host and s.session == session]

    @property
    def opened(self) -> list[int]:
        """The sessions the host adopted (sent a frame under their key), in order."""
        return sorted({s.session for s in self.seen if s.from_host and s.session >= 0})


def _decode(frame: Frame) -> Optional[Message]:
    try:
        return SCHEMA.decode(frame.msg_id, frame.payload)
    except ParseError:
        return None


HOST_CHECKS: list[Check] = []


def host_check(name: str, section: str, what: str, **kw):
    def register(run: Callable[[HostWatch], Optional[str]]):
        HOST_CHECKS.append(Check(name, section, what, run, **kw))
        return run
    return register


def _needs_session(watch: HostWatch) -> list[int]:
    if not watch.opened:
        raise Skip("the host never adopted a session")
    return watch.opened


@host_check("host-authenticates", SESSIONS, "every frame the host sends decodes and is signed: a Hello with the "
            "handshake key, everything else with its session's key")
def host_authenticates(watch: HostWatch) -> str:
    frames = watch.host()
    expect(bool(frames), "frames from a host", "none came")
    bad = [s for s in frames if s.key is None]
    what = [f"{s.error}" if s.frame is None else f"{s.name} (class {s.frame.cls}, seq {s.frame.seq}, "
            f"{'no MAC' if s.frame.counter is None else 'a MAC no key of this line verifies'})" for s in bad[:3]]
    expect(not bad, "every frame decoded and signed", f"{len(bad)} of {len(frames)} not: {'; '.join(what)}")
    return f"{len(frames)} frames"


@host_check("host-hello-cookie", SESSIONS, "the host's Hello carries a zero cookie first, and after a HelloCookie "
            "the same nonce at once with that cookie; it then adopts the session with a frame under its key")
def host_hello_cookie(watch: HostWatch) -> str:
    hellos = [s for s in watch.host() if s.name == "Hello" and s.key == "handshake"]
    expect(bool(hellos), "a Hello signed with the handshake key", "none")
    expect(hellos[0].msg.cookie == bytes(len(hellos[0].msg.cookie)), "a zero cookie in the first Hello",
           hellos[0].msg.cookie.hex())
    cookies = [n for n, s in enumerate(watch.seen) if not s.from_host and s.name == "HelloCookie"]
    for n in cookies:
        cookie = watch.seen[n]
        echo = next((s for s in watch.seen[n:] if s.from_host and s.name == "Hello" and s.key == "handshake"
                     and s.msg.host_nonce == cookie.msg.host_nonce), None)
        expect(echo is not None and echo.msg.cookie == cookie.msg.cookie,
               f"a Hello echoing the cookie {cookie.msg.cookie.hex()} for its nonce",
               "none" if echo is None else f"cookie {echo.msg.cookie.hex()}")
    _needs_session(watch)
    return f"{len(hellos)} Hello(s), {len(cookies)} cookie(s) echoed, {len(watch.opened)} session(s) adopted"


@host_check("host-counters-increase", CLIENT, "within a session the host's counters strictly increase: a resend is "
            "signed again with a new counter, never sent byte for byte")
def host_counters_increase(watch: HostWatch) -> str:
    for session in _needs_session(watch):
        counters = [s.frame.counter for s in watch.host(session)]
        back = [(a, b) for a, b in zip(counters, counters[1:]) if b <= a]
        expect(not back, f"increasing counters in session {session}",
               f"{len(back)} step(s) back or repeated, e.g. {back[0][0]} then {back[0][1]}" if back else "")
    return "increasing"


@host_check("host-commands-in-order", CLASSES, "the host numbers its commands 0, 1, 2, ... in each session; a resend "
            "keeps its number and its message; never more than 8 unanswered in flight")
def host_commands_in_order(watch: HostWatch) -> str:
    window = watch.played.link.config.window
    total = 0
    for session in _needs_session(watch):
        first: dict[int, tuple[int, bytes]] = {}
        highest = -1
        answered: set[int] = set()
        for s in [s for s in watch.seen if s.session == session]:       # in the order they crossed the line
            f = s.frame
            if f.cls != MsgClass.COMMAND:
                continue
            if not s.from_host:
                answered.add(f.seq)
                continue
            if f.seq in first:
                expect(first[f.seq] == (f.msg_id, f.payload), f"the resend of command {f.seq} as it was first sent",
                       f"msg {f.msg_id:#06x} payload {f.payload.hex()}, first {first[f.seq][0]:#06x} "
                       f"{first[f.seq][1].hex()}")
                continue
            expect(f.seq == highest + 1, f"command {highest + 1} next in session {session}", f"command {f.seq}")
            oldest = min((n for n in first if n not in answered), default=f.seq)
            expect(f.seq - oldest < window, f"at most {window} commands unanswered in flight",
                   f"command {f.seq} sent while {oldest} was unanswered")
            first[f.seq] = (f.msg_id, f.payload)
            highest = f.seq
            total += 1
    return f"{total} commands"


@host_check("host-resends", CLASSES, f"a command whose reply is lost (conform drops the reply to command {DROPPED_SEQ} "
            f"of the first session) is sent again with its number and message, signed again, within the longest "
            f"retransmission timeout and {RESEND_SLACK_S:g} s")
def host_resends(watch: HostWatch) -> str:
    _needs_session(watch)
    if watch.dropped is None:
        raise Skip(f"the host sent no command numbered {DROPPED_SEQ} in its first session (the reply dropped is its)")
    sends = [s for s in watch.host(0) if s.frame.cls == MsgClass.COMMAND and s.frame.seq == DROPPED_SEQ]
    first = sends[0]
    again = sends[1] if len(sends) > 1 else None     # a timer that fired before the reply was made counts too
    expect(again is not None, f"command {DROPPED_SEQ} ({first.name}) sent again after its reply was lost", "never")
    bound_s = watch.played.link.config.max_rto_s + RESEND_SLACK_S
    delay_s = again.time_s - first.time_s
    expect(delay_s <= bound_s, f"the resend within {bound_s:g} s of the first send", f"after {delay_s:.3f} s")
    expect(again.frame.counter > first.frame.counter and again.frame.tag != first.frame.tag,
           "the resend signed again under a new counter", f"counter {first.frame.counter} then {again.frame.counter}")
    return f"{first.name} resent {delay_s * 1000:.0f} ms after its first send"


@host_check("host-ignores-forged-no-session", SESSIONS, "a Nak(NO_SESSION) under another controller's NAK key, or "
            "echoing a tag the host never sent, is ignored: the host keeps its session and sends no new Hello")
def host_ignores_forged_no_session(watch: HostWatch) -> str:
    _needs_session(watch)
    forged_at = watch.forged_at
    if forged_at is None:
        raise Skip("they are sent once the host has resent a command (host-resends), which it did not")
    closed = min([s.time_s for s in watch.to_host(0) if s.name == "Closed"], default=float("inf"))
    until = min(closed, forged_at + watch.played.link.config.link_timeout_s)
    hello = next((s for s in watch.host() if s.name == "Hello" and forged_at <= s.time_s <= until), None)
    expect(hello is None, "no new Hello: the session kept",
           f"a Hello {hello.time_s - forged_at:.3f} s after them" if hello else "")
    later = [s for s in watch.host(0) if s.time_s > forged_at]
    if not later:
        raise Skip("the host sent nothing more in its session after them")
    return f"{len(later)} frames of its session after them"


@host_check("host-acks-events", CLASSES, f"the host acknowledges each event (the ack of any frame, an Ack if it has "
            f"nothing else) within {EVENT_ACK_S:g} s, before the controller would send it again")
def host_acks_events(watch: HostWatch) -> str:
    count, worst = 0, 0.0
    for session in _needs_session(watch):
        host = watch.host(session)
        for event in [s for s in watch.to_host(session) if s.frame.cls == MsgClass.EVENT]:
            acked = next((s for s in host if s.time_s >= event.time_s and s.frame.ack != NOTHING_RECEIVED_ACK
                          and seq_delta(s.frame.ack, event.frame.seq) >= 0), None)
            expect(acked is not None, f"an acknowledgement of event {event.frame.seq} ({event.name})", "none came")
            delay = acked.time_s - event.time_s
            expect(delay <= EVENT_ACK_S, f"event {event.frame.seq} ({event.name}) acknowledged within "
                   f"{EVENT_ACK_S:g} s", f"after {delay:.3f} s")
            count, worst = count + 1, max(worst, delay)
    if not count:
        raise Skip("no event in any session (a Close or an EStop makes one)")
    return f"{count} events, the slowest acknowledged in {worst * 1000:.0f} ms"


@host_check("host-keeps-link-alive", CLASSES, "while its session is up the host sends a frame at least every link "
            "timeout (its heartbeats), so the controller never latches LINK_LOST under a host that is there")
def host_keeps_link_alive(watch: HostWatch) -> str:
    timeout_s = watch.played.link.config.link_timeout_s
    worst = 0.0
    for session in _needs_session(watch):
        frames = watch.host(session)
        closed = next((s.time_s for s in watch.to_host(session) if s.name == "Closed"), None)
        times = [s.time_s for s in frames if closed is None or s.time_s <= closed]
        gaps = [b - a for a, b in zip(times, times[1:])]
        worst = max(gaps + [worst])
    expect(worst < timeout_s, f"no silence of the link timeout ({timeout_s:g} s)", f"{worst:.3f} s")
    return f"longest silence {worst:.3f} s"


@host_check("host-closes", CLOSING, "the host ends with Close, and acknowledges the events up to the Closed's "
            "last_event_seq before it leaves", level=SHOULD)
def host_closes(watch: HostWatch) -> str:
    session = _needs_session(watch)[-1]
    closed = next((s for s in watch.to_host(session) if s.name == "Closed"), None)
    if closed is None:
        lost = any(s.name == "StateChanged" and s.msg.reason == Reason.LINK_TIMEOUT for s in watch.to_host(session))
        raise Fail("Close, answered Closed", "the host went silent (LINK_LOST)" if lost else "no Close")
    last = closed.msg.last_event_seq
    acked = [s for s in watch.host(session) if s.time_s >= closed.time_s and s.frame.ack != NOTHING_RECEIVED_ACK
             and seq_delta(s.frame.ack, last) >= 0]
    expect(bool(acked), f"events acknowledged up to {last} after the Closed", "no such acknowledgement")
    return f"closed; events acknowledged to {last}"


def watch_host(port, psk: bytes, wait_s: float, config: Optional[LinkConfig] = None,
               clock: Optional[Clock] = None, stop: Callable[[], bool] = lambda: False) -> HostWatch:
    """Play a controller on `port` until the host is done: its session closed and forgotten, or its link lost
    (and 0.5 s more of its silence, for its last frames); or nothing from a host for `wait_s`; or `stop()`."""
    played = PlayedController(psk, config=config, clock=clock)
    watch = HostWatch(played)
    started = played.clock.now()

    def done() -> bool:
        host = [s.time_s for s in watch.seen if s.from_host]
        quiet_s = played.clock.now() - (host[-1] if host else started)
        link = played.link
        if watch.opened and (link.session is None or link.link_lost):
            return quiet_s >= SETTLE_S
        return stop() or quiet_s >= wait_s

    played.serve(port, done)
    return watch


def judge_host(watch: HostWatch, report: Callable[[Result], None] = lambda result: None) -> list[Result]:
    results = []
    for check in HOST_CHECKS:
        try:
            result = Result(check, PASS, check.run(watch) or "")
        except Fail as exc:
            result = Result(check, FAIL, expected=exc.expected, seen=exc.seen)
        except Skip as exc:
            result = Result(check, SKIP, str(exc))
        results.append(result)
        report(result)
    return results
