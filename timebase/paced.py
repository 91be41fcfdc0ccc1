"""Simulated time paced to the wall clock: a live world that slows down rather than jumps.

A live simulator whose plant and controller share one process can run them on one
simulated time. `PacedClock` lets that time advance no faster than the wall clock (times
`speed`), but never jumps it: when the process falls behind (the host was busy, the OS
descheduled it), simulated time falls behind with it and the world catches up by running
its tasks back to back, each at its own simulated instant. The plant then never integrates
a stall the controller did not live through, so a busy host can never look like a hardware
fault. A world that falls more than `max_lag_s` behind gives that lag up for good
(`slipped_s`, counted) and is paced again from where it stands, rather than racing for
seconds to catch up.

`RateMeter` measures the real-time factor (simulated seconds per wall second) over about
the last second and since the start; the paced clock and the lock-step clocks
(`protocol.lockstep`) report it through `Clock.timing()`.

Both take the wall clock as an argument (a `RealClock` in a live run, a `SimClock` standing
in for it in tests), so nothing here reads the OS clock.
"""
from __future__ import annotations

import math
from collections import deque

from timebase.clock import Clock, TimingReport


class RateMeter:
    """Simulated seconds per wall second, over a sliding window and since the start.

    `sample(wall_s, sim_s)` records a point at most every `every_s` of wall time; the
    window keeps the points of the last `window_s` (and one before it), so it holds at
    most window_s / every_s + 2 of them whatever the run's length.
    """

    def __init__(self, wall_s: float, sim_s: float, window_s: float = 1.0, every_s: float = 0.05) -> None:
        if not (window_s > 0 and every_s > 0):
            raise ValueError("window_s and every_s must be > 0")
        self.window_s = window_s
        self.every_s = every_s
        self._start = (wall_s, sim_s)
        self._points: deque[tuple[float, float]] = deque([(wall_s, sim_s)])

    def sample(self, wall_s: float, sim_s: float) -> None:
        points = self._points
        if wall_s - points[-1][0] < self.every_s:
            return
        points.append((wall_s, sim_s))
        while len(points) > 2 and wall_s - points[1][0] >= self.window_s:
            points.popleft()

    def recent(self, wall_s: float, sim_s: float) -> float:
        """The factor from the oldest point in the window to (`wall_s`, `sim_s`); NaN until the points
        span half the window (a factor over a few milliseconds says nothing)."""
        old_wall, old_sim = self._points[0]
        return (sim_s - old_sim) / (wall_s - old_wall) if wall_s - old_wall >= self.window_s / 2 else math.nan

    def total(self, wall_s: float, sim_s: float) -> float:
        start_wall, start_sim = self._start
        return (sim_s - start_sim) / (wall_s - start_wall) if wall_s > start_wall else math.nan


class PacedClock(Clock):
    """Simulated time that runs at `speed` times the wall clock at most, and slows down when late.

    `speed` is a positive factor, or `math.inf` for as fast as the work allows. Waiting
    (`sleep_until`, `advance`) sleeps on the `wall` clock until the deadline's moment comes;
    when it has already passed, time moves to the deadline at once (no further), and the
    world catches up one deadline at a time. `lag_s` is how late the last deadline was
    reached, in wall seconds; past `max_lag_s` the lag is given up (`slipped_s`, `slips`).
    """

    def __init__(self, wall: Clock, speed: float = 1.0, start_s: float = 0.0, max_lag_s: float = 0.5) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0 (or inf), got {speed}")
        if not max_lag_s > 0:
            raise ValueError(f"max_lag_s must be > 0, got {max_lag_s}")
        self.wall = wall
        self.speed = float(speed)
        self.max_lag_s = max_lag_s
        self._now = float(start_s)
        wall_now = wall.now()
        self._anchor = (wall_now, self._now)     # (wall, simulated) moments that correspond
        self.lag_s = 0.0
        self.slipped_s = 0.0
        self.slips = 0
        self.meter = RateMeter(wall_now, self._now)

    def now(self) -> float:
        return self._now

    def start(self) -> None:
        """Pace from this moment: the time spent before the run (building the world) is not lag."""
        wall_now = self.wall.now()
        self._anchor = (wall_now, self._now)
        self.lag_s = 0.0
        self.meter = RateMeter(wall_now, self._now)

    def due_wall_s(self, sim_s: float) -> float:
        """The wall-clock moment at which simulated time `sim_s` is due (-inf at infinite speed)."""
        if self.speed == math.inf:
            return -math.inf
        anchor_wall, anchor_sim = self._anchor
        return anchor_wall + (sim_s - anchor_sim) / self.speed

    def sleep_until(self, deadline: float) -> None:
        self.advance(deadline, math.inf)

    def advance(self, deadline: float, wall_deadline: float) -> None:
        if deadline <= self._now:
            return
        due = self.due_wall_s(deadline)
        wall = self.wall
        wall_now = wall.now()
        if due > wall_now:
            wall.sleep_until(min(due, wall_deadline))
            wall_now = wall.now()
            if wall_now < due:           # woken for the wall clock's sake: not there yet
                self.meter.sample(wall_now, self._now)
                return
        self._now = float(deadline)
        lag = max(0.0, wall_now - due) if due != -math.inf else 0.0
        if lag > self.max_lag_s:         # too far behind to catch up: pace again from here
            self.slipped_s += lag
            self.slips += 1
            self._anchor = (wall_now, self._now)
            lag = 0.0
        self.lag_s = lag
        self.meter.sample(wall_now, self._now)

    def timing(self) -> TimingReport:
        wall_now = self.wall.now()
        return TimingReport("paced", self.meter.recent(wall_now, self._now), self.meter.total(wall_now, self._now),
                            self.lag_s, self.slipped_s)
