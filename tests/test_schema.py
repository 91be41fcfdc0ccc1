"""Property tests of the message codec (protocol/schema.py) over every declared message.

The strategies are built from the declarations themselves (`strategy_for(spec)`), so a
message added to protocol/messages.py is covered without touching this file. The wire
layout (little-endian, packed, fields in declared order) is written down here
independently of the codec (`_WIRE`), so a change of layout is caught, not copied.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import struct
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from protocol.errors import EncodeError, ParseError
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.schema import Field, Message, MessageSpec, MsgClass, Direction, Schema

SPECS = sorted(SCHEMA.by_id.values(), key=lambda s: s.id)
NAMES = [s.name for s in SPECS]     # parametrize by name: failures then print a short example
UNDECLARED_IDS = st.integers(0, 0xFFFF).filter(lambda i: i not in SCHEMA.by_id)

# The wire format of each field type, written down independently of protocol/schema.py:
# struct code and the type's own range (None: no integer range).
_WIRE: dict[str, tuple[str, tuple[int, int] | None]] = {
    "u8": ("B", (0, 2**8 - 1)),
    "u16": ("H", (0, 2**16 - 1)),
    "u32": ("I", (0, 2**32 - 1)),
    "u64": ("Q", (0, 2**64 - 1)),
    "i8": ("b", (-(2**7), 2**7 - 1)),
    "i16": ("h", (-(2**15), 2**15 - 1)),
    "i32": ("i", (-(2**31), 2**31 - 1)),
    "f32": ("f", None),
    "bool": ("?", None),
}
FLT_MAX = float(np.finfo(np.float32).max)

RUNS = settings(max_examples=60, deadline=None)


def _bytes_len(fld: Field) -> int | None:
    return int(fld.type[5:]) if fld.type.startswith("bytes") else None


def _str_len(fld: Field) -> int | None:
    return int(fld.type[3:]) if fld.type.startswith("str") else None


def _text_len(fld: Field) -> int | None:
    """N of a `textN` field: up to N printable ASCII characters, zero-padded."""
    return int(fld.type[4:]) if fld.type.startswith("text") else None


def _ascii_len(fld: Field) -> int | None:
    """N of a field carried as N bytes of ASCII, zero-padded (names and texts)."""
    return _str_len(fld) if _str_len(fld) is not None else _text_len(fld)


def _code(fld: Field) -> str:
    n = _bytes_len(fld) if _bytes_len(fld) is not None else _ascii_len(fld)
    return f"{n}s" if n is not None else _WIRE[fld.type][0]


def wire_values(spec: MessageSpec, msg) -> list:
    """The values as the payload carries them: names and texts as ASCII bytes."""
    return [v.encode("ascii") if _ascii_len(f) is not None else v for f, v in zip(spec.fields, msg)]


def wire_struct(spec: MessageSpec) -> struct.Struct:
    """The payload layout as this test understands it: little-endian, packed, declared order."""
    return struct.Struct("<" + "".join(_code(f) for f in spec.fields))


def _int_limits(fld: Field) -> tuple[int, int]:
    """Integer range a valid value may take: the type's range narrowed by the declared one."""
    lo, hi = _WIRE[fld.type][1]
    if fld.range is not None:
        lo, hi = max(lo, math.ceil(fld.range[0])), min(hi, math.floor(fld.range[1]))
    return lo, hi


def _f32(x: float) -> float:
    return float(np.float32(x))


def _f32_step(x: float, up: bool) -> float:
    return float(np.nextafter(np.float32(x), np.float32(np.inf if up else -np.inf)))


def _f32_limits(fld: Field) -> tuple[float, float]:
    """Float32 values inside the declared range (the ends rounded inwards), else all finite."""
    if fld.range is None:
        return -FLT_MAX, FLT_MAX
    lo, hi = _f32(fld.range[0]), _f32(fld.range[1])
    if lo < fld.range[0]:
        lo = _f32_step(lo, up=True)
    if hi > fld.range[1]:
        hi = _f32_step(hi, up=False)
    return lo, hi


def _enum_members(fld: Field) -> list[enum.IntEnum]:
    lo, hi = _int_limits(fld)
    return [m for m in fld.enum if lo <= m <= hi]


def field_strategy(fld: Field) -> st.SearchStrategy[Any]:
    """Every valid value of one declared field."""
    n = _bytes_len(fld)
    if n is not None:
        return st.binary(min_size=n, max_size=n)
    n = _str_len(fld)
    if n is not None:
        return st.from_regex(rf"[A-Za-z0-9_.\-]{{0,{n}}}", fullmatch=True)
    n = _text_len(fld)
    if n is not None:
        return st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=n)
    if fld.type not in _WIRE:
        raise AssertionError(f"field {fld.name}: type {fld.type!r} is new; teach tests/test_schema.py about it")
    if fld.type == "bool":
        return st.booleans()
    if fld.type == "f32":
        lo, hi = _f32_limits(fld)
        return st.floats(min_value=lo, max_value=hi, width=32, allow_nan=False, allow_infinity=False)
    if fld.enum is not None:
        return st.sampled_from(_enum_members(fld))
    lo, hi = _int_limits(fld)
    return st.integers(lo, hi)


def strategy_for(spec: MessageSpec) -> st.SearchStrategy[Message]:
    """Valid messages of `spec`, built from its declaration."""
    return st.tuples(*(field_strategy(f) for f in spec.fields)).map(lambda values: spec.type(*values))


def bad_value_strategy(fld: Field) -> st.SearchStrategy[Any] | None:
    """Values the field's wire type can carry but the declaration forbids (None: there are none)."""
    options: list[st.SearchStrategy[Any]] = []
    if fld.type == "f32":
        options.append(st.sampled_from([math.nan, math.inf, -math.inf]))
        if fld.range is not None:
            lo, hi = fld.range
            if lo > -FLT_MAX:
                options.append(st.floats(max_value=_f32_step(_f32_limits(fld)[0], up=False),
                                         width=32, allow_nan=False, allow_infinity=False))
            if hi < FLT_MAX:
                options.append(st.floats(min_value=_f32_step(_f32_limits(fld)[1], up=True),
                                         width=32, allow_nan=False, allow_infinity=False))
    elif _str_len(fld) is not None:
        # ASCII the wire can carry, but not a name
        options.append(st.from_regex(r"[A-Za-z0-9]{0,6}[ !@#$%^&*()+=,;:~]{1,6}", fullmatch=True))
    elif _text_len(fld) is not None:
        # ASCII the wire can carry, but not printable (a zero only as padding: one inside would end the text)
        options.append(st.from_regex(r"[ -~]{0,6}[\x01-\x1f\x7f]{1,6}", fullmatch=True))
    elif fld.type in _WIRE and _WIRE[fld.type][1] is not None:
        type_lo, type_hi = _WIRE[fld.type][1]
        lo, hi = _int_limits(fld)
        if type_lo < lo:
            options.append(st.integers(type_lo, lo - 1))
        if hi < type_hi:
            options.append(st.integers(hi + 1, type_hi))
        if fld.enum is not None:
            members = {int(m) for m in fld.enum}
            outsiders = [v for v in range(lo, min(hi, lo + 4096) + 1) if v not in members]
            if outsiders:
                options.append(st.sampled_from(outsiders))
    return st.one_of(options) if options else None


def _bad_fields(spec: MessageSpec) -> list[int]:
    return [i for i, f in enumerate(spec.fields) if bad_value_strategy(f) is not None]


def _raises_parse(reason: Reason, fn, *args) -> ParseError:
    with pytest.raises(ParseError) as info:
        fn(*args)
    assert info.value.reason is reason, info.value
    return info.value


# --- round trip ------------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
@RUNS
@given(data=st.data())
def test_round_trip_of_every_message(name: str, data):
    spec = SCHEMA[name]
    msg = data.draw(strategy_for(spec), label="msg")
    payload = spec.encode(msg)
    assert len(payload) == spec.size == wire_struct(spec).size
    assert payload == wire_struct(spec).pack(*wire_values(spec, msg)), "layout: little-endian, packed, declared order"
    decoded = spec.decode(payload)
    assert decoded == msg
    assert type(decoded) is spec.type
    assert SCHEMA.decode(spec.id, payload) == msg
    assert SCHEMA.encode(msg) == (spec.id, payload)


def test_every_field_type_is_known_to_the_strategies():
    for spec in SPECS:
        for fld in spec.fields:
            field_strategy(fld)  # raises for a type this file does not know


# --- out of range ----------------------------------------------------------------------------

@pytest.mark.parametrize("name", [s.name for s in SPECS if _bad_fields(s)])
@RUNS
@given(data=st.data())
def test_out_of_range_value_refused_both_ways(name: str, data):
    spec = SCHEMA[name]
    msg = data.draw(strategy_for(spec), label="msg")
    index = data.draw(st.sampled_from(_bad_fields(spec)), label="field")
    bad = data.draw(bad_value_strategy(spec.fields[index]), label="bad value")
    values = list(msg)
    values[index] = bad
    with pytest.raises(EncodeError):
        spec.encode(spec.type(*values))
    payload = wire_struct(spec).pack(*wire_values(spec, values))
    _raises_parse(Reason.OUT_OF_RANGE, spec.decode, payload)
    _raises_parse(Reason.OUT_OF_RANGE, SCHEMA.decode, spec.id, payload)


@pytest.mark.parametrize("name", [s.name for s in SPECS if s.fields])
@RUNS
@given(data=st.data())
def test_unrepresentable_value_is_an_encode_error(name: str, data):
    """Values no wire type can carry: integers past the type, floats past float32, bytes of the wrong length."""
    spec = SCHEMA[name]
    msg = data.draw(strategy_for(spec), label="msg")
    index = data.draw(st.integers(0, len(spec.fields) - 1), label="field")
    fld = spec.fields[index]
    n = _bytes_len(fld)
    if n is not None:
        bad = data.draw(st.binary(max_size=n + 8).filter(lambda b: len(b) != n), label="bytes")
    elif fld.type == "f32":
        bad = data.draw(st.floats(min_value=FLT_MAX * 2, allow_infinity=False)
                        | st.floats(max_value=-FLT_MAX * 2, allow_infinity=False), label="huge")
    elif fld.type == "bool":
        return
    elif _str_len(fld) is not None:
        bad = data.draw(st.text(min_size=_str_len(fld) + 1, max_size=_str_len(fld) + 8)
                        | st.text(min_size=1).filter(lambda t: any(not (c.isascii() and (c.isalnum() or c in "_.-"))
                                                                    for c in t)), label="text")
    elif _text_len(fld) is not None:
        printable = st.characters(min_codepoint=0x20, max_codepoint=0x7E)
        bad = data.draw(st.text(printable, min_size=_text_len(fld) + 1, max_size=_text_len(fld) + 8)
                        | st.text(min_size=1).filter(lambda t: any(not " " <= c <= "~" for c in t)), label="text")
    else:
        type_lo, type_hi = _WIRE[fld.type][1]
        bad = data.draw(st.integers(max_value=type_lo - 1) | st.integers(min_value=type_hi + 1), label="int")
    values = list(msg)
    values[index] = bad
    with pytest.raises(EncodeError):
        spec.encode(spec.type(*values))


def test_f32_too_large_for_float32_is_an_encode_error():
    """A finite supply voltage beyond float32 (a sensor gone mad) must not crash the encoder."""
    status = SCHEMA["Status"]
    msg = status.type(0, 1, 0, 0, 0, 1e39, 20.0, 0, 0, 0, 0.0, 0.0, 0.0)
    with pytest.raises(EncodeError):
        status.encode(msg)


@pytest.mark.parametrize("length", [0, 15, 17, 32])
def test_bytes_field_of_wrong_length_is_an_encode_error(length):
    """A 16-byte nonce given 15 or 17 bytes must be refused, not padded or cut silently."""
    hello = SCHEMA["Hello"]
    with pytest.raises(EncodeError):
        hello.encode(hello.type(1, SCHEMA.hash, bytes(range(1, length + 1)), bytes(8)))


@settings(max_examples=100, deadline=None)
@given(lo=st.floats(-1e6, 1e6), width=st.floats(1e-6, 1e6), data=st.data())
def test_f32_range_whatever_encode_accepts_decode_accepts(lo, width, data):
    """For an f32 field with a declared range, the controller must never refuse (OUT_OF_RANGE)
    a value the host's encoder accepted: the range is checked on what goes on the wire."""
    hi = lo + width
    spec = MessageSpec("Probe", 0x7F, MsgClass.COMMAND, Direction.TO_CONTROLLER, "probe",
                       (Field("x", "f32", "a ranged float", range=(lo, hi)),))
    value = data.draw(st.sampled_from([lo, hi]) | st.floats(lo, hi), label="value")
    try:
        payload = spec.encode(spec.type(value))
    except EncodeError:
        return
    spec.decode(payload)


# --- length and id ---------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
@RUNS
@given(data=st.data())
def test_wrong_length_is_bad_length(name: str, data):
    spec = SCHEMA[name]
    payload = data.draw(st.binary(max_size=spec.size + 16).filter(lambda b: len(b) != spec.size))
    _raises_parse(Reason.BAD_LENGTH, spec.decode, payload)
    _raises_parse(Reason.BAD_LENGTH, SCHEMA.decode, spec.id, payload)


@RUNS
@given(msg_id=UNDECLARED_IDS, payload=st.binary(max_size=300))
def test_unknown_id_is_unknown_message(msg_id, payload):
    _raises_parse(Reason.UNKNOWN_MESSAGE, SCHEMA.decode, msg_id, payload)


# --- arbitrary bytes -------------------------------------------------------------------------

@pytest.mark.parametrize("name", NAMES)
@settings(max_examples=100, deadline=None)
@given(data=st.data())
def test_arbitrary_payload_decodes_or_raises_parse_error(name: str, data):
    spec = SCHEMA[name]
    payload = data.draw(st.binary(min_size=spec.size, max_size=spec.size) | st.binary(max_size=260),
                        label="payload")
    for decode in (spec.decode, lambda p: SCHEMA.decode(spec.id, p)):
        try:
            msg = decode(payload)
        except ParseError as exc:
            assert isinstance(exc.reason, Reason)
            continue
        assert type(msg) is spec.type
        # what decode accepts is a valid message, and its only encoding is these bytes
        assert spec.encode(msg) == payload


@settings(max_examples=300, deadline=None)
@given(msg_id=st.sampled_from(sorted(SCHEMA.by_id)) | st.integers(0, 0xFFFF),
       payload=st.binary(max_size=260))
def test_arbitrary_id_and_payload_raise_only_parse_error(msg_id, payload):
    try:
        msg = SCHEMA.decode(msg_id, payload)
    except ParseError:
        return
    assert msg.spec is SCHEMA.by_id[msg_id]


# --- equality --------------------------------------------------------------------------------

_SAME_ARITY = [(a.name, b.name) for a in SPECS for b in SPECS if a is not b and len(a.fields) == len(b.fields)]


@pytest.mark.parametrize("first_name,other_name", _SAME_ARITY)
@settings(max_examples=10, deadline=None)
@given(data=st.data())
def test_messages_of_different_types_with_equal_values_differ(first_name: str, other_name: str, data):
    a, b = SCHEMA[first_name], SCHEMA[other_name]
    first = data.draw(strategy_for(a))
    other = b.type(*first)
    assert tuple(first) == tuple(other)
    assert first != other and other != first
    assert not first == other
    assert first == a.type(*first)
    assert first != tuple(first)
    assert len({first, other}) == 2


# --- schema hash -----------------------------------------------------------------------------

def _copy(spec: MessageSpec, **changes: Any) -> MessageSpec:
    return dataclasses.replace(spec, **changes)


def _rebuild(replace: dict[str, MessageSpec] | None = None, version: int = SCHEMA.version) -> Schema:
    replace = replace or {}
    return Schema(version, [replace.get(s.name, _copy(s)) for s in SPECS])


def _with_field(spec: MessageSpec, index: int, **changes: Any) -> MessageSpec:
    fields = list(spec.fields)
    fields[index] = dataclasses.replace(fields[index], **changes)
    return _copy(spec, fields=tuple(fields))


def _other_type(fld: Field) -> str:
    n = _bytes_len(fld)
    if n is not None:
        return f"bytes{n + 1}"
    if _str_len(fld) is not None:
        return f"str{_str_len(fld) + 1}"
    if _text_len(fld) is not None:
        return f"text{_text_len(fld) + 1}"
    return {"u8": "i8", "i8": "u8", "u16": "i16", "i16": "u16", "u32": "i32", "i32": "u32",
            "u64": "u32", "f32": "u32", "bool": "u8"}[fld.type]


_FIELDS = [(s, i) for s in SPECS for i in range(len(s.fields))]
_FIELD_IDS = [f"{s.name}.{s.fields[i].name}" for s, i in _FIELDS]


def test_hash_stable_for_identical_declarations():
    assert _rebuild().hash == SCHEMA.hash
    assert Schema(SCHEMA.version, [_copy(s) for s in reversed(SPECS)]).hash == SCHEMA.hash


def test_hash_stable_when_only_docs_units_and_teleop_change():
    replaced = {}
    for spec in SPECS:
        fields = tuple(dataclasses.replace(f, doc=f.doc + " (reworded)", unit=f.unit + "x", default=1)
                       for f in spec.fields)
        replaced[spec.name] = _copy(spec, doc=spec.doc + " (reworded)", fields=fields,
                                    teleop=(spec.teleop + "2") if spec.teleop else None)
    assert _rebuild(replaced).hash == SCHEMA.hash


def test_hash_changes_with_version():
    assert _rebuild(version=SCHEMA.version + 1).hash != SCHEMA.hash


@pytest.mark.parametrize("spec,index", _FIELDS, ids=_FIELD_IDS)
def test_hash_changes_with_field_type(spec: MessageSpec, index: int):
    changed = _with_field(spec, index, type=_other_type(spec.fields[index]))
    assert _rebuild({spec.name: changed}).hash != SCHEMA.hash


_RANGED = [(s, i) for s, i in _FIELDS if s.fields[i].type in _WIRE and s.fields[i].type != "bool"]


@pytest.mark.parametrize("spec,index", _RANGED, ids=[f"{s.name}.{s.fields[i].name}" for s, i in _RANGED])
def test_hash_changes_with_field_range(spec: MessageSpec, index: int):
    fld = spec.fields[index]
    new_range = (0, 1) if fld.range is None else (fld.range[0], fld.range[1] + 1)
    assert _rebuild({spec.name: _with_field(spec, index, range=new_range)}).hash != SCHEMA.hash
    if fld.range is not None:
        assert _rebuild({spec.name: _with_field(spec, index, range=None)}).hash != SCHEMA.hash


@pytest.mark.parametrize("name", NAMES)
def test_hash_changes_with_message_id(name: str):
    spec = SCHEMA[name]
    free = next(i for i in range(0x100, 0x10000) if i not in SCHEMA.by_id)
    assert _rebuild({spec.name: _copy(spec, id=free)}).hash != SCHEMA.hash


def test_swapping_two_message_ids_changes_the_hash():
    a, b = SCHEMA["Enable"], SCHEMA["Disable"]
    assert _rebuild({a.name: _copy(a, id=b.id), b.name: _copy(b, id=a.id)}).hash != SCHEMA.hash


def test_a_text_field_fits_any_text_to_what_it_can_carry():
    detail = SCHEMA["ParamSaved"].fields[1]
    assert detail.fit("Permission denied: /srv/params.json") == "Permission denied: /srv/params.json"
    fitted = detail.fit("No space left on device: /m\u00fcnchen/\t" + "x" * 500)
    assert len(fitted) == detail.text_size and fitted.endswith("...") and detail.check(fitted) is None
    assert fitted.startswith("No space left on device: /m?nchen/?")
    assert SCHEMA["ParamSaved"].decode(SCHEMA["ParamSaved"].encode(SCHEMA["ParamSaved"].type(26, fitted))).detail \
        == fitted


@pytest.mark.parametrize("name", NAMES)
@RUNS
@given(data=st.data())
def test_a_message_built_by_name_is_the_one_built_in_order(name: str, data):
    """Values by field name land in their fields whatever the order they are given in; an unknown name or one left
    out is refused, naming the message. `of` makes the same message from the values in order."""
    spec = SCHEMA[name]
    msg = data.draw(strategy_for(spec), label="msg")
    named = dict(reversed(list(zip((f.name for f in spec.fields), msg))))
    assert spec.type(**named) == msg
    assert spec.type.of(iter(msg)) == msg and type(spec.type.of(msg)) is spec.type
    if spec.fields:
        first, *rest = spec.fields
        assert spec.type(msg[0], **{f.name: v for f, v in zip(rest, msg[1:])}) == msg
        with pytest.raises(TypeError, match=f"{spec.name} takes fields"):
            spec.type(**{f.name: v for f, v in zip(rest, msg[1:])})
    with pytest.raises(TypeError, match=f"{spec.name} has no field 'no_such_field'"):
        spec.type(*msg, no_such_field=1)
