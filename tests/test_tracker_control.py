"""The solar tracker's controller: relay logic, interlocks, temperature warning, ephemeris, feed-forward, the bus.

Unit tests drive `firmware_py.tracker.task.TrackerController` through a tiny stand-in HAL
(`StandIn`: the inputs as `ControllerHal` keeps them, the TRACKER_CMD frames it would send).
The tracker closed around its plant through a day (lag, hunting, the feed-forward, clouds) is
tested in tests/test_tracker_day.py. The bus tests run the whole controller on a
`LockstepBench`, once on a plant without the tracker (TRACKER_SENSE never arrives) and once
on a plant with the tracker, talking to it only through the link.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import random
from datetime import datetime, timedelta, timezone

import pytest

from firmware_py.tracker import task as T
from firmware_py.tracker.box import TempWatch, quantize_dial
from firmware_py.tracker.logic import DRIVE, FF_CLOSE_DEG_S, FF_ERROR_FILTER
from firmware_py.ephemeris import sun_position, sun_rates, wrap180
from firmware_py.hal import HalInputs
from firmware_py.params import ParamStore
from hil_sim.plant import PlantParams
from hil_sim.sun import MST, TUCSON, solar_position
from hil_sim.tracker import TRACKER_PARAMS, TrackerCommand
from host_tools.teleop import session as teleop
from host_tools.worlds.world import LockstepBench
from protocol.messages import MESSAGES as M
from host_tools.worlds.settings import PlantSettings
from protocol.reasons import Reason
from protocol.states import ControllerState, Fault, Switch, SwitchPosition as P, TempSide, TrackerAxis, TrackerWarning

AZ, EL, BOTH = TrackerAxis.AZ, TrackerAxis.EL, TrackerAxis.BOTH


# ---- a tiny stand-in for the HAL ------------------------------------------------------------------------------

class StandIn:
    """What the tracker sees of `ControllerHal`: `inputs`, and the TRACKER_CMD frames it sends."""

    def __init__(self) -> None:
        self.inputs = HalInputs()
        self.sent: list[TrackerCommand] = []

    def send_tracker_command(self, relays, brakes, sensor_power, motor_power, duties) -> bool:
        self.sent.append(TrackerCommand(bool(relays[0][0]), bool(relays[0][1]), bool(relays[1][0]),
                                        bool(relays[1][1]), bool(brakes[0]), bool(brakes[1]), bool(sensor_power),
                                        bool(motor_power), float(duties[0]), float(duties[1])))
        return True

    @property
    def last(self) -> TrackerCommand:
        return self.sent[-1]

    def feed(self, now: float, diff_az_mv: float = 0.0, diff_el_mv: float = 0.0, cell_sum_v: float = 0.66,
             angles=(180.0, 60.0), limits=((False, False), (False, False)), sense: bool = True,
             pos: bool = True) -> None:
        """Fresh TRACKER_SENSE (cells with these differences and sums) and TRACKER_POS at `now`."""
        if sense:
            cells = []
            for d in (diff_az_mv / 1000.0, diff_el_mv / 1000.0):
                cells += [(cell_sum_v + d) / 2, (cell_sum_v - d) / 2]
            self.inputs.cells_v, self.inputs.sense_s = cells, now
        if pos:
            self.inputs.tracker_angles_deg = list(angles)
            self.inputs.tracker_limits = [list(limits[0]), list(limits[1])]
            self.inputs.motor_supply_v, self.inputs.pos_s = 90.0, now


def make(allowed: bool = True, **params):
    """A tracker on a stand-in, the photocell filter off (each reading counts at once) unless asked."""
    store = ParamStore(T.parameter_table())
    params.setdefault("trk_filter_s", 0.0)
    for name, value in params.items():
        assert store.set(name, value)[0] is Reason.OK, name
    hal = StandIn()
    state = {"allowed": allowed}
    tracker = T.TrackerController(hal, store, 0.01, allowed=lambda: state["allowed"])
    return tracker, hal, state


def running(mode=P.SENSOR, dial: float = 0.0, **params):
    """The box set up as the operating instructions say (dial low), then the dial turned to `dial`."""
    tracker, hal, state = make(**params)
    for switch, position in ((Switch.MODE, mode), (Switch.SENSOR, P.ON), (Switch.MAIN, P.ON), (Switch.SPEED, P.ON)):
        assert tracker.switch(switch, position) == (Reason.OK, "")
    assert tracker.dial(dial)[0] is Reason.OK
    return tracker, hal, state


def relays(cmd: TrackerCommand, axis: int = 0) -> int:
    cw, ccw = (cmd.relay_cw_az, cmd.relay_ccw_az) if axis == 0 else (cmd.relay_cw_el, cmd.relay_ccw_el)
    return 1 if cw else -1 if ccw else 0


def tick(tracker, hal, now: float, **feed) -> TrackerCommand:
    hal.feed(now, **feed)
    tracker.step(now)
    return hal.last


# ---- the relay logic ---------------------------------------------------------------------------------------------

def test_at_boot_the_box_is_off_and_nothing_drives():
    tracker, hal, _ = make()
    out = tick(tracker, hal, 0.0, diff_az_mv=50.0, diff_el_mv=-50.0)
    assert out == TrackerCommand()           # relays open, brakes on, no sensor or motor power, duty 0
    box = tracker.box
    assert (box.main, box.sensor, box.mode, box.direction, box.speed, box.dial_counts) == (
        P.OFF, P.OFF, [P.MANUAL] * 2, [P.CW] * 2, [P.BRAKE] * 2, [0, 0])


def test_sensor_mode_closes_beyond_the_deadband_and_opens_inside_the_hysteresis():
    tracker, hal, _ = running(dial=40.0, trk_deadband_mv=2.0, trk_hyst_mv=1.5, trk_dwell_s=0.0)
    now = 0.0
    sequence = [(1.9, 0), (2.1, 1), (1.0, 1), (0.6, 1), (0.4, 0), (-1.9, 0), (-2.1, -1), (-0.6, -1), (-0.4, 0)]
    for diff_mv, expected in sequence:
        now += 0.01
        out = tick(tracker, hal, now, diff_az_mv=diff_mv)
        assert relays(out, 0) == expected, (diff_mv, out)
        assert relays(out, 1) == 0                                   # el's cells read 0 difference
        assert out.duty_az == (pytest.approx(quantize_dial(40.0) / 1023) if expected else 0.0)
        assert not out.brake_az and out.motor_power and out.sensor_power


def test_a_closing_waits_for_the_dwell_but_an_opening_never_waits():
    tracker, hal, _ = running(dial=40.0, trk_dwell_s=0.5, trk_chatter_s=2.0)
    assert relays(tick(tracker, hal, 0.0, diff_el_mv=5.0), 1) == 1           # first closing: no previous change
    assert relays(tick(tracker, hal, 0.1, diff_el_mv=0.0), 1) == 0           # opens at once, 0.1 s later
    for now in (0.2, 0.3, 0.59):
        assert relays(tick(tracker, hal, now, diff_el_mv=5.0), 1) == 0       # wants to close: dwell not over
    assert relays(tick(tracker, hal, 0.61, diff_el_mv=5.0), 1) == 1          # 0.51 s after the opening
    ax = tracker.axes[1]
    assert (ax.switchings, ax.chatter, ax.reversals) == (3, 1, 0)            # close, open, close; re-closed in 0.51 s
    assert relays(tick(tracker, hal, 0.62, diff_el_mv=-5.0), 1) == 0         # a reversal opens at once ...
    assert relays(tick(tracker, hal, 1.0, diff_el_mv=-5.0), 1) == 0          # ... then waits out the dwell
    assert relays(tick(tracker, hal, 1.13, diff_el_mv=-5.0), 1) == -1
    assert (ax.switchings, ax.chatter, ax.reversals) == (5, 2, 1)


def test_relays_are_never_both_closed_and_every_reversal_passes_through_open():
    tracker, hal, _ = running(dial=60.0, trk_dwell_s=0.3, trk_filter_s=0.05)
    rng = random.Random(7)
    now, last_change, previous = 0.0, [-1.0, -1.0], [0, 0]
    diff = [0.0, 0.0]
    for _ in range(5000):
        now += 0.01
        diff = [d + rng.gauss(0.0, 1.5) - 0.05 * d for d in diff]           # a wandering, noisy difference
        out = tick(tracker, hal, now, diff_az_mv=diff[0], diff_el_mv=diff[1])
        assert not (out.relay_cw_az and out.relay_ccw_az) and not (out.relay_cw_el and out.relay_ccw_el)
        for k in (0, 1):
            r = relays(out, k)
            if r != previous[k]:
                assert previous[k] == 0 or r == 0, "a direct reversal"
                if r != 0:
                    assert now - last_change[k] >= 0.3 - 1e-9, "closed within the dwell"
                last_change[k] = now
                previous[k] = r
    assert all(ax.switchings > 20 and ax.reversals > 5 for ax in tracker.axes)   # it did switch, both ways


def test_manual_mode_drives_by_the_direction_switch_at_the_dial():
    tracker, hal, _ = running(mode=P.MANUAL, dial=30.0, trk_dwell_s=0.2)
    out = tick(tracker, hal, 0.0, diff_az_mv=-50.0)                    # the cells do not matter in manual
    assert (relays(out, 0), relays(out, 1)) == (1, 1)
    assert out.duty_az == out.duty_el == pytest.approx(quantize_dial(30.0) / 1023)
    assert tracker.switch(Switch.DIRECTION, P.CCW, AZ)[0] is Reason.DIAL_NOT_LOW     # dial high: refused
    assert tracker.dial(2.0, AZ)[0] is Reason.OK
    assert tracker.switch(Switch.DIRECTION, P.CCW, AZ) == (Reason.OK, "")
    assert relays(tick(tracker, hal, 0.01), 0) == 0                    # through open ...
    assert relays(tick(tracker, hal, 0.1), 0) == 0
    out = tick(tracker, hal, 0.25)
    assert relays(out, 0) == -1 and relays(out, 1) == 1                # ... to CCW after the dwell; el unchanged
    assert out.duty_az == pytest.approx(quantize_dial(2.0) / 1023)


def test_speed_switch_at_brake_and_main_power_off_stop_everything_at_once():
    tracker, hal, _ = running(mode=P.MANUAL, dial=30.0)
    assert relays(tick(tracker, hal, 0.0), 0) == 1
    assert tracker.switch(Switch.SPEED, P.BRAKE, EL)[0] is Reason.OK   # always allowed, dial high or not
    out = tick(tracker, hal, 0.01)
    assert relays(out, 0) == 1 and not out.brake_az
    assert relays(out, 1) == 0 and out.brake_el and out.duty_el == 0.0
    assert tracker.switch(Switch.MAIN, P.OFF)[0] is Reason.OK
    out = tick(tracker, hal, 0.02)
    assert out == TrackerCommand(brake_az=True, brake_el=True, sensor_power=True, motor_power=False)


def test_no_drive_in_sensor_mode_without_sensor_power_or_fresh_photocells():
    tracker, hal, _ = running(dial=40.0, trk_dwell_s=0.0, trk_stale_s=0.1)
    assert relays(tick(tracker, hal, 0.0, diff_az_mv=10.0), 0) == 1
    assert tracker.switch(Switch.SENSOR, P.OFF)[0] is Reason.OK
    out = tick(tracker, hal, 0.01, diff_az_mv=10.0)
    assert relays(out, 0) == 0 and not out.sensor_power and not out.brake_az    # held, the speed switch on
    assert tracker.switch(Switch.SENSOR, P.ON)[0] is Reason.OK
    assert relays(tick(tracker, hal, 0.02, diff_az_mv=10.0), 0) == 1
    # TRACKER_SENSE stops: after trk_stale_s the relay opens and SENSE_STALE is raised; no fault anywhere
    assert relays(tick(tracker, hal, 0.12, sense=False), 0) == 1
    out = tick(tracker, hal, 0.13, sense=False)
    assert relays(out, 0) == 0 and tracker.warnings & TrackerWarning.SENSE_STALE
    assert relays(tick(tracker, hal, 0.2, diff_az_mv=10.0), 0) == 1             # frames back: drives again
    assert not tracker.warnings & TrackerWarning.SENSE_STALE


def test_a_stale_position_frame_stops_every_mode_and_a_limit_switch_its_direction():
    tracker, hal, _ = running(mode=P.MANUAL, dial=30.0, trk_dwell_s=0.0)
    assert relays(tick(tracker, hal, 0.0), 0) == 1
    out = tick(tracker, hal, 0.2, pos=False)
    assert relays(out, 0) == 0 and out.brake_az and tracker.warnings & TrackerWarning.POS_STALE
    out = tick(tracker, hal, 0.3, limits=((True, False), (False, False)))   # az CW limit closed
    assert relays(out, 0) == 0 and relays(out, 1) == 1 and tracker.warnings & TrackerWarning.LIMIT_AZ
    assert tracker.dial(0.0, AZ)[0] is Reason.OK and tracker.switch(Switch.DIRECTION, P.CCW, AZ)[0] is Reason.OK
    assert relays(tick(tracker, hal, 0.4, limits=((True, False), (False, False))), 0) == -1   # away from it: fine


def test_nothing_drives_unless_the_supervisor_allows_outputs():
    tracker, hal, state = running(mode=P.MANUAL, dial=30.0)
    state["allowed"] = False
    out = tick(tracker, hal, 0.0)
    assert out == TrackerCommand(sensor_power=True)        # relays open, brakes on, no motor power
    assert tracker.warnings & TrackerWarning.NOT_ENABLED
    state["allowed"] = True
    assert relays(tick(tracker, hal, 0.01), 0) == 1


def test_the_safe_state_hook_opens_the_relays_and_puts_the_speed_switches_to_brake():
    tracker, hal, _ = running(mode=P.MANUAL, dial=30.0)
    tick(tracker, hal, 0.0)
    tracker.safe()
    assert hal.last == TrackerCommand(sensor_power=True)
    assert tracker.box.speed == [P.BRAKE, P.BRAKE]
    assert relays(tick(tracker, hal, 1.0), 0) == 0                                   # stays stopped
    assert tracker.switch(Switch.SPEED, P.ON)[0] is Reason.DIAL_NOT_LOW             # a restart: the interlock


# ---- the interlocks ----------------------------------------------------------------------------------------------

def _high_dial_box(setup):
    tracker, hal, state = make()
    for switch, position, axis in setup:
        assert tracker.switch(switch, position, axis)[0] is Reason.OK
    assert tracker.dial(50.0)[0] is Reason.OK
    return tracker, hal


def _positions(box, switch: Switch) -> list:
    return {Switch.MAIN: [box.main], Switch.SENSOR: [box.sensor], Switch.MODE: box.mode,
            Switch.DIRECTION: box.direction, Switch.SPEED: box.speed}[switch]


@pytest.mark.parametrize("setup, command", [
    ([], (Switch.SPEED, P.ON, BOTH)),                                              # starting
    ([], (Switch.SPEED, P.ON, EL)),
    ([(Switch.SPEED, P.ON, AZ)], (Switch.MAIN, P.ON, BOTH)),                       # main on while speed on
    ([], (Switch.MODE, P.SENSOR, BOTH)),                                           # manual -> sensor
    ([(Switch.MODE, P.SENSOR, EL)], (Switch.MODE, P.MANUAL, EL)),                  # sensor -> manual
    ([], (Switch.DIRECTION, P.CCW, AZ)),                                           # changing direction
    ([(Switch.MAIN, P.ON, BOTH), (Switch.SPEED, P.ON, BOTH)], (Switch.DIRECTION, P.CCW, BOTH)),  # while running
])
def test_each_interlock_refuses_with_its_reason_and_changes_nothing(setup, command):
    tracker, hal = _high_dial_box(setup)
    tick(tracker, hal, 0.0)
    before_box, before_out, before_refusals = copy.deepcopy(tracker.box), hal.last, tracker.refusals
    reason, detail = tracker.switch(*command)
    assert reason is Reason.DIAL_NOT_LOW and "dial" in detail and "50.0 %" in detail
    assert tracker.box == before_box and tracker.refusals == before_refusals + 1
    assert tick(tracker, hal, 0.01) == before_out                  # the outputs did not change either
    assert tracker.dial(5.0)[0] is Reason.OK                       # low: 51 counts = 4.99 %, at the limit
    assert tracker.switch(*command) == (Reason.OK, "")
    switch, position, axis = command
    moved = _positions(tracker.box, switch)
    addressed = range(len(moved)) if axis is BOTH or len(moved) == 1 else [int(axis)]
    assert all(moved[k] is position for k in addressed)


def test_what_the_interlocks_leave_alone():
    tracker, hal = _high_dial_box([(Switch.MAIN, P.ON, BOTH), (Switch.SPEED, P.ON, BOTH)])
    assert tracker.switch(Switch.SPEED, P.BRAKE) == (Reason.OK, "")         # stopping: always
    assert tracker.switch(Switch.MAIN, P.OFF) == (Reason.OK, "")
    assert tracker.switch(Switch.MAIN, P.ON) == (Reason.OK, "")             # speed at brake: not a start
    assert tracker.switch(Switch.SENSOR, P.ON) == (Reason.OK, "")
    assert tracker.switch(Switch.DIRECTION, P.CW) == (Reason.OK, "")        # already there: no change
    assert tracker.refusals == 0


@pytest.mark.parametrize("command, reason", [
    ((Switch.MAIN, P.CW, BOTH), Reason.SWITCH_POSITION),
    ((Switch.SPEED, P.OFF, BOTH), Reason.SWITCH_POSITION),
    ((Switch.MODE, P.ON, AZ), Reason.SWITCH_POSITION),
    ((Switch.MAIN, P.ON, AZ), Reason.OUT_OF_RANGE),          # one main switch for both axes
    ((Switch.SENSOR, P.ON, EL), Reason.OUT_OF_RANGE),
    ((9, P.ON, BOTH), Reason.OUT_OF_RANGE),
])
def test_a_position_the_switch_does_not_have_is_refused_and_changes_nothing(command, reason):
    tracker, _hal, _ = make()
    before = copy.deepcopy(tracker.box)
    assert tracker.switch(*command)[0] is reason
    assert tracker.box == before and tracker.refusals == 0


def test_the_dial_reads_as_a_ten_bit_adc():
    tracker, hal, _ = make()
    assert tracker.dial(12.5)[0] is Reason.OK
    assert tracker.box.dial_counts == [128, 128]                       # round(0.125 x 1023) = 128
    assert tracker.box.dial_pct(0) == pytest.approx(12.512, abs=1e-3)
    assert tracker.dial(100.0, EL)[0] is Reason.OK and tracker.box.dial_counts == [128, 1023]
    for bad in (-0.1, 100.1, math.nan, math.inf):
        assert tracker.dial(bad)[0] is Reason.OUT_OF_RANGE
    assert tracker.box.dial_counts == [128, 1023]
    assert len({quantize_dial(p / 100) for p in range(10001)}) == 1024          # every count reachable
    tracker.switch(Switch.MODE, P.MANUAL)
    for switch in (Switch.SENSOR, Switch.MAIN):
        tracker.switch(switch, P.ON)
    assert tracker.dial(0.0)[0] is Reason.OK and tracker.switch(Switch.SPEED, P.ON)[0] is Reason.OK
    assert tracker.dial(12.5)[0] is Reason.OK
    out = tick(tracker, hal, 0.0)
    assert out.duty_az == out.duty_el == pytest.approx(128 / 1023)             # what the speed controller gets


def test_parameters_that_would_break_the_hysteresis_are_refused():
    tracker, _hal, _ = make()
    store = tracker.params
    store._check = lambda name, value: T.check_param(store, name, value)     # as the controller wires it
    assert store.set("trk_hyst_mv", 3.0)[0] is Reason.OUT_OF_RANGE            # above the 2 mV deadband
    assert store.set("trk_deadband_mv", 1.0)[0] is Reason.OUT_OF_RANGE        # below the 1.5 mV hysteresis
    assert store.set("trk_ff", 0.5)[0] is Reason.OUT_OF_RANGE
    assert (store["trk_hyst_mv"], store["trk_deadband_mv"], store["trk_ff"]) == (1.5, 2.0, 0.0)


# ---- the temperature warning -------------------------------------------------------------------------------------

def test_temperature_warning_near_each_limit_once_per_crossing():
    watch = TempWatch()
    seen = []
    for temp in (20.0, 39.9, 40.0, 40.3, 44.0, 46.0, 39.8, 39.6, 39.4, 39.8, 40.0, math.nan, 20.0,
                 -4.9, -5.0, -6.0, -4.6, -4.4):
        seen += [(temp, side, active) for side, active, _limit in watch.update(temp, -10.0, 45.0, 5.0)]
    assert seen == [(40.0, TempSide.HOT, True), (39.4, TempSide.HOT, False), (40.0, TempSide.HOT, True),
                    (20.0, TempSide.HOT, False), (-5.0, TempSide.COLD, True), (-4.4, TempSide.COLD, False)]
    assert watch.update(-7.0, -10.0, 45.0, 5.0) == [(TempSide.COLD, True, -10.0)]
    assert watch.flags == TrackerWarning.TEMP_LOW


def test_temperature_warning_a_reading_seen_again_is_not_judged_again_and_a_changed_limit_is():
    """The health task asks at every run, mostly with the same reading (issue 35: the same reading and limits are
    not judged again): a crossing still comes at the first reading or limit that makes it, and once only."""
    watch = TempWatch()
    assert [watch.update(41.0, -10.0, 45.0, 3.0) for _ in range(3)] == [[], [], []]      # 4 below the limit
    assert watch.update(41.0, -10.0, 45.0, 5.0) == [(TempSide.HOT, True, 45.0)]         # temp_warn_c widened
    assert watch.update(41.0, -10.0, 45.0, 5.0) == [] and watch.flags == TrackerWarning.TEMP_HIGH
    assert watch.update(41.0, -10.0, 44.0, 2.0) == [(TempSide.HOT, False, 44.0)]        # narrowed: back inside
    assert watch.update(math.nan, -10.0, 44.0, 2.0) == [] and watch.update(42.0, -10.0, 44.0, 2.0) == [
        (TempSide.HOT, True, 44.0)]


# ---- the ephemeris -----------------------------------------------------------------------------------------------

def test_ephemeris_against_the_nrel_spa_papers_example():
    # Reda and Andreas (2004/2008), the SPA paper's example: 2003-10-17 12:30:30 UTC-7 at 39.742476 N,
    # 105.1786 W, 820 mbar, 11 C -> topocentric zenith 50.11162 deg, azimuth 194.34024 deg.
    when = datetime(2003, 10, 17, 12, 30, 30, tzinfo=timezone(timedelta(hours=-7))).timestamp()
    sun = sun_position(when, 39.742476, -105.1786, 820.0, 11.0)
    assert 90.0 - sun.elevation_deg == pytest.approx(50.11162, abs=0.05)
    assert sun.azimuth_deg == pytest.approx(194.34024, abs=0.05)
    assert 90.0 - sun.elevation_deg == pytest.approx(50.11162, abs=0.005)     # measured: 3e-5 and 0.0023 deg
    assert sun.azimuth_deg == pytest.approx(194.34024, abs=0.005)


def test_ephemeris_puts_the_june_solstice_where_the_almanac_does():
    # The June solstice of 2026 is on June 21 at 08:24 UT (USNO, "Earth's Seasons"): the declination
    # peaks then, at the obliquity of the ecliptic, 23.436 deg in 2026 (plus 0.002 deg of nutation).
    solstice = datetime(2026, 6, 21, 8, 24, tzinfo=timezone.utc).timestamp()
    samples = [solstice + k * 600.0 for k in range(-144, 145)]          # +-1 day, every 10 minutes
    peak = max(samples, key=lambda t: sun_position(t, 0.0, 0.0).declination_deg)
    assert abs(peak - solstice) <= 3600.0
    assert sun_position(solstice, 0.0, 0.0).declination_deg == pytest.approx(23.438, abs=0.005)
    # at a site's solar noon the sun is due south, at 90 - latitude + declination
    # (near 19:26 UT at 111 W: 12:00 local mean time is 19:24 UT, and the equation of time is -1.7 min)
    day = datetime(2026, 6, 21, 19, 0, tzinfo=timezone.utc).timestamp()
    noon = min((day + k for k in range(0, 3600, 10)), key=lambda t: abs(sun_position(t, 32.0, -111.0, 0.0)
                                                                          .hour_angle_deg))
    assert noon - day == pytest.approx((24 + 1.7) * 60, abs=30.0)
    sun = sun_position(noon, 32.0, -111.0, 0.0)
    assert sun.azimuth_deg == pytest.approx(180.0, abs=0.5)
    assert sun.elevation_deg == pytest.approx(90.0 - 32.0 + sun.declination_deg, abs=0.01)


def test_ephemeris_follows_the_plants_spa_over_a_day_at_tucson():
    start = datetime(2026, 6, 21, 5, 30, tzinfo=MST)
    times = [start + timedelta(minutes=m) for m in range(0, 14 * 60, 10)]
    ref = solar_position(times, TUCSON)
    site = (TUCSON.latitude_deg, TUCSON.longitude_deg, 928.8, TUCSON.temperature_c)
    worst_az = worst_el = 0.0
    for when, az, el in zip(times, ref["azimuth"], ref["apparent_elevation"]):
        if el < 1.0:
            continue
        sun = sun_position(when.timestamp(), *site)
        worst_az = max(worst_az, abs(wrap180(sun.azimuth_deg - az)))
        worst_el = max(worst_el, abs(sun.elevation_deg - el))
    assert worst_az < 0.02 and worst_el < 0.01                        # measured: 0.0095 and 0.0036 deg
    # the rates the feed-forward uses: the SPA's own, by a difference over a minute
    for when in (start + timedelta(hours=3), start + timedelta(hours=6, minutes=55)):
        a = solar_position([when - timedelta(seconds=30), when + timedelta(seconds=30)], TUCSON)
        rate_az, rate_el = sun_rates(when.timestamp(), *site)
        assert rate_az == pytest.approx(wrap180(a["azimuth"][1] - a["azimuth"][0]) / 60.0, rel=0.01, abs=2e-6)
        assert rate_el == pytest.approx((a["apparent_elevation"][1] - a["apparent_elevation"][0]) / 60.0,
                                        rel=0.01, abs=2e-6)
    transit = datetime(2026, 6, 21, 12, 25, tzinfo=MST).timestamp()
    assert sun_rates(transit, *site)[0] * 60 == pytest.approx(1.50, abs=0.02)   # deg/min, the design day's fastest


# ---- the feed-forward --------------------------------------------------------------------------------------------

def test_the_firmwares_drive_model_matches_the_plants_numbers():
    for duty in (0.02, 0.05, 0.1, 0.3, 0.5, 1.0):
        assert DRIVE.speed_deg_s(duty) == pytest.approx(TRACKER_PARAMS.steady_speed_deg_s(duty), rel=1e-9)
        assert DRIVE.duty_for(DRIVE.speed_deg_s(duty)) == pytest.approx(duty)


def test_feed_forward_sets_the_duty_from_the_suns_rate_and_the_dial_caps_it():
    when = datetime(2026, 6, 21, 12, 25, tzinfo=MST).timestamp()          # transit: azimuth at 1.5 deg/min
    tracker, hal, _ = running(dial=100.0, trk_ff=1)
    tracker.set_clock(when, 0.0)
    out = tick(tracker, hal, 0.0, angles=(180.0, 81.0))
    rate_az, rate_el = tracker.sun_rates()
    assert rate_az == pytest.approx(1.50 / 60, abs=0.001) and tracker.ff_active
    assert relays(out, 0) == 1 and out.duty_az == pytest.approx(DRIVE.duty_for(rate_az, 90.0))
    assert DRIVE.speed_deg_s(out.duty_az) == pytest.approx(rate_az)      # the speed the sun needs
    assert abs(rate_el) < FF_CLOSE_DEG_S and relays(out, 1) == 0  # el: standstill
    # the photocells say the sun is ahead (CW) by atan(4 mV / 0.66 V) / cos(81 deg) = 2.2 deg of azimuth
    out = tick(tracker, hal, 0.01, diff_az_mv=4.0, angles=(180.0, 81.0))
    error = math.degrees(math.atan(0.004 / 0.66)) / math.cos(math.radians(81.0))
    filtered = error * -math.expm1(-0.01 / (FF_ERROR_FILTER * 30.0))          # its low-pass, one step on
    correction = filtered / 30.0
    assert tracker.axes[0].rate_cmd_dps == pytest.approx(rate_az + correction, rel=1e-6)
    assert out.duty_az > quantize_dial(3.0) / 1023
    assert tracker.dial(3.0, AZ)[0] is Reason.OK
    out = tick(tracker, hal, 0.02, diff_az_mv=4.0, angles=(180.0, 81.0))
    assert out.duty_az == pytest.approx(quantize_dial(3.0) / 1023)       # capped by the dial


def test_feed_forward_without_a_clock_falls_back_to_the_relay_logic_and_says_so():
    tracker, hal, _ = running(dial=40.0, trk_ff=1)
    out = tick(tracker, hal, 0.0, diff_az_mv=5.0)
    assert relays(out, 0) == 1 and out.duty_az == pytest.approx(quantize_dial(40.0) / 1023)
    assert tracker.warnings & TrackerWarning.FF_FALLBACK and tracker.warnings & TrackerWarning.NO_CLOCK
    assert not tracker.ff_active
    night = datetime(2026, 6, 21, 23, 0, tzinfo=MST).timestamp()
    tracker.set_clock(night, 0.0)
    out = tick(tracker, hal, 0.01, diff_az_mv=5.0)
    assert relays(out, 0) == 0 and tracker.warnings & TrackerWarning.SUN_DOWN


# ---- over the HAL bus and the link -------------------------------------------------------------------------------

@pytest.fixture
def plain_bench():
    """A world whose plant has no tracker, so TRACKER_SENSE and TRACKER_POS never arrive."""
    bench = LockstepBench(seed=5, plant=PlantSettings(tracker=False))
    assert bench.connect()
    yield bench
    bench.close()


def tracker_telemetry(bench):
    return [m for m in bench.telemetry if m.spec.name == "TelemetryTracker"]


def box_on(bench, mode: str = "sensor", dials=("40 az", "20 el")) -> None:
    """The operating instructions, typed as an operator would at teleop."""
    for line in ("dial 0", f"switch mode {mode}", "switch sensor on", "switch main on", "switch speed on", *(
            f"dial {d}" for d in dials)):
        handle = bench.call(teleop.parse_line(line, 1).message)
        assert handle.ok, (line, handle.describe())


def test_without_the_trackers_frames_the_controller_runs_on_and_says_why_the_tracker_does_not(plain_bench):
    bench = plain_bench
    box_on(bench, mode="manual")
    assert bench.call(M["Enable"]()).ok
    sent = bench.controller.hal.sent_by_name.get("TRACKER_CMD", 0)
    bench.run_for(2.0)
    assert bench.controller.supervisor.state is ControllerState.ENABLED and not bench.controller.supervisor.faults
    assert 195 <= bench.controller.hal.sent_by_name["TRACKER_CMD"] - sent <= 205     # every 10 ms regardless
    last = tracker_telemetry(bench)[-1]
    assert last.warnings & TrackerWarning.SENSE_STALE and last.warnings & TrackerWarning.POS_STALE
    assert (last.relay_az, last.relay_el, last.brake_az, last.duty_az) == (0, 0, True, 0.0)
    assert bench.call(M["Ping"](3)).ok                        # and the link, the arm's loop go on


def test_the_box_over_the_link_refuses_by_the_interlocks_and_reports_its_state(plain_bench):
    bench = plain_bench
    assert teleop.parse_line("switch mode sensor", 1).message == M["BoxSwitch"](int(Switch.MODE), int(P.SENSOR),
                                                                                 int(BOTH))
    assert teleop.parse_line("switch direction ccw az", 1).message == M["BoxSwitch"](3, int(P.CCW), int(AZ))
    assert teleop.parse_line("dial 12.5", 1).message == M["BoxDial"](12.5, int(BOTH))
    assert bench.call(teleop.parse_line("dial 50", 1).message).reply.dial_az == pytest.approx(50.048876, abs=1e-4)
    refused = bench.call(teleop.parse_line("switch speed on", 1).message)
    assert refused.reason is Reason.DIAL_NOT_LOW
    assert (refused.reply.speed_az, refused.reply.speed_el) == (P.BRAKE, P.BRAKE)   # unchanged
    assert bench.call(teleop.parse_line("switch main cw", 1).message).reason is Reason.SWITCH_POSITION
    with pytest.raises(teleop.TeleopError):
        teleop.parse_line("dial 101", 1)                      # refused before it is sent
    assert bench.call(teleop.parse_line("switch sensor on", 1).message).ok
    bench.run_for(0.3)
    last = tracker_telemetry(bench)[-1]                       # sensor power on: the box is in use
    assert last.refusals == 1 and last.sensor == P.ON and last.dial_az == pytest.approx(50.048876, abs=1e-4)


def test_a_temperature_warning_once_per_crossing_and_no_fault():
    bench = LockstepBench(seed=6, plant_params=PlantParams(ambient_c=41.0))
    try:
        assert bench.connect()
        bench.run_for(2.0)
        warnings = [e for e in bench.events if e.spec.name == "TemperatureWarning"]
        assert [(w.side, w.active, w.limit_c) for w in warnings] == [(TempSide.HOT, True, 45.0)]
        assert 40.0 <= warnings[0].temp_c < 45.0
        assert bench.controller.supervisor.state is ControllerState.IDLE
        bench.world.plant.temp_true_c = 30.0                 # the box cooled (a fan, the shade)
        bench.run_for(0.5)
        warnings = [e for e in bench.events if e.spec.name == "TemperatureWarning"]
        assert [(w.side, w.active) for w in warnings] == [(TempSide.HOT, True), (TempSide.HOT, False)]
    finally:
        bench.close()


@pytest.mark.parametrize("ambient_c, side, beyond_c", [(-7.0, TempSide.COLD, -12.0), (42.0, TempSide.HOT, 47.0)])
def test_near_a_temperature_limit_a_warning_and_beyond_it_the_safe_state(ambient_c, side, beyond_c):
    bench = LockstepBench(seed=7, plant_params=PlantParams(ambient_c=ambient_c),
                          plant=PlantSettings(start=datetime(2026, 6, 21, 10, 0, tzinfo=MST)))
    try:
        assert bench.connect()
        box_on(bench, mode="manual")
        assert bench.call(M["Enable"]()).ok
        bench.run_for(2.0)
        plant, sup = bench.world.plant, bench.controller.supervisor
        warnings = [e for e in bench.events if e.spec.name == "TemperatureWarning"]
        assert [(w.side, w.active) for w in warnings] == [(side, True)]
        assert sup.state is ControllerState.ENABLED and plant.tracker.relay_closed[0] == [True, False]   # a warning only
        plant.temp_true_c = beyond_c
        plant.params = dataclasses.replace(plant.params, ambient_c=beyond_c)      # and it stays there
        bench.run_for(0.5)
        assert sup.state is ControllerState.FAULT and sup.faults & Fault.OVER_TEMPERATURE
        assert plant.tracker.relay_closed == [[False, False], [False, False]]      # the safe state, at the plant
        assert bench.call(M["Reset"]()).reason is Reason.OVER_TEMPERATURE          # still out of range: latched
    finally:
        bench.close()


@pytest.fixture
def tracker_bench():
    """A LockstepBench whose plant runs the tracker, from 10:00 MST on the June solstice at Tucson."""
    bench = LockstepBench(seed=2, plant=PlantSettings(start=datetime(2026, 6, 21, 10, 0, tzinfo=MST)))
    assert bench.connect()
    yield bench
    bench.close()


@pytest.mark.long
def test_over_the_bus_the_tracker_closes_on_the_sun_and_the_feed_forward_holds_it(tracker_bench):
    bench = tracker_bench
    tracker = bench.world.plant.tracker
    el, az, _, _ = tracker.sun()
    tracker.set_angles(az - 1.0, el - 0.6)                   # the sun CW of the tracker on both axes
    utc = tracker.utc.timestamp()
    assert bench.call(M["SetClock"](int(utc), int(round((utc % 1) * 1000)) % 1000)).ok
    box_on(bench)
    assert bench.call(M["Enable"]()).ok
    assert bench.call(M["SetTelemetryRate"](10)).ok
    bench.run_for(1.0)
    first = tracker_telemetry(bench)[-1]
    assert (first.relay_az, first.relay_el) == (1, 1) and first.cell_diff_az > 0 and first.cell_diff_el > 0
    assert first.sun_az == pytest.approx(tracker.sun()[1], abs=0.02)      # the controller's ephemeris
    assert first.sun_el == pytest.approx(tracker.sun()[0], abs=0.02)
    assert 0.3 < first.error_az < 1.1 and 0.0 < first.error_el < 0.7          # closing on the sun
    assert bench.wait_until(lambda: tracker.angular_error_deg() < 0.2, 60.0)      # closed on the sun
    assert tracker.relay_closures[0] >= 1 and tracker.relay_closures[1] >= 1
    relay_error = tracker.angular_error_deg()
    assert bench.call(M["ParamSet"]("trk_ff", 1.0)).ok
    bench.run_for(60.0)                                       # two of the correction's time constants
    last = tracker_telemetry(bench)[-1]
    assert last.ff_active and last.warnings & ~(TrackerWarning.TEMP_LOW | TrackerWarning.TEMP_HIGH) == 0
    print(f"over the bus: {relay_error:.3f} deg when the feed-forward took over, after 60 s "
          f"{tracker.angular_error_deg():.3f} deg")
    assert tracker.angular_error_deg() < min(0.05, relay_error)
    assert abs(last.error_az) < 0.1 and abs(last.error_el) < 0.1
    when = tracker.utc
    spa = solar_position([when - timedelta(seconds=30), when + timedelta(seconds=30)], TUCSON)
    assert last.sun_rate_az == pytest.approx((spa["azimuth"][1] - spa["azimuth"][0]) / 60.0, rel=0.02)
    assert last.sun_rate_el == pytest.approx((spa["apparent_elevation"][1] - spa["apparent_elevation"][0]) / 60.0,
                                             rel=0.02)
    assert bench.controller.supervisor.state is ControllerState.ENABLED


def test_estop_opens_the_relays_at_the_plant_and_a_restart_needs_the_interlock(tracker_bench):
    bench = tracker_bench
    box_on(bench, mode="manual")
    assert bench.call(M["Enable"]()).ok
    bench.run_for(0.5)
    plant = bench.world.plant
    assert plant.tracker.relay_closed == [[True, False], [True, False]]
    assert bench.call(M["EStop"]()).ok
    bench.run_for(0.1)
    assert plant.tracker.relay_closed == [[False, False], [False, False]]
    cmd = plant.tracker_commands.current(bench.clock.now())
    assert cmd.brake_az and cmd.brake_el and not cmd.motor_power
    assert bench.call(M["Reset"]()).ok and bench.call(M["Enable"]()).ok
    bench.run_for(0.5)
    assert plant.tracker.relay_closed == [[False, False], [False, False]]       # the speed switches went to brake
    assert bench.call(teleop.parse_line("switch speed on", 1).message).reason is Reason.DIAL_NOT_LOW
