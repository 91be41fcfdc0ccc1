"""The arm plant's tick as one function over flat per-channel rows: drives, loads, readouts.

Design: docs/plant.md#the-arm-plants-tick

`arm_plant_tick` is the arm plant's one tick: for the six channels, the plant's gating (its
faults, the gripper's end switches), the motor bank (`hil_sim.motor.DcMotorBank` holds its state
and constants), the loads of the mass model (`hil_sim.arm.LoadModel` holds its constants), the
supply current, encoders and switches. `ArmPlant.step` and `Plant.tick` run it; nothing else
steps the arm. It takes only numbers and groups of per-channel rows,
each row indexed by channel and each group's rows named by the constants below:

- `command` (floats): the per-channel command, DUTY, ENABLE, BRAKE (0 or 1);
- `state` (floats): the hot state at the output shaft, stepped in place;
- `table` (floats): the drive constants for the step length in use, and the sensors';
- `flags` (bools): the faults that are flags, and the readouts that are switches;
- `counts` (ints): the encoder faults' counts, and the counts read out;
- `constants`: one row of numbers, the mass model's (`LoadConstants`), then the gripper's.

A group is a list of lists, or a 2-D numpy array for the kernel compiled by numba
(hil_sim/arm_tick_compiled.py), the same to the bit: numba's per-call cost grows with the number
of arrays it is handed, so a tick takes these six. `ArmTick` holds the groups of one plant and
keeps the per-step-length constants; the classes keep their state in its `state` rows (lists
shared, or array rows adopted: `DcMotorBank.keep_state_in`), so both see one state.
"""
from __future__ import annotations

import math
import struct
from typing import TYPE_CHECKING, NamedTuple, Optional, Sequence

import numpy as np

from hil_sim.arm_params import GRIPPER, J1, J2, J3, J4, MOUNT

if TYPE_CHECKING:  # pragma: no cover
    from hil_sim.arm import ArmPlant, LoadModel

# command: what the plant's node hands a step, per channel
DUTY, ENABLE, BRAKE = range(3)
COMMAND_ROWS = 3
# state: the hot state, per channel at the output shaft
(POS_RAD, VEL_RAD_S, CURRENT_A,
 STOP_TORQUE_NM,      # absorbed by a hard stop in the last step (< 0: the lower one)
 LOAD_TORQUE_NM,      # gravity's pull (the holding torque), held over a step
 LOAD_INERTIA_KG_M2,  # the arm's pose-dependent inertia on top of the drive's own
 STOP_LO_RAD,         # hard stops (a jam closes both on the shaft, an object moves the gripper's)
 STOP_HI_RAD) = range(8)
STATE_ROWS = 8
# table: the drive constants for one step length h (`DcMotorBank.step_coefficients`), then the sensors'
(L_EFF_PER_H,         # L_eff / h = R / expm1(R h / L) [ohm]
 INV_L_EFF_R,         # 1 / (L_eff/h + R) [1/ohm]
 EMF_PER_RAD_S,       # ke_out / (L_eff/h + R) [A s/rad]
 INERTIA_KG_M2,       # rotor through the train plus the fixed output parts
 KT_NM_A,             # output torque per amp, gear losses included
 VISCOUS_NM_S_RAD,
 COULOMB_NM,          # kinetic friction
 BREAKAWAY_EXTRA_NM,  # breakaway minus kinetic friction
 BRAKE_HOLD_NM,       # 0: no brake (braked and not driven shorts the armature instead)
 POS0_RAD,            # the angle at power-on (the encoders count from 0 there)
 COUNTS_PER_RAD,
 HOME_RAD,            # home flag: closed at and above
 LIMIT_LO_RAD,        # closed at and below
 LIMIT_HI_RAD) = range(14)  # closed at and above
DRIVE_ROWS = 9
TABLE_ROWS = 14
# flags: the plant's faults that are flags (`Plant.inject`, hil_sim/faults.py), then the readouts that are
(OPEN_CIRCUIT, STUCK_BRAKE,
 DROPPED_OUT,         # encoder_dropout: the count shows FROZEN_COUNT
 DRIVEN, BRAKED,      # what each channel got: its bridge switching, its brake on
 HOME, LIMIT_LO, LIMIT_HI) = range(8)
FLAG_ROWS = 8
# counts: the encoder faults' counts, then the counts read out
(COUNT_OFFSET,        # encoder_glitch: added to the count
 FROZEN_COUNT,
 COUNTS) = range(3)
COUNT_ROWS = 3


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
    # Squares are written x ** square: C's pow(x, 2.0), as CPython computes x ** 2,
    # which is not always x * x (the last bit differs for about one value in a thousand). Given as a
    # number, not a literal, so that the compiled kernel calls pow too: numba turns x ** 2 into x * x.
    square: float = 2.0


# constants: the mass model's, then the gripper's end switches (screw angle, rad), which open its motor
# circuit for travel toward their end (-inf, +inf if they cut nothing), then the external force at the hand [N]
# in the arm plane (x, z), held over a tick's substeps (`ArmPlant.set_hand_force`; 0: none)
LOAD_CONSTANTS = len(LoadConstants._fields)
GRIPPER_CLOSED_RAD, GRIPPER_OPEN_RAD = LOAD_CONSTANTS, LOAD_CONSTANTS + 1
HAND_FX_N, HAND_FZ_N = LOAD_CONSTANTS + 2, LOAD_CONSTANTS + 3
CONSTANTS = LOAD_CONSTANTS + 4


class GripperCut(NamedTuple):
    """The gripper's end switches, which open its motor circuit for travel toward their end."""

    cuts_power: bool
    closed_rad: float
    open_rad: float


class Sensors(NamedTuple):
    """Encoder and switch constants per channel."""

    pos0_rad: list[float]            # the angle at power-on (the encoders count from 0 there)
    counts_per_rad: list[float]
    home_rad: list[float]            # home flag: closed at and above
    limit_lo_rad: list[float]        # closed at and below
    limit_hi_rad: list[float]        # closed at and above


class ChannelFaults(NamedTuple):
    """The plant's per-channel faults, as `Plant.inject` sets them (rows of `ArmTick`'s flags and counts)."""

    open_circuit: Sequence[bool]
    stuck_brake: Sequence[bool]
    count_offset: Sequence[int]      # encoder_glitch: added to the count
    dropped_out: Sequence[bool]      # encoder_dropout: the count shows `frozen_count`
    frozen_count: Sequence[int]


def arm_plant_tick(h_s: float, substeps: int, supply_v: float, outputs_enabled: bool, brake_all: bool,
                   command, state, table, flags, counts, constants) -> tuple[float, float]:
    """Advance the arm `substeps` steps of `h_s` seconds; sample the readouts; return what the bridges draw.

    `outputs_enabled`, `brake_all` are the global command, `command` the per-channel one;
    `supply_v` the bus voltage the bridges switch (the last step's). `state` is stepped in
    place; the readouts go to `flags` and `counts`. Returns the current the bridges draw from
    the supply [A] (< 0 while motors regenerate) and the sum of the squared armature currents
    [A^2] (the bridges' conduction losses per ohm).
    """
    duty, enable, brake = command[DUTY], command[ENABLE], command[BRAKE]
    pos, vel, cur, stop_t = state[POS_RAD], state[VEL_RAD_S], state[CURRENT_A], state[STOP_TORQUE_NM]
    load_nm, load_j = state[LOAD_TORQUE_NM], state[LOAD_INERTIA_KG_M2]
    stop_lo, stop_hi = state[STOP_LO_RAD], state[STOP_HI_RAD]
    l_eff_h, inv_l_eff_r, emf_per_w = table[L_EFF_PER_H], table[INV_L_EFF_R], table[EMF_PER_RAD_S]
    drive_j, kt, visc = table[INERTIA_KG_M2], table[KT_NM_A], table[VISCOUS_NM_S_RAD]
    coulomb, breakaway_extra, hold = table[COULOMB_NM], table[BREAKAWAY_EXTRA_NM], table[BRAKE_HOLD_NM]
    open_circuit, stuck_brake, driven, braked = flags[OPEN_CIRCUIT], flags[STUCK_BRAKE], flags[DRIVEN], flags[BRAKED]
    closed_rad, open_rad = constants[GRIPPER_CLOSED_RAD], constants[GRIPPER_OPEN_RAD]
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
        gripper_on = driven[GRIPPER] and not ((d < 0 and x <= closed_rad) or (d > 0 and x >= open_rad))
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
            # Position by semi-implicit Euler; an inelastic hard stop clamps it, stops the shaft and
            # takes the torque that pushed into it (< 0 into the lower stop).
            x = pos[k] + h_s * w
            if x <= stop_lo[k]:
                x, w, t = stop_lo[k], 0.0, (s if s < 0.0 else 0.0)
            elif x >= stop_hi[k]:
                x, w, t = stop_hi[k], 0.0, (s if s > 0.0 else 0.0)
            else:
                t = 0.0
            pos[k], vel[k], cur[k], stop_t[k] = x, w, p - q * w, t
        gravity_and_inertia(pos[J1], pos[J2], pos[J3], constants, load_nm, load_j)
    # The bridges' draw from the supply (lossless switches): sum of clipped duty * i over driven channels;
    # and their conduction losses per ohm, sum of i^2 over all channels.
    bridges_a = 0.0
    squares = 0.0
    for k in range(n):
        i = cur[k]
        if driven[k]:
            d = duty[k]
            d = d if d < 1.0 else 1.0                              # NaN reads as 1 here
            bridges_a += (d if d > -1.0 else -1.0) * i
        squares += i * i
    sample_readouts(pos, table, flags, counts)
    return bridges_a, squares


def gravity_and_inertia(q1: float, q2: float, q3: float, constants, load_nm, load_inertia) -> None:
    """The lumped mass model at joint angles q1..q3 [rad]: holding torques and inertias, in place.

    Gravity torques, and an external force's at the hand, into `load_nm` (J1-J3), the inertias each
    channel turns, the other joints frozen, into `load_inertia` (J1-J4, mount); hil_sim/arm.py's module
    docstring gives the model. `constants`: the `LoadConstants`, the gripper's two, the hand force's two.
    """
    (l2, l3, cg, tip, g, k1, k2, k3, rod2, rod3, turned, i3, i4, link2_kg, elbow_kg, link3_kg, fixed_kg, turned_kg, p,
     r0, reach, at_base, mobile_arm, guide_wheels, two, _, _, fx, fz) = constants
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
    if fx != 0.0 or fz != 0.0:
        # A force F at the tip P loads joint J as gravity does: (P_z - J_z) F_x - (P_x - J_x) F_z, J^T F.
        # (Skipped without one, so that the loads are to the bit what they were before the hand force.)
        load_nm[J1] += tz * fx - tx * fz
        load_nm[J2] += (tz - ez) * fx - (tx - ex) * fz
        load_nm[J3] += (tz - wz) * fx - (tx - wx) * fz
    # Inertias [kg m^2]: rods m L^2/12 about their centres plus m d^2 (parallel axes), points m d^2 (p: payload).
    span = (wx - ex) ** two + (wz - ez) ** two                     # link III's length squared
    i2 = (rod3 + link3_kg * span / 4.0 + fixed_kg * span + turned
          + turned_kg * ((rx - ex) ** two + (rz - ez) ** two) + p * ((tx - ex) ** two + (tz - ez) ** two))
    i1 = (rod2 + link2_kg * (ex * ex + ez * ez) / 4.0 + elbow_kg * (ex * ex + ez * ez)
          + rod3 + link3_kg * ((ex + wx) ** two + (ez + wz) ** two) / 4.0
          + fixed_kg * (wx * wx + wz * wz)
          + turned + turned_kg * (rx * rx + rz * rz) + p * (tx * tx + tz * tz))
    load_inertia[J1], load_inertia[J2], load_inertia[J3], load_inertia[J4] = i1, i2, i3, i4
    # The mount turns everything about the central shaft: each part at its distance r from it.
    r2, re, r3, rw, rr, rt = (r0 + reach * ex / 2.0, r0 + reach * ex, r0 + reach * (ex + wx) / 2.0,
                              r0 + reach * wx, r0 + reach * rx, r0 + reach * tx)
    total = (at_base + link2_kg * r2 * r2 + elbow_kg * re * re + link3_kg * r3 * r3 + fixed_kg * rw * rw
             + turned_kg * rr * rr + p * rt * rt)
    # Rods about a vertical axis through their centre: m (L cos a)^2 / 12.
    total += (link2_kg * (l2 * c1) ** two + link3_kg * (l3 * c2) ** two) / 12.0
    total += turned * c3 * c3
    load_inertia[MOUNT] = total + mobile_arm + guide_wheels


def sample_readouts(pos, table, flags, counts) -> None:
    """Encoder counts (x4 quadrature, floor, since power-on, through the encoder faults) and switches."""
    pos0, counts_per_rad = table[POS0_RAD], table[COUNTS_PER_RAD]
    home_rad, limit_lo_rad, limit_hi_rad = table[HOME_RAD], table[LIMIT_LO_RAD], table[LIMIT_HI_RAD]
    dropped_out, home, limit_lo, limit_hi = flags[DROPPED_OUT], flags[HOME], flags[LIMIT_LO], flags[LIMIT_HI]
    count_offset, frozen_count, count = counts[COUNT_OFFSET], counts[FROZEN_COUNT], counts[COUNTS]
    for k in range(len(pos)):
        x = pos[k]
        count[k] = (frozen_count[k] if dropped_out[k]     # math.floor gives an int, compiled too
                    else math.floor((x - pos0[k]) * counts_per_rad[k]) + count_offset[k])
        home[k] = x >= home_rad[k]
        limit_lo[k] = x <= limit_lo_rad[k]
        limit_hi[k] = x >= limit_hi_rad[k]


class ArmTick:
    """`arm_plant_tick` bound to one `ArmPlant` and its plant's sensors; the groups of rows it steps.

    Plain (`compiled=False`): the groups are lists of lists, `state`'s rows the very lists the
    classes own. Compiled: 2-D numpy arrays, the classes' state adopted into `state`'s rows, and
    the tick compiled by numba (MissingExtra without it). `faults` are the rows the plant sets.

    Keeps the drive constants for the step length in use and the readouts the last tick
    sampled, handed out as Python values (`gating`, `counts`, `switches`, `currents`); counts
    and switches are sampled again if the arm's state was overwritten since (a joint moved by
    hand). After changing an encoder fault, call `sample()`.
    """

    def __init__(self, arm: ArmPlant, sensors: Sensors, compiled: bool = False) -> None:
        motors = arm.motors
        self._arm, self._motors = arm, motors
        self.compiled = compiled
        n = self._n = motors.n
        pos, vel, cur, stop_t = motors.state_lists()
        load_nm, load_inertia = arm.load_lists()
        stop_lo, stop_hi = motors.stop_lists()
        rows = [pos, vel, cur, stop_t, load_nm, load_inertia, stop_lo, stop_hi]
        table = [[0.0] * n for _ in range(DRIVE_ROWS)] + [list(row) for row in sensors]
        assert len(rows) == STATE_ROWS and len(table) == TABLE_ROWS
        flags = [[False] * n for _ in range(FLAG_ROWS)]
        flags[BRAKED] = [True] * n
        count_rows = [[0] * n for _ in range(COUNT_ROWS)]
        if compiled:
            from hil_sim.arm_tick_compiled import compiled_arm_plant_tick, machine_code_for
            self.command = np.zeros((COMMAND_ROWS, n))
            # A tick's command goes in as one pack of its numbers (half the time numpy takes to copy a list in).
            self._pack_command = struct.Struct(f"{COMMAND_ROWS * n}d").pack_into
            self.state = np.array(rows, dtype=np.float64)
            motors.keep_state_in(*(self.state[r] for r in (POS_RAD, VEL_RAD_S, CURRENT_A, STOP_TORQUE_NM,
                                                             STOP_LO_RAD, STOP_HI_RAD)))
            arm.keep_loads_in(self.state[LOAD_TORQUE_NM], self.state[LOAD_INERTIA_KG_M2])
            self.table = np.array(table, dtype=np.float64)
            self.flags = np.array(flags, dtype=np.bool_)
            self.counts = np.array(count_rows, dtype=np.int64)
            self.constants = np.zeros(CONSTANTS)
            # The scalars' types as `step` passes them: h_s, substeps, supply_v, outputs_enabled, brake_all.
            self._tick = machine_code_for(compiled_arm_plant_tick(), 0.001, 1, 28.0, True, False, self.command,
                                          self.state, self.table, self.flags, self.counts, self.constants)
        else:
            self._tick = arm_plant_tick
            self.command = [[0.0] * n, [False] * n, [True] * n]
            self.state, self.table, self.flags, self.counts = rows, table, flags, count_rows
            self.constants = [0.0] * CONSTANTS
        f, c = self.flags, self.counts
        self.faults = ChannelFaults(f[OPEN_CIRCUIT], f[STUCK_BRAKE], c[COUNT_OFFSET], f[DROPPED_OUT], c[FROZEN_COUNT])
        # The flag readouts as lists of Python bools (`_flag_lists`): the live rows (plain), or converted when
        # first asked for after a tick.
        self._flags_out: Optional[list] = None
        cut = arm.gripper_cut()
        closed_rad, open_rad = (cut.closed_rad, cut.open_rad) if cut.cuts_power else (-math.inf, math.inf)
        self.constants[GRIPPER_CLOSED_RAD], self.constants[GRIPPER_OPEN_RAD] = closed_rad, open_rad
        self._model: Optional[LoadModel] = None
        self._max_substep_s = arm.params.max_substep_s
        self._dt_s = math.nan
        self._substeps, self._h_s = 0, math.nan
        self._given: Sequence = [0.0] * n         # the command of the last tick, as given
        self.bridges_a = 0.0                      # what the bridges drew from the supply at the last tick [A]
        self._set_drive(self._max_substep_s)
        self.sample()

    def _set_drive(self, h_s: float) -> None:
        """The drive rows of `table` for step length `h_s`."""
        self._h_s = h_s
        self.table[:DRIVE_ROWS] = [list(row) for row in zip(*self._motors.step_coefficients(h_s))]

    def _set_loads(self, model: LoadModel) -> None:
        """The mass model's constants into `constants` (again when the payload or gravity has changed)."""
        self._model = model
        self.constants[:LOAD_CONSTANTS] = model.tick_constants

    def set_hand_force(self, fx_n: float, fz_n: float) -> None:
        """The external force at the hand [N] (arm plane) the ticks from now on hold over their substeps."""
        self.constants[HAND_FX_N], self.constants[HAND_FZ_N] = fx_n, fz_n

    def _set_step_length(self, dt_s: float) -> None:
        """Split `dt_s` into equal substeps no longer than `max_substep_s`, as `ArmPlant.step` does."""
        self._dt_s = dt_s
        if dt_s == 0.0:
            self._substeps = 0
            return
        self._substeps = max(1, math.ceil(dt_s / self._max_substep_s - 1e-9))
        h_s = dt_s / self._substeps
        if h_s != self._h_s:
            self._set_drive(h_s)

    def step(self, dt_s: float, outputs_enabled: bool, brake_all: bool, command: Sequence,
             supply_v: float) -> tuple[float, float]:
        """One tick of `dt_s` seconds (see `arm_plant_tick`): the bridges' supply current [A], the sum of i^2.

        `command`: the rows of `command` in one sequence, the n duties, the n enables, the n brakes
        (MOTOR_CMD's order: `ExpiringMotorCommands.current_values`)."""
        if dt_s != self._dt_s:
            self._set_step_length(dt_s)
        model = self._arm.load_model()
        if model is not self._model:
            self._set_loads(model)
        if self.compiled:
            self._pack_command(self.command, 0, *command)
        else:
            n = self._n
            duty, enable, brake = self.command
            duty[:], enable[:], brake[:] = command[:n], command[n:2 * n], command[2 * n:3 * n]
        drawn = self._tick(self._h_s, self._substeps, supply_v, outputs_enabled, brake_all, self.command, self.state,
                           self.table, self.flags, self.counts, self.constants)
        self._given = command
        self.bridges_a = drawn[0]
        self._flags_out = None
        self._sampled_writes = self._motors.state_writes
        return drawn

    @property
    def step_split(self) -> tuple[float, int]:
        """The substep length and the substeps of a tick of the step length in use (`_set_step_length`)."""
        return self._h_s, self._substeps

    def _flag_lists(self) -> list[list[bool]]:
        """The flag readouts (DRIVEN, BRAKED, HOME, LIMIT_LO, LIMIT_HI) as lists of Python bools, once a tick."""
        if self._flags_out is None:
            f = self.flags
            self._flags_out = f[DRIVEN:].tolist() if self.compiled else f[DRIVEN:]
        return self._flags_out

    def duty(self) -> list:
        """The duties the last tick was given, as given (a list of the caller's own)."""
        return list(self._given[:self._n])

    def gating(self) -> tuple[list[bool], list[bool]]:
        """What each channel got at the last tick: (driven, braked), lists of the caller's own."""
        driven, braked = self._flag_lists()[:2]
        return list(driven), list(braked)

    def currents(self) -> list[float]:
        """The armature currents, a list of the caller's own."""
        current = self.state[CURRENT_A]
        return current.tolist() if self.compiled else list(current)

    def encoder_counts(self) -> list[int]:
        """What each channel's encoder interface shows (Python ints), a list of the caller's own."""
        if self._motors.state_writes != self._sampled_writes:
            self.sample()
        count = self.counts[COUNTS]
        return count.tolist() if self.compiled else list(count)

    def switches(self) -> tuple[tuple[bool, ...], tuple[bool, ...], tuple[bool, ...]]:
        """(home, limit_lo, limit_hi) per channel, True = closed."""
        if self._motors.state_writes != self._sampled_writes:
            self.sample()
        _, _, home, limit_lo, limit_hi = self._flag_lists()
        return tuple(home), tuple(limit_lo), tuple(limit_hi)

    def readouts(self) -> tuple[list[int], list[float], tuple[tuple[bool, ...], tuple[bool, ...], tuple[bool, ...]]]:
        """(`encoder_counts()`, `currents()`, `switches()`) at one go: what the plant's node sends each tick."""
        if self._motors.state_writes != self._sampled_writes:
            self.sample()
        _, _, home, limit_lo, limit_hi = self._flag_lists()
        count, current = self.counts[COUNTS], self.state[CURRENT_A]
        if self.compiled:
            count, current = count.tolist(), current.tolist()
        else:
            count, current = list(count), list(current)
        return count, current, (tuple(home), tuple(limit_lo), tuple(limit_hi))

    def true_counts(self) -> list[int]:
        """The encoders' true counts (Python ints), as `sample_readouts` counts them with no encoder fault."""
        n = self._n
        flags = [[False] * n for _ in range(FLAG_ROWS)]
        counts = [[0] * n for _ in range(COUNT_ROWS)]
        sample_readouts(list(self.state[POS_RAD]), [list(row) for row in self.table], flags, counts)
        return counts[COUNTS]

    def sample(self) -> None:
        """Sample the counts and switches from the state as it is (outside a tick)."""
        sample_readouts(self.state[POS_RAD], self.table, self.flags, self.counts)
        self._flags_out = None
        self._sampled_writes = self._motors.state_writes


__all__ = ["ArmTick", "ChannelFaults", "GripperCut", "LoadConstants", "Sensors", "arm_plant_tick",
           "gravity_and_inertia", "sample_readouts"]
