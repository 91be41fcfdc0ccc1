"""Teleop drives the arm: `aspod sim --pty` as a subprocess, teleop scripts over the real pty.

Real time (homing alone takes about 7 s), so the moves are small (2-3 deg at the default
3 deg/s) and run side by side; bounds are generous and the tests assert behaviour, not speed.
The tests that run on one pytest worker share one simulator (module scope); each one that needs
the arm homed homes it itself if an earlier test there did not, and none reads another's results.
"""
from __future__ import annotations

import io
import json
import os
import re
import signal
import sys
from pathlib import Path

import pytest

from host_tools.client.bench import BenchClient
from host_tools.client.live import HostClient
from host_tools.exit_codes import EXIT_FAILED, EXIT_OK
from host_tools.teleop.session import run_script
from host_tools.teleop.motion import MotionTracker
from host_tools.teleop.words import parse_line
from host_tools.worlds.world import LockstepBench
from host_tools.worlds.child import Child, run
from protocol import auth
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.states import ARM_AXES, Axis, AxisMode, MotionOutcome

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
AXES = ("j1", "j2", "j3", "j4", "gripper", "mount")
JOINTS = ("j1", "j2", "j3", "j4", "mount")
HOME = "reset\nenable\nhome all\nwait all 60\n"
END = re.compile(r"^! (\w+)#(\d+) (\w+) at (-?[\d.]+) (deg|mm) \(line (\d+): ([^,]+)", re.M)


class ArmSim:
    def __init__(self, tmp: Path) -> None:
        self.env = {**os.environ, "XDG_CONFIG_HOME": str(tmp / "config")}
        self.params = tmp / "params.json"
        self.log = tmp / "sim.stderr"                 # what the simulator says (state changes and why): for failures
        # --link-timeout 10: in three CI runs of 2026-11-24 this session's sim went to its safe state with
        # LINK_TIMEOUT during `home all` (uptime 7.7-10.1 s) while teleop kept sending; not understood yet (the sim
        # kept real time in every run reproduced here, busy loops beside it or not). The link timeout itself is
        # tested in test_e2e; here it would only hide what these tests are about.
        with self.log.open("wb") as log:
            self.child = Child(["sim", "--pty", "--telemetry-hz", "10", "--link-timeout", "10",
                                "--params", str(self.params)], stderr=log, env=self.env)
        self.url = self.child.ready("ASPOD-LINK ").split(" ", 1)[1]
        self.key_path = Path(self.child.ready("ASPOD-KEY ").split(" ", 1)[1])
        self.homed = False

    def teleop(self, script: str, tmp: Path, *args: str) -> tuple[int, str, str]:
        path = tmp / "script.txt"
        path.write_text(script)
        done = run(ASPOD + ["teleop", self.url, "--script", str(path), *args], env=self.env, timeout_s=120,
                   peers=(self.child.pid,))
        said = self.log.read_text(errors="replace").splitlines()[-12:]
        return done.returncode, done.stdout.decode(), done.stderr.decode() + "\nthe simulator:\n" + "\n".join(said)

    def ensure_homed(self, tmp: Path) -> None:
        if not self.homed:
            status, out, err = self.teleop(HOME, tmp)
            assert status == EXIT_OK, out + err
            self.homed = True

    def stop(self) -> None:
        self.child.stop(signal.SIGTERM, timeout_s=10)


# ---- the motion tracker, without a link ----
def accepted(axis: Axis, motion_id: int):
    """A MotionAccepted for `axis` (`all`: every axis, each with `motion_id`)."""
    ids = [motion_id if axis in (a, Axis.ALL) else 0 for a in ARM_AXES]
    return SCHEMA["MotionAccepted"].type(0, int(axis), 0 if axis is Axis.ALL else motion_id, *ids, "", 0.0, 0.0)


def done(axis: Axis, motion_id: int, outcome=MotionOutcome.DONE, reason=Reason.OK, uptime_ms: int = 1000):
    return SCHEMA["MotionDone"].type(int(axis), motion_id, int(outcome), int(reason), 1.0, uptime_ms)


def test_home_all_ends_are_matched_per_axis_by_the_ids_its_reply_names():
    tracker = MotionTracker()
    tracker.on_done(done(Axis.J1, 4, uptime_ms=100), 0.0)        # an end held over from an earlier session
    tracker.sending()
    motions, replaced, held = tracker.started(parse_line("home all", 3), accepted(Axis.ALL, 5), 1.0)
    assert [m.label for m in motions] == ["j1#5", "j2#5", "j3#5", "j4#5", "gripper#5", "mount#5"]
    assert replaced == [] and held == []
    mine, _, show = tracker.on_done(done(Axis.J1, 4, uptime_ms=600), 2.0)   # not the id the reply named
    assert mine is None and show
    mine, _, _ = tracker.on_done(done(Axis.J1, 5, uptime_ms=700), 3.0)
    assert mine is motions[0] and mine.ok
    assert len(tracker.running()) == 5 and tracker.running(int(Axis.J1)) == []


def test_an_end_that_comes_before_its_reply_is_held_then_claimed():
    tracker = MotionTracker()
    tracker.sending()
    mine, _, show = tracker.on_done(done(Axis.GRIPPER, 2), 1.0)
    assert mine is None and not show                              # held: the reply may name it
    motions, _, held = tracker.started(parse_line("grip open", 1), accepted(Axis.GRIPPER, 2), 1.1)
    assert held == [(held[0][0], motions[0])] and not motions[0].running


def start(tracker: MotionTracker, line: str, line_no: int, reply, now: float):
    tracker.sending()
    return tracker.started(parse_line(line, line_no), reply, now)


def test_a_replaced_motion_is_not_waited_for_and_a_failed_end_is_counted_once():
    tracker = MotionTracker()
    first, _, _ = start(tracker, "moveby j1 5", 1, accepted(Axis.J1, 2), 0.0)
    second, replaced, _ = start(tracker, "moveby j1 1", 2, accepted(Axis.J1, 3), 0.5)
    assert replaced == first and first[0].replaced_by == "this moveby j1 1" and tracker.running() == second
    tracker.on_done(done(Axis.J1, 2, MotionOutcome.SUPERSEDED, Reason.HOST_REQUEST), 0.6)   # expected of it
    assert first[0].ok and tracker.take_failures() == []
    tracker.on_done(done(Axis.J1, 3, MotionOutcome.DISABLED, Reason.CANCELLED), 1.0)
    assert [m.label for m in tracker.take_failures()] == ["j1#3"] and tracker.take_failures() == []
    jog, _, _ = start(tracker, "jog j2 1", 3, accepted(Axis.J2, 1), 2.0)
    tracker.on_done(done(Axis.J2, 1, MotionOutcome.STOPPED, Reason.HOST_REQUEST), 3.0)
    assert jog[0].ok and tracker.take_failures() == []           # a jog ends STOPPED by `stop`
    assert tracker.counts() == {"started": 3, "done": 1, "failed": 1, "replaced": 1, "running": 0}


def test_a_superseded_end_before_the_reply_of_its_replacement_is_expected_too():
    tracker = MotionTracker()
    first, _, _ = start(tracker, "moveby j2 5", 1, accepted(Axis.J2, 1), 0.0)
    tracker.sending()                                             # the second moveby, not answered yet
    mine, _, _ = tracker.on_done(done(Axis.J2, 1, MotionOutcome.SUPERSEDED, Reason.HOST_REQUEST), 0.1)
    assert mine is first[0] and mine.ok and mine.superseded
    tracker.started(parse_line("moveby j2 5", 2), accepted(Axis.J2, 2), 0.2)
    tracker.on_done(done(Axis.J2, 2), 3.0)
    assert tracker.take_failures() == []
    assert tracker.counts() == {"started": 2, "done": 1, "failed": 0, "replaced": 1, "running": 0}
    # replaced by no command of this session (another host's): a failure
    lone, _, _ = start(tracker, "moveby j3 1", 3, accepted(Axis.J3, 1), 4.0)
    tracker.on_done(done(Axis.J3, 1, MotionOutcome.SUPERSEDED, Reason.HOST_REQUEST), 4.5)
    assert [m.label for m in tracker.take_failures()] == ["j3#1"]


# ---- a teleop script on the simulated clock (BenchClient on a LockstepBench) ----
@pytest.fixture
def arm_bench():
    bench = LockstepBench(seed=5)
    executed: list[str] = []                 # every command the controller executed, by name
    handler = bench.controller.link._handler

    def counting(msg, urgent, now):
        executed.append(msg.spec.name)
        return handler(msg, urgent, now)
    bench.controller.link._handler = counting
    yield bench, executed
    bench.close()


def bench_script(bench, script: str) -> tuple[int, str, str, dict[str, int]]:
    """Run a teleop script: (exit status, output, errors, the session's motion counts)."""
    client = BenchClient(bench)
    client.connect()
    out, err = io.StringIO(), io.StringIO()
    status, session = run_script(client, script.splitlines(), out, err=err, wall_time=client.wall_time)
    session.close()
    return status, out.getvalue(), err.getvalue(), session.tracker.counts()


def test_a_motion_replaced_by_a_newer_one_ends_superseded_as_expected_and_the_script_succeeds(arm_bench):
    bench, _ = arm_bench
    status, out, err, counts = bench_script(bench, "enable\nmoveby j2 5\nmoveby j2 5\nwait all\n")
    assert status == EXIT_OK, out + err
    assert "j2#1 (line 2: moveby j2 5) was replaced by this moveby j2 5; it ends SUPERSEDED, as expected" in out
    assert re.search(r"^! j2#1 SUPERSEDED at ", out, re.M) and re.search(r"^! j2#2 DONE at ", out, re.M), out
    assert counts == {"started": 2, "done": 1, "failed": 0, "replaced": 1, "running": 0}


def test_home_all_in_a_script_waits_for_every_homing_the_reply_names(arm_bench):
    bench, _ = arm_bench
    status, out, err, _ = bench_script(bench, "enable\nhome all\nwait all 60\n")
    assert status == EXIT_OK, out + err
    assert "ok   motion all started, one end each: j1#1 j2#1 j3#1 j4#1 gripper#1 mount#1" in out
    assert len(re.findall(r"^! \w+#1 DONE at .*\(line 2: home all", out, re.M)) == 6, out
    assert "ok   wait all: 6 motion(s) ended" in out


def test_a_refused_move_names_the_limit_and_its_value_with_no_parameter_read(arm_bench):
    bench, executed = arm_bench
    status, out, err, _ = bench_script(bench, "enable\nhome j1\nwait j1 60\nmove j1 100\n")
    assert status == EXIT_FAILED, out + err
    assert "FAIL Move: rejected: SOFT_LIMIT (28)" in out
    assert "j1: target 100 deg is beyond j1_max_deg = 85 deg (soft limits j1_min_deg .. j1_max_deg)" in out, out
    status, out, err, _ = bench_script(bench, "move j1 4 20\n")
    assert status == EXIT_FAILED and "FAIL Move: rejected: OUT_OF_RANGE" in out, out + err
    assert "j1: speed 20 deg/s is above its highest, j1_speed_dps = 3 deg/s" in out, out
    assert "ParamGet" not in executed, executed


# ---- over a real pty, with `aspod sim` ----
@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    arm = ArmSim(tmp_path_factory.mktemp("arm"))
    yield arm
    arm.stop()


def ends(out: str) -> dict[str, list[tuple]]:
    """MotionDone lines by axis: (id, outcome, position, line number, command)."""
    found: dict[str, list[tuple]] = {}
    for axis, motion_id, outcome, pos, _unit, line_no, text in END.findall(out):
        found.setdefault(axis, []).append((int(motion_id), outcome, float(pos), int(line_no), text.strip()))
    return found


SESSION = """\
reset
enable
home all
wait all 60
watch 0.5
move j1 2
move j2 2
move j3 2
move j4 2
moveby mount 3
grip close
wait all 30
grip open
wait gripper 30
watch 0.5
get j1_max_deg
set j1_speed_dps 2.5
save
status
"""


@pytest.mark.pty
@pytest.mark.long
def test_a_script_homes_the_arm_moves_every_joint_grips_and_saves_a_parameter(sim, tmp_path):
    status, out, err = sim.teleop(SESSION, tmp_path, "--summary")
    assert status == EXIT_OK, out + err
    sim.homed = True
    assert re.search(r"^ok   motion all started, one end each: j1#\d+ j2#\d+ j3#\d+ j4#\d+ gripper#\d+ mount#\d+ ",
                     out, re.M), out
    by_axis = ends(out)
    for axis in AXES:                       # home all: one end per axis, DONE, from line 3
        assert by_axis[axis][0][1:2] == ("DONE",) and by_axis[axis][0][3:] == (3, "home all"), by_axis[axis]
    for axis in ("j1", "j2", "j3", "j4"):   # each joint reached its target
        motion_id, outcome, pos, _line, text = by_axis[axis][1]
        assert f"ok   motion {axis}#{motion_id} started" in out
        assert outcome == "DONE" and text == f"move {axis} 2" and abs(pos - 2.0) < 0.05, by_axis[axis]
    home_end = by_axis["mount"][0][2]
    _id, outcome, pos, _line, _text = by_axis["mount"][1]
    assert outcome == "DONE" and abs(pos - (home_end + 3.0)) < 0.1, by_axis["mount"]
    grip = by_axis["gripper"]
    assert [g[1] for g in grip] == ["DONE"] * 3 and [g[4] for g in grip] == ["home all", "grip close", "grip open"]
    assert 0.0 <= grip[1][2] <= 60.0, grip                              # a sane opening after closing
    assert abs(grip[2][2] - 50.3) < 1.0                                 # open at its open switch again
    assert out.count("ok   wait all: 6 motion(s) ended") == 2
    assert "ok   wait gripper: 1 motion(s) ended" in out
    assert "homed 6/6" in out and "arm loop 1000 us: exec max" in out   # the watch block
    for axis in AXES:
        assert re.search(rf"^{axis}\s+yes\s+-?[\d.]+ (deg|mm)\s+-?[\d.]+ (deg|mm)/s\s+-?[\d.]+ A\s+HOLDING", out, re.M)
    assert "name=j1_max_deg value=85.00" in out and "name=j1_speed_dps value=2.50" in out
    assert json.loads(sim.params.read_text())["params"]["j1_speed_dps"] == 2.5
    assert "state=ENABLED faults=none" in out
    assert "motions: 13 started, 13 done, 0 failed, 0 replaced, 0 running" in out
    session = out.split("\ncommands: ")[0]                              # all but the --summary
    assert max(len(line) for line in session.splitlines()) <= 100, max(session.splitlines(), key=len)


@pytest.mark.pty
@pytest.mark.long
def test_a_move_beyond_a_soft_limit_is_refused_with_its_reason_and_remedy(sim, tmp_path):
    sim.ensure_homed(tmp_path)
    status, out, err = sim.teleop("reset\nenable\nmove j1 100\nstatus\n", tmp_path)
    assert status == EXIT_FAILED, out + err
    assert "FAIL Move: rejected: SOFT_LIMIT (28)" in out
    assert "the target lies beyond the joint's soft limit" in out and "remedy: choose a target inside the limits" in out
    assert "j1: target 100 deg is beyond j1_max_deg = 85 deg (soft limits j1_min_deg .. j1_max_deg)" in out
    assert "> status" not in out                                  # the script stopped there
    assert "error: line 3: 'move j1 100' failed; stopping" in err
    assert "motion j1#" not in out                                # nothing started


def positions(msg) -> dict[str, float]:
    return {a: getattr(msg, f"{a}_pos") for a in AXES}


@pytest.mark.pty
def test_estop_in_the_middle_of_a_move_stops_every_motor_until_reset_and_enable(sim):
    client = HostClient(sim.url, auth.load_key(sim.key_path))
    samples: list[tuple[float, object]] = []    # (the controller's time, telemetry): the host's receive times
    # bunch up when its process is descheduled, the controller's own stamps do not
    client.telemetry_listeners.append(
        lambda msg, now: msg.spec.name == "TelemetryJoints" and samples.append((msg.uptime_ms / 1000, msg)))
    try:
        client.connect()
        out, err = io.StringIO(), io.StringIO()
        script = ["reset", "enable", "moveby j1 3", "moveby j2 -3", "moveby j3 3", "moveby j4 3", "moveby mount 3",
                  "grip close", "wait 1", "estop", "wait 2", "status"]
        status, _session = run_script(client, script, out, keep_going=True, err=err)
        text = out.getvalue()
        moving = next(k for k, (_now, msg) in enumerate(samples) if msg.j1_mode == AxisMode.MOVING)
        estop_s = next(now for now, msg in samples[moving:] if msg.j1_mode == AxisMode.IDLE)
        # `wait 2` is wall time: on a busy machine the controller's own may be less; what follows wants 1.8 s of it
        assert sim.child.wait_for(lambda seconds: client.wait_for(lambda: samples[-1][0] >= estop_s + 1.8, seconds),
                                  30.0)
        # the motions were cut short: each ends DISABLED (CANCELLED, with its doc and remedy) and fails the script
        assert status == EXIT_FAILED, text + err.getvalue()
        by_axis = ends(text)
        assert {a: [e[1] for e in by_axis[a]] for a in AXES} == {a: ["DISABLED"] for a in AXES}, text
        assert "CANCELLED (38)" in text and "remedy: see the controller's state; enable and command it again" in text
        assert err.getvalue().count("ended DISABLED (CANCELLED)") == 6
        assert "state=ESTOP faults=ESTOP" in text
        # every motor off and braked; once the brakes have caught the joints, nothing moves for a second
        after = [(now, msg) for now, msg in samples if now >= estop_s + 0.6]
        assert after and after[-1][0] - after[0][0] >= 1.0, len(after)
        first = positions(after[0][1])
        for _now, msg in after:
            assert all(getattr(msg, f"{a}_mode") == AxisMode.IDLE for a in AXES)
            assert all(getattr(msg, f"{a}_current") == 0.0 for a in AXES)
            for axis in JOINTS:
                assert abs(getattr(msg, f"{axis}_pos") - first[axis]) < 0.01, (axis, first, msg)
        # the gripper too: the shorted armature (dynamic braking) stops the jaws within about 0.4 s
        jaws = [msg.gripper_pos for now, msg in samples if estop_s + 0.6 <= now <= estop_s + 1.8]
        assert jaws and max(jaws) - min(jaws) < 0.1, jaws
        # while the e-stop is latched, motion is refused with its reason
        status, _session = run_script(client, ["moveby j1 1"], out := io.StringIO(), err=io.StringIO())
        assert status == EXIT_FAILED and "FAIL MoveBy: rejected: ESTOP (18)" in out.getvalue()
        assert "remedy: clear the cause, then send reset" in out.getvalue()
        # reset and enable: motion works again, from where the arm stood
        held = positions(samples[-1][1])
        status, _session = run_script(client, ["reset", "enable", "moveby j1 1", "moveby mount -1", "wait all 20",
                                               "status"], out := io.StringIO(), err=io.StringIO())
        text = out.getvalue()
        assert status == EXIT_OK, text
        done = ends(text)
        assert done["j1"][0][1] == "DONE" and abs(done["j1"][0][2] - (held["j1"] + 1.0)) < 0.1, (held, text)
        assert done["mount"][0][1] == "DONE" and abs(done["mount"][0][2] - (held["mount"] - 1.0)) < 0.1, text
        assert "state=ENABLED" in text
    finally:
        client.close()


def test_params_shows_every_parameter_with_its_unit_range_and_description(arm_bench):
    bench, executed = arm_bench
    status, out, err, _ = bench_script(bench, "params\n")
    assert status == EXIT_OK, out + err
    assert re.search(r"^  j1_speed_dps +3 deg/s +\[0\.1 \.\. 28\] +j1 ", out, re.M), out
    assert re.search(r"^  supply_min_v +22 V +\[0 \.\. 60\] +supply below this is a fault \(nominal 28 V\)$", out,
                     re.M), out
    assert executed.count("ParamList") == len(bench.controller.params.order)
