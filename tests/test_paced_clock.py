"""Simulated time paced to the wall clock: late, it slows down instead of jumping (timebase/paced.py).

The wall clock here is a `SimClock` the tests move by hand, so a stall of the host is a jump of
it that the paced clock did not ask for.
"""
from __future__ import annotations

import math

import pytest

from timebase.scheduler import Scheduler, run_live
from timebase import PacedClock, RateMeter, SimClock


def test_on_time_it_sleeps_until_each_deadline_and_reaches_it():
    wall = SimClock(100.0)
    clock = PacedClock(wall)
    clock.sleep_until(0.25)
    assert clock.now() == 0.25 and wall.now() == pytest.approx(100.25)
    assert clock.lag_s == 0.0 and clock.slips == 0


def test_late_it_moves_to_the_next_deadline_only_and_catches_up_one_deadline_at_a_time():
    wall = SimClock()
    clock = PacedClock(wall)
    clock.sleep_until(0.001)
    wall.advance_by(0.030)                      # the host stalled the process for 30 ms
    clock.sleep_until(0.002)
    assert clock.now() == 0.002                 # not 0.031: the world never jumps
    assert clock.lag_s == pytest.approx(0.029)
    for k in range(3, 32):                      # the next deadlines are due at once: the world catches up
        clock.sleep_until(k * 0.001)
    assert wall.now() == pytest.approx(0.031)   # without sleeping
    clock.sleep_until(0.032)
    assert wall.now() == pytest.approx(0.032) and clock.lag_s == 0.0 and clock.slips == 0


def test_too_far_behind_it_gives_the_lag_up_and_paces_again_from_there():
    wall = SimClock()
    clock = PacedClock(wall, max_lag_s=0.5)
    wall.advance_by(2.0)                        # a 2 s stall: beyond what it catches up
    clock.sleep_until(0.001)
    assert clock.now() == 0.001 and clock.slips == 1 and clock.slipped_s == pytest.approx(1.999)
    clock.sleep_until(0.002)
    assert wall.now() == pytest.approx(2.001)   # paced again: the next millisecond takes a millisecond


def test_it_returns_by_the_wall_deadline_without_advancing():
    wall = SimClock()
    clock = PacedClock(wall)
    clock.advance(1.0, wall_deadline=0.2)
    assert clock.now() == 0.0 and wall.now() == pytest.approx(0.2)
    clock.advance(1.0, wall_deadline=math.inf)
    assert clock.now() == 1.0 and wall.now() == pytest.approx(1.0)


@pytest.mark.parametrize("speed, wall_s", [(2.0, 0.5), (math.inf, 0.0)])
def test_speed_scales_the_pace(speed, wall_s):
    wall = SimClock()
    clock = PacedClock(wall, speed)
    clock.sleep_until(1.0)
    assert clock.now() == 1.0 and wall.now() == pytest.approx(wall_s)


def test_start_does_not_count_the_time_spent_before_the_run_as_lag():
    wall = SimClock()
    clock = PacedClock(wall)
    wall.advance_by(3.0)                         # building the world took 3 s
    clock.start()
    clock.sleep_until(0.001)
    assert clock.slips == 0 and clock.lag_s == 0.0 and wall.now() == pytest.approx(3.001)


def test_the_rate_meter_measures_over_the_last_second_and_since_start():
    meter = RateMeter(0.0, 0.0)
    assert math.isnan(meter.recent(0.2, 0.2))    # too short a span to say anything
    for k in range(1, 21):                       # 1 s at full speed ...
        meter.sample(k * 0.05, k * 0.05)
    for k in range(21, 41):                      # ... then 1 s at half speed
        meter.sample(k * 0.05, 1.0 + (k - 20) * 0.025)
    assert meter.recent(2.0, 1.5) == pytest.approx(0.5, abs=0.03)
    assert meter.total(2.0, 1.5) == pytest.approx(0.75)
    assert len(meter._points) <= 1.0 / 0.05 + 2  # bounded, whatever the run's length


def test_run_live_serves_the_wall_clock_tasks_while_the_world_catches_up():
    """The link (wall clock) keeps its 1 ms polls while the world (paced) catches up after a stall."""
    wall = SimClock()
    world = Scheduler(PacedClock(wall))
    link = Scheduler(wall)
    world_runs, link_runs, stall = [], [], [True]

    def world_tick(now):
        world_runs.append(now)
        if stall and now >= 0.010:
            stall.clear()
            wall.advance_by(0.050)               # the process was descheduled for 50 ms
        return now + 0.001

    world.add("tick", world_tick, period_s=0.001)
    link.add("poll", lambda now: (link_runs.append(now), now + 0.001)[1])
    run_live(world, link, lambda: wall.now() >= 0.2)
    # the world ran every simulated millisecond, none skipped, and caught up: 200 ticks in 200 wall ms
    assert world_runs == pytest.approx([k * 0.001 for k in range(len(world_runs))])
    assert world.tasks["tick"].stats.skipped == 0 and 195 <= len(world_runs) <= 201
    # the link polled on the wall clock throughout, catching up included
    late_polls = [t for t in link_runs if 0.060 < t < 0.2]
    assert len(late_polls) >= 130


# ---- held (pause), stepped, resumed: the control endpoint's hand on time (host_tools/worlds/plant_control.py) ----

def test_held_time_stands_still_while_the_wall_clock_and_its_tasks_go_on():
    wall = SimClock()
    world = Scheduler(PacedClock(wall))
    link = Scheduler(wall)
    world_runs, link_runs = [], []
    world.add("tick", lambda now: world_runs.append(now), period_s=0.001)
    link.add("poll", lambda now: (link_runs.append(now), now + 0.001)[1])
    run_live(world, link, lambda: wall.now() >= 0.1)
    world.clock.pause()
    ticks, held_at = len(world_runs), world.clock.now()
    run_live(world, link, lambda: wall.now() >= 1.1)            # a wall second held
    assert len(world_runs) == ticks and world.clock.now() == held_at
    assert len([t for t in link_runs if 0.1 < t <= 1.1]) >= 990  # the link polled all along
    assert world.clock.paused and not world.clock.stepping


def held_after_a_second(held_s: float) -> tuple[SimClock, PacedClock]:
    """A paced clock that ran a simulated second on time, then was held for `held_s` wall seconds."""
    wall = SimClock()
    clock = PacedClock(wall)
    for k in range(1, 1001):
        clock.sleep_until(k * 0.001)
    clock.pause()
    wall.advance_by(held_s)
    return wall, clock


def test_a_held_clock_reports_no_recent_rate_and_no_lag_so_it_is_never_slow():
    wall, clock = held_after_a_second(5.0)
    timing = clock.timing()
    assert math.isnan(timing.rtf_recent) and timing.lag_s == 0.0
    assert timing.rtf_total == pytest.approx(1.0)


def test_resume_paces_from_where_time_stands_and_counts_no_lag_and_no_slow_spell():
    wall, clock = held_after_a_second(30.0)     # held for 30 wall seconds: far beyond max_lag_s
    clock.resume()
    for k in range(1001, 2001):
        clock.sleep_until(k * 0.001)
    assert wall.now() == pytest.approx(32.0)     # paced from the resume: a simulated second took a wall second
    assert clock.slips == 0 and clock.lag_s == 0.0
    timing = clock.timing()
    assert timing.rtf_recent == pytest.approx(1.0, abs=0.06)
    assert timing.rtf_total == pytest.approx(1.0)    # the 30 held seconds left out


def test_a_step_runs_held_time_to_its_end_at_once_then_holds_it_there():
    wall = SimClock()
    clock = PacedClock(wall)
    clock.pause()
    clock.step_to(0.5)
    assert clock.stepping and clock.step_end_s == 0.5
    for k in range(1, 501):                      # the world's 1 ms deadlines, without waiting on the wall clock
        clock.advance(k * 0.001, math.inf)
    assert clock.now() == 0.5 and wall.now() == 0.0
    assert not clock.stepping and clock.paused and clock.step_end_s is None
    clock.advance(0.501, math.inf)               # held again after the step
    assert clock.now() == 0.5 and wall.now() == pytest.approx(PacedClock.HELD_WAIT_S)


def test_a_step_ends_exactly_at_its_end_between_two_deadlines():
    wall = SimClock()
    clock = PacedClock(wall)
    clock.pause()
    clock.step_to(0.0105)
    clock.advance(0.010, math.inf)
    clock.advance(0.011, math.inf)
    assert clock.now() == 0.0105 and wall.now() == 0.0


def test_pause_ends_a_step_under_way_and_step_needs_a_held_clock():
    wall = SimClock()
    clock = PacedClock(wall)
    with pytest.raises(ValueError, match="pause it first"):
        clock.step_to(1.0)
    clock.pause()
    clock.step_to(1.0)
    clock.advance(0.2, math.inf)
    clock.pause()
    clock.advance(0.3, math.inf)
    assert clock.now() == 0.2 and not clock.stepping
    for bad in (0.1, math.nan, math.inf):
        with pytest.raises(ValueError):
            clock.step_to(bad)
    with pytest.raises(RuntimeError, match="held"):
        clock.sleep_until(0.5)


def test_held_with_nothing_on_the_wall_clock_it_still_returns():
    wall = SimClock()
    clock = PacedClock(wall)
    clock.pause()
    clock.advance(1.0, math.inf)
    assert clock.now() == 0.0 and wall.now() == pytest.approx(PacedClock.HELD_WAIT_S)
    clock.resume()
    clock.resume()                               # running: nothing changes
    clock.advance(1.0, math.inf)
    assert clock.now() == 1.0
