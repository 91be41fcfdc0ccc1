"""End to end: `aspod sim` and `aspod teleop` as real subprocesses over a real pty or TCP.

These run in real time; they assert behaviour, not speed. Their waits are bounded on the sim's own time (the wall
time less its waits for a CPU: host_tools/worlds/own_time.py), so a busy machine slows them, never fails them.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import serial

from host_tools.client.live import HostClient
from host_tools.worlds.child import DEVNULL, PIPE, Child, ChildError, run
from protocol import auth
from protocol.errors import LinkError
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.states import ControllerState, Fault
from timebase import RealClock

pytestmark = pytest.mark.pty
ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
SESSION = "ping\nstatus\nestop\nreset\nquit\n"


def read_line(child: Child, timeout_s: float = 30.0, stream=None) -> str:
    """One line from the child's stdout (or stream="stderr"), waiting at most `timeout_s` for each byte."""
    try:
        return child.line(timeout_s, stream)
    except ChildError as exc:
        raise AssertionError(str(exc)) from None


@pytest.fixture
def env(tmp_path):
    """A private per-user config directory, so the parameter file is the test's own."""
    return {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}


class Sim:
    def __init__(self, env: dict, *args: str) -> None:
        self.env = env
        self.child = Child(["sim", *args], env=env)
        self.proc = self.child.proc
        link, key = read_line(self.child), read_line(self.child)
        assert link.startswith("ASPOD-LINK "), link
        assert key.startswith("ASPOD-KEY "), key
        self.url = link.split(" ", 1)[1]
        self.key_path = Path(key.split(" ", 1)[1])
        self.control_path = None           # the control endpoint's socket (aspod sim serves one by default)
        if "--no-control" not in args and "--hal" not in args:
            control = read_line(self.child)
            assert control.startswith("ASPOD-CONTROL "), control
            self.control_path = Path(control.split(" ", 1)[1])

    def teleop(self, script: str, *args: str, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
        return run(ASPOD + ["teleop", self.url, *args], input=script.encode(), env=self.env, timeout_s=timeout_s,
                   peers=(self.child.pid,))

    def wait(self, client: HostClient, predicate, timeout_s: float) -> bool:
        """`client.wait_for(predicate, ...)`, for at most `timeout_s` of this sim's own time."""
        return self.child.wait_for(lambda seconds: client.wait_for(predicate, seconds), timeout_s)

    def teleop_started(self, script: str, *args: str) -> Child:
        """`aspod teleop` running `script` in the background, once it has printed its first Pong."""
        host = Child(["teleop", self.url, *args], stdin=PIPE, env=self.env, peers=(self.child.pid,))
        host.proc.stdin.write(script.encode())
        host.proc.stdin.close()
        while "ok   Pong" not in read_line(host):
            pass
        return host

    def client(self) -> HostClient:
        client = HostClient(self.url, auth.load_key(self.key_path))
        client.connect()
        return client

    def stop(self) -> tuple[int, str]:
        """SIGTERM (then SIGKILL after 10 s); (exit status, the rest of its stderr)."""
        return self.child.stop(signal.SIGTERM, timeout_s=10)


@pytest.fixture
def sim_factory(env):
    sims = []

    def start(*args: str) -> Sim:
        sims.append(Sim(env, *args))
        return sims[-1]
    yield start
    for sim in sims:
        sim.stop()


def test_sim_prints_link_then_key_and_a_piped_session_exits_zero(sim_factory, env):
    sim = sim_factory("--pty")
    assert re.fullmatch(r"/dev/pts/\d+", sim.url)
    assert sim.key_path.name == f"sim-{sim.proc.pid}.key"
    assert oct(sim.key_path.stat().st_mode & 0o777) == "0o600"
    folder = sim.key_path.parent.lstat()
    assert folder.st_uid == os.getuid() and oct(folder.st_mode & 0o777) == "0o700"
    done = sim.teleop(SESSION)
    out = done.stdout.decode()
    assert done.returncode == 0, done.stderr.decode() + out
    assert "ok   Pong" in out and "state=ESTOP" not in out
    assert out.count("\nok ") + out.startswith("ok ") >= 4


def test_each_sim_makes_a_key_of_its_own_which_host_tools_find_and_which_goes_when_it_stops(sim_factory, tmp_path):
    """Every `aspod sim` of a user once shared one development key, so one simulator could sign what another's
    host would take for its own controller's."""
    sims = [sim_factory("--pty", "--no-tracker"), sim_factory("--tcp", "0", "--no-tracker"),
            sim_factory("--pty", "--no-tracker", "--hal", "udp_multicast")]     # the controller alone has one too
    keys = [auth.load_key(sim.key_path) for sim in sims]
    assert len(set(keys)) == 3 and len({sim.key_path for sim in sims}) == 3
    for sim in sims:                                       # teleop given only the link: the key is found
        done = sim.teleop("ping\nstatus\n")
        assert done.returncode == 0 and "ok   Pong" in done.stdout.decode(), done.stderr.decode()
    shared = tmp_path / "fleet.key"                        # a key shared on purpose: --key-file on every end
    auth.write_key(shared, bytes(range(32)))
    fleet = sim_factory("--pty", "--no-tracker", "--key-file", str(shared))
    assert fleet.key_path == shared and fleet.teleop("ping\n").returncode == 0
    status, err = sims[0].stop()
    assert status == 0 and not sims[0].key_path.exists(), err
    assert shared.exists() and sims[1].key_path.exists()  # a given key file is the user's: it stays


def test_the_same_session_over_tcp(sim_factory):
    sim = sim_factory("--tcp", "0")
    assert re.fullmatch(r"socket://127\.0\.0\.1:\d+", sim.url)
    done = sim.teleop(SESSION)
    assert done.returncode == 0, done.stderr.decode()
    done = sim.teleop("status\nfrobnicate 3\n")
    assert done.returncode == 2 and "unknown command 'frobnicate'" in done.stderr.decode()


def test_a_script_with_an_unknown_command_sends_nothing_and_names_it(sim_factory, tmp_path):
    sim = sim_factory("--pty")
    script = tmp_path / "bench.txt"
    script.write_text("ping\nestop\nlaunch rocket\n")
    done = sim.teleop("", "--script", str(script))
    assert done.returncode != 0
    assert "line 3: unknown command 'launch'" in done.stderr.decode()
    client = sim.client()
    try:
        status = client.call(M["GetStatus"]()).reply
        assert status.state == ControllerState.IDLE and status.commands_executed == 0   # estop never went
    finally:
        client.close()


def test_a_client_whose_simulator_has_gone_closes_without_an_error(sim_factory):
    """The pty's other end gone, pyserial's reset_input_buffer raises termios.error (not an OSError), which
    HostClient.close let out."""
    sim = sim_factory("--pty")
    client = sim.client()
    assert client.call(M["Ping"](1)).ok
    sim.stop()
    client.close()


def test_a_failing_command_makes_the_script_exit_non_zero(sim_factory):
    sim = sim_factory("--pty")
    done = sim.teleop("estop\nenable\nping\n")
    assert done.returncode == 1
    assert "FAIL Enable: rejected: ESTOP" in done.stdout.decode()
    assert "> ping" not in done.stdout.decode()       # stopped at the failure


def test_another_key_is_refused_with_a_reason_and_nothing_it_sent_executes(sim_factory, tmp_path):
    sim = sim_factory("--pty")
    other = tmp_path / "other.key"
    auth.write_key(other, bytes(range(32)))
    done = sim.teleop("estop\n", "--key-file", str(other), "--connect-timeout", "3")
    assert done.returncode == 3
    assert "BAD_MAC" in done.stderr.decode() and "different keys" in done.stderr.decode()
    client = sim.client()
    try:
        status = client.call(M["GetStatus"]()).reply
        assert status.state == ControllerState.IDLE and status.commands_executed == 0
        assert sim.wait(client, lambda: client.link.peer_stats is not None, 10.0)
        assert client.link.peer_stats.auth_errors > 0        # the foreign frames were counted
    finally:
        client.close()


def test_a_megabyte_of_garbage_then_the_same_session_still_succeeds(sim_factory):
    sim = sim_factory("--pty", "--no-pacing")
    garbage = random_bytes(1 << 20)
    with serial.serial_for_url(sim.url, timeout=1, write_timeout=120) as port:
        port.write(garbage)
        port.flush()
    done = sim.teleop(SESSION)
    assert done.returncode == 0, done.stderr.decode()
    client = sim.client()
    try:
        assert sim.wait(client, lambda: client.link.peer_stats is not None, 10.0)
        peer = client.link.peer_stats
        assert peer.bytes_rx >= 1 << 20            # the controller counted the garbage ...
        assert peer.crc_errors > 1000              # ... as frames that failed COBS/CRC
        assert client.call(M["Ping"](5)).ok        # and still works
    finally:
        client.close()


def test_killing_the_host_sends_the_controller_to_its_safe_state_within_the_timeout(sim_factory):
    wall = RealClock()
    sim = sim_factory("--pty", "--link-timeout", "1.0")
    started = wall.now()
    teleop = Child(["teleop", sim.url], stdin=PIPE, stderr=DEVNULL, env=sim.env, peers=(sim.child.pid,))
    host = teleop.proc
    host.stdin.write(b"enable\nping\nwait 600\n")
    host.stdin.close()
    pong_uptime_ms = None
    while pong_uptime_ms is None:
        line = read_line(teleop)
        found = re.search(r"Pong token=0 uptime_ms=(\d+)", line)
        if found:
            pong_uptime_ms = int(found.group(1))
    host.kill()                                   # no goodbye, no more frames
    killed = wall.now()
    since_kill = sim.child.own_time()
    host.wait()
    while True:                                   # the simulator logs every state change on stderr
        line = read_line(sim.child, 30.0, "stderr")
        found = re.search(r"uptime (\d+) ms: ENABLED -> FAULT \(LINK_TIMEOUT\), faults LINK_LOST", line)
        if found:
            break
    counters = read_line(sim.child, 30.0, "stderr")   # what the link had counted: a timeout's first clue
    assert re.search(r"the link until then: \d+ frames .* own stalls excused", counters), counters
    faulted = wall.now()
    took = since_kill.look()
    # The link timeout is on the wall clock (the host is a real process): the fault came no sooner than 1 s
    # after the host's last frame (itself after the host started) and within the timeout, plus slack, of the
    # kill, counted on the sim's own time (the controller excuses its own stalls: a busy machine only delays
    # it). On the controller's clock (paced: slower than the wall clock on a busy machine, never faster) it
    # came after the Pong, within the same bound of wall time.
    assert faulted - started >= 1.0 and took.own_s <= 1.0 + 3.0, took.describe()
    assert 0 < int(found.group(1)) - pong_uptime_ms <= (faulted - killed + 3.0) * 1000
    client = sim.client()
    try:
        status = client.call(M["GetStatus"]()).reply
        assert status.state == ControllerState.FAULT and status.faults & Fault.LINK_LOST   # latched
        assert sim.wait(client, lambda: any(e.spec.name == "StateChanged" and e.reason == Reason.LINK_TIMEOUT
                                             for e in client.events), 10.0)
        assert client.call(M["Reset"]()).ok
    finally:
        client.close()


def random_bytes(n: int) -> bytes:
    import random
    return random.Random(1).randbytes(n)


def test_teleop_reads_sets_and_saves_parameters(sim_factory, tmp_path):
    params = tmp_path / "params.json"
    sim = sim_factory("--pty", "--params", str(params))
    done = sim.teleop("get supply_min_v\nset telemetry_hz 5\nparams\nsave\n")
    out = done.stdout.decode()
    assert done.returncode == 0, done.stderr.decode() + out
    assert "name=supply_min_v value=22.00" in out and "telemetry_hz" in out and "[0 .. 200]" in out
    assert '"telemetry_hz": 5' in params.read_text()
    done = sim.teleop("set supply_min_v 99\n")
    assert done.returncode == 1 and "OUT_OF_RANGE" in done.stdout.decode()


def test_over_tcp_a_live_session_cannot_be_taken_over_and_the_next_host_gets_the_line(sim_factory):
    """Another local process connects while the genuine host's session is live and writes garbage: it is
    closed at once, the genuine session goes on undisturbed; when the genuine host leaves, the next connects."""
    import socket
    sim = sim_factory("--tcp", "0")
    host, port = sim.url[len("socket://"):].rsplit(":", 1)
    genuine = sim.client()
    try:
        assert genuine.call(M["Ping"](1)).ok
        intruder = socket.create_connection((host, int(port)), timeout=30)
        try:
            intruder.sendall(random_bytes(4096))
            try:
                assert intruder.recv(1) == b""          # closed by the controller's port ...
            except ConnectionResetError:
                pass                                    # ... with its unread garbage thrown away
        finally:
            intruder.close()
        for token in range(2, 7):
            assert genuine.call(M["Ping"](token)).ok, genuine.io_error
        status = genuine.call(M["GetStatus"]()).reply
        assert not status.faults & Fault.LINK_LOST
        assert sim.wait(genuine, lambda: genuine.link.peer_stats is not None, 10.0)
        before = genuine.link.peer_stats_s
        assert sim.wait(genuine, lambda: genuine.link.peer_stats_s != before, 10.0)   # a heartbeat after it all
        assert genuine.link.peer_stats.crc_errors == 0     # none of the intruder's bytes reached the link
        assert genuine.io_error is None and genuine.link.stats.auth_errors == 0
    finally:
        genuine.close()
    following = sim.client()          # the genuine host left: the next one gets the line at once
    try:
        assert following.call(M["Ping"](7)).ok
    finally:
        following.close()
    _, err = sim.stop()
    assert re.search(r"aspod sim: refused a TCP connection from 127\.0\.0\.1:\d+: a live authenticated session "
                     r"holds the line", err)


def test_a_closed_socket_is_reported_as_what_it_is_and_exits_3(sim_factory):
    sim = sim_factory("--tcp", "0", "--no-control")   # (killed below: no control socket's file left behind)
    host = sim.teleop_started("ping\nwait 5\nping\nping\n", "--key-file", str(sim.key_path))
    sim.proc.kill()                               # the controller's end of the socket closes
    sim.proc.wait()
    assert host.wait_exit(60) == 3
    out, err = host.proc.stdout.read().decode(), host.proc.stderr.read().decode()
    # the closed end says so, in a user's words, whether pyserial saw an end of file ("socket disconnected") or a
    # reset (the sim's end still held bytes unread when it was killed: once so beside a second test run and hogs)
    closed = f"the other end of {sim.url} closed it (the device unplugged, or the program serving it stopped)"
    assert f"FAIL Ping: no answer, the link is down: {closed}" in out, out
    assert f"error: line 3: 'ping': the link is down: {closed}" in err, err
    assert "retry limit" not in out + err


@pytest.mark.long
def test_a_second_host_on_the_pty_is_named_as_the_trouble_and_exits_3(sim_factory):
    """Two hosts on one pty steal each other's frames; the one whose session was replaced says so."""
    sim = sim_factory("--pty")
    # pings 2 s apart for 30 s: the first after the second host has its session fails (a loaded machine once took
    # longer than one 8 s pause to give the second host its session, and the first ended well, exit 0)
    first = sim.teleop_started("ping\n" + "wait 2\nping\n" * 15)
    second = None
    for _attempt in range(10):                    # its HelloReply may be read by the first host: try again
        try:
            second = sim.client()
            break
        except LinkError:
            continue
    assert second is not None, "the second host never got a session"
    try:
        assert first.wait_exit(90) == 3
        out, err = first.proc.stdout.read().decode(), first.proc.stderr.read().decode()
        # the cause as this end saw it: frames under another session's key, or (pyserial's words, when the other
        # host read the bytes this one was woken for) "multiple access on port?"
        assert "FAIL Ping: no answer, the link is down: " in out
        assert "another program seems to be writing on the line" in err or "multiple access on port" in err, err
        assert re.search(r"error: line \d+: 'ping': the link is down: ", err), err
        assert "retry limit" not in out + err
    finally:
        second.close()


def test_a_failed_save_shows_the_operating_systems_reason_at_teleop(sim_factory, tmp_path):
    params = tmp_path / "params.json"
    (tmp_path / "params.json.tmp").mkdir()        # where the save writes first: it cannot (root or not)
    sim = sim_factory("--pty", "--params", str(params))
    done = sim.teleop("set telemetry_hz 5\nsave\n")
    out = done.stdout.decode()
    assert done.returncode == 1, done.stderr.decode() + out
    assert f"FAIL ParamSave: rejected: SAVE_FAILED (26) (Is a directory: {params}.tmp)" in out
    assert not params.exists()
    (tmp_path / "params.json.tmp").rmdir()
    done = sim.teleop("save\n")
    assert done.returncode == 0 and f"ok   parameters saved to {params}" in done.stdout.decode()
