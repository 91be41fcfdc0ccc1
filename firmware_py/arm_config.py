"""What the firmware knows about the arm it drives: its drives, its mass properties, its parameters.

A real controller carries a description of the hardware it drives: motor constants from the
datasheets, gear ratios and encoder resolutions from the build, link masses and lengths for
gravity compensation. This is that description, one `ArmDescription` per arm: a controller is
built for one (`ControllerConfig.arm`), so two controllers in one process can drive two different
arms. It is the firmware's own copy: the firmware never imports the plant (`hil_sim`), exactly as
it could not import the real arm; `tests/test_arm_config.py` checks that the two agree where they must.

Two arms (docs/arm.md, "The arm description"):

* `ASPOD_ARM`, the default: the report's arm. Sources: the report (`../shared/seed/000_54a4d1d9271955c2.txt`),
  sections "JOINTS AND ACTUATORS", "WRIST AND GRIPPER", "DESIGN OF THE MOBILE MOUNT" and the keys to Figures 8
  and 9; where the report is silent the numbers are the ones `hil_sim/arm_params.py` documents as ASSUMED (motor
  internals, encoders, limits).
* `EXAMPLE_ARM`: ASPOD's controller driving an arm built to the report's coordinated example (two 1 m, 1 kg
  links; host_tools/plan/example.py): its own shoulder and elbow drives and masses, ASPOD's J3, J4, gripper and
  mount (the numbers are decided in issue 39's EXAMPLE_ARM.md; the report gives none).

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
from protocol.states import ARM_CHANNELS
from protocol.units import IN_TO_M, LB_TO_KG

OZ_IN_TO_NM = round(units.OZ_IN_TO_NM, 8)   # the firmware's table keeps the conversion to six figures: 0.00706155
SUPPLY_NOMINAL_V = 28.0               # both arms' motors run from the 28 V bus
ENCODER_COUNTS_PER_MOTOR_REV = 400     # 100-line quadrature encoders, counted x4 (both arms)
DRIVE_NAMES = tuple(name for name in ARM_CHANNELS if name != "gripper")    # an arm's drives, in channel order


@dataclass(frozen=True)
class Drive:
    """One motor channel as the firmware sees it (joint side unless named motor); the defaults are ASPOD's."""

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
    max_acc_rad_s2: float = 2.0         # the largest acceleration the estimator follows (its process noise)
    speed_cap_dps: float = 30.0         # the most `<axis>_speed_dps` may be, below the no-load speed
    i_limit_max_a: float = 20.0         # the most `<axis>_i_lim_a` may be

    @property
    def rad_per_count(self) -> float:
        return 2 * math.pi / (ENCODER_COUNTS_PER_MOTOR_REV * self.ratio)

    @property
    def no_load_speed_rad_s(self) -> float:
        return SUPPLY_NOMINAL_V / (self.kt_nm_a * self.ratio)


@dataclass(frozen=True)
class GripperModel:
    """The push/pull gripper: a 27.5 VDC motor, a 20:1 head, a lead screw (Key to Figure 9); the defaults are
    ASPOD's."""

    ratio: float = 20.0
    lead_m_per_rad: float = 0.0004042535554534142    # jaw opening per screw radian
    open_switch_m: float = 2.0 * IN_TO_M - 0.0005     # opening at which the open switch closes

    @property
    def m_per_count(self) -> float:
        return 2 * math.pi / (ENCODER_COUNTS_PER_MOTOR_REV * self.ratio) * self.lead_m_per_rad



@dataclass(frozen=True)
class MassModel:
    """Link lengths and lumped masses for gravity compensation; the defaults are ASPOD's (report, "ARM DESIGN"
    and Key to Figure 8).

    Links II and III: 6061-T6 square tube 2x2x1/8 in, 24 and 12 in long (2.2 and 1.1 lb), uniform;
    elbow hardware at J2, the wrist split into a part fixed at J3 and a part J3 turns; the hand (where a
    payload is held) `tip_m` beyond J3 along the gripper.
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


# the row's columns are the fields, in order
assert [getattr(jt, f.name.upper()) for f in fields(MassModel)] == list(range(jt.MASS_COLUMNS))


# ---- the arm, and its parameters ---------------------------------------------------------------------
@dataclass(frozen=True)
class ArmDescription:
    """One arm as its controller knows it: its drives (J1..J4 and the mount, in their HAL channels' order), its
    mass model (gravity feed-forward) and its gripper; and its parameter table, which takes its defaults and
    ranges from them (each joint's soft limits, speed cap, gains and current limit)."""

    name: str
    drives: tuple[Drive, ...]
    masses: MassModel
    gripper: GripperModel

    def __post_init__(self) -> None:
        names = tuple(d.name for d in self.drives)
        if names != DRIVE_NAMES:
            raise ValueError(f"{self.name}: the drives must be {', '.join(DRIVE_NAMES)} in that order, not "
                             f"{', '.join(names)}")

    def drive(self, name: str) -> Drive:
        """The drive of joint `name` (KeyError: none)."""
        for d in self.drives:
            if d.name == name:
                return d
        raise KeyError(name)

    def parameter_table(self) -> list[ParamSpec]:
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
        for d in self.drives:
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
                ParamSpec(f"{n}_i_lim_a", d.i_limit_a, 0.1, d.i_limit_max_a, "A", f"{n} motor current limit"),
            ]
        specs += [
            ParamSpec("grip_duty", 0.8, 0.05, 1.0, "", "gripper duty while opening or closing"),
            ParamSpec("grip_hold_duty", 0.3, 0.0, 1.0, "", "gripper duty holding a grip (sets the grip force)"),
            ParamSpec("grip_current_a", 0.6, 0.05, 5.0, "A", "gripper current that, with the jaws still, means a grip"),
            ParamSpec("grip_timeout_s", 5.0, 0.5, 60.0, "s", "longest open or close before a GRIPPER fault"),
        ]
        return specs

    def check_param(self, values: dict[str, float], dt_s: float, name: str, value: float) -> Optional[str]:
        """Why `name` = `value` would make a joint's configuration inconsistent (e.g. its minimum above its
        maximum), given the other parameter `values`; None if it would not."""
        for drive in self.drives:
            if name.startswith(drive.name + "_"):
                try:
                    axis_config(drive, values, dt_s, override=(name, value))
                except ValueError as exc:
                    return str(exc)
        return None


def highest_speed_dps(d: Drive) -> float:
    """The most `<axis>_speed_dps` may be: the drive's cap (ASPOD's: 30 deg/s), and never faster than the motor
    turns unloaded at the nominal supply, in whole deg/s (ASPOD's J1 28 for its 28.4, the mount 23 for its 23.7:
    exact on the wire's f32), a speed no load lets it follow."""
    return min(d.speed_cap_dps, float(math.floor(math.degrees(d.no_load_speed_rad_s))))


def default_gains(d: Drive) -> dict[str, float]:
    return motor_gains(d.kt_nm_a, d.r_ohm, d.ratio, SUPPLY_NOMINAL_V, d.inertia_kg_m2 + d.load_inertia_kg_m2,
                       d.viscous_nm_s_rad, vel_bandwidth_rad_s=d.vel_bandwidth_rad_s, efficiency=d.efficiency)


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
                                  max_vel_rad_s=1.5 * d.no_load_speed_rad_s, max_acc_rad_s2=d.max_acc_rad_s2,
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


# ---- ASPOD's arm (the default) ---------------------------------------------------------------------
# Motor constants: the 400 oz-in gear-head motor (J1, J2; report, Key to Figure 8 part 44),
# the 200 oz-in one (J3, part 58), the wrist roll's small gearmotor, the TENV mount gearmotor.
# Ratios: gear heads 100:1 (J1-J3), 200:1 (J4), 300:1 (mount); sprockets 16:1 (J1, two 4:1
# pairs), 6:1 (J2), 3:1 (J3) from "JOINTS AND ACTUATORS"; the mount's 4:1 chain.
#
# Current limits: near each motor's rating, so that a joint can hold and move its load
# (J1 needs about 1.1 A against gravity at full stretch, the report's 285.6 oz-in) but cannot
# drag its own spring-applied brake (1.5 x the rated output torque): a stuck brake then
# stalls the joint instead of wearing the brake away.
ASPOD_ARM = ArmDescription("ASPOD", (
    Drive("j1", 5.0 * OZ_IN_TO_NM, 6.0, 1600.0, 0.687, 38.40, 3.5, 4.35, -55.0, 85.0, i_limit_a=1.5),
    Drive("j2", 5.0 * OZ_IN_TO_NM, 6.0, 600.0, 0.708, 5.40, 0.34, 0.61, -130.0, 130.0, i_limit_a=1.5),
    Drive("j3", 3.5 * OZ_IN_TO_NM, 8.0, 300.0, 0.708, 0.72, 0.011, 0.072, -130.0, 130.0, i_limit_a=1.0),
    Drive("j4", 2.5 * OZ_IN_TO_NM, 10.0, 200.0, 0.66, 0.12, 0.0005, 0.0052, -175.0, 175.0, i_limit_a=0.4),
    Drive("mount", 8.0 * OZ_IN_TO_NM, 4.0, 1200.0, 0.665, 172.85, 15.8, 5.76, -165.0, 165.0, i_limit_a=1.2),
), MassModel(), GripperModel())


# ---- the example arm ---------------------------------------------------------------------------------
# ASPOD's controller driving an arm built to the report's coordinated example (host_tools/plan/example.py; issue 39's
# EXAMPLE_ARM.md decides the numbers, the plant's copy is hil_sim/arm_params.py's). Links II and III: 1 m, 1 kg
# uniform rods; nothing at the elbow or the wrist; the hand at the J3 axis (the planner's "rod" links). J3, J4, the
# gripper and the mount are ASPOD's.
#
# [EMU] The report gives the example no drives. The shoulder's and the elbow's: one 28 V brushed PM DC motor class
# (R 0.4 ohm, kt = ke 0.04 N m/A, rotor 3.0e-5 kg m^2, viscous 2e-6 N m s/rad) through a 50:1 gear head of efficiency
# 0.85: 1.7 N m/A at the joint, 14 rad/s unloaded at 28 V, the rotor 0.075 kg m^2 at the joint (plus the output's own
# 2e-3 and 1e-3). Current limits 21 A at the shoulder (35.7 N m: the example's |u1| < 30 and |u3| < 35) and 12 A at
# the elbow (20.4 N m: |u2| < 20, |u4| < 15), at most 30 A (the current that would drag the brake, 1.5 x the motor's
# rated 0.8 N m). Soft limits -90..135 and -3..170 deg (the example's paths span -40.5..112.5 and 66.9..149.4). Speed
# cap 600 deg/s (10.5 rad/s, 75 % of no-load; the minimum-time plans peak at 6.9 rad/s). Typical load, the arm
# stretched out: at J1 link II's m l^2 / 3, link III's m l^2 / 12 + m (1.5 l)^2 (2.667 kg m^2); at J2 m l^2 / 3.
#
# Loops. ASPOD's joints see their loads through 300:1 to 1600:1, the load at most a tenth of the rotor; here the load
# is up to 35 times the rotor, so J1's inertia falls from 2.74 to 0.76 kg m^2 as the elbow folds (0 to 170 deg), and
# the counts are 32 times coarser than ASPOD's J1's. With ASPOD's tuning (the velocity loop at 60 rad/s, the estimator
# following 2 rad/s^2) the shoulder's loop is unstable with the elbow bent past 60 deg and damped 0.06 stretched out.
# So the velocity loops run at 40 rad/s and the estimators follow 50 rad/s^2 (what the drives give their loads at
# their current limits: the elbow's 20.4 N m on 0.41 kg m^2). Every loop's damping ratio at 1 kHz is then 0.59 or more
# over the shoulder's whole range of inertia, 0.69 at the elbow, the duty applied at once or a tick late (ASPOD's
# joints: 0.71 or more); tests/test_arm_description.py. The acceleration feed-forward takes the stretched-out
# inertia, as ASPOD's does its typical load: folded, it overshoots its share 3.6 times and the loops take the rest.
EXAMPLE_LINK_M = 1.0
EXAMPLE_LINK_KG = 1.0


def _example_drive(name: str, output_inertia_kg_m2: float, load_inertia_kg_m2: float, soft_deg: tuple[float, float],
                   i_limit_a: float) -> Drive:
    ratio = 50.0
    return Drive(name, 0.04, 0.4, ratio, 0.85, 3.0e-5 * ratio ** 2 + output_inertia_kg_m2, load_inertia_kg_m2,
                 2e-6 * ratio ** 2, *soft_deg, i_limit_a=i_limit_a, vel_bandwidth_rad_s=40.0, max_acc_rad_s2=50.0,
                 speed_cap_dps=600.0, i_limit_max_a=30.0)


_M, _L = EXAMPLE_LINK_KG, EXAMPLE_LINK_M
EXAMPLE_ARM = ArmDescription("example", (
    _example_drive("j1", 2e-3, _M * _L ** 2 / 3 + _M * _L ** 2 / 12 + _M * (1.5 * _L) ** 2, (-90.0, 135.0), 21.0),
    _example_drive("j2", 1e-3, _M * _L ** 2 / 3, (-3.0, 170.0), 12.0),     # (homed at -1.15 deg: inside)
) + ASPOD_ARM.drives[2:], MassModel(link2_m=_L, link3_m=_L, link2_kg=_M, link3_kg=_M, elbow_hw_kg=0.0,
                                    wrist_fixed_kg=0.0, wrist_turned_kg=0.0, wrist_turned_cg_m=0.0, tip_m=0.0),
    ASPOD_ARM.gripper)
