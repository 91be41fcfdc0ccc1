"""The plant: supply bus, control-box temperature and the arm, with expiring commands and faults.

Design: docs/plant.md
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from numbers import Integral
from typing import Optional, Sequence

import numpy as np

from hil_sim.arm import ArmPlant
from hil_sim.arm_params import ARM_PLANT_PARAMS, ArmPlantParams
from hil_sim.arm_tick import ArmTick
from hil_sim.commands import N_CHANNELS, ExpiringMotorCommands, ExpiringOutputs, ExpiringTrackerCommands
from hil_sim.faults import CHANNEL_FAULTS, PLANT_FAULTS, Channel, fault_key, resolve
from hil_sim.sun import DEFAULT_START, TUCSON, DateTimeLike, Site
from hil_sim.tracker import TRACKER_PARAMS, TrackerParams, TrackerPlant

# The plant-wide faults (no channel). Per-channel ones: CHANNEL_FAULTS; all: hil_sim.faults.
FAULTS = PLANT_FAULTS

_NOISE_BATCH = 512   # normal deviates drawn from the generator at once (two per step)


@dataclass(frozen=True)
class PlantParams:
    """Plant constants. Defaults are stand-ins chosen to be plausible, not measured."""

    # Supply EMF. The report gives no supply voltage for the arm; the one rated motor voltage on
    # it is the gripper's "27.5 VDC DAYTOM" (seed/000_54a4d1d9271955c2.txt, Key to Figure 9,
    # part 64), so a 28 V bus stands in for the supply. (The tracker's 90 VDC motors will need a
    # supply of their own when they are modelled.)
    supply_nominal_v: float = 28.0
    # Source resistance of supply plus wiring: the sag per amp drawn.
    supply_source_ohm: float = 0.25
    # Supply EMF while the "supply_sag" fault is injected (a failing supply or flat battery).
    supply_sag_v: float = 18.0
    # Control electronics, always drawn.
    idle_current_a: float = 0.25
    # Extra current while outputs are enabled: gate drivers and bridge supplies energised. The
    # motors' own currents come on top (ArmPlant.supply_current_a).
    enabled_current_a: float = 0.75
    # ASSUMED: each channel's H-bridge conducts through two power MOSFETs of the IRF540 class
    # (0.077 ohm each): i^2 * 0.15 ohm per channel heats the box. Switching losses neglected.
    drive_on_resistance_ohm: float = 0.15
    ambient_c: float = 22.0
    # Ambient while the "over_temperature" fault is injected: box left in the sun, 15 degC above
    # the report's limit (operating step 4: keep the controller between -10 C and 45 C).
    over_temperature_ambient_c: float = 60.0
    # Box to ambient. Idle (7 W) sits 3.5 degC above ambient, enabled (28 W) about 14 degC.
    thermal_resistance_c_per_w: float = 0.5
    # Box plus electronics, about 0.7 kg of aluminium. With 0.5 degC/W: time constant 300 s.
    thermal_capacity_j_per_c: float = 600.0
    # Standard deviations of the measurement noise.
    supply_noise_v: float = 0.02
    temp_noise_c: float = 0.1
    # A CTRL_OUTPUTS command older than this is void: outputs off, brakes on.
    output_timeout_s: float = 0.1
    # A MOTOR_CMD older than this is void: every arm channel off and braked (20 ms: twenty
    # controller ticks at 1 kHz).
    motor_cmd_timeout_s: float = 0.02
    # The jump of the "encoder_glitch" fault, in counts (J1: 11 deg, a 1 ms speed no joint has).
    encoder_glitch_counts: int = 20000
    # A TRACKER_CMD older than this is void: relays open, brakes on, sensors and motors unpowered
    # (protocol/hal.dbc: "the plant expires it after 0.1 s").
    tracker_cmd_timeout_s: float = 0.1

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not math.isfinite(value):
                raise ValueError(f"PlantParams.{f.name} must be finite, got {value}")
        for name in ("supply_source_ohm", "idle_current_a", "enabled_current_a", "drive_on_resistance_ohm",
                     "supply_noise_v", "temp_noise_c", "supply_sag_v"):
            if getattr(self, name) < 0:
                raise ValueError(f"PlantParams.{name} must be >= 0, got {getattr(self, name)}")
        for name in ("supply_nominal_v", "thermal_resistance_c_per_w",
                     "thermal_capacity_j_per_c", "output_timeout_s", "motor_cmd_timeout_s", "tracker_cmd_timeout_s"):
            if getattr(self, name) <= 0:
                raise ValueError(f"PlantParams.{name} must be > 0, got {getattr(self, name)}")
        glitch = self.encoder_glitch_counts
        if not isinstance(glitch, Integral) or isinstance(glitch, bool) or glitch == 0:
            raise ValueError(f"PlantParams.encoder_glitch_counts must be a non-zero integer, got {glitch!r}")

    @property
    def thermal_time_constant_s(self) -> float:
        return self.thermal_resistance_c_per_w * self.thermal_capacity_j_per_c


class Plant:
    """Supply, box temperature and arm, stepped by `dt_s`; measured values are sampled per step.

    `arm` is the `ArmPlant` (set an object between the jaws, a payload, the gravity mode,
    or move a joint by hand through it). `commanded` and `motor_commands` hold what the bus
    last commanded; the node feeds them and hands `step` what they read at its `now`.

    The solar tracker: `tracker` (`hil_sim.tracker.TrackerPlant`, built from
    `tracker_params`, `site`, `start` and `clouds`; see the module docstring) and
    `tracker_commands` (TRACKER_CMD, expiring). `start` is the simulated date-time at which
    the tracker's clock starts, an aware datetime or a POSIX timestamp (default
    `hil_sim.sun.DEFAULT_START`, the June solstice 2026 at 06:00 MST); `site` defaults to
    Tucson; `clouds` is None, a spec string ("12:00+300s@0.9,14:30+10m@0.5",
    `hil_sim.sun.parse_clouds`) or `CloudPassage` items.

    The arm's channels are stepped by the arm's tick (`hil_sim.arm_tick`, `ArmPlant.tick`).
    `compiled_arm_tick`: that tick compiled by numba (hil_sim/arm_tick_compiled.py), the same to
    the bit; None (default) takes `kernels.compiled_by_default()` (`ASPOD_COMPILED=1`). Asked for
    without numba: MissingExtra (kernels/extras.py).
    """

    def __init__(self, params: PlantParams, rng: np.random.Generator, *,
                 arm_params: ArmPlantParams = ARM_PLANT_PARAMS, gravity: str = "earth",
                 payload_kg: float = 0.0, site: Site = TUCSON, start: DateTimeLike = DEFAULT_START,
                 clouds=None, tracker_params: TrackerParams = TRACKER_PARAMS,
                 compiled_arm_tick: Optional[bool] = None) -> None:
        self.params = params
        self._rng = rng
        self._noise: list[float] = []
        self._noise_at = 0
        self.arm = ArmPlant(arm_params, gravity=gravity, payload_kg=payload_kg, compiled=compiled_arm_tick)
        self._arm_tick: ArmTick = self.arm.tick
        # Faults: active keys ("jam:j2"), and per-channel state the step reads (the tick's own rows, changed in place).
        self._faults: set[str] = set()
        (self._open_circuit, self._stuck_brake, self._count_offset, self._dropped_out,
         self._frozen_count) = self._arm_tick.faults
        self._jam_saved_stops: dict[int, tuple[float, float]] = {}
        # What the bus last commanded (the node feeds them); `step` applies what it is given.
        self.commanded = ExpiringOutputs(params.output_timeout_s)
        self.motor_commands = ExpiringMotorCommands(params.motor_cmd_timeout_s, N_CHANNELS)
        # As applied by the last step (and `channel_duty`, `channel_driven`, `channel_braked`).
        self.outputs_enabled = False
        self.brake = True
        # The solar tracker, with a generator of its own so that the arm's noise stream does not change.
        self.tracker = TrackerPlant(tracker_params, _spawn(rng), site=site, start=start, clouds=clouds)
        self.tracker_commands = ExpiringTrackerCommands(params.tracker_cmd_timeout_s)
        self.temp_true_c = params.ambient_c  # box starts at ambient (just powered on)
        self.supply_true_v = params.supply_nominal_v
        self.current_a = 0.0          # total drawn from the supply at the last step
        self._decay_dt_s, self._decay = math.nan, 1.0   # the temperature's decay factor for that step length
        self.step(0.0, outputs_enabled=False, brake=True)

    @property
    def compiled_arm_tick(self) -> bool:
        """True if the arm's tick runs compiled by numba."""
        return self._arm_tick.compiled

    # -- faults -------------------------------------------------------------------------------
    @property
    def faults(self) -> frozenset[str]:
        """Active faults: "supply_sag", "over_temperature", "<name>:<channel>" (e.g. "jam:j2")."""
        return frozenset(self._faults)

    def inject(self, fault: str, channel: Optional[Channel] = None) -> None:
        """Start fault `fault` (on `channel`, a name or index, for per-channel faults).

        See `hil_sim.faults.FAULT_TABLE`. Already active: nothing changes. Bad name or
        channel: ValueError, nothing changes.
        """
        spec, index = resolve(fault, channel)
        key = fault_key(spec, index)
        if key in self._faults:
            return
        if index is not None:
            self._set_channel_fault(spec.name, index, True)
        elif spec.name == "clouds":
            self.tracker.overcast = True
        self._faults.add(key)

    def clear(self, fault: str, channel: Optional[Channel] = None) -> None:
        """End fault `fault` (on `channel`). Not active: nothing changes. Bad input: ValueError."""
        spec, index = resolve(fault, channel)
        key = fault_key(spec, index)
        if key not in self._faults:
            return
        if index is not None:
            self._set_channel_fault(spec.name, index, False)
        elif spec.name == "clouds":
            self.tracker.overcast = False
        self._faults.discard(key)

    def _set_channel_fault(self, name: str, k: int, on: bool) -> None:
        if name == "open_circuit":
            self._open_circuit[k] = on
        elif name == "stuck_brake":
            self._stuck_brake[k] = on
        elif name == "encoder_dropout":
            # Freeze what the encoder interface shows now; cleared, it shows the true count again.
            if on:
                self._frozen_count[k] = self.encoder_counts[k]
            self._dropped_out[k] = on
        elif name == "encoder_glitch":
            self._count_offset[k] = self.params.encoder_glitch_counts if on else 0
        elif name == "jam":
            motors = self.arm.motors
            if on:
                self._jam_saved_stops[k] = motors.stops_rad(k)
                here = motors.positions()[k]
                motors.set_stops(k, here, here)
            else:
                motors.set_stops(k, *self._jam_saved_stops.pop(k))
        else:  # pragma: no cover - the table and this method must agree
            raise AssertionError(f"fault {name!r} is declared but not implemented")
        self._arm_tick.sample()         # the counts show an encoder fault at once

    @property
    def ambient_c(self) -> float:
        p = self.params
        return p.over_temperature_ambient_c if "over_temperature" in self._faults else p.ambient_c

    @property
    def supply_emf_v(self) -> float:
        p = self.params
        return p.supply_sag_v if "supply_sag" in self._faults else p.supply_nominal_v

    # -- integration --------------------------------------------------------------------------
    def step(self, dt_s: float, outputs_enabled: bool, brake: bool, duty: Optional[Sequence[float]] = None,
             enable: Optional[Sequence[bool]] = None, channel_brake: Optional[Sequence[bool]] = None) -> None:
        """Advance `dt_s` seconds with these commands applied, then sample the sensors.

        `outputs_enabled` and `brake` are the global command (CTRL_OUTPUTS); `duty`,
        `enable` and `channel_brake` the per-channel one (MOTOR_CMD, order `ARM_CHANNELS`),
        all three or none (none: every channel off and braked). See the module docstring
        for how they combine.
        """
        if not dt_s >= 0 or not math.isfinite(dt_s):
            raise ValueError(f"dt_s must be finite and >= 0, got {dt_s}")
        if duty is None and enable is None and channel_brake is None:
            duty, enable, channel_brake = self.motor_commands.safe
        elif duty is None or enable is None or channel_brake is None:
            raise ValueError("give duty, enable and channel_brake together, or none of them")
        elif not len(duty) == len(enable) == len(channel_brake) == N_CHANNELS:
            raise ValueError(f"duty, enable and channel_brake need {N_CHANNELS} entries each")
        self.tick(dt_s, outputs_enabled, brake, [*duty, *enable, *channel_brake])

    def tick(self, dt_s: float, outputs_enabled: bool, brake: bool, command: Sequence) -> None:
        """`step` as the plant's node takes it once a tick, without the checks: `dt_s` finite and >= 0,
        `command` the per-channel command in one sequence, the duties, the enables, the brakes (as
        `ExpiringMotorCommands.current_values` hands it out; not to be changed after)."""
        p = self.params
        outputs_enabled = self.outputs_enabled = bool(outputs_enabled)
        brake = self.brake = bool(brake)
        bridges_a, squares = self._arm_tick.step(dt_s, outputs_enabled, brake, command, self.supply_true_v)
        if dt_s != self._decay_dt_s:      # the same step length every tick: the same factor
            self._decay_dt_s, self._decay = dt_s, math.exp(-dt_s / p.thermal_time_constant_s)
        at = self._noise_at
        if at >= len(self._noise):
            # Drawn in batches: the same sequence of deviates as two per step, for less overhead.
            self._noise = self._rng.standard_normal(_NOISE_BATCH).tolist()
            at = 0
        self._noise_at = at + 2
        self.current_a, self.supply_true_v, self.temp_true_c, self._supply_v, self._temp_c = electronics_step(
            bridges_a, squares, outputs_enabled, self.temp_true_c, self._decay, self._noise[at], self._noise[at + 1],
            self.supply_emf_v, self.ambient_c, p.idle_current_a, p.enabled_current_a, p.supply_source_ohm,
            p.drive_on_resistance_ohm, p.thermal_resistance_c_per_w, p.supply_noise_v, p.temp_noise_c)

    # -- what the last step applied --------------------------------------------------------------
    @property
    def channel_duty(self) -> list:
        """Each channel's duty at the last step, as commanded (a list of the caller's own)."""
        return self._arm_tick.duty()

    @property
    def channel_driven(self) -> list[bool]:
        """Whether each channel's bridge switched at the last step (a list of the caller's own)."""
        return self._arm_tick.gating()[0]

    @property
    def channel_braked(self) -> list[bool]:
        """Whether each channel's brake was on at the last step (a list of the caller's own)."""
        return self._arm_tick.gating()[1]

    @property
    def currents_a(self) -> list[float]:
        """The armature currents at the last step (current sense, exact; a list of the caller's own)."""
        return self._arm_tick.currents()

    # -- sensors --------------------------------------------------------------------------------
    @property
    def supply_v(self) -> float:
        """Measured supply voltage at the controller [V] (noisy, sampled at the last step)."""
        return self._supply_v

    @property
    def temp_c(self) -> float:
        """Measured control-box temperature [degC] (noisy, sampled at the last step)."""
        return self._temp_c

    @property
    def encoder_counts(self) -> list[int]:
        """What each channel's encoder interface shows: quadrature counts since power-on.

        The true count (unbounded Python ints) plus any glitch offset, or the frozen value while
        the encoder has dropped out, as the arm's tick samples them at its end (and again after a
        fault or a move by hand).
        """
        return self._arm_tick.encoder_counts()

    def switches(self) -> tuple[tuple[bool, ...], tuple[bool, ...], tuple[bool, ...]]:
        """(home, limit_lo, limit_hi) per channel, True = closed (as `ArmPlant`'s switch arrays)."""
        return self._arm_tick.switches()

    def readouts(self) -> tuple[list[int], list[float], tuple[tuple[bool, ...], tuple[bool, ...], tuple[bool, ...]]]:
        """(`encoder_counts`, `currents_a`, `switches()`) at one go: what the node sends each tick."""
        return self._arm_tick.readouts()


def electronics_step(bridges_a: float, squares: float, outputs_enabled: bool, temp_true_c: float, decay: float,
                     supply_noise: float, temp_noise: float, supply_emf_v: float, ambient_c: float,
                     idle_current_a: float, enabled_current_a: float, supply_source_ohm: float,
                     drive_on_resistance_ohm: float, thermal_resistance_c_per_w: float, supply_noise_v: float,
                     temp_noise_c: float) -> tuple[float, float, float, float, float]:
    """A tick of the box's electronics, the one implementation (`Plant.tick`, and the world's fast loop,
    host_tools/worlds/fast_loop.py), after the arm's tick: the supply current (the electronics' and the bridges'
    `bridges_a`), the supply's voltage at the controller behind its source resistance, the box's temperature (a
    first-order lag toward ambient plus the heat times the thermal resistance, integrated exactly for a step with
    constant input: `decay` is exp(-dt / time constant)), and the two sensors with their noise (`supply_noise`,
    `temp_noise`: standard normal deviates). Returns (current_a, supply_true_v, temp_true_c, supply_v, temp_c)."""
    electronics_a = idle_current_a + (enabled_current_a if outputs_enabled else 0.0)
    current_a = electronics_a + bridges_a
    drop = supply_emf_v - current_a * supply_source_ohm
    supply_true_v = drop if drop > 0.0 else 0.0          # max(0.0, drop), NaN as 0.0
    # Heat left in the box: electronics, and the bridges' conduction losses (i^2 R per channel).
    heat_w = supply_true_v * electronics_a + drive_on_resistance_ohm * squares
    target_c = ambient_c + heat_w * thermal_resistance_c_per_w
    temp_true_c = target_c + (temp_true_c - target_c) * decay
    return (current_a, supply_true_v, temp_true_c, supply_true_v + supply_noise * supply_noise_v,
            temp_true_c + temp_noise * temp_noise_c)


def _spawn(rng: np.random.Generator) -> np.random.Generator:
    """An independent child generator; the parent's stream is left as it was (numpy's `Generator.spawn`)."""
    try:
        return rng.spawn(1)[0]
    except (AttributeError, TypeError, ValueError):
        # A generator without a seed sequence (built from a bare state) cannot spawn: seed a child from it.
        return np.random.default_rng(int(rng.integers(2**63)))


__all__ = ["CHANNEL_FAULTS", "FAULTS", "Plant", "PlantParams"]
