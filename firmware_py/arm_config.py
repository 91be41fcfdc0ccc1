"""What the firmware knows about the arm: its drives, its mass properties, its parameters.

A real controller carries a description of the hardware it drives: motor constants from the
datasheets, gear ratios and encoder resolutions from the build, link masses and lengths for
gravity compensation. This is that description. It is the firmware's own copy: the firmware
never imports the plant (`hil_sim`), exactly as it could not import the real arm;
`tests/test_arm_control.py` checks that the two agree where they must.

Sources: the report (`../shared/seed/000_54a4d1d9271955c2.txt`), sections "JOINTS AND
ACTUATORS", "WRIST AND GRIPPER", "DESIGN OF THE MOBILE MOUNT" and the keys to Figures 8 and 9;
where the report is silent the numbers are the ones `hil_sim/arm_params.py` documents as
ASSUMED (motor internals, encoders, limits).

Units inside the firmware are SI (rad, m, N m); the protocol and the parameters speak
degrees and millimetres, converted at the border (`firmware_py/arm.py`).
"""
from __future__ import annotations

import math
from dataclasses import astuple, dataclass, fields
from typing import Optional

from firmware_py import joints_tick as jt
from firmware_py.axis import AxisConfig, motor_gains
from firmware_py.estimator import EstimatorConfig
from firmware_py.params import ParamSpec
from firmware_py.profiles import REPORT_JOINT_SPEED_RAD_S
from protocol import units
from protocol.units import IN_TO_M, LB_TO_KG

OZ_IN_TO_NM = round(units.OZ_IN_TO_NM, 8)   # the firmware's table keeps the conversion to six figures: 0.00706155
SUPPLY_NOMINAL_V = 28.0
ENCODER_COUNTS_PER_MOTOR_REV = 400     # 100-line quadrature encoders, counted x4


@dataclass(frozen=True)
class Drive:
    """One motor channel as the firmware sees it (joint side unless named motor)."""

    name: str
    kt_nm_a: float              # motor torque constant (= back-EMF constant, SI)
    r_ohm: float                # armature resistance
    ratio: float                # gear head x external stages
    efficiency: float           # of the whole train
    inertia_kg_m2: float        # rotor reflected through the train, plus the output's own
    load_inertia_kg_m2: float   # typical arm load seen at the joint (outstretched, Earth)
    viscous_nm_s_rad: float     # joint side
    soft_min_deg: float
    soft_max_deg: float
    home_dir: int = 1           # the home flag is active at and above home: seek it upward
    i_limit_a: float = 1.5
    vel_bandwidth_rad_s: float = 60.0   # the velocity loop's (docs/arm.md, Gains and Settling)

    @property
    def rad_per_count(self) -> float:
        return 2 * math.pi / (ENCODER_COUNTS_PER_MOTOR_REV * self.ratio)

    @property
    def no_load_speed_rad_s(self) -> float:
        return SUPPLY_NOMINAL_V / (self.kt_nm_a * self.ratio)


# Motor constants: the 400 oz-in gear-head motor (J1, J2; report, Key to Figure 8 part 44),
# the 200 oz-in one (J3, part 58), the wrist roll's small gearmotor, the TENV mount gearmotor.
# Ratios: gear heads 100:1 (J1-J3), 200:1 (J4), 300:1 (mount); sprockets 16:1 (J1, two 4:1
# pairs), 6:1 (J2), 3:1 (J3) from "JOINTS AND ACTUATORS"; the mount's 4:1 chain.
#
# Current limits: near each motor's rating, so that a joint can hold and move its load
# (J1 needs about 1.1 A against gravity at full stretch, the report's 285.6 oz-in) but cannot
# drag its own spring-applied brake (1.5 x the rated output torque): a stuck brake then
# stalls the joint instead of wearing the brake away.
DRIVES = (
    Drive("j1", 5.0 * OZ_IN_TO_NM, 6.0, 1600.0, 0.687, 38.40, 3.5, 4.35, -55.0, 85.0, i_limit_a=1.5),
    Drive("j2", 5.0 * OZ_IN_TO_NM, 6.0, 600.0, 0.708, 5.40, 0.34, 0.61, -130.0, 130.0, i_limit_a=1.5),
    Drive("j3", 3.5 * OZ_IN_TO_NM, 8.0, 300.0, 0.708, 0.72, 0.011, 0.072, -130.0, 130.0, i_limit_a=1.0),
    Drive("j4", 2.5 * OZ_IN_TO_NM, 10.0, 200.0, 0.66, 0.12, 0.0005, 0.0052, -175.0, 175.0, i_limit_a=0.4),
    Drive("mount", 8.0 * OZ_IN_TO_NM, 4.0, 1200.0, 0.665, 172.85, 15.8, 5.76, -165.0, 165.0, i_limit_a=1.2),
)
JOINTS = {d.name: d for d in DRIVES}


@dataclass(frozen=True)
class GripperModel:
    """The push/pull gripper: a 27.5 VDC motor, a 20:1 head, a lead screw (Key to Figure 9)."""

    ratio: float = 20.0
    lead_m_per_rad: float = 0.0004042535554534142    # jaw opening per screw radian
    open_switch_m: float = 2.0 * IN_TO_M - 0.0005     # opening at which the open switch closes

    @property
    def m_per_count(self) -> float:
        return 2 * math.pi / (ENCODER_COUNTS_PER_MOTOR_REV * self.ratio) * self.lead_m_per_rad


GRIPPER = GripperModel()


@dataclass(frozen=True)
class MassModel:
    """Link lengths and lumped masses for gravity compensation (report, "ARM DESIGN" and Key to Figure 8).

    Links II and III: 6061-T6 square tube 2x2x1/8 in, 24 and 12 in long (2.2 and 1.1 lb);
    elbow hardware at J2, the wrist split into a part fixed at J3 and a part J3 turns.
    """

    link2_m: float = 24 * IN_TO_M
    link3_m: float = 12 * IN_TO_M
    link2_kg: float = 2.2 * LB_TO_KG
    link3_kg: float = 1.1 * LB_TO_KG
    elbow_hw_kg: float = 1.678291769
    wrist_fixed_kg: float = 1.36077711
    wrist_turned_kg: float = 1.36077711
    wrist_turned_cg_m: float = 0.0677333333
    tip_m: float = 0.2032

    def holding_torques_nm(self, q1: float, q2: float, q3: float, g: float,
                           payload_kg: float = 0.0) -> tuple[float, float, float]:
        """Torques J1, J2, J3 must apply to hold the pose against gravity `g` [m/s^2] (computed by
        `joints_tick.holding_torques_nm`, which the joints' kernel runs too)."""
        return jt.holding_torques_nm(q1, q2, q3, g, payload_kg, self.row)

    @property
    def row(self) -> tuple[float, ...]:
        """The model as a row of numbers, its fields in order (the columns named in firmware_py/joints_tick.py)."""
        return astuple(self)


MASSES = MassModel()
# the row's columns are the fields, in order
assert all(getattr(jt, f.name.upper()) == k for k, f in enumerate(fields(MassModel))) and len(MASSES.row) == jt.MASS_COLUMNS


# ---- parameters ----------------------------------------------------------------------------------
def parameter_table() -> list[ParamSpec]:
    """The arm's parameters: per joint limits, speed, acceleration, gains, current limit; gripper; gravity."""
    specs = [ParamSpec("gravity_m_s2", 9.80665, 0.0, 20.0, "m/s^2",
                       "gravity the feed-forward compensates (9.80665 on Earth, 0 in orbit)"),
             ParamSpec("payload_kg", 0.0, 0.0, 5.0, "kg", "mass carried at the gripper, for the feed-forward"),
             # Staleness limits (docs/realtime.md). In a simulated world (paced or lock-step) time never
             # stalls, so they only ever judge the plant; on real time they must also outlast the stalls a
             # CPython process sees on a busy host (measured here: loops 25 ms late at load 5, CAN gaps of
             # 8.7 ms between two quiet processes), hence about twice the worst seen.
             ParamSpec("encoder_stale_s", 0.05, 0.002, 10.0, "s",
                       "an axis with no new encoder count for this long faults (HAL_STALE, ENCODER_STALE)"),
             ParamSpec("current_stale_s", 0.05, 0.002, 10.0, "s",
                       "a driving axis with no current reading for this long faults (HAL_STALE, CURRENT_STALE)")]
    for d in DRIVES:
        gains = default_gains(d)
        n = d.name
        specs += [
            ParamSpec(f"{n}_min_deg", d.soft_min_deg, -360.0, 360.0, "deg", f"{n} soft limit, low side"),
            ParamSpec(f"{n}_max_deg", d.soft_max_deg, -360.0, 360.0, "deg", f"{n} soft limit, high side"),
            ParamSpec(f"{n}_speed_dps", math.degrees(REPORT_JOINT_SPEED_RAD_S), 0.1, highest_speed_dps(d), "deg/s",
                      f"{n} default and highest speed (report: 1/2 RPM = 3 deg/s)"),
            ParamSpec(f"{n}_acc_dps2", 3.0, 0.1, 100.0, "deg/s^2", f"{n} acceleration limit"),
            ParamSpec(f"{n}_kp", round(gains["kp_pos_1_s"], 4), 0.0, 1000.0, "1/s", f"{n} position loop gain"),
            ParamSpec(f"{n}_kv", round(gains["kv_duty_s_rad"], 4), 0.0, 1000.0, "duty s/rad",
                      f"{n} velocity loop proportional gain"),
            ParamSpec(f"{n}_ki", round(gains["ki_duty_rad"], 4), 0.0, 100000.0, "duty/rad",
                      f"{n} velocity loop integral gain"),
            ParamSpec(f"{n}_i_lim_a", d.i_limit_a, 0.1, 20.0, "A", f"{n} motor current limit"),
        ]
    specs += [
        ParamSpec("grip_duty", 0.8, 0.05, 1.0, "", "gripper duty while opening or closing"),
        ParamSpec("grip_hold_duty", 0.3, 0.0, 1.0, "", "gripper duty holding a grip (sets the grip force)"),
        ParamSpec("grip_current_a", 0.6, 0.05, 5.0, "A", "gripper current that, with the jaws still, means a grip"),
        ParamSpec("grip_timeout_s", 5.0, 0.5, 60.0, "s", "longest open or close before a GRIPPER fault"),
    ]
    return specs


SPEED_PARAM_MAX_DPS = 30.0


def highest_speed_dps(d: Drive) -> float:
    """The most `<axis>_speed_dps` may be: 30 deg/s, and never faster than the motor turns unloaded at the
    nominal supply, in whole deg/s (J1 28 for its 28.4, the mount 23 for its 23.7: exact on the wire's f32), a
    speed no load lets it follow."""
    return min(SPEED_PARAM_MAX_DPS, float(math.floor(math.degrees(d.no_load_speed_rad_s))))


def default_gains(d: Drive) -> dict[str, float]:
    return motor_gains(d.kt_nm_a, d.r_ohm, d.ratio, SUPPLY_NOMINAL_V, d.inertia_kg_m2 + d.load_inertia_kg_m2,
                       d.viscous_nm_s_rad, vel_bandwidth_rad_s=d.vel_bandwidth_rad_s, efficiency=d.efficiency)


def check_param(values: dict[str, float], dt_s: float, name: str, value: float) -> Optional[str]:
    """Why `name` = `value` would make a joint's configuration inconsistent (e.g. its minimum above its maximum),
    given the other parameter `values`; None if it would not."""
    for drive in DRIVES:
        if name.startswith(drive.name + "_"):
            try:
                axis_config(drive, values, dt_s, override=(name, value))
            except ValueError as exc:
                return str(exc)
    return None


def axis_config(d: Drive, values: dict[str, float], dt_s: float, override: Optional[tuple[str, float]] = None
                ) -> AxisConfig:
    """The AxisConfig of joint `d` from the parameter values (with one value overridden, to check it)."""
    if override is not None:
        values = dict(values)
        values[override[0]] = override[1]
    n = d.name
    gains = default_gains(d)
    vel = math.radians(values[f"{n}_speed_dps"])
    return AxisConfig(
        estimator=EstimatorConfig(rad_per_count=d.rad_per_count, dt_s=dt_s,
                                  max_vel_rad_s=1.5 * d.no_load_speed_rad_s, max_acc_rad_s2=2.0,
                                  stale_ticks=max(1, math.ceil(values["encoder_stale_s"] / dt_s - 1e-9))),
        name=n, vel_limit_rad_s=vel, acc_limit_rad_s2=math.radians(values[f"{n}_acc_dps2"]),
        kp_pos_1_s=values[f"{n}_kp"], kv_duty_s_rad=values[f"{n}_kv"], ki_duty_rad=values[f"{n}_ki"],
        ff_vel_duty_s_rad=gains["ff_vel_duty_s_rad"], ff_acc_duty_s2_rad=gains["ff_acc_duty_s2_rad"],
        ff_torque_duty_nm=gains["ff_torque_duty_nm"],
        i_limit_a=values[f"{n}_i_lim_a"], i_trip_a=values[f"{n}_i_lim_a"] * 2.0, i_trip_s=0.1,
        soft_min_rad=math.radians(values[f"{n}_min_deg"]), soft_max_rad=math.radians(values[f"{n}_max_deg"]),
        following_error_rad=0.05, in_position_rad=2e-4, in_position_vel_rad_s=2e-3, settle_timeout_s=3.0,
        stall_time_s=0.5, stall_vel_rad_s=0.002,
        home_dir=d.home_dir, home_vel_rad_s=min(0.02, vel), home_pos_rad=0.0, home_backoff_rad=0.02,
        home_max_travel_rad=math.radians(60.0),
        current_stale_s=values["current_stale_s"])
