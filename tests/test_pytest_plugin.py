"""The pytest plugin as a user meets it: a project outside this repository, with the package installed, runs
`pytest` with the `aspod_target` fixture and a `*.aspod` script: on the lock-step world, then against a live
`aspod sim` over a pty (`--aspod-target`), whose plant the fault test reaches through the simulator's control
endpoint (found from the target's URL), and against one without it (`--no-control`, as real hardware), where
that test is skipped with its reason."""
from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from host_tools.worlds.child import run
from tests import test_e2e

env, sim_factory = test_e2e.env, test_e2e.sim_factory      # the fixtures, shared

BENCH = '''
from protocol.messages import MESSAGES as M
from protocol.states import Axis, MotionOutcome


def ends(target, axis):
    return [e for e in target.events if e.spec.name == "MotionDone" and e.axis == int(axis)]


def test_moveby_lands_within_the_spec(aspod_target):
    assert aspod_target.call(M["Enable"]()).ok
    assert aspod_target.call(M["MoveBy"](int(Axis.J1), 2.0, 2.0)).reply.result == 0
    assert aspod_target.wait_until(lambda: ends(aspod_target, Axis.J1), 15)
    end = ends(aspod_target, Axis.J1)[0]
    aspod_target.measure("j1_error_deg", abs(end.position - 2.0), "deg")
    assert end.outcome == MotionOutcome.DONE and abs(end.position - 2.0) < 0.05


def test_an_encoder_dropout_stops_the_motion_as_a_fault(aspod_target):
    assert aspod_target.call(M["Enable"]()).ok
    aspod_target.inject("encoder_dropout", "j1")
    aspod_target.call(M["MoveBy"](int(Axis.J1), 2.0, 2.0))
    assert aspod_target.wait_until(lambda: ends(aspod_target, Axis.J1), 15)
    assert ends(aspod_target, Axis.J1)[0].outcome == MotionOutcome.FAULT
    assert aspod_target.true_state()["faults"] == ["encoder_dropout:j1"]
'''
SCRIPT = "#! aspod bench --seed 3\nenable\nmoveby j2 1 1\nwait\nstatus\n"


@pytest.fixture
def project(tmp_path):
    (tmp_path / "test_arm_bench.py").write_text(BENCH)
    (tmp_path / "moves.aspod").write_text(SCRIPT)
    return tmp_path


def run_pytest(project, *args: str, env=None, peers=()) -> tuple[subprocess.CompletedProcess, dict]:
    done = run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-p", "no:xdist", "-rs",
                "--junitxml", str(project / "junit.xml"), "--aspod-json", str(project / "records"), *args],
               cwd=project, text=True, timeout_s=300, env=env, peers=peers)
    cases = {c.get("name"): c for c in ET.parse(project / "junit.xml").getroot().iter("testcase")}
    return done, cases


def test_outside_the_repository_on_the_lockstep_world(project):
    done, cases = run_pytest(project)
    assert done.returncode == 0, done.stdout[-3000:]
    assert "3 passed" in done.stdout
    assert set(cases) == {"test_moveby_lands_within_the_spec", "test_an_encoder_dropout_stops_the_motion_as_a_fault",
                          "moves.aspod"}
    props = {p.get("name"): p.get("value") for p in cases["moves.aspod"].iter("property")}
    assert props["line 3"] == "ok: moveby j2 1 1"
    record = json.loads((project / "records" / "test_arm_bench.py_test_moveby_lands_within_the_spec.json").read_text())
    assert record["outcome"] == "passed" and record["target"] == "lockstep"
    assert record["measurements"]["j1_error_deg"]["value"] < 0.05
    script = json.loads((project / "records" / "moves.aspod_moves.aspod.json").read_text())
    assert [s["text"] for s in script["steps"]] == ["enable", "moveby j2 1 1", "wait", "status"]


@pytest.mark.parametrize("option, said", [
    ("--aspod-target=bogus://x", "--aspod-target: bogus://x: unknown link scheme bogus://; a link is a device"),
    ("--aspod-gravity=mars", "--aspod options: argument --gravity: invalid choice: 'mars'"),
    ("--aspod-payload-kg=-1", "--aspod options: argument --payload-kg: -1.0 is outside 0.0..1000.0"),
    ("--aspod-param=nosuch=1", "--aspod options: --param nosuch: the controller has no such parameter"),
    ("--aspod-param=trk_ff=0.5", "--aspod options: --param trk_ff=0.5: 0 (relay logic) or 1 (feed-forward)"),
])
def test_a_bad_option_is_the_runs_usage_error_said_once_before_anything_runs(project, option, said):
    done = run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-p", "no:xdist", option,
                "test_arm_bench.py"], cwd=project, text=True, timeout_s=300)
    assert done.returncode == pytest.ExitCode.USAGE_ERROR, done.stdout[-2000:] + done.stderr[-2000:]
    assert said in done.stderr and done.stderr.count(said) == 1, done.stderr
    assert "passed" not in done.stdout and "error" not in done.stdout.lower()


@pytest.mark.pty
def test_outside_the_repository_against_a_live_sim_its_plant_through_the_control_endpoint(project, sim_factory):
    sim = sim_factory("--pty", "--no-tracker")
    # (option=value: pytest takes a separate value that names a file, such as /dev/pts/N, for a path to test)
    done, cases = run_pytest(project, f"--aspod-target={sim.url}", f"--aspod-key-file={sim.key_path}", env=sim.env,
                             peers=(sim.child.pid,))
    assert done.returncode == 0, done.stdout[-3000:]
    assert "3 passed" in done.stdout
    record = json.loads((project / "records" / "test_arm_bench.py_test_moveby_lands_within_the_spec.json").read_text())
    assert record["target"].startswith("live ") and record["outcome"] == "passed"
    sim.child.wait_stderr(r"^aspod sim: control: injected encoder_dropout:j1$")    # each change said by the sim


@pytest.mark.pty
def test_outside_the_repository_against_a_live_target_without_a_plant_the_fault_test_skips(project, sim_factory):
    sim = sim_factory("--pty", "--no-tracker", "--no-control")      # as real hardware: no plant to reach
    done, cases = run_pytest(project, f"--aspod-target={sim.url}", f"--aspod-key-file={sim.key_path}",
                             "test_arm_bench.py", env=sim.env, peers=(sim.child.pid,))
    assert done.returncode == 0, done.stdout[-3000:]
    assert "1 passed, 1 skipped" in done.stdout
    skipped = cases["test_an_encoder_dropout_stops_the_motion_as_a_fault"].find("skipped")
    message = skipped.get("message") if skipped is not None else ""
    assert "no plant to fault" in message and "no control endpoint" in message and "--aspod-control" in message


SLOW_BENCH = '''
def test_a_wait_and_the_time_are_the_controllers(aspod_target):
    said = lambda: aspod_target.telemetry["TelemetryStatus"].uptime_ms / 1000
    assert aspod_target.wait_until(lambda: "TelemetryStatus" in aspod_target.telemetry, 5)
    first, start = said(), aspod_target.now()
    assert not aspod_target.wait_until(lambda: False, 2.0)
    # (times are whole ms of uptime over 1000: 3.8 - 1.8 is 1.9999999999999998, so a nanosecond's grace)
    assert aspod_target.now() - start >= 2.0 - 1e-9 and said() - first >= 1.8 - 1e-9, \
        (start, aspod_target.now(), first, said())
'''


@pytest.mark.pty
def test_a_live_targets_waits_and_time_are_the_controllers_so_a_slower_world_is_waited_for(sim_factory, tmp_path):
    """A simulator on a busy machine slows its world down rather than fault (docs/realtime.md); `--speed 0.25` does so
    on purpose. A bench's `wait_until(..., 2.0)` is 2 s of the controller's time, as on the lock-step world (it was
    2 s of the wall clock: half a second of the controller's, and a fault drill's reaction measured four times too
    long)."""
    sim = sim_factory("--pty", "--no-tracker", "--speed", "0.25")
    (tmp_path / "test_slow.py").write_text(SLOW_BENCH)
    done, _ = run_pytest(tmp_path, f"--aspod-target={sim.url}", f"--aspod-key-file={sim.key_path}", env=sim.env,
                         peers=(sim.child.pid,))
    assert done.returncode == 0 and "1 passed" in done.stdout, done.stdout[-3000:]


def test_the_worked_example_fault_drill_runs_as_pytest_benches(tmp_path):
    """`pytest benches/...` as docs/benches.md shows it (the pick-and-place and the procedure are run by their own
    tests: test_demo, test_procedure_bench)."""
    root = Path(__file__).resolve().parent.parent
    done = run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-p", "no:xdist",
                "--aspod-json", str(tmp_path), str(root / "benches" / "test_fault_drill.py")],
               cwd=root, text=True, timeout_s=300)
    assert done.returncode == 0, done.stdout[-3000:]
    records = [json.loads(p.read_text()) for p in tmp_path.glob("*.json")]
    assert len(records) == 3 and all(r["outcome"] == "passed" for r in records)
    assert all(0 < r["measurements"]["reaction_s"]["value"] <= 2.0 for r in records)


@pytest.mark.pty
@pytest.mark.long
def test_the_worked_example_benches_run_twice_in_a_row_on_one_live_sim_with_no_reset(sim_factory, tmp_path):
    """Issue 34's bench from a clean start: a fresh `aspod sim --pty`, then `pytest benches/ --aspod-target=URL`
    twice. Each test's session closes (no LINK_LOST for the next), and the fault drills leave the simulator as they
    found it (their plant faults cleared, the fault they latched reset), so every test of the second run starts
    IDLE too. The pick-and-place needs the lock-step world and the procedure a world of its own: skipped, saying
    so."""
    sim = sim_factory("--pty")
    root = Path(__file__).resolve().parent.parent
    for attempt in range(2):
        done = run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-p", "no:xdist", "-rs",
                    f"--aspod-target={sim.url}", str(root / "benches")], cwd=tmp_path, text=True, timeout_s=600,
                   env=sim.env, peers=(sim.child.pid,))
        if done.returncode != 0:
            _, said = sim.stop()
            raise AssertionError(f"run {attempt + 1}: {done.stdout[-3000:]}\nthe simulator: {said[-3000:]}")
        assert "3 passed, 2 skipped" in done.stdout, done.stdout[-3000:]
    sim.child.wait_stderr(r"the host closed its session")
    assert not any("LINK_LOST" in line for line in sim.child.seen)
