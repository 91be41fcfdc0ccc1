"""A campaign's matrix: which settings vary, how, and the list of runs it makes.

    --vary payload_kg=0,0.5,1.0          a grid axis: these values
    --vary payload_kg=0..2/5             a grid axis: 5 values evenly from 0 to 2 (numbers or ISO date-times)
    --draw fault=none,jam:j2,open_circuit:j1    drawn for each run: one of these
    --draw fault_at_s=1..20              drawn for each run: uniform between (numbers or ISO date-times)
    --seeds 1000  (or 100..199)          every grid point runs with each of these seeds

Values are separated by commas, except on the axes whose values hold commas themselves (`impairment`:
`radio,seed=4`; `clouds`), where they are separated by `|` (quote it in the shell).

The runs are the grid's points (every combination of the `--vary` axes) times the seeds, in a fixed order;
each run's draws come from a generator seeded by the axis's name and the run's seed alone. The same matrix
gives the same runs wherever it runs, and two grid points with the same seed see the same draws (common
random numbers: comparing payloads under the same faults at the same times).

An axis is a setting of the world (`WORLD_AXES`), a controller parameter (`param.NAME`), or else a
variable of the bench (a script's `${NAME}`, a pytest bench's `aspod_target.variables[NAME]`).
"""
from __future__ import annotations

import itertools
import math
import random
import re
from dataclasses import dataclass
from datetime import datetime
from typing import Union

from host_tools.datetimes import parse_iso

Value = Union[str, float, int]

# The world's axes and what they are: (kind, what it sets). Others are `param.NAME` or the bench's variables.
WORLD_AXES: dict[str, str] = {
    "seed": "int",               # the world's seed (as --seeds gives it)
    "gravity": "str",            # earth | orbit
    "payload_kg": "float",
    "sun_start": "str",          # ISO date-time with its offset
    "clouds": "str",             # a clouds spec (hil_sim/sun.py parse_clouds)
    "fault": "str",              # none | NAME[:CHANNEL] (hil_sim/faults.py), injected at fault_at_s
    "fault_at_s": "float",       # simulated seconds from the world's start
    "fault_until_s": "float",    # cleared then (default: never)
    "impairment": "str",         # the link's, as `aspod proxy --impair`
}
PARAM_PREFIX = "param."
BAR_SEPARATED = ("impairment", "clouds")      # their values hold commas
MAX_RUNS = 1_000_000
MAX_VALUES = 10_000
DAY_S = 86400.0
DECIMALS = 3                     # drawn numbers are rounded to this (a millisecond, a gram): short, exact commands
_RANGE = re.compile(r"^(?P<lo>.+?)\.\.(?P<hi>.+?)(?:/(?P<n>\d+))?$")


def kind_of(name: str) -> str:
    if name in WORLD_AXES:
        return WORLD_AXES[name]
    if name.startswith(PARAM_PREFIX):
        if not name[len(PARAM_PREFIX):]:
            raise ValueError(f"axis {name!r}: write param.NAME with a controller parameter's name")
        return "float"
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ValueError(f"axis {name!r}: a variable's name is letters, digits and _ (the world's axes: "
                         f"{', '.join(WORLD_AXES)}, param.NAME)")
    return "str"


def _typed(name: str, kind: str, text: str) -> Value:
    text = text.strip()
    try:
        if kind == "int":
            return int(text)
        if kind == "float":
            value = float(text)
            if not math.isfinite(value):
                raise ValueError
            return value
    except ValueError:
        raise ValueError(f"axis {name}: {text!r} is not {'a whole number' if kind == 'int' else 'a number'}") \
            from None
    if not text:
        raise ValueError(f"axis {name}: an empty value")
    return text


def _is_date_time(text: str) -> bool:
    return bool(re.match(r"^\d{4}-\d{2}-\d{2}T", text.strip()))


def _span(name: str, kind: str, lo_text: str, hi_text: str):
    """(lo, hi, to_value) of a range: numbers, or ISO date-times (as POSIX seconds, turned back into text in
    lo's offset, to the minute; to whole days when the ends are a whole number of days apart, so that the
    date varies and the time of day does not)."""
    if _is_date_time(lo_text) and _is_date_time(hi_text):
        lo, hi = parse_iso(lo_text.strip(), f"axis {name}"), parse_iso(hi_text.strip(), f"axis {name}")
        zone = datetime.fromisoformat(lo_text.strip().replace("Z", "+00:00")).tzinfo
        step = DAY_S if (hi - lo) % DAY_S == 0 else 60.0

        def to_text(seconds: float) -> str:
            when = datetime.fromtimestamp(lo + round((seconds - lo) / step) * step, tz=zone)
            return when.isoformat(timespec="minutes")
        return lo, hi, to_text
    if kind == "str" and name in WORLD_AXES:
        raise ValueError(f"axis {name}: a range needs numbers or ISO date-times at both ends")
    lo, hi = _typed(name, "float", lo_text), _typed(name, "float", hi_text)
    if kind == "int":
        return lo, hi, lambda x: int(round(x))
    return lo, hi, lambda x: round(x, DECIMALS)


@dataclass(frozen=True)
class GridAxis:
    name: str
    values: tuple[Value, ...]

    @classmethod
    def parse(cls, text: str) -> "GridAxis":
        """`NAME=A,B,C` or `NAME=LO..HI/N`; ValueError saying what is wrong."""
        name, values = _split(text, "--vary")
        kind = kind_of(name)
        found = _RANGE.match(values)
        if found and found.group("n"):
            n = int(found.group("n"))
            if not 2 <= n <= MAX_VALUES:
                raise ValueError(f"--vary {text}: between 2 and {MAX_VALUES} values")
            lo, hi, to_value = _span(name, kind, found.group("lo"), found.group("hi"))
            return cls(name, tuple(to_value(lo + (hi - lo) * i / (n - 1)) for i in range(n)))
        items = _items(name, values)
        if len(items) > MAX_VALUES:
            raise ValueError(f"--vary {name}: at most {MAX_VALUES} values")
        return cls(name, tuple(_typed(name, kind, item) for item in items))


@dataclass(frozen=True)
class DrawnAxis:
    """Drawn for each run: one of `choices`, or uniform in [lo, hi] (`to_value` turns the draw into its value)."""
    name: str
    choices: tuple[Value, ...] = ()
    span: tuple = ()             # (lo, hi, to_value)

    @classmethod
    def parse(cls, text: str) -> "DrawnAxis":
        """`NAME=A,B,C` or `NAME=LO..HI`; ValueError saying what is wrong."""
        name, values = _split(text, "--draw")
        kind = kind_of(name)
        items = _items(name, values)
        if len(items) > 1 or ".." not in values:
            if len(items) > MAX_VALUES:
                raise ValueError(f"--draw {name}: at most {MAX_VALUES} choices")
            return cls(name, choices=tuple(_typed(name, kind, item) for item in items))
        lo_text, _, hi_text = values.partition("..")
        lo, hi, to_value = _span(name, kind, lo_text, hi_text)
        if not hi >= lo:
            raise ValueError(f"--draw {text}: the range's end is below its start")
        return cls(name, span=(lo, hi, to_value))

    def draw(self, seed: int) -> Value:
        rng = random.Random(f"{self.name}|{seed}")          # str seeds are hashed with SHA-512: the same anywhere
        if self.choices:
            return rng.choice(self.choices)
        lo, hi, to_value = self.span
        return to_value(rng.uniform(lo, hi))


def _items(name: str, values: str) -> list[str]:
    return values.split("|" if name in BAR_SEPARATED else ",")


def _split(text: str, option: str) -> tuple[str, str]:
    name, sep, values = text.partition("=")
    name = name.strip()
    if not sep or not name or not values.strip():
        raise ValueError(f"{option} {text!r}: write NAME=VALUES, e.g. payload_kg=0,0.5,1 or fault_at_s=1..20")
    if name == "seed":
        raise ValueError(f"{option} seed: give the seeds with --seeds N or --seeds FIRST..LAST")
    return name, values.strip()


def parse_seeds(text: str) -> tuple[int, ...]:
    """`N` (0..N-1) or `FIRST..LAST` (inclusive); ValueError saying what is wrong."""
    first, sep, last = text.partition("..")
    try:
        seeds = range(int(first), int(last) + 1) if sep else range(int(text))
    except ValueError:
        raise ValueError(f"--seeds {text!r}: write a count (100) or a range (100..199)") from None
    if not 1 <= len(seeds) <= MAX_RUNS or seeds.start < 0:
        raise ValueError(f"--seeds {text!r}: between 1 and {MAX_RUNS} seeds, none below 0")
    return tuple(seeds)


@dataclass(frozen=True)
class Run:
    """One run of the campaign: its place in the order and the value of every axis (seed first)."""
    index: int
    values: tuple[tuple[str, Value], ...]

    def as_dict(self) -> dict[str, Value]:
        return dict(self.values)


@dataclass(frozen=True)
class Matrix:
    grid: tuple[GridAxis, ...] = ()
    drawn: tuple[DrawnAxis, ...] = ()
    seeds: tuple[int, ...] = (0,)

    def __post_init__(self) -> None:
        names = [a.name for a in self.grid] + [a.name for a in self.drawn]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"axis {', '.join(twice)} given more than once")
        if ("fault_at_s" in names or "fault_until_s" in names) and "fault" not in names:
            raise ValueError("fault_at_s and fault_until_s time a fault: vary or draw `fault` too")
        if "fault" in names and "fault_at_s" not in names:
            raise ValueError("a fault needs its time: vary or draw fault_at_s too")
        if self.size > MAX_RUNS:
            raise ValueError(f"the matrix makes {self.size} runs; at most {MAX_RUNS}")

    @property
    def size(self) -> int:
        return math.prod(len(a.values) for a in self.grid) * len(self.seeds)

    @property
    def axes(self) -> list[str]:
        return ["seed"] + [a.name for a in self.grid] + [a.name for a in self.drawn]

    def runs(self) -> list[Run]:
        out = []
        for point in itertools.product(*(a.values for a in self.grid)):
            for seed in self.seeds:
                values = [("seed", seed), *zip((a.name for a in self.grid), point)]
                values += [(a.name, a.draw(seed)) for a in self.drawn]
                out.append(Run(len(out), tuple(values)))
        return out
