"""The plant's end of the HAL bus: a scheduler task that plays the I/O hardware.

Each `step(now)` (one plant tick):

1. reads every waiting frame: CTRL_OUTPUTS goes to `plant.commanded`, MOTOR_CMD to
   `plant.motor_commands`, each stamped `now` (both expire: 0.1 s and 20 ms by default,
   see `hil_sim.plant`);
2. integrates the plant over the time that passed since the last step (on a paced or
   lock-step clock exactly one period; on the wall clock whatever passed, clamped to
   `max_dt_s`, because a real-time run can stall; clamps are counted), with the commands
   as they stand at `now` (the safe state once expired);
3. sends MOTOR_FB (every step), DIGITAL_IN (when any switch changed since the last one
   sent, and at least every `digital_every_n` steps) and ANALOG_IN (every
   `analog_every_n` steps);
4. with `tracker=True`, every `tracker_every_n` steps (10 ms, the DBC's cycle of
   TRACKER_SENSE and TRACKER_POS), at tick `tracker_phase` modulo that (5: half-way between
   two ANALOG_IN ticks, so the slow work of the two does not pile into one tick): steps
   `plant.tracker` over the time gone since its last step with the TRACKER_CMD as it
   stands (`plant.tracker_commands`, read in 1. like the others; the safe state once
   expired, 0.1 s), then sends TRACKER_SENSE and TRACKER_POS;
5. sends PLANT_SYNC last, with the tick, the tick's length and whether the plant runs in
   lock-step (`lockstep`: it then integrates each tick only once the controller has
   answered the last one with CTRL_SYNC: `protocol.lockstep`, docs/hal_bus.md). Every
   frame of the tick is on the bus before it, so a controller that follows PLANT_SYNC
   has the whole tick in hand.

The tracker is off by default: an arm-only node sends exactly what it sent before and pays
nothing for the tracker. With it on (measured as below, median, best of 3 runs of 30,000
ticks): the tracker's ticks cost about 30 us more (its step 5 us, the two frames packed
and sent the rest), the others about 1 us more (reading TRACKER_CMD every 10th tick, the
bookkeeping): about 4 us a tick on average, a tenth of the arm node's 38 us.

The slow frames go out at the periods declared in the DBC (GenMsgCycleTime, 10 ms), not
every tick: at 1 kHz every classic 8-byte frame costs about 11-13 % of a 1 Mbit/s bus.
A switch change goes out in the tick it happens. Measured values saturate at the DBC's
declared ranges, as a real ADC would; encoder counts wrap at 32 bits, as a hardware
counter does (the controller unwraps by difference).

Cost. The simulation runs at 1 kHz in lock-step and aims at 20x real time: about 50 us of
wall time per simulated millisecond for plant, bus and controller together. So:

* cantools takes 12-15 us to encode a many-signal frame such as MOTOR_FB and 4-6 us to
  decode MOTOR_CMD. The frames this node sends, and MOTOR_CMD, are packed and unpacked by
  `FrameLayout` instead: the layout is read once from the same DBC declaration through
  cantools (start bit, length, sign, scale, offset, range), and a frame then costs 1-2.5
  us, byte for byte what `HalCodec` gives (tests/test_plant_node.py checks both ways).
  CTRL_OUTPUTS (every 10 ms) and anything unexpected go through `HalCodec.decode`.
* python-can's virtual bus deep-copies every frame; `_Frame` makes that copy 3 us cheaper.
* `dt_s` is rounded to the nanosecond, so that float noise in `now` does not change the
  step length: the motor bank recomputes its per-step constants (16 us, twice the step
  itself) whenever it changes. (In real-time runs the clock's jitter changes it every tick:
  about 31 us per arm step there, affordable at 1x.)
* Plain Python floats and lists per channel, no numpy per element; signal orders and
  ranges resolved once.

Measured (time.perf_counter around each `step`, a MOTOR_CMD to read every tick and a
CTRL_OUTPUTS every 10th, all six channels driven, the other end drained outside the
timing; 20,000 steps, best of 5 runs) on the shared 2-core development machine: median
48 us per step, p99 about 90 us. Of the median: ArmPlant.step 13 us (7.8 us when timed
alone, caches warm), the rest of Plant.step 8, reading the bus 9 (two `recv` calls, one
of which finds the queue empty, 2.3 us unpacking), sending PLANT_SYNC 6 and MOTOR_FB 10
(values 3, pack and send 7; python-can's virtual `send` alone is about 4-5 us a frame),
DIGITAL_IN and ANALOG_IN 1-2 on average.
"""
from __future__ import annotations

from typing import Optional

import can

from hil_sim.commands import N_CHANNELS
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
        n = N_CHANNELS
        self.on_frame("MOTOR_CMD", lambda v, now: plant.motor_commands.command(
            v[:n], v[n:2 * n], v[2 * n:3 * n], v[3 * n], now),
            (*(f"duty_{ch}" for ch in ARM_CHANNELS), *(f"enable_{ch}" for ch in ARM_CHANNELS),
             *(f"brake_{ch}" for ch in ARM_CHANNELS), "alive"))
        self.on_frame("CTRL_OUTPUTS", lambda v, now: plant.commanded.command(
            bool(v["outputs_enabled"]), bool(v["brake_all"]), int(v["alive"]), now))
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
            # The sun for the day now (pvlib's import and a day's table, about 1 s the first time in a
            # process), not in the middle of a real-time run when the photocells are first powered.
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
        self.dt_clamps = 0       # steps whose elapsed time exceeded max_dt_s (stalls)
        self._last_switches: Optional[tuple] = None
        self._digital_tick = 0   # tick of the last DIGITAL_IN sent

    def step(self, now: float) -> float:
        """Read commands, integrate, publish; return the next wake time."""
        self.poll(now)
        if self._last_now is None:
            dt_s = 0.0
        else:
            # To the nanosecond: float noise in `now` (0.0010000000000000009 s) must not change the
            # step length, or the motor bank recomputes its per-step constants (16 us).
            dt_s = round(now - self._last_now, 9)
            if dt_s < 0.0:
                dt_s = 0.0
            elif dt_s > self.max_dt_s:
                dt_s = self.max_dt_s
                self.dt_clamps += 1
        self._last_now = now
        plant = self.plant
        enabled, brake = plant.commanded.current(now)
        duty, enable, channel_brake = plant.motor_commands.current(now)
        plant.step(dt_s, enabled, brake, duty, enable, channel_brake)
        tick = self.tick
        wire_tick = tick & 0xFFFF_FFFF
        lo, hi = self._current_range_a
        self.send_frame(self._motor_fb, (
            wire_tick,
            *[((c + _HALF) & 0xFFFF_FFFF) - _HALF for c in plant.encoder_counts],
            *[lo if i < lo else hi if i > hi else i for i in plant.currents_a]))
        switches = plant.switches()
        if switches != self._last_switches or tick - self._digital_tick >= self.digital_every_n:
            if self.send_frame(self._digital, (*switches[0], *switches[1], *switches[2], wire_tick)):
                self._last_switches = switches
                self._digital_tick = tick
        if tick % self.analog_every_n == 0:
            self.send_frame(self._analog, (_saturate(plant.supply_v, self._supply_range_v),
                                      _saturate(plant.temp_c, self._temp_range_c)))
        if self.tracker:
            self._tracker_dt += dt_s
            if tick % self.tracker_every_n == self.tracker_phase:
                self._step_tracker(now)
        self.send_frame(self._sync, (wire_tick, int(self.lockstep), self._period_us))
        self.tick = tick + 1
        return now + self.period_s

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
