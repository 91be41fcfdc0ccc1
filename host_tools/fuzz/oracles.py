"""Oracles beyond "nothing crashed", judged against the declaration (protocol/messages.py) and the link's rules,
never against the code under test.

A decoder and an encoder that both accept one past a field's declared maximum round-trip perfectly: the codec
target's round trip passed such a defect, and the controller ran the command. So what a field may hold is read
here from the declaration alone (its type, `range`, `enum`, the rules of names and texts), with a decoding of our
own (`payload_violation`), and the codec's checks (`Field.check`, `fast_check`) are not used.

    declared_violation   a message's values against the declaration
    payload_violation    a payload against the declaration: its size, then its values
    reply_violation      a reply against the command it answers: its own reply or a Result refusing it (docs/
                         protocol.md rule 4), every field declared, a refusal with its reason, a command the
                         declaration refuses refused
    param_refusal_changed  a ParamSet refused whose reply says the value in force moved (a refused frame must
                         change nothing)
    nak_violation        a Nak that does not say why
    state_violation      a state and faults the protocol does not allow together (a fault latched outside the safe
                         states)
    case_violation       a black-box case's replies, by the two above the last

Each returns None when all is well, else what is wrong, in words a finding can carry.
"""
from __future__ import annotations

import math
import numbers
import re
import struct
from typing import Any, Mapping, Optional

from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.schema import Field, Message, MessageSpec
from protocol.states import ControllerState, Fault

_WHOLE = {"u8": (0, 0xFF), "u16": (0, 0xFFFF), "u32": (0, 0xFFFFFFFF), "u64": (0, 2**64 - 1), "i8": (-0x80, 0x7F),
          "i16": (-0x8000, 0x7FFF), "i32": (-0x80000000, 0x7FFFFFFF), "bool": (0, 1)}
_CODES = {"u8": "B", "u16": "H", "u32": "I", "u64": "Q", "i8": "b", "i16": "h", "i32": "i", "bool": "B", "f32": "f"}
_NAME = re.compile(r"[A-Za-z0-9_.\-]*")
_TEXT = re.compile(r"[ -~]*")
_F32_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]


def field_violation(fld: Field, value: Any) -> Optional[str]:
    """None if the declaration allows `value` in `fld`, else why not."""
    kind = fld.type
    if kind.startswith("bytes"):
        return None if isinstance(value, (bytes, bytearray)) and len(value) == fld.text_size else \
            f"{fld.name}={value!r} is not {fld.text_size} bytes"
    if kind.startswith(("str", "text")):
        rule = _NAME if kind.startswith("str") else _TEXT
        ok = isinstance(value, str) and len(value) <= fld.text_size and rule.fullmatch(value) is not None
        return None if ok else f"{fld.name}={value!r} is not a {kind}"
    if kind == "f32":      # (a handler's value may be numpy's: a Real, not a float)
        if not isinstance(value, numbers.Real) or not math.isfinite(value) or abs(value) > _F32_MAX:
            return f"{fld.name}={value!r} is not a finite f32"
    else:
        lo, hi = _WHOLE[kind]
        if not isinstance(value, numbers.Integral) or not lo <= value <= hi:
            return f"{fld.name}={value!r} is not a {kind}"
    if fld.range is not None and not fld.range[0] <= value <= fld.range[1]:
        return f"{fld.name}={value!r} is outside its declared range [{fld.range[0]:g}, {fld.range[1]:g}]"
    if fld.enum is not None and value not in {int(m) for m in fld.enum}:
        return f"{fld.name}={value!r} is not one of {fld.enum.__name__}'s {len(fld.enum)} members"
    return None


def declared_violation(spec: MessageSpec, values) -> Optional[str]:
    """None if every value of `values` (a message of `spec`, or its values in order) is one the declaration
    allows, else the first that is not."""
    values = tuple(values)
    if len(values) != len(spec.fields):
        return f"{spec.name} has {len(spec.fields)} fields, not {len(values)}"
    for fld, value in zip(spec.fields, values):
        why = field_violation(fld, value)
        if why is not None:
            return f"{spec.name}: {why}"
    return None


def payload_violation(spec: MessageSpec, payload: bytes) -> Optional[str]:
    """None if `payload` is a `spec` the declaration allows, else why not: decoded here, from the fields' types
    alone (a name or text: ASCII then zeros only), not by the codec under test."""
    codes = "".join(f"{f.text_size}s" if f.type.startswith(("bytes", "str", "text")) else _CODES[f.type]
                    for f in spec.fields)
    layout = struct.Struct("<" + codes)
    if len(payload) != layout.size:
        return f"{spec.name} is {layout.size} bytes, this payload {len(payload)}"
    values = list(layout.unpack(payload))
    for i, fld in enumerate(spec.fields):
        if fld.type.startswith(("str", "text")):
            text = values[i].rstrip(b"\x00")
            if b"\x00" in text or not text.isascii():
                return f"{spec.name}: {fld.name}={values[i]!r} is not ASCII then zeros"
            values[i] = text.decode("ascii")
    return declared_violation(spec, values)


def _result(msg: Message) -> Optional[int]:
    fields = msg.spec.fields
    return msg[0] if fields and fields[0].name == "result" else None


def reply_violation(command: MessageSpec, payload: Optional[bytes], reply: Message) -> Optional[str]:
    """None if `reply` is an answer the protocol allows to `command` (its payload `payload`, None: not known), else
    what is wrong: a reply of a type no rule allows, a value outside the declaration, a refusal without its reason
    (a Result saying OK to a command that has a reply of its own), or a command whose payload the declaration
    refuses taken (answered by anything but a Result refusing it)."""
    name = reply.spec.name
    if name != command.reply and name != "Result":
        return f"{name} in answer to {command.name}, which {command.reply} answers (or a Result refusing it)"
    why = declared_violation(reply.spec, reply)
    if why is not None:
        return f"the reply to {command.name} breaks the declaration: {why}"
    result = _result(reply)
    if name == "Result" and command.reply != "Result" and result == Reason.OK:
        return f"a Result saying OK, with no reason, in answer to {command.name}, which {command.reply} answers"
    refused = payload_violation(command, payload) if payload is not None else None
    if refused is not None and not (name == "Result" and result != Reason.OK):
        how = "taken" if result in (None, Reason.OK) else "passed to its handler"    # its own refusal, not the codec's
        return (f"{command.name} {how} (answered {name} {_said(result)}, not a Result refusing it) though the "
                f"declaration refuses it: {refused}")
    return None


def nak_violation(nak: Message) -> Optional[str]:
    """None if a Nak names why it refused (a reason other than OK, of the declared reasons)."""
    return declared_violation(nak.spec, nak) or (None if nak.reason != Reason.OK else "a Nak with no reason (OK)")


SAFE_STATES = (ControllerState.FAULT, ControllerState.ESTOP)


def state_violation(state: int, faults: int) -> Optional[str]:
    """None if the controller's state and faults are a pair the protocol allows: a fault bit is latched on entry to
    a safe state (FAULT or ESTOP) and cleared only by the Reset that leaves it (docs/protocol.md, "Fault bits"), so
    outside the safe states no fault is latched, and ESTOP is entered with the ESTOP bit."""
    name = ControllerState(state).name if state in ControllerState._value2member_map_ else str(state)
    if state not in SAFE_STATES and faults:
        return (f"state {name} with faults {faults:#x} latched: a fault is latched only in a safe state (FAULT, "
                f"ESTOP) and cleared only by the Reset that leaves it")
    if state == ControllerState.ESTOP and not faults & Fault.ESTOP:
        return f"state ESTOP without the ESTOP fault bit (faults {faults:#x})"
    return None


def param_refusal_changed(name: str, refused: Message, before: Mapping[str, float]) -> Optional[str]:
    """A ParamSet of `name` was refused: its reply (a ParamValue carrying the value in force) must say the value
    `before` held; None if it does (or the parameter was not known before)."""
    if name not in before or refused.spec.name != "ParamValue" or refused.name != name:
        return None
    was = before[name]
    if refused.value == was or (math.isnan(refused.value) and math.isnan(was)):
        return None
    return (f"ParamSet {name} refused ({_said(refused.result)}) yet its value moved from {was:g} to "
            f"{refused.value:g}: a refused command changed the controller")


def case_violation(handles, before: Mapping[str, float]) -> Optional[str]:
    """A black-box case's commands, each (spec, payload, handle) in the order sent, judged: each reply by
    `reply_violation` (a reply that did not decode at all included), and each ParamSet refused by
    `param_refusal_changed` against what the parameters held (`before`: the parameters nothing else of the case
    may have changed, as the target listed them; an accepted ParamSet of the case moves its own)."""
    held = dict(before)
    for spec, payload, handle in handles:
        if not handle.done:
            if spec.name == "ParamSet":
                held.pop(_param_name(payload), None)      # it may yet run
            continue
        if handle.reply is None:
            if handle.detail.startswith("unreadable reply"):     # (protocol/host_link.py: it did not decode)
                return f"the reply to {spec.name} breaks the declaration: {handle.detail}"
            continue
        problem = reply_violation(spec, payload, handle.reply)
        if problem is not None:
            return problem
        if spec.name == "ParamSet" and handle.reply.spec.name == "ParamValue":
            name = _param_name(payload)
            if handle.ok:
                held[handle.reply.name] = handle.reply.value
            elif name is not None:
                problem = param_refusal_changed(name, handle.reply, held)
                if problem is not None:
                    return problem
    return None


def _param_name(payload: bytes) -> Optional[str]:
    """The name a ParamSet payload carries, if the declaration allows the payload (else it names nothing)."""
    spec = SCHEMA["ParamSet"]
    if payload_violation(spec, payload) is not None:
        return None
    return payload[:spec.fields[0].text_size].rstrip(b"\x00").decode("ascii")


def _said(result: Optional[int]) -> str:
    if result is None:
        return "(no result field)"
    return Reason(result).name if result in Reason._value2member_map_ else str(result)
