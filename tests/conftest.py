"""Shared fixtures: a whole world on the simulated clock (plant, controller, host link); private CAN buses.

And the one rule the parallel suite needs (`make test`: pytest-xdist, one worker per core). The
CPU-hog test (`cpu_hog` marker, tests/test_busy_machine.py) keeps every core busy on purpose; a
test on the wall clock (`realtime` marker, implied by `pty`) running beside it would measure the
hogs, not the code. So the hog test holds a file lock exclusively while the others hold it
shared: real-time tests still run beside each other and beside the simulated tests, never
beside the hogs. A hog test waiting for the lock is let in before any newcomer (a turnstile),
so it cannot be starved by a stream of real-time tests on the other workers.
"""
from __future__ import annotations

import fcntl
import os
import signal
import uuid
from contextlib import contextmanager
from pathlib import Path

import can
import pytest

from host_tools.worlds.child import Child
from host_tools.worlds.world import LockstepBench


@pytest.fixture
def bench():
    """A connected lock-step world; faster than real time, the same for the same seed."""
    world = LockstepBench(seed=1)
    assert world.connect()
    yield world
    world.close()


@pytest.fixture
def start_sim(env):
    """`start(*options)`: a new `aspod sim --pty` (with `options`; none: `--no-tracker`) in the test module's own
    `env` (its runtime folder), once its control endpoint is up: (the child, its link's URL). Each is stopped at the
    test's end."""
    sims = []

    def start(*options: str) -> tuple[Child, str]:
        child = Child(["sim", "--pty", *(options or ("--no-tracker",))], env=env)
        sims.append(child)
        link = child.line(30.0)
        assert link.startswith("ASPOD-LINK "), link
        child.line(30.0), child.line(30.0)                # ASPOD-KEY, ASPOD-CONTROL: the endpoint is up
        return child, link.split(" ", 1)[1]
    yield start
    for child in sims:
        child.stop(signal.SIGTERM, timeout_s=10)


@pytest.fixture
def virtual_can():
    """Factory: each call gives `open_bus()` for a fresh, unique virtual channel.

    Every bus opened through it is shut down at teardown.
    """
    opened: list[can.BusABC] = []

    def new_channel():
        channel = f"aspod-test-{uuid.uuid4().hex}"

        def open_bus() -> can.BusABC:
            bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
            opened.append(bus)
            return bus

        return open_bus

    yield new_channel
    for bus in opened:
        bus.shutdown()


# ---- the CPU hogs apart from the real-time tests ----------------------------------------------------------------

def pytest_xdist_auto_num_workers(config) -> int:
    """`-n auto`: one worker more than the cores. The real-time tests spend much of their time
    waiting on the wall clock (a subprocess's reply, a timeout running out); the extra worker
    fills those waits with simulated tests instead of leaving a core idle."""
    return len(os.sched_getaffinity(0)) + 1


def pytest_collection_modifyitems(items):
    """`pty` implies `realtime`. Order: the CPU-hog tests first, the simulated tests, the real-time
    tests last, the `long` ones first within each group so that none starts near the end and ends
    the run alone. xdist (`--dist load`) hands each worker a run of consecutive tests to start with,
    so the hog tests start on one worker while the others run simulated tests instead of waiting
    for the lock. (`--dist loadgroup` would be the tool, but pytest-xdist 3.8 marks a group by
    renaming `item._nodeid`, which pytest 9 no longer reads: the groups are silently ignored.)"""
    for item in items:
        if item.get_closest_marker("pty") and not item.get_closest_marker("realtime"):
            item.add_marker(pytest.mark.realtime)

    def rank(item) -> tuple[int, bool]:
        group = 0 if item.get_closest_marker("cpu_hog") else 2 if item.get_closest_marker("realtime") else 1
        return group, item.get_closest_marker("long") is None
    items.sort(key=rank)


@pytest.fixture(scope="session")
def _realtime_lock_dir(tmp_path_factory) -> Path:
    """A directory all the workers of this run share (xdist's workers: basetemp/popen-gwN)."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@contextmanager
def _flock(path: Path, mode: int):
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, mode)
        yield
    finally:
        os.close(fd)            # closing releases the lock


@pytest.fixture(autouse=True)
def _apart_from_the_hogs(request):
    hog = request.node.get_closest_marker("cpu_hog") is not None
    if not hog and request.node.get_closest_marker("realtime") is None:
        yield
        return
    lock_dir = request.getfixturevalue("_realtime_lock_dir")
    turnstile, room = lock_dir / "aspod-realtime.turnstile", lock_dir / "aspod-realtime.lock"
    if hog:
        with _flock(turnstile, fcntl.LOCK_EX), _flock(room, fcntl.LOCK_EX):
            yield
    else:
        with _flock(turnstile, fcntl.LOCK_EX):
            pass
        with _flock(room, fcntl.LOCK_SH):
            yield
