"""The controller's end of the HAL bus: inputs from the plant, outputs to it.

`ControllerHal` never blocks and never raises on what arrives: `poll(now)` (from
`HalEndpoint`) drains whatever frames are waiting, keeps the latest value of each input together with
the `now` at which it arrived (so the supervisor can tell a live input from a
stale one), and counts what it could not use. `send_outputs` sends the global
enable/brake command with a rolling `alive` counter; the plant expires that
command if it stops arriving, so a controller that stalls ends in the safe state
without having to do anything.

The solar tracker's frames: TRACKER_SENSE (photocells) and TRACKER_POS (angles, limit
switches, 90 VDC bus) land in `HalInputs` with the `now` they arrived (`sense_s`,
`pos_s`; None until the first, so a plant without the tracker leaves them None);
`send_tracker_command` sends TRACKER_CMD. What a stale tracker input means is the
tracker's business (`firmware_py/tracker/`), not the supervisor's: the tracker frames
never make the HAL stale.

This module knows the bus only through `protocol.hal` (the DBC) and python-can's
`BusABC`: it runs unchanged on a virtual bus, socketcan, or any other interface.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import can

from protocol.hal import HalCodec, HalEndpoint
from protocol.states import ARM_CHANNELS

_N = len(ARM_CHANNELS)
_FB_ORDER = ("tick", *(f"count_{ch}" for ch in ARM_CHANNELS), *(f"current_{ch}" for ch in ARM_CHANNELS))
_SWITCH_ORDER = (*(f"home_{ch}" for ch in ARM_CHANNELS), *(f"limit_lo_{ch}" for ch in ARM_CHANNELS),
                 *(f"limit_hi_{ch}" for ch in ARM_CHANNELS), "tick")
_CMD_ORDER = (*(f"duty_{ch}" for ch in ARM_CHANNELS), *(f"enable_{ch}" for ch in ARM_CHANNELS),
              *(f"brake_{ch}" for ch in ARM_CHANNELS), "alive")
TRACKER_AXES = ("az", "el")
_SENSE_ORDER = ("cell_az_a", "cell_az_b", "cell_el_a", "cell_el_b")
_POS_ORDER = ("angle_az", "angle_el", "limit_cw_az", "limit_ccw_az", "limit_cw_el", "limit_ccw_el", "motor_supply_v")
_TRACKER_CMD_ORDER = ("relay_cw_az", "relay_ccw_az", "relay_cw_el", "relay_ccw_el", "brake_az", "brake_el",
                      "sensor_power", "motor_power", "duty_az", "duty_el", "alive")


def _duty_step(codec: HalCodec) -> float:
    """MOTOR_CMD's duty resolution: every channel's duty signal has the same scale, no offset."""
    message = codec.database.get_message_by_name("MOTOR_CMD")
    steps = {(message.get_signal_by_name(f"duty_{ch}").scale, message.get_signal_by_name(f"duty_{ch}").offset)
             for ch in ARM_CHANNELS}
    if len(steps) != 1 or next(iter(steps))[1] != 0:
        raise ValueError(f"MOTOR_CMD: the duties' (scale, offset) differ or have an offset: {steps}")
    return float(next(iter(steps))[0])


@dataclass
class HalInputs:
    """Latest inputs seen on the bus. Values are NaN until their first frame arrives."""

    tick: int = 0                    # last PLANT_SYNC tick
    supply_v: float = math.nan       # ANALOG_IN supply_v [V]
    temp_c: float = math.nan         # ANALOG_IN controller_temp_c [degC]
    updated_s: Optional[float] = None  # `now` of the last ANALOG_IN
    tick_s: Optional[float] = None     # `now` of the last PLANT_SYNC
    tick_period_s: float = 0.001       # the simulated time a plant tick stands for (PLANT_SYNC period_us)
    # MOTOR_FB, per arm channel in ARM_CHANNELS order
    counts: list = field(default_factory=lambda: [0] * _N)        # raw 32-bit counts, unsigned
    currents_a: list = field(default_factory=lambda: [0.0] * _N)
    fb_s: Optional[float] = None       # `now` of the last MOTOR_FB
    # DIGITAL_IN
    home: list = field(default_factory=lambda: [False] * _N)
    limit_lo: list = field(default_factory=lambda: [False] * _N)
    limit_hi: list = field(default_factory=lambda: [False] * _N)
    switches_s: Optional[float] = None
    # TRACKER_SENSE: photocell voltages (cell_az_a, cell_az_b, cell_el_a, cell_el_b) [V]
    cells_v: list = field(default_factory=lambda: [math.nan] * 4)
    sense_s: Optional[float] = None    # `now` of the last TRACKER_SENSE
    # TRACKER_POS: axis angles [az, el] (deg), limit switches [[cw, ccw] az, [cw, ccw] el], the 90 V bus
    tracker_angles_deg: list = field(default_factory=lambda: [math.nan, math.nan])
    tracker_limits: list = field(default_factory=lambda: [[False, False], [False, False]])
    motor_supply_v: float = math.nan
    pos_s: Optional[float] = None      # `now` of the last TRACKER_POS


def quantized_duty(duty: float, step: float) -> float:
    """`duty` saturated at -1..1 and rounded to a whole number of `step`s (half to even), as MOTOR_CMD's packing
    rounds it: the one implementation (`ControllerHal.send_motor_command`, the world's fast loop). ValueError or
    OverflowError for a duty that is not a number."""
    return round((-1.0 if duty < -1.0 else 1.0 if duty > 1.0 else duty) / step) * step


class ControllerHal(HalEndpoint):
    """Controller-side HAL: `poll(now)` for inputs, `send_outputs(...)` for outputs."""

    def __init__(self, bus: can.BusABC, codec: Optional[HalCodec] = None,
                 max_frames_per_poll: int = 256) -> None:
        super().__init__(bus, codec, max_frames_per_poll)
        self.sends_as("CONTROLLER")
        self.inputs = HalInputs()
        self.alive = 0           # value the next CTRL_OUTPUTS frame will carry
        self.motor_alive = 0     # value the next MOTOR_CMD frame will carry
        self.on_frame("PLANT_SYNC", self._on_sync, ("tick", "lockstep", "period_us"))
        self.on_frame("ANALOG_IN", self._on_analog, ("supply_v", "controller_temp_c"))
        self.on_frame("MOTOR_FB", self._on_feedback, _FB_ORDER)
        self.on_frame("DIGITAL_IN", self._on_switches, _SWITCH_ORDER)
        self._motor_cmd = self.codec.layout("MOTOR_CMD", _CMD_ORDER)
        self.duty_step = _duty_step(self.codec)
        self._flags_for: tuple[list, list] = ([], [])     # the enables and brakes `_flags` was made of
        self._flags: list = []
        self.tracker_alive = 0   # value the next TRACKER_CMD frame will carry
        self.tracker_both_refused = 0   # TRACKER_CMD requests with both relays of an axis closed (sent open)
        self.on_frame("TRACKER_SENSE", self._on_tracker_sense, _SENSE_ORDER)
        self.on_frame("TRACKER_POS", self._on_tracker_pos, _POS_ORDER)
        self._tracker_cmd = self.codec.layout("TRACKER_CMD", _TRACKER_CMD_ORDER)
        self._outputs = self.codec.layout("CTRL_OUTPUTS", ("outputs_enabled", "brake_all", "alive"))

    def _on_sync(self, values: list, now: float) -> None:
        self.inputs.tick = values[0]
        self.inputs.tick_s = now
        if values[2] > 0:
            self.inputs.tick_period_s = values[2] * 1e-6

    def _on_analog(self, values: list, now: float) -> None:
        self.inputs.supply_v, self.inputs.temp_c = values
        self.inputs.updated_s = now

    def _on_feedback(self, values: list, now: float) -> None:
        inputs = self.inputs
        inputs.counts = [c & 0xFFFF_FFFF for c in values[1:_N + 1]]
        inputs.currents_a = values[_N + 1:]
        inputs.fb_s = now

    def _on_switches(self, values: list, now: float) -> None:
        inputs = self.inputs
        inputs.home = [v == 1 for v in values[:_N]]
        inputs.limit_lo = [v == 1 for v in values[_N:2 * _N]]
        inputs.limit_hi = [v == 1 for v in values[2 * _N:3 * _N]]
        inputs.switches_s = now

    def _on_tracker_sense(self, values: list, now: float) -> None:
        self.inputs.cells_v = values
        self.inputs.sense_s = now

    def _on_tracker_pos(self, values: list, now: float) -> None:
        inputs = self.inputs
        inputs.tracker_angles_deg = values[:2]
        inputs.tracker_limits = [[values[2] == 1, values[3] == 1], [values[4] == 1, values[5] == 1]]
        inputs.motor_supply_v = values[6]
        inputs.pos_s = now

    def send_tracker_command(self, relays: list, brakes: list, sensor_power: bool, motor_power: bool,
                             duties: list) -> bool:
        """Send TRACKER_CMD: per axis (az, el) `relays` [cw, ccw], `brakes`, `duties` (0..1, saturated).

        The last line of the relay interlock: an axis asked for both relays gets neither (counted in
        `tracker_both_refused`). `tracker_alive` advances on every attempt; a failed send is counted
        in `bus_errors` (the plant expires the last command after 0.1 s: relays open, brakes on).
        """
        bits = []
        for cw, ccw in relays:
            if cw and ccw:
                self.tracker_both_refused += 1
                cw = ccw = False
            bits += [1 if cw else 0, 1 if ccw else 0]
        values = [bits[0], bits[1], bits[2], bits[3], 1 if brakes[0] else 0, 1 if brakes[1] else 0,
                  1 if sensor_power else 0, 1 if motor_power else 0,
                  *(0.0 if not d > 0.0 else 1.0 if d > 1.0 else d for d in duties), self.tracker_alive]
        self.tracker_alive = (self.tracker_alive + 1) & 0xFF
        return self.send_frame(self._tracker_cmd, values)

    def send_motor_command(self, duty: list, enable: list, brake: list) -> None:
        """Send MOTOR_CMD: per arm channel duty (-1..1, saturated), enable and brake; `motor_alive` advances.

        The values go as the bus carries them: each duty a whole number of the DBC's steps (`duty_step`, as the
        frame's packing rounds it), flags as 0/1. On a bus that carries values they go as they are, with no
        round trip through the layout (`FrameLayout.roundtrip` would give them back unchanged: they are what
        unpacking the frame gives; tests/test_hal.py holds every step of the range to that). A duty that is
        not a number takes the layout's checked path, which refuses it as before."""
        step = self.duty_step
        try:
            values = [quantized_duty(d, step) for d in duty]
        except (ValueError, OverflowError):
            self.send_frame(self._motor_cmd, [-1.0 if d < -1.0 else 1.0 if d > 1.0 else d for d in duty]
                            + [1 if e else 0 for e in enable] + [1 if b else 0 for b in brake] + [self.motor_alive])
            self.motor_alive = (self.motor_alive + 1) & 0xFF
            return
        values += self._motor_flags(enable, brake)
        values.append(self.motor_alive)
        self.send_carried(self._motor_cmd, values)
        self.motor_alive = (self.motor_alive + 1) & 0xFF

    def _motor_flags(self, enable: list, brake: list) -> list:
        """MOTOR_CMD's enables and brakes as 0/1, made again only when they change (seldom: enable, the safe state)."""
        if enable != self._flags_for[0] or brake != self._flags_for[1]:
            self._flags_for = (list(enable), list(brake))
            self._flags = [1 if e else 0 for e in enable] + [1 if b else 0 for b in brake]
        return self._flags

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
        self.send_frame(self._outputs, (1 if enabled else 0, 1 if brake else 0, self.alive))
        self.alive = (self.alive + 1) & 0xFF
