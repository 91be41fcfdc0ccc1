"""The minimal plant: supply bus and control-box temperature, with faults.

No motors yet (a later issue adds them): the load is a stand-in current that is
drawn while the outputs are enabled. The plant knows nothing of buses or clocks:
`step(dt_s, ...)` integrates it, and its measured values are sampled (with noise
from the injected generator) once per step, so the same seed and the same
sequence of steps give the same numbers however often they are read.

Seams for the motor plant: `_load_current_a()` (what flows through the supply)
and `_box_heat_w()` (what heats the control box) are the two places the motors
will add to; `ExpiringOutputs` is the shape each motor channel's PWM command will
take (Klipper's pwm ``max_duration``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Optional

import numpy as np

FAULTS = ("supply_sag", "over_temperature")


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
    # Extra current while outputs are enabled: power stages energised. Stand-in until motors exist.
    enabled_current_a: float = 0.75
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

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not math.isfinite(value):
                raise ValueError(f"PlantParams.{f.name} must be finite, got {value}")
        for name in ("supply_source_ohm", "idle_current_a", "enabled_current_a",
                     "supply_noise_v", "temp_noise_c", "supply_sag_v"):
            if getattr(self, name) < 0:
                raise ValueError(f"PlantParams.{name} must be >= 0, got {getattr(self, name)}")
        for name in ("supply_nominal_v", "thermal_resistance_c_per_w",
                     "thermal_capacity_j_per_c", "output_timeout_s"):
            if getattr(self, name) <= 0:
                raise ValueError(f"PlantParams.{name} must be > 0, got {getattr(self, name)}")

    @property
    def thermal_time_constant_s(self) -> float:
        return self.thermal_resistance_c_per_w * self.thermal_capacity_j_per_c


class ExpiringOutputs:
    """The last output command received, void after `timeout_s` without a fresh one.

    Expired (and before the first command) it reads as the safe state: outputs
    disabled, brakes applied. A command whose `alive` counter repeats the previous
    one is a duplicate (CAN can deliver a frame twice, a stuck sender repeats one
    forever) and does not refresh the timer. Expiry does not latch: a fresh command
    applies again. Latching belongs to the controller's supervisor.
    """

    SAFE = (False, True)  # (outputs_enabled, brake)

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self._commanded = self.SAFE
        self._refreshed_s: Optional[float] = None
        self._last_alive: Optional[int] = None
        self.expired = True       # as of the last current() call
        self.expiries = 0         # times a live command lapsed
        self.alive_repeats = 0    # commands ignored for repeating `alive`

    def command(self, outputs_enabled: bool, brake: bool, alive: int, now: float) -> bool:
        """Record a command received at `now`; return False if it was ignored as a repeat."""
        if alive == self._last_alive:
            self.alive_repeats += 1
            return False
        self._last_alive = alive
        self._commanded = (bool(outputs_enabled), bool(brake))
        self._refreshed_s = now
        return True

    def current(self, now: float) -> tuple[bool, bool]:
        """(outputs_enabled, brake) to apply at `now`."""
        if self._refreshed_s is None or now - self._refreshed_s > self.timeout_s:
            if not self.expired:
                self.expiries += 1
                self.expired = True
            return self.SAFE
        self.expired = False
        return self._commanded


class Plant:
    """Supply and box temperature, stepped by `dt_s`; measured values are noisy samples."""

    def __init__(self, params: PlantParams, rng: np.random.Generator) -> None:
        self.params = params
        self._rng = rng
        self._faults: set[str] = set()
        # What the bus last commanded (the node feeds it); `step` applies what it is given.
        self.commanded = ExpiringOutputs(params.output_timeout_s)
        self.outputs_enabled = False  # as applied by the last step
        self.brake = True
        self.temp_true_c = params.ambient_c  # box starts at ambient (just powered on)
        self.supply_true_v = params.supply_nominal_v
        self.current_a = 0.0
        self.step(0.0, outputs_enabled=False, brake=True)

    @property
    def faults(self) -> frozenset[str]:
        return frozenset(self._faults)

    def inject(self, fault: str) -> None:
        self._faults.add(self._check_fault(fault))

    def clear(self, fault: str) -> None:
        self._faults.discard(self._check_fault(fault))

    @staticmethod
    def _check_fault(fault: str) -> str:
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; known faults: {', '.join(FAULTS)}")
        return fault

    @property
    def ambient_c(self) -> float:
        p = self.params
        return p.over_temperature_ambient_c if "over_temperature" in self._faults else p.ambient_c

    @property
    def supply_emf_v(self) -> float:
        p = self.params
        return p.supply_sag_v if "supply_sag" in self._faults else p.supply_nominal_v

    def _load_current_a(self) -> float:
        p = self.params
        return p.idle_current_a + (p.enabled_current_a if self.outputs_enabled else 0.0)

    def _box_heat_w(self) -> float:
        # For now everything drawn is dissipated in the box (there is nothing else to heat).
        # With motors, only electronics and drive-stage losses stay here.
        return self.supply_true_v * self.current_a

    def step(self, dt_s: float, outputs_enabled: bool, brake: bool) -> None:
        """Advance `dt_s` seconds with these outputs applied, then sample the sensors.

        `brake` is tracked but has no physical effect until motors exist.
        """
        if not dt_s >= 0 or not math.isfinite(dt_s):
            raise ValueError(f"dt_s must be finite and >= 0, got {dt_s}")
        p = self.params
        self.outputs_enabled = bool(outputs_enabled)
        self.brake = bool(brake)
        self.current_a = self._load_current_a()
        self.supply_true_v = max(0.0, self.supply_emf_v - self.current_a * p.supply_source_ohm)
        # First-order lag toward ambient + P * Rth, integrated exactly for a step with constant input
        # (stable for any dt_s).
        target_c = self.ambient_c + self._box_heat_w() * p.thermal_resistance_c_per_w
        decay = math.exp(-dt_s / p.thermal_time_constant_s)
        self.temp_true_c = target_c + (self.temp_true_c - target_c) * decay
        noise = self._rng.standard_normal(2)
        self._supply_v = self.supply_true_v + float(noise[0]) * p.supply_noise_v
        self._temp_c = self.temp_true_c + float(noise[1]) * p.temp_noise_c

    @property
    def supply_v(self) -> float:
        """Measured supply voltage at the controller [V] (noisy, sampled at the last step)."""
        return self._supply_v

    @property
    def temp_c(self) -> float:
        """Measured control-box temperature [degC] (noisy, sampled at the last step)."""
        return self._temp_c
