"""The checks of `aspod conform`: each a small function named with the rule it tests and the section of
docs/protocol.md that states it.

A check gets the `Context` (the probe on the line, the options, what the controller said of itself) and returns
a note on success, or raises `Fail(expected, seen)` or `Skip(why)`. Every check leaves a session up and the
controller as it found it where it can (an EStop is followed by a Reset, a telemetry rate set back, a parameter
restored). No check sends a command that drives an output unless the check is marked `motion` and the suite was
given --allow-motion: the suite is safe on real hardware.

Time is judged on the controller's own progress: its uptime in Pong, Status, events and telemetry, and the order
of its answers (a frame that is not answered before the answer to a later one never will be). The bounds on the
probe's clock (`Context.bound_s`) only end a hang.
"""
from __future__ import annotations

import random
import struct
from dataclasses import dataclass, field
from typing import Callable, Optional

from protocol import auth
from protocol.framing import COUNTER_MAX, FLAG_AUTH, TAG_SIZE, decode_frame
from protocol.host_link import CommandHandle
from protocol.link import NAK_TAG_BYTES, LinkConfig, LinkState
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.reasons import Reason
from protocol.reliable import REPLY_CACHE_SIZE
from protocol.schema import Message, MsgClass
from protocol.states import ControllerState, Fault

from host_tools.conform.probe import Probe, Seen

# The sections of docs/protocol.md, as its headings say them (tests/test_conform.py checks they are there).
FRAMING = "Framing"
SESSIONS = "Sessions and authentication"
CLOSING = "Closing a session"
CLASSES = "Classes and delivery"
REFUSALS = "Refusals, sequence numbers and limits, exactly"
CLIENT = "What a client needs besides the tables"
MESSAGES = "Messages"
SECTIONS = (FRAMING, SESSIONS, CLOSING, CLASSES, REFUSALS, CLIENT, MESSAGES)

MUST, SHOULD = "MUST", "SHOULD"
REPLY_BOUND_S = 10.0          # an answer not here in this long will not come (a retry limit ends sooner)
RATE_TOLERANCE = 0.2          # telemetry at a set rate: within 20 %
RATE_SPAN_MS = 3000           # measured over this much of the controller's uptime
GARBAGE_FRAMES = 40          # unsigned frames sent at once
NAK_RATE_PER_S = int(LinkConfig.nak_rate_per_s)     # answers to unsigned or malformed frames a second (protocol.md)
TELEMETRY_RATES_HZ = (5, 2, 1)  # the telemetry rate tried: the first the controller takes
LOSS_SLACK_S = 0.5            # the link-loss failsafe: within the link timeout plus 20 % and this


class Fail(Exception):
    """The rule was broken: what the rule expects and what came."""

    def __init__(self, expected: str, seen: str) -> None:
        super().__init__(f"expected {expected}; saw {seen}")
        self.expected, self.seen = expected, seen


class Skip(Exception):
    """The check could not run here (the reason says why); nothing was judged."""


@dataclass
class Options:
    allow_motion: bool = False
    skip_slow: bool = False


@dataclass
class Context:
    probe: Probe
    options: Options = field(default_factory=Options)
    bound_s: float = REPLY_BOUND_S

    @property
    def info(self) -> Message:
        return self.probe.link.controller_info

    @property
    def link_timeout_s(self) -> float:
        return self.info.link_timeout_ms / 1000.0

    def session(self, new: bool = False) -> None:
        """A session up: a new one if `new`, or if the last is gone (closed, suspended, refused)."""
        if self.probe.up and not new:
            return
        if not self.probe.connect():
            link = self.probe.link
            why = link.refusal.detail if link.refusal else link.handshake_seen.why_not_up(
                link.hellos_sent, link.stats.auth_errors, link.stats.bytes_rx)
            raise Fail("a session (Hello, HelloCookie, Hello with the cookie, HelloReply OK)",
                       f"no session: {why}")

    def call(self, msg: Message, ok: bool = True) -> CommandHandle:
        handle = self.probe.call(msg, self.bound_s)
        if not handle.done:
            raise Fail(f"an answer to {msg.spec.name}", f"none in {self.bound_s:g} s")
        if ok and not handle.ok:
            raise Fail(f"{msg.spec.name} answered OK", handle.describe())
        return handle

    def status(self) -> Message:
        return self.call(SCHEMA["GetStatus"].type()).reply

    def ping(self, token: int) -> Message:
        pong = self.call(SCHEMA["Ping"].type(token)).reply
        if pong.token != token:
            raise Fail(f"Pong with the Ping's token {token:#x}", f"token {pong.token:#x}")
        return pong

    def answer(self, mark: int, what: str, predicate: Callable[[Seen], bool]) -> Seen:
        seen = self.probe.answer(mark, predicate, self.bound_s)
        if seen is None:
            raise Fail(what, f"none in {self.bound_s:g} s ({self.heard(mark)})")
        return seen

    def heard(self, mark: int) -> str:
        """What came since `mark`: how many frames, and the last few that are not heartbeats or telemetry."""
        frames = self.probe.seen[mark:]
        told = [s for s in frames if s.frame is None or not (s.name == "Heartbeat" or s.frame.cls == MsgClass.TELEMETRY)]
        shown = ", ".join(s.describe() for s in told[-6:])
        return f"{len(frames)} frame(s) came{', the last besides heartbeats and telemetry: ' + shown if shown else ''}"

    def hand_answer(self, wire: bytes, seq: int, what: str, cls: int = MsgClass.COMMAND) -> Seen:
        """Send a command frame made by hand and wait for the frame answering it (class `cls`, number `seq`)."""
        mark = len(self.probe.seen)
        self.probe.write(wire)
        return self.answer(mark, what, lambda s: s.frame.cls == cls and s.frame.seq == seq and s.key == "session")

    def executed(self) -> int:
        return self.status().commands_executed

    def expect_no_nak(self, mark: int, expected: str) -> None:
        naks = self.probe.since(mark, MsgClass.LINK, "Nak")
        expect(not naks, expected, nak_fields(naks[0]) if naks else "")

    def expect_executed(self, before: int, n: int, what: str) -> None:
        """`commands_executed` in Status is `n` above `before`: the commands `what` names, each once."""
        after = self.executed()
        expect(after - before == n, f"commands_executed up by {n} ({what})", f"up by {after - before}")


@dataclass(frozen=True)
class Check:
    name: str
    section: str
    what: str
    run: Callable[[Context], Optional[str]]
    level: str = MUST
    slow: bool = False
    motion: bool = False

    @property
    def cites(self) -> str:
        return f"protocol.md §{self.section}"


CHECKS: list[Check] = []


def check(name: str, section: str, what: str, **kw):
    def register(run: Callable[[Context], Optional[str]]) -> Callable[[Context], Optional[str]]:
        CHECKS.append(Check(name, section, what, run, **kw))
        return run
    return register


def expect(ok: bool, expected: str, seen: str) -> None:
    if not ok:
        raise Fail(expected, seen)


def tag_of(wire: bytes) -> bytes:
    return decode_frame(wire[1:-1]).tag


def nak_fields(seen: Seen) -> str:
    m = seen.msg
    return (f"Nak({_reason(m.reason)}, class {m.refused_class}, seq {m.refused_seq}, msg {m.refused_msg:#06x}, "
            f"expected {m.expected_seq}, tag {m.refused_tag.hex()}) under the {seen.key or 'no known'} key")


def _reason(code: int) -> str:
    return Reason(code).name if code in Reason._value2member_map_ else str(code)


def pong_for(ctx: Context, token: int, seq: Optional[int] = None) -> tuple[bytes, int, Seen]:
    """A Ping made by hand (numbered `seq`, default the next) and the frame answering it."""
    wire = ctx.probe.command(SCHEMA["Ping"].type(token), seq)
    seq = decode_frame(wire[1:-1]).seq
    return wire, seq, ctx.hand_answer(wire, seq, f"an answer to the Ping numbered {seq}")


def expect_pong(seen: Seen, token: int, why: str) -> None:
    expect(seen.name == "Pong" and seen.msg.token == token, f"Pong({token:#x}) {why}",
           seen.describe() + (f" token {seen.msg.token:#x}" if seen.name == "Pong" else ""))


# ---- sessions ----------------------------------------------------------------------------------------------

@check("handshake", SESSIONS, "Hello, HelloCookie, Hello with the cookie, HelloReply OK with the controller's hash, "
       "version, timeouts and identity; the first frame under the session key adopts the session")
def handshake(ctx: Context) -> str:
    p = ctx.probe
    ctx.session(new=True)
    cookies = [s for s in p.seen if s.name == "HelloCookie" and s.key == "handshake"]
    expect(bool(cookies), "a HelloCookie signed with the handshake key before the HelloReply", "none")
    info = ctx.info
    expect(info.protocol_version == PROTOCOL_VERSION and info.schema_hash == SCHEMA.hash,
           f"HelloReply naming protocol v{PROTOCOL_VERSION} and schema {SCHEMA.hash:016x}",
           f"v{info.protocol_version}, schema {info.schema_hash:016x}")
    expect(0 < info.heartbeat_ms < info.link_timeout_ms, "0 < heartbeat_ms < link_timeout_ms",
           f"heartbeat_ms {info.heartbeat_ms}, link_timeout_ms {info.link_timeout_ms}")
    ctx.ping(0x600D)
    return (f"link timeout {info.link_timeout_ms} ms, heartbeat {info.heartbeat_ms} ms, controller id "
            f"{info.controller_id.hex()}")


def _refused_hello(ctx: Context, **hello) -> Message:
    """A Hello made by hand, with its cookie, and the HelloReply to it."""
    p = ctx.probe
    nonce = auth.new_nonce()
    mark = len(p.seen)
    p.write(p.hello(nonce, **hello))
    cookie = ctx.answer(mark, "a HelloCookie for the Hello's nonce, under the handshake key",
                        lambda s: s.name == "HelloCookie" and s.key == "handshake" and s.msg.host_nonce == nonce)
    mark = len(p.seen)
    p.write(p.hello(nonce, cookie.msg.cookie, counter=2, **hello))
    return ctx.answer(mark, "a HelloReply to the Hello with its cookie, under the handshake key",
                      lambda s: s.name == "HelloReply" and s.key == "handshake" and s.msg.host_nonce == nonce).msg


@check("hello-schema-mismatch", SESSIONS, "a Hello with another schema hash is refused SCHEMA_MISMATCH by name, "
       "with the controller's hash and version; the live session goes on")
def hello_schema_mismatch(ctx: Context) -> str:
    ctx.session()
    other = SCHEMA.hash ^ 0x1
    reply = _refused_hello(ctx, schema_hash=other)
    expect(reply.result == Reason.SCHEMA_MISMATCH and reply.schema_hash == SCHEMA.hash
           and reply.protocol_version == PROTOCOL_VERSION,
           f"HelloReply(SCHEMA_MISMATCH) with the controller's hash {SCHEMA.hash:016x} and v{PROTOCOL_VERSION}",
           f"HelloReply({_reason(reply.result)}) hash {reply.schema_hash:016x} v{reply.protocol_version}")
    ctx.ping(0x5C4E)
    return "refused by name; the session went on"


@check("hello-version-mismatch", SESSIONS, "a Hello speaking another protocol version is refused "
       "UNSUPPORTED_VERSION, with the controller's version; the live session goes on")
def hello_version_mismatch(ctx: Context) -> str:
    ctx.session()
    reply = _refused_hello(ctx, version=PROTOCOL_VERSION + 1)
    expect(reply.result == Reason.UNSUPPORTED_VERSION and reply.protocol_version == PROTOCOL_VERSION,
           f"HelloReply(UNSUPPORTED_VERSION) naming the controller's v{PROTOCOL_VERSION}",
           f"HelloReply({_reason(reply.result)}) v{reply.protocol_version}")
    ctx.ping(0x7E55)
    return "refused by name; the session went on"


@check("hello-wrong-key", SESSIONS, "a Hello signed with another key gets no HelloCookie and no HelloReply (the MAC "
       "is checked first); the live session goes on")
def hello_wrong_key(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    wrong = auth.handshake_keys(bytes(reversed(p.psk)) + b"not the key", is_controller=False).tx
    bad, good = auth.new_nonce(), auth.new_nonce()
    mark = len(p.seen)
    p.write(p.hello(bad, key=wrong))
    p.write(p.hello(good))              # answered after the bad one would have been: the bad one's answer, if any,
    ctx.answer(mark, "a HelloCookie for a good Hello sent after it",  # comes first
               lambda s: s.name == "HelloCookie" and s.msg.host_nonce == good)
    ctx.ping(0x3E7)
    answered = [s for s in p.seen[mark:] if s.name in ("HelloCookie", "HelloReply") and s.msg.host_nonce == bad]
    expect(not answered, "no answer to the Hello signed with another key", answered[0].describe() if answered else "")
    naks = [s for s in p.seen[mark:] if s.name == "Nak" and s.msg.reason != Reason.BAD_MAC]
    expect(not naks, "no answer, or Nak(BAD_MAC)", nak_fields(naks[0]) if naks else "")
    return "no answer; the session went on"


# ---- framing -----------------------------------------------------------------------------------------------

def _answer_before_next(ctx: Context, data: bytes, what: str) -> Seen:
    """Write `data`, which ends in a command made by hand, then the next command (a Ping): the controller takes
    frames in order, so the answer to the first comes before the second's answer, or before the second's
    Nak(SEQUENCE_GAP) if the first was lost. That answer, or Fail saying what came instead."""
    p = ctx.probe
    seq = decode_frame(data[data.rindex(0, 0, len(data) - 1) + 1:-1]).seq
    mark = len(p.seen)
    p.write(data)
    after = p.command(SCHEMA["Ping"].type(0xAF7E))
    following = decode_frame(after[1:-1]).seq
    p.write(after)
    ctx.answer(mark, f"an answer to the command numbered {following}, sent after it, or a NAK of it",
               lambda s: s.key == "session" and ((s.frame.cls == MsgClass.COMMAND and s.frame.seq == following)
                                                 or (s.name == "Nak" and s.msg.refused_seq == following)))
    answers = [s for s in p.since(mark, MsgClass.COMMAND) if s.frame.seq == seq and s.key == "session"]
    expect(bool(answers), what, f"no answer to it before the next command's answer ({ctx.heard(mark)})")
    return answers[0]


@check("framing-resync-garbage", FRAMING, "after garbage (random bytes with and without 0x00, a run longer than any "
       "frame) the next good frame is answered, sent in the same write")
def framing_resync_garbage(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    rng = random.Random(37)
    garbage = [("random bytes without a delimiter", bytes(rng.randrange(1, 256) for _ in range(120))),
               ("random bytes with delimiters", bytes(rng.choice([0, rng.randrange(1, 256)]) for _ in range(200))),
               ("a run of 700 bytes without a delimiter (longer than any frame)", b"\x55" * 700)]
    for n, (what, junk) in enumerate(garbage):
        token = 0x6A00 + n
        wire = p.command(SCHEMA["Ping"].type(token))
        seen = _answer_before_next(ctx, junk + wire, f"the Ping sent right after {what} answered")
        expect_pong(seen, token, f"after {what}")
    ctx.ping(0x6AFF)
    return f"{len(garbage)} kinds of garbage"


@check("framing-resync-torn", FRAMING, "a frame cut short (its first half, then the next frame) costs only itself: "
       "the next good frame is answered, and the torn one is not executed")
def framing_resync_torn(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    seq = p.take_command_seq()
    torn = p.command(SCHEMA["Ping"].type(0x70A1), seq)
    good = p.command(SCHEMA["Ping"].type(0x70A2), seq)
    seen = _answer_before_next(ctx, torn[:len(torn) // 2] + good, "the frame after the torn one answered")
    expect_pong(seen, 0x70A2, "(the good frame's, not the torn one's)")
    ctx.ping(0x70FF)
    return "resynchronised at the next delimiter"


@check("framing-bad-crc", FRAMING, "a frame whose CRC fails is never answered nor executed; the good frame sent "
       "after it with the same number is")
def framing_bad_crc(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    seq = p.take_command_seq()
    bad = bytearray(p.command(SCHEMA["Ping"].type(0xBAD0), seq))
    bad[len(bad) // 2] ^= 0x01 if bad[len(bad) // 2] not in (0x01,) else 0x02   # never a 0x00: still one segment
    good = p.command(SCHEMA["Ping"].type(0xBAD1), seq)
    mark = len(p.seen)
    seen = _answer_before_next(ctx, bytes(bad) + good, "the good frame after it answered")
    expect_pong(seen, 0xBAD1, "(the good frame's: the corrupted one never ran)")
    ctx.expect_no_nak(mark, "no answer to a frame that fails its CRC")
    return "dropped silently"


# ---- commands ----------------------------------------------------------------------------------------------

@check("commands-in-order", CLASSES, "a window of 8 commands sent at once: each executed once, in order, answered "
       "with its own sequence number and reply")
def commands_in_order(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    before = ctx.executed()
    first = p.next_command_seq
    mark = len(p.seen)
    tokens = [0xC0DE0000 + n for n in range(p.link.config.window)]
    handles = [p.link.submit(SCHEMA["Ping"].type(t), p.now()) for t in tokens]
    p.pump()
    p.until(lambda: all(h.done for h in handles), ctx.bound_s)
    for t, h in zip(tokens, handles):
        expect(h.ok and h.reply.token == t, f"Pong({t:#x})", h.describe() + (
            f" token {h.reply.token:#x}" if h.ok else ""))
    answers = [s.frame.seq for s in p.since(mark, MsgClass.COMMAND, "Pong")]
    wanted = [(first + n) & 0xFFFF for n in range(len(tokens))]
    expect(answers[:len(wanted)] == wanted, f"the answers numbered {wanted} in that order", f"{answers}")
    ctx.expect_executed(before, len(tokens) + 1, "the Pings and one GetStatus")
    return f"{len(tokens)} in flight, answered in order"


@check("commands-beyond-window", CLASSES, "twice the window of commands sent at once (a host outside rule 6): "
       "each executed once, in order, answered with its own number and reply; the window is the host's duty, "
       "never a reason to drop a command", level=SHOULD)
def commands_beyond_window(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    before = ctx.executed()
    ping = SCHEMA["Ping"]
    tokens = [0xB10C0000 + n for n in range(2 * p.link.config.window)]
    seqs = [p.take_command_seq() for _ in tokens]
    mark = len(p.seen)
    p.write(b"".join(p.command(ping.type(t), seq) for t, seq in zip(tokens, seqs)))
    ctx.answer(mark, f"an answer to the last, numbered {seqs[-1]}", lambda s: s.frame.cls == MsgClass.COMMAND
               and s.frame.seq == seqs[-1] and s.key == "session")
    answers = [s for s in p.since(mark, MsgClass.COMMAND) if s.key == "session"]
    expect([s.frame.seq for s in answers] == seqs, f"the answers numbered {seqs}, in order, once each",
           f"{[s.frame.seq for s in answers]}")
    for t, seen in zip(tokens, answers):
        expect_pong(seen, t, f"to the Ping numbered {seen.frame.seq}")
    ctx.expect_executed(before, len(tokens) + 1, "the Pings and one GetStatus")
    return f"{len(tokens)} at once, answered in order"


@check("duplicate-from-cache", CLASSES, "a command sent again with the same number (re-signed, a new counter) is "
       "answered from the reply cache, byte for byte the first reply, and never executed again")
def duplicate_from_cache(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    before = ctx.executed()
    _, seq, first = pong_for(ctx, 0xD0B1)
    expect_pong(first, 0xD0B1, "to the first send")
    again = p.command(SCHEMA["Ping"].type(0xD0B1), seq)
    second = ctx.hand_answer(again, seq, f"an answer to the resent Ping numbered {seq}")
    expect(second.name == "Pong" and second.frame.payload == first.frame.payload,
           f"the cached Pong (payload {first.frame.payload.hex()})",
           f"{second.describe()} payload {second.frame.payload.hex()}")
    ctx.expect_executed(before, 2, "the Ping once, one GetStatus")
    return "answered from the cache, executed once"


@check("replay-dropped", SESSIONS, "a frame sent again byte for byte (its counter used) is dropped before any "
       "state changes: no answer, no NAK, nothing executed")
def replay_dropped(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    wire, seq, first = pong_for(ctx, 0x4E91)
    before = ctx.executed()
    mark = len(p.seen)
    p.write(wire)
    _, later, _ = pong_for(ctx, 0x4E92)
    replies = [s for s in p.seen[mark:] if s.frame is not None and s.frame.seq == seq
               and s.frame.cls == MsgClass.COMMAND]
    expect(not replies, "no answer to the replayed frame", replies[0].describe() if replies else "")
    ctx.expect_no_nak(mark, "no NAK of a replayed counter (a duplicating line makes them routinely)")
    ctx.expect_executed(before, 2, "the next Ping, one GetStatus")
    return "dropped silently"


@check("forgery-refused", SESSIONS, "a frame with a bad MAC, or none, is refused before any state changes "
       "(Nak BAD_MAC / UNAUTHENTICATED); a forged huge counter does not block the genuine frames after it")
def forgery_refused(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    before = ctx.executed()
    seq = p.take_command_seq()
    ping = SCHEMA["Ping"]
    payload = ping.encode(ping.type(0xF0F0))
    wrong = bytes(b ^ 0x5A for b in p.link.session.keys.tx.key)
    cases = [("BAD_MAC", p.made(MsgClass.COMMAND, seq, ping.id, payload, key=wrong, counter=COUNTER_MAX)),
             ("UNAUTHENTICATED", p.made(MsgClass.COMMAND, seq, ping.id, payload, flags=0))]
    for reason, wire in cases:
        mark = len(p.seen)
        p.write(wire)
        nak = ctx.answer(mark, f"Nak({reason})", lambda s: s.name == "Nak" or (
            s.frame.cls == MsgClass.COMMAND and s.frame.seq == seq))
        expect(nak.name == "Nak" and nak.msg.reason == Reason[reason] and nak.key == "session",
               f"Nak({reason}) under the session key", nak_fields(nak) if nak.name == "Nak" else nak.describe())
        tag = tag_of(wire)[:NAK_TAG_BYTES] if reason == "BAD_MAC" else bytes(NAK_TAG_BYTES)
        expect(nak.msg.refused_tag == tag and nak.msg.refused_seq == seq and nak.msg.refused_msg == ping.id,
               f"the Nak echoing the refused frame (seq {seq}, msg {ping.id:#06x}, tag {tag.hex()})", nak_fields(nak))
    genuine = p.command(ping.type(0xF0F1), seq)       # a normal counter, far below the forged one
    answer = ctx.hand_answer(genuine, seq, f"an answer to the genuine Ping numbered {seq}")
    expect_pong(answer, 0xF0F1, "(the genuine frame's: the forged ones never ran)")
    ctx.expect_executed(before, 2, "the genuine Ping, one GetStatus")
    return "refused, and the counter not committed"


@check("garbage-bounded", CLASSES, f"{GARBAGE_FRAMES} unsigned frames at once get at most {NAK_RATE_PER_S} NAKs a "
       "second (a burst of as many), all UNAUTHENTICATED, and change nothing: garbage cannot make the controller "
       "flood the line, reset or stop")
def garbage_bounded(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    before = ctx.status()
    ping = SCHEMA["Ping"]
    payload = ping.encode(ping.type(0x6A6A))
    seq = p.next_command_seq
    mark = len(p.seen)
    p.write(b"".join(p.made(MsgClass.COMMAND, seq, ping.id, payload, flags=0) for _ in range(GARBAGE_FRAMES)))
    pong = ctx.ping(0x6A6B)                  # the NAKs the burst gets come before this answer
    naks = p.since(mark, MsgClass.LINK, "Nak")
    elapsed_s = max(0, pong.uptime_ms - before.uptime_ms) / 1000.0
    most = int(NAK_RATE_PER_S * (1 + elapsed_s)) + 1
    expect(len(naks) <= most, f"at most {most} NAKs ({NAK_RATE_PER_S} a second and a burst of as many, over "
           f"{elapsed_s:.3f} s of its uptime)", f"{len(naks)}")
    wrong = [s for s in naks if s.msg.reason != Reason.UNAUTHENTICATED or s.key != "session"]
    expect(not wrong, "Nak(UNAUTHENTICATED) under the session key", nak_fields(wrong[0]) if wrong else "")
    after = ctx.status()
    expect(after.state == before.state and after.uptime_ms > before.uptime_ms
           and after.commands_executed - before.commands_executed == 2,
           f"the controller as it was ({ControllerState(before.state).name}, its uptime going on, 2 commands "
           f"executed: the Ping and a GetStatus)",
           f"{ControllerState(after.state).name}, uptime {before.uptime_ms} -> {after.uptime_ms} ms, "
           f"{after.commands_executed - before.commands_executed} executed")
    return f"{len(naks)} NAKs for {GARBAGE_FRAMES} frames"


@check("nak-echo", REFUSALS, "each refusal of an authenticated frame is a Nak under the session key naming the reason "
       "and echoing the refused frame's class, number, message and tag; SEQUENCE_GAP says where to resume, once "
       "per expected number; a NAK uses up no number")
def nak_echo(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    before = ctx.executed()
    seq = p.next_command_seq
    ping, pong = SCHEMA["Ping"], SCHEMA["Pong"]
    token = ping.encode(ping.type(0x0ECC))
    cases = [(Reason.UNKNOWN_MESSAGE, p.made(MsgClass.COMMAND, seq, 0x0777, token)),
             (Reason.WRONG_DIRECTION, p.made(MsgClass.COMMAND, seq, pong.id, pong.encode(pong.type(0, 1, 2)))),
             (Reason.SEQUENCE_GAP, p.made(MsgClass.COMMAND, (seq + 3) & 0xFFFF, ping.id, token))]
    for reason, wire in cases:
        frame = decode_frame(wire[1:-1])
        mark = len(p.seen)
        p.write(wire)
        nak = ctx.answer(mark, f"Nak({reason.name})", lambda s: s.name == "Nak")
        m = nak.msg
        expect(m.reason == reason and nak.key == "session", f"Nak({reason.name}) under the session key",
               nak_fields(nak))
        expect(nak.frame.cls == MsgClass.LINK and nak.frame.seq == 0, "the Nak in class LINK, seq 0",
               f"class {nak.frame.cls}, seq {nak.frame.seq}")
        expect((m.refused_class, m.refused_seq, m.refused_msg, m.refused_tag)
               == (frame.cls, frame.seq, frame.msg_id, frame.tag[:NAK_TAG_BYTES]),
               f"the echo: class {frame.cls}, seq {frame.seq}, msg {frame.msg_id:#06x}, "
               f"tag {frame.tag[:NAK_TAG_BYTES].hex()}", nak_fields(nak))
        if reason is Reason.SEQUENCE_GAP:
            expect(m.expected_seq == seq, f"expected_seq {seq} (where to resume)", nak_fields(nak))
    mark = len(p.seen)
    p.write(p.made(MsgClass.COMMAND, (seq + 4) & 0xFFFF, ping.id, token))     # the same gap: not NAKed again
    _, got, answer = pong_for(ctx, 0x0ECD)
    expect(got == seq, f"the next command numbered {seq} (no NAK uses a number)", f"numbered {got}")
    expect_pong(answer, 0x0ECD, f"to the command numbered {seq}")
    again = [s for s in p.since(mark, MsgClass.LINK, "Nak") if s.msg.reason == Reason.SEQUENCE_GAP]
    expect(not again, "one SEQUENCE_GAP NAK per expected number", nak_fields(again[0]) if again else "")
    ctx.expect_executed(before, 2, "one Ping, one GetStatus")
    return "UNKNOWN_MESSAGE, WRONG_DIRECTION, SEQUENCE_GAP"


@check("reply-cache-depth", REFUSALS, f"a duplicate among the last {REPLY_CACHE_SIZE} numbers is answered from the "
       f"cache; an older one gets Nak(REPLAY, expected_seq) and is never executed")
def reply_cache_depth(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    _, first, answer = pong_for(ctx, 0xCAC0)
    window = p.link.config.window
    while (p.next_command_seq - first) & 0xFFFF < REPLY_CACHE_SIZE:
        n = min(window, REPLY_CACHE_SIZE - ((p.next_command_seq - first) & 0xFFFF))
        handles = [p.link.submit(SCHEMA["Ping"].type(k), p.now()) for k in range(n)]
        p.pump()
        p.until(lambda: all(h.done for h in handles), ctx.bound_s)
        expect(all(h.ok for h in handles), "every Ping answered", "; ".join(h.describe() for h in handles))
    oldest = ctx.hand_answer(p.command(SCHEMA["Ping"].type(0xCAC0), first), first,
                             f"the cached answer to the Ping numbered {first}, {REPLY_CACHE_SIZE} back")
    expect(oldest.name == "Pong" and oldest.frame.payload == answer.frame.payload,
           f"the cached Pong of number {first}", oldest.describe())
    ctx.ping(0xCAC1)                                        # now `first` is 65 back
    before = ctx.executed()
    expected = p.next_command_seq
    mark = len(p.seen)
    p.write(p.command(SCHEMA["Ping"].type(0xCAC0), first))
    nak = ctx.answer(mark, "Nak(REPLAY)", lambda s: s.name == "Nak" or (
        s.frame.cls == MsgClass.COMMAND and s.frame.seq == first))
    expect(nak.name == "Nak" and nak.msg.reason == Reason.REPLAY and nak.msg.refused_seq == first
           and nak.msg.expected_seq == expected,
           f"Nak(REPLAY) of number {first}, expected_seq {expected}",
           nak_fields(nak) if nak.name == "Nak" else nak.describe())
    ctx.expect_executed(before, 1, "the GetStatus only: the old duplicate not executed")
    return f"cache of {REPLY_CACHE_SIZE}"


# ---- the urgent lane, events, the failsafe, the close ------------------------------------------------------

def _reset(ctx: Context) -> Message:
    """Reset, and the Status after it (not ESTOP, not FAULT)."""
    handle = ctx.call(SCHEMA["Reset"].type(), ok=False)
    status = ctx.status()
    expect(handle.ok and status.state not in (ControllerState.ESTOP, ControllerState.FAULT),
           "Reset OK, the controller out of its safe state",
           f"{handle.describe()}, state {ControllerState(status.state).name}")
    return status


@check("urgent-lane", CLASSES, "EStop and Stop travel in URGENT and run at once while the command stream waits on a "
       "gap; EStop latches the safe state (ESTOP, a StateChanged event) until Reset; a duplicate urgent request "
       "is answered from the cache")
def urgent_lane(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    expect(SCHEMA["EStop"].cls == MsgClass.URGENT and SCHEMA["Stop"].cls == MsgClass.URGENT,
           "EStop and Stop declared URGENT", "another class")
    seq = p.next_command_seq
    ping = SCHEMA["Ping"]
    mark = len(p.seen)
    p.write(p.made(MsgClass.COMMAND, (seq + 2) & 0xFFFF, ping.id, ping.encode(ping.type(1))))   # a gap: waiting
    ctx.answer(mark, "Nak(SEQUENCE_GAP)", lambda s: s.name == "Nak")
    mark = len(p.seen)
    estop = ctx.call(SCHEMA["EStop"].type(), ok=False)
    expect(estop.ok, "EStop answered OK while the command stream waits", estop.describe())
    answered = p.since(mark, MsgClass.URGENT)
    expect(bool(answered) and answered[0].name == "Result", "the EStop's Result in class URGENT",
           ", ".join(s.describe() for s in p.since(mark)))
    event = ctx.answer(mark, "StateChanged to ESTOP", lambda s: s.name == "StateChanged"
                       and s.msg.state == ControllerState.ESTOP)
    status = ctx.status()
    expect(status.state == ControllerState.ESTOP and status.faults & Fault.ESTOP, "Status: ESTOP, latched",
           f"state {ControllerState(status.state).name}, faults {status.faults:#x}")
    urgent = p.take_urgent_seq()
    stop = SCHEMA["Stop"]
    first = ctx.hand_answer(p.made(MsgClass.URGENT, urgent, stop.id, b""), urgent, "the Stop's Result",
                            MsgClass.URGENT)
    again = ctx.hand_answer(p.made(MsgClass.URGENT, urgent, stop.id, b""), urgent, "the resent Stop's Result",
                            MsgClass.URGENT)
    expect(first.name == "Result" and again.frame.payload == first.frame.payload,
           "the resent Stop answered from the cache", f"{first.describe()} then {again.describe()}")
    _reset(ctx)
    return f"EStop at uptime {event.msg.uptime_ms} ms; reset"


@check("link-loss-failsafe", CLASSES, "a host gone silent: the controller enters its safe state (LINK_LOST, "
       "latched) within its link timeout of the last valid frame, by its own uptime, and stops heartbeats and "
       "telemetry until the host returns", slow=True)
def link_loss_failsafe(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    timeout_s = ctx.link_timeout_s
    p.pump()
    handle = p.link.submit(SCHEMA["Ping"].type(0x1055), p.now())
    out = p.link.take_all(p.now())
    sent_s = p.now()
    p.write(out)                     # the Ping is the last frame the controller gets
    p.mute = True
    try:
        p.until(lambda: handle.done, ctx.bound_s)
        expect(handle.ok, "Pong to the last Ping", handle.describe())
        last_ms = handle.reply.uptime_ms
        most_s = timeout_s * (1 + RATE_TOLERANCE) + LOSS_SLACK_S
        mark = len(p.seen)

        def lost_or_late(s: Seen) -> bool:
            # the event, or a frame of the controller's past due on both clocks: its uptime (a loaded line or host
            # cannot make it look late) and this end's (a simulator catching up after a stall runs its uptime
            # faster than the wall: 16 s of it in 2 s beside three CPU hogs)
            return s.key == "session" and ((s.name == "StateChanged" and s.msg.reason == Reason.LINK_TIMEOUT) or (
                s.name in ("TelemetryStatus", "Heartbeat") and s.msg.uptime_ms > last_ms + 1000 * most_s + 200
                and s.time_s - sent_s > most_s))

        lost = p.answer(mark, lost_or_late, 2 * timeout_s + ctx.bound_s)
        beats = [s.msg for s in p.seen[mark:] if s.key == "session" and s.name == "Heartbeat"]
        heard = (f"; its heartbeats counted {beats[-1].frames_rx - beats[0].frames_rx} frame(s) from this end "
                 "meanwhile" if len(beats) >= 2 else "")
        writes = sum(1 for t, _ in p.sent if t > sent_s) - 1        # after the last Ping (none: it kept quiet)
        heard += f"; this end wrote {writes} time(s) after the last Ping" if writes else ""
        expect(lost is not None and lost.name == "StateChanged",
               f"StateChanged(LINK_TIMEOUT) within the link timeout ({timeout_s:g} s)",
               f"none by its uptime {lost.msg.uptime_ms} ms, {lost.msg.uptime_ms - last_ms} ms after the last frame "
               f"({lost.describe()}){heard}" if lost is not None else
               f"none in {2 * timeout_s + ctx.bound_s:g} s of silence ({ctx.heard(mark)})")
        # not before the timeout: judged on this end's clock, from before the last frame went to after the event
        # came (a controller whose own time runs slow cannot look early); not after the deadline: late only if late
        # by the controller's own uptime (a loaded line or host cannot make it look late) and by this end's clock
        # (a simulator catching up after a stall cannot either)
        waited_s, uptime_s = lost.time_s - sent_s, (lost.msg.uptime_ms - last_ms) / 1000.0
        silent_s = min(uptime_s, waited_s)                    # late only if late on both clocks
        expect(waited_s >= timeout_s - 0.01, f"the safe state no sooner than the link timeout ({timeout_s:g} s) "
               "after the last frame", f"the event here {waited_s:.3f} s after that frame was sent")
        expect(silent_s <= most_s, f"the safe state within {most_s:g} s of the last frame (the link timeout "
               f"{timeout_s:g} s, 20 % and {LOSS_SLACK_S:g} s, by the controller's uptime or this end's clock)",
               f"{silent_s:.3f} s")
        # then quiet: no telemetry made after the safe state (by its uptime), and no heartbeat once what was queued
        # on the line before it has drained (a heartbeat period: 9600 baud carries about 1 kB a second)
        quiet_from = len(p.seen)
        heartbeat_s = ctx.info.heartbeat_ms / 1000.0
        p.until(lambda: False, 3 * heartbeat_s)
        made_after = [s for s in p.seen[quiet_from:] if s.key == "session" and s.name == "TelemetryStatus"
                      and s.msg.uptime_ms > lost.msg.uptime_ms + 100]
        beats = [s for s in p.seen[quiet_from:] if s.key == "session" and s.name == "Heartbeat"
                 and s.time_s >= lost.time_s + heartbeat_s]
        expect(not made_after and not beats, "no heartbeats or telemetry while the host is gone",
               f"{len(made_after)} TelemetryStatus made after the safe state, {len(beats)} Heartbeat(s) from "
               f"{heartbeat_s:g} s to {3 * heartbeat_s:g} s after it")
    finally:
        p.mute = False
    status = ctx.status()
    expect(status.state == ControllerState.FAULT and status.faults & Fault.LINK_LOST,
           "Status: FAULT with LINK_LOST latched after the host returns",
           f"state {ControllerState(status.state).name}, faults {status.faults:#x}")
    _reset(ctx)
    return (f"safe state {waited_s:.3f} s after the last frame here, {uptime_s:.3f} s of its uptime (link timeout "
            f"{timeout_s:g} s); reset")


@check("events-redelivered", CLASSES, "events a session did not acknowledge come again in the next session, behind "
       "an EventsCarriedOver that counts them")
def events_redelivered(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    p.hold_events = True
    try:
        mark = len(p.seen)
        ctx.call(SCHEMA["EStop"].type())
        held = ctx.answer(mark, "StateChanged to ESTOP", lambda s: s.name == "StateChanged" and s.key == "session"
                          and s.msg.state == ControllerState.ESTOP)
    finally:
        p.hold_events = False
    first_event = len(p.events)
    ctx.session(new=True)            # the event never acknowledged
    p.until(lambda: any(m.spec.name == "StateChanged" and m.uptime_ms == held.msg.uptime_ms
                        for _, m, _ in p.events[first_event:]), ctx.bound_s)
    events = p.events[first_event:]
    names = [m.spec.name for _, m, _ in events]
    expect(bool(events) and names[0] == "EventsCarriedOver", "EventsCarriedOver first in the new session",
           f"events {names}")
    count = events[0][1].count
    carried = [m for _, m, _ in events[1:1 + count]]
    expect(any(m.spec.name == "StateChanged" and m.uptime_ms == held.msg.uptime_ms for m in carried),
           f"the unacknowledged StateChanged (uptime {held.msg.uptime_ms} ms) among the {count} carried over",
           f"events {names}")
    _reset(ctx)
    return f"{count} carried over; reset"


@check("event-window", CLASSES, "with its events unacknowledged, the controller keeps at most the event window (8) "
       "in flight; once they are acknowledged it sends the later ones, each delivered once, in order")
def event_window(ctx: Context) -> str:
    p = ctx.probe
    window = LinkConfig.window
    ctx.session(new=True)                         # event numbers from 0
    first_event = len(p.events)
    mark = len(p.seen)
    cycles = window // 2 + 1                      # an EStop and a Reset make two StateChanged each
    p.hold_events = True
    try:
        for _ in range(cycles):
            ctx.call(SCHEMA["EStop"].type())
            _reset(ctx)
        start_ms = ctx.ping(0xE1).uptime_ms       # half a second of its own time to send what it would
        while ctx.ping(0xE2).uptime_ms - start_ms < 500:
            pass
        held = sorted({s.frame.seq for s in p.since(mark, MsgClass.EVENT) if s.key == "session"})
    finally:
        p.hold_events = False
    expect(bool(held) and held[-1] - held[0] < window, f"event numbers within one window ({window}) while none "
           "was acknowledged", f"numbers {held}")
    made = 2 * cycles

    def changes() -> list[Message]:
        return [m for _, m, earlier in p.events[first_event:] if m.spec.name == "StateChanged" and not earlier]

    p.until(lambda: len(changes()) >= made, ctx.bound_s)
    changes = changes()
    states = [ControllerState(m.state).name for m in changes]
    # in order: their times never go back (two may share a millisecond: a fast controller answers an EStop and the
    # Reset after it within one; a duplicate would break the count or the ESTOP, IDLE alternation)
    expect(len(changes) == made and states[::2] == ["ESTOP"] * cycles and "ESTOP" not in states[1::2]
           and all(a.uptime_ms <= b.uptime_ms for a, b in zip(changes, changes[1:])),
           f"{made} StateChanged delivered once each, in order (ESTOP, out of it, ...)", f"{states}")
    return f"{len(held)} in flight unacknowledged; all {made} delivered in order once acknowledged"


@check("clean-close", CLOSING, "Close is answered Closed naming the session's last event, its SessionClosed; then "
       "no heartbeat or telemetry, and a command under the old key gets Nak(SESSION_CLOSED) or, the session "
       "forgotten, Nak(NO_SESSION) under the controller's NAK key, echoing its tag")
def clean_close(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    mark = len(p.seen)
    handle = p.link.close(p.now())
    p.pump()
    p.until(lambda: p.link.state is not LinkState.CLOSING, ctx.bound_s)
    expect(handle.ok and p.link.state is LinkState.CLOSED, "Closed OK, and every event to its last_event_seq",
           f"{handle.describe()}, link {p.link.state.value}")
    closed = handle.reply
    ended = [s for s in p.since(mark, MsgClass.EVENT, "SessionClosed") if s.key == "session"]
    expect(bool(ended) and ended[0].frame.seq == closed.last_event_seq,
           f"SessionClosed numbered last_event_seq {closed.last_event_seq}",
           ended[0].describe() if ended else "no SessionClosed")
    after = len(p.seen)
    p.until(lambda: False, 2 * ctx.info.heartbeat_ms / 1000.0 + 0.2)
    periodic = [s for s in p.seen[after:] if s.key == "session" and (
        s.name == "Heartbeat" or s.frame.cls == MsgClass.TELEMETRY)]
    expect(not periodic, "no heartbeat or telemetry after Closed", periodic[0].describe() if periodic else "")
    seq = p.next_command_seq
    wire = p.command(SCHEMA["Ping"].type(0xC105), seq)
    mark = len(p.seen)
    p.write(wire)
    nak = ctx.answer(mark, "Nak(SESSION_CLOSED) or Nak(NO_SESSION)", lambda s: s.name == "Nak"
                     or (s.frame.cls == MsgClass.COMMAND and s.frame.seq == seq))
    ok = nak.name == "Nak" and ((nak.msg.reason == Reason.SESSION_CLOSED and nak.key == "session")
                                or (nak.msg.reason == Reason.NO_SESSION and nak.key == "nak"))
    expect(ok, "Nak(SESSION_CLOSED) under the session key or Nak(NO_SESSION) under the NAK key",
           nak_fields(nak) if nak.name == "Nak" else nak.describe())
    expect(nak.msg.refused_tag == tag_of(wire)[:NAK_TAG_BYTES], f"the tag echoed ({tag_of(wire)[:8].hex()})",
           nak_fields(nak))
    ctx.session()
    return f"Closed, last event {closed.last_event_seq}; {Reason(nak.msg.reason).name} after"


@check("close-disables", CLOSING, "Close from ENABLED leaves the controller IDLE without a fault (needs Enable: "
       "--allow-motion)", motion=True)
def close_disables(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    ctx.call(SCHEMA["Enable"].type())
    handle = p.link.close(p.now())
    p.pump()
    p.until(lambda: p.link.state is not LinkState.CLOSING, ctx.bound_s)
    expect(handle.ok and handle.reply.state == ControllerState.IDLE and not handle.reply.faults,
           "Closed: IDLE, no fault", handle.describe() + (
               f" state {ControllerState(handle.reply.state).name}" if handle.ok else ""))
    ctx.session()
    return "IDLE after the close"


# ---- limits and rates --------------------------------------------------------------------------------------

@check("out-of-range-refused", REFUSALS, "a field outside its range (SetTelemetryRate above its range, a payload of "
       "the wrong length) is answered Result with the decoder's reason, and a ParamSet outside the parameter's "
       "range ParamValue(OUT_OF_RANGE): nothing changes")
def out_of_range_refused(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    rate = SCHEMA["SetTelemetryRate"]
    hi = rate.fields[0].range[1]
    rate_before = ctx.status().telemetry_hz
    handle = p.call_payload("SetTelemetryRate", struct.pack("<H", hi + 1), ctx.bound_s)
    expect(handle.done and handle.reason is Reason.OUT_OF_RANGE and handle.reply is not None
           and handle.reply.spec.name == "Result", f"Result(OUT_OF_RANGE) to SetTelemetryRate {hi + 1}",
           handle.describe())
    rate_after = ctx.status().telemetry_hz
    expect(rate_after == rate_before, f"the telemetry rate unchanged ({rate_before} Hz)", f"{rate_after} Hz")
    handle = p.call_payload("GetStatus", b"\x00", ctx.bound_s)
    expect(handle.done and handle.reason is Reason.BAD_LENGTH and handle.reply is not None
           and handle.reply.spec.name == "Result", "Result(BAD_LENGTH) to a GetStatus with a byte too many",
           handle.describe())
    listed = ctx.call(SCHEMA["ParamList"].type(0), ok=False)
    if not listed.ok:
        return f"telemetry rate and length refused; no parameter to try ({listed.describe()})"
    param = listed.reply
    above = param.max + max(1.0, abs(param.max))
    handle = ctx.call(SCHEMA["ParamSet"].type(param.name, above), ok=False)
    now = ctx.call(SCHEMA["ParamGet"].type(param.name)).reply
    if now.value != param.value:             # put it back before judging
        ctx.call(SCHEMA["ParamSet"].type(param.name, param.value), ok=False)
    expect(handle.reason is Reason.OUT_OF_RANGE and handle.reply is not None
           and handle.reply.spec.name == "ParamValue", f"ParamValue(OUT_OF_RANGE) to {param.name} = {above:g}",
           handle.describe())
    expect(now.value == param.value, f"{param.name} unchanged ({param.value:g})", f"{now.value:g}")
    return f"SetTelemetryRate {hi + 1}, a long GetStatus, {param.name} = {above:g}"


def _telemetry_uptimes(p: Probe, mark: int) -> list[int]:
    return [m.uptime_ms for _, m in p.telemetry[mark:] if m.spec.name == "TelemetryStatus"]


def _settable_rate(ctx: Context) -> int:
    """Set the first of TELEMETRY_RATES_HZ the controller takes (a slow line may refuse a rate it cannot carry,
    with a reason: protocol.md); Fail if it takes none."""
    refusals = []
    for rate in TELEMETRY_RATES_HZ:
        handle = ctx.call(SCHEMA["SetTelemetryRate"].type(rate), ok=False)
        if handle.ok:
            return rate
        expect(handle.reply is not None, f"SetTelemetryRate {rate} answered", handle.describe())
        refusals.append(f"{rate} Hz: {handle.describe()}")
    raise Fail(f"one of the rates {TELEMETRY_RATES_HZ} Hz taken", "; ".join(refusals))


@check("telemetry-rate", CLASSES, "SetTelemetryRate r: TelemetryStatus comes r times a second of the controller's "
       "uptime (within 20 %); 0 stops it", slow=True)
def telemetry_rate(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    before = ctx.status().telemetry_hz
    try:
        target = _settable_rate(ctx)
        start = ctx.ping(0x7E1E).uptime_ms          # telemetry made before this was at the old rate
        mark = len(p.telemetry)

        def fresh() -> list[int]:
            return [u for u in _telemetry_uptimes(p, mark) if u > start]

        p.until(lambda: len(fresh()) >= 2 and fresh()[-1] - fresh()[0] >= RATE_SPAN_MS,
                RATE_SPAN_MS / 1000.0 * 3 + ctx.bound_s)
        uptimes = fresh()
        expect(len(uptimes) >= 2, f"TelemetryStatus at {target} Hz", f"{len(uptimes)} frame(s)")
        span_s = (uptimes[-1] - uptimes[0]) / 1000.0
        rate = (len(uptimes) - 1) / span_s if span_s > 0 else float("inf")
        expect(abs(rate - target) <= RATE_TOLERANCE * target, f"{target} Hz within 20 %",
               f"{rate:.2f} Hz ({len(uptimes)} frames over {span_s:.2f} s of its uptime)")
        ctx.call(SCHEMA["SetTelemetryRate"].type(0))
        stopped = ctx.ping(0x7E10).uptime_ms
        mark = len(p.telemetry)
        while ctx.ping(0x7E11).uptime_ms - stopped < 1000:
            p.until(lambda: False, 0.1)
        late = [u for u in _telemetry_uptimes(p, mark) if u > stopped]
        expect(not late, "no TelemetryStatus after SetTelemetryRate 0", f"{len(late)} in 1 s of its uptime")
    finally:
        if p.up:
            ctx.call(SCHEMA["SetTelemetryRate"].type(before), ok=False)
    return f"{rate:.2f} Hz asked {target}; 0 stops it; set back to {before} Hz"


@check("heartbeat", CLASSES, "an idle controller sends a Heartbeat at its heartbeat period (HelloReply "
       "heartbeat_ms), by its own uptime", level=SHOULD, slow=True)
def heartbeat(ctx: Context) -> str:
    p = ctx.probe
    ctx.session()
    period_ms = ctx.info.heartbeat_ms
    mark = len(p.seen)

    def beats() -> list[int]:
        return [s.msg.uptime_ms for s in p.since(mark, MsgClass.LINK, "Heartbeat") if s.key == "session"]

    p.until(lambda: len(beats()) >= 4, 4 * period_ms / 1000.0 + ctx.bound_s)
    times = beats()
    expect(len(times) >= 4, f"a Heartbeat every {period_ms} ms", f"{len(times)} in {4 * period_ms} ms and more")
    gaps = [b - a for a, b in zip(times, times[1:])]
    expect(max(gaps) <= 1.5 * period_ms + 100, f"gaps of at most {1.5 * period_ms + 100:g} ms",
           f"gaps {gaps} ms")
    return f"gaps {gaps} ms"


def by_name() -> dict[str, Check]:
    return {c.name: c for c in CHECKS}


assert TAG_SIZE >= NAK_TAG_BYTES and FLAG_AUTH
