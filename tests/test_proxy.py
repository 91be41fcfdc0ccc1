"""`aspod proxy` between a real `aspod sim` and a real `aspod teleop`, over real ptys: impairments on, the live view
decoded, the capture read by `aspod log` and by tshark with the dissector; an endpoint that goes away is named."""
from __future__ import annotations

import re
import shutil
import signal
import threading

import pytest

from protocol import auth
from protocol.messages import MESSAGES as M
from host_tools.sessions.decode import MAC_OK, SessionDecoder
from host_tools.worlds.child import Child, run
from tests import test_e2e
from tests.captures import read_capture
from tests.test_wireshark_dissector import tshark_fields

pytestmark = pytest.mark.pty
ASPOD = test_e2e.ASPOD
env, sim_factory = test_e2e.env, test_e2e.sim_factory      # the fixtures, shared
read_line = test_e2e.read_line


def start_proxy(env, controller_url: str, *args: str) -> tuple[Child, str, list[bytes]]:
    """The proxy, the URL it offers the host, and its live view as it comes (read by a thread, so that a full pipe
    never stops it)."""
    proxy = Child(["proxy", "--controller", controller_url, *args], env=env)
    line = read_line(proxy)
    assert line.startswith("ASPOD-LINK "), line
    view: list[bytes] = []

    def read_view() -> None:
        try:
            view.extend(iter(proxy.proc.stdout.readline, b""))
        except (ValueError, OSError):      # the proxy stopped and its pipe was closed under the read
            pass
    threading.Thread(target=read_view, daemon=True).start()
    return proxy, line.split(" ", 1)[1], view


def test_a_teleop_session_through_an_impaired_proxy_is_seen_live_and_captured(sim_factory, env, tmp_path):
    sim = sim_factory("--pty", "--no-tracker")
    capture = tmp_path / "proxy.pcapng"
    proxy, url, view_lines = start_proxy(env, sim.url, "--impair", "ber=3e-4,drop=0.03,latency_ms=5,jitter_ms=5,seed=3",
                             "--record", str(capture), "--key-file", str(sim.key_path))
    script = "ping 1\nenable\ntelemetry 20\n" + "".join(f"ping {n}\n" for n in range(2, 40)) + "status\nquit\n"
    done = run(ASPOD + ["teleop", url, "--summary", "--key-file", str(sim.key_path)],     # (a proxy's address
               input=script.encode(), env=env, timeout_s=180, peers=(proxy.pid, sim.child.pid))   # is not the sim's)
    out = done.stdout.decode()
    assert done.returncode == 0, done.stderr.decode() + out
    assert out.count("ok   Pong") == 39
    status, err = proxy.stop(signal.SIGINT, timeout_s=10)
    assert status == 0, err
    view = b"".join(view_lines).decode()
    assert "host -> controller:" in err and "controller -> host:" in err       # the summary
    # the live view: decoded frames with verified MACs, and what the line did to some of them
    assert re.search(r"H>C COMMAND +seq=\d+ +ack=\d+ +Ping\(token=2\)  mac=ok", view), view[:2000]
    assert "[lost (drop)]" in view or "bit(s) flipped]" in view

    psk = auth.load_key(sim.key_path)
    recorded, frames, _ = read_capture(capture)
    assert recorded.error is None and recorded.info.tool == "aspod proxy"
    decoder = SessionDecoder(psk)
    decoded = [decoder.decode(f.data, f.time_s, f.link, f.direction, f.original_length) for f in frames]
    assert sum(d.name == "Ping" for d in decoded) >= 39                      # as sent, retransmissions too
    assert all(d.mac == MAC_OK for d in decoded if d.frame is not None)      # the capture holds frames as sent
    assert any(f.comment for f in frames)                           # each impaired one says how
    log = run(ASPOD + ["log", str(capture), "--stats"], text=True, timeout_s=60)
    assert log.returncode == 0 and "round trip COMMAND" in log.stdout

    if shutil.which("tshark"):
        lua = tmp_path / "aspod.lua"
        assert run(ASPOD + ["wireshark", "-o", str(lua)], timeout_s=60).returncode == 0
        rows = tshark_fields(lua, capture)
        assert [r["aspod.message"] for r in rows] == [d.name for d in decoded]


def test_a_proxy_whose_controller_goes_away_says_which_and_exits_nonzero(sim_factory, env):
    sim = sim_factory("--pty", "--no-tracker")
    proxy, _, _ = start_proxy(env, sim.url, "--no-view")
    sim.stop()
    status = proxy.wait_exit(30)
    err = proxy.proc.stderr.read().decode()
    assert status == 3, err
    assert "controller side" in err and sim.url in err and "Traceback" not in err


def test_proxy_refuses_bad_arguments_by_name(env):
    for args, words in ((["--controller", "tcp:99999"], "within 0..65535"),
                        (["--controller", "/dev/null", "--impair", "sunny"], "no impairment preset"),
                        (["--controller", "/no/such/device"], "/no/such/device")):
        done = run(ASPOD + ["proxy", *args], text=True, env=env, timeout_s=60)
        assert done.returncode in (2, 3) and words in done.stderr and "Traceback" not in done.stderr


def test_a_controller_that_reads_nothing_neither_hangs_the_proxy_nor_makes_it_grow(env):
    """The controller's end (a socket:// URL the proxy opens) takes nothing while the host floods: the proxy holds
    a bounded amount and stops reading the host (its writes wait, as on a full line), and it still stops at
    Ctrl-C. (pyserial's non-blocking write used to spin for ever on a peer that reads nothing, deaf to signals.)"""
    import socket
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    proxy = Child(["proxy", "--controller", f"socket://127.0.0.1:{listener.getsockname()[1]}", "--host", "tcp:0",
                   "--no-view"], env=env)
    sockets = [listener]
    try:
        line = read_line(proxy)
        assert line.startswith("ASPOD-LINK socket://127.0.0.1:"), line
        sockets.append(listener.accept()[0])          # the controller's end: never read
        host = socket.create_connection(("127.0.0.1", int(line.rsplit(":", 1)[1])), timeout=5)
        sockets.append(host)
        frame = b"\x00" + bytes(range(1, 41)) + b"\x00"
        sent = 0
        try:
            while sent < 64 * 1024 * 1024:             # until the proxy stops taking (a socket timeout)
                host.sendall(frame * 1000)
                sent += len(frame) * 1000
        except socket.timeout:
            pass
        assert sent < 64 * 1024 * 1024                 # held back: it did not read everything
        status, err = proxy.stop(signal.SIGINT, timeout_s=20)
        assert status == 0, err
        assert "host -> controller:" in err and "Traceback" not in err
    finally:
        proxy.stop(signal.SIGKILL)
        for s in sockets:
            s.close()


def test_two_new_endpoints_of_the_same_kind_are_two_sides():
    """`pty` and `tcp:0` make a new endpoint each time (tcp:0 a free port each): both sides may ask for one; the
    same fixed port twice is refused."""
    from host_tools.cli import settings
    from host_tools.cli.main import build_parser
    for endpoint in ("pty", "tcp:0"):
        args = build_parser().parse_args(["proxy", "--host", endpoint, "--controller", endpoint])
        assert (settings.proxy_settings(args).host, settings.proxy_settings(args).controller) == (endpoint, endpoint)
    with pytest.raises(ValueError, match="must differ"):
        settings.proxy_settings(build_parser().parse_args(["proxy", "--host", "tcp:7000", "--controller", "tcp:7000"]))


def test_a_tcp_host_with_a_live_session_is_not_displaced_by_a_new_connection(sim_factory, env):
    """As aspod sim's own TCP port does: a connection that comes while the host's frames flow is closed at once
    (the proxy attack of 2026-11-25: any new connection took the line from a host mid-session); once the host has
    gone, the next one is taken."""
    import socket
    from host_tools.client.live import HostClient
    sim = sim_factory("--pty", "--no-tracker")
    proxy, url, _ = start_proxy(env, sim.url, "--host", "tcp:0", "--no-view")
    host, port = url.removeprefix("socket://").rsplit(":", 1)
    psk = auth.load_key(sim.key_path)
    first = HostClient(url, psk)
    try:
        first.connect()
        assert first.call(M["Ping"](1)).ok
        intruder = socket.create_connection((host, int(port)), timeout=10)
        try:
            intruder.settimeout(10)
            assert intruder.recv(1) == b""                     # closed at once
        finally:
            intruder.close()
        assert first.call(M["Ping"](2)).ok                    # the host keeps its line
    finally:
        first.close()
    second = HostClient(url, psk)
    try:
        second.connect()
        assert second.call(M["Ping"](3)).ok
    finally:
        second.close()
    status, err = proxy.stop(signal.SIGINT, timeout_s=10)
    assert status == 0, err


def test_with_the_key_a_keyless_client_sending_well_formed_frames_does_not_hold_the_tcp_slot(sim_factory, env):
    """The finding: a keyless client sending CRC-valid frames held the proxy's TCP slot (each kept it "live"), and
    no host could come in. With --key-file only frames whose MAC verifies count; without it the proxy cannot tell
    (docs/sessions.md)."""
    import socket
    from protocol.framing import encode_frame
    from protocol.schema import MsgClass
    from host_tools.client.live import HostClient
    sim = sim_factory("--pty", "--no-tracker")
    proxy, url, _ = start_proxy(env, sim.url, "--host", "tcp:0", "--no-view", "--key-file", str(sim.key_path))
    host, port = url.removeprefix("socket://").rsplit(":", 1)
    squatter = socket.create_connection((host, int(port)), timeout=10)
    stop = threading.Event()

    def squat() -> None:              # a well-formed frame every 50 ms, signed with a key of its own
        counter = 1
        while not stop.wait(0.05):
            try:
                squatter.sendall(encode_frame(MsgClass.COMMAND, 0, 0, M["Ping"].spec.id, bytes(4),
                                              key=b"squatter-key-0123456789abcdef0", counter=counter))
            except OSError:
                return
            counter += 1
    threading.Thread(target=squat, daemon=True).start()
    try:
        client = HostClient(url, auth.load_key(sim.key_path))
        try:
            client.connect()
            assert client.call(M["Ping"](1)).ok
        finally:
            client.close()
    finally:
        stop.set()
        squatter.close()
    status, err = proxy.stop(signal.SIGINT, timeout_s=10)
    assert status == 0, err


def test_a_stopped_proxy_delivers_what_is_in_flight_so_a_hosts_close_reaches_the_controller(sim_factory, env):
    """Stopped while a host's Close is in its latency, the proxy delivers it before it closes: the session ends
    closed, not lost (before, the frames in flight died with the proxy and the controller latched LINK_LOST)."""
    from host_tools.client.live import HostClient
    sim = sim_factory("--pty", "--no-tracker")
    proxy, url, view = start_proxy(env, sim.url, "--impair", "latency_ms=700")
    client = HostClient(url, auth.load_key(sim.key_path))
    closing = threading.Thread(target=client.close, daemon=True)
    try:
        client.connect(timeout_s=60)
        assert client.call(M["Ping"](1)).ok
        closing.start()
        clock = test_e2e.RealClock()
        deadline = clock.now() + 60
        while not any(b"Close(" in line for line in view) and clock.now() < deadline:
            clock.sleep(0.01)             # the proxy shows the Close as it takes it in, before its latency
        assert any(b"Close(" in line for line in view), b"".join(view)[-2000:]
        proxy.proc.send_signal(signal.SIGTERM)
        status, err = proxy.stop(signal.SIGTERM, timeout_s=30)
        assert status == 0, err
        closing.join(timeout=30)
    finally:
        if closing.ident is None:        # it failed before the close began
            client.close()
    sim.child.wait_stderr(r"the host closed its session \(done\)")
