"""The controller's TCP port over real loopback sockets: who holds the line, and whose bytes reach the controller.

`TcpServerPort` under a `PacedUart`, driven with an explicit `now` (the line's time), while real
sockets connect, write and close. The only waits are for the kernel to move bytes between two
sockets of this process: bounded polls of at most `WAIT_S`, each ending as soon as the bytes are
there. The same policy through the real `aspod sim --tcp` is in tests/test_e2e.py.
"""
from __future__ import annotations

import select
import socket

import pytest

from firmware_py.uart import PacedUart
from host_tools.worlds.ports import TcpServerPort
from bench.bench_handshake import recorded_hello
from protocol.messages import SCHEMA
from timebase import RealClock

pytestmark = pytest.mark.pty
WAIT_S = 10.0        # loopback moves bytes in microseconds; this bound only ends a test that would hang
BYTE_S = 10 / 9600   # one byte on the wire at 9600 baud
HELLO = recorded_hello(b"tcp-port-test-key-0123456789", b"\x07" * 16)     # a frame the test's `vouch` believes


def hello_proves_a_key(frame) -> int:
    """The port's judge here: a Hello proves 1 (as `ControllerLink.vouch` says of a Hello that verifies)."""
    return 1 if frame.msg_id == SCHEMA["Hello"].id else 0


def until(predicate, what: str):
    clock = RealClock()
    deadline = clock.now() + WAIT_S
    while not predicate():
        if clock.now() > deadline:
            raise AssertionError(f"not within {WAIT_S} s: {what}")
        clock.sleep(0.002)


def closed_by_peer(sock: socket.socket) -> bool:
    """The other end closed `sock` (end of stream, or a reset because unread bytes were thrown away)."""
    sock.settimeout(WAIT_S)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True


def settle(uart: PacedUart, now: float, predicate, what: str) -> None:
    """Poll the port (through the UART, at line time `now`: nothing more is delivered) until `predicate()`."""
    until(lambda: uart.receive(now) == b"" and predicate(), what)


def delivered_after(uart: PacedUart, n: int, now: float) -> tuple[bytes, float]:
    """The next `n` bytes the line delivers, the line's time stepping 10 ms at a time from `now`."""
    got = bytearray()
    settle(uart, now, lambda: uart.rx_busy, f"{n} bytes reach the UART")
    while len(got) < n:
        now += 0.01
        got += uart.receive(now)
        assert now < 10.0, bytes(got)
    return bytes(got), now


@pytest.fixture
def line():
    port = TcpServerPort(0)
    port.vouch = hello_proves_a_key
    uart = PacedUart(port, 9600)
    sockets: list[socket.socket] = []

    def connect() -> socket.socket:
        sockets.append(socket.create_connection(("127.0.0.1", port.port), timeout=WAIT_S))
        return sockets[-1]
    yield port, uart, connect
    for sock in sockets:
        sock.close()
    uart.close()


def test_a_client_without_a_session_is_displaced_and_what_it_left_in_the_uart_is_not_delivered(line):
    port, uart, connect = line
    old = connect()
    old.sendall(b"\x01" * 2000)          # 2 s of line at 9600 baud
    first, now = delivered_after(uart, 50, 0.0)     # some are delivered, most wait in the UART
    assert set(first) == {1} and uart.rx_busy
    new = connect()
    new.sendall(HELLO)                   # it proves a key (the old one proved nothing)
    settle(uart, now, lambda: port.connections == 2, "the new client is taken")
    assert uart.discarded_rx_bytes > 1000
    new.sendall(b"\x02" * 10)
    got, now = delivered_after(uart, len(HELLO) + 10, now)
    assert got == HELLO + b"\x02" * 10                # its Hello, sent while it waited, first; none of the old's
    assert closed_by_peer(old)


def test_the_last_bytes_a_client_writes_before_it_closes_reach_the_controller(line):
    """A host writes its last Ack and closes (protocol.md, "Sessions and authentication"): the bytes and the end of
    stream come in one read, and the bytes are still delivered (a conformance client lost its last Ack in 2 runs
    of 6 when they were dropped with the client)."""
    port, uart, connect = line
    now = 0.0
    for n in range(1, 4):
        client = connect()
        client.sendall(HELLO)
        settle(uart, now, lambda: port.connections == n, f"client {n} taken")
        got, now = delivered_after(uart, len(HELLO), now)
        last = bytes([n]) * 40
        client.sendall(last)
        client.close()                                    # its last bytes and its end of stream, in one read
        settle(uart, now, lambda: port.generation == n, f"client {n} gone")
        got, now = delivered_after(uart, len(last), now)
        assert got == last


def test_a_client_that_proves_nothing_never_displaces_one_in_its_handshake(line):
    """The finding: a keyless local loop connecting every 5 ms kept every reconnecting host off `aspod sim --tcp`
    (0 of 4), each connection displacing the last. Now newcomers wait, and one that proves nothing takes the line
    from no one; the candidates are bounded."""
    port, uart, connect = line
    squatter = connect()
    settle(uart, 0.0, lambda: port.connections == 1, "a free line: the first comer takes it")
    genuine = connect()
    genuine.sendall(HELLO)
    settle(uart, 0.0, lambda: port.connections == 2, "a Hello displaces a client that proved nothing")
    assert closed_by_peer(squatter)
    loop = [connect() for _ in range(3 * TcpServerPort.MAX_CANDIDATES)]     # the keyless loop
    settle(uart, 0.0, lambda: port.dropped >= 2 * TcpServerPort.MAX_CANDIDATES, "the candidates stay bounded")
    assert port.connections == 2 and len(port._candidates) <= TcpServerPort.MAX_CANDIDATES
    genuine.sendall(b"\x05" * 5)
    got, _ = delivered_after(uart, len(HELLO) + 5, 0.0)
    assert got == HELLO + b"\x05" * 5                 # the host still holds the line
    for sock in loop:
        sock.close()


def test_a_link_of_several_admits_only_the_live_sessions_host(line):
    port, uart, connect = line
    port.live_only = True
    port.live_session = lambda: "a session the other links carry"
    port.vouch = lambda frame: {SCHEMA["Hello"].id: 2, SCHEMA["Ping"].id: 3}.get(frame.msg_id, 0)
    stranger = connect()
    stranger.sendall(HELLO)              # holds the key now, but is not the session's host
    settle(uart, 0.0, lambda: len(port._candidates) == 1 and port._candidates[0].proof == 2, "heard")
    assert port.connections == 0
    from protocol.framing import encode_frame
    from protocol.schema import MsgClass
    host = connect()
    host.sendall(encode_frame(MsgClass.COMMAND, 0, 0, SCHEMA["Ping"].id, bytes(4), key=b"k" * 32, counter=1))
    settle(uart, 0.0, lambda: port.connections == 1, "the session's host is taken")
    assert port._client is not None and port._candidates and port._candidates[0].proof == 2


def test_a_client_that_brought_a_live_session_keeps_the_line_and_the_newcomer_is_closed_at_once(line):
    port, uart, connect = line
    live = [None]
    port.live_session = lambda: live[0]
    genuine = connect()
    settle(uart, 0.0, lambda: port.connections == 1, "the genuine host is taken")
    live[0] = object()                   # its handshake completed: a session the controller holds
    intruder = connect()
    intruder.sendall(b"\xff" * 100)
    settle(uart, 0.0, lambda: port.refused == 1, "the intruder is refused")
    assert closed_by_peer(intruder)
    genuine.sendall(b"\x03" * 5)
    got, now = delivered_after(uart, 5, 0.0)
    assert got == b"\x03" * 5 and port.connections == 1 and port.generation == 0
    live[0] = None                       # the link timed out: no live session any more
    newcomer = connect()
    newcomer.sendall(HELLO)
    settle(uart, now, lambda: port.connections == 2, "a newcomer displaces a host whose link timed out")
    assert closed_by_peer(genuine)
    newcomer.close()


def test_a_session_that_was_live_before_the_client_connected_is_not_the_clients(line):
    """A squatter that connects while the previous host's session has not timed out yet does not inherit it."""
    port, uart, connect = line
    stale = object()
    port.live_session = lambda: stale    # the last host left a second ago; its link has not timed out
    squatter = connect()
    settle(uart, 0.0, lambda: port.connections == 1, "the squatter is taken")
    genuine = connect()
    genuine.sendall(HELLO)
    settle(uart, 0.0, lambda: port.connections == 2, "the genuine host displaces it")
    assert port.refused == 0 and closed_by_peer(squatter)
    genuine.close()
    settle(uart, 0.0, lambda: port.generation == 2, "the genuine host's leaving is seen")


def test_a_burst_of_connections_is_completed_by_the_kernel_before_any_is_taken():
    """32 connections at once, before the port reads: each completes at once (the listen backlog holds them),
    none waits for its SYN to be sent again, 1 s later, as the sixth did with a backlog of 4 (300 connections one
    after another took 52 s). The kernel completes them: no bound here depends on this process being scheduled."""
    port = TcpServerPort(0)
    clients = [socket.socket() for _ in range(32)]
    try:
        for sock in clients:
            sock.setblocking(False)
            sock.connect_ex(("127.0.0.1", port.port))
        pending, clock = list(clients), RealClock()
        deadline = clock.now() + 0.9                # the first SYN retransmission comes at 1 s
        while pending and clock.now() < deadline:
            _, ready, _ = select.select([], pending, [], max(0.0, deadline - clock.now()))
            pending = [sock for sock in pending if sock not in ready]
        assert not pending, f"{len(pending)} of 32 connections not completed within 0.9 s"
        assert all(sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) == 0 for sock in clients)
    finally:
        for sock in clients:
            sock.close()
        port.close()


def test_a_host_reconnects_to_aspod_sim_through_a_keyless_loop_connecting_every_5_ms(tmp_path):
    """The finding, through the real `aspod sim --tcp`: a local loop that connects every 5 ms (and sends nothing)
    kept every reconnecting host off (0 of 4). Now each of four connects in a row succeeds while it runs."""
    from tests import test_e2e
    from bench.bench_handshake import ConnectLoop
    from host_tools.client.live import HostClient
    from protocol import auth
    from protocol.messages import MESSAGES as M
    env = {**test_e2e.os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}
    sim = test_e2e.Sim(env, "--tcp", "0", "--no-tracker")
    try:
        psk = auth.load_key(sim.key_path)
        with ConnectLoop(sim.url) as loop:
            for attempt in range(4):
                client = HostClient(sim.url, psk)
                try:
                    client.connect(timeout_s=30)
                    assert client.call(M["Ping"](attempt)).ok
                finally:
                    client.close()
        assert loop.count > 100                 # the loop ran all along
    finally:
        sim.stop()
