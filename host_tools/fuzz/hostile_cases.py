"""The hostile controller's cases (host_tools/fuzz/hostile.py): each step kind, what it draws from the grammar, and
the check of a finding's steps before they are replayed.

A case is 1-6 steps from a seeded generator (the same seed, the same cases), each wrong in one thing: a reply
changed (`REPLY_HOWS`), an event or telemetry frame from the grammar, a frame with one thing wrong (`WRONGS`), a
NAK, a hello in mid-session, raw bytes, a flood, a stall. A step is a JSON object, as a finding keeps it.
"""
from __future__ import annotations

from typing import Callable, Optional

from protocol.framing import MAX_ENCODED, MAX_PAYLOAD
from protocol.messages import SCHEMA
from protocol.schema import MsgClass

from host_tools.fuzz.blackbox import _hex, _number, _one_of, _whole
from host_tools.fuzz.grammar import TO_HOST, RandomDraw, draw_payload, draw_valid, pack_raw
from host_tools.fuzz.link_targets import MACS

REPLIES = tuple(SCHEMA[name] for name in dict.fromkeys(s.reply for s in SCHEMA.by_id.values() if s.reply))
EVENTS = tuple(s for s in TO_HOST if s.cls == MsgClass.EVENT)
TELEMETRY = tuple(s for s in TO_HOST if s.cls == MsgClass.TELEMETRY)
HELLOS = (SCHEMA["HelloReply"], SCHEMA["HelloCookie"])
FLOODS = TELEMETRY + (SCHEMA["Heartbeat"], SCHEMA["Nak"])
STEP_KINDS = ("reply",) * 6 + ("event",) * 3 + ("telemetry",) * 2 + ("frame",) * 3 + ("nak", "hello", "raw", "flood")
REPLY_HOWS = ("fields", "fields", "fields", "other", "refusal", "class", "seq", "drop", "late", "twice", "nak")
WRONGS = ("mac", "mac", "version", "flags", "length", "msg_id", "cls", "seq")
STALL_ONE_IN = 100             # a stall in one step of this many
STALL_MIN_S, STALL_MAX_S = 0.3, 2.5
LATE_MAX_S = 2.0               # a late reply's delay, at most
MAX_STEPS = 6                  # a case's steps, at most
DELAY_MAX_MS = 19              # the pause before a step, at most (0 three times in four)
FLOOD_MIN, FLOOD_MAX = 10, 200
RAW_MAX = MAX_ENCODED + 8
SAVED_STEPS = 600              # a finding keeps at most this many steps (the host's session's last)


def draw_case(draw: RandomDraw, case: int) -> list[dict]:
    steps = []
    for _ in range(1 + draw.pick(MAX_STEPS)):
        kind = "stall" if draw.pick(STALL_ONE_IN) == 0 else STEP_KINDS[draw.pick(len(STEP_KINDS))]
        step: dict = {"case": case, "kind": kind,
                      "delay_s": 0.0 if draw.pick(4) else draw.pick(DELAY_MAX_MS + 1) / 1000.0}
        if kind == "reply":
            how = REPLY_HOWS[draw.pick(len(REPLY_HOWS))]
            step["how"] = how
            if how == "fields":           # the payload is drawn for the reply it meets, from this seed
                step["fields"] = draw.int_in(0, (1 << 32) - 1)
            elif how == "other":
                spec = REPLIES[draw.pick(len(REPLIES))]
                step.update(msg=spec.name, payload=draw_payload(spec, draw)[:MAX_PAYLOAD].hex())
            elif how == "refusal":
                result = SCHEMA["Result"]
                step.update(payload=pack_raw(result, [draw.int_in(0, 255) if draw.pick(4) == 0 else
                                                      draw_valid(result.fields[0], draw)]).hex())
            elif how == "class":
                step["cls"] = draw.int_in(0, 255) if draw.pick(2) else int((MsgClass.COMMAND, MsgClass.URGENT,
                                                                             MsgClass.EVENT, MsgClass.TELEMETRY,
                                                                             MsgClass.LINK)[draw.pick(5)])
            elif how == "seq":
                step.update(seq=("duplicate", "gap", "any")[draw.pick(3)], offset=draw.pick(4),
                            any_seq=draw.int_in(0, 0xFFFF))
            elif how == "late":
                step["late_s"] = draw.int_in(1, int(LATE_MAX_S * 100)) / 100.0
            elif how == "nak":
                nak = SCHEMA["Nak"]
                step.update(reason=int(draw_valid(nak.fields[0], draw)) if draw.pick(4) else draw.int_in(0, 255),
                            expected=draw.int_in(0, 0xFFFF))
        elif kind in ("event", "telemetry"):
            spec = (EVENTS if kind == "event" else TELEMETRY)[draw.pick(len(EVENTS if kind == "event" else TELEMETRY))]
            step.update(msg=spec.name, payload=draw_payload(spec, draw)[:MAX_PAYLOAD].hex())
        elif kind == "frame":
            spec = TO_HOST[draw.pick(len(TO_HOST))]
            step.update(msg=spec.name, payload=draw_payload(spec, draw)[:MAX_PAYLOAD].hex(),
                        wrong=WRONGS[draw.pick(len(WRONGS))], mac=MACS[4 + draw.pick(len(MACS) - 4)],
                        value=draw.int_in(0, 255), length_delta=draw.int_in(1, 4) * (1 if draw.pick(2) else -1),
                        msg_id=draw.int_in(0, 0xFFFF), seq=draw.int_in(0, 0xFFFF))
        elif kind == "nak":
            nak = SCHEMA["Nak"]
            step.update(payload=draw_payload(nak, draw).hex(), names_command=bool(draw.pick(2)))
        elif kind == "hello":
            spec = HELLOS[draw.pick(len(HELLOS))]
            step.update(msg=spec.name, payload=draw_payload(spec, draw)[:MAX_PAYLOAD].hex(),
                        same_nonce=bool(draw.pick(2)))
        elif kind == "raw":
            step["bytes"] = draw.raw(RAW_MAX).hex()
        elif kind == "flood":
            spec = FLOODS[draw.pick(len(FLOODS))]
            step.update(msg=spec.name, count=draw.int_in(FLOOD_MIN, FLOOD_MAX),
                        payload=draw_payload(spec, draw)[:MAX_PAYLOAD].hex())
        elif kind == "stall":
            step["seconds"] = draw.int_in(int(STALL_MIN_S * 10), int(STALL_MAX_S * 10)) / 10.0
        steps.append(step)
    return steps


# ---- a finding's steps, checked before any host starts ---------------------------------------------------------

def _flag(v: object) -> Optional[str]:
    return None if isinstance(v, bool) else "true or false"


_NAMES = lambda specs: _one_of(s.name for s in specs)      # noqa: E731
_FIELDS: dict[str, dict[str, Callable[[object], Optional[str]]]] = {
    "reply": {"how": _one_of(REPLY_HOWS)},
    "event": {"msg": _NAMES(EVENTS), "payload": _hex(MAX_PAYLOAD)},
    "telemetry": {"msg": _NAMES(TELEMETRY), "payload": _hex(MAX_PAYLOAD)},
    "frame": {"msg": _NAMES(TO_HOST), "payload": _hex(MAX_PAYLOAD), "wrong": _one_of(WRONGS), "mac": _one_of(MACS),
              "value": _whole(0, 255), "length_delta": _whole(-4, 4), "msg_id": _whole(0, 0xFFFF),
              "seq": _whole(0, 0xFFFF)},
    "nak": {"payload": _hex(MAX_PAYLOAD), "names_command": _flag},
    "hello": {"msg": _NAMES(HELLOS), "payload": _hex(MAX_PAYLOAD), "same_nonce": _flag},
    "raw": {"bytes": _hex(RAW_MAX)},
    "flood": {"msg": _NAMES(FLOODS), "count": _whole(FLOOD_MIN, FLOOD_MAX), "payload": _hex(MAX_PAYLOAD)},
    "stall": {"seconds": _number(STALL_MIN_S, STALL_MAX_S)},
}
_REPLY_FIELDS: dict[str, dict[str, Callable[[object], Optional[str]]]] = {     # by "how"
    "fields": {"fields": _whole(0, (1 << 32) - 1)},
    "other": {"msg": _NAMES(REPLIES), "payload": _hex(MAX_PAYLOAD)},
    "refusal": {"payload": _hex(MAX_PAYLOAD)},
    "class": {"cls": _whole(0, 255)},
    "seq": {"seq": _one_of(("duplicate", "gap", "any")), "offset": _whole(0, 3), "any_seq": _whole(0, 0xFFFF)},
    "late": {"late_s": _number(0.01, LATE_MAX_S)},
    "nak": {"reason": _whole(0, 255), "expected": _whole(0, 0xFFFF)},
}
_OPTIONAL = {"wire": _hex(MAX_ENCODED + 2), "payload": _hex(MAX_PAYLOAD)}
_COMMON = {"case": _whole(0, (1 << 63) - 1), "kind": _one_of(_FIELDS), "delay_s": _number(0, DELAY_MAX_MS / 1000)}


def check_steps(steps: object) -> None:
    """`steps` as this fuzzer writes them: 1..SAVED_STEPS objects, each with its kind's fields, each of its type and
    within the bounds the fuzzer draws it from; ValueError naming the step, the field and what it must be (so that
    a replay neither crashes, nor stalls for ever, nor floods without end)."""
    if not isinstance(steps, list) or not 1 <= len(steps) <= SAVED_STEPS:
        raise ValueError(f"\"steps\" must be a list of 1..{SAVED_STEPS} steps")
    for index, step in enumerate(steps):
        if not isinstance(step, dict):
            raise ValueError(f"step {index} must be an object")
        rules = dict(_COMMON)
        kind = step.get("kind")
        rules.update(_FIELDS.get(kind, {}) if isinstance(kind, str) else {})
        if kind == "reply" and isinstance(step.get("how"), str):
            rules.update(_REPLY_FIELDS.get(step["how"], {}))
        for name, rule in rules.items():
            if name not in step:
                raise ValueError(f"step {index} ({kind if kind in _FIELDS else 'a step'}) has no \"{name}\"; it "
                                 f"must be {rule(None)}")
        for name, rule in {**_OPTIONAL, **rules}.items():
            if name in step and (must := rule(step[name])) is not None:
                shown = repr(step[name])
                raise ValueError(f"step {index}, \"{name}\": {shown if len(shown) <= 40 else shown[:37] + '...'}; "
                                 f"it must be {must}")
