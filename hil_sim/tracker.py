"""The solar tracker's plant: two axes, their 90 VDC motors, relays, brakes, limits and photocells.

Design: docs/tracker.md#the-plant-in-detail
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from datetime import datetime, timedelta
from numbers import Integral, Real
from typing import NamedTuple, Optional, Union

import numpy as np

from hil_sim.sun import (DEFAULT_START, DEFAULT_TABLE_STEP_S, TUCSON, CloudSchedule, DateTimeLike, Site, SunTable,
                         as_clouds, to_utc)
from protocol.states import AZ, EL, TRACKER_AXES
from protocol.units import DEG

_NOISE_PER_STEP = 7          # 4 cells, 2 potentiometers, 1 supply
_NOISE_BATCH = 7 * 128


class TrackerCommand(NamedTuple):
    """What TRACKER_CMD carries (signal order of the DBC, without `alive`); the default is the safe state.

    Relays True = closed (coil energised), brakes True = applied (the speed switch at Brake:
    dynamic braking, no drive), duties 0..1 (the speed controller's armature duty, set by
    the dial).
    """

    relay_cw_az: bool = False
    relay_ccw_az: bool = False
    relay_cw_el: bool = False
    relay_ccw_el: bool = False
    brake_az: bool = True
    brake_el: bool = True
    sensor_power: bool = False
    motor_power: bool = False
    duty_az: float = 0.0
    duty_el: float = 0.0


SAFE_COMMAND = TrackerCommand()   # relays open, brakes applied, sensors and motors unpowered, duty 0


@dataclass(frozen=True)
class TrackerAxisParams:
    """One axis's travel: limit switches (closed at or beyond), hard stops, start angle, load inertia."""

    name: str
    start_deg: float
    limit_ccw_deg: float
    limit_cw_deg: float
    stop_ccw_deg: float
    stop_cw_deg: float
    # ASSUMED: the cutter and tracker head about the axis; reflected through 20,000:1 it is
    # nothing beside the rotor (20 / 20000^2 = 5e-8 kg m^2), kept for completeness.
    output_inertia_kg_m2: float = 20.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name != "name" and not (isinstance(value, Real) and math.isfinite(value)):
                raise ValueError(f"TrackerAxisParams {self.name!r}: {f.name} must be a finite number, got {value!r}")
        if not self.stop_ccw_deg < self.limit_ccw_deg < self.limit_cw_deg < self.stop_cw_deg:
            raise ValueError(f"TrackerAxisParams {self.name!r}: need stop_ccw < limit_ccw < limit_cw < stop_cw, got "
                             f"{self.stop_ccw_deg}, {self.limit_ccw_deg}, {self.limit_cw_deg}, {self.stop_cw_deg}")
        if not self.stop_ccw_deg <= self.start_deg <= self.stop_cw_deg:
            raise ValueError(f"TrackerAxisParams {self.name!r}: start_deg {self.start_deg} is outside the stops")
        if not (-327.68 <= self.stop_ccw_deg and self.stop_cw_deg <= 327.67):
            raise ValueError(f"TrackerAxisParams {self.name!r}: the stops must lie within TRACKER_POS's "
                             f"-327.68..327.67 deg")
        if self.output_inertia_kg_m2 < 0:
            raise ValueError(f"TrackerAxisParams {self.name!r}: output_inertia_kg_m2 must be >= 0")


@dataclass(frozen=True)
class TrackerParams:
    """The tracker's constants; see the module docstring for the reasons behind each (all ASSUMED but 90 V)."""

    # The 90 VDC bus: the report ("a 90-VDC motor"; "THIS ADJUSTABLE SPEED CONTROLLER IS DESIGNED
    # TO OPERATE FOR A 90 VDC MOTOR").
    supply_v: float = 90.0
    supply_source_ohm: float = 0.5
    supply_noise_v: float = 0.05
    # Motor, at its shaft: 1/8 hp, 1750 rpm, 90 VDC PM class.
    r_ohm: float = 8.0
    l_h: float = 0.04
    k_v_s_rad: float = 0.43          # Kt [N m/A] = Ke [V s/rad]
    rotor_inertia_kg_m2: float = 2.5e-4
    coulomb_nm: float = 0.06         # brushes, bearings and the gear train, at the motor shaft
    stiction_nm: float = 0.08
    viscous_nm_s_rad: float = 2e-4
    rated_torque_nm: float = 0.51    # 1/8 hp at 1750 rpm
    gear_ratio: float = 20_000.0     # motor turns per axis turn
    # The speed switch's Brake position (report, operating step 7): the armature on a braking resistor.
    brake_resistor_ohm: float = 8.0
    relay_operate_s: float = 0.015
    relay_release_s: float = 0.005
    # The report: "ALWAYS keep the speed dial on low when starting operation ... when switching
    # direction". A start (idle -> driven) at a higher duty counts in `high_duty_starts`. "Low" ASSUMED 0.25.
    low_duty: float = 0.25
    limit_switch_cuts_drive: bool = True
    cell_v_per_w_m2: float = 0.5 / 1000.0
    cell_tilt_deg: float = 45.0
    cell_diffuse_view: float = 0.5
    cell_noise_v: float = 0.001
    pot_noise_deg: float = 0.02
    # The `clouds` fault: a cloud bank over the sun removes this fraction of the direct beam
    # (ASSUMED: a thick cumulus passes 5 % or less).
    overcast_attenuation: float = 0.95
    sun_table_step_s: float = DEFAULT_TABLE_STEP_S
    az: TrackerAxisParams = field(default_factory=lambda: TrackerAxisParams("az", 90.0, 50.0, 310.0, 45.0, 315.0))
    el: TrackerAxisParams = field(default_factory=lambda: TrackerAxisParams("el", 0.0, -2.0, 85.0, -5.0, 88.0, 10.0))

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, (TrackerAxisParams, bool)):
                continue
            if not (isinstance(value, Real) and math.isfinite(value)):
                raise ValueError(f"TrackerParams.{f.name} must be a finite number, got {value!r}")
            if value < 0:
                raise ValueError(f"TrackerParams.{f.name} must be >= 0, got {value}")
        for name in ("supply_v", "r_ohm", "k_v_s_rad", "rotor_inertia_kg_m2", "gear_ratio", "relay_operate_s",
                     "relay_release_s", "cell_v_per_w_m2", "sun_table_step_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TrackerParams.{name} must be > 0, got {getattr(self, name)}")
        if self.stiction_nm < self.coulomb_nm:
            raise ValueError("TrackerParams.stiction_nm must be >= coulomb_nm")
        if not 0 < self.cell_tilt_deg < 90:
            raise ValueError(f"TrackerParams.cell_tilt_deg must be in (0, 90), got {self.cell_tilt_deg}")
        for name in ("low_duty", "overcast_attenuation", "cell_diffuse_view"):
            if not getattr(self, name) <= 1:
                raise ValueError(f"TrackerParams.{name} must be in [0, 1], got {getattr(self, name)}")
        if not isinstance(self.az, TrackerAxisParams) or not isinstance(self.el, TrackerAxisParams):
            raise ValueError("TrackerParams.az and .el must be TrackerAxisParams")

    @property
    def axes(self) -> tuple[TrackerAxisParams, TrackerAxisParams]:
        return (self.az, self.el)

    def steady_motor_speed_rad_s(self, duty: float) -> float:
        """Motor speed at `duty` with the nominal 90 V, no load but friction (0 inside the dead band)."""
        k, r = self.k_v_s_rad, self.r_ohm
        v = duty * self.supply_v - r * self.coulomb_nm / k
        return max(0.0, v / (k + r * self.viscous_nm_s_rad / k))

    def steady_speed_deg_s(self, duty: float) -> float:
        """An axis's steady speed at `duty` [deg/s] (sag of the bus neglected)."""
        return self.steady_motor_speed_rad_s(duty) / self.gear_ratio / DEG

    @property
    def top_speed_deg_s(self) -> float:
        """An axis's speed at full duty, no load [deg/s]."""
        return self.steady_speed_deg_s(1.0)


TRACKER_PARAMS = TrackerParams()


def wrap180(angle_deg: float) -> float:
    """An angle in degrees wrapped to [-180, 180)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


class TrackerPlant:
    """Two tracker axes with their relays, brakes, limits, 90 V bus and photocells; stepped by `dt_s`.

    `TrackerPlant(params, rng, site=, start=, clouds=)`: `rng` a numpy Generator or an int
    seed; `site` a `hil_sim.sun.Site` (Tucson by default); `start` the simulated date-time
    at elapsed 0 (aware datetime or POSIX timestamp; default the June solstice 2026, 06:00
    MST); `clouds` None, a spec string ("12:00+300s@0.9", `hil_sim.sun`) or CloudPassage
    items. `step(dt_s, cmd)` advances it; nothing here reads the OS clock.

    State and sensors after a step (per-axis lists are [az, el]): `elapsed_s`, `utc`;
    `angle_deg` (true), `speed_deg_s`, `current_a`, `relay_closed` ([[cw, ccw], [cw, ccw]]),
    `cells_v` (az_a, az_b, el_a, el_b), `angles_measured_deg`, `limits` (cw_az, ccw_az,
    cw_el, ccw_el), `motor_supply_v` (measured), `motor_supply_true_v`; counters
    `both_relays_refused`, `relay_closures`, `high_duty_starts`, `both_closed_s`, `steps`.
    `overcast` True adds the `clouds` fault's attenuation. `sun()`, `beam_transmission()`,
    `pointing_error_deg()` and `angular_error_deg()` give the sun and the errors at the
    present time (truth, for reports and tests; a controller only has the cells);
    `set_angles()` moves the axes by hand; `preload_sun()` computes the day's sun ahead.

    Without a bus (a whole day, fast)::

        t = TrackerPlant(TRACKER_PARAMS, 1, start=DEFAULT_START, clouds="12:00+300s@0.9")
        cmd = TrackerCommand(relay_cw_az=True, brake_az=False, brake_el=False, sensor_power=True,
                             motor_power=True, duty_az=0.4)
        for _ in range(100):
            t.step(0.01, cmd)
        a_az, b_az, a_el, b_el = t.cells_v
    """

    def __init__(self, params: TrackerParams = TRACKER_PARAMS, rng: Union[np.random.Generator, int] = 0, *,
                 site: Site = TUCSON, start: DateTimeLike = DEFAULT_START, clouds=None) -> None:
        if not isinstance(params, TrackerParams):
            raise ValueError(f"params must be TrackerParams, got {params!r}")
        if isinstance(rng, Integral) and not isinstance(rng, bool):
            rng = np.random.default_rng(int(rng))
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy Generator or an int seed, got {rng!r}")
        if not isinstance(site, Site):
            raise ValueError(f"site must be a hil_sim.sun.Site, got {site!r}")
        p = self.params = params
        self._rng = rng
        self.site = site
        self.start_utc = to_utc(start)
        self._epoch_unix = self.start_utc.timestamp()
        self.clouds = CloudSchedule(as_clouds(clouds, self.start_utc, site), self.start_utc)
        self._sun = SunTable(site, p.sun_table_step_s)
        self.overcast = False
        self.elapsed_s = 0.0
        self.steps = 0
        # Per axis.
        self.angle_deg = [p.az.start_deg, p.el.start_deg]
        self._w = [0.0, 0.0]                 # motor shaft speed, rad/s (+ = CW)
        self.current_a = [0.0, 0.0]          # armature current (+ = CW)
        self._coil = [[False, False], [False, False]]
        self.relay_closed = [[False, False], [False, False]]
        self._flip_at: list[list[Optional[float]]] = [[None, None], [None, None]]
        self.both_relays_refused = [0, 0]    # steps whose command asked for both directions
        self.relay_closures = [0, 0]         # contact closings
        self.high_duty_starts = [0, 0]       # starts (armature from idle to driven) above params.low_duty
        self._driven = [False, False]
        self.both_closed_s = 0.0             # time both contacts of an axis were closed: stays 0
        self._lim_ccw = [p.az.limit_ccw_deg, p.el.limit_ccw_deg]
        self._lim_cw = [p.az.limit_cw_deg, p.el.limit_cw_deg]
        self._stop_ccw = [p.az.stop_ccw_deg, p.el.stop_ccw_deg]
        self._stop_cw = [p.az.stop_cw_deg, p.el.stop_cw_deg]
        self._inertia = [p.rotor_inertia_kg_m2 + a.output_inertia_kg_m2 / p.gear_ratio ** 2 for a in p.axes]
        self._deg_per_motor_rad = 1.0 / (p.gear_ratio * DEG)
        self._cos_tilt = math.cos(p.cell_tilt_deg * DEG)
        self._sin_tilt = math.sin(p.cell_tilt_deg * DEG)
        self._h = -1.0
        self._coef: tuple = ()
        self._bus_current_a = 0.0
        self.motor_supply_true_v = 0.0
        self.motor_supply_v = 0.0
        self.cells_v = (0.0, 0.0, 0.0, 0.0)
        self.angles_measured_deg = list(self.angle_deg)
        self.limits = (False, False, False, False)
        self._noise: list[float] = []
        self._noise_at = 0
        self.step(0.0, SAFE_COMMAND)

    # -- time and sun ---------------------------------------------------------------------------------
    @property
    def utc(self) -> datetime:
        """The simulated date-time now (start + elapsed), in UTC."""
        return self.start_utc + timedelta(seconds=self.elapsed_s)

    def sun(self) -> tuple[float, float, float, float]:
        """(apparent elevation deg, azimuth deg, DNI after clouds W/m^2, DHI W/m^2) now."""
        el, az, dni, dhi = self._sun.at(self._epoch_unix + self.elapsed_s)
        return el, az, dni * self.beam_transmission(), dhi

    def beam_transmission(self) -> float:
        """Fraction of the clear-sky beam getting through now: scheduled clouds and the `clouds` fault."""
        tr = self.clouds.transmission(self.elapsed_s)
        return tr * (1.0 - self.params.overcast_attenuation) if self.overcast else tr

    def preload_sun(self) -> None:
        """Compute the sun for the present local day now (about 70 ms), rather than at the first step with the
        photocells powered: for real-time runs."""
        self._sun.preload(self._epoch_unix + self.elapsed_s)

    def pointing_error_deg(self) -> tuple[float, float]:
        """(azimuth, elevation) error now: sun - tracker, azimuth wrapped to +-180 deg."""
        el, az, _, _ = self._sun.at(self._epoch_unix + self.elapsed_s)
        return wrap180(az - self.angle_deg[AZ]), el - self.angle_deg[EL]

    def angular_error_deg(self) -> float:
        """The angle between the focal axis and the sun now [deg]: how far off the cutter's beam points."""
        el, az, _, _ = self._sun.at(self._epoch_unix + self.elapsed_s)
        az_t, el_t = self.angle_deg
        c = (math.cos(el_t * DEG) * math.cos(el * DEG) * math.cos((az - az_t) * DEG)
             + math.sin(el_t * DEG) * math.sin(el * DEG))
        return math.acos(max(-1.0, min(1.0, c))) / DEG

    @property
    def speed_deg_s(self) -> list[float]:
        """Axis speeds [deg/s] (+ = CW)."""
        return [w * self._deg_per_motor_rad for w in self._w]

    def set_angles(self, az_deg: Optional[float] = None, el_deg: Optional[float] = None) -> None:
        """Move the axes by hand (setting up a test or a run); motors stopped. ValueError outside the stops."""
        for k, value in ((AZ, az_deg), (EL, el_deg)):
            if value is None:
                continue
            if not (isinstance(value, Real) and self._stop_ccw[k] <= value <= self._stop_cw[k]):
                raise ValueError(f"{TRACKER_AXES[k]} angle must be within its stops {self._stop_ccw[k]}..{self._stop_cw[k]}"
                                 f" deg, got {value!r}")
            self.angle_deg[k] = float(value)
            self._w[k] = 0.0
            self.current_a[k] = 0.0

    # -- integration ----------------------------------------------------------------------------------
    def _set_step(self, h: float) -> None:
        p = self.params

        def loop(r: float) -> tuple[float, float, float]:
            x = min(r * h / p.l_h, 700.0) if p.l_h > 0 else 700.0
            a_e = r / math.expm1(x)              # L_eff / h (hil_sim.motor's exponential fitting)
            inv = 1.0 / (a_e + r)
            return a_e, inv, p.k_v_s_rad * inv

        # The armature on the drive, and on the braking resistor.
        self._coef = (loop(p.r_ohm), loop(p.r_ohm + p.brake_resistor_ohm), [j / h for j in self._inertia])
        self._h = h

    def _relays(self, k: int, req_cw: bool, req_ccw: bool, t0: float, t1: float) -> tuple[float, float]:
        """Advance axis k's relay pair over [t0, t1]; return how long each contact was closed in it."""
        coil, closed, flip = self._coil[k], self.relay_closed[k], self._flip_at[k]
        if flip[0] is None and flip[1] is None and coil[0] == (req_cw and not closed[1]) \
                and coil[1] == (req_ccw and not closed[0]):
            # Nothing switches in this step (the common case): each contact stays as it is.
            if closed[0] and closed[1]:
                self.both_closed_s += t1 - t0
            return (t1 - t0 if closed[0] else 0.0), (t1 - t0 if closed[1] else 0.0)
        p = self.params
        req = (req_cw, req_ccw)
        on = [0.0, 0.0]
        t = t0
        while True:
            for j in (0, 1):
                c = req[j] and not closed[1 - j]          # the interlock: the other contact must be open
                if c != coil[j]:
                    coil[j] = c
                    flip[j] = None if c == closed[j] else t + (p.relay_operate_s if c else p.relay_release_s)
            f0, f1 = flip
            nxt = min(f0 if f0 is not None else math.inf, f1 if f1 is not None else math.inf)
            end = nxt if nxt < t1 else t1
            if closed[0]:
                on[0] += end - t
            if closed[1]:
                on[1] += end - t
            if closed[0] and closed[1]:
                self.both_closed_s += end - t
            if nxt > t1:
                return on[0], on[1]
            t = nxt
            for j in (0, 1):
                if flip[j] is not None and flip[j] <= t:
                    closed[j] = coil[j]
                    flip[j] = None
                    if closed[j]:
                        self.relay_closures[k] += 1

    def step(self, dt_s: float, cmd: TrackerCommand = SAFE_COMMAND) -> None:
        """Advance `dt_s` seconds under `cmd` (a TrackerCommand or a tuple in its order), then sample the sensors.

        ValueError (nothing changes) for a bad `dt_s`, a command of the wrong length or a
        duty outside [0, 1].
        """
        if not (dt_s >= 0.0 and math.isfinite(dt_s)):
            raise ValueError(f"dt_s must be finite and >= 0, got {dt_s}")
        try:
            cw_az, ccw_az, cw_el, ccw_el, brake_az, brake_el, sensor_power, motor_power, duty_az, duty_el = cmd
            duty_ok = 0.0 <= duty_az <= 1.0 and 0.0 <= duty_el <= 1.0        # NaN is not
        except (TypeError, ValueError):
            raise ValueError(f"cmd must be a TrackerCommand (10 fields), got {cmd!r}") from None
        if not duty_ok:
            raise ValueError(f"duties must be in [0, 1], got az {duty_az!r}, el {duty_el!r}")
        p = self.params
        h = dt_s
        t0 = self.elapsed_s
        t1 = t0 + h
        if h > 0.0 and h != self._h:
            self._set_step(h)
        # The 90 V bus as the drives see it this step (the previous step's load: a one-step lag).
        v_bus = max(0.0, p.supply_v - p.supply_source_ohm * self._bus_current_a) if motor_power else 0.0
        bus_current = 0.0
        kt = p.k_v_s_rad
        for k, req_cw, req_ccw, brake, duty in ((AZ, cw_az, ccw_az, brake_az, duty_az),
                                                (EL, cw_el, ccw_el, brake_el, duty_el)):
            req_cw, req_ccw = bool(req_cw), bool(req_ccw)
            if req_cw and req_ccw:
                self.both_relays_refused[k] += 1
                req_cw = req_ccw = False
            on_cw, on_ccw = self._relays(k, req_cw, req_ccw, t0, t1)
            if h <= 0.0:
                continue
            angle = self.angle_deg[k]
            if p.limit_switch_cuts_drive:
                if angle >= self._lim_cw[k]:
                    on_cw = 0.0
                if angle <= self._lim_ccw[k]:
                    on_ccw = 0.0
            (a_e, inv_aer, q), (b_e, inv_ber, qb), masses = self._coef
            m = masses[k]
            w = self._w[k]
            connected = bool(motor_power) and not brake and (on_cw > 0.0 or on_ccw > 0.0)
            if connected != self._driven[k]:
                self._driven[k] = connected
                if connected and duty > p.low_duty:
                    self.high_duty_starts[k] += 1
            if brake:
                # The speed switch at Brake: the armature on the braking resistor, whatever the relays say.
                pp = b_e * self.current_a[k] * inv_ber
                qq = qb
            elif connected:
                u = duty * v_bus * (on_cw - on_ccw) / h
                pp = (a_e * self.current_a[k] + u) * inv_aer       # current if the shaft stood still
                qq = q
            else:
                pp = qq = 0.0
            if w == 0.0 and pp == 0.0:
                w2 = i2 = 0.0                                      # at rest, nothing applied: stays at rest
            else:
                w2, i2 = _shaft(w, pp, qq, m, kt, p)
            if connected and i2 * (on_cw - on_ccw) < 0.0:
                # The drive cannot sink current: the armature is effectively open, the motor coasts.
                w2, i2 = _shaft(w, 0.0, 0.0, m, kt, p)
            angle += h * w2 * self._deg_per_motor_rad
            if angle >= self._stop_cw[k]:
                angle, w2, i2 = self._stop_cw[k], 0.0, (pp if pp > 0.0 else 0.0)     # stalled against the stop
            elif angle <= self._stop_ccw[k]:
                angle, w2, i2 = self._stop_ccw[k], 0.0, (pp if pp < 0.0 else 0.0)
            self.angle_deg[k] = angle
            self._w[k] = w2
            self.current_a[k] = i2
            if connected:
                bus_current += duty * abs(i2) * (on_cw + on_ccw) / h
        self.elapsed_s = t1
        self.steps += 1
        if h > 0.0:
            self._bus_current_a = bus_current
        self.motor_supply_true_v = v_bus
        # Sensors.
        at = self._noise_at
        if at + _NOISE_PER_STEP > len(self._noise):
            self._noise = self._rng.standard_normal(_NOISE_BATCH).tolist()
            at = 0
        self._noise_at = at + _NOISE_PER_STEP
        noise = self._noise
        az_t, el_t = self.angle_deg
        self.angles_measured_deg = [az_t + noise[at + 4] * p.pot_noise_deg, el_t + noise[at + 5] * p.pot_noise_deg]
        self.limits = (az_t >= self._lim_cw[AZ], az_t <= self._lim_ccw[AZ],
                       el_t >= self._lim_cw[EL], el_t <= self._lim_ccw[EL])
        supply = v_bus + noise[at + 6] * p.supply_noise_v if motor_power else 0.0
        self.motor_supply_v = supply if supply > 0.0 else 0.0
        if sensor_power:
            self.cells_v = self._cells(az_t, el_t, noise, at)
        else:
            self.cells_v = (0.0, 0.0, 0.0, 0.0)

    def _cells(self, az_t: float, el_t: float, noise: list, at: int) -> tuple[float, float, float, float]:
        p = self.params
        el_s, az_s, dni, dhi = self._sun.at(self._epoch_unix + self.elapsed_s)
        dni *= self.beam_transmission()
        ce, se = math.cos(el_t * DEG), math.sin(el_t * DEG)
        cs, ss = math.cos(el_s * DEG), math.sin(el_s * DEG)
        d = (az_s - az_t) * DEG
        cd = math.cos(d)
        f_s = ce * cs * cd + se * ss                  # focal axis . sun
        eaz_s = cs * math.sin(d)                      # direction of increasing azimuth . sun
        eel_s = ce * ss - se * cs * cd                # direction of increasing elevation . sun
        a_f = self._cos_tilt * f_s                     # each cell: cos incidence = cos45 (f.s) +- sin45 (e.s)
        b_az, b_el = self._sin_tilt * eaz_s, self._sin_tilt * eel_s
        k = p.cell_v_per_w_m2
        kb = k * dni
        base = k * p.cell_diffuse_view * dhi
        sigma = p.cell_noise_v
        c0, c1, c2, c3 = a_f + b_az, a_f - b_az, a_f + b_el, a_f - b_el
        v0 = base + (kb * c0 if c0 > 0.0 else 0.0) + noise[at] * sigma
        v1 = base + (kb * c1 if c1 > 0.0 else 0.0) + noise[at + 1] * sigma
        v2 = base + (kb * c2 if c2 > 0.0 else 0.0) + noise[at + 2] * sigma
        v3 = base + (kb * c3 if c3 > 0.0 else 0.0) + noise[at + 3] * sigma
        return (v0 if v0 > 0.0 else 0.0, v1 if v1 > 0.0 else 0.0, v2 if v2 > 0.0 else 0.0, v3 if v3 > 0.0 else 0.0)


def _shaft(w: float, p_i: float, q: float, m: float, kt: float, p: TrackerParams) -> tuple[float, float]:
    """One implicit step of the motor shaft (hil_sim.motor's friction-as-constraint): (new speed, new current).

    `p_i` is the current if the shaft stood still this step, `q` the current's drop per rad/s
    of the new speed (back-EMF); both 0 with the armature open.
    """
    s = m * w + kt * p_i                              # what friction must hold to stop the shaft this step
    kinetic = p.coulomb_nm
    cap = p.stiction_nm if w == 0.0 else kinetic
    if s > cap:
        w2 = (s - kinetic) / (m + p.viscous_nm_s_rad + kt * q)
    elif s < -cap:
        w2 = (s + kinetic) / (m + p.viscous_nm_s_rad + kt * q)
    else:
        w2 = 0.0
    return w2, p_i - q * w2


__all__ = ["AZ", "EL", "SAFE_COMMAND", "TRACKER_PARAMS", "TrackerAxisParams", "TrackerCommand",
           "TrackerParams", "TrackerPlant", "wrap180"]
