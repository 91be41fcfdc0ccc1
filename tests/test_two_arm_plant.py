"""Two example arms holding the report's object (`hil_sim/two_arms.py`, `EXAMPLE_ARM_PLANT`, the hand force in the
arm's tick): the joints carry J^T F as the planner's independent model says, the object follows the example's path,
a squeeze past the grip's limit slips, and the free arms on the grasp springs stay stable at the plant's step.

The planner (`host_tools.plan.model`) is the independent model: its own kinematics, its own statics and dynamics of
the closed chain, with the load shared between the grasps."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hil_sim.arm import ArmPlant, static_torques_nm
from hil_sim.arm_params import EXAMPLE_ARM_PLANT, GRIPPER, J1, J2, J3, J4, MOUNT
from hil_sim.two_arms import EXAMPLE_BASES_M, TwoArmPlant
from protocol.states import GraspState
from protocol.units import G_EARTH_M_S2

DT = 0.001
SUPPLY_V = 28.0
HOLD_DUTY = 0.3                       # the firmware's grip_hold_duty
JOINTS = (J1, J2)


def gripping(duty: float = HOLD_DUTY) -> dict:
    """Joints braked and not driven; the gripper driven closed at `duty` (default: the hold duty)."""
    duties, enable = [0.0] * 6, [False] * 6
    duties[GRIPPER], enable[GRIPPER] = -duty, True
    return dict(duty=duties, enable=enable, brake=[True] * 6)


def example(gravity: bool):
    """The report's example planned with the example arm's links (rods) and the plant's gravity: the problem, its
    minimum-time plan, and the planner's model of the closed chain."""
    from host_tools.plan.example import report_problem
    from host_tools.plan.reach import plan_reach
    problem = report_problem(gravity=gravity, links="rod")
    system = dataclasses.replace(problem.system, gravity=G_EARTH_M_S2 if gravity else 0.0)
    return problem, plan_reach(problem, 100).profile, system


def along(profile, t: float) -> tuple[float, float, float]:
    """s, s', s'' at time t of a profile (s'' constant per interval); at rest at the end after it."""
    if t >= profile.duration:
        return 1.0, 0.0, 0.0
    i = min(int(np.searchsorted(profile.t, t, side="right")) - 1, len(profile.sdd) - 1)
    tau = t - profile.t[i]
    sdd = profile.sdd[i]
    return profile.s[i] + profile.sd[i] * tau + sdd * tau * tau / 2, profile.sd[i] + sdd * tau, sdd


def joints_at(problem, system, s: float, sd: float = 0.0, sdd: float = 0.0):
    """q, q', q'' (4,) of both arms where the object is at s, moving at s', s'' (the planner's inverse kinematics)."""
    jp = system.joint_path(problem.path, [s])
    return jp.q[0], jp.q_s[0] * sd, jp.q_s[0] * sdd + jp.q_ss[0] * sd * sd


def place(arms, q, qd=(0.0, 0.0, 0.0, 0.0)) -> None:
    for k, arm in enumerate(arms):
        for joint in JOINTS:
            arm.set_joint_state(joint, float(q[2 * k + joint]), float(qd[2 * k + joint]))


def two_example_arms(gravity: bool, q, compiled: bool = False) -> TwoArmPlant:
    """Two example arms at joint angles q, jaws closed on the object (0.6 s at full duty, then 0.2 s at the hold
    duty), the object grasped."""
    arms = [ArmPlant(EXAMPLE_ARM_PLANT, gravity="earth" if gravity else "orbit", compiled=compiled)
            for _ in range(2)]
    place(arms, q)
    for arm in arms:
        arm.set_object(0.02)
        for duty, steps in ((1.0, 600), (HOLD_DUTY, 200)):
            for _ in range(steps):
                arm.step(DT, supply_v=SUPPLY_V, **gripping(duty))
    pair = TwoArmPlant(arms)
    pair.grasp()
    return pair


def tick(pair: TwoArmPlant, command: dict) -> None:
    for arm in pair.arms:
        arm.step(DT, supply_v=SUPPLY_V, **command)
    pair.step(DT)


def hand_force_part(arm: ArmPlant) -> np.ndarray:
    """The plant's J1, J2 loads less gravity's: what its joints carry for the hand force."""
    q = arm.motors.positions()
    own = static_torques_nm(q[J1], q[J2], q[J3], arm.params.geometry, arm.g_m_s2)
    return np.array(arm.static_torques_nm()[:2]) - np.array(own[:2])


# ---- the example arm's parameters ----------------------------------------------------------------------------

def test_the_example_arms_drives_give_the_shared_numbers():
    """EXAMPLE_ARM.md: 1.7 N m/A at the joint, 14 rad/s no-load at 28 V, the rotor reflected 0.075 kg m^2, 35.7 and
    20.4 N m at the firmware's 21 A and 12 A; J3, J4, gripper and mount ASPOD's."""
    from hil_sim.arm_params import ARM_PLANT_PARAMS
    p = EXAMPLE_ARM_PLANT
    for joint, amps, torque in ((J1, 21.0, 35.7), (J2, 12.0, 20.4)):
        d = p.channels[joint].drive
        assert d.kt_out_nm_a == pytest.approx(1.7)
        assert SUPPLY_V / d.ke_out_v_s_rad == pytest.approx(14.0)
        assert d.ratio ** 2 * d.motor.rotor_inertia_kg_m2 == pytest.approx(0.075)
        assert amps * d.kt_out_nm_a == pytest.approx(torque)
        assert d.brake_hold_nm == pytest.approx(1.5 * 0.8 * 50 * 0.85)
    assert p.channels[J3:] == ARM_PLANT_PARAMS.channels[J3:] and p.mount == ARM_PLANT_PARAMS.mount
    g = p.geometry
    assert (g.link2_m, g.link3_m, g.link2_kg, g.link3_kg, g.tip_m) == (1.0, 1.0, 1.0, 1.0, 0.0)


def test_the_example_arms_mass_model_is_the_planners_diagonal():
    """Rods and nothing else: the plant's gravity torques are the planner's G(q) and its inertias the diagonal of
    the planner's mass matrix, at every pose of the example's path."""
    problem, _, system = example(gravity=True)
    arm_model = system.arms[0]
    for s in np.linspace(0.0, 1.0, 11):
        q = joints_at(problem, system, s)[0]
        for k in range(2):
            qk = q[2 * k:2 * k + 2]
            plant = ArmPlant(EXAMPLE_ARM_PLANT)
            place([plant], qk)
            zero = np.zeros((1, 2))
            g = arm_model.torques(qk[None], zero, zero, G_EARTH_M_S2)[0]
            assert plant.static_torques_nm()[:2] == pytest.approx(tuple(g), rel=1e-12, abs=1e-12)
            for j in JOINTS:
                unit = np.zeros((1, 2))
                unit[0, j] = 1.0
                d_jj = arm_model.torques(qk[None], zero, unit, 0.0)[0, j]
                assert plant.load_inertia_kg_m2[j] == pytest.approx(d_jj, rel=1e-12)


# ---- statics: the object's weight through both arms -----------------------------------------------------------

def test_held_by_their_brakes_the_arms_carry_half_the_objects_weight_each():
    """Both arms at the example's start, joints held by their brakes in Earth gravity, the object grasped: after
    0.2 s each arm's J1 and J2 carry their own weight and J^T of half the object's, as the planner's statics
    (its inverse dynamics at rest, the load shared between the grasps) say, within 1e-3 N m."""
    problem, _, system = example(gravity=True)
    q = joints_at(problem, system, 0.0)[0]
    pair = two_example_arms(True, q)
    for _ in range(200):
        tick(pair, gripping())
    planner = system.inverse_dynamics(q[None], np.zeros((1, 4)), np.zeros((1, 4)))[0]
    m_g = pair.object.params.mass_kg * G_EARTH_M_S2
    for k, arm in enumerate(pair.arms):
        assert arm.motors.positions()[:2] == pytest.approx(list(q[2 * k:2 * k + 2]), abs=0.0)   # the brakes hold
        assert arm.static_torques_nm()[:2] == pytest.approx(tuple(planner[2 * k:2 * k + 2]), abs=1e-3)
        # the rise: J^T (0, -m g / 2) of the hand force, i.e. m g / 2 times the hand's x from each joint
        tx = pair.hands()[0][k][0] - EXAMPLE_BASES_M[k][0]
        ex = math.cos(q[2 * k])
        assert hand_force_part(arm) == pytest.approx((m_g / 2 * tx, m_g / 2 * (tx - ex)), abs=1e-3)
    assert pair.object.states == (GraspState.HELD, GraspState.HELD)
    assert pair.object.squeeze_n == pytest.approx(0.0, abs=1e-6)


# ---- dynamics: carried along the example's path ---------------------------------------------------------------

def carry(gravity: bool):
    """The joints moved by hand along the example's path at the planner's minimum-time profile (and 0.1 s at rest
    after), the object coupled at 1 ms: the object's worst distance from the path, and each arm's hand-force
    torques against the planner's J^T F part (its inverse dynamics less the arms' own)."""
    problem, profile, system = example(gravity)
    q0 = joints_at(problem, system, 0.0)[0]
    pair = two_example_arms(gravity, q0)
    for _ in range(100):                          # settled on its grasps before it moves
        tick(pair, gripping())
    worst, errors, peaks = 0.0, [], []
    (x0, z0), (x1, z1) = problem.path(np.array([0.0, 1.0])).w
    for k in range(1, round((profile.duration + 0.1) / DT) + 1):
        t = k * DT
        s, sd, sdd = along(profile, t)
        q, qd, qdd = joints_at(problem, system, s, sd, sdd)
        for arm in pair.arms:
            arm.step(DT, supply_v=SUPPLY_V, **gripping())
        place(pair.arms, q, qd)
        pair.step(DT)
        worst = max(worst, math.hypot(pair.object.pose[0] - (x0 + (x1 - x0) * s),
                                      pair.object.pose[1] - (z0 + (z1 - z0) * s)))
        planner = system.inverse_dynamics(q[None], qd[None], qdd[None])[0]
        own = np.concatenate([arm.torques(q[None, sl], qd[None, sl], qdd[None, sl], system.gravity)[0]
                              for arm, sl in zip(system.arms, (slice(0, 2), slice(2, 4)))])
        expected = planner - own
        errors.append(np.concatenate([hand_force_part(arm) for arm in pair.arms]) - expected)
        peaks.append(expected)
        assert pair.object.states == (GraspState.HELD, GraspState.HELD)
    return worst, np.array(errors), np.array(peaks), pair


@pytest.mark.parametrize("gravity", [True, False], ids=["earth", "orbit"])
def test_carried_along_the_example_the_object_follows_and_the_joints_carry_the_planners_force(gravity):
    """Along the example's line at the planner's minimum time (rod links: 0.46 s in Earth gravity, 0.40 s in orbit)
    the object stays within 1.1 mm of its path, nine times inside the 1 cm goal, and the torques the plant's joints
    carry for the object are the planner's J^T F part (up to 4.7 N m). The plan's s'' is constant per interval
    and jumps between them (bang-bang at its switching points): the planner's rigid grasp passes each jump at once,
    the plant's grasp springs over their 31 ms period, so at a jump the two differ by up to its size (3.6 N m once).
    Averaged over 50 ms they agree within 0.27 N m, 0.19 (Earth) and 0.22 N m (orbit) RMS; over the last 50 ms,
    at rest, within 1e-3 N m."""
    worst, errors, expected, _ = carry(gravity)
    assert worst < 0.0011, f"the object strayed {worst * 1000:.2f} mm from its path"
    assert np.abs(expected).max() > 4.0                      # the part compared is not nothing
    assert math.sqrt((errors ** 2).mean()) < 0.25
    window = np.ones(50) / 50                                # 50 steps of 1 ms
    averaged = [np.convolve(errors[:, j], window, "valid") for j in range(errors.shape[1])]
    assert np.abs(averaged).max() < 0.3, f"{np.abs(averaged).max():.3f} N m"
    assert np.abs(errors[-50:]).max() < 1e-3                 # the last 50 ms, at rest


# ---- the grip's limit ------------------------------------------------------------------------------------------

def test_hands_closing_in_squeeze_past_the_grips_limit_and_the_grasps_slip():
    """Both hands moved 1.5 cm towards each other over 0.5 s (the joints moved by hand): 75 N of squeeze if the
    grasps held, past friction x jaws (0.5 x 118 N = 59 N): both grasps slip, each an event with its reason, the
    force across each held at the limit, and each arm's joints carry what its grasp passes."""
    problem, _, system = example(gravity=False)
    q = joints_at(problem, system, 0.5)[0]
    pair = two_example_arms(False, q)
    limit = pair.object.params.friction * pair.arms[1].grip_force_n
    assert limit == pytest.approx(59.0, rel=0.01)
    events = pair.object.event_count
    start = pair.hands()[0]
    for k in range(1, 501):
        d = 0.015 * k / 500
        for arm in pair.arms:
            arm.step(DT, supply_v=SUPPLY_V, **gripping())
        for a, (arm, sign) in enumerate(zip(pair.arms, (1.0, -1.0))):
            x, z = start[a]
            place([arm], system.arms[a].inverse(np.array([[x + sign * d, z]]))[0])
        pair.step(DT)
        assert max(pair.object.carried_n) <= limit * (1 + 1e-9)
    assert pair.object.states == (GraspState.SLIPPING, GraspState.SLIPPING)
    assert pair.object.event_count == events + 2
    assert "slips" in pair.object.last_event.reason
    assert pair.object.squeeze_n == pytest.approx(limit, rel=0.02)
    for arm, force in zip(pair.arms, pair.object.hand_forces):
        assert arm.hand_force_n == force


# ---- the explicit lag is stable -------------------------------------------------------------------------------

def test_the_free_arms_on_the_grasp_springs_settle():
    """In orbit, brakes released, nothing driven (bridges open: no back-EMF to damp them): arm 2's hand kicked 3 mm
    off its grasp. The arms swing on the grasp springs, the object between them, each seeing the object's force one
    1 ms step late; friction and the grasps' dampers settle them within 1 s, no swing grows."""
    problem, _, system = example(gravity=False)
    q = joints_at(problem, system, 0.0)[0]
    pair = two_example_arms(False, q)
    arm = pair.arms[1]
    arm.set_joint_state(J1, arm.motors.positions()[J1] + 0.003 / 1.5)       # about 3 mm at the hand
    free = gripping()
    free["brake"] = [False] * 6
    swings = []
    for _ in range(1000):
        tick(pair, free)
        swings.append(max(pair.object.carried_n))
    swings = np.array(swings)
    assert swings[:100].max() > 5.0                                           # kicked: a few N across the grasps
    assert swings[-100:].max() < 0.05 * swings[:100].max()
    assert all(np.isfinite(a.motors.positions()).all() for a in pair.arms)
    assert pair.object.states == (GraspState.HELD, GraspState.HELD)


# ---- the hand force in the tick ---------------------------------------------------------------------------------

def test_no_hand_force_leaves_the_loads_as_they_were():
    """ASPOD's arm with the hand force set and then set back to 0: its loads are to the bit what they were."""
    arm = ArmPlant()
    before = list(arm.load_lists()[0])
    arm.set_hand_force(3.0, -4.0)
    assert arm.load_lists()[0][:3] != before[:3]
    arm.set_hand_force(0.0, 0.0)
    assert [x.hex() for x in arm.load_lists()[0]] == [x.hex() for x in before]


def test_a_hand_force_loads_the_joints_as_gravity_on_a_mass_at_the_tip_would():
    """A force (0, -m g) at ASPOD's gripper tip is a payload m there: the same torques at J1, J2, J3 (J4, the
    gripper and the mount carry none)."""
    payload = 0.4
    by_force = ArmPlant()
    by_payload = ArmPlant(payload_kg=payload)
    for arm in (by_force, by_payload):
        for channel, angle in ((J1, 0.3), (J2, -0.7), (J3, 0.9)):
            arm.set_joint_state(channel, angle)
    by_force.set_hand_force(0.0, -payload * G_EARTH_M_S2)
    loads, with_payload = by_force.load_lists()[0], by_payload.load_lists()[0]
    assert loads[:3] == pytest.approx(with_payload[:3], rel=1e-12)
    assert loads[J4] == loads[GRIPPER] == loads[MOUNT] == 0.0


@pytest.mark.parametrize("force", [(math.nan, 0.0), (0.0, math.inf)])
def test_a_hand_force_not_finite_is_refused_and_changes_nothing(force):
    arm = ArmPlant()
    arm.set_hand_force(1.0, 2.0)
    loads = list(arm.load_lists()[0])
    with pytest.raises(ValueError, match="hand force must be finite"):
        arm.set_hand_force(*force)
    assert arm.hand_force_n == (1.0, 2.0) and arm.load_lists()[0] == loads


# ---- what the plant leaves out for the example arm --------------------------------------------------------------

@pytest.mark.parametrize("gravity, shoulder, elbow", [(True, 16.0, 15.4), (False, 20.1, 17.6)],
                         ids=["earth", "orbit"])
def test_the_diagonal_mass_model_leaves_out_torques_the_size_of_the_drives(gravity, shoulder, elbow):
    """docs/plant.md: along the example's minimum-time plan, the coupling and velocity torques the plant's diagonal
    mass model leaves out (the planner's full inverse dynamics of each arm less its diagonal part, D_jj q''_j +
    G_j) peak at 16.0 / 15.4 N m (Earth) and 20.1 / 17.6 N m (orbit), shoulder / elbow over both arms: half the
    shoulder drives' 35.7 N m, most of the elbows' 20.4."""
    problem, profile, system = example(gravity)
    times = np.linspace(0.0, profile.duration, 2001)
    left = np.zeros((len(times), 4))
    for n, t in enumerate(times):
        q, qd, qdd = joints_at(problem, system, *along(profile, t))
        for k, arm in enumerate(system.arms):
            sl = slice(2 * k, 2 * k + 2)
            full = arm.torques(q[None, sl], qd[None, sl], qdd[None, sl], system.gravity)[0]
            diagonal = [arm.torques(q[None, sl], np.zeros((1, 2)), (qdd[sl] * unit)[None], system.gravity)[0, j]
                        for j, unit in enumerate(np.eye(2))]
            left[n, sl] = full - diagonal
    peaks = np.abs(left).max(axis=0)
    assert max(peaks[0], peaks[2]) == pytest.approx(shoulder, abs=0.05)
    assert max(peaks[1], peaks[3]) == pytest.approx(elbow, abs=0.05)
