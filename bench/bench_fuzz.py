"""Fuzzing: how fast each engine runs, and `aspod fuzz` beside boofuzz on the same live target.

1. **In process.** Each built-in target under atheris for 10 s (3 s with --quick), one job on one core:
   executions per second, libFuzzer's coverage (edges) and corpus.
   **Per CPU-second.** `controller-link` beside its peer, a bare loop: the same child, harness and libFuzzer
   with a target that does nothing (`bare_target`). Each runs twice from an empty corpus with one seed, to N1
   and to N2 executions; the difference of the child's CPU times over N2 - N1 is the cost of an execution,
   the start (imports, instrumenting, the first world) left out. One seed keeps two versions of the code
   comparable, not equal: a target that keeps its world between inputs does not repeat a run exactly, so the
   difference is the cost of about N2 - N1 executions, and a row is worth running more than once.
2. **Black-box over a pty.** `aspod fuzz --target-cmd 'aspod sim --pty ...'` for 20 s (8 s) at --no-pacing and
   at 115200 baud: cases and steps per second (each case is a few steps; a health check of two commands comes
   every 16 cases, or sooner when the target's behaviour changes).
3. **Beside boofuzz.** The same unpaced TCP target for both, one after the other, never together: `aspod fuzz`
   black-box with its grammar from the declaration, and boofuzz 0.4.2 with the best grammar written for it by hand
   (bench/boofuzz_peer.py). First the real simulator (`aspod sim --no-pacing`), 30 s each (10 s with --quick):
   cases per second, side by side, and their ratio. Then the planted simulator (host_tools/fuzz/planted.py:
   BoxDial at exactly 100 % crashes the controller), 60 s each (20 s): whether and when each found the bug, cases
   per second over the whole run and, for `aspod fuzz`, over the time it ran cases (pinning each finding to its
   case and shrinking it on fresh targets left out).
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

from bench import PartsResult, run_parts
from protocol import auth

_ROOT = Path(__file__).resolve().parents[1]
ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
TARGETS = ("frames", "codec", "controller-link", "host-link", "hal", "params-file", "key-file", "teleop")


def _load() -> str:
    return "load %.1f" % os.getloadavg()[0]


def in_process(tmp: Path, quick: bool) -> list[str]:
    seconds = 3 if quick else 10
    done = subprocess.run([*ASPOD, "fuzz", *TARGETS, "--time", str(seconds), "--serial", "--json", "--no-progress",
                           "--corpus", str(tmp / "corpus"), "--findings", str(tmp / "found")],
                          capture_output=True, text=True, timeout=60 * len(TARGETS) + 120, cwd=tmp)
    if done.returncode not in (0, 1):
        raise RuntimeError(done.stderr[-800:])
    lines = [f"in process, atheris, one core, {seconds} s per target ({_load()}):",
             f"  {'target':17} {'exec/s':>8} {'executions':>11} {'cov':>5} {'corpus':>6} findings"]
    for s in json.loads(done.stdout)["targets"]:
        lines.append(f"  {s['target']:17} {s['execs_per_core_s']:8,.0f} {s['execs']:11,} {s['cov']:5} {s['corpus']:6} "
                     f"{s['findings']}")
    return lines


class _Bare:
    """The peer of the per-CPU-second row: a target that does nothing with its input."""
    name = "bare"

    def one_input(self, data: bytes) -> None:
        pass


def bare_target() -> _Bare:
    return _Bare()


def _child_cpu_s(tmp: Path, target: str, runs: int) -> float:
    """CPU seconds (user + system) of one fuzzing child run to `runs` executions from an empty corpus, seed 1."""
    run = tmp / f"cpu-{target.replace(':', '_')}-{runs}"
    (run / "corpus").mkdir(parents=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([sys.executable, "-m", "host_tools.fuzz.child", target, str(run / "found"), "10",
                           "-seed=1", "-max_len=4096", f"-runs={runs}", str(run / "corpus")],
                          capture_output=True, text=True, timeout=600, cwd=tmp,
                          env=dict(os.environ, PYTHONPATH=str(_ROOT)))     # `bench` is not installed: its folder
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{target}: the fuzzing child exited with {done.returncode}: {done.stderr[-800:]}")
    return after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime


def per_cpu_second(tmp: Path, quick: bool) -> list[str]:
    rows = (("controller-link", 500, 2500 if quick else 5500), ("bench.bench_fuzz:bare_target", 1000, 201000))
    lines = [f"in process, executions per CPU-second between N1 and N2 executions, seed 1, empty corpus ({_load()}):"]
    rates = {}
    for target, n1, n2 in rows:
        cpu = _child_cpu_s(tmp, target, n2) - _child_cpu_s(tmp, target, n1)
        rates[target] = (n2 - n1) / cpu
        lines.append(f"  {target:29} N1 {n1:7,} N2 {n2:7,} {cpu:6.2f} CPU s {rates[target]:9,.0f} exec/CPU-s")
    bare = rates["bench.bench_fuzz:bare_target"]
    lines.append(f"  controller-link: 1/{bare / rates['controller-link']:,.0f} of the bare loop ({_load()})")
    return lines


def _key(tmp: Path) -> Path:
    key = tmp / "link.key"
    if not key.exists():
        auth.write_key(key, bytes(range(32)))
    return key


def _blackbox(tmp: Path, module: str, port: str, seconds: float, pacing: bool, extra=()) -> dict:
    key = _key(tmp)
    target = [sys.executable, "-m", module, "sim", port, "--key-file", str(key), "--no-control",
              "--params", str(tmp / "params.json")] + ([] if pacing else ["--no-pacing"])
    done = subprocess.run([*ASPOD, "fuzz", "--target-cmd", " ".join(target), "--key-file", str(key), "--time",
                           str(seconds), "--json", "--no-progress", "--findings", str(tmp / "bb-found"), *extra],
                          capture_output=True, text=True, timeout=seconds * 4 + 300, cwd=tmp,
                          env=dict(os.environ, XDG_CONFIG_HOME=str(tmp)))
    if done.returncode not in (0, 1):
        raise RuntimeError(done.stderr[-800:])
    return json.loads(done.stdout)


def black_box(tmp: Path, quick: bool) -> list[str]:
    seconds = 8 if quick else 20
    lines = [f"black-box over a pty, {seconds} s each:"]
    for pacing, what in ((False, "--no-pacing"), (True, "115200 baud")):
        r = _blackbox(tmp, "host_tools.cli.main", "--pty", seconds, pacing)
        lines.append(f"  {what:12} {r['cases_per_s']:6.1f} cases/s, {r['steps'] / r['wall_s']:6.1f} steps/s "
                     f"({r['cases']} cases, {len(r['findings'])} findings; {_load()})")
    return lines


def beside_boofuzz(tmp: Path, quick: bool) -> list[str]:
    from bench.boofuzz_peer import run_boofuzz
    seconds = 10 if quick else 30
    lines = [f"the real simulator over TCP at --no-pacing, {seconds} s each:"]
    r = _blackbox(tmp, "host_tools.cli.main", "--tcp=0", seconds, False)
    b = run_boofuzz(tmp / "boofuzz-real", seconds, planted=False)
    lines.append(f"  aspod fuzz  {r['cases_per_s']:6.1f} cases/s ({r['cases']} cases, {r['checks']} health checks, "
                 f"{len(r['findings'])} findings; {_load()})")
    lines.append(f"  boofuzz     {b.cases_per_s:6.1f} cases/s ({b.cases} cases; {_load()})")
    lines.append(f"  aspod fuzz / boofuzz: {r['cases_per_s'] / b.cases_per_s:.2f}" if b.cases_per_s else
                 "  boofuzz ran no case")
    seconds = 20 if quick else 60
    lines.append(f"the planted BoxDial crash over TCP at --no-pacing, {seconds} s each:")
    r = _blackbox(tmp, "host_tools.fuzz.planted", "--tcp=0", seconds, False)
    crashes = [f for f in r["findings"] if Path(f).name.startswith("crash-")]
    first = json.loads((tmp / crashes[0]).read_text()) if crashes else None
    lines.append(f"  aspod fuzz  {r['cases_per_s']:6.1f} cases/s ({r['fuzzing_cases_per_s']:.1f} running cases); "
                 "planted bug " + (f"found after {first['execs']} cases, {first['count']} times, one file, "
                                   f"{len(first['steps'])} step{'s' if len(first['steps']) > 1 else ''}"
                                   if first else "not found") + f" ({r['cases']} cases; {_load()})")
    b = run_boofuzz(tmp / "boofuzz", seconds, planted=True)
    lines.append(f"  boofuzz     {b.cases_per_s:6.1f} cases/s; planted bug "
                 + (f"found after {b.found_after_cases} cases" if b.found else "not found") + f" ({b.cases} cases; "
                 f"{_load()})")
    return lines


def main(quick: bool = False) -> PartsResult:
    return run_parts("fuzz: in-process targets, black-box over a pty, beside boofuzz",
                     (per_cpu_second, in_process, black_box, beside_boofuzz), quick, "aspod-bench-fuzz-")


if __name__ == "__main__":
    sys.exit(1 if main(quick="--quick" in sys.argv).error else 0)
