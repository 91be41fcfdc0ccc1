"""Teleop's `sim` words: the simulated plant's hand, outside the controller's link.

    sim fault jam j2        sim clear jam j2        sim clear all       sim faults
    sim gravity orbit       sim payload 1.5         sim object 0.02     sim object none
    sim clouds on|off       sim pause               sim resume          sim step 0.5
    sim state               sim time

Each line is a request of the control endpoint (host_tools/worlds/plant_control.py), whose
declaration (`OPS`) gives these words, their arguments, help and completion: `sim OP ARGS...`,
the arguments in declared order. A line is checked whole (names, channels, ranges) before a
script sends anything. It runs against a live `aspod sim`'s endpoint (`aspod teleop --control
PATH`, or found from the link's URL) or, in `aspod bench`, on the lock-step world's plant
directly: the same requests, the same replies. A real controller has no plant to reach: there a
`sim` line fails, saying so.
"""
from __future__ import annotations

import difflib
from typing import Optional

from protocol.errors import shown
from protocol.states import ARM_CHANNELS

from host_tools.client.control import ControlUnavailable
from host_tools.worlds.plant_control import OPS, Arg, Op, RequestError, check_request
from hil_sim.faults import FAULT_NAMES

WORD = "sim"
SWITCH_WORDS = {"on": True, "off": False, "true": True, "false": False, "yes": True, "no": False, "1": True, "0": False}
NULL_WORD = "none"
NO_ENDPOINT = ("no control endpoint: {where} is not a simulator whose plant can be reached from here (a real "
               "controller has no plant to fault). `aspod sim` serves one unless --no-control (its ASPOD-CONTROL "
               "line); give it to `aspod teleop --control PATH` if it is not found from the link's URL")


class SimWordError(ValueError):
    """A `sim` line that is not a request."""


def arg_usage(arg: Arg) -> str:
    if arg.kind == "choice":
        text = "|".join(arg.choices)
    elif arg.kind == "switch":
        text = "on|off"
    else:
        text = arg.key.upper() + (f"|{NULL_WORD}" if arg.nullable else "")
    return text if arg.required else f"[{text}]"


def usage(op: Op) -> str:
    return " ".join([WORD, op.name, *(arg_usage(a) for a in op.args)])


def summary() -> str:
    """The one line `help` lists for `sim`."""
    return (f"{WORD} OP ...: the simulated plant, outside the controller's link (a live aspod sim's control endpoint, "
            f"or the lock-step world): {', '.join(OPS)}; `help {WORD}` for each")


def help_lines() -> list[tuple[str, str]]:
    """(usage, what it does) for each op."""
    rows = []
    for op in OPS.values():
        args = "; ".join(f"{a.key}: {a.doc}" for a in op.args)
        rows.append((usage(op), f"{op.doc}{' (' + args + ')' if args else ''}"))
    return rows


HELP_NOTE = ("Against a live `aspod sim` (its control endpoint: `aspod teleop URL --control PATH`, or found from URL) "
             "or in `aspod bench` (the lock-step world's plant). A real controller has no plant to reach from here. "
             "Each change is said on the simulator's stderr. While held (`sim pause`) the plant and the controller's "
             "loops stand still and telemetry stops; the link stays up.")


def parse(args: list[str]) -> dict:
    """The request a `sim` line's words ask for, checked as the endpoint checks it; SimWordError else."""
    if not args:
        raise SimWordError(f"{WORD} OP ...: one of {', '.join(OPS)} (`help {WORD}`)")
    name = args[0].lower()
    op = OPS.get(name)
    if op is None:
        close = difflib.get_close_matches(name, list(OPS), n=2) if len(name) <= 20 else []
        hint = f" (did you mean {' or '.join(f'`{WORD} {c}`' for c in close)}?)" if close else ""
        raise SimWordError(f"{WORD}: no op {shown(args[0])}{hint}; ops: {', '.join(OPS)}")
    words = args[1:]
    if len(words) > len(op.args) or len(words) < sum(a.required for a in op.args):
        raise SimWordError(f"{usage(op)}: {op.doc}")
    request = {"op": op.name}
    for arg, word in zip(op.args, words):
        request[arg.key] = _value(op, arg, word)
    try:
        check_request(request)
    except RequestError as exc:
        raise SimWordError(f"{WORD} {exc}") from None
    return request


def _value(op: Op, arg: Arg, word: str):
    text = word.lower()
    if arg.kind == "switch":
        if text not in SWITCH_WORDS:
            raise SimWordError(f"{usage(op)}: {shown(word)} is not on or off")
        return SWITCH_WORDS[text]
    if arg.kind == "number":
        if arg.nullable and text == NULL_WORD:
            return None
        try:
            return float(text)
        except ValueError:
            raise SimWordError(f"{usage(op)}: {shown(word)} is not a number ({arg.doc})") from None
    if arg.kind == "channel" and text.isdigit() and len(text) < 3:
        return int(text)
    return text


def completions(position: int, before: list[str]) -> list[str]:
    """The words that may come at `position` after `sim` (`before`: the words after `sim` so far)."""
    if position == 0:
        return list(OPS)
    op = OPS.get(before[0].lower()) if before else None
    if op is None or position > len(op.args):
        return []
    arg = op.args[position - 1]
    if arg.kind == "fault":
        return list(FAULT_NAMES) + (["all"] if op.name == "clear" else [])
    if arg.kind == "channel":
        return list(ARM_CHANNELS)
    if arg.kind == "choice":
        return list(arg.choices)
    if arg.kind == "switch":
        return ["on", "off"]
    return [NULL_WORD] if arg.nullable else []


def run(control, request: dict, where: str) -> tuple[bool, list[str]]:
    """Send `request` to `control` (None: there is none, at `where`); (ok, the lines to print)."""
    head = f"{WORD} {request['op']}"
    if control is None:
        return False, [f"FAIL {head}: {NO_ENDPOINT.format(where=where)}"]
    try:
        reply = control.request(request)
    except ControlUnavailable as exc:
        return False, [f"FAIL {head}: {exc}"]
    if not reply.get("ok"):
        return False, [f"FAIL {head}: {reply.get('error')}"]
    lines = [f"ok   {head}: {reply.get('said')}"]
    if "state" in reply:
        lines += ["     " + line for line in state_lines(reply["state"])]
    return True, lines


def state_lines(state: dict) -> list[str]:
    """The plant's true state (host_tools/worlds/plant_state.py) in words."""
    joints = ", ".join(f"{name} {x:.3f}" for name, x in state["joints_deg"].items())
    width = state.get("object_width_m")
    lines = [f"joints {joints} deg; gripper {state['gripper_opening_mm']:.1f} mm open, grip {state['grip_force_n']:.1f} N",
             f"gravity {state['gravity']}, payload {state['payload_kg']:g} kg, object "
             f"{'none' if width is None else f'{width * 1e3:g} mm'}; faults: {', '.join(state['faults']) or 'none'}"]
    tracker: Optional[dict] = state.get("tracker")
    if tracker is not None:
        lines.append(f"tracker az {tracker['az_deg']:.3f} el {tracker['el_deg']:.3f} deg, sun az "
                     f"{tracker['sun_az_deg']:.3f} el {tracker['sun_el_deg']:.3f} deg, off the sun by "
                     f"{tracker['off_sun_deg']:.3f} deg; relay closings az {tracker['relay_closings'][0]} el "
                     f"{tracker['relay_closings'][1]}")
    return lines
