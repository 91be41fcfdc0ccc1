"""A serial line over TCP (`socket://`), at either end: frames go out as written, as on a serial line."""
from __future__ import annotations

import socket

import pytest

from host_tools.client.lines import RedundantLines, SerialLine
from host_tools.conform.probe import Probe
from host_tools.worlds.ports import DevicePort
from timebase import SimClock


@pytest.fixture
def listener():
    server = socket.create_server(("127.0.0.1", 0))
    yield server
    server.close()


def _no_delay(port) -> int:
    return port._socket.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)


def test_a_tcp_line_turns_nagle_off_so_a_small_frame_never_waits_for_a_delayed_ack(listener):
    """pyserial leaves Nagle's algorithm on: a frame written while the last was unacknowledged waited for the
    peer's delayed ACK (40 ms on Linux; the black-box fuzzer's commands took 43 ms, 3 ms with it off)."""
    url = f"socket://127.0.0.1:{listener.getsockname()[1]}"
    line = SerialLine(url, 115200)
    lines = RedundantLines([("radio", url), ("optical", url)], 115200, SimClock())
    probe = Probe(url, bytes(32), clock=SimClock())            # the conformance suite's host
    device = DevicePort(url, 115200)                           # a controller on a pyserial URL
    try:
        assert _no_delay(line.serial) == 1
        assert [_no_delay(port) for port in lines.ports.values()] == [1, 1]
        assert _no_delay(probe.port) == 1 and _no_delay(device._serial) == 1
    finally:
        for port in (line, lines, probe.port, device._serial):
            port.close()
