"""The report's two arms carrying one object along its example's path, planned and executed (issue 39), measured.

Two example arms (hil_sim EXAMPLE_ARM_PLANT, firmware EXAMPLE_ARM), each with its own controller and link on a
lock-step bench (`LockstepBench(arms=2)`), the object between their grasps (hil_sim/two_arms.py). Each arm is
enabled, homed, brought to the plan's start and closes its jaws; the object is taken. The plan is the planner's
minimum-time plan at `MARGIN` of the example's torque limits, run `SLOWER` times slower (host_tools/apps/
two_arm_plan.py `executable_plan`); each arm's knots from it, both started on one plant tick. Measured against the plan, on
the simulated clock, in Earth gravity and in orbit: the object's path error, the squeeze (the plan shares the load
without one: 0 N), each arm's shoulder and elbow against their knots' curves, and the time until every joint has
settled against the plan's. `carry` takes each arm's knots from a trajectory file of `aspod plan --output` instead,
if given one of the same plan. Not yet measured: the energy against the objective's prediction, and paths other than
the example's (docs/two_arms.md).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import numpy as np

from bench import PartsResult, run_parts
from firmware_py.arm_config import EXAMPLE_ARM
from firmware_py.controller import ControllerConfig
from firmware_py.hermite import HermiteProfile
from hil_sim.arm_params import EXAMPLE_ARM_PLANT
from hil_sim.held_object import GraspState, ObjectParams
from host_tools.apps.two_arm_plan import arm_knots, executable_plan, profile_at, start_pose_deg, start_together
from host_tools.client.bench import BenchClient
from host_tools.client.trajectory import load_trajectory
from host_tools.plan.example import PATH, report_problem
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M, TRAJECTORY_JOINTS
from protocol.states import Axis, GripAction, MotionOutcome

MARGIN = 0.8             # the plan's torque limits, of the example's: the rest is the loops' to follow it with
SLOWER = 2.0             # and the minimum-time plan run this much slower (the TrajPoint's 360 deg/s, the loops' lag)
JAW_GAP_M = 0.02         # the part of the object the jaws close on
KNOTS = 60


def _done(events, ids: dict[int, int]) -> bool:
    return all(any(e.spec.name == "MotionDone" and e.axis == a and e.motion_id == i for e in events)
               for a, i in ids.items())


def _ready(bench: LockstepBench, call, events, controller, plant, start_deg) -> None:
    """Enabled, homed, its shoulder and elbow at the plan's start, its jaws closed on the object's grip."""
    assert call(M["Enable"]()).ok
    reply = call(M["Home"](int(Axis.ALL))).reply
    assert bench.wait_until(lambda: _done(events, {int(a): getattr(reply, f"{a.name.lower()}_motion_id")
                                                   for a in Axis if a is not Axis.ALL}), 60.0)
    for name, value in (("j1_speed_dps", 600.0), ("j2_speed_dps", 600.0), ("j1_acc_dps2", 50.0),
                        ("j2_acc_dps2", 50.0)):
        assert call(M["ParamSet"](name, value)).reply.result == 0, name
    moves = {int(axis): call(M["Move"](int(axis), target, 60.0)).reply.motion_id
             for axis, target in zip((Axis.J1, Axis.J2), start_deg)}
    assert bench.wait_until(lambda: _done(events, moves), 60.0)
    plant.arm.set_object(JAW_GAP_M)
    grip = call(M["Grip"](int(GripAction.CLOSE))).reply
    assert bench.wait_until(lambda: _done(events, {int(Axis.GRIPPER): grip.motion_id}), 30.0)


def carry(gravity: str, trajectory: Optional[Path] = None) -> dict:
    bench = LockstepBench(seed=5, arms=2, controller_config=ControllerConfig(arm=EXAMPLE_ARM),
                          arm_params=EXAMPLE_ARM_PLANT, held_object=ObjectParams(),
                          plant=PlantSettings(gravity=gravity, tracker=False))
    try:
        arm2 = bench.world.arm2
        assert bench.connect() and bench.arm2.connect(arm2.controller)
        problem = report_problem(gravity=gravity == "earth", links="rod")
        arms = ((bench.call, bench.events, bench.controller, bench.world.plant),
                (bench.arm2.call, bench.arm2.events, arm2.controller, arm2.plant))
        for (call, events, controller, plant), start in zip(arms, start_pose_deg(problem)):
            _ready(bench, call, events, controller, plant, start)
        arm2.take_object()
        bench.run_for(0.5)
        assert arm2.pair.object.states == (GraspState.HELD, GraspState.HELD)
        limited, plan = executable_plan(problem, MARGIN, SLOWER, 200)       # as `aspod plan --output` makes it
        held = [[math.degrees(c.arm.channels[int(a)].pos_sp_rad) for a in TRAJECTORY_JOINTS] for _, _, c, _ in arms]
        knots = (tuple(arm_knots(limited, plan, KNOTS, k, held[k]) for k in range(2)) if trajectory is None else
                 tuple(load_trajectory(trajectory, arm) for arm in (1, 2)))
        ids = start_together(BenchClient(bench), bench.arm2, knots)
        start = bench.controller.trajectory_sync.last_start_tick
        curves = [[HermiteProfile([k.t_s for k in arm], [math.radians(k.q_deg[j]) for k in arm],
                                  [math.radians(k.qd_deg_s[j]) for k in arm]) for j in range(2)] for arm in knots]
        (x0, z0), (x1, z1) = PATH
        worst = {"path_m": 0.0, "squeeze_n": 0.0, "tracking_deg": 0.0}
        states = set()
        end = start + round((plan.duration + 0.5) / 0.001)
        while bench.controller.hal.inputs.tick < end:
            bench.run_for(0.001)
            t = (bench.controller.hal.inputs.tick - start) * 0.001
            if t < 0.0:
                continue
            s = profile_at(plan, np.array([t]))[0][0]
            obj = arm2.pair.object
            worst["path_m"] = max(worst["path_m"], math.hypot(obj.pose[0] - x0 - (x1 - x0) * s,
                                                              obj.pose[1] - z0 - (z1 - z0) * s))
            worst["squeeze_n"] = max(worst["squeeze_n"], abs(obj.squeeze_n))
            states.add(obj.states)
            for plant, arm_curves in zip((bench.world.plant, arm2.plant), curves):
                for j, curve in enumerate(arm_curves):
                    worst["tracking_deg"] = max(worst["tracking_deg"], abs(math.degrees(
                        plant.arm.pos_rad[j] - curve.sample(t)[0])))
        wanted = [{(int(a), i) for a, i in zip(TRAJECTORY_JOINTS, motions)} for motions in ids]

        def ends() -> list:
            return [e for events, motions in zip((bench.events, bench.arm2.events), wanted) for e in events
                    if e.spec.name == "MotionDone" and (e.axis, e.motion_id) in motions]
        bench.wait_until(lambda: len(ends()) == 2 * len(TRAJECTORY_JOINTS), 5.0)
        settled_s = (bench.controller.hal.inputs.tick - start) * 0.001
        return {**worst, "plan_s": plan.duration, "settled_s": settled_s, "ends": len(ends()),
                "outcomes": {MotionOutcome(e.outcome) for e in ends()}, "states": states,
                "limit_n": min(arm2.pair.object.limits_n),
                "controllers": (bench.controller.supervisor.state, arm2.controller.supervisor.state)}
    finally:
        bench.close()


def example(tmp: Path, quick: bool) -> list[str]:
    lines = [f"the report's example path, a minimum-time plan at {MARGIN:g} of its torque limits run {SLOWER:g}x "
             f"slower, two example arms, {KNOTS} knots each:"]
    for gravity in (("earth",) if quick else ("earth", "orbit")):
        got = carry(gravity)
        held = "held all the way" if got["states"] == {(GraspState.HELD, GraspState.HELD)} else f"{got['states']}"
        lines.append(f"  {gravity:5s}  object off its path <= {got['path_m'] * 1000:5.2f} mm (goal 10); squeeze <= "
                     f"{got['squeeze_n']:4.1f} N (plan 0, grip limit {got['limit_n']:.0f} N), {held}; joints off "
                     f"their knots' curves <= {got['tracking_deg']:.2f} deg; plan {got['plan_s']:.3f} s, every joint "
                     f"settled at {got['settled_s']:.3f} s ({', '.join(o.name for o in got['outcomes'])}); "
                     f"controllers {', '.join(s.name for s in got['controllers'])}")
    return lines


def main(quick: bool = False) -> PartsResult:
    return run_parts("two arms: the report's example carried, planned and executed", (example,), quick,
                     "aspod-bench-two-arms-")
