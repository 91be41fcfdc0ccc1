"""`aspod tracker-day`: the solar tracker through a simulated day at the site, faster than real time.

What runs. The tracker's firmware (`firmware_py.tracker.task.TrackerController`: the control box,
the report's relay logic or the sun-rate feed-forward, unchanged) and its plant
(`hil_sim.tracker.TrackerPlant`: the sun, clouds, photocells, relays, 90 VDC motors and
gear trains), both every 10 ms (TRACKER_CMD's cycle), from when the sun climbs above
`MIN_ELEVATION_DEG` until it sinks below it again (or between `--from` and `--to`).

How they meet. Not through CAN frames: a day is 5 million steps, and packing, sending,
receiving and unpacking three frames a step would triple its cost. `DayHal` hands each
value across quantized and saturated exactly as its TRACKER_SENSE, TRACKER_POS or
TRACKER_CMD signal encodes it (resolution and range from the DBC; tests check it against
the codec byte for byte), one step late as on the bus. Over the real bus the same
firmware and plant run in `aspod sim` and in tests/test_tracker_control.py.

How the day starts. The report's operating instructions, from their note "If the solar
tracker is already aligned with the sun, skip to step 7": the plant starts pointing at
the sun, and the run operates the box as steps 7-10 do, through the controller's own
box commands (so its interlocks apply): speed switch at brake, dial low, mode sensor,
sensor power on; main power on and speed switch on (the start, with the dial low); then
the dial to the setting under test. `--mode feedforward` also sets the controller's clock
from the plant's and its parameter `trk_ff` to 1.

What is measured (truth from the plant, once a simulated second):

* pointing error: the angle between the cutter's focal axis and the sun (always >= 0);
  `rms_pointing_error_deg`, `max_pointing_error_deg`, `p95_pointing_error_deg`;
* lag: the pointing error's component along the sun's path across the sky, positive when
  the tracker is behind the sun (`mean_lag_deg`), and `lead_fraction`, the share of the
  samples where it is ahead of the sun: a tracker that lags has a clearly positive mean
  lag and a lead fraction near 0; one that hunts swings to both sides;
* `relay_switchings` (every relay closing and opening of both axes, the controller's
  counters) and per axis `switchings`, `reversals` (closings opposite to the previous
  one: hunting), `chatter`, `motor_on_fraction` (share of the steps a relay was closed:
  "the motor is running smoothly" near the right dial) and `rms_error_deg`.

A day at 10 ms steps takes about a minute of wall time here (`wall_time_s`, and
`speed_x_real_time` in the JSON).
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from datetime import date, datetime, time as clock_time, timedelta
from typing import BinaryIO, Optional, Sequence, TextIO, Union

import numpy as np

from firmware_py.tracker import task as firmware
from firmware_py.hal import HalInputs
from firmware_py.params import ParamStore
from hil_sim.sun import TUCSON, Site, as_clouds, solar_position
from hil_sim.tracker import TRACKER_PARAMS, TrackerCommand, TrackerParams, TrackerPlant, wrap180
from protocol.errors import shown
from protocol.hal import HalCodec
from protocol.reasons import Reason
from protocol.states import Switch, SwitchPosition, TrackerAxis
from protocol.units import DEG
from timebase import RealClock

from host_tools.outputs import Output
from host_tools.progress import Progress

MODES = ("relay", "feedforward")
MIN_ELEVATION_DEG = 5.0      # the day's window: the sun above this (the photocells see a usable beam)
STEP_S = 0.01                # the tracker's cycle (TRACKER_CMD, TRACKER_SENSE, TRACKER_POS: 10 ms)
SAMPLE_EVERY = 100           # steps between samples of the truth: once a simulated second
FIRST_DATE, LAST_DATE = date(2000, 1, 1), date(2099, 12, 31)    # the controller's clock (SetClock)


# ---- the HAL between the two, as the DBC quantizes it ------------------------------------------------------

class _Signals:
    """Quantize and saturate values as one frame's signals encode them (`FrameLayout` order)."""

    def __init__(self, codec: HalCodec, frame: str, names: Sequence[str]) -> None:
        message = codec.database.get_message_by_name(frame)
        self.spec = []
        for name in names:
            s = message.get_signal_by_name(name)
            self.spec.append((s.scale, 1.0 / s.scale, s.offset, s.minimum, s.maximum))

    def __call__(self, values: Sequence[float]) -> list[float]:
        return [round(((lo if v < lo else hi if v > hi else v) - offset) * inv) * scale + offset
                for v, (scale, inv, offset, lo, hi) in zip(values, self.spec)]


class DayHal:
    """What the tracker's firmware sees of the HAL (`inputs`, `send_tracker_command`), coupled to a plant directly.

    `sample(plant, now)` puts the plant's sensors into `inputs` as TRACKER_SENSE and
    TRACKER_POS would carry them; `send_tracker_command` keeps the command as TRACKER_CMD
    would carry it (`command`, a `TrackerCommand`), with `ControllerHal`'s last-line relay
    interlock (an axis asked for both relays gets neither, counted in `both_refused`).
    """

    def __init__(self, codec: Optional[HalCodec] = None) -> None:
        codec = codec or HalCodec()
        self.inputs = HalInputs()
        self.command = TrackerCommand()
        self.both_refused = 0
        self._cells = _Signals(codec, "TRACKER_SENSE", ("cell_az_a", "cell_az_b", "cell_el_a", "cell_el_b"))
        self._angles = _Signals(codec, "TRACKER_POS", ("angle_az", "angle_el", "motor_supply_v"))
        self._duties = _Signals(codec, "TRACKER_CMD", ("duty_az", "duty_el"))

    def sample(self, plant: TrackerPlant, now: float) -> None:
        inputs = self.inputs
        inputs.cells_v = self._cells(plant.cells_v)
        inputs.sense_s = now
        az, el = plant.angles_measured_deg
        az, el, supply = self._angles((az, el, plant.motor_supply_v))
        limits = plant.limits
        inputs.tracker_angles_deg = [az, el]
        inputs.tracker_limits = [[limits[0], limits[1]], [limits[2], limits[3]]]
        inputs.motor_supply_v = supply
        inputs.pos_s = now

    def send_tracker_command(self, relays: list, brakes: list, sensor_power: bool, motor_power: bool,
                             duties: list) -> bool:
        bits = []
        for cw, ccw in relays:
            if cw and ccw:
                self.both_refused += 1
                cw = ccw = False
            bits += [bool(cw), bool(ccw)]
        duty_az, duty_el = self._duties(duties)
        self.command = TrackerCommand(*bits, bool(brakes[0]), bool(brakes[1]), bool(sensor_power),
                                      bool(motor_power), duty_az, duty_el)
        return True


# ---- the day -------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class DaySettings:
    """One day's run. `dial_pct` per axis (az, el); `start`/`end` local standard clock times (None: the sun's
    window); `clouds` a `hil_sim.sun` spec; `params` firmware parameters to set first (name -> value)."""

    mode: str = "relay"
    dial_pct: tuple[float, float] = (50.0, 50.0)
    day: date = date(2026, 6, 21)
    clouds: Optional[str] = None
    seed: int = 0
    start: Optional[clock_time] = None
    end: Optional[clock_time] = None
    params: tuple[tuple[str, float], ...] = ()
    site: Site = TUCSON
    plant_params: TrackerParams = TRACKER_PARAMS

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode {self.mode!r} is not one of {', '.join(MODES)}")
        if len(self.dial_pct) != 2 or not all(isinstance(d, (int, float)) and 0.0 <= d <= 100.0
                                              for d in self.dial_pct):
            raise ValueError(f"dial must be 0..100 % for each axis, got {self.dial_pct!r}")
        if not FIRST_DATE <= self.day <= LAST_DATE:
            raise ValueError(f"date {self.day} is outside {FIRST_DATE}..{LAST_DATE} (the controller's clock)")
        if self.start is not None and self.end is not None and self.end <= self.start:
            raise ValueError(f"--to {self.end} must be after --from {self.start}")
        as_clouds(self.clouds, self.local(clock_time(12)), self.site)      # a bad spec fails here, with its reason

    def local(self, t: clock_time) -> datetime:
        """`t` on the run's day, the site's local standard time, as an aware datetime."""
        return datetime.combine(self.day, t, tzinfo=self.site.local_tz)


def sun_window(day: date, site: Site = TUCSON, min_elevation_deg: float = MIN_ELEVATION_DEG
               ) -> Optional[tuple[datetime, datetime]]:
    """First and last minute of `day` (local standard time) with the sun above `min_elevation_deg`; None if never."""
    t0 = datetime.combine(day, clock_time(0), tzinfo=site.local_tz)
    minutes = [t0 + timedelta(minutes=m) for m in range(24 * 60)]
    up = np.asarray(solar_position(minutes, site)["apparent_elevation"]) > min_elevation_deg
    if not up.any():
        return None
    idx = np.flatnonzero(up)
    return minutes[int(idx[0])], minutes[int(idx[-1])]


@dataclass
class DayResult:
    settings: DaySettings
    start: datetime
    end: datetime
    times_h: np.ndarray                 # local standard time of each sample, hours
    error_deg: np.ndarray               # angle between focal axis and sun
    lag_deg: np.ndarray                 # along the sun's path, + = behind the sun
    axis_error_deg: np.ndarray          # (n, 2): sun - tracker per axis, azimuth wrapped
    switchings: list[int]
    reversals: list[int]
    chatter: list[int]
    motor_on_fraction: list[float]
    high_duty_starts: list[int]
    both_relays_refused: int
    wall_time_s: float
    sim_time_s: float
    extra: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """The JSON object `aspod tracker-day --json` prints."""
        e, lag = self.error_deg, self.lag_deg
        s = self.settings
        axes = {}
        for k, name in enumerate(("az", "el")):
            axes[name] = {"dial_pct": _round(s.dial_pct[k], 3), "switchings": self.switchings[k],
                          "reversals": self.reversals[k], "chatter": self.chatter[k],
                          "motor_on_fraction": _round(self.motor_on_fraction[k], 4),
                          "rms_error_deg": _round(float(np.sqrt(np.mean(self.axis_error_deg[:, k] ** 2))), 4),
                          "high_duty_starts": self.high_duty_starts[k]}
        return {
            "mode": s.mode,
            "dial_pct": {"az": s.dial_pct[0], "el": s.dial_pct[1]},
            "date": s.day.isoformat(),
            "site": s.site.name,
            "start_local": self.start.isoformat(timespec="minutes"),
            "end_local": self.end.isoformat(timespec="minutes"),
            "clouds": s.clouds or "",
            "seed": s.seed,
            "params": dict(s.params),
            "samples": int(len(e)),
            "rms_pointing_error_deg": _round(float(np.sqrt(np.mean(e ** 2))), 4),
            "max_pointing_error_deg": _round(float(e.max()), 4),
            "p95_pointing_error_deg": _round(float(np.percentile(e, 95)), 4),
            "mean_lag_deg": _round(float(lag.mean()), 4),
            "lead_fraction": _round(float(np.mean(lag < 0.0)), 4),
            "relay_switchings": sum(self.switchings),
            "reversals": sum(self.reversals),
            "axes": axes,
            "both_relays_refused": self.both_relays_refused,
            "sim_time_s": _round(self.sim_time_s, 3),
            "wall_time_s": _round(self.wall_time_s, 3),
            "speed_x_real_time": _round(self.sim_time_s / self.wall_time_s, 1) if self.wall_time_s > 0 else None,
            **self.extra,
        }


def _round(x: float, digits: int) -> float:
    return round(x, digits) if math.isfinite(x) else x


def _operate_box(tracker: firmware.TrackerController, settings: DaySettings) -> None:
    """Operating steps 7-10 through the box's own commands; each must be accepted."""
    P = SwitchPosition
    steps = [("speed brake", lambda: tracker.switch(Switch.SPEED, P.BRAKE)),
             ("dial 0", lambda: tracker.dial(0.0)),
             ("mode sensor", lambda: tracker.switch(Switch.MODE, P.SENSOR)),
             ("sensor on", lambda: tracker.switch(Switch.SENSOR, P.ON)),
             ("main on", lambda: tracker.switch(Switch.MAIN, P.ON)),
             ("speed on", lambda: tracker.switch(Switch.SPEED, P.ON)),
             ("dial az", lambda: tracker.dial(settings.dial_pct[0], TrackerAxis.AZ)),
             ("dial el", lambda: tracker.dial(settings.dial_pct[1], TrackerAxis.EL))]
    for what, step in steps:
        reason, detail = step()
        if reason is not Reason.OK:
            raise RuntimeError(f"the control box refused {what!r}: {reason.name} {detail}")


def day_window(settings: DaySettings) -> tuple[datetime, datetime]:
    """When the run starts and ends (local): `--from`/`--to`, else when the sun climbs above and sinks below
    MIN_ELEVATION_DEG. ValueError if the sun does not, or the end is not after the start."""
    if settings.start is None or settings.end is None:
        window = sun_window(settings.day, settings.site)
        if window is None:
            raise ValueError(f"the sun does not rise above {MIN_ELEVATION_DEG} deg on {settings.day} at "
                             f"{settings.site.name}")
    start = settings.local(settings.start) if settings.start is not None else window[0]
    end = settings.local(settings.end) if settings.end is not None else window[1]
    if end <= start:
        raise ValueError(f"nothing to run: {start:%H:%M} to {end:%H:%M}")
    return start, end


def day_s(settings: DaySettings) -> float:
    """The simulated seconds the run goes through."""
    start, end = day_window(settings)
    return (end - start).total_seconds()


def run_day(settings: DaySettings, shown: Optional[Progress] = None) -> DayResult:
    """Run the tracker through the settings' day; `shown` follows the simulated time done of the day's (its total),
    with the pointing error once a simulated minute."""
    start, end = day_window(settings)
    plant = TrackerPlant(settings.plant_params, settings.seed, site=settings.site, start=start,
                         clouds=settings.clouds)
    plant.preload_sun()
    el, az, _, _ = plant.sun()
    plant.set_angles(min(max(az, settings.plant_params.az.limit_ccw_deg), settings.plant_params.az.limit_cw_deg),
                     min(max(el, settings.plant_params.el.limit_ccw_deg), settings.plant_params.el.limit_cw_deg))
    hal = DayHal()
    store = ParamStore(firmware.parameter_table(), check=lambda name, value: firmware.check_param(store, name, value))
    tracker = firmware.TrackerController(hal, store, STEP_S, allowed=lambda: True)
    for name, value in (*settings.params, ("trk_ff", 1.0 if settings.mode == "feedforward" else 0.0)):
        reason, detail = store.set(name, value)
        if reason is not Reason.OK:
            raise ValueError(f"parameter {name}: {reason.name}: {detail}")
    tracker.set_clock(plant.utc.timestamp(), 0.0)
    _operate_box(tracker, settings)

    n_steps = int(round((end - start).total_seconds() / STEP_S))
    n_samples = n_steps // SAMPLE_EVERY
    times_h = np.empty(n_samples)
    error = np.empty(n_samples)
    lag = np.empty(n_samples)
    axis_error = np.empty((n_samples, 2))
    on_steps = [0, 0]
    start_h = start.hour + start.minute / 60.0 + start.second / 3600.0
    prev_sun = plant.sun()
    wall0 = RealClock.precise_now()
    step, sample_every = plant.step, SAMPLE_EVERY
    axes = tracker.axes
    i = 0
    done_s = [0.0]
    if shown is not None:
        shown.follow(lambda: done_s[0])
    for s in range(n_samples):
        for _ in range(sample_every):
            step(STEP_S, hal.command)
            i += 1
            hal.sample(plant, i * STEP_S)
            tracker.step(i * STEP_S)
            if axes[0].relay:
                on_steps[0] += 1
            if axes[1].relay:
                on_steps[1] += 1
        sun = plant.sun()
        el_s, az_s = sun[0], sun[1]
        az_t, el_t = plant.angle_deg
        e_az, e_el = wrap180(az_s - az_t), el_s - el_t
        # The sun's path direction over the last second, in the sky's tangent plane.
        d_x, d_y = wrap180(az_s - prev_sun[1]) * math.cos(el_s * DEG), el_s - prev_sun[0]
        norm = math.hypot(d_x, d_y)
        times_h[s] = start_h + i * STEP_S / 3600.0
        error[s] = plant.angular_error_deg()
        lag[s] = (e_az * math.cos(el_s * DEG) * d_x + e_el * d_y) / norm if norm > 0.0 else 0.0
        axis_error[s] = (e_az, e_el)
        prev_sun = sun
        if shown is not None:
            done_s[0] = i * STEP_S
            if s % 60 == 59:
                shown.note(local=f"{times_h[s]:05.2f} h", error=f"{error[s]:.3f} deg")
    wall = RealClock.precise_now() - wall0
    steps = max(1, i)
    return DayResult(settings, start, end, times_h, error, lag, axis_error,
                     [a.switchings for a in axes], [a.reversals for a in axes], [a.chatter for a in axes],
                     [on_steps[0] / steps, on_steps[1] / steps], list(plant.high_duty_starts),
                     hal.both_refused + sum(plant.both_relays_refused), wall, i * STEP_S)


# ---- the plot ------------------------------------------------------------------------------------------------

def label(result: DayResult) -> str:
    s = result.settings
    dial = f"{s.dial_pct[0]:g} %" if s.dial_pct[0] == s.dial_pct[1] else f"az {s.dial_pct[0]:g} %, el {s.dial_pct[1]:g} %"
    summary = result.summary()
    what = "feed-forward" if s.mode == "feedforward" else "relay logic"
    return (f"{what}, dial {dial}: RMS {summary['rms_pointing_error_deg']:.3f} deg, "
            f"{summary['relay_switchings']} switchings")


def plot_days(results: Sequence[DayResult], path: Union[str, BinaryIO], title: Optional[str] = None) -> None:
    """Pointing error and lag over the day, one line per run, to a PNG (`path`: a name, or a binary file)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(11, 7.5), sharex=True, constrained_layout=True)
    for r in results:
        line, = top.plot(r.times_h, r.lag_deg, lw=0.8, label=label(r))
        bottom.plot(r.times_h, r.error_deg, lw=0.8, color=line.get_color())
    first = results[0]
    for passage in as_clouds(first.settings.clouds, first.start, first.settings.site):
        local = passage.start.astimezone(first.settings.site.local_tz)
        h0 = local.hour + local.minute / 60 + local.second / 3600
        for ax in (top, bottom):
            ax.axvspan(h0, h0 + passage.duration_s / 3600, color="0.85", zorder=0)
    top.axhline(0.0, color="black", lw=0.6)
    top.set_ylabel("lag along the sun's path [deg]\n(+ behind the sun, - ahead)")
    bottom.set_ylabel("pointing error [deg]\n(focal axis to sun)")
    bottom.set_xlabel(f"local standard time (UTC{first.settings.site.utc_offset_h:+g})")
    bottom.set_yscale("log")
    bottom.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(
        lambda h, _pos: f"{int(h) % 24:02d}:{int(round(h % 1 * 60)) % 60:02d}"))
    for ax in (top, bottom):
        ax.grid(True, which="both", lw=0.3)
    top.legend(loc="upper left", fontsize=8)
    s = first.settings
    fig.suptitle(title or f"ASPOD solar tracker, {s.site.name}, {s.day.isoformat()}"
                 + (f", clouds {s.clouds}" if s.clouds else ""))
    fig.savefig(path, format="png", dpi=110)
    plt.close(fig)


def print_summary(summary: dict, out: TextIO = sys.stdout) -> None:
    """A person's view of one day's figures."""
    out.write(f"{summary['mode']} on {summary['date']}, {summary['start_local'][11:16]} to {summary['end_local'][11:16]} "
              f"local standard time (UTC{summary['start_local'][16:]}), dial az {summary['dial_pct']['az']:g} % el {summary['dial_pct']['el']:g} %\n")
    out.write(f"  pointing error   RMS {summary['rms_pointing_error_deg']:.3f} deg, max "
              f"{summary['max_pointing_error_deg']:.3f} deg, p95 {summary['p95_pointing_error_deg']:.3f} deg\n")
    out.write(f"  lag              mean {summary['mean_lag_deg']:+.3f} deg, ahead of the sun "
              f"{100 * summary['lead_fraction']:.1f} % of the time\n")
    out.write(f"  relays           {summary['relay_switchings']} switchings, {summary['reversals']} reversals\n")
    for name, ax in summary["axes"].items():
        out.write(f"    {name}: {ax['switchings']} switchings, {ax['reversals']} reversals, {ax['chatter']} chatter, "
                  f"motor on {100 * ax['motor_on_fraction']:.1f} %, RMS {ax['rms_error_deg']:.3f} deg\n")
    out.write(f"  simulated {summary['sim_time_s'] / 3600:.2f} h in {summary['wall_time_s']:.1f} s "
              f"({summary['speed_x_real_time']}x real time)\n")


# ---- the command line ----------------------------------------------------------------------------------------

def parse_dial(text: str) -> tuple[float, float]:
    """`X` for both axes or `AZ,EL`, percent 0..100."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) not in (1, 2):
        raise ValueError(f"--dial {shown(text)}: one setting for both axes (40) or az,el (40,20), each 0..100 %")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"--dial {shown(text)}: not a number of percent, 0..100") from None
    if not all(0.0 <= v <= 100.0 for v in values):
        raise ValueError(f"--dial {shown(text)}: outside 0..100 % (the dial turns from 0 to 100 %)")
    return (values[0], values[-1])


def parse_date(text: str) -> date:
    try:
        day = date.fromisoformat(text)
    except ValueError:
        raise ValueError(f"date {text!r} is not YYYY-MM-DD") from None
    if not FIRST_DATE <= day <= LAST_DATE:
        raise ValueError(f"date {day} is outside {FIRST_DATE}..{LAST_DATE} (the controller's clock)")
    return day


def parse_clock(text: str) -> clock_time:
    try:
        hours, minutes = (int(p) for p in text.split(":"))
        return clock_time(hours, minutes)
    except ValueError:
        raise ValueError(f"time {text!r} is not HH:MM (local standard time, 00:00 to 23:59)") from None


def parse_param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise ValueError(f"--param {text!r}: expected NAME=VALUE, e.g. trk_deadband_mv=1.5")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise ValueError(f"--param {text!r}: {value!r} is not a number") from None


def run_tracker_day(settings: DaySettings, *, as_json: bool = False, plot: Optional[Output] = None) -> int:
    """`aspod tracker-day`: the day, its summary on stdout (or one JSON object), the plot if asked."""
    import json
    with Progress("tracker-day", day_s(settings)) as shown:
        result = run_day(settings, shown)
    summary = result.summary()
    if plot is not None:
        with plot.open() as png:
            plot_days([result], png)
        summary["plot"] = str(plot)
    if as_json:
        print(json.dumps(summary, indent=1))
    else:
        print_summary(summary)
        if plot is not None:
            print(f"  plot             {plot}")
    return 0
