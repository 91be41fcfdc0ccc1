"""`aspod sim` and `aspod plant` with the solar tracker: --sun-start, --clouds, --no-tracker.

The options become `PlantSettings` (`cli/settings.py`), `now` is resolved (`resolve_sun`) and the sun's start
printed (`sun_line`)
without a subprocess; bad values are refused by the real command line (exit 2, a reason, nothing
started); the real `aspod sim` (in one process, and with the plant as its child over
udp_multicast, `--hal`) is started once each to see that the options reach the plant.
"""
from __future__ import annotations

import argparse
import re
from datetime import datetime, timedelta, timezone

import pytest
import test_separate_processes as separate
from test_separate_processes import ASPOD, WAIT_S, Proc, link_of

from host_tools.worlds.child import run
from host_tools.worlds.ports import BufferPort
from hil_sim.sun import MST
from host_tools.cli.main import build_parser
from host_tools.cli.plant import resolve_sun, sun_line
from host_tools.cli.settings import plant_settings
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import World
from timebase import RealClock, SimClock

EQUINOX = "2026-03-20T06:50-07:00"
# the fixtures of the separate-process tests: a private config directory, a udp_multicast probe, a parameter file
env, multicast_works, params_file = separate.env, separate.multicast_works, separate.params_file


def options(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(["sim", *argv])


def test_a_start_with_its_offset_and_clouds_on_that_day():
    args = options("--sun-start", EQUINOX, "--clouds", "07:00+5m@0.5, 2026-03-21T07:00+1h@0.9")
    plant = plant_settings(args)
    assert plant.tracker and plant.start == datetime(2026, 3, 20, 6, 50, tzinfo=MST)
    assert resolve_sun(plant) is plant
    passages = plant.passages()
    assert [p.start for p in passages] == [datetime(2026, 3, 20, 7, 0, tzinfo=MST),
                                           datetime(2026, 3, 21, 7, 0, tzinfo=MST)]
    assert [(p.duration_s, p.attenuation) for p in passages] == [(300.0, 0.5), (3600.0, 0.9)]
    world = World(SimClock(), BufferPort(), b"k" * 32, plant=plant)
    try:
        tracker = world.plant.tracker
        assert tracker.start_utc == datetime(2026, 3, 20, 13, 50, tzinfo=timezone.utc)
        line = sun_line("aspod sim", plant, tracker)
        assert line.startswith("aspod sim: the sun starts at 2026-03-20T06:50:00-07:00 (2026-03-20T13:50:00Z) at "
                               "Tucson, azimuth 92.52 deg, elevation 4.13 deg"), line
        assert "clouds 07:00:00+300s@0.5, 07:00:00+3600s@0.9" in line
        assert "`clock 2026-03-20T06:50:00-07:00`" in line
    finally:
        world.close()
    assert plant.to_argv() == ["--gravity", "earth", "--payload-kg", "0.0", "--sun-start", "2026-03-20T13:50:00+00:00",
                               "--clouds", "07:00+5m@0.5, 2026-03-21T07:00+1h@0.9"]


def test_now_is_the_wall_clock_and_no_tracker_is_no_tracker():
    before = RealClock.wall_time()
    unresolved = plant_settings(options())
    assert unresolved.start is None and unresolved.to_argv() == ["--gravity", "earth", "--payload-kg", "0.0"]
    plant = resolve_sun(unresolved)
    after = RealClock.wall_time()
    assert before - 1.0 <= plant.start.timestamp() <= after and plant.passages() == ()
    assert "now" in sun_line("aspod sim", plant, from_now=True) and "`clock now`" in sun_line("p", plant, from_now=True)
    none = plant_settings(options("--no-tracker"))
    assert none == PlantSettings(tracker=False) and none.to_argv()[-1] == "--no-tracker"
    assert sun_line("aspod plant", none) == "aspod plant: no solar tracker (--no-tracker)"


@pytest.mark.parametrize("argv, message", [
    (["sim", "--sun-start", "2026-03-20T06:50"], "it needs its UTC offset, e.g. -07:00 for Tucson"),
    (["sim", "--sun-start", "tomorrow"], "'tomorrow' is not `now` nor YYYY-MM-DDTHH:MM[:SS]+HH:MM"),
    (["sim", "--sun-start", "1990-06-21T12:00-07:00"], "outside the controller clock's range, 2000-01-01"),
    (["sim", "--sun-start", "2026-02-30T12:00-07:00"], "day is out of range for month"),
    (["sim", "--clouds", "12:00+5m"], "expected TIME+DURATION@ATTENUATION"),
    (["sim", "--clouds", "12:00+5m@1.5"], "attenuation is the fraction of the direct beam removed, in [0, 1]"),
    (["sim", "--no-tracker", "--sun-start", EQUINOX], "--sun-start set the solar tracker's sun, but --no-tracker"),
    (["sim", "--hal", "udp_multicast", "--no-tracker", "--clouds", "12:00+5m@0.5"], "but --no-tracker leaves"),
    (["plant", "--interface", "udp_multicast", "--channel", "239.74.1.1", "--sun-start", "noon"], "'noon' is not"),
    (["plant", "--interface", "udp_multicast", "--channel", "239.74.1.1", "--no-tracker", "--clouds",
      "12:00+5m@0.5"], "--clouds set the solar tracker's sun, but --no-tracker"),
])
def test_bad_tracker_options_exit_2_with_a_reason_and_start_nothing(env, argv, message):
    done = run(ASPOD + argv, env=env, timeout_s=60)
    err = done.stderr.decode()
    assert done.returncode == 2, err
    assert message in err
    assert b"ASPOD-LINK" not in done.stdout and b"ASPOD-PLANT" not in done.stdout


def _stop(proc: Proc) -> None:
    proc.wait_stderr(r"BOOT -> IDLE")         # running: its SIGTERM handler is in place
    status, rest = proc.stop()
    assert status == 0, rest


@pytest.mark.pty
def test_sim_says_where_its_sun_starts_now_and_without_the_tracker(env):
    sim = Proc(["sim", "--pty"], env)
    try:
        link_of(sim)
        when = sim.wait_stderr(r"aspod sim: the sun starts at (\S+) \((\S+)Z, now\) at Tucson, azimuth")
        start = datetime.fromisoformat(when.group(1))
        assert start.utcoffset() == timedelta(hours=-7)
        assert abs(start.timestamp() - RealClock.wall_time()) < WAIT_S
    finally:
        _stop(sim)
    sim = Proc(["sim", "--pty", "--no-tracker"], env)
    try:
        link_of(sim)
        sim.wait_stderr(r"^aspod sim: no solar tracker \(--no-tracker\)$")
    finally:
        _stop(sim)


@pytest.mark.pty
def test_sim_with_hal_hands_the_sun_and_the_clouds_to_its_plant_process(multicast_works, env,
                                                                       params_file, tmp_path):
    sim = Proc(["sim", "--hal", "udp_multicast", "--pty", "--params", str(params_file), "--sun-start", EQUINOX,
                "--clouds", "06:00+2h@1"], env)
    try:
        url, key = link_of(sim)
        sim.wait_stderr(r"aspod plant: the sun starts at 2026-03-20T06:50:00-07:00 \(2026-03-20T13:50:00Z\) at "
                        r"Tucson, azimuth 92\.52 deg, elevation 4\.13 deg.*; clouds 06:00:00\+7200s@1;")
        script = tmp_path / "clouded.txt"
        script.write_text(f"telemetry 10\nclock {EQUINOX}\nswitch mode sensor\nswitch sensor on\nwait 1\nbox\n")
        done = run(ASPOD + ["teleop", url, "--key-file", key, "--script", str(script)], env=env, timeout_s=120,
                   peers=(sim.pid,))
        out = done.stdout.decode()
        assert done.returncode == 0, out + done.stderr.decode()
        # the whole beam is clouded out: the cells see only the diffuse light, far below trk_sun_min_v (0.1 V);
        # a clear sky at this hour gives about 0.2 V (tests/test_teleop_tracker.py)
        assert "warnings: NO_SUN" in out and "NO_SUN: sensor power on but a photocell pair sums below" in out, out
        sums = [float(row.split()[9]) for row in re.findall(r"^(?:az|el) .*$", out, re.M)]    # the a+b column
        assert len(sums) == 2 and all(0.0 < v < 0.05 for v in sums), out
    finally:
        _stop(sim)
