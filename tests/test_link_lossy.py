"""The command channel over a lossy line: exactly once, in order, one outcome each."""
from __future__ import annotations

import math
import random

import pytest

from host_tools.worlds.link_emulator import LineFaults, LossyLine
from protocol.controller_link import ControllerLink
from protocol.host_link import HostLink
from protocol.link import LinkConfig, LinkState
from protocol.messages import SCHEMA
from protocol.reliable import Outcome

Ping, Pong, StateChanged = SCHEMA["Ping"].type, SCHEMA["Pong"].type, SCHEMA["StateChanged"].type
KEY = bytes(range(32))


class LossyPair:
    """Host and controller links joined by two lossy lines, on simulated time (1 ms steps)."""

    def __init__(self, faults: LineFaults, seed: int, latency_steps: int = 3) -> None:
        rng = random.Random(seed)
        self.executed: list[int] = []
        self.events: list = []
        self.controller = ControllerLink(KEY, self._execute, LinkConfig(link_timeout_s=30.0),
                                         nonce_source=lambda: rng.randbytes(16))
        self.host = HostLink(KEY, LinkConfig(), nonce_source=lambda: rng.randbytes(16),
                             on_event=lambda m, now: self.events.append(m))
        self.up = LossyLine(faults, random.Random(seed + 1))
        self.down = LossyLine(faults, random.Random(seed + 2))
        self.latency = latency_steps
        self.in_flight: list[tuple[int, str, bytes]] = []
        self.step_no = 0

    def _execute(self, msg, urgent, now):
        self.executed.append(msg.token)
        return Pong(0, msg.token, 0)

    @property
    def now(self) -> float:
        return self.step_no * 0.001

    def skip_idle(self, max_steps: int = 50) -> None:
        """Jump over the steps in which nothing can happen: no frame arrives, neither end has a frame queued
        or a timer due (`next_timer_s`, as the comms task sleeps on it); at most `max_steps` at a time."""
        if self.host.tx_backlog or self.controller.tx_backlog:
            return
        due = [arrival for arrival, _, _ in self.in_flight]
        for end in (self.host, self.controller):
            timer = end.next_timer_s()
            if timer != math.inf:
                due.append(math.ceil(timer / 0.001 - 1e-9) if timer != -math.inf else self.step_no)
        target = min(due, default=self.step_no + max_steps + 1)
        self.step_no = max(self.step_no, min(target, self.step_no + max_steps + 1) - 1)

    def step(self) -> None:
        self.step_no += 1
        now = self.now
        due = [x for x in self.in_flight if x[0] <= self.step_no]
        self.in_flight = [x for x in self.in_flight if x[0] > self.step_no]
        for _, where, data in due:
            (self.controller if where == "c" else self.host).feed(data, now)
        self.host.poll(now)
        self.controller.poll(now)
        while (frame := self.host.take_frame(now)) is not None:
            self.in_flight.append((self.step_no + self.latency, "c", self.up.transfer(frame)))
        while (frame := self.controller.take_frame(now)) is not None:
            self.in_flight.append((self.step_no + self.latency, "h", self.down.transfer(frame)))


def run_commands(pair: LossyPair, count: int, window: int = 6, max_steps: int = 20_000_000) -> list:
    handles = []
    pair.host.connect(pair.now)
    next_token = 0
    oldest_open = 0          # handles before it are all done (done never reverts): no scan of every handle a step
    while True:
        while oldest_open < len(handles) and handles[oldest_open].done:
            oldest_open += 1
        if not (next_token < count or oldest_open < len(handles)) or pair.step_no >= max_steps:
            break
        if pair.host.state in (LinkState.SUSPENDED, LinkState.REFUSED, LinkState.NO_SESSION):
            pair.host.connect(pair.now)   # what teleop does: handshake again and go on
        submitted = len(handles)
        if pair.host.state is LinkState.UP:
            while next_token < count and pair.host.outstanding < window:
                handles.append(pair.host.submit(Ping(next_token), pair.now))
                next_token += 1
        if len(handles) == submitted:
            pair.skip_idle()
        pair.step()
    return handles


def check_exactly_once(pair: LossyPair, handles: list) -> dict:
    executed = pair.executed
    # never twice, never out of order
    assert all(a < b for a, b in zip(executed, executed[1:])), "a command ran twice or out of order"
    assert set(executed) <= {h.msg.token for h in handles}
    outcomes = {o: 0 for o in Outcome}
    for h in handles:
        assert h.done, f"command {h.msg.token} has no outcome"
        outcomes[h.outcome] += 1
        if h.outcome is Outcome.SUCCEEDED:
            assert h.reply.token == h.msg.token, "a reply was matched to the wrong command"
            assert h.msg.token in executed, "succeeded without running"
    assert outcomes[Outcome.PENDING] == 0
    assert sum(outcomes.values()) == len(handles)
    assert pair.controller.stats.stale_duplicates == 0
    return outcomes


def test_ten_thousand_commands_over_a_lossy_fading_line_run_exactly_once_in_order():
    faults = LineFaults(bit_error_rate=2e-4, drop_rate=0.03, duplicate_rate=0.03,
                        fade_start_rate=0.0005, fade_end_rate=0.002)
    pair = LossyPair(faults, seed=11)
    handles = run_commands(pair, 10_000)
    outcomes = check_exactly_once(pair, handles)
    # the line really was bad, and the channel really worked through it
    assert pair.up.bits_flipped + pair.down.bits_flipped > 100
    assert pair.up.dropped + pair.down.dropped > 100
    assert pair.up.duplicated + pair.down.duplicated > 100
    assert pair.up.faded + pair.down.faded > 0
    assert pair.host.stats.retransmits > 100
    assert pair.controller.stats.replays > 0          # duplicates were caught by the counter check
    assert pair.controller.stats.stale_duplicates == 0  # every resend was still in the reply cache
    assert len(handles) == 10_000
    assert outcomes[Outcome.SUCCEEDED] > 9_000
    assert len(pair.executed) >= outcomes[Outcome.SUCCEEDED]


def test_a_long_fade_suspends_the_link_and_fails_outstanding_commands_visibly():
    pair = LossyPair(LineFaults(), seed=3)
    pair.host.connect(pair.now)
    while pair.host.state is not LinkState.UP:
        pair.step()
    for _ in range(200):
        pair.step()
    pair.up.faults = LineFaults(fade_start_rate=1.0, fade_end_rate=0.0)   # the line goes dead
    handles = [pair.host.submit(Ping(i), pair.now) for i in range(3)]
    for _ in range(60_000):
        pair.step()
        if all(h.done for h in handles):
            break
    assert pair.host.state is LinkState.SUSPENDED
    assert [h.outcome for h in handles] == [Outcome.FAILED] * 3
    assert all(h.reason.name == "LINK_SUSPENDED" for h in handles)
    assert pair.executed == []
    # a command submitted while suspended fails at once, it is not queued silently
    late = pair.host.submit(Ping(99), pair.now)
    assert late.outcome is Outcome.FAILED


def test_events_arrive_once_and_in_order_over_a_lossy_line():
    faults = LineFaults(bit_error_rate=1e-4, drop_rate=0.05, duplicate_rate=0.05)
    pair = LossyPair(faults, seed=5)
    pair.host.connect(pair.now)
    while pair.host.state is not LinkState.UP or pair.controller.session is None:
        pair.step()
    for i in range(300):
        pair.controller.send_event(StateChanged(1, 1, 0, 0, i))
        for _ in range(5):
            pair.step()
    for _ in range(20_000):
        pair.step()
    assert [e.uptime_ms for e in pair.events] == list(range(300))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_exactly_once_holds_for_other_seeds(seed):
    faults = LineFaults(bit_error_rate=5e-4, drop_rate=0.1, duplicate_rate=0.1,
                        fade_start_rate=0.002, fade_end_rate=0.01)
    pair = LossyPair(faults, seed=seed)
    check_exactly_once(pair, run_commands(pair, 500))


def test_events_survive_a_fade_longer_than_the_retry_limit():
    pair = LossyPair(LineFaults(), seed=9)
    pair.host.connect(pair.now)
    while pair.host.state is not LinkState.UP or pair.controller.session is None:
        pair.step()
    dead = LineFaults(fade_start_rate=1.0, fade_end_rate=0.0)
    pair.up.faults = pair.down.faults = dead
    for i in range(5):
        pair.controller.send_event(StateChanged(1, 1, 0, 0, i))
    for _ in range(40_000):                     # 40 s: the event sender gives up several times
        pair.step()
    assert pair.controller.stats.event_resumes > 0
    pair.up.faults = pair.down.faults = LineFaults()
    pair.up.fading = pair.down.fading = False
    for _ in range(20_000):
        pair.step()
    assert [e.uptime_ms for e in pair.events] == list(range(5))
