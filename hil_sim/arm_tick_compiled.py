"""The arm plant's tick compiled by numba: optional, behind the switch of the `kernels` package.

`compiled_arm_plant_tick()` is `arm_plant_tick` (hil_sim/arm_tick.py) compiled without fastmath,
with the two functions it calls (`gravity_and_inertia`, `sample_readouts`) compiled into it, so
its results are the same to the bit as the plain function's (tests/test_arm_plant_tick.py runs
both side by side). It runs over the numpy arrays of an
`ArmTick(compiled=True)`. `ASPOD_COMPILED=1` (kernels/__init__.py) makes it the plant's default
(`Plant(compiled_arm_tick=None)`).
"""
from __future__ import annotations

import functools
from typing import Callable

from hil_sim.arm_tick import arm_plant_tick, gravity_and_inertia, sample_readouts
from kernels import compile_kernel


@functools.lru_cache(maxsize=1)
def compiled_arm_plant_tick() -> Callable[..., tuple[float, float]]:
    """`arm_plant_tick` compiled by numba (MissingExtra if numba is not installed)."""
    return compile_kernel(arm_plant_tick, "arm plant", helpers=(gravity_and_inertia, sample_readouts))


def machine_code_for(kernel: Callable, *example_args) -> Callable:
    """`kernel`'s machine code for the types of `example_args`, called without numba's dispatcher.

    On every call numba's dispatcher types each argument to choose the machine code: about half of
    the arm plant's call (0.75 of 1.6 us, five scalars and six arrays). The machine code's own entry
    point (what `Dispatcher.compile` returns for a signature) takes the arguments as they come and
    converts each as its signature says, so the caller must pass the types of `example_args` on
    every call: the same float, int and bool scalars (ints and bools are converted as floats or truth
    would be), arrays of the same dtype and dimensions (`ArmTick` keeps its groups, and makes its
    scalars so). Not compiled (NUMBA_DISABLE_JIT=1: no dispatcher): `kernel` itself.
    """
    if not hasattr(kernel, "overloads"):
        return kernel
    import numba
    return kernel.compile(tuple(numba.typeof(arg) for arg in example_args))
