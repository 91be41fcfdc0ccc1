"""A light start: what `aspod` costs before it does anything, and what its long-lived children hold.

1. **The command line.** `aspod --version`, `aspod --help` and `aspod sim --help` beside a bare `python -c pass`
   of the same interpreter, run in turn, many times (as hyperfine does, from here): the CPU time of each (user +
   system, from the kernel's accounting of the child), its median and its best, and the ratio to `python -c
   pass`'s. Goal: `aspod --version` at most 2x. Also the modules each leaves imported, and whether numpy, the
   plant or pandas is among them (goal: none).
2. **`aspod sim` to its ready line.** Started as a user starts it (`aspod sim`: a pty, the sun now), stopped at
   its last ready line (`ASPOD-CONTROL`): its CPU time and peak RSS then, read from /proc. Goals: 0.6 s and
   120 MiB. With numba installed, the same with `ASPOD_COMPILED=1`, its machine code loaded from numba's cache.
3. **Long-lived children.** A fuzzing job (the atheris child `aspod fuzz` starts, `python -m
   host_tools.fuzz.child`, on `controller-link` and on `hal`, the target that builds the plant) run for a number
   of executions: its peak RSS. A campaign worker (a Dask worker of a local cluster) after two bench runs of
   12 simulated s: its peak RSS, and which heavy libraries it holds. Goal: 150 MiB each.
4. **numba's cache.** Something that compiles, twice, with a fresh `NUMBA_CACHE_DIR`: `ASPOD_COMPILED=1 aspod
   bench` of a short script (the joints' and the arm plant's kernels) beside the same without the switch, and
   `aspod plan --method reach --order 2` (the planner's passes). The first run compiles, the second loads.

Every child runs with Python's bytecode cache on (PYTHONDONTWRITEBYTECODE removed from its environment), after a
first run that writes it, as a user's second command would.
"""
from __future__ import annotations

import json
import os
import signal
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Optional, Sequence

from bench import PartsResult, run_parts
from timebase import RealClock

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
ASPOD = str(BIN / "aspod")
PYTHON = sys.executable
MIB = 1024.0
HEAVY = ("numpy", "hil_sim.plant", "firmware_py.controller", "pandas", "pvlib", "scipy", "numba")
# Run inside a child: `main(argv)`, then which modules it left imported (argparse's exit caught).
MODULES_AFTER = ("import json, sys\nfrom host_tools.cli.main import main\ntry:\n    main(sys.argv[1:])\n"
                 "except SystemExit:\n    pass\nprint(json.dumps({'count': len(sys.modules), 'heavy': [m for m in "
                 f"{HEAVY!r} if m in sys.modules]}}), file=sys.stderr)\n")
SHORT_BENCH = "enable\nmoveby j1 5 2\nwait\nstatus\n"


def child_env(**extra: str) -> dict[str, str]:
    """The environment a user's command has: bytecode written and read (this bench's may say otherwise)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(extra)
    return env


def run_child(argv: Sequence[str], env: Optional[dict[str, str]] = None, cwd: Optional[Path] = None
              ) -> tuple[float, float, float, int]:
    """(CPU s, wall s, peak RSS MiB, exit status) of one run of `argv`, output discarded."""
    wall0 = RealClock.precise_now()
    child = subprocess.Popen(list(argv), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env or child_env(),
                             cwd=cwd or ROOT)
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    return (usage.ru_utime + usage.ru_stime, RealClock.precise_now() - wall0, usage.ru_maxrss / MIB,
            child.returncode)


def _load() -> str:
    return f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores"


def command_line(folder: Path, quick: bool) -> list[str]:
    rounds = 10 if quick else 40
    commands = {"python -c pass": [PYTHON, "-c", "pass"], "aspod --version": [ASPOD, "--version"],
                "aspod --help": [ASPOD, "--help"], "aspod sim --help": [ASPOD, "sim", "--help"]}
    for argv in commands.values():                         # bytecode written; files in the page cache
        run_child(argv)
    cpu: dict[str, list[float]] = {name: [] for name in commands}
    wall: dict[str, list[float]] = {name: [] for name in commands}
    load0 = _load()
    for _ in range(rounds):                                # in turn, so that the machine's load falls on each alike
        for name, argv in commands.items():
            c, w, _, status = run_child(argv)
            if status != 0:
                raise RuntimeError(f"{name} exited {status}")
            cpu[name].append(c)
            wall[name].append(w)
    base = statistics.median(cpu["python -c pass"])
    base_best = min(cpu["python -c pass"])
    lines = [f"  {rounds} rounds, each command once a round; CPU time (user + system) of the child; {load0} before, "
             f"{_load()} after"]
    for name in commands:
        med, best = statistics.median(cpu[name]), min(cpu[name])
        ratio = "" if name == "python -c pass" else \
            f"  {med / base:.2f}x python -c pass (best {best / base_best:.2f}x)"
        lines.append(f"  {name:<17} CPU median {med * 1000:6.1f} ms, best {best * 1000:6.1f} ms; wall median "
                     f"{statistics.median(wall[name]) * 1000:6.1f} ms{ratio}")
    goal = statistics.median(cpu["aspod --version"]) / base
    lines.append(f"  aspod --version / python -c pass: {goal:.2f}x (goal 2x: {'met' if goal <= 2.0 else 'NOT met'})")
    for argv in (["--version"], ["--help"], ["sim", "--help"]):
        probe = subprocess.run([PYTHON, "-c", MODULES_AFTER, *argv], capture_output=True, text=True, env=child_env(),
                               cwd=ROOT)
        found = json.loads(probe.stderr.strip().splitlines()[-1])
        lines.append(f"  aspod {' '.join(argv)}: {found['count']} modules imported; "
                     f"{', '.join(found['heavy']) if found['heavy'] else 'none'} of {', '.join(HEAVY)}")
    return ["command line: aspod beside a bare python -c pass"] + lines


def _cpu_and_peak(pid: int) -> tuple[float, float]:
    """(CPU s so far, peak RSS MiB) of a running process, from /proc."""
    with open(f"/proc/{pid}/stat") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    peak = 0.0
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmHWM:"):
                peak = int(line.split()[1]) / MIB
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK"), peak


def sim_to_ready(env: dict[str, str]) -> tuple[float, float, float]:
    """(CPU s, peak RSS MiB, wall s) of `aspod sim` at its last ready line."""
    wall0 = RealClock.precise_now()
    with subprocess.Popen([ASPOD, "sim"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env,
                          cwd=ROOT) as child:
        try:
            for line in child.stdout:
                if line.startswith("ASPOD-CONTROL"):
                    break
            else:
                raise RuntimeError(f"aspod sim ended before its ready lines (exit {child.wait()})")
            wall = RealClock.precise_now() - wall0
            cpu, peak = _cpu_and_peak(child.pid)
        finally:
            child.send_signal(signal.SIGTERM)
            child.wait()
    return cpu, peak, wall


def sim_start(folder: Path, quick: bool) -> list[str]:
    runs = 3 if quick else 9
    cases = [("aspod sim", child_env(ASPOD_COMPILED="0"))]
    if _numba_installed():
        cases.append(("ASPOD_COMPILED=1 aspod sim (numba's cache warm)", child_env(ASPOD_COMPILED="1")))
    lines = [f"  {runs} starts each, stopped at ASPOD-CONTROL, after one that warms the caches; {_load()}"]
    for name, env in cases:
        sim_to_ready(env)
        got = [sim_to_ready(env) for _ in range(runs)]
        cpu = statistics.median(g[0] for g in got)
        peak = max(g[1] for g in got)
        lines.append(f"  {name}: CPU median {cpu:.2f} s (best {min(g[0] for g in got):.2f}), peak RSS {peak:.0f} MiB "
                     f"(largest of the starts), wall median {statistics.median(g[2] for g in got):.2f} s"
                     + ("" if "COMPILED=1" in name else
                        f"; goals 0.6 s: {'met' if cpu <= 0.6 else 'NOT met'}, 120 MiB: "
                        f"{'met' if peak <= 120 else 'NOT met'}"))
    return ["aspod sim to its ready line"] + lines


def _fuzz_job_peak(folder: Path, target: str, runs: int) -> tuple[float, float]:
    from host_tools.fuzz.inprocess import JobSettings, child_command
    job = JobSettings(target, folder / "corpus" / target, folder / "findings", seconds=None, runs=runs)
    cpu, _, peak, status = run_child(child_command(job), env=child_env(PYTHONUNBUFFERED="1"))
    if status != 0:
        raise RuntimeError(f"the fuzzing job on {target} exited {status}")
    return cpu, peak


def _worker_peak() -> tuple[float, list[str]]:
    """Run in a Dask worker: its peak RSS (MiB) and the heavy libraries it has imported."""
    import resource
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / MIB,
            [m for m in ("pandas", "pvlib", "scipy", "numba", "matplotlib", "pyarrow") if m in sys.modules])


def children(folder: Path, quick: bool) -> list[str]:
    runs = 500 if quick else 5000
    lines = []
    for target in ("controller-link", "hal"):
        cpu, peak = _fuzz_job_peak(folder, target, runs)
        lines.append(f"  fuzzing job, {target}, {runs} executions: peak RSS {peak:.0f} MiB (CPU {cpu:.1f} s); goal "
                     f"150 MiB: {'met' if peak <= 150 else 'NOT met'}")
    from distributed import Client, LocalCluster

    from bench.bench_campaign import MOVING, _runs
    from host_tools.campaign.runs import run_one
    bench, matrix = _runs(MOVING, 2, folder)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=50) as cluster, Client(cluster) as client:
        idle, _ = next(iter(client.run(_worker_peak).values()))
        for run in matrix:
            if not client.submit(run_one, bench, run, pure=False).result().row["ok"]:
                raise RuntimeError("a campaign run failed")
        peak, held = next(iter(client.run(_worker_peak).values()))
    lines.append(f"  campaign worker (Dask, 1 of a local cluster) after {len(matrix)} runs of 12 simulated s: peak RSS "
                 f"{peak:.0f} MiB ({idle:.0f} MiB before the first run), holding "
                 f"{', '.join(held) if held else 'none'} of pandas, pvlib, scipy, numba, matplotlib, pyarrow; goal "
                 f"150 MiB: {'met' if peak <= 150 else 'NOT met'}")
    return ["long-lived children: peak RSS"] + lines


def _numba_installed() -> bool:
    import importlib.util
    return importlib.util.find_spec("numba") is not None


def numba_cache(folder: Path, quick: bool) -> list[str]:
    if not _numba_installed():
        return ["numba's cache: numba is not installed (pip install 'aspod[compiled]'): nothing compiles"]
    script = folder / "short.aspod"
    script.write_text(SHORT_BENCH)
    cache = folder / "numba-cache"
    cases = [("ASPOD_COMPILED=0 aspod bench (plain Python, the reference)", [ASPOD, "bench", str(script)],
              child_env(ASPOD_COMPILED="0")),
             ("ASPOD_COMPILED=1 aspod bench (joints' and arm plant's kernels)", [ASPOD, "bench", str(script)],
              child_env(ASPOD_COMPILED="1", NUMBA_CACHE_DIR=str(cache))),
             ("aspod plan --method reach --order 2 --nodes 99 (the planner's passes)",
              [ASPOD, "plan", "--method", "reach", "--order", "2", "--nodes", "99", "--objective", "time"],
              child_env(NUMBA_CACHE_DIR=str(cache)))]
    lines = [f"  a fresh NUMBA_CACHE_DIR for this run ({_load()}); each command run twice in a row"]
    for name, argv, env in cases:
        got = []
        for _ in range(2):
            cpu, wall, peak, status = run_child(argv, env=env)
            if status != 0:
                raise RuntimeError(f"{name} exited {status}")
            got.append((cpu, wall, peak))
        (c1, w1, p1), (c2, w2, p2) = got
        lines.append(f"  {name}: first CPU {c1:.2f} s (wall {w1:.2f}), second CPU {c2:.2f} s (wall {w2:.2f}); "
                     f"peak RSS {p1:.0f} / {p2:.0f} MiB")
    entries = sorted(p.name for p in cache.rglob("*.nbi"))
    lines.append(f"  cached index files: {', '.join(entries) or 'none'}")
    return ["numba's cache: the first run compiles, the second loads"] + lines


def main(quick: bool = False) -> PartsResult:
    return run_parts("start: the command line, aspod sim to ready, long-lived children, numba's cache",
                     (command_line, sim_start, children, numba_cache), quick, "aspod-bench-start-")


if __name__ == "__main__":
    sys.exit(1 if main(quick="--quick" in sys.argv).error else 0)
