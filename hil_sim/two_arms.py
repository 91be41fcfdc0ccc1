"""Two arms and the object they hold: two `ArmPlant`s and one `HeldObject`, the closed chain's physics (issue 39).

Design: docs/two_arms.md ("The shared object"). Each arm is today's `ArmPlant`, stepped by its own plant node as
the world steps a plant; the object joins the two hands. This class is the coupling between them, and only that:
the lead's world steps both plants, then calls `step(dt_s)` once a tick.

Frames. The object lives in one vertical plane (x horizontal, z up: `hil_sim.held_object`). Each arm's plane is
that plane, its x along the object's x, its J1 axis at its base (`bases_m`, in the object's frame: the example's
arm 1 at (0, 0), arm 2 at (2.0, 0)), so that both shoulders' angles are measured from +x as the planner's are
(`host_tools.plan.model`). The mount is taken at home: the coupling reads J1-J3 only. A mount turned off home
would carry the hand out of the object's plane, which this model does not see; the example holds both mounts at
home (docs/two_arms.md), and a force in the arm plane puts no torque on the mount's vertical shaft.

Each tick, `step(dt_s)`:

1. reads each hand (the gripper's tip, `ArmGeometry.tip_m` along the gripper from J3: for the example arm the J3
   axis) and its velocity, forward kinematics of J1-J3 from the plant's state after its step;
2. steps the object by `dt_s` with those hands and each jaw's force (`ArmPlant.grip_force_n`: 0 unless the jaws
   are closed on an object, `ArmPlant.set_object`);
3. sets each arm's hand force (`ArmPlant.set_hand_force`) to what its grasp now puts on it, which its joints
   carry as J^T F over the next tick.

So the arms see the object's force one tick late: an explicit lag, as the supply's voltage is (docs/plant.md). It
is stable while the modes the grasp springs give the joints stay slow against the plants' 1 ms step: along the
example's path, 5000 N/m at the hand's distance r from a joint against its inertia I (the plant's diagonal model
with the reflected rotor), omega = sqrt(k r^2 / I) is at most 81 rad/s at a shoulder and 111 rad/s at an elbow,
omega dt 0.08 and 0.11 (tests/test_two_arm_plant.py kicks the free arms and watches them settle).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Sequence

from hil_sim.arm import ArmPlant
from hil_sim.arm_params import J1, J2, J3
from hil_sim.held_object import HeldObject, ObjectParams

# The report's example (section 4): the two bases 2.0 m apart along x, in the object's frame.
EXAMPLE_BASES_M = ((0.0, 0.0), (2.0, 0.0))


class TwoArmPlant:
    """Two `ArmPlant`s holding one `HeldObject` (module docstring). `grasp()` takes the object between the two
    hands; `step(dt_s)` advances it after both plants have stepped. Readings: `object` (its `pose`, `velocity`,
    `squeeze_n`, `states`, `carried_n`, `limits_n`, `hand_forces`, `last_event`, `event_count`), `hands()`.

    The object's gravity is the arms' (both arms must agree); `object_params`' own `gravity_m_s2` is replaced."""

    def __init__(self, arms: Sequence[ArmPlant], bases_m=EXAMPLE_BASES_M,
                 object_params: ObjectParams = ObjectParams()) -> None:
        if len(arms) != 2:
            raise ValueError(f"two arms hold the object, got {len(arms)}")
        if arms[0].g_m_s2 != arms[1].g_m_s2:
            raise ValueError(f"the two arms must be in one gravity, got {arms[0].gravity!r} and {arms[1].gravity!r}")
        (b0x, b0z), (b1x, b1z) = bases_m
        if not all(math.isfinite(v) for v in (b0x, b0z, b1x, b1z)):
            raise ValueError(f"bases_m must be two finite (x, z) pairs in metres, got {bases_m!r}")
        self.arms = (arms[0], arms[1])
        self.bases_m = ((float(b0x), float(b0z)), (float(b1x), float(b1z)))
        self.object = HeldObject(dataclasses.replace(object_params, gravity_m_s2=arms[0].g_m_s2))

    def hands(self) -> tuple[tuple[tuple[float, float], tuple[float, float]],
                             tuple[tuple[float, float], tuple[float, float]]]:
        """Each hand's position (m, the object's frame) and velocity (m/s), from J1-J3 of its plant now."""
        positions, velocities = [], []
        for arm, (bx, bz) in zip(self.arms, self.bases_m):
            q, w = arm.motors.positions(), arm.motors.vel_rad_s
            (ex, ez), (wx, wz), _, (tx, tz), _ = arm.load_model().pose(q[J1], q[J2], q[J3])
            w1, w2, w3 = float(w[J1]), float(w[J2]), float(w[J3])
            w12, w123 = w1 + w2, w1 + w2 + w3
            # d/dt of the tip: each joint turns everything outboard of it (J1 at the origin of the arm's plane)
            vx = -ez * w1 - (wz - ez) * w12 - (tz - wz) * w123
            vz = ex * w1 + (wx - ex) * w12 + (tx - wx) * w123
            positions.append((bx + tx, bz + tz))
            velocities.append((vx, vz))
        return (positions[0], positions[1]), (velocities[0], velocities[1])

    def grasp(self) -> None:
        """Place the object at rest between the two hands (grasp 0 at arm 1's) and hold it with both
        (`HeldObject.grasp`: refused, GraspRefused, unless the hands are the grasps' distance apart); each arm
        carries its grasp's force from now on."""
        self.object.grasp(self.hands()[0])
        self._set_hand_forces()

    def step(self, dt_s: float) -> None:
        """Advance the object `dt_s` seconds against the hands where both plants' last step left them, and set
        the force each hand carries over the plants' next step. Bad input: ValueError, nothing changed."""
        hands, velocities = self.hands()
        self.object.step(dt_s, hands, velocities, (self.arms[0].grip_force_n, self.arms[1].grip_force_n))
        self._set_hand_forces()

    def _set_hand_forces(self) -> None:
        for arm, (fx, fz) in zip(self.arms, self.object.hand_forces):
            arm.set_hand_force(fx, fz)


__all__ = ["EXAMPLE_BASES_M", "TwoArmPlant"]
