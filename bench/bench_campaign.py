"""Campaigns and targets: what Dask gives a campaign, and one bench on the lock-step world beside a live `aspod sim`.

1. **Throughput.** A campaign of moving runs (a teleop script: enable, a joint jogged and moved, 12 simulated s
   each) on a Dask local cluster of 1 worker and of 2 workers: simulated seconds per wall second summed over
   the workers, from the first task given to the last row back (the cluster's start-up shown apart), beside
   the same runs in this process without Dask, whose rows must be the same. Goal: 2 workers at least 1.8x one. On a 2-core machine the second worker shares the cores with this process,
   the Dask scheduler and whatever else runs.
2. **Engine overhead.** The same short runs (a script of one `status`: a world built, a session opened, one
   command) through Dask's 2 workers and through a bare `concurrent.futures.ProcessPoolExecutor` of 2: the
   wall time per run of each and the difference, Dask's cost per run.
3. **Lock-step against live.** One bench script (two moves and a status) by `aspod bench --json` on the
   lock-step world and by `aspod teleop --script --json` against `aspod sim --pty`: the wall time of each, and
   whether they agree (every line's outcome, every motion's end, the final positions within 0.05 deg).
"""
from __future__ import annotations

import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from bench import PartsResult, run_parts
from timebase import RealClock
from host_tools.campaign.matrix import GridAxis, Matrix, parse_seeds
from host_tools.campaign.runs import BenchSpec, run_one
from host_tools.worlds.child import Child, run

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
MOVING = "enable\njog j2 ${speed}\nwait 4\nstop\nmoveby j1 3 3\nwait\nwait 4\n"
SHORT = "status\n"
AGREE = "enable\nmoveby j1 5 3\nwait\nmoveby j2 -3 3\nwait\nstatus\n"


def _runs(script: str, count: int, cwd: Path):
    axes = (GridAxis.parse("speed=1,2"),) if "${speed}" in script else ()
    seeds = parse_seeds(str(count // 2 if axes else count))
    return BenchSpec("script", "bench.aspod", text=script, cwd=str(cwd)), Matrix(axes, (), seeds).runs()


def _dask_wall(bench: BenchSpec, runs, workers: int) -> tuple[float, list, float]:
    """(wall s from the first task given to the last result back, the results, the cluster's start-up s), on a
    local cluster whose workers have each run one warm-up run first (their imports, numba's compilation)."""
    from distributed import Client, LocalCluster, wait
    wall0 = RealClock.precise_now()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=50) as cluster, Client(cluster) as client:
        for address in client.scheduler_info()["workers"]:
            wait(client.submit(run_one, bench, runs[0], workers=[address], pure=False))
        startup = RealClock.precise_now() - wall0
        wall0 = RealClock.precise_now()
        results = client.gather(client.map(run_one, [bench] * len(runs), runs, pure=False))
        return RealClock.precise_now() - wall0, results, startup


def throughput(folder: Path, quick: bool) -> list[str]:
    bench, runs = _runs(MOVING, 8 if quick else 24, folder)
    lines, rates = [], {}
    for workers in (1, 2):
        wall, results, startup = _dask_wall(bench, runs, workers)
        sim = sum(r.row["sim_s"] for r in results)
        bad = [r.row for r in results if not r.row["ok"]]
        if bad:
            raise RuntimeError(f"a run failed: {bad[0]['error']}")
        rates[workers] = sim / wall
        lines.append(f"  {workers} worker{'s' if workers > 1 else ' '}: {len(runs)} runs, {sim:.0f} simulated s in "
                     f"{wall:.1f} wall s: {sim / wall:.1f} simulated s per wall s (start-up and warm-up "
                     f"{startup:.1f} s apart)")
    wall0 = RealClock.precise_now()
    serial = [run_one(bench, run) for run in runs]          # the peer: the same runs in this process, no engine
    wall = RealClock.precise_now() - wall0
    if [r.row for r in serial] != [r.row for r in results]:
        raise RuntimeError("the serial rows differ from Dask's")
    lines.append(f"  serial, in this process (no Dask): {sum(r.row['sim_s'] for r in serial) / wall:.1f} simulated s "
                 f"per wall s; the same rows as Dask's")
    lines.append(f"  2 workers / 1: {rates[2] / rates[1]:.2f}x (goal 1.8x); 2 workers / serial "
                 f"{rates[2] * wall / sum(r.row['sim_s'] for r in serial):.2f}x; cores {os.cpu_count()}, load average "
                 f"{os.getloadavg()[0]:.2f}")
    return ["throughput: moving runs (a jog and a move, 12 simulated s each) on a Dask local cluster"] + lines


def overhead(folder: Path, quick: bool) -> list[str]:
    bench, runs = _runs(SHORT, 20 if quick else 60, folder)
    with ProcessPoolExecutor(2) as pool:
        list(pool.map(run_one, [bench] * 4, runs[:4]))            # warm: the workers' imports
        wall0 = RealClock.precise_now()
        results = list(pool.map(run_one, [bench] * len(runs), runs))
        pool_wall = RealClock.precise_now() - wall0
    dask_wall, dask_results, _ = _dask_wall(bench, runs, 2)
    if [r.row for r in results] != [r.row for r in dask_results]:
        raise RuntimeError("the process pool's rows and Dask's differ")
    per_pool, per_dask = pool_wall / len(runs) * 1e3, dask_wall / len(runs) * 1e3
    return ["engine overhead: short runs (one `status` each: a world built, a session, one command), 2 warm workers",
            f"  ProcessPoolExecutor: {per_pool:.1f} ms per run; Dask: {per_dask:.1f} ms per run; Dask's cost "
            f"{per_dask - per_pool:+.1f} ms per run ({per_dask / per_pool:.2f}x); the same rows from both"]


def lockstep_against_live(folder: Path, quick: bool) -> list[str]:
    script = folder / "agree.aspod"
    script.write_text(AGREE)
    wall0 = RealClock.precise_now()
    done = run([*ASPOD, "bench", str(script), "--json", "--no-tracker"], text=True, timeout_s=300)
    lockstep_wall = RealClock.precise_now() - wall0
    lockstep = json.loads(done.stdout)
    env = {**os.environ, "XDG_CONFIG_HOME": str(folder / "config")}      # a parameter file of its own
    child = Child(["sim", "--pty", "--no-tracker"], env=env)
    try:
        url = child.ready("ASPOD-LINK ").split(" ", 1)[1]
        child.ready("ASPOD-KEY ")
        wall0 = RealClock.precise_now()
        done = run([*ASPOD, "teleop", url, "--script", str(script), "--json"], env=env, text=True, timeout_s=300,
                   peers=(child.pid,))
        live_wall = RealClock.precise_now() - wall0
    finally:
        child.stop()
    live = json.loads(done.stdout)
    same_steps = [s["ok"] for s in lockstep["steps"]] == [s["ok"] for s in live["steps"]]
    ends = [(m["axis"], m["outcome"]) for m in lockstep["motions"]] == [(m["axis"], m["outcome"])
                                                                        for m in live["motions"]]
    worst = max(abs(a["position"] - b["position"]) for a, b in zip(lockstep["motions"], live["motions"]))
    agree = same_steps and ends and worst <= 0.05
    return ["the same bench (two moves and a status) on the lock-step world and on a live aspod sim over a pty",
            f"  lock-step (aspod bench, process start included): {lockstep_wall:.2f} s wall for "
            f"{lockstep['sim_time_s']:.1f} simulated s; live (aspod teleop --script): {live_wall:.2f} s wall "
            f"({live_wall / lockstep_wall:.1f}x)",
            f"  outcomes {'agree' if agree else 'DIFFER'}: lines {'same' if same_steps else 'differ'}, motion ends "
            f"{'same' if ends else 'differ'}, end positions within {worst:.4f} deg"]


def main(quick: bool = False) -> PartsResult:
    return run_parts("campaign: Dask throughput 1 and 2 workers, engine overhead, lock-step against live",
                     (throughput, overhead, lockstep_against_live), quick, "aspod-bench-campaign-")


if __name__ == "__main__":
    sys.exit(1 if main(quick="--quick" in sys.argv).error else 0)
