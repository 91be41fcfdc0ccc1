"""The solar tracker's controller: the report's control box, its relay logic, its interlocks, a sun-rate feed-forward.

The report ("SOLAR TRACKER" and its OPERATING INSTRUCTIONS, seed/000_54a4d1d9271955c2.txt)
describes two independent directional systems (azimuth, elevation), each a gear train, a
90 VDC motor on an adjustable speed controller, and a pair of photocells at a right angle
whose voltage difference says on which side the sun is; and a control box with a main
power switch, a sensor power switch, a control mode switch (manual / sensor), a direction
switch (CW / CCW), a speed switch (brake / on) and a speed dial. The box lives here, in the
controller; the operator works it over the link (`switch`, `dial`; protocol/messages.py),
a remote control box. The plant (relays, motors, cells) is across the HAL bus: this module
sends TRACKER_CMD and reads TRACKER_SENSE and TRACKER_POS (protocol/hal.dbc) through
`firmware_py/hal.py`, and nothing else.

One box, two axes. The report's figure of the box is not in the text; its block diagram
has two independent directional systems, and the sun's two rates differ sevenfold (at
Tucson in June up to 1.5 deg/min in azimuth, 0.21 deg/min in elevation), so one dial could
not suit both. So the mode, direction and speed switches and the dial are one per axis
(ASSUMED), addressed with an `axis` argument that defaults to both (`switch mode sensor`
sets both; `dial 40 az` one). Main power and sensor power are one each, as TRACKER_CMD
carries one of each. At boot: main off, sensor off, manual, CW, speed at brake, dial 0.

The speed dial is a potentiometer read by a 10-bit ADC in the report's box: a setting is
quantized to counts 0..1023 (`round(pct / 100 x 1023)`), and the dial reads, and the speed
controller gets, counts / 1023 (0.098 % a count). Telemetry reports the quantized value.

Per axis, each 10 ms (`step`, the TRACKER_CMD cycle):

* Drive is permitted only while the supervisor allows outputs (ENABLED), main power is on,
  the axis's speed switch is on and TRACKER_POS is fresh (its angles and limit switches
  known). Otherwise the relays open at once and the brake is applied (the speed switch's
  Brake position: the plant's dynamic brake). Motor power (TRACKER_CMD `motor_power`)
  follows the main switch while outputs are allowed; sensor power follows its switch always
  (the cells drive nothing, and the operator may watch them while idle).
* Manual mode: the direction switch picks the relay (CW or CCW), the dial sets the duty.
* Sensor mode, the report's relay logic: the photocell difference d = a - b (> 0: the sun is
  CW of the focal axis), low-passed (`trk_filter_s`, first order, on each new TRACKER_SENSE),
  closes the CW relay when d > +deadband and the CCW relay when d < -deadband
  (`trk_deadband_mv`); a closed relay opens when |d| falls below deadband - hysteresis
  (`trk_hyst_mv`); the duty is the dial's. Below `trk_sun_min_v` for the pair's sum (the
  cells' total: clouds, night, or the sun far outside their view) the axis holds, relays
  open: no direction to follow, so no hunting on noise. Sensor power off, or TRACKER_SENSE
  stale, in sensor mode: no drive.
* Relays: the two of an axis are never both closed (one relay state per axis, -1/0/+1; the
  HAL sends an impossible both-closed request as both open and counts it; the plant's relays
  are interlocked as well). Anti-chatter dwell: a relay closes only `trk_dwell_s` after the
  axis's previous relay change; opening never waits (a stop is never delayed), so a
  reversal is CW -> open -> (dwell) -> CCW. A relay does not close towards a closed travel
  limit switch, and opens when one closes (the plant's switches cut the drive too).
* Speed switch to brake, main power off, the supervisor's safe state: no drive at once.

Interlocks (the report: "ALWAYS keep the speed dial on low when starting operation. This
includes the transition from manual mode to the sensor mode and when switching direction";
instructions 1, 4, 5, 7 and the IMPORTANT note): starting (speed switch to on, or main power
on while a speed switch is on), changing the control mode, or changing direction is refused
with DIAL_NOT_LOW unless the dial of each axis it concerns is at or below
`trk_dial_low_pct`; a refused command changes nothing and counts in `refusals`. Putting a
switch where it already is changes nothing and is accepted; speed to brake, main or sensor
power off are always accepted. A position the switch does not have is refused with
SWITCH_POSITION, main or sensor power for one axis only with OUT_OF_RANGE.

The safe state (the supervisor's one path; also Disable) runs `safe`: relays open, brakes
on, motor power off, sent at once; and both speed switches go to brake (as a motor
starter's no-volt release), so every restart goes through the interlock again.

Counters (telemetry): `switchings` per axis, relay operations (each closing and each opening:
the figure a relay's rated life is counted in); `chatter`, closings that come within
`trk_chatter_s` of the axis's previous opening (in either direction: the relay flickering,
a symptom of a too-narrow deadband or hysteresis, or a dial set too high); `reversals`,
closings opposite to the axis's previous closing (hunting: the report's "fluctuating from
leading then lagging"); `refusals`, interlock refusals (DIAL_NOT_LOW).

Sun-rate feed-forward (beyond the report; parameter `trk_ff` = 1, in sensor mode). The
controller knows the UTC date-time from `SetClock` (POSIX seconds, carried on by its own
monotonic clock; never set: NO_CLOCK) and the site from parameters (`trk_lat_deg`,
`trk_lon_deg`, `trk_press_hpa`, `trk_air_temp_c`; Tucson by default), and computes the sun's
position and its azimuth and elevation rates once a second with its own ephemeris
(`firmware_py/ephemeris.py`, NOAA's algorithm), extrapolating linearly in between. Per axis
the commanded rate is

    w = w_sun + e / tau         (deg/s; tau = `trk_ff_tau_s`)

where e is the pointing error the photocells measure: for two cells at +-45 deg from the
focal axis (the report's right-angled pair) (a - b) / (a + b) = tan(error) for the direct
beam, so e = atan(d / s) (d, s: the filtered difference and sum; the diffuse light in s
makes e read about 5 % small, which a proportional correction does not mind); for azimuth
the error across the beam is divided by cos(the tracker's elevation) (floored at 0.1) to
give the azimuth angle to turn. e is low-passed again at tau / 30 (1 s by default): the
correction loop's bandwidth is 1 / tau, so this costs it about 2 deg of phase and takes the
cells' noise (1 mV rms a cell, about 0.1 deg of azimuth error a sample in the morning) out
of the relays' decisions. Without a sun in the cells (sum below `trk_sun_min_v`) the
correction is 0 and the feed-forward alone carries the axis through the cloud. The relays
follow the sign of w, with hysteresis on |w| (close above 0.02 deg/min, open below 0.007
deg/min; the sun's azimuth rate at Tucson in June is 0.11 deg/min at its slowest,
mid-morning and late afternoon, and the elevation rate passes through 0 at transit) and the
same dwell; the duty is the one that
gives |w| by the firmware's model of the drive (`TrackerDrive`, below), at the 90 V bus
voltage TRACKER_POS measures, capped by the dial (the dial stays the operator's speed
limit). So the axis runs at the sun's speed
instead of stopping and starting (it neither lags, the feed-forward supplies the rate, nor
hunts, the correction is proportional and small), and a model error only leaves a steady
error of (rate error) x tau. Sun below the horizon: the feed-forward holds the axis
(SUN_DOWN). `trk_ff` = 1 without a clock runs the relay logic and says so (FF_FALLBACK).
Why a model and not online learning of the duty per deg/s: the potentiometers are noisy
(about 0.02 deg a sample) against the 0.1-1.5 deg/min the axes move, so an estimate of the
axis rate needs tens of seconds of travel, and the proportional correction already removes
what the model gets wrong; measured in tests/test_tracker_control.py.

Staleness. The tracker's inputs are its own business, never the supervisor's: a missing or
stale TRACKER_SENSE (no frame for `trk_stale_s`, 0.1 s = ten periods) stops sensor-mode drive
(SENSE_STALE), a stale TRACKER_POS all drive (POS_STALE: the limit switches are unknown);
neither latches a fault nor touches the arm, and the tracker resumes when the frames return
(a closing still waits out its dwell). On a plant without the tracker the controller runs as
before: the sensor logic never drives, and TRACKER_CMD (safe unless the box is switched on)
goes out every 10 ms to nobody.

The control box's temperature (report: keep the controller between -10 C and 45 C; the
supervisor faults outside `temp_min_c`/`temp_max_c`): `TempWatch` raises a warning within
`temp_warn_c` of either limit (TEMP_LOW / TEMP_HIGH in telemetry, and one TemperatureWarning
event per crossing each way), cleared 0.5 C back inside (hysteresis, so noise on the
0.1 C reading does not flood the link with events).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional

from protocol.reasons import Reason
from protocol.states import (AZ, EL, SWITCH_POSITIONS, TRACKER_AXES, Switch, SwitchPosition, TempSide, TrackerAxis,
                             TrackerWarning)

from firmware_py import ephemeris
from firmware_py.params import ParamSpec, ParamStore
from protocol.units import DEG

ADC_COUNTS = 1023                # the dial's 10-bit ADC: 0..1023
EPHEMERIS_PERIOD_S = 1.0         # sun position and rates recomputed this often, extrapolated in between
FF_CLOSE_DEG_S = 0.02 / 60.0     # feed-forward: a relay closes above this commanded rate
FF_OPEN_DEG_S = 0.007 / 60.0     # ... and opens below this one
FF_ERROR_FILTER = 1.0 / 30.0     # feed-forward: the photocell error is low-passed at this x trk_ff_tau_s
TEMP_WARN_HYST_C = 0.5           # a temperature warning clears this far back inside its band
COS_EL_FLOOR = 0.1               # azimuth error = cross-beam error / max(cos(elevation), this)

# Warning bits as plain ints, for the 10 ms path.
_TEMP_LOW, _TEMP_HIGH = int(TrackerWarning.TEMP_LOW), int(TrackerWarning.TEMP_HIGH)
_SENSE_STALE, _POS_STALE, _NO_CLOCK = (int(TrackerWarning.SENSE_STALE), int(TrackerWarning.POS_STALE),
                                       int(TrackerWarning.NO_CLOCK))
_NOT_ENABLED, _NO_SUN, _SUN_DOWN = int(TrackerWarning.NOT_ENABLED), int(TrackerWarning.NO_SUN), int(TrackerWarning.SUN_DOWN)
_FF_FALLBACK = int(TrackerWarning.FF_FALLBACK)
_LIMIT = (int(TrackerWarning.LIMIT_AZ), int(TrackerWarning.LIMIT_EL))

ON, OFF, BRAKE = SwitchPosition.ON, SwitchPosition.OFF, SwitchPosition.BRAKE
MANUAL, SENSOR, CW, CCW = SwitchPosition.MANUAL, SwitchPosition.SENSOR, SwitchPosition.CW, SwitchPosition.CCW


@dataclass(frozen=True)
class TrackerDrive:
    """One axis's drive as the firmware knows it: a 90 VDC PM motor on a 20,000:1 train.

    The report gives the 90 V only; the rest is ASSUMED, the catalogue figures of the 1/8 hp,
    1750 rpm, 90 VDC motor class such a speed controller drives and its gear train (the numbers
    hil_sim/tracker.py documents for the plant; tests/test_tracker_control.py checks the two
    agree, as a controller's configuration must match the build it drives).
    """

    supply_v: float = 90.0
    r_ohm: float = 8.0
    k_v_s_rad: float = 0.43            # Kt = Ke
    coulomb_nm: float = 0.06           # friction at the motor shaft
    viscous_nm_s_rad: float = 2e-4
    gear_ratio: float = 20_000.0

    def speed_deg_s(self, duty: float, bus_v: Optional[float] = None) -> float:
        """Steady axis speed at `duty` (friction dead band included) [deg/s]."""
        k, r = self.k_v_s_rad, self.r_ohm
        v = duty * (bus_v if bus_v else self.supply_v) - r * self.coulomb_nm / k
        return max(0.0, v / (k + r * self.viscous_nm_s_rad / k)) / self.gear_ratio / DEG

    def duty_for(self, speed_deg_s: float, bus_v: Optional[float] = None) -> float:
        """The duty that gives |speed_deg_s| in steady state (the inverse of `speed_deg_s`), unclipped."""
        k, r = self.k_v_s_rad, self.r_ohm
        w = abs(speed_deg_s) * DEG * self.gear_ratio
        return (w * (k + r * self.viscous_nm_s_rad / k) + r * self.coulomb_nm / k) / (bus_v if bus_v else self.supply_v)

    @property
    def top_speed_deg_s(self) -> float:
        return self.speed_deg_s(1.0)


DRIVE = TrackerDrive()


def parameter_table() -> list[ParamSpec]:
    """The tracker's parameters (the controller adds them to its table)."""
    return [
        ParamSpec("trk_deadband_mv", 2.0, 0, 100, "mV",
                  "sensor mode: a photocell difference beyond +-this closes a relay (about 0.17 deg of "
                  "elevation error at noon)"),
        ParamSpec("trk_hyst_mv", 1.5, 0, 100, "mV",
                  "hysteresis: a closed relay opens when |difference| < deadband - this (at most trk_deadband_mv)"),
        ParamSpec("trk_filter_s", 0.2, 0, 5, "s", "time constant of the photocell low-pass (0: none)"),
        ParamSpec("trk_dwell_s", 0.5, 0, 10, "s",
                  "anti-chatter: a relay closes only this long after its axis's last relay change "
                  "(opening never waits)"),
        ParamSpec("trk_chatter_s", 2.0, 0, 60, "s",
                  "a closing this soon after the axis's last opening counts as chatter"),
        ParamSpec("trk_dial_low_pct", 5.0, 0, 100, "%",
                  "interlocks: the dial is low at or below this (starting, mode and direction changes need it)"),
        ParamSpec("trk_stale_s", 0.1, 0.02, 10, "s",
                  "TRACKER_SENSE / TRACKER_POS older than this are stale: no sensor drive / no drive (no fault)"),
        ParamSpec("trk_sun_min_v", 0.1, 0, 10, "V",
                  "a photocell pair summing below this sees no sun: the relay logic holds, the feed-forward "
                  "goes on uncorrected"),
        ParamSpec("trk_ff", 0, 0, 1, "", "1: sun-rate feed-forward in sensor mode (needs SetClock); 0: the report's "
                  "relay logic"),
        ParamSpec("trk_ff_tau_s", 30.0, 0.5, 600, "s",
                  "feed-forward: photocell correction rate = pointing error / this"),
        ParamSpec("trk_lat_deg", 32.2319, -90, 90, "deg", "site latitude (default: the University of Arizona, Tucson)"),
        ParamSpec("trk_lon_deg", -110.9501, -180, 180, "deg", "site longitude, east positive"),
        ParamSpec("trk_press_hpa", 928.8, 0, 1100, "hPa",
                  "air pressure for refraction (standard atmosphere at Tucson's 728 m; 0: no refraction)"),
        ParamSpec("trk_air_temp_c", 12.0, -50, 60, "degC", "air temperature for refraction"),
    ]


def quantize_dial(pct: float) -> int:
    """ADC counts (0..1023) of a dial setting in percent (0..100), as the box's 10-bit ADC reads it."""
    return max(0, min(ADC_COUNTS, round(pct / 100.0 * ADC_COUNTS)))


@dataclass
class Box:
    """The control box's switches and dials (per axis where it has one per axis)."""

    main: SwitchPosition = OFF
    sensor: SwitchPosition = OFF
    mode: list = field(default_factory=lambda: [MANUAL, MANUAL])
    direction: list = field(default_factory=lambda: [CW, CW])
    speed: list = field(default_factory=lambda: [BRAKE, BRAKE])
    dial_counts: list = field(default_factory=lambda: [0, 0])

    def dial_pct(self, k: int) -> float:
        return self.dial_counts[k] * 100.0 / ADC_COUNTS

    def dial_duty(self, k: int) -> float:
        return self.dial_counts[k] / ADC_COUNTS


@dataclass
class AxisState:
    """One axis: its relay (-1 CCW, 0 open, +1 CW), the logic's wish, filters, counters."""

    relay: int = 0
    want: int = 0                      # the relay logic's (or feed-forward's) hysteresis state
    changed_s: Optional[float] = None  # `now` of the last relay change
    opened_s: Optional[float] = None   # `now` of the last opening
    last_closed: int = 0               # direction of the last closing
    duty: float = 0.0                  # as sent
    brake: bool = True                 # as sent
    diff_v: float = math.nan           # filtered photocell difference a - b
    sum_v: float = math.nan            # filtered a + b
    rate_cmd_dps: float = 0.0          # feed-forward: the commanded rate
    error_deg: float = math.nan        # feed-forward: the photocells' pointing error, low-passed
    error_s: Optional[float] = None    # `now` of its last update
    switchings: int = 0
    chatter: int = 0
    reversals: int = 0


class TempWatch:
    """Warnings near the edges of the control box's allowed temperature range, once per crossing."""

    def __init__(self) -> None:
        self.active = {TempSide.COLD: False, TempSide.HOT: False}

    @property
    def flags(self) -> TrackerWarning:
        return TrackerWarning(self.bits)

    @property
    def bits(self) -> int:
        """`flags` as a plain int."""
        return (_TEMP_LOW if self.active[TempSide.COLD] else 0) | (_TEMP_HIGH if self.active[TempSide.HOT] else 0)

    def update(self, temp_c: float, min_c: float, max_c: float, margin_c: float
               ) -> list[tuple[TempSide, bool, float]]:
        """The crossings at this reading: (side, now active, the fault limit it is about). NaN: none."""
        if not math.isfinite(temp_c):
            return []
        crossings = []
        for side, limit, near, back in (
                (TempSide.COLD, min_c, temp_c <= min_c + margin_c, temp_c > min_c + margin_c + TEMP_WARN_HYST_C),
                (TempSide.HOT, max_c, temp_c >= max_c - margin_c, temp_c < max_c - margin_c - TEMP_WARN_HYST_C)):
            if not self.active[side] and near:
                self.active[side] = True
                crossings.append((side, True, limit))
            elif self.active[side] and back:
                self.active[side] = False
                crossings.append((side, False, limit))
        return crossings


class TrackerController:
    """The control box and both axes; `step(now)` every TRACKER_CMD cycle (10 ms).

    `hal` needs `inputs` (cells_v, sense_s, tracker_angles_deg, tracker_limits, motor_supply_v,
    pos_s) and `send_tracker_command(relays, brakes, sensor_power, motor_power, duties)`;
    `allowed()` says whether the supervisor allows outputs.
    """

    def __init__(self, hal, params: ParamStore, period_s: float = 0.01,
                 allowed: Callable[[], bool] = lambda: False, drive: TrackerDrive = DRIVE) -> None:
        self.hal = hal
        self.params = params
        self.period_s = period_s
        self._allowed = allowed
        self.drive = drive
        self.box = Box()
        self.axes = [AxisState(), AxisState()]
        self.refusals = 0
        self.temp_watch = TempWatch()
        self.warnings = TrackerWarning.NONE
        self.ff_active = False
        self._clock: Optional[tuple[float, float]] = None          # (UTC POSIX seconds, `now`) when set
        self._eph: Optional[tuple[float, float, float, float, float]] = None  # now, az, el, rate az, rate el
        self._sense_seen: Optional[float] = None
        self._last_now = 0.0

    # ---- parameters ----
    def check_param(self, name: str, value: float) -> Optional[str]:
        p = self.params
        if name == "trk_hyst_mv" and value > p["trk_deadband_mv"]:
            return f"the hysteresis may not exceed trk_deadband_mv ({p['trk_deadband_mv']:g} mV)"
        if name == "trk_deadband_mv" and value < p["trk_hyst_mv"]:
            return f"the deadband may not be below trk_hyst_mv ({p['trk_hyst_mv']:g} mV)"
        if name == "trk_ff" and value not in (0.0, 1.0):
            return "0 (relay logic) or 1 (feed-forward)"
        return None

    def param_changed(self, name: str, value: float) -> None:
        if name in ("trk_lat_deg", "trk_lon_deg", "trk_press_hpa", "trk_air_temp_c"):
            self._eph = None               # the sun again at the next step

    # ---- the clock and the sun ----
    def set_clock(self, utc_s: float, now: float) -> None:
        """The UTC date-time (POSIX seconds) at `now`; carried on by the controller's clock."""
        self._clock = (utc_s, now)
        self._eph = None

    @property
    def in_use(self) -> bool:
        """Main or sensor power on: TelemetryTracker goes out only then (the link's bandwidth is the arm's
        otherwise: at 9600 baud one TelemetryTracker frame takes 0.17 s of the line)."""
        return self.box.main is ON or self.box.sensor is ON

    @property
    def clock_set(self) -> bool:
        return self._clock is not None

    def utc(self, now: float) -> Optional[float]:
        """UTC POSIX seconds at `now`, or None before SetClock."""
        if self._clock is None:
            return None
        utc_s, at = self._clock
        return utc_s + (now - at)

    def _update_ephemeris(self, now: float) -> None:
        if self._clock is None:
            self._eph = None
            return
        if self._eph is not None and now - self._eph[0] < EPHEMERIS_PERIOD_S:
            return
        p = self.params
        utc = self.utc(now)
        site = (p["trk_lat_deg"], p["trk_lon_deg"], p["trk_press_hpa"], p["trk_air_temp_c"])
        pos = ephemeris.sun_position(utc, *site)
        rate_az, rate_el = ephemeris.sun_rates(utc, *site)
        self._eph = (now, pos.azimuth_deg, pos.elevation_deg, rate_az, rate_el)

    def sun(self, now: float) -> Optional[tuple[float, float]]:
        """(azimuth, elevation) of the sun at `now` [deg], or None without a clock."""
        if self._eph is None:
            return None
        at, az, el, rate_az, rate_el = self._eph
        return (az + rate_az * (now - at)) % 360.0, el + rate_el * (now - at)

    def sun_rates(self) -> tuple[float, float]:
        """(azimuth, elevation) rate of the sun [deg/s]; zeros without a clock."""
        return (self._eph[3], self._eph[4]) if self._eph is not None else (0.0, 0.0)

    def pointing_error(self, now: float) -> Optional[tuple[float, float]]:
        """Sun (ephemeris) - tracker (potentiometers), azimuth wrapped to +-180 [deg]; None if either is unknown."""
        sun = self.sun(now)
        angles = self.hal.inputs.tracker_angles_deg
        if sun is None or not (math.isfinite(angles[0]) and math.isfinite(angles[1])):
            return None
        return ephemeris.wrap180(sun[0] - angles[0]), sun[1] - angles[1]

    # ---- the box (commands) ----
    def _dial_low(self, k: int) -> bool:
        return self.box.dial_pct(k) <= self.params["trk_dial_low_pct"] + 1e-9

    def _refuse_high(self, ks: list[int], what: str) -> tuple[Reason, str]:
        self.refusals += 1
        dials = ", ".join(f"{TRACKER_AXES[k]} {self.box.dial_pct(k):.1f} %" for k in ks)
        return Reason.DIAL_NOT_LOW, (f"{what} needs the dial low (<= {self.params['trk_dial_low_pct']:g} %): "
                                     f"dial {dials}")

    def switch(self, switch: int, position: int, axis: int = TrackerAxis.BOTH) -> tuple[Reason, str]:
        """Set one of the box's switches; refused (nothing changes) by the interlocks or a bad position."""
        try:
            sw, pos, axis = Switch(switch), SwitchPosition(position), TrackerAxis(axis)
        except ValueError:
            return Reason.OUT_OF_RANGE, f"no switch {switch}, position {position} or axis {axis}"
        if pos not in SWITCH_POSITIONS[sw]:
            allowed = " or ".join(p.name.lower() for p in SWITCH_POSITIONS[sw])
            return Reason.SWITCH_POSITION, f"the {sw.name.lower()} switch is {allowed}, not {pos.name.lower()}"
        box = self.box
        if sw in (Switch.MAIN, Switch.SENSOR):
            if axis is not TrackerAxis.BOTH:
                return Reason.OUT_OF_RANGE, f"{sw.name.lower()} power is one switch for both axes"
            if sw is Switch.MAIN:
                if pos is ON and box.main is not ON:
                    high = [k for k in (AZ, EL) if box.speed[k] is ON and not self._dial_low(k)]
                    if high:
                        return self._refuse_high(high, "main power on with the speed switch on")
                box.main = pos
            else:
                box.sensor = pos
            return Reason.OK, ""
        ks = [AZ, EL] if axis is TrackerAxis.BOTH else [int(axis)]
        setting = {Switch.MODE: box.mode, Switch.DIRECTION: box.direction, Switch.SPEED: box.speed}[sw]
        changing = [k for k in ks if setting[k] is not pos]
        if sw is not Switch.SPEED or pos is ON:          # speed to brake is always allowed
            high = [k for k in changing if not self._dial_low(k)]
            if high:
                what = {Switch.MODE: "changing mode", Switch.DIRECTION: "changing direction",
                        Switch.SPEED: "starting (speed switch on)"}[sw]
                return self._refuse_high(high, what)
        for k in ks:
            setting[k] = pos
        return Reason.OK, ""

    def dial(self, pct: float, axis: int = TrackerAxis.BOTH) -> tuple[Reason, str]:
        """Turn the speed dial (0..100 %); read as a 10-bit ADC would read it. Never interlocked."""
        if not (isinstance(pct, (int, float)) and math.isfinite(pct) and 0.0 <= pct <= 100.0):
            return Reason.OUT_OF_RANGE, f"dial {pct!r} outside 0..100 %"
        try:
            axis = TrackerAxis(axis)
        except ValueError:
            return Reason.OUT_OF_RANGE, f"no axis {axis}"
        counts = quantize_dial(pct)
        for k in ([AZ, EL] if axis is TrackerAxis.BOTH else [int(axis)]):
            self.box.dial_counts[k] = counts
        return Reason.OK, ""

    # ---- the safe state ----
    def safe(self) -> None:
        """The safe-state hook: relays open, brakes on, motor power off, sent at once; speed switches to brake."""
        now = self._last_now
        for k, ax in enumerate(self.axes):
            ax.want = 0
            if ax.relay:
                self._set_relay(ax, 0, now)
            ax.duty, ax.brake = 0.0, True
        self.box.speed = [BRAKE, BRAKE]
        self.ff_active = False
        self._send(motor_power=False)

    # ---- the task ----
    def step(self, now: float) -> float:
        self._last_now = now
        p, inputs, box = self.params, self.hal.inputs, self.box
        stale_s = p["trk_stale_s"]
        sense_ok = inputs.sense_s is not None and now - inputs.sense_s <= stale_s
        pos_ok = inputs.pos_s is not None and now - inputs.pos_s <= stale_s
        self._filter(inputs.sense_s, inputs.cells_v, stale_s)
        self._update_ephemeris(now)
        allowed = self._allowed()
        # Warning bits as a plain int on this 10 ms path (IntFlag arithmetic costs a microsecond an operation).
        warn = self.temp_watch.bits
        if not sense_ok:
            warn |= _SENSE_STALE
        if not pos_ok:
            warn |= _POS_STALE
        if self._clock is None:
            warn |= _NO_CLOCK
        ff_wanted = p["trk_ff"] >= 0.5
        sun = self.sun(now)
        sun_min = p["trk_sun_min_v"]
        dwell_s, chatter_s = p["trk_dwell_s"], p["trk_chatter_s"]
        main_on, sensor_on = box.main is ON, box.sensor is ON
        ff_active = False
        for k, ax in enumerate(self.axes):
            speed_on = box.speed[k] is ON
            permitted = allowed and main_on and speed_on and pos_ok
            if main_on and speed_on and not allowed:
                warn |= _NOT_ENABLED
            sensor_mode = box.mode[k] is SENSOR
            if sensor_mode and sensor_on and sense_ok and not ax.sum_v >= sun_min:
                warn |= _NO_SUN
            target, duty = 0, 0.0
            if not (permitted and sensor_mode and ff_wanted):
                ax.error_deg, ax.error_s = math.nan, None      # the feed-forward starts afresh
            if not permitted:
                ax.want = 0
            elif not sensor_mode:
                ax.want = 0
                target, duty = (1 if box.direction[k] is CW else -1), box.dial_duty(k)
            elif not sensor_on or not sense_ok:
                ax.want = 0
            elif ff_wanted and sun is not None:
                if sun[1] < 0.0:
                    warn |= _SUN_DOWN
                    ax.want = 0
                else:
                    ff_active = True
                    target, duty = self._feedforward(k, ax, sun_min, now)
            else:
                if ff_wanted:
                    warn |= _FF_FALLBACK
                target, duty = self._relay_logic(k, ax, sun_min)
            if inputs.pos_s is not None:
                limit_cw, limit_ccw = inputs.tracker_limits[k]
                if limit_cw or limit_ccw:
                    warn |= _LIMIT[k]
                if (target > 0 and limit_cw) or (target < 0 and limit_ccw):
                    target = 0
            if target != ax.relay:
                self._apply(ax, target, now, dwell_s, chatter_s)
            ax.duty = duty if ax.relay else 0.0
            ax.brake = not permitted
        self.ff_active = ff_active
        if warn != self.warnings:
            self.warnings = TrackerWarning(warn)
        self._send(motor_power=allowed and main_on)
        return now + self.period_s

    def _filter(self, sense_s: Optional[float], cells: list, stale_s: float) -> None:
        """Low-pass each pair's difference and sum, once per new TRACKER_SENSE."""
        if sense_s is None or sense_s == self._sense_seen:
            return
        previous, self._sense_seen = self._sense_seen, sense_s
        tau = self.params["trk_filter_s"]
        dt = None if previous is None else sense_s - previous
        alpha = 1.0 if dt is None or dt > stale_s or tau <= 0.0 else -math.expm1(-dt / tau)
        for k, ax in enumerate(self.axes):
            a, b = cells[2 * k], cells[2 * k + 1]
            if not math.isfinite(ax.diff_v) or alpha >= 1.0:
                ax.diff_v, ax.sum_v = a - b, a + b
            else:
                ax.diff_v += alpha * (a - b - ax.diff_v)
                ax.sum_v += alpha * (a + b - ax.sum_v)

    def _relay_logic(self, k: int, ax: AxisState, sun_min: float) -> tuple[int, float]:
        """The report's sensor mode: the photocell difference picks the relay, with deadband and hysteresis."""
        if not ax.sum_v >= sun_min:
            ax.want = 0
            return 0, 0.0
        p = self.params
        d = ax.diff_v * 1000.0
        close = p["trk_deadband_mv"]
        hold = close - p["trk_hyst_mv"]
        w = ax.want
        if w == 0:
            w = 1 if d > close else -1 if d < -close else 0
        elif w > 0:
            w = -1 if d < -close else 0 if d < hold else 1
        else:
            w = 1 if d > close else 0 if d > -hold else -1
        ax.want = w
        return w, self.box.dial_duty(k)

    def _feedforward(self, k: int, ax: AxisState, sun_min: float, now: float) -> tuple[int, float]:
        """Sun rate + photocell correction; the relays follow its sign, the duty its size (capped by the dial)."""
        rate = self.sun_rates()[k]
        tau = self.params["trk_ff_tau_s"]
        correction = 0.0
        if ax.sum_v >= sun_min and ax.sum_v > 0.0:
            error = math.atan(ax.diff_v / ax.sum_v) / DEG
            if k == AZ:
                el = self.hal.inputs.tracker_angles_deg[EL]
                error /= max(math.cos(el * DEG), COS_EL_FLOOR) if math.isfinite(el) else 1.0
            if ax.error_s is None or not math.isfinite(ax.error_deg):
                ax.error_deg = error
            else:
                ax.error_deg += -math.expm1(-(now - ax.error_s) / (FF_ERROR_FILTER * tau)) * (error - ax.error_deg)
            ax.error_s = now
            correction = ax.error_deg / tau
        else:
            ax.error_deg, ax.error_s = math.nan, None
        cmd = rate + correction
        ax.rate_cmd_dps = cmd
        size, sign = abs(cmd), (1 if cmd > 0 else -1)
        w = ax.want
        if w == 0:
            w = sign if size > FF_CLOSE_DEG_S else 0
        elif w != sign or size < FF_OPEN_DEG_S:
            w = 0
        ax.want = w
        bus_v = self.hal.inputs.motor_supply_v
        bus_v = bus_v if math.isfinite(bus_v) and bus_v > 0.5 * self.drive.supply_v else None
        return w, min(self.drive.duty_for(size, bus_v), self.box.dial_duty(k))

    def _apply(self, ax: AxisState, target: int, now: float, dwell_s: float, chatter_s: float) -> None:
        """Move the relay towards `target` (not where it is): open at once; close only after the dwell;
        reverse through open."""
        if ax.relay != 0:
            self._set_relay(ax, 0, now)
            return
        if ax.changed_s is not None and now - ax.changed_s < dwell_s - 1e-9:
            return
        if ax.opened_s is not None and now - ax.opened_s < chatter_s:
            ax.chatter += 1
        if ax.last_closed and target != ax.last_closed:
            ax.reversals += 1
        ax.last_closed = target
        self._set_relay(ax, target, now)

    def _set_relay(self, ax: AxisState, relay: int, now: float) -> None:
        if relay == 0:
            ax.opened_s = now
        ax.relay = relay
        ax.changed_s = now
        ax.switchings += 1

    def _send(self, motor_power: bool) -> None:
        axes = self.axes
        self.hal.send_tracker_command([[ax.relay > 0, ax.relay < 0] for ax in axes], [ax.brake for ax in axes],
                                      self.box.sensor is ON, motor_power, [ax.duty for ax in axes])

    # ---- telemetry ----
    def telemetry_fields(self, now: float) -> dict:
        """TelemetryTracker's fields but uptime_ms (protocol/messages.py)."""
        box, inputs = self.box, self.hal.inputs
        sun = self.sun(now)
        error = self.pointing_error(now)
        utc = self.utc(now)
        rates = self.sun_rates()
        out = {
            "utc_s": int(utc) if utc is not None and 0 <= utc < 2 ** 32 else 0,
            "main": int(box.main), "sensor": int(box.sensor), "ff_active": self.ff_active,
            "warnings": int(self.warnings), "refusals": self.refusals & 0xFFFFFFFF,
            "motor_supply_v": _finite(inputs.motor_supply_v),
            "sun_az": sun[0] if sun else 0.0, "sun_el": sun[1] if sun else 0.0,
        }
        for k, (name, ax) in enumerate(zip(TRACKER_AXES, self.axes)):
            out.update({
                f"mode_{name}": int(box.mode[k]), f"direction_{name}": int(box.direction[k]),
                f"speed_{name}": int(box.speed[k]), f"dial_{name}": box.dial_pct(k),
                f"relay_{name}": ax.relay, f"brake_{name}": ax.brake, f"duty_{name}": ax.duty,
                f"cell_diff_{name}": _finite(ax.diff_v), f"cell_sum_{name}": _finite(ax.sum_v),
                f"angle_{name}": _finite(inputs.tracker_angles_deg[k]),
                f"sun_rate_{name}": rates[k], f"error_{name}": error[k] if error else 0.0,
                f"switchings_{name}": ax.switchings & 0xFFFFFFFF, f"chatter_{name}": ax.chatter & 0xFFFFFFFF,
                f"reversals_{name}": ax.reversals & 0xFFFFFFFF,
            })
        return out


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0
