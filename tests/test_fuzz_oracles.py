"""Oracles beyond "no crash" (host_tools/fuzz/oracles.py), judged against the declaration and the link's rules: each
finds its planted defect (in a copy: a spec copied, a handler class patched for the test and put back, a simulator
started from a script the test writes) and holds on the real code."""
from __future__ import annotations

import copy
import json
import math
import random
import struct
import sys

import pytest

from host_tools.fuzz import findings, oracles
from host_tools.fuzz.boundaries import f32_step
from host_tools.fuzz.link_targets import ControllerLinkTarget
from host_tools.fuzz.targets import CodecTarget
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from aspod_cli import aspod
from test_fuzz_boundaries import first_failure, sim_script

# Both ends of the codec made to accept one past a field's declared maximum (the next f32, or the next integer):
# they round-trip, so the codec target's round trip cannot see it. `accept_one_past(spec, field)` patches `spec`.
PLANT_ONE_PAST = '''
import math
import struct

def accept_one_past(spec, field_name):
    index = [f.name for f in spec.fields].index(field_name)
    fld = spec.fields[index]
    lo, hi = fld.range
    if fld.type == "f32":
        bits = struct.unpack("<i", struct.pack("<f", hi))[0]
        past = struct.unpack("<f", struct.pack("<i", bits + 1))[0]
        ok = lambda v: math.isfinite(v) and lo <= v <= past
    else:
        past = hi + 1
        ok = lambda v: lo <= v <= past                       # the defect: should be hi
    spec._decode_checks = tuple((i, f, ok if i == index else c) for i, f, c in spec._decode_checks)
    spec._encode_checks = tuple((i, f, ok if i == index else c) for i, f, c in spec._encode_checks)
'''


def _plant(source: str, name: str):
    scope: dict = {}
    exec(source, scope)
    return scope[name]


def test_what_a_field_may_hold_is_read_from_the_declaration():
    dial = SCHEMA["BoxDial"]
    assert oracles.payload_violation(dial, dial.encode(dial.type(100.0, 1))) is None
    past = f32_step(100.0, math.inf)
    raw = dial.encode(dial.type(100.0, 1))
    too_far = struct.pack("<f", past) + raw[4:]
    assert "outside its declared range" in oracles.payload_violation(dial, too_far)
    assert "not one of" in oracles.payload_violation(dial, raw[:4] + b"\x09")
    assert "bytes" in oracles.payload_violation(dial, raw + b"\x00")
    assert "not a finite f32" in oracles.declared_violation(dial, (math.nan, 1))
    param_get = SCHEMA["ParamGet"]
    assert "not ASCII" in oracles.payload_violation(param_get, b"a\x00b".ljust(16, b"\x00"))
    assert "not a str16" in oracles.payload_violation(param_get, b"a b".ljust(16, b"\x00"))
    assert oracles.declared_violation(SCHEMA["TrajState"], (0, 1, 256, 0.0, True)) is None   # a bool is a 0/1


def test_a_codec_that_accepts_one_past_the_declared_maximum_both_ways_is_found():
    """SetClock's utc_ms (0..999) accepted up to 1000 by decode and encode alike, in a copy of the spec: the round
    trip holds, the declaration's oracle does not. The real codec passes the same inputs."""
    planted = copy.copy(SCHEMA["SetClock"])
    _plant(PLANT_ONE_PAST, "accept_one_past")(planted, "utc_ms")
    specs = tuple(planted if s.name == "SetClock" else s for s in sorted(SCHEMA.by_id.values(), key=lambda s: s.id))
    rng = random.Random(5)
    inputs = [rng.randbytes(rng.randint(0, 200)) for _ in range(40000)]
    execs, failure = first_failure(CodecTarget(specs=specs), inputs)
    assert failure is not None and failure.oracle in ("decodes as declared", "encodes as declared"), failure
    assert "utc_ms=1000" in failure.error and "declared range" in failure.error
    assert first_failure(CodecTarget(), inputs[:execs])[1] is None


def test_replies_the_protocol_does_not_allow_are_findings():
    box, result = SCHEMA["GetBoxState"], SCHEMA["Result"]
    box_state = SCHEMA["BoxState"]
    good = box_state.type(0, *(f.default or 0 for f in box_state.fields[1:]))
    assert oracles.reply_violation(box, b"", good) is None
    assert oracles.reply_violation(box, b"", result.type(int(Reason.BUSY))) is None          # a Result refusing
    assert "with no reason" in oracles.reply_violation(box, b"", result.type(0))
    assert "which BoxState answers" in oracles.reply_violation(box, b"", SCHEMA["Pong"].type(0, 1, 2))
    assert "breaks the declaration" in oracles.reply_violation(box, b"", box_state.type(0, 7, *good[2:]))
    dial = SCHEMA["BoxDial"]
    past = dial.encode(dial.type(100.0, 1))
    past = struct.pack("<f", f32_step(100.0, math.inf)) + past[4:]
    assert "though the declaration refuses it" in oracles.reply_violation(dial, past, good)
    assert oracles.reply_violation(dial, past, result.type(int(Reason.OUT_OF_RANGE))) is None
    assert oracles.nak_violation(SCHEMA["Nak"].type(0, 1, 2, 3, 0, bytes(8))) == "a Nak with no reason (OK)"
    assert oracles.nak_violation(SCHEMA["Nak"].type(int(Reason.BAD_MAC), 1, 2, 3, 0, bytes(8))) is None


class _Planted(ControllerLinkTarget):
    """controller-link with a defect planted in its controller by `plant(controller)` each time its world is built."""

    def __init__(self, plant) -> None:
        super().__init__()
        self.plant = plant

    def fresh(self) -> None:
        super().fresh()
        self.plant(self.bench.controller)


def _random_inputs(seed: int, n: int) -> list[bytes]:
    rng = random.Random(seed)
    return [rng.randbytes(rng.randint(20, 300)) for _ in range(n)]


def test_in_process_a_reply_of_another_type_and_a_refusal_without_its_reason_are_found(monkeypatch):
    """Planted in controller-link: GetBoxState answered with a Result saying OK (a refusal with no reason, of a type
    the command's rule does not allow), and, apart, a NAK of a sequence gap sent with reason OK. Each is found as its
    oracle's failure; the real controller passes the same inputs."""
    from firmware_py.tracker.commands import TrackerCommands
    from protocol.controller_link import ControllerLink
    inputs = _random_inputs(21, 4000)
    monkeypatch.setattr(TrackerCommands, "_get_box_state", lambda self, msg, now: SCHEMA["Result"].type(0))
    _, failure = first_failure(ControllerLinkTarget(), inputs)
    assert failure is not None and failure.oracle == "replies as declared" and "GetBoxState" in failure.error, failure
    monkeypatch.undo()

    def silent_naks(c) -> None:
        link = c.link
        link._refuse = lambda frame, reason, now, expected=0: ControllerLink._refuse(link, frame, Reason.OK, now, expected)
    execs, failure = first_failure(_Planted(silent_naks), inputs)
    assert failure is not None and failure.oracle == "a refusal says why", failure
    assert first_failure(ControllerLinkTarget(), inputs[:max(execs, 1500)])[1] is None


def test_in_process_a_decoder_accepting_one_past_the_declared_maximum_is_found(monkeypatch):
    """The controller's BoxDial decoding (and encoding) accepts a dial one f32 step past 100 %: controller-link runs
    it, and the declaration says it must not run ("exactly once", judged by the declaration, not by the codec)."""
    spec = SCHEMA["BoxDial"]
    monkeypatch.setattr(spec, "_decode_checks", spec._decode_checks)
    monkeypatch.setattr(spec, "_encode_checks", spec._encode_checks)
    _plant(PLANT_ONE_PAST, "accept_one_past")(spec, "percent")
    _, failure = first_failure(ControllerLinkTarget(), _random_inputs(31, 6000))
    assert failure is not None and failure.oracle == "exactly once", failure
    assert "refused by the declaration" in failure.error and "percent" in failure.error, failure


def _black_box(tmp_path, plant: str, call: str, only: str, cases: int = 300):
    script = tmp_path / "planted_sim.py"
    script.write_text(sim_script(plant, call))
    done = aspod("fuzz", "--target-cmd", f"{sys.executable} {script} sim --pty --no-pacing", "--only", only,
                 "--cases", str(cases), "--max-findings", "1", "--json", cwd=tmp_path, timeout_s=600)
    assert done.returncode == 1, done.stdout[-2000:] + done.stderr[-2000:]
    figures = json.loads(done.stdout)
    assert len(figures["findings"]) == 1 and figures["cases"] < cases, figures
    return findings.load(tmp_path / figures["findings"][0])


@pytest.mark.pty
@pytest.mark.long
def test_black_box_finds_a_controller_that_takes_one_past_the_declared_maximum(tmp_path):
    """A simulator whose BoxDial codec accepts one f32 step past 100 %: the black-box fuzzer sees a BoxState saying
    OK to a dial the declaration refuses (its own decoding of what it sent)."""
    finding = _black_box(tmp_path, PLANT_ONE_PAST, "from protocol.messages import SCHEMA\n"
                         "accept_one_past(SCHEMA['BoxDial'], 'percent')", "BoxDial")
    assert finding.failure.kind == "oracle" and "though the declaration refuses it" in finding.failure.error, \
        finding.failure


PLANT_REFUSED_SET = '''
def plant_refused_set():
    from firmware_py.param_commands import ParamCommands
    from protocol.reasons import Reason
    real = ParamCommands._param_set

    def param_set(self, msg, now):
        reply = real(self, msg, now)
        spec = self.params.specs.get(msg.name)
        if reply.result == Reason.OUT_OF_RANGE and spec is not None and msg.value > spec.hi:
            self.params.set(msg.name, spec.hi)          # the defect: a refused value still clamps the parameter
            return self._param_value(Reason.OUT_OF_RANGE, msg.name)
        return reply
    ParamCommands._param_set = param_set
'''


@pytest.mark.pty
@pytest.mark.long
def test_black_box_finds_a_controller_whose_parameter_moved_on_a_refused_set(tmp_path):
    """A simulator whose ParamSet, refusing a value above a parameter's maximum, sets the parameter to its maximum all
    the same: the refusal's ParamValue says the value in force moved, a refused command changed the controller."""
    finding = _black_box(tmp_path, PLANT_REFUSED_SET, "plant_refused_set()", "ParamSet")
    assert finding.failure.kind == "oracle" and "refused" in finding.failure.error \
        and "a refused command changed the controller" in finding.failure.error, finding.failure


@pytest.mark.pty
def test_a_case_that_closes_its_session_cleanly_is_not_a_finding(tmp_path):
    """A case's Close, answered Closed: the session is over, as the protocol says, and the fuzzer opens a new one
    before its health check, as a host does. Before, the check's Ping was refused and the case saved as a hang
    (in `--cases 60 --seed 5` against the real simulator, once the grammar drew from the target's limits)."""
    steps = [{"kind": "command", "delay_s": 0.0, "msg": "Close", "payload": "02"},
             {"kind": "command", "delay_s": 0.0, "msg": "GetBoxState", "payload": ""}]
    path = findings.Finding("blackbox", findings.Failure("hang", "TargetGone: Ping: SESSION_RESET"),
                            steps=steps).save(tmp_path / "found")
    target = f"{sys.executable} -m host_tools.cli.main sim --pty --no-pacing"
    done = aspod("fuzz", "--replay", str(path), "--target-cmd", target, cwd=tmp_path)
    assert done.returncode == 0 and "no longer fails" in done.stdout, done.stdout + done.stderr


def test_a_state_and_faults_the_protocol_does_not_allow_together_are_a_finding():
    """A fault is latched on entry to a safe state and cleared only by the Reset that leaves it (protocol.md, "Fault
    bits"): bench/fuzz_plants.py's disable-estop (Disable in ESTOP goes to IDLE, the ESTOP bit still latched) breaks
    it; every pair the real supervisor makes keeps it."""
    from host_tools.fuzz.oracles import state_violation
    from protocol.states import ControllerState as S, Fault
    assert "latched only in a safe state" in state_violation(S.IDLE, int(Fault.ESTOP))
    assert state_violation(S.ENABLED, int(Fault.LINK_LOST)) is not None
    assert "without the ESTOP fault bit" in state_violation(S.ESTOP, 0)
    for state, faults in ((S.IDLE, 0), (S.ENABLED, 0), (S.ESTOP, int(Fault.ESTOP)), (S.FAULT, int(Fault.STALL)),
                          (S.BOOT, 0), (S.ESTOP, int(Fault.ESTOP | Fault.LINK_LOST))):
        assert state_violation(state, faults) is None, (state, faults)
