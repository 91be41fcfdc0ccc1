"""Boundaries the target says at run time, and the numbers it compares with: what the grammar draws beside the
declaration's own.

The declaration knows a field's range; it does not know how many parameters a controller has, each one's range,
how many knots its trajectory buffer holds, or the constant a handler compares a value with. An off-by-one against
any of those lives one step from a number only the target knows: a ParamList `index` at exactly the table's length
is one draw in 65,536 for a grammar that does not know the length, and one in a few for one that does.

`Boundaries` keeps what was learned: for a message's field ("ParamList.index"), the values below, at and past each
count or limit a reply revealed; for a parameter's name, its range (ParamSet's value, drawn one f32 step below,
at and past each end); and interior values, numbers seen in replies or harvested from the handlers' code, which
no comparison traced in process would give the engine (atheris 2.3.0 traces comparisons of ints, bytes and str
to libFuzzer, not of floats: its tracer's TraceCompareOp). Besides, what the target's last reply says the next
command must carry to be taken (`now_for`: the knot the trajectory buffer takes next), for the sequences that
build state step by step (grammar.py `draw_chain`). `learn` takes any message the target sent; the in-process
link targets feed it their controller's own replies when their world is built (and `follow` each reply after),
the black-box fuzzer every reply, event and telemetry frame it hears.
"""
from __future__ import annotations

import math
import struct
import types
from typing import Any, Callable, Iterable, Optional

from protocol.schema import Field, Message, MessageSpec

_F32 = struct.Struct("<f")
F32_MAX = 3.4028234663852886e38
INTERIOR_MAX = 128           # interior values kept (drawn at random: a few hundred would drown the edges)


def f32(value: float) -> float:
    """`value` as the nearest f32 (infinite beyond its range)."""
    if math.isnan(value) or math.isinf(value):
        return value
    if abs(value) > F32_MAX:
        return math.copysign(math.inf, value)
    return _F32.unpack(_F32.pack(value))[0]


def f32_step(value: float, towards: float) -> float:
    """The next f32 after `value` towards `towards`: the first value beyond a float boundary."""
    value = f32(value)
    if value == 0:
        return math.copysign(1.4e-45, towards - value)
    bits = struct.unpack("<i", _F32.pack(value))[0]
    up = (towards > value) == (bits >= 0)
    return struct.unpack("<f", struct.pack("<i", bits + (1 if up else -1)))[0]


def count_edges(n: int) -> tuple[int, ...]:
    """Below, at and past a count or a capacity `n` (an index `n` is the first one out of a table of `n`)."""
    return (n - 1, n, n + 1)


def range_edges(lo: float, hi: float) -> tuple[float, ...]:
    """One f32 step below, at and one step past each end of [lo, hi], both ways: where an off-by-one lives."""
    lo, hi = f32(lo), f32(hi)
    return tuple(dict.fromkeys((f32_step(lo, -math.inf), lo, f32_step(lo, math.inf),
                                f32_step(hi, -math.inf), hi, f32_step(hi, math.inf))))


# What each reply says about the target's own counts and limits: (reply, its field) -> the fields it bounds.
_COUNTS = {("ParamValue", "count"): ("ParamList.index",),
           ("TrajState", "knots"): ("TrajPoint.index", "TrajRun.count"),
           ("TrajState", "capacity"): ("TrajPoint.index", "TrajRun.count")}
_TIMES = {("TrajState", "t_last"): ("TrajPoint.t",)}     # a knot must come strictly after the last one
# What a reply says the next command must carry to be taken, as things stand now (`Boundaries.now_for`): the knot
# the buffer takes next, the count a run must name, a time at or just after the last knot's (the first knot is at
# 0, the last one's time while the buffer is empty; a later one after it).
_NEXT = {("TrajState", "knots"): ("TrajPoint.index", "TrajRun.count")}
_NEXT_TIME = {("TrajState", "t_last"): ("TrajPoint.t",)}
FOLLOWS = frozenset(where for table in (_NEXT, _NEXT_TIME) for targets in table.values() for where in targets)
FOLLOWED = frozenset(reply for table in (_NEXT, _NEXT_TIME) for reply, _field in table)    # replies that tell it


class Boundaries:
    """What the target revealed about itself, for the grammar (`values_for`)."""

    def __init__(self) -> None:
        self.edges: dict[str, set] = {}                      # "Message.field" -> values around the target's limits
        self.ranges: dict[str, tuple[float, float]] = {}     # a parameter's name -> its (min, max)
        self.interior: list[float] = []                      # numbers the target uses (in replies, in its code)
        self._interior_seen: set[float] = set()
        self._spill = 0                                      # where the next interior value goes once full
        self.now: dict[str, tuple] = {}                      # "Message.field" -> what the next one must carry

    def __bool__(self) -> bool:
        return bool(self.edges or self.ranges or self.interior)

    def add_edges(self, where: str, values: Iterable[float]) -> None:
        self.edges.setdefault(where, set()).update(v for v in values if not math.isnan(v))

    def add_interior(self, values: Iterable[Any]) -> None:
        """Numbers to draw now and then in any numeric field (at most INTERIOR_MAX, later ones replacing earlier
        ones in turn)."""
        for value in values:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                continue
            if value in self._interior_seen:
                continue
            self._interior_seen.add(value)
            if len(self.interior) < INTERIOR_MAX:
                self.interior.append(value)
            else:
                self._interior_seen.discard(self.interior[self._spill])
                self.interior[self._spill] = value
                self._spill = (self._spill + 1) % INTERIOR_MAX

    def learn(self, msg: Optional[Message], numbers: bool = True) -> None:
        """What `msg`, sent by the target, says: a table's length, a parameter's range, a buffer's knots and
        capacity, the time of its last knot; and (`numbers`) every float in it, as an interior value."""
        if msg is None:
            return
        self.follow(msg)
        name = msg.spec.name
        values = msg.as_dict()
        for fld in msg.spec.fields:
            value = values[fld.name]
            for where in _COUNTS.get((name, fld.name), ()):
                self.add_edges(where, count_edges(int(value)))
            for where in _TIMES.get((name, fld.name), ()):
                self.add_edges(where, (f32_step(value, -math.inf), f32(value), f32_step(value, math.inf)))
        if name == "ParamValue" and values["result"] == 0 and values["name"]:
            self.ranges[values["name"]] = (values["min"], values["max"])
        if name == "MotionAccepted" and values["limit"]:         # refused for a limit: it says the limit's value
            limit = values["limit_value"]
            self.add_interior((f32_step(limit, -math.inf), limit, f32_step(limit, math.inf)))
        if numbers:
            self.add_interior(v for v in values.values() if isinstance(v, float))

    def follow(self, msg: Optional[Message]) -> None:
        """What `msg`, a reply of the target's, says the next command of a sequence must carry (cheap: the
        in-process targets call it on every reply)."""
        if msg is None or msg.spec.name not in FOLLOWED:
            return
        name = msg.spec.name
        for fld in msg.spec.fields:
            for where in _NEXT.get((name, fld.name), ()):
                self.now[where] = (int(getattr(msg, fld.name)),)
            for where in _NEXT_TIME.get((name, fld.name), ()):
                t = f32(getattr(msg, fld.name))
                self.now[where] = (t, f32_step(t, math.inf), f32(t + 1.0))

    def now_for(self, spec: MessageSpec, fld: Field) -> tuple:
        """The values `fld` of `spec` must take to be taken next, as the target's last reply said (empty: none)."""
        return self.now.get(f"{spec.name}.{fld.name}", ())

    def values_for(self, spec: MessageSpec, fld: Field, before: list) -> tuple:
        """The learned values for `fld` of `spec`, given the fields drawn before it (ParamSet's value: the edges of
        the range of the parameter its name names), each of the field's wire type; empty if nothing is known."""
        out = list(self.edges.get(f"{spec.name}.{fld.name}", ()))
        if fld.type == "f32" and before and spec.fields[0].name == "name":
            known = self.ranges.get(before[0]) if isinstance(before[0], str) else None
            if known is not None:
                out += range_edges(*known)
        return _of_type(fld, out)

    def interior_for(self, fld: Field) -> tuple:
        return _of_type(fld, self.interior)


NO_BOUNDARIES = Boundaries()     # nothing learned (never added to: each fuzzer makes its own)


def _of_type(fld: Field, values: Iterable[float]) -> tuple:
    """`values` that the field's wire type holds (ints for an integer field, within its type's limits)."""
    if fld.is_text or fld.type.startswith("bytes"):
        return ()
    if fld.type == "f32":
        return tuple(float(v) for v in values)
    lo, hi = _TYPE_LIMITS[fld.type]
    return tuple(sorted({int(v) for v in values if float(v).is_integer() and lo <= v <= hi}))


_TYPE_LIMITS = {"u8": (0, 0xFF), "u16": (0, 0xFFFF), "u32": (0, 0xFFFFFFFF), "u64": (0, 2**64 - 1),
                "i8": (-0x80, 0x7F), "i16": (-0x8000, 0x7FFF), "i32": (-0x80000000, 0x7FFFFFFF), "bool": (0, 1)}


def constants_of(functions: Iterable[Callable]) -> tuple:
    """The float constants in the code of `functions` and the code nested in it, and the float globals that code
    reads (`PARK_DEG = 123.0` at the top of its module): what a handler compares with (`x == 123.0`,
    `x == PARK_DEG`), which the engine cannot see in a float comparison (an int comparison it sees: atheris traces
    it to libFuzzer, whose mutations then insert the value)."""
    found: dict = {}
    todo = [(getattr(fn, "__code__", None), getattr(fn, "__globals__", {})) for fn in functions]
    while todo:
        code, names = todo.pop()
        if code is None:
            continue
        for const in code.co_consts:
            if isinstance(const, types.CodeType):
                todo.append((const, names))
            elif isinstance(const, float):
                found[const] = None
        for name in code.co_names:
            value = names.get(name)
            if type(value) is float:
                found[value] = None
    return tuple(found)
