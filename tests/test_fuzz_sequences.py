"""Sequences that build state (host_tools/fuzz/grammar.py `draw_chain`): a crash only after TrajClear, two
TrajPoints and TrajRun(2) is found in process and black box, where commands drawn one by one never reached it
(docs/fuzzing.md, "What it finds": 49,835 executions in process, none black box, before sequences). The defect is
planted in a copy: this process's handler class patched for the test (firmware_py/handlers.py), a simulator started
from a script the test writes."""
from __future__ import annotations

import json
import random
import sys

import pytest

from host_tools.fuzz import findings
from host_tools.fuzz.boundaries import Boundaries, f32_step
from host_tools.fuzz.grammar import RandomDraw, draw_chain, draw_payload, refollow
from host_tools.fuzz.link_targets import CHAIN_COMMANDS, ControllerLinkTarget
from protocol.messages import SCHEMA
from aspod_cli import aspod
from test_fuzz_boundaries import first_failure, sim_script

# TrajClear empties a cache that only a run of 3+ knots fills; TrajRun of two knots reads it: IndexError.
PLANT_TRAJ_TWO = '''
def plant_traj_two():
    from firmware_py.arm_commands import ArmCommands
    from protocol.reasons import Reason
    real_clear, real_run = ArmCommands._traj_clear, ArmCommands._traj_run

    def traj_clear(self, msg, now):
        reply = real_clear(self, msg, now)
        if reply.result == Reason.OK:
            self.segments = []
        return reply

    def traj_run(self, msg, now):
        if msg.count == len(self.trajectory.knots) == 2 and getattr(self, "segments", None) is not None:
            self.segments[0]                   # the defect: the cache is empty
        return real_run(self, msg, now)
    ArmCommands._traj_clear, ArmCommands._traj_run = traj_clear, traj_run
'''


def test_a_reply_says_what_the_next_command_of_a_sequence_carries():
    learned = Boundaries()
    learned.learn(SCHEMA["TrajState"].type(0, 1, 16, 2.0, False))        # one knot held, at 2 s
    point, run = SCHEMA["TrajPoint"], SCHEMA["TrajRun"]
    draw = RandomDraw(random.Random(3))
    for _ in range(50):
        knot = point.decode(draw_payload(point, draw, learned=learned, follow=True))   # valid: it decodes
        assert knot.index == 1 and knot.t in (2.0, f32_step(2.0, float("inf")), 3.0)
        assert run.decode(draw_payload(run, draw, learned=learned, follow=True)).count == 1
    stale = point.encode(point.type(0, 0.0, *[0.0] * 10))
    assert point.decode(refollow(point, stale, learned, draw)).index == 1      # at the time it is sent
    assert refollow(point, stale[:-1], learned, draw) == stale[:-1]             # not of its size: as it is
    for _ in range(50):
        chain = draw_chain(CHAIN_COMMANDS, draw, 6)
        assert 1 <= len(chain) <= 6 and chain[-1].name in ("TrajPoint", "TrajRun")
        assert all(spec.reply == "TrajState" for spec in chain[:-1])


def test_in_process_a_crash_after_a_sequence_is_found(monkeypatch):
    """Random inputs through the grammar (no engine): found within 3,000 executions (97-439 in three seeds when
    written); the real handlers pass the same inputs."""
    namespace: dict = {}
    exec(PLANT_TRAJ_TWO, namespace)
    from firmware_py.arm_commands import ArmCommands
    monkeypatch.setattr(ArmCommands, "_traj_clear", ArmCommands._traj_clear)      # put back after
    monkeypatch.setattr(ArmCommands, "_traj_run", ArmCommands._traj_run)
    namespace["plant_traj_two"]()
    rng = random.Random(5)
    inputs = [rng.randbytes(rng.randint(20, 300)) for _ in range(3000)]
    execs, failure = first_failure(ControllerLinkTarget(), inputs)
    assert failure is not None and failure.kind == "crash" and "IndexError" in failure.error, failure
    monkeypatch.undo()
    assert first_failure(ControllerLinkTarget(), inputs[:execs])[1] is None


@pytest.mark.pty
@pytest.mark.long
def test_black_box_finds_a_crash_after_a_sequence(tmp_path):
    """A simulator with the planted defect, the trajectory's three commands only: found as a crash, its steps
    (once shrunk) the sequence, the last a TrajRun of two knots."""
    script = tmp_path / "planted_sim.py"
    script.write_text(sim_script(PLANT_TRAJ_TWO, "plant_traj_two()"))
    target = f"{sys.executable} {script} sim --pty --no-pacing"
    done = aspod("fuzz", "--target-cmd", target, "--only", "TrajClear", "--only", "TrajPoint", "--only", "TrajRun",
                 "--cases", "2000", "--max-findings", "1", "--json", cwd=tmp_path, timeout_s=600)
    assert done.returncode == 1, done.stderr[-2000:]
    figures = json.loads(done.stdout)
    assert len(figures["findings"]) == 1 and figures["cases"] < 2000, figures
    finding = findings.load(tmp_path / figures["findings"][0])
    assert finding.failure.kind == "crash" and "IndexError" in finding.failure.trace, finding.failure
    if finding.minimized:         # shrunk: the sequence's last command, as sent (the count the reply before it said)
        last = finding.steps[-1]
        assert last["msg"] == "TrajRun" and SCHEMA["TrajRun"].decode(bytes.fromhex(last["payload"])).count == 2
