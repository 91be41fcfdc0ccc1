"""The limit of the lock-step world's speed: the joints' tick and the arm plant's tick, all ticks in one call.

`limit_ticks` runs, `ticks` times, what the world's 1 kHz loop does with its two kernels and
nothing else: the arm's joints' tick (`arm_joints_tick`, firmware_py/joints_tick.py) on the
counts, currents and home switches the plant sampled at the end of the tick before, then the
arm plant's tick (`arm_plant_tick`, hil_sim/arm_tick.py) on its duties, every channel enabled
and no brake (the gripper's channel at the duty its command row holds). No HAL between them (no
quantisation), no bus, no scheduler, no slow task and no event: a joint that hands an event to
its facade ends the call. `compiled_limit_ticks()` is the same function compiled by numba with
both kernels compiled into it (not cached on disk: its helpers live in other files, whose edits
numba's cache would not see). The bench's limit row (bench/bench_lockstep.py) runs it over a
moving world's own rows.
"""
from __future__ import annotations

import functools
from typing import Callable

from firmware_py.joints_tick import (arm_joints_tick, count_step, filter_step, holding_torques_nm, joints_tick,
                                     sample_profile, stopping_distance)
from hil_sim.arm_tick import (BRAKE, COUNTS, CURRENT_A, DUTY, ENABLE, HOME, arm_plant_tick, gravity_and_inertia,
                              sample_readouts)
from kernels import compile_kernel


def limit_ticks(ticks: int, now: float, dt_s: float, joints: int, g: float, payload_kg: float, masses, counts,
                currents_a, home, gravity_nm, duties, state, int_state, config, int_config, profile, h_s: float,
                substeps: int, supply_v: float, command, plant_state, table, flags, plant_counts,
                constants) -> int:
    """Run `ticks` ticks of `dt_s` from `now` (the joints' rows, then the plant's); return the ticks done (fewer:
    a joint handed an event to its facade, its tick not finished)."""
    channels = len(duties)
    for done in range(ticks):
        if arm_joints_tick(joints, now, now, now, g, payload_kg, masses, counts, currents_a, home, gravity_nm,
                           duties, state, int_state, config, int_config, profile) < joints:
            return done
        for c in range(channels):
            command[DUTY][c] = duties[c]
            command[ENABLE][c] = 1.0
            command[BRAKE][c] = 0.0
        arm_plant_tick(h_s, substeps, supply_v, True, False, command, plant_state, table, flags, plant_counts,
                       constants)
        for c in range(channels):
            counts[c] = plant_counts[COUNTS][c]
            currents_a[c] = plant_state[CURRENT_A][c]
            home[c] = flags[HOME][c]
        now += dt_s
    return ticks


@functools.lru_cache(maxsize=1)
def compiled_limit_ticks() -> Callable[..., int]:
    """`limit_ticks` compiled by numba, both kernels compiled into it (RuntimeError without numba)."""
    return compile_kernel(limit_ticks, "limit", cache=False,
                          helpers=(count_step, filter_step, sample_profile, stopping_distance, joints_tick,
                                   holding_torques_nm, arm_joints_tick, gravity_and_inertia, sample_readouts,
                                   arm_plant_tick))
