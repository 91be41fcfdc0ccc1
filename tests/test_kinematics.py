"""Inverse kinematics against `hil_sim.arm.gripper_position_m`, and the demo scene's poses and paths."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from hil_sim.arm import gripper_position_m, static_torques_nm
from hil_sim.arm_params import ARM_PLANT_PARAMS, CHANNEL_PARAMS
from host_tools.apps.kinematics import (DEMO_SCENE, JointPose, Scene, Unreachable, chain_points_m, check_limits,
                                   forward, inverse, steps)
from protocol.units import DEG, G_EARTH_M_S2

GEO = ARM_PLANT_PARAMS.geometry
MOUNT = ARM_PLANT_PARAMS.mount
GRIP = ARM_PLANT_PARAMS.gripper
R0 = MOUNT.base_radius_m
REACH = GEO.link2_m + GEO.link3_m + GEO.tip_m
LIMITS = {c.drive.name: (c.limit_lo_rad, c.limit_hi_rad) for c in CHANNEL_PARAMS}
RATED_NM = {c.drive.name: c.drive.rated_output_torque_nm for c in CHANNEL_PARAMS}
DOWN = -math.pi / 2
TOL_M = 1e-9
MARGIN_RAD = 10 * DEG          # every demo pose at least this far inside every limit switch


def fk(pose: JointPose) -> np.ndarray:
    return gripper_position_m(pose.positions(), GEO, MOUNT)


def angle_diff(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


def inside(name: str, margin: float = 1e-6):
    lo, hi = LIMITS[name]
    return st.floats(lo + margin, hi - margin)


# ---- inverse kinematics --------------------------------------------------------------------------
@settings(max_examples=400, deadline=None)
@given(q1=inside("j1"), q2=inside("j2"), q3=inside("j3"), phi=inside("mount"))
def test_inverse_recovers_every_pose_within_the_limits(q1, q2, q3, phi):
    pose = JointPose(q1, q2, q3, phi)
    target = fk(pose)
    assume(math.hypot(target[0], target[1]) > 1e-3)
    pitch = q1 + q2 + q3
    solved = inverse(target, pitch, elbow="up" if q2 <= 0 else "down")
    np.testing.assert_allclose(fk(solved), target, rtol=0, atol=TOL_M)
    assert angle_diff(solved.q1 + solved.q2 + solved.q3, pitch) < 1e-9
    assert angle_diff(solved.mount, phi) < 1e-9
    if abs(q2) > 1e-3:          # away from the stretched/fold singularity the solution is unique
        for got, want in zip((solved.q1, solved.q2, solved.q3), (q1, q2, q3)):
            assert abs(got - want) < 1e-7


@settings(max_examples=400, deadline=None)
@given(x=st.floats(-2.0, 2.0), y=st.floats(-2.0, 2.0), z=st.floats(-1.0, 1.6),
       pitch=st.floats(-math.pi, math.pi), elbow=st.sampled_from(["up", "down"]))
def test_inverse_either_hits_the_target_or_says_unreachable(x, y, z, pitch, elbow):
    try:
        solved = inverse((x, y, z), pitch, elbow=elbow)
    except Unreachable:
        return
    np.testing.assert_allclose(fk(solved), (x, y, z), rtol=0, atol=TOL_M)
    assert angle_diff(solved.q1 + solved.q2 + solved.q3, pitch) < 1e-9
    assert (solved.q2 <= 0) if elbow == "up" else (solved.q2 >= 0)
    check_limits(solved)


def test_stretched_out_flat_is_all_zeros_on_both_branches():
    for elbow in ("up", "down"):
        pose = inverse((R0 + REACH, 0.0, GEO.link1_m), 0.0, elbow=elbow)
        assert max(abs(pose.q1), abs(pose.q2), abs(pose.q3), abs(pose.mount)) < 1e-7
        np.testing.assert_allclose(fk(pose), (R0 + REACH, 0.0, GEO.link1_m), atol=TOL_M)


def test_both_elbow_branches_reach_the_same_point():
    target = (0.3, 1.5, 0.6)            # azimuth 78.7 deg, 0.77 m out from J1, 0.30 m above it
    up = inverse(target, 0.0, elbow="up")
    down = inverse(target, 0.0, elbow="down")
    assert up.q2 < 0 < down.q2 and up.q1 > down.q1
    assert math.isclose(up.q2, -down.q2, abs_tol=1e-12)
    for pose in (up, down):
        np.testing.assert_allclose(fk(pose), target, atol=TOL_M)
        assert math.isclose(pose.mount, math.atan2(1.5, 0.3), abs_tol=1e-12)


def test_known_pose_pointing_down():
    # Link II horizontal, link III and the gripper hanging straight down, mount at -90 deg:
    # tip (L2, -L3 - tip) from J1 in the plane.
    target = (0.0, -(R0 + GEO.link2_m), GEO.link1_m - GEO.link3_m - GEO.tip_m)
    pose = inverse(target, DOWN, elbow="up")
    assert (pose.q1, pose.q2, pose.q3, pose.mount) == pytest.approx((0.0, -math.pi / 2, 0.0, -math.pi / 2),
                                                                    abs=1e-12)
    np.testing.assert_allclose(fk(pose), target, atol=TOL_M)


def test_elbow_up_solution_of_a_surface_pick_is_the_expected_one():
    pose = inverse(DEMO_SCENE.debris_xyz_m, DOWN, elbow="up")
    # Wrist point in the plane: (0.538, -0.0826) from J1; triangle L2, L3, r.
    wx = math.hypot(*DEMO_SCENE.debris_xyz_m[:2]) - R0
    wz = DEMO_SCENE.debris_xyz_m[2] + GEO.tip_m - GEO.link1_m
    r2 = wx * wx + wz * wz
    q2 = -math.acos((r2 - GEO.link2_m ** 2 - GEO.link3_m ** 2) / (2 * GEO.link2_m * GEO.link3_m))
    assert pose.q2 == pytest.approx(q2, abs=1e-12)
    assert pose.q1 + pose.q2 + pose.q3 == pytest.approx(DOWN, abs=1e-12)
    assert pose.mount == pytest.approx(-45 * DEG, abs=1e-12)


@pytest.mark.parametrize("target, pitch, words", [
    ((R0 + REACH + 0.01, 0.0, GEO.link1_m), 0.0, "out of reach"),
    ((3.0, 2.0, 0.3), DOWN, "out of reach"),
    # wrist point right on J1: closer than L2 - L3
    ((R0 + GEO.tip_m, 0.0, GEO.link1_m), 0.0, "too close"),
    ((0.0, 0.0, 0.5), DOWN, "central shaft"),
])
def test_unreachable_targets_raise_with_the_reason(target, pitch, words):
    for elbow in ("up", "down"):
        with pytest.raises(Unreachable, match=words):
            inverse(target, pitch, elbow=elbow)


def test_limit_switch_violations_name_the_joint_and_angle():
    # Tip far below J1 pointing down: elbow up works, elbow down needs J1 at -90 deg.
    inverse((R0 + 0.3, 0.0, -0.55), DOWN, elbow="up")
    with pytest.raises(Unreachable, match=r"j1 would be at -1\.57[0-9]+ rad \(-90\.[0-9] deg\).*-60\.0 \.\. 90\.0"):
        inverse((R0 + 0.3, 0.0, -0.55), DOWN, elbow="down")
    # The elbow-down branch of the demo's surface pick would bend J3 back past -135 deg.
    with pytest.raises(Unreachable, match="elbow down: j3 would be at"):
        inverse(DEMO_SCENE.debris_xyz_m, DOWN, elbow="down")
    # Directly behind the mount's zero: the mount's +-170 deg switches.
    with pytest.raises(Unreachable, match=r"mount would be at 3\.1416 rad \(180\.0 deg\)"):
        inverse((-1.3, 0.0, 0.2), DOWN)
    # Folded tighter than J2's -135 deg switch (and, mirrored, past +135).
    high_in = (1.3 * math.cos(80 * DEG), 1.3 * math.sin(80 * DEG), 0.4)
    with pytest.raises(Unreachable, match=r"j2 would be at -2\.50[0-9]+ rad \(-143\.3 deg\)"):
        inverse(high_in, -0.5, elbow="up")
    with pytest.raises(Unreachable, match=r"j2 would be at 2\.50[0-9]+ rad \(143\.3 deg\)"):
        inverse(high_in, -0.5, elbow="down")
    # A margin narrows the range.
    pose = inverse(DEMO_SCENE.debris_xyz_m, DOWN)
    inverse(DEMO_SCENE.debris_xyz_m, DOWN, margin_rad=15 * DEG)
    with pytest.raises(Unreachable, match="margin of 20.0 deg"):
        inverse(DEMO_SCENE.debris_xyz_m, DOWN, margin_rad=20 * DEG)
    assert LIMITS["j2"][0] + 15 * DEG < pose.q2 < LIMITS["j2"][0] + 20 * DEG


@pytest.mark.parametrize("kwargs, words", [
    (dict(target_xyz_m=(1.0, 0.0), pitch_rad=0.0), "three finite numbers"),
    (dict(target_xyz_m=(1.0, float("nan"), 0.0), pitch_rad=0.0), "three finite numbers"),
    (dict(target_xyz_m="abc", pitch_rad=0.0), "three numbers"),
    (dict(target_xyz_m=(1.5, 0.0, 0.3), pitch_rad=float("inf")), "pitch_rad must be finite"),
    (dict(target_xyz_m=(1.5, 0.0, 0.3), pitch_rad=0.0, elbow="left"), "elbow must be one of"),
    (dict(target_xyz_m=(1.5, 0.0, 0.3), pitch_rad=0.0, margin_rad=-0.1), "margin_rad"),
    (dict(target_xyz_m=(1.5, 0.0, 0.3), pitch_rad=0.0, geometry=dataclasses.replace(GEO, link3_m=0.0)),
     "link3_m"),
    (dict(target_xyz_m=(1.5, 0.0, 0.3), pitch_rad=0.0, mount=dataclasses.replace(MOUNT, reach_sign=0.0)),
     "reach_sign"),
])
def test_bad_input_is_a_value_error_not_unreachable(kwargs, words):
    with pytest.raises(ValueError, match=words) as err:
        inverse(**kwargs)
    assert not isinstance(err.value, Unreachable)


def test_other_geometry_and_inward_reach_round_trip():
    geo = dataclasses.replace(GEO, link2_m=0.3, link3_m=0.2, tip_m=0.1, link1_m=0.2)
    mnt = dataclasses.replace(MOUNT, reach_sign=-1.0)
    pose = JointPose(0.3, -0.9, 0.2, 1.0)
    target = gripper_position_m(pose.positions(), geo, mnt)
    solved = inverse(target, pose.q1 + pose.q2 + pose.q3, geo, mnt, elbow="up")
    np.testing.assert_allclose(gripper_position_m(solved.positions(), geo, mnt), target, atol=TOL_M)
    assert (solved.q1, solved.q2, solved.q3, solved.mount) == pytest.approx((0.3, -0.9, 0.2, 1.0), abs=1e-9)


def test_pose_helpers_agree_with_the_plant():
    pose = JointPose(0.4, -1.2, -0.3, 0.7)
    assert pose.as_targets() == {"j1": 0.4, "j2": -1.2, "j3": -0.3, "mount": 0.7}
    assert pose.positions(j4_rad=0.5, gripper_rad=2.0) == [0.4, -1.2, -0.3, 0.5, 2.0, 0.7]
    np.testing.assert_allclose(forward(pose), fk(pose), atol=1e-15)
    pts = chain_points_m(pose)
    np.testing.assert_allclose(pts["tip"], fk(pose), atol=1e-12)
    np.testing.assert_allclose(pts["j1"], (R0 * math.cos(0.7), R0 * math.sin(0.7), GEO.link1_m), atol=1e-12)
    assert np.linalg.norm(pts["elbow"] - pts["j1"]) == pytest.approx(GEO.link2_m)
    assert np.linalg.norm(pts["wrist"] - pts["elbow"]) == pytest.approx(GEO.link3_m)
    assert np.linalg.norm(pts["tip"] - pts["wrist"]) == pytest.approx(GEO.tip_m)


# ---- the demo scene ------------------------------------------------------------------------------
STEPS = steps(DEMO_SCENE)
MOVES = [s for s in STEPS if s.action is None]


def test_step_sequence_and_shape():
    assert [s.name for s in STEPS] == ["home", "open gripper", "approach debris", "descend", "close gripper",
                                       "lift", "carry to bin", "lower", "release", "retreat", "return home"]
    assert [s.action for s in STEPS if s.action] == ["open", "close", "open"]
    for s in STEPS:
        if s.action:
            assert s.targets == {}
        else:
            assert s.targets and set(s.targets) <= {"j1", "j2", "j3", "mount"}
    # The carry is the mount alone; the joints move alone going down and up.
    by_name = {s.name: s for s in STEPS}
    assert set(by_name["carry to bin"].targets) == {"mount"}
    for name in ("descend", "lift", "lower", "retreat"):
        assert set(by_name[name].targets) == {"j1", "j2", "j3"}
    assert [s.held_kg for s in STEPS] == [0, 0, 0, 0, DEMO_SCENE.debris_mass_kg, DEMO_SCENE.debris_mass_kg,
                                          DEMO_SCENE.debris_mass_kg, DEMO_SCENE.debris_mass_kg, 0, 0, 0]


def test_targets_applied_in_order_reach_each_expected_tip_position():
    angles: dict[str, float] = {}
    for s in STEPS:
        angles.update(s.targets)
        pose = JointPose(angles["j1"], angles["j2"], angles["j3"], angles["mount"])
        for got, want in zip((pose.q1, pose.q2, pose.q3, pose.mount), (s.pose.q1, s.pose.q2, s.pose.q3, s.pose.mount)):
            assert abs(got - want) < 1e-9
        np.testing.assert_allclose(fk(pose), s.tip_xyz_m, atol=1e-8)


def test_tip_lands_on_the_scene_points():
    by_name = {s.name: s for s in STEPS}
    sc = DEMO_SCENE
    for name, point in [("approach debris", sc.debris_approach_xyz_m), ("descend", sc.debris_xyz_m),
                        ("lift", sc.debris_approach_xyz_m), ("carry to bin", sc.bin_approach_xyz_m),
                        ("lower", sc.release_xyz_m), ("retreat", sc.bin_approach_xyz_m)]:
        np.testing.assert_allclose(by_name[name].tip_xyz_m, point, atol=TOL_M)
        assert angle_diff(by_name[name].pose.q1 + by_name[name].pose.q2 + by_name[name].pose.q3, DOWN) < 1e-12


def test_every_pose_is_inside_the_limits_with_margin():
    for s in STEPS:
        check_limits(s.pose, MARGIN_RAD, s.name)


def test_scene_numbers():
    sc = DEMO_SCENE
    # Debris rests on the surface, fits the open jaws with room, and is a small piece.
    assert sc.debris_xyz_m[2] - sc.debris_height_m / 2 == pytest.approx(sc.surface_z_m)
    assert sc.debris_width_m < GRIP.open_switch_m - 0.01
    assert sc.debris_width_m > GRIP.closed_switch_m + 0.01
    assert 0.2 <= sc.debris_mass_kg <= 0.5
    # Debris and bin at least 60 deg of mount apart; the carry step turns the mount by that.
    az_debris = math.atan2(sc.debris_xyz_m[1], sc.debris_xyz_m[0])
    az_bin = math.atan2(sc.bin_xyz_m[1], sc.bin_xyz_m[0])
    assert angle_diff(az_debris, az_bin) >= 60 * DEG
    carry = next(s for s in STEPS if s.name == "carry to bin")
    lift = next(s for s in STEPS if s.name == "lift")
    assert abs(carry.targets["mount"] - lift.pose.mount) >= 60 * DEG
    # Both within the arm's reach from J1 (0.538 m out of 1.118 m).
    for xyz in (sc.debris_xyz_m, sc.bin_xyz_m):
        assert math.hypot(xyz[0], xyz[1]) - R0 < 0.6 * REACH
    # The released block's bottom clears the rim; the carried block clears the rim well.
    assert sc.release_xyz_m[2] - sc.debris_height_m / 2 == pytest.approx(sc.bin_xyz_m[2] + sc.release_clearance_m)
    assert sc.bin_approach_xyz_m[2] - sc.debris_height_m / 2 > sc.bin_xyz_m[2] + 0.1


def test_joints_hold_the_load_on_earth():
    """Static torques in every pose (with what the jaws hold) well inside each joint's rating."""
    for s in STEPS:
        torques = static_torques_nm(s.pose.q1, s.pose.q2, s.pose.q3, GEO, G_EARTH_M_S2, s.held_kg)
        for name, tau in zip(("j1", "j2", "j3"), torques):
            # J1: the report's own safety factor is 1.4 (71 %); allow up to 80 %.
            assert abs(tau) < 0.8 * RATED_NM[name], (s.name, name, tau)
    # Even with the gripper held horizontal, J3 keeps a safety factor above 2.5 with the block.
    tau3 = static_torques_nm(0.0, 0.0, 0.0, GEO, G_EARTH_M_S2, DEMO_SCENE.debris_mass_kg)[2]
    assert RATED_NM["j3"] / tau3 > 2.5


def _interpolated(a: JointPose, b: JointPose, n: int = 200):
    for k in range(n + 1):
        t = k / n
        yield JointPose(*(x + t * (y - x) for x, y in zip((a.q1, a.q2, a.q3, a.mount), (b.q1, b.q2, b.q3, b.mount))))


def test_straight_joint_space_paths_stay_above_the_work_surface():
    sc = DEMO_SCENE
    grip_z = sc.debris_xyz_m[2]
    for prev, step in zip(MOVES, MOVES[1:]):
        for pose in _interpolated(prev.pose, step.pose):
            pts = chain_points_m(pose)
            # Links are straight between these points, so these bound the whole chain.
            for name in ("elbow", "wrist"):
                assert pts[name][2] > sc.surface_z_m + 0.05, (step.name, name)
            # The tip never dips below the grip point (the jaws' centre at the block's centre).
            assert pts["tip"][2] >= grip_z - 1e-6, step.name
            if step.held_kg:        # carrying: the block's bottom stays off the surface ...
                assert pts["tip"][2] - sc.debris_height_m / 2 >= sc.surface_z_m - 1e-6
            if step.name == "carry to bin":     # ... and well above the bin's rim
                assert pts["tip"][2] - sc.debris_height_m / 2 > sc.bin_xyz_m[2] + 0.1


def test_vertical_moves_stay_close_to_the_vertical():
    """Descend, lift, lower, retreat: straight joint-space moves drift little sideways."""
    for prev, step in zip(MOVES, MOVES[1:]):
        if step.name not in ("descend", "lift", "lower", "retreat"):
            continue
        x0, y0 = step.tip_xyz_m[:2]
        drift = max(math.hypot(p[0] - x0, p[1] - y0) for p in map(fk, _interpolated(prev.pose, step.pose)))
        assert drift < 0.02, (step.name, drift)


def test_scene_validation():
    with pytest.raises(ValueError, match="debris_mass_kg"):
        Scene(debris_mass_kg=0.0)
    with pytest.raises(ValueError, match="debris_xyz_m"):
        Scene(debris_xyz_m=(1.0, float("nan"), 0.0))
    with pytest.raises(ValueError, match="below the work surface"):
        Scene(surface_z_m=0.1)
    with pytest.raises(ValueError, match="release_clearance_m"):
        Scene(release_clearance_m=-0.01)
    with pytest.raises(ValueError, match="does not fit the jaws"):
        steps(Scene(debris_width_m=GRIP.stroke_m))
    with pytest.raises(Unreachable, match="home pose: j2"):
        steps(Scene(home=JointPose(0.0, -140 * DEG, 0.0, 0.0)))
    far = (3.0, 0.0, DEMO_SCENE.debris_xyz_m[2])
    with pytest.raises(Unreachable, match="out of reach"):
        steps(Scene(debris_xyz_m=far))
