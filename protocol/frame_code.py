"""Straight-line pack and unpack functions for one `FrameLayout`, compiled once from its fields.

MOTOR_CMD (19 signals, six duties and twelve single bits) crosses the HAL bus every
millisecond, and so do PLANT_SYNC and MOTOR_FB. A loop over a table of fields costs a
few tenths of a microsecond per signal and per direction; the lock-step world's budget
is 50 us a millisecond for everything. So each layout gets, once, the code a person
would write for it by hand, without the loop: one expression per signal, the range
checks that can fail and no others, every constant a literal (the way `dataclasses`
and `collections.namedtuple` build their methods). Measured on the development
machine: MOTOR_CMD 6.9 -> 1.9 us to pack, 4.6 -> 1.6 us to unpack.

The functions only take the fast path. `pack` returns None (or raises TypeError,
ValueError, OverflowError or `struct.error`) where a value needs a closer look, and
`unpack` returns None where a value is outside its range or the length is wrong: the
layout's own table-driven code then says exactly what is wrong (or, for a value that is
fine after all, gives the bytes). `source` keeps the code of each, for reading.

A third function, `roundtrip`, gives what `unpack(pack(values))` gives without the bytes: the
one-process world's nodes hand each other values that way (`protocol.value_frame`). It is
written from the same expressions as the other two (`_raw`, `_physical`), so it computes the
very same numbers; `roundtrip_source` says why the result is the one the bytes would give.

`Field` is what the generator needs of a signal; `FrameLayout` builds the list from
the DBC through cantools.
"""
from __future__ import annotations

import math
import operator
from fractions import Fraction
import struct
from dataclasses import dataclass
from typing import Callable, Optional, Sequence


@dataclass(frozen=True)
class Field:
    """One signal of a layout, in the layout's order."""

    start: int            # first bit, little-endian numbering
    length: int           # bits
    signed: bool
    scale: float
    offset: float
    encode_lo: float      # accepted on pack (the declared range, cantools' strict tolerance)
    encode_hi: float
    decode_lo: float      # accepted on unpack (the declared range widened by half a count)
    decode_hi: float

    @property
    def identity(self) -> bool:
        return self.scale == 1 and self.offset == 0

    def physical(self, raw: int) -> float:
        return raw if self.identity else raw * self.scale + self.offset

    def raw_span(self) -> tuple[int, int]:
        if self.signed:
            return -(1 << (self.length - 1)), (1 << (self.length - 1)) - 1
        return 0, (1 << self.length) - 1

    def accepted_ints(self) -> tuple[int, int]:
        """The integers an identity signal packs: inside its encode range (where declared) and its raw range."""
        lo, hi = self.raw_span()
        if math.isfinite(self.encode_lo):
            lo = max(lo, math.ceil(self.encode_lo))
        if math.isfinite(self.encode_hi):
            hi = min(hi, math.floor(self.encode_hi))
        return lo, hi

    def decodes_inside(self) -> bool:
        """True if every raw value decodes inside [decode_lo, decode_hi] (no check needed on unpack).

        raw * scale + offset is monotonic in raw for floats too, so the two ends decide.
        """
        ends = [self.physical(r) for r in self.raw_span()]
        return all(self.decode_lo <= v <= self.decode_hi for v in ends)


def _literal(value: float) -> str:
    """Python source for a number; repr round-trips floats exactly."""
    if isinstance(value, float) and not math.isfinite(value):
        return ("-" if value < 0 else "") + "_INF"
    return repr(value)


def _compile(source: str, name: str, namespace: dict) -> Callable:
    namespace = {"_INF": math.inf, **namespace}
    exec(compile(source, f"<frame layout {name}>", "exec"), namespace)
    return namespace["fn"]


def _check(var: str, lo: float, hi: float) -> str:
    return f"{_literal(lo)} <= {var} <= {_literal(hi)}"


def _quotient(var: str, f: Field) -> str:
    """What `pack` rounds to a scaled signal's raw integer: (value - offset) / scale."""
    shifted = f"({var} - {_literal(f.offset)})" if f.offset else var     # x - 0 is x, to the bit
    return f"{shifted} / {_literal(f.scale)}"


def _raw(var: str, f: Field) -> str:
    """The raw integer `pack` computes from a scaled signal's physical value."""
    return f"round({_quotient(var, f)})"


def _physical(raw: str, f: Field) -> str:
    """The physical value `unpack` computes from a scaled signal's raw integer."""
    # + 0 changes nothing unless raw * scale is -0.0, which only a negative scale gives
    plus = f" + {_literal(f.offset)}" if f.offset or f.scale < 0 else ""
    return f"{raw} * {_literal(f.scale)}{plus}"


def _unpack_names(names: Sequence[str], source: str) -> str:
    return f"    {', '.join(names)}{',' if len(names) == 1 else ''} = {source}"


# struct format codes of the whole-byte integer fields, by (bits, signed)
STRUCT_CODES = {(8, False): "B", (8, True): "b", (16, False): "H", (16, True): "h",
                 (32, False): "I", (32, True): "i", (64, False): "Q", (64, True): "q"}


def struct_plan(fields: Sequence[Field], length: int) -> Optional[tuple[str, list[list[int]]]]:
    """A struct format for the frame and, per item, the fields it carries; None if there is none.

    An item is one byte-aligned 8/16/32/64-bit field, or one byte holding single-bit fields (or any
    fields that stay inside that byte). Small ints for the bits are cheaper than shifting them into
    one integer of the whole frame's width.
    """
    by_start = sorted(range(len(fields)), key=lambda i: fields[i].start)
    fmt, items, at = "<", [], 0
    for i in by_start:
        f = fields[i]
        byte, end = f.start // 8, f.start + f.length
        if f.start % 8 == 0 and (f.length, f.signed) in STRUCT_CODES:
            if f.start < at:
                return None
            fmt += f"{(f.start - at) // 8}x" if f.start > at else ""
            fmt += STRUCT_CODES[(f.length, f.signed)]
            items.append([i])
            at = end
        elif not f.signed and end <= 8 * (byte + 1):
            if items and at == 8 * (byte + 1) and fmt.endswith("B") and fields[items[-1][0]].length < 8:
                items[-1].append(i)                  # another field in the same byte
                continue
            if 8 * byte < at:
                return None
            fmt += f"{byte - at // 8}x" if 8 * byte > at else ""
            fmt += "B"
            items.append([i])
            at = 8 * (byte + 1)
        else:
            return None
    if at > 8 * length:
        return None
    fmt += f"{length - at // 8}x" if at < 8 * length else ""
    return fmt, items


def _bits(f: Field) -> bool:
    """Carried inside a byte with others (not a whole struct item of its own)."""
    return not (f.start % 8 == 0 and (f.length, f.signed) in STRUCT_CODES)


def pack_source(fields: Sequence[Field], length: int, check_all: bool) -> tuple[str, Optional[str]]:
    """Source of `fn(values) -> bytes | None`, and the struct format `_S` it packs with (None: the
    raw values are shifted into one integer). `check_all`: every value against its encode range
    (else none: struct refuses what does not fit a full-range layout)."""
    names = [f"v{i}" for i in range(len(fields))]
    lines = ["def fn(values, round=round):", _unpack_names(names, "values")]
    if check_all:
        lines.append("    if not (" + " and ".join(_check(n, f.encode_lo, f.encode_hi)
                                             for n, f in zip(names, fields)) + "):")
        lines.append("        return None")
    raws = []
    for n, f in zip(names, fields):
        if f.identity and f.length == 1 and not f.signed and check_all:
            raws.append(f"({n} > 0.5)")     # round() of a value the check kept within [0, 1] (it rounds 0.5 to 0)
        elif f.identity:
            raws.append(f"round({n})" if check_all else n)
        else:
            raws.append(_raw(n, f))
    plan = struct_plan(fields, length)
    if plan is not None:
        fmt, items = plan
        args = []
        for item in items:
            if len(item) == 1 and not _bits(fields[item[0]]):
                args.append(raws[item[0]])
            else:
                terms = []
                for i in item:
                    shift = fields[i].start % 8
                    term = raws[i] if fields[i].length == 1 and check_all and fields[i].identity \
                        else f"({raws[i]} & {(1 << fields[i].length) - 1:#x})"
                    terms.append(f"{term} << {shift}" if shift else term)
                args.append(" | ".join(terms))
        lines.append(f"    return _S({', '.join(args)})")
        return "\n".join(lines) + "\n", fmt
    terms = []
    for raw, f in zip(raws, fields):
        term = f"({raw} & {(1 << f.length) - 1:#x})"
        terms.append(f"{term} << {f.start}" if f.start else term)
    lines.append(f"    return ({' | '.join(terms)}).to_bytes({length}, 'little')")
    return "\n".join(lines) + "\n", None


def unpack_source(fields: Sequence[Field], length: int) -> tuple[str, Optional[str]]:
    """Source of `fn(data) -> list | None` (physical values, None if a length or a value is wrong) and
    the struct format `_U` it unpacks with (None: one integer of the whole frame, shifted)."""
    lines = ["def fn(data):", f"    if len(data) != {length}:", "        return None"]
    names = [f"v{i}" for i in range(len(fields))]
    raws = [f"r{i}" for i in range(len(fields))]
    plan = struct_plan(fields, length)
    if plan is not None:
        fmt, items = plan
        item_names = [f"r{item[0]}" if len(item) == 1 and not _bits(fields[item[0]]) else f"b{k}"
                      for k, item in enumerate(items)]
        lines.append(f"    {', '.join(item_names)}{',' if len(items) == 1 else ''} = _U(data)")
        for item, item_name in zip(items, item_names):
            if item_name.startswith("b"):
                for i in item:
                    f = fields[i]
                    shifted = f"{item_name} >> {f.start % 8}" if f.start % 8 else item_name
                    lines.append(f"    r{i} = {shifted} & {(1 << f.length) - 1:#x}")
    else:
        fmt = None
        lines.append("    x = int.from_bytes(data, 'little')")
        for i, f in enumerate(fields):
            bits = f"x >> {f.start} & {(1 << f.length) - 1:#x}" if f.start else f"x & {(1 << f.length) - 1:#x}"
            if f.signed:       # two's complement: flip the sign bit, subtract its weight
                sign = 1 << (f.length - 1)
                bits = f"(({bits}) ^ {sign:#x}) - {sign:#x}"
            lines.append(f"    r{i} = {bits}")
    checks = []
    for n, r, f in zip(names, raws, fields):
        if not f.identity:
            lines.append(f"    {n} = {_physical(r, f)}")
        if not f.decodes_inside():
            checks.append(_check(n if not f.identity else r, f.decode_lo, f.decode_hi))
    if checks:
        lines += ["    if not (" + " and ".join(checks) + "):", "        return None"]
    lines.append(f"    return [{', '.join(n if not f.identity else r for n, r, f in zip(names, raws, fields))}]")
    return "\n".join(lines) + "\n", fmt


# Rounding a float to the nearest integer, ties to even, as `round` does, without the call (a fifth of
# its cost): for |x| < 2**51, x + 1.5 * 2**52 lies where the doubles are the integers, so IEEE addition
# rounds x to an integer there, ties to the even one (1.5 * 2**52 is even), and subtracting 1.5 * 2**52
# again is exact. The result is round(x) as a float (never -0.0), whose product with a scale is the very
# double round(x)'s int gives (an int below 2**53 converts to a double exactly).
ROUNDER = 1.5 * 2.0 ** 52


def _raw_bounds(f: Field) -> Optional[tuple[int, int]]:
    """The least and the greatest raw value a scaled signal's value that passed its encode check can give
    (exact bounds of the quotient, widened by 2**-50 of it for the subtraction's and the division's
    rounding, then rounded to the nearest integer outward); None without a finite encode range or past
    2**50 (the adding trick's reach, with room)."""
    if not (math.isfinite(f.encode_lo) and math.isfinite(f.encode_hi)):
        return None
    ends = [(Fraction(end) - Fraction(f.offset)) / Fraction(f.scale) for end in (f.encode_lo, f.encode_hi)]
    widen = max(abs(e) for e in ends) / 2 ** 50
    lo, hi = math.ceil(min(ends) - widen - Fraction(1, 2)), math.floor(max(ends) + widen + Fraction(1, 2))
    return (lo, hi) if max(-lo, hi) < 2 ** 50 else None


def roundtrip_source(fields: Sequence[Field]) -> str:
    """Source of `fn(values) -> list | None`: the list `unpack(pack(values))` gives, without the bytes.

    Why it is that list, to the bit and the type: for each signal `fn` computes the raw integer
    with pack's own expression (`_raw`: `round((v - offset) / scale)`; an identity signal's value
    is its raw integer) and the physical value from it with unpack's own (`_physical`). The bytes
    hold each raw integer as it is when it fits its field (fields do not overlap: cantools
    refuses that), and unpack reads it back as the same `int`. So `fn` checks just that: each
    scaled value inside its encode range (pack's check), each raw value an exact `int`
    (`operator.index`: a bool or a numpy integer gives its int; a float for an identity signal
    is refused, pack would round it) inside what its field holds (an identity signal's also
    inside its encode range), each physical value inside what unpack accepts. Where a check
    fails it returns None (or raises TypeError, ValueError, ArithmeticError for what is not a
    number); the caller then takes the bytes, and with them pack's and unpack's own errors.
    Checking more than pack does (a layout whose pack leaves ranges to `struct`) only declines.

    Two shortcuts keep to that. A scaled signal whose encode range bounds its raw value below
    2**50 (`_raw_bounds`) rounds a Python float by adding and subtracting `ROUNDER` (the same
    integer as `round`, as a float, and so the same physical value); anything else (an int's
    quotient is a float too; a numpy float is not) goes through `round` and `index`. And a check
    that those bounds already imply (the raw value inside its field, the physical value inside
    what unpack accepts) is left out. (And the single bits, exact ints by then, are checked
    together: `not (r1 | r2 | ...) >> 1`.)
    """
    names = [f"v{i}" for i in range(len(fields))]
    lines = ["def fn(values, round=round, index=index, type=type, float=float):", _unpack_names(names, "values")]
    scaled = [(n, f) for n, f in zip(names, fields) if not f.identity]
    if scaled:
        lines += ["    if not (" + " and ".join(_check(n, f.encode_lo, f.encode_hi) for n, f in scaled) + "):",
                  "        return None"]
    raw_checks, decode_checks, results, bits = [], [], [], []
    for i, (n, f) in enumerate(zip(names, fields)):
        r = f"r{i}"
        decodes_inside = f.decodes_inside()
        if f.identity:
            lines.append(f"    {r} = index({n})")
            if f.accepted_ints() == (0, 1):
                bits.append(r)
            else:
                raw_checks.append(_check(r, *f.accepted_ints()))
            result = r
        else:
            bounds = _raw_bounds(f)
            raw_lo, raw_hi = f.raw_span()
            if bounds is None:
                lines.append(f"    {r} = index({_raw(n, f)})")
            else:
                lines.append(f"    x{i} = {_quotient(n, f)}")
                lines.append(f"    {r} = x{i} + {ROUNDER!r} - {ROUNDER!r} if type(x{i}) is float "
                             f"else index(round(x{i}))")
            if bounds is not None and raw_lo <= bounds[0] and bounds[1] <= raw_hi:
                decodes_inside = decodes_inside or _decodes_inside(f, *bounds)     # and the raw value fits
            else:
                raw_checks.append(_check(r, raw_lo, raw_hi))
            result = f"p{i}"
        if not decodes_inside:
            decode_checks.append(_check(result, f.decode_lo, f.decode_hi))
        results.append(result)
    if len(bits) > 1:
        # Ints all 0 or 1: their bitwise or is (a negative int's is negative, one of 2 or more has a higher bit).
        raw_checks.append(f"not ({' | '.join(bits)}) >> 1")
    else:
        raw_checks += [_check(r, 0, 1) for r in bits]
    if raw_checks:
        lines += ["    if not (" + " and ".join(raw_checks) + "):", "        return None"]
    lines += [f"    p{i} = {_physical(f'r{i}', f)}" for i, f in enumerate(fields) if not f.identity]
    if decode_checks:
        lines += ["    if not (" + " and ".join(decode_checks) + "):", "        return None"]
    lines.append(f"    return [{', '.join(results)}]")
    return "\n".join(lines) + "\n"


def _decodes_inside(f: Field, raw_lo: int, raw_hi: int) -> bool:
    """True if every raw value in [raw_lo, raw_hi] decodes inside [decode_lo, decode_hi] (monotonic: the ends
    decide, computed as unpack computes them)."""
    return all(f.decode_lo <= f.physical(r) <= f.decode_hi for r in (raw_lo, raw_hi))


def compile_pack(name: str, fields: Sequence[Field], length: int, check_all: bool) -> tuple[Callable, str]:
    source, fmt = pack_source(fields, length, check_all)
    return _compile(source, name, {"_S": struct.Struct(fmt).pack} if fmt else {}), source


def compile_unpack(name: str, fields: Sequence[Field], length: int) -> tuple[Callable, str]:
    source, fmt = unpack_source(fields, length)
    return _compile(source, name, {"_U": struct.Struct(fmt).unpack} if fmt else {}), source


def compile_roundtrip(name: str, fields: Sequence[Field]) -> tuple[Callable, str]:
    source = roundtrip_source(fields)
    return _compile(source, name, {"index": operator.index}), source
