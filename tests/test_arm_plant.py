"""The arm, mount and gripper plant against the report's figures and against physics.

Simulated time only: every run is a count of 1 ms steps.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from hil_sim import arm_params as P
from hil_sim.arm import (ArmPlant, gripper_position_m, joint_inertias_kg_m2, mount_static_moment_nm,
                         static_torques_nm)
from hil_sim.arm_params import GRIPPER, J1, J2, J3, J4, MOUNT
from protocol import units
from protocol.states import ARM_CHANNELS

DT = 0.001
V_BUS = 28.0
GEO = P.ARM_PLANT_PARAMS.geometry
DRIVES = {c.drive.name: c.drive for c in P.CHANNEL_PARAMS}
HALF_PI = math.pi / 2


def run(plant: ArmPlant, seconds: float, duty=None, enable=None, brake=None, supply_v=V_BUS):
    duty = [0.0] * 6 if duty is None else duty
    enable = [False] * 6 if enable is None else enable
    brake = [False] * 6 if brake is None else brake
    for _ in range(round(seconds / DT)):
        plant.step(DT, duty, enable, brake, supply_v)


def only(channel: int, value, rest=0.0) -> list:
    out = [rest] * 6
    out[channel] = value
    return out


def posed(q1: float, q2: float, q3: float, gravity: str = "earth", payload_kg: float = 0.0) -> ArmPlant:
    plant = ArmPlant(gravity=gravity, payload_kg=payload_kg)
    for channel, q in ((J1, q1), (J2, q2), (J3, q3)):
        plant.set_joint_state(channel, q)
    return plant


# ---- the report's numbers ----------------------------------------------------------------------
def test_link_weights_follow_from_tube_size_and_density():
    """Table 2's weights agree with Table 1's density for 2 x 2 x 1/8 in tube (within 1 %)."""
    for length_in, weight_lb in ((12, 1.1), (24, 2.2), (12, 1.1)):
        assert P.square_tube_weight_lb(2.0, 0.125, length_in) == pytest.approx(weight_lb, rel=0.01)
    assert units.OZ_IN_TO_NM == pytest.approx(0.00706155, rel=1e-6)
    assert units.LBF_FT_TO_NM == pytest.approx(1.3558179, rel=1e-6)


def report_cantilever_moment_lb_in(end_load_lb: float, length_in: float, link_lb: float) -> float:
    """Appendix A's formula M = P L + w L^2 / 2 (w = weight per inch)."""
    return end_load_lb * length_in + (link_lb / length_in) * length_in ** 2 / 2.0


def test_report_joint_torques_come_out_in_the_report_load_case():
    """The report's J1 and J2 figures are each link as a cantilever, outboard weight at its end.

    Appendix A: link III carries P = 6.0 lb over 12 in -> 78.60 lb in = 1257.6 oz-in;
    link II carries P = 3.7 + 6 + 1.1 = 10.8 lb over 24 in -> 285.6 lb in = 4569.6 oz-in.
    That is exactly the static torque of the poses where everything outboard hangs
    straight down from the link's end: J1 with link II level and link III and the gripper
    hanging; J2 with link III level and the gripper hanging. No safety factor is in these
    figures; the factors 1.4 and 1.9 come from the 400 oz-in rating afterwards.
    """
    assert report_cantilever_moment_lb_in(10.8, 24, 2.2) * 16 == pytest.approx(P.REPORT_J1_TORQUE_OZ_IN)
    assert report_cantilever_moment_lb_in(6.0, 12, 1.1) * 16 == pytest.approx(P.REPORT_J2_TORQUE_OZ_IN)

    g = units.G_EARTH_M_S2
    t1 = static_torques_nm(0.0, -HALF_PI, 0.0, GEO, g)[0]
    t2 = static_torques_nm(0.0, 0.0, -HALF_PI, GEO, g)[1]
    assert t1 / units.OZ_IN_TO_NM == pytest.approx(4569.6, rel=1e-9)
    assert t2 / units.OZ_IN_TO_NM == pytest.approx(1257.6, rel=1e-9)
    # At the motor (the report ignores gear losses): 285.6 and 209.6 oz-in, factors 1.4 and 1.9.
    j1_sprockets = DRIVES["j1"].ratio / DRIVES["j1"].motor.gearhead.ratio
    j2_sprockets = DRIVES["j2"].ratio / DRIVES["j2"].motor.gearhead.ratio
    assert (j1_sprockets, j2_sprockets) == (16.0, 6.0)
    at_motor_1 = t1 / j1_sprockets / units.OZ_IN_TO_NM
    at_motor_2 = t2 / j2_sprockets / units.OZ_IN_TO_NM
    assert at_motor_1 == pytest.approx(285.6) and at_motor_2 == pytest.approx(209.6)
    rated_oz_in = DRIVES["j1"].motor.rated_torque_nm / units.OZ_IN_TO_NM
    assert rated_oz_in == pytest.approx(400.0)
    assert round(rated_oz_in / at_motor_1, 1) == P.REPORT_J1_SAFETY_FACTOR
    assert round(DRIVES["j2"].motor.rated_torque_nm / units.OZ_IN_TO_NM / at_motor_2, 1) == P.REPORT_J2_SAFETY_FACTOR


def test_full_horizontal_extension_needs_more_than_the_report_case():
    """Stretched out level, the same masses need 372.2 lb in at J1 and 86.6 lb in at J2.

    Still inside the 400 oz-in motor through 16:1 with the assumed sprocket losses, so
    the arm can hold any pose on Earth, with little margin at J1.
    """
    t1, t2, t3 = static_torques_nm(0.0, 0.0, 0.0, GEO, units.G_EARTH_M_S2)
    assert t1 / units.LBF_IN_TO_NM == pytest.approx(372.2, rel=1e-9)
    assert t2 / units.LBF_IN_TO_NM == pytest.approx(86.6, rel=1e-9)
    assert t1 < DRIVES["j1"].rated_output_torque_nm
    assert t2 < DRIVES["j2"].rated_output_torque_nm


def test_wrist_bend_safety_factor():
    """'WRIST AND GRIPPER': 200 oz-in motor, 3:1 sprockets, safety factor 4.7 (gripper level)."""
    t3 = static_torques_nm(0.0, 0.0, 0.0, GEO, units.G_EARTH_M_S2)[2]
    factor = 200.0 * 3.0 / (t3 / units.OZ_IN_TO_NM)
    assert round(factor, 1) == P.REPORT_J3_SAFETY_FACTOR


def test_report_test_load_adds_table_4_differences():
    """Table 4: the 1 oz load adds 0.75 lb in to link III's moment and 1.50 lb in to link II's."""
    g, load = units.G_EARTH_M_S2, P.REPORT_TEST_LOAD_KG
    for pose, joint, diff_lb_in in (((0.0, 0.0, -HALF_PI), 1, 0.75), ((0.0, -HALF_PI, 0.0), 0, 1.50)):
        loaded = static_torques_nm(*pose, GEO, g, load)[joint]
        unloaded = static_torques_nm(*pose, GEO, g)[joint]
        assert (loaded - unloaded) / units.LBF_IN_TO_NM == pytest.approx(diff_lb_in, rel=1e-9)


def test_mount_moment_is_near_table_4():
    """Table 4's 'mobile mount' moment, 888 lb in: the assumed masses give it within 10 %."""
    m = mount_static_moment_nm(0.0, 0.0, 0.0, GEO, P.ARM_PLANT_PARAMS.mount, units.G_EARTH_M_S2)
    assert m / units.LBF_IN_TO_NM == pytest.approx(P.REPORT_MOUNT_MOMENT_LB_IN, rel=0.10)
    # Below the shaft's 55 lbf ft plus the moment of the mobile arm itself: same order.
    assert m < 1.5 * P.REPORT_SHAFT_TORQUE_LBF_FT * units.LBF_FT_TO_NM


def test_report_torque_is_carried_by_the_motor_current():
    """Holding J1 in the report's load case takes current = torque / (eta N Kt)."""
    plant = posed(0.0, -HALF_PI, 0.0)
    drive = DRIVES["j1"]
    need_nm = P.REPORT_J1_TORQUE_OZ_IN * units.OZ_IN_TO_NM
    hold_a = need_nm / drive.kt_out_nm_a
    duty = hold_a * drive.motor.r_ohm / V_BUS
    run(plant, 2.0, duty=only(J1, duty), enable=only(J1, True, False))
    assert plant.vel_rad_s[J1] == 0.0
    assert plant.pos_rad[J1] == pytest.approx(0.0, abs=1e-4)   # only the first ms of current rise
    assert plant.i_a[J1] == pytest.approx(hold_a, rel=1e-6)
    gearhead_out_oz_in = hold_a * drive.motor.kt_nm_a * drive.motor.gearhead.ratio \
        * drive.motor.gearhead.efficiency / units.OZ_IN_TO_NM
    assert gearhead_out_oz_in == pytest.approx(285.6 / P.SPROCKET_EFFICIENCY ** 2, rel=1e-6)


# ---- motor physics -----------------------------------------------------------------------------
def analytic_steady_speed(drive, volts: float, load_nm: float = 0.0) -> float:
    m = drive.motor
    n = m.gearhead.ratio * math.prod(s.ratio for s in drive.stages)
    eta = m.gearhead.efficiency * math.prod(s.efficiency for s in drive.stages)
    kt, ke = eta * n * m.kt_nm_a, n * m.ke_v_s_rad
    coulomb = n * m.coulomb_nm + drive.output_coulomb_nm
    viscous = n * n * m.viscous_nm_s_rad + drive.output_viscous_nm_s_rad
    return (kt * volts / m.r_ohm - load_nm - coulomb) / (viscous + kt * ke / m.r_ohm)


def test_constant_duty_reaches_the_analytic_steady_speed():
    """In orbit (no gravity) J2 at duty 0.5 settles where drive = back-EMF + friction."""
    plant = posed(0.0, -1.5, 0.0, gravity="orbit")
    drive = DRIVES["j2"]
    run(plant, 3.0, duty=only(J2, 0.5), enable=only(J2, True, False))
    expected = analytic_steady_speed(drive, 0.5 * V_BUS)
    assert plant.vel_rad_s[J2] == pytest.approx(expected, rel=1e-6)
    u = 0.5 * V_BUS
    assert plant.i_a[J2] == pytest.approx((u - drive.ke_out_v_s_rad * expected) / drive.motor.r_ohm, rel=1e-6)
    assert expected == pytest.approx(drive.steady_speed_rad_s(u), rel=1e-12)


def test_half_rpm_is_reachable_against_gravity_at_full_extension():
    """The report's 1/2 RPM: J1 can lift the stretched-out arm at that speed from 24 V."""
    load = static_torques_nm(0.0, 0.0, 0.0, GEO, units.G_EARTH_M_S2)[0]
    assert analytic_steady_speed(DRIVES["j1"], 24.0, load) > P.JOINT_SPEED_RAD_S


def test_current_follows_the_exact_rl_response_with_the_shaft_held():
    """Brake on, shaft still: i(t) = V/R (1 - exp(-t R / L)) at every 1 ms step, exactly."""
    plant = posed(0.0, 0.0, 0.0, gravity="orbit")
    drive = DRIVES["j2"]
    r, l_h, u = drive.motor.r_ohm, drive.motor.l_h, 0.3 * V_BUS
    for k in range(1, 20):
        plant.step(DT, only(J2, 0.3), only(J2, True, False), [True] * 6, V_BUS)
        assert plant.vel_rad_s[J2] == 0.0
        assert plant.i_a[J2] == pytest.approx(u / r * (1 - math.exp(-k * DT * r / l_h)), rel=1e-12)


def test_large_steps_stay_stable_and_match_the_settled_state():
    """The stiff RL circuit (tau 0.2-1 ms) at steps of 1 to 50 ms (substeps as long): no blow-up, same end state."""
    channels = list(P.ARM_PLANT_PARAMS.channels)
    free = channels[J4].drive
    free = dataclasses.replace(free, stop_lo_rad=-math.inf, stop_hi_rad=math.inf)
    channels[J4] = dataclasses.replace(channels[J4], drive=free)
    params = dataclasses.replace(P.ARM_PLANT_PARAMS, channels=tuple(channels))
    fine = ArmPlant(params, gravity="orbit")
    coarse = ArmPlant(dataclasses.replace(params, max_substep_s=0.05), gravity="orbit")
    for plant, dt_s, steps in ((fine, 0.001, 10_000), (coarse, 0.05, 200)):    # 10 s: settled at either step
        for _ in range(steps):
            plant.step(dt_s, only(J4, 0.6), only(J4, True, False), [False] * 6, 27.5)
    assert abs(coarse.i_a[J4]) < 27.5 / free.motor.r_ohm
    assert coarse.vel_rad_s[J4] == pytest.approx(fine.vel_rad_s[J4], rel=1e-6)
    assert coarse.i_a[J4] == pytest.approx(fine.i_a[J4], rel=1e-6)
    assert coarse.vel_rad_s[J4] == pytest.approx(free.steady_speed_rad_s(0.6 * 27.5), rel=1e-6)


# ---- gravity, brakes, orbit --------------------------------------------------------------------
def test_brake_holds_the_stretched_out_arm_against_gravity():
    plant = posed(0.0, 0.0, 0.0)
    start = plant.pos_rad.copy()
    run(plant, 10.0, brake=[True] * 6)
    assert np.array_equal(plant.pos_rad[:4], start[:4])
    assert np.all(plant.vel_rad_s == 0.0)


def test_unpowered_unbraked_arm_falls_on_earth_but_not_in_orbit():
    earth, orbit = posed(0.0, 0.0, 0.0), posed(0.0, 0.0, 0.0, gravity="orbit")
    run(earth, 1.0)
    run(orbit, 1.0)
    assert earth.pos_rad[J1] < -0.1 and earth.pos_rad[J2] < -0.1
    assert np.array_equal(orbit.pos_rad[:3], [0.0, 0.0, 0.0])
    # J1's first millisecond: a = (gravity - Coulomb) / inertia, opposed by nothing else.
    plant = posed(0.0, 0.0, 0.0)
    inertia = DRIVES["j1"].inertia_kg_m2 + joint_inertias_kg_m2(0.0, 0.0, 0.0, GEO)[0]
    gravity = static_torques_nm(0.0, 0.0, 0.0, GEO, units.G_EARTH_M_S2)[0]
    plant.step(DT, [0.0] * 6, [False] * 6, [False] * 6, V_BUS)
    expected = -(gravity - DRIVES["j1"].coulomb_nm) / (inertia / DT + DRIVES["j1"].viscous_nm_s_rad)
    assert plant.vel_rad_s[J1] == pytest.approx(expected, rel=1e-9)


def test_a_joint_coasts_in_orbit_and_stops_by_friction_alone():
    """J2 set spinning, bridge open: w(t) = (w0 + f/b) exp(-b t / J) - f/b, then it stays put."""
    plant = posed(0.0, 0.0, 0.0, gravity="orbit")
    plant.set_joint_state(J2, 0.0, vel_rad_s=0.5)
    drive = DRIVES["j2"]
    inertia = drive.inertia_kg_m2 + joint_inertias_kg_m2(0.0, 0.0, 0.0, GEO)[1]
    f, b = drive.coulomb_nm, drive.viscous_nm_s_rad
    stop_s = inertia / b * math.log(1 + b * 0.5 / f)
    steps = 0
    while plant.vel_rad_s[J2] != 0.0:
        plant.step(DT, [0.0] * 6, [False] * 6, [False] * 6, V_BUS)
        steps += 1
        assert steps < 10_000
    assert steps * DT == pytest.approx(stop_s, rel=0.01)
    resting = plant.pos_rad[J2]
    run(plant, 1.0)
    assert plant.pos_rad[J2] == resting


def test_energy_never_grows_without_power_in_orbit():
    """Passivity: with drives open or shorted and no gravity, kinetic energy only decays."""
    for enable in ([False] * 6, [True] * 6):
        plant = ArmPlant(gravity="orbit")
        for channel, w in zip(range(6), (0.2, -0.5, 1.0, 2.0, 10.0, 0.1)):
            plant.set_joint_state(channel, plant.pos_rad[channel], vel_rad_s=w)
        energy = plant.kinetic_energy_j()
        for _ in range(3000):
            plant.step(DT, [0.0] * 6, enable, [False] * 6, V_BUS)
            now = plant.kinetic_energy_j()
            assert now <= energy * (1 + 1e-6) + 1e-12
            energy = now
        assert energy == 0.0


def test_sixty_seconds_of_random_commands_stay_bounded():
    """1 ms steps for 60 s, duty, enable and brake changing at random every 0.1 s: no blow-up."""
    rng = np.random.default_rng(7)
    plant = ArmPlant()
    drives = [c.drive for c in P.CHANNEL_PARAMS]
    max_i = np.array([2 * V_BUS / d.motor.r_ohm for d in drives])
    max_w = np.array([3 * V_BUS / d.ke_out_v_s_rad for d in drives])
    lo = np.array([d.stop_lo_rad for d in drives])
    hi = np.array([d.stop_hi_rad for d in drives])
    for tick in range(60_000):
        if tick % 100 == 0:
            duty = rng.uniform(-1, 1, 6).tolist()
            enable = (rng.random(6) < 0.8).tolist()
            brake = (rng.random(6) < 0.2).tolist()
        plant.step(DT, duty, enable, brake, V_BUS)
        if tick % 50 == 0:
            assert np.all(np.abs(plant.i_a) <= max_i)
            assert np.all(np.abs(plant.vel_rad_s) <= max_w)
    assert np.all(np.isfinite(plant.pos_rad)) and np.all((plant.pos_rad >= lo) & (plant.pos_rad <= hi))


def test_a_long_step_is_the_same_as_its_1_ms_substeps():
    a, b = posed(0.3, -0.4, 0.2), posed(0.3, -0.4, 0.2)
    duty, enable = [0.4, -0.3, 0.2, 0.5, -0.5, 0.3], [True] * 6
    for _ in range(50):
        a.step(DT, duty, enable, [False] * 6, V_BUS)
    b.step(0.05, duty, enable, [False] * 6, V_BUS)
    assert np.allclose(a.pos_rad, b.pos_rad, rtol=0, atol=1e-12)
    assert np.allclose(a.i_a, b.i_a, rtol=0, atol=1e-12)
    b.step(0.0, duty, enable, [False] * 6, V_BUS)
    assert np.array_equal(a.pos_rad, b.pos_rad)


# ---- gripper -----------------------------------------------------------------------------------
def test_gripper_stops_at_its_end_switches_and_grips_nothing_empty():
    plant = ArmPlant()
    close = only(GRIPPER, -1.0), only(GRIPPER, True, False)
    run(plant, 3.0, *close)
    assert plant.limit_lo_switch[GRIPPER] and not plant.limit_hi_switch[GRIPPER]
    assert 0.0 <= plant.gripper_opening_m <= P.GripperParams().closed_switch_m
    assert plant.i_a[GRIPPER] == 0.0 and plant.vel_rad_s[GRIPPER] == 0.0
    assert plant.grip_force_n == 0.0
    run(plant, 3.0, only(GRIPPER, 1.0), only(GRIPPER, True, False))
    assert plant.limit_hi_switch[GRIPPER] and plant.home_switch[GRIPPER]
    assert P.GripperParams().open_switch_m <= plant.gripper_opening_m <= P.GripperParams().stroke_m
    assert plant.i_a[GRIPPER] == 0.0


def test_gripper_closed_on_an_object_grips_with_the_stall_force():
    plant = ArmPlant()
    plant.set_object(0.02)
    run(plant, 3.0, only(GRIPPER, -1.0), only(GRIPPER, True, False))
    drive = DRIVES["gripper"]
    stall_n = drive.stall_torque_nm(V_BUS) / P.GripperParams().lead_m_per_rad
    assert plant.gripper_opening_m == pytest.approx(0.02, abs=1e-12)
    assert not plant.limit_lo_switch[GRIPPER]
    assert plant.grip_force_n == pytest.approx(stall_n, rel=1e-6)
    assert 200 < plant.grip_force_n < 500
    # Drive off (shorted): the force goes; open again: the object can be taken away.
    run(plant, 0.1, [0.0] * 6, only(GRIPPER, True, False))
    assert plant.grip_force_n < 1e-9
    run(plant, 0.5, only(GRIPPER, 1.0), only(GRIPPER, True, False))
    assert plant.grip_force_n == 0.0 and plant.gripper_opening_m > 0.02
    plant.set_object(None)
    run(plant, 3.0, only(GRIPPER, -1.0), only(GRIPPER, True, False))
    assert plant.limit_lo_switch[GRIPPER]


def test_an_object_wider_than_the_jaws_cannot_be_put_in():
    plant = ArmPlant()
    with pytest.raises(ValueError):
        plant.set_object(plant.gripper_opening_m + 0.001)


# ---- encoders and switches ---------------------------------------------------------------------
def test_encoders_count_motor_quadrature_edges_from_power_on():
    plant = ArmPlant()
    assert np.array_equal(plant.encoder_counts, np.zeros(6, dtype=np.int64))
    cpr = P.CHANNEL_PARAMS[J1].counts_per_output_rev
    assert cpr == 400 * 1600
    count_rad = 2 * math.pi / cpr
    start = plant.pos_rad[J1]
    for counts in (1, 7, 12345, -1, -640_000):
        plant.set_joint_state(J1, start + (counts + 0.5) * count_rad)
        assert plant.encoder_counts[J1] == counts
        plant.set_joint_state(J1, start + (counts + 0.999) * count_rad)
        assert plant.encoder_counts[J1] == counts
    assert plant.encoder_counts.dtype == np.int64


def test_home_and_limit_switches():
    plant = ArmPlant()
    params = P.CHANNEL_PARAMS
    assert not plant.home_switch[J2]                      # powers on just below home
    for channel in (J1, J2, J3, J4, MOUNT):
        c = params[channel]
        plant.set_joint_state(channel, c.home_rad)
        assert plant.home_switch[channel] and not plant.limit_lo_switch[channel]
        plant.set_joint_state(channel, c.limit_hi_rad + 0.01)
        assert plant.limit_hi_switch[channel]
        plant.set_joint_state(channel, c.limit_lo_rad - 0.01)
        assert plant.limit_lo_switch[channel] and not plant.home_switch[channel]
    run(plant, 2.0, only(J2, -1.0), only(J2, True, False))   # driven into the hard stop
    assert plant.pos_rad[J2] == P.CHANNEL_PARAMS[J2].drive.stop_lo_rad


# ---- kinematics and the mount ------------------------------------------------------------------
def test_forward_kinematics_at_known_poses():
    r0 = P.MountParams().base_radius_m
    reach = GEO.link2_m + GEO.link3_m + GEO.tip_m
    h = GEO.link1_m
    pose = np.zeros(6)
    assert np.allclose(gripper_position_m(pose), [r0 + reach, 0, h], atol=1e-12)
    pose[J1] = HALF_PI
    assert np.allclose(gripper_position_m(pose), [r0, 0, h + reach], atol=1e-12)
    pose[:] = 0.0
    pose[J2], pose[J3] = -HALF_PI, -HALF_PI                # link III down, gripper back inward
    assert np.allclose(gripper_position_m(pose),
                       [r0 + GEO.link2_m - GEO.tip_m, 0, h - GEO.link3_m], atol=1e-12)
    pose[:] = 0.0
    pose[MOUNT], pose[J4], pose[GRIPPER] = HALF_PI, 1.0, 50.0   # roll and jaws move no tip
    assert np.allclose(gripper_position_m(pose), [0, r0 + reach, h], atol=1e-12)
    plant = posed(0.0, 0.0, 0.0)
    plant.set_joint_state(MOUNT, 0.0)
    assert np.allclose(plant.gripper_position_m(), [r0 + reach, 0, h], atol=1e-12)


def test_mount_turns_the_arm_about_the_shaft_without_gravity_load():
    plant = posed(0.0, 0.0, 0.0)
    assert plant.static_torques_nm()[0] > 0                 # the arm itself is loaded
    before = plant.gripper_position_m()
    brakes = [True, True, True, True, False, False]        # arm braked, mount free
    run(plant, 1.0, brake=brakes)
    assert plant.pos_rad[MOUNT] == P.CHANNEL_PARAMS[MOUNT].start_pos_rad   # no gravity on the mount
    run(plant, 4.0, only(MOUNT, 0.8), only(MOUNT, True, False), brakes)
    after = plant.gripper_position_m()
    assert plant.pos_rad[MOUNT] > 0.5
    assert math.hypot(*after[:2]) == pytest.approx(math.hypot(*before[:2]), rel=1e-12)
    assert after[2] == pytest.approx(before[2], abs=1e-12)
    # The mount's load is the arm's inertia about the shaft: folding the arm in lowers it.
    stretched = plant.load_inertia_kg_m2[MOUNT]
    plant.set_joint_state(J1, HALF_PI)
    assert plant.load_inertia_kg_m2[MOUNT] < stretched


def test_payload_and_modes_are_checked():
    with pytest.raises(ValueError):
        ArmPlant(gravity="moon")
    with pytest.raises(ValueError):
        ArmPlant(payload_kg=-1.0)
    plant = ArmPlant(payload_kg=0.5)
    assert plant.params.channels[0].drive.name == ARM_CHANNELS[0]
    heavy = plant.static_torques_nm()
    plant.set_payload(0.0)
    assert plant.static_torques_nm()[0] < heavy[0]
    plant.set_gravity("orbit")
    assert plant.static_torques_nm() == (0.0, 0.0, 0.0)
