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

A paced clock can also be held (`pause`): simulated time stands still, the plant and the
control loops with it, while whatever runs on the wall clock (the controller's link) goes on.
`step_to` lets a held world run to a later moment as fast as the work allows, then holds it
again; `resume` paces it from where it stands, so the wall time spent held is neither lag nor
a slow world (the rate meter's window starts afresh and its total leaves that time out).
A test harness's hand on the simulator (host_tools/worlds/plant_control.py), never a
controller's: real hardware cannot be paused.

Both take the wall clock as an argument (a `RealClock` in a live run, a `SimClock` standing
in for it in tests), so nothing here reads the OS clock.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Optional

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

    def leave_out(self, wall_s: float, sim_s: float, held_wall_s: float) -> None:
        """`held_wall_s` of wall time, ending at (`wall_s`, `sim_s`), did not count (the world was held): the
        window starts afresh there, and the total is taken as if that time had not passed."""
        start_wall, start_sim = self._start
        self._start = (start_wall + held_wall_s, start_sim)
        self._points = deque([(wall_s, sim_s)])


class PacedClock(Clock):
    """Simulated time that runs at `speed` times the wall clock at most, and slows down when late.

    `speed` is a positive factor, or `math.inf` for as fast as the work allows. Waiting
    (`sleep_until`, `advance`) sleeps on the `wall` clock until the deadline's moment comes;
    when it has already passed, time moves to the deadline at once (no further), and the
    world catches up one deadline at a time. `lag_s` is how late the last deadline was
    reached, in wall seconds; past `max_lag_s` the lag is given up (`slipped_s`, `slips`).

    Held (`pause`), `advance` moves no time: it waits on the wall clock for the wall deadline (at
    most `HELD_WAIT_S`, so a caller with nothing on the wall clock still gets control back) and
    returns; while stepping (`step_to`) it moves to each deadline at once, up to the step's end.
    """

    HELD_WAIT_S = 0.05      # held, `advance` returns at least this often (wall seconds)

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
        self._held_since: Optional[float] = None     # wall moment of `pause`; None: running
        self._hold_s = math.inf                       # held: time may run up to here (a step), no further

    def now(self) -> float:
        return self._now

    @property
    def paused(self) -> bool:
        return self._held_since is not None

    @property
    def stepping(self) -> bool:
        """Held, but running to the end of a step (`step_to`)."""
        return self._held_since is not None and self._now < self._hold_s

    @property
    def step_end_s(self) -> Optional[float]:
        """Where the step under way ends (None: none under way)."""
        return self._hold_s if self.stepping else None

    def pause(self) -> None:
        """Hold simulated time where it stands (a step under way ends here). Held already: nothing changes."""
        if self._held_since is None:
            self._held_since = self.wall.now()
        self._hold_s = self._now

    def resume(self) -> None:
        """Pace again from where time stands; the wall time spent held is not lag. Running: nothing changes."""
        if self._held_since is None:
            return
        wall_now = self.wall.now()
        self.meter.leave_out(wall_now, self._now, wall_now - self._held_since)
        self._anchor = (wall_now, self._now)
        self.lag_s = 0.0
        self._held_since = None
        self._hold_s = math.inf

    def step_to(self, sim_s: float) -> None:
        """Held: let time run to `sim_s` as fast as the work allows, then hold it there again."""
        if self._held_since is None:
            raise ValueError("step_to needs a held clock: pause it first")
        if not (math.isfinite(sim_s) and sim_s >= self._now):
            raise ValueError(f"a step ends at or after now ({self._now} s), got {sim_s}")
        self._hold_s = float(sim_s)

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
        if self._held_since is not None and deadline > self._hold_s:
            raise RuntimeError(f"simulated time is held at {self._hold_s} s: a wait until {deadline} s would never "
                               "end (resume the clock first)")
        self.advance(deadline, math.inf)

    def advance(self, deadline: float, wall_deadline: float) -> None:
        if deadline <= self._now:
            return
        if self._held_since is not None:
            if self._now < self._hold_s:      # a step: at once, to the deadline or the step's end
                self._now = float(min(deadline, self._hold_s))
            else:                             # held: only the wall clock moves
                wall = self.wall
                wall.sleep_until(min(wall_deadline, wall.now() + self.HELD_WAIT_S))
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
        """Held (stepping too), no recent factor and no lag: the world is not paced then, so it cannot be slow."""
        wall_now = self.wall.now()
        if self._held_since is not None:
            return TimingReport("paced", math.nan, self.meter.total(self._held_since, self._now), 0.0, self.slipped_s,
                                self.speed)
        return TimingReport("paced", self.meter.recent(wall_now, self._now), self.meter.total(wall_now, self._now),
                            self.lag_s, self.slipped_s, self.speed)
