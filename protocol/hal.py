"""The HAL bus codec: the frames declared once in `hal.dbc`, as python-can messages.

The DBC file is the single declaration of the bus between the controller
(`firmware_py`) and the plant (`hil_sim`, or real hardware). This module parses it
once with cantools and pre-resolves every message by name and by frame ID, so a
per-tick encode or decode is one dict lookup plus cantools' own work (a few
microseconds).

Decoding is deliberately lenient about *what* arrives and strict about *how*:
a frame whose ID is not declared (or that is an error, remote or 29-bit frame) is
simply not ours and decodes to ``None``; a frame with a declared ID whose length
or values break the declaration raises `HalDecodeError`.
"""
from __future__ import annotations

import copy
import functools
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import can
import cantools
from cantools.database.can import Database, Message as DbcMessage

from protocol.frame_code import STRUCT_CODES, Field, compile_pack, compile_roundtrip, compile_unpack
from protocol.value_frame import ValueFrame

DBC_PATH = Path(__file__).with_name("hal.dbc")

SignalValues = dict[str, Union[int, float]]

# Data lengths a CAN FD frame can have (ISO 11898-1:2015, DLC 9..15 -> 12..64 bytes).
FD_LENGTHS = (8, 12, 16, 20, 24, 32, 48, 64)



class HalEncodeError(ValueError):
    """A message that cannot be built: unknown name, missing/unknown signal, value out of range."""


class HalDecodeError(ValueError):
    """A frame with a declared ID whose data does not match its declaration."""


@functools.lru_cache(maxsize=1)
def _default_database() -> Database:
    # Parsed once per process and never mutated; every HalCodec() without a path shares it.
    return cantools.database.load_file(DBC_PATH, database_format="dbc", strict=True)


@functools.lru_cache(maxsize=1)
def default_codec() -> "HalCodec":
    """The codec of `hal.dbc`, one per process: nodes built without a codec share it, and so its layouts."""
    return HalCodec()


@dataclass(frozen=True)
class _Spec:
    """One declared message, resolved once."""

    name: str
    frame_id: int
    length: int
    message: DbcMessage
    # (signal, lowest, highest) accepted on decode: the declared range widened by half a count,
    # so that a value saturated at a limit survives the integer round trip.
    checks: tuple[tuple[str, float, float], ...]
    is_fd: bool


class HalCodec:
    """Encode and decode HAL bus frames as declared in one DBC file (default: `hal.dbc`)."""

    def __init__(self, dbc_path: Optional[Union[str, os.PathLike]] = None) -> None:
        if dbc_path is None:
            self.database = _default_database()
        else:
            self.database = cantools.database.load_file(dbc_path, database_format="dbc", strict=True)
        self._by_name: dict[str, _Spec] = {}
        self._by_id: dict[int, _Spec] = {}
        self._layouts: dict[tuple[str, tuple[str, ...]], FrameLayout] = {}
        for message in self.database.messages:
            if message.is_extended_frame:
                raise ValueError(f"{message.name}: the HAL bus uses standard 11-bit IDs")
            if message.length not in (FD_LENGTHS if message.is_fd else (8,)):
                raise ValueError(f"{message.name}: a classic frame must be 8 bytes, a CAN FD frame one of "
                                 f"{FD_LENGTHS}; declared {message.length}")
            checks = tuple(
                (s.name, s.minimum - abs(s.scale) / 2, s.maximum + abs(s.scale) / 2)
                for s in message.signals
                if s.minimum is not None and s.maximum is not None
            )
            spec = _Spec(message.name, message.frame_id, message.length, message, checks, message.is_fd)
            self._by_name[spec.name] = spec
            self._by_id[spec.frame_id] = spec

    def ids_sent_by(self, node: str) -> frozenset[int]:
        """The frame IDs the DBC declares as sent by `node` (CONTROLLER, PLANT)."""
        return frozenset(m.frame_id for m in self.database.messages if node in (m.senders or ()))

    def ids_between_peers(self, node: str) -> frozenset[int]:
        """The frame IDs `node` both sends and listens to (TRAJ_START): one node of that kind to another."""
        return frozenset(m.frame_id for m in self.database.messages if node in (m.senders or ())
                         and any(node in s.receivers for s in m.signals))

    @property
    def names(self) -> tuple[str, ...]:
        """Declared message names, in frame-ID (priority) order."""
        return tuple(s.name for s in sorted(self._by_name.values(), key=lambda s: s.frame_id))

    def layout(self, name: str, order: Optional[Sequence[str]] = None) -> "FrameLayout":
        """A fast packer/unpacker of `name` with its signals in `order` (default: as declared).

        One per name and order: every caller of this codec gets the same object (a `ValueFrame`'s
        receiver knows it by that)."""
        key = (name, tuple(s.name for s in self._spec(name).message.signals) if order is None else tuple(order))
        layout = self._layouts.get(key)
        if layout is None:
            layout = self._layouts[key] = FrameLayout(self, *key)
        return layout

    def is_fd(self, name: str) -> bool:
        return self._spec(name).is_fd

    def frame_id(self, name: str) -> int:
        return self._spec(name).frame_id

    def limits(self, name: str, signal: str) -> tuple[float, float]:
        """Declared (minimum, maximum) of a signal, in its physical unit."""
        sig = self._spec(name).message.get_signal_by_name(signal)
        return float(sig.minimum), float(sig.maximum)

    def cycle_time_s(self, name: str) -> Optional[float]:
        """Declared send period (DBC attribute GenMsgCycleTime), or None if not declared."""
        cycle_ms = self._spec(name).message.cycle_time
        return cycle_ms / 1000.0 if cycle_ms else None

    def _spec(self, name: str) -> _Spec:
        try:
            return self._by_name[name]
        except KeyError:
            raise HalEncodeError(
                f"no HAL message named {name!r}; declared: {', '.join(self.names)}") from None

    def encode(self, name: str, **signals: Union[int, float]) -> can.Message:
        """Build the frame `name` from physical signal values (every signal is required)."""
        spec = self._spec(name)
        try:
            data = spec.message.encode(signals, scaling=True, padding=False, strict=True)
        except (cantools.database.EncodeError, TypeError, ValueError, OverflowError) as exc:
            raise HalEncodeError(f"cannot encode {name}: {exc}") from exc
        return can.Message(arbitration_id=spec.frame_id, data=data, dlc=spec.length,
                           is_extended_id=False, is_fd=spec.is_fd)

    def decode(self, msg: can.Message) -> Optional[tuple[str, SignalValues]]:
        """Return (message name, physical signal values), or None if the frame is not declared.

        Raises `HalDecodeError` for a declared ID with the wrong length or a value outside
        its declared range. Never raises for an undeclared ID.
        """
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            return None
        spec = self._by_id.get(msg.arbitration_id)
        if spec is None:
            return None
        data = msg.data
        if len(data) != spec.length:
            raise HalDecodeError(
                f"{spec.name} (0x{spec.frame_id:03X}): {len(data)} data bytes, declared {spec.length}")
        try:
            values = spec.message.decode(bytes(data), decode_choices=False, scaling=True,
                                         allow_truncated=False, allow_excess=False)
        except cantools.database.DecodeError as exc:
            raise HalDecodeError(f"{spec.name} (0x{spec.frame_id:03X}): {exc}") from exc
        for signal, lowest, highest in spec.checks:
            value = values[signal]
            if not lowest <= value <= highest:
                raise HalDecodeError(
                    f"{spec.name} (0x{spec.frame_id:03X}): {signal}={value} outside its declared range")
        return spec.name, values  # type: ignore[return-value]


_new_message = can.Message.__new__
_new_value_frame = object.__new__


class HalFrame(can.Message):
    """A `can.Message` that is cheaper to build and to deep-copy; its copies are plain `can.Message`s.

    python-can's virtual bus deep-copies every frame it delivers, and `Message.__deepcopy__`
    copies the data bytearray through the generic `copy` machinery: 2.5 of the 3.7 us a copy
    takes, on a path that runs for every frame. This copies the data with `bytearray()`,
    which is as deep (a bytearray holds only ints) and takes 0.7 us in all. Real
    interfaces (socketcan and the like) do not copy; there it changes nothing.

    `data_frame` builds a standard-ID data frame with every other field at `can.Message`'s
    default, in 0.4 us against the constructor's 0.95 (its keyword handling and checks).
    """

    __slots__ = ()

    @classmethod
    def data_frame(cls, arbitration_id: int, data: bytes, is_fd: bool) -> "HalFrame":
        """What `cls(arbitration_id=..., data=data, is_extended_id=False, is_fd=...)` builds, sooner."""
        msg = _new_message(cls)
        msg.timestamp = 0.0
        msg.arbitration_id = arbitration_id
        msg.is_extended_id = msg.is_remote_frame = msg.is_error_frame = False
        msg.channel = None
        msg.is_fd = is_fd
        msg.is_rx = True
        msg.bitrate_switch = msg.error_state_indicator = False
        msg.data = bytearray(data)
        msg.dlc = len(msg.data)
        return msg

    def __deepcopy__(self, memo: Optional[dict]) -> can.Message:
        return can.Message(timestamp=self.timestamp, arbitration_id=self.arbitration_id,
                           is_extended_id=self.is_extended_id, is_remote_frame=self.is_remote_frame,
                           is_error_frame=self.is_error_frame, channel=copy.deepcopy(self.channel, memo),
                           dlc=self.dlc, data=bytearray(self.data), is_fd=self.is_fd, is_rx=self.is_rx,
                           bitrate_switch=self.bitrate_switch, error_state_indicator=self.error_state_indicator)


# What the generated roundtrip raises for a value that is not a number (FrameLayout.roundtrip: None).
ROUNDTRIP_DECLINES = (TypeError, ValueError, ArithmeticError)


class FrameLayout:
    """One declared message packed and unpacked by hand, its signals in a fixed order.

    Built from the cantools declaration (so the DBC stays the one declaration); supports
    what the HAL bus uses: little-endian integer signals with linear scaling, no
    multiplexing. `pack` takes physical values, checks each against its declared range
    as `HalCodec.encode` (strict) does and raises `HalEncodeError`; its bytes are the
    codec's. `unpack` gives the physical values `HalCodec.decode` would, as a list, and
    raises `HalDecodeError` where it would (wrong length, a value outside its declared
    range widened by half a count). Byte-aligned layouts of 8/16/32/64-bit fields pack
    through `struct`, others (single bits) by shifting into one integer. Both directions
    first try straight-line code compiled for the layout (`protocol.frame_code`,
    `pack_source` and `unpack_source`), which declines to the checked table-driven code
    whenever a value needs a closer look.
    """

    def __init__(self, codec: "HalCodec", name: str, order: Sequence[str]) -> None:
        message = codec.database.get_message_by_name(name)
        signals = {s.name: s for s in message.signals}
        if sorted(order) != sorted(signals):
            raise ValueError(f"{name}: layout order {tuple(order)} does not list the declared signals "
                             f"{tuple(signals)}")
        if message.is_multiplexed():
            raise ValueError(f"{name}: multiplexed messages are not supported")
        self.name = name
        self.order = tuple(order)
        self.frame_id = codec.frame_id(name)
        self.length = message.length
        self.is_fd = codec.is_fd(name)
        conv, bits, fields_in = [], [], []
        for signal_name in self.order:
            s = signals[signal_name]
            if s.byte_order != "little_endian" or s.is_float:
                raise ValueError(f"{name}.{signal_name}: only little-endian integer signals are supported")
            scale, offset = s.scale, s.offset
            tolerance = abs(scale) * 1e-6          # cantools' strict range check, exactly
            lo = -float("inf") if s.minimum is None else s.minimum - tolerance
            hi = float("inf") if s.maximum is None else s.maximum + tolerance
            conv.append((scale == 1 and offset == 0, scale, offset, lo, hi, signal_name))
            bits.append((s.start, (1 << s.length) - 1))
            # Decoding accepts the declared range widened by half a count, as HalCodec.decode does.
            half = abs(scale) / 2
            fields_in.append((s.start, (1 << s.length) - 1, 1 << (s.length - 1) if s.is_signed else 0,
                              1 << s.length, scale == 1 and offset == 0, scale, offset,
                              -float("inf") if s.minimum is None else s.minimum - half,
                              float("inf") if s.maximum is None else s.maximum + half, signal_name))
        self._conv = tuple(conv)
        self._bits = tuple(bits)
        self._fields_in = tuple(fields_in)
        # Signals whose declared range is their whole raw range need no range check of their own:
        # struct refuses what does not fit, and any raw value decodes inside the range.
        self._full_range = all(_covers_raw_range(signals[n]) for n in self.order)
        self._struct: Optional[struct.Struct] = None
        fields = sorted((signals[n].start, signals[n].length, signals[n].is_signed, i)
                        for i, n in enumerate(self.order))
        if all(start % 8 == 0 and (length, signed) in STRUCT_CODES for start, length, signed, _ in fields) \
                and [i for *_, i in fields] == list(range(len(fields))):
            fmt, at = "<", 0
            for start, length, signed, _ in fields:
                if start < at:
                    break                             # overlapping signals: use the shifting path
                fmt += f"{(start - at) // 8}x" if start > at else ""
                fmt += STRUCT_CODES[(length, signed)]
                at = start + length
            else:
                if at <= 8 * self.length:
                    fmt += f"{(8 * self.length - at) // 8}x" if at < 8 * self.length else ""
                    self._struct = struct.Struct(fmt)
        # The fast paths: straight-line code for this layout (protocol/frame_code.py); the table-driven
        # code below stays the reference and says what is wrong when they decline.
        code_fields = [Field(signals[n].start, signals[n].length, signals[n].is_signed, c[1], c[2], c[3], c[4],
                             f[7], f[8]) for n, c, f in zip(self.order, conv, fields_in)]
        self._fast_pack, self.pack_source = compile_pack(
            name, code_fields, self.length, check_all=not (self._full_range and self._struct is not None))
        self._fast_unpack, self.unpack_source = compile_unpack(name, code_fields, self.length)
        # The generated function itself: None, or one of `ROUNDTRIP_DECLINES` raised, where `roundtrip` says None.
        self.roundtrip_or_raise, self.roundtrip_source = compile_roundtrip(name, code_fields)

    def pack(self, values: Sequence) -> bytes:
        """Frame bytes for physical `values` in `order`; HalEncodeError if one is out of range."""
        try:
            data = self._fast_pack(values)
        except (struct.error, TypeError, ValueError, OverflowError):
            data = None    # a wrong count, out of range, not a number or not an integer: the checks below say which
        return data if data is not None else self._pack_checked(values)

    def _pack_checked(self, values: Sequence) -> bytes:
        if len(values) != len(self._conv):
            raise HalEncodeError(f"{self.name}: {len(values)} values for {len(self._conv)} signals")
        raws = []
        for v, (identity, scale, offset, lo, hi, signal_name) in zip(values, self._conv):
            if not lo <= v <= hi:
                raise HalEncodeError(f"cannot encode {self.name}: {signal_name}={v!r} outside its declared range")
            raws.append(round(v) if identity else round((v - offset) / scale))
        if self._struct is not None:
            return self._struct.pack(*raws)
        acc = 0
        for raw, (shift, mask) in zip(raws, self._bits):
            acc |= (raw & mask) << shift
        return acc.to_bytes(self.length, "little")

    def unpack(self, data: bytes) -> list:
        """Physical values in `order` from frame bytes; HalDecodeError as `HalCodec.decode` raises it."""
        values = self._fast_unpack(data)
        return values if values is not None else self._unpack_checked(data)

    def _unpack_checked(self, data: bytes) -> list:
        if len(data) != self.length:
            raise HalDecodeError(
                f"{self.name} (0x{self.frame_id:03X}): {len(data)} data bytes, declared {self.length}")
        x = int.from_bytes(data, "little")
        values = []
        for start, mask, sign, span, identity, scale, offset, lo, hi, signal_name in self._fields_in:
            raw = (x >> start) & mask
            if raw & sign:
                raw -= span
            value = raw if identity else raw * scale + offset
            if not lo <= value <= hi:
                raise HalDecodeError(
                    f"{self.name} (0x{self.frame_id:03X}): {signal_name}={value} outside its declared range")
            values.append(value)
        return values

    def roundtrip(self, values: Sequence) -> Optional[list]:
        """What `unpack(pack(values))` gives, to the bit and the type, computed without the bytes; None
        where that takes the bytes after all (a value `pack` refuses, or one of a kind not proven
        here: `protocol.frame_code.roundtrip_source`). For a carrier that hands values over."""
        try:
            return self.roundtrip_or_raise(values)
        except ROUNDTRIP_DECLINES:
            return None

    def message(self, values: Sequence) -> can.Message:
        return HalFrame.data_frame(self.frame_id, self.pack(values), self.is_fd)


def _covers_raw_range(signal) -> bool:
    """True if the signal's declared range is exactly what its raw integer can hold."""
    if signal.minimum is None or signal.maximum is None:
        return True
    if signal.is_signed:
        raw_lo, raw_hi = -(1 << (signal.length - 1)), (1 << (signal.length - 1)) - 1
    else:
        raw_lo, raw_hi = 0, (1 << signal.length) - 1
    lo = raw_lo * signal.scale + signal.offset
    hi = raw_hi * signal.scale + signal.offset
    tolerance = abs(signal.scale) * 1e-6
    return abs(min(lo, hi) - signal.minimum) <= tolerance and abs(max(lo, hi) - signal.maximum) <= tolerance


Handler = Callable[[object, float], None]


class BusView:
    """A python-can bus seen through something that looks at what it receives.

    Subclasses override `recv`; everything else (`send`, `shutdown`, any attribute) is the
    wrapped bus's, so a node uses a view as it would the bus (`host_tools.worlds.nodes.OwnEchoFilter`,
    `protocol.lockstep.SyncTap`). A context manager, as python-can's buses are.
    """

    def __init__(self, bus: Any) -> None:
        self.bus = bus

    def recv(self, timeout: Optional[float] = None) -> Optional[can.Message]:
        return self.bus.recv(timeout)

    def send(self, msg: can.Message, timeout: Optional[float] = None) -> None:
        self.bus.send(msg, timeout)

    def shutdown(self) -> None:
        self.bus.shutdown()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.bus, name)

    def __enter__(self) -> "BusView":
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()


class HalEndpoint:
    """One node's end of the HAL bus: never blocks, never raises on what arrives, counts everything.

    A node registers what it listens to with `on_frame(name, handler, order)`: `poll(now)`
    then reads the waiting frames (at most `max_frames_per_poll`, so a flooded bus cannot
    starve a cooperative scheduler; the rest wait for the next call) and calls
    `handler(values, now)` for each, the values a list in `order` (by default as declared)
    unpacked by a `FrameLayout`; `send_frame(layout, values)` packs one. Declared frames
    nobody listens to (the node's own echo, say) are read and ignored. Undeclared IDs,
    frames that break their declaration and frames a handler refuses (ValueError) are
    counted in `bad_frames`; a `can.CanError` from the bus is counted in `bus_errors`, never
    raised: a node that cannot talk lets the other side's expiry rules take it to the safe
    state.

    On a bus whose `carries_values` is True (the one-process world's), `send_frame` hands the
    receiver its values instead of bytes (`protocol.value_frame`), and `poll` passes on the
    values of such a frame as they came; everything else, and every count, is as with bytes.
    """

    def __init__(self, bus: can.BusABC, codec: Optional[HalCodec] = None, max_frames_per_poll: int = 256) -> None:
        self.bus = bus
        self.codec = codec if codec is not None else default_codec()
        self.carries_values = getattr(bus, "carries_values", False) is True
        self.max_frames_per_poll = max_frames_per_poll
        self.frames_received = 0
        self.frames_sent = 0
        self.bad_frames = 0
        self.bus_errors = 0
        self.last_bus_error: Optional[can.CanError] = None
        self.sent_by_name: dict[str, int] = {}
        self.own_id_frames = 0     # frames with an ID this endpoint sends (`own_ids`) that came from another node
        self.own_ids: frozenset[int] = frozenset()
        self._listeners: dict[int, tuple[FrameLayout, Handler]] = {}

    def sends_as(self, node: str) -> None:
        """The DBC node this endpoint is: frames with the IDs that node sends, when they come in, came from
        another node (`own_id_frames`): on a bus that gives a node its own frames back, a filter drops those
        first (host_tools/worlds/nodes.py OwnEchoFilter). A frame the node also listens to (one between peers,
        TRAJ_START) is not among them."""
        self.own_ids = self.codec.ids_sent_by(node) - self.codec.ids_between_peers(node)

    def foreign_frames(self) -> int:
        """Frames with this node's own IDs that another node sent: those that reached the endpoint, and, on a bus
        that gives a node its own frames back and drops them (`own_echoes`), the echoes beyond the frames sent
        through it (`own_sent`: the lock-step CTRL_SYNCs too, which do not pass through the endpoint)."""
        echoes, sent = getattr(self.bus, "own_echoes", 0), getattr(self.bus, "own_sent", 0)
        beyond = echoes - sent if isinstance(echoes, int) and isinstance(sent, int) else 0
        return self.own_id_frames + max(0, beyond)

    def on_frame(self, name: str, handler: Handler, order: Optional[Sequence[str]] = None) -> FrameLayout:
        """Listen to frames `name`, their values in `order` (default: as declared); returns the layout."""
        layout = self.codec.layout(name, order)      # raises for an undeclared name
        self._listeners[layout.frame_id] = (layout, handler)
        return layout

    def poll(self, now: float) -> int:
        """Read and dispatch the waiting frames; return how many were read (bad ones included)."""
        recv, listeners = self.bus.recv, self._listeners
        read = 0
        while read < self.max_frames_per_poll:
            try:
                msg = recv(0)
            except can.CanError as exc:
                self._bus_error(exc)
                break
            if msg is None:
                break
            read += 1
            try:
                entry = listeners.get(msg.arbitration_id)
                if entry is None:
                    self._not_listened_to(msg)
                elif msg.__class__ is ValueFrame and msg.layout is entry[0]:
                    entry[1](msg.values, now)        # the values its unpack would give (`send_frame`)
                elif msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
                    self._not_listened_to(msg)
                else:
                    entry[1](entry[0].unpack(msg.data), now)
            except ValueError:      # HalDecodeError, or values the handler refuses
                self.bad_frames += 1
        self.frames_received += read
        return read

    def _not_listened_to(self, msg: Union[can.Message, ValueFrame]) -> None:
        """A frame no handler takes: a declared one passes (one with this node's own ID counted), anything else
        is a bad frame."""
        if msg.arbitration_id in self.own_ids and not msg.is_extended_id:
            self.own_id_frames += 1
        if self.codec.decode(msg) is None:
            self.bad_frames += 1

    def send_frame(self, layout: FrameLayout, values: Sequence) -> bool:
        """Pack (fast path) and send one frame; False (and counted) if the bus refused it.

        On a bus that carries values, what the receiver would unpack goes instead, where
        `layout.roundtrip` vouches for it (`ValueFrame`); `values` must then stay as they are."""
        carried = None
        if self.carries_values:
            try:
                carried = layout.roundtrip_or_raise(values)     # layout.roundtrip(values), one call fewer
            except ROUNDTRIP_DECLINES:
                pass
        if carried is None:
            msg = layout.message(values)
        else:
            # ValueFrame(layout, values, carried) with its slots filled here: a Python __init__'s call
            # would be most of what building it costs, on a path that runs for every frame.
            msg = _new_value_frame(ValueFrame)
            msg.arbitration_id, msg.layout, msg.sent, msg.values = layout.frame_id, layout, values, carried
        return self._send(layout, msg)

    def send_carried(self, layout: FrameLayout, values: list) -> bool:
        """`send_frame` for values that are already what unpacking the frame gives (each a whole number of its
        signal's steps, within range, of the type unpack returns): on a bus that carries values they go as they
        are, without the round trip. The sender vouches for that (firmware_py/hal.py's MOTOR_CMD, held to it by
        tests/test_hal.py); anywhere else they are packed as always."""
        if not self.carries_values:
            return self._send(layout, layout.message(values))
        msg = _new_value_frame(ValueFrame)
        msg.arbitration_id, msg.layout, msg.sent, msg.values = layout.frame_id, layout, values, list(values)
        return self._send(layout, msg)

    def _send(self, layout: FrameLayout, msg: Union[can.Message, ValueFrame]) -> bool:
        try:
            self.bus.send(msg, 0)
        except can.CanError as exc:
            self._bus_error(exc)
            return False
        self.frames_sent += 1
        sent = self.sent_by_name
        sent[layout.name] = sent.get(layout.name, 0) + 1
        return True

    def _bus_error(self, exc: can.CanError) -> None:
        self.bus_errors += 1
        self.last_bus_error = exc
