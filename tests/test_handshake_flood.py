"""Recorded Hellos played back at most of the line rate, on the lock-step bench (115200 baud, paced, simulated time).

Each copy of a genuine Hello used to be answered at urgent priority, ahead of the session's replies, in an
unbounded queue, and a few distinct ones evicted a genuine host's pending session. Now the answers are bounded
and come after the session's traffic: the live session's commands keep their round trip, and a new host still
connects (protocol/controller_link.py, docs/protocol_security.md).
"""
from __future__ import annotations

from protocol.controller_link import MAX_PENDING_SESSIONS, PENDING_MIN_LIFE_S
from protocol.messages import SCHEMA
from protocol.reasons import Reason

from host_tools.worlds.world import LockstepBench
from line_tap import decoded, recorded_hello

KEY = b"flood-test-key-0123456789abcdef"
LINE_BYTES_PER_S = 115200 / 10
FLOOD_SHARE = 0.8                      # of the line rate
Ping, GetStatus = SCHEMA["Ping"].type, SCHEMA["GetStatus"].type
HELLO_REPLY_ID = SCHEMA["HelloReply"].id
RTT_BOUND_S = 0.05                     # a round trip: measured 11-22 ms under the flood (11-16 ms without)
CONNECT_BOUND_S = 1.0                  # a new handshake: measured 0.03 s (one recording), 0.25 s (six)


class Flood:
    """An attacker's transmitter on the bench's line: `frames` in turn, `share` of the line rate on average."""

    def __init__(self, bench: LockstepBench, frames: list[bytes], share: float = FLOOD_SHARE) -> None:
        self.bench, self.frames = bench, frames
        self.rate = share * LINE_BYTES_PER_S
        self.start_s = bench.clock.now()
        self.sent = 0
        self.count = 0
        bench.world.scheduler.add("attacker", self._step)

    def _step(self, now: float) -> float:
        while (due := self.start_s + self.sent / self.rate) <= now:
            frame = self.frames[self.count % len(self.frames)]
            self.bench.port.deliver(frame)
            self.sent += len(frame)
            self.count += 1
        return due

    def stop(self) -> None:
        self.bench.world.scheduler.remove("attacker")


class RecordedBench(LockstepBench):
    """A bench whose line records what each end sent."""

    def __init__(self, seed: int) -> None:
        self.sent, self.received = bytearray(), bytearray()
        super().__init__(KEY, seed=seed, to_controller=lambda data: self._record(self.sent, data),
                         to_host=lambda data: self._record(self.received, data))

    @staticmethod
    def _record(into: bytearray, data: bytes) -> bytes:
        into += data
        return data

    def hello_replies(self) -> int:
        """HelloReplies the host was sent so far."""
        return sum(1 for frame, _ in decoded(self.received) if frame.msg_id == HELLO_REPLY_ID)


def flooded_bench(frames_for) -> tuple[RecordedBench, list[bytes]]:
    """A connected bench, and the frames to flood it with: `frames_for(the Hello its host sent)`."""
    bench = RecordedBench(seed=3)
    assert bench.connect()
    hello = next(wire for frame, wire in decoded(bench.sent) if frame.msg_id == SCHEMA["Hello"].id)
    return bench, frames_for(hello)


def round_trips(bench: LockstepBench, seconds: int) -> list[float]:
    """A ping and a status every second for `seconds`: their round trips (all must succeed)."""
    rtts = []
    for i in range(seconds):
        for msg in (Ping(i), GetStatus()):
            handle = bench.call(msg, timeout_s=30.0)
            assert handle.ok, handle.describe()
            rtts.append(handle.latency_s)
        bench.run_for(1.0)
    return rtts


def test_one_recorded_hello_played_back_is_never_answered_and_the_session_goes_on():
    bench, frames = flooded_bench(lambda hello: [hello])
    try:
        replies_before = bench.hello_replies()
        flood = Flood(bench, frames)
        rtts = round_trips(bench, 20)
        link = bench.controller.link
        assert max(rtts) < RTT_BOUND_S, f"round trips {min(rtts):.3f}..{max(rtts):.3f} s"
        assert flood.sent >= 0.75 * LINE_BYTES_PER_S * 19               # the flood really filled the line
        assert link.stats.reasons[Reason.REPLAY] >= flood.count - 10     # every copy refused as a replay
        assert bench.hello_replies() == replies_before                  # none was answered
    finally:
        bench.close()


def test_six_recorded_hellos_fresh_to_this_boot_neither_starve_the_session_nor_keep_a_new_host_out():
    fresh = [recorded_hello(KEY, bytes([i]) * 16) for i in range(1, 7)]    # from hosts that never completed a session
    bench, frames = flooded_bench(lambda hello: [hello] + fresh)
    try:
        link = bench.controller.link
        flood = Flood(bench, frames)
        replies_before = bench.hello_replies()
        rtts = round_trips(bench, 20)
        assert max(rtts) < RTT_BOUND_S, f"round trips {min(rtts):.3f}..{max(rtts):.3f} s"
        assert flood.sent >= 0.75 * LINE_BYTES_PER_S * 19
        # each recording was answered at most once in HELLO_REANSWER_S, all of them within the rate
        replies = bench.hello_replies() - replies_before
        assert 0 < replies <= 2 + bench.clock.now() * link.config.hello_rate_per_s
        assert link.stats.reasons[Reason.REPLAY] > flood.count / 8      # the live session's own Hello: refused
        # a new host (the same bench host, a new nonce) connects while the flood goes on
        for _ in range(5):
            began = bench.clock.now()
            assert bench.connect(timeout_s=10.0)
            assert bench.clock.now() - began < CONNECT_BOUND_S
            assert bench.call(Ping(99)).ok
            bench.run_for(0.7)
        assert bench.host.sessions_started == 6
        flood.stop()
    finally:
        bench.close()


def test_more_recorded_hellos_than_pending_places_do_not_evict_a_pending_session_its_host_is_adopting():
    count = 2 * MAX_PENDING_SESSIONS
    fresh = [recorded_hello(KEY, bytes([i]) * 16) for i in range(1, count + 1)]
    bench = RecordedBench(seed=4)
    try:
        flood = Flood(bench, fresh, share=0.9)
        bench.run_for(3.0)                         # every pending place holds a recording's session
        assert len(bench.controller.link._pending) == MAX_PENDING_SESSIONS
        for _ in range(3):
            began = bench.clock.now()
            assert bench.connect(timeout_s=10.0)   # the genuine host is answered first when a place frees,
            assert bench.clock.now() - began < PENDING_MIN_LIFE_S + 0.5   # and its session lives to be adopted
            assert bench.call(Ping(1)).ok
        assert bench.host.sessions_started == 3
        flood.stop()
    finally:
        bench.close()


def test_answers_to_hellos_go_after_the_sessions_replies_and_nothing_grows_without_bound():
    from protocol.controller_link import HELLO_MEMORY, MAX_WAITING_HELLOS
    from protocol.framing import decode_frame
    from test_auth_replay import KEY as WIRE_KEY, Wire

    wire = Wire()
    wire.connect()
    link = wire.controller
    wire.host.submit(Ping(1), wire.now)
    ping = wire.host.take_all(wire.now)
    link.feed(recorded_hello(WIRE_KEY, b"\x01" * 16) + recorded_hello(WIRE_KEY, b"\x02" * 16) + ping, wire.now)
    first = decode_frame(link.take_frame(wire.now).strip(b"\x00"))
    assert first.msg_id == SCHEMA["Pong"].id               # the session's reply first, then the answers
    link.feed(b"".join(recorded_hello(WIRE_KEY, n.to_bytes(16, "little")) for n in range(1000)), wire.now)
    assert len(link._waiting) <= MAX_WAITING_HELLOS and link.stats.hellos_dropped >= 1000 - MAX_WAITING_HELLOS
    sent_before = len(wire.to_host)
    wire.step(10_000)                                       # 10 s
    replies = sum(1 for chunk in wire.to_host[sent_before:] for frame, _ in decoded(chunk)
                  if frame.msg_id == HELLO_REPLY_ID)
    assert replies <= MAX_WAITING_HELLOS + 2               # only those waiting were answered, within the rate
    assert len(link._pending) <= MAX_PENDING_SESSIONS and len(link._answered) <= HELLO_MEMORY
    assert link.tx_backlog == 0 and wire.call(Ping(2)).ok
