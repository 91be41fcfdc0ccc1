"""The link's grammar, from its one declaration (`protocol/messages.py` SCHEMA): what a fuzzer may put in each field.

A field's interesting values come from its type, its range and its enum: the boundaries, one step beyond them
(still in the wire type), zero, the type's own extremes, NaN and the infinities for floats, names and texts that
break their rules (too long, a character not allowed, a zero inside, a byte above 127). `pack_raw` packs any
such values with the field's struct code and none of the codec's checks, so a payload may be wrong on purpose.

Every choice comes from a `Draw`: `FdpDraw` over atheris' FuzzedDataProvider (in process: the coverage-guided
engine steers the choices), `RandomDraw` over a seeded `random.Random` (black-box: the same seed, the same cases).

Texts whose valid values the declaration cannot know (a parameter's name is the controller's, not the protocol's)
come from `Words`, a dictionary by field name, as libFuzzer's `-dict` gives words: without it no `ParamSet`
named a parameter, and the first campaign never set one (firmware_py/controller.py `_param_changed` unrun).
Numbers whose edges the declaration cannot know (a table's length, a parameter's range, a buffer's capacity, a
constant a handler compares with) come from `Boundaries` (host_tools/fuzz/boundaries.py), learned from the target.
"""
from __future__ import annotations

import math
import random
import struct
from types import MappingProxyType
from typing import Any, Mapping, Protocol as TypingProtocol, Sequence

from protocol.messages import SCHEMA
from protocol.schema import Direction, Field, MessageSpec

from host_tools.fuzz.boundaries import F32_MAX, FOLLOWED, FOLLOWS, NO_BOUNDARIES, Boundaries, f32, f32_step

_INT_LIMITS = {"b": (-2**7, 2**7 - 1), "B": (0, 2**8 - 1), "h": (-2**15, 2**15 - 1), "H": (0, 2**16 - 1),
               "i": (-2**31, 2**31 - 1), "I": (0, 2**32 - 1), "q": (-2**63, 2**63 - 1), "Q": (0, 2**64 - 1),
               "?": (0, 1)}
_F32 = struct.Struct("<f")
_f32, _f32_step = f32, f32_step

Words = Mapping[str, Sequence[str]]       # valid texts by field name (a parameter's name: its controller's)
NO_WORDS: Words = MappingProxyType({})

TO_CONTROLLER = tuple(s for s in SCHEMA.by_id.values() if s.direction in (Direction.TO_CONTROLLER, Direction.BOTH))
TO_HOST = tuple(s for s in SCHEMA.by_id.values() if s.direction in (Direction.TO_HOST, Direction.BOTH))


class Draw(TypingProtocol):
    """Where a fuzzer's choices come from."""

    def pick(self, n: int) -> int: ...                   # 0 <= i < n
    def int_in(self, lo: int, hi: int) -> int: ...       # lo <= i <= hi
    def raw(self, n: int) -> bytes: ...                  # at most n bytes
    def any_float(self) -> float: ...                    # any double, NaN and infinities included
    def left(self) -> int: ...                           # how much input is left (0: choices are all zeros now)


class FdpDraw:
    """Choices from libFuzzer's input, through atheris' FuzzedDataProvider."""

    def __init__(self, data: bytes) -> None:
        import atheris
        self._fdp = atheris.FuzzedDataProvider(data)

    def pick(self, n: int) -> int:
        return self._fdp.ConsumeIntInRange(0, n - 1) if n > 1 else 0

    def int_in(self, lo: int, hi: int) -> int:
        return self._fdp.ConsumeIntInRange(lo, hi)

    def raw(self, n: int) -> bytes:
        return self._fdp.ConsumeBytes(n)

    def any_float(self) -> float:
        return self._fdp.ConsumeRegularFloat() if self._fdp.ConsumeBool() else self._fdp.ConsumeFloat()

    def left(self) -> int:
        return self._fdp.remaining_bytes()


class RandomDraw:
    """Choices from a seeded generator (the black-box fuzzer's: the same seed gives the same cases)."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def pick(self, n: int) -> int:
        return self.rng.randrange(n) if n > 1 else 0

    def int_in(self, lo: int, hi: int) -> int:
        return self.rng.randint(lo, hi)

    def raw(self, n: int) -> bytes:
        return self.rng.randbytes(self.rng.randint(0, n))

    def any_float(self) -> float:
        return _F32.unpack(self.rng.randbytes(4))[0] if self.rng.random() < 0.5 else self.rng.uniform(-1e6, 1e6)

    def left(self) -> int:
        return 1 << 30


def interesting(fld: Field) -> list[Any]:
    """The values worth trying in `fld`: its boundaries and one beyond, zero, the type's extremes, broken texts."""
    if fld.type.startswith("bytes"):
        n = fld.text_size
        return [bytes(n), b"\xff" * n, bytes(range(n))]
    if fld.is_text:
        n = fld.text_size
        name_ok = "a" * n if fld.type.startswith("str") else "~" * n
        return ["", "x", name_ok, name_ok[:-1] + "\x7f", "a b" if fld.type.startswith("str") else "\t",
                b"\x00a", b"a\x00b", b"\xc3\xa9", b"\xff" * n, "J1"]
    code = fld.struct_code
    if code == "f":
        values = [0.0, -0.0, math.nan, math.inf, -math.inf, F32_MAX, -F32_MAX, 1.4e-45, 1.0, -1.0]
        if fld.range is not None:
            lo, hi = (_f32(v) for v in fld.range)
            values += [lo, hi, _f32_step(lo, -math.inf), _f32_step(hi, math.inf), (lo + hi) / 2]
        return values
    lo_t, hi_t = _INT_LIMITS[code]
    values = {lo_t, hi_t, 0, 1, hi_t - 1}
    if fld.range is not None:
        lo, hi = (int(v) for v in fld.range)
        values |= {lo, hi, lo - 1, hi + 1}
    if fld.enum is not None:
        members = [int(m) for m in fld.enum]
        values |= set(members) | {max(members) + 1, min(members) - 1}
    return sorted(v for v in values if lo_t <= v <= hi_t)


def draw_value(fld: Field, draw: Draw) -> Any:
    """One value for `fld`: mostly an interesting one, sometimes a valid one at random, sometimes anything."""
    how = draw.pick(5)
    if how == 4 and fld.range is not None and not fld.is_text:     # a boundary itself: where off-by-ones live
        return type(interesting(fld)[0])(fld.range[draw.pick(2)])
    if how <= 1:
        values = interesting(fld)
        return values[draw.pick(len(values))]
    if fld.type.startswith("bytes"):
        return draw.raw(fld.text_size).ljust(fld.text_size, b"\x00")
    if fld.is_text:
        return draw.raw(fld.text_size)
    if fld.struct_code == "f":
        if how == 2 and fld.range is not None:
            lo, hi = fld.range
            return lo + (hi - lo) * draw.int_in(0, 1 << 16) / (1 << 16)
        return draw.any_float()
    lo_t, hi_t = _INT_LIMITS[fld.struct_code]
    if how == 2 and fld.range is not None:
        return draw.int_in(max(lo_t, int(fld.range[0])), min(hi_t, int(fld.range[1])))
    return draw.int_in(lo_t, hi_t)


def pack_raw(spec: MessageSpec, values: Sequence[Any]) -> bytes:
    """`values` packed as `spec`'s payload with none of the codec's checks (texts as bytes, zero-padded and cut)."""
    return b"".join(_pack_field(fld, value) for fld, value in zip(spec.fields, values))


def _pack_field(fld: Field, value: Any) -> bytes:
    if fld.is_text or fld.type.startswith("bytes"):
        raw = value.encode("latin-1") if isinstance(value, str) else bytes(value)
        return raw[:fld.text_size].ljust(fld.text_size, b"\x00")
    if fld.struct_code == "f":
        return _F32.pack(_f32(value))
    return struct.pack("<" + fld.struct_code, value)


def draw_valid(fld: Field, draw: Draw, words: Words = NO_WORDS) -> Any:
    """A value the declaration allows: an enum member, a number in range (a quarter of the time one of the range's
    own ends, which are valid and where off-by-ones live), a text of `words` (three times in four) for a text
    field they name; a field with no declared rule, any value."""
    known = words.get(fld.name) if fld.is_text else None
    if known and draw.pick(4):
        return known[draw.pick(len(known))]
    if fld.enum is not None and not fld.is_text:
        members = [int(m) for m in fld.enum]
        return members[draw.pick(len(members))]
    if fld.range is not None and not fld.is_text:
        lo, hi = fld.range
        if draw.pick(4) == 0:
            return type(interesting(fld)[0])((lo, hi)[draw.pick(2)])
        if fld.struct_code == "f":
            return lo + (hi - lo) * draw.int_in(0, 1 << 16) / (1 << 16)
        return draw.int_in(int(lo), int(hi))
    return draw_value(fld, draw)


def draw_payload(spec: MessageSpec, draw: Draw, words: Words = NO_WORDS,
                 learned: Boundaries = NO_BOUNDARIES, follow: bool = False) -> bytes:
    """A payload for `spec`: bytes of any length (1 in 8); every field from the grammar (3 in 8); or every field
    valid but one, which comes from the grammar (half): a message that decodes, and so reaches its handler, with
    one field at or beyond its edge (a fuzzer of single fields, as boofuzz mutates one primitive at a time).
    A field the target told something about (`learned`) takes, one time in three, a value below, at or past
    one of the target's own limits for it, and one time in six an interior value the target uses. `follow`: a
    payload the target takes, to go on a sequence (`draw_chain`): every field valid, and those the target's last
    reply says the next command must carry (`Boundaries.now_for`) as it says."""
    if follow:
        return pack_raw(spec, [_now_or(learned.now_for(spec, fld), lambda fld=fld: draw_valid(fld, draw, words), draw)
                               for fld in spec.fields])
    how = draw.pick(8)
    if how == 0:
        return draw.raw(spec.size + 4)
    odd = draw.pick(len(spec.fields)) if how > 3 and spec.fields else -1
    values: list[Any] = []
    for i, fld in enumerate(spec.fields):
        told = learned.values_for(spec, fld, values) if learned else ()
        inner = learned.interior_for(fld) if learned else ()
        which = draw.pick(6) if told or inner else 5
        if which <= 1 and told:
            values.append(told[draw.pick(len(told))])
        elif which == 2 and inner:
            values.append(inner[draw.pick(len(inner))])
        elif odd < 0 or i == odd:
            values.append(draw_value(fld, draw))
        else:
            values.append(draw_valid(fld, draw, words))
    return pack_raw(spec, values)


def _now_or(now: tuple, otherwise, draw: Draw) -> Any:
    return now[draw.pick(len(now))] if now else otherwise()


def refollow(spec: MessageSpec, payload: bytes, learned: Boundaries, draw: Draw) -> bytes:
    """`payload` with the fields a sequence's next command must carry set as the target's last reply says (at the
    time it is sent, not when its case was drawn); a payload not of `spec`'s size as it is."""
    if len(payload) != spec.size:
        return payload
    out, offset = bytearray(payload), 0
    for fld in spec.fields:
        size = struct.calcsize("<" + fld.struct_code)
        now = learned.now_for(spec, fld)
        if now:
            out[offset:offset + size] = _pack_field(fld, now[draw.pick(len(now))])
        offset += size
    return bytes(out)


def draw_chain(commands: Sequence[MessageSpec], draw: Draw, most: int) -> list[MessageSpec]:
    """A sequence of commands that builds state step by step, as RESTler's producer-consumer sequences do: a
    command one of whose fields must carry what a reply says (TrajPoint's index, TrajRun's count: the knots the
    buffer holds), after 0..`most`-1 commands whose replies say it (TrajClear, TrajPoint: TrajState). A crash that
    needs TrajClear, two TrajPoints and TrajRun(2) is one draw of such chains in a few hundred, where commands drawn
    one by one, each TrajPoint's fields at random, never made it in 50,000 cases. Empty if none of `commands`
    follows a reply."""
    consumers = [s for s in commands if any(f"{s.name}.{f.name}" in FOLLOWS for f in s.fields)]
    producers = [s for s in commands if s.reply in FOLLOWED]
    if not consumers or not producers or most < 2:
        return []
    chain = [producers[draw.pick(len(producers))] for _ in range(draw.pick(most))]
    return chain + [consumers[draw.pick(len(consumers))]]
