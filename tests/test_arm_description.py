"""The arm a controller drives is its configuration's (`ControllerConfig.arm`): ASPOD's by default, unchanged, or the
report's example arm, whose figures are issue 39's EXAMPLE_ARM.md, whose loops are stable and well damped, and whose
gravity feed-forward is the planner's rod model. Two controllers in one process each keep their own arm."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from firmware_py.arm_config import ASPOD_ARM, EXAMPLE_ARM, ArmDescription, Drive, axis_config, highest_speed_dps
from firmware_py.controller import ControllerConfig
from firmware_py.estimator import COUNT_MODULUS, steady_state_gain
from firmware_py.hermite import HermiteProfile
from firmware_py.joint_bank import single_axis
from hil_sim.arm_params import CHANNEL_PARAMS
from host_tools.plan.model import Arm
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.states import AxisMode, MotionOutcome

DT_S = 0.001
EARTH = 9.80665
REFERENCE = Path(__file__).resolve().parent / "data" / "aspod_arm_parameters.json"


def defaults(arm: ArmDescription) -> dict[str, float]:
    return {spec.name: spec.default for spec in arm.parameter_table()}


# ---- ASPOD's arm, the default, unchanged --------------------------------------------------------------------------
def test_aspods_parameters_are_what_they_were_before_the_arm_description():
    """Names, order, defaults, ranges, units and docs, against the values commit 9c7a6eb gave (stored)."""
    stored = json.loads(REFERENCE.read_text())["parameters"]
    now = [[p.name, p.default, p.lo, p.hi, p.unit, p.doc] for p in ASPOD_ARM.parameter_table()]
    assert now == stored


def test_the_default_controller_drives_aspods_arm():
    assert ControllerConfig().arm is ASPOD_ARM


def test_an_arm_without_every_drive_in_channel_order_is_refused():
    with pytest.raises(ValueError, match="j1, j2, j3, j4, mount in that order"):
        dataclasses.replace(ASPOD_ARM, drives=ASPOD_ARM.drives[::-1])


# ---- the example arm: EXAMPLE_ARM.md's figures --------------------------------------------------------------------
def test_the_example_arms_shoulder_and_elbow_are_example_arm_md_s():
    j1, j2 = EXAMPLE_ARM.drive("j1"), EXAMPLE_ARM.drive("j2")
    table = {spec.name: spec for spec in EXAMPLE_ARM.parameter_table()}
    for drive in (j1, j2):
        assert drive.no_load_speed_rad_s == pytest.approx(14.0)                           # 28 / (0.04 x 50)
        assert drive.efficiency * drive.kt_nm_a * drive.ratio == pytest.approx(1.7)       # N m/A at the joint
        assert (drive.kt_nm_a, drive.r_ohm, drive.ratio, drive.efficiency) == (0.04, 0.4, 50.0, 0.85)
        assert table[f"{drive.name}_speed_dps"].hi == 600.0                                # 10.5 rad/s, 75 % of 14
        assert drive.rad_per_count == pytest.approx(2 * math.pi / (400 * 50))
        assert drive.viscous_nm_s_rad == pytest.approx(2e-6 * 50 ** 2)
    assert j1.inertia_kg_m2 == pytest.approx(0.075 + 2e-3) and j2.inertia_kg_m2 == pytest.approx(0.075 + 1e-3)
    assert (j1.i_limit_a, j2.i_limit_a) == (21.0, 12.0)
    assert (table["j1_i_lim_a"].default, table["j2_i_lim_a"].default) == (21.0, 12.0)
    assert j1.i_limit_a * 1.7 == pytest.approx(35.7) and j2.i_limit_a * 1.7 == pytest.approx(20.4)
    assert (j1.soft_min_deg, j1.soft_max_deg, j2.soft_min_deg, j2.soft_max_deg) == (-90.0, 135.0, -3.0, 170.0)


def test_the_example_arms_links_are_the_planners_rods_and_the_rest_is_aspods():
    m = EXAMPLE_ARM.masses
    assert (m.link2_m, m.link3_m, m.link2_kg, m.link3_kg) == (1.0, 1.0, 1.0, 1.0)
    assert (m.elbow_hw_kg, m.wrist_fixed_kg, m.wrist_turned_kg, m.wrist_turned_cg_m, m.tip_m) == (0.0,) * 5
    assert EXAMPLE_ARM.drives[2:] == ASPOD_ARM.drives[2:] and EXAMPLE_ARM.gripper == ASPOD_ARM.gripper
    aspod, example = defaults(ASPOD_ARM), defaults(EXAMPLE_ARM)
    assert {n: v for n, v in example.items() if not n.startswith(("j1_", "j2_"))} == \
        {n: v for n, v in aspod.items() if not n.startswith(("j1_", "j2_"))}


@pytest.mark.parametrize("pose", [(0.0, 0.0), (-0.7, 1.17), (0.57, 2.48), (1.96, 1.8), (-1.5, 2.9)])
@pytest.mark.parametrize("g", [EARTH, 0.0])
def test_the_example_arms_gravity_feed_forward_is_the_planners_rod_model(pose, g):
    """J1 and J2's holding torques from the firmware's mass model equal the planner's (host_tools/plan/model.py,
    links="rod", whose dynamics check against an independent model), J3 holds nothing; and the J1 inertia the loops
    are tuned for is the planner's stretched out."""
    planner = Arm(base=(0.0, 0.0), links="rod")
    q = np.array([pose])
    expected = planner.torques(q, np.zeros((1, 2)), np.zeros((1, 2)), g)[0]
    assert EXAMPLE_ARM.masses.holding_torques_nm(*pose, 0.3, g) == pytest.approx((*expected, 0.0), abs=1e-12)
    stretched = planner.torques(np.zeros((1, 2)), np.zeros((1, 2)), np.array([[1.0, 0.0]]), 0.0)[0][0]
    assert EXAMPLE_ARM.drive("j1").load_inertia_kg_m2 == pytest.approx(stretched)


# ---- the loops ----------------------------------------------------------------------------------------------------
def inductance_h(arm: ArmDescription, drive: Drive) -> float:
    """The armature's inductance (the firmware does not know it): the plant's for ASPOD's motors, EXAMPLE_ARM.md's
    0.5 mH for the example's shoulder and elbow."""
    if arm is EXAMPLE_ARM and drive.name in ("j1", "j2"):
        return 0.5e-3
    return next(c.drive.motor.l_h for c in CHANNEL_PARAMS if c.drive.name == drive.name)


def j1_inertia_kg_m2(arm: ArmDescription, elbow_rad: float) -> float:
    """J1's inertia with the elbow at `elbow_rad`: the rotor's and the rods' (the planner's d11)."""
    rods = Arm(base=(0.0, 0.0), links="rod").torques(np.array([[0.0, elbow_rad]]), np.zeros((1, 2)),
                                                     np.array([[1.0, 0.0]]), 0.0)[0][0]
    return arm.drive("j1").inertia_kg_m2 + rods


def closed_loop_poles(arm: ArmDescription, drive: Drive, inertia_kg_m2: float, delay_ticks: int) -> np.ndarray:
    """The poles (z plane, 1 kHz) of the joint's loops with the controller's default configuration closed around a
    linear joint: the armature (R, L), the inertia `inertia_kg_m2`, viscous friction and back-EMF (the plant's
    equations, as tests/test_arm_config.py checks the feed-forwards against); the estimator's steady-state filter,
    the velocity PI and the position P as firmware_py/joints_tick.py runs them; the duty applied at once or
    `delay_ticks` (0 or 1) later. Friction's dead band and the counts' quantization are left out (the simulation
    below has them)."""
    config = axis_config(drive, defaults(arm), DT_S)
    k_pos, k_vel, _ = steady_state_gain(config.estimator)
    kp, kv, ki = config.kp_pos_1_s, config.kv_duty_s_rad, config.ki_duty_rad
    r, l_h, n, kt, eta = drive.r_ohm, inductance_h(arm, drive), drive.ratio, drive.kt_nm_a, drive.efficiency
    plant = np.array([[-r / l_h, -kt * n / l_h, 0.0],
                      [eta * kt * n / inertia_kg_m2, -drive.viscous_nm_s_rad / inertia_kg_m2, 0.0],
                      [0.0, 1.0, 0.0]])
    duty_in = np.array([[28.0 / l_h], [0.0], [0.0]])
    exp = scipy.linalg.expm(np.block([[plant, duty_in], [np.zeros((1, 4))]]) * DT_S)
    a_d, b_d = exp[:3, :3], exp[:3, 3:]
    size = 6 + delay_ticks                            # current, speed, angle; estimate, its speed, integral; duty
    e = np.eye(size)
    angle, est, est_vel, integral = e[2], e[3], e[4], e[5]
    predicted = est + DT_S * est_vel
    est_next = predicted + k_pos * (angle - predicted)
    vel_next = est_vel + k_vel * (angle - predicted)
    vel_err = kp * (0.0 - est_next) - vel_next
    duty = kv * vel_err + integral
    applied = e[6] if delay_ticks else duty
    loop = np.zeros((size, size))
    loop[0:3] = a_d @ e[0:3] + b_d @ applied[None, :]
    loop[3], loop[4], loop[5] = est_next, vel_next, integral + DT_S * ki * vel_err
    if delay_ticks:
        loop[6] = duty
    return np.linalg.eigvals(loop)


def least_damping(poles: np.ndarray) -> float:
    """The smallest damping ratio of the oscillating poles (1: none oscillates); negative: unstable."""
    s = np.log(poles.astype(complex)) / DT_S
    return min((-p.real / abs(p) for p in s if abs(p.imag) > 1e-6), default=1.0)


def inertias(arm: ArmDescription, drive: Drive) -> list[float]:
    """The joint's inertia at its loops' design (rotor and typical load) and, for the example's shoulder, over
    the arm's range: the elbow folded to 170 deg (0.76 kg m^2) through stretched out (2.74)."""
    if arm is EXAMPLE_ARM and drive.name == "j1":
        return [j1_inertia_kg_m2(arm, math.radians(q2)) for q2 in (170.0, 140.0, 110.0, 80.0, 40.0, 0.0)]
    return [drive.inertia_kg_m2 + drive.load_inertia_kg_m2]


@pytest.mark.parametrize("arm, drive", [(arm, d) for arm in (ASPOD_ARM, EXAMPLE_ARM) for d in arm.drives
                                        if arm is ASPOD_ARM or d.name in ("j1", "j2")],
                         ids=lambda x: x.name if isinstance(x, (Drive, ArmDescription)) else str(x))
def test_every_joints_loops_are_stable_and_well_damped(arm, drive):
    """Measured: ASPOD's joints damped 0.71 or more; the example's shoulder 0.59 or more over its whole range of
    inertia (the least folded, a tick late), its elbow 0.69; the duty applied at once or a tick late."""
    for inertia in inertias(arm, drive):
        for delay in (0, 1):
            poles = closed_loop_poles(arm, drive, inertia, delay)
            assert max(abs(poles)) < 0.999, (inertia, delay)          # every mode decays within a second
            assert least_damping(poles) > 0.55, (inertia, delay)


def test_aspods_loop_tuning_would_make_the_example_shoulder_unstable_folded():
    """Why the example's drives have loops of their own (firmware_py/arm_config.py, "the example arm"): ASPOD's
    60 rad/s velocity loop, with an estimator that follows 2 rad/s^2, is damped 0.06 stretched out and diverges with
    the elbow bent past 60 deg."""
    aspods = dataclasses.replace(EXAMPLE_ARM.drive("j1"), vel_bandwidth_rad_s=60.0, max_acc_rad_s2=2.0)
    arm = dataclasses.replace(EXAMPLE_ARM, drives=(aspods,) + EXAMPLE_ARM.drives[1:])
    folded = closed_loop_poles(arm, aspods, j1_inertia_kg_m2(arm, math.radians(170.0)), 1)
    stretched = closed_loop_poles(arm, aspods, j1_inertia_kg_m2(arm, 0.0), 1)
    assert max(abs(folded)) > 1.0
    assert least_damping(stretched) < 0.1


class RodJoint:
    """The example's shoulder (the elbow held at `other_rad`) or elbow (the shoulder held), as EXAMPLE_ARM.md builds
    them: the motor (R, L, kt = ke) through 50:1, the rods' inertia and gravity, Coulomb friction at the motor and the
    joint, 400 counts per motor turn; stepped at 1 ms."""

    def __init__(self, name: str, other_rad: float, angle_rad: float, g: float) -> None:
        self.name, self.other_rad, self.angle_rad, self.g = name, other_rad, angle_rad, g
        self.vel_rad_s = self.i_a = 0.0
        self.coulomb_nm = (0.2 if name == "j1" else 0.1) + 5e-3 * 50 * 0.85
        self.rods = Arm(base=(0.0, 0.0), links="rod")

    def _q(self, angle_rad: float) -> np.ndarray:
        return np.array([[angle_rad, self.other_rad] if self.name == "j1" else [self.other_rad, angle_rad]])

    def inertia_kg_m2(self) -> float:
        k = 0 if self.name == "j1" else 1
        unit = np.zeros((1, 2))
        unit[0, k] = 1.0
        rotor = 3.0e-5 * 50 ** 2 + (2e-3 if k == 0 else 1e-3)
        return rotor + self.rods.torques(self._q(self.angle_rad), np.zeros((1, 2)), unit, 0.0)[0][k]

    def gravity_nm(self) -> float:
        zero = np.zeros((1, 2))
        return self.rods.torques(self._q(self.angle_rad), zero, zero, self.g)[0][0 if self.name == "j1" else 1]

    @property
    def count(self) -> int:
        return math.floor(self.angle_rad * 50 * 400 / (2 * math.pi)) % COUNT_MODULUS

    def step(self, duty: float, brake: bool) -> None:
        volts = max(-1.0, min(1.0, duty)) * 28.0
        i_ss = (volts - 0.04 * 50 * self.vel_rad_s) / 0.4
        self.i_a = i_ss + (self.i_a - i_ss) * math.exp(-DT_S * 0.4 / 0.5e-3)
        if brake:
            self.vel_rad_s = 0.0
            return
        drive = 1.7 * self.i_a - self.gravity_nm()
        w = self.vel_rad_s
        if w == 0.0 and abs(drive) <= self.coulomb_nm:
            return
        friction = self.coulomb_nm * math.copysign(1.0, w if w != 0.0 else drive)
        w_new = w + DT_S * (drive - friction - 2e-6 * 50 ** 2 * w) / self.inertia_kg_m2()
        if w != 0.0 and w_new * w < 0 and abs(drive) <= self.coulomb_nm:
            w_new = 0.0
        self.vel_rad_s = w_new
        self.angle_rad += DT_S * w_new


def smooth_move(start_rad: float, distance_rad: float, duration_s: float, knots: int = 21) -> HermiteProfile:
    """A quintic rest-to-rest move as a trajectory's knots."""
    times = np.linspace(0.0, duration_s, knots)
    s = times / duration_s
    return HermiteProfile(list(times), list(start_rad + distance_rad * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)),
                          list(distance_rad / duration_s * (30 * s ** 2 - 60 * s ** 3 + 30 * s ** 4)))


@pytest.mark.parametrize("name, other_deg", [("j1", 0.0), ("j1", 67.0), ("j1", 170.0), ("j2", -40.0)],
                         ids=["shoulder stretched out", "shoulder", "shoulder folded", "elbow"])
@pytest.mark.parametrize("g", [EARTH, 0.0], ids=["earth", "orbit"])
def test_the_example_joints_follow_a_fast_trajectory_settle_and_hold(name, other_deg, g):
    """The firmware's axis, configured from EXAMPLE_ARM's defaults with the gravity feed-forward of its mass model,
    on the joint EXAMPLE_ARM.md builds: a 1 rad move in 1.2 s (1.6 rad/s, 5.2 rad/s^2 at the peaks) is followed within
    0.3 deg, ends DONE within a second, and the joint then holds within 4 counts (0.07 deg) without a fault."""
    start = math.radians(-40.0 if name == "j1" else 70.0)
    joint = RodJoint(name, math.radians(other_deg), start, g)
    values = defaults(EXAMPLE_ARM)
    values[f"{name}_speed_dps"] = 600.0
    config = axis_config(EXAMPLE_ARM.drive(name), values, DT_S)
    k = 0 if name == "j1" else 1

    def gravity(pos_rad: float) -> float:
        q = (pos_rad, joint.other_rad) if name == "j1" else (joint.other_rad, pos_rad)
        return EXAMPLE_ARM.masses.holding_torques_nm(*q, 0.0, g)[k]

    faults: list = []
    axis = single_axis(config, gravity_nm=gravity, on_fault=lambda bits, now: faults.append(bits))
    now = 0.0

    def tick() -> None:
        nonlocal now
        joint.step(axis.update(now, joint.count, now, joint.i_a, now, False), axis.brake)
        now += DT_S

    axis.set_zero(start)
    axis.enable(now)
    for _ in range(500):
        tick()
    profile = smooth_move(start, 1.0, 1.2)
    assert axis.check_trajectory(profile, math.radians(0.5), math.radians(1.0))[0].name == "OK"
    axis.follow(profile, now)
    began, error = now, 0.0
    while axis.mode is AxisMode.MOVING and now - began < profile.duration_s + 3.0:
        tick()
        error = max(error, abs(joint.angle_rad - profile.sample(now - began)[0]))
    assert axis.outcome is MotionOutcome.DONE and now - began < profile.duration_s + 1.0
    assert math.degrees(error) < 0.3
    held = []
    for _ in range(1000):
        tick()
        held.append(joint.angle_rad - profile.end_pos_rad)
    assert max(abs(x) for x in held) < 4 * EXAMPLE_ARM.drive(name).rad_per_count
    assert faults == [] and axis.mode is AxisMode.HOLDING


# ---- two controllers, two arms, one process -----------------------------------------------------------------------
def param(bench: LockstepBench, name: str):
    handle = bench.call(M["ParamGet"](name))
    assert handle.ok, handle.describe()
    return handle.reply


def test_two_controllers_in_one_process_each_drive_and_keep_their_own_arm():
    """ASPOD's and the example's controllers side by side: each answers with its own arm's parameters (the speed
    caps, current limits, gains), a speed only the example's allows is refused by ASPOD's and kept by the example's
    alone, and each one's gravity feed-forward is computed from its own arm's masses."""
    aspod = LockstepBench(seed=1)
    example = LockstepBench(seed=2, controller_config=ControllerConfig(arm=EXAMPLE_ARM))
    try:
        assert aspod.connect() and example.connect()
        for name, aspod_hi, example_hi in (("j1", 28.0, 600.0), ("j2", 30.0, 600.0), ("j3", 30.0, 30.0),
                                           ("mount", 23.0, 23.0)):
            assert param(aspod, f"{name}_speed_dps").max == aspod_hi
            assert param(example, f"{name}_speed_dps").max == example_hi
        assert (param(aspod, "j1_i_lim_a").value, param(example, "j1_i_lim_a").value) == (1.5, 21.0)
        assert (param(aspod, "j2_kp").value, param(example, "j2_kp").value) == (12.0, 8.0)
        refused = aspod.call(M["ParamSet"]("j1_speed_dps", 500.0))
        assert refused.reason is Reason.OUT_OF_RANGE
        assert example.call(M["ParamSet"]("j1_speed_dps", 500.0)).ok
        assert example.call(M["ParamSet"]("j2_i_lim_a", 25.0)).ok
        assert param(aspod, "j1_speed_dps").value == pytest.approx(3.0)
        assert param(example, "j1_speed_dps").value == 500.0
        assert aspod.controller.arm.joints["j1"].config.vel_limit_rad_s == pytest.approx(math.radians(3.0))
        assert example.controller.arm.joints["j1"].config.vel_limit_rad_s == pytest.approx(math.radians(500.0))
        assert param(aspod, "j2_i_lim_a").value == 1.5
        aspod.run_for(0.2)
        example.run_for(0.2)
        for bench, arm in ((aspod, ASPOD_ARM), (example, EXAMPLE_ARM)):
            joints = bench.controller.arm.joints
            pose = [joints[n].estimator.pos_rad for n in ("j1", "j2", "j3")]
            assert list(bench.controller.arm.bank.gravity_nm[:3]) == pytest.approx(
                arm.masses.holding_torques_nm(*pose, EARTH), rel=1e-9)
        assert highest_speed_dps(EXAMPLE_ARM.drive("j1")) != highest_speed_dps(ASPOD_ARM.drive("j1"))
    finally:
        aspod.close()
        example.close()
