"""The solar tracker's plant: the sun (SPA reference values), photocells, relays, motors, limits, brakes, the bus.

The sun comes from pvlib (NREL SPA) through `hil_sim.sun`; the tracker (`hil_sim.tracker`)
is stepped directly, without a bus, except in the bus tests at the end, where a
`PlantNode(..., tracker=True)` runs on a private python-can virtual channel and a stand-in
controller speaks TRACKER_CMD / TRACKER_SENSE / TRACKER_POS through `HalCodec`. Nothing
sleeps on wall time; the only OS time read is the cost measurement's stopwatch.
"""
from __future__ import annotations

import math
import statistics
import sys
from dataclasses import replace
from datetime import date, datetime, timedelta, timezone
from pathlib import Path

import can
import numpy as np
import pytest

from hil_sim.hal_node import PlantNode
from hil_sim.commands import ExpiringTrackerCommands
from hil_sim.plant import Plant, PlantParams
from hil_sim.sun import (DEFAULT_START, MST, TUCSON, CloudPassage, CloudSchedule, Site, SunTable, parse_clouds,
                         solar_position, to_utc)
from hil_sim.tracker import AZ, EL, SAFE_COMMAND, TRACKER_PARAMS, TrackerCommand, TrackerPlant, wrap180
from protocol.hal import HalCodec
from host_tools.worlds import child

ROOT = Path(__file__).resolve().parent.parent
CODEC = HalCodec()
QUIET = replace(TRACKER_PARAMS, cell_noise_v=0.0, pot_noise_deg=0.0, supply_noise_v=0.0)
SENSORS = TrackerCommand(sensor_power=True)
P = TRACKER_PARAMS


def at_mst(hour: int, minute: int = 0, second: int = 0, day: int = 21) -> datetime:
    return datetime(2026, 6, day, hour, minute, second, tzinfo=MST)


def drive(az: int = 0, el: int = 0, duty_az: float = 1.0, duty_el: float = 1.0, *, brake: bool = False,
          sensors: bool = True, motor_power: bool = True) -> TrackerCommand:
    """A command: az/el = +1 CW, -1 CCW, 0 relays open."""
    return TrackerCommand(az > 0, az < 0, el > 0, el < 0, brake, brake, sensors, motor_power, duty_az, duty_el)


def run(tracker: TrackerPlant, cmd: TrackerCommand, seconds: float, dt_s: float = 0.01) -> None:
    for _ in range(round(seconds / dt_s)):
        tracker.step(dt_s, cmd)


def aligned(start: datetime = at_mst(10), params=QUIET, **kw) -> TrackerPlant:
    """A tracker pointing exactly at the sun at `start`, cells sampled."""
    t = TrackerPlant(params, 0, start=start, **kw)
    el, az, _, _ = t.sun()
    t.set_angles(az, el)
    t.step(0.0, SENSORS)
    return t


def diffs(t: TrackerPlant) -> tuple[float, float]:
    a_az, b_az, a_el, b_el = t.cells_v
    return a_az - b_az, a_el - b_el


# ---- the sun ----------------------------------------------------------------------------------------

def test_spa_reference_example_of_reda_and_andreas():
    # NREL SPA paper (Reda and Andreas 2004/2008), Table A4.1's example: 2003-10-17 12:30:30 local,
    # UTC-7, delta T 67 s, 39.742476 N 105.1786 W, 1830.14 m, 820 mbar, 11 C ->
    # topocentric zenith 50.11162 deg (with refraction), azimuth 194.34024 deg.
    site = Site("NREL SPA example (Golden, Colorado)", 39.742476, -105.1786, 1830.14, -7.0,
                pressure_pa=82000.0, temperature_c=11.0)
    when = datetime(2003, 10, 17, 12, 30, 30, tzinfo=timezone(timedelta(hours=-7)))
    sun = solar_position(when, site, delta_t_s=67.0)
    assert sun["apparent_zenith"][0] == pytest.approx(50.11162, abs=2e-5)
    assert sun["azimuth"][0] == pytest.approx(194.34024, abs=2e-5)
    assert sun["apparent_elevation"][0] == pytest.approx(90.0 - 50.11162, abs=2e-5)


def day_table(day: int = 21, step_s: float = 10.0):
    """(MST datetimes, elevation, azimuth unwrapped, dni) over a local day from the tabulated sun."""
    table = SunTable(TUCSON)
    t0 = at_mst(0, day=day).timestamp()
    ts = [t0 + k * step_s for k in range(int(86400 / step_s))]
    rows = np.array([table.at(t) for t in ts])
    return ts, rows[:, 0], np.unwrap(rows[:, 1], period=360.0), rows[:, 2], rows[:, 3]


def test_tucson_june_solstice_noon_elevation():
    ts, el, az, dni, _ = day_table()
    i = int(np.argmax(el))
    # Solar noon at the June solstice: 90 - (latitude - obliquity 23.44 deg).
    assert el[i] == pytest.approx(90.0 - (TUCSON.latitude_deg - 23.44), abs=0.05)
    noon = datetime.fromtimestamp(ts[i], MST)
    # 12:00 MST at 105 W; 110.95 W is 23.8 min later, the equation of time -1.7 min: 12:25.6 MST.
    assert (noon.hour, noon.minute) in ((12, 25), (12, 26))
    assert az[i] % 360.0 == pytest.approx(180.0, abs=0.2)          # due south at transit


def test_table_interpolation_matches_the_spa():
    table = SunTable(TUCSON)
    ts = [at_mst(5, 30).timestamp() + k * 13.7 for k in range(3000)]   # 05:30 to 17:15, odd instants
    exact = solar_position(ts, TUCSON)
    got = np.array([table.at(t) for t in ts])
    assert np.max(np.abs(got[:, 0] - exact["apparent_elevation"])) < 1e-4
    assert max(abs(wrap180(a - b)) for a, b in zip(got[:, 1], exact["azimuth"])) < 1e-4


def test_fastest_sun_rates_and_the_gear_ratio():
    ts, el, az, dni, _ = day_table(step_s=10.0)
    up = el > 0.0
    az_rate = np.abs(np.gradient(az, 10.0))[up] * 60.0        # deg/min
    el_rate = np.abs(np.gradient(el, 10.0))[up] * 60.0
    assert az_rate.max() == pytest.approx(1.50, abs=0.01)       # at transit, 15 deg/h x 0.917 / 0.153
    assert el_rate.max() == pytest.approx(0.21, abs=0.01)
    top = P.top_speed_deg_s * 60.0
    assert top / az_rate.max() == pytest.approx(23.5, abs=0.2)   # the sun's fastest need: 4.3 % of full duty
    # The travel covers the sun's whole day: sunrise and sunset azimuths inside the limit switches.
    assert P.az.limit_ccw_deg < az[up][0] % 360 and az[up][-1] % 360 < P.az.limit_cw_deg
    assert el.max() < P.el.limit_cw_deg


def test_clear_sky_beam():
    ts, el, az, dni, dhi = day_table()
    noon = int(np.argmax(el))
    assert 850.0 < dni[noon] < 1050.0                           # a clear desert noon
    assert 0.0 < dhi[noon] < 0.2 * dni[noon]
    assert np.all(dni[el < -1.0] == 0.0) and np.all(dhi[el < -1.0] == 0.0)    # night


def test_start_times_are_explicit():
    assert to_utc(DEFAULT_START) == datetime(2026, 6, 21, 13, 0, tzinfo=timezone.utc)
    assert to_utc(1_782_046_800) == datetime(2026, 6, 21, 13, 0, tzinfo=timezone.utc)
    with pytest.raises(ValueError, match="timezone-aware"):
        TrackerPlant(start=datetime(2026, 6, 21, 6, 0))
    with pytest.raises(ValueError, match="finite"):
        to_utc(float("nan"))
    with pytest.raises(ValueError, match="aware datetime or a POSIX timestamp"):
        Plant(PlantParams(), np.random.default_rng(0), start="06:00")
    with pytest.raises(ValueError, match="latitude"):
        Site("nowhere", 95.0, 0.0, 0.0, 0.0)
    t = TrackerPlant(start=at_mst(6))
    run(t, SAFE_COMMAND, 3.0, 0.5)
    assert t.utc == datetime(2026, 6, 21, 13, 0, 3, tzinfo=timezone.utc)


# ---- clouds ---------------------------------------------------------------------------------------------

def test_clouds_spec_is_parsed_in_local_standard_time():
    passages = parse_clouds("12:00+300s@0.9, 14:30+10m@0.5,2026-06-22T09:15:30+1.5h@0.2", date(2026, 6, 21), -7.0)
    assert [(to_utc(p.start), p.duration_s, p.attenuation) for p in passages] == [
        (datetime(2026, 6, 21, 19, 0, tzinfo=timezone.utc), 300.0, 0.9),
        (datetime(2026, 6, 21, 21, 30, tzinfo=timezone.utc), 600.0, 0.5),
        (datetime(2026, 6, 22, 16, 15, 30, tzinfo=timezone.utc), 5400.0, 0.2)]
    assert parse_clouds("", date(2026, 6, 21), -7.0) == ()
    sky = CloudSchedule(parse_clouds("12:00+10m@0.5,12:05+10m@0.8", date(2026, 6, 21), -7.0), at_mst(12))
    assert [sky.transmission(t) for t in (-1.0, 0.0, 299.0, 300.0, 599.9, 600.0, 899.0, 900.0)] == \
        [1.0, 0.5, 0.5, pytest.approx(0.1), pytest.approx(0.1), pytest.approx(0.2), pytest.approx(0.2), 1.0]


def test_clouds_as_passages():
    passage = CloudPassage(at_mst(10), 60.0, 1.0)
    t = TrackerPlant(QUIET, 0, start=at_mst(9, 59), clouds=[passage])
    assert t.beam_transmission() == 1.0
    run(t, SENSORS, 61.0, 0.5)
    assert t.beam_transmission() == 0.0
    with pytest.raises(ValueError, match="attenuation"):
        CloudPassage(at_mst(10), 60.0, 1.2)
    with pytest.raises(ValueError, match="timezone-aware"):
        CloudPassage(datetime(2026, 6, 21, 10), 60.0, 0.5)
    with pytest.raises(ValueError, match="CloudPassage items"):
        TrackerPlant(clouds=[("10:00", 60, 0.5)])


@pytest.mark.parametrize("spec,message", [
    ("12:00+300@0.9", "needs a number and a unit"),
    ("12:00+300s@1.5", r"in \[0, 1\]"),
    ("12:00+5m@x", "not a number"),
    ("25:00+300s@0.5", "out of range"),
    ("noon+300s@0.5", "is not HH:MM"),
    ("12:00+300s", "expected TIME\\+DURATION@ATTENUATION"),
    ("12:00+300s@0.5,,13:00+1m@0.2", "passage 2 .*empty"),
    ("12:00+0s@0.5", "duration must be > 0"),
    ("2026-02-30T12:00+5m@0.5", "date"),
])
def test_bad_clouds_specs_say_what_is_wrong(spec, message):
    with pytest.raises(ValueError, match=message):
        parse_clouds(spec, date(2026, 6, 21), -7.0)
    with pytest.raises(ValueError, match=message):
        Plant(PlantParams(), np.random.default_rng(0), clouds=spec)


def test_clouds_attenuate_the_beam_and_the_fault_covers_the_sun():
    start = at_mst(9, 59, 30)
    t = aligned(start, clouds="10:00+60s@0.9")
    _, _, _, dhi = t.sun()
    diffuse_v = P.cell_v_per_w_m2 * P.cell_diffuse_view * dhi
    clear = [v - diffuse_v for v in t.cells_v]                  # the beam's share of each cell
    run(t, SENSORS, 40.0)                                       # 10:00:10, under the cloud
    dimmed = [v - diffuse_v for v in t.cells_v]
    assert all(d / c == pytest.approx(0.1, abs=0.01) for d, c in zip(dimmed, clear))
    run(t, SENSORS, 60.0)                                       # 10:01:10, clear again
    assert all(v - diffuse_v == pytest.approx(c, rel=0.01) for v, c in zip(t.cells_v, clear))
    # The fault, through the plant: 95 % of the beam gone until cleared.
    plant = Plant(PlantParams(), np.random.default_rng(0), start=at_mst(12), tracker_params=QUIET)
    tr = plant.tracker
    el, az, _, dhi = tr.sun()
    tr.set_angles(az, el)
    tr.step(0.0, SENSORS)
    before = sum(tr.cells_v)
    plant.inject("clouds")
    assert plant.faults == {"clouds"}
    tr.step(0.0, SENSORS)
    diffuse_v = P.cell_v_per_w_m2 * P.cell_diffuse_view * dhi
    assert (sum(tr.cells_v) - 4 * diffuse_v) / (before - 4 * diffuse_v) == pytest.approx(0.05, abs=0.005)
    plant.clear("clouds")
    tr.step(0.0, SENSORS)
    assert sum(tr.cells_v) == pytest.approx(before, rel=1e-3)


# ---- photocells -----------------------------------------------------------------------------------------

def test_cells_are_balanced_at_alignment_and_say_which_side_the_sun_is_on():
    t = aligned(at_mst(10))
    el, az, dni, dhi = t.sun()
    d_az, d_el = diffs(t)
    assert d_az == pytest.approx(0.0, abs=1e-12) and d_el == pytest.approx(0.0, abs=1e-12)
    assert all(v > 0.2 for v in t.cells_v)                      # each cell sees the sun at 45 deg
    for k, offset, sign in ((AZ, -1.0, +1), (AZ, +1.0, -1), (EL, -1.0, +1), (EL, +1.0, -1)):
        t.set_angles(*((az + offset, el) if k == AZ else (az, el + offset)))
        t.step(0.0, SENSORS)
        error = t.pointing_error_deg()[k]
        assert math.copysign(1, error) == sign                   # sun - tracker
        assert math.copysign(1, diffs(t)[k]) == sign             # a - b > 0: the sun is CW of the axis
        assert diffs(t)[1 - k] == pytest.approx(0.0, abs=2e-4)   # the other pair hardly notices


def test_cell_difference_is_proportional_near_alignment():
    t = aligned(at_mst(10))
    el, az, dni, dhi = t.sun()
    k = P.cell_v_per_w_m2
    for delta in (0.25, 0.5, 1.0, 2.0):
        t.set_angles(az - delta, el)
        t.step(0.0, SENSORS)
        # sqrt(2) k DNI cos(sun elevation) sin(error): the azimuth pair's gain falls as cos(elevation).
        assert diffs(t)[AZ] == pytest.approx(math.sqrt(2) * k * dni * math.cos(math.radians(el))
                                             * math.sin(math.radians(delta)), rel=1e-3)
        t.set_angles(az, el - delta)
        t.step(0.0, SENSORS)
        assert diffs(t)[EL] == pytest.approx(math.sqrt(2) * k * dni * math.sin(math.radians(delta)), rel=2e-3)
    # About 12 mV per degree of elevation error at 10:00.
    assert diffs(t)[EL] / 2.0 == pytest.approx(0.0117, abs=0.001)


def test_cells_read_zero_with_sensor_power_off_or_the_sun_behind_them():
    t = aligned(at_mst(12), params=TRACKER_PARAMS)              # with noise
    assert all(v > 0.2 for v in t.cells_v)
    t.step(0.01, replace_cmd(SENSORS, sensor_power=False))
    assert t.cells_v == (0.0, 0.0, 0.0, 0.0)
    # Pointing away from the sun: only the diffuse light, the same on both cells (noise aside).
    q = aligned(at_mst(7))
    el, az, dni, dhi = q.sun()
    assert 15.0 < el < 25.0 and dni > 500.0                     # morning, sun in the east-north-east
    q.set_angles(az + 180.0, 0.0)                               # facing west, horizontal
    q.step(0.0, SENSORS)
    diffuse_v = P.cell_v_per_w_m2 * P.cell_diffuse_view * dhi
    assert q.cells_v == pytest.approx((diffuse_v,) * 4, abs=1e-12)


def replace_cmd(cmd: TrackerCommand, **changes) -> TrackerCommand:
    return cmd._replace(**changes)


# ---- relays ---------------------------------------------------------------------------------------------

def closed_at(t: TrackerPlant, cmd: TrackerCommand, steps: int, axis: int = AZ) -> list[tuple[bool, bool]]:
    out = []
    for _ in range(steps):
        t.step(0.001, cmd)
        out.append(tuple(t.relay_closed[axis]))
    return out


def test_relay_operate_and_release_times():
    t = TrackerPlant(QUIET, 0)
    seen = closed_at(t, drive(az=+1, duty_az=0.1), 30)
    assert seen.index((True, False)) == 14                      # closed at the end of the 15th ms
    seen = closed_at(t, drive(duty_az=0.1), 10)
    assert seen.index((False, False)) == 4                      # open 5 ms after the coil drops
    # A direct reversal: CW releases (5 ms), only then does CCW pick up (15 ms more).
    closed_at(t, drive(az=+1, duty_az=0.1), 30)
    seen = closed_at(t, drive(az=-1, duty_az=0.1), 30)
    assert seen.index((False, False)) == 4 and seen.index((False, True)) == 19
    assert (True, True) not in seen
    # A pulse shorter than the operate time never closes the contact.
    closed_at(t, drive(duty_az=0.1), 30)
    n = t.relay_closures[AZ]
    assert (True, False) not in closed_at(t, drive(az=+1, duty_az=0.1), 10) + closed_at(t, drive(duty_az=0.1), 20)
    assert t.relay_closures[AZ] == n
    # Within a long step the contact time is resolved: a 0.1 s step from rest drives for 85 ms.
    u = TrackerPlant(QUIET, 0)
    u.step(0.1, drive(el=+1))
    assert u.angle_deg[EL] == pytest.approx(P.top_speed_deg_s * 0.085, rel=0.25)


def test_both_directions_commanded_opens_both_and_is_counted():
    t = TrackerPlant(QUIET, 0)
    run(t, drive(az=+1, duty_az=0.1), 0.1)
    assert t.relay_closed[AZ] == [True, False]
    both = TrackerCommand(True, True, False, False, False, False, False, True, 0.1, 0.0)
    seen = closed_at(t, both, 20)
    assert seen[-1] == (False, False) and (True, True) not in seen
    assert t.both_relays_refused == [20, 0]
    run(t, both, 1.0)
    assert t.speed_deg_s[AZ] == 0.0                             # coasted to a stop
    angle = t.angle_deg[AZ]
    run(t, both, 1.0)
    assert t.angle_deg[AZ] == angle


def test_relays_are_never_both_closed_whatever_the_commands():
    rng = np.random.default_rng(5)
    t = TrackerPlant(QUIET, 0)
    for _ in range(5000):
        bits = rng.integers(0, 2, 4).astype(bool)
        cmd = TrackerCommand(*bits, False, False, False, True, float(rng.uniform()), float(rng.uniform()))
        t.step(float(rng.choice([0.0, 0.001, 0.004, 0.01, 0.03])), cmd)
        assert not all(t.relay_closed[AZ]) and not all(t.relay_closed[EL])
    assert t.both_closed_s == 0.0
    assert min(t.relay_closures) > 100 and min(t.both_relays_refused) > 100


def test_starting_at_high_duty_is_counted():
    t = TrackerPlant(QUIET, 0)
    run(t, drive(az=+1, duty_az=0.2), 0.1)                      # the dial low: fine
    run(t, drive(duty_az=0.2), 0.1)
    run(t, drive(az=-1, duty_az=0.9), 0.1)                      # reversing at 0.9: the report's warning
    assert t.relay_closures[AZ] == 2 and t.high_duty_starts[AZ] == 1


# ---- motors, limits, brakes -----------------------------------------------------------------------------

def steady_speed(duty: float, direction: int = +1, axis: int = EL) -> float:
    t = TrackerPlant(QUIET, 0)
    t.set_angles(180.0, 40.0)
    cmd = drive(az=direction, duty_az=duty) if axis == AZ else drive(el=direction, duty_el=duty)
    run(t, cmd, 2.0)
    before = t.angle_deg[axis]
    run(t, cmd, 10.0)
    return (t.angle_deg[axis] - before) / 10.0


def test_relay_cw_turns_the_axis_cw_at_a_speed_proportional_to_duty():
    speeds = {d: steady_speed(d) for d in (0.1, 0.25, 0.5, 1.0)}
    for d, v in speeds.items():
        assert v == pytest.approx(P.steady_speed_deg_s(d), rel=0.01)
        assert v / speeds[1.0] == pytest.approx(d, abs=0.015)   # proportional, but for the friction dead band
    assert speeds[1.0] * 60.0 == pytest.approx(35.2, abs=0.1)   # deg/min at full duty
    assert steady_speed(0.5, -1) == pytest.approx(-speeds[0.5], rel=1e-6)
    assert steady_speed(0.5, +1, AZ) == pytest.approx(speeds[0.5], rel=1e-6)
    assert steady_speed(0.01) == 0.0                            # inside the dead band: stiction holds


def test_no_motion_without_motor_power_and_the_supply_reads_zero():
    t = TrackerPlant(QUIET, 0)
    run(t, drive(az=+1, el=+1, motor_power=False), 2.0)
    assert t.angle_deg == [P.az.start_deg, P.el.start_deg] and t.current_a == [0.0, 0.0]
    assert t.motor_supply_v == 0.0 and t.relay_closed[AZ] == [True, False]
    run(t, drive(az=+1, el=+1), 0.5)
    assert t.motor_supply_v == pytest.approx(90.0 - 0.5 * sum(t.current_a), abs=1e-3)    # sags by I R
    assert sum(t.current_a) == pytest.approx(2 * 0.235, abs=0.01)   # no-load current 0.23 A a motor


def test_limit_switch_stops_the_axis_and_lets_it_back():
    t = TrackerPlant(QUIET, 0)
    t.set_angles(az_deg=P.az.limit_cw_deg - 0.05)
    run(t, drive(az=+1), 3.0)
    assert t.limits[0] and not t.limits[1]                      # limit_cw_az closed
    assert P.az.limit_cw_deg <= t.angle_deg[AZ] < P.az.limit_cw_deg + 0.25      # coasted past it a little (0.18)
    assert t.speed_deg_s[AZ] == 0.0 and t.current_a[AZ] == 0.0
    held = t.angle_deg[AZ]
    run(t, drive(az=+1), 3.0)
    assert t.angle_deg[AZ] == held
    run(t, drive(az=-1), 3.0)
    assert t.angle_deg[AZ] < P.az.limit_cw_deg and not t.limits[0]
    # The elevation's lower switch alike.
    t.set_angles(el_deg=P.el.limit_ccw_deg + 0.01)
    run(t, drive(el=-1), 2.0)
    assert t.limits[3] and t.angle_deg[EL] > P.el.limit_ccw_deg - 0.25


def test_hard_stop_stalls_the_motor_when_the_switch_does_not_cut_it():
    t = TrackerPlant(replace(QUIET, limit_switch_cuts_drive=False), 0)
    t.set_angles(az_deg=P.az.stop_cw_deg - 0.05)
    run(t, drive(az=+1, duty_az=0.5), 3.0)
    assert t.angle_deg[AZ] == P.az.stop_cw_deg and t.speed_deg_s[AZ] == 0.0
    assert t.limits[0]
    assert t.current_a[AZ] == pytest.approx(0.5 * t.motor_supply_true_v / P.r_ohm, rel=0.01)   # stall current


def test_brake_stops_the_axis_and_holds_it_whatever_the_drive():
    t = TrackerPlant(QUIET, 0)
    t.set_angles(180.0, 40.0)
    run(t, drive(az=+1, el=-1, brake=True), 5.0)                 # relays closed, full duty, brake on
    assert t.angle_deg == [180.0, 40.0] and t.current_a == [0.0, 0.0]       # exactly still, not driven
    run(t, drive(az=+1, el=-1), 2.0)                             # released: full speed
    moving = list(t.angle_deg)
    assert t.speed_deg_s[AZ] == pytest.approx(P.top_speed_deg_s, rel=0.01)
    t.step(0.01, drive(az=+1, el=-1, brake=True))
    assert t.current_a[AZ] < -1.0 and t.current_a[EL] > 1.0     # dynamic braking: the current reverses
    run(t, drive(az=+1, el=-1, brake=True), 0.2)
    assert t.speed_deg_s == [0.0, 0.0]                           # stopped within 0.2 s ...
    assert abs(t.angle_deg[AZ] - moving[AZ]) < 0.02 and abs(t.angle_deg[EL] - moving[EL]) < 0.02   # ... at once (0.011)
    held = list(t.angle_deg)
    run(t, drive(az=+1, el=-1, brake=True), 3.0)
    assert t.angle_deg == held
    assert t.high_duty_starts == [1, 1]                          # releasing the brake at full duty: a start


def test_bad_commands_are_refused():
    t = TrackerPlant(QUIET, 0)
    with pytest.raises(ValueError, match="duties"):
        t.step(0.01, drive(az=+1, duty_az=1.5))
    with pytest.raises(ValueError, match="duties"):
        t.step(0.01, drive(az=+1, duty_az=float("nan")))
    with pytest.raises(ValueError, match="dt_s"):
        t.step(-0.01, SAFE_COMMAND)
    with pytest.raises(ValueError, match="10 fields"):
        t.step(0.01, (True, False))
    with pytest.raises(ValueError, match="within its stops"):
        t.set_angles(az_deg=10.0)
    cmds = ExpiringTrackerCommands(0.1)
    with pytest.raises(ValueError, match="duties"):
        cmds.command(drive(duty_el=-0.1), 1, 0.0)
    with pytest.raises(ValueError, match="10 values"):
        cmds.command(list(range(12)), 1, 0.0)
    assert cmds.current(0.0) == SAFE_COMMAND


# ---- a whole stretch of day, closed around the cells ------------------------------------------------------

def test_a_bang_bang_loop_on_the_cells_keeps_the_beam_on_the_sun_through_noon():
    # The report's sensor mode, in the test: per axis, run toward the brighter cell at a fixed dial
    # speed, stop when the difference changes sign. 12:00-12:50 MST, when the azimuth turns fastest.
    t = TrackerPlant(TRACKER_PARAMS, 3, start=at_mst(12))
    el, az, _, _ = t.sun()
    t.set_angles(az, el)
    state = [0, 0]
    worst = 0.0
    dt = 0.02
    for n in range(round(50 * 60 / dt)):
        d = diffs(t)
        for k, threshold in ((AZ, 0.004), (EL, 0.004)):
            if state[k] == 0 and abs(d[k]) > threshold:
                state[k] = 1 if d[k] > 0 else -1
            elif state[k] * d[k] < 0:
                state[k] = 0
        t.step(dt, drive(az=state[AZ], el=state[EL], duty_az=0.5, duty_el=0.2, brake=False))
        if n % 50 == 0:
            worst = max(worst, t.angular_error_deg())
    assert worst < 0.5
    assert t.both_relays_refused == [0, 0] and t.both_closed_s == 0.0
    assert t.relay_closures[AZ] > 20 and t.relay_closures[EL] > 5


# ---- determinism and cost ---------------------------------------------------------------------------------

def script(t: TrackerPlant) -> list:
    out = []
    for cmd, seconds in ((drive(az=+1, el=+1, duty_az=0.3, duty_el=0.6), 2.0), (drive(az=-1), 1.0),
                         (SENSORS, 0.5)):
        for _ in range(round(seconds / 0.01)):
            t.step(0.01, cmd)
            out.append((tuple(t.cells_v), tuple(t.angles_measured_deg), t.motor_supply_v, tuple(t.angle_deg)))
    return out


def test_same_seed_same_numbers():
    first = script(TrackerPlant(TRACKER_PARAMS, 11, start=at_mst(11)))
    assert script(TrackerPlant(TRACKER_PARAMS, 11, start=at_mst(11))) == first
    other = script(TrackerPlant(TRACKER_PARAMS, 12, start=at_mst(11)))
    assert [r[0] for r in other] != [r[0] for r in first]        # the noise differs
    assert [r[3] for r in other] == [r[3] for r in first]        # the mechanics do not


def test_the_tracker_leaves_the_arms_noise_alone():
    a, b = (Plant(PlantParams(), np.random.default_rng(4)) for _ in range(2))
    run(a.tracker, drive(az=+1, el=+1), 1.0)
    readings = []
    for plant in (a, b):
        for _ in range(100):
            plant.step(0.001, False, True)
        readings.append((plant.supply_v, plant.temp_c))
    assert readings[0] == readings[1]


def test_an_arm_only_plant_never_imports_pvlib():
    code = ("import sys, numpy as np\n"
            "from hil_sim.plant import Plant, PlantParams\n"
            "p = Plant(PlantParams(), np.random.default_rng(0))\n"
            "p.tracker.step(0.01, p.tracker_commands.current(0.0))\n"
            "for _ in range(10): p.step(0.001, False, True)\n"
            "print('pandas' in sys.modules, 'pvlib' in sys.modules)\n")
    done = child.run([sys.executable, "-c", code], cwd=ROOT, text=True, timeout_s=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["False", "False"]


def test_steps_interpolate_the_suns_table_and_compute_the_day_once(monkeypatch):
    """Each step reads the tabulated sun (plain floats); pvlib runs once for the local day, never per step.
    (The cost per step is a figure of `make bench`: bench/bench_tracker.py prints each day's wall time.)"""
    import hil_sim.sun as sun

    loads = []
    real_chunk = sun._chunk
    monkeypatch.setattr(sun, "_chunk", lambda *args: loads.append(args) or real_chunk(*args))
    t = TrackerPlant(TRACKER_PARAMS, 0, start=at_mst(12))
    t.set_angles(*reversed(t.sun()[:2]))
    cmd = drive(az=+1, el=+1, duty_az=0.5, duty_el=0.5)
    before = list(t.angle_deg)
    for _ in range(5000):                                       # 50 simulated seconds
        t.step(0.01, cmd)
    assert len(loads) == 1
    assert t.angle_deg[AZ] > before[AZ] and t.angle_deg[EL] > before[EL]      # it did drive


# ---- on the bus -------------------------------------------------------------------------------------------

class BusRig:
    """A PlantNode with the tracker on a virtual channel, a stand-in controller on the same channel.

    Each 1 ms: the node steps at `now`; then the controller reads what the plant sent and, every
    10 ms while `sending`, sends TRACKER_CMD built from `cmd`.
    """

    def __init__(self, open_bus, tracker: bool = True, start: datetime = at_mst(9)) -> None:
        self.plant = Plant(PlantParams(), np.random.default_rng(1), start=start)
        self.node = PlantNode(open_bus(), self.plant, codec=CODEC, tracker=tracker)
        self.bus = open_bus()
        self.cmd = SAFE_COMMAND
        self.sending = True
        self.alive = 0
        self.now = 0.0
        self.ticks = 0
        self.frames: list[tuple[float, str, dict]] = []

    def run_for(self, seconds: float) -> None:
        for _ in range(round(seconds / 0.001)):
            self.node.step(self.now)
            while (msg := self.bus.recv(timeout=0)) is not None:
                name, values = CODEC.decode(msg)
                self.frames.append((self.now, name, values))
            if self.sending and self.ticks % 10 == 0:
                self.bus.send(CODEC.encode("TRACKER_CMD", alive=self.alive,
                                           **{k: (int(v) if isinstance(v, bool) else v)
                                              for k, v in self.cmd._asdict().items()}))
                self.alive = (self.alive + 1) % 256
            self.ticks += 1
            self.now = round(self.now + 0.001, 9)

    def seen(self, name: str) -> list[tuple[float, dict]]:
        return [(t, v) for t, n, v in self.frames if n == name]


def test_tracker_frames_every_10_ms_and_the_command_drives_the_axes(virtual_can):
    rig = BusRig(virtual_can())
    tracker = rig.plant.tracker
    el, az, _, _ = tracker.sun()
    tracker.set_angles(az - 2.0, el - 2.0)                      # the sun 2 deg CW of both axes
    rig.cmd = drive(az=+1, el=+1, duty_az=0.5, duty_el=0.5)
    rig.run_for(1.0)
    for name in ("TRACKER_SENSE", "TRACKER_POS"):
        times = [t for t, _ in rig.seen(name)]
        assert len(times) == 100
        assert all(b - a == pytest.approx(0.010) for a, b in zip(times, times[1:]))
        assert times[0] == pytest.approx(0.005)                 # tick 5: half-way between ANALOG_IN ticks
    assert rig.node.bad_frames == 0 and rig.node.bus_errors == 0
    sense = rig.seen("TRACKER_SENSE")[-1][1]
    pos = rig.seen("TRACKER_POS")[-1][1]
    assert sense["cell_az_a"] > sense["cell_az_b"] and sense["cell_el_a"] > sense["cell_el_b"]
    assert [sense[f"cell_{ax}_{c}"] for ax in ("az", "el") for c in "ab"] == \
        [pytest.approx(v, abs=0.0006) for v in tracker.cells_v]
    assert pos["angle_az"] == pytest.approx(tracker.angle_deg[AZ], abs=0.1)
    assert pos["angle_az"] > az - 2.0 and pos["angle_el"] > el - 2.0           # moving CW
    assert pos["motor_supply_v"] == pytest.approx(90.0, abs=0.5)
    assert (pos["limit_cw_az"], pos["limit_ccw_az"], pos["limit_cw_el"], pos["limit_ccw_el"]) == (0, 0, 0, 0)
    assert tracker.utc == to_utc(at_mst(9)) + timedelta(seconds=0.995)        # its clock follows the plant's
    # The arm's frames are as before.
    assert rig.node.sent_by_name["PLANT_SYNC"] == 1000 and rig.node.sent_by_name["ANALOG_IN"] == 100


def test_tracker_cmd_expires_after_100_ms(virtual_can):
    rig = BusRig(virtual_can())
    tracker = rig.plant.tracker
    tracker.set_angles(180.0, 40.0)
    rig.cmd = drive(az=+1, el=-1)
    rig.run_for(0.5)
    assert tracker.relay_closed == [[True, False], [False, True]]
    rig.sending = False
    stopped_s = rig.now
    rig.run_for(0.095)
    assert tracker.relay_closed == [[True, False], [False, True]]             # still fresh
    rig.run_for(0.03)
    assert tracker.relay_closed == [[False, False], [False, False]]           # expired: relays open
    assert rig.plant.tracker_commands.expired and rig.plant.tracker_commands.expiries == 1
    rig.run_for(0.2)
    assert tracker.speed_deg_s == [0.0, 0.0]                                 # brakes on: stopped
    held = list(tracker.angle_deg)
    rig.run_for(1.0)
    assert tracker.angle_deg == held
    assert all(v["cell_az_a"] == 0.0 for t, v in rig.seen("TRACKER_SENSE") if t > stopped_s + 0.12)
    assert rig.seen("TRACKER_POS")[-1][1]["motor_supply_v"] == 0.0          # motor power off too
    rig.sending = True
    rig.run_for(0.1)
    assert tracker.relay_closed == [[True, False], [False, True]]             # a fresh command applies again


def test_bad_tracker_cmd_is_counted_and_an_arm_only_node_sends_no_tracker_frames(virtual_can):
    rig = BusRig(virtual_can())
    data = bytearray(8)
    data[1:3] = (20000).to_bytes(2, "little")                  # duty_az = 2.0, outside its declared range
    rig.bus.send(can.Message(arbitration_id=CODEC.frame_id("TRACKER_CMD"), data=data, is_extended_id=False))
    rig.sending = False
    rig.run_for(0.02)
    assert rig.node.bad_frames == 1
    plain = BusRig(virtual_can(), tracker=False)
    plain.run_for(0.05)
    assert "TRACKER_SENSE" not in plain.node.sent_by_name and not plain.seen("TRACKER_POS")
    assert plain.plant.tracker.steps == 1                     # built (one sampling step), never stepped


def test_plant_node_steps_the_tracker_from_its_start_date_time(virtual_can):
    rig = BusRig(virtual_can(), start=at_mst(6))
    rig.cmd = SENSORS
    rig.run_for(0.2)
    el, az, dni, _ = rig.plant.tracker.sun()
    assert 5.0 < el < 12.0 and 60.0 < az < 75.0                  # just after sunrise, east-north-east
    assert statistics.mean(v["cell_az_b"] for _, v in rig.seen("TRACKER_SENSE")[-5:]) > \
        statistics.mean(v["cell_az_a"] for _, v in rig.seen("TRACKER_SENSE")[-5:])   # stowed at az 90: sun CCW
