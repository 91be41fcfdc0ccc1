"""Where a campaign's runs go: Dask's distributed scheduler (a local cluster of worker processes, one thread each,
by default on every core; or a running scheduler at `tcp://HOST:8786` with workers on other machines), or this
process alone (`serial`: the reference that a distributed run must equal, row for row).

Runs are independent and each builds its own world, so they are spread one task per run; the results come back
in any order and are put back in the matrix's. A run that raises (a bug, never the bench's own failure: that
is its row) or whose worker dies becomes an error row saying so; the campaign goes on.

A `--scheduler` address is tried within Dask's own connect timeout (`distributed.comm.timeouts.connect`, 30 s
unless configured, e.g. DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT=5s), the Dask handshake included:
distributed's Client bounds the TCP connect but then waits for the handshake without a bound, so a port that
accepts and never speaks Dask would hold it for ever (`SchedulerUnreachable` says so instead).
"""
from __future__ import annotations

import logging
import os
import traceback
from dataclasses import dataclass
from typing import Callable, Optional

from host_tools.campaign.matrix import Run
from host_tools.campaign.runs import BenchSpec, RunResult, run_one
from host_tools.progress import Progress

OnResult = Callable[[RunResult], None]


class SchedulerUnreachable(ConnectionError):
    """--scheduler names no Dask scheduler that answered in time: nothing listens there, or what does never spoke
    Dask's protocol."""


@dataclass(frozen=True)
class EngineSettings:
    workers: Optional[int] = None          # local workers (None: one per core)
    scheduler: Optional[str] = None        # a running Dask scheduler's address instead of a local cluster
    serial: bool = False                   # no Dask: every run in this process, one after the other

    def __post_init__(self) -> None:
        if self.workers is not None and not 1 <= self.workers <= 1024:
            raise ValueError(f"--workers {self.workers}: between 1 and 1024")
        if self.serial and (self.workers is not None or self.scheduler is not None):
            raise ValueError("--serial runs in this process: no --workers or --scheduler with it")
        if self.scheduler is not None and self.workers is not None:
            raise ValueError("--workers starts a local cluster; a --scheduler has its own workers")

    def describe(self) -> str:
        if self.serial:
            return "serial, in this process"
        if self.scheduler is not None:
            return f"Dask scheduler at {self.scheduler}"
        return f"Dask local cluster, {self.local_workers()} workers"

    def local_workers(self) -> int:
        return self.workers if self.workers is not None else (os.cpu_count() or 1)


def _error_result(run: Run, why: str) -> RunResult:
    return RunResult(run.index, {"run": run.index, **run.as_dict(), "outcome": "error", "ok": False,
                                 "error": why, "reproduce": ""}, 0.0)


def run_serial(bench: BenchSpec, runs: list[Run], on_result: OnResult) -> list[RunResult]:
    """Every run here, in order; on a terminal each run's simulated time is shown under the campaign's bar."""
    results = []
    for run in runs:
        try:
            with Progress(f"run {run.index}", None, position=1) as shown:
                result = run_one(bench, run, shown)
        except Exception as exc:               # a bug in the emulator: the row says so, the campaign goes on
            result = _error_result(run, f"the run raised {type(exc).__name__}: {exc} "
                                        f"({traceback.extract_tb(exc.__traceback__)[-1].filename})")
        results.append(result)
        on_result(result)
    return results


def map_on_dask(fn: Callable, items: list, settings: EngineSettings, on_done: Callable[[int, object], None],
                error_of: Callable[[object, str], object], shared: object = None,
                on_started: Callable[[str], None] = lambda where: None) -> list:
    """`fn(shared, item)` for every item as Dask tasks (one each, any order); results in the items' order.

    `on_done(index, result)` as each ends; a task that raises, or whose worker dies, gives `error_of(item, why)`.
    """
    from distributed import Client, LocalCluster, as_completed
    cluster = None
    if settings.scheduler is None:
        cluster = LocalCluster(n_workers=settings.local_workers(), threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        client = Client(settings.scheduler, timeout=scheduler_handshake(settings.scheduler))
    try:
        on_started(client.dashboard_link if settings.scheduler is not None else settings.describe())
        scattered = client.scatter(shared, broadcast=True) if shared is not None else None
        futures = client.map(fn, [scattered] * len(items), items, pure=False)
        index_of = {f.key: i for i, f in enumerate(futures)}
        results: dict[int, object] = {}
        for future in as_completed(futures):
            index = index_of[future.key]
            try:
                result = future.result()
            except Exception as exc:           # a bug in the task, or its worker died (KilledWorker)
                result = error_of(items[index], f"the task raised {type(exc).__name__}: {exc}")
            results[index] = result
            on_done(index, result)
        return [results[i] for i in range(len(items))]
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def scheduler_handshake(address: str) -> float:
    """Open a connection to `address` and complete Dask's handshake on it, all within Dask's connect timeout; that
    timeout in seconds, for the Client's own connection. SchedulerUnreachable naming the address if it fails."""
    import asyncio

    import dask
    from dask.utils import parse_timedelta
    from distributed.comm import connect
    timeout_s = parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"), default="seconds")

    async def handshake() -> None:
        comm = await asyncio.wait_for(connect(address, timeout=timeout_s), timeout_s)
        await comm.close()
    try:
        asyncio.run(handshake())
    except asyncio.TimeoutError:
        raise SchedulerUnreachable(f"--scheduler {address}: no Dask scheduler answered within {timeout_s:g} s (a port "
                                   "that accepts but does not speak Dask's protocol, or one too slow; Dask's "
                                   "distributed.comm.timeouts.connect sets the bound)") from None
    except (OSError, ValueError, TypeError) as exc:
        raise SchedulerUnreachable(f"--scheduler {address}: {exc}") from None
    return timeout_s


def run_distributed(bench: BenchSpec, runs: list[Run], settings: EngineSettings, on_result: OnResult,
                    on_started: Callable[[str], None] = lambda where: None) -> list[RunResult]:
    """Every run a Dask task; results in the matrix's order. `on_started` is told where they run."""
    return map_on_dask(run_one, runs, settings, lambda index, result: on_result(result),
                       lambda run, why: _error_result(run, why.replace("the task raised", "the run raised")),
                       shared=bench, on_started=on_started)


def run_runs(bench: BenchSpec, runs: list[Run], settings: EngineSettings, on_result: OnResult = lambda r: None,
             on_started: Callable[[str], None] = lambda where: None) -> list[RunResult]:
    if settings.serial:
        on_started(settings.describe())
        return run_serial(bench, runs, on_result)
    return run_distributed(bench, runs, settings, on_result, on_started)
