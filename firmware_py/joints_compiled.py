"""The joints' tick compiled by numba: optional, behind the switch of the `kernels` package.

`compiled_joints_tick()` is `joints_tick` (firmware_py/joints_tick.py) compiled without fastmath,
so its duties are the same to the bit as the plain function's (tests/test_joints_tick.py runs
both side by side); `compiled_arm_joints_tick()` is `arm_joints_tick`
(the gravity feed-forward, then `joints_tick` from the first joint), the arm's one call a tick.
They run over the numpy arrays of a `JointBank(compiled=True)`. `ASPOD_COMPILED=1`
(kernels/__init__.py) makes them the controller's default (`ControllerConfig.compiled_joints`).
"""
from __future__ import annotations

import functools
from typing import Callable

from firmware_py.joints_tick import (arm_joints_tick, count_step, filter_step, holding_torques_nm, joints_tick,
                                     sample_profile, stopping_distance)
from kernels import compile_kernel


@functools.lru_cache(maxsize=1)
def compiled_joints_tick() -> Callable[..., int]:
    """`joints_tick` compiled by numba, the estimator's two steps and the profile's sampling compiled into it
    (MissingExtra if numba is not installed)."""
    return compile_kernel(joints_tick, "joints", helpers=(count_step, filter_step, sample_profile, stopping_distance))


@functools.lru_cache(maxsize=1)
def compiled_arm_joints_tick() -> Callable[..., int]:
    """`arm_joints_tick` compiled by numba, `joints_tick` (with the estimator's steps) and the gravity compiled
    into it."""
    return compile_kernel(arm_joints_tick, "joints", helpers=(count_step, filter_step, sample_profile,
                                                              stopping_distance, joints_tick, holding_torques_nm))
