"""The joints' tick compiled by numba: optional, behind a switch.

`compiled_joints_tick()` is `joints_tick` (firmware_py/joints_tick.py) compiled with numba's `njit`,
without fastmath: IEEE arithmetic in the source's order, so its duties are the same to the bit as
the plain function's and `Axis.update`'s (tests/test_joints_tick.py runs it against both). It runs
over the numpy arrays of a `JointBank(compiled=True)`. The machine code is cached beside the module
(`cache=True`), so only the first process compiles it (a few seconds).

The switch: `ControllerConfig.compiled_joints`, whose default is the environment variable
`ASPOD_COMPILED_JOINTS=1` (so that a bench or a simulator picks it up unchanged). numba is not a
dependency of the package: without it the switch stays off and the joints run as plain Python;
turned on without numba, building the controller says so. `NUMBA_DISABLE_JIT=1` runs the same
arrays through the plain function (slow: numpy scalars), for debugging.
"""
from __future__ import annotations

import functools
import os
from typing import Callable

from firmware_py.joints_tick import joints_tick

ENVIRONMENT_SWITCH = "ASPOD_COMPILED_JOINTS"


def compiled_by_default() -> bool:
    """Whether the environment asks for the compiled joints (`ASPOD_COMPILED_JOINTS=1`)."""
    return os.environ.get(ENVIRONMENT_SWITCH, "") == "1"


@functools.lru_cache(maxsize=1)
def compiled_joints_tick() -> Callable[..., int]:
    """`joints_tick` compiled by numba (RuntimeError if numba is not installed)."""
    try:
        import numba
    except ImportError as exc:
        raise RuntimeError(f"compiled joints ({ENVIRONMENT_SWITCH}=1, compiled_joints=True) need numba: "
                           "pip install numba") from exc
    return numba.njit(cache=True)(joints_tick)
