"""The command channel over a lossy line: exactly once, in order, one outcome each.

The line is the impairment model `aspod proxy` and the lock-step world use (host_tools/sessions/impairment.py):
bit errors, drops, duplicates, latency, fades."""
from __future__ import annotations

import math
import random

import pytest

from host_tools.sessions.impairment import Impairment, ImpairedLink
from protocol.controller_link import ControllerLink
from protocol.host_link import HostLink
from protocol.link import LinkConfig, LinkState
from protocol.messages import SCHEMA
from protocol.reliable import Outcome, ReliableSender, RttEstimator

Ping, Pong, StateChanged = SCHEMA["Ping"].type, SCHEMA["Pong"].type, SCHEMA["StateChanged"].type
KEY = bytes(range(32))


class LossyPair:
    """Host and controller links joined by an impaired link, on simulated time (1 ms steps)."""

    def __init__(self, spec: Impairment, seed: int, latency_ms: float = 3.0) -> None:
        rng = random.Random(seed)
        self.executed: list[int] = []
        self.events: list = []
        self.controller = ControllerLink(KEY, self._execute, LinkConfig(link_timeout_s=30.0),
                                         nonce_source=lambda: rng.randbytes(16))
        self.host = HostLink(KEY, LinkConfig(), nonce_source=lambda: rng.randbytes(16),
                             on_event=lambda m, now: self.events.append(m))
        self.link = ImpairedLink(Impairment(**{**spec.__dict__, "seed": seed, "latency_ms": latency_ms}))
        self.up, self.down = self.link.to_controller, self.link.to_host
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
        due = [math.ceil(self.link.next_due_s() / 0.001 - 1e-9)] if self.link.next_due_s() != math.inf else []
        for end in (self.host, self.controller):
            timer = end.next_timer_s()
            if timer != math.inf:
                due.append(math.ceil(timer / 0.001 - 1e-9) if timer != -math.inf else self.step_no)
        target = min(due, default=self.step_no + max_steps + 1)
        self.step_no = max(self.step_no, min(target, self.step_no + max_steps + 1) - 1)

    def step(self) -> None:
        self.step_no += 1
        now = self.now + 1e-9      # what is due at this step arrives in it
        for line, end in ((self.up, self.controller), (self.down, self.host)):
            data = line.receive(now)
            if data:
                end.feed(data, self.now)
        self.host.poll(self.now)
        self.controller.poll(self.now)
        while (frame := self.host.take_frame(self.now)) is not None:
            self.up.send(frame, self.now)
        while (frame := self.controller.take_frame(self.now)) is not None:
            self.down.send(frame, self.now)


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
    faults = Impairment(ber=2e-4, drop=0.03, dup=0.03, fade_every_s=20.0, fade_s=0.5)
    pair = LossyPair(faults, seed=11)
    handles = run_commands(pair, 10_000)
    outcomes = check_exactly_once(pair, handles)
    # the line really was bad, and the channel really worked through it
    up, down = pair.up.stats, pair.down.stats
    assert up.bits_flipped + down.bits_flipped > 100
    assert up.dropped + down.dropped > 100
    assert up.duplicated + down.duplicated > 100
    assert up.faded + down.faded > 0
    assert pair.host.stats.retransmits > 100
    assert pair.controller.stats.replays > 0          # duplicates were caught by the counter check
    assert pair.controller.stats.stale_duplicates == 0  # every resend was still in the reply cache
    assert len(handles) == 10_000
    assert outcomes[Outcome.SUCCEEDED] > 9_000
    assert len(pair.executed) >= outcomes[Outcome.SUCCEEDED]


def test_a_long_fade_suspends_the_link_and_fails_outstanding_commands_visibly():
    pair = LossyPair(Impairment(fades=((0.5, 1e6),)), seed=3)      # the line goes dead at 0.5 s, for good
    pair.host.connect(pair.now)
    while pair.host.state is not LinkState.UP:
        pair.step()
    while pair.now < 0.5:
        pair.step()
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
    pair = LossyPair(Impairment(ber=1e-4, drop=0.05, dup=0.05), seed=5)
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
    faults = Impairment(ber=5e-4, drop=0.1, dup=0.1, fade_every_s=5.0, fade_s=0.5)
    pair = LossyPair(faults, seed=seed)
    check_exactly_once(pair, run_commands(pair, 500))


def test_events_survive_a_fade_longer_than_the_retry_limit():
    pair = LossyPair(Impairment(fades=((1.0, 40.0),)), seed=9)    # 40 s: the event sender gives up several times
    pair.host.connect(pair.now)
    while pair.host.state is not LinkState.UP or pair.controller.session is None:
        pair.step()
    while pair.now < 1.0:
        pair.step()
    for i in range(5):
        pair.controller.send_event(StateChanged(1, 1, 0, 0, i))
    for _ in range(40_000):
        pair.step()
    assert pair.controller.stats.event_resumes > 0
    for _ in range(20_000):
        pair.step()
    assert [e.uptime_ms for e in pair.events] == list(range(5))


def test_a_sender_is_idle_only_when_due_has_nothing_whenever_asked():
    """The host's poll leaves its senders alone while both are idle (issue 35): idle must mean that `due` has
    nothing now or later without a submit, and a suspended sender, even emptied, is never idle (its suspension
    is news to the host's poll)."""
    sender = ReliableSender(window=2, retry_limit=2, rtt=RttEstimator(0.1, 0.05, 0.2))
    assert sender.idle and sender.due(0.0) == [] and sender.next_due_s() == math.inf
    first = sender.submit(1, b"a")
    assert not sender.idle and sender.next_due_s() == -math.inf   # waiting: due sends it
    assert sender.due(0.0) == [first] and not sender.idle          # in flight: its timer may expire
    assert sender.next_due_s() == first.due_s == 0.1
    sender.answered(first.seq, 0.01)
    assert sender.idle and all(sender.due(t) == [] for t in (0.02, 1.0, 100.0))
    assert sender.next_due_s() == math.inf
    second = sender.submit(2, b"b")
    assert sender.due(1.0) == [second] and sender.due(1.2) == [second]   # sent, then sent again
    assert sender.due(1.5) == [] and sender.suspended and not sender.idle   # the retry limit
    assert sender.take_failed() == [second] and not sender.idle        # emptied, still suspended
