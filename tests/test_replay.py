"""`aspod replay`: a recorded session re-simulated; a simulated-clock recording to the bit and byte for byte, a
real-time one within tolerances; a changed parameter makes it diverge, and the first divergence is named."""
from __future__ import annotations

import dataclasses
import io
import json
import re
import struct
from pathlib import Path

import pytest

from protocol.messages import MESSAGES as M
from protocol.states import Axis
from host_tools.apps.replay import (BENCH_KEY, BITS_PER_BYTE, REPLY, ReplayError, Tolerances, _Answers, _Plan, _Said,
                                    _Sorter, _survey, replay)
from host_tools.cli.settings import pairs
from host_tools.cli.main import main
from host_tools.sessions.capture import CaptureWriter, SessionCapture, SessionInfo
from host_tools.sessions.decode import SessionDecoder
from host_tools.worlds.child import PIPE, Child, run
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench
from timebase import RealClock
from tests import test_e2e
from tests.captures import copy_capture, read_capture, read_frames

ASPOD = test_e2e.ASPOD
env, sim_factory = test_e2e.env, test_e2e.sim_factory      # the fixtures, shared


def record_bench_session(path: Path, seed: int = 2) -> None:
    """A session on the simulated clock, as `aspod demo --record` makes one: commands, motion, a payload put in
    the gripper (a world event), telemetry at 20 Hz."""
    bench = LockstepBench(seed=seed)
    bench.record(CaptureWriter.create(path, SessionInfo(clock="simulated", tool="test", seed=seed,
                                                        settings=bench.settings())))
    assert bench.connect()
    for msg in (M["SetTelemetryRate"](20), M["Enable"](), M["MoveBy"](int(Axis.J1), 2.0, 2.0),
                M["Jog"](int(Axis.J2), -1.5)):
        assert bench.call(msg).ok
    bench.run_for(0.7)
    bench.act("set_payload", 0.4)
    bench.run_for(0.5)
    assert bench.call(M["Stop"]()).ok
    bench.run_for(0.3)
    bench.close()


@pytest.fixture(scope="module")
def bench_capture(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("replay") / "bench.pcapng"
    record_bench_session(path)
    return path


def replay_file(path: Path, **options):
    with SessionCapture.open(path) as capture:
        return replay(capture, **options)


def test_a_simulated_clock_recording_replays_to_the_bit_and_byte_for_byte(bench_capture):
    _, _, events = read_capture(bench_capture)
    assert [e.event["action"] for e in events] == ["set_payload"]
    report = replay_file(bench_capture)
    assert report.matches, report.describe()
    assert report.exact and report.commands == 5 and report.replies == 5
    assert report.telemetry > 40 and report.events >= 2
    assert report.identical_bytes == report.controller_frames > 50


def test_a_changed_parameter_diverges_and_the_first_divergence_is_named(bench_capture):
    report = replay_file(bench_capture, params={"j1_kp": 2.0})
    assert not report.matches
    d = report.divergence
    # nothing can differ before j1 is driven: the gain acts on its motion only
    decoder = SessionDecoder(None)
    moved_s = next(f.time_s for f in read_frames(bench_capture)
                   if decoder.decode(f.data, f.time_s, f.link, f.direction).name == "MoveBy")
    assert d.time_s > moved_s and d.recorded != d.replayed
    assert "first divergence at" in report.describe() and f"{d.message}.{d.field}" in report.describe()


def test_a_world_event_left_out_is_a_divergence(bench_capture, tmp_path):
    left_out = tmp_path / "left_out.pcapng"
    copy_capture(bench_capture, left_out, world_events=False)     # as if the payload had never been put in the gripper
    report = replay_file(left_out)
    assert not report.matches
    assert report.divergence.time_s >= 0.7


@pytest.mark.parametrize("after_s", [0.5, 3600.0, 200_000.0])
def test_a_world_event_after_the_last_frame_is_not_redone(bench_capture, after_s, tmp_path):
    """A simulator keeps its control endpoint after the host has gone, so a recording may hold world events
    long after its last frame; they cannot change what is compared, and are not redone (a jam would have
    been a divergence, a day later a day of simulation)."""
    last_s = max(f.time_s for f in read_frames(bench_capture))
    later = tmp_path / "later.pcapng"
    copy_capture(bench_capture, later, more_events=((last_s + after_s, {"action": "inject", "args": ["jam:j1"]}),))
    report = replay_file(later)
    assert report.matches, report.describe()


def test_replay_refuses_what_it_cannot_replay(bench_capture, tmp_path):
    broken = tmp_path / "cut.pcapng"
    broken.write_bytes(bench_capture.read_bytes()[:-10])
    with pytest.raises(ReplayError, match="breaks at byte"):
        replay_file(broken)
    host_only = tmp_path / "host.pcapng"
    CaptureWriter.create(host_only, SessionInfo(clock="wall", tool="aspod teleop")).close()
    with pytest.raises(ReplayError, match="without the world"):
        replay_file(host_only)
    with pytest.raises(ReplayError, match="no_such_param"):
        replay_file(bench_capture, params={"no_such_param": 1.0})
    with pytest.raises(ValueError, match="NAME=VALUE"):
        pairs(["j1_kp"], "--param")


def test_a_replay_under_another_key_says_how_many_recorded_frames_do_not_verify(bench_capture):
    assert replay_file(bench_capture).mac_failures == 0          # no key given: the MACs are not checked
    report = replay_file(bench_capture, psk=bytes(32))
    assert report.mac_failures > 50 and report.identical_bytes == 0
    assert f"{report.mac_failures} recorded frames do not verify under the key given" in report.describe()


def test_aspod_replay_command_json_and_exit_status(bench_capture, tmp_path, capsys):
    out = tmp_path / "replayed.pcapng"
    assert main(["replay", str(bench_capture), "--json", "--output", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["match"] is True and doc["exact"] is True and doc["divergence"] is None
    assert read_capture(out)[0].info.tool == "aspod replay"
    assert main(["replay", str(bench_capture), "--param", "j1_kp=2"]) == 1
    assert "first divergence at" in capsys.readouterr().out
    assert main(["replay", str(tmp_path / "none.pcapng")]) == 2


def test_tolerances_by_unit():
    tol = Tolerances()
    assert tol.allows("deg", 10.0, 10.09) and not tol.allows("deg", 10.0, 10.2)
    assert tol.allows("ms", 1000, 1020) and not tol.allows("ms", 1000, 1030)
    assert tol.allows("", 100.0, 101.5) and not tol.allows("", 100.0, 103.0)
    f32 = struct.unpack("<f", struct.pack("<f", 22.1))[0]             # five steps' difference as the link carries it
    assert tol.allows("degC", f32, 21.6) and not tol.allows("degC", f32, 21.5)     # two noisy samples: 0.5


def test_a_real_time_recording_whose_frames_reached_the_port_late_replays_within_tolerances():
    """tests/data/replay_late_writes.pcapng is the session of the test below, recorded by `aspod sim --record` on
    a loaded machine (two busy loops and a fuzz campaign beside it; it failed 1 run in 30). The simulator's frames
    reached its port late: j2's MotionDone, made at uptime 2712 ms, was written 44 ms later, and the Stop before
    it was answered 50 ms after it came in, though j2's stop shows the controller acted on it within about 3 ms.
    Replay took the late answer for a late arrival, moved the Stop 42 ms later and so j2's stop 170 ms later:
    a divergence the controller had not made. Now the lag of the writing, which every frame carrying the uptime
    shows, is taken off the answer's time (`_Output.made_s`). (Its description's schema hash was moved to the schema
    of Reason.UNCOMMANDED_MOTION, a reason added with no message's layout changed, then to issue 34's, whose Hello
    and HelloReply layouts changed: replay reads those two by their ids and compares nothing of them, and no other
    message's layout changed. The recording is otherwise as made, and could not be made again at will.)"""
    report = replay_file(Path(__file__).parent / "data" / "replay_late_writes.pcapng")
    assert report.matches, report.describe()
    assert report.commands == 8 and report.events == 4 and report.uncertainty_ms < 10


def test_a_command_is_never_replayed_before_the_recorded_controller_could_have_had_it():
    """tests/data/replay_stop_before_request.pcapng is the session of the test below, recorded with two busy loops
    and a fuzz campaign beside it (it failed 1 run in 6 so; once in CI beside the campaign, that capture not
    kept). The Stop reached the port at 2.731 s and was answered at 2.740; the writing looked late, so its answer
    was taken as made the moment the Stop came, and replay moved the Stop 8 ms earlier to answer then: the replayed
    controller had it 5 ms before the recorded one did, and j2's stop ended 16 ms early (MotionDone at uptime
    2760 against 2776; the telemetry's 10 ms window missed it). A command now goes no earlier than its own time on
    the line before it was recorded. (Its description's schema hash was moved to issue 34's, as the capture's above
    was.)"""
    report = replay_file(Path(__file__).parent / "data" / "replay_stop_before_request.pcapng")
    assert report.matches, report.describe()
    assert report.commands == 8 and report.events == 4


def test_a_recording_whose_world_stalled_beyond_judging_is_refused_saying_so():
    """tests/data/replay_world_stalled.pcapng, recorded as the one below, stalled longer: its world's lag rose by
    208 ms between two TelemetryStatus 50 ms apart (the machine ran at load 10 on 2 cores). Replay cannot know
    where in that stretch the link's clock stood, so it cannot time the link's own events (the timeout, a command's
    arrival) to within its tolerances: before, it reported `first divergence ... TelemetryJoints.j1_current`, a
    divergence the controller had not made. It now refuses the recording, saying why, before running anything."""
    with pytest.raises(ReplayError, match=r"stalled: its lag rose by 208 ms .* uptime 7\.396 s"):
        replay_file(Path(__file__).parent / "data" / "replay_world_stalled.pcapng")


def test_an_event_made_just_before_the_recording_ended_is_not_held_against_the_replay():
    """tests/data/replay_event_after_the_last_frame.pcapng (recorded at --speed 0.25 beside the ones above) ends
    with the link timeout's FaultReport, made at uptime 7977 ms and written at 8.002 s; its StateChanged was made
    with it, but the simulator stopped before writing it. The replayed StateChanged, made at 7.976 s, came before
    the recording's last frame's time and was taken for an event the recording did not have (`first divergence
    ... StateChanged ... recorded (none)`). A replayed event within the time tolerance of the recording's end may
    have been made while the recorded one was being written, and is not held against the replay."""
    report = replay_file(Path(__file__).parent / "data" / "replay_event_after_the_last_frame.pcapng")
    assert report.matches, report.describe()
    assert report.events == 4


def test_a_replys_snapshot_is_judged_as_telemetry_is_within_the_window_of_its_uptime():
    """tests/data/replay_status_as_a_motion_starts.pcapng (--speed 0.25, recorded beside the ones above): teleop's
    `wait` sent a GetStatus 3 ms after the MoveBy, and the Status, made at uptime 828 ms, read the supply at
    27.937 V, before j1's current drew it down. Replayed, the MoveBy came 4 ms earlier within what the recording
    shows, and the Status read 27.674 V: `first divergence at 0.831 s: Status.supply_v`, a divergence the
    controller had not made. A reply's snapshot is now judged as telemetry is: it may match what the replayed
    controller showed within the window of its uptime. A changed parameter still diverges (the tests below)."""
    report = replay_file(Path(__file__).parent / "data" / "replay_status_as_a_motion_starts.pcapng")
    assert report.matches, report.describe()
    assert report.replies == 6
    slow = replay_file(Path(__file__).parent / "data" / "replay_status_as_a_motion_starts.pcapng",
                       params={"j1_acc_dps2": 1.0})
    assert not slow.matches


def test_a_lag_given_up_by_the_pacer_is_followed_at_the_worlds_recent_rate():
    """tests/data/replay_lag_given_up.pcapng (--speed 1, the host killed, recorded beside two other runs of the
    real-time tests and two CPU hogs): the world ran at 0.62-0.79x, so its lag passed the pacer's 0.5 s twice and
    was given up (483 ms to 4 ms between two reports). Replay took such a stretch at the paced rate, losing the
    half second of wall time the world had slipped each time, and its link timed out 107 ms after the recorded
    one (`first divergence at 11.272 s: FaultReport`). The stretch now runs at the rate of the world's last
    second as its report gives it (`rtf_recent`)."""
    report = replay_file(Path(__file__).parent / "data" / "replay_lag_given_up.pcapng")
    assert report.matches, report.describe()
    assert report.events == 5


def test_after_the_last_report_the_link_keeps_the_worlds_pace():
    """tests/data/replay_close_after_a_catching_up.pcapng (--speed 1, recorded beside the ones above) ends with a
    Close: the controller stops its telemetry, so the last lag it reports is that of uptime 7221 ms, and the world
    was then catching up (its lag fell 16.5 ms in 18 ms of its time). Replay held that stretch's rate for the rest
    of the session: the link's clock ran at 0.08 of the world's, the Close's answer came 145 ms after the Close
    instead of 23, and the StateChanged with it too late (`first divergence at 7.300 s: StateChanged.(frame):
    recorded sent, re-simulated (none)`). After the last report the link now keeps the world's pace."""
    report = replay_file(Path(__file__).parent / "data" / "replay_close_after_a_catching_up.pcapng")
    assert report.matches, report.describe()
    assert report.events == 5 and report.replies == 7


def test_a_link_timeout_after_the_world_stalled_replays_within_what_its_reports_show():
    """tests/data/replay_stall_before_link_loss.pcapng is a session of test_a_host_that_went_silent_..._[1-killed]
    below, recorded beside a second run of it, a CPU hog and other test runs (it failed 1 run in 4 so). The host
    was killed at 7.3 s; the controller's link timeout, 3 s of the wall clock later, came at uptime 10106 ms. Its
    world was paced at real time but stalled under load: its lag rose by up to 34 ms between two TelemetryStatus
    (50 ms apart), and where in those 50 ms the stall fell the recording cannot show. The replay, following the
    lag from report to report, timed out the link 34 ms later in the world's time: beyond the 25 ms tolerance,
    `first divergence ... FaultReport`. A time the link's clock sets is now compared within what the recording
    shows of that clock too (`_Survey.lag_rise_ms`)."""
    capture = Path(__file__).parent / "data" / "replay_stall_before_link_loss.pcapng"
    report = replay_file(capture)
    assert report.matches, report.describe()
    assert 30 < report.link_map_ms < 40 and report.events == 5
    changed = replay_file(capture, params={"link_timeout_s": 2.0})      # a second sooner: still seen
    assert not changed.matches and changed.divergence.message in ("FaultReport", "StateChanged")


def judged_recording(tmp_path: Path, record) -> tuple[Path, object]:
    """A real-time recording `record(capture)` made, that replay takes, and its replay: one whose world stalled too
    long for replay to judge (a busy machine) is refused, saying so; then it is recorded again, at most three times
    in all; the test is skipped, saying why, if replay refused every one."""
    stalled = []
    for attempt in range(3):
        capture = tmp_path / f"session-{attempt}.pcapng"
        record(capture)
        try:
            return capture, replay_file(capture)
        except ReplayError as exc:
            if "the recording's world stalled" not in str(exc):
                raise
            stalled.append(str(exc))
    pytest.skip("the machine stalled every recording beyond what replay can judge: " + " / ".join(stalled))


@pytest.mark.pty
def test_a_real_time_sim_recording_replays_within_tolerances_and_a_changed_gain_diverges(sim_factory, tmp_path):
    def record(capture: Path) -> None:
        sim = sim_factory("--pty", "--record", str(capture), "--seed", "9", "--no-tracker")
        # `wait` after the stop: the quit's Close then comes after j2 has come to rest, not while it slows (a race
        # between the two ends of the motion, one or the other recorded, that replay cannot know)
        script = "ping\nenable\ntelemetry 20\nmoveby j1 3 3\nwait\njog j2 -2\nping\nstop\nwait\nstatus\nquit\n"
        done = sim.teleop(script)
        assert done.returncode == 0, done.stderr.decode()
        sim.stop()
    capture, report = judged_recording(tmp_path, record)
    assert report.matches, report.describe()
    # the script's 8, the quit's Close, and the GetStatus its wait sends if no TelemetryStatus has come yet
    assert not report.exact and report.commands in (9, 10) and report.telemetry > 10
    changed = replay_file(capture, params={"j1_acc_dps2": 1.0})
    assert not changed.matches and changed.divergence.message in ("TelemetryJoints", "MotionDone")
    shown = run(ASPOD + ["replay", str(capture), "--param", "j1_acc_dps2=1"], text=True, timeout_s=120)
    assert shown.returncode == 1 and "first divergence at" in shown.stdout


@pytest.mark.pty
def test_the_lag_of_a_recordings_writing_is_measured_on_the_controllers_uptime_not_the_links(sim_factory, tmp_path):
    """A Heartbeat's uptime_ms is the link's, counted on the link's clock (the wall clock under `aspod sim`), not
    the controller's on the world's: at --speed 0.5 the two part by half a second a second. Taking the Heartbeats
    put the least of (time written - uptime) 1.8 s too low, so every reply's lag came out near 1.8 s, every reply
    was taken as made the moment its request came, and the recording's uncertainty as 0 ms."""
    capture = tmp_path / "half.pcapng"
    sim = sim_factory("--pty", "--record", str(capture), "--seed", "9", "--no-tracker", "--speed", "0.5")
    done = sim.teleop("ping\nenable\ntelemetry 20\nmoveby j1 3 3\nwait\nping\nstatus\nquit\n")
    assert done.returncode == 0, done.stderr.decode()
    sim.stop()
    line_s_per_byte = BITS_PER_BYTE / 115_200
    with SessionCapture.open(capture) as recorded:
        survey = _survey(recorded, None, line_s_per_byte)
        answers = _Answers(_Plan(BENCH_KEY, 9, PlantSettings(), {}, 115_200, False, survey, survey.last_s), io.BytesIO())
        sorter, decoder, written = _Sorter(line_s_per_byte), SessionDecoder(None), {}
        for f in recorded.frames():
            d = decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length)
            said = sorter.take(d, f.offset)
            answers.recorded(d, said, sorter.session_started_s)
            if isinstance(said, _Said) and said.kind == REPLY:
                written[said.key] = d.time_s
    answers.finish()
    lags = [written[key] - made for key, (made, _) in answers._made.items()]
    assert len(lags) == len(written) > 4 and max(lags) < 0.5, lags       # tens of ms under load


def recorded_names(capture: Path) -> list[str]:
    decoder = SessionDecoder(None)
    return [decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length).name
            for f in read_frames(capture)]


def record_until_the_host_is_gone(sim, capture: Path, script: str, ending: str) -> None:
    """Run `script` through `aspod teleop` and end the host as `ending` says: "closed" (it quits: a Close) or
    "killed" (SIGKILL while it waits: it goes silent); keep the simulator until the capture holds what the
    controller said of it (SessionClosed, or the link's loss and its FaultReport), then stop it."""
    if ending == "closed":
        done = sim.teleop(script)
        assert done.returncode == 0, done.stderr.decode()
        sim.child.wait_stderr(r"the host closed its session", 120.0)
        last = "SessionClosed"
    else:
        host = Child(["teleop", sim.url], stdin=PIPE, env=sim.env)
        host.proc.stdin.write((script + "wait 3600\n").encode())
        host.proc.stdin.close()
        while "state=ENABLED" not in host.line(120.0):
            pass
        host.proc.kill()                   # no Close: the host just stops
        host.proc.wait(60)
        sim.child.wait_stderr(r"FAULT LINK_LOST \(LINK_TIMEOUT\)", 120.0)
        last = "FaultReport"
    # the capture is written beside its place (host_tools/outputs.py) until the simulator stops: read that
    clock = RealClock()
    deadline = clock.now() + 120.0          # the frame follows within milliseconds; this bound only ends a hang
    while not any(last in recorded_names(part) for part in capture.parent.glob(f".{capture.name}.*.part.pcapng")):
        assert clock.now() < deadline, f"no {last} in the capture"
        clock.sleep(0.05)
    sim.stop()


@pytest.mark.pty
@pytest.mark.parametrize("speed, ending", [("1", "killed"), ("0.25", "killed"), ("1", "closed")])
def test_a_host_that_went_silent_or_closed_is_replayed_so_and_the_end_matches(sim_factory, tmp_path, speed, ending):
    """The host going silent, or closing, is part of what is re-simulated. Before, the replayed host kept sending
    heartbeats after the recorded one had gone, so the recorded LINK_TIMEOUT FaultReport, 3 s after its last frame,
    was a divergence (`first divergence ... FaultReport`, exit 1). And at --speed 0.25 the replay ran the link (the
    line, the heartbeats, the link timeout) on the world's clock, four times slower than the recording's wall clock:
    the handshake and the Enable came 20 ms late (divergence at 1.078 s), and the link's loss would have come 2.25 s
    late. Now the replayed host is silent after the recorded one's last frame (its Close re-run as any command), and
    the link runs on a clock of its own that keeps to the recording's, measured from the controller's Heartbeats."""
    def record(capture: Path) -> None:
        sim = sim_factory("--pty", "--record", str(capture), "--seed", "9", "--no-tracker", "--speed", speed)
        record_until_the_host_is_gone(sim, capture, "ping\nenable\ntelemetry 20\nmoveby j1 1 2\nwait\nstatus\n",
                                      ending)
    capture, report = judged_recording(tmp_path, record)        # (in this process: then as the command does it)
    assert report.matches, report.describe()
    shown = run(ASPOD + ["replay", str(capture)], text=True, timeout_s=300)
    assert shown.returncode == 0 and shown.stdout.endswith("match\n"), shown.stdout + shown.stderr
    factor = float(re.search(r"world ran at ([\d.]+)x real time", shown.stdout).group(1))
    assert 0 < factor <= float(speed) * 1.1         # paced at `speed`: never faster (slower on a busy machine)
    if ending == "killed":
        changed = run(ASPOD + ["replay", str(capture), "--param", "link_timeout_s=2"], text=True, timeout_s=300)
        assert changed.returncode == 1 and re.search(r"first divergence at .*(FaultReport|StateChanged)",
                                                     changed.stdout)


def test_a_real_time_recording_that_does_not_show_its_real_time_factor_is_not_judged(bench_capture, tmp_path):
    """A real-time recording's timing is judged against its own real-time factor; one whose frames do not show it
    (no two controller Heartbeats, no Status or TelemetryStatus) is refused with the reason, not judged against a
    guess (before, it was replayed as if its world had run at real time)."""
    with SessionCapture.open(bench_capture) as capture:
        info = capture.info
    paced = tmp_path / "paced.pcapng"
    copy_capture(bench_capture, paced, info=dataclasses.replace(info, clock="paced"),
                 keep=lambda name: name not in ("Heartbeat", "Status", "TelemetryStatus"))
    with pytest.raises(ReplayError, match="does not show how fast its world ran against the wall clock"):
        replay_file(paced)
