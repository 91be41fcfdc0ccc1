"""Black-box findings made small: the fewest steps of a case that still fail, each made plainer, and what sets a
finding off (its `trigger`, part of its signature: host_tools/fuzz/findings.py).

A case's steps are shrunk by delta debugging (any step may be the failing one: the health check comes after them
all), then each step is made plainer one change at a time while the finding still fails with the same signature:
its pause dropped, a crafted frame's knobs (version, flags, length, MAC) set right, each field of its payload set
back to a plain valid value (its declared default, its first enum member, zero or its range's low end, an empty
text), a payload of another length cut to its message's, raw bytes halved. What is left names the message and the
fields that trigger the bug: for the planted BoxDial crash, `BoxDial.percent` (the dial at 100 %, the axis set
back to its default).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Callable

from protocol.messages import SCHEMA

from host_tools.fuzz.boundaries import FOLLOWS
from host_tools.fuzz.findings import _ddmin


def minimal_steps(steps: list[dict], fails: Callable[[list[dict]], bool]) -> list[dict]:
    """The fewest of `steps` that still fail (delta debugging; the failing step may be any of them), each then
    made plainer (`shrink_steps`)."""
    return shrink_steps(_ddmin([dict(s) for s in steps], fails, keep_last=False), fails)


def shrink_steps(steps: list[dict], fails: Callable[[list[dict]], bool]) -> list[dict]:
    """Each step made plainer while `fails` holds: its pause gone, a crafted frame's knobs back to their right
    values, and each field of its payload set back to its default (or zero, or an empty text), one at a time; a
    payload that does not decode, and raw bytes, shortened. The steps as they last failed."""
    steps = [dict(s) for s in steps]
    for index in range(len(steps)):
        plainer = True
        while plainer:                # each change kept makes the step plainer: this ends
            plainer = False
            for candidate in _plainer(steps[index]):
                trial = steps[:index] + [candidate] + steps[index + 1:]
                if fails(trial):
                    steps, plainer = trial, True
                    break
    return steps


def _plainer(step: dict):
    """Plainer versions of `step`, one change each, generated from the step as it stands then."""
    step = {k: v for k, v in step.items() if k != "wire"}
    if step["delay_s"]:
        yield {**step, "delay_s": 0.0}
    if step["kind"] == "frame":
        for knob, right in (("version", 1), ("flags", 0x10), ("length_delta", 0), ("mac", "good")):
            if step[knob] != right:
                yield {**step, knob: right}
    if step["kind"] in ("command", "frame") and step.get("payload"):
        spec = SCHEMA[step["msg"]]
        payload = bytes.fromhex(step["payload"])
        if len(payload) == spec.size:
            kept = {f.name for f in spec.fields if f"{spec.name}.{f.name}" in FOLLOWS} if step.get("follow") else ()
            for candidate in _fields_back(spec, payload, kept):
                yield {**step, "payload": candidate.hex()}
        elif len(payload) > spec.size:
            yield {**step, "payload": payload[:spec.size].hex()}
    if step["kind"] == "raw" and len(step["bytes"]) > 2:
        data = bytes.fromhex(step["bytes"])
        yield {**step, "bytes": data[:len(data) // 2].hex()}
        yield {**step, "bytes": data[len(data) // 2:].hex()}


def _fields_back(spec, payload: bytes, kept=()):
    """`payload` with one field at a time set back to a plain valid value (`_plain_value`), but those `kept` (a
    sequence's command carries what the reply before it says, whatever its payload held: set back, the finding
    would show a value never sent)."""
    offset = 0
    for fld in spec.fields:
        code = "<" + fld.struct_code
        size = struct.calcsize(code)
        value = _plain_value(fld)
        plain = value.ljust(size, b"\x00") if isinstance(value, bytes) else struct.pack(code, value)
        if fld.name not in kept and payload[offset:offset + size] != plain:
            yield payload[:offset] + plain + payload[offset + size:]
        offset += size


def _plain_value(fld):
    """A field's declared default; else its first enum member, zero (or its range's low end if zero is outside
    it), or an empty text."""
    if fld.is_text or fld.type.startswith("bytes"):
        return fld.default.encode("latin-1") if isinstance(fld.default, str) else b""
    if fld.default is not None:
        return fld.default
    if fld.enum is not None:
        return int(min(fld.enum))
    zero = 0.0 if fld.struct_code == "f" else 0
    if fld.range is not None and not fld.range[0] <= zero <= fld.range[1]:
        return type(zero)(fld.range[0])
    return zero


def trigger(steps: list[dict]) -> str:
    """What sets a finding off, for its signature: the message of its last step that names one, and the fields of
    that step's payload not at their plain values (`payload` for one of another length); else the last step's
    kind."""
    named = [step for step in steps if step.get("msg") and step["kind"] in ("command", "frame", "burst")]
    if not named:
        return steps[-1]["kind"] if steps else ""
    step = named[-1]
    spec = SCHEMA[step["msg"]]
    payload = bytes.fromhex(step.get("payload", ""))
    if len(payload) != spec.size:
        return f"{spec.name}.payload"
    offset, odd = 0, []
    for fld in spec.fields:
        size = struct.calcsize("<" + fld.struct_code)
        plain = next(_fields_back(_OneField(fld), payload[offset:offset + size]), None)
        if plain is not None:
            odd.append(fld.name)
        offset += size
    return f"{spec.name}." + ",".join(odd)


@dataclass(frozen=True)
class _OneField:
    """A message of one field (`_fields_back` of one field's bytes)."""
    field: object

    @property
    def fields(self) -> tuple:
        return (self.field,)
