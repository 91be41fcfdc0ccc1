"""`aspod bench SCRIPT` (a teleop script on the lock-step world) and `--json` there and on `aspod teleop --script`:
one JSON object with each line's outcome and output, the motions and their ends, the plant's true state."""
from __future__ import annotations

import json
import os

import pytest

from host_tools.apps.replay import replay
from host_tools.cli.main import main
from host_tools.sessions.capture import SessionCapture, WorldEvent
from host_tools.worlds.child import run
from tests import test_e2e

ASPOD = test_e2e.ASPOD
env, sim_factory = test_e2e.env, test_e2e.sim_factory      # the fixtures, shared
SCRIPT = "enable\nmoveby j1 2 2\nwait\nstatus\n"


def bench_json(tmp_path, script: str, *args: str, capsys) -> tuple[int, dict]:
    path = tmp_path / "s.txt"
    path.write_text(script)
    status = main(["bench", str(path), "--json", *args])
    out = capsys.readouterr().out
    try:
        return status, json.loads(out)
    except json.JSONDecodeError as exc:
        raise AssertionError(f"stdout is not one JSON object ({exc}): {out[:2000]!r}") from None


def test_a_bench_script_as_json_says_what_each_line_did_and_where_the_plant_ended(tmp_path, capsys):
    status, doc = bench_json(tmp_path, SCRIPT, capsys=capsys)
    assert status == 0 and doc["ok"] and doc["target"] == "lockstep"
    assert [(s["line"], s["text"], s["ok"]) for s in doc["steps"]] == [
        (1, "enable", True), (2, "moveby j1 2 2", True), (3, "wait", True), (4, "status", True)]
    assert any("j1#1 DONE" in line for line in doc["steps"][2]["output"])
    (motion,) = doc["motions"]
    assert (motion["axis"], motion["kind"], motion["outcome"], motion["ok"]) == ("j1", "MoveBy", "DONE", True)
    assert abs(motion["position"] - 2.0) < 0.05
    assert doc["commands"] == {"sent": 3, "ok": 3, "failed": 0}
    # the plant's truth: j1 moved by about the 2 degrees asked, from where it started
    joints = doc["plant"]["joints_deg"]
    assert abs(joints["j1"] - joints["j2"] - 2.0) < 0.05 and doc["sim_time_s"] > 1.0


def test_a_failing_line_fails_its_step_and_the_run_and_runs_the_same_every_time(tmp_path, capsys):
    script = "moveby j1 2 2\nenable\nmove j1 10\nstatus\n"     # not enabled; then an absolute move not homed
    status, first = bench_json(tmp_path, script, "--keep-going", capsys=capsys)
    assert status == 1 and not first["ok"]
    assert [s["ok"] for s in first["steps"]] == [False, True, False, True]
    _, second = bench_json(tmp_path, script, "--keep-going", capsys=capsys)
    for doc in (first, second):
        doc.pop("wall_time_s")
    assert first == second                                     # deterministic, to the output's last character


def test_a_bench_recorded_replays_to_the_bit(tmp_path, capsys):
    capture = tmp_path / "b.pcapng"
    status, _ = bench_json(tmp_path, SCRIPT, "--record", str(capture), capsys=capsys)
    assert status == 0
    with SessionCapture.open(capture) as recorded:
        report = replay(recorded)
    assert report.matches and report.exact and report.identical_bytes == report.controller_frames > 10


def test_bench_refuses_a_bad_script_before_anything_runs(tmp_path, capsys):
    path = tmp_path / "bad.txt"
    path.write_text("enable\nteleport j1\n")
    assert main(["bench", str(path)]) == 2
    assert main(["bench", str(tmp_path / "missing.txt")]) == 2


@pytest.mark.pty
def test_teleop_script_json_over_a_pty_is_one_json_object(sim_factory, tmp_path):
    sim = sim_factory("--pty", "--no-tracker")
    script = tmp_path / "s.txt"
    script.write_text("ping 5\nenable\nstatus\n")
    done = run(ASPOD + ["teleop", sim.url, "--script", str(script), "--json"], text=True, env=sim.env, timeout_s=120,
               peers=(sim.child.pid,))
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout)                              # nothing but the object on stdout
    assert doc["target"] == sim.url and doc["link"].startswith("link up:")
    assert [s["text"] for s in doc["steps"]] == ["ping 5", "enable", "status"] and all(s["ok"] for s in doc["steps"])
    assert doc["round_trip_ms"]["p50"] > 0


def test_a_bench_world_takes_timed_faults_an_impairment_parameters_and_variables(tmp_path, capsys):
    status, doc = bench_json(tmp_path, "enable\njog j2 ${speed}\nwait 3\n", "--fault", "jam:j2@1.5", "--var",
                             "speed=2", "--impairment", "radio,seed=3", "--param", "j2_kp=40", "--no-tracker",
                             capsys=capsys)
    assert status == 1 and doc["steps"][2]["ok"] is False
    (fault,) = doc["faults"]
    assert fault["fault"] == "jam:j2" and fault["at_s"] == 1.5 and "STALL" in fault["fault_bits"]
    assert 0 < fault["safe_after_s"] <= fault["stated_s"] == 1.0 and fault["within_stated"] is True
    assert "tracker" not in doc["plant"]


@pytest.mark.parametrize("args, reason", [
    (["--fault", "jam:j9@1"], "unknown channel"), (["--fault", "jam:j2"], "NAME[:CHANNEL]@SECONDS"),
    (["--fault", "supply_sag@5-2"], "cleared after"), (["--var", "speed"], "NAME=VALUE"),
    (["--var", "speed=1", "--var", "other=2"], "uses no ${other}"), ([], "no value for ${speed}"),
    (["--var", "speed=1", "--param", "j2_kp=1e9"], "j2_kp"), (["--var", "speed=1", "--impairment", "stormy"], "stormy"),
    (["--var", "speed=1", "--param", "nosuch=1"], "--param nosuch: the controller has no such parameter"),
    (["--var", "speed=1", "--param", "mount_speed_dps=30"], "--param mount_speed_dps=30.0 outside 0.1..23.0 deg/s"),
    (["--var", "speed=1", "--param", "j2_max_deg=10", "--param", "j2_min_deg=20"],      # the firmware's own veto
     "--param j2_min_deg=20.0: j2: soft_min_rad must be below soft_max_rad"),
])
def test_a_bad_bench_world_is_refused_with_its_reason(tmp_path, capsys, args, reason):
    path = tmp_path / "s.txt"
    path.write_text("enable\njog j2 ${speed}\n")
    assert main(["bench", str(path), *args]) == 2
    assert reason in capsys.readouterr().err


def test_a_timed_fault_is_recorded_as_a_world_event_and_replays_to_the_bit(tmp_path, capsys):
    capture = tmp_path / "f.pcapng"
    status, doc = bench_json(tmp_path, "enable\njog j2 2\nwait 2.5\n", "--fault", "jam:j2@1.2", "--record",
                             str(capture), capsys=capsys)
    assert status == 1 and doc["faults"][0]["within_stated"] is True
    with SessionCapture.open(capture) as recorded:
        assert [(e.event["action"], e.event["args"]) for e in recorded.items() if isinstance(e, WorldEvent)] == [
            ("inject", ["jam:j2"])]
        report = replay(recorded)
    assert report.matches and report.exact, report.describe()


def test_plant_actions_by_name_change_the_plant_or_refuse_saying_why():
    from host_tools.worlds.world import LockstepBench
    bench = LockstepBench()
    try:
        bench.act("set_gravity", "orbit")
        bench.act("inject", "supply_sag")
        assert bench.world.plant.arm.gravity == "orbit" and bench.world.plant.faults == frozenset({"supply_sag"})
        for name, args, reason in (("set_gravity", ("mars",), "mars"), ("inject", ("jam:j9",), "j9"),
                                   ("fly", (), "no plant action"), ("set_payload", (1, 2), "set_payload")):
            with pytest.raises(ValueError, match=reason):
                bench.act(name, *args)
        assert bench.world.plant.arm.gravity == "orbit" and bench.world.plant.faults == frozenset({"supply_sag"})
    finally:
        bench.close()


def test_a_scripts_first_line_gives_its_world_and_the_command_line_wins(tmp_path, capsys):
    script = "#! aspod bench --no-tracker --seed 3 --fault supply_sag@0.5\nenable\nwait 1\n"
    status, doc = bench_json(tmp_path, script, capsys=capsys)
    assert doc["seed"] == 3 and "tracker" not in doc["plant"] and doc["faults"][0]["fault"] == "supply_sag"
    _, doc = bench_json(tmp_path, script, "--seed", "5", capsys=capsys)
    assert doc["seed"] == 5 and "tracker" not in doc["plant"]


@pytest.mark.parametrize("first, said", [
    ("#! aspod bench --record victim.txt", "'--record'"),
    ("#! aspod bench --seed 3 --log-file=victim.txt", "'--log-file=victim.txt'"),
    ("#! aspod bench --rec victim.txt", "'--rec'"),                   # argparse would take it for --record
    ("#! aspod bench --json", "'--json'"),
    ("#! aspod bench " + "--seed 1 " * 1000, "more than 4096"),      # argparse takes quadratic time over it
])
def test_a_scripts_first_line_gives_only_its_world_else_it_is_refused_and_nothing_is_written(
        tmp_path, capsys, first, said, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "victim.txt").write_text("keep me")
    (tmp_path / "s.txt").write_text(first + "\nenable\n")
    assert main(["bench", "s.txt"]) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err
    assert (tmp_path / "victim.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.txt", "victim.txt"]


def test_every_world_option_a_script_may_give_is_one_of_the_bench_world_options():
    import argparse

    from host_tools.cli import options as cli
    from host_tools.teleop.words import WORLD_OPTIONS
    parser = argparse.ArgumentParser()
    cli.add_seed_arg(parser, "x")
    for add in (cli.add_arm_args, cli.add_tracker_args, cli.add_bench_world_args):
        add(parser)
    world = {o: a.nargs != 0 for a in parser._actions for o in a.option_strings if o.startswith("--")}
    world.pop("--help")
    assert WORLD_OPTIONS == world


def test_a_record_over_the_script_or_to_a_folder_or_a_device_is_refused_before_the_run(tmp_path, capsys):
    script = tmp_path / "s.txt"
    script.write_text(SCRIPT)
    (tmp_path / "adir").mkdir()
    os.link(script, tmp_path / "hard.txt")
    for record, said in ((script, "an input of this run"), (tmp_path / "hard.txt", "an input of this run"),
                         (tmp_path / "adir", "a folder, not a file"), ("/dev/full", "not a regular file"),
                         (tmp_path / "nowhere" / "r.pcapng", "no folder")):
        assert main(["bench", str(script), "--record", str(record)]) == 2, record
        err = capsys.readouterr().err
        assert said in err and "Traceback" not in err, err
    assert script.read_text() == SCRIPT
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "hard.txt", "s.txt"]
    assert list((tmp_path / "adir").iterdir()) == []


def test_a_clouds_spec_too_long_for_a_recordings_header_is_refused_before_the_record_is_touched(tmp_path, capsys):
    script, record = tmp_path / "s.txt", tmp_path / "r.pcapng"
    script.write_text(SCRIPT)
    record.write_bytes(b"an earlier recording")
    for clouds, said in ((",".join(["12:00+1s@0.5"] * 6000), "at most 4096"),
                         (",".join(["12:00+1s@0.5"] * 250), "at most 200")):
        with pytest.raises(SystemExit) as exited:
            main(["bench", str(script), "--clouds", clouds, "--record", str(record)])
        assert exited.value.code == 2
        assert said in capsys.readouterr().err
    assert record.read_bytes() == b"an earlier recording"
