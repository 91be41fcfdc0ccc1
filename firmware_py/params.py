"""Parameters that persist: declared with ranges, set over the link, saved atomically, loaded at boot.

A save writes the whole set to a temporary file beside the target, flushes and fsyncs
it, renames it over the target (atomic on POSIX) and fsyncs the directory, so a crash
at any point leaves either the previous set or the new one, never a mix or nothing.
A load never crashes the controller: a missing file means defaults; an unreadable or
malformed file, an unknown name, an out-of-range value or one the controller's veto refuses
(a minimum above its maximum) is reported and skipped, and that parameter keeps its default.
The file is applied in passes (`set_all`), so values that depend on each other come back
whichever of them the file names first. The file is read through `protocol.files`: what is
not a regular file (a FIFO, a device, a directory) or is larger than PARAMS_FILE_LIMIT is
not read at all (reported; the defaults stay), so a load can neither hang nor fill memory.
"""
from __future__ import annotations

import json
import math
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from protocol import files
from protocol.messages import SCHEMA
from protocol.reasons import Reason

FILE_VERSION = 1
PARAMS_FILE_LIMIT = 256 * files.KIB   # a saved set is a few KiB; a file far larger is not a parameter file
# What ParamValue carries of a parameter (protocol/messages.py): a declaration must fit, never be cut on the wire.
_ON_THE_WIRE = {f.name: f for f in SCHEMA["ParamValue"].fields}


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: float
    lo: float
    hi: float
    unit: str
    doc: str

    def __post_init__(self) -> None:
        if not self.lo <= self.default <= self.hi:
            raise ValueError(f"parameter {self.name}: default {self.default} outside {self.lo}..{self.hi}")
        for what, text in (("name", self.name), ("unit", self.unit), ("description", self.doc)):
            wire = _ON_THE_WIRE[what]
            problem = wire.check(text)
            if problem is not None:
                raise ValueError(f"parameter {self.name}: {problem} (ParamValue.{what} is {wire.type})")


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _at_an_end(value: float, lo: float, hi: float) -> float:
    """An end of [lo, hi] for a value that misses it only as the link's f32 carries it (ParamSet 0.01 arrives as
    0.0099999998, below a minimum of 0.01, and was refused); the value itself otherwise."""
    for end in (lo, hi):
        if value != end and abs(value - end) <= 1e-6 * max(1.0, abs(end)) and _f32(value) == _f32(end):
            return end
    return value


class ParamStore:
    """Values by name; `on_change(name, value)` applies a value when it is set or loaded.

    `check(name, value)` may veto a value that is in range but inconsistent with the others
    (a soft minimum above its maximum, say): it returns the problem, or None.
    """

    def __init__(self, specs: list[ParamSpec], path: Optional[Path] = None,
                 on_change: Callable[[str, float], None] = lambda name, value: None,
                 check: Callable[[str, float], Optional[str]] = lambda name, value: None) -> None:
        self.specs = {spec.name: spec for spec in specs}
        self.order = [spec.name for spec in specs]
        self.path = Path(path) if path is not None else None
        self._values = {spec.name: float(spec.default) for spec in specs}
        self._on_change = on_change
        self._check = check
        self.load_problems: list[str] = []

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def values(self) -> dict[str, float]:
        """A copy of every value by name."""
        return dict(self._values)

    def set(self, name: str, value: float) -> tuple[Reason, str]:
        """Set one value; refused (and nothing changes) if unknown, not finite or out of range."""
        spec = self.specs.get(name)
        if spec is None:
            return Reason.UNKNOWN_PARAM, f"no parameter {name!r}"
        if isinstance(value, int) and not isinstance(value, bool) and not -2**63 <= value < 2**63:
            return Reason.OUT_OF_RANGE, (f"{name}: a whole number of {len(str(abs(value)))} digits, outside "
                                         f"{spec.lo}..{spec.hi} {spec.unit}").rstrip()
        if isinstance(value, (int, float)) and math.isfinite(value):
            value = _at_an_end(value, spec.lo, spec.hi)
        if not isinstance(value, (int, float)) or not math.isfinite(value) or not spec.lo <= value <= spec.hi:
            return Reason.OUT_OF_RANGE, f"{name}={value} outside {spec.lo}..{spec.hi} {spec.unit}".rstrip()
        problem = self._check(name, float(value))
        if problem is not None:
            return Reason.OUT_OF_RANGE, f"{name}={value}: {problem}"
        self._values[name] = float(value)
        self._on_change(name, float(value))
        return Reason.OK, ""

    def load(self) -> list[str]:
        """Read the file, if any; returns (and keeps) the problems found. Never raises."""
        problems: list[str] = []
        self.load_problems = problems
        if self.path is None:
            return problems
        try:
            raw = files.read_bounded(self.path, PARAMS_FILE_LIMIT)
        except files.InputFileError as exc:
            if not exc.missing:
                problems.append(f"{exc}; all parameters keep their defaults")
            return problems
        try:
            data = json.loads(raw.decode("utf-8"))
            if not isinstance(data, dict) or data.get("version") != FILE_VERSION or not isinstance(
                    data.get("params"), dict):
                raise ValueError(f"not a version-{FILE_VERSION} parameter file")
        except (UnicodeDecodeError, ValueError, RecursionError) as exc:
            problems.append(f"{self.path}: {exc}; all parameters keep their defaults")
            return problems
        refused = self.set_all(data["params"].items())
        problems.extend(f"{self.path}: {detail}; kept the default" for detail in refused.values())
        return problems

    def set_all(self, items) -> dict[str, str]:
        """Set every (name, value) of `items`, in passes: a value the veto refuses against a partner's present
        value (a minimum above the default maximum) is taken once its own partner, later in `items`, is in. One
        pass in order lost a saved, consistent set at boot (an attack on 2026-11-27). What is still refused, by
        name, with the reason; a value that is not a number (a JSON text, a boolean) is refused as such."""
        refused: dict[str, str] = {}
        pending: dict[str, float] = {}
        for name, value in items:
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                pending[name] = value
            else:
                refused[name] = f"{name}: {value!r} is not a number"
        while pending:
            left = {}
            for name, value in pending.items():
                reason, detail = self.set(name, value)
                if reason is Reason.OK:
                    refused.pop(name, None)
                else:
                    left[name], refused[name] = value, detail
            if len(left) == len(pending):
                break
            pending = left
        return refused

    def save(self) -> tuple[Reason, str]:
        if self.path is None:
            return Reason.SAVE_FAILED, "no parameter file configured (aspod sim --params FILE)"
        text = json.dumps({"version": FILE_VERSION, "params": {n: self._values[n] for n in self.order}}, indent=1)
        tmp = self.path.with_name(self.path.name + ".tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "w", encoding="utf-8") as out:
                out.write(text + "\n")
                out.flush()
                os.fsync(out.fileno())
            os.replace(tmp, self.path)
            directory = os.open(self.path.parent, os.O_RDONLY)
            try:
                os.fsync(directory)
            finally:
                os.close(directory)
        except OSError as exc:    # the reason first (a short reply carries it to the host), then the path
            return Reason.SAVE_FAILED, f"{exc.strerror or exc}: {exc.filename or self.path}"
        return Reason.OK, ""
