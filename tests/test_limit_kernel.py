"""The bench's limit (bench/limit_kernel.py): the joints' and the plant's ticks, every tick in one call.

It steps a moving world's own rows; it must move the joints as the world's loop would start to,
hand nothing to the facade on a plain jog, and, compiled, end where plain does, to the bit.
"""
from __future__ import annotations

import importlib.util

import pytest

from bench.bench_lockstep import LimitRow

HAVE_NUMBA = importlib.util.find_spec("numba") is not None


def angles(row: LimitRow) -> list[str]:
    return [float(x).hex() for x in row.world.bench.world.plant.arm.pos_rad]


def run_limit(compiled: bool, seconds: float) -> list[str]:
    row = LimitRow("limit", compiled=compiled)
    try:
        before, start = angles(row), row.now
        row.advance(seconds)                                         # raises if a joint handed an event over
        after = angles(row)
        assert sum(a != b for a, b in zip(before, after)) >= 5      # the jogged joints moved
        assert row.now - start == pytest.approx(seconds)
        return after
    finally:
        row.close()


def test_the_limit_steps_the_moving_world_in_one_call():
    run_limit(compiled=False, seconds=0.3)


@pytest.mark.long
@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed (the compiled kernels are optional)")
def test_the_compiled_limit_ends_where_the_plain_one_does():
    assert run_limit(compiled=True, seconds=0.3) == run_limit(compiled=False, seconds=0.3)
