"""Parameters of the arm, mount and gripper plant: one file, every number sourced.

"report" is the ASPOD report (shared/seed/000_54a4d1d9271955c2.txt, University of Arizona
/ USRA 1990-91); citations name its section or table. Numbers the report does not give
are marked ASSUMED with the reasoning: they are plausible values for the motor class
the report names, chosen so the report's own figures (torques, safety factors, 1/2 RPM)
come out, not measurements of the real parts.

Conventions (see `hil_sim.arm` for the geometry):
- Channels, in this order: J1 shoulder, J2 elbow, J3 wrist bend, J4 wrist roll, gripper,
  mount (`ARM_CHANNELS`). The tracker axes AZ and EL belong to a later issue.
- The arm moves in a vertical plane through the mount's central shaft. Link I stands
  vertical on the mobile mount's arm at the track radius; J1 sits on its top. Joint
  angles J1-J3 are measured in that plane, positive = raising (J1 = 0: link II
  horizontal, pointing away from the shaft; J2 = J3 = 0: in line with the previous link).
- Motor-side values (resistance, Kt, rotor inertia, motor friction) are at the motor
  shaft; everything else is at the channel's output shaft (the joint).

The report's load cases, reproduced by `hil_sim.arm` (see tests/test_arm_plant.py):
- Appendix A treats each link as a cantilever with all outboard weight at its end:
  M = P L + w L^2 / 2. Link III: P = 6.0 lb, L = 12 in, w L = 1.1 lb -> 78.60 lb in
  (Table 4) = 1257.6 oz-in at J2 ("JOINTS AND ACTUATORS"). Link II: P = 3.7 + 6 + 1.1
  = 10.8 lb, L = 24 in, w L = 2.2 lb -> 285.6 lb in (Table 4) = 4569.6 oz-in at J1.
  P = 6.0 lb at the end of link III is not itemised; it is what reproduces 78.60 lb in.
  These are the exact static torques of the poses where the outboard parts hang straight
  down; the arm stretched out horizontally needs more (J1 372.2 lb in, J2 86.6 lb in).
- J1: 4569.6 / 16 = 285.6 oz-in at the motor, 400 / 285.6 = 1.4; J2: 1257.6 / 6 =
  209.6 oz-in, 400 / 209.6 = 1.9; J3: 200 oz-in motor, 3:1, "safety factor of 4.7" ->
  128 oz-in (8.0 lb in) at J3 with the gripper horizontal. No gear losses in the report.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hil_sim.motor import DriveParams, GearStage, MotorSpec
from protocol.states import ARM_CHANNELS
from protocol.units import DEG, G_EARTH_M_S2, IN_TO_M, LB_TO_KG, LBF_IN_TO_NM, OZ_IN_TO_NM, RPM_TO_RAD_S

GRAVITY_M_S2 = {"earth": G_EARTH_M_S2, "orbit": 0.0}

J1, J2, J3, J4, GRIPPER, MOUNT = range(6)

# ---- report figures, kept as printed (tests compare against these) ------------------------------
REPORT_J1_TORQUE_OZ_IN = 4569.6      # "JOINTS AND ACTUATORS"
REPORT_J2_TORQUE_OZ_IN = 1257.6      # "JOINTS AND ACTUATORS"
REPORT_J1_SAFETY_FACTOR = 1.4        # "JOINTS AND ACTUATORS"
REPORT_J2_SAFETY_FACTOR = 1.9        # "JOINTS AND ACTUATORS"
REPORT_J3_SAFETY_FACTOR = 4.7        # "WRIST AND GRIPPER"
REPORT_MOUNT_MOMENT_LB_IN = 888.0    # "DEFLECTION AND MOMENT ANALYSIS", Table 4, mobile mount, unloaded
REPORT_SHAFT_TORQUE_LBF_FT = 55.0    # "SHAFT ASSEMBLY": "approximated at 55 lbf ft"
REPORT_ARM_TORQUE_LB_IN = 650.0      # "MOBILE ARM and WHEEL GUIDE ASSEMBLY": "650 lb/in" (sic)
REPORT_TEST_LOAD_KG = 0.0625 * LB_TO_KG   # Appendix A: "LOAD = 1 oz (0.0625 lb)"
POSITIONING_SPEC_M = 0.01            # "DEFLECTION AND MOMENT ANALYSIS": 1 cm (0.39 in)
JOINT_SPEED_RAD_S = 0.5 * RPM_TO_RAD_S    # same section: keep joints at or below 1/2 RPM
AL_6061_DENSITY_LB_IN3 = 0.098       # "MANIPULATOR LINK AND JOINT MATERIAL", Table 1


def square_tube_weight_lb(side_in: float, wall_in: float, length_in: float) -> float:
    """Weight of a 6061-T6 square tube from Table 1's density (checks Table 2's weights)."""
    area_in2 = side_in ** 2 - (side_in - 2.0 * wall_in) ** 2
    return area_in2 * length_in * AL_6061_DENSITY_LB_IN3


# ---- geometry and masses -------------------------------------------------------------------------
@dataclass(frozen=True)
class ArmGeometry:
    """Lengths [m], masses [kg] and inertias of the manipulator (lumped model, `hil_sim.arm`)."""

    # Table 2 ("DEFLECTION AND MOMENT ANALYSIS"): 6061-T6 2 x 2 x 1/8 in square tube.
    link1_m: float = 12.0 * IN_TO_M
    link2_m: float = 24.0 * IN_TO_M
    link3_m: float = 12.0 * IN_TO_M
    link1_kg: float = 1.1 * LB_TO_KG
    link2_kg: float = 2.2 * LB_TO_KG
    link3_kg: float = 1.1 * LB_TO_KG
    # ASSUMED: J1's motor, yoke and double sprocket pair on top of link I; like the elbow's
    # 3.7 lb plus the second sprocket pair. Only the mount's inertia sees it.
    shoulder_hw_kg: float = 4.0 * LB_TO_KG
    # Appendix A, link II: "P = 3.7 lb + 6 lb + 1.1 lb = 10.8 lb" (OCR reads "317 lb"; the
    # sum fixes it): 3.7 lb of J2 motor, yoke and sprockets at the elbow.
    elbow_hw_kg: float = 3.7 * LB_TO_KG
    # Appendix A: 6.0 lb at the end of link III (reproduces Table 4's 78.60 lb in). Split
    # (ASSUMED) into what J3 turns and what stays on link III:
    # - turned by J3: the gripper, 2.0 lb ("WRIST AND GRIPPER"), plus the J4 motor, the
    #   3.5 in extension and the collar, taken as 1.0 lb -> 3.0 lb;
    # - fixed at the J3 axis: J3 motor, gripper end block, sprockets -> the other 3.0 lb.
    wrist_fixed_kg: float = 3.0 * LB_TO_KG
    wrist_turned_kg: float = 3.0 * LB_TO_KG
    # Centre of gravity of the turned part from the J3 axis, along the gripper. Chosen so
    # the report's J3 safety factor comes out: 200 oz-in * 3 / 4.7 = 127.7 oz-in; with
    # 3.0 lb at 8/3 in: 8.0 lb in = 128 oz-in, 600 / 128 = 4.69.
    wrist_turned_cg_m: float = 8.0 / 3.0 * IN_TO_M
    # ASSUMED: the turned part about its own centre, as a 3 lb, 8 in rod: m L^2 / 12.
    wrist_turned_inertia_kg_m2: float = 3.0 * LB_TO_KG * (8.0 * IN_TO_M) ** 2 / 12.0
    # ASSUMED: gripper tip (between the jaws) 8 in from the J3 axis along the gripper:
    # 3.5 in extension ("WRIST AND GRIPPER") + 1.5 in collar (Key to Figure 9, part 65,
    # 1 1/2 in O.D.) + about 3 in of housing and jaws.
    tip_m: float = 8.0 * IN_TO_M
    # ASSUMED: gripper housing and jaws about the roll axis (J4): a 2.0 lb block of
    # 2.5 x 2 in section, m (a^2 + b^2) / 12.
    roll_inertia_kg_m2: float = 2.0 * LB_TO_KG * ((2.5 * IN_TO_M) ** 2 + (2.0 * IN_TO_M) ** 2) / 12.0
    # ASSUMED: a payload's radius of gyration about the roll axis.
    payload_gyration_m: float = 0.03

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"ArmGeometry.{name} must be finite and >= 0, got {value}")


@dataclass(frozen=True)
class MountParams:
    """The mobile mount: a shaft-driven arm carrying the manipulator around a circular track."""

    # "TRACK and TRACK MOUNTS": steel track formed into a 5 ft diameter circle; "DESIGN OF
    # THE MOBILE MOUNT": the manipulator rides on the far end of the arm near the guide
    # wheels. ASSUMED: link I's axis at the track radius.
    track_diameter_m: float = 60.0 * IN_TO_M
    # "MOBILE ARM and WHEEL GUIDE ASSEMBLY": 2 x 5 in rectangular aluminium, 3/16 in wall.
    # ASSUMED: 30 in long (shaft to track), weight from Table 1's density: 7.3 lb.
    mobile_arm_kg: float = ((2 * (2.0 + 5.0) * 0.1875 - 4 * 0.1875 ** 2) * 30.0
                            * AL_6061_DENSITY_LB_IN3 * LB_TO_KG)
    # ASSUMED: guide wheel assembly (four 6200 bearings, 10 x 40 mm bolts, 1.5 in square
    # 6061 stock, same section) about 2 lb, at the track radius.
    guide_wheels_kg: float = 2.0 * LB_TO_KG
    # +1: the arm's plane points away from the shaft at J1 = 0 (radially outward).
    reach_sign: float = 1.0

    @property
    def base_radius_m(self) -> float:
        return self.track_diameter_m / 2.0


@dataclass(frozen=True)
class GripperParams:
    """The push/pull motor's lead screw, the jaw stroke and the end-of-travel switches."""

    # ASSUMED: 10 turns/in Acme screw (0.1 in per turn), opening grows with screw angle.
    lead_m_per_rad: float = 0.1 * IN_TO_M / (2.0 * math.pi)
    # ASSUMED: 2 in jaw stroke (the report gives none); opening 0 = closed.
    stroke_m: float = 2.0 * IN_TO_M
    # End-of-travel switches trip 0.5 mm inside the hard stops (ASSUMED).
    closed_switch_m: float = 0.0005
    open_switch_m: float = 2.0 * IN_TO_M - 0.0005
    # ASSUMED, as in most push/pull actuators: each switch, with its bypass diode, opens the
    # motor circuit for travel toward its end only, so the jaws stop at the switch.
    switches_cut_power: bool = True
    start_opening_m: float = 1.0 * IN_TO_M


# ---- motors --------------------------------------------------------------------------------------
# ASSUMED 24 V class PM DC gearmotors run from the 28 V bus (PlantParams.supply_nominal_v).
# Gear heads: spur, 0.9 per stage. Rotor inertias for the frame sizes; friction from a
# no-load current of about 0.1 A; viscous friction a third of Coulomb at no-load speed.

# "JOINTS AND ACTUATORS" and Key to Figure 8 part 44: "DC PM (400 oz in)" gear-head motor,
# for J1 and J2 (the parts list gives J2's motor, part 58, as 200 oz-in; the text's 400
# oz-in and its safety factor 1.9 = 400 / 209.6 are used). ASSUMED internals: 5 oz-in/A,
# 6 ohm, 3 mH; 100:1 three-stage gear head. Gives 65 RPM no-load and 1460 oz-in stall at
# the gear head at 24 V (3.6 x the 400 oz-in rating, which is the gear head's limit).
MOTOR_400_OZ_IN = MotorSpec(
    name="DC PM gear-head motor, 400 oz-in", nominal_v=24.0,
    r_ohm=6.0, l_h=3.0e-3, kt_nm_a=5.0 * OZ_IN_TO_NM, ke_v_s_rad=5.0 * OZ_IN_TO_NM,
    rotor_inertia_kg_m2=1.5e-5, coulomb_nm=3.5e-3, stiction_nm=5.0e-3, viscous_nm_s_rad=1.7e-6,
    gearhead=GearStage("gear head 100:1, 3 spur stages", 100.0, 0.73),
    rated_torque_nm=400.0 * OZ_IN_TO_NM)

# "WRIST AND GRIPPER" and Key to Figure 8 part 58: "200 oz-in DC gear head motor" for the
# wrist bend. ASSUMED: 3.5 oz-in/A, 8 ohm, 3 mH, 100:1; 93 RPM no-load, 770 oz-in stall.
MOTOR_200_OZ_IN = MotorSpec(
    name="DC PM gear-head motor, 200 oz-in", nominal_v=24.0,
    r_ohm=8.0, l_h=3.0e-3, kt_nm_a=3.5 * OZ_IN_TO_NM, ke_v_s_rad=3.5 * OZ_IN_TO_NM,
    rotor_inertia_kg_m2=8.0e-6, coulomb_nm=2.5e-3, stiction_nm=3.5e-3, viscous_nm_s_rad=8.0e-7,
    gearhead=GearStage("gear head 100:1, 3 spur stages", 100.0, 0.73),
    rated_torque_nm=200.0 * OZ_IN_TO_NM)

# "WRIST AND GRIPPER": "a DC motor connected directly to the gripper" turning a 1/4 in
# shaft. ASSUMED: a small 100 oz-in gearmotor, 2.5 oz-in/A, 10 ohm, 2 mH, 200:1 four-stage
# head (65 RPM no-load).
MOTOR_WRIST_ROLL = MotorSpec(
    name="DC PM gearmotor, wrist roll (100 oz-in)", nominal_v=24.0,
    r_ohm=10.0, l_h=2.0e-3, kt_nm_a=2.5 * OZ_IN_TO_NM, ke_v_s_rad=2.5 * OZ_IN_TO_NM,
    rotor_inertia_kg_m2=3.0e-6, coulomb_nm=6.0e-4, stiction_nm=8.5e-4, viscous_nm_s_rad=1.3e-7,
    gearhead=GearStage("gear head 200:1, 4 spur stages", 200.0, 0.66),
    rated_torque_nm=100.0 * OZ_IN_TO_NM)

# Key to Figure 9 part 64: "27.5 VDC DAYTOM" (Dayton) motor, the gripper's push/pull motor.
# ASSUMED: 2.8 oz-in/A, 20 ohm, 4 mH, 20:1 head driving the lead screw; 28 mm/s no-load
# jaw speed and about 350 N stall grip at 27.5 V.
MOTOR_GRIPPER = MotorSpec(
    name="Dayton 27.5 VDC push/pull motor", nominal_v=27.5,
    r_ohm=20.0, l_h=4.0e-3, kt_nm_a=0.02, ke_v_s_rad=0.02,
    rotor_inertia_kg_m2=2.0e-6, coulomb_nm=1.0e-3, stiction_nm=1.5e-3, viscous_nm_s_rad=2.5e-7,
    gearhead=GearStage("gear head 20:1, 2 spur stages", 20.0, 0.81),
    rated_torque_nm=0.0)

# "DESIGN OF THE MOBILE MOUNT": "a parallel shaft TENV gearmotor, which is geared down
# before driving the shaft". ASSUMED: a 24 V PM DC TENV parallel-shaft gearmotor, 1/15 hp
# class, 300:1 head rated 100 lb in; 8 oz-in/A, 4 ohm, 4 mH.
MOTOR_MOUNT = MotorSpec(
    name="TENV parallel-shaft PM DC gearmotor", nominal_v=24.0,
    r_ohm=4.0, l_h=4.0e-3, kt_nm_a=8.0 * OZ_IN_TO_NM, ke_v_s_rad=8.0 * OZ_IN_TO_NM,
    rotor_inertia_kg_m2=1.2e-4, coulomb_nm=5.0e-3, stiction_nm=7.0e-3, viscous_nm_s_rad=4.0e-6,
    gearhead=GearStage("parallel-shaft gear head 300:1", 300.0, 0.70),
    rated_torque_nm=100.0 * LBF_IN_TO_NM)

# External stages. Key to Figure 8: Flex-E-Gear sprockets 1.5 and 6.0 in pitch diameter
# (parts 45-48) make a 4:1 pair; two pairs give J1's 16:1 ("JOINTS AND ACTUATORS"). Parts
# 52 (1.0 PD) and 46 (6.0 PD) give J2's 6:1; parts 60 and 61 (1.0 and 3.0 PD) J3's 3:1.
# ASSUMED efficiency 0.97 per pair (belt-and-sprocket drives run at 0.95-0.98).
SPROCKET_EFFICIENCY = 0.97
J1_SPROCKETS = (GearStage("Flex-E-Gear 1.5/6.0 PD pair", 4.0, SPROCKET_EFFICIENCY),
                GearStage("Flex-E-Gear 1.5/6.0 PD pair", 4.0, SPROCKET_EFFICIENCY))
J2_SPROCKETS = (GearStage("Flex-E-Gear 1.0/6.0 PD pair", 6.0, SPROCKET_EFFICIENCY),)
J3_SPROCKETS = (GearStage("Flex-E-Gear 1.0/3.0 PD pair", 3.0, SPROCKET_EFFICIENCY),)
# ASSUMED: the mount's "geared down" stage, a 4:1 chain; Acme lead screw efficiency 0.35.
MOUNT_REDUCTION = (GearStage("chain and sprocket 4:1 to the central shaft", 4.0, 0.95),)
GRIPPER_SCREW = (GearStage("Acme lead screw (turns stay turns; efficiency only)", 1.0, 0.35),)

# ASSUMED: a spring-applied, power-released (fail-safe) brake on each joint and the mount,
# holding 1.5 x the channel's rated output torque, so it holds any static pose (J1 needs
# at most 42 N m) but a motor at full duty can drag it. The gripper has none: its lead
# screw holds.
BRAKE_HOLD_FACTOR = 1.5


def _drive(name, motor, stages, *, out_coulomb_nm, out_inertia_kg_m2, stop_deg, brake=True):
    rated = motor.rated_torque_nm * math.prod(s.ratio * s.efficiency for s in stages)
    return DriveParams(
        name=name, motor=motor, stages=stages,
        output_inertia_kg_m2=out_inertia_kg_m2,
        output_coulomb_nm=out_coulomb_nm, output_stiction_nm=1.4 * out_coulomb_nm,
        brake_hold_nm=BRAKE_HOLD_FACTOR * rated if brake else 0.0,
        stop_lo_rad=stop_deg[0] * DEG, stop_hi_rad=stop_deg[1] * DEG)


@dataclass(frozen=True)
class ChannelParams:
    """One channel: its drive, its encoder and its switches.

    Encoders are quadrature encoders on the motor shaft, counted x4: `encoder_cpr` counts
    per MOTOR revolution, so `encoder_cpr * drive.ratio` per output revolution. They count
    from zero at power-on (incremental): the controller must home.
    The home switch is a flag: active at and above `home_rad`, so its edge is found from
    either side. Limit switches: `limit_lo` active at or below `limit_lo_rad`, `limit_hi`
    at or above `limit_hi_rad`; the hard stops (`drive.stop_*_rad`) lie beyond them.
    """

    drive: DriveParams
    encoder_cpr: int
    home_rad: float
    limit_lo_rad: float
    limit_hi_rad: float
    start_pos_rad: float

    def __post_init__(self) -> None:
        d = self.drive
        if not self.encoder_cpr > 0:
            raise ValueError(f"{d.name}: encoder_cpr must be > 0")
        if not (d.stop_lo_rad <= self.limit_lo_rad < self.limit_hi_rad <= d.stop_hi_rad):
            raise ValueError(f"{d.name}: need stop_lo <= limit_lo < limit_hi <= stop_hi")
        if not (d.stop_lo_rad <= self.start_pos_rad <= d.stop_hi_rad):
            raise ValueError(f"{d.name}: start_pos_rad outside the hard stops")

    @property
    def counts_per_output_rev(self) -> float:
        return self.encoder_cpr * self.drive.ratio


# ASSUMED: 100-line encoders (400 counts per motor turn); J1 then resolves 640,000 counts per
# joint turn, 10 um at the 1 m reach, far below the 1 cm spec (gear backlash not modelled).
ENCODER_CPR = 400

# ASSUMED ranges. Joints: J1 -60..+90 deg (link II from below horizontal to straight up),
# J2 and J3 +-135 deg (yokes), J4 +-180 deg (wires through the collar), mount +-170 deg
# around the track (cables); hard stops 5 deg beyond the limit switches. The arm powers on
# 0.1 rad below each home flag (arm out, brakes holding), so homing moves positive.
_GRIP = GripperParams()
CHANNEL_PARAMS = (
    ChannelParams(_drive("j1", MOTOR_400_OZ_IN, J1_SPROCKETS, out_coulomb_nm=0.2,
                         out_inertia_kg_m2=2e-3, stop_deg=(-65.0, 95.0)),
                  ENCODER_CPR, home_rad=0.0, limit_lo_rad=-60 * DEG, limit_hi_rad=90 * DEG,
                  start_pos_rad=-0.1),
    ChannelParams(_drive("j2", MOTOR_400_OZ_IN, J2_SPROCKETS, out_coulomb_nm=0.1,
                         out_inertia_kg_m2=1e-3, stop_deg=(-140.0, 140.0)),
                  ENCODER_CPR, home_rad=0.0, limit_lo_rad=-135 * DEG, limit_hi_rad=135 * DEG,
                  start_pos_rad=-0.1),
    ChannelParams(_drive("j3", MOTOR_200_OZ_IN, J3_SPROCKETS, out_coulomb_nm=0.05,
                         out_inertia_kg_m2=5e-4, stop_deg=(-140.0, 140.0)),
                  ENCODER_CPR, home_rad=0.0, limit_lo_rad=-135 * DEG, limit_hi_rad=135 * DEG,
                  start_pos_rad=-0.1),
    ChannelParams(_drive("j4", MOTOR_WRIST_ROLL, (), out_coulomb_nm=0.01,
                         out_inertia_kg_m2=1e-5, stop_deg=(-185.0, 185.0)),
                  ENCODER_CPR, home_rad=0.0, limit_lo_rad=-180 * DEG, limit_hi_rad=180 * DEG,
                  start_pos_rad=-0.1),
    # Gripper: output = the lead screw's angle; opening = angle * lead. Hard stops at
    # closed (0) and the stroke; its end switches are the limit switches, and the open
    # switch doubles as home.
    ChannelParams(_drive("gripper", MOTOR_GRIPPER, GRIPPER_SCREW, out_coulomb_nm=0.005,
                         out_inertia_kg_m2=0.0, brake=False,
                         stop_deg=(0.0, _GRIP.stroke_m / _GRIP.lead_m_per_rad / DEG)),
                  ENCODER_CPR, home_rad=_GRIP.open_switch_m / _GRIP.lead_m_per_rad,
                  limit_lo_rad=_GRIP.closed_switch_m / _GRIP.lead_m_per_rad,
                  limit_hi_rad=_GRIP.open_switch_m / _GRIP.lead_m_per_rad,
                  start_pos_rad=_GRIP.start_opening_m / _GRIP.lead_m_per_rad),
    # Mount: ASSUMED guide wheels and shaft bearings (SKF FY 1 1/2 TM, "SHAFT ASSEMBLY")
    # 2 N m of Coulomb friction at the shaft; the level platform puts no gravity on it.
    ChannelParams(_drive("mount", MOTOR_MOUNT, MOUNT_REDUCTION, out_coulomb_nm=2.0,
                         out_inertia_kg_m2=0.05, stop_deg=(-175.0, 175.0)),
                  ENCODER_CPR, home_rad=0.0, limit_lo_rad=-170 * DEG, limit_hi_rad=170 * DEG,
                  start_pos_rad=-0.1),
)


@dataclass(frozen=True)
class ArmPlantParams:
    """Everything `hil_sim.arm.ArmPlant` needs."""

    channels: tuple[ChannelParams, ...] = CHANNEL_PARAMS
    geometry: ArmGeometry = ArmGeometry()
    mount: MountParams = MountParams()
    gripper: GripperParams = _GRIP
    # Longest integration step: longer steps (a real-time stall) are split into equal
    # substeps no longer than this, so gravity and the switches are re-evaluated.
    max_substep_s: float = 0.001

    def __post_init__(self) -> None:
        if tuple(c.drive.name for c in self.channels) != ARM_CHANNELS:
            raise ValueError(f"channels must be {ARM_CHANNELS} in that order")
        if not self.max_substep_s > 0:
            raise ValueError("max_substep_s must be > 0")

    def jaw_force_n(self, hold_duty: float, supply_v: float) -> float:
        """The force the jaws press an object with, holding at `hold_duty` (the controller's `grip_hold_duty`)
        from a `supply_v` supply: the gripper's drive stalled on the object, its torque through the lead screw
        (`ArmPlant.grip_force_n` once the jaws have closed; friction neglected). The grip's limit is friction
        times this (hil_sim/held_object.py)."""
        return self.channels[GRIPPER].drive.stall_torque_nm(hold_duty * supply_v) / self.gripper.lead_m_per_rad


ARM_PLANT_PARAMS = ArmPlantParams()


# ---- the example arm (issue 39): the report's coordinated example, built as an arm ------------------------
# docs/two_arms.md; the firmware keeps its own copy of these numbers (docs/fidelity.md, table "example-arm", says
# where each comes from). [REPORT]: the report's section 4 example (unit links, unit masses,
# bases 2.0 m apart; host_tools/plan/example.py). [EMU]: chosen for the emulator (the report gives the example no
# drive). ASPOD's: this file's own channel, unchanged (the report gives the example nothing for it).
#
# [REPORT] the example's links: 1.0 m and 1.0 kg each, uniform rods (the planner's links="rod"); nothing else on
# the arm (no elbow hardware, no wrist, no gripper mass: the planner's model exactly); the hand, where the held
# object's grasp acts, on the J3 axis (tip 0). Link I, the shoulder hardware and the mount as ASPOD's: they load
# only the mount, which stays at home for the example (the object lives in the arm plane).
EXAMPLE_ARM_GEOMETRY = ArmGeometry(
    link2_m=1.0, link3_m=1.0, link2_kg=1.0, link3_kg=1.0,          # [REPORT] section 4
    elbow_hw_kg=0.0, wrist_fixed_kg=0.0, wrist_turned_kg=0.0,      # the two rods and nothing else
    wrist_turned_cg_m=0.0, wrist_turned_inertia_kg_m2=0.0,
    roll_inertia_kg_m2=0.0,
    tip_m=0.0)                                                     # [PLANNER] the hand at link III's end

# [EMU] one 28 V brushed PM DC motor class at both joints through a 50:1 gear head: 1.7 N m/A at the joint,
# no-load 28 / (0.04 * 50) = 14 rad/s, the rotor reflected 0.075 kg m^2. Its rating, 0.8 N m at the motor, is
# 0.8 * 50 * 0.85 = 34 N m at the gear head's output (`MotorSpec.rated_torque_nm` is there).
MOTOR_EXAMPLE_ARM = MotorSpec(
    name="example arm's PM DC gear-head motor", nominal_v=28.0,
    r_ohm=0.4, l_h=0.5e-3, kt_nm_a=0.04, ke_v_s_rad=0.04,
    rotor_inertia_kg_m2=3.0e-5, coulomb_nm=5.0e-3, stiction_nm=7.0e-3, viscous_nm_s_rad=2.0e-6,
    gearhead=GearStage("gear head 50:1", 50.0, 0.85),
    rated_torque_nm=0.8 * 50.0 * 0.85)

# [EMU] ranges: the example's path spans shoulder -40.5..112.5 deg and elbow 66.9..149.4 deg over both arms (rod
# links), so the shoulder's limit switches at -90 and +135 deg (hard stops -95, +140), the elbow's at -4 and +170
# (hard stops -5, +175). Home flags at 0 as ASPOD's. The shoulder powers on 0.1 rad below its flag as ASPOD's
# joints do; 0.1 rad below the elbow's flag is past its hard stop, so it powers on at -2.5 deg. Homing backs a
# joint off its flag to -1.15 deg: the elbow's lower switch and soft limit (-3 deg) lie below that (with both at 0
# its homed pose was outside its soft limits, and its first move was stopped there: found carrying the object). Encoders 400 counts per motor turn as ASPOD's. Output friction and
# inertia (0.2 / 0.1 N m, 2e-3 / 1e-3 kg m^2) and the brakes' rule (`BRAKE_HOLD_FACTOR` x rated: 51 N m) as
# ASPOD's J1 and J2.
EXAMPLE_ARM_CHANNELS = (
    ChannelParams(_drive("j1", MOTOR_EXAMPLE_ARM, (), out_coulomb_nm=0.2, out_inertia_kg_m2=2e-3,
                         stop_deg=(-95.0, 140.0)),
                  ENCODER_CPR, home_rad=0.0, limit_lo_rad=-90 * DEG, limit_hi_rad=135 * DEG, start_pos_rad=-0.1),
    ChannelParams(_drive("j2", MOTOR_EXAMPLE_ARM, (), out_coulomb_nm=0.1, out_inertia_kg_m2=1e-3,
                         stop_deg=(-5.0, 175.0)),
                  ENCODER_CPR, home_rad=0.0, limit_lo_rad=-4 * DEG, limit_hi_rad=170 * DEG, start_pos_rad=-2.5 * DEG),
    *CHANNEL_PARAMS[2:],                                           # J3, J4, gripper, mount: ASPOD's
)

# The example arm's plant: its geometry and its shoulder and elbow drives; the rest ASPOD's.
EXAMPLE_ARM_PLANT = ArmPlantParams(channels=EXAMPLE_ARM_CHANNELS, geometry=EXAMPLE_ARM_GEOMETRY)
