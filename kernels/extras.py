"""The optional parts of `aspod`: one check, `require`, at the start of each command or option that needs one.

`pip install aspod` installs the core (sim, teleop, bench, log, proxy, replay, plan, demo, tracker-day, the
pytest plugin); the rest are extras (pyproject.toml): `plot` (matplotlib), `fuzz` (atheris, coverage, Dask),
`campaign` (Dask, pyarrow, matplotlib, pytest), `compiled` (numba), `reference` (pvlib, filterpy), `foxglove`
(foxglove-sdk). A command whose extra is missing raises `MissingExtra` before it starts, a ValueError: `aspod`
prints its one line and exits 2 (EXIT_USAGE, host_tools/exit_codes.py), as for any other bad input.

A module counts as installed when Python can find it (`importlib.util.find_spec`), without importing it: the
check costs nothing at a light start, and a module set to None in `sys.modules` counts as missing.

It lives here, in the lowest package, because every layer that has an optional import reaches it: kernels
(numba), hil_sim (pvlib), firmware_py (filterpy) and host_tools. It imports nothing of the project.
"""
from __future__ import annotations

import importlib.util
import platform

# Modules an extra installs only where they have wheels: (where, what to do elsewhere).
ONLY_ON = {
    "atheris": (("Linux", "x86_64"), "atheris has wheels for Linux x86-64 only, so the fuzz extra leaves it out "
                                    "here; `pip install atheris` builds it with clang and libFuzzer, or fuzz "
                                    "black-box (--url, --target-cmd), which needs no atheris (docs/fuzzing.md)"),
}


class MissingExtra(ValueError):
    """A command or option needs an extra that is not installed; the message names the extra and the pip line."""


def missing(*modules: str) -> list[str]:
    """The top-level modules among `modules` that Python cannot find."""
    absent = []
    for name in modules:
        if not name or not name.isidentifier():
            raise ValueError(f"{name!r} is not a top-level module name")
        if importlib.util.find_spec(name) is None:
            absent.append(name)
    return absent


def require(extra: str, *modules: str, what: str) -> None:
    """Nothing if all of `modules` can be imported; else MissingExtra: `what` (the command or option) needs
    `extra`, and how to install it, in one line."""
    if not modules:
        raise ValueError("require: name the modules the extra installs")
    absent = missing(*modules)
    if not absent:
        return
    names = ", ".join(absent)
    here = (platform.system(), platform.machine())
    elsewhere = [note for name, (where, note) in ONLY_ON.items() if name in absent and here != where]
    if elsewhere:
        raise MissingExtra(f"{what}: needs {names}, not installed: " + "; ".join(elsewhere))
    verb = "is" if len(absent) == 1 else "are"
    raise MissingExtra(f"{what}: needs the {extra} extra ({names} {verb} not installed): pip install 'aspod[{extra}]'")


__all__ = ["MissingExtra", "ONLY_ON", "missing", "require"]
