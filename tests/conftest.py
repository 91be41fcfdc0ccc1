"""Shared fixtures: a whole world on the simulated clock (plant, controller, host link); private CAN buses."""
from __future__ import annotations

import uuid

import can
import pytest

from host_tools.worlds.world import LockstepBench


@pytest.fixture
def bench():
    """A connected lock-step world; faster than real time, the same for the same seed."""
    world = LockstepBench(seed=1)
    assert world.connect()
    yield world
    world.close()


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
