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
`example_arm_drives` gives the motors of the plant's example arms instead (a 50:1 gear-head motor at each joint),
which execute the example's plans: the objective's prediction of what they draw (bench/bench_two_arms.py).
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


def plant_drives(params, whose: str, where: str) -> Motors:
    """Each arm's shoulder and elbow as the plant models the J1 and J2 drives of `params` (a hil_sim
    `ArmPlantParams`), at both arms, each arm's drives drawing what the plant's do while enabled; `whose` and `where`
    say whose drives they are and where they come from."""
    from hil_sim.arm_params import J1, J2
    from hil_sim.plant import PlantParams
    drives = []
    for channel in (J1, J2):
        drive = params.channels[channel].drive
        chain = (drive.motor.gearhead, *drive.stages)
        drives.append((drive.motor.r_ohm, drive.motor.kt_nm_a, math.prod(s.ratio for s in chain),
                       math.prod(s.efficiency for s in chain)))
    shoulder, elbow = drives
    joints = (shoulder, elbow, shoulder, elbow)
    plant = PlantParams()
    arm_w = plant.enabled_current_a * plant.supply_nominal_v
    return Motors(*(tuple(j[k] for j in joints) for k in range(4)), drive_w=2 * arm_w,
                  source=f"{whose}, each arm's drives {arm_w:g} W while enabled ({where})")


def aspod_drives() -> Motors:
    """ASPOD's J1 drive at each arm's shoulder and its J2 drive at each elbow, as the plant models them."""
    from hil_sim.arm_params import ARM_PLANT_PARAMS
    return plant_drives(ARM_PLANT_PARAMS, "ASPOD's J1 drive at each shoulder, its J2 drive at each elbow",
                        "hil_sim; the report gives none for its example's arms")


def example_arm_drives() -> Motors:
    """The example arm's shoulder and elbow drives at both arms, as the plant models them (hil_sim/arm_params.py
    `EXAMPLE_ARM_PLANT`: a 50:1 gear-head motor at each joint): the motors of the arms that execute the example's
    plans (bench/bench_two_arms.py), for the objective's prediction of what they draw."""
    from hil_sim.arm_params import EXAMPLE_ARM_PLANT
    return plant_drives(EXAMPLE_ARM_PLANT, "the example arm's J1 drive at each shoulder, its J2 drive at each elbow",
                        "hil_sim EXAMPLE_ARM_PLANT; the report gives none")
