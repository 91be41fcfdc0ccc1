"""The lock-step world with two arms, as `aspod bench --arms 2` and the pytest plugin's `--aspod-arms 2` build it
(host_tools/worlds/bench_world.py `WorldSettings.arms`): two example arms, each controller a target of its own
(`aspod_target`, `aspod_target.arm2`), the example's object waiting between them, as in `aspod sim --arms 2`."""
from __future__ import annotations

import math

import pytest

from firmware_py.arm_config import EXAMPLE_ARM
from host_tools.apps.two_arm_execute import TwoArmRun
from host_tools.apps.two_arm_plan import controller_knots, executable_plan
from host_tools.plan.example import PATH, report_problem
from host_tools.plugin.target import LockstepTarget
from host_tools.worlds.bench_world import WorldSettings
from host_tools.worlds.settings import PlantSettings
from protocol.messages import MESSAGES as M
from protocol.states import ControllerState


def test_two_arms_round_trip_through_both_command_lines():
    world = WorldSettings(seed=2, arms=2)
    assert world.to_bench_argv()[-2:] == ["--arms", "2"] and "--aspod-arms=2" in world.to_pytest_argv()
    assert "--arms" not in WorldSettings(seed=2).to_bench_argv()
    with pytest.raises(ValueError, match="arms is 1 or 2"):
        WorldSettings(arms=3)


def test_each_arm_is_a_target_and_the_two_carry_the_object_with_plan_executes_steps():
    target = LockstepTarget(WorldSettings(seed=1, arms=2, plant=PlantSettings(tracker=False)))
    try:
        arm2 = target.arm2
        assert arm2 is not None and arm2.control is None and target.control is not None
        assert target.true_state()["object"] == {"held": False, "waits_at_m": list(PATH[0])}
        problem = report_problem(gravity=True, links="rod")
        limited, profile = executable_plan(problem, 0.8, 2.0, 201)
        knots = controller_knots(limited, profile, 60, EXAMPLE_ARM)
        for t in (target, arm2):
            for name, value in (("j1_speed_dps", 200.0), ("j2_speed_dps", 200.0), ("j1_acc_dps2", 50.0),
                                ("j2_acc_dps2", 50.0)):     # the moves to the start in seconds, not a minute
                assert t.call(M["ParamSet"](name, value)).reply.result == 0
        run = TwoArmRun((target.client, arm2.client), knots)       # `aspod plan --execute`'s steps, simulated clock
        run.ready(tuple((k[0].q_deg[0], k[0].q_deg[1]) for k in knots), (30.0, 30.0))
        assert target.true_state()["object"]["held"] is True
        done = run.run(limited, profile)
        assert all(o == "DONE" for arm in done.outcomes for o in arm.values()) and max(done.tracking_deg) < 2.0
        held = target.true_state()["object"]
        assert held["held"] and math.hypot(held["x_m"] - PATH[1][0], held["z_m"] - PATH[1][1]) < 0.01
        assert [g["state"] for g in held["grasps"]] == ["HELD", "HELD"]
        for t in (target, arm2):
            assert t.call(M["GetStatus"]()).reply.state == ControllerState.ENABLED
    finally:
        target.close()


def test_a_one_arm_bench_has_no_second_target():
    target = LockstepTarget(WorldSettings(seed=1))
    try:
        assert target.arm2 is None
    finally:
        target.close()
