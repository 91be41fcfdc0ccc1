"""How the controller answered a plant fault: whether it reached its safe state, how soon, and whether that was
within the time its documentation states (docs/arm.md, "Faults").

Read from the events the host received: the first `StateChanged` into FAULT at or after the fault's
injection. Its `uptime_ms` is the controller's own clock, so the reaction time is the controller's
measure, not the host's (the event's trip over the link adds nothing to it).
"""
from __future__ import annotations

from typing import Iterable, Optional, Sequence

from protocol.schema import Message
from protocol.states import ControllerState, Fault

from host_tools.worlds.bench_world import TimedFault
from host_tools.worlds.world import LockstepBench

# The time to the safe state that docs/arm.md states for each plant fault (its "tested bound"). None: the
# fault has no safe state to reach (clouds: the tracker holds and waits for the sun).
SAFE_STATE_WITHIN_S: dict[str, Optional[float]] = {
    "encoder_glitch": 0.005,
    "encoder_dropout": 2.0,         # "under 2 s at 3 deg/s"; a joint at rest shows no fault to see
    "open_circuit": 0.5,
    "jam": 1.0,
    "stuck_brake": 1.0,
    "supply_sag": 0.05,
    "over_temperature": 300.0,      # the box's thermal lag: about 250 s from 22 C
    "clouds": None,
}


def reaction(events: Iterable[Message], fault: str, at_s: float, started_s: float = 0.0) -> dict:
    """The controller's answer to `fault` ("jam:j2") injected at `at_s` (the world's time; the controller
    started at `started_s`): {"fault", "at_s", "safe_after_s" (None: not reached), "fault_bits" (names),
    "stated_s", "within_stated" (None where nothing is stated)}."""
    name = fault.split(":", 1)[0]
    stated = SAFE_STATE_WITHIN_S.get(name)
    row = {"fault": fault, "at_s": at_s, "safe_after_s": None, "fault_bits": "", "stated_s": stated,
           "within_stated": None if stated is None else False}
    for event in events:
        if event.spec.name != "StateChanged" or event.state != ControllerState.FAULT:
            continue
        when = started_s + event.uptime_ms / 1000.0
        if when + 0.0005 < at_s:        # uptime is whole milliseconds
            continue
        row["safe_after_s"] = round(max(0.0, when - at_s), 3)
        row["fault_bits"] = "|".join(f.name for f in Fault if f and event.faults & f)
        if stated is not None:
            row["within_stated"] = row["safe_after_s"] <= stated
        break
    return row


EVENTS_IN_FLIGHT_S = 0.2     # a bench may end (a demo step raising on the safe state it saw in telemetry) before
                             # the controller's StateChanged event has reached the host: this much more lets it


def reactions(bench: LockstepBench, events: Sequence[Message], faults: Sequence[TimedFault]) -> list[dict]:
    """The controller's answer to each of `faults` injected so far on `bench`, after letting the events on their
    way arrive (the world runs EVENTS_IN_FLIGHT_S further, when a fault was injected)."""
    injected = [f for f in faults if f.at_s <= bench.clock.now()]
    if injected:
        bench.run_for(EVENTS_IN_FLIGHT_S)
    started = bench.controller.started_s or 0.0
    return [reaction(events, f.fault, f.at_s, started) for f in injected]
