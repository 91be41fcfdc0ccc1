"""The plant's end of the HAL bus: a scheduler task that plays the I/O hardware.

Each `step(now)`:

1. reads every waiting frame; CTRL_OUTPUTS goes to `plant.commanded`, stamped `now`;
2. integrates the plant over the time that really passed since the last step
   (clamped to `max_dt_s`, because a real-time run can stall; clamps are counted),
   with the commanded outputs, or the safe state once they have expired;
3. sends PLANT_SYNC (every step) and ANALOG_IN (every `analog_every_n` steps).

ANALOG_IN goes out at the period declared in the DBC (GenMsgCycleTime, 10 ms),
not every tick: supply and box temperature change slowly, and at 1 kHz every
8-byte frame costs about 11-13 % of a 1 Mbit/s bus, which the motor frames of a
later issue will need. Measured values saturate at the DBC's declared ranges,
as a real ADC would.
"""
from __future__ import annotations

from typing import Optional

import can

from hil_sim.plant import Plant
from protocol.hal import HalCodec, HalEndpoint


class PlantNode(HalEndpoint):
    """Runs a `Plant` on a python-can bus; `step(now)` is a scheduler task."""

    def __init__(self, bus: can.BusABC, plant: Plant, period_s: float = 0.001,
                 codec: Optional[HalCodec] = None, *, analog_period_s: Optional[float] = None,
                 max_dt_s: float = 0.1, max_frames_per_step: int = 256) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        if not max_dt_s >= period_s:
            raise ValueError(f"max_dt_s ({max_dt_s}) must be >= period_s ({period_s})")
        super().__init__(bus, codec, max_frames_per_step)
        self.plant = plant
        self.period_s = period_s
        if analog_period_s is None:
            analog_period_s = self.codec.cycle_time_s("ANALOG_IN") or period_s
        self.analog_every_n = max(1, round(analog_period_s / period_s))
        self.max_dt_s = max_dt_s
        self._supply_range_v = self.codec.limits("ANALOG_IN", "supply_v")
        self._temp_range_c = self.codec.limits("ANALOG_IN", "controller_temp_c")
        self.tick = 0            # index of the next step; PLANT_SYNC carries it modulo 2**32
        self._last_now: Optional[float] = None
        self.dt_clamps = 0       # steps whose elapsed time exceeded max_dt_s (stalls)

    def step(self, now: float) -> float:
        """Read commands, integrate, publish; return the next wake time."""
        self._drain(now)
        if self._last_now is None:
            dt_s = 0.0
        else:
            dt_s = max(0.0, now - self._last_now)
            if dt_s > self.max_dt_s:
                dt_s = self.max_dt_s
                self.dt_clamps += 1
        self._last_now = now
        plant = self.plant
        enabled, brake = plant.commanded.current(now)
        plant.step(dt_s, enabled, brake)
        self.send("PLANT_SYNC", tick=self.tick & 0xFFFF_FFFF)
        if self.tick % self.analog_every_n == 0:
            self.send("ANALOG_IN", supply_v=_saturate(plant.supply_v, self._supply_range_v),
                      controller_temp_c=_saturate(plant.temp_c, self._temp_range_c))
        self.tick += 1
        return now + self.period_s

    def _drain(self, now: float) -> None:
        for name, values in self.receive():
            if name == "CTRL_OUTPUTS":
                self.plant.commanded.command(bool(values["outputs_enabled"]), bool(values["brake_all"]),
                                             int(values["alive"]), now)
            # Other declared frames were sent by a plant (our own echo, say): not for us.


def _saturate(value: float, limits: tuple[float, float]) -> float:
    low, high = limits
    return low if value < low else high if value > high else value
