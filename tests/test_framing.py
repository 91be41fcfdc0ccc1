"""Property tests of the framing layer (protocol/framing.py): codec, pure finder, receiver.

The central property is the design's promise: a fault costs at most the frames it
touches. A stream of signed frames gets one fault (bit flip, dropped or inserted byte,
stray 0x00, garbage burst, truncation); the byte offsets of every frame are known, so
the frames the fault touches are computed exactly, and every other frame must arrive
intact and in order while nothing altered is ever accepted. Every stream is also fed
in arbitrary chunks, as a serial port would deliver it.
"""
from __future__ import annotations

import zlib
from dataclasses import dataclass

import pytest
from cobs import cobs
from hypothesis import given, settings, strategies as st

from protocol.errors import ParseError
from protocol.framing import (COUNTER_MAX, MAX_ENCODED, MAX_PAYLOAD, MAX_RAW, Frame, FrameReceiver,
                              decode_frame, encode_frame, find_frames)
from protocol.reasons import Reason

KEY = bytes(range(0x40, 0x60))
OTHER_KEY = bytes([KEY[0] ^ 1]) + KEY[1:]

u16 = st.integers(0, 0xFFFF)
payloads = st.binary(max_size=MAX_PAYLOAD) | st.binary(min_size=MAX_PAYLOAD - 40, max_size=MAX_PAYLOAD)
keys = st.binary(min_size=1, max_size=80)


def flip_key(key: bytes) -> bytes:
    """A different HMAC key (appending zeros would not do: HMAC pads short keys with zeros)."""
    return bytes([key[0] ^ 0x01]) + key[1:]


def identity(frame: Frame) -> tuple:
    return frame.cls, frame.seq, frame.ack, frame.msg_id, bytes(frame.payload), frame.counter


def split(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c for c in cuts if 0 < c < len(data)})
    return [data[a:b] for a, b in zip([0] + points, points + [len(data)])]


@st.composite
def chunkings(draw, data: bytes) -> list[bytes]:
    """`data` as a serial port might deliver it: at once, a byte at a time, or in random pieces."""
    how = draw(st.sampled_from(["once", "bytes", "random", "random"]))
    if how == "once":
        return [data]
    if how == "bytes" and len(data) <= 6000:
        return [data[i:i + 1] for i in range(len(data))]
    return split(data, draw(st.lists(st.integers(0, len(data)), max_size=40)))


def feed(receiver: FrameReceiver, chunks: list[bytes]) -> list[Frame | ParseError]:
    """Feed every chunk, checking the receiver's invariants after each."""
    out: list[Frame | ParseError] = []
    for chunk in chunks:
        items = receiver.feed(chunk)
        assert receiver.buffered <= MAX_ENCODED
        for item in items:
            assert isinstance(item, (Frame, ParseError)), item
        out += items
    return out


def frames_of(items) -> list[Frame]:
    return [i for i in items if isinstance(i, Frame)]


# --- encode / decode -------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(cls=st.integers(0, 255), seq=u16, ack=u16, msg_id=u16, payload=payloads,
       key=st.none() | keys, counter=st.integers(0, COUNTER_MAX))
def test_frame_round_trip(cls, seq, ack, msg_id, payload, key, counter):
    wire = encode_frame(cls, seq, ack, msg_id, payload, key=key, counter=counter)
    assert wire[0] == 0 and wire[-1] == 0 and 0 not in wire[1:-1]
    assert len(wire) - 2 <= MAX_ENCODED
    frame = decode_frame(wire[1:-1])
    assert (frame.cls, frame.seq, frame.ack, frame.msg_id, frame.payload) == (cls, seq, ack, msg_id, payload)
    if key is None:
        assert frame.counter is None and not frame.authenticated
        assert not frame.verify(KEY)
    else:
        assert frame.counter == counter and frame.authenticated
        assert frame.verify(key)
        assert not frame.verify(flip_key(key))


@pytest.mark.parametrize("counter", [0, 1, 0xFF, 0x1_0000_0000, COUNTER_MAX - 1, COUNTER_MAX])
def test_counter_is_48_bits(counter):
    frame = decode_frame(encode_frame(1, 0, 0, 0x10, b"", key=KEY, counter=counter)[1:-1])
    assert frame.counter == counter and frame.verify(KEY)


@pytest.mark.parametrize("counter", [-1, COUNTER_MAX + 1, 1 << 63])
def test_counter_outside_48_bits_is_refused(counter):
    with pytest.raises(ValueError):
        encode_frame(1, 0, 0, 0x10, b"", key=KEY, counter=counter)


def test_payload_over_maximum_is_refused():
    encode_frame(1, 0, 0, 0x10, bytes(MAX_PAYLOAD))
    with pytest.raises(ValueError):
        encode_frame(1, 0, 0, 0x10, bytes(MAX_PAYLOAD + 1))


# Fixed byte vectors. The bytes were derived once and checked by hand against the layout
# in protocol/framing.py's docstring; they are hard-coded so that any change of layout,
# byte order, COBS or CRC shows up here.
#
# encode_frame(cls=1, seq=2, ack=3, msg_id=0x10, payload=01 02), no key. Raw frame:
#   01          version 1
#   00          flags (no AUTH)
#   01          class COMMAND
#   02 00       seq 2, little-endian
#   03 00       ack 3
#   10 00       msg_id 0x0010
#   02          payload length
#   01 02       payload
#   a4 c0 dd 84 CRC-32 (zlib) of the 12 bytes above = 0x84ddc0a4, little-endian
# COBS replaces each zero by the distance to the next one (code byte = run length + 1):
#   [01] 00 -> 02 01 | [01 02] 00 -> 03 01 02 | [03] 00 -> 02 03 | [10] 00 -> 02 10 |
#   [02 01 02 a4 c0 dd 84] end -> 08 02 01 02 a4 c0 dd 84;   then 0x00 before and after.
PLAIN_WIRE = bytes.fromhex("00 02 01 03 01 02 02 03 02 10 08 02 01 02 a4 c0 dd 84 00")

# encode_frame(cls=3, seq=0x0102, ack=0x0304, msg_id=0x30, payload=aa 00 bb,
#              key=bytes(range(16)), counter=0x000000000105). Raw frame:
#   01 10 03 02 01 04 03 30 00 03    version, flags AUTH (0x10), class 3, seq, ack, msg_id, length 3
#   05 01 00 00 00 00                counter, 48-bit little-endian
#   aa 00 bb                         payload
#   60 ce e4 d4 9d 9e 4c 9b a3 32 b4 6f f1 7d 9e b3   HMAC-SHA256(key, the 19 bytes above)[:16]
#   2f ca a2 e9                      CRC-32 of everything before, little-endian
# COBS: [01 10 03 02 01 04 03 30] -> 09 ..; [03 05 01] -> 04 ..; three empty runs -> 01 01 01;
#   [aa] -> 02 aa; [bb tag crc] (21 bytes) -> 16 ...
SIGNED_KEY = bytes(range(16))
SIGNED_WIRE = bytes.fromhex(
    "00 09 01 10 03 02 01 04 03 30 04 03 05 01 01 01 01 02 aa 16 bb"
    " 60 ce e4 d4 9d 9e 4c 9b a3 32 b4 6f f1 7d 9e b3 2f ca a2 e9 00")


def test_fixed_vector_plain():
    assert encode_frame(1, 2, 3, 0x10, b"\x01\x02") == PLAIN_WIRE
    frame = decode_frame(PLAIN_WIRE[1:-1])
    assert identity(frame) == (1, 2, 3, 0x10, b"\x01\x02", None)


def test_fixed_vector_signed():
    assert encode_frame(3, 0x0102, 0x0304, 0x30, b"\xaa\x00\xbb", key=SIGNED_KEY, counter=0x105) == SIGNED_WIRE
    frame = decode_frame(SIGNED_WIRE[1:-1])
    assert identity(frame) == (3, 0x0102, 0x0304, 0x30, b"\xaa\x00\xbb", 0x105)
    assert frame.verify(SIGNED_KEY) and not frame.verify(KEY)
    assert frame.tag == bytes.fromhex("60cee4d49d9e4c9ba332b46ff17d9eb3")


def _segment(raw: bytes) -> bytes:
    """COBS segment of a raw frame with a correct CRC (to reach the checks behind the CRC)."""
    return cobs.encode(raw + zlib.crc32(raw).to_bytes(4, "little"))


def _reason(segment: bytes) -> Reason:
    with pytest.raises(ParseError) as info:
        decode_frame(segment)
    return info.value.reason


def test_decode_reasons():
    header = bytes.fromhex("01 00 01 02 00 03 00 10 00 02")
    assert decode_frame(_segment(header + b"\x01\x02")).payload == b"\x01\x02"
    assert _reason(PLAIN_WIRE[1:4] + bytes([PLAIN_WIRE[4] ^ 0x04]) + PLAIN_WIRE[5:-1]) is Reason.BAD_CRC
    assert _reason(_segment(b"\x02" + header[1:] + b"\x01\x02")) is Reason.UNSUPPORTED_VERSION
    assert _reason(_segment(header[:1] + b"\x20" + header[2:] + b"\x01\x02")) is Reason.UNSUPPORTED_FLAGS
    assert decode_frame(_segment(header[:1] + b"\x0f" + header[2:] + b"\x01\x02")).payload == b"\x01\x02"
    assert _reason(_segment(header + b"\x01")) is Reason.BAD_LENGTH
    assert _reason(_segment(header[:1] + b"\x10" + header[2:] + b"\x01\x02")) is Reason.BAD_LENGTH
    assert _reason(_segment(header[:5])) is Reason.BAD_FRAME
    assert _reason(b"\x05\x01") is Reason.BAD_FRAME                      # COBS run past the end
    assert _reason(b"\x01" * (MAX_ENCODED + 1)) is Reason.BAD_FRAME


@pytest.mark.parametrize("length", [MAX_PAYLOAD + 1, 255])
def test_decode_refuses_payload_over_maximum(length):
    """The header says 0..MAX_PAYLOAD; a frame encode_frame would refuse is not accepted either."""
    header = bytes.fromhex("01 00 01 02 00 03 00 10 00") + bytes([length])
    assert _reason(_segment(header + b"x" * length)) is Reason.BAD_LENGTH


@settings(max_examples=500, deadline=None)
@given(segment=st.binary(max_size=MAX_ENCODED + 20))
def test_decode_frame_of_arbitrary_bytes_raises_only_parse_error(segment):
    try:
        decode_frame(segment)
    except ParseError:
        pass


# --- the pure frame finder and the receiver on arbitrary bytes -------------------------------

def _valid_wire(draw) -> bytes:
    return encode_frame(draw(st.integers(0, 4)), draw(u16), draw(u16), draw(u16),
                        draw(st.binary(max_size=60)), key=draw(st.sampled_from([None, KEY])),
                        counter=draw(st.integers(0, COUNTER_MAX)))


@st.composite
def hostile_bytes(draw) -> bytes:
    """Anything: random bytes, long repeats, long runs without 0x00, and bits of valid frames."""
    parts = draw(st.lists(st.one_of(
        st.binary(max_size=600),
        st.tuples(st.binary(min_size=1, max_size=300), st.integers(1, 40)).map(lambda t: t[0] * t[1]),
        st.tuples(st.integers(1, 255), st.integers(MAX_ENCODED - 3, 2000)).map(lambda t: bytes([t[0]]) * t[1]),
        st.just(None),
    ), max_size=8))
    out = b""
    for part in parts:
        if part is None:                       # a whole or partial valid frame
            wire = _valid_wire(draw)
            a = draw(st.integers(0, len(wire)))
            b = draw(st.integers(a, len(wire)))
            part = draw(st.sampled_from([wire, wire[a:b]]))
        out += part
    return out


@settings(max_examples=250, deadline=None)
@given(data=st.data())
def test_receiver_never_raises_and_stays_bounded(data):
    stream = data.draw(hostile_bytes(), label="stream")
    chunks = data.draw(chunkings(stream), label="chunks")
    receiver = FrameReceiver()
    feed(receiver, chunks)
    # and it resynchronises: whatever came before, the next delimited frame is received
    wire = encode_frame(1, 7, 8, 0x10, b"after the storm", key=KEY, counter=99)
    frames = frames_of(feed(receiver, [wire]))
    assert frames and identity(frames[-1]) == (1, 7, 8, 0x10, b"after the storm", 99)
    assert receiver.buffered == 0


@settings(max_examples=20, deadline=None)
@given(seed=st.binary(min_size=1, max_size=64), reps=st.integers(300, 1500), data=st.data())
def test_receiver_on_large_inputs(seed, reps, data):
    stream = seed * reps                      # up to ~100 kB
    chunks = data.draw(chunkings(stream), label="chunks")
    receiver = FrameReceiver()
    feed(receiver, chunks)


@settings(max_examples=500, deadline=None)
@given(buf=st.binary(max_size=1000) | hostile_bytes())
def test_find_frames_consumes_up_to_the_last_delimiter(buf):
    segments, consumed = find_frames(buf)
    assert 0 <= consumed <= len(buf)
    assert consumed == 0 or buf[consumed - 1] == 0
    assert 0 not in buf[consumed:], "bytes after the last delimiter stay for the next read"
    assert (consumed == 0) == (0 not in buf)
    assert all(seg and 0 not in seg for seg in segments)
    assert segments == [s for s in buf[:consumed].split(b"\x00") if s]


# --- streams of valid frames -----------------------------------------------------------------

@dataclass
class Stream:
    data: bytes
    spans: list[tuple[int, int]]       # [start, end) of each frame's wire bytes, delimiters included
    ids: list[tuple]                   # identity() of each frame


def build_stream(specs, key: bytes | None, counter0: int) -> Stream:
    data, spans, ids = b"", [], []
    for n, (cls, seq, ack, msg_id, payload) in enumerate(specs):
        counter = counter0 + n
        wire = encode_frame(cls, seq, ack, msg_id, payload, key=key, counter=counter)
        spans.append((len(data), len(data) + len(wire)))
        ids.append((cls, seq, ack, msg_id, payload, counter if key is not None else None))
        data += wire
    return Stream(data, spans, ids)


frame_specs = st.tuples(st.integers(0, 4), u16, u16, u16, payloads)


@settings(max_examples=120, deadline=None)
@given(specs=st.lists(frame_specs, min_size=1, max_size=15), key=st.none() | st.just(KEY),
       counter0=st.integers(0, 1 << 40), data=st.data())
def test_chunking_invariance(specs, key, counter0, data):
    stream = build_stream(specs, key, counter0)
    at_once = feed(FrameReceiver(), [stream.data])
    assert [identity(f) for f in at_once] == stream.ids       # all Frames, none lost
    chunked = feed(FrameReceiver(), data.draw(chunkings(stream.data), label="chunks"))
    assert chunked == at_once


@settings(max_examples=120, deadline=None)
@given(specs=st.lists(frame_specs, min_size=1, max_size=8), data=st.data())
def test_chunking_invariance_with_garbage_between_frames(specs, data):
    """Frames (and, while no segment is over-long, every item) do not depend on chunking."""
    stream = build_stream(specs, KEY, 1)
    mixed = b""
    for start, end in stream.spans:
        mixed += data.draw(hostile_bytes(), label="garbage") + stream.data[start:end]
    at_once = feed(FrameReceiver(), [mixed])
    chunked = feed(FrameReceiver(), data.draw(chunkings(mixed), label="chunks"))
    assert [identity(f) for f in frames_of(chunked)] == [identity(f) for f in frames_of(at_once)]
    received = iter(identity(f) for f in frames_of(at_once))   # garbage may hold valid frames too
    assert all(ident in received for ident in stream.ids), "every frame arrives, in order"
    if all(len(s) <= MAX_ENCODED for s in mixed.split(b"\x00")):
        def view(items):
            return [identity(i) if isinstance(i, Frame) else i.reason for i in items]
        assert view(chunked) == view(at_once)


FAULTS = ["flip", "drop", "insert", "zero", "burst", "overwrite", "truncate"]


@settings(max_examples=400, deadline=None)
@given(specs=st.lists(frame_specs, min_size=5, max_size=20), counter0=st.integers(0, 1 << 40),
       kind=st.sampled_from(FAULTS), data=st.data())
def test_single_fault_costs_at_most_the_frames_it_touches(specs, counter0, kind, data):
    stream = build_stream(specs, KEY, counter0)
    raw, spans, n = stream.data, stream.spans, len(stream.data)
    indices = range(len(spans))

    def inside(p: int) -> set[int]:            # an insertion before byte p lands inside these
        return {i for i in indices if spans[i][0] < p < spans[i][1]}

    def covering(a: int, b: int) -> set[int]:  # frames with a byte in [a, b)
        return {i for i in indices if spans[i][0] < b and a < spans[i][1]}

    sent = list(indices)                       # frames whose bytes (or part of them) were sent
    extra: list[tuple] = []
    if kind == "flip":
        p = data.draw(st.integers(0, n - 1), label="pos")
        bit = data.draw(st.integers(0, 7), label="bit")
        faulty = raw[:p] + bytes([raw[p] ^ (1 << bit)]) + raw[p + 1:]
        touched = covering(p, p + 1)
    elif kind == "drop":
        p = data.draw(st.integers(0, n - 1), label="pos")
        faulty = raw[:p] + raw[p + 1:]
        touched = covering(p, p + 1)
    elif kind in ("insert", "zero", "burst"):
        p = data.draw(st.integers(0, n), label="pos")
        if kind == "insert":
            junk = bytes([data.draw(st.integers(0, 255), label="byte")])
        elif kind == "zero":
            junk = b"\x00"
        else:
            junk = data.draw(st.binary(min_size=1, max_size=700)
                             | st.integers(1, 2 * MAX_ENCODED).map(lambda k: b"\x5a" * k), label="burst")
        faulty = raw[:p] + junk + raw[p:]
        touched = inside(p)
    elif kind == "overwrite":
        p = data.draw(st.integers(0, n - 1), label="pos")
        junk = data.draw(st.binary(min_size=1, max_size=700), label="burst")[: n - p]
        faulty = raw[:p] + junk + raw[p + len(junk):]
        touched = covering(p, p + len(junk))
    else:  # truncate: the line is cut at p, then further valid frames follow
        p = data.draw(st.integers(0, n), label="cut")
        more = data.draw(st.lists(frame_specs, min_size=1, max_size=4), label="after the cut")
        after = build_stream(more, KEY, counter0 + len(specs))
        faulty = raw[:p] + after.data
        sent = [i for i in indices if spans[i][0] < p]
        touched = inside(p)
        extra = after.ids

    all_ids = stream.ids + extra
    position = {ident: k for k, ident in enumerate(all_ids)}   # counters make every frame unique
    may_arrive = set(sent) | set(range(len(specs), len(all_ids)))
    must_arrive = may_arrive - touched

    receiver = FrameReceiver()
    items = feed(receiver, data.draw(chunkings(faulty), label="chunks"))
    got = []
    for frame in frames_of(items):
        # (a) nothing altered is accepted: every frame that passed the CRC is an original
        assert identity(frame) in position, f"{kind} at {p}: accepted an altered frame {frame}"
        assert frame.verify(KEY)
        got.append(position[identity(frame)])
    # (b) in order, no duplicates, nothing that was never sent, only touched frames lost
    assert got == sorted(set(got)), f"{kind} at {p}: out of order or duplicated: {got}"
    assert set(got) <= may_arrive
    assert must_arrive <= set(got), f"{kind} at {p}: lost {sorted(must_arrive - set(got))}, touched {touched}"


@pytest.mark.parametrize("kind", ["zero", "burst"])
def test_fault_exactly_between_frames_loses_nothing(kind):
    stream = build_stream([(1, i, 0, 0x10, bytes([i]) * 30) for i in range(6)], KEY, 1)
    boundary = stream.spans[3][0]
    junk = b"\x00" if kind == "zero" else bytes(range(1, 200)) * 3
    faulty = stream.data[:boundary] + junk + stream.data[boundary:]
    for chunks in ([faulty], [faulty[i:i + 1] for i in range(len(faulty))]):
        assert [identity(f) for f in frames_of(feed(FrameReceiver(), chunks))] == stream.ids


# --- the oversize rule -----------------------------------------------------------------------

def _oversize_stream(length: int, fill: int = 0x77) -> tuple[bytes, list[tuple], int]:
    """Frame A, then `length` bytes without 0x00, then frame B (with its leading delimiter).

    Also returns the offset of B's leading delimiter, where the over-long segment ends.
    """
    stream = build_stream([(1, 1, 0, 0x10, b"A" * 20), (1, 2, 0, 0x10, b"B" * 20)], KEY, 5)
    (a0, a1), (b0, b1) = stream.spans
    return stream.data[a0:a1] + bytes([fill]) * length + stream.data[b0:b1], stream.ids, a1 + length


oversize_lengths = st.integers(MAX_ENCODED + 1, 4 * MAX_ENCODED)


@settings(max_examples=100, deadline=None)
@given(length=oversize_lengths, fill=st.integers(1, 255), data=st.data())
def test_oversize_segment_is_dropped_and_next_frame_received(length, fill, data):
    stream, ids, b_start = _oversize_stream(length, fill)
    assert stream[b_start] == 0 and stream[b_start - 1] == fill
    # at random, and with a read ending exactly where the over-long segment ends
    for chunks in (data.draw(chunkings(stream), label="chunks"),
                   [stream[:b_start], stream[b_start:]], [stream[:b_start + 1], stream[b_start + 1:]]):
        receiver = FrameReceiver()
        items = feed(receiver, chunks)
        assert [identity(f) for f in frames_of(items)] == ids
        assert receiver.buffered == 0


@settings(max_examples=100, deadline=None)
@given(length=oversize_lengths, data=st.data())
def test_oversize_segment_is_counted_once_in_overflows(length, data):
    """One over-long segment is one overflow, however the bytes arrive."""
    stream, _, _ = _oversize_stream(length)
    receiver = FrameReceiver()
    feed(receiver, data.draw(chunkings(stream), label="chunks"))
    assert receiver.overflows == 1


@pytest.mark.parametrize("how", ["at once", "byte by byte"])
def test_oversize_segment_counted_in_overflows_example(how):
    stream, ids, _ = _oversize_stream(1000)
    chunks = [stream] if how == "at once" else [stream[i:i + 1] for i in range(len(stream))]
    receiver = FrameReceiver()
    frames = frames_of(feed(receiver, chunks))
    assert [identity(f) for f in frames] == ids
    assert receiver.overflows == 1


def _longest_frame() -> bytes:
    """A signed frame with a full payload whose raw bytes hold no 0x00: COBS makes it MAX_ENCODED long."""
    for counter in range(0x010101010101, 0x010101010101 + 1000):
        wire = encode_frame(1, 0x0101, 0x0101, 0x0101, b"\x11" * MAX_PAYLOAD, key=KEY, counter=counter)
        if len(wire) - 2 == MAX_ENCODED:
            return wire
    raise AssertionError("no zero-free frame found")


def test_longest_frame_is_not_oversize():
    wire = _longest_frame()
    assert len(cobs.decode(wire[1:-1])) == MAX_RAW
    receiver = FrameReceiver()
    frames = frames_of(feed(receiver, [wire[i:i + 1] for i in range(len(wire))]))
    assert len(frames) == 1 and frames[0].verify(KEY)
    assert receiver.overflows == 0
    # one byte more without a delimiter is over the limit
    receiver = FrameReceiver()
    feed(receiver, [b"\x00" + b"\x11" * (MAX_ENCODED + 1)])
    assert receiver.overflows == 1 and receiver.buffered == 0


@pytest.mark.parametrize("key_len", [16, 32, 64, 65, 100])
def test_prepared_mac_key_gives_the_standard_hmac_sha256_tag(key_len):
    import hmac as std_hmac
    import os
    from protocol.framing import MacKey
    key, data = os.urandom(key_len), os.urandom(77)
    assert MacKey(key).tag(data) == std_hmac.digest(key, data, "sha256")[:16]
