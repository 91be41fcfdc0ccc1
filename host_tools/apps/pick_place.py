"""The pick-and-place run: home, pick the debris, carry it with the mount turning, drop it in the bin.

Everything goes through the protocol, as ground software would drive the real arm: a
`LockstepBench` (plant, controller and a host link on the simulated clock) receives
Enable, Home, Move and Grip commands and answers with MotionAccepted replies and MotionDone
events. The plant is touched only where the world itself acts: the debris is put between
the jaws when the gripper reaches it, and its mass rides on the tip once gripped.

After each step the gripper tip's true position (the plant's forward kinematics of the
true joint angles) is compared with where the step should have put it
(`host_tools.apps.kinematics.steps`): that is the positioning error the report specifies
within 1 cm. Joint moves of one step are coordinated: each joint gets the speed that makes
all of them take as long as the slowest one at its speed limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from protocol.messages import MESSAGES as M, started_motions
from protocol.reasons import Reason
from protocol.states import Axis, GripAction, MotionOutcome
from timebase import RealClock

from host_tools.apps.kinematics import DEMO_SCENE, Scene, Step, steps
from host_tools.outputs import Output
from host_tools.progress import Progress
from host_tools.sessions.capture import CaptureWriter, SessionInfo
from host_tools.worlds.world import LockstepBench
from host_tools.worlds.settings import PlantSettings

AXIS_BY_NAME = {a.name.lower(): a for a in Axis if a is not Axis.ALL}
SPEC_M = 0.01                     # the report's positioning spec: within 1 cm
MOTION_TIMEOUT_S = 120.0
SIM_S = 145.0                     # the whole run's simulated time, for its progress (144.5-144.6 s, earth and orbit)


class DemoFailed(RuntimeError):
    """A step could not be done; the message says which and why."""


@dataclass
class StepResult:
    name: str
    position_error_m: float
    sim_time_s: float              # simulated time the step took
    outcomes: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"name": self.name, "position_error_m": self.position_error_m,
                "sim_time_s": round(self.sim_time_s, 3), "outcomes": self.outcomes}


class PickAndPlace:
    def __init__(self, gravity: str = "earth", seed: int = 0, scene: Scene = DEMO_SCENE,
                 bench: Optional[LockstepBench] = None) -> None:
        self.scene = scene
        self.gravity = gravity
        self.bench = bench if bench is not None else LockstepBench(seed=seed, plant=PlantSettings(gravity=gravity))
        self.plant = self.bench.world.plant
        self.results: list[StepResult] = []
        self.homing_s = math.nan

    @classmethod
    def on_bench(cls, bench: LockstepBench, scene: Scene = DEMO_SCENE) -> "PickAndPlace":
        """The pick-and-place on a world someone else built (a bench target), in that world's gravity."""
        return cls(bench.plant_settings.gravity, scene=scene, bench=bench)

    # ---- protocol helpers ----
    def _call(self, msg, what: str):
        handle = self.bench.call(msg)
        if not handle.ok:
            raise DemoFailed(f"{what}: {handle.describe()}")
        return handle.reply

    def _wait_motions(self, started: dict[int, int], what: str,
                      accept: frozenset = frozenset({MotionOutcome.DONE})) -> dict[str, str]:
        """Wait for the MotionDone of each (axis -> motion_id); fail unless every one ends as `accept` says."""
        done: dict[int, object] = {}
        events = self.bench.events
        seen = 0            # the events looked at already: the predicate runs every tick, the list only grows

        def finished() -> bool:
            nonlocal seen
            while seen < len(events):
                event = events[seen]
                seen += 1
                if event.spec.name == "MotionDone" and started.get(event.axis) == event.motion_id:
                    done[event.axis] = event
            return len(done) == len(started) or self.bench.controller.supervisor.in_safe_state

        if not self.bench.wait_until(finished, MOTION_TIMEOUT_S, between_loops=True):
            raise DemoFailed(f"{what}: no MotionDone within {MOTION_TIMEOUT_S} s of simulated time")
        outcomes = {Axis(a).name.lower(): MotionOutcome(e.outcome).name for a, e in done.items()}
        bad = {a: e for a, e in done.items() if e.outcome not in accept}
        if bad or len(done) < len(started):
            sup = self.bench.controller.supervisor
            details = ", ".join(f"{Axis(a).name.lower()} {MotionOutcome(e.outcome).name} ({Reason(e.reason).name})"
                                for a, e in bad.items())
            raise DemoFailed(f"{what}: {details or 'the controller went to its safe state'}; "
                             f"controller {sup.state.name}, reason {sup.safe_reason.name}")
        return outcomes

    # ---- the run ----
    def tip_error_m(self, expected_xyz: tuple[float, float, float]) -> float:
        return float(np.linalg.norm(self.plant.arm.gripper_position_m() - np.asarray(expected_xyz)))

    def prepare(self) -> None:
        """Connect, tell the controller the gravity it works in, enable, home every axis."""
        if not self.bench.connect():
            raise DemoFailed("connect: no session")
        if self.gravity == "orbit":
            self._call(M["ParamSet"]("gravity_m_s2", 0.0), "set gravity_m_s2 0 (orbit)")
        self._call(M["Enable"](), "enable")
        start = self.bench.clock.now()
        # `home all` answers with the id of every axis's homing; each axis's MotionDone carries its own
        reply = self._call(M["Home"](int(Axis.ALL)), "home all")
        self._wait_motions(started_motions(reply), "home all")
        self.homing_s = self.bench.clock.now() - start

    def run_step(self, step: Step) -> StepResult:
        start = self.bench.clock.now()
        if step.action is not None:
            outcomes = self._grip(step)
        else:
            outcomes = self._move(step)
        result = StepResult(step.name, self.tip_error_m(step.tip_xyz_m), self.bench.clock.now() - start, outcomes)
        self.results.append(result)
        return result

    def _move(self, step: Step) -> dict[str, str]:
        arm = self.bench.controller.arm
        durations = {}
        for name, target in step.targets.items():
            axis = arm.joints[name]
            distance = abs(target - axis.target_rad)
            durations[name] = distance / axis.config.vel_limit_rad_s
        longest = max(durations.values(), default=0.0)
        started = {}
        for name, target in step.targets.items():
            axis_id = AXIS_BY_NAME[name]
            limit_dps = math.degrees(arm.joints[name].config.vel_limit_rad_s)
            speed = limit_dps * durations[name] / longest if longest > 0 else 0.0
            speed = min(limit_dps, max(speed, 0.1)) if speed > 0 else 0.0
            reply = self._call(M["Move"](int(axis_id), math.degrees(target), speed), f"{step.name}: move {name}")
            started[int(axis_id)] = reply.motion_id
        return self._wait_motions(started, step.name)

    def _grip(self, step: Step) -> dict[str, str]:
        close = step.action == "close"
        arm = self.plant.arm
        if close:
            self.bench.act("set_object", self.scene.debris_width_m)     # the jaws are around the debris now
        reply = self._call(M["Grip"](int(GripAction.CLOSE if close else GripAction.OPEN)), f"{step.name}: grip")
        outcomes = self._wait_motions({int(Axis.GRIPPER): reply.motion_id}, step.name)
        if close:
            if not self.bench.controller.arm.gripper.gripped or arm.grip_force_n <= 0:
                raise DemoFailed(f"{step.name}: the gripper closed without gripping the debris")
            self.bench.act("set_payload", step.held_kg)
            self._call(M["ParamSet"]("payload_kg", step.held_kg), "tell the controller the payload")
        else:
            self.bench.act("set_object", None)
            self.bench.act("set_payload", 0.0)
            self._call(M["ParamSet"]("payload_kg", 0.0), "tell the controller the payload")
        return outcomes

    def close(self) -> None:
        self.bench.close()


def run(gravity: str = "earth", seed: int = 0, progress=None, record: Optional[Output] = None,
        shown: Optional[Progress] = None) -> dict:
    """Run the whole demo; return the report (see `aspod demo --json`). With `record`, the session's capture, put in
    place when the demo ends (a run that raises, Ctrl-C say, leaves it as it was); `shown` follows its simulated
    clock (host_tools/progress.py)."""
    wall0 = RealClock.precise_now()
    demo = PickAndPlace(gravity, seed)
    if shown is not None:
        shown.follow(demo.bench.clock.now)
    writer = None
    if record is not None:
        writer = CaptureWriter.create(record, SessionInfo(clock="simulated", tool="aspod demo", seed=seed,
                                                          settings=demo.bench.settings()))
        demo.bench.record(writer)
    error: Optional[str] = None
    try:
        demo.prepare()
        for step in steps(demo.scene):
            result = demo.run_step(step)
            if progress:
                progress(result)
    except DemoFailed as exc:
        error = str(exc)
    except BaseException:
        if writer is not None:
            writer.discard()
        raise
    finally:
        sim_time_s = demo.bench.clock.now()
        wall_time_s = RealClock.precise_now() - wall0
        demo.close()
    max_error = max((r.position_error_m for r in demo.results), default=None)
    return {
        "gravity": gravity,
        "seed": seed,
        "homing_sim_time_s": round(demo.homing_s, 3) if math.isfinite(demo.homing_s) else None,
        "steps": [r.as_dict() for r in demo.results],
        "max_position_error_m": max_error,
        "spec_m": SPEC_M,
        "within_spec": error is None and max_error is not None and max_error <= SPEC_M,
        "sim_time_s": round(sim_time_s, 3),
        "wall_time_s": round(wall_time_s, 3),
        "speed_x_real_time": round(sim_time_s / wall_time_s, 2) if wall_time_s > 0 else None,
        "error": error,
    }
