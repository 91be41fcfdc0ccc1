"""The arm plant's tick as one function over flat per-channel lists: drives, loads, readouts.

Design: docs/plant.md#the-arm-plants-tick

`arm_plant_tick` does, for the six channels, what `Plant.step` has the per-concept classes
do (`hil_sim.arm.ArmPlant`, `hil_sim.motor.DcMotorBank`, `hil_sim.arm.LoadModel` and the
plant's own gating, supply current, encoders and switches), with the very same
floating-point operations in the same order: its results are those of the classes to the
bit (tests/test_arm_plant_tick.py). It takes only numbers and sequences of numbers
(lists now; numpy arrays for a compiled kernel later): the hot state lives in the lists
the classes own, changed in place, and the constants come in precomputed. `ArmTick` binds
it to one plant's lists and keeps the per-step-length constants.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple, Sequence

from hil_sim.arm_params import GRIPPER, J1, J2, J3, J4, MOUNT
from hil_sim.motor import hard_stop

if TYPE_CHECKING:  # pragma: no cover
    from hil_sim.arm import ArmPlant


class ArmState(NamedTuple):
    """The hot state, per channel at the output shaft; the lists of `DcMotorBank` and `ArmPlant`."""

    pos_rad: list[float]
    vel_rad_s: list[float]
    current_a: list[float]
    stop_torque_nm: list[float]      # absorbed by a hard stop in the last step (< 0: the lower one)
    load_torque_nm: list[float]      # gravity's pull (the holding torque), held over a step
    load_inertia_kg_m2: list[float]  # the arm's pose-dependent inertia on top of the drive's own
    stop_lo_rad: list[float]         # hard stops (a jam closes both on the shaft, an object moves the gripper's)
    stop_hi_rad: list[float]


class DriveTable(NamedTuple):
    """Per-channel drive constants for one step length h (`DcMotorBank.step_coefficients`)."""

    l_eff_per_h: list[float]         # L_eff / h = R / expm1(R h / L) [ohm]
    inv_l_eff_r: list[float]         # 1 / (L_eff/h + R) [1/ohm]
    emf_per_rad_s: list[float]       # ke_out / (L_eff/h + R) [A s/rad]
    inertia_kg_m2: list[float]       # rotor through the train plus the fixed output parts
    kt_nm_a: list[float]             # output torque per amp, gear losses included
    viscous_nm_s_rad: list[float]
    coulomb_nm: list[float]          # kinetic friction
    breakaway_extra_nm: list[float]  # breakaway minus kinetic friction
    brake_hold_nm: list[float]       # 0: no brake (braked and not driven shorts the armature instead)


class GripperCut(NamedTuple):
    """The gripper's end switches, which open its motor circuit for travel toward their end."""

    cuts_power: bool
    closed_rad: float
    open_rad: float


class LoadConstants(NamedTuple):
    """The lumped mass model's pose-independent constants (`LoadModel`, hil_sim/arm.py)."""

    link2_m: float
    link3_m: float
    turned_cg_m: float               # the part J3 turns: its centre of gravity from the J3 axis
    tip_m: float
    g_m_s2: float
    k1_kg_m: float                   # gravity torques: t3 = g K3 c3, t2 = g K2 c2 + t3, t1 = g K1 c1 + t2
    k2_kg_m: float
    k3_kg_m: float
    rod2_kg_m2: float                # links II and III about their centres, m L^2 / 12
    rod3_kg_m2: float
    turned_kg_m2: float              # the turned part about its own centre of gravity
    j3_kg_m2: float                  # what J3 and J4 turn (pose-independent)
    j4_kg_m2: float
    link2_kg: float
    elbow_kg: float
    link3_kg: float
    wrist_fixed_kg: float
    wrist_turned_kg: float
    payload_kg: float
    base_radius_m: float             # link I's axis from the central shaft
    reach_sign: float
    at_base_kg_m2: float             # link I and the shoulder hardware about the shaft
    mobile_arm_kg_m2: float
    guide_wheels_kg_m2: float


class Sensors(NamedTuple):
    """Encoder and switch constants per channel."""

    pos0_rad: list[float]            # the angle at power-on (the encoders count from 0 there)
    counts_per_rad: list[float]
    home_rad: list[float]            # home flag: closed at and above
    limit_lo_rad: list[float]        # closed at and below
    limit_hi_rad: list[float]        # closed at and above


class ChannelFaults(NamedTuple):
    """The plant's per-channel faults, as `Plant.inject` sets them (hil_sim/faults.py)."""

    open_circuit: list[bool]
    stuck_brake: list[bool]
    count_offset: list[int]          # encoder_glitch: added to the count
    dropped_out: list[bool]          # encoder_dropout: the count shows `frozen_count`
    frozen_count: list[int]


class Readouts(NamedTuple):
    """What a tick leaves for the plant's node: the channels' gating, counts and switches."""

    driven: list[bool]
    braked: list[bool]
    counts: list[int]
    home: list[bool]
    limit_lo: list[bool]
    limit_hi: list[bool]


def arm_plant_tick(h_s: float, substeps: int, supply_v: float, outputs_enabled: bool, brake_all: bool,
                   duty: Sequence[float], enable: Sequence[bool], brake: Sequence[bool],
                   state: ArmState, drive: DriveTable, gripper: GripperCut, loads: LoadConstants,
                   sensors: Sensors, faults: ChannelFaults, out: Readouts) -> float:
    """Advance the arm `substeps` steps of `h_s` seconds; sample the readouts; return the bridges' current.

    `outputs_enabled`, `brake_all` are the global command, `duty`, `enable`, `brake` the
    per-channel one (order `ARM_CHANNELS`); `supply_v` the bus voltage the bridges switch
    (the last step's). `state` is stepped in place; `out` receives the readouts. Returns the
    current the bridges draw from the supply [A] (< 0 while motors regenerate).
    """
    pos, vel, cur, stop_t, load_nm, load_j, stop_lo, stop_hi = state
    l_eff_h, inv_l_eff_r, emf_per_w, drive_j, kt, visc, coulomb, breakaway_extra, hold = drive
    open_circuit, stuck_brake = faults.open_circuit, faults.stuck_brake
    cuts_power, closed_rad, open_rad = gripper
    driven, braked = out.driven, out.braked
    n = len(pos)
    # What each channel gets: its bridge switches only if outputs are enabled, its own command
    # enables it and its circuit is whole; its brake is on if either command or a stuck brake says so.
    for k in range(n):
        driven[k] = outputs_enabled and bool(enable[k]) and not open_circuit[k]
        braked[k] = brake_all or bool(brake[k]) or stuck_brake[k]
    inv_h = 1.0 / h_s if substeps else 0.0
    for _ in range(substeps):
        # The gripper's end switch ahead of the jaws' travel opens its motor circuit.
        d, x = duty[GRIPPER], pos[GRIPPER]
        gripper_on = driven[GRIPPER] and not (cuts_power and ((d < 0 and x <= closed_rad) or (d > 0 and x >= open_rad)))
        for k in range(n):
            # Armature, implicit in the new current i' and speed w' (docs/arm.md, the motors):
            #   L_eff/h (i' - i) = u - R i' - ke_out w'   ->   i' = p - q w'
            w = vel[k]
            q = emf_per_w[k]
            if gripper_on if k == GRIPPER else driven[k]:
                u = duty[k]                          # duty clipped to [-1, 1] (NaN reads as 0) times the bus
                if -1.0 < u < 1.0:
                    u *= supply_v
                else:
                    u = supply_v if u >= 1.0 else -supply_v if u <= -1.0 else 0.0
                p = (l_eff_h[k] * cur[k] + u) * inv_l_eff_r[k]     # the current if the shaft stood still [A]
            elif braked[k] and hold[k] == 0.0:
                p = l_eff_h[k] * cur[k] * inv_l_eff_r[k]          # no brake: the armature shorted (dynamic braking)
            else:
                p = q = 0.0                                        # bridge open: no current, no back-EMF drag
            # Shaft: J/h (w' - w) = kt_out i' - b w' - tau_load - f, friction f as a constraint.
            m = (drive_j[k] + load_j[k]) * inv_h                   # J/h [N m s/rad]
            s = m * w - load_nm[k] + kt[k] * p                     # what friction must hold to stop it [N m]
            kinetic = coulomb[k] + (hold[k] if braked[k] else 0.0)
            breakaway = kinetic + breakaway_extra[k] if w == 0.0 else kinetic
            if s > breakaway:
                w = (s - kinetic) / (m + visc[k] + kt[k] * q)
            elif s < -breakaway:
                w = (s + kinetic) / (m + visc[k] + kt[k] * q)
            else:
                w = 0.0                                            # held by friction (and brake): exactly still
            # Position by semi-implicit Euler; a hard stop clamps it and takes the torque pushing into it.
            x, w, t = hard_stop(pos[k] + h_s * w, w, s, stop_lo[k], stop_hi[k])
            pos[k], vel[k], cur[k], stop_t[k] = x, w, p - q * w, t
        gravity_and_inertia(pos[J1], pos[J2], pos[J3], loads, load_nm, load_j)
    # The bridges' draw from the supply (lossless switches): sum of clipped duty * i over driven channels.
    bridges_a = 0.0
    for k in range(n):
        if driven[k]:
            d = duty[k]
            d = d if d < 1.0 else 1.0                              # NaN reads as 1 here
            bridges_a += (d if d > -1.0 else -1.0) * cur[k]
    sample_readouts(pos, sensors, faults, out)
    return bridges_a


def gravity_and_inertia(q1: float, q2: float, q3: float, constants: LoadConstants,
                        load_nm: list[float], load_inertia: list[float]) -> None:
    """The lumped mass model at joint angles q1..q3 [rad]: holding torques and inertias, in place.

    Gravity torques into `load_nm` (J1-J3), the inertias each channel turns, the other joints
    frozen, into `load_inertia` (J1-J4, mount); hil_sim/arm.py's module docstring gives the model.
    """
    (l2, l3, cg, tip, g, k1, k2, k3, rod2, rod3, turned, i3, i4, link2_kg, elbow_kg, link3_kg, fixed_kg, turned_kg, p,
     r0, reach, at_base, mobile_arm, guide_wheels) = constants
    # The arm plane, from J1: elbow e, wrist w, turned part's cg r, tip t; absolute angles a1..a3.
    c1, s1 = math.cos(q1), math.sin(q1)
    a2 = q1 + q2
    c2, s2 = math.cos(a2), math.sin(a2)
    c3, s3 = math.cos(a2 + q3), math.sin(a2 + q3)
    ex, ez = l2 * c1, l2 * s1
    wx, wz = ex + l3 * c2, ez + l3 * s2
    rx, rz = wx + cg * c3, wz + cg * s3
    tx, tz = wx + tip * c3, wz + tip * s3
    # Holding torques [N m]: g times the outboard masses' moments.
    t3 = g * k3 * c3
    t2 = g * k2 * c2 + t3
    load_nm[J1], load_nm[J2], load_nm[J3] = g * k1 * c1 + t2, t2, t3
    # Inertias [kg m^2]: rods m L^2/12 about their centres plus m d^2 (parallel axes), points m d^2 (p: payload).
    span = (wx - ex) ** 2 + (wz - ez) ** 2                         # link III's length squared
    i2 = (rod3 + link3_kg * span / 4.0 + fixed_kg * span + turned
          + turned_kg * ((rx - ex) ** 2 + (rz - ez) ** 2) + p * ((tx - ex) ** 2 + (tz - ez) ** 2))
    i1 = (rod2 + link2_kg * (ex * ex + ez * ez) / 4.0 + elbow_kg * (ex * ex + ez * ez)
          + rod3 + link3_kg * ((ex + wx) ** 2 + (ez + wz) ** 2) / 4.0
          + fixed_kg * (wx * wx + wz * wz)
          + turned + turned_kg * (rx * rx + rz * rz) + p * (tx * tx + tz * tz))
    load_inertia[J1], load_inertia[J2], load_inertia[J3], load_inertia[J4] = i1, i2, i3, i4
    # The mount turns everything about the central shaft: each part at its distance r from it.
    r2, re, r3, rw, rr, rt = (r0 + reach * ex / 2.0, r0 + reach * ex, r0 + reach * (ex + wx) / 2.0,
                              r0 + reach * wx, r0 + reach * rx, r0 + reach * tx)
    total = (at_base + link2_kg * r2 * r2 + elbow_kg * re * re + link3_kg * r3 * r3 + fixed_kg * rw * rw
             + turned_kg * rr * rr + p * rt * rt)
    # Rods about a vertical axis through their centre: m (L cos a)^2 / 12.
    total += (link2_kg * (l2 * c1) ** 2 + link3_kg * (l3 * c2) ** 2) / 12.0
    total += turned * c3 * c3
    load_inertia[MOUNT] = total + mobile_arm + guide_wheels


def sample_readouts(pos: Sequence[float], sensors: Sensors, faults: ChannelFaults, out: Readouts) -> None:
    """Encoder counts (x4 quadrature, floor, since power-on, through the encoder faults) and switches."""
    pos0, counts_per_rad, home_rad, limit_lo_rad, limit_hi_rad = sensors
    _, _, count_offset, dropped_out, frozen_count = faults
    _, _, counts, home, limit_lo, limit_hi = out
    for k in range(len(pos)):
        x = pos[k]
        counts[k] = (frozen_count[k] if dropped_out[k]
                     else math.floor((x - pos0[k]) * counts_per_rad[k]) + count_offset[k])
        home[k] = x >= home_rad[k]
        limit_lo[k] = x <= limit_lo_rad[k]
        limit_hi[k] = x >= limit_hi_rad[k]


class ArmTick:
    """`arm_plant_tick` bound to one `ArmPlant`'s lists and its plant's sensors and faults.

    Keeps the drive constants for the step length in use and the readouts the last tick
    sampled (`sampled()` samples again if the arm's state was overwritten since: a joint
    moved by hand). After changing an encoder fault, call `sample()`.
    """

    def __init__(self, arm: ArmPlant, sensors: Sensors, faults: ChannelFaults) -> None:
        motors = arm.motors
        self._arm, self._motors = arm, motors
        self.state = ArmState(*motors.state_lists(), *arm.load_lists(), *motors.stop_lists())
        self.sensors, self.faults = sensors, faults
        self.gripper = arm.gripper_cut()
        n = motors.n
        self.readouts = Readouts([False] * n, [True] * n, [0] * n, [False] * n, [False] * n, [False] * n)
        self._max_substep_s = arm.params.max_substep_s
        self._dt_s = math.nan
        self._substeps, self._h_s = 0, self._max_substep_s
        self._drive = self._drive_table(self._h_s)
        self.sample()

    def _drive_table(self, h_s: float) -> DriveTable:
        return DriveTable(*map(list, zip(*self._motors.step_coefficients(h_s))))

    def _set_step_length(self, dt_s: float) -> None:
        """Split `dt_s` into equal substeps no longer than `max_substep_s`, as `ArmPlant.step` does."""
        self._dt_s = dt_s
        if dt_s == 0.0:
            self._substeps = 0
            return
        self._substeps = max(1, math.ceil(dt_s / self._max_substep_s - 1e-9))
        h_s = dt_s / self._substeps
        if h_s != self._h_s:
            self._h_s, self._drive = h_s, self._drive_table(h_s)

    def step(self, dt_s: float, outputs_enabled: bool, brake_all: bool, duty: Sequence[float],
             enable: Sequence[bool], brake: Sequence[bool], supply_v: float) -> float:
        """One tick of `dt_s` seconds (see `arm_plant_tick`); returns the bridges' supply current [A]."""
        if dt_s != self._dt_s:
            self._set_step_length(dt_s)
        bridges_a = arm_plant_tick(self._h_s, self._substeps, supply_v, outputs_enabled, brake_all, duty, enable,
                                   brake, self.state, self._drive, self.gripper,
                                   self._arm.load_model().tick_constants, self.sensors, self.faults, self.readouts)
        self._sampled_writes = self._motors.state_writes
        return bridges_a

    def sample(self) -> None:
        """Sample the counts and switches from the state as it is (outside a tick)."""
        sample_readouts(self.state.pos_rad, self.sensors, self.faults, self.readouts)
        self._sampled_writes = self._motors.state_writes

    def sampled(self) -> Readouts:
        """The readouts, sampled again first if the arm's state was overwritten since the last sample."""
        if self._motors.state_writes != self._sampled_writes:
            self.sample()
        return self.readouts


__all__ = ["ArmState", "ArmTick", "ChannelFaults", "DriveTable", "GripperCut", "LoadConstants", "Readouts",
           "Sensors", "arm_plant_tick", "gravity_and_inertia", "sample_readouts"]
