"""The report's two links: `aspod sim --link radio=pty --link optical=tcp:0`, a host on both, each link through
an `aspod proxy` that takes it out for a while (a fade on the radio, a blockage on the optical link, at other
times): every command runs exactly once and none is lost. Plus the merger alone: copies dropped, nothing else."""
from __future__ import annotations

import re
import signal
import select

import pytest

from protocol import auth
from protocol.errors import LinkError
from protocol.framing import encode_frame
from protocol.link import LinkConfig
from protocol.messages import MESSAGES as M, SCHEMA
from timebase import RealClock, SimClock
from host_tools.client.lines import EMPTY_READY_LIMIT_S, READ_TIMEOUT_S, RedundantLines, parse_links
from host_tools.worlds.ports import url_schemes
from host_tools.client.live import HostClient
from host_tools.sessions.redundancy import MEMORY, FrameMerger
from host_tools.worlds.ports import PtyPort
from tests import test_e2e
from tests.test_proxy import start_proxy

env, sim_factory = test_e2e.env, test_e2e.sim_factory      # the fixtures, shared


def test_the_merger_keeps_the_first_copy_of_each_frame_and_cuts_each_path_on_its_own():
    frames = [encode_frame(1, i, 0, SCHEMA["Ping"].id, i.to_bytes(4, "little")) for i in range(6)]
    merger = FrameMerger(["radio", "optical"])
    a = merger.feed("radio", b"".join(frames[:3]) + frames[3][:5], 0.0)    # radio stops inside frame 3
    b = merger.feed("optical", b"".join(frames[:5]), 0.1)                  # optical brings 0-4
    c = merger.feed("radio", frames[3][5:] + frames[4] + frames[5], 0.2)  # radio finishes 3, brings 4, 5
    assert a == b"".join(frames[:3]) and b == b"".join(frames[3:5]) and c == frames[5]
    radio, optical = merger.paths["radio"], merger.paths["optical"]
    assert (radio.frames, radio.first, radio.copies) == (6, 4, 2)
    assert (optical.frames, optical.first, optical.copies) == (5, 2, 3)
    damaged = bytearray(frames[0])
    damaged[3] ^= 0x10
    assert merger.feed("optical", bytes(damaged), 0.3) == bytes(damaged)   # not a copy: the link layer judges it


def test_the_merger_forgets_old_frames_so_its_memory_stays_bounded():
    merger = FrameMerger(["a"])
    frames = [encode_frame(1, i % 65536, 0, SCHEMA["Ping"].id, i.to_bytes(4, "little")) for i in range(3 * MEMORY)]
    for frame in frames:
        merger.feed("a", frame, 0.0)
    assert len(merger._seen) == MEMORY
    assert merger.feed("a", frames[0], 1.0) == frames[0]       # long gone from memory: passed on, for the link


def test_link_addresses_parse_as_the_simulator_prints_them():
    assert parse_links("/dev/pts/3") == [("link", "/dev/pts/3")]
    assert parse_links("radio=socket://127.0.0.1:4000") == [("radio", "socket://127.0.0.1:4000")]   # one, named
    assert parse_links("radio=/dev/pts/3,optical=socket://127.0.0.1:4000") == [
        ("radio", "/dev/pts/3"), ("optical", "socket://127.0.0.1:4000")]
    assert parse_links("/dev/pts/3,/dev/pts/4") == [("link0", "/dev/pts/3"), ("link1", "/dev/pts/4")]
    with pytest.raises(ValueError):
        parse_links("a=/dev/pts/3,a=/dev/pts/4")


@pytest.mark.parametrize("url", ["socket://127.0.0.1:99999", "socket://", "socket://127.0.0.1:abc",
                                 "socket://:4000", "optical=socket://127.0.0.1:0,radio=/dev/null"])
def test_a_socket_link_that_is_not_host_and_port_is_refused_saying_what_it_must_be(url):
    with pytest.raises(LinkError, match=r"a socket link is socket://HOST:PORT, PORT a number 1\.\.65535"):
        HostClient(url, bytes(32))


@pytest.mark.pty
def test_links_without_tcp_serve_a_teleop_session_over_both(sim_factory):
    """`--link radio=pty --link optical=pty` (no link guards its line as TCP does) once stopped the simulator
    with a traceback before its ready line."""
    sim = sim_factory("--link", "radio=pty", "--link", "optical=pty", "--no-tracker")
    links = dict(parse_links(sim.url))
    assert set(links) == {"radio", "optical"} and all(re.fullmatch(r"/dev/pts/\d+", u) for u in links.values())
    done = sim.teleop("ping\nstatus\nestop\nreset\nquit\n")
    out = done.stdout.decode()
    assert done.returncode == 0, done.stderr.decode() + out
    assert "ok   Pong" in out
    client = HostClient(sim.url, auth.load_key(sim.key_path))
    try:
        client.connect()
        assert client.call(M["Ping"](7)).reply.token == 7
        health = client.line.health()
    finally:
        client.close()
    assert len(health) == 2 and not any("nothing heard yet" in line for line in health), health   # both carried it


@pytest.mark.pty
def test_commands_over_two_links_through_a_fade_and_a_blockage_run_once_each(sim_factory, env):
    sim = sim_factory("--link", "radio=pty", "--link", "optical=tcp:0", "--no-tracker")
    links = dict(parse_links(sim.url))
    assert set(links) == {"radio", "optical"}
    # the outages come after the host has connected: 8 s after the radio's proxy starts, and if three processes
    # starting and a handshake took longer than that on a busy machine, the proxies start again with twice the lead
    clock = RealClock()
    for lead_s in (8.0, 16.0, 32.0):
        radio, radio_url, _ = start_proxy(env, links["radio"], "--no-view", "--impair",
                                          f"radio,fade={lead_s:g}+2.5,seed=1")
        radio_start = clock.now()
        optical, optical_url, _ = start_proxy(env, links["optical"], "--no-view", "--impair",
                                              f"optical,block={lead_s + 4:g}+2,seed=2")
        # each proxy's outage counts from its own start (a busy machine once started the optical one over 3 s later)
        outages_over = max(radio_start + lead_s + 2.5, clock.now() + lead_s + 4 + 2) + 0.5
        # a retry limit that outlasts a busy machine's stalls (the default 8 sends give up after about 7 s, which a
        # CI run beside other work once exceeded): what this test is about is that no command runs twice or is lost
        client = HostClient(f"radio={radio_url},optical={optical_url}", auth.load_key(sim.key_path),
                            config=LinkConfig(retry_limit=20))
        try:
            client.connect()
        except LinkError as exc:       # what each path carried says which of four processes was not there
            client.close()
            raise AssertionError(f"{exc}; {client.line.health()}; host link {client.link.stats}") from exc
        connected_at = clock.now() - radio_start
        if connected_at < lead_s:
            break
        client.close()                 # connected after the fade began (8.2 s once, beside a second test run)
        radio.stop()
        optical.stop()
    else:
        raise AssertionError(f"the host connected {connected_at:.1f} s after the radio's proxy started, after the "
                             f"fade began, three times")
    try:
        # at least 600 commands, and on until both outages are over
        handles, sent_at = [], []
        while len(handles) < 600 or clock.now() < outages_over:
            sent_at.append(clock.now() - radio_start)
            handles.append(client.call(M["Ping"](len(handles)), timeout_s=60))
        count = len(handles)
        failed = [k for k, h in enumerate(handles) if not h.ok]
        if failed:      # when it was sent, what the host's link and each path saw, what the simulator said
            _, said = sim.child.stop(timeout_s=10)
            raise AssertionError(f"Ping {failed[0]} sent {sent_at[failed[0]]:.1f} s after the radio's proxy started: "
                                 f"{handles[failed[0]].describe()}; {client.line.health()}; host link "
                                 f"{client.link.stats}; the simulator: {said[-3000:]}")
        assert [h.reply.token for h in handles] == list(range(count))
        status = client.call(M["GetStatus"]()).reply
        assert status.commands_executed == count       # none twice (GetStatus is counted once it has answered)
        health = client.line.health()
    finally:
        client.close()
    assert len(health) == 2 and all("copies dropped" in line for line in health)
    lost, said = {}, {}
    for name, proxy in (("radio", radio), ("optical", optical)):
        status, said[name] = proxy.stop()
        assert status == 0, said[name]
        lost[name] = [int(n) for n in re.findall(r"(\d+) in fades, (\d+) in blockages", said[name])[0]]
    # the outages really took frames: the radio's in its fade, the optical link's in its blockage
    assert lost["radio"][0] > 0 and lost["optical"][1] > 0, (lost, health, said)


def _read_as_many(lines: RedundantLines, expected: bytes, within_s: float = 10.0) -> bytes:
    """Read `lines` until as many bytes as `expected` have come (bounded: a real pty, real time)."""
    clock, got = RealClock(), b""
    deadline = clock.now() + within_s
    while len(got) < len(expected) and clock.now() < deadline:
        got += lines.read()
    return got


def test_a_link_whose_other_end_has_gone_is_dropped_and_the_other_carries_on():
    first, second = PtyPort(), PtyPort()
    lines = RedundantLines([("a", first.url), ("b", second.url)], 115200, RealClock())
    try:
        frames = [encode_frame(1, i, 0, SCHEMA["Ping"].id, i.to_bytes(4, "little")) for i in range(2)]
        second.write(frames[0])
        assert _read_as_many(lines, frames[0]) == frames[0] and not lines.failed
        first.close()                          # the controller's end of link a is gone (its pty closed)
        second.write(frames[1])
        assert _read_as_many(lines, frames[1]) == frames[1]
        clock = RealClock()
        deadline = clock.now() + 10.0
        while "a" not in lines.failed and clock.now() < deadline:
            lines.read()
        assert set(lines.failed) == {"a"} and any("FAILED" in line for line in lines.health())
    finally:
        lines.close()
        second.close()


class _FindsNothing:
    """Stands in for link a's port: ready to the selector (its real fd has a byte waiting), yet its read finds
    nothing (the race: the one thing here that cannot be made to happen at will). Counts its reads."""

    def __init__(self, real) -> None:
        self.real, self.reads = real, 0

    def read(self, size: int) -> bytes:
        self.reads += 1
        return b""

    def fileno(self) -> int:
        return self.real.fileno()

    def close(self) -> None:
        self.real.close()


def _ready_but_empty(clock) -> tuple[RedundantLines, _FindsNothing, list]:
    """Two links on real ptys, link a's port a `_FindsNothing` whose fd the selector sees ready."""
    first, second = PtyPort(), PtyPort()
    lines = RedundantLines([("a", first.url), ("b", second.url)], 115200, clock)
    stub = lines.ports["a"] = _FindsNothing(lines.ports["a"])
    first.write(b"\x00")
    ready, _, _ = select.select([stub.fileno()], [], [], 10.0)      # the byte has reached the host's end
    assert ready, "the byte written to link a never made its fd ready"
    return lines, stub, [first, second]


def test_a_link_that_selects_ready_but_reads_nothing_stays():
    """pyserial's read, without a timeout, does its own select: it can find nothing where the selector found the
    port ready. That is no closed link (pyserial raises for one); the link stays in the set."""
    lines, stub, ports = _ready_but_empty(SimClock())
    try:
        for _ in range(3):
            lines.read()
        assert stub.reads == 3 and not lines.failed and set(lines.ports) == {"a", "b"}
    finally:
        lines.close()
        for port in ports:
            port.close()


def test_a_link_that_stays_ready_with_nothing_to_read_is_paced_then_dropped():
    """Each read that finds a link ready and nothing to read waits out READ_TIMEOUT_S (the selector returns at
    once: without it the reading thread spins), and after EMPTY_READY_LIMIT_S of that the link is dropped; the
    other carries on."""
    clock = SimClock()
    lines, stub, ports = _ready_but_empty(clock)
    try:
        while "a" not in lines.failed and stub.reads < 2 * EMPTY_READY_LIMIT_S / READ_TIMEOUT_S:
            before = clock.now()
            lines.read()
            if "a" not in lines.failed:
                assert clock.now() - before >= READ_TIMEOUT_S * (1 - 1e-9), stub.reads      # paced
        assert set(lines.failed) == {"a"} and "nothing came" in lines.failed["a"] and set(lines.ports) == {"b"}
        assert EMPTY_READY_LIMIT_S <= clock.now() <= EMPTY_READY_LIMIT_S + 2 * READ_TIMEOUT_S
    finally:
        lines.close()
        for port in ports:
            port.close()


def test_the_host_says_how_long_its_pump_was_held_up():
    """A host whose pump cannot turn sends nothing, heartbeats neither: `pump_pause_max_s` says how long that
    lasted (teleop's summary prints it). Held here by its own lock while its clock moves on 2 s."""
    from timebase import SimClock
    port, clock = PtyPort(), SimClock(100.0)
    client = HostClient(port.url, bytes(32), clock=clock)
    try:
        with client._cond:
            clock.advance_by(2.0)
        for _ in range(200):                    # its next turn, within 10 s of the wall clock (the clock is frozen)
            with client._cond:
                if client.pump_pause_max_s >= 2.0:
                    break
                client._cond.wait(0.05)
        assert 2.0 <= client.pump_pause_max_s < 2.5
    finally:
        client.close()
        port.close()


@pytest.mark.parametrize("url", ["bogus://x", "a=/dev/pts/3,b=BOGUS://x", "socket://:4000"])
def test_a_link_address_pyserial_cannot_take_is_refused_when_parsed_before_anything_opens(url):
    with pytest.raises(ValueError, match=r"unknown link scheme bogus://; .* socket://|a socket link is"):
        parse_links(url)
    assert {"socket", "loop", "rfc2217"} <= set(url_schemes())


@pytest.mark.pty
def test_a_dropped_optical_link_is_taken_up_again_by_the_host_and_admitted_for_the_session_only(sim_factory, env):
    """The finding: the host never took a failed link up again, and the controller's port then served any local
    client. Now the host opens it again every second while its line is open (`RedundantLines`), and the
    controller's optical port, while the session lives, admits only a connection its host's frames come over."""
    import socket
    from tests.test_proxy import start_proxy
    sim = sim_factory("--link", "radio=pty", "--link", "optical=tcp:0", "--no-tracker")
    links = dict(parse_links(sim.url))
    with socket.socket() as probe:               # a port for the optical link's proxy, the same across its restart
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    optical, optical_url, _ = start_proxy(env, links["optical"], "--host", f"tcp:{port}", "--no-view")
    client = HostClient(f"radio={links['radio']},optical={optical_url}", auth.load_key(sim.key_path))
    clock = RealClock()
    try:
        client.connect(timeout_s=60)
        assert client.call(M["Ping"](1)).ok
        optical.stop(signal.SIGKILL, timeout_s=10)        # the beam is cut: the host's optical link fails
        deadline = clock.now() + 60
        while "optical" not in client.line.failed and clock.now() < deadline:
            assert client.call(M["Ping"](2)).ok            # the radio carries the session meanwhile
        assert "optical" in client.line.failed, client.line.health()
        stranger = socket.create_connection(links["optical"].removeprefix("socket://").rsplit(":", 1), timeout=10)
        stranger.sendall(b"\x00garbage\x00")               # a local client on the free optical port: not admitted
        optical, _, _ = start_proxy(env, links["optical"], "--host", f"tcp:{port}", "--no-view")
        carried = client.line.merger.paths["optical"].frames
        deadline = clock.now() + 60
        while client.line.merger.paths["optical"].frames <= carried + 3 and clock.now() < deadline:
            assert client.call(M["Ping"](3)).ok
        assert client.line.reopened >= 1 and "optical" not in client.line.failed, client.line.health()
        assert client.line.merger.paths["optical"].frames > carried + 3      # the controller answers over it again
        stranger.settimeout(30)
        assert stranger.recv(1) == b""                       # it waited as a candidate, then was closed
        stranger.close()
    finally:
        client.close()
        optical.stop(signal.SIGINT, timeout_s=10)


@pytest.mark.pty
@pytest.mark.parametrize("line, said", [
    ("silent", "nothing came back to"),
    ("busy", "with a cookie but not with a session"),      # only other hosts' answers and its own cookies: not a key problem
    ("other key", "different keys"),
])
def test_a_handshake_that_fails_says_which_way_it_failed(line, said):
    """The finding: a starved handshake was reported as "the two ends have different keys". Now an unanswered
    Hello, a busy line and a MAC failure under this key are told apart (protocol/host_link.py `HandshakeSeen`)."""
    import threading
    from protocol.controller_link import ControllerLink
    from bench.bench_handshake import recorded_hello
    key = b"diagnosis-test-key-0123456789abc"
    controller_end = PtyPort()
    stop = threading.Event()
    if line != "silent":
        answering = ControllerLink(key if line == "busy" else b"another-key-0123456789abcdef012", lambda *a: None)
        for n in range(4):
            answering.feed(recorded_hello(key, bytes([n]) * 16), 0.0)
        others = answering.take_all(0.0)

        def cookies_only(data: bytes) -> bytes:     # a controller too busy to answer with a session
            from protocol.framing import decode_frame
            kept = [s for s in data.split(b"\x00") if s and decode_frame(s).msg_id != SCHEMA["HelloReply"].id]
            return b"".join(b"\x00" + s + b"\x00" for s in kept)

        def answer() -> None:         # other hosts' cookies, and a cookie for whatever this host sends
            while not stop.wait(0.05):
                data = controller_end.read(4096)
                if data and line == "busy":
                    answering.feed(data, 0.0)
                    controller_end.write(cookies_only(answering.take_all(0.0)) + others)
                elif line != "busy":
                    controller_end.write(others)
        threading.Thread(target=answer, daemon=True).start()
    client = HostClient(controller_end.url, key)
    try:
        with pytest.raises(LinkError) as refused:
            client.connect(timeout_s=2.0)
        assert said in str(refused.value), str(refused.value)
        if line != "other key":
            assert "different keys" not in str(refused.value)
    finally:
        stop.set()
        client.close()
        controller_end.close()


@pytest.mark.parametrize("kind", ["socket", "pty"])
def test_a_line_counts_every_byte_waiting_so_a_read_takes_them_at_once(kind):
    """pyserial's `in_waiting` for socket:// says at most 1, and a read then cost a select and a recv a byte (200 kB
    took 1.5 CPU s, 0.025 now: host_tools/client/lines.py); the line asks the kernel how many are waiting."""
    import socket
    from host_tools.client.lines import SerialLine
    payload = bytes(range(256)) * 12
    if kind == "socket":
        server = socket.socket()
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        line = SerialLine(f"socket://127.0.0.1:{server.getsockname()[1]}", 115200)
        peer, _ = server.accept()
        send, closing = peer.sendall, [peer, server]
    else:
        port = PtyPort()
        line = SerialLine(port.url, 115200)
        send, closing = port.write, [port]
    try:
        send(payload)
        fd = line.serial.fileno()
        assert select.select([fd], [], [], 10.0)[0]
        deadline = RealClock().now() + 10.0
        while line._waiting() < len(payload) and RealClock().now() < deadline:
            select.select([], [], [], 0.001)      # the kernel moves the rest across
        assert line._waiting() == len(payload)
        assert line.read() == payload
    finally:
        line.close()
        for thing in closing:
            thing.close()
