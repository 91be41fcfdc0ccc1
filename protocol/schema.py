"""The machinery for declaring messages once (see protocol/messages.py for the list).

A `MessageSpec` names a message, its id, class, direction, reply, teleop name and
typed fields (with units, ranges and docs). From it come: a NamedTuple-like class
per message, a precompiled `struct` codec, range checks on decode, the tables of
docs/protocol.md, teleop's commands and completion, and the schema hash exchanged
in HELLO (so a mismatch is refused by name rather than read as noise).
"""
from __future__ import annotations

import enum
import hashlib
import math
import re
import struct
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Optional

from protocol.errors import EncodeError, ParseError, shown
from protocol.reasons import Reason


class MsgClass(enum.IntEnum):
    """The header's class byte: how a frame is delivered."""

    LINK = 0        # handshake, heartbeat, ack/nak: per-frame, never queued behind commands
    COMMAND = 1     # host->controller, reliable, in order, exactly once; replies come back in this class
    URGENT = 2      # host->controller stop/e-stop: bypasses ordering, still exactly once
    TELEMETRY = 3   # controller->host, unreliable, sequence-numbered for loss counting
    EVENT = 4       # controller->host, reliable and in order (faults, completions)


class Direction(enum.Enum):
    TO_CONTROLLER = "host -> controller"
    TO_HOST = "controller -> host"
    BOTH = "both"


# Field types: struct code, size, natural range.
_TYPES: dict[str, tuple[str, tuple[float, float] | None]] = {
    "u8": ("B", (0, 0xFF)),
    "u16": ("H", (0, 0xFFFF)),
    "u32": ("I", (0, 0xFFFFFFFF)),
    "u64": ("Q", (0, 0xFFFFFFFFFFFFFFFF)),
    "i8": ("b", (-0x80, 0x7F)),
    "i16": ("h", (-0x8000, 0x7FFF)),
    "i32": ("i", (-0x80000000, 0x7FFFFFFF)),
    "f32": ("f", None),
    "bool": ("B", (0, 1)),     # one byte, 0 or 1 (a struct "?" would read any non-zero byte as True)
}
_F32 = struct.Struct("<f")
F32_MAX = _F32.unpack(b"\xff\xff\x7f\x7f")[0]     # the largest finite float32, 3.4028235e38
_NAME = re.compile(r"[A-Za-z0-9_.\-]*")
_TEXT = re.compile(r"[ -~]*")          # printable ASCII
_SIZED = ("bytes", "str", "text")      # types with their size in their name: bytes16, str16, text200


def _round_f32(value: float) -> float:
    """The float32 that goes on the wire for `value` (raises OverflowError if none does)."""
    return _F32.unpack(_F32.pack(value))[0]


@dataclass(frozen=True)
class Field:
    """One typed field. `type` is a key of the table above, `bytesN` (N raw bytes), `strN` (a name: up to N
    of [A-Za-z0-9_.-], zero-padded) or `textN` (up to N printable ASCII characters, zero-padded)."""

    name: str
    type: str
    doc: str
    unit: str = ""
    range: Optional[tuple[float, float]] = None
    enum: Optional[type[enum.IntEnum]] = None
    default: Any = None      # what teleop fills in when the argument is left out

    @property
    def struct_code(self) -> str:
        if self.type.startswith(_SIZED):
            return f"{self.text_size}s"
        return _TYPES[self.type][0]

    @property
    def text_size(self) -> int:
        """N of a `bytesN`, `strN` or `textN` field."""
        return int(self.type[len(self.type.rstrip("0123456789")):])

    @property
    def is_text(self) -> bool:
        """A `strN` or `textN` field: a Python str, ASCII on the wire, zero-padded to N bytes."""
        return self.type.startswith(("str", "text"))

    def fit(self, text: str) -> str:
        """`text` made valid for this `textN` field: other than printable ASCII becomes `?`, and what is longer
        than N is cut, ending in `...` (for a controller's free-text detail, say an OS error)."""
        text = "".join(c if " " <= c <= "~" else "?" for c in text[:self.text_size + 1])
        return text if len(text) <= self.text_size else text[:self.text_size - 3] + "..."

    @property
    def limits(self) -> Optional[tuple[float, float]]:
        """The range checked on decode (declared, else the type's own for integers)."""
        if self.range is not None:
            return self.range
        if self.type.startswith(_SIZED) or self.type == "f32":
            return None
        return _TYPES[self.type][1]

    def fast_check(self) -> Optional[Callable[[Any], bool]]:
        """A quick test of a decoded value (None if every value of the type is valid).

        `check` gives the reason; this only says yes or no, cheaply, on the hot path.
        """
        lo, hi = self.range if self.range is not None else (None, None)
        if self.is_text:
            size, pattern = self.text_size, (_NAME if self.type.startswith("str") else _TEXT)
            return lambda v: isinstance(v, str) and len(v) <= size and pattern.fullmatch(v) is not None
        if self.enum is not None:
            allowed = frozenset(int(m) for m in self.enum)
            return allowed.__contains__
        if self.type == "f32":
            isfinite = math.isfinite
            if lo is None:
                return isfinite
            return lambda v: isfinite(v) and lo <= v <= hi
        if lo is None and self.type == "bool":
            lo, hi = 0, 1
        if lo is None:
            return None
        return lambda v: lo <= v <= hi

    def check(self, value: Any) -> Optional[str]:
        """None if `value` is valid, else why not."""
        if self.type.startswith("bytes"):
            size = int(self.type[5:])
            if not isinstance(value, (bytes, bytearray)) or len(value) != size:
                return f"{self.name} must be exactly {size} bytes"
            return None
        if self.type.startswith("str"):
            if not isinstance(value, str) or len(value) > self.text_size or not _NAME.fullmatch(value):
                what = shown(value) if isinstance(value, str) else repr(value)
                return f"{self.name}={what} is not a name of up to {self.text_size} of A-Z a-z 0-9 _ . -"
            return None
        if self.type.startswith("text"):
            if not isinstance(value, str) or len(value) > self.text_size or not _TEXT.fullmatch(value):
                what = shown(value) if isinstance(value, str) else repr(value)
                return f"{self.name}={what} is not text of up to {self.text_size} printable ASCII characters"
            return None
        if self.type == "bool" and value not in (0, 1):
            return f"{self.name}={value} is not 0 or 1"
        if self.type == "f32":
            if not math.isfinite(value):
                return f"{self.name} is not a finite number ({value})"
            try:
                _round_f32(value)
            except OverflowError:
                return f"{self.name}={value:g} does not fit in f32 (at most {F32_MAX:g} either side of 0)"
        if self.range is not None:
            lo, hi = self.range
            if not lo <= value <= hi:
                return f"{self.name}={value} is outside [{lo}, {hi}]{' ' + self.unit if self.unit else ''}"
        if self.enum is not None:
            try:
                self.enum(value)
            except ValueError:
                return f"{self.name}={value} is not one of {', '.join(m.name for m in self.enum)}"
        return None


def _enum_text(values: Optional[type[enum.IntEnum]]) -> str:
    return "" if values is None else "|".join(f"{m.name}={int(m)}" for m in values)


class Message(tuple):
    """Base of the generated message classes: a tuple of field values with names.

    Two messages are equal only if they are of the same type and values.
    """

    __slots__ = ()
    spec: "MessageSpec"

    def __eq__(self, other: object) -> bool:
        return type(self) is type(other) and tuple.__eq__(self, other)

    def __ne__(self, other: object) -> bool:
        return not self.__eq__(other)

    __hash__ = tuple.__hash__

    def __repr__(self) -> str:
        inner = ", ".join(f"{f.name}={v!r}" for f, v in zip(self.spec.fields, self))
        return f"{self.spec.name}({inner})"

    def as_dict(self) -> dict[str, Any]:
        return {f.name: v for f, v in zip(self.spec.fields, self)}

    @classmethod
    def of(cls, values: Iterable[Any]) -> "Message":
        """The message of `values`, every field's in the declared order, as decode makes one: not checked here
        that each is given (encode raises for a missing, extra or wrong value). For a telemetry task, which
        builds its 38-40 values at every run."""
        return tuple.__new__(cls, values)


@dataclass
class MessageSpec:
    """A message as declared: the single source for codec, docs and teleop."""

    name: str
    id: int
    cls: MsgClass
    direction: Direction
    doc: str
    fields: tuple[Field, ...] = ()
    reply: Optional[str] = None          # name of the reply message (commands and urgent)
    teleop: Optional[str] = None         # teleop command word, when a person may send it
    type: type[Message] = field(init=False, repr=False)
    _struct: struct.Struct = field(init=False, repr=False)
    _decode_checks: tuple = field(init=False, repr=False)
    _encode_checks: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._struct = struct.Struct("<" + "".join(f.struct_code for f in self.fields))
        # (index, field, quick test): the quick test runs on every value, `Field.check` only on failure
        self._decode_checks = tuple((i, f, ok) for i, f in enumerate(self.fields) if (ok := f.fast_check()))
        encode_checks = []
        for i, f in enumerate(self.fields):
            if f.type == "f32" and f.range is not None:
                # check the value that goes on the wire, so what encode accepts decode accepts
                encode_checks.append((i, f, lambda v, ok=f.fast_check(): ok(_round_f32(v))))
            elif f.type.startswith("bytes"):
                size = int(f.type[5:])
                encode_checks.append((i, f, lambda v, n=size: isinstance(v, (bytes, bytearray)) and len(v) == n))
            elif f.fast_check() is not None:
                encode_checks.append((i, f, f.fast_check()))
        self._encode_checks = tuple(encode_checks)
        self._text = tuple(i for i, f in enumerate(self.fields) if f.is_text)
        names = [f.name for f in self.fields]
        at = {name: i for i, name in enumerate(names)}    # a field's place by its name (TelemetryTracker has 40)
        spec = self

        def new(cls, *args: Any, **kwargs: Any) -> Message:
            if kwargs:
                values = list(args) + [None] * (len(names) - len(args))
                for key, value in kwargs.items():
                    i = at.get(key)
                    if i is None:
                        raise TypeError(f"{spec.name} has no field {key!r}")
                    values[i] = value
                args = tuple(values)
            if len(args) != len(names) or any(v is None for v in args):
                raise TypeError(f"{spec.name} takes fields {', '.join(names) or '(none)'}")
            return tuple.__new__(cls, args)

        attrs: dict[str, Any] = {"__slots__": (), "spec": self, "__new__": new, "__doc__": self.doc}
        for index, name in enumerate(names):
            attrs[name] = property(lambda s, i=index: tuple.__getitem__(s, i))
        self.type = type(self.name, (Message,), attrs)

    @property
    def size(self) -> int:
        return self._struct.size

    def encode(self, msg: Message) -> bytes:
        """Payload bytes of `msg`; raises `EncodeError` for a value out of range."""
        try:
            for index, fld, ok in self._encode_checks:
                if not ok(msg[index]):
                    raise EncodeError(f"{self.name}: {fld.check(msg[index]) or 'not representable as ' + fld.type}")
            if self._text:
                msg = [v.encode("ascii") if i in self._text else v for i, v in enumerate(msg)]
            return self._struct.pack(*msg)
        except (struct.error, OverflowError, TypeError) as exc:
            raise EncodeError(f"{self.name}: {exc}") from exc

    def decode(self, payload: bytes) -> Message:
        """The message in `payload`; raises `ParseError` (BAD_LENGTH / OUT_OF_RANGE)."""
        if len(payload) != self._struct.size:
            raise ParseError(Reason.BAD_LENGTH,
                             f"{self.name} takes {self._struct.size} payload bytes, got {len(payload)}")
        values = self._struct.unpack(payload)
        if self._text:
            values = self._text_from_wire(values)
        for index, fld, ok in self._decode_checks:
            if not ok(values[index]):
                raise ParseError(Reason.OUT_OF_RANGE, f"{self.name}: {fld.check(values[index])}")
        return tuple.__new__(self.type, values)

    def _text_from_wire(self, values: tuple) -> tuple:
        """`strN` and `textN` fields from their zero-padded bytes; anything but ASCII then zeros is refused (the
        decode checks then test a name's characters, a text's printability)."""
        values = list(values)
        for index in self._text:
            raw = values[index]
            text = raw.rstrip(b"\x00")
            if b"\x00" in text or not text.isascii():
                raise ParseError(Reason.OUT_OF_RANGE, f"{self.name}: {self.fields[index].name} is not "
                                 + ("a name" if self.fields[index].type.startswith("str") else "text"))
            values[index] = text.decode("ascii")
        return tuple(values)

    def canonical(self) -> str:
        """Text that the schema hash covers: everything that changes the wire."""
        fields = ",".join(f"{f.name}:{f.type}:{f.range}:{_enum_text(f.enum)}" for f in self.fields)
        return f"{self.id}|{self.name}|{self.cls.name}|{self.direction.name}|{self.reply}|{fields}"


class Schema:
    """A set of message specs with lookup by id and name, and its hash."""

    def __init__(self, version: int, specs: Iterable[MessageSpec]) -> None:
        self.version = version
        self.by_id: dict[int, MessageSpec] = {}
        self.by_name: dict[str, MessageSpec] = {}
        for spec in specs:
            if spec.id in self.by_id or spec.name in self.by_name:
                raise ValueError(f"message {spec.name} (id {spec.id:#x}) is declared twice")
            self.by_id[spec.id] = spec
            self.by_name[spec.name] = spec
        for spec in self.by_id.values():
            if spec.reply is not None and spec.reply not in self.by_name:
                raise ValueError(f"{spec.name} replies with undeclared {spec.reply}")
        self.reply_ids = frozenset(self.by_name[s.reply].id for s in self.by_id.values() if s.reply)
        # a reply travels in the classes of the requests it answers (Result: both, as EStop's and Reset's reply;
        # it is also how any command whose payload does not decode is refused, in the command's class)
        self._reply_classes: dict[int, frozenset[int]] = {
            reply_id: frozenset(int(s.cls) for s in self.by_id.values()
                                if s.reply and self.by_name[s.reply].id == reply_id) for reply_id in self.reply_ids}
        text = f"v{version}\n" + "\n".join(s.canonical() for s in sorted(self.by_id.values(), key=lambda s: s.id))
        self.hash = int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little")
        self._receivable: dict[Direction, dict[tuple[int, int], MessageSpec]] = {}

    def __getitem__(self, name: str) -> MessageSpec:
        return self.by_name[name]

    def class_allowed(self, spec: MessageSpec, cls: int) -> bool:
        """Replies travel in the class of the requests they answer (COMMAND, URGENT or both); others in their own."""
        if spec.id in self.reply_ids:
            return cls in self._reply_classes[spec.id]
        return spec.cls == cls

    def receivable(self, direction: Direction) -> dict[tuple[int, int], MessageSpec]:
        """(message id, class byte) -> spec of every message an end receiving in `direction` takes, in the classes
        it may come in (`class_allowed`); any other pair is refused. Made once per direction: a link's receive
        path looks every frame up in it."""
        table = self._receivable.get(direction)
        if table is None:
            table = self._receivable[direction] = {
                (spec.id, int(cls)): spec for spec in self.by_id.values() for cls in MsgClass
                if self.class_allowed(spec, cls) and spec.direction in (direction, Direction.BOTH)}
        return table

    def teleop_commands(self) -> dict[str, MessageSpec]:
        return {s.teleop: s for s in self.by_id.values() if s.teleop}

    def encode(self, msg: Message) -> tuple[int, bytes]:
        spec = msg.spec
        return spec.id, spec.encode(msg)

    def decode(self, msg_id: int, payload: bytes) -> Message:
        spec = self.by_id.get(msg_id)
        if spec is None:
            raise ParseError(Reason.UNKNOWN_MESSAGE, f"message id {msg_id:#06x} is not declared")
        return spec.decode(payload)
