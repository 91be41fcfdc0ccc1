"""Date-times as people type them: teleop's `clock` and the simulator's `--sun-start`.

    now                              the host's UTC, read (through timebase) when it is used
    1782000000                       POSIX seconds (`clock` only; `date -u +%s` prints them)
    2026-03-20T06:50-07:00           ISO 8601 with its UTC offset (seconds and a fraction optional)
    2026-03-20T13:50:00Z             ... Z for UTC

A date-time without an offset is refused: it does not say which time zone it is in (at
Tucson, MST, -07:00 all year). Everything must lie inside the controller clock's range
(SetClock: 2000-01-01 to 2099-12-31 UTC), so that what the simulator's sun starts from can
also be set on the controller. Nothing here reads the OS clock: `now` is resolved by the
caller through `timebase.RealClock.wall_time()` (or a simulated wall clock).
"""
from __future__ import annotations

import math
import re
from datetime import datetime, timezone
from typing import Optional

from protocol.errors import shown
from protocol.messages import SCHEMA

_UTC_FIELD = next(f for f in SCHEMA["SetClock"].fields if f.name == "utc_s")
FIRST_S, LAST_S = _UTC_FIELD.range                      # 2000-01-01T00:00:00Z .. 2099-12-31T23:59:59Z
NOW = "now"
FORMAT = "YYYY-MM-DDTHH:MM[:SS]+HH:MM (or Z for UTC)"
_ISO = re.compile(r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}(:\d{2}(\.\d{1,6})?)?(Z|[+-]\d{2}:\d{2})$")


def utc_text(seconds: float) -> str:
    return datetime.fromtimestamp(seconds, tz=timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


def check_range(seconds: float, what: str) -> float:
    """`seconds` if it lies in the controller clock's range; else ValueError saying so."""
    if not (math.isfinite(seconds) and FIRST_S <= seconds <= LAST_S + 0.999):
        shown = utc_text(seconds) if math.isfinite(seconds) and -62e9 < seconds < 253e9 else repr(seconds)
        raise ValueError(f"{what} {shown} is outside the controller clock's range, {utc_text(FIRST_S)} to "
                         f"{utc_text(LAST_S)} (SetClock)")
    return seconds


def parse_iso(text: str, what: str = "date-time", also: str = "") -> float:
    """POSIX seconds of an ISO 8601 date-time with its offset; ValueError with the reason.

    `also`: the other forms the caller takes, named in the error (e.g. "`now`")."""
    if not _ISO.match(text):
        hint = (" (it needs its UTC offset, e.g. -07:00 for Tucson, MST, or Z for UTC)"
                if re.match(r"^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}(:\d{2}(\.\d+)?)?$", text) else "")
        raise ValueError(f"{what} {shown(text)} is not {also + ' nor ' if also else ''}{FORMAT}{hint}")
    try:
        when = datetime.fromisoformat(text[:-1] + "+00:00" if text.endswith("Z") else text)
    except ValueError as exc:
        raise ValueError(f"{what} {shown(text)}: {exc}") from None
    return check_range(when.timestamp(), what)


def parse_when(text: str, what: str = "date-time", *, posix: bool = True) -> Optional[float]:
    """None for `now` (resolve it when used), else POSIX seconds; `posix` also takes bare seconds."""
    if text.lower() == NOW:
        return None
    if posix and re.match(r"^\d+(\.\d*)?$", text):
        return check_range(float(text), what)
    return parse_iso(text, what, "`now`, POSIX seconds" if posix else "`now`")


def split_seconds(seconds: float) -> tuple[int, int]:
    """(whole seconds, milliseconds) as SetClock carries them."""
    whole, ms = divmod(int(round(seconds * 1000)), 1000)
    return whole, ms
