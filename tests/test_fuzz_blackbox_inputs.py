"""aspod fuzz, black-box: bad input refused before any target starts (a finding's fields and steps, --only/--skip,
--findings), a target it started stopped on every way out, and a finding that cannot be saved not lost."""
from __future__ import annotations

import json
import os
import random
from pathlib import Path

import pytest

from host_tools.client.params import ParamTable
from host_tools.fuzz import blackbox, findings
from host_tools.fuzz.grammar import RandomDraw
from timebase import RealClock
from aspod_cli import aspod

GOOD_STEP = {"kind": "command", "delay_s": 0.0, "msg": "BoxDial", "payload": "0000c84202"}


def finding_file(tmp_path: Path, **fields) -> Path:
    data = {"format": findings.FORMAT, "target": "blackbox", "failure": {"kind": "crash", "error": "x"},
            "url": "sim", "steps": [GOOD_STEP]}
    data.update(fields)
    path = tmp_path / "f.json"
    path.write_text(json.dumps(data))
    return path


def fake_target(tmp_path: Path, ready: str = "ASPOD-LINK socket://127.0.0.1:1", name: str = "pid") -> str:
    """A target that writes its PID to `name`, says `ready`, then sleeps (it never opens a link)."""
    return f"sh -c 'echo $$ > {tmp_path / name}; echo {ready}; exec sleep 60'"


def gone(pid: int, within_s: float = 5.0) -> bool:
    clock = RealClock()
    end = clock.now() + within_s
    while clock.now() < end:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        clock.sleep_until(clock.now() + 0.05)
    return False


@pytest.mark.parametrize("fields, said", [
    ({"failure": None}, '"failure" must be an object'),
    ({"failure": "crash"}, '"failure" must be an object'),
    ({"failure": ["crash", "x"]}, '"failure" must be an object'),
    ({"failure": {"kind": "crash"}}, '"failure" has no "error"'),
    ({"failure": {"kind": "crash", "error": 3}}, '"failure"."error" must be a string'),
    ({"failure": {"kind": "nosuch", "error": "x"}}, '"failure"."kind"'),
    ({"execs": float("inf")}, 'number 1e400 is out of range'),
    ({"execs": 1.5}, '"execs" must be a whole number'),
    ({"execs": -1}, '"execs" must be a whole number'),
    ({"minimized": "false"}, '"minimized" must be true or false'),
    ({"minimized": 1}, '"minimized" must be true or false'),
    ({"inputs": "00"}, '"inputs" must be a list'),
    ({"target": 3}, '"target" must be a string'),
])
def test_a_findings_fields_of_the_wrong_type_are_refused_naming_the_file_and_the_field(tmp_path, fields, said):
    path = finding_file(tmp_path, **fields)
    if "execs" in fields and fields["execs"] == float("inf"):
        path.write_text(path.read_text().replace("Infinity", "1e400"))       # json reads it as inf
    with pytest.raises(findings.FindingError) as caught:
        findings.load(path)
    assert str(path) in str(caught.value) and said in str(caught.value), str(caught.value)


def test_minimized_is_a_json_boolean(tmp_path):
    assert findings.load(finding_file(tmp_path, minimized=True)).minimized is True
    assert findings.load(finding_file(tmp_path, minimized=False)).minimized is False


BAD_STEPS = [
    ({"delay_s": 0.0, "msg": "BoxDial", "payload": ""}, '"kind"'),
    ({"kind": "nosuch", "delay_s": 0.0}, '"kind"'),
    ({"kind": "command", "msg": "BoxDial", "payload": ""}, '"delay_s"'),
    ({**GOOD_STEP, "delay_s": "abc"}, '"delay_s"'),
    ({**GOOD_STEP, "delay_s": 1e9}, '"delay_s"'),
    ({**GOOD_STEP, "delay_s": -5}, '"delay_s"'),
    ({**GOOD_STEP, "msg": "NoSuchMsg"}, '"msg"'),
    ({**GOOD_STEP, "msg": "Pong"}, '"msg"'),                       # the controller's, not the host's
    ({**GOOD_STEP, "payload": "zz"}, '"payload"'),
    ({**GOOD_STEP, "payload": "00" * 241}, '"payload"'),
    ({**GOOD_STEP, "seed": "abc"}, '"seed"'),
    ({**GOOD_STEP, "seed": 1 << 40}, '"seed"'),
    ({"kind": "silence", "delay_s": 0}, '"fraction"'),
    ({"kind": "silence", "delay_s": 0, "fraction": 1e6}, '"fraction"'),
    ({"kind": "burst", "delay_s": 0, "count": 10 ** 8}, '"count"'),
    ({"kind": "burst", "delay_s": 0, "count": 3, "msg": "Hello"}, '"msg"'),
    ({"kind": "replay", "delay_s": 0, "which": "x"}, '"which"'),
    ({"kind": "raw", "delay_s": 0, "bytes": "01" * 1000}, '"bytes"'),
    ({"kind": "hello", "delay_s": 0, "payload": "00" * 300}, '"payload"'),
    ({"kind": "frame", "delay_s": 0, "msg": "Ping"}, '"cls"'),
]
FRAME = {"kind": "frame", "delay_s": 0.0, "msg": "Ping", "cls": 1, "seq": "any", "offset": 1, "any_seq": 5,
         "payload": "01000000", "mac": "good", "version": 1, "flags": 16, "length_delta": 0}
BAD_STEPS += [({**FRAME, name: value}, f'"{name}"') for name, value in (
    ("cls", 999), ("any_seq", 10 ** 9), ("seq", "nosuch"), ("mac", "nosuch"), ("version", 999), ("flags", -1),
    ("length_delta", 100), ("offset", True), ("msg", "HelloReply"), ("wire", "0" * 2000))]


@pytest.mark.parametrize("step, field", BAD_STEPS)
def test_a_black_box_findings_steps_are_checked_when_it_is_loaded(tmp_path, step, field):
    """Every step: its kind's fields there, of their type, within what the fuzzer draws (no KeyError, TypeError or
    struct.error on replay, no pause of a billion seconds, no burst of a hundred million commands)."""
    path = finding_file(tmp_path, steps=[GOOD_STEP, step])
    with pytest.raises(findings.FindingError) as caught:
        findings.load(path)
    said = str(caught.value)
    assert str(path) in said and "step 1" in said and field in said and "must be" in said, said


@pytest.mark.parametrize("steps", [[], [GOOD_STEP] * 7, {"0": GOOD_STEP}, [3]])
def test_a_black_box_finding_has_one_to_six_steps_each_an_object(tmp_path, steps):
    with pytest.raises(findings.FindingError) as caught:
        findings.load(finding_file(tmp_path, steps=steps))
    assert "f.json" in str(caught.value)


def test_every_step_the_fuzzer_draws_passes_the_check():
    """The check's bounds are the draw's: what the fuzzer writes, it can replay."""
    settings = blackbox.BlackBoxSettings(url="x", cases=1)
    kinds = set()
    for seed in range(60000):         # until every kind came (a silence is one step in 20,000)
        case = blackbox.Case.draw(RandomDraw(random.Random(seed)), settings)
        blackbox.check_steps(blackbox._steps_with_seed(case, random.Random(seed).getrandbits(32)))
        kinds |= {s["kind"] for s in case.steps}
        if kinds == set(blackbox._STEP_FIELDS) and seed >= 3000:
            break
    assert kinds == set(blackbox._STEP_FIELDS)
    for k in range(31):       # each silence the draw can make, at its ends too
        blackbox.check_steps([{"kind": "silence", "delay_s": 0.019, "fraction": 0.5 + k / 100.0}])


def test_a_bad_step_is_refused_by_the_command_before_the_target_starts(tmp_path):
    path = finding_file(tmp_path, steps=[{"kind": "burst", "delay_s": 0, "count": 10 ** 8}])
    done = aspod("fuzz", "--replay", str(path), "--target-cmd", fake_target(tmp_path), cwd=tmp_path)
    assert done.returncode == 2 and "f.json" in done.stderr and '"count"' in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "pid").exists()


def test_only_and_skip_that_leave_no_command_are_refused_before_the_target_starts(tmp_path):
    for args in (["--only", "BoxDial", "--skip", "BoxDial"], ["--only", "ParamSave"]):
        done = aspod("fuzz", "--target-cmd", fake_target(tmp_path), *args, "--cases", "3", cwd=tmp_path)
        assert done.returncode == 2 and "no command to send" in done.stderr, done.stderr
    done = aspod("fuzz", "--target-cmd", fake_target(tmp_path), "--only", "Pong", "--cases", "3", cwd=tmp_path)
    assert done.returncode == 2 and "not a command the controller takes" in done.stderr, done.stderr
    assert not (tmp_path / "pid").exists()


@pytest.mark.parametrize("command, said", [("no-such-program-xyz --pty", "no program no-such-program-xyz"),
                                            ("./nowhere/target", "no program ./nowhere/target"),
                                            ("aspod sim 'unclosed", "No closing quotation")])
def test_a_target_command_that_cannot_be_run_is_refused_before_anything_starts(tmp_path, command, said):
    done = aspod("fuzz", "--target-cmd", command, "--cases", "2", cwd=tmp_path)
    assert done.returncode == 2 and f"--target-cmd {command}: {said}" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and not any(tmp_path.iterdir())


def test_a_target_that_ends_before_its_link_says_why(tmp_path):
    """Its own complaint (here aspod sim's usage error) is in the error, not only its exit status."""
    done = aspod("fuzz", "--target-cmd", "aspod sim --pty --no-such-option", "--cases", "2", cwd=tmp_path)
    assert done.returncode == 3 and "aspod sim (pid" in done.stderr, done.stderr
    assert "unrecognized arguments: --no-such-option" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize("ready", ["ASPOD-LINK socket://127.0.0.1:1", "ASPOD-LINK", "something else",
                                   "ASPOD-LINK /nonexistent/tty"])
def test_a_target_started_whose_link_cannot_be_opened_is_stopped(tmp_path, ready):
    """A closed port, no URL, a wrong ready line, a URL that is not there: the command exits 3 and the target
    it started is not left running."""
    done = aspod("fuzz", "--target-cmd", fake_target(tmp_path, ready), "--cases", "2", cwd=tmp_path)
    assert done.returncode == 3 and "Traceback" not in done.stderr, done.stderr
    pid = int((tmp_path / "pid").read_text())
    assert gone(pid), f"the target (pid {pid}) is still running"
    done = aspod("fuzz", "--replay", str(finding_file(tmp_path)), "--target-cmd",
                 fake_target(tmp_path, ready, "pid2"), cwd=tmp_path)
    assert done.returncode in (1, 3) and "Traceback" not in done.stderr, done.stderr
    assert gone(int((tmp_path / "pid2").read_text()))


def test_the_findings_folder_is_checked_before_the_target_starts(tmp_path):
    (tmp_path / "afile").write_text("")
    for where, said in (("afile", "not a folder"), ("afile/sub", "cannot be made")):
        done = aspod("fuzz", "--target-cmd", fake_target(tmp_path), "--findings", where, "--cases", "2",
                     cwd=tmp_path)
        assert done.returncode == 2 and "--findings" in done.stderr and said in done.stderr, done.stderr
    assert not (tmp_path / "pid").exists() and (tmp_path / "afile").read_text() == ""


def test_a_finding_that_cannot_be_saved_goes_to_stderr_whole(tmp_path, monkeypatch, capsys):
    class FakeSession:
        url, child = "fake", None

        def close(self) -> str:
            return ""

    fuzzer = blackbox.BlackBoxFuzzer(blackbox.BlackBoxSettings(url="fake", cases=1, findings=tmp_path), b"k" * 32)
    fuzzer.params = blackbox.TargetParams(ParamTable())       # as the first `_open` leaves it: here, none read
    class FakeHealth:
        cases = 0                 # checked

    monkeypatch.setattr(fuzzer, "_open", lambda: (FakeSession(), FakeHealth()))
    monkeypatch.setattr(blackbox, "run_case", lambda *a, **k: findings.Failure("oracle", "HealthCheck: wrong", "", "x"))

    def refuse(self, folder, path=None):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(findings.Finding, "save", refuse)
    result = fuzzer.run()
    err = capsys.readouterr().err
    assert result.findings == [] and len(result.unsaved) == 1 and "No space left on device" in err
    shown = json.loads(err[err.index("{"):])
    assert shown == result.unsaved[0] and shown["failure"]["error"] == "HealthCheck: wrong" and shown["steps"]


class _BenchSession:
    """The fuzzer's session's `call` and settings, on a lock-step bench: a real controller, on the simulated clock."""

    def __init__(self, bench) -> None:
        self.bench, self.settings = bench, blackbox.BlackBoxSettings(url="lockstep", cases=1)

    def call(self, msg, timeout_s: float):
        return self.bench.call(msg, timeout_s)


def test_a_parameter_that_cannot_be_set_back_yet_is_owed_and_set_back_after_a_later_case(bench, capsys):
    """A case set j1's speed, then started a jog still running at its end: the set-back is refused BUSY (a joint's
    speed does not change under its motion). It is owed, said once, and set back after the next case, once the joint
    holds; it was put among the 'stuck' and never tried again, and every later case ran with it changed."""
    from host_tools.client.params import read_param_table
    from protocol.messages import MESSAGES as M, SCHEMA
    session = _BenchSession(bench)
    params = blackbox.TargetParams(read_param_table(session, 5.0))
    found = params.found["j1_speed_dps"]
    assert bench.call(M["Enable"]()).ok
    payload = SCHEMA["ParamSet"].encode(M["ParamSet"]("j1_speed_dps", 2.0))
    handles = [(SCHEMA["ParamSet"], payload, bench.call(M["ParamSet"]("j1_speed_dps", 2.0)))]
    assert bench.call(M["Jog"](0, 1.0)).ok
    assert params.restore(session, blackbox.Case([]), handles)
    assert params.owed == {"j1_speed_dps"} and params.put_back == 0
    assert "j1_speed_dps could not be set back" in capsys.readouterr().err
    assert bench.call(M["Stop"]()).ok
    bench.run_for(3.0)
    assert params.restore(session, blackbox.Case([]), [])
    assert params.owed == set() and params.put_back == 1
    assert bench.controller.params["j1_speed_dps"] == pytest.approx(found, rel=1e-6)


def test_an_authentic_frame_of_ours_never_takes_a_number_the_hosts_own_command_claims():
    """The host's Ping is lost on the line and its number stays unanswered; a case's authentic frame drawn as a
    repeat of the last number the host sent took that very number: the controller ran our GetStatus under it and
    took the host's Ping, sent again, for a repeat, answering it with a Status ("Status in answer to MoveBy", found
    in a 150 s run: the fuzzer's own making, not the target's). Our frame now takes a number answered already."""
    from types import SimpleNamespace
    from host_tools.worlds.world import LockstepBench
    from protocol.messages import MESSAGES as M, SCHEMA
    from protocol.schema import MsgClass
    lose = [False]

    def line(data: bytes) -> bytes:
        if lose[0]:
            lose[0] = False
            return b""
        return data
    bench = LockstepBench(seed=4, to_controller=line)
    try:
        assert bench.connect() and bench.call(M["Ping"](1)).ok       # one command answered: a number to repeat
        lose[0] = True
        ping = bench.host.submit(M["Ping"](2), bench.link_clock.now())
        bench.run_for(0.005)                                          # sent, and lost
        assert not ping.done and bench.host._commands.in_flight_seqs()
        step = {"msg": "GetStatus", "cls": int(MsgClass.COMMAND), "seq": "duplicate", "offset": 0, "any_seq": 0,
                "payload": "", "mac": "good", "version": 1, "flags": 0x10, "length_delta": 0}
        session = SimpleNamespace(host=bench.host, accepted_counter=-1, sent=[])
        bench.port.deliver(blackbox.Case._frame(step, session, RandomDraw(random.Random(1))))
        assert bench.wait_until(lambda: ping.done, 5.0)
        assert ping.ok and ping.reply.spec is SCHEMA["Pong"] and ping.reply.token == 2
    finally:
        bench.close()
