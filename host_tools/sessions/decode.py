"""Frames of a session, decoded: header, message and fields, MAC verdict, or what is wrong.

`SessionDecoder` turns wire segments into `DecodedFrame`s, one at a time in the order they were
seen, so the same code serves a capture read back (`aspod log`) and the proxy's live view. Given
the pre-shared key it follows the handshakes as the two ends do (protocol/auth.py): a Hello or
HelloReply is checked with the handshake key of its direction, and once a Hello's nonce is
answered by a HelloReply, that session's keys check the frames after it. Without the key, MACs
are shown as not checked, never as good.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Optional

from protocol import auth
from protocol.errors import ParseError
from protocol.framing import Frame, MacKey, decode_frame
from protocol.messages import SCHEMA
from protocol.schema import Direction, Message, MsgClass

MAC_OK, MAC_BAD, MAC_NONE, MAC_UNCHECKED = "ok", "BAD", "none", "unchecked"
SESSIONS_KEPT = 4      # handshakes whose keys stay candidates (a pending Hello may be answered late)
ARROW = {Direction.TO_CONTROLLER: "H>C", Direction.TO_HOST: "C>H"}


@dataclass
class DecodedFrame:
    """One wire segment and all that could be read from it."""

    time_s: float
    link: str
    direction: Direction
    size: int
    frame: Optional[Frame] = None
    message: Optional[Message] = None
    error: str = ""                 # why the frame or its message could not be read ("" if both could)
    mac: str = MAC_UNCHECKED

    @property
    def name(self) -> str:
        if self.message is not None:
            return self.message.spec.name
        if self.frame is not None:
            spec = SCHEMA.by_id.get(self.frame.msg_id)
            return spec.name if spec else f"id {self.frame.msg_id:#06x}"
        return "(not a frame)"

    @property
    def class_name(self) -> str:
        if self.frame is None:
            return "-"
        try:
            return MsgClass(self.frame.cls).name
        except ValueError:
            return f"class {self.frame.cls}"

    def fields(self) -> dict[str, Any]:
        return {} if self.message is None else self.message.as_dict()


class SessionDecoder:
    """Decodes segments in order; keeps only the last few handshakes' keys."""

    def __init__(self, psk: Optional[bytes] = None) -> None:
        self._psk = psk
        if psk is not None:
            hs = auth.handshake_keys(psk, is_controller=False)
            self._handshake = {Direction.TO_CONTROLLER: hs.tx, Direction.TO_HOST: hs.rx}
        self._hellos: deque[bytes] = deque(maxlen=SESSIONS_KEPT)
        self._sessions: deque[dict[Direction, MacKey]] = deque(maxlen=SESSIONS_KEPT)
        self._nak_keys: deque[MacKey] = deque(maxlen=SESSIONS_KEPT)     # the controllers' (HelloReply's identity)

    def decode(self, segment: bytes, time_s: float, link: str, direction: Direction,
               original_length: Optional[int] = None) -> DecodedFrame:
        out = DecodedFrame(time_s, link, direction, len(segment) if original_length is None else original_length)
        if original_length is not None and original_length != len(segment):
            out.error = f"BAD_FRAME: {original_length} bytes between delimiters, longer than any frame"
            return out
        try:
            frame = decode_frame(segment)
        except ParseError as exc:
            out.error = f"{exc.reason.name}: {exc.detail}"
            return out
        out.frame = frame
        out.mac = self._check_mac(frame, direction)
        try:
            out.message = SCHEMA.decode(frame.msg_id, frame.payload)
        except ParseError as exc:
            out.error = f"{exc.reason.name}: {exc.detail}"
            return out
        if out.mac != MAC_BAD:
            self._follow_handshake(out.message)
        return out

    def mac_verdict(self, frame: Frame, direction: Direction) -> str:
        """The MAC verdict of `frame` under the keys followed so far, nothing learned from it."""
        return self._check_mac(frame, direction)

    def _check_mac(self, frame: Frame, direction: Direction) -> str:
        if frame.counter is None:
            return MAC_NONE
        if self._psk is None:
            return MAC_UNCHECKED
        if frame.cls == MsgClass.LINK and frame.msg_id in HANDSHAKE_IDS:
            return MAC_OK if frame.verify(self._handshake[direction]) else MAC_BAD
        for keys in reversed(self._sessions):
            if frame.verify(keys[direction]):
                return MAC_OK
        if frame.msg_id == NAK_ID:
            # with no session, a controller signs its NAKs with its NAK key, a host with the handshake key
            keys = self._nak_keys if direction is Direction.TO_HOST else [self._handshake[direction]]
            if any(frame.verify(key) for key in keys):
                return MAC_OK
        return MAC_BAD

    def _follow_handshake(self, message: Message) -> None:
        if self._psk is None:
            return
        name = message.spec.name
        if name == "Hello":
            self._hellos.append(message.host_nonce)
        elif name == "HelloReply" and message.host_nonce in self._hellos:
            keys = auth.session_keys(self._psk, message.host_nonce, message.controller_nonce, is_controller=False)
            self._sessions.append({Direction.TO_CONTROLLER: keys.tx, Direction.TO_HOST: keys.rx})
            self._nak_keys.append(auth.nak_key(self._psk, message.controller_id))


HANDSHAKE_IDS = frozenset(SCHEMA[name].id for name in ("Hello", "HelloReply", "HelloCookie"))
NAK_ID = SCHEMA["Nak"].id


def format_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (bytes, bytearray)):
        return value.hex()
    return str(value)


def message_text(decoded: DecodedFrame) -> str:
    """The message as `Name(field=value, ...)`, enumerations by name (`MotionDone(axis=J1, ...)`)."""
    enum_names = {f.name: f.enum for f in decoded.message.spec.fields if f.enum} if decoded.message else {}
    parts = []
    for name, value in decoded.fields().items():
        kind = enum_names.get(name)
        if kind is not None:
            try:
                value = kind(value).name
            except ValueError:
                pass
        parts.append(f"{name}={format_value(value)}")
    return f"{decoded.name}({', '.join(parts)})"


def describe(decoded: DecodedFrame, origin_s: float = 0.0) -> str:
    """One line: time, link, direction, class, seq/ack, message and fields or the error, MAC verdict."""
    head = f"{decoded.time_s - origin_s:12.6f} {decoded.link:<8} {ARROW[decoded.direction]}"
    frame = decoded.frame
    if frame is None:
        return f"{head} {'-':<9} {decoded.size:4d} B  {decoded.error}"
    body = message_text(decoded) if decoded.message else f"{decoded.name}  {decoded.error}"
    return (f"{head} {decoded.class_name:<9} seq={frame.seq:<5d} ack={frame.ack:<5d} {body}"
            f"  mac={decoded.mac}")
