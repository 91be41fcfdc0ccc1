"""A process's own time, read from Linux's /proc: a wait for a process judged on what it had of the machine.

A process that has not yet done what it is waited for (a child's ready line, the plant's next tick) is gone,
stopped, stuck, or kept from running by a busy machine. Only the last excuses it: at load 45-49 on 2 CPUs a
live process waited on a run queue for seconds. So a wait counts the process's own time: the wall time since
the wait began, less the time the process was runnable but waiting for a CPU (the kernel's schedstat run_delay,
as host_tools/fuzz/hangs.py counts an input's). The kernel adds a wait to run_delay only once the process gets
its CPU, so a process found runnable at a look (state R) may be in the middle of one: its own time is then its
CPU time alone, as it is for one found in the kernel's uninterruptible sleep (state D: a page read from disk,
memory reclaimed), which waits on the machine too. Either way a wait is judged late, by at most the time the
process was kept from running, never early. A process stopped (SIGSTOP, state T) or gone has no excuse: `Look.gone` says which.

Where the kernel keeps no run_delay (no /proc/PID/schedstat), or /proc cannot be read, the whole wall time is
the process's own, as it was before.

`OwnTime(pid)` judges one process; `OwnTime(pid, tree=True)` the process and every process it has started since
(a child `aspod sim` starting its own plant): the tree's own time is the wall time less the longest wait for a
CPU any of them had, since any of them may be the one waited for. `peers` are processes the one waited for waits
on in turn (an `aspod teleop` on its `aspod sim`): their waits for a CPU excuse it too. `LockstepWait` judges
the lock-step controller's wait for its plant's tick (protocol/lockstep.py `WaitJudge`;
docs/separate_processes.md).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from timebase import Clock, RealClock

PROC = Path("/proc")
FRESH_S = 0.05       # LockstepWait: /proc read again as a wait begins if the latest reading is older (the watch's)
STOPPED = {"T": "stopped (SIGSTOP)", "t": "stopped by a debugger", "Z": "ended (a zombie)", "X": "ended"}


@dataclass(frozen=True)
class Sample:
    """One look at a process: its state letter (/proc/PID/stat: R runs or waits for a CPU, S and D sleep, T is
    stopped, Z ended), its main thread's CPU time and wait for a CPU (schedstat; None where the kernel keeps
    none), and its start (clock ticks since boot: a pid reused by another process starts at another)."""
    state: str
    cpu_s: Optional[float]
    waited_s: Optional[float]
    started: int


def sample(pid: int, proc: Path = PROC) -> Optional[Sample]:
    """A look at process `pid`; None if there is none (ended and reaped, or not ours to read)."""
    try:
        stat = (proc / str(pid) / "stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[-1].split()       # after the command's name, which may hold spaces and ")"
    if len(fields) < 20:
        return None
    cpu_s = waited_s = None
    try:
        ran_ns, waited_ns = (proc / str(pid) / "schedstat").read_text().split()[:2]
        cpu_s, waited_s = int(ran_ns) / 1e9, int(waited_ns) / 1e9
    except (OSError, ValueError):
        pass
    return Sample(fields[0], cpu_s, waited_s, int(fields[19]))


def children(pid: int, proc: Path = PROC) -> list[int]:
    """The processes `pid` has started and that run (or wait to be reaped) now: the threads' `children` lists."""
    found: list[int] = []
    try:
        tasks = list((proc / str(pid) / "task").iterdir())
    except OSError:
        return found
    for task in tasks:
        try:
            found += [int(word) for word in (task / "children").read_text().split()]
        except (OSError, ValueError):
            continue
    return found


@dataclass(frozen=True)
class Look:
    """What a wait has cost so far: `wall_s` since it began, `own_s` of it the process's own (the rest it was kept
    from running), and `gone`: why the process cannot be doing what it is waited for (it ended or is stopped), or
    None."""
    wall_s: float
    own_s: float
    gone: Optional[str] = None

    def describe(self) -> str:
        kept = self.wall_s - self.own_s
        return f"{self.own_s:.1f} s of its own time ({self.wall_s:.1f} s of wall time, {kept:.1f} s of it waiting " \
               "for a CPU)"


class OwnTime:
    """The own time of process `pid` (with `tree`, of it and the processes it starts; with `peers`, of them too,
    and with `tree` of the processes they start) since `begin()`.

    `look()` reads /proc (some 30 us a process) and says how much of the wall time since `begin()` was the
    process's own. A process's excuse is its wait for a CPU since the wait began: its run_delay's growth, or, found
    runnable, all but its CPU time; the tree's is the longest of its processes'. A process that ended keeps the
    excuse it had at its last look. The root process ended or stopped is `Look.gone`, and then nothing is excused.

    `begin()` reads /proc again only if its latest reading is older than `fresh_s`; otherwise the wait counts from
    that reading's counters, so the waits for a CPU between it and `begin()` are excused too (a wait judged late by
    at most that, never early). The lock-step controller begins a wait at every tick, a thousand a second, and looks
    every 50 ms: with `fresh_s` 0.05 it reads /proc some 20 times a second, not a thousand.
    """

    def __init__(self, pid: int, clock: Clock, tree: bool = False, fresh_s: float = 0.0, peers: tuple[int, ...] = (),
                 proc: Path = PROC) -> None:
        self.pid = pid
        self.clock = clock
        self.tree = tree
        self.peers = tuple(peers)
        self.fresh_s = fresh_s
        self.proc = proc
        first = sample(pid, proc)
        self._started = None if first is None else first.started    # the process this is: not a pid reused
        self._latest: dict[int, Sample] = {}    # the latest reading of each process
        self._read_s = -math.inf                # when it was taken
        self._begun_s = clock.now()
        self._base: dict[int, Sample] = {}      # each process's counters as the wait began (or as it was first seen)
        self._excused: dict[int, float] = {}    # each process's excuse at its last look
        self.begin()

    def begin(self) -> None:
        """A new wait begins now: nothing of it counted yet."""
        self._begun_s = now = self.clock.now()
        if now - self._read_s >= self.fresh_s:
            self._read()
        self._base, self._excused = dict(self._latest), {}

    def _read(self) -> dict[int, Sample]:
        self._read_s = self.clock.now()
        pids = list(dict.fromkeys((self.pid, *self.peers)))
        if self.tree:
            k = 0
            while k < len(pids) and len(pids) < 1000:
                pids += [p for p in children(pids[k], self.proc) if p not in pids]
                k += 1
        self._latest = {}
        for pid in pids:
            seen = sample(pid, self.proc)
            if seen is not None:
                self._latest[pid] = seen
        return self._latest

    def gone(self, seen: Optional[Sample]) -> Optional[str]:
        """Why the root process cannot be doing anything (given a look at it), or None."""
        if seen is None or seen.started != self._started:
            return "ended"
        return STOPPED.get(seen.state)

    def look(self) -> Look:
        wall_s = max(0.0, self.clock.now() - self._begun_s)
        samples = self._read()
        why = self.gone(samples.get(self.pid))
        if why is not None:
            return Look(wall_s, wall_s, why)
        for pid, seen in samples.items():
            base = self._base.setdefault(pid, Sample(seen.state, 0.0, 0.0, seen.started))   # new: born in the wait
            self._excused[pid] = _excuse(base, seen, wall_s)
        excused = max(self._excused.values(), default=0.0)
        return Look(wall_s, max(0.0, wall_s - excused))


def _excuse(base: Sample, seen: Sample, wall_s: float) -> float:
    """How much of `wall_s` one process was kept from running, from its counters then (`base`) and now (`seen`)."""
    if seen.started != base.started or seen.waited_s is None or base.waited_s is None:
        return 0.0
    if seen.state in ("R", "D"):
        # runnable: perhaps waiting for a CPU now, a wait run_delay does not hold yet; or in the kernel's
        # uninterruptible sleep (a page read from disk, memory reclaimed): waiting on the machine either way
        return min(wall_s, max(0.0, wall_s - (seen.cpu_s - base.cpu_s)))
    return min(wall_s, max(0.0, seen.waited_s - base.waited_s))


class LockstepWait:
    """The lock-step controller's wait for its plant's tick, judged on the plant's own time (a `WaitJudge`).

    The wall time waited, less what the thread that waits (this process's, running the controller) waited for a
    CPU meanwhile, and, where the plant's process is known (`plant_pid`: `aspod sim --hal`'s child, or `aspod
    firmware --plant-pid`), less what the plant's process waited for one. A plant whose process has ended or is
    stopped is excused nothing: its silence counts whole, from the wall clock. `last` is the plant's latest `Look`
    (None: not known, or not looked at yet), for the log to say why it was silent.
    """

    def __init__(self, clock: Clock, plant_pid: Optional[int] = None, fresh_s: float = FRESH_S) -> None:
        self.clock = clock
        self.fresh_s = fresh_s
        self.plant = None if plant_pid is None else OwnTime(plant_pid, clock, fresh_s=fresh_s)
        self.last: Optional[Look] = None
        self._mine: Optional[float] = None          # this thread's wait for a CPU at the latest reading
        self._mine_s = -math.inf                    # when it was read
        self._mine_base: Optional[float] = None     # ... as the wait began
        self.begin()

    def _read_mine(self) -> Optional[float]:
        self._mine_s = self.clock.now()
        self._mine = RealClock.cpu_wait_s(threading.get_native_id())
        return self._mine

    def begin(self) -> None:
        if self.clock.now() - self._mine_s >= self.fresh_s:
            self._read_mine()
        self._mine_base = self._mine
        if self.plant is not None:
            self.plant.begin()

    def own_s(self, waited_s: float) -> float:
        mine, base = self._read_mine(), self._mine_base
        excused = 0.0 if mine is None or base is None else max(0.0, mine - base)
        if self.plant is not None:
            self.last = look = self.plant.look()
            if look.gone is not None:
                return waited_s
            excused += look.wall_s - look.own_s
        return max(0.0, waited_s - excused)
