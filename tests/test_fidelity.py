"""docs/fidelity.md, "The report, figure by figure": every emulator figure on the page, computed here.

Each table of the page sits between `<!-- table:KEY ... -->` and `<!-- end table:KEY -->` and is
rendered by `render(KEY)` from the emulator's own code: the plant's mass model and drives
(`hil_sim`), the firmware's parameters, profiles and control box (`firmware_py`), the tracker
closed around its plant on the simulated clock (`host_tools.apps.tracker_day`). The report's
side of each row is the report's text, cited. A test fails, with a diff, when a table on the
page is not what the code gives now. To write the tables into the page again:

    PYTHONPATH=. .venv/bin/python tests/test_fidelity.py

Units: the report's inches, pounds and ounce-inches beside SI (`protocol.units`).
"""
from __future__ import annotations

import dataclasses
import difflib
import itertools
import math
import re
from datetime import time
from functools import lru_cache
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
import pytest

from firmware_py import arm_config, profiles
from firmware_py import controller as firmware_controller
from firmware_py.params import ParamStore
from firmware_py.tracker import task as tracker_task
from firmware_py.tracker.box import ADC_COUNTS, quantize_dial
from hil_sim.arm import (ArmPlant, LoadModel, gripper_position_m, joint_inertias_kg_m2, mount_static_moment_nm,
                         static_torques_nm)
from hil_sim.arm_params import (AL_6061_DENSITY_LB_IN3, ARM_PLANT_PARAMS, BRAKE_HOLD_FACTOR, EXAMPLE_ARM_PLANT,
                                J1, J2, J3, MOUNT, REPORT_TEST_LOAD_KG, ArmPlantParams,
                                square_tube_weight_lb)
from hil_sim.held_object import ObjectParams
from hil_sim.plant import Plant, PlantParams
from hil_sim.tracker import TRACKER_PARAMS, TrackerPlant
from host_tools.apps.tracker_day import DayHal, DaySettings, run_day
from protocol.hal import HalCodec
from protocol.reasons import Reason
from protocol.states import Switch, SwitchPosition
from protocol.units import (G_EARTH_M_S2, IN_TO_M, LB_TO_KG, LBF_FT_TO_NM, LBF_IN_TO_NM, OZ_IN_TO_NM,
                            RPM_TO_RAD_S)

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "fidelity.md"
REGENERATE = "write the tables again with `PYTHONPATH=. .venv/bin/python tests/test_fidelity.py`"
HALF_PI = math.pi / 2.0
Pose = tuple[float, float, float]           # J1, J2, J3 in radians (`hil_sim.arm`'s angles)


class Row(NamedTuple):
    """One figure: the report's value (cited) beside the emulator's, and how they compare."""

    id: str
    figure: str
    report: str
    emulator: str
    compared: str


# ---- units and numbers -----------------------------------------------------------------------------------------

def lb_in(nm: float) -> float:
    return nm / LBF_IN_TO_NM


def oz_in(nm: float) -> float:
    return nm / OZ_IN_TO_NM


def inches(m: float) -> float:
    return m / IN_TO_M


def lb(kg: float) -> float:
    return kg / LB_TO_KG


def fahrenheit(c: float) -> float:
    return c * 9.0 / 5.0 + 32.0


def change(value: float, reference: float) -> str:
    """`value` against `reference` as a signed percentage."""
    return f"{(value / reference - 1.0) * 100.0:+.1f} %"


def compare(value: float, reported: float, digits: int) -> str:
    """"same" when `value` rounds to the report's figure (printed with `digits` decimals), else the change."""
    return "same" if round(value, digits) == round(reported, digits) else change(value, reported)


def pose_text(pose: Pose) -> str:
    return ", ".join(f"J{k + 1} {math.degrees(q):.0f}°" for k, q in enumerate(pose))


# ---- the arm: the report's poses and the travel --------------------------------------------------------------

# Appendix A treats each link as a level cantilever with everything outboard hung from its end:
J1_REPORT_POSE = (0.0, -HALF_PI, 0.0)      # link II level, link III and the gripper hanging
J2_REPORT_POSE = (0.0, 0.0, -HALF_PI)      # link III level, the gripper hanging
STRETCHED = (0.0, 0.0, 0.0)                # the whole arm level, pointing away from the shaft


def holding_lb_in(pose, arm: ArmPlantParams = ARM_PLANT_PARAMS, payload_kg: float = 0.0) -> tuple[float, ...]:
    """What J1, J2, J3 hold against gravity in `pose`, lb in (the plant's mass model)."""
    return tuple(lb_in(t) for t in static_torques_nm(*pose, arm.geometry, G_EARTH_M_S2, payload_kg))


def mount_lb_in(pose, arm: ArmPlantParams = ARM_PLANT_PARAMS, payload_kg: float = 0.0) -> float:
    """The manipulator's weight times its distance from the mount's shaft, lb in (Table 4's "mobile mount")."""
    return lb_in(mount_static_moment_nm(*pose, arm.geometry, arm.mount, G_EARTH_M_S2, payload_kg))


def travel(arm: ArmPlantParams = ARM_PLANT_PARAMS, step_deg: float = 15.0) -> list[Pose]:
    """J1-J3 poses between their limit switches every `step_deg`.

    The grid holds 0 on every joint, so it holds the stretched-out pose, where every gravity
    torque and the mount's moment peak (each is a sum of cosines with positive weights).
    """
    axes = []
    for channel in arm.channels[:3]:
        lo, hi = math.degrees(channel.limit_lo_rad) / step_deg, math.degrees(channel.limit_hi_rad) / step_deg
        axes.append([math.radians(k * step_deg) for k in range(math.ceil(lo - 1e-9), math.floor(hi + 1e-9) + 1)])
    return list(itertools.product(*axes))


def extreme(f: Callable[..., float], arm: ArmPlantParams, sign: float = 1.0) -> tuple[float, Pose]:
    """The largest (`sign` -1: the smallest) `f(pose, arm)` over the travel, and its pose.

    Many poses tie (J2's torque depends only on the angles of link III and the gripper, say): the
    one nearest the stretched-out pose, by the sum of the joint angles' sizes, is named.
    """
    def rank(found: tuple[float, Pose]) -> tuple[float, float]:
        value, pose = found
        return round(sign * value, 9), -sum(abs(q) for q in pose)
    return max(((f(pose, arm), pose) for pose in travel(arm)), key=rank)


def sprockets(drive) -> tuple[float, float]:
    """(ratio, efficiency) of a drive's stages after its gear head: the report's sprocket pairs."""
    return math.prod(s.ratio for s in drive.stages), math.prod(s.efficiency for s in drive.stages)


def motor_side(joint_lb_in: float, drive) -> tuple[float, float]:
    """The gear head's output torque (oz-in) for a joint torque, as the report does it and with the plant's losses."""
    ratio, efficiency = sprockets(drive)
    lossless = joint_lb_in * 16.0 / ratio
    return lossless, lossless / efficiency


def rated_oz_in(drive) -> float:
    return oz_in(drive.motor.rated_torque_nm)


def safety(joint_lb_in: float, drive) -> str:
    """The report's safety factor (rating / torque at the motor), then with the plant's sprocket losses."""
    lossless, lossy = motor_side(joint_lb_in, drive)
    return f"{rated_oz_in(drive) / lossless:.2f} ({rated_oz_in(drive) / lossy:.2f} with the sprockets' losses)"


def drive_of(arm: ArmPlantParams, channel: int):
    return arm.channels[channel].drive


# ---- Tables 1 and 2: links, mobile arm, track --------------------------------------------------------------

def link_rows(arm: ArmPlantParams = ARM_PLANT_PARAMS) -> list[Row]:
    geo, mount = arm.geometry, arm.mount
    rows = []
    for k, (name, length_m, mass_kg, length_in, weight_lb) in enumerate((
            ("link I", geo.link1_m, geo.link1_kg, 12, 1.1), ("link II", geo.link2_m, geo.link2_kg, 24, 2.2),
            ("link III", geo.link3_m, geo.link3_kg, 12, 1.1)), start=1):
        same = compare(inches(length_m), length_in, 1) == compare(lb(mass_kg), weight_lb, 2) == "same"
        rows.append(Row(f"L{k}", name, f"2 × 2 × 1/8 in tube, {length_in} in, {weight_lb} lb (Table 2)",
                        f"{inches(length_m):.1f} in ({length_m * 1000:.0f} mm), {lb(mass_kg):.2f} lb "
                        f"({mass_kg:.3f} kg): `ArmGeometry`", "same" if same else "differs"))
    tube_lb = square_tube_weight_lb(2.0, 0.125, inches(geo.link1_m))
    wrist_lb, elbow_lb = lb(geo.wrist_fixed_kg + geo.wrist_turned_kg), lb(geo.elbow_hw_kg)
    rows += [
        Row("L4", "12 in of tube from Table 1's density",
            f"{AL_6061_DENSITY_LB_IN3} lb/in³ (Table 1); Table 2 says 1.1 lb",
            f"{tube_lb:.3f} lb (`square_tube_weight_lb`)", change(tube_lb, 1.1)),
        Row("L5", "link II's length in the parts list", "2 × 2 × 21 in (Key to Figure 8, part 50)",
            f"{inches(geo.link2_m):.0f} in, as Table 2 and Appendix A", "the report disagrees with itself"),
        Row("L6", "weight at link III's end",
            "6 lb (Appendix A: link II's P = 3.7 + 6 + 1.1 = 10.8 lb)",
            f"{wrist_lb:.1f} lb: {lb(geo.wrist_fixed_kg):.1f} fixed at J3, {lb(geo.wrist_turned_kg):.1f} turned by "
            "it, the 2.0 lb gripper among them (`wrist_fixed_kg`, `wrist_turned_kg`)", compare(wrist_lb, 6.0, 1)),
        Row("L7", "elbow hardware at J2", "3.7 lb (Appendix A, link II's P; the OCR reads 317 lb)",
            f"{elbow_lb:.1f} lb (`elbow_hw_kg`)", compare(elbow_lb, 3.7, 1)),
        Row("L8", "mobile arm", "2 × 5 in rectangular aluminium, 3/16 in wall (MOBILE ARM); no weight",
            f"{lb(mount.mobile_arm_kg):.1f} lb ({mount.mobile_arm_kg:.2f} kg): that tube, an ASSUMED "
            f"{mobile_arm_length_in(mount):.0f} in long (`MountParams.mobile_arm_kg`)", "not in the report"),
    ]
    rows.append(track_row(arm))
    tip_in = inches(gripper_position_m([0.0] * 6, geo, mount)[0])
    rows += [
        Row("L10", "reach", "a stationary robot would need over ten feet (ROBOT MANIPULATOR ARM)",
            f"tip {tip_in:.1f} in ({tip_in / 12:.2f} ft, {tip_in * IN_TO_M:.2f} m) from the shaft stretched out: "
            f"a circle {2 * tip_in / 12:.1f} ft across",
            "over ten feet across, from shorter links" if 2 * tip_in > 120.0 else "under ten feet across"),
        Row("L11", "degrees of freedom", "six (ROBOT MANIPULATOR ARM)",
            f"{len(arm.channels)} channels: {', '.join(c.drive.name for c in arm.channels)}",
            compare(len(arm.channels), 6, 0)),
    ]
    return rows


def mobile_arm_length_in(mount) -> float:
    """The length the plant's mobile-arm weight implies for the report's 2 x 5 in, 3/16 in wall tube."""
    wall = 3.0 / 16.0
    area_in2 = 2.0 * (2.0 + 5.0) * wall - 4.0 * wall ** 2
    return lb(mount.mobile_arm_kg) / (area_in2 * AL_6061_DENSITY_LB_IN3)


def track_row(arm: ArmPlantParams) -> Row:
    """The track: a 5 ft circle about 12 ft long, against the mount's travel between its limit switches."""
    mount = arm.mount.base_radius_m
    channel = arm.channels[MOUNT]
    travel_deg = math.degrees(channel.limit_hi_rad - channel.limit_lo_rad)
    arc_deg = 12.0 / (math.pi * 5.0) * 360.0
    return Row("L9", "track", "a 5 ft (1.52 m) circle formed from about 12 ft (3.66 m) of steel (TRACK)",
               f"link I rides {inches(mount):.1f} in ({mount * 1000:.0f} mm) from the shaft; the mount travels "
               f"{travel_deg:.0f}° between its limit switches",
               f"12 ft is {arc_deg:.0f}° of a 5 ft circle ({math.pi * 5.0:.1f} ft round)")


# ---- Table 3: deflections ------------------------------------------------------------------------------------

E_PSI = 10.3e6                                            # Table 1, Appendix A
TUBE_I_IN4 = 2.0 ** 4 / 12.0 - (2.0 - 2 * 0.125) ** 4 / 12.0   # Appendix A: 0.5518 in^4


def cantilever_in(p_lb: float, length_in: float, link_lb: float, moment_lb_in: float = 0.0) -> float:
    """Appendix A: delta = P L^3 / 3EI + M L^2 / 2EI + w L^4 / 8EI (w the link's weight per inch)."""
    ei = E_PSI * TUBE_I_IN4
    return (p_lb * length_in ** 3 / (3 * ei) + moment_lb_in * length_in ** 2 / (2 * ei)
            + link_lb / length_in * length_in ** 4 / (8 * ei))


def deflection_rows(arm: ArmPlantParams = ARM_PLANT_PARAMS) -> list[Row]:
    """The emulator's links are rigid; Appendix A's formula, fed the emulator's loads, stands beside the report's."""
    geo, load = arm.geometry, lb(REPORT_TEST_LOAD_KG)
    p3, l3, w3 = lb(geo.wrist_fixed_kg + geo.wrist_turned_kg), inches(geo.link3_m), lb(geo.link3_kg)
    p2, l2, w2 = lb(geo.elbow_hw_kg) + w3 + p3, inches(geo.link2_m), lb(geo.link2_kg)
    m2 = holding_lb_in(J2_REPORT_POSE, arm)[1]
    m2_loaded = holding_lb_in(J2_REPORT_POSE, arm, REPORT_TEST_LOAD_KG)[1]
    rigid = "0: rigid links (`hil_sim/arm.py`)"

    def formula(unloaded: float, loaded: float, table_3: tuple[float, float]) -> str:
        agrees = (round(unloaded, 4), round(loaded, 4)) == table_3
        return (f"Appendix A's formula on the emulator's loads: {unloaded:.5f} / {loaded:.5f} in "
                f"({unloaded * 25.4:.4f} / {loaded * 25.4:.4f} mm), difference {loaded - unloaded:.6f} in: "
                + ("Table 3's to four places" if agrees else "not Table 3's"))

    j1 = arm.channels[J1]
    tip_m = gripper_position_m([0.0] * 6, geo, arm.mount)[0] - arm.mount.base_radius_m
    step_m = tip_m * 2 * math.pi / j1.counts_per_output_rev
    return [
        Row("D1", "link III, unloaded / loaded / difference", "0.0006 / 0.0007 / 0.0001 in (Table 3)", rigid,
            formula(cantilever_in(p3, l3, w3), cantilever_in(p3 + load, l3, w3), (0.0006, 0.0007))),
        Row("D2", "link II, unloaded / loaded / difference", "0.0134 / 0.0135 / 0.0001 in (Table 3)", rigid,
            formula(cantilever_in(p2, l2, w2, m2), cantilever_in(p2 + load, l2, w2, m2_loaded), (0.0134, 0.0135))),
        Row("D3", "link I, unloaded / loaded / difference", "0.0054 / 0.0054 / < 0.0001 in (Table 3)", rigid,
            "not reproduced: Appendix A's page for link I is not in the text"),
        Row("D4", "positioning", "1 cm (0.39 in) at most between loaded and unloaded (DEFLECTION AND MOMENT ANALYSIS)",
            f"no deflection; one J1 encoder count moves the stretched-out tip {step_m * 1000:.3f} mm "
            f"({inches(step_m):.5f} in)", "inside the specification"),
    ]


# ---- Table 4: moments at the links' ends ---------------------------------------------------------------------

def triple(unloaded: float, loaded: float) -> str:
    return f"{unloaded:.2f} / {loaded:.2f} / {loaded - unloaded:.2f} lb in"


def moment_rows(arm: ArmPlantParams = ARM_PLANT_PARAMS) -> list[Row]:
    load = REPORT_TEST_LOAD_KG
    j2 = (holding_lb_in(J2_REPORT_POSE, arm)[1], holding_lb_in(J2_REPORT_POSE, arm, load)[1])
    j1 = (holding_lb_in(J1_REPORT_POSE, arm)[0], holding_lb_in(J1_REPORT_POSE, arm, load)[0])
    posed = (mount_lb_in(J1_REPORT_POSE, arm), mount_lb_in(J1_REPORT_POSE, arm, load))
    stretched = (mount_lb_in(STRETCHED, arm), mount_lb_in(STRETCHED, arm, load))
    return [
        Row("E1", "link III (at J2)", "78.60 / 79.35 / 0.75 lb in (Table 4)",
            f"{triple(*j2)} ({j2[0] * LBF_IN_TO_NM:.3f} N m): J2 holding link III level, the gripper hanging",
            compare(j2[0], 78.60, 2)),
        Row("E2", "link II (at J1)", "285.61 / 287.11 / 1.50 lb in (Table 4)",
            f"{triple(*j1)} ({j1[0] * LBF_IN_TO_NM:.2f} N m): J1 holding link II level, the rest hanging",
            f"{j1[0] - 285.61:+.2f} lb in (10.8 lb × 24 in + 2.2 lb × 12 in is 285.60)"),
        Row("E3", "link I (at its foot)", "285.61 / 287.11 / 1.50 lb in (Table 4)",
            f"{triple(*j1)}: link I stands vertical and passes J1's moment on; no joint there", "as E2"),
        Row("E4", "mobile mount", "888.0 / 891.75 / 3.75 lb in (Table 4)",
            f"{triple(*posed)} in E2's pose; {triple(*stretched)} stretched out "
            f"({stretched[0] * LBF_IN_TO_NM:.1f} N m): weight × distance from the shaft",
            f"{change(posed[0], 888.0)}; {change(stretched[0], 888.0)}"),
    ]


# ---- joints, motors and safety factors -------------------------------------------------------------------------

class ReportedJoint(NamedTuple):
    """A joint as "JOINTS AND ACTUATORS" gives it."""

    name: str
    channel: int
    torque_oz_in: float
    torque_text: str
    reduction: float
    sprocket_pairs: str
    at_motor_oz_in: float
    motor_oz_in: float
    safety_factor: float


REPORTED_JOINTS = (
    ReportedJoint("J1 (links I-II)", J1, 4569.6, "285.6 lb in, 32.27 N m", 16.0, "a double sprocket pair",
                  285.6, 400.0, 1.4),
    ReportedJoint("J2 (links II-III)", J2, 1257.6, "78.6 lb in, 8.88 N m", 6.0, "a single sprocket pair",
                  209.6, 400.0, 1.9))
REPORT_POSES = {J1: J1_REPORT_POSE, J2: J2_REPORT_POSE}


def joint_rows(joint: ReportedJoint, first: int, arm: ArmPlantParams) -> list[Row]:
    """Torque, reduction, torque at the motor, rating and safety factor of J1 or J2, report beside plant."""
    drive = drive_of(arm, joint.channel)
    torque = holding_lb_in(REPORT_POSES[joint.channel], arm)[joint.channel]
    ratio, _ = sprockets(drive)
    lossless, lossy = motor_side(torque, drive)
    cite = "(JOINTS AND ACTUATORS)"
    name = joint.name
    return [
        Row(f"T{first}", f"{name}: torque required", f"{joint.torque_oz_in} oz-in ({joint.torque_text}) {cite}",
            f"{torque * 16:.1f} oz-in, in Table 4's pose (`LoadModel.torques`)",
            compare(torque * 16, joint.torque_oz_in, 1)),
        Row(f"T{first + 1}", f"{name}: reduction after the gear head",
            f"{joint.reduction:.0f}:1, {joint.sprocket_pairs} {cite}",
            f"{ratio:.0f}:1 ({' + '.join(s.name for s in drive.stages)}), each pair "
            f"{drive.stages[0].efficiency:.2f} efficient (ASSUMED)", compare(ratio, joint.reduction, 0)),
        Row(f"T{first + 2}", f"{name}: torque at the motor", f"{joint.at_motor_oz_in} oz-in {cite}",
            f"{lossless:.1f} oz-in; {lossy:.1f} with the sprockets' losses",
            f"{compare(lossless, joint.at_motor_oz_in, 1)}; {change(lossy, joint.at_motor_oz_in)}"),
        Row(f"T{first + 3}", f"{name}: motor's maximum torque; safety factor",
            f"{joint.motor_oz_in:.0f} oz-in; {joint.safety_factor} {cite}",
            f"{rated_oz_in(drive):.0f} oz-in (`MotorSpec.rated_torque_nm`); {safety(torque, drive)}",
            compare(rated_oz_in(drive) / lossless, joint.safety_factor, 1)),
    ]


def torque_rows(arm: ArmPlantParams = ARM_PLANT_PARAMS) -> list[Row]:
    rows = joint_rows(REPORTED_JOINTS[0], 1, arm) + joint_rows(REPORTED_JOINTS[1], 5, arm)
    d2, d3, d4, gripper = (drive_of(arm, k) for k in (J2, J3, 3, 4))
    t3 = holding_lb_in(STRETCHED, arm)[2]
    with_200 = 200.0 / motor_side(holding_lb_in(J2_REPORT_POSE, arm)[1], d2)[0]
    rows += [
        Row("T9", "J2's motor in the parts list", "DC PM (200 oz in) (Key to Figure 8, part 58)",
            f"{rated_oz_in(d2):.0f} oz-in, the text's", f"with 200 oz-in the safety factor would be {with_200:.2f}"),
        Row("T10", "J3 (wrist bend): motor, reduction, safety factor",
            "200 oz-in gear-head motor, 3:1 sprocket pair; 4.7 (WRIST AND GRIPPER)",
            f"{rated_oz_in(d3):.0f} oz-in, {sprockets(d3)[0]:.0f}:1; {safety(t3, d3)}, holding "
            f"{t3:.1f} lb in ({t3 * 16:.0f} oz-in) with the gripper level",
            f"{compare(rated_oz_in(d3) / motor_side(t3, d3)[0], 4.7, 1)}, by construction: the wrist's centre of "
            "gravity is chosen to give 4.7"),
        Row("T11", "J4 (wrist roll)", "a DC motor connected directly to the gripper, no rating (WRIST AND GRIPPER)",
            f"{rated_oz_in(d4):.0f} oz-in, {d4.ratio:.0f}:1 gear head (ASSUMED)", "not in the report"),
        Row("T12", "gripper's motor", "27.5 VDC Dayton push/pull motor (Key to Figure 9, part 64)",
            f"{gripper.motor.nominal_v} V motor (`MOTOR_GRIPPER`) on a {PlantParams().supply_nominal_v:.0f} V bus "
            "(`PlantParams.supply_nominal_v`)", compare(gripper.motor.nominal_v, 27.5, 1) + " motor; the report gives "
            "the arm no supply"),
    ]
    return rows


# ---- J1's worst case against the report's "maximum load" -------------------------------------------------------

def holding_of(joint: int) -> Callable[..., float]:
    """`f(pose, arm)`: the size of what `joint` holds in `pose`, lb in."""
    return lambda pose, arm: abs(holding_lb_in(pose, arm)[joint])


def worst_rows(arm: ArmPlantParams = ARM_PLANT_PARAMS) -> list[Row]:
    d1, d2, d3 = drive_of(arm, J1), drive_of(arm, J2), drive_of(arm, J3)
    (w1, p1), (w2, p2), (w3, p3) = (extreme(holding_of(k), arm) for k in (J1, J2, J3))
    worse = holding_lb_in(J1_REPORT_POSE, arm)[0] < w1 - 1e-9
    gripper_level = abs(sum(p3)) < 1e-9
    rated_joint_lb_in = lb_in(d1.rated_output_torque_nm)
    lever_in = inches(LoadModel(arm.geometry).pose(*p1)[3][0])
    payload_rated = (rated_joint_lb_in - w1) / lever_in
    limit_a = arm_config.ASPOD_ARM.drive("j1").i_limit_a
    limit_lb_in = lb_in(limit_a * d1.kt_out_nm_a)
    payload_limit = (limit_lb_in - w1) / lever_in
    return [
        Row("W1", "J1's largest holding torque", "4569.6 oz-in, its \"maximum load\" (JOINTS AND ACTUATORS)",
            f"{w1 * 16:.1f} oz-in ({w1:.1f} lb in, {w1 * LBF_IN_TO_NM:.2f} N m) over the travel, at "
            f"{pose_text(p1)}{': stretched out level' if p1 == STRETCHED else ''}", change(w1 * 16, 4569.6)),
        Row("W2", "J1's safety factor at it", "1.4 \"at maximum load\" (JOINTS AND ACTUATORS)", safety(w1, d1),
            f"{change(rated_oz_in(d1) / motor_side(w1, d1)[0], 1.4)}: "
            + ("the report's pose is not J1's worst" if worse else "the report's pose is J1's worst")),
        Row("W3", "J2's largest holding torque", "1257.6 oz-in; 1.9 (JOINTS AND ACTUATORS)",
            f"{w2 * 16:.1f} oz-in ({w2:.1f} lb in) at {pose_text(p2)}; {safety(w2, d2)}", change(w2 * 16, 1257.6)),
        Row("W4", "J3's largest holding torque", "safety factor 4.7 (WRIST AND GRIPPER)",
            f"{w3 * 16:.0f} oz-in at {pose_text(p3)}; {safety(w3, d3)}",
            "the gripper level: the report's case" if gripper_level else "not the report's case"),
        Row("W5", "payload J1 holds stretched out within its 400 oz-in rating",
            "none given; Appendix A's test load is 1 oz (0.0625 lb)",
            f"{payload_rated:.3f} lb ({lb_to_g(payload_rated):.0f} g) at the tip, {lever_in:.0f} in from J1",
            f"{payload_rated / lb(REPORT_TEST_LOAD_KG):.1f} × the 1 oz test load"),
        Row("W6", "J1 at the firmware's current limit", "none given",
            f"{limit_a:.1f} A (`arm_config.ASPOD_ARM`) gives {limit_lb_in * 16:.0f} oz-in, "
            f"{limit_lb_in / rated_joint_lb_in:.2f} × the rating: {payload_limit:.2f} lb "
            f"({lb_to_g(payload_limit):.0f} g) of payload stretched out",
            "above the gear head's rating" if limit_lb_in > rated_joint_lb_in else "within the gear head's rating"),
    ]


def lb_to_g(pounds: float) -> float:
    return pounds * LB_TO_KG * 1000.0


# ---- the mount: the shaft's 55 lbf ft and the arm's 650 lb in ---------------------------------------------------

def mount_rows(arm: ArmPlantParams = ARM_PLANT_PARAMS) -> list[Row]:
    (top, top_pose), (low, low_pose) = extreme(mount_lb_in, arm), extreme(mount_lb_in, arm, -1.0)
    links_sum = holding_lb_in(J2_REPORT_POSE, arm)[1] + 2 * holding_lb_in(J1_REPORT_POSE, arm)[0]
    drive = drive_of(arm, MOUNT)
    gravity_on_drive = mount_drive_gravity_nm(arm)
    most = (f"{top:.1f} lb in ({top / 12:.1f} lbf ft, {top * LBF_IN_TO_NM:.1f} N m) at {pose_text(top_pose)}, "
            "the most over the travel (`mount_static_moment_nm`)")
    return [
        Row("M1", "the shaft's maximum torque",
            "55 lbf ft (660 lb in, 74.6 N m), \"approximated\" (SHAFT ASSEMBLY)", most, change(top, 660.0)),
        Row("M2", "the mobile arm's maximum torque", "650 lb in (printed \"650 lb/in\"; 73.4 N m) (MOBILE ARM)",
            "as M1", change(top, 650.0)),
        Row("M3", "the mobile mount's moment", "888.0 lb in unloaded (Table 4)",
            f"{top:.1f} lb in stretched out; {mount_lb_in(J1_REPORT_POSE, arm):.1f} lb in in Table 4's J1 pose",
            f"{change(top, 888.0)}; {change(mount_lb_in(J1_REPORT_POSE, arm), 888.0)}"),
        Row("M4", "Table 4's three link moments added",
            "78.60 + 285.61 + 285.61 = 649.82 lb in (54.15 lbf ft), from Table 4",
            f"{links_sum:.2f} lb in: the emulator's E1 + E2 + E3", f"{links_sum - 650.0:+.2f} lb in from 650 lb in"),
        Row("M5", "the least moment over the travel", "none given",
            f"{low:.1f} lb in at {pose_text(low_pose)}", f"the most is {top / low:.1f} × it"),
        Row("M6", "torque on the mount's drive", "the shaft \"supports the torque generated by the weight\"",
            f"{gravity_on_drive:.1f} N m of gravity (the platform is level); the drive "
            f"is rated {lb_in(drive.rated_output_torque_nm):.0f} lb in ({lb_in(drive.rated_output_torque_nm) / 12:.1f} "
            "lbf ft) at the shaft",
            "a bending moment, not a drive torque" if gravity_on_drive == 0.0 else "a drive torque"),
    ]


def mount_drive_gravity_nm(arm: ArmPlantParams) -> float:
    """The gravity load the plant puts on the mount's channel with the arm stretched out (the plant's own rows)."""
    plant = ArmPlant(arm)
    for channel, q in zip((J1, J2, J3), STRETCHED):
        plant.set_joint_state(channel, q)
    return plant.load_lists()[0][MOUNT]


# ---- 1/2 RPM and 30 s ------------------------------------------------------------------------------------------

def axis_configs() -> dict:
    """The firmware's axis configurations from its default parameters (what `Move` runs with)."""
    values = {spec.name: spec.default for spec in arm_config.ASPOD_ARM.parameter_table()}
    return {d.name: arm_config.axis_config(d, values, 0.001) for d in arm_config.ASPOD_ARM.drives}


def speed_rows(arm: ArmPlantParams = ARM_PLANT_PARAMS) -> list[Row]:
    configs = axis_configs()
    specs = {spec.name: spec for spec in arm_config.ASPOD_ARM.parameter_table()}
    speeds = {name: math.degrees(c.vel_limit_rad_s) for name, c in configs.items()}
    highest = {name: specs[f"{name}_speed_dps"].hi for name in configs}
    j2 = configs["j2"]
    half = profiles.trapezoid(-HALF_PI, HALF_PI, j2.vel_limit_rad_s, j2.acc_limit_rad_s2).duration_s
    quarter = profiles.trapezoid(-HALF_PI, 0.0, j2.vel_limit_rad_s, j2.acc_limit_rad_s2).duration_s
    acc = configs["j1"].acc_limit_rad_s2
    appendix_b_acc = 4 * math.pi / 30.0 ** 2
    arm_inertia = joint_inertias_kg_m2(*STRETCHED, arm.geometry)[0]
    drive_inertia = drive_of(arm, J1).inertia_kg_m2
    static_nm = holding_lb_in(STRETCHED, arm)[0] * LBF_IN_TO_NM
    return [
        Row("S1", "joint speed", "1/2 RPM (3 deg/s, 0.0524 rad/s) or lower (DEFLECTION AND MOMENT ANALYSIS)",
            f"{', '.join(sorted({f'{v:.1f}' for v in speeds.values()}))} deg/s "
            f"({configs['j1'].vel_limit_rad_s / RPM_TO_RAD_S:.2f} RPM) by default on {', '.join(speeds)} "
            f"(`<axis>_speed_dps`); settable up to {max(highest.values()):.0f} deg/s, "
            + ", ".join(f"{n} {v:.0f}" for n, v in highest.items() if v < max(highest.values()))
            + " (their motors' no-load speed at 28 V)",
            compare(speeds["j1"], 3.0, 1) + " by default"),
        Row("S2", "vertically down to vertically up (a half turn)",
            "\"1/2 RPM corresponds to a time of 30 seconds\" (Figure 7's text)",
            f"{half:.1f} s: J2 from hanging to upright at the default speed and acceleration (`profiles.trapezoid`)",
            f"{half / 30.0:.2f} × the report's 30 s; 1/2 RPM takes 60 s for a half turn"),
        Row("S3", "vertically down to level (a quarter turn)", "none given; 1/2 RPM takes 30 s for it",
            f"{quarter:.1f} s, the same way", "the report's 30 s fits a quarter turn"),
        Row("S4", "acceleration",
            "APPENDIX B: constant to level, then its negative; a half turn in 30 s is 0.0140 rad/s² "
            "(0.80 deg/s²), peaking at 2 RPM",
            f"{acc:.4f} rad/s² ({math.degrees(acc):.1f} deg/s², `<axis>_acc_dps2`) up to the speed limit",
            f"{acc / appendix_b_acc:.2f} × Appendix B's"),
        Row("S5", "inertial torque against the static torque",
            "\"several orders of magnitude less\" (Figure 7's text); Appendix B's 104.70 kg m² at 0.0140 rad/s² "
            "against 317.2 N m: 0.46 %",
            f"J1 stretched out at the default acceleration: the arm's {arm_inertia:.2f} kg m², "
            f"{arm_inertia * acc / static_nm * 100:.2f} % of {static_nm:.1f} N m; with the rotor through "
            f"{drive_of(arm, J1).ratio:.0f}:1 ({drive_inertia:.1f} kg m²), "
            f"{(arm_inertia + drive_inertia) * acc / static_nm * 100:.1f} %",
            f"the rotor is {drive_inertia / arm_inertia:.0f} × the arm's inertia; the report's Lagrangian leaves "
            "it out"),
    ]


# ---- the solar tracker: lag and hunting --------------------------------------------------------------------------

@lru_cache(maxsize=None)
def tracker_run(dial_pct: float, start: time, minutes: int):
    """The firmware's relay logic closed around the tracker's plant, June 21 at Tucson, on the simulated clock."""
    end_min = start.hour * 60 + start.minute + minutes
    return run_day(DaySettings(mode="relay", dial_pct=(dial_pct, dial_pct), start=start,
                               end=time(end_min // 60, end_min % 60)))


LAG_RUN = (3.0, time(12, 15), 2)          # near transit, where the azimuth turns fastest
HUNT_RUN = (100.0, time(10, 0), 2)
GOOD_RUN = (40.0, time(10, 0), 2)


def sun_rate_deg_min(run) -> float:
    """The sun's azimuth rate over the run's first minute, from the plant's own sun."""
    plant = TrackerPlant(start=run.start)
    before = plant.sun()[1]
    plant.step(60.0)
    return plant.sun()[1] - before


def axis_speed_deg_min(dial_pct: float) -> float:
    """An axis's steady speed at the duty the box sends for a dial setting (its 10-bit ADC's reading)."""
    return TRACKER_PARAMS.steady_speed_deg_s(quantize_dial(dial_pct) / ADC_COUNTS) * 60.0


def tracker_rows() -> list[Row]:
    lag, hunt, good = tracker_run(*LAG_RUN), tracker_run(*HUNT_RUN), tracker_run(*GOOD_RUN)
    ls, hs, gs = lag.summary(), hunt.summary(), good.summary()
    step10 = "(OPERATING INSTRUCTIONS, step 10)"
    window = "June 21, Tucson, {:%H:%M}-{:%H:%M} MST"
    tilt = TRACKER_PARAMS.cell_tilt_deg
    lags = ls["lead_fraction"] == 0.0 and lag.lag_deg[-1] > lag.lag_deg[0]
    hunts = hs["reversals"] > 0 and 0.0 < hs["lead_fraction"] < 1.0 and hs["relay_switchings"] > gs["relay_switchings"]
    smooth = gs["axes"]["az"]["motor_on_fraction"] > 0.5
    return [
        Row("SU1", "motor", "90 VDC (SOLAR TRACKER; the box's CAUTION)",
            f"{TRACKER_PARAMS.supply_v:.0f} V bus (`TrackerParams.supply_v`)",
            compare(TRACKER_PARAMS.supply_v, 90.0, 0)),
        Row("SU2", "sensors",
            "a pair of photocells at a right angle, bisector on the focal axis (Solar Photovoltaic Cells)",
            f"two cells at ±{tilt:.0f}° from the focal axis, {2 * tilt:.0f}° apart, per axis",
            compare(2 * tilt, 90.0, 0)),
        Row("SU3", "dial too low", f"\"lagging the sun constantly trying to catch up\" {step10}",
            f"dial {LAG_RUN[0]:.0f} %, {window.format(lag.start, lag.end)}: the axis turns "
            f"{axis_speed_deg_min(LAG_RUN[0]):.2f} deg/min, the sun's azimuth {sun_rate_deg_min(lag):.2f}; the lag "
            f"grows from {lag.lag_deg[0]:.2f} to {lag.lag_deg[-1]:.2f} deg, ahead {ls['lead_fraction'] * 100:.0f} % "
            f"of the time, the azimuth motor on {ls['axes']['az']['motor_on_fraction'] * 100:.0f} %",
            "reproduced" if lags else "not reproduced"),
        Row("SU4", "dial too high", f"\"constantly be fluctuating from leading then lagging\" {step10}",
            f"dial {HUNT_RUN[0]:.0f} %, {window.format(hunt.start, hunt.end)}: {hs['reversals']} reversals, ahead "
            f"{hs['lead_fraction'] * 100:.0f} % of the time, {hs['relay_switchings']} relay switchings "
            f"(dial {GOOD_RUN[0]:.0f} %: {gs['reversals']} reversals, {gs['relay_switchings']} switchings)",
            "reproduced" if hunts else "not reproduced"),
        Row("SU5", "dial right", f"\"the motor is running smoothly\" {step10}",
            f"dial {GOOD_RUN[0]:.0f} %, the same minutes: RMS pointing error {gs['rms_pointing_error_deg']:.2f} deg, "
            f"ahead {gs['lead_fraction'] * 100:.0f} % of the time; the relays close in bursts, the azimuth motor on "
            f"{gs['axes']['az']['motor_on_fraction'] * 100:.1f} % of the time",
            "smooth" if smooth else "tracks, in bursts: not smoothly"),
    ]


# ---- the control box's limits ----------------------------------------------------------------------------------

def box_rise_c(outputs_enabled: bool) -> float:
    """How far the plant's control box settles above ambient, idle or with the outputs enabled.

    The plant's thermal model with its capacity cut to make the time constant 0.1 s: the settled
    rise is heat x thermal resistance and does not depend on the capacity; 3 s is 30 time constants.
    """
    params = PlantParams()
    fast = dataclasses.replace(params, thermal_capacity_j_per_c=0.1 / params.thermal_resistance_c_per_w)
    plant = Plant(fast, np.random.default_rng(0))
    for _ in range(300):
        plant.step(0.01, outputs_enabled=outputs_enabled, brake=True)
    return plant.temp_true_c - fast.ambient_c


def firmware_limits() -> dict[str, float]:
    table = firmware_controller.parameter_table(firmware_controller.ControllerConfig())
    return {spec.name: spec.default for spec in table}


def new_tracker() -> tracker_task.TrackerController:
    return tracker_task.TrackerController(DayHal(), ParamStore(tracker_task.parameter_table()), 0.01,
                                          allowed=lambda: True)


def highest_dial_taken(switch: Switch, position: SwitchPosition) -> float:
    """The highest dial setting (percent, as the box's ADC reads it) at which a fresh box takes this switch."""
    taken = None
    for counts in range(ADC_COUNTS + 1):
        tracker = new_tracker()
        tracker.dial(counts * 100.0 / ADC_COUNTS)
        if tracker.switch(switch, position)[0] is not Reason.OK:
            break
        taken = counts
    return taken * 100.0 / ADC_COUNTS


def box_rows() -> list[Row]:
    limits = firmware_limits()
    cold, hot, warn = limits["temp_min_c"], limits["temp_max_c"], limits["temp_warn_c"]
    idle, enabled = box_rise_c(False), box_rise_c(True)
    taken = {what: highest_dial_taken(sw, pos) for what, sw, pos in (
        ("a start", Switch.SPEED, SwitchPosition.ON), ("a mode change", Switch.MODE, SwitchPosition.SENSOR),
        ("a direction change", Switch.DIRECTION, SwitchPosition.CCW))}
    if len(set(taken.values())) == 1:
        low = f"up to {next(iter(taken.values())):.2f} % for a start, a mode change and a direction change alike"
    else:
        low = ", ".join(f"up to {pct:.2f} % for {what}" for what, pct in taken.items())
    safety_item = "(GENERAL SAFETY INFORMATION, item 4)"
    return [
        Row("B1", "temperature range", f"-10 C (15 F) to 45 C (115 F) ambient {safety_item}",
            f"a fault below {cold:.1f} C ({fahrenheit(cold):.0f} F) and above {hot:.1f} C ({fahrenheit(hot):.0f} F) "
            "(`temp_min_c`, `temp_max_c`)", f"{compare(cold, -10.0, 1)} at -10 C, {compare(hot, 45.0, 1)} at 45 C"),
        Row("B2", "what is measured", f"the ambient temperature {safety_item}",
            f"the box's own temperature, {idle:.1f} C above ambient idle and {enabled:.1f} C with the outputs "
            "enabled (`Plant`'s thermal model)",
            f"the hot fault comes at {hot - idle:.1f} C ambient idle, {hot - enabled:.1f} C enabled; the cold one at "
            f"{cold - idle:.1f} and {cold - enabled:.1f} C"),
        Row("B3", "warning", "none", f"within {warn:.1f} C of either limit (`temp_warn_c`, TemperatureWarning)",
            "beyond the report"),
        Row("B4", "the speed dial low", "\"ALWAYS keep the speed dial on low when starting operation\", from manual "
            "to sensor mode, and when switching direction (Control Box)",
            f"the box takes the dial {low} (`trk_dial_low_pct`), refuses above (DIAL_NOT_LOW); the plant counts "
            f"a start above {TRACKER_PARAMS.low_duty * 100:.0f} % duty as a high-duty start (`low_duty`)",
            f"{'same rule' if all(pct < 100.0 for pct in taken.values()) else 'not interlocked'}; two figures "
            "for \"low\""),
        Row("B5", "dust, water, grounding, servicing",
            "not sealed, keep dry and clean; grounded; power off before servicing (the box's WARNING, items 1-3)",
            "not modelled", "outside an emulator"),
    ]


# ---- the planner's worked example (the report's section 4) -------------------------------------------------------

@lru_cache(maxsize=None)
def planned_example():
    """The example planned here: time-optimal (ab2 and rk4), and by dynamic programming on the report's grid."""
    from host_tools.plan.energy import DpGrid, Pricing, costs_of, plan_cost_optimal
    from host_tools.plan.example import DP_INTERVALS, DP_SPEED_STEP, DP_SPEEDS, report_problem
    from host_tools.plan.timeopt import plan_time_optimal
    problem, with_gravity = report_problem(), report_problem(gravity=True)
    fastest = {k: plan_time_optimal(problem, 1000, k) for k in ("ab2", "rk4")}
    grid = DpGrid(DP_INTERVALS, DP_SPEEDS, DP_SPEED_STEP)
    energy = plan_cost_optimal(problem, "energy", grid)
    up = plan_time_optimal(with_gravity, 1000)
    up_energy = plan_cost_optimal(with_gravity, "energy", grid)
    heat = plan_cost_optimal(with_gravity, "thermal", grid)
    spanning = DpGrid(DP_INTERVALS, DP_SPEEDS, 1.2 * up.profile.sd.max() / (DP_SPEEDS - 1))   # aspod plan's default
    electrical = plan_cost_optimal(with_gravity, "electrical", spanning)
    return fastest, energy, costs_of(up.grid.t, up.profile.sd, Pricing.of(with_gravity)), up_energy, heat, electrical


def planner_rows() -> list[Row]:
    from host_tools.plan.example import PATH, beside_report
    fastest, energy, up_costs, up_energy, heat, electrical = planned_example()
    rk4, ab2 = fastest["rk4"], fastest["ab2"]
    rows = [Row("P1", "the object's path", "garbled in the text: only \"1/2 s\" survives for one coordinate "
                "(4.1)", f"w(s) = ({PATH[0][0]} + {PATH[1][0] - PATH[0][0]:.3f} s, {PATH[0][1]} + "
                f"{PATH[1][1] - PATH[0][1]:.3f} s) m; point-mass links, gravity off (`plan/example.py`)",
                "chosen: the only model of 16 tried with zero-inertia points near both of the report's")]
    for n, near in enumerate(beside_report(rk4.switching_points), start=2):
        r, h = near["report"], near["here"]
        what = f"zero-inertia, a{r['joint']}" if r["joint"] else near["kind"]
        here = f"a{h['joint']}: " if h.get("joint") else ""
        rows.append(Row(f"P{n}", f"switching point, {what}", f"(s, s') = ({r['s']}, {r['sd']}) (4.2)",
                        f"{here}({h['s']:.4f}, {h['sd']:.3f}); {'kept' if h['kept'] else 'discarded: ' + h['why']}",
                        f"{near['error_s'] * 100:+.1f} % in s, {near['error_sd'] * 100:+.1f} % in s'"))
    rows += [
        Row("P5", "limit curves' integrator", "second-order Adams-Bashforth (4.2)",
            f"ab2 or rk4: minimum time {ab2.duration:.5f} s and {rk4.duration:.5f} s at 1000 intervals",
            f"they differ by {abs(ab2.duration / rk4.duration - 1) * 1e6:.0f} ppm; the report gives no time"),
        Row("P6", "saturation", "at any given time at least one actuator torque is saturated (4.2, Fig. 14)",
            f"a joint within 1 % of its limit {rk4.profile.saturated_time * 100:.2f} % of the time",
            "same" if rk4.profile.saturated_time > 0.99 else "NOT everywhere"),
        Row("P7", "dynamic programming grid", "101 points in s, 201 speeds 0.005 apart (4.3)",
            f"the same grid: the minimum-energy profile takes {energy.profile.duration:.1f} s, "
            f"energy index {energy.costs['energy']:.2g} J",
            "every profile's index is 0 without gravity: the grid's tie-break chooses"),
        Row("P8", "energy index sum(u dq)", "minimized (section 3)",
            f"with gravity on: {up_costs['energy']:.4f} J time-optimal ({up_costs['time']:.3f} s), "
            f"{up_energy.costs['energy']:.4f} J energy-optimal ({up_energy.profile.duration:.2f} s)",
            "the rise in potential energy, whatever the profile: it cannot choose one"),
        Row("P9", "copper loss sum(R i^2 dt), with gravity", "not in the report",
            f"least at {heat.profile.duration:.2f} s: {heat.costs['thermal']:.2f} J against "
            f"{up_costs['thermal']:.2f} J time-optimal (ASPOD's J1 drive at each shoulder, J2 at each elbow)",
            "beyond the report: the report gives no motor for the example"),
        Row("P10", "electrical energy, with gravity", "not in the report",
            f"least at {electrical.profile.duration:.3f} s: {electrical.costs['electrical']:.2f} J against "
            f"{up_costs['electrical']:.2f} J time-optimal and {up_energy.costs['electrical']:.0f} J for the "
            f"index's {up_energy.profile.duration:.0f} s plan", "beyond the report: work, copper loss, and the "
            "drives' 21 W an arm (hil_sim); the default objective of `aspod plan`"),
    ]
    return rows


# ---- the shared object (issue 39) -------------------------------------------------------------------------------

def object_rows(params: ObjectParams = ObjectParams()) -> list[Row]:
    """The object two hands carry (`hil_sim/held_object.py`): the report's figures, the planner's, and those
    chosen here. The compared column tags each: [REPORT], [PLANNER], [EMU] (chosen or assumed for the emulator),
    [NOBODY] (no source gives it)."""
    p = params
    (g0x, g0z), (g1x, g1z) = p.grasps_m
    (kx, kz), (cx, cz) = p.stiffness_n_m, p.damping_n_s_m
    hold_duty = {spec.name: spec.default for spec in arm_config.ASPOD_ARM.parameter_table()}["grip_hold_duty"]
    supply_v = PlantParams().supply_nominal_v
    jaws_n = ARM_PLANT_PARAMS.jaw_force_n(hold_duty, supply_v)
    limit_n = p.friction * jaws_n
    codec = HalCodec()
    period = p.stiffest_period_s()
    report_object = (0.25, 0.25, 0.1)
    return [
        Row("G1", "the object's mass and size", "\"a mass of 0.25 kg with a length dimension of 0.25 m and [a h]eight "
            "dimension of 0.1 m\" (4.1, OCR)", f"{p.mass_kg} kg, {p.size_m[0]} x {p.size_m[1]} m (`ObjectParams`)",
            "[REPORT] same" if (p.mass_kg, *p.size_m) == report_object else "[REPORT] changed"),
        Row("G2", "its moment of inertia about its centre", "not in the report",
            f"{p.inertia_kg_m2:.3g} kg m^2: a uniform block, m (a^2 + b^2) / 12",
            "[EMU] from the report's mass and size, the density assumed uniform"),
        Row("G3", "how it is held", "not in the report: no grasp type, grasp points, friction or compliance (1)",
            f"at ({g0x}, {g0z}) and ({g1x}, {g1z}) m from its centre: its ends, each a spring-damper to one hand "
            "passing a force and no moment; nothing pins its angle",
            "[PLANNER] the planner's grasps and its pin (`plan/model.py`, `Held`)"),
        Row("G4", "grasp stiffness", "not in the report; its one positioning tolerance is 1 cm (DEFLECTION AND "
            "MOMENT ANALYSIS)", f"{kx:.0f} N/m along x, {kz:.0f} N/m along z, each grasp: 1 cm is "
            f"{kx * 0.01:.0f} N", "[EMU] chosen from the 1 cm specification"),
        Row("G5", "grasp damping", "not in the report",
            f"{cx:.0f} N s/m along x, {cz:.0f} N s/m along z: damping ratio {p.damping_ratio(0):.2f} and "
            f"{p.damping_ratio(1):.2f} for the object on its two grasps",
            "[EMU] chosen: settles in a few periods with little overshoot"),
        Row("G6", "friction coefficient of the grip", "not in the report", f"{p.friction}",
            "[NOBODY] assumed"),
        Row("G7", "the jaws' force", "not in the report (the gripper: 2.0 lb, a push/pull motor; WRIST AND "
            "GRIPPER)", f"{jaws_n:.1f} N at hold duty {hold_duty} (`grip_hold_duty`) and {supply_v:.0f} V: the "
            "plant's gripper drive stalled on the object", "[EMU] the plant's ASSUMED gripper motor and screw"),
        Row("G8", "the grip's limit", "not in the report",
            f"slips past {p.friction} x {jaws_n:.1f} = {limit_n:.1f} N across a grasp, the force held at that; "
            f"lets go past twice it at once ({2 * limit_n:.1f} N), with the jaws open (below {p.open_jaw_n} N) or "
            "slid off the object", "[NOBODY] the rule chosen here"),
        Row("G9", "gravity on the example", "not stated (4); the plane is not stated either",
            f"Earth {G_EARTH_M_S2} m/s^2 or orbit 0 (`gravity_m_s2`), as the arm (`hil_sim/arm.py`)",
            "[NOBODY] both are run"),
        Row("G10", "the step", "not in the report",
            f"1 ms, the plant's; the fastest mode is the object turning on its grasps, {period * 1000:.1f} ms "
            f"(omega = {2 * math.pi / period:.0f} rad/s, omega dt = {2 * math.pi * 0.001 / period:.2f}, stable below 2)",
            "[EMU] velocity Verlet, the dampers implicit"),
        Row("G11", "what a controller knows of its grasp", "not in the report: no wrist sensor",
            f"a wrist force sensor per arm (`GRASP_FORCE`): the force across its grasp, the grip's limit, the squeeze "
            f"and the grasp's state, every {codec.cycle_time_s('GRASP_FORCE') * 1000:.0f} ms and at once on a change "
            f"of state, {codec.limits('GRASP_FORCE', 'force_n')[1]:g} N full scale in 0.01 N; ideal: the plant's own "
            "values, no noise, offset or filter, read 1 ms on (with the next tick's frames); a slip or a drop is GRIP_SLIP",
            "[EMU] assumed: a real sensor's noise and bandwidth are not modelled"),
    ]


# ---- the example arm (issue 39) ----------------------------------------------------------------------------------

EXAMPLE_LIMITS_NM = (30.0, 20.0, 35.0, 15.0)        # the report's section 4: |u1| .. |u4|, arm 1's then arm 2's
EXAMPLE_CURRENT_LIMITS_A = (21.0, 12.0)             # the firmware's i_limit_a for the example's shoulder, elbow


@lru_cache(maxsize=None)
def example_arm_path():
    """The example's minimum-time plan with the example arm's rod links, in Earth gravity: each joint's range
    (deg) and peak speed (rad/s) along it, in the planner's order (arm 1 shoulder, elbow, arm 2 shoulder, elbow)."""
    from host_tools.plan.example import report_problem
    from host_tools.plan.reach import plan_reach
    problem = report_problem(gravity=True, links="rod")
    profile = plan_reach(problem, 100).profile
    jp = problem.system.joint_path(problem.path, profile.s)
    q = np.degrees(jp.q)
    return q.min(axis=0), q.max(axis=0), np.abs(jp.q_s * profile.sd[:, None]).max(axis=0)


def example_arm_rows(arm: ArmPlantParams = EXAMPLE_ARM_PLANT) -> list[Row]:
    """The example arm (`EXAMPLE_ARM_PLANT`): the report's example's two links, drives chosen for it, ASPOD's
    wrist, gripper and mount. Tagged as the object's rows: [REPORT], [PLANNER], [EMU]."""
    geo, aspod = arm.geometry, ARM_PLANT_PARAMS
    shoulder, elbow = arm.channels[J1].drive, arm.channels[J2].drive
    motor = shoulder.motor
    low, high, speeds = example_arm_path()
    limits = [(math.degrees(c.limit_lo_rad), math.degrees(c.limit_hi_rad)) for c in arm.channels[:2]]
    stops = [(math.degrees(c.drive.stop_lo_rad), math.degrees(c.drive.stop_hi_rad)) for c in arm.channels[:2]]
    inside = all(lo <= low[j::2].min() and high[j::2].max() <= hi for j, (lo, hi) in enumerate(limits))
    extra = (geo.elbow_hw_kg, geo.wrist_fixed_kg, geo.wrist_turned_kg, geo.wrist_turned_inertia_kg_m2,
             geo.roll_inertia_kg_m2, geo.tip_m)
    (ks, ke) = (shoulder.kt_out_nm_a, elbow.kt_out_nm_a)
    worst_shoulder, worst_elbow = max(EXAMPLE_LIMITS_NM[0::2]), max(EXAMPLE_LIMITS_NM[1::2])
    (i_shoulder, i_elbow) = EXAMPLE_CURRENT_LIMITS_A
    no_load = PlantParams().supply_nominal_v / shoulder.ke_out_v_s_rad
    return [
        Row("X1", "the example's links", "\"manipulator links have unit mass (kg) and unit length (m)\" (4)",
            f"link II {geo.link2_m} m, {geo.link2_kg} kg; link III {geo.link3_m} m, {geo.link3_kg} kg; uniform rods "
            "(`EXAMPLE_ARM_GEOMETRY`)", "[REPORT] same; rods: [PLANNER] links=\"rod\" (the report does not say "
            "rods or points; points place its switching points nearer, P1)"),
        Row("X2", "what else the arm carries", "nothing said beyond the two links (4)",
            "nothing: no elbow hardware, wrist or gripper mass; the hand, where the object's grasp acts, on the J3 "
            "axis (tip 0 m)" if not any(extra) else "some wrist or elbow mass", "[PLANNER] the planner's model"),
        Row("X3", "the bases", "\"The distance between the bases of the manipulators is 2.0 [m]\" (4, OCR)",
            "(0, 0) and (2.0, 0) m in the object's frame, both arms' x along it (`two_arms.EXAMPLE_BASES_M`)",
            "[REPORT] same"),
        Row("X4", "the drives", "none: torque limits only",
            f"one 28 V PM DC motor at each joint: {motor.r_ohm} ohm, {motor.l_h * 1000} mH, {motor.kt_nm_a} N m/A, "
            f"rotor {motor.rotor_inertia_kg_m2:.1e} kg m^2; {motor.gearhead.ratio:.0f}:1 gear head, efficiency "
            f"{motor.gearhead.efficiency}: {ks:.2f} N m/A and {no_load:.0f} rad/s no-load at the joint, the rotor "
            f"{shoulder.ratio ** 2 * motor.rotor_inertia_kg_m2:.3f} kg m^2 there", "[EMU] chosen for the example"),
        Row("X5", "torque limits", f"|u1| < {EXAMPLE_LIMITS_NM[0]:.0f}, |u2| < {EXAMPLE_LIMITS_NM[1]:.0f}, "
            f"|u3| < {EXAMPLE_LIMITS_NM[2]:.0f}, |u4| < {EXAMPLE_LIMITS_NM[3]:.0f} N m (4)",
            f"the drives' current limits: shoulder {i_shoulder:.0f} A, {i_shoulder * ks:.1f} N m; elbow "
            f"{i_elbow:.0f} A, {i_elbow * ke:.1f} N m", "[EMU] one drive for both arms, covering the larger limit: "
            + ("each covered" if i_shoulder * ks >= worst_shoulder and i_elbow * ke >= worst_elbow else "NOT covered")),
        Row("X6", "brakes", "none", f"{shoulder.brake_hold_nm:.0f} N m at each joint: {BRAKE_HOLD_FACTOR} x the gear "
            f"head's {motor.rated_torque_nm:.0f} N m rating "
            f"({motor.rated_torque_nm / (motor.gearhead.ratio * motor.gearhead.efficiency):.1f} N m at the motor)",
            "[EMU] ASPOD's rule (`BRAKE_HOLD_FACTOR`)"),
        Row("X7", "joint ranges", "none; the path is lost (4.1)",
            f"along the planned path (rod links) the shoulders span {low[0::2].min():.1f}..{high[0::2].max():.1f}°, "
            f"the elbows {low[1::2].min():.1f}..{high[1::2].max():.1f}°; limit switches {limits[0][0]:.0f}..+"
            f"{limits[0][1]:.0f}° and {limits[1][0]:.0f}..+{limits[1][1]:.0f}°, hard stops {stops[0][0]:.0f}..+"
            f"{stops[0][1]:.0f}° and {stops[1][0]:.0f}..+{stops[1][1]:.0f}°",
            "[EMU] chosen around the path: " + ("it lies inside" if inside else "it does NOT lie inside")),
        Row("X8", "joint speeds", "none given (the report's plan has no time: P5)",
            f"the minimum-time plan in Earth gravity peaks at {' / '.join(f'{v:.1f}' for v in speeds)} rad/s; "
            f"no-load {no_load:.0f} rad/s", f"[EMU] the fastest joint at {speeds.max() / no_load * 100:.0f} % of "
            "no-load"),
        Row("X9", "J3, J4, gripper, mount", "none: the example's arms have two joints (4)",
            "ASPOD's own channels (`CHANNEL_PARAMS`: T10-T12), the mount held at home (the object lives in the "
            "arm plane)" if arm.channels[J3:] == aspod.channels[J3:] and arm.mount == aspod.mount
            else "changed from ASPOD's", "[EMU] ASPOD's, unchanged"),
    ]


# ---- the page ----------------------------------------------------------------------------------------------------

SECTIONS: dict[str, Callable[[], list[Row]]] = {
    "links": link_rows, "deflections": deflection_rows, "moments": moment_rows, "torques": torque_rows,
    "worst-case": worst_rows, "mount": mount_rows, "speed": speed_rows, "tracker": tracker_rows, "box": box_rows,
    "planner": planner_rows, "object": object_rows, "example-arm": example_arm_rows}

HEADER = ("| id | figure | report (where) | emulator | compared |", "|---|---|---|---|---|")
BLOCK = re.compile(r"(?P<head><!-- table:(?P<key>[\w-]+) [^>]*-->\n)(?P<body>.*?)"
                   r"(?P<tail><!-- end table:(?P=key) -->\n)", re.S)


def cell(text: str) -> str:
    return text.replace("|", "\\|")


def table(rows: list[Row]) -> str:
    """A markdown table, one line a row."""
    return "\n".join((*HEADER, *("| " + " | ".join(cell(c) for c in row) + " |" for row in rows))) + "\n"


def render(key: str) -> str:
    return table(SECTIONS[key]())


def blocks(page: str) -> dict[str, str]:
    """The generated tables on the page, by key."""
    return {m["key"]: m["body"] for m in BLOCK.finditer(page)}


def fill(page: str) -> str:
    """The page with every generated table rendered again from the code."""
    return BLOCK.sub(lambda m: m["head"] + render(m["key"]) + m["tail"], page)


# ---- the tests ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("key", list(SECTIONS))
def test_the_page_states_what_the_code_gives(key):
    page = blocks(PAGE.read_text())
    assert key in page, f"docs/fidelity.md has no table {key!r}: add its markers, then {REGENERATE}"
    expected = render(key)
    if page[key] != expected:
        diff = "\n".join(difflib.unified_diff(page[key].splitlines(), expected.splitlines(), "docs/fidelity.md",
                                              "the code now", lineterm=""))
        pytest.fail(f"docs/fidelity.md's table {key!r} disagrees with the code; if the code is right, "
                    f"{REGENERATE}\n{diff}")


def test_the_page_has_each_table_once_and_names_only_rows_it_has():
    text = PAGE.read_text()
    keys = [m["key"] for m in BLOCK.finditer(text)]
    assert sorted(keys) == sorted(SECTIONS), "each table of SECTIONS once on the page, and no other"
    ids = re.findall(r"^\| ([A-Z]+\d+) \|", text, re.M)
    assert len(ids) == len(set(ids)), "row ids are unique"
    prose = BLOCK.sub("", text)
    named = set(re.findall(r"\b(?:L|D|E|T|W|M|S|SU|B|P|G|X)\d+\b", prose))
    assert named <= set(ids), f"the prose names rows the tables do not have: {sorted(named - set(ids))}"


def test_the_arm_figures_come_from_the_plants_parameters():
    """Heavier elbow hardware changes J1's figures and the mount's, and leaves the report's side alone."""
    geometry = dataclasses.replace(ARM_PLANT_PARAMS.geometry, elbow_hw_kg=ARM_PLANT_PARAMS.geometry.elbow_hw_kg * 2)
    heavier = dataclasses.replace(ARM_PLANT_PARAMS, geometry=geometry)
    for rows_of in (torque_rows, moment_rows, mount_rows):
        now, then = rows_of(), rows_of(heavier)
        assert [r.report for r in now] == [r.report for r in then]
        assert [r.emulator for r in now] != [r.emulator for r in then], rows_of.__name__


def test_the_report_side_arithmetic():
    """The figures the page derives from the report's own numbers (in its report column and its prose), worked
    again."""
    assert round(78.60 + 285.61 + 285.61, 2) == 649.82 and round(649.82 / 12, 2) == 54.15     # M4
    assert round(55 * 12) == 660 and round(55 * LBF_FT_TO_NM, 1) == 74.6                      # M1
    assert round(650 * LBF_IN_TO_NM, 1) == 73.4                                                # M2
    assert 180.0 / (0.5 * 360.0 / 60.0) == 60.0 and 90.0 / (0.5 * 360.0 / 60.0) == 30.0       # S2, S3
    acc = 4 * math.pi / 30.0 ** 2                      # Appendix B: EQ.17 over each half of a half turn in 30 s
    assert round(acc, 4) == 0.0140 and round(math.degrees(acc), 2) == 0.80
    assert round(acc * 15.0 / RPM_TO_RAD_S) == 2                                               # S4: peak 2 RPM
    assert round(104.70 * acc / 317.2 * 100, 2) == 0.46                                        # S5
    assert round(fahrenheit(-10.0)) == 14 and round(fahrenheit(45.0)) == 113                   # B1
    assert round(0.5 * RPM_TO_RAD_S, 4) == 0.0524 and round(0.5 * 360 / 60, 1) == 3.0          # S1
    assert round(4569.6 * OZ_IN_TO_NM, 2) == 32.27 and round(1257.6 * OZ_IN_TO_NM, 2) == 8.88  # T1, T5
    assert round(TUBE_I_IN4, 4) == 0.5518 and round(E_PSI / AL_6061_DENSITY_LB_IN3 / 1e6, 1) == 105.1
    assert round(40e3 / AL_6061_DENSITY_LB_IN3 / 1e6, 2) == 0.41            # Table 1's yield over its density
    assert round(0.0135 * 25.4, 2) == 0.34 and 0.0135 / 0.39 < 0.04          # Table 3 against its 1 cm
    assert round(10.8 * 24 + 2.2 * 12, 2) == 285.60 and round(285.61 * LBF_IN_TO_NM, 1) == 32.3   # E2
    assert round(888.0 / 660.0 - 1, 2) == 0.35 and round(888.0 / 12, 1) == 74.0                  # the mount
    assert round(888.0 - 649.82, 2) == 238.18 and round(891.75 - 888.0, 2) == 0.75 + 1.50 + 1.50
    assert round(317.2 / (285.61 * LBF_IN_TO_NM)) == 10                      # Appendix B against Table 4
    assert round(math.pi * 5.0, 1) == 15.7 and round(12.0 / (math.pi * 5.0) * 360.0) == 275    # the track
    assert round(LBF_IN_TO_NM, 4) == 0.1130 and round(OZ_IN_TO_NM * 1000, 3) == 7.062         # the units


if __name__ == "__main__":
    PAGE.write_text(fill(PAGE.read_text()))
