"""Plant and controller in separate processes, meeting on a real python-can interface (udp_multicast).

`aspod plant`, `aspod firmware` and `aspod sim --hal` run as real subprocesses, in real
time, on a multicast group and UDP port of their own (so parallel runs do not meet); a
host talks to the controller over a real pty. Bounds are generous (tens of seconds) and
the assertions are about behaviour, not speed. If udp_multicast does not work here (no
msgpack, no multicast on loopback), a real probe says so and the sessions are skipped.

Plant and controller run in lock-step (the default): however long either process is
descheduled on a busy machine, the other's time waits for it, so no staleness check can trip
on it; a plant that has gone for good is HAL_STALE after `lockstep_wait_s` of its own time
(the wall clock, less the waits for a CPU: docs/separate_processes.md).
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

import can
import pytest

from host_tools.worlds import nodes
from host_tools.client.live import HostClient
from host_tools.worlds.child import Child, ChildError, run
from host_tools.worlds.own_time import OwnTime
from protocol import auth
from protocol.messages import MESSAGES as M
from protocol.reasons import Reason
from protocol.states import ControllerState, Fault
from timebase import RealClock

pytestmark = pytest.mark.pty
ASPOD = [sys.executable, "-m", "host_tools.cli.main"]
WAIT_S = 30.0
COUNTERS = re.compile(r"aspod plant: stopped after [\d.]+ s; counters (.*)")


@pytest.fixture(scope="module")
def multicast_works():
    """A real probe: two udp_multicast buses, a 48-byte CAN FD frame from one to the other."""
    group, port = nodes.fresh_udp_multicast()
    try:
        sender = nodes.open_bus("udp_multicast", group, port=port)
    except (OSError, ValueError) as exc:
        pytest.skip(f"udp_multicast cannot be opened here: {exc}")
    try:
        receiver = nodes.open_bus("udp_multicast", group, port=port)
        try:
            sender.send(can.Message(arbitration_id=0x200, data=bytes(range(48)), is_fd=True, is_extended_id=False))
            got = receiver.recv(timeout=5.0)
        finally:
            receiver.shutdown()
    except (OSError, can.CanError) as exc:
        pytest.skip(f"udp_multicast does not carry frames here: {exc}")
    finally:
        sender.shutdown()
    if got is None or not got.is_fd or bytes(got.data) != bytes(range(48)):
        pytest.skip(f"udp_multicast opened but a CAN FD frame did not arrive intact on loopback (got {got})")


@pytest.fixture
def env(tmp_path):
    """A private per-user config directory, so the parameter file is the test's own."""
    return {**os.environ, "XDG_CONFIG_HOME": str(tmp_path / "config")}


@pytest.fixture
def params_file(tmp_path) -> Path:
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"version": 1, "params": {}}))
    return path


class Proc(Child):
    """`aspod ...` with unbuffered stdout/stderr pipes, read line by line with a bound per line."""

    def __init__(self, args: list[str], env: dict) -> None:
        super().__init__(args, env=env)

    def line(self, timeout_s: float = WAIT_S, stream=None) -> str:
        try:
            return super().line(timeout_s, stream)
        except ChildError as exc:
            raise AssertionError(str(exc)) from None

    def wait_stderr(self, pattern: str, timeout_s: float = WAIT_S) -> re.Match:
        return super().wait_stderr(pattern, timeout_s)

    def stop(self, sig: int = signal.SIGTERM) -> tuple[int, str]:
        """Signal it, wait (then SIGTERM, then SIGKILL), return (exit status, the rest of its stderr)."""
        return super().stop(sig, timeout_s=WAIT_S)


@pytest.fixture
def procs(env):
    """Start `aspod ...` subprocesses; every one is stopped at teardown, whatever happened."""
    started: list[Proc] = []

    def start(*args: str) -> Proc:
        started.append(Proc(list(args), env))
        return started[-1]
    yield start
    for proc in reversed(started):
        proc.stop(signal.SIGKILL)


@pytest.fixture
def clients():
    opened: list[HostClient] = []

    def connect(url: str, key_path: str) -> HostClient:
        client = HostClient(url, auth.load_key(Path(key_path)))
        opened.append(client)
        client.connect()
        return client
    yield connect
    for client in opened:
        client.close()


def counters(text: str) -> dict[str, float]:
    found = COUNTERS.search(text)
    assert found, f"no counters line in {text!r}"
    return {key: float(value) for key, value in (item.split("=") for item in found.group(1).split())}


def start_plant(procs, group: str, port: int) -> Proc:
    plant = procs("plant", "--interface", "udp_multicast", "--channel", group, "--bus-arg", f"port={port}")
    ready = plant.line()
    assert ready.startswith("ASPOD-PLANT ready "), ready
    assert f"interface=udp_multicast channel={group} port={port}" in ready
    return plant


def link_of(proc: Proc) -> tuple[str, str]:
    """The ready lines of `aspod firmware` or `aspod sim --hal`: the link, its key, the control endpoint."""
    link, key, control = proc.line(), proc.line(), proc.line()
    assert link.startswith("ASPOD-LINK "), link
    assert key.startswith("ASPOD-KEY "), key
    assert control.startswith("ASPOD-CONTROL ") and Path(control.split(" ", 1)[1]).exists(), control
    return link.split(" ", 1)[1], key.split(" ", 1)[1]


def status(client: HostClient):
    handle = client.call(M["GetStatus"]())
    assert handle.ok, handle.describe()
    return handle.reply


def test_plant_and_firmware_as_two_processes_close_the_loop_and_plant_loss_is_hal_stale(
        multicast_works, procs, clients, params_file):
    group, port = nodes.fresh_udp_multicast()
    plant = start_plant(procs, group, port)
    firmware = procs("firmware", "--interface", "udp_multicast", "--channel", group, "--bus-arg", f"port={port}",
                     "--pty", "--params", str(params_file), "--plant-pid", str(plant.pid))
    url, key_path = link_of(firmware)
    firmware.wait_stderr(r"BOOT -> IDLE \(OK\)")          # HAL inputs arrived over the interface
    client = clients(url, key_path)
    reply = status(client)
    assert reply.state == ControllerState.IDLE and reply.faults == 0, (reply, firmware.seen)
    assert 20.0 < reply.supply_v < 35.0                    # the plant's 28 V supply, measured
    assert client.call(M["Enable"]()).ok
    assert status(client).state == ControllerState.ENABLED
    assert client.call(M["Ping"](7)).ok

    code, err = plant.stop()                               # the plant goes away
    assert code == 0, err
    seen = counters(err)
    assert seen["frames_received"] > 0                     # CTRL_OUTPUTS from the other process ...
    assert seen["own_echoes"] > 0                          # ... its own frames came back and were dropped
    assert seen["bad_frames"] == 0 and seen["bus_errors"] == 0

    firmware.wait_stderr(r"ENABLED -> FAULT \(HAL_STALE\), faults HAL_STALE")
    firmware.wait_stderr(rf"aspod firmware: lock-step: the plant process \(pid {plant.pid}\): ended")   # --plant-pid
    client.wait_for(lambda: False, 1.0)                    # the plant stays gone: the cause is still there
    reply = status(client)
    assert reply.state == ControllerState.FAULT and reply.faults & Fault.HAL_STALE
    assert reply.safe_reason == Reason.HAL_STALE
    assert firmware.wait_for(lambda seconds: client.wait_for(
        lambda: any(e.spec.name == "StateChanged" and e.reason == Reason.HAL_STALE for e in client.events), seconds),
        WAIT_S)
    refused = client.call(M["Reset"]())
    assert not refused.ok and refused.reason == Reason.HAL_STALE   # the cause is still there

    again = start_plant(procs, group, port)                # a new plant on the same bus

    def reset_ok(seconds: float) -> bool:                  # its first ANALOG_IN is 10 ms of its own time away
        reset = client.call(M["Reset"]())
        assert reset.ok or reset.reason == Reason.HAL_STALE, reset.describe()
        return reset.ok or client.wait_for(lambda: False, min(seconds, 0.1))
    assert again.wait_for(reset_ok, WAIT_S)
    assert status(client).state == ControllerState.IDLE
    client.close()
    code, rest = firmware.stop()                           # a plant restarted: one resync, nothing to say
    assert code == 0 and "sync_steps_back=1 " in rest, rest   # its tick went back once (a resync or old syncs)
    assert "two plants" not in rest and not any("two plants" in line for line in firmware.seen)


def test_a_second_controller_or_plant_on_a_pairs_bus_is_said_on_stderr(multicast_works, procs, tmp_path, params_file):
    """Each is said by the node that can see it; a second controller's frames, with the first's own IDs, fault
    the first (UNCOMMANDED_MOTION: two controllers drive one plant)."""
    group, port = nodes.fresh_udp_multicast()
    bus = ("--interface", "udp_multicast", "--channel", group, "--bus-arg", f"port={port}")
    plant = start_plant(procs, group, port)
    firmware = procs("firmware", *bus, "--pty", "--params", str(params_file))
    link_of(firmware)
    firmware.wait_stderr(r"BOOT -> IDLE \(OK\)")
    second = procs("firmware", *bus, "--pty", "--params", str(tmp_path / "params2.json"))
    link_of(second)
    plant.wait_stderr(r"aspod plant: CTRL_SYNC from two controllers \(.*another aspod firmware on this bus\?")
    firmware.wait_stderr(r"IDLE -> FAULT \(UNCOMMANDED_MOTION\)")
    firmware.wait_stderr(r"aspod firmware: HAL bus another node sends this controller's own frames")
    code, _ = second.stop()
    assert code == 0
    start_plant(procs, group, port)
    firmware.wait_stderr(r"aspod firmware: PLANT_SYNC from two plants \(ticks near \d+ and near \d+.*"
                         r"another aspod plant")


def enabled_sim_over_hal(procs, clients, params: Path) -> tuple[Proc, int, HostClient]:
    """`aspod sim --hal udp_multicast` with its plant's pid, booted, and a host that has enabled it."""
    sim = procs("sim", "--hal", "udp_multicast", "--pty", "--params", str(params))
    url, key_path = link_of(sim)
    plant_pid = int(sim.wait_stderr(r"plant process (\d+) ready on interface=udp_multicast").group(1))
    sim.wait_stderr(r"BOOT -> IDLE \(OK\)")               # the first ticks came: enable is allowed
    client = clients(url, key_path)
    assert client.call(M["Enable"]()).ok
    return sim, plant_pid, client


def test_sim_with_hal_runs_the_plant_as_a_child_and_says_when_it_dies(multicast_works, procs, clients, params_file):
    sim, plant_pid, client = enabled_sim_over_hal(procs, clients, params_file)

    os.kill(plant_pid, signal.SIGKILL)                     # no goodbye, no counters
    sim.wait_stderr(rf"the plant process \(pid {plant_pid}\) ended: killed by SIGKILL")
    # the controller's time stands still without its plant: the wall clock says how long it has waited
    silent = sim.wait_stderr(r"FAULT HAL_STALE \(HAL_STALE\): lock-step: no tick from the plant .*: ([\d.]+) ms "
                             r"against a limit of 2000.0 ms \(parameter lockstep_wait_s\)")
    assert float(silent.group(1)) >= 2000.0
    sim.wait_stderr(r"ENABLED -> FAULT \(HAL_STALE\)")
    reply = status(client)
    assert reply.state == ControllerState.FAULT and reply.faults & Fault.HAL_STALE
    client.close()
    code, err = sim.stop()
    assert code == 0, err
    lockstep = re.search(r"HAL counters .*ctrl_syncs=(\d+) resyncs=(\d+)", err)
    assert lockstep and int(lockstep.group(1)) > 0 and lockstep.group(2) == "0", err     # it ran in lock-step


# a busy loop in bursts: BUSY_S on its CPU, then IDLE_S asleep
BURSTS = """
import sys, time
busy_s, idle_s = float(sys.argv[1]), float(sys.argv[2])
while True:
    end = time.monotonic() + busy_s
    while time.monotonic() < end:
        pass
    time.sleep(idle_s)
"""


@contextmanager
def kept_from_running(pid: int, busy_s: float = 0.9, idle_s: float = 0.3):
    """`pid` pinned to one core beside a busy loop at real-time priority (SCHED_FIFO) that takes the core for
    `busy_s` at a time (the kernel leaves others 5 % of each second: 0.95 s at most), then leaves it for `idle_s`:
    `pid` waits on a run queue for that long at a stretch, as a plant did at load 45-49 (busy loops at nice 0, or
    `pid` at SCHED_IDLE, give it short slices too often to be sure of it). Skipped where this process may not give
    SCHED_FIFO."""
    cpu = min(os.sched_getaffinity(pid))
    hog = subprocess.Popen([sys.executable, "-c", BURSTS, str(busy_s), str(idle_s)])
    try:
        os.sched_setaffinity(hog.pid, {cpu})
        os.sched_setaffinity(pid, {cpu})
        try:
            os.sched_setscheduler(hog.pid, os.SCHED_FIFO, os.sched_param(1))
        except PermissionError:
            pytest.skip("keeping a process from running for certain needs SCHED_FIFO (CAP_SYS_NICE, or an "
                        "RLIMIT_RTPRIO above 0)")
        yield
    finally:
        hog.kill()
        hog.wait()


@pytest.mark.cpu_hog        # a busy loop on one core: never beside the other real-time tests (conftest)
def test_a_plant_kept_from_running_is_not_taken_for_gone_and_a_stopped_one_is(multicast_works, procs, clients,
                                                                              tmp_path):
    """At load 45-49 the lock-step pair faulted HAL_STALE after 2 s of wall time waiting for a plant that was alive.
    The plant is judged on its own time: here, with lockstep_wait_s at its least (0.1 s), it is kept on a run queue
    for 0.9 s at a time; the controller says it waited past the limit on the wall clock, and stays ENABLED (the wall
    clock alone faulted it); stopped (SIGSTOP) beside the same busy loop, it is HAL_STALE, and the log says why."""
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"version": 1, "params": {"lockstep_wait_s": 0.1}}))
    sim, plant_pid, client = enabled_sim_over_hal(procs, clients, params)
    with kept_from_running(plant_pid):
        kept = sim.wait_stderr(r"lock-step: no tick from the plant for ([\d.]+) s of wall time, ([\d.]+) s of its own: "
                               r"the machine keeps the pair from running \(not a fault|-> FAULT .*")
        assert kept.group(2) is not None and float(kept.group(2)) <= 0.1, "\n".join(sim.seen[-12:])   # said past 0.1 s
        reply = status(client)
        assert reply.state == ControllerState.ENABLED and reply.faults == 0, sim.seen
        os.kill(plant_pid, signal.SIGSTOP)
        try:
            silent = sim.wait_stderr(r"FAULT HAL_STALE \(HAL_STALE\): lock-step: no tick from the plant .*: ([\d.]+) ms "
                                     r"against a limit of 100.0 ms")
            sim.wait_stderr(rf"lock-step: the plant process \(pid {plant_pid}\): stopped \(SIGSTOP\)")
        finally:
            os.kill(plant_pid, signal.SIGCONT)
    assert float(silent.group(1)) >= 100.0
    assert status(client).faults & Fault.HAL_STALE
    client.close()
    code, err = sim.stop()
    assert code == 0, err
    assert int(re.search(r"HAL counters .* kept_waits=(\d+)", err).group(1)) >= 1, err


def test_stopping_sim_with_hal_stops_its_plant_which_saw_the_controller(multicast_works, procs, clients,
                                                                       params_file):
    sim, plant_pid, client = enabled_sim_over_hal(procs, clients, params_file)
    assert client.call(M["Ping"](1)).ok
    client.close()
    code, err = sim.stop()
    assert code == 0, err
    seen = counters(err)                                   # the child shares the parent's stderr
    assert seen["frames_received"] > 0 and seen["bad_frames"] == 0
    assert not _running(plant_pid)
    assert "ended" not in err                              # a plant we stopped is not news


def test_a_plant_whose_parent_is_killed_stops_by_itself(multicast_works, procs, params_file):
    sim = procs("sim", "--hal", "udp_multicast", "--pty", "--params", str(params_file))
    link_of(sim)
    plant_pid = int(sim.wait_stderr(r"plant process (\d+) ready").group(1))
    code, err = sim.stop(signal.SIGKILL)                   # the parent cannot stop its child now ...
    assert code == -signal.SIGKILL
    # ... but the child's stdin (a pipe from the parent) closes, and the plant stops; its
    # stderr is the parent's (now our pipe), so its farewell arrives on it.
    assert "standard input closed" in err and COUNTERS.search(err), err
    assert _gone_within(plant_pid, WAIT_S)                 # it closed stderr; give it time to finish exiting


def _gone_within(pid: int, timeout_s: float) -> bool:
    """Wait until `pid` has exited, at most `timeout_s` of its own time (host_tools/worlds/own_time.py)."""
    clock = RealClock()
    own = OwnTime(pid, clock)
    while _running(pid):
        if own.look().own_s > timeout_s:
            return False
        clock.sleep(0.05)
    return True


def _running(pid: int) -> bool:
    """True if `pid` exists and is not a zombie waiting for a reaper."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    except OSError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.parametrize("args, message", [
    (["plant", "--interface", "nosuchbus", "--channel", "x"], "unknown python-can interface 'nosuchbus'"),
    (["plant", "--interface", "virtual", "--channel", "x"], "joins only buses in the same process"),
    (["sim", "--hal", "virtual"], "joins only buses in the same process"),
    (["sim", "--hal", "socketcan"], "needs --hal-channel"),
    (["firmware", "--interface", "udp_multicast"], "--channel"),
    (["firmware", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--plant-pid", str(2**22)],
     f"--plant-pid {2**22}: no such process on this machine"),
    (["firmware", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--timing", "realtime", "--plant-pid",
      "1"], "--plant-pid judges the wait for the plant's tick in lock-step: it takes --timing lockstep"),
    (["plant", "--interface", "udp_multicast", "--channel", "10.1.2.3"], "not a multicast group"),
    (["plant", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--bus-arg", "port=70000"],
     "port 70000 is not a whole number in 1..65535"),
    (["plant", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--bus-arg", "port"], "is not KEY=VALUE"),
    (["plant", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--gravity", "moon"],
     "invalid choice: 'moon' (choose from 'earth', 'orbit')"),
    (["plant", "--interface", "udp_multicast", "--channel", "239.1.2.3", "--payload-kg", "-1"], "outside"),
])
def test_bad_bus_arguments_exit_2_with_a_reason(env, args, message):
    done = run(ASPOD + args, env=env, stdin=subprocess.DEVNULL, timeout_s=60)
    assert done.returncode == 2, done.stderr.decode()
    assert message in done.stderr.decode()


def test_a_bus_that_cannot_be_opened_here_exits_3(env):
    done = run(ASPOD + ["plant", "--interface", "socketcan", "--channel", "aspodnone0"], env=env,
               stdin=subprocess.DEVNULL, timeout_s=60)
    assert done.returncode == 3, done.stderr.decode()
    assert "cannot open the socketcan bus on channel 'aspodnone0'" in done.stderr.decode()


def test_own_echo_filter_drops_only_what_the_node_declares_as_its_own():
    channel = "aspod-echo-test"
    raw = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    other = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    bus = nodes.OwnEchoFilter(raw, nodes.PLANT)
    try:
        for frame_id in (0x010, 0x280, 0x020, 0x7FF):          # PLANT_SYNC, ANALOG_IN (own), CTRL_OUTPUTS, undeclared
            other.send(can.Message(arbitration_id=frame_id, data=bytes(8), is_extended_id=False))
        got: list[Optional[int]] = []
        while (msg := bus.recv(timeout=0)) is not None:
            got.append(msg.arbitration_id)
        assert got == [0x020, 0x7FF] and bus.own_echoes == 2
    finally:
        bus.shutdown()
        other.shutdown()


def test_own_echo_filter_returns_to_the_node_during_a_flood_of_its_own_ids():
    """A third node flooding frames with the plant's own IDs (0x200 as fast as it could, over udp_multicast) kept
    the plant's poll inside OwnEchoFilter.recv for the whole flood: no tick, no re-offer for 20 s, the controller
    in HAL_STALE. Each recv now drops at most MAX_ECHOES_PER_RECV echoes, then returns None."""
    class Babbler(can.BusABC):
        def __init__(self) -> None:
            self.reads = 0
            super().__init__(channel="babbler")

        def _recv_internal(self, timeout):
            self.reads += 1
            assert self.reads < 100_000, "the filter never returned"
            return can.Message(arbitration_id=0x200, data=bytes(48), is_fd=True, is_extended_id=False), False

        def send(self, msg, timeout=None) -> None:
            pass

    raw = Babbler()
    bus = nodes.OwnEchoFilter(raw, nodes.PLANT)
    try:
        assert bus.recv(timeout=0) is None and bus.recv(timeout=0.5) is None
        assert raw.reads == bus.own_echoes == 2 * nodes.MAX_ECHOES_PER_RECV
    finally:
        bus.shutdown()
