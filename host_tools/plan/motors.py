"""The motors behind a plan's joints: what the electrical-energy and heat objectives need (energy.py).

A joint's torque u comes from a DC motor through gearing of ratio N and efficiency eta: the motor's current is
i = u / (k_t N eta), so its copper loss is R i^2 = c u^2 with c = R / (k_t N eta)^2 (watts per (N m)^2 at the
joint), and the power it draws is u q' + c u^2 (the gearing's own loss folded into c's eta, an approximation
that holds while the motor drives; the losses while it is driven back are taken the same). Besides, the drives
draw `drive_w` while their outputs are enabled, whatever the motors do: what makes a crawl cost energy where
nothing else would (no gravity to hold against, no friction in the planner's model).

The report gives no motor for either of its example's arms (docs/second_arm_sources.md 1.3): a problem that names
none is planned with ASPOD's own arm's shoulder and elbow drives, J1 for each shoulder and J2 for each elbow, as
the plant models them (hil_sim/arm_params.py: the report's 400 oz-in PM DC gear-head motor class and its 16:1 and
6:1 sprocket trains; the motor's resistance and torque constant are the emulator's ASSUMED values), each arm's
drives drawing what the plant's do while enabled (hil_sim/plant.py: 0.75 A at 28 V, 21 W), and says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from host_tools.plan.errors import PlanError


@dataclass(frozen=True)
class Motors:
    """Per joint: winding resistance (ohm), torque constant (N m/A at the motor), gear ratio (motor turns per joint
    turn) and the gearing's efficiency."""

    resistance_ohm: tuple[float, ...]
    torque_constant: tuple[float, ...]
    ratio: tuple[float, ...]
    efficiency: tuple[float, ...]
    drive_w: float = 0.0            # the drives' own draw while enabled (W, all joints together)
    source: str = "the problem file"

    def __post_init__(self) -> None:
        values = (self.resistance_ohm, self.torque_constant, self.ratio, self.efficiency)
        if len({len(v) for v in values}) != 1:
            raise PlanError("motors", "resistance_ohm, torque_constant, ratio and efficiency need one value per joint")
        if not all(math.isfinite(x) and x > 0 for v in values for x in v) or any(e > 1 for e in self.efficiency):
            raise PlanError("motors", "each motor's resistance, torque constant and ratio must be above 0, its "
                                      "efficiency above 0 and at most 1")
        if not (math.isfinite(self.drive_w) and self.drive_w >= 0):
            raise PlanError("motors", "the drives' power must be a finite number of watts, at least 0")

    def copper(self) -> np.ndarray:
        """c per joint: the copper loss R i^2 is c u^2 for a torque u at the joint (W / (N m)^2)."""
        r, kt, n, eta = (np.asarray(v, float) for v in (self.resistance_ohm, self.torque_constant, self.ratio,
                                                          self.efficiency))
        return r / (kt * n * eta) ** 2

    def describe(self) -> dict:
        return {"resistance_ohm": list(self.resistance_ohm), "torque_constant": list(self.torque_constant),
                "ratio": list(self.ratio), "efficiency": list(self.efficiency), "drive_w": self.drive_w,
                "source": self.source,
                "copper_w_per_nm2": [round(float(c), 9) for c in self.copper()]}


def aspod_drives() -> Motors:
    """ASPOD's J1 drive at each arm's shoulder and its J2 drive at each elbow, as the plant models them."""
    from hil_sim import arm_params as p
    from hil_sim.plant import PlantParams
    drives = []
    for motor, stages in ((p.MOTOR_400_OZ_IN, p.J1_SPROCKETS), (p.MOTOR_400_OZ_IN, p.J2_SPROCKETS)):
        chain = (motor.gearhead, *stages)
        drives.append((motor.r_ohm, motor.kt_nm_a, math.prod(s.ratio for s in chain),
                       math.prod(s.efficiency for s in chain)))
    shoulder, elbow = drives
    joints = (shoulder, elbow, shoulder, elbow)
    plant = PlantParams()
    arm_w = plant.enabled_current_a * plant.supply_nominal_v
    return Motors(*(tuple(j[k] for j in joints) for k in range(4)), drive_w=2 * arm_w,
                  source=f"ASPOD's J1 drive at each shoulder, its J2 drive at each elbow, each arm's drives "
                         f"{arm_w:g} W while enabled (hil_sim; the report gives none for its example's arms)")
