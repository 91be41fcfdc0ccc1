"""The hostile controller (`aspod fuzz --as-controller`, host_tools/fuzz/hostile.py) against real hosts over real
ptys: `aspod teleop`, a ground tool on `HostClient` and its copy with a planted defect; and what it found in teleop.

Every wait on a host is judged on the host's own time (host_tools/worlds/own_time.py), never on the wall clock."""
from __future__ import annotations

import io
import json
import queue
import random
import secrets
import shlex
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

from host_tools.client.live import HostClient
from host_tools.fuzz import findings
from host_tools.fuzz.findings import Failure, Finding
from host_tools.fuzz.grammar import RandomDraw
from host_tools.fuzz.hostile import TARGET, HostileController, HostileSettings
from host_tools.teleop.session import Session
from host_tools.worlds.child import ASPOD, Child, run
from host_tools.worlds.ports import PtyPort
from host_tools.teleop.words import parse_line
from protocol import auth
from protocol.host_link import CommandHandle
from protocol.link import LinkState
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.reliable import Outcome
from timebase import SimClock


class RefusingController:
    """What teleop's Session uses of a client: every command refused by a `Result` (a reply the protocol allows for
    any command: docs/protocol.md)."""

    def __init__(self, reason: Reason) -> None:
        self.reason = reason
        self.clock = SimClock()
        self.io_error = None
        self.telemetry_listeners, self.event_listeners = [], []
        self.link = SimpleNamespace(state=LinkState.UP, stats=SimpleNamespace(crc_errors=0, auth_errors=0),
                                    event_from_earlier_session=False)

    def call(self, msg, timeout_s: float = 30.0) -> CommandHandle:
        handle = CommandHandle(msg, self.clock.now())
        handle._finish(Outcome.REJECTED, self.reason, self.clock.now(), SCHEMA["Result"].type(int(self.reason)))
        return handle


def test_teleop_says_a_motion_refused_by_a_result_and_goes_on():
    """Found by the hostile controller: a Move refused with a `Result` (not a MotionAccepted) crashed teleop, which
    read the refusal's `limit` (AttributeError: 'Result' object has no attribute 'limit'). A controller answers so
    whenever a command's payload does not decode (protocol/controller_link.py)."""
    for reason in (Reason.OUT_OF_RANGE, Reason.NOT_ALLOWED_IN_STATE):
        out = io.StringIO()
        session = Session(RefusingController(reason), out)
        assert not session.run_step(parse_line("move j1 10", 1))
        assert reason.name in out.getvalue()


# ---- the hostile controller against real hosts over a pty ----------------------------------------------------

HOST = [sys.executable, "-m", "host_tools.fuzz.hostile_planted", "{url}", "{key}", "60"]


def fuzz(*args: str, timeout_s: float = 120.0):
    """`aspod fuzz --as-controller ...` as a child, bounded on its own time; (exit status, stdout, stderr)."""
    done = run([*ASPOD, "fuzz", "--as-controller", "--no-progress", *args], timeout_s=timeout_s)
    return done.returncode, done.stdout.decode(), done.stderr.decode()


def run_aspod(*args: str):
    done = run([*ASPOD, *args], timeout_s=60.0)
    return done.returncode, done.stdout.decode(), done.stderr.decode()


def finding_file(folder: Path, *steps: dict, kind: str = "crash") -> Path:
    """A finding as the fuzzer writes one, of `steps` (for a replay of a known attack)."""
    steps = [{"case": 0, "delay_s": 0.0, **s} for s in steps]
    return Finding(TARGET, Failure(kind, "written by hand"), steps=steps).save(folder)


def event(name: str, **values) -> dict:
    spec = SCHEMA[name]
    return {"kind": "event", "msg": name, "payload": spec.encode(spec.type(**values)).hex()}


@pytest.mark.pty
@pytest.mark.long
def test_it_finds_a_host_that_crashes_on_an_event_shrinks_and_replays_it(tmp_path):
    """The planted host names a MotionDone's axis from a table one short: the fuzzer, from nothing, finds it (seed 1:
    at case 11 of at most 300), shrinks it, and `--replay` fails as found; against the host without the defect the
    same finding no longer fails."""
    planted = shlex.join(HOST + ["crash"])
    status, out, err = fuzz("--host-cmd", planted, "--cases", "300", "--max-findings", "1", "--hang-s", "5",
                            "--findings", str(tmp_path), "--json")
    assert status == 1, err
    lines = out.splitlines()
    assert lines[0].startswith("ASPOD-LINK /dev/pts/") and lines[1].startswith("ASPOD-KEY "), out
    figures = json.loads("\n".join(lines[2:]))
    assert figures["cases"] <= 300 and len(figures["findings"]) == 1
    found = findings.load(Path(figures["findings"][0]))
    assert found.target == TARGET and found.failure.kind == "crash"
    assert "IndexError: tuple index out of range" in found.failure.trace
    assert found.minimized and len(found.steps) <= 3
    assert any(s["kind"] == "event" and s["msg"] == "MotionDone" for s in found.steps)
    status, out, err = fuzz("--replay", str(found_path := Path(figures["findings"][0])), "--host-cmd", planted,
                            "--hang-s", "5")
    assert status == 1 and "fails as found: crash" in out, out + err
    status, out, err = fuzz("--replay", str(found_path), "--host-cmd", shlex.join(HOST), "--hang-s", "5")
    assert status == 0 and "no longer fails" in out, out + err


@pytest.mark.pty
@pytest.mark.long
def test_a_host_that_hangs_on_an_event_is_a_hang(tmp_path):
    """The planted host waits for ever on a lock it holds when a TemperatureWarning says HOT: no traceback, no exit,
    its link silent: a hang, once it has had --hang-s of its own time."""
    warning = event("TemperatureWarning", side=1, active=True, temp_c=90.0, limit_c=80.0, uptime_ms=1)
    path = finding_file(tmp_path, warning, kind="hang")
    status, out, err = fuzz("--replay", str(path), "--hang-s", "2",
                            "--host-cmd", shlex.join(HOST + ["hang"]))
    assert status == 1 and "fails as found: hang" in out and "sent nothing on the link" in out, out + err
    status, out, err = fuzz("--replay", str(path), "--hang-s", "2", "--host-cmd", shlex.join(HOST))
    assert status == 0 and "no longer fails" in out, out + err


@pytest.mark.pty
@pytest.mark.cpu_hog
def test_a_host_a_busy_machine_holds_up_is_not_a_hang(tmp_path):
    """The tool without a defect, its threads at SCHED_IDLE on one CPU beside a busy loop there (0.9 s busy in each
    second): its link falls silent for most of a second at a time, past --hang-s 0.5 of wall time, but not of its
    own. Judged on the wall clock, the same run made 40 hang findings in 40 cases."""
    status, out, err = fuzz("--host-cmd", shlex.join(HOST + ["starved"]), "--cases", "40", "--hang-s", "0.5",
                            "--findings", str(tmp_path), "--json")
    figures = json.loads("\n".join(out.splitlines()[2:]))
    assert status == 0 and figures["findings"] == [], out + err
    assert figures["longest_silence_s"] > 0.5, figures       # what a wall clock would have taken for a hang


@pytest.mark.pty
def test_a_probe_that_fails_is_a_finding_saved_once_per_run(tmp_path):
    """--probe says the host is unwell (here: exit 3 once the key file exists, so at every case): an oracle finding,
    saved once; the same failure again is counted, not saved (a finding per bug, not per case)."""
    probe = "sh -c 'test -e {key} && exit 3'"
    status, out, err = fuzz("--host-cmd", shlex.join(HOST), "--probe", probe, "--cases", "3", "--hang-s", "5",
                            "--findings", str(tmp_path), "--json")
    figures = json.loads("\n".join(out.splitlines()[2:]))
    assert status == 1 and len(figures["findings"]) == 1 and figures["repeats"] == 2, out + err
    found = findings.load(Path(figures["findings"][0]))
    assert found.failure.kind == "oracle" and found.failure.oracle == "probe"
    error = found.failure.error
    assert error.startswith("the probe `sh -c 'test -e ") and "ended: exit status 3" in error


@pytest.mark.pty
def test_a_host_the_user_starts_is_pointed_at_it_as_at_aspod_sim(tmp_path):
    """Without --host-cmd the fuzzer says its line and key as `aspod sim` does and waits for a host; cases count
    only while one is in session. Here over TCP, with a key of the user's."""
    key = tmp_path / "link.key"
    auth.write_key(key, secrets.token_bytes(32))
    fuzzer = Child(["fuzz", "--as-controller", "--serve", "tcp:0", "--key-file", str(key), "--cases", "10",
                    "--json", "--no-progress", "--findings", str(tmp_path)])
    host = None
    try:
        url = fuzzer.ready("ASPOD-LINK ").split(" ", 1)[1]
        assert url.startswith("socket://127.0.0.1:")
        assert fuzzer.ready("ASPOD-KEY ").split(" ", 1)[1] == str(key)
        host = Child(["-m", "host_tools.fuzz.hostile_planted", url, str(key), "60"], command=[sys.executable])
        assert fuzzer.wait_exit(60.0) == 0
        figures = json.loads(fuzzer.proc.stdout.read().decode())
        assert figures["cases"] == 10 and figures["sessions"] >= 1 and figures["findings"] == []
    finally:
        for child in (fuzzer, host):
            if child is not None:
                child.stop()


@pytest.mark.pty
def test_teleop_refused_a_motion_by_a_result_over_a_pty_lives_on(tmp_path):
    """The teleop defect above, end to end: `aspod teleop` running `move j1 10`, its Move refused by a Result. Before
    the mend this replay failed as a crash (a traceback on teleop's stderr)."""
    script = tmp_path / "move.txt"
    script.write_text("move j1 10\nping\n")
    path = finding_file(tmp_path, {"kind": "reply", "how": "refusal", "payload": "0d"})     # OUT_OF_RANGE
    teleop = f"aspod teleop {{url}} --key-file {{key}} --script {script} --keep-going"
    status, out, err = fuzz("--replay", str(path), "--host-cmd", teleop)
    assert status == 0 and "no longer fails" in out, out + err


@pytest.mark.pty
@pytest.mark.long
def test_teleop_survives_a_short_run(tmp_path):
    """Twenty cases against `aspod teleop` running a script of every kind of line it sends (seed 1): no finding."""
    script = tmp_path / "s.txt"
    script.write_text("ping\nstatus\nparams\nget toy_gain\nset toy_gain 2\nlink\nenable\nmove j1 10\nbox\n"
                      "disable\nestop\nreset\nstatus\n" * 3)
    teleop = f"aspod teleop {{url}} --key-file {{key}} --script {script} --keep-going"
    status, out, err = fuzz("--host-cmd", teleop, "--cases", "20", "--hang-s", "5", "--findings", str(tmp_path),
                            "--json")
    figures = json.loads("\n".join(out.splitlines()[2:]))
    assert status == 0 and figures["cases"] == 20 and figures["findings"] == [], out + err
    assert figures["sessions"] >= 1


def test_a_finding_with_a_bad_step_is_refused_before_any_host_starts(tmp_path):
    path = finding_file(tmp_path, {"kind": "stall", "seconds": 3600})
    status, out, err = fuzz("--replay", str(path), "--host-cmd", shlex.join(HOST))
    assert status == 2 and "step 0, \"seconds\": 3600; it must be a number 0.3..2.5" in err, out + err
    assert "ASPOD-LINK" not in out
    status, out, err = run_aspod("fuzz", "--replay", str(finding_file(tmp_path, {"kind": "raw", "bytes": "00"})),
                                 "--url", "/dev/null")
    assert status == 2 and "replay it with --as-controller" in err, out + err


@pytest.mark.long
def test_the_command_refuses_what_does_not_fit_with_its_reason(tmp_path):
    for args, reason in ((["--url", "/dev/pts/1"], "give no TARGET, --list, --url or --target-cmd"),
                         (["--replay", str(tmp_path / "f.json")], "needs --host-cmd: the host to replay it against"),
                         (["--host-cmd", "no-such-program-here {url}"], "--host-cmd no-such-program-here {url}: no "
                                                                        "program no-such-program-here"),
                         (["--only", "Ping"], "are not for --as-controller")):
        status, out, err = fuzz(*args, "--findings", str(tmp_path))
        assert status == 2 and reason in err and "ASPOD-LINK" not in out, (args, out, err)


# ---- HostClient in process, against the hostile controller in a thread -----------------------------------------

class Served:
    """The hostile controller on a pty, turned by a thread of its own; `client()` a HostClient connected to it."""

    def __init__(self) -> None:
        self.psk = secrets.token_bytes(32)
        self.port = PtyPort()
        self.controller = HostileController(HostileSettings(cases=1, seconds=None), self.psk, Path("unused.key"),
                                            self.port)
        self.steps: queue.Queue = queue.Queue()
        self.stopping = False
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        draw = RandomDraw(random.Random(0))
        while not self.stopping:
            while not self.steps.empty():
                self.controller.do(self.steps.get(), draw)
            self.controller.turn()

    def close(self) -> None:
        self.stopping = True
        self.thread.join(10.0)
        self.port.close()


@pytest.mark.pty
def test_a_listener_that_raises_does_not_stop_the_client(caplog):
    """A listener of the caller's that raises (here on a MotionDone of the mount) stopped HostClient's pump thread:
    the link went silent for good, every later call waited its whole timeout and nothing said why. Now the error is
    logged with its traceback and the link goes on."""
    served = Served()
    client = HostClient(served.port.url, served.psk)
    try:
        client.event_listeners.append(lambda msg, now: ("j1", "j2")[msg.axis])
        client.connect(30.0)
        assert client.wait_for(served.controller.in_session, 30.0)    # the controller has adopted the session
        served.steps.put(event("MotionDone", axis=5, motion_id=1, outcome=2, reason=0, position=0.0, uptime_ms=1))
        assert client.wait_for(lambda: len(client.events) == 1, 30.0)
        assert client.call(SCHEMA["Ping"].type(token=3), 30.0).ok      # before the mend: never answered
        assert "IndexError: tuple index out of range" in caplog.text
    finally:
        client.close()
        served.close()
