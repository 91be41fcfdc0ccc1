"""The plant's true state: what no controller reading shows (`aspod bench`, the plugin, the control endpoint)."""
from __future__ import annotations

import math

from hil_sim.plant import Plant
from protocol.states import ARM_AXES, Axis


def plant_state(plant: Plant, tracker: bool = True) -> dict:
    """Joints, gripper, what the arm carries and under which gravity, the active faults, and (`tracker`: the plant
    has its solar tracker on the bus) the tracker beside its sun, as JSON values."""
    arm = plant.arm
    angles = {axis.name.lower(): math.degrees(x) for axis, x in zip(ARM_AXES, arm.pos_rad) if axis is not Axis.GRIPPER}
    state = {"joints_deg": angles, "gripper_opening_mm": arm.gripper_opening_m * 1e3, "grip_force_n": arm.grip_force_n,
             "gravity": arm.gravity, "payload_kg": arm.payload_kg, "object_width_m": arm.object_width_m,
             "faults": sorted(plant.faults)}
    if tracker:
        t = plant.tracker
        el, az, _dni, _dhi = t.sun()
        state["tracker"] = {"az_deg": t.angle_deg[0], "el_deg": t.angle_deg[1], "sun_az_deg": az,
                            "sun_el_deg": el, "off_sun_deg": t.angular_error_deg(),
                            "relay_closings": list(t.relay_closures), "high_duty_starts": t.high_duty_starts}
    return state
