"""A fault drill: a plant fault injected while a joint moves, and the controller must take it where its docs say,
in the time they give (docs/arm.md: a joint that does not move under drive is a stall within the stall time).
On a target that cannot take faults (real hardware) these are skipped, saying so. Run: `pytest benches/`."""
from __future__ import annotations

import pytest

from protocol.messages import MESSAGES as M
from protocol.states import Axis, MotionOutcome

DRILLS = [("encoder_dropout", "j1", Axis.J1), ("open_circuit", "j2", Axis.J2), ("jam", "j3", Axis.J3)]
FAULT_WITHIN_S = 2.0      # the controller's stall detection, with margin (docs/arm.md)


def ends(target, axis):
    return [e for e in target.events if e.spec.name == "MotionDone" and e.axis == int(axis)]


@pytest.mark.parametrize("fault, channel, axis", DRILLS, ids=[d[0] for d in DRILLS])
def test_a_fault_under_motion_stops_the_joint_as_a_fault_in_time(aspod_target, fault, channel, axis):
    assert aspod_target.call(M["Enable"]()).ok
    assert aspod_target.call(M["Jog"](int(axis), 2.0)).ok
    aspod_target.wait_until(lambda: False, 0.5)                 # moving
    injected = aspod_target.now()
    aspod_target.inject(fault, channel)
    assert aspod_target.wait_until(lambda: ends(aspod_target, axis), 10.0), "the joint never stopped"
    took = aspod_target.now() - injected
    aspod_target.measure("reaction_s", round(took, 3), "s")
    assert ends(aspod_target, axis)[0].outcome == MotionOutcome.FAULT
    assert took <= FAULT_WITHIN_S
