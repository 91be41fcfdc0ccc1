"""The one module that reads the operating system's clock or sleeps.

Everything else receives a `Clock` and asks it for `now()` (monotonic seconds,
``float``) or to wait until a deadline. `RealClock` is used for live sessions,
`SimClock` for lock-step runs, tests and benches: waiting on a `SimClock` jumps
straight to the deadline (as trio's MockClock does), so a simulated hour takes
as long as the work done in it. Clocks whose time runs apart from the wall clock
but is paced by it (`timebase.paced.PacedClock`, the lock-step clocks of
`protocol.lockstep`) are built on a `RealClock` given to them; they never read the
OS clock themselves.

Every clock can say how its time relates to the wall clock (`timing()`, a
`TimingReport`), and can `advance(deadline, wall_deadline)`: move its time toward
`deadline` but return by `wall_deadline` on the wall clock, so that one thread can
run a simulated world and a real link side by side (`timebase.scheduler.run_live`).
"""
from __future__ import annotations

import abc
import math
import time
from dataclasses import dataclass
from typing import Optional


@dataclass(frozen=True)
class TimingReport:
    """How a clock's time relates to the wall clock, for telemetry and `status`.

    `mode`: "realtime" (the wall clock itself), "paced" (simulated time paced to the wall
    clock; late, it slows down rather than jumping), "lockstep" (simulated time granted
    tick by tick by another process on the HAL bus) or "simulated" (no wall clock at all).
    `rtf_recent` and `rtf_total`: simulated seconds per wall second over about the last
    second and since the start (NaN where nothing is measured). `lag_s`: wall seconds by
    which time is behind its schedule now; `slipped_s`: lag given up for good (the world
    fell too far behind to catch up and was re-anchored), in wall seconds. `speed`: the factor
    asked for (`--speed`; math.inf: as fast as the work allows), what `rtf_recent` is judged
    against: a world asked for 0.01x real time that runs at 0.01x is not slow.
    """

    mode: str
    rtf_recent: float = math.nan
    rtf_total: float = math.nan
    lag_s: float = 0.0
    slipped_s: float = 0.0
    speed: float = 1.0


class Clock(abc.ABC):
    """Monotonic time in seconds and a way to wait for a deadline."""

    @abc.abstractmethod
    def now(self) -> float:
        """Current time in seconds; never decreases."""

    @abc.abstractmethod
    def sleep_until(self, deadline: float) -> None:
        """Return when `now()` >= `deadline` (at once if it already is)."""

    def sleep(self, duration_s: float) -> None:
        self.sleep_until(self.now() + max(0.0, duration_s))

    @abc.abstractmethod
    def advance(self, deadline: float, wall_deadline: float) -> None:
        """Move time toward `deadline`; return once it is there, or by `wall_deadline` on the wall
        clock, whichever comes first (at once if either has passed). `wall_deadline` is wall-clock
        time (`RealClock.now`); a clock with no wall clock ignores it."""

    @abc.abstractmethod
    def timing(self) -> TimingReport:
        """How this clock's time relates to the wall clock now."""

    def stalled_s(self) -> float:
        """Wall seconds this clock has been waiting for its time to be granted by someone else (a lock-step
        clock whose peer is silent); 0 for a clock whose time is never withheld."""
        return 0.0


class RealClock(Clock):
    """Wall-clock time from `time.monotonic`; waits with `time.sleep`."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, deadline: float) -> None:
        delay = deadline - time.monotonic()
        if delay > 0:
            time.sleep(delay)

    def advance(self, deadline: float, wall_deadline: float) -> None:
        self.sleep_until(min(deadline, wall_deadline))

    def timing(self) -> TimingReport:
        return TimingReport("realtime", 1.0, 1.0)

    @staticmethod
    def precise_now() -> float:
        """`time.perf_counter`, for benchmarks that time code rather than schedule it."""
        return time.perf_counter()

    @staticmethod
    def cpu_wait_s(thread_id: int) -> Optional[float]:
        """Seconds the thread with native id `thread_id` (of this process) has been runnable but waiting for a CPU,
        from Linux's schedstat (run_delay); None where the kernel does not keep it."""
        try:
            with open(f"/proc/self/task/{thread_id}/schedstat", "rb") as stat:
                return int(stat.read().split()[1]) / 1e9
        except (OSError, ValueError, IndexError):
            return None

    @staticmethod
    def wall_time() -> float:
        """Seconds since the epoch, for log file names and timestamps only."""
        return time.time()


class SimClock(Clock):
    """Simulated time: advances only when told to, or when someone waits."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now = float(start_s)

    def now(self) -> float:
        return self._now

    def sleep_until(self, deadline: float) -> None:
        if deadline > self._now:
            self._now = float(deadline)

    def advance_by(self, duration_s: float) -> None:
        if duration_s < 0:
            raise ValueError(f"cannot advance a clock by a negative duration ({duration_s} s)")
        self._now += duration_s

    def advance(self, deadline: float, wall_deadline: float) -> None:
        self.sleep_until(deadline)      # no wall clock here: straight to the deadline

    def timing(self) -> TimingReport:
        return TimingReport("simulated")
