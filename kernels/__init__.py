"""The switch for the compiled kernels: the hot functions compiled by numba, optional.

Two functions carry the world's 1 kHz work: the controller's joints' tick
(firmware_py/joints_tick.py) and the arm plant's tick (hil_sim/arm_tick.py). Each is plain Python
over flat rows of numbers, and each can run compiled by numba's `njit`, without fastmath: IEEE
arithmetic in the source's order, so the compiled results are the plain function's to the bit
(tests/test_joints_tick.py, tests/test_arm_plant_tick.py run both). The machine code is cached on
disk (`cache=True`): in `__pycache__/` beside the source file of the compiled function (an `.nbi`
index and `.nbc` code per function), in `$NUMBA_CACHE_DIR` if set, or in numba's per-user cache
(`~/.cache/numba`) where that folder cannot be written. The index is keyed on the source file's
modification time and size, so the first process after a fresh clone, an upgrade or an edit of that
file compiles (some 14 s of CPU for the joints' and the plant's kernels), and every later one loads
the code (tests/test_kernels_cache.py; bench/bench_start.py measures both).

The switch: `ASPOD_COMPILED=1` in the environment turns both on, so that a bench, a simulator or a
test session picks it up unchanged; `ControllerConfig.compiled_joints` and the plant's
`compiled_arm_tick` take it as their default. numba is not a dependency of the package (the extra
`compiled` installs it): without it the switch stays off and everything runs as plain Python;
turned on without numba, building the controller or the plant says which extra to install
(`MissingExtra`, kernels/extras.py; `aspod` exits 2). `NUMBA_DISABLE_JIT=1` runs
the same arrays through the plain functions (slow: numpy scalars), for debugging.

`compile_kernel` also compiles the reachability planner's order-2 passes (host_tools/plan/reach2.py),
but whenever numba is installed, without the switch: a planner is not held to the bit as the world is.

This package sits below every other (tests/test_code_rules.py) and imports none of them.
"""
from __future__ import annotations

import contextlib
import hashlib
import inspect
import os
from pathlib import Path
from typing import Callable, Iterator, Optional, Sequence, TypeVar

ENVIRONMENT_SWITCH = "ASPOD_COMPILED"

F = TypeVar("F", bound=Callable)


def compiled_by_default() -> bool:
    """Whether the environment asks for the compiled kernels (`ASPOD_COMPILED=1`)."""
    return os.environ.get(ENVIRONMENT_SWITCH, "") == "1"


@contextlib.contextmanager
def switched(on: Optional[bool]) -> Iterator[None]:
    """Within: the switch set to `on` (None: left as the environment has it), for what is built there."""
    if on is None:
        yield
        return
    before = os.environ.get(ENVIRONMENT_SWITCH)
    os.environ[ENVIRONMENT_SWITCH] = "1" if on else "0"
    try:
        yield
    finally:
        if before is None:
            del os.environ[ENVIRONMENT_SWITCH]
        else:
            os.environ[ENVIRONMENT_SWITCH] = before


def compile_kernel(function: F, what: str, helpers: Sequence[Callable] = (), cache: bool = True) -> F:
    """`function` compiled by numba (`njit(cache=cache)`, no fastmath); without numba, MissingExtra (a ValueError:
    `aspod` exits 2) naming `what` and the `compiled` extra (kernels/extras.py).

    `helpers`: the plain functions `function` calls, compiled into it where it calls them and left
    as they are for Python callers (numba's `register_jitable`). numba refreshes its disk cache when
    `function`'s own file changes; helpers from other files are added to that (`_stamp_with`).
    """
    from kernels.extras import require
    require("compiled", "numba", what=f"the compiled {what} ({ENVIRONMENT_SWITCH}=1)")
    import numba
    from numba.extending import register_jitable
    for helper in helpers:
        register_jitable(helper)
    compiled = numba.njit(cache=cache)(function)
    others = sorted({inspect.getfile(helper) for helper in helpers} - {inspect.getfile(function)})
    if cache and others:
        _stamp_with(compiled, others)
    return compiled


def _stamp_with(compiled, files: Sequence[str]) -> None:
    """Make `compiled`'s disk cache stale when any of `files` (its helpers' sources) changes, not only its own file.

    numba keys a cached function on its own source file's stamp (`IndexDataCacheFile._source_stamp`, written with
    the code and compared on loading): the helpers compiled into it from other files would be loaded stale after an
    edit there. Their contents' digest joins that stamp. Where numba keeps it elsewhere (another version), caching
    is turned off for `compiled`: it compiles in every process, never stale."""
    digest = hashlib.sha256()
    for path in files:
        digest.update(Path(path).read_bytes())
    cache_file = getattr(getattr(compiled, "_cache", None), "_cache_file", None)
    if cache_file is None or not hasattr(cache_file, "_source_stamp"):
        from numba.core.caching import NullCache
        compiled._cache = NullCache()
        return
    cache_file._source_stamp = (cache_file._source_stamp, digest.hexdigest())


__all__ = ["ENVIRONMENT_SWITCH", "compile_kernel", "compiled_by_default", "switched"]
