"""The solar tracker's task: `TrackerController`, stepped every 10 ms, with its parameters, its clock and
sun, the safe state, TRACKER_CMD and telemetry. The box is in box.py, the per-axis logic in logic.py.

Design: docs/tracker.md
"""
from __future__ import annotations

import math
from typing import Callable, Optional

from protocol.states import TrackerWarning

from firmware_py import ephemeris
from firmware_py.params import ParamSpec, ParamStore
from firmware_py.tracker.box import BRAKE, CW, ON, SENSOR, Box, BoxCommands, TempWatch
from firmware_py.tracker.logic import DRIVE, AxisState, RelayLogic, TrackerDrive

EPHEMERIS_PERIOD_S = 1.0         # sun position and rates recomputed this often, extrapolated in between

# Warning bits as plain ints, for the 10 ms path.
_SENSE_STALE, _POS_STALE, _NO_CLOCK = (int(TrackerWarning.SENSE_STALE), int(TrackerWarning.POS_STALE),
                                       int(TrackerWarning.NO_CLOCK))
_NOT_ENABLED, _NO_SUN, _SUN_DOWN = int(TrackerWarning.NOT_ENABLED), int(TrackerWarning.NO_SUN), int(TrackerWarning.SUN_DOWN)
_FF_FALLBACK = int(TrackerWarning.FF_FALLBACK)
_LIMIT = (int(TrackerWarning.LIMIT_AZ), int(TrackerWarning.LIMIT_EL))


def check_param(p: ParamStore, name: str, value: float) -> Optional[str]:
    """Why `name` = `value` would not fit the tracker's other parameters in `p`; None if it would."""
    if name == "trk_hyst_mv" and value > p["trk_deadband_mv"]:
        return f"the hysteresis may not exceed trk_deadband_mv ({p['trk_deadband_mv']:g} mV)"
    if name == "trk_deadband_mv" and value < p["trk_hyst_mv"]:
        return f"the deadband may not be below trk_hyst_mv ({p['trk_hyst_mv']:g} mV)"
    if name == "trk_ff" and value not in (0.0, 1.0):
        return "0 (relay logic) or 1 (feed-forward)"
    return None


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


class TrackerController(BoxCommands, RelayLogic):
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

    def _send(self, motor_power: bool) -> None:
        axes = self.axes
        self.hal.send_tracker_command([[ax.relay > 0, ax.relay < 0] for ax in axes], [ax.brake for ax in axes],
                                      self.box.sensor is ON, motor_power, [ax.duty for ax in axes])

    # ---- telemetry ----
    def telemetry_values(self, now: float) -> tuple:
        """TelemetryTracker's fields but uptime_ms, in the message's order (protocol/messages.py): a tuple, not a
        dict of 40 names made at every run."""
        box, inputs = self.box, self.hal.inputs
        sun = self.sun(now)
        error = self.pointing_error(now)
        utc = self.utc(now)
        rates = self.sun_rates()
        out = [int(utc) if utc is not None and 0 <= utc < 2 ** 32 else 0,
               int(box.main), int(box.sensor), self.ff_active, int(self.warnings), self.refusals & 0xFFFFFFFF,
               _finite(inputs.motor_supply_v), sun[0] if sun else 0.0, sun[1] if sun else 0.0]
        for k, ax in enumerate(self.axes):
            out += (int(box.mode[k]), int(box.direction[k]), int(box.speed[k]), box.dial_pct(k), ax.relay, ax.brake,
                    ax.duty, _finite(ax.diff_v), _finite(ax.sum_v), _finite(inputs.tracker_angles_deg[k]), rates[k],
                    error[k] if error else 0.0, ax.switchings & 0xFFFFFFFF, ax.chatter & 0xFFFFFFFF,
                    ax.reversals & 0xFFFFFFFF)
        return tuple(out)


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0
