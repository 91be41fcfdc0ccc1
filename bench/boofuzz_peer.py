"""boofuzz as the peer of `aspod fuzz`: the same live target, the best grammar we could write for it by hand.

`run_boofuzz(tmp, duration_s, planted)` starts `aspod sim --tcp 0` (or, `planted`, the simulator of
`host_tools.fuzz.planted`, whose BoxDial handler raises IndexError at exactly 100 %), and runs boofuzz 0.4.2 against
it for `duration_s` or until the target dies: executions per second, and whether the planted bug was found, after how
many cases, by which case.

What boofuzz is given (the most a careful boofuzz user could give it):

- the pre-shared key. A pre-send hook (`_Monitor.pre_send`) does the Hello / HelloCookie / Hello / HelloReply
  handshake and derives the session keys with `protocol.auth.session_keys`, then pings once so that the controller
  adopts the session; a handshake not answered is tried again until the target has had `CONNECT_S` of its own time;
- a grammar written by hand from docs/protocol.md and protocol/messages.py (not generated from `SCHEMA`): per message a
  `Request` whose raw frame is boofuzz primitives (header bytes and words, a `Size` for the length byte, a 48-bit
  `BitField` for the counter, the payload's fields), the HMAC tag a `Checksum` with a callable algorithm over the signed
  block, the CRC-32 boofuzz's own `Checksum("crc32")`, and the COBS framing a block `encoder`;
- the session's state through `ProtocolSessionReference`s filled in by the edge callback before each case: the next
  counter, the next command sequence number (from the `ack` of the controller's last frame), the event ack;
- a health check in boofuzz's style, a `BaseMonitor` whose `post_send` says whether the target survived the case: the
  case was answered (a reply or a NAK), or else a signed Ping sent after it was, within `probe_wait_s` of the target's
  own time (host_tools/worlds/own_time.py: a busy machine that keeps it from its CPU is no crash); the process is
  running; the TCP line is open. A failure ends the run (the first crash is the figure wanted; the simulator is not restarted).

The header is fuzzed in one message (Ping) and held valid in the others, which fuzz their payloads: boofuzz
enumerates mutations message by message, field by field, in the order the grammar declares them (the messages in their
declared order, as docs/protocol.md lists them), so a field's place in that order decides when it is reached.
"""
from __future__ import annotations

import math
import os
import select
import socket
import struct
import sys
import tempfile
import zlib
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from boofuzz import (BitField, Block, Byte, Bytes, Checksum, DWord, ProtocolSessionReference, Request, Session, Size,
                     String, Target, TCPSocketConnection, Word)
from boofuzz.monitors import BaseMonitor
from cobs import cobs

from bench import retry_on_own_time
from host_tools.worlds.child import ASPOD, Child, ChildError
from protocol import auth
from protocol.errors import ParseError
from protocol.framing import FrameReceiver, MacKey
from protocol.messages import SCHEMA
from timebase import RealClock

REPO_ROOT = Path(__file__).resolve().parent.parent
PLANTED = (sys.executable, "-m", "host_tools.fuzz.planted")

# ---- the wire, written out by hand from docs/protocol.md ----
VERSION, FLAG_AUTH = 1, 0x10
LINK, COMMAND, URGENT, TELEMETRY, EVENT = range(5)          # the header's class byte
HELLO, HELLO_REPLY, HEARTBEAT, NAK, HELLO_COOKIE = 0x01, 0x02, 0x03, 0x05, 0x06
PING, PONG = 0x10, 0x81
NOTHING_ACKED = 0xFFFF
CONNECT_S = 10.0        # a session's handshake: of the target's own time (each try bounded on the wall clock)
HEADER = struct.Struct("<BBBHHHB")
HELLO_PAYLOAD = struct.Struct("<BQ16s8s")                     # protocol_version, schema_hash, host_nonce, cookie
HELLO_COOKIE_PAYLOAD = struct.Struct("<16s8s")                # host_nonce, cookie: echo it in a fresh Hello
HELLO_REPLY_PAYLOAD = struct.Struct("<BBQ16s16sII8s")        # result, version, hash, host and controller nonces, ...
STATUS_HEAD = struct.Struct("<BBIBIffI")                      # Status: result ... commands_executed


def f32_bits(x: float) -> int:
    return struct.unpack("<I", struct.pack("<f", x))[0]


def bits_f32(b: int) -> float:
    return struct.unpack("<f", struct.pack("<I", b & 0xFFFFFFFF))[0]


def _f32_step(x: float, up: bool) -> int:
    """The bits of the float32 next to `x` toward +inf (`up`) or -inf."""
    b = f32_bits(x)
    if x == 0:
        return 0x00000001 if up else 0x80000001
    toward_bigger_magnitude = up == (x > 0)
    return b + 1 if toward_bigger_magnitude else b - 1


F32_SPECIALS = (0.0, -0.0, 1.0, -1.0, math.nan, math.inf, -math.inf, 3.4028234663852886e38, -3.4028234663852886e38,
                1.401298464324817e-45, 1.1754943508222875e-38)


def f32_picks(lo: Optional[float] = None, hi: Optional[float] = None) -> list[int]:
    """Hand-picked float32 values, as bit patterns for an s_dword: the specials (zeros, one, NaN, infinities, the
    largest finite, the smallest subnormal and normal) and, for a field with a declared range, its two bounds, the
    floats just outside them and the middle (boundary-value analysis, what a careful user writes)."""
    picks = [f32_bits(v) for v in F32_SPECIALS]
    if lo is not None and hi is not None:
        picks += [f32_bits(lo), f32_bits(hi), _f32_step(lo, up=False), _f32_step(hi, up=True), f32_bits((lo + hi) / 2)]
    return list(dict.fromkeys(picks))


def _f32(name: str, default: float, lo: Optional[float] = None, hi: Optional[float] = None) -> DWord:
    """boofuzz has no float primitive: an s_dword of the float's bits (its own 140 integer mutations) plus the picks."""
    return DWord(name, default_value=f32_bits(default), endian="<", fuzz_values=f32_picks(lo, hi))


def _delimit(raw: bytes) -> bytes:
    """The block encoder: 0x00 COBS(raw) 0x00."""
    return b"\x00" + cobs.encode(raw) + b"\x00"


# ---- the host's end, as the callbacks keep it ----
class Refused(ConnectionError):
    """The controller answered the Hello with a refusal: trying again will not help."""


class Line:
    """Keys, counters and sequence numbers shared by the hooks and the grammar's tag `Checksum`; reads the controller's
    frames (checked with protocol.framing and the session key) to learn its ack and to see answers."""

    def __init__(self, psk: bytes, conn: TCPSocketConnection, clock: RealClock) -> None:
        self.psk = psk
        self.conn = conn
        self.clock = clock
        self.handshake = auth.handshake_keys(psk, is_controller=False)
        self.keys: Optional[auth.DirectionKeys] = None
        self.hs_counter = 0
        self.tx_counter = 0
        self.rx_counter = -1
        self.last_ack = NOTHING_ACKED
        self.event_next = 0
        self.urgent_seq = 0
        self.probe_token = 0
        self.rx = FrameReceiver()
        self.closed = False
        self.answers: list[tuple[str, int, int, int, bytes]] = []   # (kind, class, seq, msg_id, payload) since a mark
        self.hello_replies: list[bytes] = []
        self.hello_cookies: list[bytes] = []
        self.frames_in = 0

    # -- the grammar's callables --
    def session_tag(self, signed: bytes) -> bytes:
        return self.keys.tx.tag(signed) if self.keys is not None else bytes(16)

    def handshake_tag(self, signed: bytes) -> bytes:
        return self.handshake.tx.tag(signed)

    @property
    def next_seq(self) -> int:
        return (self.last_ack + 1) & 0xFFFF

    @property
    def event_ack(self) -> int:
        return (self.event_next - 1) & 0xFFFF

    # -- frames the hooks send (the handshake, the probe) --
    def frame(self, cls: int, seq: int, msg_id: int, payload: bytes, key: MacKey, counter: int) -> bytes:
        ack = NOTHING_ACKED if key is self.handshake.tx else self.event_ack
        signed = HEADER.pack(VERSION, FLAG_AUTH, cls, seq, ack, msg_id, len(payload)) + counter.to_bytes(6, "little")
        signed += payload
        raw = signed + key.tag(signed)
        return _delimit(raw + struct.pack("<I", zlib.crc32(raw)))

    def send(self, data: bytes) -> None:
        try:
            self.conn._sock.sendall(data)
        except OSError:
            self.closed = True

    def next_counter(self) -> int:
        self.tx_counter += 1
        return self.tx_counter

    # -- reading --
    def read(self, timeout_s: float) -> None:
        """Read what the controller sent within `timeout_s` (at once what is there)."""
        sock = self.conn._sock
        if self.closed or sock is None:
            return
        ready, _, _ = select.select([sock], [], [], max(0.0, timeout_s))
        if not ready:
            return
        try:
            data = sock.recv(65536)
        except (BlockingIOError, InterruptedError, socket.timeout):
            return
        except OSError:
            data = b""
        if not data:
            self.closed = True
            return
        self._absorb(data)

    def _absorb(self, data: bytes) -> None:
        for item in self.rx.feed(data):
            if isinstance(item, ParseError) or item.counter is None:
                continue
            if self.keys is not None and item.verify(self.keys.rx):
                if item.counter <= self.rx_counter:
                    continue
                self.rx_counter = item.counter
                self.frames_in += 1
                self.last_ack = item.ack
                if item.cls == EVENT:
                    if item.seq == self.event_next:
                        self.event_next = (self.event_next + 1) & 0xFFFF
                elif item.msg_id == NAK:
                    self.answers.append(("nak", item.cls, item.seq, item.msg_id, item.payload))
                elif item.cls in (COMMAND, URGENT):
                    self.answers.append(("reply", item.cls, item.seq, item.msg_id, item.payload))
            elif item.verify(self.handshake.rx):
                if item.msg_id == HELLO_REPLY:
                    self.hello_replies.append(item.payload)
                    self.answers.append(("hello-reply", item.cls, item.seq, item.msg_id, item.payload))
                elif item.msg_id == HELLO_COOKIE:
                    self.hello_cookies.append(item.payload)
                elif item.msg_id == NAK:
                    self.answers.append(("handshake-nak", item.cls, item.seq, item.msg_id, item.payload))

    def wait(self, until, timeout_s: float) -> bool:
        """Read until `until()` or the line closes or `timeout_s` passes; `until()` at the end."""
        deadline = self.clock.now() + timeout_s
        while not until() and not self.closed:
            left = deadline - self.clock.now()
            if left <= 0:
                break
            self.read(min(left, 0.05))
        return until()

    # -- the handshake --
    def connect(self, timeout_s: float) -> None:
        """Hello, HelloCookie (echoed at once in a fresh Hello), HelloReply, session keys, then a Ping so that the
        controller adopts the session."""
        # boofuzz's TCPSocketConnection leaves Nagle on: a Ping sent after a case nobody answered would wait for the
        # delayed ACK of the case (40 ms)
        self.conn._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        nonce = auth.new_nonce()
        cookie = bytes(auth.COOKIE_BYTES)       # none yet: the controller answers the first Hello with one
        deadline = self.clock.now() + timeout_s
        controller_nonce = None
        while controller_nonce is None:
            if self.clock.now() >= deadline or self.closed:
                raise ConnectionError("no HelloReply from the controller")
            self.hs_counter += 1
            self.hello_replies.clear()
            self.hello_cookies.clear()
            self.send(self.frame(LINK, 0, HELLO, HELLO_PAYLOAD.pack(VERSION, SCHEMA.hash, nonce, cookie),
                                 self.handshake.tx, self.hs_counter))

            def replies() -> list[tuple]:
                return [r for r in (HELLO_REPLY_PAYLOAD.unpack(p) for p in self.hello_replies
                                    if len(p) == HELLO_REPLY_PAYLOAD.size) if r[3] == nonce]

            def cookies() -> list[bytes]:
                return [c for n, c in (HELLO_COOKIE_PAYLOAD.unpack(p) for p in self.hello_cookies
                                       if len(p) == HELLO_COOKIE_PAYLOAD.size) if n == nonce and c != cookie]
            if self.wait(lambda: bool(replies() or cookies()), 1.0):
                for result, _, _, _, cnonce, _, _, _ in replies():
                    if result != 0:
                        raise Refused(f"the controller refused the Hello (reason {result})")
                    controller_nonce = cnonce
                if controller_nonce is None and cookies():
                    cookie = cookies()[-1]      # valid for seconds: the next Hello goes at once
        self.keys = auth.session_keys(self.psk, nonce, controller_nonce, is_controller=False)
        self.tx_counter, self.rx_counter, self.last_ack, self.event_next, self.urgent_seq = 0, -1, NOTHING_ACKED, 0, 0
        if not self.probe(max(0.5, deadline - self.clock.now())):
            raise ConnectionError("the controller did not answer the first Ping of the session")

    def probe(self, timeout_s: float) -> bool:
        """A signed Ping at the next sequence number; True when it (or the cached reply of that number) is answered.
        A NAK says the number was stale: the ack it carries is fresh, so ping again."""
        deadline = self.clock.now() + timeout_s
        while self.clock.now() < deadline and not self.closed:
            seq = self.next_seq
            self.probe_token = (self.probe_token + 1) & 0xFFFFFFFF
            self.answers.clear()
            self.send(self.frame(COMMAND, seq, PING, struct.pack("<I", self.probe_token), self.keys.tx,
                                 self.next_counter()))

            def answered() -> bool:
                return any(kind != "reply" or (cls == COMMAND and s == seq) for kind, cls, s, _, _ in self.answers)
            if self.wait(answered, min(1.0, max(0.0, deadline - self.clock.now()))):
                if any(kind == "reply" for kind, *_ in self.answers):
                    return True
        return False


    def executed(self, timeout_s: float = 2.0) -> Optional[int]:
        """The controller's count of commands executed since boot (GetStatus), None without an answer."""
        seq = self.next_seq
        self.answers.clear()
        self.send(self.frame(COMMAND, seq, 0x11, b"", self.keys.tx, self.next_counter()))

        def status() -> Optional[bytes]:
            return next((p for kind, cls, s, m, p in self.answers if kind == "reply" and s == seq and m == 0x82), None)
        if not self.wait(lambda: status() is not None, timeout_s):
            return None
        return STATUS_HEAD.unpack_from(status())[7]


# ---- the grammar, by hand ----
def _frame(name: str, cls: int, msg_id: int, payload: tuple, line: Line, fuzz_header: bool = False,
           handshake: bool = False) -> Request:
    """One message's frame: header, counter and payload (the signed block), the HMAC tag, the CRC-32, COBS around."""
    h = fuzz_header
    path = "wire.crc_covered"                # names resolve from the request down
    signed = Block("signed", children=(
        Byte("version", default_value=VERSION, fuzzable=h),
        Byte("flags", default_value=FLAG_AUTH, fuzzable=h),
        Byte("class", default_value=cls, fuzzable=h),
        Word("seq", default_value=ProtocolSessionReference("seq", 0), endian="<", fuzzable=h),
        Word("ack", default_value=ProtocolSessionReference("ack", NOTHING_ACKED), endian="<", fuzzable=h),
        Word("msg_id", default_value=msg_id, endian="<", fuzzable=h),
        Size("length", block_name=f"{path}.signed.payload", length=1, endian="<", fuzzable=h),
        # a counter that goes back or jumps to 2^48-1 would only end the session (replays are dropped): held valid
        BitField("counter", default_value=ProtocolSessionReference("counter", 1), width=48, endian="<", fuzzable=False),
        Block("payload", children=payload),
    ))
    tag = Checksum("tag", block_name=f"{path}.signed", algorithm=line.handshake_tag if handshake else line.session_tag,
                   length=16, fuzzable=False)
    crc = Checksum("crc", block_name=path, algorithm="crc32", endian="<", fuzzable=False)
    return Request(name, children=(Block("wire", encoder=_delimit, children=(
        Block("crc_covered", children=(signed, tag)), crc)),))


def _name(name: str, default: str) -> String:
    """A str16 field: a name of up to 16 characters, zero-padded."""
    return String(name, default_value=default, size=16, padding=b"\x00")


def grammar(line: Line) -> list[Request]:
    """Every host-to-controller command with a payload, in the declared order, then the urgent ones and Hello."""
    return [
        _frame("Ping", COMMAND, 0x10, (DWord("token", default_value=0x12345678, endian="<"),), line, fuzz_header=True),
        # no payload is due: the bytes a frame may carry where none is expected
        _frame("GetStatus", COMMAND, 0x11, (Bytes("extra", default_value=b""),), line),
        _frame("SetTelemetryRate", COMMAND, 0x15, (Word("rate_hz", default_value=10, endian="<",
                                                        fuzz_values=[200, 201]),), line),
        _frame("ParamGet", COMMAND, 0x16, (_name("name", "trk_dial_low_pct"),), line),
        _frame("ParamSet", COMMAND, 0x17, (_name("name", "trk_dial_low_pct"), _f32("value", 5.0)), line),
        _frame("ParamList", COMMAND, 0x18, (Word("index", default_value=0, endian="<"),), line),
        _frame("Move", COMMAND, 0x1A, (Byte("axis", default_value=0), _f32("target", 10.0, -360.0, 360.0),
                                       _f32("speed", 3.0, 0.0, 360.0)), line),
        _frame("MoveBy", COMMAND, 0x1B, (Byte("axis", default_value=0), _f32("distance", 1.0, -360.0, 360.0),
                                         _f32("speed", 3.0, 0.0, 360.0)), line),
        _frame("Jog", COMMAND, 0x1C, (Byte("axis", default_value=0), _f32("speed", 1.0, -360.0, 360.0)), line),
        _frame("Home", COMMAND, 0x1D, (Byte("axis", default_value=255),), line),
        _frame("Grip", COMMAND, 0x1E, (Byte("action", default_value=0),), line),
        _frame("BoxSwitch", COMMAND, 0x50, (Byte("switch", default_value=0), Byte("position", default_value=1),
                                            Byte("axis", default_value=2)), line),
        _frame("BoxDial", COMMAND, 0x51, (_f32("percent", 50.0, 0.0, 100.0), Byte("axis", default_value=2)), line),
        _frame("SetClock", COMMAND, 0x52, (DWord("utc_s", default_value=1767225600, endian="<",
                                                 fuzz_values=[946684800, 946684799, 4102444799, 4102444800]),
                                           Word("utc_ms", default_value=0, endian="<", fuzz_values=[999, 1000])), line),
        _frame("TrajClear", COMMAND, 0x60, (Bytes("extra", default_value=b""),), line),
        # a knot: index, time, then position and velocity of j1, j2, j3, j4 and the mount; the buffer holds 256
        _frame("TrajPoint", COMMAND, 0x61, (Word("index", default_value=0, endian="<", fuzz_values=[1, 255, 256]),
                                            _f32("t", 0.0, 0.0, 3600.0))
               + tuple(_f32(f"{joint}_{what}", 0.0, -360.0, 360.0)
                       for joint in ("j1", "j2", "j3", "j4", "mount") for what in ("pos", "vel")), line),
        _frame("TrajRun", COMMAND, 0x62, (Word("count", default_value=2, endian="<", fuzz_values=[0, 1, 256, 257]),),
               line),
        _frame("EStop", URGENT, 0x20, (Bytes("extra", default_value=b""),), line),
        _frame("Stop", URGENT, 0x21, (Bytes("extra", default_value=b""),), line),
        _frame("Hello", LINK, HELLO, (Byte("protocol_version", default_value=VERSION),
                                      BitField("schema_hash", default_value=SCHEMA.hash, width=64, endian="<"),
                                      Bytes("host_nonce", default_value=bytes(range(16)), size=16),
                                      Bytes("cookie", default_value=bytes(8), size=8)), line,
               handshake=True),
    ]


# ---- the health check and the session hooks ----
class _Monitor(BaseMonitor):
    """pre_send: a session (the handshake when there is none). post_send: did the target survive the case?"""

    def __init__(self, line: Line, child: Child, clock: RealClock, deadline: float, answer_wait_s: float,
                 probe_wait_s: float, byte_time_s: float) -> None:
        super().__init__()
        self.byte_time_s = byte_time_s  # paced: the wire time of a byte (a long case holds the line that long)
        self.line = line
        self.child = child
        self.clock = clock
        self.deadline = deadline
        self.answer_wait_s = answer_wait_s
        self.probe_wait_s = probe_wait_s
        self.cases = 0
        self.probes = 0
        self.answered = 0
        self.dead = ""                  # why the target is taken for dead ("" while alive)
        self.found_case = ""
        self.found_after = None
        self.last_sent = b""
        self.stopped_for_time = False
        self.depth1_cases = 0
        self.executed: Optional[int] = None
        self.no_session = ""
        self.depth1_done_s: Optional[float] = None     # when boofuzz had tried every field alone
        self.started_s = clock.now()

    def alive(self) -> bool:
        return True

    def pre_send(self, target=None, fuzz_data_logger=None, session=None) -> None:
        if self.line.keys is None:
            try:        # each handshake bounded on the wall clock, tried again for CONNECT_S of the target's own time
                retry_on_own_time(self.child, lambda: self.line.connect(CONNECT_S), CONNECT_S,
                                  lambda exc: isinstance(exc, ConnectionError) and not isinstance(exc, Refused)
                                  and not self.line.closed)
            except (ConnectionError, OSError) as exc:     # boofuzz would log it and go on: post_send raises it
                self.no_session = f"{type(exc).__name__}: {exc}"
                return
        self.line.read(0.0)
        self.line.answers.clear()

    def post_send(self, target=None, fuzz_data_logger=None, session=None) -> bool:
        line = self.line
        if line.keys is None:
            raise ConnectionError(f"no session with the controller: {self.no_session}")
        self.cases += 1
        if self.cases == self.depth1_cases:
            self.depth1_done_s = self.clock.now() - self.started_s
        self.last_sent = session.last_send or b""
        on_the_wire_s = len(self.last_sent) * self.byte_time_s      # 100 kB at 115200 baud: 8.7 s
        answered = line.wait(lambda: bool(line.answers), self.answer_wait_s + on_the_wire_s)
        if answered:
            self.answered += 1
        elif not line.closed:
            self.probes += 1        # Pings for probe_wait_s of the target's own time: a busy machine is no crash
            answered = self.child.wait_for(lambda seconds: line.probe(seconds) or line.closed,
                                           self.probe_wait_s + on_the_wire_s) and not line.closed
        status = self.child.exit_status()
        if line.closed or status is not None or not answered:
            if status is None and line.closed:
                try:
                    status = self.child.proc.wait(timeout=5.0)
                except Exception:
                    status = None
            why = ("the simulator ended" if status is not None else
                   "the controller closed the line" if line.closed else
                   f"no answer to the case nor to a Ping within {self.probe_wait_s:g} s of its own time")
            self.dead = why + (f" ({status})" if status is not None else "")
            self.found_case = f"#{session.total_mutant_index} {session.current_test_case_name}"
            self.found_after = self.cases
            session._index_end = session.total_mutant_index       # boofuzz has no stop(): end after this case
            return False
        if self.clock.now() >= self.deadline:
            self.stopped_for_time = True
            session._index_end = session.total_mutant_index
            self.executed = line.executed()     # now: boofuzz closes the connection when its loop ends
        return True

    def get_crash_synopsis(self) -> str:
        return self.dead

    def restart_target(self, target=None, fuzz_data_logger=None, session=None) -> bool:
        return False


def _before_case(line: Line):
    """The edge callback: the session's values for this case's ProtocolSessionReferences."""
    def before_case(target, fuzz_data_logger, session, node, edge, test_case_context, *args, **kwargs):
        v = test_case_context.session_variables
        if node.name == "Hello":
            line.hs_counter += 1
            v["counter"], v["seq"], v["ack"] = line.hs_counter, 0, NOTHING_ACKED
        else:
            v["counter"] = line.next_counter()
            v["ack"] = line.event_ack
            if node.name in ("EStop", "Stop"):
                v["seq"] = line.urgent_seq
                line.urgent_seq = (line.urgent_seq + 1) & 0xFFFF
            else:
                v["seq"] = line.next_seq
        return None
    return before_case


@dataclass
class BoofuzzResult:
    cases: int                 # test cases boofuzz executed
    wall_s: float
    cases_per_s: float
    found: bool                # the target crashed / stopped answering (planted bug found)
    found_after_cases: Optional[int]
    found_case: str            # boofuzz's name/description of the case that did it ("" if none)
    notes: list[str] = field(default_factory=list)   # anything a reader must know (e.g. what boofuzz could not express)


def describe_frame(wire: bytes) -> str:
    """The header and payload of a frame the grammar rendered (for the report)."""
    try:
        raw = cobs.decode(wire.strip(b"\x00"))
        version, flags, cls, seq, ack, msg_id, length = HEADER.unpack_from(raw)
        payload = raw[HEADER.size + 6:-20]
    except Exception as exc:
        return f"undecodable ({exc}): {wire.hex()}"
    shown = payload[:32].hex() + (f"... ({len(payload)} bytes)" if len(payload) > 32 else "")
    text = (f"version {version} flags {flags:#04x} class {cls} seq {seq} ack {ack} msg {msg_id:#06x} length {length} "
            f"payload {shown}")
    if msg_id == 0x51 and len(payload) == 5:
        text += f" (BoxDial percent {bits_f32(struct.unpack_from('<I', payload)[0])!r}, axis {payload[4]})"
    return text


def _grammar_size(requests: list[Request]) -> tuple[int, dict[str, int]]:
    per = {r.name: r.get_num_mutations() for r in requests}
    return sum(per.values()), per


def run_boofuzz(tmp: Path, duration_s: float, planted: bool, baud: Optional[int] = None,
                command: Optional[tuple[str, ...]] = None) -> BoofuzzResult:
    """Start the live target, fuzz it with boofuzz for `duration_s` or until it dies, and say what happened.
    `command`: what runs `sim ...` (default: the planted simulator if `planted`, else aspod); the benchmark of
    planted bugs gives its own (bench/fuzz_plants.py)."""
    tmp = Path(tmp)
    tmp.mkdir(parents=True, exist_ok=True)
    psk = auth.new_nonce() + auth.new_nonce()
    key_file = tmp / "boofuzz-peer.key"
    auth.write_key(key_file, psk)
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp / "config"),
           "PYTHONPATH": os.pathsep.join(p for p in (str(REPO_ROOT), os.environ.get("PYTHONPATH", "")) if p)}
    args = ["sim", "--tcp", "0", "--key-file", str(key_file), "--params", str(tmp / "params.json"), "--no-control"]
    args += ["--no-pacing"] if baud is None else ["--baud", str(baud)]
    load_before = os.getloadavg()[0]
    child = Child(args, env=env, command=command or (PLANTED if planted else ASPOD))
    stderr_tail: deque[str] = deque(maxlen=50)
    child.follow_stderr(stderr_tail.append)
    clock = RealClock()
    notes: list[str] = []
    try:
        try:
            url = child.ready("ASPOD-LINK ", timeout_s=120.0).split(" ", 1)[1]
            child.ready("ASPOD-KEY ")
        except ChildError as exc:
            raise RuntimeError(f"the simulator did not start: {exc}; stderr: {list(stderr_tail)}") from None
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        conn = TCPSocketConnection(host, int(port), send_timeout=5.0, recv_timeout=5.0)
        line = Line(psk, conn, clock)
        # a reply comes within about 1 ms unpaced (3 ms at worst, measured); paced, after the case's and the reply's
        # wire time (a frame is at most 280 bytes, 10 bits a byte) and a telemetry frame that may be on the wire
        # before it. A late answer costs only a Ping more.
        answer_wait_s = 0.005 if baud is None else 0.005 + 3 * 280 * 10 / baud
        start = clock.now()
        monitor = _Monitor(line, child, clock, start + duration_s, answer_wait_s, probe_wait_s=5.0,
                           byte_time_s=0.0 if baud is None else 10 / baud)
        session = Session(target=Target(connection=conn, monitors=[monitor]), web_port=None, keep_web_open=False,
                          fuzz_loggers=[], db_filename=str(tmp / "boofuzz-results.db"), sleep_time=0.0,
                          receive_data_after_each_request=False, receive_data_after_fuzz=False,
                          reuse_target_connection=True, restart_sleep_time=0)
        session.on_failure += lambda logger=None, **kw: None    # no restart: the run ends at the first failure
        requests = grammar(line)
        callback = _before_case(line)
        for request in requests:
            session.connect(request, callback=callback)
        total, per = _grammar_size(requests)
        monitor.depth1_cases = total
        session.fuzz()               # boofuzz's default: every field alone (depth 1), then every pair (depth 2), ...
        wall_s = clock.now() - start
    finally:
        status, _ = child.stop()
    cases = monitor.cases
    found = bool(monitor.dead)
    order, before = [], 0
    for name, n in per.items():
        order.append(f"{name} {n}")
    for name, n in per.items():
        if name == "BoxDial":
            break
        before += n
    notes.append(f"grammar: {len(requests)} requests, {total} single-field mutations (boofuzz depth 1), in this order: "
                 + ", ".join(order) + f"; BoxDial's first case is #{before + 1}, percent's hand-picked values "
                 f"#{before + 141}..#{before + 140 + len(f32_picks(0.0, 100.0))} (after s_dword's own 140)")
    if monitor.depth1_done_s is not None:
        notes.append(f"boofuzz tried every field alone (depth 1, {total} cases) in {monitor.depth1_done_s:.1f} s, "
                     "then went on with pairs of fields (depth 2)")
    notes.append(f"target: {'the planted simulator (BoxDial IndexError at 100 %)' if planted else 'aspod sim'}, "
                 f"TCP, {'unpaced (--no-pacing)' if baud is None else f'paced at {baud} baud'}; boofuzz's results DB "
                 f"{tmp / 'boofuzz-results.db'}")
    notes.append(f"machine: load average (1 min) {load_before:.2f} before, {os.getloadavg()[0]:.2f} after, "
                 f"{os.cpu_count()} cores: the rate is the target's and boofuzz's share of them")
    notes.append(f"health check: {monitor.answered} cases answered at once, {monitor.probes} needed a Ping after them "
                 f"(answer wait {answer_wait_s * 1000:.0f} ms; NAKs to malformed frames are rate-limited to 10/s)")
    if monitor.executed is not None:
        reached = monitor.executed - monitor.probes - 1
        notes.append(f"the controller had executed {monitor.executed} commands at the end (its GetStatus), the hooks' "
                     f"{monitor.probes + 1} Pings included: about {reached} of the {cases} cases reached a handler "
                     "(the others were refused by the link or the decoder, with a NAK or a Result, or dropped)")
    if found:
        notes.append(f"found: {monitor.dead}; the case's frame: {describe_frame(monitor.last_sent)}")
        errors = [text for text in stderr_tail if "Error" in text]
        if errors:
            notes.append(f"the simulator's last error line: {errors[-1]}")
    elif status not in (0, None):
        notes.append(f"the simulator ended with status {status} at the stop")
    notes.append("floats: no float primitive in boofuzz; each f32 field is an s_dword of its bits (boofuzz's 140 "
                 "integer mutations: small integers, powers of two and their neighbours, as bit patterns mostly "
                 "denormals or NaNs) plus hand-picked fuzz_values: 0, -0, 1, -1, NaN, +-inf, +-max, the smallest "
                 "subnormal and normal, and for a declared range its bounds, the floats just outside and the middle. "
                 f"s_dword's own mutations never give 100.0 ({f32_bits(100.0):#010x}); only the hand-picked bound does")
    notes.append("held valid, not fuzzed: the 48-bit counter (a signed counter that goes back is dropped as a replay, "
                 "one that jumps to 2^48-1 ends the session for good), the HMAC tag and the CRC (Checksum "
                 "fuzzable=False, respected in 0.4.2); the header is fuzzed in Ping only, the others fuzz payloads")
    notes.append("what boofuzz could not express by itself: the session (handshake, keys, counter, sequence numbers "
                 "from the controller's acks, event acks) lives in hand-written hooks that read the controller's "
                 "frames (protocol.framing to check them, protocol.auth for the keys); the ranges and enums of the "
                 "fields (boofuzz mutates every field the same way whatever it means); one field at a time, then "
                 "every pair (depth 2) in a fixed order, never a value chosen from the answers; a stop after the first "
                 "failure (the hook sets the session's private _index_end) and a stop at a time (the same); no restart "
                 "of the target after a crash")
    notes.append("worked around in boofuzz 0.4.2: TCPSocketConnection leaves Nagle on (a Ping after an unanswered case "
                 "waited 40 ms for the delayed ACK; TCP_NODELAY set on its private _sock); its recv returns b'' both "
                 "for a timeout and for the peer's end of stream (the hooks read the socket themselves); exceptions in "
                 "post_test_case_callbacks are logged and swallowed (the health check is a BaseMonitor whose post_send "
                 "returns False); without an on_failure handler a failure closes and reopens the connection or sleeps "
                 "restart_sleep_time. Not met here: #452 (a callable Checksum beside an s_size: they coexist, the size "
                 "is of the payload block), #503 (Checksum fuzzable=False is respected), #134 (no recv-based check)")
    notes.append("the Hello's schema_hash is protocol.messages.SCHEMA.hash (a constant the user would copy from "
                 "docs/protocol.md); nothing else of SCHEMA is read")
    rate = cases / wall_s if wall_s > 0 else 0.0
    return BoofuzzResult(cases, wall_s, rate, found, monitor.found_after if found else None,
                         monitor.found_case if found else "", notes)


def print_result(title: str, result: BoofuzzResult) -> None:
    print(f"{title}: {result.cases} cases in {result.wall_s:.1f} s = {result.cases_per_s:.1f} cases/s; "
          + (f"target died after {result.found_after_cases} cases: {result.found_case}" if result.found else
             "the target survived"), flush=True)
    for note in result.notes:
        print(f"  - {note}", flush=True)


if __name__ == "__main__":
    duration = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    line_baud = int(sys.argv[2]) if len(sys.argv) > 2 else None
    with tempfile.TemporaryDirectory(prefix="boofuzz-peer-") as scratch:
        for plant in (False, True):
            res = run_boofuzz(Path(scratch) / ("planted" if plant else "plain"), duration, plant, line_baud)
            print_result(f"boofuzz 0.4.2, {'planted' if plant else 'plain'} target, "
                         f"{'unpaced' if line_baud is None else f'{line_baud} baud'}", res)
