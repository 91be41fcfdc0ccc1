"""The link's clock in a lock-step world that re-simulates a real-time recording.

Under `aspod sim` the world runs on simulated time paced to the wall clock (slower than real time when the
machine is busy, or as `--speed` asks), while the link (the controller's comms task: the line's pacing, the
heartbeats, the link timeout; and the host at the other end) runs on the wall clock itself. A recording keeps
the world's time; its controller Heartbeats carry the link's (`uptime_ms`). To re-simulate such a session in
lock-step, `aspod replay` gives the link a clock of its own that runs against the world's as the recording's
did: `LinkTime`, at a rate (link seconds per world second) set afresh as the recording shows it, and
`LinkScheduler`, which runs the link's tasks on the world's one scheduler with their times on that clock.
"""
from __future__ import annotations

import math
from typing import Callable, Optional

from timebase import Clock, TimingReport
from timebase.scheduler import Scheduler, Task

LinkTaskFn = Callable[[float], Optional[float]]


class LinkTime:
    """Link seconds against world seconds: continuous, at `rate` link seconds per world second from the moment it
    was last set (`set_rate`). Only the present and the near future are asked for (a task's next run)."""

    def __init__(self, rate: float = 1.0) -> None:
        if not rate > 0:
            raise ValueError(f"a link clock runs forward: rate {rate}")
        self.rate = rate
        self._world0 = 0.0
        self._link0 = 0.0

    def set_rate(self, world_s: float, rate: float) -> None:
        """From `world_s` on, the link's clock runs at `rate`."""
        if not rate > 0:
            raise ValueError(f"a link clock runs forward: rate {rate}")
        self._link0, self._world0, self.rate = self.to_link(world_s), world_s, rate

    def to_link(self, world_s: float) -> float:
        return self._link0 + (world_s - self._world0) * self.rate

    def to_world(self, link_s: float) -> float:
        return self._world0 + (link_s - self._link0) / self.rate


class LinkClock(Clock):
    """The link's time, read off the world's clock through `LinkTime`. It never waits: the world's scheduler does."""

    def __init__(self, world: Clock, link_time: LinkTime) -> None:
        self._world = world
        self._link_time = link_time

    def now(self) -> float:
        return self._link_time.to_link(self._world.now())

    def sleep_until(self, deadline: float) -> None:
        raise RuntimeError("the link's clock is read, never waited on: run the world's scheduler")

    def advance(self, deadline: float, wall_deadline: float) -> None:
        self.sleep_until(deadline)

    def timing(self) -> TimingReport:
        return TimingReport("simulated")


class LinkScheduler:
    """The link's tasks (`add`, `wake`, as `timebase.scheduler.Scheduler`) on the world's scheduler: each runs with
    the link's time and says its next run in it; the world's scheduler keeps both in its own time.

    A task run for the link time it asked for is given at least that time: a time taken to the world's and back
    may come out a hair earlier, and a timer due then would not fire, and ask again for the same moment."""

    def __init__(self, scheduler: Scheduler, link_time: LinkTime) -> None:
        self._scheduler = scheduler
        self._link_time = link_time
        self._asked: dict[str, float] = {}
        self.clock = LinkClock(scheduler.clock, link_time)

    def add(self, name: str, fn: LinkTaskFn, first_wake_s: Optional[float] = None, tolerance_s: float = 0.002, *,
            priority: int = 10) -> Task:
        link_time, asked = self._link_time, self._asked

        def run(world_s: float) -> Optional[float]:
            link_s = link_time.to_link(world_s)
            if name in asked:
                link_s = max(link_s, asked.pop(name))
            wake = fn(link_s)
            if wake is None:
                return None
            asked[name] = wake
            return link_time.to_world(wake)
        first = self.clock.now() if first_wake_s is None else first_wake_s
        asked[name] = first
        return self._scheduler.add(name, run, link_time.to_world(first), tolerance_s, priority=priority)

    def wake(self, name: str, at_s: Optional[float] = None) -> None:
        at_s = self.clock.now() if at_s is None else at_s
        if at_s < self._asked.get(name, math.inf):
            self._asked[name] = at_s
        self._scheduler.wake(name, self._link_time.to_world(at_s))
