"""The controller's end of the HAL bus: inputs from the plant, outputs to it.

`ControllerHal` never blocks and never raises on what arrives: `poll(now)` drains
whatever frames are waiting, keeps the latest value of each input together with
the `now` at which it arrived (so the supervisor can tell a live input from a
stale one), and counts what it could not use. `send_outputs` sends the global
enable/brake command with a rolling `alive` counter; the plant expires that
command if it stops arriving, so a controller that stalls ends in the safe state
without having to do anything.

This module knows the bus only through `protocol.hal` (the DBC) and python-can's
`BusABC`: it runs unchanged on a virtual bus, socketcan, or any other interface.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import can

from protocol.hal import ARM_CHANNELS, HalCodec, HalEndpoint, SignalValues

_N = len(ARM_CHANNELS)
_COUNT = tuple(f"count_{ch}" for ch in ARM_CHANNELS)
_CURRENT = tuple(f"current_{ch}" for ch in ARM_CHANNELS)
_HOME = tuple(f"home_{ch}" for ch in ARM_CHANNELS)
_LIMIT_LO = tuple(f"limit_lo_{ch}" for ch in ARM_CHANNELS)
_LIMIT_HI = tuple(f"limit_hi_{ch}" for ch in ARM_CHANNELS)
_CMD_NAMES = tuple(f"duty_{ch}" for ch in ARM_CHANNELS) + tuple(f"enable_{ch}" for ch in ARM_CHANNELS) \
    + tuple(f"brake_{ch}" for ch in ARM_CHANNELS)


@dataclass
class HalInputs:
    """Latest inputs seen on the bus. Values are NaN until their first frame arrives."""

    tick: int = 0                    # last PLANT_SYNC tick
    supply_v: float = math.nan       # ANALOG_IN supply_v [V]
    temp_c: float = math.nan         # ANALOG_IN controller_temp_c [degC]
    updated_s: Optional[float] = None  # `now` of the last ANALOG_IN
    tick_s: Optional[float] = None     # `now` of the last PLANT_SYNC
    # MOTOR_FB, per arm channel in ARM_CHANNELS order
    counts: list = field(default_factory=lambda: [0] * _N)        # raw 32-bit counts, unsigned
    currents_a: list = field(default_factory=lambda: [0.0] * _N)
    fb_s: Optional[float] = None       # `now` of the last MOTOR_FB
    # DIGITAL_IN
    home: list = field(default_factory=lambda: [False] * _N)
    limit_lo: list = field(default_factory=lambda: [False] * _N)
    limit_hi: list = field(default_factory=lambda: [False] * _N)
    switches_s: Optional[float] = None


class ControllerHal(HalEndpoint):
    """Controller-side HAL: `poll(now)` for inputs, `send_outputs(...)` for outputs."""

    def __init__(self, bus: can.BusABC, codec: Optional[HalCodec] = None,
                 max_frames_per_poll: int = 256) -> None:
        super().__init__(bus, codec, max_frames_per_poll)
        self.inputs = HalInputs()
        self.alive = 0           # value the next CTRL_OUTPUTS frame will carry
        self.motor_alive = 0     # value the next MOTOR_CMD frame will carry
        self._handlers = {"PLANT_SYNC": self._on_sync, "ANALOG_IN": self._on_analog,
                          "MOTOR_FB": self._on_feedback, "DIGITAL_IN": self._on_switches}

    def poll(self, now: float) -> int:
        """Drain waiting frames and update `inputs`; return how many frames were read.

        The count includes frames that were then counted as bad. Frames declared
        for the other direction (CTRL_OUTPUTS from another controller, say) are
        read and ignored.
        """
        before = self.frames_received
        for name, values in self.receive():
            handler = self._handlers.get(name)
            if handler is not None:
                handler(values, now)
        return self.frames_received - before

    def _on_sync(self, values: SignalValues, now: float) -> None:
        self.inputs.tick = int(values["tick"])
        self.inputs.tick_s = now

    def _on_analog(self, values: SignalValues, now: float) -> None:
        self.inputs.supply_v = float(values["supply_v"])
        self.inputs.temp_c = float(values["controller_temp_c"])
        self.inputs.updated_s = now

    def _on_feedback(self, values: SignalValues, now: float) -> None:
        inputs = self.inputs
        inputs.counts = [int(values[name]) & 0xFFFF_FFFF for name in _COUNT]
        inputs.currents_a = [values[name] for name in _CURRENT]
        inputs.fb_s = now

    def _on_switches(self, values: SignalValues, now: float) -> None:
        inputs = self.inputs
        inputs.home = [bool(values[name]) for name in _HOME]
        inputs.limit_lo = [bool(values[name]) for name in _LIMIT_LO]
        inputs.limit_hi = [bool(values[name]) for name in _LIMIT_HI]
        inputs.switches_s = now

    def send_motor_command(self, duty: list, enable: list, brake: list) -> None:
        """Send MOTOR_CMD: per arm channel duty (-1..1), enable and brake; `motor_alive` advances."""
        signals = dict(zip(_CMD_NAMES, [max(-1.0, min(1.0, d)) for d in duty] + [int(e) for e in enable]
                           + [int(b) for b in brake]))
        self.send("MOTOR_CMD", alive=self.motor_alive, **signals)
        self.motor_alive = (self.motor_alive + 1) & 0xFF

    def is_stale(self, now: float, max_age_s: float) -> bool:
        """True if no ANALOG_IN has arrived, or the last one is older than `max_age_s`."""
        updated_s = self.inputs.updated_s
        return updated_s is None or now - updated_s > max_age_s

    def send_outputs(self, enabled: bool, brake: bool) -> None:
        """Send CTRL_OUTPUTS; `alive` advances on every attempt.

        A failed send (`can.CanError`, e.g. a full transmit queue) is counted in
        `bus_errors`, not raised: the plant will expire the last command, which is
        the safe outcome, and the supervisor can watch the counter.
        """
        self.send("CTRL_OUTPUTS", outputs_enabled=int(bool(enabled)), brake_all=int(bool(brake)), alive=self.alive)
        self.alive = (self.alive + 1) & 0xFF
