"""aspod fuzz: the grammar, the in-process targets and their oracles, findings (saved, minimized, replayed), the
planted defects found in process and black-box, and the command's bad input."""
from __future__ import annotations

import json
import math
import os
import random
import re
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools.fuzz import findings
from host_tools.fuzz.grammar import TO_CONTROLLER, interesting
from host_tools.fuzz.inprocess import JobSettings, run_job
from host_tools.fuzz.targets import builtin_targets, load_target
from host_tools.worlds.child import run
from protocol.errors import ParseError
from protocol.messages import SCHEMA
from aspod_cli import aspod

PLANTED_CODEC = "host_tools.fuzz.planted:planted_codec_target"


def test_the_grammar_holds_each_fields_boundaries_and_one_beyond():
    dial = SCHEMA["BoxDial"].fields[0]
    values = interesting(dial)
    assert 0.0 in values and 100.0 in values
    assert any(v > 100.0 and v < 100.0001 for v in values)          # the next f32 after the boundary
    assert any(isinstance(v, float) and math.isnan(v) for v in values) and math.inf in values
    axis = SCHEMA["Move"].fields[0]
    members = [int(m) for m in axis.enum]
    assert set(members) <= set(interesting(axis)) and set(interesting(axis)) - set(members)   # and some not
    assert {s.name for s in TO_CONTROLLER} >= {"Ping", "Move", "EStop", "Hello", "Heartbeat"}


def test_valid_values_decode_and_include_the_ranges_own_ends():
    """`draw_valid` makes every numeric field something its message decodes, its range's ends among them: the
    single-field mode of `draw_payload` reaches the handlers with the other fields right."""
    import random
    from host_tools.fuzz.grammar import RandomDraw, draw_valid, pack_raw
    draw = RandomDraw(random.Random(3))
    numeric = [s for s in TO_CONTROLLER if s.fields and not any(f.is_text or f.type.startswith("bytes")
                                                                    for f in s.fields)]
    assert any(s.name == "BoxDial" for s in numeric)
    for spec in numeric:
        for _ in range(50):
            spec.decode(pack_raw(spec, [draw_valid(f, draw) for f in spec.fields]))
    dials = {draw_valid(SCHEMA["BoxDial"].fields[0], draw) for _ in range(400)}
    assert {0.0, 100.0} <= dials and all(0.0 <= d <= 100.0 for d in dials)


@pytest.mark.parametrize("name", sorted(builtin_targets()))
def test_every_target_takes_any_bytes_and_its_oracles_hold(name):
    """300 inputs of random bytes per target, in this process (no atheris engine): nothing escapes."""
    target = load_target(name)
    rng = random.Random(name)
    try:
        failure = findings.run_inputs(target, [rng.randbytes(rng.randint(0, 200)) for _ in range(300)])
    finally:
        target.close()
    assert failure is None, failure.describe() + "\n" + failure.trace


def test_the_controller_link_target_reaches_the_handlers_with_frames_it_signed():
    target = load_target("controller-link")
    rng = random.Random(3)
    try:
        target.fresh()
        executed = target.bench.controller.link.commands_executed
        for _ in range(200):
            target.one_input(rng.randbytes(60))
        assert target.bench.controller.link.commands_executed > executed + 20
    finally:
        target.close()


def test_the_host_link_target_forges_replies_to_commands_in_flight_that_end_them():
    """Forged replies take the sequence numbers in flight: some end a command, as a success or as a refusal (a
    reply that says no or does not decode), before the controller's own reply comes and is ignored."""
    from protocol.reliable import Outcome
    target = load_target("host-link")
    rng = random.Random(5)
    try:
        target.fresh()
        ended = set()
        for _ in range(400):
            target.one_input(rng.randbytes(80))
            ended |= {h.outcome for h in target.pings if h.done}
        assert Outcome.REJECTED in ended, ended
        assert all(h.reply.spec.name == "Pong" for h in target.pings if h.outcome is Outcome.SUCCEEDED)
    finally:
        target.close()


def test_the_host_refuses_an_authenticated_reply_of_another_commands_type_saying_which():
    """Seen once the host-link target's forged replies met commands in flight (2026-11-28): nothing checked a
    reply's type, so a Result saying OK (or any reply saying OK) in answer to a Ping ended it a success with no Pong
    in it. A command is answered by its own reply or refused by a Result; anything else ends it REJECTED, and the
    controller's own reply, coming after, changes nothing."""
    from host_tools.fuzz.link_targets import FrameRecipe, build
    from protocol.reliable import Outcome
    from protocol.reasons import Reason
    from protocol.schema import MsgClass
    target = load_target("host-link")
    try:
        target.fresh()
        bench, host = target.bench, target.bench.host
        now = bench.clock.now()
        ping = host.submit(SCHEMA["Ping"].type(token=7), now)
        host.poll(now)
        [seq] = host._commands.in_flight_seqs()
        result = SCHEMA["Result"]
        recipe = FrameRecipe(result, int(MsgClass.COMMAND), seq, result.encode(result.type(int(Reason.OK))))
        session, handshake = target.sender()
        host.feed(build(recipe, session, host.session, handshake, target.ack_value(), None), now)
        assert ping.outcome is Outcome.REJECTED and ping.reason is Reason.UNKNOWN_MESSAGE, ping.describe()
        assert "Result in answer to Ping, which Pong answers" in ping.detail
        bench.run_for(0.05)                                   # the controller's Pong comes, and is too late
        assert ping.reason is Reason.UNKNOWN_MESSAGE
        assert bench.call(SCHEMA["Ping"].type(token=8), 1.0).ok   # the session goes on
    finally:
        target.close()


def test_a_planted_off_by_one_in_the_codec_is_found_minimized_and_replayed(tmp_path):
    """The codec's length check off by one (host_tools/fuzz/planted.py): found by the round-trip oracle within
    20,000 executions, shrunk to a few bytes, and `aspod fuzz --replay` says it still fails."""
    job = JobSettings(PLANTED_CODEC, tmp_path / "corpus", tmp_path / "found", seconds=None, runs=20000)
    result = run_job(job)
    assert len(result.findings) == 1 and result.execs <= 20000
    finding = findings.load(Path(result.findings[0]))
    assert finding.failure.kind == "oracle" and finding.failure.oracle == "round trip"
    assert finding.minimized and len(finding.inputs) == 1 and len(finding.inputs[0]) <= 8
    done = aspod("fuzz", "--replay", result.findings[0], cwd=tmp_path)
    assert done.returncode == 2 and "name it after the file to say you trust it" in done.stderr   # it runs code
    done = aspod("fuzz", "--replay", result.findings[0], PLANTED_CODEC, cwd=tmp_path)
    assert done.returncode == 1 and "fails as found" in done.stdout
    clean = run_job(JobSettings("codec", tmp_path / "corpus2", tmp_path / "found2", seconds=None, runs=5000))
    assert clean.findings == [] and clean.execs == 5000 and clean.cov > 50


def test_findings_that_are_not_findings_are_refused_with_a_reason(tmp_path):
    bad = tmp_path / "bad.json"
    for text in ("not json", json.dumps([1]), json.dumps({"format": "aspod-fuzz-finding/1", "target": "codec"}),
                 json.dumps({"format": "aspod-fuzz-finding/1", "target": "codec", "failure": {"kind": "crash",
                                                                                            "error": "x"},
                             "inputs": ["zz"]})):
        bad.write_text(text)
        with pytest.raises(findings.FindingError):
            findings.load(bad)
    for text, said in (("[" * 100_000, "nests deeper than 32 levels"),
                       ('{"format": "aspod-fuzz-finding/1", "seed": NaN}', "NaN is not a number JSON allows")):
        bad.write_text(text)
        with pytest.raises(findings.FindingError, match=said):       # read as strictly as every JSON from outside
            findings.load(bad)
    done = aspod("fuzz", "--replay", str(bad), cwd=tmp_path)
    assert done.returncode == 2 and "bad.json" in done.stderr


def test_the_link_targets_count_edges_not_how_often_they_ran(tmp_path):
    """controller-link runs libFuzzer with its own options (`engine_options`: -use_counters=0): its world runs the
    controller's 1 kHz tasks for as long as an input waits, and with hit counts every longer wait was new coverage
    (before 2026-11-28: features above edges; its corpus full of inputs that only wait). Without them libFuzzer's
    features are its edges."""
    (tmp_path / "corpus").mkdir()
    done = subprocess.run([sys.executable, "-m", "host_tools.fuzz.child", "controller-link", str(tmp_path / "found"),
                           "10", "-seed=1", "-runs=400", str(tmp_path / "corpus")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    cov, ft = (int(x) for x in re.search(r"#400\s+DONE\s+cov: (\d+) ft: (\d+)", done.stderr).groups())
    assert ft == cov > 100, done.stderr[-1000:]


_FIND_PLANTED_LINK = """
import random, sys
from pathlib import Path
from host_tools.fuzz import findings
from host_tools.fuzz.planted import planted_controller_link_target
target = planted_controller_link_target()
rng = random.Random(3)
since = []
for n in range(20 * target.fresh_every):          # as the child's harness: a fresh world every fresh_every inputs
    if n % target.fresh_every == 0:
        target.fresh()
        since = []
    since.append(rng.randbytes(rng.randint(20, 300)))
    try:
        target.one_input(since[-1])
    except Exception as exc:
        print(findings.Finding(sys.argv[1], findings.failure_of(exc), since).save(Path(sys.argv[2])))
        break
target.close()
"""


@pytest.mark.long
def test_a_controller_link_finding_replays_alone_to_the_same_failure(tmp_path):
    """The controller-link target keeps its world between inputs: a finding is every input since the world was
    built, and replayed alone, on a world built anew, it fails the same way, every time. Found here over the
    planted BoxDial handler (in a child: planting changes that process's handler class)."""
    planted = "host_tools.fuzz.planted:planted_controller_link_target"
    done = subprocess.run([sys.executable, "-c", _FIND_PLANTED_LINK, planted, str(tmp_path)], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip(), done.stderr[-2000:]
    path = done.stdout.strip().splitlines()[-1]
    finding = findings.load(Path(path))
    assert finding.failure.kind == "crash" and "IndexError" in finding.failure.error, finding.failure
    assert finding.failure.where.startswith("host_tools/fuzz/planted.py:")
    for _ in range(2):
        done = aspod("fuzz", "--replay", path, planted, cwd=tmp_path)
        assert done.returncode == 1 and "fails as found" in done.stdout, done.stdout + done.stderr


def test_a_finding_with_more_inputs_than_the_fuzzer_keeps_is_refused_before_it_runs(tmp_path):
    path = findings.Finding("controller-link", findings.Failure("crash", "x"), [b""] * 501).save(tmp_path)
    with pytest.raises(findings.FindingError, match="holds at most 500 inputs"):
        findings.replay(findings.load(path), lambda: load_target("controller-link"))


def test_the_command_refuses_bad_input_with_its_reason(tmp_path):
    for args, said in ((["nosuch"], "no fuzz target 'nosuch'"), (["codec", "--cases", "3"], "black-box"),
                       ([], "name an in-process TARGET"), (["codec", "--url", "/dev/null"], "one at a time"),
                       (["--url", "/dev/null", "--only", "Pong"], "not a command the controller takes"),
                       (["nosuch.module:f"], "cannot load it"), (["codec", "--max-findings", "1"], "black-box"),
                       (["--url", "/dev/null", "--max-findings", "0"], "--max-findings"),
                       (["codec", "codec"], "named twice"), (["codec", "--list"], "give it alone"), (["builtins:input"], "its factory raised EOFError"),
                       (["host_tools.fuzz.planted:PLANTED_DIAL_PCT"], "is not a factory")):
        done = aspod("fuzz", *args, cwd=tmp_path, timeout_s=60)
        assert done.returncode == 2 and said in done.stderr, (args, done.stderr)
    assert not (tmp_path / "fuzz-findings").exists() or not any((tmp_path / "fuzz-findings").iterdir())
    (tmp_path / "afile").write_text("")
    for args, said in ((["--findings", "afile"], "--findings afile: not a folder"),
                       (["--corpus", "afile"], "--corpus afile/codec: cannot be made")):
        done = aspod("fuzz", "codec", "--runs", "10", *args, cwd=tmp_path, timeout_s=60)
        assert done.returncode == 2 and said in done.stderr, (args, done.stderr)
    assert not (tmp_path / "fuzz-corpus").exists()              # nothing made for a run that was refused
    done = aspod("--log-file", str(tmp_path), "fuzz", "--list", cwd=tmp_path)     # a folder: every command says so
    assert done.returncode == 2 and f"--log-file {tmp_path}: a folder, not a file" in done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.pty
@pytest.mark.long
def test_black_box_finds_the_planted_handler_crash_over_a_pty_and_replays_it(tmp_path):
    """A simulator whose BoxDial handler crashes at exactly 100 % (planted): the black-box fuzzer, sending only
    BoxDial, finds it within 300 cases, shrinks it, stops (--max-findings 1), and the finding fails again on a fresh
    simulator. No --key-file: each target started (and restarted) makes a key of its own and says it on its
    ASPOD-KEY line."""
    target = f"{sys.executable} -m host_tools.fuzz.planted sim --pty --no-pacing"
    done = aspod("fuzz", "--target-cmd", target, "--only", "BoxDial", "--cases", "300", "--max-findings", "1",
                 "--json", cwd=tmp_path, timeout_s=600)
    assert done.returncode == 1, done.stderr[-2000:]
    figures = json.loads(done.stdout)
    crashes = [f for f in figures["findings"] if Path(f).name.startswith("crash-")]
    assert crashes == figures["findings"] and len(crashes) == 1 and figures["cases"] < 300, figures  # then it stops
    finding = findings.load(tmp_path / crashes[0])
    assert any(s["kind"] == "command" and s["msg"] == "BoxDial" for s in finding.steps)
    again = aspod("fuzz", "--replay", crashes[0], "--target-cmd", target, cwd=tmp_path, timeout_s=300)
    assert again.returncode == 1 and "fails as found" in again.stdout, again.stdout + again.stderr


@pytest.mark.pty
@pytest.mark.cpu_hog        # a busy loop on one core: never beside the other real-time tests (conftest)
def test_a_target_the_black_box_fuzzer_started_and_a_busy_machine_keeps_from_running_is_not_a_hang(tmp_path):
    """Under load (two busy loops beside `make test`) the planted-crash fuzzing above also reported a hang: a health
    check's Ping not answered within 5 s of wall time by a target only kept from running. A target the fuzzer started
    is judged on its own time. Here a busy loop at real-time priority takes its core for 0.9 s at a time, its health
    bound 0.5 s: checks take longer than that on the wall clock, and none is a hang."""
    from host_tools.fuzz.blackbox import BlackBoxSettings, HealthCheck, Session
    from host_tools.worlds.own_time import sample
    from test_separate_processes import kept_from_running
    from protocol import auth
    from timebase import RealClock
    psk = bytes(range(32))
    key = tmp_path / "k.key"
    auth.write_key(key, psk)
    settings = BlackBoxSettings(command=(sys.executable, "-m", "host_tools.cli.main", "sim", "--pty", "--no-pacing",
                                         "--no-tracker", "--key-file", str(key)), cases=1, health_timeout_s=0.5)
    session = Session(settings, psk)
    pid = session.child.pid
    try:
        with kept_from_running(pid):
            clock, before, took = RealClock(), sample(pid), []
            health = HealthCheck(session)
            while sum(took) < 5.0:                  # checks one after another, through bursts of the busy loop
                start = clock.now()
                assert health.check([]) is None
                took.append(clock.now() - start)
            waited = sample(pid).waited_s - before.waited_s
    finally:
        session.close()
    assert max(took) > 0.5, (took, waited)      # the premise: kept waiting past the bound


@pytest.mark.pty
@pytest.mark.long
def test_black_box_against_the_real_simulator_finds_nothing(tmp_path):
    key = tmp_path / "k.key"
    from protocol import auth
    auth.write_key(key, bytes(range(32)))
    target = f"{sys.executable} -m host_tools.cli.main sim --pty --no-pacing --key-file {key}"
    done = aspod("fuzz", "--target-cmd", target, "--key-file", str(key), "--cases", "60", "--seed", "5", "--json",
                 cwd=tmp_path, timeout_s=600)
    figures = json.loads(done.stdout)
    assert done.returncode == 0 and figures["findings"] == [] and figures["cases"] == 60, done.stderr[-3000:]


@pytest.mark.pty
def test_a_replayed_counter_is_one_the_target_answered_so_a_refused_frame_does_not_make_a_false_finding(tmp_path):
    """A frame under another key (refused: its counter never taken), then an EStop "replayed" with the counter the
    fuzzer last used: that counter must be one the target has answered, else the EStop is authentic, rightly runs,
    and the health check calls it a second execution. (A false finding the fuzzer once made.)"""
    key = tmp_path / "k.key"
    from protocol import auth
    auth.write_key(key, bytes(range(32)))
    frame = {"kind": "frame", "delay_s": 0.0, "offset": 1, "version": 1, "flags": 16, "length_delta": 0}
    steps = [{**frame, "msg": "ParamSet", "cls": 1, "seq": "any", "any_seq": 50488,
              "payload": "6161616161616161616161616161616169a0a6e4", "mac": "other-key"},
             {**frame, "msg": "EStop", "cls": 2, "seq": "duplicate", "any_seq": 52547, "payload": "",
              "mac": "stale-counter", "delay_s": 0.006}]
    path = findings.Finding("blackbox", findings.Failure("oracle", "HealthCheck: not exactly once"),
                            steps=steps).save(tmp_path / "found")
    target = f"{sys.executable} -m host_tools.cli.main sim --pty --no-pacing --key-file {key}"
    done = aspod("fuzz", "--replay", str(path), "--target-cmd", target, "--key-file", str(key), cwd=tmp_path)
    assert done.returncode == 0 and "no longer fails" in done.stdout, done.stdout + done.stderr


def test_the_teleop_targets_words_include_the_sim_words_from_their_declaration():
    """Its words come from the declarations it parses against, the `sim` ops', faults' and switches' too: without
    them no `sim` line named an op, and the arguments' parsing went unfuzzed (sim_words.py 30.5 % of its lines
    after 10^7 executions; 61.9 % after 300,000 with them)."""
    from hil_sim.faults import FAULT_NAMES
    from host_tools.teleop import sim_words
    from host_tools.worlds.plant_control import OPS
    target = load_target("teleop")
    try:
        missing = (set(OPS) | set(FAULT_NAMES) | set(sim_words.SWITCH_WORDS)) - set(target.vocabulary)
    finally:
        target.close()
    assert not missing, missing


_TRACED = """
import json, sys
from host_tools.fuzz.child import instrumenting, load_for_fuzzing
with instrumenting(sys.argv[1]):
    target = load_for_fuzzing(sys.argv[1])

def traced(module):
    # functions of `module` whose code calls atheris' coverage hooks (a function with no branch and no
    # comparison has none to call, so a module counts if any of its functions does)
    found = 0
    for obj in vars(module).values():
        for fn in [obj, *vars(obj).values()] if isinstance(obj, type) else [obj]:
            code = getattr(fn, "__code__", None)
            if code is not None and getattr(fn, "__module__", None) == module.__name__:
                found += bool({"_trace_branch", "_trace_cmp"} & set(code.co_names))
    return found

carriers = ("hil_sim.plant", "hil_sim.arm_tick", "host_tools.worlds.world", "host_tools.fuzz.grammar",
            "host_tools.fuzz.link_targets", "timebase.scheduler")
from host_tools.fuzz.child import FAST_LOOP
print(json.dumps({"covers": {path: traced(sys.modules[path.removesuffix(".py").replace("/", ".")])
                             for path in target.covers},
                  "carriers": {m: traced(sys.modules[m]) for m in carriers if m in sys.modules},
                  "fast loop": {m: traced(sys.modules[m]) for m in FAST_LOOP if m in sys.modules}}))
target.close()
"""


@pytest.mark.parametrize("name", sorted(builtin_targets()))
def test_every_file_a_target_covers_is_instrumented_for_the_coverage_guided_fuzzer(name):
    """As `aspod fuzz`'s child loads it: the files a target covers run instrumented, so libFuzzer sees their
    branches. The controller, protocol/controller_link.py, host_link.py and the HAL decoders did not until
    2026-11-25: they were first imported when the harness first built the target's world, after atheris' hook.
    What carries the world and builds the inputs (the plant, the worlds, the grammar, the clock) does not: until
    2026-11-27 atheris took `hil_sim.hal_node` for all of hil_sim and `host_tools.teleop` for all of host_tools,
    and controller-link ran 15-25 % slower for it, its corpus kept for the plant's branches and the grammar's."""
    done = run([sys.executable, "-c", _TRACED, name], text=True, timeout_s=120)
    assert done.returncode == 0, done.stderr[-2000:]
    traced = json.loads(done.stdout.splitlines()[-1])
    assert traced["covers"] and all(n > 0 for n in traced["covers"].values()), traced
    assert all(n == 0 for n in traced["carriers"].values()), traced
    if name in ("controller-link", "host-link"):
        assert {"hil_sim.plant", "host_tools.worlds.world", "host_tools.fuzz.grammar"} <= set(traced["carriers"])
        # the 1 kHz loops and the HAL bus carry the world too (host_tools/fuzz/child.py FAST_LOOP): until
        # 2026-11-28 they ran instrumented, and cost controller-link half its time
        assert {"firmware_py.joints_tick", "protocol.hal", "hil_sim.hal_node"} <= set(traced["fast loop"])
        assert all(n == 0 for n in traced["fast loop"].values()), traced


@pytest.mark.long
def test_controller_link_fuzzes_with_the_compiled_kernels(tmp_path):
    """`ASPOD_COMPILED=1`: the child builds its world with the joints' kernel compiled by numba. Until 2026-11-28
    atheris instrumented that kernel's module, and numba, typing the instrumented bytecode, failed: the child died
    before its first input."""
    pytest.importorskip("numba")
    (tmp_path / "corpus").mkdir()
    done = subprocess.run([sys.executable, "-m", "host_tools.fuzz.child", "controller-link", str(tmp_path / "found"),
                           "10", "-seed=1", "-runs=50", str(tmp_path / "corpus")],
                          capture_output=True, text=True, timeout=600, env=dict(os.environ, ASPOD_COMPILED="1"))
    assert done.returncode == 0 and "Done 50 runs" in done.stderr, done.stderr[-3000:]


def test_the_campaign_counts_since_a_commit_only_the_chunks_run_at_it_or_after(tmp_path):
    """`python -m bench.fuzz_campaign --since REV`: a harness mended at REV starts its targets' count afresh."""
    from bench import fuzz_campaign
    head = subprocess.run(["git", "-C", str(fuzz_campaign.ROOT), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True).stdout.strip()
    row = {"target": "hal", "seed": 1, "execs": 500000, "wall_s": 50.0, "execs_per_s": 1e4, "cov": 1, "ft": 1,
           "corpus": 1, "findings": [], "error": ""}
    ledger = tmp_path / "ledger.jsonl"
    ledger.write_text("".join(json.dumps({**row, "seed": seed, "commit": commit}) + "\n"
                              for seed, commit in ((1, "0000000"), (2, head), (3, head))))
    assert [j.seed for j in fuzz_campaign.counted(ledger, None)] == [1, 2, 3]
    assert [j.seed for j in fuzz_campaign.counted(ledger, head)] == [2, 3]     # an unknown commit is not after


def test_the_campaign_report_says_when_a_targets_corpus_is_not_on_this_machine(tmp_path, capsys):
    """The ledger of record lives in the repository, the corpus in the campaign's folder: on a new machine the
    folder is gone, and `--report` said so with a traceback from coverage.py's child."""
    from bench import fuzz_campaign
    row = {"target": "hal", "seed": 7, "execs": 500000, "wall_s": 50.0, "execs_per_s": 1e4, "cov": 1, "ft": 1,
           "corpus": 1, "findings": [], "error": "", "commit": "0000000"}
    ledger = tmp_path / "ledger.jsonl"
    ledger.write_text(json.dumps(row) + "\n")
    assert fuzz_campaign.main([str(tmp_path / "campaign"), "--ledger", str(ledger), "--report"]) == 0
    line = [x for x in capsys.readouterr().out.splitlines() if x.startswith("hal ")]
    assert len(line) == 1 and "500,000" in line[0]
    assert f"not measured: no corpus at {tmp_path / 'campaign' / 'corpus' / 'hal'}" in line[0]


def test_the_campaign_report_reports_only_the_targets_asked_for(tmp_path, capsys):
    """`--report --targets a,b` measures only those (a corpus's coverage takes minutes; the others' corpora may be
    growing in a campaign beside)."""
    from bench import fuzz_campaign
    rows = [{"target": t, "seed": 7, "execs": 500000, "wall_s": 50.0, "execs_per_s": 1e4, "cov": 1, "ft": 1,
             "corpus": 1, "findings": [], "error": "", "commit": "0000000"} for t in ("hal", "codec")]
    ledger = tmp_path / "ledger.jsonl"
    ledger.write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert fuzz_campaign.main([str(tmp_path / "campaign"), "--ledger", str(ledger), "--report",
                               "--targets", "codec"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [x.split()[0] for x in out[1:]] == ["codec"]


def test_the_campaign_refuses_a_target_it_does_not_have_saying_which(tmp_path, capsys):
    """A misspelt `--targets` name is refused with the names there are, not reported as an empty table."""
    from bench import fuzz_campaign
    ledger = tmp_path / "ledger.jsonl"
    with pytest.raises(SystemExit) as exit_:
        fuzz_campaign.main([str(tmp_path / "campaign"), "--ledger", str(ledger), "--report",
                            "--targets", "codec,host-lnk"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "no target named host-lnk" in err and "host-link" in err
    assert not ledger.exists() and not (tmp_path / "campaign").exists()


def test_the_controller_link_target_names_its_controllers_parameters_in_param_set():
    """A parameter's name is the controller's, not the declaration's: the target gives its controller's names to
    the grammar (`Words`), without which no ParamSet of the first campaign's 10^7 executions set a parameter."""
    from host_tools.fuzz.grammar import RandomDraw, draw_payload
    target = load_target("controller-link")
    try:
        target.fresh()
        names = set(target.bench.controller.params.order)
        draw, spec = RandomDraw(random.Random(2)), SCHEMA["ParamSet"]
        named = []
        for _ in range(400):
            try:
                named.append(spec.decode(draw_payload(spec, draw, target.words)).name)
            except ParseError:           # a payload wrong on purpose
                pass
    finally:
        target.close()
    assert len(names & set(named)) >= 10, sorted(set(named))[:20]


@pytest.mark.pty
def test_black_box_learns_the_targets_parameters_sets_them_and_sets_them_back_after_each_case(tmp_path):
    """A parameter's name is the controller's: the black-box fuzzer reads the target's table (ParamList) and draws
    ParamGet's and ParamSet's names from it. Before, it drew names from the grammar alone, and no ParamSet of a run
    set a parameter. What a case's ParamSets change is set back after its health check, so every case (and a
    finding replayed alone on a fresh target) starts from the configuration the target was found in: the table read
    afterwards through a new session is the table found."""
    from host_tools.client.params import read_param_table
    from host_tools.fuzz.blackbox import BlackBoxFuzzer, BlackBoxSettings, Session
    from host_tools.worlds.child import Child
    from host_tools.worlds.world import LockstepBench
    from protocol import auth
    psk = bytes(range(32))
    key = tmp_path / "k.key"
    auth.write_key(key, psk)
    bench = LockstepBench(seed=0)
    try:
        order = tuple(bench.controller.params.order)
    finally:
        bench.close()
    sim = Child(["sim", "--pty", "--no-pacing", "--key-file", str(key)],
                env={**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")})     # not the user's params file
    try:
        url = sim.ready("ASPOD-LINK ").split(" ", 1)[1].strip()
        settings = BlackBoxSettings(url=url, seconds=None, cases=80, seed=3, findings=tmp_path / "found",
                                    only=("ParamSet",))
        fuzzer = BlackBoxFuzzer(settings, psk)
        result = fuzzer.run()
        session = Session(settings, psk)
        try:
            after = read_param_table(session, 10.0)
        finally:
            session.close()
    finally:
        sim.stop()
    assert result.findings == [] and result.cases == 80
    assert fuzzer.params.words["name"] == order
    assert result.params_put_back >= 3 and not fuzzer.params.owed, (result, fuzzer.params.owed)
    assert after.failed is None and {r.name: r.value for r in after.replies} == fuzzer.params.found


def test_a_refused_frame_while_the_joints_home_compiled_is_not_a_finding(tmp_path, monkeypatch):
    """With ASPOD_COMPILED=1 the controller-link fuzzer found 'refused changes nothing' in 4,645 executions: a joint's
    homing target is NaN, each read of it from the compiled joints' arrays a new float, and NaN != NaN. The oracle
    compares numbers by their bits; the finding (kept) replays as no longer failing."""
    pytest.importorskip("numba")
    monkeypatch.setenv("ASPOD_COMPILED", "1")
    finding = Path(__file__).parent / "data" / "nan_target_refused_frame_finding.json"
    done = aspod("fuzz", "--replay", str(finding), cwd=tmp_path, timeout_s=600)
    assert done.returncode == 0 and "no longer fails" in done.stdout, done.stdout + done.stderr[-3000:]


EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _fuzz_example(tmp_path: Path, spec: str) -> tuple[subprocess.CompletedProcess, list[findings.Finding]]:
    """`aspod fuzz examples/SPEC` (your own code, as docs/fuzzing.md runs it), with its findings."""
    done = aspod("fuzz", f"{EXAMPLES / spec}", "--runs", "20000", "--no-progress", "--findings", "found", cwd=tmp_path)
    return done, [findings.load(p) for p in sorted((tmp_path / "found").glob("*.json"))]


def test_your_own_parser_is_fuzzed_by_the_command_and_its_bug_found(tmp_path):
    """examples/fuzz_parser.py: a hand-written parser whose bounds check is off by one. Its target has
    `one_input` and no `close` (optional): before, the command crashed (AttributeError: no attribute 'close')."""
    pytest.importorskip("atheris")
    done, found = _fuzz_example(tmp_path, "fuzz_parser.py:target")
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert len(found) == 1 and found[0].failure.kind == "crash", found
    assert found[0].failure.error.startswith("error: unpack_from") and "fuzz_parser.py" in found[0].failure.where
    assert found[0].minimized and len(found[0].inputs) == 1, found[0].inputs


def test_your_own_controller_on_the_link_is_fuzzed_by_the_command_and_its_bug_found(tmp_path):
    """examples/fuzz_controller.py: a controller of the user's own on protocol.controller_link, with its own
    handlers; its ParamSet divides by `gain`, and 0 is in range. The fuzzer reaches the handler through a live
    session and finds it."""
    pytest.importorskip("atheris")
    done, found = _fuzz_example(tmp_path, "fuzz_controller.py:target")
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert len(found) == 1 and found[0].failure.kind == "crash", found
    assert found[0].failure.error.startswith("ZeroDivisionError") and "fuzz_controller.py" in found[0].failure.where


CLOSES_BADLY = '''
class World:
    """A stateful target of a user's own whose close fails on what an input left (a byte 0x5a seen)."""
    stateful = True
    fresh_every = 4

    def __init__(self):
        self.seen = None

    def fresh(self):
        self.close()
        self.seen = bytearray()

    def one_input(self, data):
        self.seen += data[:1]

    def close(self):
        if self.seen is not None and 0x5A in self.seen:
            raise RuntimeError("close found what an input left")
        self.seen = None


def target():
    return World()
'''


def test_a_stateful_target_failing_as_its_world_is_made_fresh_is_a_finding_that_replays(tmp_path):
    """Before, an exception in `fresh()` (here its close of the world the last inputs left) killed the fuzzing
    child with no finding saved (the child exit 77, `aspod fuzz` exit 2)."""
    pytest.importorskip("atheris")
    (tmp_path / "closes_badly.py").write_text(CLOSES_BADLY)
    done = aspod("fuzz", "closes_badly.py:target", "--runs", "20000", "--no-progress", "--findings", "found",
                 cwd=tmp_path)
    found = sorted((tmp_path / "found").glob("*.json"))
    assert done.returncode == 1 and len(found) == 1, done.stderr[-2000:]
    finding = findings.load(found[0])
    assert "close found what an input left" in finding.failure.error and any(
        i[:1] == b"Z" for i in finding.inputs), finding
    again = aspod("fuzz", "--replay", str(found[0]), "closes_badly.py:target", cwd=tmp_path)
    assert again.returncode == 1 and "close found what an input left" in again.stdout + again.stderr, again
