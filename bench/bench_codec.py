"""Codec throughput: our frames beside pymavlink's MAVLink 2 frames, in the same run.

Both sides carry a payload of the same length, whatever length `TelemetryStatus` has today:

* ours: `TelemetryStatus` (57 bytes as of issue 35), class TELEMETRY, built with `encode_frame`
  (COBS, header, CRC-32, and with a key a 48-bit counter and a 16-byte
  HMAC-SHA256 tag) and read back by a `FrameReceiver` fed 4 KiB chunks, then
  `SCHEMA.decode` (range and enum checks included). Authenticated decode also
  checks every tag (`Frame.verify`) and that counters strictly increase, as the
  link does before it accepts a frame. Every field holds a valid value, non-zero
  where its type allows (`_our_value`).
* pymavlink: the message of the `common` dialect whose MAVLink 2 payload (extensions
  included) has exactly our payload's length, chosen at run time (`mav_peer`): of those
  without text fields, the one with the field count nearest ours (then the lowest id),
  so both codecs unpack a like number of fields (57 bytes: `GPS2_RAW`, id 124, 18 fields
  against our 17). Every field is non-zero, so MAVLink 2's trailing-zero truncation
  leaves the whole payload on the wire. Encode is `msg.pack(mav)`; decode is
  `MAVLink.parse_buffer` fed the same 4 KiB chunks. Signed frames use MAVLink 2 signing
  (SHA-256 of key and frame, 6 bytes kept, 48-bit timestamp checked per stream).
  Should no message have our length, the nearest does (the longer of two as near) and
  the ratios are taken per payload byte instead of per frame: the report says which.

Each figure is the best of several rounds (frames / seconds, `RealClock.precise_now`,
garbage collector paused while timing, as `timeit` does); within a round the
contenders take turns, so load from elsewhere on the machine hits them alike. Every repeat's output is
checked afterwards: encoders must give the reference bytes, decoders must give back
every original message, equal field for field, so no side can win by skipping work.
"""
from __future__ import annotations

import gc
import os
import struct
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

from protocol.framing import FrameReceiver, encode_frame, MacKey
from protocol.messages import SCHEMA
from protocol.schema import Field, MsgClass
from timebase import RealClock

CHUNK_BYTES = 4096
KEY = bytes(range(1, 33))                   # 32-byte key, both sides
OURS = "TelemetryStatus"
MAV_SIGNING_T0 = 1_000_000                  # first signing timestamp (10 us units)


class BenchError(AssertionError):
    """A benchmark's output did not check out: its figures would be meaningless."""


Prepare = Callable[[], Callable[[], Any]]   # untimed set-up returning the timed run
Check = Callable[[Any], None]                # checks a run's output; raises BenchError


@dataclass
class Row:
    """One contender: its measures (column -> set-up and check) and, once run, its rates."""

    name: str
    wire_bytes: int
    payload_bytes: int = 0
    measures: dict[str, tuple[Prepare, Check]] = field(default_factory=dict, repr=False)
    best_s: dict[str, float] = field(default_factory=dict)
    frames: int = 0
    optional: bool = False      # a failure is reported in `note` instead of stopping the benchmark
    note: str = ""

    def fps(self, column: str) -> Optional[float]:
        best = self.best_s.get(column)
        return None if best is None else self.frames / best

    def payload_bps(self, column: str) -> Optional[float]:
        """Payload bytes a second: what the ratios compare when the two sides' payloads differ in length."""
        fps = self.fps(column)
        return None if fps is None else fps * self.payload_bytes

    @property
    def encode_fps(self) -> Optional[float]:
        return self.fps("encode")

    @property
    def decode_fps(self) -> Optional[float]:
        return self.fps("decode")

    @property
    def both_fps(self) -> Optional[float]:
        return self.fps("both")


@dataclass
class CodecResult:
    frames: int
    repeats: int
    payload_bytes: int = 0
    peer: str = ""              # the MAVLink message compared with ours, and why it
    per_byte: bool = False      # the peer's payload is not as long as ours: ratios per payload byte
    rows: list[Row] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


# ---------------------------------------------------------------- timing

COLUMNS = ("encode", "decode", "both")


def _time_once(prepare: Prepare, check: Check) -> float:
    """Seconds of one run (set-up untimed, collector paused); its output is checked afterwards."""
    run = prepare()                     # fresh receivers and encoders, untimed
    gc.collect()
    gc.disable()
    try:
        t0 = RealClock.precise_now()
        out = run()
        elapsed = RealClock.precise_now() - t0
    finally:
        gc.enable()
    check(out)
    return elapsed


def measure(rows: list[Row], repeats: int) -> None:
    """Best time of each measure over `repeats` rounds, contenders interleaved within a round.

    Interleaving means a burst of load from elsewhere on the machine hits every
    contender alike instead of one whole row, which keeps the ratios honest.
    A contender that fails mid-way keeps its reason in `note` and loses its figures.
    """
    for _ in range(repeats):
        for column in COLUMNS:
            for row in rows:
                if column not in row.measures:
                    continue
                try:
                    elapsed = _time_once(*row.measures[column])
                except Exception as exc:   # an optional contender's failure is reported, not hidden
                    if not row.optional:
                        raise
                    row.note = f"not measured: {type(exc).__name__}: {exc}"
                    row.measures.clear()
                    row.best_s.clear()
                    continue
                row.best_s[column] = min(elapsed, row.best_s.get(column, float("inf")))


def _chunks(stream: bytes) -> list[bytes]:
    return [stream[i:i + CHUNK_BYTES] for i in range(0, len(stream), CHUNK_BYTES)]


def _check_equal_bytes(reference: list[bytes], what: str) -> Callable[[list[bytes]], None]:
    def check(out: list[bytes]) -> None:
        if out != reference:
            raise BenchError(f"{what}: encoded bytes differ from the reference")
    return check


# ---------------------------------------------------------------- ours

_F32 = struct.Struct("<f")


def _our_value(f: Field, i: int):
    """A valid value of field `f` for message `i`: non-zero where the type allows, in the declared range, an f32
    exactly as it goes on the wire (so the decoded message compares equal), varied from one message to the next."""
    if f.enum is not None:
        members = [int(m) for m in f.enum if int(m)] or [int(m) for m in f.enum]
        return members[i % len(members)]
    if f.type == "bool":
        return 1
    if f.type == "f32":
        lo, hi = f.range if f.range is not None else (-1000.0, 1000.0)
        return _F32.unpack(_F32.pack(lo + (hi - lo) * (1 + 2 * (i % 8)) / 16))[0]   # never the middle
    if f.type.startswith("bytes"):
        return bytes((i + k) % 255 + 1 for k in range(f.text_size))
    if f.is_text:
        return "bench"[:f.text_size]
    lo, hi = f.limits
    return max(lo, 1) + i % min(hi - max(lo, 1) + 1, 1000)


def _our_messages(n: int) -> list:
    spec = SCHEMA[OURS]
    return [spec.type(*(_our_value(f, i) for f in spec.fields)) for i in range(n)]


def _ours(n: int, authenticated: bool) -> Row:
    spec = SCHEMA[OURS]
    msgs = _our_messages(n)
    msg_id, encode, cls = spec.id, spec.encode, int(MsgClass.TELEMETRY)
    key = MacKey(KEY) if authenticated else None   # prepared once per session, as the link does
    decode = SCHEMA.decode

    def encode_all() -> list[bytes]:
        return [encode_frame(cls, i & 0xFFFF, 0, msg_id, encode(m), key, i + 1) for i, m in enumerate(msgs)]

    def decode_unauth(chunks: list[bytes]) -> list:
        rx = FrameReceiver()
        out: list = []
        append = out.append
        for chunk in chunks:
            for frame in rx.feed(chunk):
                append(decode(frame.msg_id, frame.payload))
        return out

    def decode_auth(chunks: list[bytes]) -> list:
        rx = FrameReceiver()
        out: list = []
        append = out.append
        last = 0
        for chunk in chunks:
            for frame in rx.feed(chunk):
                counter = frame.counter
                if counter is None or counter <= last or not frame.verify(key):
                    raise BenchError(f"authenticated frame refused (counter {counter}, last {last})")
                last = counter
                append(decode(frame.msg_id, frame.payload))
        return out

    decode_all = decode_auth if authenticated else decode_unauth
    reference = encode_all()
    chunks = _chunks(b"".join(reference))
    what = f"ours ({'authenticated' if authenticated else 'unauthenticated'})"

    def check_decoded(out: list) -> None:
        if len(out) != n:
            raise BenchError(f"{what}: decoded {len(out)} of {n} frames")
        if out != msgs:
            raise BenchError(f"{what}: decoded messages differ from the originals")

    row = Row(f"ours, {'authenticated' if authenticated else 'unauthenticated'}", len(reference[0]), spec.size,
              frames=n)
    row.measures = {
        "encode": (lambda: encode_all, _check_equal_bytes(reference, what)),
        "decode": (lambda: lambda: decode_all(chunks), check_decoded),
        "both": (lambda: lambda: decode_all(_chunks(b"".join(encode_all()))), check_decoded),
    }
    row.note = (f"{len(reference[0])} wire bytes: 10 header"
                + (" + 6 counter" if authenticated else "") + f" + {spec.size} payload"
                + (" + 16 HMAC-SHA256 tag" if authenticated else "") + " + 4 CRC-32 + COBS 1 + 2 delimiters")
    return row


# ---------------------------------------------------------------- pymavlink

def _load_pymavlink():
    os.environ["MAVLINK20"] = "1"           # before the first pymavlink import
    from pymavlink.dialects.v20 import common
    return common


def pymavlink_crc_report(common) -> list[str]:
    """Which CRC-16/MCRF4XX implementation pymavlink's generated dialect and generator use."""
    import inspect
    from importlib import metadata

    from pymavlink.generator import mavcrc

    lines = []
    impl = common.x25crc
    uses_fast = impl is getattr(common, "_x25crc_fast", None) and common.mcrf4xx is not None
    if uses_fast:
        fn = common.mcrf4xx
        where = f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', getattr(fn, '__name__', '?'))}"
        try:
            version = metadata.version("fastcrc")
        except metadata.PackageNotFoundError:
            version = "?"
        sample = bytes(range(256)) * 3
        agrees = common._x25crc_slow(sample).crc == impl(sample).crc
        kind = "compiled extension function" if inspect.isbuiltin(fn) else "Python function"
        lines.append(f"pymavlink CRC: dialects.v20.common.x25crc = {impl.__name__} -> {where} "
                     f"(fastcrc {version}, {kind}); agrees with the pure-Python _x25crc_slow: {agrees}")
    else:
        lines.append(f"pymavlink CRC: dialects.v20.common.x25crc = {impl.__name__} "
                     "(pure Python, byte by byte: fastcrc is NOT in use)")
    lines.append(f"pymavlink generator/mavcrc.x25crc = {mavcrc.x25crc.__name__} "
                 f"({'fastcrc' if mavcrc.mcrf4xx is not None else 'pure Python'})")
    lines.append("ours CRC: zlib.crc32 (C, stdlib); ours MAC: HMAC-SHA256 with the key's inner/outer SHA-256 states prepared once per session (framing.MacKey)")
    return lines


_MAV_INT_BYTES = {"int8_t": 1, "uint8_t": 1, "int16_t": 2, "uint16_t": 2, "int32_t": 4, "uint32_t": 4,
                  "int64_t": 8, "uint64_t": 8}


def mav_peer(common, payload_bytes: int) -> tuple[type, bool]:
    """The `common` message to set beside a payload of `payload_bytes`, and whether its MAVLink 2 payload (extensions
    included) is exactly as long.

    Of the messages without text fields (a string decodes stripped, so would not compare equal), those of exactly
    that length, else the nearest (the longer of two as near); of them the one whose field count is nearest ours,
    so both codecs unpack a like number of fields; then the lowest id, so every run picks the same one."""
    ours = len(SCHEMA[OURS].fields)
    classes = [c for c in common.mavlink_map.values() if c.unpacker.size and "char" not in c.fieldtypes]
    nearest = min(classes, key=lambda c: (abs(c.unpacker.size - payload_bytes), -c.unpacker.size,
                                          abs(len(c.fieldnames) - ours), c.id))
    return nearest, nearest.unpacker.size == payload_bytes


def _mav_value(kind: str, k: int, i: int):
    """A non-zero value of MAVLink type `kind` for field (or element) `k` of message `i`: floats exactly
    representable in float32, integers with every byte non-zero and below 0x80 (so signed ones stay positive), so
    no trailing zero byte is cut from the payload and decoded values compare equal."""
    if kind in ("float", "double"):
        return 0.5 + ((k + i) % 8) * 0.0625
    return int.from_bytes(bytes((k + i + j) % 0x7E + 1 for j in range(_MAV_INT_BYTES[kind])), "little")


def _mav_messages(cls, n: int) -> list:
    def values(i: int) -> list:
        out = []
        for k, (kind, length) in enumerate(zip(cls.fieldtypes, cls.array_lengths)):
            out.append([_mav_value(kind, k + e, i) for e in range(length)] if length else _mav_value(kind, k, i))
        return out
    return [cls(*values(i)) for i in range(n)]


def _mav_values(m) -> tuple:
    return tuple(tuple(v) if isinstance(v, list) else v for v in (getattr(m, f) for f in m.fieldnames))


def _pymavlink(common, cls, n: int, signed: bool) -> Row:
    msgs = _mav_messages(cls, n)
    expected = [_mav_values(m) for m in msgs]
    size, name = cls.unpacker.size, cls.msgname

    def new_mav():
        mav = common.MAVLink(None, srcSystem=1, srcComponent=1)
        if signed:
            mav.signing.secret_key = KEY
            mav.signing.link_id = 0
            mav.signing.timestamp = MAV_SIGNING_T0
            mav.signing.sign_outgoing = True
        return mav

    def encoder():
        mav = new_mav()

        def run() -> list[bytes]:
            out = []
            append = out.append
            for m in msgs:
                append(m.pack(mav))
                mav.seq = (mav.seq + 1) & 0xFF
            return out
        return run

    def decode_all(mav, chunks: list[bytes]) -> list:
        out: list = []
        parse = mav.parse_buffer
        for chunk in chunks:
            got = parse(chunk)
            if got:
                out.extend(got)
        return out

    what = f"pymavlink ({'signed' if signed else 'unsigned'})"

    def check_decoded(out: list) -> None:
        if len(out) != n:
            raise BenchError(f"{what}: decoded {len(out)} of {n} frames")
        for m, want in zip(out, expected):
            if m.get_type() != name or _mav_values(m) != want:
                raise BenchError(f"{what}: decoded {m} differs from the original")
            if signed and not m.get_signed():
                raise BenchError(f"{what}: a frame was accepted without a verified signature")

    reference = encoder()()
    plen = reference[0][1]
    if plen != size:
        raise BenchError(f"{what}: payload truncated on the wire to {plen} of {size} bytes")
    chunks = _chunks(b"".join(reference))
    row = Row(f"pymavlink{', signed' if signed else ''}", len(reference[0]), size, frames=n, optional=signed)

    def prepare_decode():
        mav = new_mav()
        return lambda: decode_all(mav, chunks)

    def prepare_both():
        enc, rx = encoder(), new_mav()
        return lambda: decode_all(rx, _chunks(b"".join(enc())))

    row.measures = {
        "encode": (encoder, _check_equal_bytes(reference, what)),
        "decode": (prepare_decode, check_decoded),
        "both": (prepare_both, check_decoded),
    }
    row.note = (f"{len(reference[0])} wire bytes: 10 header + {plen} payload + 2 CRC-16"
                + (" + 13 signature (link id, 48-bit timestamp, 6-byte SHA-256)" if signed else ""))
    return row


def _pymavlink_guarded(common, cls, n: int, signed: bool) -> Row:
    """Signed pymavlink is reported if it works; if not, the row says why instead of a figure."""
    if not signed:
        return _pymavlink(common, cls, n, signed)
    try:
        return _pymavlink(common, cls, n, signed)
    except Exception as exc:   # report, not hide: the reason is printed in the table
        return Row("pymavlink, signed", 0, optional=True, note=f"not measured: {type(exc).__name__}: {exc}")


# ---------------------------------------------------------------- run and print

def run(quick: bool = False) -> CodecResult:
    n, repeats = (2_000, 3) if quick else (20_000, 7)
    result = CodecResult(n, repeats, SCHEMA[OURS].size)
    result.rows.append(_ours(n, authenticated=False))
    result.rows.append(_ours(n, authenticated=True))
    try:
        common = _load_pymavlink()
    except ImportError as exc:
        result.notes.append(f"pymavlink not importable ({exc}): install the bench extra, pip install -e '.[bench]'")
    else:
        result.notes.extend(pymavlink_crc_report(common))
        cls, exact = mav_peer(common, result.payload_bytes)
        result.per_byte = not exact
        result.peer = (f"{cls.msgname} (id {cls.id}, common dialect, {len(cls.fieldnames)} fields, MAVLink 2 payload "
                       f"{'exactly ' if exact else ''}{cls.unpacker.size} B, all fields non-zero so nothing is "
                       "truncated)")
        result.rows.append(_pymavlink_guarded(common, cls, n, signed=False))
        result.rows.append(_pymavlink_guarded(common, cls, n, signed=True))
    measure(result.rows, repeats)
    return result


def _fmt(value: Optional[float]) -> str:
    return "-" if value is None else f"{value:,.0f}"


def _ratio(a: Optional[float], b: Optional[float]) -> str:
    return "-" if not a or not b else f"{a / b:.2f}"


def report(result: CodecResult) -> str:
    spec = SCHEMA[OURS]
    per = "payload byte" if result.per_byte else "frame"
    lines = [f"Codec throughput, {result.payload_bytes}-byte payloads: {result.frames:,} frames per run, best of "
             f"{result.repeats} rounds, contenders interleaved (frames/s, higher is better; decode fed "
             f"{CHUNK_BYTES}-byte chunks)",
             f"  ours: {OURS} (id {spec.id:#04x}, {len(spec.fields)} fields, {spec.size} B)"
             + (f"; pymavlink: {result.peer}" if result.peer else ""),
             "",
             f"  {'':<26}{'wire B':>7}{'encode/s':>12}{'decode/s':>12}{'enc+dec/s':>12}"]
    for row in result.rows:
        lines.append(f"  {row.name:<26}{row.wire_bytes or '-':>7}{_fmt(row.encode_fps):>12}"
                     f"{_fmt(row.decode_fps):>12}{_fmt(row.both_fps):>12}")
    by = {r.name: r for r in result.rows}
    pairs = [("ours unauth / pymavlink", "ours, unauthenticated", "pymavlink", "goal > 1"),
             ("ours auth / pymavlink signed", "ours, authenticated", "pymavlink, signed", ""),
             ("ours auth / pymavlink unsigned", "ours, authenticated", "pymavlink", "")]
    lines += ["", f"  {f'ratio per {per} (ours / pymavlink)':<34}{'encode':>8}{'decode':>8}{'enc+dec':>9}"]
    for label, a, b, goal in pairs:
        if a in by and b in by:
            ra, rb = by[a], by[b]
            rates = {c: (ra.payload_bps(c), rb.payload_bps(c)) for c in COLUMNS}
            verdict = ""
            if goal:
                ok = all(x is not None and y is not None and x > y for x, y in (rates["decode"], rates["both"]))
                verdict = f"  ({goal}: {'met' if ok else 'NOT met'})"
            lines.append(f"  {label:<34}" + "".join(f"{_ratio(*rates[c]):>{w}}" for c, w in zip(COLUMNS, (8, 8, 9)))
                         + verdict)
    if result.per_byte:
        lines.append(f"  No message of the common dialect has a {result.payload_bytes}-byte payload: the ratios are "
                     "of payload bytes a second, not frames.")
    lines.append("")
    for row in result.rows:
        if row.note:
            lines.append(f"  {row.name}: {row.note}")
    lines += [f"  {note}" for note in result.notes]
    lines.append("  Checked: every run's encoder output equals the reference bytes and every decoded message "
                 f"equals its original ({result.frames:,} of {result.frames:,}); authenticated runs verify every "
                 "tag/signature and counter/timestamp order.")
    return "\n".join(lines)


def main(quick: bool = False) -> CodecResult:
    result = run(quick)
    print(report(result), flush=True)
    return result
