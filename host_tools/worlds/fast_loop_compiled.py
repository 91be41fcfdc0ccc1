"""The world's fast loop (host_tools/worlds/fast_loop.py `fast_ticks`) compiled by numba, the ticks it calls into it.

Without fastmath, as the kernels are (kernels/__init__.py): the same functions the tasks call, so a tick run here is
the tasks' to the bit (tests/test_fast_loop.py). Cached on disk as the kernels are (kernels/__init__.py), stale when
this file or one of the ticks' files changes.
"""
from __future__ import annotations

import functools
from typing import Callable

from firmware_py.estimator import unwrap_delta
from firmware_py.gripper_tick import moving_tick, track
from firmware_py.hal import quantized_duty
from firmware_py.hermite import hermite_sample
from firmware_py.joints_tick import (arm_joints_tick, count_step, filter_step, holding_torques_nm, joints_tick,
                                     sample_profile, stopping_distance)
from hil_sim.arm_tick import arm_plant_tick, gravity_and_inertia, sample_readouts
from hil_sim.plant import electronics_step
from host_tools.worlds.fast_loop import copy_groups, fast_ticks
from kernels import compile_kernel


@functools.lru_cache(maxsize=1)
def compiled_fast_ticks() -> Callable[..., int]:
    """`fast_ticks` compiled by numba (MissingExtra if numba is not installed)."""
    return compile_kernel(fast_ticks, "fast loop", helpers=(
        count_step, filter_step, sample_profile, stopping_distance, joints_tick, holding_torques_nm, arm_joints_tick,
        gravity_and_inertia, sample_readouts, arm_plant_tick, unwrap_delta, track, moving_tick, quantized_duty,
        electronics_step, hermite_sample, copy_groups))
