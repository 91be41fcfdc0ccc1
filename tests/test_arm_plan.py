"""Time-optimal moves of ASPOD's own arm (host_tools/apps/arm_plan.py): the plan keeps every motor within its
voltage and current shares, saturates one of them, and refuses what cannot be planned."""
from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_py.arm_config import ASPOD_ARM, SUPPLY_NOMINAL_V
from host_tools.apps.arm_plan import ARM_JOINTS, HELD, ArmPlanSettings, plan_move
from host_tools.plan.errors import PlanError

LIMITS_A = {d.name: d.i_limit_a for d in ASPOD_ARM.drives}
SPEEDS = {d.name: math.radians(30.0) for d in ASPOD_ARM.drives}      # the speed parameters' largest value
START = {"j1": math.radians(60), "j2": math.radians(-110), "j3": math.radians(-40), "j4": 0.0, "mount": 0.0}
TARGET = {"j1": math.radians(21.2), "j2": math.radians(-116.9), "j3": math.radians(5.7), "j4": math.radians(30),
          "mount": math.radians(-45)}
EARTH = 9.80665


def motor_demands(move, gravity, payload):
    """Each moving joint's current and voltage along the plan, from the drive constants directly."""
    prof = move.plan.profile
    dq = move.path.q1 - move.path.q0
    sdd = np.concatenate([prof.sdd, prof.sdd[-1:]])
    q = move.path.q(prof.s)
    currents, volts = [], []
    for k, name in enumerate(move.names):
        d = ASPOD_ARM.drive(name)
        qd, qdd = prof.sd * dq[k], sdd * dq[k]
        angles = np.tile([START["j1"], START["j2"], START["j3"]], (len(q), 1))
        for j, other in enumerate(move.names):
            if other in HELD:
                angles[:, HELD.index(other)] = q[:, j]
        hold = 0.0 if name not in HELD else np.array(
            [ASPOD_ARM.masses.holding_torques_nm(*row, gravity, payload)[HELD.index(name)] for row in angles])
        torque = (d.inertia_kg_m2 + d.load_inertia_kg_m2) * qdd + d.viscous_nm_s_rad * qd + hold
        i = torque / (d.efficiency * d.kt_nm_a * d.ratio)
        currents.append(i / d.i_limit_a)
        volts.append((d.r_ohm * i + d.kt_nm_a * d.ratio * qd) / SUPPLY_NOMINAL_V)
    return np.array(currents).T, np.array(volts).T


@pytest.mark.parametrize("gravity", [EARTH, 0.0], ids=["earth", "orbit"])
def test_a_planned_move_keeps_every_motor_within_its_shares_and_saturates_one(gravity):
    settings = ArmPlanSettings()
    move = plan_move(START, TARGET, gravity, 0.0, LIMITS_A, SPEEDS, settings)
    assert move.names == ARM_JOINTS
    current, volts = motor_demands(move, gravity, 0.0)
    slack = 1.03         # the phase plane's profile exceeds its limits by O(1/nodes) at the nodes (docs/planning.md)
    assert np.abs(current).max() <= settings.current_share * slack
    assert np.abs(volts).max() <= settings.voltage_share * slack
    near = np.maximum(np.abs(current) / settings.current_share, np.abs(volts) / settings.voltage_share).max(axis=1)
    assert np.mean(near >= 0.97) > 0.9                   # time-optimal: some motor at its share nearly always
    dq = move.path.q1 - move.path.q0
    assert (np.abs(move.plan.profile.sd[:, None] * dq) <= math.radians(30.0) + 1e-9).all()   # the speed limits
    slowest = max(abs(TARGET[n] - START[n]) for n in ARM_JOINTS) / math.radians(3.0)
    assert move.duration_s < slowest / 3                 # far quicker than cruising at the report's 1/2 RPM


def test_a_lower_speed_limit_caps_the_move_and_its_knots():
    slow = {**SPEEDS, "j3": math.radians(5.0)}
    move = plan_move(START, {"j3": TARGET["j3"]}, EARTH, 0.0, LIMITS_A, slow)
    assert max(abs(k.qd_deg_s[2]) for k in move.knots(41)) <= 5.0
    assert move.duration_s > math.degrees(abs(TARGET["j3"] - START["j3"])) / 5.0     # cruising at the cap
    assert move.duration_s > plan_move(START, {"j3": TARGET["j3"]}, EARTH, 0.0, LIMITS_A, SPEEDS).duration_s


def test_a_lift_is_quicker_in_orbit_and_slower_with_a_payload():
    """Raising the arm (J1..J3 from TARGET back to START: J1 from 21 to 60 degrees) works against gravity on Earth."""
    lift = {n: START[n] for n in HELD}
    earth = plan_move(TARGET, lift, EARTH, 0.0, LIMITS_A, SPEEDS).duration_s
    assert plan_move(TARGET, lift, 0.0, 0.0, LIMITS_A, SPEEDS).duration_s < earth
    assert plan_move(TARGET, lift, EARTH, 2.0, LIMITS_A, SPEEDS).duration_s > earth


def test_the_knots_start_and_end_at_rest_on_the_poses_and_follow_the_profile():
    move = plan_move(START, {"j1": TARGET["j1"]}, EARTH, 0.0, LIMITS_A, SPEEDS)
    knots = move.knots(21)
    assert knots[0].t_s == 0 and knots[-1].t_s == pytest.approx(move.duration_s)
    assert all(b.t_s > a.t_s for a, b in zip(knots, knots[1:]))
    assert knots[0].q_deg == pytest.approx([math.degrees(START[n]) for n in ARM_JOINTS])
    assert knots[-1].q_deg[0] == pytest.approx(math.degrees(TARGET["j1"]))
    assert knots[-1].q_deg[1:] == pytest.approx([math.degrees(START[n]) for n in ARM_JOINTS[1:]])
    assert not any(knots[0].qd_deg_s) and not any(knots[-1].qd_deg_s)
    assert max(abs(k.qd_deg_s[0]) for k in knots) == pytest.approx(
        math.degrees(abs(TARGET["j1"] - START["j1"])) * move.plan.profile.sd.max(), rel=0.05)


@pytest.mark.parametrize("targets, why", [
    ({"gripper": 0.3}, "not an arm joint"),
    ({"j1": START["j1"]}, "no joint moves"),
])
def test_what_cannot_be_planned_is_refused_with_the_reason(targets, why):
    with pytest.raises(PlanError, match=why):
        plan_move(START, targets, EARTH, 0.0, LIMITS_A, SPEEDS)


def test_limits_too_weak_to_hold_the_arm_are_refused_naming_a_joint():
    with pytest.raises(PlanError, match="joint"):
        plan_move(START, TARGET, EARTH, 0.0, {**LIMITS_A, "j1": 0.01}, SPEEDS)


@pytest.mark.parametrize("field, value", [("voltage_share", 0.0), ("current_share", 1.5), ("nodes", 5),
                                          ("knots", 1000)])
def test_settings_out_of_range_are_refused(field, value):
    with pytest.raises(PlanError, match=field):
        ArmPlanSettings(**{field: value})


@pytest.mark.parametrize("gravity", ["earth", "orbit"])
def test_planned_moves_run_on_the_emulated_arm_through_the_protocol_within_a_centimetre(gravity):
    """The pick-and-place's first moves as planned trajectories on the lock-step bench: each ends with the tip
    within the report's 1 cm, and its plan takes a fraction of the 1/2 RPM trapezoid's time."""
    from host_tools.apps.kinematics import steps
    from host_tools.apps.pick_place import SPEC_M
    from host_tools.apps.planned_moves import PlannedPickAndPlace, PlannedStep
    demo = PlannedPickAndPlace(gravity)
    try:
        demo.prepare()
        before = None
        for step in steps(demo.scene)[:4]:              # home, open, approach (the mount too), descend
            pose = demo._pose()
            result = demo.run_step(step)
            assert result.position_error_m <= SPEC_M, (step.name, result)
            if isinstance(result, PlannedStep) and step.name != "home":
                cruise = max(abs(q - pose[n]) for n, q in step.targets.items() if n in pose) / math.radians(3.0)
                assert result.planned_s < cruise / 2, (step.name, result.planned_s, cruise)
                before = result
        assert before is not None and set(before.outcomes) >= set(ARM_JOINTS)
    finally:
        demo.close()
