"""The pick-and-place with its arm moves planned time-optimally and sent as trajectories, beside the same moves as
trapezoids at the report's 1/2 RPM (issue 16, item 6).

Both runs go through the protocol on a `LockstepBench` (the simulated clock), as `apps/pick_place.py` does: the
same scene, homing, grips and payloads. In the planned run each move of j1..j4 and the mount is planned by
`apps/arm_plan.plan_move` from what the controller says (its current and speed limit parameters, read with
ParamGet; its gravity), sent with `client/trajectory.send_trajectory`, and followed by the firmware. The joints' speed parameters are raised to what the planner
may use (`PLANNED_SPEED_DPS`, each its parameter's highest), since the controller refuses a trajectory faster than them. After each step the
gripper tip's true position is compared with where the step should put it: the report's 1 cm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_py.arm_config import ASPOD_ARM
from host_tools.apps.arm_plan import ARM_JOINTS, ArmPlanSettings, plan_move
from host_tools.apps.kinematics import DEMO_SCENE, steps
from host_tools.apps.pick_place import SPEC_M, DemoFailed, PickAndPlace, StepResult
from host_tools.client.trajectory import TrajectoryRefused, send_trajectory
from host_tools.plan.errors import PlanError
from protocol.messages import MESSAGES as M, TRAJECTORY_JOINTS

GRAVITY_M_S2 = {"earth": 9.80665, "orbit": 0.0}
# each joint's speed parameter at its largest value (ASPOD's arm: the pick-and-place's)
PLANNED_SPEED_DPS = {p.name[:-len("_speed_dps")]: p.hi for p in ASPOD_ARM.parameter_table()
                     if p.name.endswith("_speed_dps")}


@dataclass
class PlannedStep(StepResult):
    planned_s: float = math.nan        # the plan's own duration (the step also settles)


class PlannedPickAndPlace(PickAndPlace):
    """The pick-and-place whose arm moves are planned trajectories."""

    def __init__(self, gravity: str = "earth", seed: int = 0, settings: ArmPlanSettings = ArmPlanSettings()) -> None:
        super().__init__(gravity, seed)
        self.settings = settings
        self.current_a: dict[str, float] = {}
        self.speed_rad_s: dict[str, float] = {}

    def prepare(self) -> None:
        super().prepare()
        for name in ARM_JOINTS:
            self._call(M["ParamSet"](f"{name}_speed_dps", PLANNED_SPEED_DPS[name]), f"raise {name}'s speed limit")
            self.speed_rad_s[name] = math.radians(self._call(M["ParamGet"](f"{name}_speed_dps"), "read it").value)
            self.current_a[name] = self._call(M["ParamGet"](f"{name}_i_lim_a"), f"read {name}'s current limit").value

    def _pose(self) -> dict[str, float]:
        """Where each arm joint holds now (the controller's targets, as the last steps left them)."""
        return {name: self.bench.controller.arm.joints[name].target_rad for name in ARM_JOINTS}

    def run_step(self, step) -> StepResult:
        arm_targets = {n: q for n, q in step.targets.items() if n in ARM_JOINTS}
        if step.action is not None or not arm_targets:
            return super().run_step(step)
        start_s = self.bench.clock.now()
        try:
            move = plan_move(self._pose(), arm_targets, GRAVITY_M_S2[self.gravity], step.held_kg, self.current_a,
                             self.speed_rad_s, self.settings)
        except PlanError as exc:
            raise DemoFailed(f"{step.name}: cannot plan it: {exc}") from exc
        try:
            ids = send_trajectory(self.bench, move.knots(self.settings.knots))
        except (TrajectoryRefused, ValueError) as exc:
            raise DemoFailed(f"{step.name}: trajectory refused: {exc}") from exc
        started = {int(axis): motion for axis, motion in zip(TRAJECTORY_JOINTS, ids)}
        outcomes = self._wait_motions(started, step.name)
        result = PlannedStep(step.name, self.tip_error_m(step.tip_xyz_m), self.bench.clock.now() - start_s, outcomes,
                             move.duration_s)
        self.results.append(result)
        return result


def run_both(gravity: str = "earth", seed: int = 0) -> dict:
    """Every move of the pick-and-place, trapezoid and planned: time and positioning error each, and the totals."""
    runs = {}
    for how, demo in (("trapezoid", PickAndPlace(gravity, seed)), ("planned", PlannedPickAndPlace(gravity, seed))):
        try:
            demo.prepare()
            for step in steps(demo.scene):
                demo.run_step(step)
        finally:
            demo.close()
        runs[how] = demo.results
    moves = []
    for step, trap, plan in zip(steps(DEMO_SCENE), runs["trapezoid"], runs["planned"]):
        if step.action is None and step.name != "home":        # the moves between the homed pose and home
            moves.append({"step": step.name, "trapezoid_s": round(trap.sim_time_s, 3),
                          "planned_s": round(plan.sim_time_s, 3),
                          "plan_s": round(getattr(plan, "planned_s", math.nan), 3),
                          "trapezoid_error_m": trap.position_error_m, "planned_error_m": plan.position_error_m})
    return {"gravity": gravity, "moves": moves,
            "trapezoid_s": round(sum(r["trapezoid_s"] for r in moves), 3),
            "planned_s": round(sum(r["planned_s"] for r in moves), 3),
            "max_planned_error_m": max(r["planned_error_m"] for r in moves), "spec_m": SPEC_M}
