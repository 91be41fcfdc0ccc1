"""`aspod conform`: every check passes against the emulator (a real `aspod sim` on a pty and on TCP), the JUnit
XML names each check, the exit codes; and against controllers broken in one rule each, the check named for that
rule fails.

The broken controllers are a `ControllerLink` with a small application of its own (`Toy`), served on a TCP port by
a thread of this process, one behaviour patched per variant. Unpatched, the toy passes every check: the suite
judges the link, not the emulator's plant.
"""
from __future__ import annotations

import os
import socket
import struct
import sys
import threading
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Callable, Optional

import pytest

from protocol import auth
from protocol.controller_link import ControllerLink
from protocol.errors import ParseError
from protocol.framing import Frame, FrameReceiver
from protocol.link import PRIO_RELIABLE, LinkConfig, TokenBucket
from protocol.messages import SCHEMA
from protocol.reasons import Reason
from protocol.reliable import Verdict
from protocol.schema import MsgClass
from host_tools.cli.main import main
from host_tools.conform import checks as conform_checks
from host_tools.conform.checks import CHECKS, SECTIONS, Options, by_name
from host_tools.conform.controller import PlayedController
from host_tools.conform.host_checks import HOST_CHECKS, judge_host, watch_host
from host_tools.conform.junit import junit_xml
from host_tools.conform.probe import Probe
from host_tools.conform.runner import FAIL, PASS, SKIP, run_checks
from host_tools.worlds.child import Child, run
from host_tools.worlds.ports import TcpServerPort

ROOT = Path(__file__).resolve().parent.parent
KEY = bytes(range(32))


# ---- a controller of the link alone, on TCP, in this process --------------------------------------------------

class Toy:
    """conform's own `PlayedController` (a `ControllerLink`, or `link_class`, with a small application), served on
    a TCP port by a thread of this process: 1 s link timeout, 0.3 s heartbeats."""

    def __init__(self, link_class=ControllerLink, failsafe: bool = True, receiver: Optional[FrameReceiver] = None,
                 played_class=PlayedController, gone_after: Optional[str] = None):
        self.played = played_class(KEY, link_class, LinkConfig(heartbeat_s=0.3, link_timeout_s=1.0),
                                   failsafe=failsafe, receiver=receiver)
        self.port = TcpServerPort(0)
        self.url = self.port.url
        self._stop = False
        if gone_after is not None:           # the line goes (the port closed) once this command has run
            execute = self.played.link._handler

            def and_go(msg, urgent, now):
                self._stop = self._stop or msg.spec.name == gone_after
                return execute(msg, urgent, now)
            self.played.link._handler = and_go
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        self.played.serve(self.port, lambda: self._stop)
        self.port.close()

    def close(self) -> None:
        self._stop = True
        self._thread.join(5.0)


# ---- the broken variants: each breaks one rule ----------------------------------------------------------------

class AnswersReplays(ControllerLink):
    """Forgets the counters it accepted: a frame sent again byte for byte goes on to be answered."""

    def _session_for(self, frame: Frame):
        session = super()._session_for(frame)
        if session is not None:
            session.rx_counter = -1
        return session


class NaksWithoutEcho(ControllerLink):
    """Its NAKs name the reason only: no class, number, message or tag of the refused frame."""

    def _send_nak(self, reason, frame, expected):
        super()._send_nak(reason, None, expected)


class RunsDuplicates(ControllerLink):
    """Executes a command sent again with the same number a second time (no reply cache)."""

    def _handle(self, frame: Frame, spec, now: float) -> None:
        if frame.cls == MsgClass.COMMAND and self._commands.classify(frame.seq) is Verdict.DUPLICATE \
                and self._commands.cached_reply(frame.seq) is not None:
            reply = self._handler(spec.decode(frame.payload), False, now)
            self.commands_executed += 1
            self._queue(PRIO_RELIABLE, frame.cls, frame.seq, reply.spec.id, reply.spec.encode(reply))
            return
        super()._handle(frame, spec, now)


class NaksEveryFrame(ControllerLink):
    """Answers every unauthenticated frame with a NAK, however many come (no rate limit)."""

    def __init__(self, *args, **kw) -> None:
        super().__init__(*args, **kw)
        self._naks = TokenBucket(1e6, 1e6)


class IgnoresLinkTimeout(ControllerLink):
    """Never notices that the host has gone: no safe state, telemetry and heartbeats go on."""

    @property
    def quiet(self) -> bool:
        return False

    def poll(self, now: float) -> None:
        super().poll(now)
        self.link_lost = False


class NoEventWindow(ControllerLink):
    """Sends every event at once, however many are unacknowledged (no event window)."""

    def _new_channels(self) -> None:
        super()._new_channels()
        self._events.window = 64


class DropsBeyondWindow(ControllerLink):
    """Of the new commands that come in one read, takes only a window's worth and drops the rest unanswered."""

    def feed(self, data: bytes, now: float) -> None:
        self.taken_in_this_read = 0
        super().feed(data, now)

    def _handle(self, frame: Frame, spec, now: float) -> None:
        if frame.cls == MsgClass.COMMAND and self._commands.classify(frame.seq) is Verdict.NEW:
            self.taken_in_this_read = getattr(self, "taken_in_this_read", 0) + 1
            if self.taken_in_this_read > self.config.window:
                return
        super()._handle(frame, spec, now)


class LateResync(FrameReceiver):
    """After a segment that does not decode, drops the next one too (resynchronises a frame late)."""

    def __init__(self) -> None:
        super().__init__()
        self.skip_next = False

    def feed(self, data: bytes):
        out = []
        for item in super().feed(data):
            if isinstance(item, ParseError):
                self.skip_next = True
            elif self.skip_next:
                self.skip_next = False
                continue
            out.append(item)
        return out


class SlowLine(PlayedController):
    """Refuses telemetry above 2 Hz (as a controller on a slow line may, with a reason)."""

    def execute(self, msg, urgent, now):
        if msg.spec.name == "SetTelemetryRate" and msg.rate_hz > 2:
            return SCHEMA["Result"].type(int(Reason.OUT_OF_RANGE))
        return super().execute(msg, urgent, now)


def _run(toy: Toy, names: list[str], options: Options = Options()) -> dict[str, object]:
    probe = Probe(toy.url, KEY)
    try:
        checks = [c for c in CHECKS if c.name in set(names) | {"handshake"}]
        return {r.check.name: r for r in run_checks(probe, checks, options)}
    finally:
        probe.close()


@pytest.fixture
def toy_factory():
    toys: list[Toy] = []

    def make(**kw) -> Toy:
        toys.append(Toy(**kw))
        return toys[-1]
    yield make
    for toy in toys:
        toy.close()


@pytest.mark.realtime
@pytest.mark.long
def test_the_toy_controller_passes_every_check(toy_factory):
    results = _run(toy_factory(), [c.name for c in CHECKS], Options(allow_motion=True))
    failed = {name: r.lines() for name, r in results.items() if r.status != PASS}
    assert not failed


@pytest.mark.realtime
@pytest.mark.parametrize("variant, kw, caught_by", [
    ("answers a replayed frame", dict(link_class=AnswersReplays), ["replay-dropped"]),
    ("NAKs without the echo", dict(link_class=NaksWithoutEcho), ["nak-echo"]),
    ("runs a duplicate twice", dict(link_class=RunsDuplicates), ["duplicate-from-cache"]),
    ("NAKs every unsigned frame", dict(link_class=NaksEveryFrame), ["garbage-bounded"]),
    ("ignores the link timeout", dict(link_class=IgnoresLinkTimeout, failsafe=False), ["link-loss-failsafe"]),
    ("resynchronises a frame late", dict(receiver=LateResync()), ["framing-resync-garbage", "framing-resync-torn"]),
    ("sends events past its window", dict(link_class=NoEventWindow), ["event-window"]),
    ("drops commands past the window", dict(link_class=DropsBeyondWindow), ["commands-beyond-window"]),
])
def test_a_controller_broken_in_one_rule_is_caught_by_the_check_named_for_it(toy_factory, variant, kw, caught_by):
    results = _run(toy_factory(**kw), caught_by)
    assert results["handshake"].status == PASS, results["handshake"].lines()
    for name in caught_by:
        assert results[name].status == FAIL, (variant, results[name].lines())
        assert results[name].expected and results[name].seen


def test_every_check_names_a_section_of_the_protocol_page_and_is_unique():
    headings = {line[3:].strip() for line in (ROOT / "docs" / "protocol.md").read_text().splitlines()
                if line.startswith("## ")}
    assert set(SECTIONS) <= headings, set(SECTIONS) - headings
    assert {c.section for c in CHECKS} <= set(SECTIONS)
    assert len(by_name()) == len(CHECKS)
    assert [c.name for c in CHECKS if c.motion] == ["close-disables"]     # the only one that sends Enable


def test_no_check_sends_motion_without_allow_motion():
    """The source of every check but the motion ones names no command that drives an output."""
    import inspect
    motion = ("Enable", "Move", "MoveBy", "Jog", "Home", "Grip", "TrajRun", "BoxSwitch", "BoxDial")
    for check in CHECKS:
        if check.motion:
            continue
        source = inspect.getsource(check.run)
        assert not [m for m in motion if f'SCHEMA["{m}"]' in source], check.name
    assert "Enable" not in inspect.getsource(conform_checks._reset)


def test_the_junit_report_names_each_check_with_its_section_and_outcome():
    results = []
    from host_tools.conform.runner import Result
    for n, check in enumerate(CHECKS):
        status = (PASS, FAIL, SKIP)[n % 3]
        results.append(Result(check, status, "why" if status != FAIL else "", "this", "that", 0.5))
    root = ET.fromstring(junit_xml(results, "socket://x:1", 12.0))
    suite = root.find("testsuite")
    cases = suite.findall("testcase")
    assert [c.get("name") for c in cases] == [c.name for c in CHECKS]
    assert all(c.get("classname") == f"protocol.md.{check.section}" for c, check in zip(cases, CHECKS))
    assert int(suite.get("failures")) == len([c for c in cases if c.find("failure") is not None])
    assert int(suite.get("skipped")) == len([c for c in cases if c.find("skipped") is not None])
    failure = next(c.find("failure") for c in cases if c.find("failure") is not None)
    assert "expected: this" in failure.text and "saw: that" in failure.text


# ---- the command line: exit codes ----------------------------------------------------------------------------

def test_bad_usage_exits_2(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    assert main(["conform", "socket://127.0.0.1:9", "--only", "no-such-check", "--key-file", str(_key(tmp_path))]) == 2
    assert "no check named no-such-check" in capsys.readouterr().err
    assert main(["conform"]) == 2
    key = _key(tmp_path)
    assert main(["conform", "socket://127.0.0.1:9", "--key-file", str(key), "--junit", str(key)]) == 2


def test_a_link_that_cannot_be_opened_exits_3(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    with socket.create_server(("127.0.0.1", 0)) as closed:
        port = closed.getsockname()[1]
    assert main(["conform", f"socket://127.0.0.1:{port}", "--key-file", str(_key(tmp_path))]) == 3


@pytest.mark.realtime
def test_a_controller_with_another_key_exits_3(capsys, tmp_path, monkeypatch, toy_factory):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    toy = toy_factory()
    code = main(["conform", toy.url, "--key-file", str(_key(tmp_path, bytes(range(1, 33)))), "--only", "handshake"])
    out = capsys.readouterr()
    assert code == 3, out
    assert "FAIL handshake" in out.out


@pytest.mark.realtime
def test_a_line_that_fails_during_the_run_exits_3_and_skips_the_rest(capsys, tmp_path, monkeypatch, toy_factory):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    toy = toy_factory(gone_after="EStop")          # urgent-lane's EStop: the controller's line goes
    code = main(["conform", toy.url, "--key-file", str(_key(tmp_path)), "--skip-slow"])
    out = capsys.readouterr()
    assert code == 3, out
    assert "SKIP clean-close" in out.out and "not run: the line failed" in out.out, out.out


def test_list_names_every_check(capsys):
    assert main(["conform", "--list"]) == 0
    out = capsys.readouterr().out
    assert all(f"{c.name} ({c.level}, {c.cites}" in out for c in CHECKS)


def _key(folder: Path, key: bytes = KEY) -> Path:
    path = folder / f"k{key[0]}.key"
    path.write_text(key.hex() + "\n")
    return path


# ---- against the emulator: `aspod sim` on a pty and on TCP -----------------------------------------------------

@pytest.fixture
def env(tmp_path):
    (tmp_path / "run").mkdir(mode=0o700)
    return {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config"), "XDG_RUNTIME_DIR": str(tmp_path / "run"),
            "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}


@pytest.mark.pty
@pytest.mark.long
@pytest.mark.parametrize("where", ["--pty", "--tcp"])
def test_every_check_passes_against_the_emulator(env, tmp_path, where):
    sim = Child(["sim", where, *(["0"] if where == "--tcp" else []), "--no-tracker"], env=env)
    try:
        link = sim.line(30.0)
        assert link.startswith("ASPOD-LINK "), link
        sim.line(30.0), sim.line(30.0)                  # ASPOD-KEY, ASPOD-CONTROL: the endpoint is up
        url = link.split(" ", 1)[1]
        report = tmp_path / "conform.xml"
        done = run([sys.executable, "-m", "host_tools.cli.main", "conform", url, "--junit", str(report)],
                   cwd=ROOT, env=env, text=True, timeout_s=300, peers=(sim.pid,))
    finally:
        _status, sim_said = sim.stop(timeout_s=10)
    assert done.returncode == 0, done.stdout + done.stderr + "\nthe simulator said:\n" + sim_said
    lines = done.stdout.splitlines()
    for check in CHECKS:
        status = "SKIP" if check.motion else "PASS"
        assert any(line.startswith(f"{status} {check.name} ({check.level}, {check.cites})") for line in lines), \
            (check.name, done.stdout)
    cases = ET.parse(report).getroot().find("testsuite").findall("testcase")
    assert [c.get("name") for c in cases] == [c.name for c in CHECKS]
    assert not [c for c in cases if c.find("failure") is not None]


def test_the_probe_refuses_a_bad_url():
    from protocol.errors import LinkError
    with pytest.raises(LinkError):
        Probe("nosuchscheme://x", KEY)
    assert struct.calcsize("<H") == 2


def test_the_conformance_page_names_every_check_with_its_section():
    page = (ROOT / "docs" / "conformance.md").read_text()
    for check in CHECKS + HOST_CHECKS:
        row = next((line for line in page.splitlines() if line.startswith(f"| `{check.name}`")), None)
        assert row is not None and f"| {check.section} |" in row, check.name


# ---- --host: conform plays the controller, a host is judged ------------------------------------------------------

def _host_session(url: str, key: bytes) -> None:
    """A host's ordinary work: connect, a Ping, an EStop and its Reset, a Ping, a clean close. conform drops the
    Reset's reply (command 1) and, once it has sent it again, two forged NAKs the host must ignore; the last Ping's
    reply comes behind them on the line, so the host is still in its session when they come (without it the host
    closed at once on the Reset's reply, and a host that believed them was in CLOSING: never caught, a race)."""
    from host_tools.client.live import HostClient
    client = HostClient(url, key)
    try:
        client.connect()
        for msg in (SCHEMA["Ping"].type(7), SCHEMA["EStop"].type(), SCHEMA["Reset"].type(), SCHEMA["Ping"].type(8)):
            assert client.call(msg, 10.0).ok
    finally:
        client.close()


@pytest.mark.pty
def test_conform_host_judges_a_good_host_and_passes_it(env, tmp_path):
    child = Child(["conform", "--host", "--tcp", "0", "--wait", "20", "--junit", str(tmp_path / "host.xml")],
                  env=env)
    try:
        url = child.ready("ASPOD-LINK ").split(" ", 1)[1]
        key = auth.load_key(child.ready("ASPOD-KEY ").split(" ", 1)[1])
        _host_session(url, key)
        status = child.wait_exit(60.0)
        out = child.proc.stdout.read().decode()
    finally:
        child.stop(timeout_s=10)
    assert status == 0, out
    for check in HOST_CHECKS:
        assert f"PASS {check.name} ({check.level}, {check.cites})" in out, (check.name, out)
    cases = ET.parse(tmp_path / "host.xml").getroot().find("testsuite").findall("testcase")
    assert [c.get("name") for c in cases] == [c.name for c in HOST_CHECKS]


def _watch_a_host(session: Callable[[str, bytes], None] = None) -> dict[str, object]:
    """conform's played controller on TCP in a thread, a host's session against it, the host checks' results."""
    port = TcpServerPort(0)
    watched = []
    server = threading.Thread(target=lambda: watched.append(watch_host(
        port, KEY, 10.0, LinkConfig(heartbeat_s=0.3, link_timeout_s=1.0))), daemon=True)
    server.start()
    try:
        try:
            (session or _host_session)(port.url, KEY)
        except AssertionError:
            pass                        # a broken host may fail its own work; its frames are judged all the same
        server.join(30.0)
    finally:
        port.close()
    return {r.check.name: r for r in judge_host(watched[0])}


@pytest.mark.realtime
def test_conform_host_catches_a_host_that_never_acknowledges_events(monkeypatch):
    from protocol.host_link import HostLink
    from protocol.reliable import NOTHING_RECEIVED_ACK
    monkeypatch.setattr(HostLink, "_ack_value", lambda self: NOTHING_RECEIVED_ACK)
    monkeypatch.setattr(HostLink, "_event", lambda self, frame, spec, now: None)
    results = _watch_a_host()
    assert results["host-acks-events"].status == FAIL, results["host-acks-events"].lines()
    assert results["host-authenticates"].status == PASS
    assert results["host-commands-in-order"].status == PASS


@pytest.mark.realtime
def test_conform_host_catches_a_host_that_never_resends(monkeypatch):
    from protocol.reliable import ReliableSender
    due = ReliableSender.due
    monkeypatch.setattr(ReliableSender, "due", lambda self, now, resend=True: due(self, now, resend=False))

    def session(url: str, key: bytes) -> None:
        from host_tools.client.live import HostClient
        client = HostClient(url, key)
        try:
            client.connect()
            client.call(SCHEMA["Ping"].type(1), 3.0)
            client.call(SCHEMA["Ping"].type(2), 3.0)        # its reply is the one dropped: never asked for again
        finally:
            client.close()
    results = _watch_a_host(session)
    assert results["host-resends"].status == FAIL, results["host-resends"].lines()
    assert "never" in results["host-resends"].seen
    assert results["host-authenticates"].status == PASS


@pytest.mark.realtime
def test_conform_host_catches_a_host_that_believes_any_no_session(monkeypatch):
    from protocol.host_link import HostLink
    from protocol.link import LinkState

    def believes(self, frame, now):
        if self.state is LinkState.UP:
            self.connect(now)
    monkeypatch.setattr(HostLink, "_verifies_handshake_nak", lambda self, frame: True)
    monkeypatch.setattr(HostLink, "_handle_handshake_nak", believes)
    results = _watch_a_host()
    assert results["host-resends"].status == PASS, results["host-resends"].lines()
    assert results["host-ignores-forged-no-session"].status == FAIL, results["host-ignores-forged-no-session"].lines()


@pytest.mark.realtime
def test_a_telemetry_rate_refused_for_the_line_is_measured_at_a_lower_one(toy_factory):
    result = _run(toy_factory(played_class=SlowLine), ["telemetry-rate"])["telemetry-rate"]
    assert result.status == PASS and "asked 2" in result.detail, result.lines()
