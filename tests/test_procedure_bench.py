"""The report's ten-step operating procedure, then each interlock broken on purpose: benches/tracker_procedure.aspod.

Twice: on the simulated clock, the script's steps run one by one through teleop's `Session` on a
`LockstepBench` (`BenchClient`) while a probe samples the plant (relays, brakes, motor power,
angles, the true pointing error) every 50 ms, so each step is checked against what the plant
really did; and over a real pty, `aspod teleop --script` against `aspod sim --pty --sun-start`
(real time, generous bounds, behaviour not speed). The sun: the March equinox at Tucson, 06:50
MST, a little after sunrise due east (azimuth 92.5, elevation 4.1), near the stow (90, 0).
"""
from __future__ import annotations

import copy
import io
import os
import re
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import pytest
from test_teleop_arm import ASPOD

from hil_sim.sun import MST
from hil_sim.tracker import TrackerCommand
from host_tools.exit_codes import EXIT_OK
from host_tools.teleop.session import Session
from host_tools.client.bench import BenchClient
from host_tools.teleop.words import Step, check_script
from host_tools.worlds.world import LockstepBench
from host_tools.worlds import child
from host_tools.worlds.child import Child
from host_tools.worlds.settings import PlantSettings
from protocol.states import ControllerState, SwitchPosition as P

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "benches" / "tracker_procedure.aspod"
START = datetime(2026, 3, 20, 6, 50, tzinfo=MST)
PROBE_S = 0.05
STILL_DEG = 1e-9          # an axis held by its brake (or unpowered) does not move at all


@dataclass
class Sample:
    t: float
    angle: tuple[float, float]
    relays: tuple[tuple[bool, bool], tuple[bool, bool]]
    cmd: TrackerCommand
    error: tuple[float, float]        # sun - tracker per axis, the truth
    off_sun: float                    # angle between the focal axis and the sun


@dataclass
class Record:
    step: Step
    ok: bool
    t0: float
    t1: float
    box_before: object
    box_after: object


@dataclass
class Run:
    bench: LockstepBench
    records: list[Record]
    samples: list[Sample]
    out: str

    def record(self, text: str, nth: int = 0) -> Record:
        found = [r for r in self.records if r.step.text == text]
        assert len(found) > nth, f"no {nth + 1}. step {text!r} in the script"
        return found[nth]

    def next_change(self, record: Record) -> float:
        """When the box was next changed after `record` (the end of the run if never)."""
        later = self.records[self.records.index(record) + 1:]
        return next((r.t0 for r in later if r.box_after != r.box_before), self.samples[-1].t)

    def at(self, t: float) -> Sample:
        """The first sample at or after `t`."""
        return next(s for s in self.samples if s.t >= t - 1e-9)

    def before(self, t: float) -> Sample:
        """The last sample at or before `t`."""
        return [s for s in self.samples if s.t <= t + 1e-9][-1]

    def between(self, t0: float, t1: float) -> list[Sample]:
        return [s for s in self.samples if t0 - 1e-9 <= s.t <= t1 + 1e-9]


@pytest.fixture(scope="module")
def run():
    bench = LockstepBench(seed=3, plant=PlantSettings(start=START))
    client = BenchClient(bench)
    client.connect()
    tracker, plant = bench.world.plant.tracker, bench.world.plant
    samples: list[Sample] = []

    def probe(now: float) -> float:
        samples.append(Sample(now, tuple(tracker.angle_deg), tuple(tuple(r) for r in tracker.relay_closed),
                              plant.tracker_commands.current(now), tracker.pointing_error_deg(),
                              tracker.angular_error_deg()))
        return now + PROBE_S
    bench.world.scheduler.add("probe", probe, period_s=PROBE_S)
    steps, problems = check_script(SCRIPT.read_text(encoding="utf-8").splitlines())
    assert problems == []
    out = io.StringIO()
    session = Session(client, out, wall_time=client.wall_time)
    records = []
    box = bench.controller.tracker.box
    for step in steps:
        before, t0 = copy.deepcopy(box), bench.clock.now()
        ok = session.run_step(step)
        records.append(Record(step, ok, t0, bench.clock.now(), before, copy.deepcopy(box)))
    bench.run_for(0.2)
    session.close()
    yield Run(bench, records, samples, out.getvalue())
    bench.close()


def test_every_line_of_the_procedure_passes(run):
    failed = [f"line {r.step.line_no}: {r.step.text}" for r in run.records if not r.ok]
    assert failed == [], run.out
    assert "FAIL" not in run.out
    print(f"\nthe procedure: {len(run.records)} lines, {run.bench.clock.now():.1f} simulated s")


def test_steps_1_to_5_start_both_motors_at_a_low_dial_towards_the_sun(run):
    assert run.at(run.record("switch main on").t1 + 0.05).cmd.motor_power
    started = run.record("wait 1")                               # after step 5, the dial still at 0
    s0, s1 = run.at(started.t0 + 0.1), run.before(started.t1)
    assert s1.relays == ((True, False), (True, False))           # CW on both axes: towards the sun
    assert s1.cmd.duty_az == 0.0 and s1.angle == s0.angle        # closed at the dial's zero: nothing turns yet
    assert run.bench.world.plant.tracker.high_duty_starts == [0, 0]     # never a start at a high dial


def test_step_6_runs_each_axis_towards_the_sun_until_close_and_step_7_brakes_it(run):
    az_wait, el_wait = run.record("wait aligned az 1 120"), run.record("wait aligned el 1 120")
    moving = run.between(az_wait.t0, az_wait.t1)
    for k in (0, 1):                                             # both axes turn CW, steadily
        assert all(b.angle[k] >= a.angle[k] for a, b in zip(moving, moving[1:]))
        assert moving[-1].angle[k] - moving[0].angle[k] > 0.9
        assert moving[-1].error[k] < moving[0].error[k]
    assert 0.5 < run.at(az_wait.t1).error[0] < 1.05              # close: within about a degree
    braked_az = run.at(run.record("switch speed brake az").t1 + 0.05)
    assert braked_az.cmd.brake_az and braked_az.relays[0] == (False, False) and not braked_az.cmd.brake_el
    resumed = run.record("switch speed on", 1)                   # step 10: the motors again, in sensor mode
    still = run.between(braked_az.t, resumed.t0)
    assert max(s.angle[0] for s in still) - min(s.angle[0] for s in still) < STILL_DEG
    assert still[-1].angle[1] > braked_az.angle[1] + 0.5         # elevation ran on alone ...
    assert 0.5 < run.at(el_wait.t1).error[1] < 1.05              # ... until close too
    braked = run.between(run.record("switch speed brake el").t1 + 0.05, resumed.t0)
    assert all(s.cmd.brake_az and s.cmd.brake_el and s.angle == braked[0].angle for s in braked)


def test_steps_8_to_10_sensor_mode_closes_on_the_sun_through_the_photocells(run):
    assert run.at(run.record("switch sensor on").t1 + 0.05).cmd.sensor_power
    box = run.record("switch sensor on").box_after
    assert (box.mode, box.sensor, box.speed) == ([P.SENSOR, P.SENSOR], P.ON, [P.BRAKE, P.BRAKE])
    closing = run.record("wait aligned 0.5 120")
    during = run.between(closing.t0, closing.t1)
    for k in (0, 1):                                             # the sun is CW of both axes: only CW relays close
        assert any(s.relays[k] == (True, False) for s in during)
        assert not any(s.relays[k][1] for s in during)
    assert run.at(closing.t1).off_sun < 0.6 < during[0].off_sun
    assert run.bench.world.plant.tracker.both_closed_s == 0.0


@pytest.mark.parametrize("text", ["switch speed on", "switch main on", "switch mode manual", "switch direction ccw"])
def test_each_interlock_refuses_with_its_reason_and_nothing_changes(run, text):
    refused = run.record(f"expect DIAL_NOT_LOW {text}")
    assert refused.ok and refused.box_after == refused.box_before
    before = run.before(refused.t0)
    after = run.between(refused.t0, run.next_change(refused))       # until the box is next changed
    assert after[-1].t - refused.t1 > 1.9
    for name in ("brake_az", "brake_el", "motor_power", "sensor_power"):
        assert all(getattr(s.cmd, name) == getattr(before.cmd, name) for s in after), name
    assert "ok   BoxSwitch refused as expected: DIAL_NOT_LOW (39)" in run.out


def test_a_refused_start_leaves_the_tracker_braked_and_unpowered(run):
    stopped = run.record("switch speed brake").t1 + 0.05
    remedy = run.record("switch main on", 1)                     # the remedy after the second refusal
    held = run.between(stopped, remedy.t0)
    assert all(s.angle == held[0].angle and s.relays == ((False, False), (False, False)) for s in held)
    assert all(s.cmd.brake_az and s.cmd.brake_el for s in held)
    unpowered = run.between(run.record("switch main off").t1 + 0.05, remedy.t0)
    assert unpowered and not any(s.cmd.motor_power for s in unpowered)    # main stayed off through its refusal


def test_refused_mode_and_direction_changes_leave_it_tracking_in_sensor_mode(run):
    first = run.record("expect DIAL_NOT_LOW switch mode manual")
    last = run.record("wait aligned 0.75 30")
    box = run.bench.controller.tracker.box
    assert (box.mode, box.direction, box.speed, box.main) == ([P.SENSOR] * 2, [P.CW] * 2, [P.ON] * 2, P.ON)
    tracking = run.between(first.t0, last.t1)
    assert all(s.cmd.motor_power and not s.cmd.brake_az and not s.cmd.brake_el for s in tracking)
    assert max(s.off_sun for s in tracking) < 0.75
    assert run.bench.controller.tracker.refusals == 4


def test_the_procedure_ends_on_the_sun_with_a_healthy_controller(run):
    end = run.samples[-1]
    assert end.off_sun < 0.75
    assert run.bench.controller.supervisor.state is ControllerState.ENABLED
    assert not run.bench.controller.supervisor.faults
    assert run.bench.world.plant.tracker.high_duty_starts == [0, 0]
    # the panel at the end says so too
    panel = run.out.split("> box")[-1]
    assert re.search(r"^pointing error 0\.\d\d deg; .* refusals 4$", panel, re.M), panel


def test_the_doc_shows_the_script_and_the_panel_as_they_are():
    doc = (ROOT / "docs" / "tracker_procedure.md").read_text(encoding="utf-8")
    lines = {line.split("#", 1)[0].strip() for line in SCRIPT.read_text(encoding="utf-8").splitlines()}
    bench = doc.split("## The operating procedure as a bench")[1].split("Run it by hand")[0]
    tables = [row for row in bench.splitlines() if row.startswith("| ")]
    quoted = {q for row in tables for q in re.findall(r"`([a-z][^`]*)`", row) if q.split()[0] in
              ("reset", "telemetry", "clock", "enable", "dial", "switch", "wait", "expect")}
    assert len(quoted) > 20 and quoted <= lines, sorted(quoted - lines)
    assert re.search(r"\naxis +mode +dir +speed +% +relay +brake +% +mV +V +deg +deg\n", doc)     # box.AXIS_COLUMNS
    for word in ("--sun-start", "--clouds", "--no-tracker", "aspod sim --hal", "watch box", "expect REASON",
                 "wait aligned [az|el] DEG [TIMEOUT]", "aspod bench benches/tracker_procedure.aspod"):
        assert word in doc, word


# ---- over a real pty -----------------------------------------------------------------------------------------

@pytest.mark.pty
@pytest.mark.long
def test_the_procedure_over_a_real_pty_against_aspod_sim(tmp_path):
    env = {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}
    errors = (tmp_path / "sim.err").open("w+b")      # a file, not a pipe: nobody reads it during the run
    # at up to 4x real time: the procedure's waits are in the controller's time, so it is the same procedure, sooner
    sim = Child(["sim", "--pty", "--speed", "4", "--params", str(tmp_path / "params.json"),
                 "--sun-start", "2026-03-20T06:50-07:00"], env=env, stderr=errors)
    try:
        url = sim.ready("ASPOD-LINK ").split(" ", 1)[1]
        sim.ready("ASPOD-KEY ")
        done = child.run(ASPOD + ["teleop", url, "--script", str(SCRIPT), "--summary"], env=env, timeout_s=900,
                         peers=(sim.pid,))
        out, err = done.stdout.decode(), done.stderr.decode()
        assert done.returncode == EXIT_OK, out + err
    finally:
        sim.stop(timeout_s=30)
        errors.seek(0)
        sim_err = errors.read().decode(errors="replace")
        errors.close()
    assert "aspod sim: the sun starts at 2026-03-20T06:50:00-07:00 (2026-03-20T13:50:00Z) at Tucson" in sim_err
    assert out.count("ok   BoxSwitch refused as expected: DIAL_NOT_LOW (39)") == 4
    assert out.count("nothing changed: main") == 4
    for line in ("wait aligned az 1 120", "wait aligned el 1 120", "wait aligned 0.5 120", "wait aligned 0.75 30"):
        assert re.search(rf"^ok   {line.rsplit(' ', 1)[0]} deg: [\d.]+ deg after", out, re.M), (line, out)
    panels = [p.splitlines() for p in out.split("> box\n")[1:]]
    refused_start = panels[2]                                            # after break a: stopped, not restarted
    assert [row.split()[3] for row in refused_start[4:6]] == ["BRAKE", "BRAKE"], refused_start
    assert [row.split()[5:7] for row in refused_start[4:6]] == [["open", "on"]] * 2, refused_start
    assert panels[3][0].startswith("box  main OFF"), panels[3]          # after break b: main still off
    assert re.search(r"^pointing error 0\.\d\d deg; .* refusals 4$", "\n".join(panels[-1]), re.M), panels[-1]
    assert "commands: " in out and " 0 failed" in out
