"""Brushed DC motors behind gear trains, held as one bank of channels (the arm plant's tick steps them).

Design: docs/arm.md#the-motors
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class GearStage:
    """One reduction: `ratio` input turns per output turn, power efficiency in (0, 1]."""

    name: str
    ratio: float
    efficiency: float

    def __post_init__(self) -> None:
        if not self.ratio > 0:
            raise ValueError(f"GearStage {self.name!r}: ratio must be > 0, got {self.ratio}")
        if not 0 < self.efficiency <= 1:
            raise ValueError(f"GearStage {self.name!r}: efficiency must be in (0, 1], got {self.efficiency}")


@dataclass(frozen=True)
class MotorSpec:
    """A PM DC gearmotor as bought: the motor (values at the motor shaft) and its gear head."""

    name: str
    nominal_v: float
    r_ohm: float
    l_h: float
    kt_nm_a: float
    ke_v_s_rad: float
    rotor_inertia_kg_m2: float
    coulomb_nm: float          # brush and bearing friction at the motor shaft, while turning
    stiction_nm: float         # breakaway friction at the motor shaft, >= coulomb_nm
    viscous_nm_s_rad: float    # at the motor shaft
    gearhead: GearStage
    rated_torque_nm: float     # catalogue maximum at the gear-head output (the report's "oz-in")

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not (math.isfinite(value) and value >= 0):
                raise ValueError(f"MotorSpec {self.name!r}: {f.name} must be finite and >= 0, got {value}")
        for name in ("nominal_v", "r_ohm", "kt_nm_a", "ke_v_s_rad", "rotor_inertia_kg_m2"):
            if not getattr(self, name) > 0:
                raise ValueError(f"MotorSpec {self.name!r}: {name} must be > 0")
        if self.stiction_nm < self.coulomb_nm:
            raise ValueError(f"MotorSpec {self.name!r}: stiction_nm must be >= coulomb_nm")


@dataclass(frozen=True)
class DriveParams:
    """One motor channel: a gearmotor, external gear stages, output-side load, brake, stops."""

    name: str
    motor: MotorSpec
    stages: tuple[GearStage, ...] = ()
    output_inertia_kg_m2: float = 0.0     # fixed parts on the output (sprockets, shafts)
    output_coulomb_nm: float = 0.0        # output bearings, belts, guide wheels
    output_stiction_nm: float = 0.0
    output_viscous_nm_s_rad: float = 0.0
    brake_hold_nm: float = 0.0            # holding torque at the output; 0 = no brake
    stop_lo_rad: float = -math.inf        # hard end stops of the output shaft
    stop_hi_rad: float = math.inf

    def __post_init__(self) -> None:
        for name in ("output_inertia_kg_m2", "output_coulomb_nm", "output_stiction_nm",
                     "output_viscous_nm_s_rad", "brake_hold_nm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"DriveParams {self.name!r}: {name} must be finite and >= 0, got {value}")
        if self.output_stiction_nm < self.output_coulomb_nm:
            raise ValueError(f"DriveParams {self.name!r}: output_stiction_nm must be >= output_coulomb_nm")
        if not self.stop_lo_rad < self.stop_hi_rad:
            raise ValueError(f"DriveParams {self.name!r}: stop_lo_rad must be < stop_hi_rad")

    @property
    def ratio(self) -> float:
        """Motor turns per output turn, gear head and external stages together."""
        return self.motor.gearhead.ratio * math.prod(s.ratio for s in self.stages)

    @property
    def efficiency(self) -> float:
        return self.motor.gearhead.efficiency * math.prod(s.efficiency for s in self.stages)

    @property
    def kt_out_nm_a(self) -> float:
        """Output torque per armature amp, gear losses included."""
        return self.efficiency * self.ratio * self.motor.kt_nm_a

    @property
    def ke_out_v_s_rad(self) -> float:
        """Back-EMF per output rad/s."""
        return self.ratio * self.motor.ke_v_s_rad

    @property
    def inertia_kg_m2(self) -> float:
        """Rotor reflected through the whole train plus the fixed output parts."""
        return self.ratio ** 2 * self.motor.rotor_inertia_kg_m2 + self.output_inertia_kg_m2

    @property
    def viscous_nm_s_rad(self) -> float:
        return self.ratio ** 2 * self.motor.viscous_nm_s_rad + self.output_viscous_nm_s_rad

    @property
    def coulomb_nm(self) -> float:
        return self.ratio * self.motor.coulomb_nm + self.output_coulomb_nm

    @property
    def stiction_nm(self) -> float:
        return self.ratio * self.motor.stiction_nm + self.output_stiction_nm

    @property
    def rated_output_torque_nm(self) -> float:
        """The gear head's catalogue torque carried through the external stages."""
        ext = self.stages
        return self.motor.rated_torque_nm * math.prod(s.ratio * s.efficiency for s in ext)

    def stall_torque_nm(self, volts_v: float) -> float:
        """Output torque with the shaft held and `volts_v` across the winding."""
        return self.kt_out_nm_a * volts_v / self.motor.r_ohm

    def steady_speed_rad_s(self, volts_v: float, load_torque_nm: float = 0.0) -> float:
        """Steady output speed at `volts_v` against a constant load, friction included (>= 0 side)."""
        r = self.motor.r_ohm
        drive = self.kt_out_nm_a * volts_v / r - load_torque_nm
        if abs(drive) <= self.coulomb_nm:
            return 0.0
        drive -= math.copysign(self.coulomb_nm, drive)
        return drive / (self.viscous_nm_s_rad + self.kt_out_nm_a * self.ke_out_v_s_rad / r)


class DcMotorBank:
    """Several `DriveParams` channels, indexed by channel: their state, stops and step constants (the arm plant's
    tick, `hil_sim.arm_tick`, steps them).

    State, read as fresh numpy arrays: `pos_rad`, `vel_rad_s` (output shaft), `i_a`
    (armature current, the current-sense value), `stop_torque_nm` (torque a hard stop
    absorbed in the last step: < 0 into the lower stop, > 0 into the upper). Write state
    only through `set_state`; move a channel's stops with `set_stops` (an object between
    gripper jaws; a jam is both stops at the present position).
    """

    def __init__(self, drives: Sequence[DriveParams]) -> None:
        if not drives:
            raise ValueError("DcMotorBank needs at least one drive")
        self.drives = tuple(drives)
        self.names = tuple(d.name for d in drives)
        self.n = len(drives)
        self.ratio = np.array([d.ratio for d in drives])
        self.inertia_kg_m2 = np.array([d.inertia_kg_m2 for d in drives])
        self._stop_lo = [d.stop_lo_rad for d in drives]
        self._stop_hi = [d.stop_hi_rad for d in drives]
        # The state, as lists changed in place and never replaced: a fused tick (hil_sim.arm_tick)
        # holds them and steps them directly (or rows of its arrays, `keep_state_in`).
        self._pos = [0.0] * self.n
        self._vel = [0.0] * self.n
        self._i = [0.0] * self.n
        self._stop_t = [0.0] * self.n
        self._as_list = list       # a row's values as a list of Python floats
        self.state_writes = 0      # how often `set_state` overwrote the state (readers that sample per step compare it)

    def set_state(self, pos_rad=None, vel_rad_s=None, i_a=None) -> None:
        """Overwrite state (power-on pose, tests). Arguments are per-channel sequences or None."""
        for name, value in (("_pos", pos_rad), ("_vel", vel_rad_s), ("_i", i_a)):
            if value is not None:
                value = [float(v) for v in value]
                if len(value) != self.n or not all(math.isfinite(v) for v in value):
                    raise ValueError(f"state needs {self.n} finite values, got {value}")
                getattr(self, name)[:] = value
        self.state_writes += 1

    def set_stops(self, channel: int, lo_rad: float, hi_rad: float) -> None:
        """Move one channel's hard stops (they may not cross)."""
        if not lo_rad <= hi_rad:
            raise ValueError(f"stops cross: lo {lo_rad} > hi {hi_rad}")
        self._stop_lo[channel] = float(lo_rad)
        self._stop_hi[channel] = float(hi_rad)

    def positions(self) -> list[float]:
        """Output shaft angles as a list of floats (cheaper than `pos_rad` for a few channels)."""
        return self._as_list(self._pos)

    def currents(self) -> list[float]:
        """Armature currents as a list of floats (cheaper than `i_a` for a few channels)."""
        return self._as_list(self._i)

    def stops_rad(self, channel: int) -> tuple[float, float]:
        return float(self._stop_lo[channel]), float(self._stop_hi[channel])

    def state_lists(self) -> tuple[list[float], list[float], list[float], list[float]]:
        """The live state rows: position, speed, current, stop torque (changed in place, never replaced)."""
        return self._pos, self._vel, self._i, self._stop_t

    def stop_lists(self) -> tuple[list[float], list[float]]:
        """The live rows of the hard stops, low and high (`set_stops` changes them in place)."""
        return self._stop_lo, self._stop_hi

    def keep_state_in(self, pos: np.ndarray, vel: np.ndarray, i: np.ndarray, stop_torque: np.ndarray,
                      stop_lo: np.ndarray, stop_hi: np.ndarray) -> None:
        """Keep the state and the stops from now on in these float64 rows (a compiled tick's arrays), values kept.

        Everything here reads and writes them as it did the lists; what it hands out stays Python
        floats.
        """
        for name, row in (("_pos", pos), ("_vel", vel), ("_i", i), ("_stop_t", stop_torque), ("_stop_lo", stop_lo),
                          ("_stop_hi", stop_hi)):
            row[:] = getattr(self, name)
            setattr(self, name, row)
        self._as_list = np.ndarray.tolist

    def step_coefficients(self, h: float) -> list[tuple[float, ...]]:
        """Per-channel constants of a step of length `h`, as `step` uses them.

        Per channel: (L_eff/h, 1/(L_eff/h + R), ke_out/(L_eff/h + R), inertia, kt_out, viscous,
        Coulomb, breakaway minus Coulomb, brake holding torque), all at the output shaft: the drive
        rows of the plant's tick (`hil_sim.arm_tick.arm_plant_tick`, which steps the bank's state).
        """
        coef = []
        for d in self.drives:
            r, l_h = d.motor.r_ohm, d.motor.l_h
            x = min(r * h / l_h, 700.0) if l_h > 0 else 700.0
            a_e = r / math.expm1(x)                 # L_eff / h, see the module docstring
            inv_aer = 1.0 / (a_e + r)
            coef.append((a_e, inv_aer, d.ke_out_v_s_rad * inv_aer, d.inertia_kg_m2, d.kt_out_nm_a,
                         d.viscous_nm_s_rad, d.coulomb_nm, d.stiction_nm - d.coulomb_nm, d.brake_hold_nm))
        return coef

    @property
    def pos_rad(self) -> np.ndarray:
        return np.array(self._pos)

    @property
    def vel_rad_s(self) -> np.ndarray:
        return np.array(self._vel)

    @property
    def i_a(self) -> np.ndarray:
        return np.array(self._i)

    @property
    def stop_torque_nm(self) -> np.ndarray:
        return np.array(self._stop_t)
