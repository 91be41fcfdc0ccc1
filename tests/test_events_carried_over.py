"""Events an earlier session was sent come to the next one marked (EventsCarriedOver), and teleop says so."""
from __future__ import annotations

import io
import random

from protocol.controller_link import MAX_UNDELIVERED_EVENTS
from protocol.framing import encode_signed
from protocol.host_link import HostLink
from protocol.messages import SCHEMA
from protocol.schema import MsgClass
from protocol.states import Axis, ControllerState, MotionOutcome
from protocol.reasons import Reason

from host_tools.teleop.session import EARLIER_SESSION_NOTE, Session
from line_tap import decoded
from test_auth_replay import KEY, Wire

StateChanged, MotionDone = SCHEMA["StateChanged"].type, SCHEMA["MotionDone"].type
CarriedOver = SCHEMA["EventsCarriedOver"].type


def state_event(i: int):
    return StateChanged(ControllerState.IDLE, ControllerState.IDLE, Reason.OK, 0, i)


class Received:
    """A host's events as `on_event` got them, each with `event_from_earlier_session` at that moment."""

    def __init__(self, host: HostLink) -> None:
        self.host = host
        self.events: list[tuple[object, bool]] = []
        host.on_event = lambda msg, now: self.events.append((msg, host.event_from_earlier_session))


def new_host(wire: Wire, seed: int) -> Received:
    """Another host (or the same one restarted) takes over the controller."""
    rng = random.Random(seed)
    wire.host = HostLink(KEY, nonce_source=lambda: rng.randbytes(16))
    received = Received(wire.host)
    wire.connect()
    wire.step(500)
    return received


def deliver_without_acks(wire: Wire, steps: int) -> None:
    """The controller's frames reach the host; the host's (its Acks) are lost on the line."""
    for _ in range(steps):
        wire.now += 0.001
        wire.controller.poll(wire.now)
        wire.host.poll(wire.now)
        wire.host.feed(wire.controller.take_all(wire.now), wire.now)
        wire.host.take_all(wire.now)


def test_events_whose_acks_were_lost_come_to_the_next_host_marked_and_new_ones_do_not():
    wire = Wire()
    first = Received(wire.host)
    wire.connect()
    wire.step(200)
    for i in range(3):
        wire.controller.send_event(state_event(i))
    deliver_without_acks(wire, 50)
    assert [m.uptime_ms for m, _ in first.events] == [0, 1, 2]       # the first host saw them all
    second = new_host(wire, seed=7)
    wire.controller.send_event(state_event(3))
    wire.step(200)
    assert second.events == [(CarriedOver(3, 0), False), (state_event(0), True), (state_event(1), True),
                             (state_event(2), True), (state_event(3), False)]
    third = new_host(wire, seed=8)                  # all acknowledged: nothing is carried over again
    wire.step(200)
    assert third.events == []


def test_only_the_events_an_earlier_host_was_sent_are_marked():
    wire = Wire()
    wire.connect()
    wire.step(200)
    window = wire.controller.config.window
    for i in range(window + 2):                     # the line is down: the window's worth go out into the void
        wire.controller.send_event(state_event(i))
    for _ in range(20):
        wire.now += 0.001
        wire.controller.poll(wire.now)
        wire.controller.take_all(wire.now)
    received = new_host(wire, seed=7)
    assert received.events[0] == (CarriedOver(window, 0), False)
    assert [earlier for _, earlier in received.events[1:]] == [True] * window + [False] * 2
    assert [m.uptime_ms for m, _ in received.events[1:]] == list(range(window + 2))


def test_events_from_before_any_session_are_new_and_those_beyond_the_room_are_counted_as_dropped():
    wire = Wire()
    for i in range(MAX_UNDELIVERED_EVENTS + 6):
        wire.controller.send_event(state_event(i))
    received = Received(wire.host)
    wire.connect()
    wire.step(2000)
    assert received.events[0] == (CarriedOver(0, 6), False)
    assert [m.uptime_ms for m, _ in received.events[1:]] == list(range(6, MAX_UNDELIVERED_EVENTS + 6))
    assert not any(earlier for _, earlier in received.events[1:])


def test_a_marker_that_was_never_acknowledged_is_replaced_and_its_count_kept():
    wire = Wire()
    for i in range(MAX_UNDELIVERED_EVENTS + 2):
        wire.controller.send_event(state_event(i))
    wire.host.connect(wire.now)
    for _ in range(100):                             # the session comes up, its host acknowledges nothing
        if wire.controller.session is not None and wire.host.state.value == "up":
            break
        wire.step()
    deliver_without_acks(wire, 300)
    received = new_host(wire, seed=9)
    wire.step(2000)
    marker, earlier = received.events[0]
    assert marker.spec.name == "EventsCarriedOver" and not earlier
    assert marker.dropped == 2 and marker.count > 0
    assert sum(1 for m, _ in received.events if m.spec.name == "EventsCarriedOver") == 1


def test_a_lost_link_resends_no_event_until_its_host_is_heard_again():
    """While the watchdog says the link is lost, the session's events are not resent (a new event goes out once):
    a new connection on the line got them every 2 s under a key it does not hold (issue 37's second client)."""
    wire = Wire()
    received = Received(wire.host)
    wire.connect()
    wire.step(200)
    timeout = wire.controller.config.link_timeout_s
    wire.controller.send_event(state_event(0))
    sent = []
    for _ in range(int((timeout + 10) / 0.01)):       # the host is gone: nothing it would send arrives
        wire.now += 0.01
        wire.controller.poll(wire.now)
        if wire.controller.link_lost:
            sent.append(wire.controller.take_all(wire.now))
        else:
            wire.controller.take_all(wire.now)
    assert wire.controller.link_lost and sent and not any(sent)
    assert wire.controller.next_timer_s() > wire.now          # and no timer spins on them
    wire.controller.send_event(state_event(1))       # a new one goes out once, into the silence
    wire.now += 0.01
    wire.controller.poll(wire.now)
    assert wire.controller.take_all(wire.now)
    for _ in range(500):
        wire.now += 0.01
        wire.controller.poll(wire.now)
        assert not wire.controller.take_all(wire.now)
    wire.step(300)                                   # the host speaks again (its heartbeat): the events follow
    assert not wire.controller.link_lost
    assert [m.uptime_ms for m, _ in received.events] == [0, 1]


def test_an_ack_counts_on_every_session_frame_that_checks_out_even_a_refused_one():
    wire = Wire()
    received = Received(wire.host)
    wire.connect()
    wire.step(200)
    wire.controller.send_event(state_event(0))
    deliver_without_acks(wire, 50)
    assert received.events and wire.controller._events.outstanding == 1
    session = wire.host.session
    session.tx_counter += 1
    unknown = encode_signed(MsgClass.COMMAND, 0, 0, 0x7FFF, b"", session.keys.tx, session.tx_counter)[0]
    wire.controller.feed(unknown, wire.now)          # refused UNKNOWN_MESSAGE, but it acknowledges event 0
    assert wire.controller.stats.reasons.get(Reason.UNKNOWN_MESSAGE) == 1
    assert wire.controller._events.outstanding == 0


class WireClient:
    """What teleop's Session needs of a client, over a sans-IO host link."""

    def __init__(self, host: HostLink) -> None:
        self.link = host
        self.telemetry_listeners: list = []
        self.event_listeners: list = []
        host.on_event = lambda msg, now: [listener(msg, now) for listener in list(self.event_listeners)]


def test_teleop_shows_events_from_an_earlier_session_as_such():
    wire = Wire()
    wire.connect()
    wire.step(200)
    done = MotionDone(Axis.J1, 4, MotionOutcome.DONE, Reason.OK, 1.0, 900)
    wire.controller.send_event(state_event(0))
    wire.controller.send_event(done)
    deliver_without_acks(wire, 50)
    rng = random.Random(3)
    wire.host = HostLink(KEY, nonce_source=lambda: rng.randbytes(16))
    console, script = io.StringIO(), io.StringIO()
    client = WireClient(wire.host)
    interactive = Session(client, console, all_events=True)
    scripted = Session(client, script)
    wire.connect()
    wire.step(500)
    wire.controller.send_event(state_event(1))
    wire.step(200)
    lines = [line for line in console.getvalue().splitlines() if line]   # each event on a line of its own
    assert lines[0].startswith("! 2 event(s) from an earlier session follow")
    assert lines[1].endswith(EARLIER_SESSION_NOTE) and "uptime_ms=0 ms" in lines[1]
    assert lines[2].startswith("! j1#4 DONE") and lines[2].endswith(EARLIER_SESSION_NOTE)
    assert "uptime_ms=1 ms" in lines[3] and EARLIER_SESSION_NOTE not in lines[3] and len(lines) == 4
    assert script.getvalue().splitlines() == [f"! j1#4 DONE at 1.000 deg (not started by this session)"
                                              f"{EARLIER_SESSION_NOTE}"]
    interactive.close()
    scripted.close()


def test_a_host_client_that_closes_sends_what_its_link_still_has_queued():
    from host_tools.client.live import HostClient
    client = HostClient("loop://", KEY)
    client._stop = True                      # the pump stops with something queued that it has not written
    client._thread.join()
    client.link.connect(client.clock.now())
    client.link.poll(client.clock.now())
    assert client.link.tx_backlog == 1       # here a Hello; after an event, its Ack
    written = bytearray()
    client.line.serial.write = lambda data: written.extend(data) or len(data)
    client.close()
    assert client.link.tx_backlog == 0 and decoded(bytes(written))[0][0].msg_id == SCHEMA["Hello"].id
