"""Attacks through the real interface: `aspod sim` as a subprocess, over its pty and over TCP, with a man in the
middle (tests/line_tap.py) that records the line and plays recorded frames back into either end.

These run in real time on a shared machine: they assert behaviour, with bounds far above what was measured
(stated beside each), and far below what the holes they close cost.
"""
from __future__ import annotations

import re
import statistics

import pytest

import test_e2e
from host_tools.client.live import HostClient
from bench.bench_handshake import recorded_hello
from line_tap import LineTap, decoded
from host_tools.worlds.child import run
from protocol import auth
from protocol.link import LinkState
from protocol.messages import MESSAGES as M, SCHEMA
from protocol.reasons import Reason
from protocol.states import ControllerState
from timebase import RealClock

pytestmark = pytest.mark.pty
env, sim_factory = test_e2e.env, test_e2e.sim_factory       # the fixtures: a private config, sims stopped at the end
PORTS = [pytest.param(("--pty",), id="pty"), pytest.param(("--tcp", "0"), id="tcp")]
LINE_BYTES_PER_S = 115200 / 10
FLOOD_SHARE = 0.8
# Each command under the flood: measured median 15 ms (pty) / 43 ms (tcp), max 63 ms on an idle machine. On a
# loaded one (three test workers on two cores beside a fuzz campaign) the median was 195 ms and two commands took
# one retransmission (the initial RTO is 1 s): 1.01 and 1.11 s. Starving the session would be more: a command
# unanswered past the link timeout (3 s). So: every command within 2.5 s (one retransmission and its wait), half
# of them within 0.5 s.
RTT_BOUND_S = 2.5
RTT_MEDIAN_BOUND_S = 0.5
CONNECT_BOUND_S = 3.0    # a new host under the flood: measured 0.14-0.24 s (before: none connected, commands failed)
TELEOP_CONNECT_BOUND_S = 10.0   # the same from a teleop subprocess, which also competes for the CPU with the sim;
                                # it missed 3 s once beside two busy loops on two cores
clock = RealClock()


CONTROLLER_ID = "00000000000000a1"     # the identity the controller keeps across its restart


def handshake_naks(recorded: bytes, psk: bytes) -> list[bytes]:
    """The NAKs signed with the controller's handshake NAK key in recorded bytes, as they went on the wire."""
    key = auth.nak_key(psk, bytes.fromhex(CONTROLLER_ID))
    return [wire for frame, wire in decoded(recorded) if frame.msg_id == SCHEMA["Nak"].id and frame.verify(key)]


@pytest.fixture
def link_key(tmp_path):
    """A key file of the test's own, for simulators that must share one (a restart) and hosts that reach them
    through a tap (whose address is not a simulator's, so a host tool cannot find the key from it)."""
    path = tmp_path / "link.key"
    auth.write_key(path, auth.new_nonce() + auth.new_nonce())
    return path


@pytest.fixture
def tapped(sim_factory, link_key):
    """Factory: `aspod sim` on `where` (its arguments) with `link_key`, the key, and a LineTap in front of it (closed
    at the end)."""
    taps = []

    def start(where):
        sim = sim_factory(*where, "--key-file", str(link_key), "--controller-id", CONTROLLER_ID)
        taps.append(LineTap(sim.url))
        return sim, auth.load_key(sim.key_path), taps[-1]
    yield start
    for tap in taps:
        tap.close()


@pytest.mark.parametrize("where", PORTS)
def test_a_recorded_handshake_nak_leaves_a_live_session_alone_and_a_restart_is_still_recovered(tapped, sim_factory,
                                                                                                link_key, where):
    first, psk, tap = tapped(where)
    client = HostClient(tap.url, psk)
    try:
        client.connect()
        assert client.call(M["Ping"](1)).ok
        first.stop()                                     # the controller restarts behind the line, same key
        second = sim_factory(*where, "--key-file", str(link_key), "--controller-id", CONTROLLER_ID)
        restarted_at = len(tap.to_host)
        handle = client.submit(M["Ping"](2))             # in flight across the restart
        tap.retarget(second.url)
        assert second.wait(client, lambda: handle.done and client.link.state is LinkState.UP, 30.0)
        assert handle.reason is Reason.SESSION_RESET and client.link.sessions_started == 2
        assert client.call(M["Ping"](3)).ok              # the host is back, with the new controller
        naks = handshake_naks(tap.to_host[restarted_at:], psk)
        assert naks                                      # what the restarted controller answered: recorded
        replays = client.link.stats.replays
        for token in range(4, 9):                        # played back into the host's stream, commands in flight
            handle = client.submit(M["Ping"](token))
            for nak in naks:
                tap.inject_to_host(nak)
            assert second.wait(client, lambda: handle.done, 30.0) and handle.ok, handle.describe()
        assert second.wait(client, lambda: client.link.stats.replays >= replays + 5 * len(naks), 10.0)
        assert client.link.sessions_started == 2 and client.link.state is LinkState.UP
    finally:
        client.close()


def controller_rx(sim, client: HostClient, after_s: float, timeout_s: float = 10.0) -> tuple[float, int]:
    """(uptime s, bytes received) from the controller's first Heartbeat after `after_s` (the wall clock's, as the
    host stamps it), waiting at most `timeout_s` of `sim`'s own time (a 10 s wall-clock wait once ended first,
    beside a second test run and two CPU hogs)."""
    assert sim.wait(client, lambda: (client.link.peer_stats_s or 0.0) > after_s, timeout_s)
    return client.link.peer_stats.uptime_ms / 1000, client.link.peer_stats.bytes_rx


@pytest.mark.parametrize("where", PORTS)
def test_a_flood_of_recorded_hellos_starves_neither_the_session_nor_a_new_host(tapped, link_key, where):
    sim, psk, tap = tapped(where)                       # 115200 baud, paced
    live = HostClient(tap.url, psk)
    try:
        live.connect()
        own = next(wire for frame, wire in decoded(tap.to_controller) if frame.msg_id == SCHEMA["Hello"].id)
        fresh = [recorded_hello(psk, bytes([i]) * 16) for i in range(1, 7)]
        tap.flood([own] + fresh, FLOOD_SHARE * LINE_BYTES_PER_S)
        start = controller_rx(sim, live, clock.now() + 1.0)
        rtts = []
        for token in range(10):
            for msg in (M["Ping"](token), M["GetStatus"]()):
                handle = live.call(msg)
                assert handle.ok, handle.describe()
                rtts.append(handle.latency_s)
        said = f"round trips: median {statistics.median(rtts):.3f} s, max {max(rtts):.3f} s"
        assert max(rtts) < RTT_BOUND_S and statistics.median(rtts) < RTT_MEDIAN_BOUND_S, said
        end = controller_rx(sim, live, clock.now())
        # the line really was flooded: the flood offers 0.8 of the line; over this window of a second or two, a
        # stall of the tap or the simulator near its end is only caught up after it (a loaded CI run measured 0.59)
        assert (end[1] - start[1]) / (end[0] - start[0]) >= 0.5 * LINE_BYTES_PER_S
        live.close()
        began = clock.now()                             # a new host, the flood still on
        new = HostClient(tap.url, psk)
        try:
            new.connect(CONNECT_BOUND_S)
            assert clock.now() - began < CONNECT_BOUND_S
            assert new.call(M["Ping"](99)).ok
        finally:
            new.close()
        done = run(test_e2e.ASPOD + ["teleop", tap.url, "--key-file", str(link_key), "--connect-timeout",
                                     str(TELEOP_CONNECT_BOUND_S)],
                   input=b"ping\nstatus\n", env=sim.env, timeout_s=120, peers=(sim.child.pid,))
        out = done.stdout.decode()
        assert done.returncode == 0, done.stderr.decode() + out
        latencies = [float(ms) / 1000 for ms in re.findall(r"\((\d+\.\d) ms\)$", out, re.MULTILINE)]
        assert len(latencies) == 2 and max(latencies) < RTT_BOUND_S, out
    finally:
        tap.stop_flood()
        live.close()


def test_a_new_host_connects_through_300_distinct_recorded_hellos_over_a_real_pty(tapped):
    """The finding, through the real interface: 300 distinct recorded Hellos (hosts that never got a session on this
    boot) at 11 % of the line kept every new host out (0 of 4). Now a Hello needs a fresh cookie; the recordings
    get only HelloCookies, and four hosts in a row connect."""
    sim, psk, tap = tapped(("--pty",))
    tap.flood([recorded_hello(psk, n.to_bytes(16, "little")) for n in range(1, 301)], 0.11 * LINE_BYTES_PER_S)
    try:
        for attempt in range(4):
            began = clock.now()
            host = HostClient(tap.url, psk)
            try:
                host.connect(TELEOP_CONNECT_BOUND_S)
                assert host.call(M["Ping"](attempt)).ok
            finally:
                host.close()
            assert clock.now() - began < TELEOP_CONNECT_BOUND_S
    finally:
        tap.stop_flood()


class Events:
    """A client's events, each with whether the link said it was from an earlier session."""

    def __init__(self, client: HostClient) -> None:
        self.client = client
        self.seen: list[tuple[object, bool]] = []
        client.event_listeners.append(lambda msg, now: self.seen.append(
            (msg, client.link.event_from_earlier_session)))

    def has(self, name: str, **fields) -> bool:
        return any(m.spec.name == name and all(getattr(m, k) == v for k, v in fields.items()) for m, _ in self.seen)


@pytest.mark.parametrize("where", PORTS)
def test_an_event_whose_ack_was_lost_reaches_the_next_host_marked_as_from_an_earlier_session(tapped, where):
    sim, psk, tap = tapped(where)
    first = HostClient(tap.url, psk)
    try:
        events = Events(first)
        first.connect()
        assert sim.wait(first, lambda: events.has("StateChanged", state=ControllerState.IDLE), 10.0)
        assert events.seen == [(events.seen[0][0], False)]    # from before any session: new, and no marker
        tap.drop_after(SCHEMA["EStop"].id, until=SCHEMA["Hello"].id)   # the EStop goes through, nothing after it
                                                               # until the next host's Hello
        assert first.call(M["EStop"]()).ok
        assert sim.wait(first, lambda: events.has("StateChanged", state=ControllerState.ESTOP), 10.0)
        estop = next(m for m, _ in events.seen if m.spec.name == "StateChanged" and m.state == ControllerState.ESTOP)
    finally:
        first.close()                                         # its Ack for that event was lost on the line
    second = HostClient(tap.url, psk)
    try:
        events = Events(second)
        second.connect()
        assert sim.wait(second, lambda: any(m == estop for m, _ in events.seen), 10.0), (
            f"the second host saw {[(m.spec.name, getattr(m, 'state', None), e) for m, e in events.seen]}; "
            f"the first saw {estop}; the second's link: {second.link.stats}")     # what to read if this fails
        marker, earlier = events.seen[0]
        assert marker.spec.name == "EventsCarriedOver" and not earlier and marker.dropped == 0
        carried = events.seen[1:1 + marker.count]
        assert (estop, True) in carried and all(earlier for _, earlier in carried)
        assert second.call(M["Reset"]()).ok                   # an event of this session: new
        assert sim.wait(second, lambda: events.has("StateChanged", state=ControllerState.IDLE), 10.0)
        assert events.seen[-1][1] is False
    finally:
        second.close()
