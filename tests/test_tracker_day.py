"""The solar tracker closed around its plant through (parts of) a day: `host_tools.apps.tracker_day`.

The report's operating step 10: "If the speedpot setting is too low the solar trackers will be
lagging the sun constantly trying to catch up. However, if it is set too high the solar tracker
will constantly be fluctuating from leading then lagging (and vice versa) the sun." These tests
run the firmware's relay logic and its feed-forward against the plant for 10-20 simulated
minutes each (a few seconds of wall time); `make bench` runs whole days.
"""
from __future__ import annotations

import json
import math
import random
from datetime import date, time

import numpy as np
import pytest

from host_tools.cli import main as cli
from host_tools.apps.tracker_day import DayHal, DaySettings, run_day, sun_window
from hil_sim.tracker import TrackerPlant
from protocol.hal import HalCodec

CODEC = HalCodec()


def day(mode="relay", dial=40.0, start=(10, 0), minutes=20, **kw):
    h, m = start
    end_min = h * 60 + m + minutes
    return run_day(DaySettings(mode=mode, dial_pct=(dial, dial), start=time(h, m),
                               end=time(end_min // 60, end_min % 60), **kw))


@pytest.fixture(scope="module")
def shared_day():
    """`day(...)` for runs several tests read: each distinct run computed once per module and worker
    (tests only read it).

    The repeatability test calls `day` itself: it needs runs of its own.
    """
    runs = {}

    def get(**kw):
        key = tuple(sorted(kw.items()))
        if key not in runs:
            runs[key] = day(**kw)
        return runs[key]
    return get


# ---- the report's behaviour ---------------------------------------------------------------------------------------

def test_at_a_good_dial_the_relay_logic_tracks_within_its_deadband_and_never_reverses(shared_day):
    r = shared_day(dial=40.0).summary()
    assert r["rms_pointing_error_deg"] < 0.15 and r["max_pointing_error_deg"] < 0.25   # measured 0.105, 0.19
    assert r["reversals"] == 0 and r["mean_lag_deg"] > 0.0
    assert r["both_relays_refused"] == 0


def test_a_dial_too_low_lags_the_sun_constantly_trying_to_catch_up():
    result = day(dial=3.0, start=(12, 0), minutes=20)        # transit: azimuth at 1.5 deg/min, the dial 1.1
    r = result.summary()
    assert r["mean_lag_deg"] > 0.5 and r["lead_fraction"] == 0.0          # measured 1.25 deg, never ahead
    assert result.lag_deg[-60:].mean() > result.lag_deg[:60].mean() + 1.0      # and falling further behind
    assert r["axes"]["az"]["motor_on_fraction"] > 0.9                      # running all the time, in vain


def test_a_dial_too_high_hunts_between_leading_and_lagging(shared_day):
    good = shared_day(dial=40.0).summary()
    high = day(dial=100.0).summary()
    assert high["reversals"] > 100                                # measured about 1,000 in 20 minutes
    assert high["relay_switchings"] > 10 * good["relay_switchings"]
    assert 0.25 < high["lead_fraction"] < 0.75                    # ahead of the sun and behind it by turns
    assert high["rms_pointing_error_deg"] > good["rms_pointing_error_deg"]


def test_the_feed_forward_neither_lags_nor_hunts(shared_day):
    relay = shared_day(dial=40.0).summary()
    ff = shared_day(mode="feedforward", dial=100.0).summary()
    assert ff["rms_pointing_error_deg"] < 0.01 and ff["max_pointing_error_deg"] < 0.03   # measured 0.0024, 0.0054
    assert ff["rms_pointing_error_deg"] * 3 < relay["rms_pointing_error_deg"]
    assert ff["reversals"] == 0 and ff["relay_switchings"] < relay["relay_switchings"]
    assert abs(ff["mean_lag_deg"]) < 0.005
    assert ff["axes"]["az"]["motor_on_fraction"] > 0.99          # the motor runs smoothly, at the sun's speed


def test_a_cloud_holds_the_relay_logic_and_it_recovers_without_running_away():
    cloud = "12:05+300s@0.95"
    result = day(dial=40.0, start=(12, 0), minutes=20, clouds=cloud)
    t, err = result.times_h, result.error_deg
    during = (t > 12 + 5 / 60) & (t < 12 + 10 / 60)
    after = t > 12 + 12 / 60
    assert err[during].max() > 0.4                                # held: no beam, no direction to follow
    assert err[during].max() < 1.5 and np.all(result.lag_deg[during] > 0.0)    # ... only behind the sun (1.3)
    assert err[after].max() < 0.25                                # caught up within two minutes
    assert result.summary()["reversals"] == 0


def test_through_a_cloud_the_feed_forward_keeps_tracking():
    r = day(mode="feedforward", dial=100.0, start=(12, 0), minutes=20, clouds="12:05+300s@0.95").summary()
    assert r["max_pointing_error_deg"] < 0.1 and r["reversals"] <= 10      # measured 0.058 (the elevation turns over)


def test_the_run_is_repeatable_for_a_seed():
    a = day(dial=60.0, minutes=5).summary()
    b = day(dial=60.0, minutes=5).summary()
    c = day(dial=60.0, minutes=5, seed=1).summary()
    for key in ("rms_pointing_error_deg", "mean_lag_deg", "relay_switchings"):
        assert a[key] == b[key]
    assert (a["rms_pointing_error_deg"], a["relay_switchings"]) != (c["rms_pointing_error_deg"], c["relay_switchings"])


# ---- the measurements ---------------------------------------------------------------------------------------------

def test_a_tracker_that_never_moves_lags_by_exactly_the_suns_travel():
    result = day(dial=0.0, start=(9, 0), minutes=10)            # dial 0: relays close, the motor cannot turn
    plant = TrackerPlant(start=result.start)
    el0, az0, _, _ = plant.sun()
    plant.step(600.0)
    el1, az1, _, _ = plant.sun()
    travel = math.degrees(math.acos(math.sin(math.radians(el0)) * math.sin(math.radians(el1))
                                    + math.cos(math.radians(el0)) * math.cos(math.radians(el1))
                                    * math.cos(math.radians(az1 - az0))))
    assert result.error_deg[-1] == pytest.approx(travel, rel=1e-3)
    assert result.lag_deg[-1] == pytest.approx(travel, rel=0.01)        # all of it along the sun's path
    assert np.all(result.lag_deg > 0.0)


def test_the_sun_window_is_where_the_sun_is_above_five_degrees():
    start, end = sun_window(date(2026, 6, 21))
    assert (start.hour, end.hour) == (5, 19)                  # Tucson, June solstice: up 05:19, down 19:32 MST
    assert sun_window(date(2026, 12, 21))[1] - sun_window(date(2026, 12, 21))[0] < end - start


def test_dayhal_hands_values_across_exactly_as_the_dbc_encodes_them():
    hal = DayHal(CODEC)
    sense = CODEC.layout("TRACKER_SENSE", ("cell_az_a", "cell_az_b", "cell_el_a", "cell_el_b"))
    pos = CODEC.layout("TRACKER_POS", ("angle_az", "angle_el", "limit_cw_az", "limit_ccw_az", "limit_cw_el",
                                       "limit_ccw_el", "motor_supply_v"))
    cmd = CODEC.layout("TRACKER_CMD", ("relay_cw_az", "relay_ccw_az", "relay_cw_el", "relay_ccw_el", "brake_az",
                                       "brake_el", "sensor_power", "motor_power", "duty_az", "duty_el", "alive"))
    rng = random.Random(7)

    class Plant:
        pass

    for _ in range(500):
        p = Plant()
        p.cells_v = tuple(rng.uniform(0.0, 0.7) for _ in range(4))
        p.angles_measured_deg = [rng.uniform(45.0, 315.0), rng.uniform(-5.0, 88.0)]
        p.limits = tuple(rng.random() < 0.2 for _ in range(4))
        p.motor_supply_v = rng.uniform(0.0, 95.0)
        hal.sample(p, 1.0)
        assert hal.inputs.cells_v == pytest.approx(sense.unpack(sense.pack(p.cells_v)), abs=1e-12)
        wire = pos.unpack(pos.pack((*p.angles_measured_deg, *p.limits, p.motor_supply_v)))
        assert hal.inputs.tracker_angles_deg == pytest.approx(wire[:2], abs=1e-12)
        assert [*hal.inputs.tracker_limits[0], *hal.inputs.tracker_limits[1]] == [bool(v) for v in wire[2:6]]
        assert hal.inputs.motor_supply_v == pytest.approx(wire[6], abs=1e-12)
        duties = [rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0)]
        relays = [[rng.random() < 0.5, rng.random() < 0.5] for _ in range(2)]
        hal.send_tracker_command(relays, [False, True], True, True, duties)
        both = [cw and ccw for cw, ccw in relays]
        wire = cmd.unpack(cmd.pack([*(0 if both[k] else int(relays[k][j]) for k in (0, 1) for j in (0, 1)),
                                    0, 1, 1, 1, *duties, 0]))
        assert hal.command[:8] == tuple(bool(v) for v in wire[:8])
        assert hal.command[8:] == pytest.approx(wire[8:10], abs=1e-12)


def test_dayhal_never_sends_both_relays_of_an_axis():
    hal = DayHal(CODEC)
    hal.send_tracker_command([[True, True], [True, False]], [False, False], True, True, [0.5, 0.5])
    assert hal.command[:4] == (False, False, True, False) and hal.both_refused == 1


# ---- the command line ---------------------------------------------------------------------------------------------

def test_the_command_prints_one_json_object_and_writes_a_readable_png(tmp_path, capsys):
    png = tmp_path / "day.png"
    status = cli.main(["tracker-day", "--mode", "relay", "--dial", "3", "--from", "12:00", "--to", "12:10",
                       "--json", "--plot", str(png)])
    assert status == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("rms_pointing_error_deg", "max_pointing_error_deg", "mean_lag_deg", "relay_switchings"):
        assert isinstance(out[key], (int, float))
    assert out["mean_lag_deg"] > 0.3 and out["dial_pct"] == {"az": 3.0, "el": 3.0}
    assert out["sim_time_s"] == pytest.approx(600.0) and out["wall_time_s"] > 0
    import matplotlib.image
    image = matplotlib.image.imread(png)
    assert image.shape[0] > 400 and image.shape[1] > 600 and image.std() > 0.05      # a picture, not a blank


@pytest.mark.parametrize("args, reason", [
    (["--dial", "120"], "0 to 100"),
    (["--dial", "abc"], "not a number"),
    (["--dial", "1,2,3"], "az,el"),
    (["--date", "2026-02-30"], "YYYY-MM-DD"),
    (["--date", "1999-06-21"], "clock"),
    (["--clouds", "12:00+5@0.9"], "duration"),
    (["--clouds", "12:00+5m@1.5"], "attenuation"),
    (["--from", "noon"], "HH:MM"),
    (["--from", "12:00", "--to", "11:00"], "after"),
    (["--param", "trk_deadband_mv"], "NAME=VALUE"),
    (["--param", "nope=1"], "no such parameter"),
    (["--param", "trk_hyst_mv=5"], "hysteresis"),
    (["--plot", "/no/such/folder/x.png"], "no folder"),
    (["--plot", "day.jpg"], "PNG"),
])
def test_bad_arguments_are_refused_with_a_reason_before_anything_runs(args, reason, capsys):
    assert cli.main(["tracker-day", "--from", "12:00", "--to", "12:01", *args]) == 2
    err = capsys.readouterr().err
    assert reason in err and "Traceback" not in err


def test_bad_mode_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["tracker-day", "--mode", "bang"])
    assert exc.value.code == 2 and "relay" in capsys.readouterr().err
