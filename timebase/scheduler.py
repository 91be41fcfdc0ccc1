"""Cooperative scheduler: one thread, tasks that take `now` and return their next wake time.

As in Klipper's reactor, a task returns when it next wants to run; returning ``None``
retires it. A task added with `period_s` is phase-locked instead: it is due again at
its previous deadline plus the period, whatever its own lateness, so a 1 kHz loop runs
at 1 kHz on average and every 1 ms task shares one grid (returning `now + period`
would stretch each period by that run's lateness). The grid is counted, origin + n periods,
never summed, so it stays on n * period however long the run. A periodic task that falls more
than a whole period behind skips the periods it missed (counted in `skipped`) rather
than running back to back to catch up. Tasks due at the same time run by `priority`
(lower first), then in the order their wake-ups were scheduled. Execution time
is measured with a separate stopwatch (the wall clock's by default, injectable), or not at
all (`stopwatch=None`: on a simulated clock a task takes no time, so there is nothing to
measure and a lock-step run stays byte-for-byte deterministic); lateness against the
requested wake time is counted as an overrun when it exceeds the task's tolerance.

`run_ahead(names, runner)`: periodic tasks that run back to back at every period (the lock-step
world's 1 kHz loops) may be run for many periods at once by one call that does what running them
would, while nothing else is due (`Scheduler._run_ahead`; docs/Code_Overview.md, "The fast loop
between events").
"""
from __future__ import annotations

import itertools
import math
from heapq import heappop, heappush
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

from timebase import Clock, RealClock

TaskFn = Callable[[float], Optional[float]]
# `run_ahead`'s runner: (grid origin, period, the first tick's grid index, ticks at most) -> ticks it ran
AheadFn = Callable[[float, float, int, int], int]

_HIST_BUCKETS = 32  # log2 buckets of microseconds: bucket b holds [2**(b-1), 2**b) us
AHEAD_MAX_TICKS = 1000   # periods `run_until` offers `run_ahead`'s runner at a time


@dataclass
class TaskStats:
    """Timing of one task: runs, execution time (max, p99) and lateness."""

    runs: int = 0
    exec_total_s: float = 0.0
    exec_max_s: float = 0.0
    late_max_s: float = 0.0
    overruns: int = 0
    skipped: int = 0          # periods a periodic task missed entirely (it was more than a period late)
    _hist: list[int] = field(default_factory=lambda: [0] * _HIST_BUCKETS, repr=False)

    def record(self, exec_s: float, late_s: float, overrun: bool) -> None:
        self.runs += 1
        self.exec_total_s += exec_s
        if exec_s > self.exec_max_s:
            self.exec_max_s = exec_s
        if late_s > self.late_max_s:
            self.late_max_s = late_s
        if overrun:
            self.overruns += 1
        bucket = int(exec_s * 1e6).bit_length()
        self._hist[bucket if bucket < _HIST_BUCKETS else _HIST_BUCKETS - 1] += 1

    def record_untimed(self, late_s: float, overrun: bool) -> None:
        """`record` of a run on a simulated clock, where execution takes no time (exec_s 0).

        (`Scheduler.run_due` writes this out: it runs for every task run.)"""
        self.runs += 1
        if late_s > self.late_max_s:
            self.late_max_s = late_s
        if overrun:
            self.overruns += 1
        self._hist[0] += 1

    @property
    def exec_p99_s(self) -> float:
        """Upper bound of the bucket holding the 99th percentile (within a factor of 2)."""
        if not self.runs:
            return 0.0
        threshold = 0.99 * self.runs
        seen = 0
        for bucket, count in enumerate(self._hist):
            seen += count
            if seen >= threshold:
                return (1 << bucket) * 1e-6
        return self.exec_max_s


def poll_tick(origin_s: float, period_s: float, t_s: float, *, after: bool = False) -> float:
    """The first of the polls `origin_s + period_s`, `+ period_s` again, ... at or after `t_s`
    (strictly after, with `after`).

    For a task that polls every `period_s` from its last run at `origin_s` (returning
    `now + period_s` each time) but sleeps while polling would find nothing: it wakes at the
    very poll that would first have seen a timer due at `t_s`, or (`after`) news that came at
    `t_s` once that moment's poll was done. The polls are summed one period at a time, as the
    polling task sums them, so a wake lands on the same float the poll would have had.
    """
    if t_s == math.inf:
        return t_s
    t = origin_s + period_s
    if after:
        while t <= t_s:
            t += period_s
    else:
        while t < t_s:
            t += period_s
    return t


class Task:
    """A scheduled callable with its own statistics."""

    def __init__(self, name: str, fn: TaskFn, tolerance_s: float, period_s: Optional[float] = None,
                 priority: int = 10) -> None:
        self.name = name
        self.fn = fn
        self.tolerance_s = tolerance_s
        self.period_s = period_s
        self.priority = priority
        self.stats = TaskStats()
        self.wake_s: Optional[float] = None
        self.removed = False      # retired (`Scheduler.remove`, or its function returned None)
        # A periodic task's grid: its n-th period falls at grid_origin_s + n * period_s. Multiplied, not
        # summed: summing 1 ms drifts half a tick from n * 1 ms within 53 simulated hours, and the
        # lock-step clocks count ticks (n * period) against this grid.
        self.grid_origin_s = 0.0
        self.grid_n = 0


class Scheduler:
    """Runs tasks in wake-time order on an injected clock."""

    def __init__(self, clock: Clock, stopwatch: Optional[Callable[[], float]] = RealClock.precise_now) -> None:
        self.clock = clock
        self._stopwatch = stopwatch
        self._heap: list[tuple[float, int, int, Task]] = []
        self._order = itertools.count()
        self.tasks: dict[str, Task] = {}
        self._ahead: Optional[tuple[tuple[Task, ...], AheadFn]] = None
        self.ticks_ahead = 0        # periods `run_ahead`'s runner ran (each runs every task of its group)

    def add(self, name: str, fn: TaskFn, first_wake_s: Optional[float] = None,
            tolerance_s: float = 0.002, *, period_s: Optional[float] = None, priority: int = 10) -> Task:
        """Schedule `fn` to run first at `first_wake_s` (default: now).

        With `period_s` the task is periodic and phase-locked (see the module doc); what
        `fn` returns then only matters if it is None (retire).
        """
        if name in self.tasks:
            raise ValueError(f"a task named {name!r} is already scheduled")
        if period_s is not None and not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        task = Task(name, fn, tolerance_s, period_s, priority)
        self.tasks[name] = task
        self._push(task, self.clock.now() if first_wake_s is None else first_wake_s)
        return task

    def wake(self, name: str, at_s: Optional[float] = None) -> None:
        """Bring a task's next run forward to `at_s` (default: now)."""
        task = self.tasks[name]
        at_s = self.clock.now() if at_s is None else at_s
        if task.wake_s is None or at_s < task.wake_s:
            self._push(task, at_s)

    def remove(self, name: str) -> None:
        """Retire a task; its queued wake-ups are discarded lazily."""
        task = self.tasks.pop(name)
        task.wake_s = None
        task.removed = True

    def _push(self, task: Task, wake_s: float) -> None:
        task.wake_s = wake_s
        task.grid_origin_s, task.grid_n = wake_s, 0     # a periodic task's grid restarts where it is woken
        heappush(self._heap, (wake_s, task.priority, next(self._order), task))

    def next_wake_s(self) -> Optional[float]:
        while self._heap and self._heap[0][0] != self._heap[0][3].wake_s:
            heappop(self._heap)  # superseded by a later push
        return self._heap[0][0] if self._heap else None

    def run_due(self) -> int:
        """Run every task whose wake time had come when called; return how many ran.

        A task that keeps overrunning is due again at once, so only what was due at
        entry runs here: the caller's loop gets control back whatever the tasks do.
        (This runs for every task run: 6-8 a simulated millisecond in the lock-step world,
        whose budget is 50 us a millisecond for everything. Hence the local names and
        the heap handled in place rather than through `next_wake_s` and `_push`.)
        """
        heap, tasks, clock_now, stopwatch = self._heap, self.tasks, self.clock.now, self._stopwatch
        ran = 0
        horizon = now = clock_now()
        while heap:
            wake, _, _, task = heap[0]
            if wake != task.wake_s:
                heappop(heap)      # superseded by a later push
                continue
            if wake > horizon:
                break
            heappop(heap)
            task.wake_s = None
            late_s = now - wake
            if stopwatch is None:
                next_wake = task.fn(now)
                stats = task.stats                       # stats.record_untimed(...), written out
                stats.runs += 1
                if late_s > stats.late_max_s:
                    stats.late_max_s = late_s
                if late_s > task.tolerance_s:
                    stats.overruns += 1
                stats._hist[0] += 1
            else:
                start = stopwatch()
                next_wake = task.fn(now)
                task.stats.record(stopwatch() - start, late_s, late_s > task.tolerance_s)
            ran += 1
            now = clock_now()
            if task.removed:
                pass   # removed while it ran
            elif next_wake is None:
                del tasks[task.name]
                task.removed = True
            else:
                period = task.period_s
                if period is None:
                    if task.wake_s is None or next_wake < task.wake_s:
                        task.wake_s = next_wake
                        heappush(heap, (next_wake, task.priority, next(self._order), task))
                elif task.wake_s is None:    # (woken while it ran: that wake-up stands, its grid restarted there)
                    n = task.grid_n + 1
                    next_wake = task.grid_origin_s + n * period
                    if next_wake <= now:     # a whole period (or more) missed: skip to the next on the grid
                        missed = int((now - wake) / period)
                        task.stats.skipped += missed
                        n += missed
                        next_wake = task.grid_origin_s + n * period
                    task.wake_s, task.grid_n = next_wake, n
                    heappush(heap, (next_wake, task.priority, next(self._order), task))
        return ran

    def run_ahead(self, names: Sequence[str], runner: AheadFn) -> None:
        """Let `run_until` hand the periodic tasks `names` to `runner` for as many periods as come before anything
        else is due (`_run_ahead`). `runner(origin_s, period_s, n, ticks)` runs them, in this order, at the times
        `origin_s + k * period_s` for k from n, as running each in turn would, for at most `ticks` periods or until it
        meets something it leaves to them (0: none); returns how many it ran. For a simulated clock without a
        stopwatch (a task takes no time); None `names` ends it."""
        if not names:
            self._ahead = None
            return
        if self._stopwatch is not None:
            raise ValueError("run_ahead: only without a stopwatch (on a simulated clock a task takes no time)")
        self._ahead = (tuple(self.tasks[name] for name in names), runner)

    def run_until(self, end_s: float, bound: Optional[Callable[[float], float]] = None) -> None:
        """Run tasks until the clock reaches `end_s` (jumps ahead on a SimClock). With `bound`, once any task has
        run (the run-ahead group's runner aside), the run ends at `bound(now)` instead if that is earlier."""
        while True:
            if self.run_due() and bound is not None:
                end_s = min(end_s, bound(self.clock.now()))
            wake = self.next_wake_s()
            if wake is None or wake > end_s:
                self.clock.sleep_until(end_s)
                self.run_due()
                return
            self.clock.sleep_until(wake)
            if self._ahead is not None and self._stopwatch is None:   # (a bench may set a stopwatch later)
                self._run_ahead(wake, end_s)

    def _run_ahead(self, wake: float, end_s: float) -> None:
        """The group's runner for the periods from `wake` on, up to `end_s`, before any other task is due.

        Only when the group's tasks are the heap's first entries, at `wake`, in the group's order, one after the
        other (so nothing runs between them), on one grid; the periods offered stop before the first other task's
        wake time (due at the same time, it might run between them). Afterwards everything is as if each had run
        as `run_due` runs it: statistics (no stopwatch: runs, none late), grids, and heap entries pushed in the
        group's order with fresh order numbers (the last tick's pushes), the clock at the last period run."""
        group, runner = self._ahead
        heap = self._heap
        first = group[0]
        origin, period, n = first.grid_origin_s, first.period_s, first.grid_n
        if period is None or origin + n * period != wake:
            return
        popped = []
        for task in group:
            while heap and heap[0][0] != heap[0][3].wake_s:
                heappop(heap)       # superseded by a later push
            if (not heap or heap[0][3] is not task or heap[0][0] != wake or task.period_s != period
                    or task.grid_origin_s != origin or task.grid_n != n):
                break
            popped.append(heappop(heap))
        if len(popped) == len(group):
            while heap and heap[0][0] != heap[0][3].wake_s:
                heappop(heap)
            other = heap[0][0] if heap else math.inf
            ticks = 0
            while ticks < AHEAD_MAX_TICKS:
                at = origin + (n + ticks) * period
                if at > end_s or at >= other:
                    break
                ticks += 1
            ran = runner(origin, period, n, ticks) if ticks else 0
            if ran:
                n += ran
                for task in group:
                    stats = task.stats
                    stats.runs += ran
                    stats._hist[0] += ran
                    task.grid_n = n
                    task.wake_s = origin + n * period
                    heappush(heap, (task.wake_s, task.priority, next(self._order), task))
                self.ticks_ahead += ran
                self.clock.sleep_until(origin + (n - 1) * period)
                return
        for entry in popped:
            heappush(heap, entry)   # as they were: `run_due` runs them

    def run_forever(self, should_stop: Callable[[], bool] = lambda: False) -> None:
        while not should_stop():
            self.run_due()
            wake = self.next_wake_s()
            if wake is None:
                return
            self.clock.sleep_until(wake)


def run_live(control: Scheduler, link: Scheduler, should_stop: Callable[[], bool] = lambda: False) -> None:
    """Run two schedulers in one thread: `control` on its own clock, `link` on the wall clock.

    A live run keeps two times (docs/Code_Overview.md, "Time"). The control tasks (plant,
    motor loops, health, telemetry) run on `control.clock`: the wall clock itself on real
    hardware, simulated time paced to the wall clock in a one-process simulator
    (`timebase.PacedClock`), or time granted tick by tick over the HAL bus in lock-step
    (`protocol.lockstep`). The link to the host is a real process on the other end of a
    real port, so its task runs on the wall clock (`link.clock`) whatever the world's time
    does: `control.clock.advance(next control wake, next link wake)` returns in time for
    the link, and when the world is late it catches up one deadline at a time, with the
    link served between them. Returns when `should_stop()` or when neither has a task left.
    """
    advance = control.clock.advance
    inf = math.inf
    while not should_stop():
        link.run_due()
        control.run_due()
        control_wake = control.next_wake_s()
        link_wake = link.next_wake_s()
        if control_wake is None and link_wake is None:
            return
        advance(inf if control_wake is None else control_wake, inf if link_wake is None else link_wake)
