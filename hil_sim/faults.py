"""The plant's injectable faults: one table, by name.

`Plant.inject(name, channel=None)` and `Plant.clear(name, channel=None)` take a name from
`FAULT_TABLE`; a per-channel fault also takes a channel, as a name from
`hil_sim.arm_params.ARM_CHANNELS` ("j1" ... "mount") or its index (0-5). `Plant.faults` lists
the active ones as strings: "supply_sag", "jam:j2". Such a string is also accepted as the
name (`plant.clear("jam:j2")`), so `for f in plant.faults: plant.clear(f)` clears them all.

Rules common to all faults:

* Bad input (an unknown name, a channel where none is taken or none where one is needed,
  an unknown channel) raises `ValueError` naming the valid choices and changes nothing.
* Injecting a fault that is already active changes nothing (a glitch does not jump
  twice); clearing one that is not active changes nothing.
* Faults act inside the plant, below the bus: the frames stay well formed, what they
  carry is what the faulty hardware would report. No fault latches: clearing one
  restores normal behaviour from that moment on (see each entry for what that means).

This module holds the declaration and the name checks only; `hil_sim.plant.Plant`
implements the effects.
"""
from __future__ import annotations

from dataclasses import dataclass
from numbers import Integral
from typing import Optional, Union

from protocol.states import ARM_CHANNELS

Channel = Union[str, int]


@dataclass(frozen=True)
class FaultSpec:
    """One fault: its name, whether it takes a channel, what it does, what a controller should see."""

    name: str
    per_channel: bool
    effect: str
    controller_sees: str


FAULT_TABLE: tuple[FaultSpec, ...] = (
    FaultSpec(
        "supply_sag", False,
        "The supply's EMF drops from PlantParams.supply_nominal_v to supply_sag_v (a failing "
        "supply or a flat battery); the source resistance still applies, so the bus sags further "
        "under load. Cleared: back to the nominal EMF at once.",
        "ANALOG_IN supply_v falls about 10 V (to about 18 V at idle); motors at a given duty run "
        "slower. Low-supply limit -> safe state."),
    FaultSpec(
        "over_temperature", False,
        "Ambient around the control box rises to PlantParams.over_temperature_ambient_c (60 C, "
        "the box left in the sun). The box follows with its thermal time constant (300 s by "
        "default). Cleared: ambient returns to ambient_c; the box cools with the same lag.",
        "ANALOG_IN controller_temp_c climbs and passes 45 C within about 240 s from 22 C. "
        "Over-temperature limit -> safe state."),
    FaultSpec(
        "encoder_dropout", True,
        "The channel's encoder signal is lost: its count freezes at the value it had at the "
        "moment of injection while the shaft, motor and current carry on. Cleared: counting "
        "resumes from the true position, so the count jumps by however far the shaft moved "
        "meanwhile.",
        "MOTOR_FB count_<ch> constant while current_<ch> follows the command (and the switches "
        "in DIGITAL_IN may still change): no motion seen under drive -> stall / encoder fault."),
    FaultSpec(
        "encoder_glitch", True,
        "The channel's count jumps once by PlantParams.encoder_glitch_counts (+20000 counts, "
        "e.g. noise on the A/B lines) at injection, then counts normally from there: the "
        "count's zero has moved. Cleared: the offset is removed, so the count jumps back by "
        "the same amount.",
        "MOTOR_FB count_<ch> steps by +20000 between two ticks, an impossible speed (J1: "
        "11 deg in 1 ms) -> encoder fault; positions are wrong until re-homed."),
    FaultSpec(
        "open_circuit", True,
        "The channel's armature circuit is open (a broken wire, a failed bridge): no current, "
        "no torque, no back-EMF braking, whatever the duty. The brake still works as "
        "commanded; with it released the joint coasts or falls under its loads (gravity on "
        "J1-J3). Cleared: the bridge drives again.",
        "MOTOR_FB current_<ch> exactly 0 while driven; the count does not follow the command "
        "(a joint under gravity drifts down if its brake is released) -> drive fault."),
    FaultSpec(
        "jam", True,
        "The joint is blocked at its present angle: both hard stops of the channel close "
        "around it (DcMotorBank.set_stops). Cleared: the stops it found are restored (on the "
        "gripper, do not call ArmPlant.set_object while it is jammed: that moves the same stops).",
        "MOTOR_FB count_<ch> still whatever the duty while current_<ch> rises to the stall "
        "current (duty * supply / R) -> stall / over-current."),
    FaultSpec(
        "stuck_brake", True,
        "The channel's brake stays applied whatever CTRL_OUTPUTS and MOTOR_CMD command (a "
        "welded brake relay, a seized armature). The brake holds 1.5 x the channel's rated "
        "torque (arm_params.BRAKE_HOLD_FACTOR), so a high duty can still drag it round slowly. "
        "The gripper has no brake: on it this fault has no effect. Cleared: the brake follows "
        "the command again.",
        "MOTOR_FB count_<ch> still (or creeping at high duty) with a high current_<ch> -> "
        "stall."),
    FaultSpec(
        "clouds", False,
        "A cloud bank covers the sun over the solar tracker: the direct beam drops by "
        "TrackerParams.overcast_attenuation (95 %) on top of any scheduled cloud passages "
        "(Plant(clouds=...)); the diffuse light stays. Nothing else changes. Cleared: the beam "
        "returns at once. (Timed passages: the clouds spec, hil_sim.sun.parse_clouds.)",
        "TRACKER_SENSE: both cells of each pair drop to their diffuse level (about 0.03 V at noon), "
        "their difference to noise: no direction to follow -> the tracker should hold (brakes on) "
        "rather than hunt, and resume when the beam returns."),
)

FAULTS_BY_NAME: dict[str, FaultSpec] = {f.name: f for f in FAULT_TABLE}
FAULT_NAMES: tuple[str, ...] = tuple(f.name for f in FAULT_TABLE)
PLANT_FAULTS: tuple[str, ...] = tuple(f.name for f in FAULT_TABLE if not f.per_channel)
CHANNEL_FAULTS: tuple[str, ...] = tuple(f.name for f in FAULT_TABLE if f.per_channel)


def channel_index(channel: Channel) -> int:
    """Index in `ARM_CHANNELS` of a channel given by name or index; ValueError if there is none."""
    if isinstance(channel, str):
        if channel in ARM_CHANNELS:
            return ARM_CHANNELS.index(channel)
    elif isinstance(channel, Integral) and not isinstance(channel, bool):
        if 0 <= channel < len(ARM_CHANNELS):
            return int(channel)
    raise ValueError(f"unknown channel {channel!r}; channels: {', '.join(ARM_CHANNELS)} "
                     f"(or an index 0-{len(ARM_CHANNELS) - 1})")


def resolve(name: str, channel: Optional[Channel] = None) -> tuple[FaultSpec, Optional[int]]:
    """Check a fault name and channel; return (spec, channel index or None). ValueError if bad.

    `name` may carry its channel, as `Plant.faults` lists it ("jam:j2"); then `channel`
    must be None.
    """
    if isinstance(name, str) and ":" in name:
        if channel is not None:
            raise ValueError(f"fault {name!r} already names its channel; do not pass channel={channel!r}")
        name, channel = name.split(":", 1)
    spec = FAULTS_BY_NAME.get(name) if isinstance(name, str) else None
    if spec is None:
        raise ValueError(f"unknown fault {name!r}; known faults: {', '.join(FAULT_NAMES)} "
                         f"({', '.join(CHANNEL_FAULTS)} per channel)")
    if not spec.per_channel:
        if channel is not None:
            raise ValueError(f"fault {name!r} acts on the whole plant and takes no channel, got {channel!r}")
        return spec, None
    if channel is None:
        raise ValueError(f"fault {name!r} needs a channel: one of {', '.join(ARM_CHANNELS)} "
                         f"(or an index 0-{len(ARM_CHANNELS) - 1})")
    return spec, channel_index(channel)


def fault_key(spec: FaultSpec, index: Optional[int]) -> str:
    """The string `Plant.faults` lists: "supply_sag", "jam:j2"."""
    return spec.name if index is None else f"{spec.name}:{ARM_CHANNELS[index]}"


def describe() -> str:
    """The table as text (for a CLI's help, a log, a test report)."""
    lines = []
    for f in FAULT_TABLE:
        lines.append(f"{f.name}{' <channel>' if f.per_channel else ''}\n"
                     f"    effect: {f.effect}\n    controller sees: {f.controller_sees}")
    return "\n".join(lines)


__all__ = ["CHANNEL_FAULTS", "FAULTS_BY_NAME", "FAULT_NAMES", "FAULT_TABLE", "FaultSpec", "PLANT_FAULTS",
           "channel_index", "describe", "fault_key", "resolve"]
