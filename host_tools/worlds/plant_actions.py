"""What a bench may do to the plant directly, outside the controller's link, by name.

A pick-and-place puts debris between the jaws and a payload in them; a fault drill breaks a wire
at a given moment. Those are changes to the physical world, not commands, so the link's capture cannot show them. `LockstepBench.act(name,
*args)` does one and, when the session is recorded, writes it into the capture (as a world
event: `CaptureWriter.note`) so that `aspod replay` does it again at the same moment.
"""
from __future__ import annotations

from typing import Callable

from hil_sim.plant import Plant


def _set_object(plant: Plant, width_m) -> None:
    plant.arm.set_object(None if width_m is None else float(width_m))


def _set_payload(plant: Plant, payload_kg) -> None:
    plant.arm.set_payload(float(payload_kg))


def _set_gravity(plant: Plant, mode) -> None:
    plant.arm.set_gravity(str(mode))


ACTIONS: dict[str, Callable[..., None]] = {
    "set_gravity": _set_gravity,    # earth | orbit (the controller's feed-forward is its parameter gravity_m_s2)
    "set_object": _set_object,      # width of the object between the gripper's jaws (m), or None: nothing
    "set_payload": _set_payload,    # mass held by the gripper (kg)
    "inject": Plant.inject,         # a fault by name (hil_sim/faults.py): "jam:j2", or "jam", "j2"
    "clear": Plant.clear,           # the same, cleared
}


def act(plant: Plant, name: str, *args) -> None:
    """Do the named action; ValueError naming it if there is no such action or its values do not fit."""
    action = ACTIONS.get(name)
    if action is None:
        raise ValueError(f"no plant action {name!r}; there are {', '.join(sorted(ACTIONS))}")
    try:
        action(plant, *args)
    except TypeError as exc:
        raise ValueError(f"plant action {name}: {exc}") from None
