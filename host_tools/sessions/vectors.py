"""Test vectors of the link, for an implementation that is not this one (issue 37): docs/vectors/.

A ground station or the real controller's firmware checks itself against these files without running the
emulator: the key derivations of one handshake from a fixed key and fixed nonces (every HMAC's key, message and
inner hash), frames of every message class and the link's every NAK broken out byte by byte (header, counter,
payload, MAC input, tag, CRC, the bytes before and after COBS), COBS's edge cases, and a short capture of a
session (pcapng, as `aspod` records them) with its listing as `aspod log` prints it.

Everything is made by the real code, nothing by hand: a `HostLink` and a `ControllerLink` (protocol/) talk to
each other with fixed nonces on a fixed clock, the frames they send are taken as they are, and the refused frames
are fed to them as a peer would send them, so each NAK is the one the link really answers with. The controller's
application is a stand-in (`_Application`): its replies' values are made up, the link's handling of them is not.
So the files change only when the wire does, and a test (tests/test_vectors.py) fails when the committed files
differ from what this module writes now.

    python -m host_tools.sessions.vectors [DIR]      # writes the files into DIR (default docs/vectors)

`docs/vectors/check.py` is the other half: the same vectors recomputed from docs/protocol.md with Python's
standard library alone, never importing this project (the test runs it with `python -I`).
"""
from __future__ import annotations

import hashlib
import hmac
import io
import json
import struct
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from cobs import cobs

from protocol import auth, framing
from protocol.controller_link import COOKIE_EPOCH_S, ControllerLink
from protocol.errors import ParseError
from protocol.framing import FLAG_AUTH, HEADER, VERSION, Frame, MacKey, decode_frame, encode_frame, seal
from protocol.host_link import HostLink
from protocol.messages import PROTOCOL_VERSION, SCHEMA
from protocol.reasons import Reason
from protocol.schema import Direction, Message, MsgClass
from protocol.states import CloseWhy, ControllerState
from host_tools.sessions.capture import CaptureWriter, SessionCapture, SessionInfo
from host_tools.sessions.decode import SessionDecoder, describe

ROOT = Path(__file__).resolve().parents[2]
FOLDER = ROOT / "docs" / "vectors"

# The fixed inputs: public, for these vectors only. Counting bytes, so that a dump shows at a glance which is which.
PSK = bytes(range(0x00, 0x20))
HOST_NONCE = bytes(range(0xA0, 0xB0))
CONTROLLER_NONCE = bytes(range(0xB0, 0xC0))
CONTROLLER_ID = bytes(range(0xC0, 0xC8))
COOKIE_SECRET = bytes(range(0xD0, 0xE0))
START_S = 1000.0             # the links' clock when the host connects
FRAME_S = 0.002              # the clock moves on this much for each frame carried
COOKIE_TIME_S = START_S + FRAME_S     # the controller's clock when it makes the HelloCookie (the second frame)
CAPTURE_STARTED_S = 1_796_000_000     # the capture's if_tsoffset (2026-11-30 00:53:20 UTC): fixed, not today
CAPTURE = "session.pcapng"
HANDSHAKE_FRAMES = ["Hello (no cookie yet)", "HelloCookie", "Hello (with the cookie)", "HelloReply",
                    "the host's first Heartbeat: the first frame under a session key (the controller adopts the "
                    "session)", "the controller's first Heartbeat"]
LINK = "link"


def _label(text: str) -> bytes:
    return b"aspod/v1/" + text.encode()


@dataclass(frozen=True)
class Derivation:
    """One HMAC-SHA256 of the handshake: `key` over `message`, whose first part is the ASCII `label`."""

    name: str
    key_name: str
    key: bytes
    label: bytes
    rest: tuple[tuple[str, bytes], ...]     # the parts after the label: (what, bytes)
    truncate: int = 32                      # bytes of the HMAC used

    @property
    def message(self) -> bytes:
        return self.label + b"".join(part for _, part in self.rest)

    def vector(self, result: bytes) -> dict[str, Any]:
        block = self.key.ljust(64, b"\x00")       # every key here is shorter than SHA-256's 64-byte block
        inner = hashlib.sha256(bytes(b ^ 0x36 for b in block) + self.message).digest()
        full = hmac.digest(self.key, self.message, "sha256")
        assert full[:self.truncate] == result, self.name     # the code's own result, as HMAC computes it
        return {"name": self.name, "hmac_key": self.key_name, "hmac_key_hex": self.key.hex(),
                "label_ascii": self.label.decode(),
                "message_parts": [{"what": "label", "hex": self.label.hex()}]
                + [{"what": what, "hex": part.hex()} for what, part in self.rest],
                "message_hex": self.message.hex(), "inner_sha256_hex": inner.hex(), "hmac_sha256_hex": full.hex(),
                "result_hex": result.hex()}


def _derivations() -> list[tuple[Derivation, bytes]]:
    """The handshake's HMACs, each with the code's own result (protocol/auth.py)."""
    host_hs = auth.handshake_keys(PSK, is_controller=False)
    host_session = auth.session_keys(PSK, HOST_NONCE, CONTROLLER_NONCE, is_controller=False)
    slot = int(COOKIE_TIME_S // COOKIE_EPOCH_S)
    cookie = auth.hello_cookie(COOKIE_SECRET, HOST_NONCE, slot)
    nonces = (("host_nonce", HOST_NONCE), ("controller_nonce", CONTROLLER_NONCE))
    steps = [
        (Derivation("handshake_h2c", "psk", PSK, _label("handshake/h2c"), ()), host_hs.tx.key),
        (Derivation("handshake_c2h", "psk", PSK, _label("handshake/c2h"), ()), host_hs.rx.key),
        (Derivation("cookie", "cookie_secret", COOKIE_SECRET, _label("cookie"),
                    (("host_nonce", HOST_NONCE), ("slot_i64le", slot.to_bytes(8, "little", signed=True))),
                    auth.COOKIE_BYTES), cookie),
        (Derivation("session_h2c", "psk", PSK, _label("session/h2c"), nonces), host_session.tx.key),
        (Derivation("session_c2h", "psk", PSK, _label("session/c2h"), nonces), host_session.rx.key),
        (Derivation("nak_c2h", "psk", PSK, _label("nak/c2h"), (("controller_id", CONTROLLER_ID),)),
         auth.nak_key(PSK, CONTROLLER_ID).key),
    ]
    return steps


def _value(value: Any) -> Any:
    return value.hex() if isinstance(value, (bytes, bytearray)) else value


def message_vector(msg: Message) -> dict[str, Any]:
    spec = msg.spec
    return {"name": spec.name, "id": spec.id, "class": spec.cls.name, "direction": spec.direction.value,
            "fields": [{"name": f.name, "type": f.type, "value": _value(v)} for f, v in zip(spec.fields, msg)]}


def frame_vector(wire: bytes, direction: Direction, keys: dict[str, bytes], what: str = "") -> dict[str, Any]:
    """One frame's wire bytes (delimiters included) broken out: its header's fields, counter, payload, the MAC's
    input and tag (the key that signed it found among `keys` by trying each), CRC, raw bytes and COBS bytes.

    The frame need not be valid: a refused one is broken out as far as its bytes go (`message` None when its
    payload is no message, `key` None when no key signs it)."""
    segment = wire[1:-1]
    assert wire[0] == 0 and wire[-1] == 0 and 0 not in segment
    raw = cobs.decode(segment)
    version, flags, cls, seq, ack, msg_id, length = HEADER.unpack_from(raw)
    auth_flag = bool(flags & FLAG_AUTH)
    counter_end = framing.HEADER_SIZE + (framing.COUNTER_SIZE if auth_flag else 0)
    payload = raw[counter_end:-framing.CRC_SIZE - (framing.TAG_SIZE if auth_flag else 0)]
    crc_input = raw[:-framing.CRC_SIZE]
    out: dict[str, Any] = {"what": what, "direction": direction.value}
    try:
        frame: Optional[Frame] = decode_frame(segment)
    except ParseError as exc:            # a refused frame: the reason the link answers it with, and why
        frame = None
        out["decode_error"] = str(exc)
    message = None
    if frame is not None:
        try:
            message = SCHEMA.decode(frame.msg_id, frame.payload)
        except ParseError as exc:
            out["decode_error"] = str(exc)
    out["message"] = None if message is None else message_vector(message)
    out["header"] = {"version": version, "flags": flags, "class": cls, "seq": seq, "ack": ack, "msg_id": msg_id,
                     "length": length}
    out["header_hex"] = raw[:framing.HEADER_SIZE].hex()
    out["counter"] = int.from_bytes(raw[framing.HEADER_SIZE:counter_end], "little") if auth_flag else None
    out["counter_hex"] = raw[framing.HEADER_SIZE:counter_end].hex() if auth_flag else None
    out["payload_hex"] = payload.hex()
    if auth_flag:
        signed = raw[:-framing.CRC_SIZE - framing.TAG_SIZE]
        tag = raw[-framing.CRC_SIZE - framing.TAG_SIZE:-framing.CRC_SIZE]
        key = next((name for name, k in keys.items() if MacKey(k).tag(signed) == tag), None)
        out["key"] = key
        out["mac_input_hex"] = signed.hex()
        out["hmac_sha256_hex"] = None if key is None else hmac.digest(keys[key], signed, "sha256").hex()
        out["tag_hex"] = tag.hex()
    else:
        out.update(key=None, mac_input_hex=None, hmac_sha256_hex=None, tag_hex=None)
    crc = zlib.crc32(crc_input)
    out["crc_input_hex"] = crc_input.hex()
    out["crc32"] = f"{crc:08x}"
    out["crc_hex"] = raw[-framing.CRC_SIZE:].hex()
    out["crc_ok"] = struct.pack("<I", crc) == raw[-framing.CRC_SIZE:]
    out["raw_hex"] = raw.hex()
    out["cobs_hex"] = segment.hex()
    out["wire_hex"] = wire.hex()
    return out


@dataclass
class Carried:
    """A frame one end sent, as it went on the wire."""

    time_s: float
    direction: Direction
    wire: bytes

    def decoded(self) -> Message:
        frame = decode_frame(self.wire[1:-1])
        return SCHEMA.decode(frame.msg_id, frame.payload)


class _Application:
    """The controller's application, standing in for firmware_py's: made-up sensor values, but a state that agrees
    with itself from frame to frame (Enable makes it ENABLED, with its StateChanged; the close makes it IDLE again),
    uptimes from the one clock, and `Close` as the firmware does it (the events, then the link's close, then Closed
    naming the last event's sequence number)."""

    SUPPLY_V, TEMP_C = 24.5, 31.25

    def __init__(self) -> None:
        self.link: Optional[ControllerLink] = None
        self.state = ControllerState.IDLE

    def uptime_ms(self, now: float) -> int:
        """The controller's uptime: its link's, so that replies, events and Heartbeats agree."""
        return self.link.uptime_ms(now)

    def _change(self, state: ControllerState, reason: Reason, now: float) -> None:
        self.link.send_event(SCHEMA["StateChanged"].type(int(state), int(self.state), int(reason), 0,
                                                         self.uptime_ms(now)))
        self.state = state

    def telemetry(self, now: float) -> Message:
        """A TelemetryStatus of this moment: the state, the link's own counts."""
        stats = self.link.stats
        return SCHEMA["TelemetryStatus"].type(
            self.uptime_ms(now), int(self.state), int(Reason.OK), 0, self.SUPPLY_V, self.TEMP_C,
            self.link.commands_executed, stats.frames_rx, stats.frames_tx, stats.crc_errors + stats.auth_errors,
            180, 95, 0, 0, 0, 1.0, 0.0)

    def __call__(self, msg: Message, urgent: bool, now: float) -> Message:
        name = msg.spec.name
        uptime_ms = self.uptime_ms(now)
        if name == "Ping":
            return SCHEMA["Pong"].type(int(Reason.OK), msg.token, uptime_ms)
        if name == "GetStatus":
            return SCHEMA["Status"].type(int(Reason.OK), int(self.state), 0, int(Reason.OK), uptime_ms,
                                         self.SUPPLY_V, self.TEMP_C, self.link.commands_executed, 10, 0, 1.0, 0.0,
                                         1.0)
        if name == "Enable" and self.state is ControllerState.IDLE:
            self._change(ControllerState.ENABLED, Reason.HOST_REQUEST, now)
        if name == "Close":
            if self.state is ControllerState.ENABLED:
                self._change(ControllerState.IDLE, Reason.SESSION_CLOSED, now)
            self.link.send_event(SCHEMA["SessionClosed"].type(msg.why, int(self.state), 0, uptime_ms))
            self.link.close_session()
            return SCHEMA["Closed"].type(int(Reason.OK), int(self.state), 0, self.link.last_event_seq,
                                         int(self.link.config.link_timeout_s * 1000))
        return SCHEMA["Result"].type(int(Reason.OK))


class _Line:
    """A host and a controller on one line with the fixed inputs; every frame carried is kept in `carried`."""

    def __init__(self) -> None:
        self.now = START_S
        self.app = _Application()
        controller_nonces = iter([COOKIE_SECRET, CONTROLLER_NONCE])
        self.controller = ControllerLink(PSK, self.app, nonce_source=lambda: next(controller_nonces),
                                         controller_id=CONTROLLER_ID)
        self.app.link = self.controller
        self.host = HostLink(PSK, nonce_source=lambda: HOST_NONCE)
        self.carried: list[Carried] = []

    def carry(self) -> None:
        """Both ends polled and every frame carried across, one at a time, until neither has one to send."""
        moved = True
        while moved:
            moved = False
            self.host.poll(self.now)
            self.controller.poll(self.now)
            for sender, receiver, direction in ((self.host, self.controller, Direction.TO_CONTROLLER),
                                                (self.controller, self.host, Direction.TO_HOST)):
                wire = sender.take_frame(self.now)
                if wire is not None:
                    self.carried.append(Carried(self.now - START_S, direction, wire))
                    receiver.feed(wire, self.now)
                    self.now += FRAME_S
                    moved = True

    def connect(self) -> None:
        self.host.connect(self.now)
        self.carry()
        assert self.host.session is not None and self.controller.session is not None

    def command(self, msg: Message) -> None:
        handle = self.host.submit(msg, self.now)
        self.carry()
        assert handle.ok, handle.describe()

    def send_to_controller(self, wire: bytes) -> Optional[bytes]:
        """`wire` fed to the controller as if from the line; its answer (the first frame it sends), if any."""
        self.controller.feed(wire, self.now)
        return self.controller.take_frame(self.now)

    def next_host_counter(self) -> int:
        """A counter above every one the host used: a made-up frame the controller must not take as a replay
        (the host's own counter moves past it too)."""
        self.host.session.tx_counter += 1
        return self.host.session.tx_counter


def _session(line: _Line) -> None:
    """The session of the capture: handshake, three commands (the Enable's event), an urgent request, telemetry, the
    close (its events)."""
    line.connect()
    line.command(SCHEMA["Ping"].type(0x12345678))
    line.command(SCHEMA["GetStatus"].type())
    line.command(SCHEMA["Enable"].type())           # its StateChanged to ENABLED follows the Result
    line.command(SCHEMA["Stop"].type())             # urgent: stops motion, keeps the state
    line.controller.send_telemetry(line.app.telemetry(line.now))
    line.carry()
    handle = line.host.close(line.now, CloseWhy.DONE)
    line.carry()
    assert handle.ok and line.host.closed is not None, handle.describe()


def _keys() -> dict[str, bytes]:
    """The keys frames are signed with, by name (every derivation but the cookie's)."""
    return {d.name: result for d, result in _derivations() if d.name != "cookie"}


def handshake_json() -> dict[str, Any]:
    line = _Line()
    line.connect()
    keys = _keys()
    names = HANDSHAKE_FRAMES
    assert len(line.carried) == len(names), [c.decoded().spec.name for c in line.carried]
    assert START_S + line.carried[1].time_s == COOKIE_TIME_S
    return {
        "about": "One handshake from fixed inputs: every key derivation (HMAC-SHA256) and the frames in order. "
                 "See README.md.",
        "inputs": {"psk_hex": PSK.hex(), "host_nonce_hex": HOST_NONCE.hex(),
                   "controller_nonce_hex": CONTROLLER_NONCE.hex(), "controller_id_hex": CONTROLLER_ID.hex(),
                   "cookie_secret_hex": COOKIE_SECRET.hex(), "cookie_time_s": COOKIE_TIME_S,
                   "cookie_slot_s": COOKIE_EPOCH_S, "cookie_slot": int(COOKIE_TIME_S // COOKIE_EPOCH_S),
                   "protocol_version": PROTOCOL_VERSION, "schema_hash": f"{SCHEMA.hash:016x}"},
        "derivations": [d.vector(result) for d, result in _derivations()],
        "frames": [frame_vector(c.wire, c.direction, keys, what) for c, what in zip(line.carried, names)],
    }


def frames_json(line: _Line) -> dict[str, Any]:
    """Every frame of the capture's session after the handshake: each message class and both directions."""
    keys = _keys()
    return {"about": "The session of session.pcapng after its handshake (handshake.json): a frame of every class "
                     "(LINK, COMMAND and its replies, URGENT, TELEMETRY, EVENT), in the order sent. See README.md.",
            "frames": [frame_vector(c.wire, c.direction, keys, c.decoded().spec.name)
                       for c in line.carried[len(HANDSHAKE_FRAMES):]]}


def _made(line: _Line, cls: int, seq: int, msg_id: int, payload: bytes, key: Optional[bytes] = None,
          version: int = VERSION, flags: int = FLAG_AUTH, length: Optional[int] = None) -> bytes:
    """A frame as a peer of the controller could send it, wrong where asked: signed with `key` (the host's session
    key unless given; none if `flags` has no AUTH) over whatever header is given."""
    ack = line.host._ack_value()
    if not flags & FLAG_AUTH:
        return encode_frame(cls, seq, ack, msg_id, payload)
    counter = line.next_host_counter()
    body = HEADER.pack(version, flags, cls, seq, ack, msg_id, len(payload) if length is None else length) \
        + counter.to_bytes(framing.COUNTER_SIZE, "little") + payload
    tag = MacKey(key if key is not None else line.host.session.keys.tx.key).tag(body)
    return seal(body + tag)


def refusals_json() -> dict[str, Any]:
    """Each NAK the link sends, with the frame it refuses, made by feeding that frame to the real link."""
    keys = _keys()
    line = _Line()
    line.connect()
    ping = SCHEMA["Ping"]
    for token in (1, 2):          # two commands first: the NAKs' `ack` and `expected_seq` then say something
        line.command(ping.type(token))
    out: list[dict[str, Any]] = []

    def refused(reason: Reason, how: str, wire: bytes, answer: Optional[bytes], receiver: dict[str, Any],
                answered_by: Direction = Direction.TO_HOST) -> None:
        assert answer is not None, reason
        asked = Direction.TO_CONTROLLER if answered_by is Direction.TO_HOST else Direction.TO_HOST
        nak = frame_vector(answer, answered_by, keys, "Nak")
        assert nak["message"]["fields"][0]["value"] == int(reason), (reason, nak["message"])
        out.append({"reason": reason.name, "code": int(reason), "how": how, "receiver": receiver,
                    "refused": frame_vector(wire, asked, keys, how), "answer": nak})

    def next_seq() -> int:
        return line.controller._commands.expected

    def controller(session: str = "up") -> dict[str, Any]:
        """The refusing controller as the frame finds it: its session, the command number it expects, and the last
        counter it signed with (its answer takes the next)."""
        return {"end": "controller", "session": session, "expected_command_seq": next_seq(),
                "last_counter_sent": line.controller.session.tx_counter}

    token = ping.encode(ping.type(0xCAFE))
    expected = next_seq()         # a NAK uses up no sequence number: each of these is the next command
    pong, heartbeat, nak = SCHEMA["Pong"], SCHEMA["Heartbeat"], SCHEMA["Nak"]
    cases = [      # each made in turn (a counter above the last), and fed once
        (Reason.UNSUPPORTED_VERSION, "a Ping whose header says version 2 (signed right)",
         _made(line, MsgClass.COMMAND, expected, ping.id, token, version=2)),
        (Reason.UNSUPPORTED_FLAGS, "a Ping with flag 0x20 (must be understood, unknown) beside AUTH",
         _made(line, MsgClass.COMMAND, expected, ping.id, token, flags=FLAG_AUTH | 0x20)),
        (Reason.BAD_LENGTH, "a Ping whose length field says 5 for its 4-byte payload",
         _made(line, MsgClass.COMMAND, expected, ping.id, token, length=5)),
        (Reason.UNAUTHENTICATED, "a Ping without AUTH: no counter, no tag",
         _made(line, MsgClass.COMMAND, expected, ping.id, token, flags=0)),
        (Reason.BAD_MAC, "a Ping signed with the session's c2h key (a frame reflected back) instead of h2c",
         _made(line, MsgClass.COMMAND, expected, ping.id, token, key=keys["session_c2h"])),
        (Reason.UNKNOWN_MESSAGE, "a COMMAND frame with message id 0x0777, declared nowhere",
         _made(line, MsgClass.COMMAND, expected, 0x0777, token)),
        (Reason.WRONG_DIRECTION, "a Pong (controller -> host) sent by the host",
         _made(line, MsgClass.COMMAND, expected, pong.id, pong.encode(pong.type(0, 1, 2)))),
        (Reason.SEQUENCE_GAP, "a Ping numbered 5 beyond the next expected command (expected_seq says where)",
         _made(line, MsgClass.COMMAND, expected + 5, ping.id, token)),
        # a LINK frame whose payload does not decode is refused with a NAK (a command's, with a Result: below)
        (Reason.BAD_LENGTH, "a Heartbeat of 47 bytes, one short (its header's length says 47): the NAK names it",
         _made(line, MsgClass.LINK, 0, heartbeat.id, bytes(heartbeat.size - 1))),
        (Reason.OUT_OF_RANGE, "a Nak from the host whose reason, 200, is no reason code: the controller NAKs it",
         _made(line, MsgClass.LINK, 0, nak.id, bytes([200]) + bytes(nak.size - 1))),
    ]
    for reason, how, wire in cases:
        receiver = controller()
        refused(reason, how, wire, line.send_to_controller(wire), receiver)
        assert next_seq() == expected

    # OUT_OF_RANGE is no NAK: a command whose payload does not decode is answered with Result and the reason
    rate = SCHEMA["SetTelemetryRate"]
    carried = len(line.carried)
    receiver = controller()
    handle = line.host.submit_payload(rate, struct.pack("<H", 201), line.now)
    line.carry()
    assert handle.reason is Reason.OUT_OF_RANGE, handle.describe()
    wire, answer = (c.wire for c in line.carried[carried:carried + 2])
    out.append({"reason": "OUT_OF_RANGE", "code": int(Reason.OUT_OF_RANGE),
                "how": "a SetTelemetryRate of 201 Hz (its range is 0..200): no NAK but the command's answer, a Result "
                       "with the decoder's reason; the sequence number is used up",
                "receiver": receiver,
                "refused": frame_vector(wire, Direction.TO_CONTROLLER, keys, "SetTelemetryRate"),
                "answer": frame_vector(answer, Direction.TO_HOST, keys, "Result")})

    # REPLAY: a duplicate older than the reply cache; first enough commands to push the first out of it
    while next_seq() <= 64:
        line.command(ping.type(next_seq()))
    wire = _made(line, MsgClass.COMMAND, 0, ping.id, token)
    receiver = controller()
    refused(Reason.REPLAY, f"a Ping numbered 0 again, {next_seq()} commands later (the replies of the last 64 are "
                           "kept): a fresh counter, an old sequence number", wire, line.send_to_controller(wire),
            receiver)

    # a controller with no session (restarted, the same key and identity) answers the host's next frame
    restarted = ControllerLink(PSK, _Application(), nonce_source=lambda: COOKIE_SECRET, controller_id=CONTROLLER_ID)
    wire = _made(line, MsgClass.COMMAND, next_seq(), ping.id, token)
    restarted.feed(wire, line.now)
    refused(Reason.NO_SESSION, "the host's next Ping to a controller that restarted (no session): the NAK is signed "
                               "with the controller's NAK key and echoes the Ping's tag", wire,
            restarted.take_frame(line.now), {"end": "controller", "session": "none (it restarted)",
                                             "last_counter_sent": 0})

    # the host refuses too: an event numbered beyond the next expected, made as the controller signs (its counter
    # moved on past it)
    event = SCHEMA["StateChanged"]
    c_session = line.controller.session
    c_session.tx_counter += 1
    body = HEADER.pack(VERSION, FLAG_AUTH, MsgClass.EVENT, 3, line.controller._ack_value(), event.id,
                       event.size) + c_session.tx_counter.to_bytes(6, "little") + event.encode(
        event.type(int(ControllerState.IDLE), int(ControllerState.ENABLED), int(Reason.OK), 0, 9000))
    wire = seal(body + c_session.keys.tx.tag(body))
    host_counter = line.host.session.tx_counter
    line.host.feed(wire, line.now)
    refused(Reason.SEQUENCE_GAP, "an event numbered 3 when the host expects 0: the host NAKs it", wire,
            line.host.take_frame(line.now), {"end": "host", "session": "up", "expected_event_seq": 0,
                                             "last_counter_sent": host_counter},
            answered_by=Direction.TO_CONTROLLER)

    # SESSION_CLOSED: a command after the Close, before the host's last acknowledgement ends the linger
    line.host.close(line.now)
    line.controller.feed(line.host.take_frame(line.now), line.now)
    wire = _made(line, MsgClass.COMMAND, next_seq(), ping.id, token)
    receiver = controller("closing")
    refused(Reason.SESSION_CLOSED, "a Ping after the Close, while the closed session lingers", wire,
            line.send_to_controller(wire), receiver)
    return {"about": "Each NAK reason the link sends, with the frame it refuses (fed to the real link), and a "
                     "refusal that comes as a command's answer instead (a Result: OUT_OF_RANGE). See README.md.",
            "refusals": out}


COBS_CASES = [
    ("empty", b""),
    ("one zero", b"\x00"),
    ("two zeros", b"\x00\x00"),
    ("zeros inside", bytes.fromhex("1122003300")),
    ("no zero", bytes.fromhex("11223344")),
    ("254 bytes, none zero: one full block (code 0xFF), no zero after it", bytes(range(1, 255))),
    ("255 bytes, none zero: a full block, then a block of one", bytes(range(1, 255)) + b"\x01"),
    ("253 bytes, none zero, then a zero", bytes(range(1, 254)) + b"\x00"),
    ("254 bytes, none zero, then a zero", bytes(range(1, 255)) + b"\x00"),
]


def cobs_json() -> dict[str, Any]:
    """COBS's edge cases, encoded by the `cobs` package the framing uses (the frame-level vectors hold the rest)."""
    return {"about": "COBS (Cheshire and Baker, 1999) as the framing uses it: raw bytes -> the bytes between the "
                     "two 0x00 delimiters. See README.md.",
            "cases": [{"what": what, "raw_hex": raw.hex(), "cobs_hex": cobs.encode(raw).hex()}
                      for what, raw in COBS_CASES]}


def capture_bytes(carried: list[Carried]) -> bytes:
    """The frames as `aspod` records a session (host_tools/sessions/capture.py): pcapng, one packet a frame."""
    stream = io.BytesIO()
    writer = CaptureWriter(stream, SessionInfo(clock="simulated", tool="vectors"), (LINK,),
                           started_s=CAPTURE_STARTED_S)
    for c in carried:
        writer.write(LINK, c.direction, c.wire, c.time_s)
    data = stream.getvalue()
    writer.close()
    return data


def listing(data: bytes) -> str:
    """The capture as `aspod log session.pcapng --key-file psk.key` prints it (host_tools/cli/log.py)."""
    capture = SessionCapture(io.BytesIO(data))
    info = capture.info
    decoder = SessionDecoder(PSK)
    lines = [f"# {CAPTURE}: recorded by {info.tool} on the {info.clock} clock"]
    frames = 0
    for f in capture.frames():
        lines.append(describe(decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length)))
        frames += 1
    assert capture.error is None and not capture.warnings
    lines.append(f"# {frames} frames")
    return "\n".join(lines) + "\n"


def _json(doc: dict[str, Any]) -> bytes:
    return (json.dumps(doc, indent=1) + "\n").encode()


def build() -> dict[str, bytes]:
    """Every generated file of docs/vectors/, by name (README.md and check.py are written by hand)."""
    line = _Line()
    _session(line)
    capture = capture_bytes(line.carried)
    return {
        "psk.key": f"# The pre-shared key of the test vectors: public, for these vectors only\n{PSK.hex()}\n".encode(),
        "handshake.json": _json(handshake_json()),
        "frames.json": _json(frames_json(line)),
        "refusals.json": _json(refusals_json()),
        "cobs.json": _json(cobs_json()),
        CAPTURE: capture,
        "session.txt": listing(capture).encode(),
    }


def main(argv: Optional[list[str]] = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) > 1 or any(a.startswith("-") for a in args):
        print("usage: python -m host_tools.sessions.vectors [DIR]   (default: docs/vectors)", file=sys.stderr)
        return 2
    folder = Path(args[0]) if args else FOLDER
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in build().items():
        (folder / name).write_bytes(data)
        print(f"{folder / name}: {len(data)} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
