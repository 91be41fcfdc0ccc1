"""Frames on the wire: COBS between 0x00 delimiters, a fixed header, optional MAC, CRC-32.

Raw frame (before COBS), little-endian::

    off  size  field
    0    1     version           protocol version (1)
    1    1     flags             bits 0-3 may be ignored; bits 4-7 must be understood
                                 (bit 4 AUTH: counter and tag present)
    2    1     class             MsgClass
    3    2     seq               sequence number of this frame in its class's stream
    5    2     ack               piggybacked ack: last in-order reliable seq received
    7    2     msg_id            message id (protocol/messages.py)
    9    1     length            payload length, 0..MAX_PAYLOAD
    10   6     counter           [AUTH] 48-bit strictly increasing per direction
    ..   n     payload
    ..   16    tag               [AUTH] HMAC-SHA256(key, all bytes before the tag)[:16]
    ..   4     crc               CRC-32 (zlib/IEEE 802.3) of all bytes before it

On the wire each frame is ``0x00 COBS(raw) 0x00``. A fault can therefore cost at most
the frames it touches: the next delimiter always resynchronises. CRC-32 detects all
errors of up to 4 bits (Hamming distance 5) for data up to 2974 bits (Koopman,
"32-bit CRCs for embedded networks", DSN 2002); the longest raw frame here is 276
bytes, 2176 bits before the CRC.

`find_frames` is the pure frame finder (bytes in; frames and bytes consumed out),
`FrameReceiver` keeps the bounded remainder between reads, `decode_frame` checks one
frame, and `encode_frame` builds one.
"""
from __future__ import annotations

import hashlib
import hmac
import struct
import zlib
from dataclasses import dataclass
from typing import Optional

from cobs import cobs

from protocol.errors import ParseError
from protocol.reasons import Reason

VERSION = 1
FLAG_AUTH = 0x10
KNOWN_FLAGS = FLAG_AUTH
MUST_UNDERSTAND_MASK = 0xF0

MAX_PAYLOAD = 240
HEADER = struct.Struct("<BBBHHHB")
HEADER_SIZE = HEADER.size                 # 10
# HEADER's fields in order, with what each holds (the table above; `aspod schema --json` gives their offsets)
HEADER_FIELDS = (
    ("version", "protocol version (VERSION)"),
    ("flags", "bits 0-3 may be ignored; bits 4-7 must be understood (bit 4 AUTH: counter and tag present)"),
    ("class", "MsgClass: how the frame is delivered"),
    ("seq", "sequence number of this frame in its class's stream"),
    ("ack", "piggybacked ack: last in-order reliable sequence number received from the peer"),
    ("msg_id", "message id (protocol/messages.py)"),
    ("length", "payload length, 0..MAX_PAYLOAD"),
)
assert len(HEADER_FIELDS) == len(HEADER.unpack(bytes(HEADER_SIZE)))
COUNTER_SIZE = 6
TAG_SIZE = 16
CRC_SIZE = 4
MIN_RAW = HEADER_SIZE + CRC_SIZE
MAX_RAW = HEADER_SIZE + COUNTER_SIZE + MAX_PAYLOAD + TAG_SIZE + CRC_SIZE   # 276
MAX_ENCODED = MAX_RAW + MAX_RAW // 254 + 1                                 # COBS worst case
COUNTER_MAX = (1 << 48) - 1

# The CRC is zlib's crc32 (CRC-32/ISO-HDLC: IEEE 802.3, PKZIP), in the parameters of Williams's model as the
# CRC catalogue (reveng) gives them: a client's CRC library takes these. Appended little-endian.
CRC_WIDTH = 32
CRC_POLY = 0x04C11DB7
CRC_INIT = 0xFFFFFFFF
CRC_REFIN = True
CRC_REFOUT = True
CRC_XOROUT = 0xFFFFFFFF
CRC_CHECK = 0xCBF43926                    # the CRC of b"123456789"
assert zlib.crc32(b"123456789") == CRC_CHECK

_CRC = struct.Struct("<I")
_cobs_encode = cobs.encode
_cobs_decode = cobs.decode
_crc32 = zlib.crc32
_compare = hmac.compare_digest


class MacKey:
    """HMAC-SHA256 (RFC 2104) with the key's inner and outer states computed once.

    `hmac.digest(key, ...)` sets the key up again for every frame; copying two
    prepared SHA-256 states is about three times cheaper and gives the same tag.
    """

    __slots__ = ("key", "_inner", "_outer")

    def __init__(self, key: bytes) -> None:
        self.key = bytes(key)
        block = hashlib.sha256(self.key).digest() if len(self.key) > 64 else self.key
        block = block.ljust(64, b"\x00")
        self._inner = hashlib.sha256(bytes(b ^ 0x36 for b in block))
        self._outer = hashlib.sha256(bytes(b ^ 0x5C for b in block))

    def tag(self, data: bytes) -> bytes:
        inner = self._inner.copy()
        inner.update(data)
        outer = self._outer.copy()
        outer.update(inner.digest())
        return outer.digest()[:TAG_SIZE]


def mac_key(key: "bytes | MacKey") -> MacKey:
    return key if isinstance(key, MacKey) else MacKey(key)


@dataclass(slots=True)
class Frame:
    """A frame whose CRC checked out. Authentication is checked separately (`verify`)."""

    cls: int
    seq: int
    ack: int
    msg_id: int
    payload: bytes
    counter: Optional[int] = None      # None: the frame carries no MAC
    signed: bytes = b""                # the bytes the tag covers
    tag: bytes = b""

    @property
    def authenticated(self) -> bool:
        return self.counter is not None

    def verify(self, key: "bytes | MacKey") -> bool:
        """True if the frame carries a tag and it is right for `key`."""
        if self.counter is None:
            return False
        return _compare(mac_key(key).tag(self.signed), self.tag)


def encode_frame(cls: int, seq: int, ack: int, msg_id: int, payload: bytes,
                 key: "bytes | MacKey | None" = None, counter: int = 0) -> bytes:
    """Wire bytes of one frame, delimiters included. With `key`, the frame is signed."""
    if key is not None:
        return encode_signed(cls, seq, ack, msg_id, payload, key, counter)[0]
    n = len(payload)
    if n > MAX_PAYLOAD:
        raise ValueError(f"payload of {n} bytes exceeds the {MAX_PAYLOAD}-byte maximum")
    return seal(HEADER.pack(VERSION, 0, cls, seq, ack, msg_id, n) + payload)


def encode_signed(cls: int, seq: int, ack: int, msg_id: int, payload: bytes,
                  key: "bytes | MacKey", counter: int) -> tuple[bytes, bytes]:
    """Wire bytes of one signed frame, delimiters included, and its tag (which a NAK of it echoes)."""
    n = len(payload)
    if n > MAX_PAYLOAD:
        raise ValueError(f"payload of {n} bytes exceeds the {MAX_PAYLOAD}-byte maximum")
    if not 0 <= counter <= COUNTER_MAX:
        raise ValueError(f"counter {counter} does not fit in 48 bits")
    signed = HEADER.pack(VERSION, FLAG_AUTH, cls, seq, ack, msg_id, n) + counter.to_bytes(6, "little") + payload
    tag = mac_key(key).tag(signed)
    return seal(signed + tag), tag


def seal(body: bytes) -> bytes:
    """Wire bytes of a raw frame's `body` (everything before the CRC): its CRC-32 appended, COBS-encoded,
    delimited. The encoders above check what goes into `body`; a fuzzer calls this with anything."""
    raw = body + _CRC.pack(_crc32(body))
    return b"\x00" + _cobs_encode(raw) + b"\x00"


def decode_frame(segment: bytes) -> Frame:
    """Check one COBS segment (without delimiters) and return its frame.

    Raises `ParseError` with BAD_FRAME, BAD_CRC, UNSUPPORTED_VERSION,
    UNSUPPORTED_FLAGS or BAD_LENGTH; nothing else.
    """
    if len(segment) > MAX_ENCODED:
        raise ParseError(Reason.BAD_FRAME, f"segment of {len(segment)} bytes is longer than any frame")
    try:
        raw = _cobs_decode(segment)
    except cobs.DecodeError as exc:
        raise ParseError(Reason.BAD_FRAME, f"not valid COBS: {exc}") from None
    size = len(raw)
    if size < MIN_RAW:
        raise ParseError(Reason.BAD_FRAME, f"{size} bytes is shorter than a header and CRC")
    if _crc32(memoryview(raw)[:-CRC_SIZE]) != _CRC.unpack_from(raw, size - CRC_SIZE)[0]:
        raise ParseError(Reason.BAD_CRC, "CRC-32 mismatch")
    version, flags, cls, seq, ack, msg_id, length = HEADER.unpack_from(raw)
    if length > MAX_PAYLOAD:
        raise ParseError(Reason.BAD_LENGTH, f"length field {length} exceeds the {MAX_PAYLOAD}-byte maximum")
    if version != VERSION:
        raise ParseError(Reason.UNSUPPORTED_VERSION, f"version {version}, this end speaks {VERSION}")
    if flags & MUST_UNDERSTAND_MASK & ~KNOWN_FLAGS:
        raise ParseError(Reason.UNSUPPORTED_FLAGS, f"unknown must-understand flags {flags & 0xF0 & ~KNOWN_FLAGS:#04x}")
    if flags & FLAG_AUTH:
        end = HEADER_SIZE + COUNTER_SIZE + length
        if end + TAG_SIZE + CRC_SIZE != size:
            raise ParseError(Reason.BAD_LENGTH, f"length field {length} does not match a {size}-byte frame")
        return Frame(cls, seq, ack, msg_id, raw[HEADER_SIZE + COUNTER_SIZE:end],
                     int.from_bytes(raw[HEADER_SIZE:HEADER_SIZE + COUNTER_SIZE], "little"),
                     raw[:end], raw[end:end + TAG_SIZE])
    if HEADER_SIZE + length + CRC_SIZE != size:
        raise ParseError(Reason.BAD_LENGTH, f"length field {length} does not match a {size}-byte frame")
    return Frame(cls, seq, ack, msg_id, raw[HEADER_SIZE:HEADER_SIZE + length])


def find_frames(buf: bytes) -> tuple[list[bytes], int]:
    """The pure frame finder: the complete segments in `buf` and how many bytes they used.

    A segment is what lies between two 0x00 delimiters (empty ones are skipped).
    Bytes after the last delimiter are not consumed: they may be the start of a frame.
    Segments longer than any frame are returned too; `decode_frame` refuses them.
    """
    last = buf.rfind(b"\x00")
    if last < 0:
        return [], 0
    return [s for s in buf[:last].split(b"\x00") if s], last + 1


class FrameReceiver:
    """Keeps the bytes of a frame not yet ended (since the last delimiter), never more than `MAX_ENCODED`.

    `feed` returns, in order, a `Frame` or a `ParseError` for every segment found.
    A partial segment that grows past the longest frame is dropped (counted in
    `overflows`) together with the rest of it up to the next delimiter.
    """

    __slots__ = ("_pending", "_skipping", "overflows")

    def __init__(self) -> None:
        self._pending = b""
        self._skipping = False
        self.overflows = 0

    @property
    def buffered(self) -> int:
        return len(self._pending)

    def feed(self, data: bytes) -> list[Frame | ParseError]:
        buf = self._pending + data if self._pending else bytes(data)
        segments, consumed = find_frames(buf)
        rest = buf[consumed:]
        if consumed and self._skipping:
            # the first segment is the tail of an over-long one already dropped
            self._skipping = False
            if buf[0] != 0:
                segments = segments[1:]
        if self._skipping:
            rest = b""            # still inside an over-long segment already counted
        elif len(rest) > MAX_ENCODED:
            self.overflows += 1
            rest = b""
            self._skipping = True
        self._pending = rest
        out: list[Frame | ParseError] = []
        for segment in segments:
            if len(segment) > MAX_ENCODED:   # counted the same however the bytes were chunked
                self.overflows += 1
            try:
                out.append(decode_frame(segment))
            except ParseError as exc:
                out.append(exc)
        return out
