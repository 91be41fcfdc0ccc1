"""The cooperative scheduler and the injected clock."""
from __future__ import annotations

import math

import pytest

from timebase.scheduler import Scheduler, TaskStats, poll_tick
from timebase import SimClock


def make():
    clock = SimClock()
    return clock, Scheduler(clock, stopwatch=clock.now)


def test_periodic_tasks_run_at_their_wake_times_in_order():
    clock, sched = make()
    log = []
    sched.add("fast", lambda now: (log.append(("fast", round(now, 6))), now + 0.25)[1], 0.0)
    sched.add("slow", lambda now: (log.append(("slow", round(now, 6))), now + 0.5)[1], 0.0)
    sched.run_until(1.0)
    assert clock.now() == 1.0
    # tasks due at the same time run in the order their wake-ups were scheduled
    assert log == [("fast", 0.0), ("slow", 0.0), ("fast", 0.25), ("slow", 0.5), ("fast", 0.5),
                   ("fast", 0.75), ("slow", 1.0), ("fast", 1.0)]
    assert sched.tasks["fast"].stats.runs == 5


def test_returning_none_retires_a_task_and_remove_stops_one():
    clock, sched = make()
    runs = []
    sched.add("once", lambda now: runs.append(now), 0.1)
    sched.add("tick", lambda now: (runs.append(("tick", now)), now + 0.1)[1], 0.0)
    sched.run_until(0.15)
    assert "once" not in sched.tasks
    sched.remove("tick")
    sched.run_until(1.0)
    assert [r for r in runs if isinstance(r, tuple)] == [("tick", 0.0), ("tick", 0.1)]


def test_wake_brings_a_task_forward():
    clock, sched = make()
    seen = []
    sched.add("lazy", lambda now: (seen.append(now), now + 10.0)[1], 0.0)
    sched.run_until(1.0)
    sched.wake("lazy", 1.5)
    sched.run_until(2.0)
    assert seen == [0.0, 1.5]


def test_lateness_beyond_tolerance_counts_as_an_overrun():
    clock, sched = make()

    def hog(now):
        clock.advance_by(0.005)          # this task takes 5 ms of (simulated) time
        return now + 0.001
    sched.add("hog", hog, 0.0)
    sched.add("victim", lambda now: now + 0.001, 0.0, tolerance_s=0.002)
    sched.run_until(0.1)
    assert sched.tasks["victim"].stats.overruns > 0
    assert sched.tasks["hog"].stats.exec_max_s == pytest.approx(0.005)


def test_duplicate_names_are_refused():
    _, sched = make()
    sched.add("a", lambda now: None)
    with pytest.raises(ValueError, match="already scheduled"):
        sched.add("a", lambda now: None)


def test_sim_clock_never_goes_back():
    clock = SimClock(5.0)
    clock.sleep_until(1.0)
    assert clock.now() == 5.0
    with pytest.raises(ValueError):
        clock.advance_by(-1)


def test_periodic_tasks_stay_on_their_grid_and_skip_what_they_missed():
    clock = SimClock()
    sched = Scheduler(clock, stopwatch=clock.now)
    starts: list[float] = []

    def task(now: float) -> float:
        starts.append(now)
        if len(starts) == 3:
            clock.advance_by(0.0035)        # this run overran by three and a half periods
        return now + 0.5                 # ignored: the task is periodic

    sched.add("loop", task, 0.0, period_s=0.001)
    sched.run_until(0.0095)
    # on the 1 ms grid throughout; the periods at 3, 4 and 5 ms were missed and skipped
    assert [round(s * 1e4) for s in starts] == [0, 10, 20, 60, 70, 80, 90]
    assert sched.tasks["loop"].stats.skipped == 3


def test_tasks_due_together_run_by_priority():
    clock = SimClock()
    sched = Scheduler(clock, stopwatch=clock.now)
    order: list[str] = []
    for name, priority in (("plant", 10), ("hal", 10), ("arm", 0)):
        sched.add(name, lambda now, n=name: order.append(n) or now + 0.001, 0.0, priority=priority)
    sched.run_until(0.0)
    assert order == ["arm", "plant", "hal"]


def test_poll_tick_lands_on_the_very_float_a_polling_task_would_have_had():
    period, origin = 0.001, 0.0437
    polls = [origin]
    for _ in range(3000):
        polls.append(polls[-1] + period)          # what `return now + period` does, poll after poll
    for due in (0.0437, 0.04371, 0.0447, 0.5, 1.2345678, polls[1234], polls[1234] + 1e-12):
        assert poll_tick(origin, period, due) == min(p for p in polls[1:] if p >= due)
        assert poll_tick(origin, period, due, after=True) == min(p for p in polls[1:] if p > due)
    assert poll_tick(origin, period, -math.inf) == polls[1]       # due already: the next poll
    assert poll_tick(origin, period, math.inf) == math.inf        # nothing due: sleep


def test_a_periodic_grid_is_counted_never_summed():
    """The n-th period of a 1 ms task is n * 1 ms to the bit: summing 0.001 is off by ulps within ten
    periods and by half a tick within 53 simulated hours, where the lock-step clocks (which count
    ticks) would part from it. A wake-up restarts the grid where it lands."""
    clock = SimClock()
    sched = Scheduler(clock, stopwatch=clock.now)
    starts: list[float] = []
    sched.add("loop", lambda now: starts.append(now) or 0.0, 0.0, period_s=0.001)
    sched.run_until(20.0)
    assert len(starts) == 20_001
    assert [n for n, s in enumerate(starts) if s != n * 0.001] == []
    sched.wake("loop", 20.0003)
    sched.run_until(20.0053)
    assert starts[-6:] == [20.0003 + n * 0.001 for n in range(6)]


def test_without_a_stopwatch_tasks_run_the_same_and_take_no_time():
    """`stopwatch=None` (a simulated clock): the same runs at the same times, missed periods still counted,
    execution time 0 and the stopwatch never read."""
    runs = {}
    for stopwatch in ("clock", None):
        clock = SimClock()
        sched = Scheduler(clock, stopwatch=clock.now if stopwatch else None)
        log = []

        def late_task(now, log=log, clock=clock):
            log.append(round(now, 6))
            clock.sleep_until(now + 0.003)        # runs 3 ms: the next period is missed
            return now
        sched.add("loop", late_task, period_s=0.002, tolerance_s=0.0005)
        sched.run_until(0.02)
        stats = sched.tasks["loop"].stats
        runs[stopwatch] = (log, stats.runs, stats.overruns, stats.skipped, round(stats.late_max_s, 9))
        if stopwatch is None:
            assert stats.exec_total_s == 0.0 and stats.exec_max_s == 0.0 and stats.exec_p99_s <= 1e-6
        else:
            assert stats.exec_max_s == pytest.approx(0.003)
    assert runs["clock"] == runs[None] and runs[None][3] > 0       # periods skipped alike


def test_an_untimed_run_is_recorded_as_a_run_that_took_no_time():
    timed, untimed = TaskStats(), TaskStats()
    for late_s, overrun in [(0.0, False), (0.002, True), (0.001, False)]:
        timed.record(0.0, late_s, overrun)
        untimed.record_untimed(late_s, overrun)
    assert untimed == timed and untimed._hist == timed._hist and untimed.exec_p99_s == timed.exec_p99_s
    assert (untimed.runs, untimed.overruns, untimed.late_max_s) == (3, 1, 0.002)


def _group_world(ahead: bool) -> tuple[Scheduler, list]:
    """Three 1 ms tasks run back to back (as the lock-step world's arm, plant and hal) among others at odd times;
    with `ahead`, a runner that runs them itself, some periods at a time."""
    clock = SimClock()
    scheduler = Scheduler(clock, stopwatch=None)
    log: list = []

    def task(name, every=0.0):
        def fn(now):
            log.append((name, now))
            return now + every          # (a periodic task: only None, which retires it, would matter)
        return fn
    scheduler.add("arm", task("arm"), period_s=0.001, priority=0)
    scheduler.add("plant", task("plant"), period_s=0.001)
    scheduler.add("hal", task("hal"), period_s=0.001)
    scheduler.add("slow", task("slow", 0.0073), 0.0021)
    scheduler.add("grid", task("grid", 0.01), 0.01)
    scheduler.add("tracker", task("tracker", 0.01), 0.005, priority=5)
    if ahead:
        fns = [scheduler.tasks[name].fn for name in ("arm", "plant", "hal")]
        offered = []

        def runner(origin, period, n, ticks):
            offered.append(ticks)
            ran = min(ticks, 1 + len(offered) % 4)        # some of what is offered, as the fast loop stops early
            for k in range(ran):
                for fn in fns:
                    fn(origin + (n + k) * period)
            return ran
        scheduler.run_ahead(("arm", "plant", "hal"), runner)
    return scheduler, log


def test_run_ahead_runs_the_group_as_run_due_would_and_leaves_the_same_statistics_and_heap():
    plain, plain_log = _group_world(False)
    ahead, ahead_log = _group_world(True)
    for scheduler in (plain, ahead):
        scheduler.run_until(0.5)
    assert ahead.ticks_ahead > 250                      # most of the 500 periods
    assert ahead_log == plain_log and len(plain_log) > 1500
    assert {n: (t.stats.runs, t.stats.late_max_s, t.wake_s, t.grid_n) for n, t in ahead.tasks.items()} == \
        {n: (t.stats.runs, t.stats.late_max_s, t.wake_s, t.grid_n) for n, t in plain.tasks.items()}
    assert ahead.clock.now() == plain.clock.now() == 0.5
    for scheduler in (plain, ahead):                    # and on from there, tick by tick, the same
        scheduler.run_ahead((), None)
        scheduler.run_until(0.6)
    assert ahead_log == plain_log


def test_run_ahead_is_for_a_scheduler_without_a_stopwatch():
    scheduler = Scheduler(SimClock())
    scheduler.add("arm", lambda now: now, period_s=0.001)
    with pytest.raises(ValueError, match="stopwatch"):
        scheduler.run_ahead(("arm",), lambda *args: 0)


def test_run_until_with_a_bound_ends_at_the_bound_once_a_task_has_run():
    clock = SimClock()
    scheduler = Scheduler(clock, stopwatch=None)
    scheduler.add("once", lambda now: None, 0.0123)
    scheduler.run_until(1.0, bound=lambda at: at + 0.001)
    assert clock.now() == 0.0123 + 0.001
    scheduler.run_until(1.0, bound=lambda at: at + 0.001)      # nothing left to run: to the end
    assert clock.now() == 1.0
