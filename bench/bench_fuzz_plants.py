"""Planted bugs: what each fuzzer finds, not how fast it runs (issue 38's proof).

    python -m bench --only fuzz-plants [--quick]          (also part of --only fuzz)
    python -m bench.bench_fuzz_plants [--quick] [--budget S] [--plants a,b] [--fuzzers in-process,black-box,boofuzz]

Eight defects planted in copies made by bench/fuzz_plants.py (never in the real code), one of each kind the issue
names; the slow path is no bug and must not be reported. Each plant is fuzzed by each fuzzer that applies, one run
after the other, each for the budget (60 s with --quick, 10 minutes without; the issue's goal: every real bug within
10 minutes on this machine, and no false finding):

- **in process**: `aspod fuzz bench.fuzz_plants:NAME_target` (one atheris job, one core);
- **black box**: `aspod fuzz --target-cmd 'python -m bench.fuzz_plants NAME sim --tcp=0 --no-pacing ...'` to its
  first finding or the end of the budget (the host plant: `aspod fuzz --as-controller` against a planted teleop);
  a finding not the plant's ends the run as the plant's would, and is counted as false;
- **boofuzz** (bench/boofuzz_peer.py) on the same black-box plant over TCP, for the plants whose effect is a crash
  or silence, all its health check can see (and the slow path, which it must not report).

The fuzzers are run through their command lines and judged by the findings they save, so a change of their options
or of their JSON does not break this. A finding is the plant's when it no longer fails replayed against the real
code (`aspod fuzz --replay`, the in-process finding's target renamed to the real one; one finding of each kind, kind
being the failure and its error's words) in a run where the plant's defect acted; one that still fails there is the
real code's (a real bug, or a false finding), and one that does not in a run where the defect never acted is a false
finding; both are said so. "reached": the plant's defect acted at least once
in the run (each plant notes it on `$ASPOD_PLANT_LOG`), whether or not the fuzzer saw it. The seconds to find are
from the fuzzer's start (its target's start and the first session included) to the first time the defect acted, in
a run that found it; the executions are the fuzzer's own count in its finding (cases, black box).
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Optional, Sequence

from bench import PartsResult, run_parts
from bench.fuzz_plants import PLANT_LOG_ENV, PLANTS, Plant, target_factory
from protocol import auth
from timebase import RealClock

_ROOT = Path(__file__).resolve().parents[1]
ASPOD = (sys.executable, "-m", "host_tools.cli.main")
FUZZERS = ("in-process", "black-box", "boofuzz")
BUDGET_S, QUICK_BUDGET_S = 600.0, 60.0
REPLAYED_AT_MOST = 6          # kinds of finding of one run replayed against the real code
_CLOCK = RealClock()


@dataclass
class Outcome:
    """One fuzzer against one plant."""
    status: str                          # found | missed | not run | not reported | REPORTED
    execs: Optional[int] = None
    seconds: Optional[float] = None
    reached: bool = False
    note: str = ""
    others: int = 0                      # findings not the plant's: the real code's (a real bug, or false)

    def cell(self) -> str:
        if self.status in ("found", "REPORTED"):
            what = f"{self.status} {self.execs:,}" if self.execs is not None else self.status
            return what + (f" / {self.seconds:.0f} s" if self.seconds is not None else "")
        if self.status == "missed" and self.reached:
            return "missed (reached)"
        if self.status == "not reported":       # the slow path: right only if the fuzzer went there
            return "not reported" + (" (reached)" if self.reached else " (not reached)")
        return self.status


def _load() -> str:
    return "load %.1f" % os.getloadavg()[0]


def _env(tmp: Path, log: Path) -> dict:
    path = os.pathsep.join(p for p in (str(_ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return dict(os.environ, PYTHONPATH=path, XDG_CONFIG_HOME=str(tmp), **{PLANT_LOG_ENV: str(log)})


def _first_fired(log: Path, name: str) -> Optional[float]:
    """The wall time plant `name` first acted in the run that wrote `log`, None if it never did."""
    if not log.exists():
        return None
    times = [float(t) for n, t, _pid in (line.split() for line in log.read_text().splitlines() if line.strip())
             if n == name]
    return min(times) if times else None


def _findings(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.json"), key=lambda p: p.stat().st_mtime) if folder.is_dir() else []


def _replays_clean(cmd: list[str], env: dict, cwd: Path) -> Optional[bool]:
    """True: the finding no longer fails on the real code (it is the plant's); False: it still does; None: it could
    not be replayed."""
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=cwd, env=env)
    return {0: True, 1: False}.get(done.returncode)


def _signature(path: Path) -> tuple[str, str]:
    """What makes two findings of a run the same failure: the kind and the error's words, numbers left out."""
    failure = json.loads(path.read_text())["failure"]
    return failure["kind"], "".join(c for c in failure["error"][:60] if not c.isdigit())


def _judge(plant: Plant, findings: list[Path], replay: Callable[[Path], Optional[bool]], fired_s: Optional[float],
           start: float) -> Outcome:
    """The outcome of a run from its findings, grouped by signature: a group is the plant's when its first finding
    replays clean on the real code, the real code's when it still fails there."""
    reached = fired_s is not None
    groups: dict[tuple[str, str], list[Path]] = {}
    for path in findings:
        groups.setdefault(_signature(path), []).append(path)
    ours, others, unreplayed = [], [], 0
    for paths in list(groups.values())[:REPLAYED_AT_MOST]:
        clean = replay(paths[0])
        if clean is None:
            unreplayed += 1
        else:
            (ours if clean else others).append(paths)
    said = [f"{len(paths)} finding(s) failing on the real code too: {_signature(paths[0])[1].strip()}"
            for paths in others]
    if ours and not reached:         # the defect never acted: not the plant's, and not the real code's either
        said += [f"{len(paths)} finding(s) that do not fail again, the plant never having acted (false): "
                 f"{_signature(paths[0])[1].strip()}" for paths in ours]
        others, ours = others + ours, []
    if unreplayed:
        said.append(f"{unreplayed} kind(s) of finding could not be replayed")
    if len(groups) > REPLAYED_AT_MOST:
        said.append(f"{len(groups)} kinds of finding, {len(findings)} findings in all")
    others_count = sum(len(paths) for paths in others)
    if not ours:
        return Outcome("not reported" if not plant.is_bug else "missed", reached=reached, note="; ".join(said),
                       others=others_count)
    mine = [json.loads(p.read_text()) for paths in ours for p in paths]
    first = min(mine, key=lambda f: f.get("execs") or 0)
    failure = first["failure"]
    shape = (f"{len(first['steps'])} steps" if first.get("steps") else f"{len(first.get('inputs') or [])} inputs")
    said.insert(0, f"{len(mine)} finding(s): {failure['kind']}: {failure['error'][:80]}; {shape}, minimized "
                   f"{first.get('minimized')}")
    return Outcome("found" if plant.is_bug else "REPORTED", first.get("execs"), fired_s - start if reached else None,
                   reached, "; ".join(said), others_count)


def in_process(plant: Plant, run: Path, budget_s: float) -> Outcome:
    factory = target_factory(plant.name)
    if factory is None:
        return Outcome("not run", note="no in-process target")
    log, found = run / "fired.log", run / "found"
    env = _env(run, log)
    start = _CLOCK.wall_time()
    done = subprocess.run([*ASPOD, "fuzz", factory, "--time", f"{budget_s:g}", "--serial", "--json", "--no-progress",
                           "--corpus", str(run / "corpus"), "--findings", str(found)],
                          capture_output=True, text=True, timeout=budget_s * 2 + 600, cwd=run, env=env)
    figures, ran = "", False
    try:
        jobs = json.loads(done.stdout).get("jobs", [])
        ran = any(j["execs"] for j in jobs)
        figures = "; ".join(f"{j['execs']:,} execs in {j['wall_s']:.0f} s" + (f", error: {j['error'][-240:]}"
                                                                              if j.get("error") else "")
                            for j in jobs)
    except (ValueError, KeyError, TypeError):
        pass
    if done.returncode not in (0, 1):
        if not ran:                  # ran, then ended without a finding (a crash outside the harness's guard): judged
            return Outcome("not run", note=f"aspod fuzz exited {done.returncode}: {done.stderr.strip()[-300:]}")
        figures = f"aspod fuzz exited {done.returncode}; {figures}"

    def replay(path: Path) -> Optional[bool]:
        data = json.loads(path.read_text())
        data["target"] = plant.real_target
        real = run / f"real-{path.name}"
        real.write_text(json.dumps(data))
        return _replays_clean([*ASPOD, "fuzz", "--replay", str(real)], env, run)
    outcome = _judge(plant, _findings(found), replay, _first_fired(log, plant.name), start)
    outcome.note = "; ".join(n for n in (outcome.note, figures) if n)
    return outcome


def _sim(module: Sequence[str], run: Path, key: Path) -> list[str]:
    return [sys.executable, "-m", *module, "sim", "--tcp=0", "--key-file", str(key), "--no-control",
            "--params", str(run / "params.json"), "--no-pacing"]


def _cases(stdout: str) -> str:
    """The cases a black-box run's --json says it ran ("" if it says nothing readable)."""
    try:
        r = json.loads(stdout[stdout.find("{"):])      # after any line the fuzzer prints before it (ASPOD-LINK ...)
        return f"{r['cases']:,} cases in {r['wall_s']:.0f} s, {r['cases_per_s']:.1f} cases/s"
    except (ValueError, KeyError, TypeError):
        return ""


def _as_controller_built() -> bool:
    done = subprocess.run([*ASPOD, "fuzz", "--help"], capture_output=True, text=True, timeout=120)
    return "--as-controller" in done.stdout and "--host-cmd" in done.stdout


def _teleop(module: Sequence[str], run: Path, budget_s: float) -> str:
    """A teleop host for the hostile controller to connect: a script that asks the status again as soon as it is
    answered, for longer than the budget, and shows every event as it comes. A case whose steps change the host's
    next replies waits (at most 0.5 s) for its next command: asked once a second, the host ran 2.6 cases/s."""
    script = run / "host.teleop"
    script.write_text("status\n" * int(200 * (budget_s + 60)))
    return shlex.join([sys.executable, "-m", *module, "teleop", "{url}", "--key-file", "{key}", "--script",
                       str(script), "--keep-going"])


def as_controller(plant: Plant, run: Path, budget_s: float) -> Outcome:
    """`aspod fuzz --as-controller --host-cmd` against a planted teleop (`{url}` and `{key}` filled in by the fuzzer)."""
    if not _as_controller_built():
        return Outcome("not run", note="--as-controller not built")
    log, found = run / "fired.log", run / "found"
    env = _env(run, log)
    start = _CLOCK.wall_time()
    done = subprocess.run([*ASPOD, "fuzz", "--as-controller", "--host-cmd",
                           _teleop(("bench.fuzz_plants", plant.name), run, budget_s), "--time", f"{budget_s:g}",
                           "--max-findings", "1",
                           "--json", "--no-progress", "--findings", str(found)],
                          capture_output=True, text=True, timeout=budget_s * 2 + 600, cwd=run, env=env)
    if done.returncode not in (0, 1):
        return Outcome("not run", note=f"aspod fuzz exited {done.returncode}: {done.stderr.strip()[-300:]}")
    real = _teleop(("host_tools.cli.main",), run, budget_s)

    def replay(path: Path) -> Optional[bool]:
        return _replays_clean([*ASPOD, "fuzz", "--as-controller", "--replay", str(path), "--host-cmd", real], env, run)
    outcome = _judge(plant, _findings(found), replay, _first_fired(log, plant.name), start)
    outcome.note = "; ".join(n for n in (outcome.note, _cases(done.stdout)) if n)
    return outcome


def black_box(plant: Plant, run: Path, budget_s: float) -> Outcome:
    if plant.black_box != "sim":
        return as_controller(plant, run, budget_s)
    key, log, found = run / "link.key", run / "fired.log", run / "found"
    auth.write_key(key, bytes(range(32)))
    env = _env(run, log)
    target = _sim(("bench.fuzz_plants", plant.name), run, key)
    start = _CLOCK.wall_time()
    done = subprocess.run([*ASPOD, "fuzz", "--target-cmd", shlex.join(target), "--key-file", str(key), "--time",
                           f"{budget_s:g}", "--max-findings", "1", "--json", "--no-progress", "--findings", str(found)],
                          capture_output=True, text=True, timeout=budget_s * 2 + 600, cwd=run, env=env)
    if done.returncode not in (0, 1):
        return Outcome("not run", note=f"aspod fuzz exited {done.returncode}: {done.stderr.strip()[-300:]}")
    figures = _cases(done.stdout)
    real = shlex.join(_sim(("host_tools.cli.main",), run, key))

    def replay(path: Path) -> Optional[bool]:
        return _replays_clean([*ASPOD, "fuzz", "--replay", str(path), "--target-cmd", real, "--key-file", str(key)],
                              env, run)
    outcome = _judge(plant, _findings(found), replay, _first_fired(log, plant.name), start)
    outcome.note = "; ".join(n for n in (outcome.note, figures) if n)
    return outcome


def boofuzz(plant: Plant, run: Path, budget_s: float) -> Outcome:
    if plant.black_box != "sim":
        return Outcome("n/a", note="boofuzz plays a host, not a controller")
    if not plant.crashes:
        return Outcome("n/a", note="its health check sees a crash or silence only")
    from bench.boofuzz_peer import run_boofuzz
    log = run / "fired.log"
    before = os.environ.get(PLANT_LOG_ENV)
    os.environ[PLANT_LOG_ENV] = str(log)          # boofuzz_peer starts its target with this process's environment
    try:
        start = _CLOCK.wall_time()
        b = run_boofuzz(run / "boofuzz", budget_s, planted=True,
                        command=(sys.executable, "-m", "bench.fuzz_plants", plant.name))
    finally:
        if before is None:
            os.environ.pop(PLANT_LOG_ENV, None)
        else:
            os.environ[PLANT_LOG_ENV] = before
    fired_s = _first_fired(log, plant.name)
    figures = f"{b.cases:,} cases in {b.wall_s:.0f} s, {b.cases_per_s:.1f} cases/s"
    if not b.found:
        return Outcome("missed" if plant.is_bug else "not reported", reached=fired_s is not None, note=figures)
    ours = fired_s is not None if plant.is_bug else True
    status = ("found" if ours else "missed") if plant.is_bug else "REPORTED"
    why = next((n for n in b.notes if n.startswith("found:")), "")
    return Outcome(status, b.found_after_cases, fired_s - start if fired_s is not None else None, fired_s is not None,
                   "; ".join(n for n in (why[:160], figures, "" if ours else "a death not the plant's") if n))


RUNNERS = {"in-process": in_process, "black-box": black_box, "boofuzz": boofuzz}


def _commit() -> str:
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], capture_output=True, text=True, cwd=_ROOT).stdout.strip()
    return git("rev-parse", "--short", "HEAD") + (" (with changes)" if git("status", "--porcelain", "-uno") else "")


def plants_table(tmp: Path, budget_s: float, plants: Sequence[str], fuzzers: Sequence[str]) -> Iterator[str]:
    yield (f"conditions: budget {budget_s:g} s per fuzzer and plant, one run each, one after the other; commit "
           f"{_commit()}; {os.cpu_count()} cores, {_load()} at the start; this process at nice {os.nice(0)}")
    results: dict[tuple[str, str], Outcome] = {}
    for name in plants:
        plant = PLANTS[name]
        for fuzzer in fuzzers:
            run = tmp / f"{name}-{fuzzer}"
            run.mkdir(parents=True)
            load_before = _load()
            try:
                outcome = RUNNERS[fuzzer](plant, run, budget_s)
            except Exception as exc:      # one run that cannot run does not stop the others
                outcome = Outcome("not run", note=f"{type(exc).__name__}: {exc}"[:300])
            results[(name, fuzzer)] = outcome
            yield (f"  {name:14} {fuzzer:10} {outcome.cell():24} "
                   f"({load_before} before, {_load()} after{'; ' + outcome.note if outcome.note else ''})")
    yield ""
    yield "found: executions (cases, black box) / seconds to find; 'reached': the defect acted, unseen"
    yield f"  {'plant':14} {'kind':37} " + " ".join(f"{f:24}" for f in fuzzers)
    for name in plants:
        yield (f"  {name:14} {PLANTS[name].kind:37} "
               + " ".join(f"{results[(name, f)].cell():24}" for f in fuzzers))
    bugs = [n for n in plants if PLANTS[n].is_bug]
    for fuzzer in fuzzers:
        ran = [n for n in bugs if results[(n, fuzzer)].status in ("found", "missed")]
        found = [n for n in ran if results[(n, fuzzer)].status == "found"]
        false = [n for n in plants if results[(n, fuzzer)].status == "REPORTED"]
        others = [n for n in plants if results[(n, fuzzer)].others]
        yield (f"  {fuzzer}: {len(found)} of the {len(ran)} bugs it ran against found within {budget_s:g} s; "
               f"{len(false)} false finding(s) on the slow path; findings not the plant's (false, or the real "
               f"code's) in {len(others)} of its runs")


def main(quick: bool = False, budget_s: Optional[float] = None, plants: Sequence[str] = tuple(PLANTS),
         fuzzers: Sequence[str] = FUZZERS) -> PartsResult:
    budget = budget_s if budget_s is not None else QUICK_BUDGET_S if quick else BUDGET_S

    def planted_bugs(tmp: Path, _quick: bool) -> Iterator[str]:
        return plants_table(tmp, budget, plants, fuzzers)
    return run_parts("fuzz: planted bugs, found or missed by each fuzzer (bench/fuzz_plants.py)", (planted_bugs,),
                     quick, "aspod-bench-plants-")


def _names(text: str, allowed: Sequence[str]) -> list[str]:
    names = [n for n in text.split(",") if n]
    unknown = [n for n in names if n not in allowed]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"{','.join(unknown) or text!r}: choose from {','.join(allowed)}")
    return names


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python -m bench.bench_fuzz_plants", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help=f"{QUICK_BUDGET_S:g} s per fuzzer and plant")
    parser.add_argument("--budget", type=float, default=None, metavar="S", help="seconds per fuzzer and plant")
    parser.add_argument("--plants", type=lambda t: _names(t, tuple(PLANTS)), default=list(PLANTS))
    parser.add_argument("--fuzzers", type=lambda t: _names(t, FUZZERS), default=list(FUZZERS))
    args = parser.parse_args()
    sys.exit(1 if main(args.quick, args.budget, args.plants, args.fuzzers).error else 0)
