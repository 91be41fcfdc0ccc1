"""`aspod campaign`: the matrix and its runs, a run's world and row, the same rows on a Dask cluster of 2 workers as
in one process, a failed row's command that reproduces it alone, and bad input refused with its reason."""
from __future__ import annotations

import csv
import json
import os
import shlex
import socket
import subprocess
import sys

import pytest

from host_tools.campaign.engine import EngineSettings, run_runs
from host_tools.campaign.matrix import DrawnAxis, GridAxis, Matrix, Run, parse_seeds
from host_tools.campaign.runs import BenchSpec, world_of
from host_tools.cli.main import main
from host_tools.teleop.words import SCRIPT_LIMIT
from host_tools.worlds.bench_world import TimedFault, WorldSettings
from protocol import files

# A joint jogged while a fault may strike it: short (2.4 simulated s a run), failing when the fault comes.
DRILL = "enable\njog j2 ${speed}\nwait 2\n"


def rows_of(folder) -> list[dict]:
    with (folder / "rows.csv").open(newline="") as f:
        return list(csv.DictReader(f))


# ---- the matrix ----------------------------------------------------------------------------------------------------

def test_grid_axes_make_every_combination_times_the_seeds_in_a_fixed_order():
    matrix = Matrix((GridAxis.parse("payload_kg=0..1/3"), GridAxis.parse("gravity=earth,orbit")), (),
                    parse_seeds("10..11"))
    runs = matrix.runs()
    assert matrix.size == len(runs) == 12
    assert [r.as_dict() for r in runs[:3]] == [{"seed": 10, "payload_kg": 0.0, "gravity": "earth"},
                                               {"seed": 11, "payload_kg": 0.0, "gravity": "earth"},
                                               {"seed": 10, "payload_kg": 0.0, "gravity": "orbit"}]
    assert [r.as_dict()["payload_kg"] for r in runs[::4]] == [0.0, 0.5, 1.0]
    assert [r.index for r in runs] == list(range(12))


def test_a_date_range_of_whole_days_keeps_the_time_of_day():
    axis = GridAxis.parse("sun_start=2026-01-15T10:00-07:00..2026-12-15T10:00-07:00/12")
    assert len(axis.values) == 12 and all(v.endswith("T10:00-07:00") for v in axis.values)
    assert axis.values[0] == "2026-01-15T10:00-07:00" and axis.values[-1] == "2026-12-15T10:00-07:00"


def test_draws_depend_on_the_axis_and_the_seed_alone():
    fault, at = DrawnAxis.parse("fault=none,jam:j2,open_circuit:j1"), DrawnAxis.parse("fault_at_s=1..20")
    draws = [(fault.draw(s), at.draw(s)) for s in range(200)]
    assert draws == [(fault.draw(s), at.draw(s)) for s in range(200)]
    assert {f for f, _ in draws} == {"none", "jam:j2", "open_circuit:j1"}
    assert all(1 <= t <= 20 and round(t, 3) == t for _, t in draws)
    # common random numbers: every grid point sees the same draws for the same seed
    runs = Matrix((GridAxis.parse("payload_kg=0,1"),), (fault, at), parse_seeds("5")).runs()
    by_point = [[(r.as_dict()["fault"], r.as_dict()["fault_at_s"]) for r in runs if r.as_dict()["payload_kg"] == p]
                for p in (0.0, 1.0)]
    assert by_point[0] == by_point[1]


@pytest.mark.parametrize("make, reason", [
    (lambda: GridAxis.parse("payload_kg"), "NAME=VALUES"),
    (lambda: GridAxis.parse("payload_kg=0,heavy"), "not a number"),
    (lambda: GridAxis.parse("payload_kg=0..1/1"), "between 2"),
    (lambda: GridAxis.parse("gravity=a..b/3"), "numbers or ISO"),
    (lambda: GridAxis.parse("seed=1,2"), "--seeds"),
    (lambda: GridAxis.parse("bad name=1"), "letters, digits"),
    (lambda: DrawnAxis.parse("payload_kg=2..1"), "below its start"),
    (lambda: parse_seeds("many"), "a count"),
    (lambda: parse_seeds("0"), "between 1"),
    (lambda: Matrix((GridAxis.parse("fault=jam:j2"),)), "needs its time"),
    (lambda: Matrix((GridAxis.parse("fault_at_s=1"),)), "vary or draw `fault`"),
    (lambda: Matrix((GridAxis.parse("dial=1"), GridAxis.parse("dial=2"))), "more than once"),
    (lambda: Matrix((GridAxis.parse("a=0..1/10000"), GridAxis.parse("b=0..1/10000"))), "at most"),
])
def test_a_matrix_that_does_not_make_sense_is_refused_saying_why(make, reason):
    with pytest.raises(ValueError, match=reason):
        make()


# ---- one run -------------------------------------------------------------------------------------------------------

def test_a_runs_values_set_its_world_and_the_rest_are_the_bench_variables():
    world, variables = world_of(WorldSettings(), {"seed": 7, "gravity": "orbit", "payload_kg": 1.5,
                                                  "sun_start": "2026-03-20T06:50-07:00", "fault": "jam:j2",
                                                  "fault_at_s": 3.5, "impairment": "radio,seed=4",
                                                  "param.j1_kp": 40.0, "dial": "10"})
    assert (world.seed, world.plant.gravity, world.plant.payload_kg) == (7, "orbit", 1.5)
    assert world.plant.start.isoformat() == "2026-03-20T13:50:00+00:00"
    assert world.faults == (TimedFault("jam:j2", 3.5),) and world.impairment == "radio,seed=4"
    assert world.params == (("j1_kp", 40.0),) and variables == {"dial": "10"}
    assert world_of(WorldSettings(), {"seed": 0, "fault": "none", "fault_at_s": 2.0})[0].faults == ()
    for bad in ({"payload_kg": -1.0}, {"fault": "jam:j9", "fault_at_s": 1.0}, {"sun_start": "tomorrow"},
                {"impairment": "stormy"}):
        with pytest.raises(ValueError):
            world_of(WorldSettings(), bad)


def test_a_run_whose_settings_do_not_fit_is_an_error_row_and_the_campaign_goes_on(tmp_path):
    bench = BenchSpec("script", "drill.aspod", text=DRILL, cwd=str(tmp_path))
    runs = [Run(0, (("seed", 0), ("speed", "1"), ("param.j1_kp", 1e9))),
            Run(1, (("seed", 0), ("spede", "1"))),
            Run(2, (("seed", 0), ("speed", "1")))]
    rows = [r.row for r in run_runs(bench, runs, EngineSettings(serial=True))]
    assert [r["outcome"] for r in rows] == ["error", "error", "passed"]
    assert "j1_kp" in rows[0]["error"] and "${speed}" in rows[1]["error"]


# ---- campaigns from the command line -------------------------------------------------------------------------------

@pytest.fixture
def drill(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "drill.aspod").write_text(DRILL)
    return tmp_path


MATRIX = ["--vary", "speed=1,2", "--seeds", "3", "--draw", "fault=none,jam:j2,open_circuit:j2",
          "--draw", "fault_at_s=0.5..1.5", "--no-progress"]


@pytest.mark.cpu_hog        # two worker processes: kept apart from the tests that measure real time
@pytest.mark.long
def test_two_dask_workers_give_the_rows_of_a_serial_run_and_a_failed_rows_command_reproduces_it(drill, capsys):
    assert main(["campaign", "drill.aspod", *MATRIX, "--workers", "2", "--out", "dask",
                 "--plot", "fault.safe_after_s:fault", "--hist", "sim_s"]) == 1      # some runs fault: status 1
    assert main(["campaign", "drill.aspod", *MATRIX, "--serial", "--out", "serial"]) == 1
    assert (drill / "dask" / "rows.csv").read_bytes() == (drill / "serial" / "rows.csv").read_bytes()
    rows = rows_of(drill / "dask")
    assert len(rows) == 6 and {r["speed"] for r in rows} == {"1", "2"}
    doc = json.loads((drill / "dask" / "campaign.json").read_text())
    assert doc["runs"] == 6 and doc["engine"] == "Dask local cluster, 2 workers" and len(doc["timing"]["run_wall_s"]) == 6
    assert doc["command"].startswith("aspod campaign drill.aspod --vary speed=1,2 ") and "--workers 2" in doc["command"]
    assert (drill / "dask" / "plot-fault.safe_after_s-vs-fault.png").stat().st_size > 1000
    assert (drill / "dask" / "hist-sim_s.png").stat().st_size > 1000
    failed = [r for r in rows if r["outcome"] == "failed"]
    assert failed and all(r["fault"] != "none" and r["fault.within_stated"] == "True" for r in failed)
    assert all(r["outcome"] == "passed" for r in rows if r["fault"] == "none")
    out = capsys.readouterr().out
    assert "fault=jam:j2" in out or "fault=open_circuit:j2" in out
    # the failed row's command, run alone, does what the row says
    row = failed[0]
    argv = shlex.split(row["reproduce"])
    assert argv[:3] == ["aspod", "bench", "drill.aspod"]
    assert main([*argv[1:], "--json"]) == 1
    alone = json.loads(capsys.readouterr().out)
    assert alone["faults"][0]["safe_after_s"] == float(row["fault.safe_after_s"])
    assert alone["plant"]["joints_deg"]["j2"] == pytest.approx(float(row["plant.joints_deg.j2"]), abs=1e-6)


PYTEST_BENCH = '''
def test_jog(aspod_target):
    from protocol.messages import MESSAGES as M
    assert aspod_target.call(M["Enable"]()).ok
    from protocol.states import Axis
    assert aspod_target.call(M["Jog"](int(Axis.J1), float(aspod_target.variables["speed"]))).ok
    aspod_target.wait_until(lambda: False, 2.0)
    aspod_target.measure("j1_deg", round(aspod_target.true_state()["joints_deg"]["j1"], 6), "deg")
    assert not [e for e in aspod_target.events if e.spec.name == "MotionDone"], "the jog ended"
'''


@pytest.mark.long
def test_a_pytest_bench_runs_as_a_campaign_with_its_measurements_and_its_command_reproduces_a_row(
        tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "test_jog.py").write_text(PYTEST_BENCH)
    assert main(["campaign", "test_jog.py::test_jog", "--vary", "speed=1,3", "--draw", "fault=jam:j1",
                 "--vary", "fault_at_s=1,5", "--serial", "--out", "c", "--no-progress"]) == 1
    rows = rows_of(tmp_path / "c")
    assert [(r["speed"], r["fault_at_s"], r["outcome"]) for r in rows] == [
        ("1", "1.0", "failed"), ("1", "5.0", "passed"), ("3", "1.0", "failed"), ("3", "5.0", "passed")]
    moved = {r["speed"]: float(r["m.j1_deg"]) for r in rows if r["outcome"] == "passed"}
    assert moved["3"] > moved["1"] + 1.0                 # the variable reached the test: a faster jog went further
    assert rows[0]["fault.bits"] and rows[0]["error"].startswith("AssertionError")
    assert rows[1]["fault.safe_after_s"] == ""           # injected at 5 s, after the test ended: no answer
    argv = shlex.split(rows[0]["reproduce"])
    assert argv[:2] == ["pytest", "test_jog.py::test_jog"] and "--aspod-fault=jam:j1@1" in argv
    capsys.readouterr()
    assert pytest.main([*argv[1:], "-p", "no:cacheprovider", "--aspod-json=alone", "-q"]) == 1
    (record,) = [json.loads(p.read_text()) for p in (tmp_path / "alone").glob("*.json")]
    assert record["outcome"] == "failed" and record["faults"][0]["safe_after_s"] == float(rows[0]["fault.safe_after_s"])


@pytest.mark.parametrize("args, reason", [
    (["nowhere.aspod"], "nowhere.aspod"),
    (["drill.aspod", "--vary", "payload_kg=heavy"], "not a number"),
    (["drill.aspod", "--serial", "--workers", "2"], "--serial"),
    (["drill.aspod", "--plot", "nocolon"], "Y:X"),
    (["nothere.py"], "no file"),
])
def test_bad_campaign_arguments_are_refused_with_the_reason_and_write_nothing(drill, args, reason, capsys):
    assert main(["campaign", *args, "--out", "c", "--no-progress"]) == 2
    assert reason in capsys.readouterr().err
    assert not (drill / "c").exists()


def test_a_campaign_reads_its_script_as_bench_does_a_fifo_or_an_oversized_script_refused(drill, capsys):
    os.mkfifo(drill / "fifo.aspod")
    assert main(["campaign", "fifo.aspod", "--vary", "speed=1", "--out", "c", "--no-progress"]) == 2
    assert "FIFO" in capsys.readouterr().err
    (drill / "big.aspod").write_bytes(b"# filler\n" * (SCRIPT_LIMIT // 9 + 1))
    assert main(["campaign", "big.aspod", "--vary", "speed=1", "--out", "c", "--no-progress"]) == 2
    assert f"larger than {files.size_text(SCRIPT_LIMIT)}" in capsys.readouterr().err
    assert not (drill / "c").exists()


def test_a_campaign_refuses_a_scripts_first_line_that_gives_more_than_its_world(drill, capsys):
    (drill / "rec.aspod").write_text("#! aspod bench --seed 2 --record victim.pcapng\n" + DRILL)
    assert main(["campaign", "rec.aspod", "--vary", "speed=1", "--out", "c", "--no-progress"]) == 2
    assert "'--record' is not an option a script may give" in capsys.readouterr().err
    assert not (drill / "c").exists() and not (drill / "victim.pcapng").exists()


def test_a_folder_that_holds_a_campaign_is_not_written_over(drill, capsys):
    assert main(["campaign", "drill.aspod", "--vary", "speed=1", "--serial", "--out", "c", "--no-progress"]) == 0
    before = (drill / "c" / "rows.csv").read_bytes()
    assert main(["campaign", "drill.aspod", "--vary", "speed=2", "--serial", "--out", "c", "--no-progress"]) == 2
    assert "already holds a campaign" in capsys.readouterr().err
    assert (drill / "c" / "rows.csv").read_bytes() == before


def test_a_scheduler_address_that_accepts_but_never_speaks_dask_is_refused_within_the_connect_timeout(drill):
    """It once waited for Dask's handshake for ever: the TCP connect is bounded, the handshake was not."""
    with socket.socket() as silent:                   # the kernel accepts connections into the backlog; no one answers
        silent.bind(("127.0.0.1", 0))
        silent.listen(8)
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        done = subprocess.run([sys.executable, "-m", "host_tools.cli.main", "campaign", "drill.aspod", "--seeds", "1",
                               "--no-progress", "--scheduler", address], capture_output=True, text=True, cwd=drill,
                              env={**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"},
                              timeout=120)            # the bound asked is 2 s: a hang, not a slow machine, passes 120
    assert done.returncode == 3, done.stderr
    assert f"--scheduler {address}: no Dask scheduler answered within 2 s" in done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.cpu_hog
@pytest.mark.long
def test_a_running_dask_scheduler_takes_the_campaign_and_parquet_holds_the_same_rows(drill, capsys):
    from distributed import LocalCluster

    from host_tools.campaign.results import read_rows
    small = ["--vary", "speed=1,2", "--draw", "fault=none,jam:j2", "--draw", "fault_at_s=0.5..1.5", "--no-progress"]
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        address = cluster.scheduler_address
        assert address.startswith("tcp://")
        main(["campaign", "drill.aspod", *small, "--scheduler", address, "--out", "remote", "--format", "parquet"])
    main(["campaign", "drill.aspod", *small, "--serial", "--out", "serial"])
    remote, serial = read_rows(drill / "remote" / "rows.parquet"), rows_of(drill / "serial")
    assert [r["run"] for r in remote] == [0, 1] and remote[0]["ok"] in (True, False)
    assert [{k: "" if v is None else str(v) for k, v in r.items()} for r in remote] == serial
    assert json.loads((drill / "remote" / "campaign.json").read_text())["engine"] == f"Dask scheduler at {address}"
