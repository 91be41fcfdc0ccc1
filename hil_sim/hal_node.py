"""The plant's end of the HAL bus: a scheduler task that plays the I/O hardware.

Design: docs/hal_bus.md#the-plants-node
"""
from __future__ import annotations

from typing import Optional

import can

from hil_sim.plant import Plant
from hil_sim.tracker import TrackerCommand
from protocol.hal import HalCodec, HalEndpoint
from protocol.states import ARM_CHANNELS

_HALF = 1 << 31
TRACKER_CMD_SIGNALS = TrackerCommand._fields      # TRACKER_CMD's signals but `alive`, in the DBC's order


class PlantNode(HalEndpoint):
    """Runs a `Plant` on a python-can bus; `step(now)` is a scheduler task.

    `tick` is the index of the next step; `frames_sent` counts every frame sent and
    `sent_by_name` each kind; `dt_clamps` the steps cut to `max_dt_s`; `bad_frames`,
    `bus_errors` as in `HalEndpoint`. DIGITAL_IN and ANALOG_IN periods default to the
    DBC's declared cycle times. `tracker=True` adds the solar tracker (TRACKER_CMD in,
    TRACKER_SENSE and TRACKER_POS out every `tracker_period_s`, by default the DBC's 10 ms).
    """

    def __init__(self, bus: can.BusABC, plant: Plant, period_s: float = 0.001,
                 codec: Optional[HalCodec] = None, *, analog_period_s: Optional[float] = None,
                 digital_period_s: Optional[float] = None, max_dt_s: float = 0.1,
                 max_frames_per_step: int = 256, tracker: bool = False,
                 tracker_period_s: Optional[float] = None, lockstep: bool = False) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        if not max_dt_s >= period_s:
            raise ValueError(f"max_dt_s ({max_dt_s}) must be >= period_s ({period_s})")
        for name, value in (("analog_period_s", analog_period_s), ("digital_period_s", digital_period_s),
                            ("tracker_period_s", tracker_period_s)):
            if value is not None and not value > 0:
                raise ValueError(f"{name} must be > 0, got {value}")
        super().__init__(bus, codec, max_frames_per_step)
        self.sends_as("PLANT")
        codec = self.codec
        self.plant = plant
        self.period_s = period_s
        if analog_period_s is None:
            analog_period_s = codec.cycle_time_s("ANALOG_IN") or period_s
        if digital_period_s is None:
            digital_period_s = codec.cycle_time_s("DIGITAL_IN") or period_s
        self.analog_every_n = max(1, round(analog_period_s / period_s))
        self.digital_every_n = max(1, round(digital_period_s / period_s))
        self.max_dt_s = max_dt_s
        self._supply_range_v = codec.limits("ANALOG_IN", "supply_v")
        self._temp_range_c = codec.limits("ANALOG_IN", "controller_temp_c")
        self._current_range_a = codec.limits("MOTOR_FB", f"current_{ARM_CHANNELS[0]}")
        # MOTOR_CMD's values in the order its holder keeps them (and the arm plant's tick takes them)
        self.on_frame("MOTOR_CMD", plant.motor_commands.receive,
                      (*(f"duty_{ch}" for ch in ARM_CHANNELS), *(f"enable_{ch}" for ch in ARM_CHANNELS),
                       *(f"brake_{ch}" for ch in ARM_CHANNELS), "alive"))
        self.on_frame("CTRL_OUTPUTS", lambda v, now: plant.commanded.command(v[0], v[1], v[2], now),
                      ("outputs_enabled", "brake_all", "alive"))
        self._sync = codec.layout("PLANT_SYNC", ("tick", "lockstep", "period_us"))
        self.lockstep = bool(lockstep)
        self._period_us = round(period_s * 1e6)
        if not 1 <= self._period_us <= 65535:
            raise ValueError(f"period_s must be within 1 us .. 65.535 ms (PLANT_SYNC period_us), got {period_s}")
        self.sync_resends = 0
        self._motor_fb = codec.layout("MOTOR_FB", ("tick", *(f"count_{ch}" for ch in ARM_CHANNELS),
                                                   *(f"current_{ch}" for ch in ARM_CHANNELS)))
        self._digital = codec.layout("DIGITAL_IN", (*(f"home_{ch}" for ch in ARM_CHANNELS),
                                                    *(f"limit_lo_{ch}" for ch in ARM_CHANNELS),
                                                    *(f"limit_hi_{ch}" for ch in ARM_CHANNELS), "tick"))
        self._analog = codec.layout("ANALOG_IN", ("supply_v", "controller_temp_c"))
        self.tracker = bool(tracker)
        if tracker_period_s is None:
            tracker_period_s = codec.cycle_time_s("TRACKER_POS") or period_s
        self.tracker_every_n = max(1, round(tracker_period_s / period_s))
        self.tracker_phase = self.tracker_every_n // 2
        self._tracker_dt = 0.0
        if self.tracker:
            # The sun for the day now (a day's table, about 70 ms), not in the middle of a real-time run
            # when the photocells are first powered.
            plant.tracker.preload_sun()
            commands = plant.tracker_commands
            self.on_frame("TRACKER_CMD", lambda v, now: commands.command(v[:10], int(v[10]), now),
                          (*TRACKER_CMD_SIGNALS, "alive"))
            self._tracker_sense = codec.layout("TRACKER_SENSE", ("cell_az_a", "cell_az_b", "cell_el_a", "cell_el_b"))
            self._tracker_pos = codec.layout("TRACKER_POS", ("angle_az", "angle_el", "limit_cw_az", "limit_ccw_az",
                                                             "limit_cw_el", "limit_ccw_el", "motor_supply_v"))
            self._cell_range_v = codec.limits("TRACKER_SENSE", "cell_az_a")
            self._angle_range_deg = codec.limits("TRACKER_POS", "angle_az")
            self._motor_supply_range_v = codec.limits("TRACKER_POS", "motor_supply_v")
        self.tick = 0            # index of the next step; PLANT_SYNC carries it modulo 2**32
        self._last_now: Optional[float] = None
        self._rounded_steps: dict[float, float] = {}     # now - last now: the step length, to the nanosecond
        self.dt_clamps = 0       # steps whose elapsed time exceeded max_dt_s (stalls)
        self._last_switches: Optional[tuple] = None
        self._digital_tick = 0   # tick of the last DIGITAL_IN sent

    def step(self, now: float) -> float:
        """Read commands, integrate, publish; return the next wake time."""
        self.poll(now)
        dt_s = self._step_length(now)
        plant = self.plant
        enabled, brake = plant.commanded.current(now)
        plant.tick(dt_s, enabled, brake, plant.motor_commands.current_values(now))
        tick = self.tick
        wire_tick = tick & 0xFFFF_FFFF
        counts, currents, switches = plant.readouts()
        lo, hi = self._current_range_a
        self.send_frame(self._motor_fb, (wire_tick, *_wrapped_to_int32(counts), *_saturated(currents, lo, hi)))
        if self.tracker:
            self._tracker_dt += dt_s
        self.send_slow(tick, now, switches)
        self.send_frame(self._sync, (wire_tick, int(self.lockstep), self._period_us))
        self.tick = tick + 1
        return now + self.period_s

    def send_slow(self, tick: int, now: float, switches: tuple) -> None:
        """Tick `tick`'s frames but MOTOR_FB and PLANT_SYNC: DIGITAL_IN on a change of the `switches` or every
        `digital_every_n` ticks, ANALOG_IN every `analog_every_n`, the tracker's step and frames at its phase. (The
        world's fast loop sends them for the last tick of its ticks: host_tools/worlds/fast_loop.py.)"""
        if switches != self._last_switches or tick - self._digital_tick >= self.digital_every_n:
            if self.send_frame(self._digital, (*switches[0], *switches[1], *switches[2], tick & 0xFFFF_FFFF)):
                self._last_switches = switches
                self._digital_tick = tick
        if tick % self.analog_every_n == 0:
            plant = self.plant
            self.send_frame(self._analog, (_saturate(plant.supply_v, self._supply_range_v),
                                           _saturate(plant.temp_c, self._temp_range_c)))
        if self.tracker and tick % self.tracker_every_n == self.tracker_phase:
            self._step_tracker(now)

    def _step_length(self, now: float) -> float:
        """The time since the last step, to the nanosecond, within [0, max_dt_s] (0 at the first)."""
        last, self._last_now = self._last_now, now
        if last is None:
            return 0.0
        # To the nanosecond: float noise in `now` (0.0010000000000000009 s) must not change the step
        # length, or the motor bank recomputes its per-step constants (16 us). The noise takes a
        # handful of values: each is rounded once (round(x, 9) takes 0.3 us, a look-up 0.04).
        elapsed = now - last
        dt_s = self._rounded_steps.get(elapsed)
        if dt_s is None:
            if len(self._rounded_steps) >= 256:
                self._rounded_steps.clear()
            dt_s = self._rounded_steps[elapsed] = round(elapsed, 9)
        if dt_s < 0.0:
            return 0.0
        if dt_s > self.max_dt_s:
            self.dt_clamps += 1
            return self.max_dt_s
        if dt_s != dt_s:        # NaN: `Plant.tick` takes no step it could not take (as `Plant.step` says)
            raise ValueError(f"dt_s must be finite and >= 0, got {dt_s}")
        return dt_s

    def resend_sync(self) -> None:
        """Send the last PLANT_SYNC again (lock-step: the controller's answer is overdue)."""
        if self.tick:
            self.sync_resends += 1
            self.send_frame(self._sync, ((self.tick - 1) & 0xFFFF_FFFF, int(self.lockstep), self._period_us))

    def _step_tracker(self, now: float) -> None:
        """Step the tracker over the time since its last step; send TRACKER_SENSE and TRACKER_POS."""
        plant = self.plant
        tracker = plant.tracker
        # To the nanosecond, as dt_s: the sum of ten 1 ms steps must not drift in the last bits.
        tracker.step(round(self._tracker_dt, 9), plant.tracker_commands.current(now))
        self._tracker_dt = 0.0
        cells = self._cell_range_v
        self.send_frame(self._tracker_sense, [_saturate(v, cells) for v in tracker.cells_v])
        angles = self._angle_range_deg
        az, el = tracker.angles_measured_deg
        self.send_frame(self._tracker_pos, (_saturate(az, angles), _saturate(el, angles), *tracker.limits,
                                            _saturate(tracker.motor_supply_v, self._motor_supply_range_v)))


def _saturate(value: float, limits: tuple[float, float]) -> float:
    low, high = limits
    return low if value < low else high if value > high else value


def _wrapped_to_int32(counts: list[int]) -> list[int]:
    """The counts as MOTOR_FB's signed 32-bit fields carry them (wrapped around; as they are, mostly)."""
    if -_HALF <= min(counts) and max(counts) < _HALF:
        return counts
    return [((c + _HALF) & 0xFFFF_FFFF) - _HALF for c in counts]


def _saturated(values: list[float], low: float, high: float) -> list[float]:
    """Each value saturated at [low, high] (NaN as it is); the list itself if none needs it.

    min and max skip a NaN after the first item, and a NaN first fails the check: the whole list is
    then gone through, as it is when a value is outside."""
    if low <= min(values) and max(values) <= high:
        return values
    return [low if v < low else high if v > high else v for v in values]
