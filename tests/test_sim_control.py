"""The simulator's control endpoint: its requests on the lock-step world (every op, every kind of bad input
changes nothing), its socket server driven by hand over a real Unix socket (bounds, many clients, garbage, a
client gone mid-line, a step answered when done), and finding it from a link URL
(host_tools/worlds/plant_control.py, control_server.py, host_tools/client/control.py)."""
from __future__ import annotations

import io
import json
import os
import re
import socket
import tempfile
import threading
from pathlib import Path
from typing import Callable

import pytest

from host_tools.client.bench import BenchClient
from host_tools.client.control import ControlClient, ControlUnavailable, find_control, simulator_key
from host_tools.plugin.errors import CannotFault
from host_tools.plugin.target import LockstepTarget
from host_tools.teleop.session import run_script
from host_tools.teleop.words import completions, help_text
from host_tools.worlds.control_server import (IDLE_S, MAX_CLIENTS, MAX_LINE, OUT_HIGH, ControlServer, LinkInfo,
                                              claim_path, link_endpoints)
from host_tools.worlds.runtime_folder import RuntimeFolder, private_dir, runtime_dir, search_folders
from host_tools.worlds.plant_control import NO_PAUSE, OPS, PlantControl
from host_tools.worlds.plant_state import plant_state
from host_tools.worlds.settings import PlantSettings
from host_tools.worlds.world import LockstepBench
from protocol.errors import KeyFileError
from protocol.messages import MESSAGES as M
from tests import test_e2e
from timebase import PacedClock, SimClock

env, sim_factory = test_e2e.env, test_e2e.sim_factory      # the fixtures, shared


@pytest.fixture
def world():
    bench = LockstepBench(seed=1)
    yield bench
    bench.close()


def snapshot(bench: LockstepBench) -> dict:
    """Everything a request could change: the plant's truth (faults, gravity, payload, object included) and time."""
    return {"state": plant_state(bench.world.plant), "time_s": bench.clock.now()}


# ---- requests on the lock-step world ----

def test_every_plant_op_does_what_it_says_and_says_it(world):
    said, changes = [], []
    control = PlantControl(world.world.plant, world.clock, log=said.append, on_change=changes.append)
    plant = world.world.plant
    assert control.request({"op": "fault", "name": "jam", "channel": "j2"}) == \
        {"ok": True, "said": "injected jam:j2", "faults": ["jam:j2"]}
    assert control.request({"op": "fault", "name": "encoder_dropout", "channel": 0})["faults"] == \
        ["encoder_dropout:j1", "jam:j2"]
    assert control.request({"op": "fault", "name": "jam", "channel": "j2"})["said"] == "jam:j2 already active"
    assert control.request({"op": "faults"})["said"] == "active faults: encoder_dropout:j1, jam:j2"
    assert control.request({"op": "clear", "name": "jam:j2"})["faults"] == ["encoder_dropout:j1"]
    assert control.request({"op": "clear", "name": "jam", "channel": "j2"})["said"] == "jam:j2 was not active"
    assert control.request({"op": "fault", "name": "supply_sag"})["ok"]
    assert control.request({"op": "clear", "name": "all"})["said"] == "cleared encoder_dropout:j1, supply_sag"
    assert plant.faults == frozenset()
    assert control.request({"op": "gravity", "mode": "orbit"})["ok"] and plant.arm.gravity == "orbit"
    assert control.request({"op": "payload", "kg": 1.5})["ok"] and plant.arm.payload_kg == 1.5
    assert control.request({"op": "object", "width_m": 0.02})["ok"] and plant.arm.object_width_m == 0.02
    assert control.request({"op": "object", "width_m": None})["ok"] and plant.arm.object_width_m is None
    assert control.request({"op": "clouds", "on": True})["faults"] == ["clouds"] and plant.tracker.overcast
    assert control.request({"op": "clouds", "on": False})["faults"] == [] and not plant.tracker.overcast
    state = control.request({"op": "state"})
    assert state["ok"] and state["time_s"] == 0.0 and state["paused"] is False
    assert state["state"] == plant_state(plant) and state["state"]["gravity"] == "orbit"
    assert control.request({"op": "time"}) == {"ok": True, "said": "simulated time 0.000 s", "time_s": 0.0,
                                               "paused": False}
    assert control.request({"op": "info"})["ops"] == list(OPS)
    assert said[0] == "control: injected jam:j2" and len(said) == len(changes) == 11
    assert changes[0] == {"op": "fault", "name": "jam", "channel": "j2"}


def test_on_the_lockstep_world_there_is_nothing_to_pause_and_it_says_why(world):
    for request in ({"op": "pause"}, {"op": "resume"}, {"op": "step", "seconds": 1.0}):
        assert world.control.request(request) == {"ok": False, "error": NO_PAUSE}


BAD_LINES = [
    b"not json", b"\xff\xfe{}", b"[]", b'"fault"', b"{}", b"[" * 5000, b'{"op": "payload", "kg": NaN}',
    b'{"op": "payload", "kg": Infinity}', b'{"op": "payload", "kg": 1e400}',
    b'{"op": "payload", "kg": 1' + b"0" * 400 + b"}",
]
BAD_REQUESTS = [
    {"op": 3}, {"op": "explode"}, {"op": None}, {"op": "fault"}, {"op": "fault", "name": "jam"},
    {"op": "fault", "name": "jam", "channel": "j9"}, {"op": "fault", "name": "melt", "channel": "j1"},
    {"op": "fault", "name": "supply_sag", "channel": "j1"}, {"op": "fault", "name": "jam", "channel": True},
    {"op": "fault", "name": "jam", "channel": 7}, {"op": "fault", "name": "jam", "channel": 1.5},
    {"op": "fault", "name": ["jam"], "channel": "j1"}, {"op": "fault", "name": "x" * 5000, "channel": "j1"},
    {"op": "fault", "name": "jam:j1", "channel": "j1"}, {"op": "fault", "name": "jam", "channel": "j1", "now": 1},
    {"op": "clear", "name": "all", "channel": "j1"}, {"op": "clear"}, {"op": "gravity", "mode": "moon"},
    {"op": "gravity", "mode": None}, {"op": "gravity"}, {"op": "payload", "kg": -1}, {"op": "payload", "kg": "1"},
    {"op": "payload", "kg": True}, {"op": "payload", "kg": 1001}, {"op": "object", "width_m": 0},
    {"op": "object", "width_m": 1.0}, {"op": "object", "width_m": "none"}, {"op": "object"},
    {"op": "clouds", "on": "yes"}, {"op": "clouds", "on": 1}, {"op": "step", "seconds": 0},
    {"op": "step", "seconds": 61}, {"op": "time", "x": 1}, {"op": "state", "op2": "state"},
]


@pytest.mark.parametrize("line", BAD_LINES + [json.dumps(r).encode() for r in BAD_REQUESTS])
def test_bad_input_of_any_kind_is_refused_with_a_reason_and_changes_nothing(world, line):
    said = []
    control = PlantControl(world.world.plant, world.clock, log=said.append)
    control.request({"op": "fault", "name": "stuck_brake", "channel": "j4"})
    before = snapshot(world)
    reply = control.handle_line(line).poll()
    assert reply["ok"] is False and isinstance(reply["error"], str) and 10 < len(reply["error"]) < 400
    assert snapshot(world) == before and said == ["control: injected stuck_brake:j4"]


def test_a_fault_the_plant_refuses_changes_nothing(world):
    control = world.control
    control.request({"op": "object", "width_m": 0.02})
    before = snapshot(world)
    reply = control.request({"op": "fault", "name": "jam", "channel": "gripper"})
    assert not reply["ok"] and "holds an object" in reply["error"]
    reply = control.request({"op": "object", "width_m": 0.03})            # the jaws are open 25.4 mm
    assert not reply["ok"] and "narrower than the object" in reply["error"]
    assert snapshot(world) == before
    no_tracker = LockstepBench(seed=1, plant=PlantSettings(tracker=False))
    try:
        reply = no_tracker.control.request({"op": "clouds", "on": True})
        assert not reply["ok"] and "no solar tracker" in reply["error"] and no_tracker.world.plant.faults == set()
        assert "tracker" not in no_tracker.control.request({"op": "state"})["state"]
    finally:
        no_tracker.close()


def test_a_recorded_change_is_done_again_by_replay_and_a_bad_one_is_refused(world):
    world.control.request({"op": "fault", "name": "jam", "channel": "j3"})
    other = LockstepBench(seed=1)
    try:
        other.redo({"control": {"op": "fault", "name": "jam", "channel": "j3"}})
        assert other.world.plant.faults == world.world.plant.faults
        with pytest.raises(ValueError, match="unknown fault"):
            other.redo({"control": {"op": "fault", "name": "melt"}})
    finally:
        other.close()


# ---- the socket server, driven by hand ----

@pytest.fixture
def folder():
    """A short private folder: a Unix socket's path is at most 107 bytes."""
    with tempfile.TemporaryDirectory(prefix="aspod-t", dir="/tmp") as name:
        yield Path(name)


class Served:
    """A server on a real socket, its task run by hand (`pump`), and raw clients."""

    def __init__(self, path: Path, control: PlantControl, **kwargs) -> None:
        self.logged: list[str] = []
        self.server = ControlServer(path, control, log=self.logged.append, **kwargs)
        self.now = 0.0

    def run_in_background(self) -> Callable[[], None]:
        """Its loop in a thread, as `aspod sim` runs it, for a blocking host (`ControlClient`); returns `stop`."""
        done = threading.Event()

        def loop() -> None:
            while not done.wait(0.002):
                self.pump(1)
        thread = threading.Thread(target=loop)
        thread.start()

        def stop() -> None:
            done.set()
            thread.join()
        return stop

    def pump(self, polls: int = 3) -> None:
        for _ in range(polls):
            self.now = self.server.poll(self.now)

    def connect(self) -> socket.socket:
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        conn.connect(str(self.server.path))
        conn.setblocking(False)
        self.pump()
        return conn

    def replies(self, conn: socket.socket, count: int = 1, polls: int = 50) -> list[dict]:
        data = bytearray()
        for _ in range(polls):
            self.pump(1)
            try:
                chunk = conn.recv(1 << 20)
                if not chunk:
                    break
                data += chunk
            except BlockingIOError:
                pass
            if data.count(b"\n") >= count:
                break
        return [json.loads(line) for line in data.splitlines()]

    def ask(self, conn: socket.socket, *requests) -> list[dict]:
        conn.sendall(b"".join(json.dumps(r).encode() + b"\n" for r in requests))
        return self.replies(conn, len(requests))

    def closed_by_server(self, conn: socket.socket) -> bool:
        self.pump()
        try:
            return conn.recv(1 << 20) == b""
        except BlockingIOError:
            return False


@pytest.fixture
def served(folder, world):
    wall = SimClock()
    pacer = PacedClock(wall)
    said: list[str] = []
    served = Served(folder / "ctl.sock", PlantControl(world.world.plant, pacer, log=said.append))
    served.said, served.pacer, served.bench = said, pacer, world
    yield served
    served.server.close()


def test_requests_are_answered_in_order_and_a_line_may_come_in_pieces(served):
    conn = served.connect()
    replies = served.ask(conn, {"op": "fault", "name": "jam", "channel": "j1"}, {"op": "faults"}, {"op": "time"})
    assert [r["said"] for r in replies] == ["injected jam:j1", "active faults: jam:j1", "simulated time 0.000 s"]
    conn.sendall(b'{"op": "clear", ')
    served.pump()
    conn.sendall(b'"name": "all"}\n')
    assert served.replies(conn)[0]["said"] == "cleared jam:j1"


def test_a_line_longer_than_the_bound_is_refused_and_its_connection_closed(served):
    conn = served.connect()
    before = snapshot(served.bench)
    conn.sendall(b'{"op": "fault", "name": "' + b"j" * MAX_LINE)
    reply = served.replies(conn)
    assert reply == [{"ok": False, "error": f"a request line is at most {MAX_LINE} bytes; closing"}]
    assert served.closed_by_server(conn) and snapshot(served.bench) == before
    assert served.server.clients == [] and "longer than" in served.logged[-1]


def test_garbage_gets_errors_and_the_endpoint_serves_on(served):
    conn = served.connect()
    garbage = bytes(range(256)) * 8 + b"\n{]\n\x00\n"
    conn.sendall(garbage)
    replies = served.replies(conn, garbage.count(b"\n"))
    assert replies and all(not r["ok"] for r in replies)
    other = served.connect()
    assert served.ask(other, {"op": "time"})[0]["ok"] and served.ask(conn, {"op": "faults"})[0]["ok"]


def test_a_bounded_number_of_clients_the_next_told_why(served):
    conns = [served.connect() for _ in range(MAX_CLIENTS)]
    extra = served.connect()
    assert served.replies(extra)[0]["error"].startswith(f"too many control clients ({MAX_CLIENTS})")
    assert served.closed_by_server(extra)
    assert all(served.ask(c, {"op": "time"})[0]["ok"] for c in conns)
    conns.pop().close()
    served.pump()
    assert served.ask(served.connect(), {"op": "faults"})[0]["ok"]


def test_idle_clients_yield_their_slots_to_newcomers_busy_ones_do_not(served):
    """Eight clients that connect and say nothing once held the endpoint for good."""
    squatters = [served.connect() for _ in range(MAX_CLIENTS)]
    busy = served.connect()                   # all taken, none idle for IDLE_S yet: told so
    assert served.replies(busy)[0]["error"].startswith(f"too many control clients ({MAX_CLIENTS}), all busy")
    served.now += IDLE_S                      # (the endpoint's clock: the link's wall clock)
    newcomers = []
    for k in range(3):                        # each newcomer displaces the client idle the longest: the oldest
        newcomers.append(served.connect())
        assert served.ask(newcomers[-1], {"op": "time"})[0]["ok"]
        assert served.closed_by_server(squatters[k])
        assert "idle for 2 s to make room" in served.logged[-1]
    assert len(served.server.clients) == MAX_CLIENTS
    assert all(served.ask(s, {"op": "time"})[0]["ok"] for s in squatters[3:])      # the others are served on


def test_a_client_whose_idle_connection_was_closed_opens_it_again_and_never_resends(served, folder):
    small = Served(folder / "small.sock", served.server.control, max_clients=2)
    stop = small.run_in_background()
    client = ControlClient(small.server.path)
    try:
        assert client.request({"op": "time"})["ok"]
    finally:
        stop()
    small.now += IDLE_S + 1
    first = small.connect()
    small.connect()                           # full: the host's connection, idle the longest, makes room
    assert len(small.server.clients) == 2 and "to make room" in small.logged[-1]
    first.close()
    small.pump()
    stop = small.run_in_background()
    try:
        assert client.request({"op": "time"})["ok"] and client.reconnects == 1       # as if nothing happened
    finally:
        stop()
        client.close()
        small.server.close()
    # a request whose connection ends before its reply may have run: said, never sent again
    silent_path = folder / "silent.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as listener:
        listener.bind(str(silent_path))
        listener.listen(1)
        client = ControlClient(silent_path)
        conn, _ = listener.accept()

        def read_one_line_and_hang_up() -> None:
            received = b""
            while b"\n" not in received:
                received += conn.recv(4096)
            conn.close()
            lines.append(received)
        lines: list[bytes] = []
        thread = threading.Thread(target=read_one_line_and_hang_up)
        thread.start()
        with pytest.raises(ControlUnavailable, match="closed the connection before it answered.*may have run"):
            client.request({"op": "fault", "name": "jam", "channel": "j1"})
        thread.join()
        listener.settimeout(0.5)
        with pytest.raises(socket.timeout):
            listener.accept()                 # no second connection: nothing was sent again
    assert lines == [b'{"op": "fault", "name": "jam", "channel": "j1"}\n']


def test_a_client_gone_mid_line_changes_nothing_and_is_forgotten(served):
    conn = served.connect()
    before = snapshot(served.bench)
    conn.sendall(b'{"op": "fault", "name": "jam", "chan')
    served.pump()
    conn.close()
    served.pump()
    assert served.server.clients == [] and snapshot(served.bench) == before
    whole = served.connect()                 # a whole line then end of file: still answered, then closed
    whole.sendall(b'{"op": "fault", "name": "jam", "channel": "j4"}\n')
    whole.shutdown(socket.SHUT_WR)
    assert served.replies(whole)[0]["said"] == "injected jam:j4"
    assert served.closed_by_server(whole) and served.server.clients == []


def test_a_client_that_never_reads_is_held_to_a_bound_and_never_blocks_the_loop(served):
    conn = served.connect()
    conn.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    line = json.dumps({"op": "state"}).encode() + b"\n"
    sent = 0
    for _ in range(2000):
        try:
            sent += conn.send(line * 20)
        except BlockingIOError:
            break
        served.pump(1)
    served.pump(20)
    client = served.server.clients[0]
    assert len(client.outbox) < OUT_HIGH + 4096      # what waits for it is bounded; the polls all returned
    assert served.ask(served.connect(), {"op": "time"})[0]["ok"]


def test_a_step_is_answered_when_done_while_other_clients_are_served(served):
    stepper, other = served.connect(), served.connect()
    assert served.ask(stepper, {"op": "step", "seconds": 0.5})[0]["error"] == "step runs a held world: pause it first"
    assert served.ask(stepper, {"op": "pause"})[0]["said"] == "held at 0.000 s"
    stepper.sendall(b'{"op": "step", "seconds": 0.5}\n{"op": "time"}\n')
    assert served.replies(stepper, polls=5) == []        # not yet: the world has not run
    assert served.ask(other, {"op": "time"})[0]["time_s"] == 0.0
    assert served.ask(other, {"op": "step", "seconds": 1})[0]["error"] == "a step is under way already (to 0.500 s)"
    for k in range(1, 600):
        served.pacer.advance(k * 0.001, float("inf"))
    replies = served.replies(stepper, 2)
    assert replies[0] == {"ok": True, "said": "stepped 0.5 s to 0.500 s, held", "time_s": 0.5, "paused": True}
    assert replies[1]["time_s"] == 0.5
    assert served.said == ["control: held at 0.000 s", "control: stepping 0.5 s from 0.000 s"]
    served.ask(stepper, {"op": "step", "seconds": 0.5})  # (answered later) ...
    served.ask(other, {"op": "resume"})
    assert served.replies(stepper)[0]["error"] == "resumed at 0.500 s, before the step to 1.000 s ended"


# ---- the socket's file and folder ----

def test_the_socket_is_private_replaces_a_dead_ones_file_and_is_removed_at_close(folder, world):
    path = folder / "ctl.sock"
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(str(path))
    dead.close()                              # a file that nothing serves: a simulator that died
    server = ControlServer(path, world.control)
    assert oct(path.stat().st_mode & 0o777) == "0o600"
    with pytest.raises(OSError, match="a live process serves"):
        ControlServer(path, world.control)
    server.close()
    assert not path.exists()
    (folder / "file").write_text("mine")
    with pytest.raises(OSError, match="not a socket"):
        claim_path(folder / "file")
    with pytest.raises(OSError, match="longer than a Unix socket's path"):
        claim_path(folder / ("x" * 120))
    with pytest.raises(OSError, match="cannot make the socket"):
        ControlServer(folder / "no" / "such.sock", world.control)


def test_the_default_folder_is_private_or_refused(folder):
    mine = folder / "aspod"
    private_dir(mine)
    assert oct(mine.stat().st_mode & 0o777) == "0o700"
    assert RuntimeFolder.open({"XDG_RUNTIME_DIR": str(folder)}).control_path(42) == mine / "sim-42.sock"
    assert runtime_dir({}) == Path(f"/tmp/aspod-{os.getuid()}")
    assert runtime_dir({"TMPDIR": str(folder)}) == folder / f"aspod-{os.getuid()}"
    os.chmod(mine, 0o770)
    with pytest.raises(OSError, match="open to other users"):
        private_dir(mine)


def squat(folder: Path, how: str) -> None:
    """Make `folder` as someone else would have: open to every user, or (as root) another user's."""
    folder.mkdir()
    if how == "open to others":
        os.chmod(folder, 0o777)
    elif os.geteuid() != 0:
        pytest.skip("only root can make a folder another user's")
    else:
        os.chown(folder, 65534, 65534)


@pytest.mark.parametrize("how", ["open to others", "another user's"])
def test_a_runtime_folder_taken_first_gives_a_folder_of_its_own_that_hosts_find_and_that_goes(folder, how):
    squat(folder / f"aspod-{os.getuid()}", how)
    said: list[str] = []
    runtime = RuntimeFolder.open({"TMPDIR": str(folder)}, log=said.append)
    assert runtime.made and runtime.path.parent == folder and runtime.path.name.startswith(f"aspod-{os.getuid()}-")
    assert oct(runtime.path.lstat().st_mode & 0o777) == "0o700" and "using a folder of its own" in said[0]
    assert search_folders({"TMPDIR": str(folder)}) == [runtime.path]       # the one taken is not trusted
    key, path = runtime.new_key()
    assert path.parent == runtime.path and oct(path.stat().st_mode & 0o777) == "0o600"
    runtime.close()
    assert not runtime.path.exists()


def test_hosts_trust_only_folders_of_this_users_that_no_one_else_may_enter(folder):
    uid = os.getuid()
    good, open_one, link = folder / f"aspod-{uid}-good", folder / f"aspod-{uid}-open", folder / f"aspod-{uid}-link"
    good.mkdir(mode=0o700)
    open_one.mkdir(mode=0o700)
    os.chmod(open_one, 0o755)
    link.symlink_to(good)
    (folder / f"aspod-{uid}-file").write_text("")
    assert search_folders({"TMPDIR": str(folder)}) == [good]


def test_a_key_left_by_a_simulator_that_was_killed_goes_when_the_folder_is_next_opened(folder):
    environ = {"XDG_RUNTIME_DIR": str(folder)}
    first = RuntimeFolder.open(environ)
    _, mine = first.new_key()
    dead = mine.with_name("sim-999999999.key")      # beyond any pid Linux hands out
    mine.rename(dead)
    _, mine = first.new_key()
    RuntimeFolder.open(environ)
    assert mine.exists() and not dead.exists()


def test_a_host_finds_the_endpoint_from_the_link_url_and_skips_dead_ones(folder, world):
    environ = {"XDG_RUNTIME_DIR": str(folder)}
    private_dir(folder / "aspod")
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(str(folder / "aspod" / "sim-1.sock"))
    dead.close()
    control = PlantControl(world.world.plant, world.clock, about={"link": "radio=/dev/pts/77,optical=socket://h:1"})
    served = Served(folder / "aspod" / "sim-2.sock", control)
    stop = served.run_in_background()
    try:
        assert find_control("/dev/pts/77", environ) == served.server.path
        assert find_control("socket://h:1", environ) == served.server.path
        assert find_control("/dev/pts/78", environ) is None
        with ControlClient(served.server.path) as client:
            assert client.request({"op": "fault", "name": "jam", "channel": "j1"})["ok"]
            assert client.request({"op": "melt"})["ok"] is False
    finally:
        stop()
        served.server.close()
    with pytest.raises(ControlUnavailable, match="is its aspod sim still running"):
        ControlClient(served.server.path)
    assert link_endpoints("a=/dev/pts/1,b=socket://x:2") == {"/dev/pts/1", "socket://x:2"}


def test_a_host_finds_the_key_of_a_controller_whose_plant_is_elsewhere_but_no_plant_to_fault(folder):
    environ = {"XDG_RUNTIME_DIR": str(folder)}
    runtime = RuntimeFolder.open(environ)
    key, key_path = runtime.new_key()
    served = Served(runtime.control_path(), LinkInfo({"link": "/dev/pts/77", "pid": 1, "key": str(key_path)},
                                                     "in aspod plant"))
    stop = served.run_in_background()
    try:
        assert simulator_key("/dev/pts/77", environ=environ) == key
        assert find_control("/dev/pts/77", environ) is None         # nothing there reaches a plant
        with ControlClient(served.server.path) as client:
            assert client.request({"op": "info"})["plant"] is False
            refused = client.request({"op": "fault", "name": "jam", "channel": "j1"})
            assert refused == {"ok": False, "error": "fault: no plant here to reach: it is in aspod plant"}
        with pytest.raises(KeyFileError, match="no --key-file given, and no simulator of this user's serving "
                                               "/dev/pts/78 says its key: give --key-file FILE"):
            simulator_key("/dev/pts/78", environ=environ)
    finally:
        stop()
        served.server.close()
        runtime.close()


# ---- teleop's `sim` words ----

def script(client, text: str, keep_going: bool = True) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    status, _ = run_script(client, text.splitlines(), out, keep_going=keep_going, err=err)
    return status, out.getvalue(), err.getvalue()


def test_sim_lines_on_the_lockstep_world_fault_the_plant_and_a_jog_ends_as_a_fault(bench):
    client = BenchClient(bench)
    status, out, _ = script(client, "sim fault jam j1\nsim faults\nenable\njog j1 2\nwait j1 10\nsim state\n"
                                    "sim clear all\nsim gravity orbit\nsim payload 1.5\nsim clouds on\n")
    assert "ok   sim fault: injected jam:j1" in out and "ok   sim faults: active faults: jam:j1" in out
    assert re.search(r"j1#\d+ FAULT", out), out
    assert "gravity earth, payload 0 kg, object none; faults: jam:j1" in out
    assert "ok   sim clear: cleared jam:j1" in out and "ok   sim clouds: injected clouds" in out
    assert bench.world.plant.arm.gravity == "orbit" and bench.world.plant.faults == {"clouds"}
    assert status == 1            # the jog's FAULT fails the script, as any motion that does not end DONE


def test_a_bad_sim_line_fails_the_script_before_anything_is_sent(bench):
    client = BenchClient(bench)
    status, _, err = script(client, "enable\nsim fault jam\nsim fault melt j1\nsim payload lots\nsim clouds maybe\n"
                                    "sim step 100\nsim frob\n")
    assert status == 2 and "nothing was sent" in err and bench.world.plant.faults == set()
    for expected in ("line 2: sim fault: fault 'jam' needs a channel", "line 3: sim fault: unknown fault 'melt'",
                     "line 4: sim payload KG: 'lots' is not a number", "line 5: sim clouds on|off: 'maybe' is not on",
                     "line 6: sim step seconds: 100 s is out of range", "line 7: sim: no op 'frob'"):
        assert expected in err, err


def test_a_target_without_a_control_endpoint_says_why_a_sim_line_cannot_run(bench):
    client = BenchClient(bench)
    client.control = None                     # as a real controller: no plant to reach
    status, out, _ = script(client, "sim fault jam j1\n")
    assert status == 1 and "FAIL sim fault: no control endpoint" in out and "a real controller has no plant" in out
    assert bench.world.plant.faults == set()


def test_sim_words_help_and_completion_come_from_the_declaration():
    text = help_text("sim")
    assert all(f"sim {name}" in text for name in OPS)
    assert completions("sim ", 4, "") == list(OPS)
    assert completions("sim clear ", 10, "a") == ["all"]
    assert completions("sim fault jam ", 14, "g") == ["gripper"]
    assert completions("sim gravity ", 12, "") == ["earth", "orbit"]


# ---- the plugin's targets ----

def test_the_lockstep_target_reaches_its_plant_through_the_same_requests():
    target = LockstepTarget()
    try:
        assert target.can_fault and not target.can_pause
        target.inject("jam", "j2")
        target.act("set_payload", 1.5)
        state = target.true_state()
        assert state["faults"] == ["jam:j2"] and state["payload_kg"] == 1.5
        target.clear("jam", "j2")
        assert target.true_state()["faults"] == []
        with pytest.raises(ValueError, match="unknown fault"):
            target.inject("melt", "j1")
        with pytest.raises(CannotFault, match="nothing to pause"):
            target.pause()
    finally:
        target.close()


# ---- end to end: `aspod sim` with its endpoint, teleop's `sim` lines, a held world whose link stays up ----

@pytest.mark.pty
def test_a_live_sim_is_faulted_from_a_teleop_script_and_held_while_its_link_stays_up(sim_factory, tmp_path):
    sim = sim_factory("--pty", "--no-tracker")
    assert sim.control_path is not None and sim.control_path.is_socket()
    lines = tmp_path / "fault.txt"
    lines.write_text("sim fault jam j1\nenable\njog j1 2\nwait j1 20\n")
    done = sim.teleop("", "--script", str(lines))            # the endpoint found from the link's URL
    out = done.stdout.decode()
    assert "ok   sim fault: injected jam:j1" in out and re.search(r"j1#\d+ FAULT", out), out + done.stderr.decode()
    assert done.returncode == 1                              # the jog did not end DONE: the script failed
    sim.child.wait_stderr(r"^aspod sim: control: injected jam:j1$")
    client = sim.client()
    try:
        with ControlClient(sim.control_path) as control:
            held = control.request({"op": "pause"})
            assert held["paused"]
            uptimes = {client.call(M["Ping"](k)).reply.uptime_ms for k in range(20)}   # 20 round trips of wall time
            assert len(uptimes) == 1 and control.request({"op": "time"})["time_s"] == held["time_s"]
            assert control.request({"op": "step", "seconds": 0.5})["time_s"] == pytest.approx(held["time_s"] + 0.5)
            control.request({"op": "resume"})
            assert sim.wait(client, lambda: control.request({"op": "time"})["time_s"] > held["time_s"] + 0.6, 30.0)
            assert control.request({"op": "clear", "name": "all"})["said"] == "cleared jam:j1"
    finally:
        client.close()
    status, err = sim.stop()
    assert status == 0 and not sim.control_path.exists(), err


@pytest.mark.pty
def test_a_sim_without_its_endpoint_makes_a_sim_line_fail_with_the_reason(sim_factory):
    sim = sim_factory("--pty", "--no-tracker", "--no-control")
    done = sim.teleop("sim faults\n")                # nothing to find its key by either: said, nothing sent
    assert done.returncode == 2 and "give --key-file FILE (for a simulator, the path on its ASPOD-KEY line" in \
        done.stderr.decode(), done.stderr.decode()
    done = sim.teleop("sim faults\n", "--key-file", str(sim.key_path))
    out = done.stdout.decode()
    assert done.returncode == 1 and "FAIL sim faults: no control endpoint" in out, out


@pytest.mark.pty
def test_a_sim_whose_runtime_folder_someone_took_first_runs_and_teleop_finds_it(folder, tmp_path):
    """Another user making /tmp/aspod-<uid> first once stopped every `aspod sim` of that uid at its start; so did
    a runtime folder open to others, the case made here (the machine's own /tmp/aspod-<uid> is left alone)."""
    (folder / "run").mkdir(mode=0o700)
    squat(folder / "run" / "aspod", "open to others")
    env = dict(os.environ, XDG_RUNTIME_DIR=str(folder / "run"), TMPDIR=str(folder),
               XDG_CONFIG_HOME=str(tmp_path / "config"))
    sim = test_e2e.Sim(env, "--pty", "--no-tracker")
    try:
        own = sim.control_path.parent
        assert own.parent == folder and own.name.startswith(f"aspod-{os.getuid()}-") and sim.key_path.parent == own
        done = sim.teleop("sim faults\nping\n")              # its endpoint and its key, found in that folder
        out = done.stdout.decode()
        assert done.returncode == 0 and "ok   sim faults" in out and "ok   Pong" in out, out + done.stderr.decode()
    finally:
        status, err = sim.stop()
    assert status == 0 and "is open to other users" in err and "using a folder of its own" in err, err
    assert not own.exists()
