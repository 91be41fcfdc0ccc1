"""The grip's limit (issue 39): a two-arm plan whose hands would carry more than friction x the jaws' force is
refused before anything moves (host_tools/apps/two_arm_plan.py `within_grip`), and a grasp that slips or drops in the
plant is a fault of the controller holding it (GRIP_SLIP, from the wrist's GRASP_FORCE frame)."""
from __future__ import annotations

import json
import math

import pytest

from bench.bench_two_arms import _ready
from firmware_py.arm_config import EXAMPLE_ARM
from firmware_py.controller import ControllerConfig
from hil_sim.arm_params import ARM_PLANT_PARAMS, EXAMPLE_ARM_PLANT
from hil_sim.held_object import ObjectParams
from host_tools.apps.two_arm_plan import (arm_knots, controller_knots, executable_plan, grip_limit_n, hand_forces_n,
                                         start_pose_deg, start_together)
from host_tools.client.bench import BenchClient
from host_tools.cli.main import main
from host_tools.plan.errors import PlanError
from host_tools.plan.example import report_problem
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M, TRAJECTORY_JOINTS
from protocol.reasons import Reason
from protocol.states import Axis, ControllerState, Fault, GraspState, MotionOutcome

PLAN = ["plan", "--links", "rod", "--gravity", "--objective", "time", "--nodes", "199"]     # the bench's 200 points


def test_the_grips_limit_is_friction_times_the_plants_jaws():
    """0.5 x 117.8 N at the example arm's grip_hold_duty 0.3 from 28 V (docs/fidelity.md G7, G8)."""
    limit, why = grip_limit_n(EXAMPLE_ARM)
    assert limit == pytest.approx(58.9, abs=0.05)
    assert why == "friction 0.5 x the jaws' 117.8 N at grip_hold_duty 0.3 and 28 V"
    assert grip_limit_n(EXAMPLE_ARM, ObjectParams(friction=0.25))[0] == pytest.approx(limit / 2)
    assert ARM_PLANT_PARAMS.jaw_force_n(0.3, 28.0) == pytest.approx(117.8, abs=0.05)


def test_the_hands_share_the_objects_weight_and_its_acceleration():
    """Each hand carries half of m (w'' + g): along the example's executable plan (1.06 s in Earth gravity) 1.22 to
    1.41 N about the weight's half (1.226 N), the two hands alike; 3.73 N at most at the plan's full pace (0.53 s)."""
    problem = report_problem(gravity=True, links="rod")
    limited, profile = executable_plan(problem, 0.8, 2.0, 200)
    times, forces = hand_forces_n(limited, profile)
    assert times[0] == 0.0 and times[-1] == pytest.approx(profile.duration)
    assert forces[:, 0] == pytest.approx(forces[:, 1])
    assert forces.min() == pytest.approx(1.2240, abs=1e-3) and forces.max() == pytest.approx(1.4127, abs=1e-3)
    fast, full = executable_plan(problem, 0.8, 1.0, 200)
    assert hand_forces_n(fast, full)[1].max() == pytest.approx(3.733, abs=1e-3)


def test_a_plan_the_grip_cannot_hold_is_refused_naming_the_arm_and_the_force():
    """A weak grip (friction 0.03: 3.5 N) holds the example run 2x slower (1.41 N) but not at the plan's own pace
    (3.73 N), either hand (they share it equally)."""
    problem = report_problem(gravity=True, links="rod")
    weak = ObjectParams(friction=0.03)
    limited, profile = executable_plan(problem, 0.8, 2.0, 200)
    assert len(controller_knots(limited, profile, 41, EXAMPLE_ARM, weak)[0]) >= 41
    fast, full = executable_plan(problem, 0.8, 1.0, 200)
    with pytest.raises(PlanError, match=r"arm [12]'s grasp carries 3\.7 N at t = 0\.\d+ s, above the grip's limit 3\.5 N "
                                        r"\(friction 0\.03 x the jaws' 117\.8 N at grip_hold_duty 0\.3 and 28 V\): "
                                        r"the object would slip"):
        controller_knots(fast, full, 41, EXAMPLE_ARM, weak)


def test_aspod_plan_refuses_a_heavy_object_before_writing_anything(tmp_path, capsys):
    """A 20 kg object on arms strong enough to plan it (300 N m): each hand carries 98 N at rest, 123.7 N at most
    along the plan, above the grip's 58.9 N. `aspod plan --output` refuses, naming the arm and the force, and writes
    nothing."""
    problem = tmp_path / "heavy.json"
    problem.write_text(json.dumps({"path": {"kind": "line", "start": [0.688, 0.331], "end": [1.716, 0.504]},
                                   "arms": {"links": "rod"}, "object": {"mass": 20.0}, "gravity": 9.81,
                                   "limits": {"symmetric": [300, 300, 300, 300]}}))
    out = tmp_path / "two.json"
    assert main(["plan", "--problem", str(problem), "--objective", "time", "--nodes", "199", "--output",
                 str(out)]) == 2
    err = capsys.readouterr().err
    assert "arm 1's grasp carries 123.7 N at t = 0.470 s" in err and "above the grip's limit 58.9 N" in err, err
    assert not out.exists()


def holding(params: ObjectParams = ObjectParams()) -> LockstepBench:
    """Two example arms on the lock-step bench at the example plan's start, their jaws closed on the object, holding
    it (as bench/bench_two_arms.py readies them)."""
    bench = LockstepBench(seed=5, arms=2, controller_config=ControllerConfig(arm=EXAMPLE_ARM),
                          arm_params=EXAMPLE_ARM_PLANT, held_object=params,
                          plant=PlantSettings(gravity="earth", tracker=False))
    arm2 = bench.world.arm2
    assert bench.connect() and bench.arm2.connect(arm2.controller)
    arms = ((bench.call, bench.events, bench.controller, bench.world.plant),
            (bench.arm2.call, bench.arm2.events, arm2.controller, arm2.plant))
    for (call, events, controller, plant), start in zip(arms, start_pose_deg(report_problem(gravity=True,
                                                                                            links="rod"))):
        _ready(bench, call, events, controller, plant, start)
    return bench


def test_a_jog_past_the_grips_limit_faults_the_arm_whose_grasp_slips():
    """Both example arms hold the object; arm 2's grip is weak (grip_hold_duty 0.05: its jaws 19 N, the grip's limit
    9.7 N). Jogging arm 2's shoulder at 5 deg/s pulls on the object until, about 0.7 s on, arm 2's grasp slides off the
    object's end: its controller hears it (GRASP_FORCE DROPPED) and faults, GRIP_SLIP alone, StateChanged's reason
    FAULT_LATCHED (no reason of its own: the link's schema stays as it was). Arm 1's grasp held: its controller
    stays ENABLED. Before the object is taken no GRASP_FORCE is on either bus; then one every 10 ms on each."""
    bench = holding()
    try:
        world, arm2 = bench.world, bench.world.arm2
        assert "GRASP_FORCE" not in world.plant_node.sent_by_name | arm2.plant_node.sent_by_name
        arm2.take_object()
        bench.run_for(0.5)
        assert arm2.wrists.sent == [50, 50]
        assert bench.controller.grasp.reading.state is GraspState.HELD
        assert bench.arm2.call(M["ParamSet"]("grip_hold_duty", 0.05)).reply.result == Reason.OK
        bench.run_for(0.2)
        assert arm2.controller.grasp.reading.limit_n == pytest.approx(9.7, abs=0.1)
        assert bench.arm2.call(M["Jog"](int(Axis.J1), 5.0)).reply.result == Reason.OK
        assert bench.wait_until(lambda: any(e.spec.name == "StateChanged" and e.state == ControllerState.FAULT
                                            for e in bench.arm2.events), 5.0)
        fault = next(e for e in bench.arm2.events if e.spec.name == "StateChanged" and e.state == ControllerState.FAULT)
        assert (Fault(fault.faults), Reason(fault.reason)) == (Fault.GRIP_SLIP, Reason.FAULT_LATCHED)
        event = arm2.pair.object.last_event
        assert (event.grasp, event.state) == (1, GraspState.DROPPED) and event.force_n > event.limit_n, event
        lost = arm2.controller.grasp.lost
        assert lost.state is GraspState.DROPPED and lost.limit_n == pytest.approx(event.limit_n, abs=0.01)
        assert arm2.pair.object.states[0] is GraspState.HELD
        assert bench.controller.supervisor.state is ControllerState.ENABLED and bench.controller.grasp.losses == 0
    finally:
        bench.close()


def test_a_stop_mid_carry_brings_both_arms_to_rest_along_the_path_the_object_held():
    """The example carried (Earth, its executable plan, 60 knots an arm, started together); 0.5 s in, arm 2's shoulder
    at 130 deg/s, Stop to arm 1. Both trajectories slow to rest along their curves from one plant tick (TRAJ_STOP),
    so the hands stay on the plan's path together: both grasps hold all the way, at most 4.2 N across either (the
    plan's 1.4 N, the grip's 57 N), both controllers ENABLED, every joint's motion STOPPED. (Each joint stopping at its
    own acceleration limit, as a lone Stop stops it, the hands parted: 48 N, FOLLOWING_ERROR on both, the object
    dropped.)"""
    bench = holding()
    try:
        arm2 = bench.world.arm2
        arm2.take_object()
        bench.run_for(0.5)
        limited, plan = executable_plan(report_problem(gravity=True, links="rod"), 0.8, 2.0, 200)
        controllers = (bench.controller, arm2.controller)
        held = [[math.degrees(c.arm.channels[int(a)].pos_sp_rad) for a in TRAJECTORY_JOINTS] for c in controllers]
        ids = start_together(BenchClient(bench), bench.arm2,
                             tuple(arm_knots(limited, plan, 60, k, held[k]) for k in range(2)))
        bench.run_for(0.5)
        assert abs(math.degrees(arm2.controller.arm.channels[0].vel_rad_s)) > 100.0
        bench.host.submit(M["Stop"](), bench.link_clock.now())
        worst, states = 0.0, set()
        for _ in range(1500):
            bench.run_for(0.001)
            worst, states = max(worst, *arm2.pair.object.carried_n), states | {arm2.pair.object.states}
        assert states == {(GraspState.HELD, GraspState.HELD)} and worst < 5.0, (states, worst)
        assert [c.supervisor.state for c in controllers] == [ControllerState.ENABLED] * 2
        assert arm2.controller.trajectory_sync.stopped_by_peer == 1
        for events, motions in zip((bench.events, bench.arm2.events), ids):
            wanted = {(int(a), i) for a, i in zip(TRAJECTORY_JOINTS, motions)}
            outcomes = {MotionOutcome(e.outcome) for e in events
                        if e.spec.name == "MotionDone" and (e.axis, e.motion_id) in wanted}
            assert outcomes == {MotionOutcome.STOPPED}, outcomes
    finally:
        bench.close()
