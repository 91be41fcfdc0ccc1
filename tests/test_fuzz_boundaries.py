"""Boundaries learned from the target (host_tools/fuzz/boundaries.py): what its replies say of its limits becomes
the grammar's, and an off-by-one against a length the target knows only at run time is found, in process and
black-box. The defect is planted in a copy (this process's handler class, patched for the test: firmware_py/handlers.py;
a simulator started from a script the test writes)."""
from __future__ import annotations

import json
import math
import random
import struct
import sys

import pytest

from host_tools.fuzz import findings
from host_tools.fuzz.boundaries import Boundaries, constants_of, count_edges, f32_step, range_edges
from host_tools.fuzz.grammar import RandomDraw, draw_payload
from host_tools.fuzz.link_targets import ControllerLinkTarget
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from aspod_cli import aspod

# A copy of the controller's ParamList handler whose bound is off by one against the table's length, which the
# controller knows only at run time (its parameters): an index equal to the count reads past the table.
PLANT_PARAM_LIST = '''
def plant_param_list():
    from firmware_py.param_commands import ParamCommands
    from protocol.reasons import Reason

    def param_list(self, msg, now):
        if msg.index > len(self.params.order):                 # the defect: should be >=
            return self._param_value(Reason.OUT_OF_RANGE, "")
        return self._param_value(Reason.OK, self.params.order[msg.index])
    ParamCommands._param_list = param_list
'''


def sim_script(plant: str, call: str) -> str:
    """A program that plants a defect, then runs `aspod` with its own arguments (as host_tools/fuzz/planted.py)."""
    return plant + f"\n{call}\nimport runpy\nrunpy.run_module('host_tools.cli.main', run_name='__main__', alter_sys=True)\n"


def test_the_target_s_replies_give_its_limits_below_at_and_past_each_end():
    target = ControllerLinkTarget()
    try:
        target.fresh()
        controller, learned = target.bench.controller, target.learned
        count = len(controller.params.order)
        assert learned.edges["ParamList.index"] == {count - 1, count, count + 1}
        capacity = controller.arm_commands.trajectory.capacity
        assert {capacity - 1, capacity, capacity + 1, 0, 1} <= learned.edges["TrajPoint.index"]
        for name, spec in controller.params.specs.items():
            assert learned.ranges[name] == pytest.approx((spec.lo, spec.hi), rel=1e-6)
        assert 1000.0 in learned.interior         # a float constant of the handlers' (ms in a second)
    finally:
        target.close()
    lo, hi = 0.0, 100.0
    edges = range_edges(lo, hi)
    assert {0.0, 100.0} <= set(edges) and min(edges) < 0 and max(edges) > 100.0
    assert f32_step(100.0, math.inf) in edges and f32_step(100.0, -math.inf) in edges
    assert count_edges(76) == (75, 76, 77)

    def handler(x, y):
        return x == 123.0 or (lambda: y > -7.25)()
    assert {123.0, -7.25} <= set(constants_of([handler]))
    assert PARK_DEG in constants_of([parks])          # a float the handler reads from its module, by name


PARK_DEG = 321.5       # a module's named constant, as handlers compare with (bench/fuzz_plants.py's move-park)


def parks(target: float) -> bool:
    return target == PARK_DEG


def test_what_a_black_box_hears_becomes_the_grammar_s():
    """Replies as the target sends them: a ParamValue says the table's length and the parameter's range, a TrajState
    the buffer's knots and capacity, a refusal for a limit the limit's value; the grammar then draws the index at
    the length, and a ParamSet's value at the named parameter's ends, often. Without them, never."""
    learned = Boundaries()
    learned.learn(SCHEMA["ParamValue"].type(0, "j1_vmax", 30.0, 1.0, 90.0, 3, 76, "deg/s", ""))
    learned.learn(SCHEMA["TrajState"].type(0, 4, 256, 1.5, 0))
    learned.learn(SCHEMA["ParamValue"].type(int(Reason.UNKNOWN_PARAM), "nope", 0.0, 0.0, 0.0, 0, 76, "", ""))
    assert learned.edges["ParamList.index"] == {75, 76, 77} and learned.ranges == {"j1_vmax": (1.0, 90.0)}
    assert {3, 4, 5, 255, 256, 257} <= learned.edges["TrajPoint.index"]
    assert 1.5 in learned.interior and 30.0 in learned.interior

    def indexes(told: Boundaries) -> list[int]:
        draw = RandomDraw(random.Random(7))
        spec = SCHEMA["ParamList"]
        return [int.from_bytes(draw_payload(spec, draw, learned=told)[:2], "little") for _ in range(600)]
    assert indexes(learned).count(76) >= 10
    assert indexes(Boundaries()).count(76) == 0
    draw = RandomDraw(random.Random(8))
    words = {"name": ("j1_vmax",)}
    spec = SCHEMA["ParamSet"]
    named = [p for p in (draw_payload(spec, draw, words, learned) for _ in range(600))
             if len(p) == spec.size and p[:7] == b"j1_vmax"]
    values = {struct.unpack("<f", p[-4:])[0] for p in named}
    assert values >= set(range_edges(1.0, 90.0)), sorted(values & set(range_edges(1.0, 90.0)))


def _planted_param_list(monkeypatch):
    from firmware_py.param_commands import ParamCommands
    scope: dict = {}
    exec(PLANT_PARAM_LIST, scope)
    monkeypatch.setattr(ParamCommands, "_param_list", ParamCommands._param_list)   # put back after
    scope["plant_param_list"]()


def first_failure(target, inputs: list[bytes]):
    """(executions, failure) of the first input that fails (a stateful target's world built anew every
    fresh_every inputs, as the child's harness does), or (len(inputs), None)."""
    try:
        for n, data in enumerate(inputs, 1):
            if getattr(target, "stateful", False) and (n - 1) % target.fresh_every == 0:
                target.fresh()
            try:
                target.one_input(data)
            except Exception as exc:     # noqa: BLE001 (what the harness saves as a finding)
                return n, findings.failure_of(exc)
        return len(inputs), None
    finally:
        target.close()


def test_in_process_an_off_by_one_against_the_table_s_run_time_length_is_found(monkeypatch):
    """The planted ParamList (an index equal to the parameter count reads past the table): controller-link, random
    inputs through the grammar (no engine), finds it within 3,000 executions with the controller's limits learned;
    the real handler passes the same inputs. The declaration's grammar alone (u16: 0, 1, 65534, 65535, any) draws
    the index 76 one time in 65,536."""
    rng = random.Random(11)
    inputs = [rng.randbytes(rng.randint(20, 300)) for _ in range(3000)]
    _planted_param_list(monkeypatch)
    execs, failure = first_failure(ControllerLinkTarget(), inputs)
    assert failure is not None and failure.kind == "crash" and "IndexError" in failure.error, failure
    monkeypatch.undo()
    assert first_failure(ControllerLinkTarget(), inputs[:execs])[1] is None


def test_in_process_a_handler_s_magic_float_is_reached_from_its_own_code(monkeypatch):
    """A Jog handler that fails on exactly 123.25 deg/s (planted): atheris traces no float comparison, so the value
    comes from the handlers' code (`constants_of`), drawn as an interior value: found within 3,000 random inputs.
    Drawn from the declaration alone (any f32 of the range, its ends, one past), it is one value in 2^32."""
    from firmware_py.arm_commands import ArmCommands
    real = ArmCommands._jog

    def magic_jog(self, msg, now):
        if msg.speed == 123.25:
            raise ArithmeticError("the planted magic value")
        return real(self, msg, now)
    monkeypatch.setattr(ArmCommands, "_jog", magic_jog)
    rng = random.Random(41)
    execs, failure = first_failure(ControllerLinkTarget(), [rng.randbytes(rng.randint(20, 300)) for _ in range(3000)])
    assert failure is not None and "the planted magic value" in failure.error, failure


@pytest.mark.pty
@pytest.mark.long
def test_black_box_learns_the_table_s_length_and_finds_the_off_by_one_against_it(tmp_path):
    """A simulator with the planted ParamList: the black-box fuzzer reads the table at its first session (the count
    comes with every ParamValue) and sends ParamList at the count: a crash, stopped at the first (--max-findings 1),
    its step the index equal to the count."""
    script = tmp_path / "planted_sim.py"
    script.write_text(sim_script(PLANT_PARAM_LIST, "plant_param_list()"))
    target = f"{sys.executable} {script} sim --pty --no-pacing"
    done = aspod("fuzz", "--target-cmd", target, "--only", "ParamList", "--cases", "300", "--max-findings", "1",
                 "--json", cwd=tmp_path, timeout_s=600)
    assert done.returncode == 1, done.stderr[-2000:]
    figures = json.loads(done.stdout)
    assert len(figures["findings"]) == 1 and figures["cases"] < 300, figures
    finding = findings.load(tmp_path / figures["findings"][0])
    assert finding.failure.kind == "crash" and "IndexError" in finding.failure.trace, finding.failure
    from firmware_py.controller import ControllerConfig, parameter_table
    count = len(parameter_table(ControllerConfig()))
    indexes = [int.from_bytes(bytes.fromhex(s["payload"])[:2], "little") for s in finding.steps
               if s["kind"] == "command" and len(bytes.fromhex(s["payload"])) == 2]
    assert count in indexes, (count, finding.steps)
