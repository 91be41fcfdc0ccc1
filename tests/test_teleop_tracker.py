"""Teleop at the solar tracker's control box: `box`, `watch box`, refusals, `expect`, `wait aligned`, `clock now`.

The words are checked without a link; the panel from hand-made TelemetryTracker messages; the
session on a `LockstepBench` through `BenchClient` (the simulated clock: the plant's sun starts
at the March equinox, 06:50 MST at Tucson, a little after sunrise due east, near the stow
position). The whole operating procedure is in tests/test_procedure_bench.py.
"""
from __future__ import annotations

import io
import math
from datetime import datetime

import pytest

from hil_sim.sun import MST
from host_tools.teleop import session as teleop
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from host_tools.teleop.session import Session, run_script
from host_tools.client.bench import BenchClient
from host_tools.teleop.box import box_block, box_state_text, pointing_error_deg
from host_tools.datetimes import parse_when, split_seconds
from host_tools.teleop.words import completions, help_text, parse_line
from host_tools.worlds.world import LockstepBench
from host_tools.worlds.settings import PlantSettings
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.states import SwitchPosition as P, TrackerWarning

EQUINOX = datetime(2026, 3, 20, 6, 50, tzinfo=MST)
EQUINOX_S = EQUINOX.timestamp()


# ---- the words --------------------------------------------------------------------------------------------------

def test_clock_takes_now_an_iso_date_time_with_its_offset_or_posix_seconds():
    step = parse_line("clock now", 1)
    assert step.clock_now and step.message is None and step.sends
    assert step.build(lambda: EQUINOX_S + 0.25) == SCHEMA["SetClock"].type(int(EQUINOX_S), 250)
    assert parse_line("clock 2026-03-20T06:50-07:00", 1).message == SCHEMA["SetClock"].type(int(EQUINOX_S), 0)
    assert parse_line("clock 2026-03-20T13:50:00.5Z", 1).message == SCHEMA["SetClock"].type(int(EQUINOX_S), 500)
    assert parse_line("clock 1782000000", 1).message == SCHEMA["SetClock"].type(1782000000, 0)      # as before
    assert parse_line("clock 1782000000 7", 1).message == SCHEMA["SetClock"].type(1782000000, 7)
    assert split_seconds(1782000000.9996) == (1782000001, 0)
    assert parse_when("NOW") is None


@pytest.mark.parametrize("line, words", [
    ("clock 2026-03-20T06:50", ["line 4", "needs its UTC offset, e.g. -07:00 for Tucson"]),
    ("clock 1999-12-31T16:59-07:00", ["1999-12-31T23:59:00Z is outside the controller clock's range"]),
    ("clock now 12", ["takes nothing after it"]),
    ("clock 2026-02-30T00:00Z", ["day is out of range for month"]),
    ("clock 12", ["utc_s=12 is outside"]),
    ("expect DIAL_NOT_LOW", ["nothing follows the reason"]),
    ("expect OK switch main on", ["write the command alone"]),
    ("expect DAIL_NOT_LOW switch main on", ["'DAIL_NOT_LOW' is not a reason code"]),
    ("expect DIAL_NOT_LOW box", ["'box' is a local word"]),
    ("expect DIAL_NOT_LOW switch main upside", ["position", "'upside'"]),
    ("expect DIAL_NOT_LOW expect DIAL_NOT_LOW ping", ["not another `expect`"]),
    ("wait aligned", ["wait aligned [az|el] DEG [TIMEOUT]"]),
    ("wait aligned az", ["wait aligned [az|el] DEG [TIMEOUT]"]),
    ("wait aligned close", ["'close' is not a number of degrees"]),
    ("wait aligned -1", ["outside (0, 180]"]),
    ("wait aligned el 0.5 forever", ["'forever' is not a number of seconds"]),
    ("wait aligned 0.5 60 70", ["wait aligned [az|el] DEG [TIMEOUT]"]),
    ("watch box soon", ["'soon' is not a number of seconds"]),
    ("watch box 1 2", ["watch takes `box` and at most a number of seconds"]),
    ("box 3", ["box takes no arguments"]),
])
def test_new_words_refuse_bad_lines_with_a_reason(line, words):
    with pytest.raises(teleop.TeleopError) as err:
        parse_line(line, 4)
    for word in words:
        assert word in str(err.value)


def test_expect_wait_aligned_and_watch_box_parse_to_their_steps():
    step = parse_line("expect dial_not_low switch mode sensor az  # the interlock", 3)
    assert step.expect is Reason.DIAL_NOT_LOW and step.message == SCHEMA["BoxSwitch"].type(2, int(P.SENSOR), 0)
    assert step.text == "expect dial_not_low switch mode sensor az" and step.line_no == 3
    assert parse_line("expect SWITCH_POSITION switch main cw", 1).message.position == int(P.CW)
    step = parse_line("wait aligned 0.5", 1)
    assert step.waits_for_alignment and not step.waits_for_motion and (step.aligned_deg, step.seconds) == (0.5, 300)
    step = parse_line("wait aligned el 0.2 30", 1)
    assert (step.aligned_axis, step.aligned_deg, step.seconds) == ("el", 0.2, 30.0)
    assert (parse_line("watch box", 1).view, parse_line("watch box 2", 1).seconds) == ("box", 2.0)
    assert (parse_line("watch 2", 1).view, parse_line("watch", 1).seconds) == ("arm", 5.0)
    assert not parse_line("box", 1).sends


def test_help_and_completion_cover_the_new_words():
    text = help_text()
    for word in ("\n  box  ", "expect REASON COMMAND", "watch [box] [seconds]"):
        assert word in text
    assert "wait aligned [az|el] DEG [TIMEOUT]" in help_text("wait")
    assert "Also: `clock now`" in " ".join(help_text("clock").split())
    assert "2026-03-20T06:50-07:00" in help_text("clock")
    assert "expect DIAL_NOT_LOW switch" in help_text("switch")
    assert completions("ex", 0, "ex") == ["expect"]
    assert completions("expect DI", 7, "DI") == ["DIAL_NOT_LOW"]
    assert completions("expect dial_not_low sw", 20, "sw") == ["switch"]
    assert completions("expect DIAL_NOT_LOW switch m", 27, "m") == ["main", "mode"]
    assert completions("expect DIAL_NOT_LOW switch mode s", 32, "s") == ["sensor"]
    assert completions("wait ali", 5, "ali") == ["aligned"]
    assert completions("wait aligned ", 13, "") == ["az", "el"]
    assert completions("watch ", 6, "") == ["box"]
    assert completions("clock n", 6, "n") == ["now"]
    assert completions("b", 0, "b") == ["box", "boxstate"]


# ---- the panel --------------------------------------------------------------------------------------------------

def tracker_msg(**values):
    spec = SCHEMA["TelemetryTracker"]
    base = {f.name: (False if f.type == "bool" else 0.0 if f.type == "f32" else 0) for f in spec.fields}
    base.update({"uptime_ms": 10_000, "utc_s": int(EQUINOX_S), "main": int(P.ON), "sensor": int(P.ON),
                 "motor_supply_v": 90.0, "sun_az": 92.5, "sun_el": 4.1})
    for ax in ("az", "el"):
        base.update({f"mode_{ax}": int(P.SENSOR), f"direction_{ax}": int(P.CW), f"speed_{ax}": int(P.ON),
                     f"dial_{ax}": 9.97, f"cell_sum_{ax}": 0.2, f"brake_{ax}": False})
    base.update(values)
    return spec.type(**base)


def status_msg(uptime_ms: int = 10_000, temp_c: float = 23.5):
    spec = SCHEMA["TelemetryStatus"]
    values = {f.name: 0.0 if f.type == "f32" else 0 for f in spec.fields}
    values.update({"uptime_ms": uptime_ms, "state": 2, "temp_c": temp_c, "supply_v": 28.0})
    return spec.type(**values)


def test_the_panel_reads_as_the_box_does():
    msg = tracker_msg(relay_az=1, relay_el=-1, duty_az=0.0997, duty_el=0.0997, cell_diff_az=0.0023,
                      cell_diff_el=-0.0014, angle_az=91.5, angle_el=4.6, error_az=1.0, error_el=-0.5,
                      brake_el=True, warnings=int(TrackerWarning.NO_SUN | TrackerWarning.TEMP_HIGH), refusals=3,
                      switchings_az=7, chatter_el=2, reversals_el=1, sun_rate_az=0.134 / 60, sun_rate_el=0.205 / 60)
    lines = box_block({"TelemetryTracker": msg, "TelemetryStatus": status_msg(10_050)}, detail=True)
    text = "\n".join(lines)
    assert lines[0] == "box  main ON  sensor ON  feed-forward off  controller ENABLED  23.5 C  90 V bus 90.00 V"
    assert lines[1] == "UTC 2026-03-20 13:50:00  sun (ephemeris) az 92.50 el 4.10 deg, az +0.134 el +0.205 deg/min"
    assert lines[2].split() == ["dial", "duty", "a-b", "a+b", "angle", "error"]       # each unit under its heading
    assert lines[3].split() == ["axis", "mode", "dir", "speed", "%", "relay", "brake", "%", "mV", "V", "deg", "deg"]
    assert lines[4].split() == ["az", "SENSOR", "CW", "ON", "10.0", "CW", "off", "10.0", "+2.3", "0.200", "91.50",
                                "+1.00"]
    assert lines[5].split()[5:7] == ["CCW", "on"] and lines[5].split()[8] == "-1.4"
    assert lines[6] == "pointing error 1.12 deg; relay switchings 7/0, chatter 0/2, reversals 0/1 (az/el); refusals 3"
    assert lines[7] == "warnings: TEMP_HIGH, NO_SUN  (reading 0.1 s old)"
    assert "TEMP_HIGH: control box within temp_warn_c of temp_max_c" in text and "NO_SUN: sensor power on" in text
    assert max(len(line) for line in lines) <= 96
    # as the watch block: the same lines without the docs, so the block keeps its height
    assert box_block({"TelemetryTracker": msg, "TelemetryStatus": status_msg(10_050)}) == lines[:8]


def test_the_panel_says_what_it_cannot_know():
    assert "no TelemetryTracker yet" in box_block({})[0]
    off = tracker_msg(utc_s=0, warnings=int(TrackerWarning.NO_CLOCK), sensor=int(P.OFF), main=int(P.OFF))
    lines = box_block({"TelemetryTracker": off, "TelemetryStatus": status_msg(25_000)})
    assert lines[1].startswith("clock not set (NO_CLOCK): no sun angles, no pointing error; `clock now`")
    assert lines[4].split()[8:] == ["off", "-", "0.00", "-"]       # cells unpowered, no error without a clock
    assert lines[6].startswith("pointing error unknown (no clock)")
    assert "reading 15.0 s old: TelemetryTracker stops while main and sensor power are off" in " ".join(lines[7:])
    assert pointing_error_deg(off) is None


def test_pointing_error_is_the_angle_to_the_sun_or_one_axis():
    level = tracker_msg(angle_az=91.0, angle_el=0.0, sun_az=92.0, sun_el=0.0, error_az=1.0, error_el=0.0)
    assert pointing_error_deg(level) == pytest.approx(1.0, abs=1e-9)
    high = tracker_msg(angle_az=90.0, angle_el=60.0, sun_az=92.0, sun_el=60.0, error_az=2.0, error_el=-0.3)
    assert pointing_error_deg(high) == pytest.approx(2.0 * math.cos(math.radians(60.0)), rel=1e-3)
    assert (pointing_error_deg(high, "az"), pointing_error_deg(high, "el")) == (2.0, 0.3)


def test_wait_aligned_counts_readings_in_a_row_so_one_noisy_reading_does_not_pass():
    from host_tools.teleop.session import AlignedWatch
    watch = AlignedWatch(0.5, "el")
    for error_el, streak in ((0.4, 1), (0.6, 0), (0.45, 1), (-0.49, 2), (0.1, 3)):
        watch.feed(tracker_msg(error_el=error_el))
        assert (watch.streak, watch.error) == (streak, abs(error_el))
    watch.feed(tracker_msg(utc_s=0, warnings=int(TrackerWarning.NO_CLOCK), error_el=0.0))
    assert watch.streak == 0 and watch.error is None                 # no clock: no error to trust


def test_box_state_replies_read_in_one_line():
    reply = SCHEMA["BoxState"].type(0, int(P.ON), int(P.OFF), int(P.MANUAL), int(P.CW), int(P.ON), 30.0,
                                    int(P.MANUAL), int(P.CW), int(P.ON), 30.0)
    assert box_state_text(reply) == "main ON, sensor OFF; az+el MANUAL CW speed ON dial 30.0 %"
    apart = SCHEMA["BoxState"].type(0, int(P.ON), int(P.OFF), int(P.MANUAL), int(P.CW), int(P.BRAKE), 30.0,
                                    int(P.MANUAL), int(P.CW), int(P.ON), 30.0)
    assert box_state_text(apart) == ("main ON, sensor OFF; az MANUAL CW speed BRAKE dial 30.0 %; "
                                     "el MANUAL CW speed ON dial 30.0 %")


# ---- the session, on the simulated clock ------------------------------------------------------------------------

@pytest.fixture
def session():
    bench = LockstepBench(seed=4, plant=PlantSettings(start=EQUINOX))
    client = BenchClient(bench)
    client.connect()
    out = io.StringIO()
    yield Session(client, out, wall_time=client.wall_time), bench, out
    bench.close()


def run(session, line: str) -> tuple[bool, str]:
    s, _bench, out = session
    start = len(out.getvalue())
    ok = s.run_step(parse_line(line, 1))
    return ok, out.getvalue()[start:]


def test_a_refused_switch_says_why_what_to_do_and_that_nothing_changed(session):
    _s, bench, _out = session
    assert run(session, "dial 40 az")[0]
    before = bench.controller.tracker.box
    ok, text = run(session, "switch speed on")
    assert not ok
    assert text.startswith("FAIL BoxSwitch: rejected: DIAL_NOT_LOW (39)")
    assert "report's operating instructions forbid starting" in text
    assert "remedy: turn the dial low first (`dial 0`), repeat the switch, then turn the dial up" in text
    assert "dial az 40.0 %, el 0.0 %; low is at or below trk_dial_low_pct = 5 %" in text
    assert "nothing changed: main OFF, sensor OFF; az MANUAL CW speed BRAKE dial 40.0 %; el MANUAL CW speed " \
           "BRAKE dial 0.0 %" in text
    assert bench.controller.tracker.box == before and bench.controller.tracker.refusals == 1
    ok, text = run(session, "switch mode sensor el")          # el's dial is low: el alone may change
    assert ok and text.startswith("ok   main OFF, sensor OFF; az MANUAL CW speed BRAKE dial 40.0 %; el SENSOR CW")
    ok, text = run(session, "switch direction ccw az")
    assert not ok and "dial az 40.0 %; low is" in text
    ok, text = run(session, "switch main cw")
    assert not ok and "SWITCH_POSITION (40)" in text and "nothing changed: main OFF" in text


def test_expect_passes_only_on_exactly_its_refusal(session):
    s, bench, _out = session
    assert run(session, "dial 40")[0]
    ok, text = run(session, "expect DIAL_NOT_LOW switch speed on")
    assert ok and text.startswith("ok   BoxSwitch refused as expected: DIAL_NOT_LOW (39)")
    assert "remedy: turn the dial low first" in text and "nothing changed:" in text and "FAIL" not in text
    ok, text = run(session, "expect DIAL_NOT_LOW switch main cw")         # refused, but for another reason
    assert not ok
    assert text.startswith("FAIL expected BoxSwitch to be refused with DIAL_NOT_LOW (39), but rejected: "
                           "SWITCH_POSITION (40)")
    ok, text = run(session, "expect DIAL_NOT_LOW switch sensor on")        # accepted: it changed the box
    assert not ok and "but it was accepted" in text and bench.controller.tracker.box.sensor is P.ON
    assert (s.sent, s.failed) == (4, 2)


def test_a_script_with_a_bad_expect_sends_nothing_and_a_failed_expect_stops_it(session):
    s, bench, _out = session
    client = s.client
    executed = bench.controller.link.commands_executed
    out, err = io.StringIO(), io.StringIO()
    status, _ = run_script(client, ["dial 40", "expect DIAL_NOT_LOOW switch speed on"], out, err=err,
                           wall_time=client.wall_time)
    assert status == EXIT_USAGE and "line 2: expect: 'DIAL_NOT_LOOW' is not a reason code" in err.getvalue()
    assert bench.controller.tracker.box.dial_counts == [0, 0]             # line 1 was not sent either
    assert bench.controller.link.commands_executed == executed
    out, err = io.StringIO(), io.StringIO()
    status, _ = run_script(client, ["dial 0", "expect DIAL_NOT_LOW switch speed on", "dial 40"], out, err=err,
                           wall_time=client.wall_time)
    assert status == EXIT_FAILED and "line 2: 'expect DIAL_NOT_LOW switch speed on' failed; stopping" in err.getvalue()
    assert "> dial 40" not in out.getvalue() and bench.controller.tracker.box.dial_counts == [0, 0]
    # (the speed switch went on there: the dial was low) back to brake, the dial up, and the interlock holds
    status, _ = run_script(client, ["switch speed brake", "dial 40", "expect DIAL_NOT_LOW switch speed on"],
                           io.StringIO(), err=io.StringIO(), wall_time=client.wall_time)
    assert status == EXIT_OK


def test_clock_now_is_the_hosts_utc_which_on_the_bench_is_the_plants_sun(session):
    s, bench, _out = session
    bench.run_for(2.0)
    ok, text = run(session, "clock now")
    assert ok and text.startswith("ok   controller clock set to 2026-03-20T13:50:02.")
    now = bench.clock.now()
    assert bench.controller.tracker.utc(now) == pytest.approx(bench.world.plant.tracker.utc.timestamp(), abs=0.02)


def test_wait_aligned_needs_the_clock_and_the_box_and_waits_for_the_sun(session):
    s, bench, _out = session
    ok, text = run(session, "wait aligned 1 2")
    assert not ok and text.startswith("FAIL wait aligned 1 deg: no TelemetryTracker in 2.0 s: it goes out while "
                                      "main or sensor power is on")
    assert run(session, "switch sensor on")[0]
    start = bench.clock.now()
    ok, text = run(session, "wait aligned 1 30")
    assert not ok and "the controller's clock is not set (NO_CLOCK)" in text
    assert bench.clock.now() - start < 0.5                     # said at the first reading, not after 30 s
    assert run(session, "clock now")[0]
    ok, text = run(session, "wait aligned 1 3")                # stowed at az 90, el 0: the sun is 4.8 deg away
    assert not ok and text.startswith("FAIL wait aligned 1 deg: timed out after 3 s: 4.8")
    ok, text = run(session, "wait aligned az 3 3")             # but within 2.6 deg in azimuth
    assert ok and text.startswith("ok   wait aligned az 3 deg: 2.5")
    tracker = bench.world.plant.tracker
    el, az, _, _ = tracker.sun()
    tracker.set_angles(az - 0.1, el + 0.1)                     # by hand, onto the sun
    ok, text = run(session, "wait aligned 0.3 5")
    assert ok and text.startswith("ok   wait aligned 0.3 deg: 0.1")


def test_box_shows_the_box_after_the_lines_before_it(session):
    _s, bench, out = session
    for line in ("telemetry 10", "clock now", "switch sensor on", "wait 1", "dial 40 el"):
        assert run(session, line)[0]
    ok, text = run(session, "box")
    lines = text.splitlines()
    assert ok and lines[0].startswith("box  main OFF  sensor ON  feed-forward off  controller IDLE")
    assert lines[5].split()[:5] == ["el", "MANUAL", "CW", "BRAKE", "40.0"]       # the dial just turned
    assert float(lines[4].split()[9]) == pytest.approx(0.2, abs=0.05)   # a+b: the sun near sunrise
    assert "warnings: none" in text
    ok, text = run(session, "watch box 1")                    # on a pipe: the last reading, once, at the end
    watched = text.splitlines()
    assert ok and watched[0].startswith("box  main OFF  sensor ON") and "(no new telemetry" not in text
    assert watched[3].split()[0] == "axis" and len(watched) == 8             # the block alone: no warning docs
