"""A teleop session on the simulated clock: `BenchClient` makes a `LockstepBench` look like `HostClient`.

`Session` and `run_script` (teleop/session.py) talk to a client: `call(msg)`, `wait_for(predicate,
timeout_s)`, `clock` (`now`, `sleep`), `link`, `io_error`, `telemetry_listeners`,
`event_listeners`. `HostClient` provides them over a real port in real time, with a pump
thread; `BenchClient` provides them on a `LockstepBench`, in one thread: waiting runs the whole
world (plant, controller, host link) in simulated time, so a teleop script that takes minutes
at the real box runs in seconds and the same seed gives the same session. The host's UTC is
the plant's simulated date-time (`wall_time`: the sun's start + the simulated time), so
`clock now` in a script sets the controller to the plant's sun, as it does against `aspod sim`
with its default `--sun-start now`.

A script on the simulated clock from the command line: `aspod bench SCRIPT` (host_tools/cli/bench.py).
"""
from __future__ import annotations

from typing import Callable, Optional

from protocol.errors import LinkError
from protocol.host_link import CommandHandle
from protocol.reasons import Reason
from protocol.schema import Message
from protocol.states import CloseWhy
from timebase import Clock, TimingReport

from host_tools.worlds.world import LockstepBench


class BenchClock(Clock):
    """The bench's simulated clock; waiting on it runs the world until then."""

    def __init__(self, bench: LockstepBench) -> None:
        self.bench = bench

    def now(self) -> float:
        return self.bench.clock.now()

    def sleep_until(self, deadline: float) -> None:
        if deadline > self.now():
            self.bench.world.scheduler.run_until(deadline)

    def advance(self, deadline: float, wall_deadline: float) -> None:
        self.sleep_until(deadline)

    def timing(self) -> TimingReport:
        return self.bench.clock.timing()


class BenchClient:
    """What teleop's `Session` needs of a client, on a `LockstepBench` (which it does not own): its first arm's
    host, or with `arm` 2 its second arm's (`LockstepBench(arms=2)`), which has no `sim` words (the plant's control
    acts on the first arm's plant, as a two-arm simulator's endpoint does)."""

    def __init__(self, bench: LockstepBench, arm: int = 1) -> None:
        if arm not in (1, 2) or (arm == 2 and bench.arm2 is None):
            raise ValueError(f"arm {arm!r}: this bench has {'two arms, 1 or 2' if bench.arm2 else 'one arm, 1'}")
        self.bench = bench
        self.arm = arm
        self.clock = BenchClock(bench)
        host = bench.host if arm == 1 else bench.arm2.host
        self.link = host
        self.control = bench.control if arm == 1 else None   # `sim ...`: the plant, as a simulator's endpoint has it
        self.io_error: Optional[str] = None
        self.telemetry_listeners: list[Callable[[Message, float], None]] = []
        self.event_listeners: list[Callable[[Message, float], None]] = []
        self.events: list[Message] = []
        # the bench's own lists keep filling
        on_telemetry = host.on_telemetry or (lambda msg, now: None)
        on_event = host.on_event or (lambda msg, now: None)

        def telemetry(msg: Message, now: float) -> None:
            on_telemetry(msg, now)
            for listener in list(self.telemetry_listeners):
                listener(msg, now)

        def event(msg: Message, now: float) -> None:
            on_event(msg, now)
            self.events.append(msg)
            for listener in list(self.event_listeners):
                listener(msg, now)
        host.on_telemetry, host.on_event = telemetry, event

    def wall_time(self) -> float:
        """The host's UTC in the simulated world: the plant's sun start + the simulated time [POSIX s]."""
        return self.bench.world.plant.tracker.start_utc.timestamp() + self.bench.clock.now()

    def connect(self, timeout_s: float = 10.0) -> None:
        bench = self.bench
        up = bench.connect(timeout_s) if self.arm == 1 else bench.arm2.connect(bench.world.arm2.controller, timeout_s)
        if not up:
            raise LinkError(Reason.LINK_SUSPENDED, f"no session with the bench's controller in {timeout_s:g} s")

    def call(self, msg: Message, timeout_s: float = 30.0) -> CommandHandle:
        return self.bench.call(msg, timeout_s) if self.arm == 1 else self.bench.arm2.call(msg, timeout_s)

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Run until `predicate()` holds or `timeout_s` of simulated time pass, looking at it every millisecond: the
        plugin's `wait_until` hands it any predicate, the plant's state or the time included."""
        self.bench.wait_until(predicate, timeout_s)
        return predicate()

    def close(self, why: CloseWhy = CloseWhy.DONE) -> None:
        """Close the session cleanly, on the simulated clock (the bench itself is its owner's to close)."""
        self.bench.close_session(why, host=self.link)
