"""The joints' tick (firmware_py/joints_tick.py, the one implementation) through its cases, compiled the same to
the bit as plain.

Two levels. Whole lock-step worlds run through scripted sessions with the joints' tick plain and
(when numba is installed) compiled by numba (firmware_py/joints_compiled.py), and must send the
same duties, enables and brakes on every tick, the same bytes to the host, and end with every
joint's state the same, floats compared by `float.hex`. And one joint alone (`single_axis`) on a
small test plant with inputs the world cannot make (a current that is not a number, counts that
jump or stop), plain, and compiled beside plain compared after every tick.

Each session also says what it went through (modes, error bits, fault reasons, motion outcomes,
counts across the 32-bit wrap, events handed to the facade), so a session that stopped covering
its case fails instead of passing on nothing. (Until issue 35 the tick was written twice, here and
as `Axis.update`, and these tests held the two equal; the single implementation was checked
against that `Axis.update` on every session and scenario here, every tick, to the bit.)
"""
from __future__ import annotations

import importlib.util
import math
import os
import random
import sys
from dataclasses import dataclass, field, replace
from typing import Callable, Optional

import pytest

from firmware_py import joints_tick as jt
from firmware_py.axis import Axis, AxisError, Refusal
from firmware_py.controller import ControllerConfig
from firmware_py.estimator import COUNT_MODULUS
from firmware_py.joint_bank import BankedAxis, JointBank, single_axis
from firmware_py.joints_compiled import compiled_arm_joints_tick, compiled_joints_tick
from kernels import ENVIRONMENT_SWITCH, switched
from kernels.extras import MissingExtra
from host_tools.client.trajectory import Knot, send_trajectory
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M, TRAJECTORY_JOINTS
from protocol.reasons import Reason
from protocol.states import Axis as AxisId, AxisMode, ControllerState, MotionOutcome

from test_axis_pipeline import DT_S, Joint, make_config

JOINTS = ("j1", "j2", "j3", "j4", "mount")
HAVE_NUMBA = importlib.util.find_spec("numba") is not None
COMPILED = [False, pytest.param(True, marks=pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed "
                                                                "(the compiled joints are optional)"))]


def hexed(value) -> object:
    return value.hex() if isinstance(value, float) else value


def snapshot(axis: Axis) -> tuple:
    """Everything of an axis that a tick reads or writes, floats as `float.hex`."""
    est = axis.estimator
    profile = axis._profile
    values = (axis.mode, axis.duty, axis.duty_requested, axis.brake, axis.homed, int(axis.errors), axis.pos_sp_rad,
              axis.vel_sp_rad_s, axis.target_rad, axis.outcome, axis.motion_id, axis._integ, axis._duty_lo,
              axis._duty_hi, axis._count_s, axis._profile_t0, axis._settle_since, axis._stopping_for,
              axis._stall.since, axis._trip.since, axis._open.since, axis._homing.phase, axis._homing.start_rad,
              est.pos_rad, est.vel_rad_s, est.offset_rad, est.last_count, est.turns_counts, est.missed_ticks,
              est.glitches, est.flags, None if profile is None else tuple(
                  profile.segments if profile.constant_acceleration else profile.coefficients),
              None if profile is None else (profile.duration_s, profile.end_pos_rad, profile.end_vel_rad_s))
    return tuple(tuple(map(hexed, v)) if isinstance(v, tuple) else hexed(v) for v in values)


# ---------------------------------------------------------------- whole worlds
@dataclass
class WorldRun:
    """What one run of a session sent and went through."""

    commands: list = field(default_factory=list)     # per MOTOR_CMD: (now, duties as hex, enables, brakes)
    per_tick: list = field(default_factory=list)     # per arm tick: each joint's mode and error bits
    wire: bytearray = field(default_factory=bytearray)
    joints: list = field(default_factory=list)       # each joint's snapshot at the end
    seen: dict = field(default_factory=dict)         # what the session says it went through
    wrapped: bool = False                            # some joint's count went across the 32-bit wrap
    handed_back: Optional[int] = None                # events the joints' tick handed to the facade


class LoseMotorFeedback:
    """While `lost`, MOTOR_FB's inputs keep what they were at each poll of the controller's HAL (its frames stopped)."""

    def __init__(self, hal) -> None:
        self.hal, self.poll, self.lost = hal, hal.poll, False
        hal.poll = self._poll

    def _poll(self, now: float):
        inputs = self.hal.inputs
        kept = inputs.counts, inputs.currents_a, inputs.fb_s
        result = self.poll(now)
        if self.lost:
            inputs.counts, inputs.currents_a, inputs.fb_s = kept
        return result


def run_world(session: Callable[[LockstepBench], dict], seed: int, compiled: bool) -> WorldRun:
    """`session` on a world whose joints' tick runs plain or `compiled`."""
    run = WorldRun()

    def tap(data: bytes) -> bytes:
        run.wire.extend(data)
        return data
    config = ControllerConfig(compiled_joints=compiled)
    bench = LockstepBench(seed=seed, to_host=tap, controller_config=config)
    arm = bench.controller.arm
    hal = arm.hal
    send = hal.send_motor_command

    def record(duty, enable, brake):
        run.commands.append((bench.clock.now(), tuple(map(hexed, duty)), tuple(enable), tuple(brake)))
        run.per_tick.append(tuple((int(arm.joints[n].mode), int(arm.joints[n].errors)) for n in JOINTS))
        run.wrapped |= any(c > COUNT_MODULUS // 2 for c in hal.inputs.counts) and any(
            c < COUNT_MODULUS // 2 for c in hal.inputs.counts)
        return send(duty, enable, brake)
    hal.send_motor_command = record
    try:
        assert bench.connect()
        assert bench.call(M["SetTelemetryRate"](30)).ok
        run.seen = session(bench)
        run.joints = [snapshot(arm.joints[n]) for n in JOINTS]
        run.handed_back = arm.bank.handed_back
    finally:
        bench.close()
    return run


def call_ok(bench: LockstepBench, msg) -> None:
    handle = bench.call(msg)
    assert handle.ok, handle.describe()


def motion_ends(bench: LockstepBench) -> dict[int, list[tuple[MotionOutcome, Reason]]]:
    ends: dict[int, list] = {}
    for event in bench.events:
        if event.spec.name == "MotionDone":
            ends.setdefault(event.axis, []).append((MotionOutcome(event.outcome), Reason(event.reason)))
    return ends


def fault_reasons(bench: LockstepBench) -> list[Reason]:
    return [Reason(e.reason) for e in bench.events if e.spec.name == "FaultReport"]


def back_to_enabled(bench: LockstepBench, *faults: str) -> None:
    """Clear the plant faults, let the controller see that (ANALOG_IN comes every 10 ms), reset, enable."""
    for name in faults:
        bench.world.plant.clear(name)
    bench.run_for(0.05)
    call_ok(bench, M["Reset"]())
    call_ok(bench, M["Enable"]())


def moving_session(bench: LockstepBench) -> dict:
    """Holding, jogging both ways (counts across the wrap), moves blended into jogs, a move superseded, a stop,
    gravity feed-forward with a payload then off, gains changed mid-motion, an e-stop mid-motion."""
    call_ok(bench, M["Enable"]())
    bench.run_for(0.3)                                               # holding
    call_ok(bench, M["ParamSet"]("payload_kg", 1.5))
    for axis, dps in ((AxisId.J1, 1.0), (AxisId.J2, -2.0), (AxisId.J3, 2.5), (AxisId.J4, -3.0), (AxisId.MOUNT, 1.5)):
        call_ok(bench, M["Jog"](int(axis), dps))
    bench.run_for(1.2)
    call_ok(bench, M["MoveBy"](int(AxisId.J2), 2.0, 0))            # from a jog: blends
    call_ok(bench, M["MoveBy"](int(AxisId.MOUNT), 3.0, 2.0))
    bench.run_for(0.4)
    call_ok(bench, M["MoveBy"](int(AxisId.MOUNT), -1.0, 0))        # supersedes the last
    call_ok(bench, M["ParamSet"]("j3_kv", 1.5 * bench.call(M["ParamGet"]("j3_kv")).reply.value))
    bench.run_for(1.0)
    call_ok(bench, M["ParamSet"]("gravity_m_s2", 0.0))
    call_ok(bench, M["Stop"]())
    bench.run_for(2.5)                                               # stopping, settling, holding
    call_ok(bench, M["MoveBy"](int(AxisId.J1), 3.0, 0))
    call_ok(bench, M["MoveBy"](int(AxisId.J4), -4.0, 0))
    bench.run_for(0.8)
    call_ok(bench, M["EStop"]())                                     # mid-motion
    bench.run_for(0.3)
    call_ok(bench, M["Reset"]())
    call_ok(bench, M["Enable"]())
    call_ok(bench, M["MoveBy"](int(AxisId.J2), -1.0, 0))
    bench.run_for(1.5)
    return {"ends": motion_ends(bench), "faults": fault_reasons(bench)}


def homing_session(bench: LockstepBench) -> dict:
    """Homing every axis, then again from on the switch; absolute moves; a jog into a soft limit and a move whose
    limit is pulled in under it."""
    call_ok(bench, M["Enable"]())
    started = bench.call(M["Home"](int(AxisId.ALL))).reply
    wanted = {int(a): getattr(started, f"{a.name.lower()}_motion_id") for a in AxisId if a is not AxisId.ALL}
    ended = lambda: {(e.axis, e.motion_id) for e in bench.events if e.spec.name == "MotionDone"}  # noqa: E731
    assert bench.wait_until(lambda: set(wanted.items()) <= ended(), 60.0), "homing did not end"
    call_ok(bench, M["Jog"](int(AxisId.J2), 3.0))                  # onto the switch (closed from 0 up)
    bench.run_for(1.0)
    call_ok(bench, M["Stop"]())
    bench.run_for(1.5)
    again = bench.call(M["Home"](int(AxisId.J2))).reply.motion_id   # leaves the switch first
    call_ok(bench, M["Move"](int(AxisId.J1), 2.0, 0))
    call_ok(bench, M["ParamSet"]("j4_max_deg", 1.0))
    call_ok(bench, M["Jog"](int(AxisId.J4), 3.0))                  # into its soft limit
    call_ok(bench, M["Move"](int(AxisId.J3), 6.0, 0))
    bench.run_for(1.5)
    call_ok(bench, M["ParamSet"]("j3_max_deg", 2.0))               # the move is beyond it now
    assert bench.wait_until(lambda: (int(AxisId.J2), again) in ended(), 60.0), "homing again did not end"
    bench.run_for(1.0)
    return {"ends": motion_ends(bench), "faults": fault_reasons(bench)}


def faults_session(bench: LockstepBench) -> dict:
    """Each joint fault of the plant in the middle of a move, cleared, reset and enabled again after each."""
    sup = bench.controller.supervisor
    call_ok(bench, M["Enable"]())
    for fault, axis in (("stuck_brake", AxisId.J1), ("jam", AxisId.J3), ("open_circuit", AxisId.J2),
                        ("encoder_glitch", AxisId.J1), ("encoder_dropout", AxisId.MOUNT), ("supply_sag", None)):
        moving = AxisId.J4 if axis is None else axis
        call_ok(bench, M["MoveBy"](int(moving), 20.0, 0))
        bench.run_for(0.8)
        name = fault if axis is None else f"{fault}:{axis.name.lower()}"
        bench.world.plant.inject(name)
        assert bench.wait_until(lambda: sup.state is ControllerState.FAULT, 3.0), name
        bench.run_for(0.2)
        back_to_enabled(bench, name)
    call_ok(bench, M["MoveBy"](int(AxisId.J3), 2.0, 0))
    bench.run_for(0.5)
    return {"ends": motion_ends(bench), "faults": fault_reasons(bench)}


def stale_session(bench: LockstepBench) -> dict:
    """MOTOR_FB stops while moving: the counts go stale; then, with a longer limit for them, the currents."""
    sup = bench.controller.supervisor
    feedback = LoseMotorFeedback(bench.controller.hal)
    call_ok(bench, M["Enable"]())
    for encoder_s, current_s in ((0.02, 0.5), (0.5, 0.03)):
        call_ok(bench, M["ParamSet"]("encoder_stale_s", encoder_s))
        call_ok(bench, M["ParamSet"]("current_stale_s", current_s))
        call_ok(bench, M["MoveBy"](int(AxisId.J2), 5.0, 0))
        bench.run_for(0.6)
        feedback.lost = True
        assert bench.wait_until(lambda: sup.state is ControllerState.FAULT, 1.0)
        bench.run_for(0.1)
        feedback.lost = False
        bench.run_for(0.1)
        back_to_enabled(bench)
    bench.run_for(0.3)
    return {"ends": motion_ends(bench), "faults": fault_reasons(bench)}


def trajectory_session(bench: LockstepBench) -> dict:
    """j1..j4 homed, then along a trajectory (its ticks handed to the facade: the kernel evaluates no cubic), stopped
    midway, and again to its end; the mount moving meanwhile, in the kernel."""
    call_ok(bench, M["Enable"]())
    started = bench.call(M["Home"](int(AxisId.ALL))).reply
    wanted = {int(a): getattr(started, f"{a.name.lower()}_motion_id") for a in AxisId if a is not AxisId.ALL}
    ended = lambda: {(e.axis, e.motion_id) for e in bench.events if e.spec.name == "MotionDone"}  # noqa: E731
    assert bench.wait_until(lambda: set(wanted.items()) <= ended(), 60.0), "homing did not end"
    arm = bench.controller.arm
    for stop_after_s in (1.5, None):
        start = [math.degrees(arm.channels[int(a)].pos_sp_rad) for a in TRAJECTORY_JOINTS]
        amplitude = (2, -2, 3, -3, 0)        # the mount's part holds still, until the MoveBy below takes it over
        knots = [Knot(t, tuple(q + a * (3 * (t / 4) ** 2 - 2 * (t / 4) ** 3) for q, a in zip(start, amplitude)),
                      tuple(a * 6 * (t / 4) * (1 - t / 4) / 4 for a in amplitude)) for t in (0.0, 1.0, 2.5, 4.0)]
        ids = send_trajectory(bench, knots)
        call_ok(bench, M["MoveBy"](int(AxisId.MOUNT), 1.0, 0))
        if stop_after_s is not None:
            bench.run_for(stop_after_s)
            call_ok(bench, M["Stop"]())
        assert bench.wait_until(lambda: {(int(a), i) for a, i in zip(TRAJECTORY_JOINTS, ids)} <= ended(), 10.0)
        bench.run_for(0.5)
    return {"ends": motion_ends(bench), "faults": fault_reasons(bench)}


@dataclass(frozen=True)
class Session:
    """A scripted session and what it must go through: axis modes, error bits, motion outcomes and fault reports
    (at least these), counts across the wrap, and the largest share of joint-ticks handed to the facade."""

    script: Callable[[LockstepBench], dict]
    modes: frozenset
    bits: AxisError = AxisError.NONE
    outcomes: frozenset = frozenset()
    reasons: frozenset = frozenset()
    wrapped: bool = False
    handed_back: float = 0.001


_M, _O = AxisMode, MotionOutcome
SESSIONS = {
    "moving": Session(moving_session, frozenset({_M.IDLE, _M.HOLDING, _M.MOVING, _M.JOGGING}),
                      outcomes=frozenset({_O.DONE, _O.STOPPED, _O.SUPERSEDED, _O.DISABLED}), wrapped=True),
    # a move beyond its (pulled in) soft limit stops again at every tick while it still moves outward
    "homing": Session(homing_session, frozenset({_M.HOMING, _M.HOLDING, _M.MOVING, _M.JOGGING}), AxisError.SOFT_LIMIT,
                      frozenset({_O.DONE, _O.SOFT_LIMIT}), handed_back=0.02),
    "faults": Session(faults_session, frozenset({_M.FAULT, _M.MOVING, _M.HOLDING}),
                      AxisError.STALL | AxisError.OPEN_CIRCUIT | AxisError.ENCODER_GLITCH | AxisError.CURRENT_LIMITED,
                      frozenset({_O.FAULT}), handed_back=0.01),
    # every tick of a stale encoder is a fault (already latched or not)
    "stale": Session(stale_session, frozenset({_M.FAULT, _M.MOVING}), AxisError.ENCODER_STALE | AxisError.CURRENT_STALE,
                     reasons=frozenset({Reason.ENCODER_STALE, Reason.CURRENT_STALE}), handed_back=0.05),
    # a trajectory's every tick is handed to the facade (4 joints of 5, about half the session)
    "trajectory": Session(trajectory_session, frozenset({_M.HOMING, _M.HOLDING, _M.MOVING}),
                          outcomes=frozenset({_O.DONE, _O.STOPPED}), handed_back=0.5),
}


def assert_same(run: WorldRun, reference: WorldRun) -> None:
    assert len(run.commands) == len(reference.commands) > 2000
    first = next((k for k, (a, b) in enumerate(zip(run.commands, reference.commands)) if a != b), None)
    assert first is None, f"MOTOR_CMD {first}: {run.commands[first]}, reference {reference.commands[first]}"
    assert run.per_tick == reference.per_tick
    assert run.wire == reference.wire
    assert run.joints == reference.joints
    assert run.seen == reference.seen


def assert_went_through(session: Session, run: WorldRun) -> None:
    modes = {AxisMode(mode) for tick in run.per_tick for mode, _ in tick}
    bits = AxisError.NONE
    for tick in run.per_tick:
        for _, err in tick:
            bits |= err
    assert session.modes <= modes
    assert bits & session.bits == session.bits, bits
    assert session.outcomes <= {outcome for ends in run.seen["ends"].values() for outcome, _ in ends}
    assert session.reasons <= set(run.seen["faults"])
    assert run.wrapped or not session.wrapped
    assert 0 < run.handed_back < session.handed_back * len(JOINTS) * len(run.per_tick)


@pytest.mark.parametrize("name", [pytest.param(name, marks=pytest.mark.long) if name in ("moving", "homing", "trajectory")
                                  else name
                                  for name in SESSIONS])
def test_a_session_goes_through_its_cases_and_compiled_is_the_same_to_the_bit(name):
    """The session goes through its cases, handing only the rare ticks to the facade; compiled (if numba is
    installed): the same MOTOR_CMDs, modes and error bits at every tick, bytes to the host, joints' end states and
    events handed over as plain."""
    session = SESSIONS[name]
    seed = 20 + list(SESSIONS).index(name)
    plain = run_world(session.script, seed, compiled=False)
    assert_went_through(session, plain)
    if HAVE_NUMBA:
        compiled = run_world(session.script, seed, compiled=True)
        assert_same(compiled, plain)
        assert compiled.handed_back == plain.handed_back


# ---------------------------------------------------------------- one joint alone, compiled beside plain
class Twin:
    """One joint alone (`single_axis`) on the test plant of tests/test_axis_pipeline.py, given inputs the arm loop's
    way (a count and a current from one MOTOR_FB arriving at `fb_s`); `compiled`: numba's, beside a plain one on
    its own copy of the plant, the two compared after every tick."""

    def __init__(self, joint: Joint, compiled: bool = False, **overrides) -> None:
        self.overrides = {"vel_limit_rad_s": 0.5, "acc_limit_rad_s2": 2.0, **overrides}
        config = make_config(joint, **self.overrides)
        self.plants = (replace(joint), replace(joint))
        self.tau = [0.0]                              # the gravity torque, refreshed before each tick (as the arm)
        gravity = (lambda pos: self.tau[0]) if joint.gravity_m_s2 else None
        self.faults: tuple[list, list] = ([], [])
        self.axes = tuple(single_axis(config, gravity_nm=gravity, compiled=on,
                                      on_fault=lambda bits, now, k=k: self.faults[k].append((bits, now)))
                          for k, on in enumerate((False, True) if compiled else (False,)))
        self.bank = self.axes[-1]._bank
        self.now = 0.0
        self.fb_s = 0.0
        self.ticks = 0

    def command(self, name: str, *args):
        """The same command to both axes; the same answer from both, and the same state after it."""
        answers = [getattr(axis, name)(*args) for axis in self.axes]
        assert answers[0] == answers[-1], name
        assert snapshot(self.axes[0]) == snapshot(self.axes[-1]), name
        return answers[0]

    def reconfigure(self, **changes) -> None:
        self.command("reconfigure", make_config(self.plants[0], **{**self.overrides, **changes}))

    def start(self, name: str, *args) -> None:
        """A command that must be accepted."""
        refusal, detail = self.command(name, *args)
        assert refusal is Refusal.OK, detail

    def run(self, duration_s: float, *, fresh: bool = True, count_jump: int = 0, current: Optional[float] = None,
            until: Optional[Callable[[Axis], bool]] = None) -> None:
        """Tick both for `duration_s`: `fresh` False, MOTOR_FB stops (its last values stay); `count_jump` added to
        the counts; `current` instead of the plant's."""
        for _ in range(round(duration_s / DT_S)):
            if fresh:
                self.fb_s = self.now
            duties = []
            for axis, plant in zip(self.axes, self.plants):
                count = (plant.count + count_jump) % COUNT_MODULUS
                i_a = plant.i_a if current is None else current
                self.tau[0] = plant.gravity_nm(axis.pos_rad)
                axis._bank.duties[0] = math.nan
                duty = axis.update(self.now, count, self.fb_s, i_a, self.fb_s, plant.home_switch)
                assert duty == duty, f"tick {self.ticks}: no duty"
                duties.append(duty.hex())
                plant.step(duty, axis.brake)
            assert duties[0] == duties[-1], f"tick {self.ticks}"
            assert snapshot(self.axes[0]) == snapshot(self.axes[-1]), f"tick {self.ticks}"
            assert self.faults[0] == self.faults[len(self.axes) - 1]
            self.now += DT_S
            self.ticks += 1
            if until is not None and until(self.axes[0]):
                return

    @property
    def fused_share(self) -> float:
        return 1.0 - self.bank.handed_back / max(self.ticks, 1)


@pytest.mark.parametrize("compiled", COMPILED)
def test_holding_moving_jogging_and_soft_limits_with_gravity_are_the_same(compiled):
    twin = Twin(Joint(gravity_m_s2=9.81), compiled)
    twin.run(0.05)                                                   # idle
    twin.command("set_zero", 0.0)
    twin.start("enable", twin.now)
    twin.run(0.2)                                                    # holding against gravity
    twin.start("move_to", 0.3, twin.now)
    twin.run(3.0, until=lambda axis: axis.mode is AxisMode.HOLDING)  # the profile, settling, the end
    twin.start("move_by", -0.1, twin.now, 0.05)
    twin.run(0.5)
    twin.start("jog", 0.2, twin.now)                               # from a move: blends
    twin.run(4.0, until=lambda axis: axis.mode is AxisMode.HOLDING)  # into the soft limit at 1 rad
    assert twin.axes[0].outcome is MotionOutcome.SOFT_LIMIT
    twin.start("jog", -0.3, twin.now)
    twin.run(0.5)
    twin.command("stop", twin.now)
    twin.run(1.0)
    twin.start("move_to", 0.9, twin.now)
    twin.run(0.5)
    twin.reconfigure(soft_max_rad=0.5)                               # the move is beyond it now
    twin.run(1.0)
    twin.command("safe")                                             # mid-motion
    twin.run(0.1)
    twin.start("enable", twin.now)
    twin.run(0.3)
    assert twin.fused_share > 0.9


@pytest.mark.parametrize("start_rad", [0.2, -0.1])
@pytest.mark.parametrize("compiled", COMPILED)
def test_homing_from_off_and_from_on_the_switch_is_the_same(start_rad, compiled):
    twin = Twin(Joint(angle_rad=start_rad, switch_below_rad=0.0), compiled)
    twin.start("enable", twin.now)
    twin.start("home", twin.now)
    twin.run(30.0, until=lambda axis: axis.mode is AxisMode.HOLDING)
    assert twin.axes[0].homed and twin.axes[0].outcome is MotionOutcome.DONE
    assert twin.fused_share > 0.99


@pytest.mark.parametrize("compiled", COMPILED)
def test_homing_that_finds_no_switch_fails_the_same(compiled):
    twin = Twin(Joint(), compiled, home_max_travel_rad=0.05)
    twin.start("enable", twin.now)
    twin.start("home", twin.now)
    twin.run(10.0, until=lambda axis: axis.mode is AxisMode.FAULT)
    assert twin.axes[0].faults == AxisError.HOMING_FAILED


@pytest.mark.parametrize("case", ["stall", "following_error", "over_current", "open_circuit", "current_nan",
                                  "current_stale", "encoder_stale", "encoder_glitch"])
@pytest.mark.parametrize("compiled", COMPILED)
def test_each_fault_is_raised_on_the_same_tick(case, compiled):
    overrides = {"stall": {"following_error_rad": 10.0}, "following_error": {"stall_time_s": 10.0},
                 "over_current": {"i_trip_a": 1.0, "i_trip_s": 0.02}}.get(case, {})
    if case == "current_stale":      # counts stay fresh longer than currents
        overrides = {"estimator": replace(make_config(Joint()).estimator, stale_ticks=50)}
    twin = Twin(Joint(count_offset=COUNT_MODULUS - 50), compiled, **overrides)   # moving down across the wrap
    twin.start("enable", twin.now)
    twin.start("move_by", -0.5, twin.now)
    twin.run(0.3)
    if case in ("stall", "following_error", "over_current"):
        for plant in twin.plants:
            plant.jammed = True
    inputs = {"open_circuit": {"current": 0.0}, "current_nan": {"current": math.nan},
              "current_stale": {"fresh": False}, "encoder_stale": {"fresh": False},
              "encoder_glitch": {"count_jump": 20000}}.get(case, {})
    twin.run(3.0, until=lambda axis: axis.mode is AxisMode.FAULT, **inputs)
    expected = {"stall": AxisError.STALL, "following_error": AxisError.FOLLOWING_ERROR,
                "over_current": AxisError.OVER_CURRENT, "open_circuit": AxisError.OPEN_CIRCUIT,
                "current_nan": AxisError.CURRENT_STALE, "current_stale": AxisError.CURRENT_STALE,
                "encoder_stale": AxisError.ENCODER_STALE, "encoder_glitch": AxisError.ENCODER_GLITCH}[case]
    assert twin.axes[0].faults & expected, twin.axes[0].faults
    twin.run(0.1, **inputs)                                          # in FAULT
    twin.command("reset_errors", twin.now)
    twin.start("enable", twin.now)
    for plant in twin.plants:
        plant.jammed = False
    twin.run(0.5)                                                    # driving again (after a glitch: resynced)
    assert twin.axes[0].mode is not AxisMode.FAULT


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("compiled", COMPILED)
def test_random_commands_and_input_trouble_are_the_same(seed, compiled):
    """Commands at random times; now and then feedback that stops for a few ticks, counts that jump, a current that
    is zero, not a number or too high, a jam; after a fault, reset and enable again."""
    rng = random.Random(seed)
    twin = Twin(Joint(gravity_m_s2=9.81 * rng.random(), count_offset=rng.randrange(COUNT_MODULUS)), compiled,
                stall_time_s=0.2 + rng.random(), i_trip_a=3.0 + 3 * rng.random(), following_error_rad=0.2)
    twin.command("set_zero", rng.uniform(-0.5, 0.5))
    modes = set()
    for _ in range(60):
        now, mode = twin.now, twin.axes[0].mode
        modes.add(mode)
        if mode is AxisMode.FAULT:
            twin.command("reset_errors", now)
        if mode in (AxisMode.FAULT, AxisMode.IDLE):
            twin.command("enable", now)
        else:
            choice = rng.random()
            if choice < 0.3:
                twin.command("move_to", rng.uniform(-1.2, 1.2), now, rng.choice([None, 0.05, 0.3]))
            elif choice < 0.45:
                twin.command("move_by", rng.uniform(-0.3, 0.3), now)
            elif choice < 0.65:
                twin.command("jog", rng.uniform(-0.4, 0.4), now)
            elif choice < 0.75:
                twin.command("stop", now)
            elif choice < 0.8:
                twin.command("home", now)
            elif choice < 0.85:
                twin.command("safe")
        jammed = rng.random() < 0.1
        for plant in twin.plants:
            plant.jammed = jammed
        trouble = rng.choice([{}] * 6 + [{"fresh": False}, {"count_jump": rng.randrange(-30, 30)},
                                         {"current": rng.choice([0.0, math.nan, 20.0])}])
        twin.run(rng.uniform(0.001, 0.008) if trouble else rng.uniform(0.05, 0.6), **trouble)
    assert {AxisMode.MOVING, AxisMode.JOGGING, AxisMode.HOLDING} <= modes
    assert twin.fused_share > 0.9


def test_a_joint_handed_over_waits_for_its_facade_and_the_joints_before_it_are_done():
    bank = JointBank(2, 2)
    axes = [BankedAxis(bank, k, k, make_config(Joint())) for k in range(2)]
    for axis in axes:
        axis.enable(0.0)
    counts, currents, home = [0, 0], [0.0, 0.0], [False, False]
    bank.take_inputs(0.0, 0.0, counts, currents, home, [])
    bank.run(0, 2, 0.0)
    out = [math.nan, math.nan]
    counts[1] = 100_000                                              # joint 1's count jumps: a glitch
    stopped = jt.joints_tick(0, 2, 0.001, 0.001, 0.001, counts, currents, home, [], out, bank.state, bank.int_state,
                             bank.config, bank.int_config, bank.profile)
    assert stopped == 1
    assert bank.int_state[1][jt.EVENT] == jt.EV_FAULT and bank.int_state[1][jt.RAISED] == jt.ENCODER_GLITCH
    assert bank.int_state[0][jt.EVENT] == jt.EV_NONE
    assert math.isnan(out[1]) and not math.isnan(out[0])
    assert axes[1].mode is AxisMode.HOLDING and not axes[1].faults    # the facade has not acted yet
    bank.take_inputs(0.001, 0.001, counts, currents, home, [])
    bank.run(1, 2, 0.001)                                            # it acts: the fault, duty 0
    assert axes[1].mode is AxisMode.FAULT and axes[1].faults == AxisError.ENCODER_GLITCH
    assert bank.duties[1] == 0.0 and bank.int_state[1][jt.EVENT] == jt.EV_NONE
    assert axes[1].estimator.glitches == 1 and axes[0].mode is AxisMode.HOLDING


# ---------------------------------------------------------------- the switches
def test_the_compiled_joints_are_asked_for_by_the_environment_and_need_numba(monkeypatch):
    monkeypatch.delenv(ENVIRONMENT_SWITCH, raising=False)
    assert not ControllerConfig().compiled_joints
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "1")
    assert ControllerConfig().compiled_joints
    monkeypatch.setitem(sys.modules, "numba", None)              # as if it were not installed
    compiled_joints_tick.cache_clear()
    compiled_arm_joints_tick.cache_clear()
    try:
        with pytest.raises(MissingExtra, match=r"needs the compiled extra .*: pip install 'aspod\[compiled\]'"):
            JointBank(1, 1, compiled=True)
        JointBank(1, 1)                                          # the plain function needs nothing
    finally:
        compiled_joints_tick.cache_clear()
        compiled_arm_joints_tick.cache_clear()


def test_switched_sets_the_switch_for_what_is_built_inside_and_puts_it_back(monkeypatch):
    monkeypatch.setenv(ENVIRONMENT_SWITCH, "0")
    with switched(True):
        assert ControllerConfig().compiled_joints
    assert not ControllerConfig().compiled_joints and os.environ[ENVIRONMENT_SWITCH] == "0"
    monkeypatch.delenv(ENVIRONMENT_SWITCH)
    with switched(False):
        assert not ControllerConfig().compiled_joints
    with switched(None):                                         # None: the environment as it is
        assert ENVIRONMENT_SWITCH not in os.environ
    assert ENVIRONMENT_SWITCH not in os.environ
