"""The report's two arms carrying one object along four paths, planned and executed (issue 39), measured.

Two example arms (hil_sim EXAMPLE_ARM_PLANT, firmware EXAMPLE_ARM), each with its own controller and link on a
lock-step bench (`LockstepBench(arms=2)`), the object between their grasps (hil_sim/two_arms.py). Each arm is
enabled, homed, brought to the plan's start and closes its jaws; the object is taken. The plan is the planner's
minimum-time plan at `MARGIN` of the example's torque limits, run `SLOWER` times slower (host_tools/apps/
two_arm_plan.py `executable_plan`); each arm's knots from it, both started on one plant tick. Measured against the
plan, on the simulated clock, along the report's example and three other paths (`PATHS`), in Earth gravity and in
orbit: the object's path error, the squeeze (the plan shares the load without one: 0 N), each arm's shoulder and
elbow, the time until every joint has settled, and the electrical energy the shoulders' and elbows' motors drew
over the plan's time (`PlantMeter`), with and without regeneration, against the electrical objective's prediction
for the plan with the example arm's motors (host_tools/plan/energy.py `profile_costs`). Each carry's trace is drawn
(host_tools/apps/two_arm_figure.py) into `OUT`. `carry` takes each arm's knots from a trajectory file of `aspod plan
--output` instead, if given one of the same plan. `--quick`: the example in Earth gravity only.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from bench import PartsResult, run_parts
from firmware_py.arm_config import EXAMPLE_ARM
from firmware_py.controller import ControllerConfig
from hil_sim.arm_params import EXAMPLE_ARM_PLANT, J1, J2
from hil_sim.held_object import GraspState, ObjectParams
from host_tools.apps.two_arm_figure import carry_trace, write_carry_figure
from host_tools.apps.two_arm_plan import arm_knots, executable_plan, start_pose_deg, start_together
from host_tools.client.bench import BenchClient
from host_tools.client.trajectory import load_trajectory
from host_tools.outputs import PNG, unclaimed
from host_tools.plan.energy import Pricing, profile_costs
from host_tools.plan.example import PATH, report_problem
from host_tools.plan.motors import example_arm_drives
from host_tools.plan.phase import Problem
from host_tools.plan.profile import Profile
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M, TRAJECTORY_JOINTS
from protocol.states import Axis, GripAction, MotionOutcome

MARGIN = 0.8             # the plan's torque limits, of the example's: the rest is the loops' to follow it with
SLOWER = 2.0             # and the minimum-time plan run this much slower (the TrajPoint's 360 deg/s, the loops' lag)
JAW_GAP_M = 0.02         # the part of the object the jaws close on
KNOTS = 60
TICK_S = 0.001           # the plant's tick
# The example's path and three more within the example arms' reach and soft limits, each planned in both gravities:
# the example run backwards, a vertical lift midway between the bases, a diagonal down and away from arm 1.
PATHS = (("example", PATH), ("reversed", (PATH[1], PATH[0])), ("lift", ((1.0, 0.3), (1.0, 0.9))),
         ("diagonal", ((0.8, 0.9), (1.3, 0.4))))
GRAVITIES = ("earth", "orbit")
OUT = Path(__file__).with_name("out")     # where the benchmarks' figures go (bench/README.md)


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


class PlantMeter:
    """The electrical energy one plant's arm motors draw, from the plant's own state every tick: each channel's
    bridge hands its armature duty x the supply voltage, so it draws duty x V x i (i the armature current at the
    tick's end, V the supply's voltage the tick switched); that is how the plant counts its supply current
    (hil_sim/arm_tick.py `bridges_a`), and it is exact for the plant's motor, which takes one implicit step a tick
    (1 ms substeps: the step's current is its end's). Summed signed (regeneration: what a joint gives back returns to the supply),
    and with each joint's negative ticks left out (without regeneration), as the objective counts each joint; the
    copper loss R i^2 with the plant's own winding resistance; and the drives' own draw while enabled (the plant's
    `enabled_current_a` at V). Measured thus, not from torque and speed: the voltage and the current are what a
    meter on the bridge would read, and they carry whatever the plant's model adds (friction, the gears' loss, the
    inductance) without this meter modelling any of it again."""

    def __init__(self, plant) -> None:
        self.plant = plant
        self.r_ohm = [c.drive.motor.r_ohm for c in plant.arm.params.channels]
        self.v = plant.supply_true_v
        n = len(self.r_ohm)
        self.signed_j, self.drawn_j, self.copper_j = [0.0] * n, [0.0] * n, [0.0] * n
        self.drives_j = 0.0

    def before(self) -> None:
        """Before a tick: the supply's voltage it switches."""
        self.v = self.plant.supply_true_v

    def after(self, dt_s: float) -> None:
        """After a tick of `dt_s`: what each channel drew."""
        plant = self.plant
        for k, (duty, driven, i) in enumerate(zip(plant.channel_duty, plant.channel_driven, plant.currents_a)):
            power = max(-1.0, min(1.0, duty)) * self.v * i if driven else 0.0
            self.signed_j[k] += power * dt_s
            self.drawn_j[k] += max(power, 0.0) * dt_s
            self.copper_j[k] += self.r_ohm[k] * i * i * dt_s
        if plant.outputs_enabled:
            self.drives_j += plant.params.enabled_current_a * self.v * dt_s

    def snapshot(self) -> dict:
        """What was drawn so far (J): the shoulder and elbow together, signed ("regen") and without what they gave
        back ("drawn"), their copper loss, the drives' own draw, and the other four channels' (J3, J4, the gripper
        holding the object, the mount: signed)."""
        return {"regen": sum(self.signed_j[:2]), "drawn": sum(self.drawn_j[:2]), "copper": sum(self.copper_j[:2]),
                "drives": self.drives_j, "others": sum(self.signed_j[2:])}


def energy(problem: Problem, plan: Profile, during: Sequence[dict], total: Sequence[dict]) -> dict:
    """The energy both arms drew over the plan's time (`during`: each arm's `PlantMeter.snapshot` at the plan's end)
    and to the loop's end (`total`), beside the electrical objective's prediction for the plan as executed (the
    example arm's motors: `example_arm_drives`), with and without regeneration (J)."""
    def summed(snapshots):
        return {key: sum(s[key] for s in snapshots) for key in snapshots[0]}
    predicted = {regen: profile_costs(problem, plan, Pricing.of(problem, regen=regen)) for regen in (False, True)}
    return {"measured": summed(during), "to_end": summed(total),
            "predicted": {"drawn": predicted[False]["electrical"] - predicted[False]["drives"],
                          "regen": predicted[True]["electrical"] - predicted[True]["drives"],
                          "copper": predicted[False]["thermal"], "drives": predicted[False]["drives"],
                          "work": predicted[False]["energy"]}}


def carry(gravity: str, trajectory: Optional[Path] = None, path=PATH) -> dict:
    """The object carried along `path` (the example's unless given) in `gravity`; each arm's knots from the plan, or
    from `trajectory` (a file of `aspod plan --output`). What was measured against the plan, and the carry's trace."""
    bench = LockstepBench(seed=5, arms=2, controller_config=ControllerConfig(arm=EXAMPLE_ARM),
                          arm_params=EXAMPLE_ARM_PLANT, held_object=ObjectParams(),
                          plant=PlantSettings(gravity=gravity, tracker=False))
    try:
        arm2 = bench.world.arm2
        assert bench.connect() and bench.arm2.connect(arm2.controller)
        problem = dataclasses.replace(report_problem(gravity=gravity == "earth", links="rod", path=path),
                                      motors=example_arm_drives())
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
        plants = (bench.world.plant, arm2.plant)
        meters = tuple(PlantMeter(plant) for plant in plants)
        during = [meter.snapshot() for meter in meters]     # at the plan's end
        times, objects, squeezes, joints, states = [], [], [], [], set()
        end = start + round((plan.duration + 0.5) / TICK_S)
        while bench.controller.hal.inputs.tick < end:
            for meter in meters:
                meter.before()
            bench.run_for(TICK_S)                                           # one plant tick
            t = (bench.controller.hal.inputs.tick - start) * TICK_S
            if t <= 0.0:
                continue
            for meter in meters:
                meter.after(TICK_S)
            if t <= plan.duration:
                during = [meter.snapshot() for meter in meters]
            obj = arm2.pair.object
            times.append(t)
            objects.append(obj.pose[:2])
            squeezes.append(obj.squeeze_n)
            states.add(obj.states)
            joints.append([float(p.arm.pos_rad[j]) for p in plants for j in (J1, J2)])
        wanted = [{(int(a), i) for a, i in zip(TRAJECTORY_JOINTS, motions)} for motions in ids]

        def ends() -> list:
            return [e for events, motions in zip((bench.events, bench.arm2.events), wanted) for e in events
                    if e.spec.name == "MotionDone" and (e.axis, e.motion_id) in motions]
        bench.wait_until(lambda: len(ends()) == 2 * len(TRAJECTORY_JOINTS), 5.0)
        settled_s = (bench.controller.hal.inputs.tick - start) * TICK_S
        trace = carry_trace(limited, plan, times, objects, squeezes, joints)
        return {"trace": trace, "path_m": float(trace.path_error_m.max()),
                "squeeze_n": float(np.abs(trace.squeeze_n).max()),
                "tracking_deg": tuple(float(np.degrees(np.abs(trace.tracking_error_rad[:, 2 * k:2 * k + 2]).max()))
                                      for k in range(2)),
                "plan_s": plan.duration, "settled_s": settled_s, "ends": len(ends()),
                "outcomes": {MotionOutcome(e.outcome) for e in ends()}, "states": states,
                "limit_n": min(arm2.pair.object.limits_n),
                "controllers": (bench.controller.supervisor.state, arm2.controller.supervisor.state),
                "energy": energy(limited, plan, during, [meter.snapshot() for meter in meters])}
    finally:
        bench.close()


def _row(name: str, gravity: str, got: dict) -> str:
    e = got["energy"]
    measured, predicted = e["measured"], e["predicted"]
    held = "held" if got["states"] == {(GraspState.HELD, GraspState.HELD)} else "/".join(
        sorted({g.name for pair in got["states"] for g in pair}))
    done = ",".join(sorted(o.name for o in got["outcomes"]))
    return (f"{name:9s} {gravity:5s} {got['tracking_deg'][0]:5.2f} {got['tracking_deg'][1]:5.2f} "
            f"{got['path_m'] * 1000:6.2f}  {got['squeeze_n']:4.1f}/{got['limit_n']:2.0f} {held:4s}  "
            f"{got['plan_s']:5.3f} {got['settled_s']:7.3f} {done:4s}  "
            f"{measured['drawn']:5.1f}/{predicted['drawn']:5.1f} {measured['drawn'] / predicted['drawn']:4.2f}  "
            f"{measured['regen']:5.1f}/{predicted['regen']:5.1f} {measured['regen'] / predicted['regen']:4.2f}  "
            f"{measured['copper']:5.1f}/{predicted['copper']:5.1f}  {measured['drives']:4.1f}/{predicted['drives']:4.1f}")


def carried(tmp: Path, quick: bool):
    yield (f"each path a minimum-time plan at {MARGIN:g} of the example's torque limits run {SLOWER:g}x slower, two "
           f"example arms, {KNOTS} knots each; energies over the plan's time, the shoulders' and elbows' motors "
           "measured by the plant / the electrical objective's prediction (J):")
    yield (f"{'path':9s} {'in':5s} {'arm 1 arm 2':>11s} {'object':>6s}  {'squeeze/grip':12s}  {'plan':>5s} "
           f"{'settled':>7s} {'':4s}  {'no regeneration':>16s}  {'regeneration':>16s}  {'copper':>11s}  {'drives':>9s}")
    yield (f"{'':9s} {'':5s} {'(deg)':>11s} {'(mm)':>6s}  {'(N)':12s}  {'(s)':>5s} {'(s)':>7s} {'':4s}  "
           f"{'meas/pred ratio':>16s}  {'meas/pred ratio':>16s}  {'meas/pred':>11s}  {'meas/pred':>9s}")
    OUT.mkdir(exist_ok=True)
    for gravity in (("earth",) if quick else GRAVITIES):
        for name, path in (PATHS[:1] if quick else PATHS):
            got = carry(gravity, path=path)
            figure = OUT / f"two_arms_{name}_{gravity}.png"
            write_carry_figure(got["trace"], unclaimed(figure, PNG), f"Two example arms carrying the report's object: "
                               f"{name} path, {gravity}; plan dashed, execution solid")
            yield _row(name, gravity, got)
    yield f"(figures: {OUT}/two_arms_<path>_<gravity>.png; the goals: path within 10 mm, squeeze within the grip)"


def main(quick: bool = False) -> PartsResult:
    return run_parts("two arms: the report's object carried along four paths, planned and executed", (carried,), quick,
                     "aspod-bench-two-arms-")
