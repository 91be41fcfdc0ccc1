"""What a bench may do to the plant directly, outside the controller's link, by name.

A pick-and-place puts debris between the jaws and a payload in them; a fault drill breaks a wire
at a given moment. Those are changes to the physical world, not commands, so the link's capture
cannot show them. `LockstepBench.act(name, *args)` does one and, when the session is recorded, writes it into the capture (as a world
event: `CaptureWriter.note`) so that `aspod replay` does it again at the same moment. Each
action is also a request of the simulator's control endpoint (`control_request`: the op of
host_tools/worlds/plant_control.py that does it), which is how a bench acts on a live simulator.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from hil_sim.plant import Plant


def _set_object(plant: Plant, width_m) -> None:
    plant.arm.set_object(None if width_m is None else float(width_m))


def _set_payload(plant: Plant, payload_kg) -> None:
    plant.arm.set_payload(float(payload_kg))


def _set_gravity(plant: Plant, mode) -> None:
    plant.arm.set_gravity(str(mode))


def _inject(plant: Plant, fault) -> None:
    plant.inject(str(fault))


def _clear(plant: Plant, fault) -> None:
    plant.clear(str(fault))


@dataclass(frozen=True)
class Action:
    do: Callable[..., None]
    op: str          # the control endpoint's op that does the same ...
    key: str         # ... with its one value under this key


ACTIONS: dict[str, Action] = {
    "set_object": Action(_set_object, "object", "width_m"),   # width of the object between the jaws (m), or None
    "set_payload": Action(_set_payload, "payload", "kg"),     # mass held by the gripper (kg)
    "set_gravity": Action(_set_gravity, "gravity", "mode"),   # earth | orbit (the controller's feed-forward: its
                                                              # parameter gravity_m_s2)
    "inject": Action(_inject, "fault", "name"),               # a fault by name, with its channel: "jam:j2"
    "clear": Action(_clear, "clear", "name"),                 # the same, cleared
}


def _action(name: str) -> Action:
    action = ACTIONS.get(name)
    if action is None:
        raise ValueError(f"no plant action {name!r}; there are {', '.join(sorted(ACTIONS))}")
    return action


def act(plant: Plant, name: str, *args) -> None:
    """Do the named action; ValueError naming it if there is no such action or its values do not fit."""
    action = _action(name)
    try:
        action.do(plant, *args)
    except TypeError as exc:
        raise ValueError(f"plant action {name}: {exc}") from None


def control_request(name: str, *args) -> dict:
    """The control endpoint's request that does the named action with `args`; ValueError as `act`."""
    action = _action(name)
    if len(args) != 1:
        raise ValueError(f"plant action {name}: takes one value, got {len(args)}")
    request = {"op": action.op, action.key: args[0]}
    if action.op in ("fault", "clear") and isinstance(args[0], str) and ":" in args[0]:
        request["name"], request["channel"] = args[0].split(":", 1)      # the endpoint takes them apart
    return request
