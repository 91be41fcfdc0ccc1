"""The plant's true state at the end of a bench: what no controller reading shows (`aspod bench`, the plugin)."""
from __future__ import annotations

import math

from protocol.states import ARM_AXES, Axis

from host_tools.worlds.world import LockstepBench


def plant_state(bench: LockstepBench) -> dict:
    """The plant's true state (what no controller reading shows): joints, gripper, tracker and its sun."""
    plant = bench.world.plant
    arm = plant.arm
    angles = {axis.name.lower(): math.degrees(x) for axis, x in zip(ARM_AXES, arm.pos_rad) if axis is not Axis.GRIPPER}
    state = {"joints_deg": angles, "gripper_opening_mm": arm.gripper_opening_m * 1e3, "grip_force_n": arm.grip_force_n}
    tracker = plant.tracker if bench.plant_settings.tracker else None     # a plant without one still carries its model
    if tracker is not None:
        el, az, _dni, _dhi = tracker.sun()
        state["tracker"] = {"az_deg": tracker.angle_deg[0], "el_deg": tracker.angle_deg[1], "sun_az_deg": az,
                            "sun_el_deg": el, "off_sun_deg": tracker.angular_error_deg(),
                            "relay_closings": list(tracker.relay_closures),
                            "high_duty_starts": tracker.high_duty_starts}
    return state
