"""Campaigns and targets: what Dask gives a campaign, and one bench on the lock-step world beside a live `aspod sim`.

1. **Throughput.** A campaign of moving runs (a teleop script: enable, a joint jogged and moved, 12 simulated s
   each) on a Dask local cluster of 1 worker and of 2 workers: simulated seconds per wall second summed over
   the workers, from the first task given to the last row back (the cluster's start-up shown apart), beside
   the same runs in this process without Dask, whose rows must be the same. Goal: 2 workers at least 1.8x one.
   On a 2-core machine the second worker shares the cores with this process, the Dask scheduler and whatever
   else runs.
2. **Engine overhead.** The same short runs (a script of one `status`: a world built, a session opened, one
   command) through Dask's 2 workers and through a bare `concurrent.futures.ProcessPoolExecutor` of 2: the
   wall time per run of each and the difference, Dask's cost per run.
3. **Lock-step against live.** One bench script (two moves and a status) by `aspod bench --json` on the
   lock-step world and by `aspod teleop --script --json` against `aspod sim --pty`: the wall time of each, and
   whether they agree (every line's outcome, every motion's end, the final positions within 0.05 deg).

Each engine is handed runs until it has done them all or spent its budget of wall time (`feed`), and each part
prints its rows as they are measured: on a busy machine the benchmark does fewer runs, it does not run longer.
"""
from __future__ import annotations

import json
import os
import sys
from concurrent.futures import FIRST_COMPLETED, Executor, ProcessPoolExecutor, ThreadPoolExecutor, wait
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from bench import PartsResult, run_parts
from timebase import RealClock
from host_tools.campaign.matrix import GridAxis, Matrix, parse_seeds
from host_tools.campaign.runs import BenchSpec, run_one
from host_tools.worlds.child import Child, run

ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
MOVING = "enable\njog j2 ${speed}\nwait 4\nstop\nmoveby j1 3 3\nwait\nwait 4\n"
SHORT = "status\n"
AGREE = "enable\nmoveby j1 5 3\nwait\nmoveby j2 -3 3\nwait\nstatus\n"
THROUGHPUT_BUDGET_S = {True: 25.0, False: 90.0}     # wall time for the runs of each engine, by --quick
OVERHEAD_BUDGET_S = {True: 10.0, False: 30.0}
IN_FLIGHT_SHORT = 16        # short runs given ahead (8 a worker), so a worker never waits on the scheduler for its next


def _runs(script: str, count: int, cwd: Path):
    axes = (GridAxis.parse("speed=1,2"),) if "${speed}" in script else ()
    seeds = parse_seeds(str(count // 2 if axes else count))
    return BenchSpec("script", "bench.aspod", text=script, cwd=str(cwd)), Matrix(axes, (), seeds).runs()


@dataclass
class Batch:
    """Runs handed to an engine until its budget was spent: their results in run order, and the wall time from the
    first run given to the last result back."""
    results: list
    wall_s: float

    @property
    def rows(self) -> dict:
        return {r.index: r.row for r in self.results}

    @property
    def sim_s(self) -> float:
        return sum(r.row["sim_s"] for r in self.results)


def feed(executor: Executor, bench: BenchSpec, runs, in_flight: int, budget_s: float) -> Batch:
    """Hand `runs` to `executor`, `in_flight` at a time, until all are given or `budget_s` of wall time has passed;
    the runs given by then finish and count. So a batch ends within its budget and the longest runs in flight, on a
    busy machine too: a slower machine does fewer runs, not a longer wait. The first `in_flight` runs are given
    whatever the budget, so a batch has figures."""
    wall0 = RealClock.precise_now()
    left, pending, results = iter(runs), set(), []

    def top_up(first: bool = False) -> None:
        while len(pending) < in_flight and (first or RealClock.precise_now() - wall0 < budget_s):
            run = next(left, None)
            if run is None:
                return
            pending.add(executor.submit(run_one, bench, run))
    top_up(first=True)
    while pending:
        done, pending = wait(pending, return_when=FIRST_COMPLETED)
        results += [future.result() for future in done]
        top_up()
    return Batch(sorted(results, key=lambda r: r.index), RealClock.precise_now() - wall0)


@contextmanager
def _dask(bench: BenchSpec, run, workers: int):
    """(a concurrent.futures executor on a Dask local cluster of `workers`, its start-up s): each worker has run
    `run` once first (its imports, numba's compiled code loaded)."""
    from distributed import Client, LocalCluster
    from distributed import wait as dask_wait
    wall0 = RealClock.precise_now()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=50) as cluster, Client(cluster) as client:
        for address in client.scheduler_info()["workers"]:
            dask_wait(client.submit(run_one, bench, run, workers=[address], pure=False))
        yield client.get_executor(pure=False), RealClock.precise_now() - wall0


def _same_rows(a: Batch, b: Batch, what: str) -> int:
    """How many runs both batches did; RuntimeError if any of them gave different rows."""
    rows_a, rows_b = a.rows, b.rows
    both = rows_a.keys() & rows_b.keys()
    differ = [i for i in sorted(both) if rows_a[i] != rows_b[i]]
    if differ:
        raise RuntimeError(f"{what}: run {differ[0]} gave different rows")
    return len(both)


def throughput(folder: Path, quick: bool) -> Iterator[str]:
    budget_s = THROUGHPUT_BUDGET_S[quick]
    bench, runs = _runs(MOVING, 8 if quick else 48, folder)
    yield (f"throughput: moving runs (a jog and a move, 12 simulated s each) on a Dask local cluster, up to "
           f"{len(runs)} runs or {budget_s:.0f} s of wall time each")
    rates, batches = {}, {}
    for workers in (1, 2):
        with _dask(bench, runs[0], workers) as (executor, startup):
            batch = feed(executor, bench, runs, 2 * workers, budget_s)
        bad = [r.row for r in batch.results if not r.row["ok"]]
        if bad:
            raise RuntimeError(f"a run failed: {bad[0]['error']}")
        rates[workers], batches[workers] = batch.sim_s / batch.wall_s, batch
        yield (f"  {workers} worker{'s' if workers > 1 else ' '}: {len(batch.results)} runs, {batch.sim_s:.0f} "
               f"simulated s in {batch.wall_s:.1f} wall s: {rates[workers]:.1f} simulated s per wall s (start-up and "
               f"warm-up {startup:.1f} s apart; load {os.getloadavg()[0]:.1f})")
    with ThreadPoolExecutor(1) as one:          # the peer: the same runs in this process, one at a time, no engine
        serial = feed(one, bench, runs, 1, budget_s)
    same = min(_same_rows(serial, batches[1], "serial and 1 worker"), _same_rows(serial, batches[2], "serial and 2"))
    rate = serial.sim_s / serial.wall_s
    yield (f"  serial, in this process (no Dask): {len(serial.results)} runs, {rate:.1f} simulated s per wall s; "
           f"the same rows as Dask's ({same} runs in common)")
    yield (f"  2 workers / 1: {rates[2] / rates[1]:.2f}x (goal 1.8x); 2 workers / serial {rates[2] / rate:.2f}x; "
           f"cores {os.cpu_count()}, load average {os.getloadavg()[0]:.2f}")


def overhead(folder: Path, quick: bool) -> Iterator[str]:
    budget_s = OVERHEAD_BUDGET_S[quick]
    bench, runs = _runs(SHORT, 20 if quick else 200, folder)
    yield (f"engine overhead: short runs (one `status` each: a world built, a session, one command), 2 warm workers, "
           f"up to {len(runs)} runs or {budget_s:.0f} s of wall time each")
    with ProcessPoolExecutor(2) as pool:
        list(pool.map(run_one, [bench] * 4, runs[:4]))            # warm: the workers' imports
        pooled = feed(pool, bench, runs, IN_FLIGHT_SHORT, budget_s)
    per_pool = pooled.wall_s / len(pooled.results) * 1e3
    yield f"  ProcessPoolExecutor: {len(pooled.results)} runs, {per_pool:.1f} ms per run"
    with _dask(bench, runs[0], 2) as (executor, _):
        dask = feed(executor, bench, runs, IN_FLIGHT_SHORT, budget_s)
    same = _same_rows(pooled, dask, "the process pool and Dask")
    per_dask = dask.wall_s / len(dask.results) * 1e3
    yield (f"  Dask: {len(dask.results)} runs, {per_dask:.1f} ms per run; Dask's cost {per_dask - per_pool:+.1f} ms per "
           f"run ({per_dask / per_pool:.2f}x); the same rows from both ({same} runs in common)")


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
