"""aspod fuzz: one finding per bug (grouped by signature, counted, minimized to the fewest steps and bytes, and
`minimized` only when true), the black-box health checks every N cases with a failure pinned to its case, a Close
that is not a hang, and deadlines that stretch with a --url target's measured pace."""
from __future__ import annotations

import json
import struct
import sys

import pytest

from host_tools.fuzz import blackbox, findings, shrink
from protocol import auth
from protocol.messages import SCHEMA
from aspod_cli import aspod

PLANTED = f"{sys.executable} -m host_tools.fuzz.planted sim --pty --no-pacing"


def _dial(percent: float, axis: int) -> str:
    return (struct.pack("<f", percent) + bytes([axis])).hex()


def _planted_fails(steps: list[dict]) -> bool:
    """As the planted simulator: a BoxDial sent in sequence at exactly 100 % crashes it (whatever else is sent)."""
    return any(s["kind"] == "command" and s["msg"] == "BoxDial"
               and struct.unpack("<f", bytes.fromhex(s["payload"])[:4])[0] == 100.0 for s in steps)


def test_a_black_box_finding_is_shrunk_to_its_one_step_and_the_field_that_triggers_it():
    """Fewest steps (delta debugging), then each step plainer: its pause gone, each field of its payload back to a
    plain value while it still fails. Before, a finding kept every step it had and each field as drawn."""
    steps = [{"kind": "raw", "delay_s": 0.004, "bytes": "00ff00ff"},
             {"kind": "command", "delay_s": 0.011, "msg": "BoxDial", "payload": _dial(100.0, 0)},
             {"kind": "command", "delay_s": 0.0, "msg": "Ping", "payload": "01020304"}]
    tried = []

    def fails(candidate):
        tried.append(candidate)
        return _planted_fails(candidate)
    shrunk = shrink.minimal_steps(steps, fails)
    axis = SCHEMA["BoxDial"].fields[1]
    assert shrunk == [{"kind": "command", "delay_s": 0.0, "msg": "BoxDial",
                       "payload": _dial(100.0, shrink._plain_value(axis))}], shrunk
    assert shrink.trigger(shrunk) == "BoxDial.percent"
    assert len(tried) < 20


def _finding(steps, error="TargetGone: reading socket://127.0.0.1:40279: read failed", minimized=True,
             trace='  File "host_tools/fuzz/planted.py", line 83, in planted_box_dial\nIndexError: list index out of '
                   'range\n') -> findings.Finding:
    return findings.Finding("blackbox", findings.Failure("crash", error, "x", "health", trace), steps=steps,
                            minimized=minimized)


def test_a_bug_found_again_is_counted_in_its_file_not_saved_again(tmp_path):
    """Grouped by signature (kind, place in the target's traceback, the message and field that trigger it): a
    second hit, even before it is minimized and on another port, counts in the first one's file; another bug gets
    a file of its own."""
    known = findings.Known(tmp_path)
    dial = {"kind": "command", "delay_s": 0.0, "msg": "BoxDial", "payload": _dial(100.0, 2)}
    first = known.save(_finding([dial]))
    again = _finding([{"kind": "raw", "delay_s": 0.0, "bytes": "00"}, {**dial, "payload": _dial(100.0, 1)}],
                     error="TargetGone: reading socket://127.0.0.1:51003: read failed", minimized=False)
    assert findings.Known(tmp_path).count(again) == first              # a fresh look at the folder finds it too
    other = known.save(_finding([{**dial, "msg": "Ping", "payload": "00000000"}],
                                trace='  File "firmware_py/controller.py", line 9\nKeyError: 3\n'))
    assert other != first and sorted(tmp_path.glob("*.json")) == sorted([first, other])
    assert findings.load(first).count == 2 and findings.load(other).count == 1
    assert json.loads(first.read_text())["signature"].endswith("|BoxDial.percent")


def test_a_bug_whose_first_finding_could_not_be_shrunk_is_still_one_file(tmp_path):
    """A finding saved unshrunk (its shrinking ran out of time) keeps a trigger that is only its last step's; the
    same bug found again with other steps counts in that file, as long as kind, oracle and place agree (the
    disable-estop plant of bench/fuzz_plants.py made five files in 90 s before)."""
    known = findings.Known(tmp_path)
    state = "HealthCheck: state IDLE with faults 0x2 latched: a fault is latched only in a safe state"

    def finding(*names):
        steps = [{"kind": "command", "delay_s": 0.0, "msg": name, "payload": ""} for name in names]
        return findings.Finding("blackbox", findings.Failure("oracle", state, "x", "health"), steps=steps,
                                minimized=False)
    first = known.save(finding("EStop", "Disable", "Jog"))
    for names in (("Ping", "EStop", "Disable"), ("EStop", "Disable", "Move", "Home")):
        assert known.save(finding(*names)) == first
    assert findings.Known(tmp_path).count(finding("EStop", "Disable", "Grip")) == first
    assert [p.name for p in tmp_path.glob("*.json")] == [first.name] and findings.load(first).count == 4
    crash = findings.Finding("blackbox", findings.Failure("crash", "TargetGone: gone", "x", "health"),
                             steps=[{"kind": "command", "delay_s": 0.0, "msg": "Jog", "payload": ""}], minimized=False)
    assert known.save(crash) != first                       # another bug: another file


class _Picky:
    """A target of one's own that fails on any input holding the byte 0x2a."""

    def one_input(self, data: bytes) -> None:
        if 0x2A in data:
            raise ValueError("a star")

    def close(self) -> None:
        pass


class _Ticking:
    """A clock that moves one second each time it is read: a minimizer's budget runs out after so many tries."""

    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        self.t += 1.0
        return self.t


def test_minimized_is_said_only_when_the_minimizer_ran_to_its_end(monkeypatch):
    """Before, a minimizer stopped by its time budget part of the way still wrote `minimized: true`."""
    finding = findings.Finding("my:picky", findings.failure_of(_raise(b"xx*yy")), [b"abc*defgh"])
    done = findings.minimize(finding, _Picky, budget_s=60.0)
    assert done.minimized and done.inputs == [b"*"]
    monkeypatch.setattr(findings, "_CLOCK", _Ticking())
    cut = findings.minimize(finding, _Picky, budget_s=4.0)       # a few tries, then out of time
    assert not cut.minimized and cut.inputs != [b"*"], cut.inputs


def _raise(data: bytes) -> BaseException:
    try:
        _Picky().one_input(data)
    except ValueError as exc:
        return exc
    raise AssertionError("no failure")


def test_a_url_targets_deadlines_stretch_with_its_measured_pace():
    """A --url target was judged on the bare wall clock: one running at 0.34x real time (a busy host) missed its 5 s.
    Its deadlines now stretch with its slowness at once, shrink back gradually, and are at least 50 round trips."""
    pace = blackbox.Pace()
    assert pace.deadline_s(5.0) == 5.0
    pace.measured(rate=0.34, rtt_s=0.002)
    assert pace.deadline_s(5.0) == pytest.approx(5.0 / 0.34)
    pace.measured(rate=30.0, rtt_s=0.002)                  # unpaced again: back towards 1, not at once
    assert 5.0 < pace.deadline_s(5.0) < 5.0 / 0.34
    pace.measured(rate=0.0001, rtt_s=0.002)                # at most 1/RATE_FLOOR
    assert pace.deadline_s(5.0) == pytest.approx(5.0 / blackbox.RATE_FLOOR)
    slow_line = blackbox.Pace()
    slow_line.measured(rate=1.0, rtt_s=0.5)
    assert slow_line.deadline_s(5.0) == pytest.approx(25.0)


@pytest.mark.pty
def test_a_close_in_a_case_ends_the_session_and_is_not_a_hang(tmp_path):
    """A Close the fuzzer sends ends its session (since the Close command came to the protocol); the fuzzer took
    the refused Ping after it for a hung target, a false finding in most runs of a few minutes. It now starts a
    new session after a case's Close and checks the target there."""
    key = tmp_path / "k.key"
    auth.write_key(key, bytes(range(32)))
    steps = [{"kind": "command", "delay_s": 0.0, "msg": "Close", "payload": "01"},
             {"kind": "command", "delay_s": 0.0, "msg": "Ping", "payload": "01000000"}]
    path = findings.Finding("blackbox", findings.Failure("hang", "TargetGone: Ping: failed: SESSION_RESET"),
                            steps=steps).save(tmp_path / "found")
    target = f"{sys.executable} -m host_tools.cli.main sim --pty --no-pacing --key-file {key}"
    done = aspod("fuzz", "--replay", str(path), "--target-cmd", target, "--key-file", str(key), cwd=tmp_path)
    assert done.returncode == 0 and "no longer fails" in done.stdout, done.stdout + done.stderr


@pytest.mark.pty
@pytest.mark.long
def test_the_planted_bug_found_again_and_again_is_one_file_counted_and_shrunk_to_its_field(tmp_path):
    """The planted BoxDial crash, found several times in a run that checks the target's health every 16 cases:
    each failure is pinned to its case (the cases since the last good check run again one at a time on a fresh
    target), the first is shrunk to one step with only the dial at 100 % (the axis set back to its plain value),
    and the others are counted in its file. Before, each hit was a file of its own, each with steps it did not
    need."""
    done = aspod("fuzz", "--target-cmd", PLANTED, "--only", "BoxDial", "--cases", "150", "--json", "--no-progress",
                 cwd=tmp_path, timeout_s=900)
    assert done.returncode == 1, done.stderr[-3000:]
    figures = json.loads(done.stdout)
    assert len(figures["findings"]) == 1 and figures["repeats"] >= 1, figures
    assert figures["checks"] < figures["cases"], figures
    finding = findings.load(tmp_path / figures["findings"][0])
    axis = SCHEMA["BoxDial"].fields[1]
    assert finding.minimized and finding.count == figures["repeats"] + 1
    assert [(s["kind"], s["msg"], s["payload"], s["delay_s"]) for s in finding.steps] == [
        ("command", "BoxDial", _dial(100.0, shrink._plain_value(axis)), 0.0)], finding.steps
    assert finding.failure.kind == "crash" and "planted.py" in findings.signature(finding)


@pytest.mark.pty
def test_a_fault_latched_by_a_limit_the_case_set_is_not_a_finding_while_the_fuzzer_sets_it_back():
    """A case sets supply_min_v to 60 V (accepted: in its range) and closes; SUPPLY_LOW latches a few ticks later,
    after the check that followed the case, while the fuzzer sets the limit back. Before, that was a finding
    ("while the fuzzer set back the case's parameters: state 1/faults 0x0 became 3/0x8", 2026-11-29); the fault
    is the limit's, as the controller should."""
    name = SCHEMA["ParamSet"].fields[0]
    payload = b"supply_min_v".ljust(name.text_size, b"\0") + struct.pack("<f", 60.0)
    steps = [{"kind": "command", "delay_s": 0.0, "msg": "ParamSet", "payload": payload.hex(), "seed": 1},
             {"kind": "command", "delay_s": 0.0, "msg": "Close", "payload": "00"}]
    settings = blackbox.BlackBoxSettings(command=tuple(PLANTED.replace("-m host_tools.fuzz.planted",
                                                                       "-m host_tools.cli.main").split()), cases=1)
    fuzzer = blackbox.BlackBoxFuzzer(settings, None)
    for _ in range(3):
        assert fuzzer.replay(findings.Finding("blackbox", findings.Failure("oracle", "", "", "health"),
                                              steps=steps)) is None
