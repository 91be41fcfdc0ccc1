"""The conformance suite's host end: a real `HostLink` on a pyserial port, pumped in the caller's thread, with the
hostile tools a well-behaved host never uses.

The suite needs what no ordinary host gives: every frame the controller sends, as it came (`Probe.seen`, each with
its time and the key that signs it), frames made by hand (a replay, a forgery, a command re-signed under a new
counter, a number beyond the next expected), bytes of garbage, a line gone silent (`mute`), and events left
unacknowledged (`hold_events`). So the probe splits the incoming bytes into frames itself, keeps each, and hands
them to the `HostLink` one by one; what the link queues goes on the wire unless muted.

Nothing here waits on a bare clock: `until(predicate, bound_s)` pumps the line until the predicate holds, and its
bound only ends a hang (a check judges time by the controller's own uptime, in its replies and telemetry).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import serial

from protocol import auth
from protocol.errors import LinkError, ParseError
from protocol.framing import (COUNTER_SIZE, FLAG_AUTH, HEADER, VERSION, Frame, MacKey, decode_frame, encode_frame,
                              find_frames, seal)
from protocol.host_link import CommandHandle, HostLink
from protocol.link import LinkConfig, LinkState
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.reasons import Reason
from protocol.schema import Message, MsgClass
from timebase import Clock, RealClock

from host_tools.worlds.ports import open_url

READ_TIMEOUT_S = 0.005
READ_SIZE = 4096
HANDSHAKE_BOUND_S = 15.0      # a handshake that has not finished in this long will not (Hello every 1 s, 5 tries)


@dataclass
class Seen:
    """A frame the controller sent: when it came (the probe's clock), its wire bytes, the frame (None if it did not
    decode: `error` says why), the key that signs it (`key`: session, nak, handshake, or None) and its message."""

    time_s: float
    wire: bytes
    frame: Optional[Frame]
    error: Optional[ParseError] = None
    key: Optional[str] = None
    msg: Optional[Message] = None

    @property
    def name(self) -> str:
        return self.msg.spec.name if self.msg is not None else "?"

    def describe(self) -> str:
        if self.frame is None:
            return f"an undecodable frame ({self.error})"
        f = self.frame
        name = self.name
        if name == "Nak":
            reason = self.msg.reason
            name = f"Nak({Reason(reason).name if reason in Reason._value2member_map_ else reason})"
        return f"{name} (class {f.cls}, seq {f.seq}, key {self.key or 'none that verifies'})"


class Probe:
    """A host link on `url`, pumped by the caller; see the module's doc."""

    def __init__(self, url: str, psk: bytes, baud: int = 115200, clock: Optional[Clock] = None,
                 config: Optional[LinkConfig] = None) -> None:
        self.url = url
        self.psk = psk
        self.clock = clock or RealClock()
        try:
            self.port = open_url(url, baud, timeout=READ_TIMEOUT_S, write_timeout=2.0)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise LinkError(Reason.NO_SESSION, f"cannot open {url}: {exc}") from exc
        self.events: list[tuple[float, Message, bool]] = []      # (time, event, from an earlier session)
        self.telemetry: list[tuple[float, Message]] = []
        self.link = self._new_link(config)
        self.seen: list[Seen] = []
        self.sent: list[tuple[float, bytes]] = []                # every write, in order
        self.mute = False                                        # True: the link's frames are not sent
        self.hold_events = False                                 # True: events are seen here, never given the link
        self.line_error: Optional[str] = None                    # why the line failed, if it did (the runner's)
        self._pending = b""
        self._handshake = auth.handshake_keys(psk, is_controller=False)

    def _new_link(self, config: Optional[LinkConfig]) -> HostLink:
        def on_event(msg: Message, now: float) -> None:
            self.events.append((now, msg, self.link.event_from_earlier_session))

        return HostLink(self.psk, config, on_telemetry=lambda msg, now: self.telemetry.append((now, msg)),
                        on_event=on_event)

    # ---- the line ----
    def now(self) -> float:
        return self.clock.now()

    def write(self, data: bytes) -> None:
        self.sent.append((self.now(), data))
        self.port.write(data)

    def pump(self) -> None:
        """One turn: read what came (waiting up to READ_TIMEOUT_S for the first byte), hand it on, run the link's
        timers, write what it queued (unless muted)."""
        data = self.port.read(1)
        waiting = self.port.in_waiting if data else 0
        while data and waiting and len(data) < READ_SIZE:
            data += self.port.read(min(waiting, READ_SIZE - len(data)))
            waiting = self.port.in_waiting
        now = self.now()
        if data:
            self._received(data, now)
        self.link.poll(now)
        if not self.mute:
            out = self.link.take_all(now)
            if out:
                self.write(out)

    def _received(self, data: bytes, now: float) -> None:
        buf = self._pending + data
        segments, used = find_frames(buf)
        self._pending = buf[used:]
        for segment in segments:
            wire = b"\x00" + segment + b"\x00"
            seen = self._classify(wire, segment, now)
            self.seen.append(seen)
            if self.hold_events and seen.frame is not None and seen.frame.cls == MsgClass.EVENT:
                continue
            self.link.feed(wire, now)

    def _classify(self, wire: bytes, segment: bytes, now: float) -> Seen:
        try:
            frame = decode_frame(segment)
        except ParseError as exc:
            return Seen(now, wire, None, exc)
        seen = Seen(now, wire, frame)
        for name, key in self.keys().items():
            if key is not None and frame.verify(key):
                seen.key = name
                break
        try:
            seen.msg = SCHEMA.decode(frame.msg_id, frame.payload)
        except ParseError:
            pass
        return seen

    def keys(self) -> dict[str, Optional[MacKey]]:
        """The keys a controller's frame may be signed with, by name: this session's, the controller's NAK key
        (its identity from the last HelloReply), the handshake key."""
        link = self.link
        info = link.controller_info
        return {"session": link.session.keys.rx if link.session is not None else None,
                "nak": auth.nak_key(self.psk, info.controller_id) if info is not None else None,
                "handshake": self._handshake.rx}

    def until(self, predicate: Callable[[], bool], bound_s: float) -> bool:
        """Pump until `predicate()` holds (True) or `bound_s` has passed on the probe's clock (False)."""
        deadline = self.now() + bound_s
        while not predicate():
            if self.now() >= deadline:
                return predicate()
            self.pump()
        return True

    def since(self, mark: int, cls: Optional[int] = None, name: Optional[str] = None) -> list[Seen]:
        """The frames seen from index `mark` on (`len(probe.seen)` before an action), of class `cls` and message
        `name` if given."""
        return [s for s in self.seen[mark:] if s.frame is not None and (cls is None or s.frame.cls == cls)
                and (name is None or s.name == name)]

    def close(self) -> None:
        try:
            self.port.close()
        except (serial.SerialException, OSError):
            pass

    # ---- sessions and commands ----
    def connect(self, bound_s: float = HANDSHAKE_BOUND_S) -> bool:
        """A new session (the link's handshake); True once it is up."""
        self.link.connect(self.now())
        self.until(lambda: self.link.state in (LinkState.UP, LinkState.REFUSED, LinkState.SUSPENDED), bound_s)
        return self.link.state is LinkState.UP

    @property
    def up(self) -> bool:
        return self.link.state is LinkState.UP

    def submit(self, msg: Message) -> CommandHandle:
        handle = self.link.submit(msg, self.now())
        self.pump()
        return handle

    def call(self, msg: Message, bound_s: float = 30.0) -> CommandHandle:
        """Send a command and pump until its outcome (the link's retry limit ends it well within `bound_s`)."""
        handle = self.submit(msg)
        self.until(lambda: handle.done, bound_s)
        return handle

    def call_payload(self, name: str, payload: bytes, bound_s: float = 30.0) -> CommandHandle:
        handle = self.link.submit_payload(SCHEMA[name], payload, self.now())
        self.pump()
        self.until(lambda: handle.done, bound_s)
        return handle

    # ---- frames by hand ----
    @property
    def next_command_seq(self) -> int:
        """The sequence number the controller expects next (the link's next, nothing being in flight)."""
        return self.link._commands.next_seq

    def take_command_seq(self) -> int:
        """Use up the link's next command number for a command sent by hand (its answer then comes to the hand,
        not to the link, which never saw it)."""
        commands = self.link._commands
        seq = commands.next_seq
        commands.next_seq = (seq + 1) & 0xFFFF
        return seq

    def take_urgent_seq(self) -> int:
        urgent = self.link._urgent
        seq = urgent.next_seq
        urgent.next_seq = (seq + 1) & 0xFFFF
        return seq

    def next_counter(self) -> int:
        """A counter above every one the session used (the link's own moves past it)."""
        session = self.link.session
        session.tx_counter += 1
        return session.tx_counter

    def made(self, cls: int, seq: int, msg_id: int, payload: bytes, *, key: Optional[bytes] = None,
             counter: Optional[int] = None, version: int = VERSION, flags: int = FLAG_AUTH,
             ack: Optional[int] = None) -> bytes:
        """A frame as this host could send it, wrong where asked: signed with the session's key (or `key`) under a
        fresh counter (or `counter`), with the header given; unsigned when `flags` lacks AUTH."""
        ack = self.link._ack_value() if ack is None else ack
        if not flags & FLAG_AUTH:
            return encode_frame(cls, seq, ack, msg_id, payload)
        counter = self.next_counter() if counter is None else counter
        body = HEADER.pack(version, flags, cls, seq, ack, msg_id, len(payload)) \
            + counter.to_bytes(COUNTER_SIZE, "little") + payload
        tag = MacKey(key if key is not None else self.link.session.keys.tx.key).tag(body)
        return seal(body + tag)

    def command(self, msg: Message, seq: Optional[int] = None, **kw) -> bytes:
        """A command frame made by hand (`made`), numbered `seq` (default: the next, taken from the link)."""
        spec = msg.spec
        seq = self.take_command_seq() if seq is None else seq
        return self.made(spec.cls, seq, spec.id, spec.encode(msg), **kw)

    def hello(self, nonce: bytes, cookie: bytes = bytes(auth.COOKIE_BYTES), *, version: int = PROTOCOL_VERSION,
              schema_hash: Optional[int] = None, key: Optional[MacKey] = None, counter: int = 1) -> bytes:
        """A Hello made by hand (outside the link's own handshake), signed with the handshake key or `key`."""
        spec = SCHEMA["Hello"]
        msg = spec.type(version, SCHEMA.hash if schema_hash is None else schema_hash, nonce, cookie)
        return encode_frame(MsgClass.LINK, 0, 0xFFFF, spec.id, spec.encode(msg),
                            key or self._handshake.tx, counter)

    def answer(self, mark: int, predicate: Callable[[Seen], bool], bound_s: float) -> Optional[Seen]:
        """The first frame seen from `mark` on for which `predicate` holds, pumping up to `bound_s` for it."""
        found: list[Seen] = []

        def look() -> bool:
            found[:] = [s for s in self.seen[mark:] if s.frame is not None and predicate(s)][:1]
            return bool(found)

        self.until(look, bound_s)
        return found[0] if found else None
