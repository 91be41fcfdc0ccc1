"""Trajectories: knots uploaded (TrajClear, TrajPoint), run on j1..j4 and the mount at once (TrajRun), followed by the arm
closed around the plant, on the simulated clock.

The setpoint is checked against an independent cubic Hermite spline (scipy's `CubicHermiteSpline`), the
plant's true angles against the setpoint; every refusal against its reason and an unchanged controller.
"""
from __future__ import annotations

import math
import random

import numpy as np
import pytest
from scipy.interpolate import CubicHermiteSpline

from firmware_py.hermite import HermiteProfile
from firmware_py.trajectory import REST_TOLERANCE_DPS, START_TOLERANCE_DEG, TRAJECTORY_KNOTS
from host_tools.client.bench import BenchClient
from host_tools.client.trajectory import Knot, TrajectoryRefused, point_message, send_trajectory
from host_tools.sessions.impairment import Impairment
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M, TRAJECTORY_JOINTS
from protocol.reasons import Reason
from protocol.states import Axis, ControllerState, MotionOutcome

JOINTS = TRAJECTORY_JOINTS                     # j1..j4 and the mount
N = len(JOINTS)
# How far the plant's true angle may be from the setpoint while following: J3 lags most (a Move of J3 at the same
# speed lags 0.15 deg while it accelerates); the others stay within 0.05 deg.
FOLLOW_TOLERANCE_DEG = {Axis.J1: 0.05, Axis.J2: 0.05, Axis.J3: 0.25, Axis.J4: 0.05, Axis.MOUNT: 0.05}
END_TOLERANCE_DEG = 0.02          # where a move ends, as tests/test_arm_control.py holds a Move to
AMPLITUDE_DEG = (10.0, -8.0, 12.0, -12.0, -6.0)


# ---- helpers -----------------------------------------------------------------------------------------------
def homed_bench(**kw) -> LockstepBench:
    """A world with j1..j4 (and the rest) homed and holding."""
    bench = LockstepBench(seed=3, **kw)
    assert bench.connect()
    assert bench.call(M["Enable"]()).ok
    reply = bench.call(M["Home"](int(Axis.ALL))).reply
    started = {int(a): getattr(reply, f"{a.name.lower()}_motion_id") for a in Axis if a is not Axis.ALL}
    assert bench.wait_until(lambda: all(done(bench, a, i) for a, i in started.items()), 60.0)
    return bench


def done(bench: LockstepBench, axis: int, motion_id: int):
    return next((e for e in bench.events if e.spec.name == "MotionDone" and e.axis == axis
                 and e.motion_id == motion_id), None)


def holding_deg(bench: LockstepBench) -> list[float]:
    return [math.degrees(bench.controller.arm.channels[int(a)].pos_sp_rad) for a in JOINTS]


def smooth_knots(start_deg, amplitude_deg=AMPLITUDE_DEG, duration_s: float = 8.0, count: int = 20) -> list[Knot]:
    """A planned-looking motion: each joint along a quintic rest-to-rest blend, sampled at `count` knots."""
    knots = []
    for i in range(count):
        t = duration_s * i / (count - 1)
        s = t / duration_s
        blend, rate = 10 * s**3 - 15 * s**4 + 6 * s**5, (30 * s**2 - 60 * s**3 + 30 * s**4) / duration_s
        knots.append(Knot(t, tuple(q + a * blend for q, a in zip(start_deg, amplitude_deg)),
                          tuple(a * rate for a in amplitude_deg)))
    return knots


def spline(knots: list[Knot], j: int) -> CubicHermiteSpline:
    return CubicHermiteSpline([k.t_s for k in knots], [k.q_deg[j] for k in knots], [k.qd_deg_s[j] for k in knots])


def true_deg(bench: LockstepBench, axis: Axis) -> float:
    return math.degrees(bench.world.plant.arm.pos_rad[int(axis)])


def controller_view(bench: LockstepBench) -> tuple:
    """What a refusal must leave alone: the buffer's knots and each joint's mode, motion, setpoint and target."""
    arm = bench.controller.arm
    return (list(bench.controller.arm_commands.trajectory.knots),
            [(c.mode, c.motion_id, c.outcome, c.pos_sp_rad, c.target_rad) for c in arm.joints.values()])


def upload(bench: LockstepBench, knots: list[Knot]) -> None:
    assert bench.call(M["TrajClear"]()).ok
    for index, knot in enumerate(knots):
        handle = bench.call(point_message(index, knot))
        assert handle.ok, handle.describe()


# ---- the curve ---------------------------------------------------------------------------------------------
def test_the_hermite_profile_is_the_cubic_hermite_spline_and_knows_its_bounds():
    rng = random.Random(5)
    times = [0.0]
    for _ in range(9):
        times.append(times[-1] + rng.uniform(0.1, 2.0))
    pos = [rng.uniform(-1, 1) for _ in times]
    vel = [rng.uniform(-0.5, 0.5) for _ in times]
    profile, reference = HermiteProfile(times, pos, vel), CubicHermiteSpline(times, pos, vel)
    t = np.linspace(0.0, times[-1], 20001)
    sampled = np.array([profile.sample(x) for x in t])
    for column, derivative in enumerate((reference(t), reference(t, 1), reference(t, 2))):
        inside = t < times[-1]            # at the end the profile gives the last knot exactly, at rest in acc
        assert np.allclose(sampled[inside, column], derivative[inside], rtol=0, atol=1e-9), column
    assert profile.sample(times[-1]) == (pos[-1], vel[-1], 0.0) and profile.sample(-1.0)[:2] == (pos[0], vel[0])
    lowest, highest, top_speed = profile.bounds()
    dense, dense_speed = reference(t), np.abs(reference(t, 1))     # a fine grid: as extreme, or nearly
    assert dense.min() - 1e-6 <= lowest <= dense.min() and dense.max() <= highest <= dense.max() + 1e-6
    assert dense_speed.max() <= top_speed <= dense_speed.max() * (1 + 1e-5)
    assert lowest < min(pos) and highest > max(pos)          # this curve does overshoot its knots
    for bad in (([0.0], [0.0], [0.0]), ([0.0, 1.0], [0.0], [0.0, 0.0]), ([0.5, 1.0], [0, 0], [0, 0]),
                ([0.0, 1.0, 1.0], [0, 0, 0], [0, 0, 0]), ([0.0, 1.0], [0.0, math.nan], [0, 0])):
        with pytest.raises(ValueError):
            HermiteProfile(*bad)


def test_the_host_refuses_knots_that_cannot_be_a_trajectory_before_sending_anything():
    class NoCalls:
        def call(self, msg, timeout_s=30.0):
            raise AssertionError("nothing may be sent")
    with pytest.raises(ValueError, match=f"{N} positions"):
        Knot(0.0, (0.0, 0.0, 0.0), (0.0,) * N)
    with pytest.raises(ValueError, match="finite"):
        Knot(0.0, (0.0, math.inf) + (0.0,) * (N - 2), (0.0,) * N)
    still = Knot(0.0, (0.0,) * N, (0.0,) * N)
    for knots, words in (([still], "at least 2"), ([still, still], "increase strictly"),
                         ([Knot(1.0, (0.0,) * N, (0.0,) * N), Knot(2.0, (0.0,) * N, (0.0,) * N)], "t = 0"),
                         ([still, Knot(1.0, (400.0,) + (0.0,) * (N - 1), (0.0,) * N)], "knot 1: j1_pos=400")):
        with pytest.raises(ValueError, match=words):
            send_trajectory(NoCalls(), knots)


# ---- following -------------------------------------------------------------------------------------------------
def test_a_planned_trajectory_is_followed_and_each_joint_reports_done():
    bench = homed_bench()
    try:
        arm = bench.controller.arm
        start = holding_deg(bench)
        start[1] += 0.5 * START_TOLERANCE_DEG          # not quite where j2 holds, but within the tolerance
        knots = smooth_knots(start)
        ids = send_trajectory(BenchClient(bench), knots)
        assert len(ids) == N and all(ids)
        assert len({arm.channels[int(a)]._profile_t0 for a in JOINTS}) == 1          # one tick starts them all
        assert arm.channels[int(Axis.GRIPPER)].outcome is not MotionOutcome.RUNNING       # not part of it
        started_s, references = bench.clock.now(), [spline(knots, j) for j in range(N)]
        # while it runs, the knots cannot change
        assert bench.call(M["TrajClear"]()).reason is Reason.BUSY
        assert bench.call(point_message(len(knots), Knot(9.0, (0.0,) * N, (0.0,) * N))).reason is Reason.BUSY
        worst = dict.fromkeys(JOINTS, 0.0)
        while bench.clock.now() - started_s < knots[-1].t_s:
            bench.run_for(0.01)
            t = bench.controller.control_now() - arm.channels[0]._profile_t0
            for j, axis in enumerate(JOINTS):
                setpoint = math.degrees(arm.channels[int(axis)].pos_sp_rad)
                if t < knots[-1].t_s - 0.002:
                    # the setpoint of the last tick (at most 1 ms ago) is the spline's
                    assert abs(setpoint - references[j](t)) < 0.0035 * max(abs(k.qd_deg_s[j]) for k in knots) + 1e-6
                worst[axis] = max(worst[axis], abs(true_deg(bench, axis) - float(references[j](min(t, knots[-1].t_s)))))
        # j2 starts off where it held (within the start tolerance): its setpoint steps by that much at first
        offset = dict.fromkeys(JOINTS, 0.0) | {Axis.J2: 0.5 * START_TOLERANCE_DEG}
        assert all(worst[a] < FOLLOW_TOLERANCE_DEG[a] + offset[a] for a in JOINTS), worst
        assert worst[Axis.J1] > 0.0
        assert bench.wait_until(lambda: all(done(bench, int(a), i) for a, i in zip(JOINTS, ids)), 5.0)
        for j, (axis, motion_id) in enumerate(zip(JOINTS, ids)):
            event = done(bench, int(axis), motion_id)
            assert (event.outcome, event.reason) == (MotionOutcome.DONE, Reason.OK)
            assert true_deg(bench, axis) == pytest.approx(knots[-1].q_deg[j], abs=END_TOLERANCE_DEG)
            assert event.position == pytest.approx(knots[-1].q_deg[j], abs=END_TOLERANCE_DEG)
        assert not arm.trajectory_running() and bench.call(M["TrajClear"]()).ok
    finally:
        bench.close()


def test_stop_and_estop_end_a_trajectory_midway():
    bench = homed_bench()
    try:
        client = BenchClient(bench)
        knots = smooth_knots(holding_deg(bench))
        ids = send_trajectory(client, knots)
        bench.run_for(3.0)
        assert bench.call(M["Stop"]()).ok
        assert bench.wait_until(lambda: all(done(bench, int(a), i) for a, i in zip(JOINTS, ids)), 5.0)
        assert {done(bench, int(a), i).outcome for a, i in zip(JOINTS, ids)} == {MotionOutcome.STOPPED}
        bench.run_for(1.0)
        for j, axis in enumerate(JOINTS):       # stopped about halfway: far from both ends
            moved = true_deg(bench, axis) - knots[0].q_deg[j]
            assert 0.1 < moved / AMPLITUDE_DEG[j] < 0.9, (axis, moved)
        # from where they stopped, another; an e-stop ends it too, and nothing moves until reset
        ids = send_trajectory(client, smooth_knots(holding_deg(bench), (-4.0, 4.0, -4.0, 4.0, 4.0), 4.0))
        bench.run_for(1.5)
        assert bench.call(M["EStop"]()).ok
        assert bench.wait_until(lambda: all(done(bench, int(a), i) for a, i in zip(JOINTS, ids)), 1.0)
        assert {(done(bench, int(a), i).outcome, done(bench, int(a), i).reason) for a, i in zip(JOINTS, ids)} == {
            (MotionOutcome.DISABLED, Reason.CANCELLED)}
        bench.run_for(0.5)                      # the brakes take hold (as after an e-stop in tests/test_arm_control.py)
        held = bench.world.plant.arm.pos_rad.copy()
        bench.run_for(3.0)
        assert np.allclose(bench.world.plant.arm.pos_rad, held, atol=1e-6)
        with pytest.raises(TrajectoryRefused) as refused:
            send_trajectory(client, smooth_knots(holding_deg(bench)))
        assert refused.value.reason is Reason.ESTOP and refused.value.command == "TrajRun"
    finally:
        bench.close()


def test_a_fault_ends_a_trajectory():
    bench = homed_bench()
    try:
        ids = send_trajectory(BenchClient(bench), smooth_knots(holding_deg(bench)))
        bench.run_for(2.0)
        bench.world.plant.inject("jam:j3")
        assert bench.wait_until(lambda: all(done(bench, int(a), i) for a, i in zip(JOINTS, ids)), 3.0)
        assert bench.controller.supervisor.state is ControllerState.FAULT
        ends = {a: done(bench, int(a), i) for a, i in zip(JOINTS, ids)}
        assert (ends[Axis.J3].outcome, ends[Axis.J3].reason) == (MotionOutcome.FAULT, Reason.STALL)
        # the others are cancelled by the safe state the fault took, as any motion is
        assert {(e.outcome, e.reason) for a, e in ends.items() if a is not Axis.J3} == {
            (MotionOutcome.DISABLED, Reason.CANCELLED)}
    finally:
        bench.close()


# ---- refusals: each with its reason, nothing changed ----------------------------------------------------------
@pytest.fixture(scope="module")
def holding():
    bench = homed_bench()
    yield bench
    bench.close()


def refused(bench: LockstepBench, msg, reason: Reason):
    before = controller_view(bench)
    handle = bench.call(msg)
    assert handle.reason is reason, handle.describe()
    assert controller_view(bench) == before
    return handle.reply


def still(t: float, q, qd=(0.0,) * N) -> Knot:
    return Knot(t, tuple(q), tuple(qd))


def test_knots_out_of_order_or_out_of_range_are_refused_and_change_nothing(holding):
    q = holding_deg(holding)
    upload(holding, [still(0.0, q), still(1.0, q)])
    assert refused(holding, point_message(3, still(2.0, q)), Reason.TRAJ_ORDER).knots == 2     # not the next
    assert refused(holding, point_message(1, still(2.0, q)), Reason.TRAJ_ORDER).knots == 2     # again
    assert refused(holding, point_message(2, still(1.0, q)), Reason.TRAJ_ORDER).t_last == 1.0  # not later
    spec = M["TrajPoint"].spec
    for name, value in (("j3_vel", 400.0), ("j1_pos", math.nan), ("t", -1.0)):
        values = [value if f.name == name else v for f, v in zip(spec.fields, point_message(2, still(2.0, q)))]
        assert refused_raw(holding, spec._struct.pack(*values)) is Reason.OUT_OF_RANGE, name
    assert holding.call(M["TrajClear"]()).reply.knots == 0
    assert refused(holding, point_message(0, still(0.5, q)), Reason.TRAJ_ORDER).knots == 0     # first not at 0


def refused_raw(bench: LockstepBench, payload: bytes) -> Reason:
    """A TrajPoint with values the codec refuses to send, sent as bytes: the controller's answer; nothing changed."""
    before = controller_view(bench)
    handle = bench.host.submit_payload(M["TrajPoint"].spec, payload, bench.clock.now())
    bench.wait_until(lambda: handle.done, 5.0)
    assert controller_view(bench) == before
    return handle.reason


def test_a_full_buffer_refuses_the_next_knot(holding):
    q = holding_deg(holding)
    upload(holding, [still(0.01 * i, q) for i in range(TRAJECTORY_KNOTS)])
    reply = refused(holding, point_message(TRAJECTORY_KNOTS, still(99.0, q)), Reason.TRAJ_FULL)
    assert (reply.knots, reply.capacity) == (TRAJECTORY_KNOTS, TRAJECTORY_KNOTS)


def run_refused(bench: LockstepBench, knots: list[Knot], reason: Reason, count: int | None = None):
    upload(bench, knots)
    return refused(bench, M["TrajRun"](len(knots) if count is None else count), reason)


def test_a_run_with_the_wrong_count_or_ends_is_refused_and_nothing_moves(holding):
    q = holding_deg(holding)
    knots = smooth_knots(q)
    run_refused(holding, knots, Reason.TRAJ_COUNT, count=len(knots) - 1)       # one lost
    run_refused(holding, knots, Reason.TRAJ_COUNT, count=len(knots) + 1)       # one twice
    run_refused(holding, knots[:1], Reason.TRAJ_COUNT)
    shifted = [Knot(k.t_s, (k.q_deg[0], k.q_deg[1] + 2 * START_TOLERANCE_DEG, *k.q_deg[2:]), k.qd_deg_s)
               for k in knots]
    assert run_refused(holding, shifted, Reason.TRAJ_ENDPOINTS).axis == Axis.J2
    moving_start = [still(0.0, q, (0.0, 0.0, 0.0, 3 * REST_TOLERANCE_DPS, 0.0)), still(2.0, q)]
    assert run_refused(holding, moving_start, Reason.TRAJ_ENDPOINTS).axis == Axis.J4
    moving_end = [still(0.0, q), still(2.0, q, (0.0, 0.0, 3 * REST_TOLERANCE_DPS, 0.0, 0.0))]
    assert run_refused(holding, moving_end, Reason.TRAJ_ENDPOINTS).axis == Axis.J3


def test_a_run_beyond_a_soft_limit_or_a_speed_limit_names_the_limit(holding):
    q = holding_deg(holding)
    j1_max = holding.call(M["ParamGet"]("j1_max_deg")).reply.value
    beyond = smooth_knots(q, (j1_max - q[0] + 1.0,) + (0.0,) * (N - 1), 60.0)
    reply = run_refused(holding, beyond, Reason.SOFT_LIMIT)
    assert (reply.axis, reply.limit, reply.limit_value) == (Axis.J1, "j1_max_deg", pytest.approx(j1_max))
    assert reply.asked == pytest.approx(j1_max + 1.0, abs=1e-3)
    # between its knots, the curve overshoots below j2's lowest knot: the whole curve is checked
    j2_min = holding.call(M["ParamGet"]("j2_min_deg")).reply.value
    low = (q[0], j2_min + 0.01, *q[2:])
    at_min = [still(0.0, q), Knot(30.0, low, (0.0, -2.0) + (0.0,) * (N - 2)), still(60.0, low)]
    assert min(spline(at_min, 1)(np.linspace(0, 60, 6001))) < j2_min < min(k.q_deg[1] for k in at_min)
    assert run_refused(holding, at_min, Reason.SOFT_LIMIT).limit == "j2_min_deg"
    speed = holding.call(M["ParamGet"]("j4_speed_dps")).reply.value
    fast = smooth_knots(q, (0.0, 0.0, 0.0, speed * 8.0 / 1.875 * 1.01, 0.0), 8.0)   # the quintic's peak: 1.875 a / T
    reply = run_refused(holding, fast, Reason.OUT_OF_RANGE)
    assert (reply.axis, reply.limit, reply.limit_value) == (Axis.J4, "j4_speed_dps", pytest.approx(speed))
    assert reply.asked == pytest.approx(speed * 1.01, rel=1e-3)


def test_a_run_is_refused_while_a_joint_moves_or_the_controller_is_not_enabled(holding):
    q = holding_deg(holding)
    knots = smooth_knots(q)
    upload(holding, knots)
    moving = holding.call(M["MoveBy"](int(Axis.J2), 0.5, 0))
    assert moving.ok
    before = controller_view(holding)[0]
    reply = holding.call(M["TrajRun"](len(knots))).reply
    assert (reply.result, reply.axis) == (Reason.BUSY, Axis.J2) and controller_view(holding)[0] == before
    assert holding.wait_until(lambda: done(holding, int(Axis.J2), moving.reply.motion_id), 5.0)
    assert holding.call(M["Disable"]()).ok
    run_refused(holding, knots, Reason.NOT_ALLOWED_IN_STATE)
    assert holding.call(M["Enable"]()).ok


def test_a_run_needs_homed_joints():
    bench = LockstepBench(seed=3)
    try:
        assert bench.connect() and bench.call(M["Enable"]()).ok
        assert run_refused(bench, smooth_knots(holding_deg(bench)), Reason.NOT_HOMED).axis == Axis.J1
    finally:
        bench.close()


# ---- exactly once ---------------------------------------------------------------------------------------------
def test_over_a_line_that_drops_and_duplicates_frames_each_knot_and_the_run_happen_once():
    bench = homed_bench(impairment=Impairment(seed=4, drop=0.15, dup=0.2, latency_ms=2.0))
    try:
        link, arm = bench.controller.link, bench.controller.arm
        motions_before = [arm.channels[int(a)].motion_id for a in JOINTS]
        executed_before = link.commands_executed
        knots = smooth_knots(holding_deg(bench))
        ids = send_trajectory(BenchClient(bench), knots)
        assert link.commands_executed - executed_before == len(knots) + 2       # TrajClear, the knots, TrajRun
        assert bench.host.stats.retransmits > 0          # frames were lost and sent again: the case is there
        assert [k.t_s for k in bench.controller.arm_commands.trajectory.knots] == pytest.approx([k.t_s for k in knots])
        assert ids == [m + 1 for m in motions_before]    # one run: one new motion per joint
        assert bench.wait_until(lambda: all(done(bench, int(a), i) for a, i in zip(JOINTS, ids)), 15.0)
        assert [arm.channels[int(a)].motion_id for a in JOINTS] == ids
    finally:
        bench.close()


def test_the_reasons_state_the_tolerances_of_the_code():
    assert f"within {START_TOLERANCE_DEG:g} deg" in Reason.TRAJ_ENDPOINTS.doc
    assert f"{REST_TOLERANCE_DPS:g} deg/s" in Reason.TRAJ_ENDPOINTS.doc
