"""Shared fixtures: a whole world on the simulated clock (plant, controller, host link)."""
from __future__ import annotations

import pytest

from host_tools.world import LockstepBench


@pytest.fixture
def bench():
    """A connected lock-step world; faster than real time, the same for the same seed."""
    world = LockstepBench(seed=1)
    assert world.connect()
    yield world
    world.close()
