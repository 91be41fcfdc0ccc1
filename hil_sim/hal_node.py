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
from protocol.hal import HalCodec, HalDecodeError


class PlantNode:
    """Runs a `Plant` on a python-can bus; `step(now)` is a scheduler task."""

    def __init__(self, bus: can.BusABC, plant: Plant, period_s: float = 0.001,
                 codec: Optional[HalCodec] = None, *, analog_period_s: Optional[float] = None,
                 max_dt_s: float = 0.1, max_frames_per_step: int = 256) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        if not max_dt_s >= period_s:
            raise ValueError(f"max_dt_s ({max_dt_s}) must be >= period_s ({period_s})")
        self.bus = bus
        self.plant = plant
        self.period_s = period_s
        self.codec = codec if codec is not None else HalCodec()
        if analog_period_s is None:
            analog_period_s = self.codec.cycle_time_s("ANALOG_IN") or period_s
        self.analog_every_n = max(1, round(analog_period_s / period_s))
        self.max_dt_s = max_dt_s
        self.max_frames_per_step = max_frames_per_step
        self._supply_range_v = self.codec.limits("ANALOG_IN", "supply_v")
        self._temp_range_c = self.codec.limits("ANALOG_IN", "controller_temp_c")
        self.tick = 0            # index of the next step; PLANT_SYNC carries it modulo 2**32
        self._last_now: Optional[float] = None
        self.frames_sent = 0
        self.frames_received = 0
        self.bad_frames = 0      # undeclared IDs and frames that break their declaration
        self.bus_errors = 0      # can.CanError from recv or send
        self.last_bus_error: Optional[can.CanError] = None
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
        self._send(self.codec.encode("PLANT_SYNC", tick=self.tick & 0xFFFF_FFFF))
        if self.tick % self.analog_every_n == 0:
            self._send(self.codec.encode(
                "ANALOG_IN",
                supply_v=_saturate(plant.supply_v, self._supply_range_v),
                controller_temp_c=_saturate(plant.temp_c, self._temp_range_c)))
        self.tick += 1
        return now + self.period_s

    def _drain(self, now: float) -> None:
        for _ in range(self.max_frames_per_step):
            try:
                msg = self.bus.recv(timeout=0)
            except can.CanError as exc:
                self._bus_error(exc)
                return
            if msg is None:
                return
            self.frames_received += 1
            try:
                decoded = self.codec.decode(msg)
            except HalDecodeError:
                self.bad_frames += 1
                continue
            if decoded is None:
                self.bad_frames += 1
            elif decoded[0] == "CTRL_OUTPUTS":
                values = decoded[1]
                self.plant.commanded.command(bool(values["outputs_enabled"]),
                                             bool(values["brake_all"]),
                                             int(values["alive"]), now)
            # Other declared frames were sent by a plant (our own echo, say): not for us.

    def _send(self, msg: can.Message) -> None:
        try:
            self.bus.send(msg, timeout=0)
        except can.CanError as exc:
            self._bus_error(exc)
            return
        self.frames_sent += 1

    def _bus_error(self, exc: can.CanError) -> None:
        self.bus_errors += 1
        self.last_bus_error = exc


def _saturate(value: float, limits: tuple[float, float]) -> float:
    low, high = limits
    return low if value < low else high if value > high else value
