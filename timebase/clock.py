"""The one module that reads the operating system's clock or sleeps.

Everything else receives a `Clock` and asks it for `now()` (monotonic seconds,
``float``) or to wait until a deadline. `RealClock` is used for live sessions,
`SimClock` for lock-step runs, tests and benches: waiting on a `SimClock` jumps
straight to the deadline (as trio's MockClock does), so a simulated hour takes
as long as the work done in it.
"""
from __future__ import annotations

import abc
import time


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

    @property
    @abc.abstractmethod
    def is_real_time(self) -> bool:
        """True when time passes on its own (a live session)."""


class RealClock(Clock):
    """Wall-clock time from `time.monotonic`; waits with `time.sleep`."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, deadline: float) -> None:
        delay = deadline - time.monotonic()
        if delay > 0:
            time.sleep(delay)

    @property
    def is_real_time(self) -> bool:
        return True

    @staticmethod
    def precise_now() -> float:
        """`time.perf_counter`, for benchmarks that time code rather than schedule it."""
        return time.perf_counter()

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

    def advance(self, duration_s: float) -> None:
        if duration_s < 0:
            raise ValueError(f"cannot advance a clock by a negative duration ({duration_s} s)")
        self._now += duration_s

    @property
    def is_real_time(self) -> bool:
        return False
