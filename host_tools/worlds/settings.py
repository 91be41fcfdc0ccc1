"""The plant's settings, as every world builds it: one frozen, validated value instead of five keywords.

`World`, `LockstepBench` and `nodes.build_plant_node` take a `PlantSettings`; `aspod sim`,
`aspod plant` and `aspod sim --hal` build one from their command line (host_tools/cli/settings.py)
and hand a child `aspod plant` its options back through `to_argv()`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from datetime import datetime
from typing import Optional, Sequence, Union

from hil_sim.arm_params import GRAVITY_M_S2
from host_tools.datetimes import check_range
from hil_sim.sun import DEFAULT_START, TUCSON, CloudPassage, DateTimeLike, as_clouds, to_utc

GRAVITY_MODES = tuple(GRAVITY_M_S2)     # "earth", "orbit"
PAYLOAD_MAX_KG = 1000.0                 # a payload's bound, far past what the arm lifts: a typing mistake's
TIMINGS = ("lockstep", "realtime")      # how a plant or controller in its own process keeps time (docs/realtime.md)
Clouds = Union[str, Sequence[CloudPassage], None]


@dataclass(frozen=True)
class PlantSettings:
    """The arm's gravity and payload; the solar tracker, its sun's start and clouds.

    `start` is a datetime (any DateTimeLike is turned into an aware UTC datetime), or None: the real
    sun now, to be resolved (`with_start`) by whoever runs the plant, once its sun table is warm.
    Without the tracker there is no start and no clouds to set (ValueError if they are). `clouds`:
    None, a spec ('12:00+300s@0.9,...', local standard time on the start's date) or passages; with a
    start, they are checked against its day here.
    """
    gravity: str = "earth"
    payload_kg: float = 0.0
    tracker: bool = True
    start: Optional[datetime] = to_utc(DEFAULT_START)
    clouds: Clouds = None

    def __post_init__(self) -> None:
        if self.gravity not in GRAVITY_MODES:
            raise ValueError(f"unknown gravity {self.gravity!r}; known: {', '.join(GRAVITY_MODES)}")
        if isinstance(self.payload_kg, bool) or not isinstance(self.payload_kg, (int, float)) \
                or not 0 <= self.payload_kg <= PAYLOAD_MAX_KG:      # NaN compares false; a huge int fits no float
            raise ValueError(f"payload_kg must be in 0..{PAYLOAD_MAX_KG:g}, got {self.payload_kg!r}")
        object.__setattr__(self, "payload_kg", float(self.payload_kg))
        if not self.tracker:
            if self.clouds:
                raise ValueError("clouds set the solar tracker's sun, but the plant has no tracker")
            object.__setattr__(self, "start", None)
            object.__setattr__(self, "clouds", None)
            return
        if self.start is not None:
            object.__setattr__(self, "start", to_utc(self.start))
            as_clouds(self.clouds, self.start, TUCSON)      # ValueError for clouds that do not fit the day
        if self.clouds is not None and not isinstance(self.clouds, str):
            object.__setattr__(self, "clouds", tuple(self.clouds))

    def with_start(self, when: DateTimeLike) -> "PlantSettings":
        """These settings with the sun starting at `when` (how `now` is resolved)."""
        return dataclasses.replace(self, start=to_utc(when))

    def plant_start(self) -> datetime:
        """The start the plant is built with: without a tracker, any (the default); `now` unresolved: ValueError."""
        if not self.tracker:
            return to_utc(DEFAULT_START)
        if self.start is None:
            raise ValueError("the sun's start is `now`: resolve it (PlantSettings.with_start) before the plant is built")
        return self.start

    def passages(self) -> tuple[CloudPassage, ...]:
        """The cloud passages, read on the start's day (no tracker: none)."""
        return as_clouds(self.clouds, self.plant_start(), TUCSON) if self.tracker else ()

    def to_argv(self) -> list[str]:
        """These settings as `aspod plant` (and `aspod sim`) take them on their command line."""
        argv = ["--gravity", self.gravity, "--payload-kg", repr(self.payload_kg)]
        if not self.tracker:
            return argv + ["--no-tracker"]
        if self.start is not None:
            argv += ["--sun-start", self.start.isoformat()]
        if self.clouds is not None:
            if not isinstance(self.clouds, str):
                raise ValueError("clouds given as passages have no command-line form; give them as a spec")
            argv += ["--clouds", self.clouds]
        return argv

    def to_dict(self) -> dict:
        """These settings as JSON values (a session capture keeps them): `from_dict` gives them back."""
        if self.clouds is not None and not isinstance(self.clouds, str):
            raise ValueError("clouds given as passages have no written form; give them as a spec")
        return {"gravity": self.gravity, "payload_kg": self.payload_kg, "tracker": self.tracker,
                "start": None if self.start is None else self.start.isoformat(), "clouds": self.clouds}

    @classmethod
    def from_dict(cls, values: dict) -> "PlantSettings":
        """ValueError naming what is wrong, for values that did not come from `to_dict`."""
        known = {"gravity", "payload_kg", "tracker", "start", "clouds"}
        if not isinstance(values, dict) or set(values) - known:
            raise ValueError(f"plant settings must be a mapping of {', '.join(sorted(known))}")
        values = dict(values)
        if not isinstance(values.get("gravity", ""), str):
            raise ValueError(f"plant gravity {values['gravity']!r} is not one of {', '.join(GRAVITY_MODES)}")
        if not isinstance(values.get("tracker", True), bool):
            raise ValueError(f"plant tracker {values['tracker']!r} is not true or false")
        if not isinstance(values.get("clouds") or "", str):
            raise ValueError("plant clouds must be a spec (a string), as --clouds takes")
        if values.get("start") is not None:
            try:
                values["start"] = datetime.fromisoformat(str(values["start"]))
            except ValueError:
                raise ValueError(f"plant start {str(values['start'])[:60]!r} is not an ISO date-time") from None
            if values["start"].tzinfo is None:
                raise ValueError("plant start has no UTC offset")
            check_range(values["start"].timestamp(), "plant start")     # as --sun-start: SetClock's range
        try:
            return cls(**values)
        except TypeError as exc:
            raise ValueError(f"plant settings: {exc}") from None
