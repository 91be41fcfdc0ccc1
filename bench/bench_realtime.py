"""Real-time loop jitter: the controller's 1 kHz loop with a teleop host attached, beside a bare sleep loop.

Both loops run in this process, taking turns, for the same total time each (60 s in 6
rounds, 5 s in one round with --quick). A round is: bare loop for half its share, a
fresh world for its share, bare loop for the other half; so both rows span the same
stretch of time and meet the same load from the rest of the machine (on a shared
machine that load moves the figures more than anything measured here; the report
prints it per row):

* **bare loop**: a Python loop that does nothing but `RealClock.sleep_until(deadline)`,
  then `deadline += 1 ms`: what this machine, its OS and CPython give a 1 kHz loop.
* **world**: the whole simulator as `aspod sim --pty` runs it (`host_tools.worlds.world.World`
  on a `RealClock` and a `PtyPort`, 115200 baud paced, `Scheduler.run_forever`), with a
  teleop-like host attached from a SEPARATE process (so it does not share our GIL, as a
  real teleop does not): a `HostClient` on the pty that connects, sets telemetry to
  20 Hz, and sends a command (Ping, GetStatus, ParamGet in turn) every 100 ms.

In the world the measured loop is the controller's 1 kHz task: `arm` when the
scheduler has one (the motor loops), else `hal`. Its function is wrapped: at entry the
wrapper writes `RealClock.precise_now()` and the run's deadline (the wake time the task
asked for on its previous run) into preallocated arrays. The bare loop calls the same
wrapper around a task that returns `deadline + 1 ms`, so both are measured by the same
code. Definitions, the same for both (`now()` and `precise_now()` are both
CLOCK_MONOTONIC on Linux; their offset is measured and removed anyway):

* period jitter = |start(k) - start(k-1) - 1 ms|: p50, p99 (nearest rank), max;
* lateness = start(k) - deadline(k);
* missed deadline: a run that starts more than one full period (1 ms) after its deadline;
* `>2 ms`: periods longer than two nominal periods (at least one whole tick without a run).

The goal: the world's jitter p99 within 1.5x the bare loop's, and no more missed
deadlines than the bare loop. Under the table, to explain the figures:

* the CPU other processes used during each row, in cores, and this process's scheduling
  policy: on a shared machine the world (about 0.3 core) is preempted by CPU-bound
  neighbours far more often than the bare loop (next to no CPU);
* the world's lateness split into time other tasks (and its own previous run) held the
  thread past the deadline, and the rest (the sleep waking late, the process not
  running), with the same split for each missed run (garbage collection included: the
  collector is timed through `gc.callbacks` while a loop is measured);
* the world's mean period: a task that asks for `now + period` rather than
  `deadline + period` is late every period by its wake-up latency, and runs slow.
"""
from __future__ import annotations

import gc
import json
import math
import os
import secrets
import subprocess
import sys
import tempfile
import threading
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

from protocol import auth
from timebase import RealClock

REPO_ROOT = Path(__file__).resolve().parent.parent
PERIOD_S = 0.001               # the loop under test: 1 kHz
FULL_S = 60.0
QUICK_S = 5.0
FULL_ROUNDS = 6                # the run is split into this many bare / world / bare alternations
QUICK_ROUNDS = 1
TELEMETRY_HZ = 20              # the host asks for this rate (the goal: 10 Hz or more)
COMMAND_PERIOD_S = 0.1         # the host sends one command this often
BAUD = 115200
ATTACH_TIMEOUT_S = 30.0        # host connected and telemetry set, or the world row fails
SETTLE_S = 0.5                 # world runs this long with the host attached before measuring
HOST_STOP_TIMEOUT_S = 10.0
GOAL_P99_RATIO = 1.5           # the goal: p99_world <= 1.5 x p99_bare, missed_world <= missed_bare
LOOP_TASKS = ("arm", "hal")    # the first of these the scheduler has is measured


class BenchSetupError(RuntimeError):
    """The world or its host could not be started: no figures for that row."""


# ---------------------------------------------------------------- measurement

class Recorder:
    """Start times and deadlines of a task's runs, in preallocated arrays (no allocation per run).

    Each `wrap()` starts a segment; periods are taken within a segment only. Other tasks
    wrapped with `tap()`, the measured task itself and (with `gc_callback` in
    `gc.callbacks`) the garbage collector log when they ran, so a late run's lateness can be put down to what
    held the thread after its deadline; what no span covers is the sleep waking late or
    the OS not running the process.
    """

    def __init__(self, capacity: int, offset_s: float) -> None:
        self.capacity = capacity
        self.offset_s = offset_s                            # precise_now() - now()
        self.starts = array("d", bytes(8 * capacity))      # precise_now() at entry
        self.deadlines = array("d", bytes(8 * capacity))   # the wake time asked for (precise_now() scale)
        self.blocked = array("d", bytes(8 * capacity))     # tasks ran this long between deadline and entry
        self.gc_blocked = array("d", bytes(8 * capacity))  # of which the garbage collector
        self.culprit = array("h", bytes(2 * capacity))     # label index of the task that held it longest
        self.labels: list[str] = []
        self.n = 0
        self.dropped = 0
        self.segment_starts: list[int] = []
        self._spans: list[tuple[float, float, int]] = []   # (entry, exit, label) since the last run
        self._gc_spans: list[tuple[float, float]] = []
        self._gc_start = 0.0

    def label(self, name: str) -> int:
        if name not in self.labels:
            self.labels.append(name)
        return self.labels.index(name)

    def wrap(self, fn: Callable[[float], Optional[float]], first_deadline_s: float,
             name: str = "loop") -> Callable[[float], Optional[float]]:
        """`fn` with its entry recorded; the deadline of a run is what the previous run returned."""
        starts, deadlines, blocked, capacity = self.starts, self.deadlines, self.blocked, self.capacity
        gc_blocked, culprit, spans, gc_spans = self.gc_blocked, self.culprit, self._spans, self._gc_spans
        offset, me = self.offset_s, self.label(f"{name} itself")
        precise_now = RealClock.precise_now
        deadline = first_deadline_s + offset
        self.segment_starts.append(self.n)
        spans.clear()
        gc_spans.clear()

        def timed(now: float) -> Optional[float]:
            nonlocal deadline
            t = precise_now()
            i = self.n
            if i < capacity:
                starts[i] = t
                deadlines[i] = deadline
                busy = longest = 0.0
                who = -1
                for a, b, k in spans:
                    if b > deadline:
                        held = b - (a if a > deadline else deadline)
                        busy += held
                        if held > longest:
                            longest, who = held, k
                blocked[i] = busy
                culprit[i] = who
                busy = 0.0
                for a, b in gc_spans:
                    if b > deadline:
                        busy += b - (a if a > deadline else deadline)
                gc_blocked[i] = busy
                self.n = i + 1
            else:
                self.dropped += 1
            spans.clear()
            gc_spans.clear()
            nxt = fn(now)
            spans.append((t, precise_now(), me))
            if nxt is not None:
                deadline = nxt + offset
            return nxt
        return timed

    def tap(self, fn: Callable[[float], Optional[float]], name: str) -> Callable[[float], Optional[float]]:
        """Another task, with the span of each of its runs logged."""
        spans, precise_now, k = self._spans, RealClock.precise_now, self.label(name)

        def tapped(now: float) -> Optional[float]:
            a = precise_now()
            nxt = fn(now)
            spans.append((a, precise_now(), k))
            return nxt
        return tapped

    def gc_callback(self, phase: str, info: dict) -> None:
        """For `gc.callbacks`: each collection's span (inside whichever task triggered it)."""
        if phase == "start":
            self._gc_start = RealClock.precise_now()
        else:
            self._gc_spans.append((self._gc_start, RealClock.precise_now()))


def clock_offset_s(clock: RealClock) -> float:
    """precise_now() - now(), from the tightest of a few bracketed reads (0 when both are CLOCK_MONOTONIC)."""
    best = None
    for _ in range(50):
        a = clock.now()
        p = clock.precise_now()
        b = clock.now()
        if best is None or b - a < best[0]:
            best = (b - a, p - (a + b) / 2)
    return best[1]


def nearest_rank(sorted_data: list[float], q: float) -> float:
    rank = math.ceil(round(q * len(sorted_data), 9))
    return sorted_data[min(max(rank, 1), len(sorted_data)) - 1]


def capacity_for(duration_s: float) -> int:
    return int(duration_s / PERIOD_S * 1.5) + 1000


# ---------------------------------------------------------------- machine load

class CpuMeter:
    """CPU time from /proc (clock ticks) used by the machine, by this process and by given children.

    `others()`: what every other process used meanwhile (other people's tests, say), in
    cores; `steal()`: what the hypervisor took. They tell whether two rows met the same
    machine. Accumulates over `resume()` ... `stop()` spans.
    """

    def __init__(self, clock: RealClock) -> None:
        self.clock = clock
        self.tick_s = 1.0 / os.sysconf("SC_CLK_TCK")
        self.child_pids: tuple[int, ...] = ()
        self.elapsed_s = self.busy_s = self.steal_s = self.ours_s = 0.0
        self._start: Optional[tuple[float, float, float, float]] = None

    def _read(self) -> tuple[float, float, float, float]:
        with open("/proc/stat") as f:
            cpu = [int(x) for x in f.readline().split()[1:]]
        idle, steal = cpu[3] + cpu[4], (cpu[7] if len(cpu) > 7 else 0)
        busy = sum(cpu[:8]) - idle - steal
        ours = 0
        for pid in ("self",) + tuple(str(p) for p in self.child_pids):
            try:
                with open(f"/proc/{pid}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
                ours += int(fields[11]) + int(fields[12])   # utime, stime (all threads)
            except (OSError, IndexError, ValueError):
                pass
        return self.clock.now(), busy * self.tick_s, steal * self.tick_s, ours * self.tick_s

    def resume(self) -> None:
        self._start = self._read()

    def stop(self) -> None:
        if self._start is None:
            return
        end, start = self._read(), self._start
        self.elapsed_s += end[0] - start[0]
        self.busy_s += end[1] - start[1]
        self.steal_s += end[2] - start[2]
        self.ours_s += end[3] - start[3]
        self._start = None

    def _per_s(self, x: float) -> float:
        return x / self.elapsed_s if self.elapsed_s > 0 else 0.0

    def others(self) -> float:
        return self._per_s(max(0.0, self.busy_s - self.ours_s))

    def ours(self) -> float:
        return self._per_s(self.ours_s)

    def steal(self) -> float:
        return self._per_s(self.steal_s)


# ---------------------------------------------------------------- results

@dataclass
class LoopResult:
    label: str
    duration_s: float = 0.0
    runs: int = 0
    jitter_p50_s: float = 0.0
    jitter_p99_s: float = 0.0
    jitter_max_s: float = 0.0
    late_p50_s: float = 0.0
    late_p99_s: float = 0.0
    late_max_s: float = 0.0
    missed: int = 0
    mean_period_s: float = 0.0
    long_periods: int = 0          # periods longer than 2 ms: a whole tick with no run
    blocked_p50_s: float = 0.0     # of the lateness: other tasks running after the deadline
    blocked_p99_s: float = 0.0
    blocked_runs: int = 0          # runs that found another task running past their deadline
    rest_p50_s: float = 0.0        # of the lateness: the rest (sleep overshoot, process not running)
    rest_p99_s: float = 0.0
    missed_by: dict = field(default_factory=dict)   # what held the thread past the deadline of each missed run
    cpu_others: float = 0.0        # cores used by other processes during the row
    cpu_ours: float = 0.0          # cores used by this process (and the host child, for the world)
    cpu_steal: float = 0.0
    task: str = ""
    other_tasks: str = ""
    host: dict = field(default_factory=dict)
    error: str = ""
    detail: str = ""

    def analyse(self, rec: Recorder) -> "LoopResult":
        n = rec.n
        if n < 3:
            self.error = self.error or f"only {n} runs recorded"
            self.runs = n
            return self
        starts, deadlines, blocked_list = rec.starts[:n], rec.deadlines[:n], rec.blocked[:n]
        firsts = set(rec.segment_starts)
        periods = [starts[i] - starts[i - 1] for i in range(1, n) if i not in firsts]
        jitter = sorted(abs(p - PERIOD_S) for p in periods)
        late_list = [s - d for s, d in zip(starts, deadlines)]
        late = sorted(late_list)
        blocked = sorted(blocked_list)
        rest = sorted(x - b for x, b in zip(late_list, blocked_list))
        self.runs = n
        self.duration_s = sum(periods)
        self.jitter_p50_s, self.jitter_p99_s, self.jitter_max_s = (nearest_rank(jitter, 0.50),
                                                                   nearest_rank(jitter, 0.99), jitter[-1])
        self.late_p50_s, self.late_p99_s, self.late_max_s = nearest_rank(late, 0.50), nearest_rank(late, 0.99), late[-1]
        self.missed = sum(1 for x in late_list if x > PERIOD_S)
        self.mean_period_s = self.duration_s / len(periods)
        self.long_periods = sum(1 for p in periods if p > 2 * PERIOD_S)
        self.blocked_p50_s, self.blocked_p99_s = nearest_rank(blocked, 0.50), nearest_rank(blocked, 0.99)
        self.blocked_runs = sum(1 for b in blocked_list if b > 0)
        self.rest_p50_s, self.rest_p99_s = nearest_rank(rest, 0.50), nearest_rank(rest, 0.99)
        for i, x in enumerate(late_list):
            if x > PERIOD_S:
                if rec.gc_blocked[i] > x / 2:
                    why = "garbage collection"
                elif blocked_list[i] > x / 2:
                    why = rec.labels[rec.culprit[i]]
                else:
                    why = "nothing in the process (woke late / not running)"
                self.missed_by[why] = self.missed_by.get(why, 0) + 1
        if rec.dropped:
            self.detail += f"{rec.dropped} runs beyond the arrays not recorded. "
        return self

    def load(self, meter: CpuMeter) -> "LoopResult":
        self.cpu_others, self.cpu_ours, self.cpu_steal = meter.others(), meter.ours(), meter.steal()
        return self


# ---------------------------------------------------------------- the bare loop

def run_bare(duration_s: float, rec: Recorder, meter: CpuMeter) -> None:
    """Sleep to each deadline, deadline += 1 ms: nothing else. Measured with the world's wrapper."""
    clock = RealClock()
    deadline = clock.now() + 10 * PERIOD_S
    end = deadline + duration_s
    timed = rec.wrap(lambda d: d + PERIOD_S, deadline, "bare loop")
    sleep_until = clock.sleep_until
    gc.callbacks.append(rec.gc_callback)
    meter.resume()
    try:
        while deadline < end:
            sleep_until(deadline)
            deadline = timed(deadline)
    finally:
        meter.stop()
        gc.callbacks.remove(rec.gc_callback)


# ---------------------------------------------------------------- the host, in its own process

HOST_COMMANDS = ("Ping", "GetStatus", "ParamGet")


def host_main(url: str, key_path: str, telemetry_hz: int, command_period_s: float) -> int:
    """The teleop-like host (run in a child process): connect, set telemetry, a command every period.

    Stops when its stdin closes, then prints one JSON line of what it saw.
    """
    from host_tools.client.live import HostClient   # imports pyserial
    from protocol.messages import SCHEMA

    clock = RealClock()
    stop = threading.Event()

    def watch_stdin() -> None:
        sys.stdin.read()
        stop.set()
    threading.Thread(target=watch_stdin, name="stdin", daemon=True).start()

    summary = {"telemetry": 0, "sent": 0, "ok": 0, "failed": 0, "skipped": 0, "latencies_ms": [], "error": ""}
    client = None
    try:
        client = HostClient(url, auth.load_key(key_path), baud=BAUD)

        def on_telemetry(msg, now) -> None:
            summary["telemetry"] += 1
        client.telemetry_listeners.append(on_telemetry)
        client.connect(timeout_s=ATTACH_TIMEOUT_S)
        handle = client.call(SCHEMA["SetTelemetryRate"].type(rate_hz=telemetry_hz), timeout_s=ATTACH_TIMEOUT_S)
        if not handle.ok:
            raise RuntimeError(f"SetTelemetryRate: {handle.describe()}")
        summary["telemetry"] = 0
        pending = None
        deadline = clock.now()
        i = 0
        while not stop.is_set():
            deadline += command_period_s
            clock.sleep_until(deadline)
            if pending is not None:
                if not pending.done:
                    summary["skipped"] += 1
                    continue
                summary["ok" if pending.ok else "failed"] += 1
                if pending.ok:
                    summary["latencies_ms"].append(round(pending.latency_s * 1e3, 3))
            name = HOST_COMMANDS[i % len(HOST_COMMANDS)]
            spec = SCHEMA[name]
            msg = (spec.type(token=i) if name == "Ping" else
                   spec.type(name="telemetry_hz") if name == "ParamGet" else spec.type())
            pending = client.submit(msg)
            summary["sent"] += 1
            i += 1
    except Exception as exc:
        summary["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        if client is not None:
            client.close()
    print(json.dumps(summary), flush=True)
    return 1 if summary["error"] else 0


class HostProcess:
    """`host_main` in a child Python process on the world's pty. Always ended by `stop()`."""

    def __init__(self, url: str, key_path: Path) -> None:
        code = (f"import sys; from bench.bench_realtime import host_main; "
                f"sys.exit(host_main({url!r}, {str(key_path)!r}, {TELEMETRY_HZ}, {COMMAND_PERIOD_S}))")
        self._stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self._stderr, cwd=REPO_ROOT)

    def stderr(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace").strip()[-2000:]

    def stop(self) -> dict:
        """Close its stdin and take its summary line."""
        try:
            out, _ = self.proc.communicate(input=b"", timeout=HOST_STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
            return {"error": f"host did not stop in {HOST_STOP_TIMEOUT_S:.0f} s; stderr: {self.stderr()!r}"}
        lines = out.decode(errors="replace").strip().splitlines()
        try:
            return json.loads(lines[-1])
        except (IndexError, ValueError):
            return {"error": f"host printed no summary (status {self.proc.returncode}); stderr: {self.stderr()!r}"}


# ---------------------------------------------------------------- the world with a host attached

@dataclass
class WorldRound:
    """One world's life: its loop task's name, the scheduler's own figures, the host's summary."""

    task: str = ""
    task_runs: dict = field(default_factory=dict)
    exec_p99_s: float = 0.0
    exec_max_s: float = 0.0
    late_max_s: float = 0.0
    overruns: int = 0
    tolerance_s: float = 0.0
    host: dict = field(default_factory=dict)
    error: str = ""


def run_world(duration_s: float, key: bytes, key_path: Path, rec: Recorder, meter: CpuMeter) -> WorldRound:
    """A fresh world and host: attach, settle, then `duration_s` of `run_forever` recorded into `rec`."""
    from firmware_py.controller import ControllerConfig
    from host_tools.worlds.ports import PtyPort
    from host_tools.worlds.world import World

    clock = RealClock()
    out = WorldRound()
    world = None
    host: Optional[HostProcess] = None
    try:
        world = World(clock, PtyPort(), key, baud=BAUD, paced=True, controller_config=ControllerConfig())
        scheduler = world.scheduler
        name = next((n for n in LOOP_TASKS if n in scheduler.tasks), None)
        if name is None:
            raise BenchSetupError(f"the scheduler has none of the tasks {', '.join(LOOP_TASKS)}: "
                                  f"{', '.join(scheduler.tasks)}")
        out.task = name
        host = HostProcess(world.uart.port.url, key_path)
        controller = world.controller
        give_up = clock.now() + ATTACH_TIMEOUT_S
        while not (controller.link.session is not None and controller.telemetry_hz == TELEMETRY_HZ):
            if host.proc.poll() is not None:   # the world runs while the host connects and sets telemetry
                raise BenchSetupError(f"host exited (status {host.proc.returncode}): {host.stop().get('error')}")
            if clock.now() > give_up:
                raise BenchSetupError(f"host not attached after {ATTACH_TIMEOUT_S:.0f} s")
            scheduler.run_until(clock.now() + 0.02)
        scheduler.run_until(clock.now() + SETTLE_S)

        task = scheduler.tasks[name]
        runs_before = {n: t.stats.runs for n, t in scheduler.tasks.items()}
        stopping: list[bool] = []

        def end_of_run(now: float) -> None:
            stopping.append(True)
        scheduler.add("bench-end", end_of_run, clock.now() + duration_s, tolerance_s=1.0)
        for other in scheduler.tasks.values():
            if other is not task:
                other.fn = rec.tap(other.fn, other.name)
        task.fn = rec.wrap(task.fn, task.wake_s, name)
        meter.child_pids = (host.proc.pid,)
        gc.callbacks.append(rec.gc_callback)
        meter.resume()
        try:
            scheduler.run_forever(lambda: bool(stopping))   # as `aspod sim` runs it
        finally:
            meter.stop()
            gc.callbacks.remove(rec.gc_callback)
        out.task_runs = {n: t.stats.runs - runs_before.get(n, 0) for n, t in scheduler.tasks.items()}
        stats = task.stats
        out.exec_p99_s, out.exec_max_s, out.late_max_s = stats.exec_p99_s, stats.exec_max_s, stats.late_max_s
        out.overruns, out.tolerance_s = stats.overruns, task.tolerance_s
    except Exception as exc:   # reported in the world's row
        out.error = f"{type(exc).__name__}: {exc}"
    finally:
        meter.stop()
        if host is not None:
            out.host = host.stop()
            if out.host.get("error") and not out.error:
                out.error = f"host: {out.host['error']}"
        if world is not None:
            world.close()
    return out


def world_result(rounds: list[WorldRound], rec: Recorder, meter: CpuMeter) -> LoopResult:
    result = LoopResult("world, teleop host attached")
    result.task = "/".join(sorted({r.task for r in rounds if r.task}))
    errors = [r.error for r in rounds if r.error]
    result.error = "; ".join(errors)
    result.analyse(rec).load(meter)
    if errors and len(errors) < len(rounds):
        result.error = f"{len(errors)} of {len(rounds)} rounds failed: {result.error}"
    runs: dict[str, int] = {}
    for r in rounds:
        for n, k in r.task_runs.items():
            runs[n] = runs.get(n, 0) + k
    result.other_tasks = ", ".join(f"{n} {k}" for n, k in runs.items())
    done = [r for r in rounds if r.task_runs]
    if done:
        result.detail += (f"scheduler's own stats for {result.task} (whole life of each world, worst round): exec p99 "
                          f"<= {max(r.exec_p99_s for r in done) * 1e6:.0f} us, exec max "
                          f"{max(r.exec_max_s for r in done) * 1e6:.0f} us, late max "
                          f"{max(r.late_max_s for r in done) * 1e6:.0f} us; overruns (late > "
                          f"{done[0].tolerance_s * 1e3:g} ms) {sum(r.overruns for r in done)} in all")
    hosts = [r.host for r in rounds if r.host and not r.host.get("error")]
    if hosts:
        result.host = {k: sum(h[k] for h in hosts) for k in ("telemetry", "sent", "ok", "failed", "skipped")}
        result.host["latencies_ms"] = [x for h in hosts for x in h["latencies_ms"]]
    return result


# ---------------------------------------------------------------- report

def scheduling_policy() -> str:
    policy = os.sched_getscheduler(0)
    names = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO", os.SCHED_RR: "SCHED_RR"}
    if policy in (os.SCHED_FIFO, os.SCHED_RR):
        return f"{names[policy]} priority {os.sched_getparam(0).sched_priority}"
    return f"{names.get(policy, f'policy {policy}')}, nice {os.nice(0)}"


def us(x: float) -> str:
    return f"{x * 1e6:.0f}"


def report(bare: LoopResult, world: LoopResult, duration_s: float, rounds: int) -> str:
    lines = [f"Real-time 1 kHz loop: the controller's loop task with a teleop host attached (host in its own "
             f"process), beside a bare sleep loop; {duration_s:g} s each, same process, in {rounds} alternating "
             f"round{'s' if rounds > 1 else ''} (bare, world, bare)",
             "  jitter = |period - 1 ms|, late = start - deadline (us); missed = runs starting more than 1 ms after "
             "their deadline; >2 ms = periods over 2 ms",
             "",
             f"  {'loop':<38}{'runs':>7}{'period':>8}{'jit p50':>8}{'jit p99':>8}{'jit max':>8}"
             f"{'late p50':>9}{'late p99':>9}{'late max':>9}{'missed':>7}{'>2 ms':>6}{'others':>8}"]
    for r in (bare, world):
        label = r.label + (f" [{r.task}]" if r.task else "")
        if not r.runs:
            lines.append(f"  {label:<38}  FAILED: {r.error}")
            continue
        lines.append(f"  {label:<38}{r.runs:>7}{r.mean_period_s * 1e6:>8.1f}{us(r.jitter_p50_s):>8}"
                     f"{us(r.jitter_p99_s):>8}{us(r.jitter_max_s):>8}{us(r.late_p50_s):>9}{us(r.late_p99_s):>9}"
                     f"{us(r.late_max_s):>9}{r.missed:>7}{r.long_periods:>6}{r.cpu_others:>8.2f}")
    lines.append("")
    if bare.runs and world.runs:
        ratio = world.jitter_p99_s / bare.jitter_p99_s if bare.jitter_p99_s > 0 else math.inf
        jitter_ok = ratio <= GOAL_P99_RATIO
        missed_ok = world.missed <= bare.missed
        lines += [f"  jitter p99, world / bare: {ratio:.2f}  (goal <= {GOAL_P99_RATIO})  {'PASS' if jitter_ok else 'FAIL'}",
                  f"  missed deadlines, world vs bare: {world.missed} vs {bare.missed}  (goal: world <= bare)  "
                  f"{'PASS' if missed_ok else 'FAIL'}",
                  f"  goal {'met' if jitter_ok and missed_ok else 'NOT met'}",
                  "",
                  f"  others = CPU used by other processes during the row, in cores (of {os.cpu_count()}); "
                  f"steal: bare {bare.cpu_steal:.2f}, world {world.cpu_steal:.2f}; this process"
                  f"{' + host' if world.host else ''}: bare {bare.cpu_ours:.2f}, world {world.cpu_ours:.2f}"]
        lines.append(f"  this process's scheduling: {scheduling_policy()}")
        if abs(world.cpu_others - bare.cpu_others) > 0.25:
            lines.append("  NOTE: the two rows met differently loaded machines (others differ by more than 0.25 "
                         "core): the ratios say little; run again on a quieter machine")
    lines.append("  the bare loop keeps its 1 ms grid: after a stall it runs back to back to catch up (periods near "
                 "0, jitter near 1 ms), and every run more than 1 ms behind counts as missed; the world's periodic tasks "
                 "keep the grid too but skip the periods a stall cost them (counted as skipped) instead of bursting")
    if world.error:
        lines.append(f"  world: {world.error}")
    if world.runs:
        lines += [f"  world's lateness, split: other tasks running past the deadline p50 {us(world.blocked_p50_s)} / "
                  f"p99 {us(world.blocked_p99_s)} us ({world.blocked_runs} of {world.runs} runs delayed by one); "
                  f"the rest (sleep overshoot, process not running) p50 {us(world.rest_p50_s)} / p99 "
                  f"{us(world.rest_p99_s)} us (bare loop: all of it, p50 {us(bare.late_p50_s)} / p99 "
                  f"{us(bare.late_p99_s)} us)",
                  f"  world: mean period {world.mean_period_s * 1e6:.1f} us = {1 / world.mean_period_s:.1f} Hz "
                  f"(nominal 1000 Hz; bare loop {1 / bare.mean_period_s:.1f} Hz)" if bare.runs else None,
                  "  NOTE: the world's loop runs slow: its task asks for its next run one period after the time it "
                  "was handed (`now + period`), not after its deadline, so every period is stretched by that run's "
                  "lateness" if world.mean_period_s > PERIOD_S * 1.01 else None,
                  f"  world: task runs while measured: {world.other_tasks}",
                  f"  world: {world.detail}"]
    for r in (bare, world):
        if r.missed_by:
            lines.append(f"  {r.label}: its missed runs were held past their deadline mostly by: " + ", ".join(
                f"{why} {k}" for why, k in sorted(r.missed_by.items(), key=lambda kv: -kv[1])))
    h = world.host
    if h and not h.get("error"):
        lat = sorted(h.get("latencies_ms", []))
        lat_text = f", round trip p50 {nearest_rank(lat, 0.5):.1f} ms, max {lat[-1]:.1f} ms" if lat else ""
        pending = h['sent'] - h['ok'] - h['failed']
        lines.append(f"  host (own process): {h['telemetry']} telemetry frames, {h['sent']} commands sent: "
                     f"{h['ok']} ok, {h['failed']} failed, {pending} still pending when stopped; {h['skipped']} "
                     f"command ticks skipped (previous still pending){lat_text}")
    return "\n".join(line for line in lines if line is not None)


# ---------------------------------------------------------------- entry point

@dataclass
class RealtimeResults:
    bare: LoopResult
    world: LoopResult

    @property
    def error(self) -> str:
        return self.bare.error or self.world.error


def main(quick: bool = False, duration_s: Optional[float] = None, rounds: Optional[int] = None) -> RealtimeResults:
    """`rounds` alternations, each: bare loop, a fresh world with its host, bare loop again.

    The bare loop gets half of a round's share before the world and half after, so both
    rows span the same stretch of time and meet the same load from the rest of the machine.
    """
    duration = duration_s if duration_s is not None else (QUICK_S if quick else FULL_S)
    rounds = rounds or (QUICK_ROUNDS if quick else FULL_ROUNDS)
    share = duration / rounds
    clock = RealClock()
    offset = clock_offset_s(clock)
    bare_rec, world_rec = Recorder(capacity_for(duration), offset), Recorder(capacity_for(duration), offset)
    bare_meter, world_meter = CpuMeter(clock), CpuMeter(clock)
    world_rounds: list[WorldRound] = []
    with tempfile.TemporaryDirectory(prefix="aspod-bench-") as tmp:
        key_path = Path(tmp) / "bench.key"
        key = secrets.token_bytes(auth.KEY_BYTES)
        auth.write_key(key_path, key)
        for _ in range(rounds):
            run_bare(share / 2, bare_rec, bare_meter)
            world_rounds.append(run_world(share, key, key_path, world_rec, world_meter))
            run_bare(share / 2, bare_rec, bare_meter)
    bare = LoopResult("bare loop (sleep_until only)").analyse(bare_rec).load(bare_meter)
    world = world_result(world_rounds, world_rec, world_meter)
    print(report(bare, world, duration, rounds), flush=True)
    return RealtimeResults(bare, world)


if __name__ == "__main__":
    main(quick="--quick" in sys.argv[1:])
