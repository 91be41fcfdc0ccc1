"""The sun for the solar tracker: position, clear-sky beam and clouds, at a site and a date-time.

The position is the NREL SPA (hil_sim/spa.py), the beam the Ineichen-Perez clear sky
(hil_sim/clear_sky.py), both the project's own over numpy and pvlib's to the bit; neither pvlib
nor pandas is imported unless a site without its Linke turbidities asks for pvlib's table.
Design: docs/tracker.md#the-simulated-sun
"""
from __future__ import annotations

import bisect
import functools
import math
import re
from dataclasses import dataclass
from datetime import date, datetime, timedelta, timezone
from numbers import Real
from typing import Iterable, Optional, Sequence, Union

import numpy as np

from hil_sim import clear_sky, spa

DateTimeLike = Union[datetime, float, int]

UTC = timezone.utc
CHUNK_S = 86400             # one vectorised computation covers a local day
DEFAULT_TABLE_STEP_S = 10.0


@dataclass(frozen=True)
class Site:
    """Where the tracker stands.

    `utc_offset_h` is the local standard time's offset from UTC (clock times in the clouds
    spec and in reports are read in it; no daylight saving). `pressure_pa` None means the
    standard atmosphere's pressure at `altitude_m` (clear_sky.standard_pressure_pa);
    `temperature_c` is the air temperature for refraction. `linke_turbidity_x20`: the site's
    monthly Linke turbidity, January to December, times 20 as SoDa's worldwide table stores it;
    None: read from pvlib's copy of that table when the sun is first computed (pvlib's import).
    """

    name: str
    latitude_deg: float
    longitude_deg: float     # east positive
    altitude_m: float
    utc_offset_h: float
    pressure_pa: Optional[float] = None
    temperature_c: float = 12.0
    linke_turbidity_x20: Optional[tuple[int, ...]] = None

    def __post_init__(self) -> None:
        for f in ("latitude_deg", "longitude_deg", "altitude_m", "utc_offset_h", "temperature_c"):
            value = getattr(self, f)
            if not isinstance(value, Real) or isinstance(value, bool) or not math.isfinite(value):
                raise ValueError(f"Site.{f} must be a finite number, got {value!r}")
        if not -90.0 <= self.latitude_deg <= 90.0:
            raise ValueError(f"Site.latitude_deg must be in [-90, 90], got {self.latitude_deg}")
        if not -180.0 <= self.longitude_deg <= 180.0:
            raise ValueError(f"Site.longitude_deg must be in [-180, 180], got {self.longitude_deg}")
        if not -12.0 <= self.utc_offset_h <= 14.0:
            raise ValueError(f"Site.utc_offset_h must be in [-12, 14], got {self.utc_offset_h}")
        if not -500.0 <= self.altitude_m <= 9000.0:
            raise ValueError(f"Site.altitude_m must be in [-500, 9000], got {self.altitude_m}")
        if self.pressure_pa is not None and not (math.isfinite(self.pressure_pa) and self.pressure_pa > 0):
            raise ValueError(f"Site.pressure_pa must be None or finite and > 0, got {self.pressure_pa}")
        monthly = self.linke_turbidity_x20
        if monthly is not None and not (isinstance(monthly, tuple) and len(monthly) == 12 and all(
                isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 255 for v in monthly)):
            raise ValueError(f"Site.linke_turbidity_x20 must be None or a tuple of 12 whole numbers 0..255 "
                             f"(January to December), got {monthly!r}")

    @property
    def local_tz(self) -> timezone:
        """The site's local standard time as a fixed-offset time zone."""
        return timezone(timedelta(hours=self.utc_offset_h))


# The University of Arizona, Tucson, where the ASPOD project was built (report, abstract:
# "design project at the University of Arizona"). Coordinates of the campus, 32 deg 13' 55" N,
# 110 deg 57' 00" W (32.2319, -110.9501, as Wikipedia's "University of Arizona" article and
# GeoHack give them); elevation of Tucson 2,389 ft (728 m) (U.S. Census Bureau / GNIS, as
# quoted e.g. at fedest.com/question/20061028194801AAAFjrW and askbiography.com's "Tucson,
# Arizona"). Time zone MST, UTC-7 all year: Arizona does not observe daylight saving time
# (exempt under the Uniform Time Act of 1966 since 1968). Its monthly Linke turbidity: SoDa's table
# (pvlib 0.16's data/LinkeTurbidities.h5) at the campus' cell, row 693, column 828.
TUCSON = Site("Tucson, Arizona (University of Arizona)", 32.2319, -110.9501, 728.0, -7.0,
              linke_turbidity_x20=(45, 48, 49, 53, 58, 60, 66, 72, 62, 50, 50, 50))

MST = timezone(timedelta(hours=-7), "MST")

# The default start of a run: the June solstice of 2026 (21 June, 08:24 UTC; US Naval
# Observatory, "Earth's Seasons"), at 06:00 MST, about 40 minutes after sunrise at Tucson
# (05:19 MST). The June solstice is the design day: the sun climbs highest (81.2 deg at
# 12:26 MST) and its azimuth turns fastest (1.50 deg/min at transit) of the year.
DEFAULT_START = datetime(2026, 6, 21, 6, 0, 0, tzinfo=MST)


def to_utc(when: DateTimeLike) -> datetime:
    """A timezone-aware datetime in UTC from an aware datetime or a POSIX timestamp [s].

    ValueError for a naive datetime (which time zone?), a non-finite timestamp or anything else.
    """
    if isinstance(when, datetime):
        if when.tzinfo is None or when.tzinfo.utcoffset(when) is None:
            raise ValueError(f"a start date-time must be timezone-aware (e.g. tzinfo=hil_sim.sun.MST "
                             f"or timezone.utc), got the naive {when.isoformat()}")
        return when.astimezone(UTC)
    if isinstance(when, Real) and not isinstance(when, bool):
        if not math.isfinite(when):
            raise ValueError(f"a POSIX timestamp must be finite, got {when}")
        return datetime.fromtimestamp(float(when), tz=UTC)
    raise ValueError(f"a date-time must be an aware datetime or a POSIX timestamp in seconds, got {when!r}")


def _pressure_pa(site: Site) -> float:
    return site.pressure_pa if site.pressure_pa is not None else float(clear_sky.standard_pressure_pa(site.altitude_m))


def solar_position(times: Union[DateTimeLike, Sequence[DateTimeLike]], site: Site,
                   delta_t_s: Optional[float] = None) -> dict[str, np.ndarray]:
    """The sun at `site` at each of `times` (the NREL SPA, hil_sim/spa.py), as numpy arrays in degrees.

    Keys: "apparent_elevation", "apparent_zenith" (refraction at the site's pressure and
    temperature), "elevation", "zenith" (geometric), "azimuth" (from north through east,
    0..360). `delta_t_s` is TT - UT1 in seconds; None estimates it from the date (NASA's
    polynomial: about 69 s in 2026).
    """
    stamps = times if isinstance(times, (list, tuple, np.ndarray)) else [times]
    unix_s = np.array([to_utc(t).timestamp() for t in stamps], dtype=np.float64)    # whole microseconds
    sun = spa.sun_positions(unix_s, site.latitude_deg, site.longitude_deg, site.altitude_m, _pressure_pa(site) / 100,
                            site.temperature_c, delta_t_s)
    return {"apparent_elevation": sun.apparent_elevation, "apparent_zenith": sun.apparent_zenith,
            "elevation": sun.elevation, "zenith": sun.zenith, "azimuth": sun.azimuth}


@dataclass(frozen=True)
class _Chunk:
    t0: float                     # POSIX seconds of the first sample
    t1: float                     # POSIX seconds of the last sample
    step_s: float
    elevation: list               # apparent elevation, deg
    azimuth: list                 # unwrapped within the chunk, deg
    dni: list                     # clear-sky direct normal, W/m^2
    dhi: list                     # clear-sky diffuse horizontal, W/m^2


@functools.lru_cache(maxsize=32)
def _chunk(site: Site, t0: int, step_s: float) -> _Chunk:
    """The sun over [t0, t0 + CHUNK_S] (POSIX seconds) at `step_s`, vectorised (about 30 ms a day at 10 s)."""
    n = int(round(CHUNK_S / step_s)) + 1
    unix_s = t0 + np.arange(n) * step_s
    pressure = _pressure_pa(site)
    sun = spa.sun_positions(unix_s, site.latitude_deg, site.longitude_deg, site.altitude_m, pressure / 100,
                            site.temperature_c)
    zenith = sun.apparent_zenith
    day, leap = clear_sky.utc_day_of_year(unix_s)
    turbidity = clear_sky.linke_turbidity(day, leap, _monthly_turbidity_x20(site))
    dni, dhi = clear_sky.ineichen(zenith, clear_sky.absolute_airmass(zenith, pressure), turbidity, site.altitude_m,
                                  clear_sky.extraterrestrial_dni(day))
    dni = np.nan_to_num(dni, nan=0.0).clip(min=0.0)
    dhi = np.nan_to_num(dhi, nan=0.0).clip(min=0.0)
    azimuth = np.unwrap(sun.azimuth, period=360.0)
    return _Chunk(float(t0), float(t0 + (n - 1) * step_s), step_s, sun.apparent_elevation.tolist(), azimuth.tolist(),
                  dni.tolist(), dhi.tolist())


@functools.lru_cache(maxsize=8)
def _monthly_turbidity_x20(site: Site) -> tuple[int, ...]:
    if site.linke_turbidity_x20 is not None:
        return site.linke_turbidity_x20
    return clear_sky.lookup_monthly_turbidity_x20(site.latitude_deg, site.longitude_deg)


class SunTable:
    """The sun at one site, tabulated on first need and interpolated: `at(t_unix)`, cheap per call.

    `at` returns (apparent elevation deg, azimuth deg in [0, 360), clear-sky DNI W/m^2,
    clear-sky DHI W/m^2) at POSIX time `t_unix`, linearly interpolated from a `step_s`
    grid. Any time works (local days are computed as they are reached, or ahead with
    `preload`).
    """

    def __init__(self, site: Site = TUCSON, step_s: float = DEFAULT_TABLE_STEP_S) -> None:
        if not isinstance(site, Site):
            raise ValueError(f"site must be a hil_sim.sun.Site, got {site!r}")
        if not (isinstance(step_s, Real) and math.isfinite(step_s) and 0.5 <= step_s <= 600.0):
            raise ValueError(f"step_s must be within 0.5-600 s, got {step_s!r}")
        if CHUNK_S % step_s:
            raise ValueError(f"step_s must divide {CHUNK_S} s, got {step_s}")
        self.site = site
        self.step_s = float(step_s)
        self._chunk: Optional[_Chunk] = None
        self.chunks_loaded = 0

    def _load(self, t_unix: float) -> _Chunk:
        # The local day (standard time) holding t_unix, as POSIX seconds of its midnight.
        offset = round(self.site.utc_offset_h * 3600)
        start = int(math.floor((t_unix + offset) / CHUNK_S)) * CHUNK_S - offset
        self._chunk = _chunk(self.site, start, self.step_s)
        self.chunks_loaded += 1
        return self._chunk

    def preload(self, t_unix: float) -> None:
        """Compute (or fetch from the cache) the local day holding `t_unix` now, not at the first `at`."""
        if not (isinstance(t_unix, Real) and math.isfinite(t_unix)):
            raise ValueError(f"t_unix must be a finite number, got {t_unix!r}")
        c = self._chunk
        if c is None or not c.t0 <= t_unix < c.t1:
            self._load(t_unix)

    def at(self, t_unix: float) -> tuple[float, float, float, float]:
        """(elevation deg, azimuth deg [0, 360), DNI W/m^2, DHI W/m^2) at POSIX time `t_unix`."""
        c = self._chunk
        if c is None or not c.t0 <= t_unix < c.t1:
            if not math.isfinite(t_unix):
                raise ValueError(f"t_unix must be finite, got {t_unix}")
            c = self._load(t_unix)
        x = (t_unix - c.t0) / c.step_s
        i = int(x)
        f = x - i
        el, az, dni, dhi = c.elevation, c.azimuth, c.dni, c.dhi
        a = az[i] + f * (az[i + 1] - az[i])
        return (el[i] + f * (el[i + 1] - el[i]), a % 360.0,
                dni[i] + f * (dni[i + 1] - dni[i]), dhi[i] + f * (dhi[i + 1] - dhi[i]))


# ---- clouds ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CloudPassage:
    """One cloud over the sun: from `start` (aware datetime) for `duration_s`, removing `attenuation` of the beam."""

    start: datetime
    duration_s: float
    attenuation: float

    def __post_init__(self) -> None:
        if not isinstance(self.start, datetime) or self.start.tzinfo is None:
            raise ValueError(f"CloudPassage.start must be a timezone-aware datetime, got {self.start!r}")
        if not (isinstance(self.duration_s, Real) and math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f"CloudPassage.duration_s must be finite and > 0, got {self.duration_s!r}")
        if not (isinstance(self.attenuation, Real) and 0.0 <= self.attenuation <= 1.0):
            raise ValueError(f"CloudPassage.attenuation must be in [0, 1], got {self.attenuation!r}")


_TIME = re.compile(r"^(?:(\d{4})-(\d{2})-(\d{2})T)?(\d{1,2}):(\d{2})(?::(\d{2}(?:\.\d*)?))?$")
_DURATION = re.compile(r"^(\d+(?:\.\d*)?|\.\d+)(s|m|min|h)$")
_UNIT_S = {"s": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0}


MAX_CLOUDS_CHARS = 4096   # a spec; about 250 passages of '12:00+300s@0.9'
MAX_PASSAGES = 200


def parse_clouds(spec: str, day: date, utc_offset_h: float) -> tuple[CloudPassage, ...]:
    """Cloud passages from a spec "TIME+DURATION@ATTENUATION, ..." (module docstring).

    Bare clock times are on `day` (a local date) in the local standard time `utc_offset_h`.
    ValueError, naming the passage and what is wrong, for anything malformed.
    """
    if not isinstance(spec, str):
        raise ValueError(f"a clouds spec must be a string, got {spec!r:.80}")
    if len(spec) > MAX_CLOUDS_CHARS:
        raise ValueError(f"a clouds spec of {len(spec)} characters: at most {MAX_CLOUDS_CHARS} (it travels in a "
                         "recording's header, whose options are bounded)")
    if spec.count(",") >= MAX_PASSAGES:
        raise ValueError(f"a clouds spec of {spec.count(',') + 1} passages: at most {MAX_PASSAGES}")
    tz = timezone(timedelta(hours=utc_offset_h))
    passages = []
    items = [s.strip() for s in spec.split(",")]
    if items == [""]:
        return ()
    for n, item in enumerate(items, 1):
        where = f"clouds passage {n} ({item!r})"
        if not item:
            raise ValueError(f"{where}: empty; passages are TIME+DURATION@ATTENUATION separated by commas, "
                             f"e.g. '12:00+300s@0.9'")
        if item.count("+") != 1 or item.count("@") != 1 or item.index("+") > item.index("@"):
            raise ValueError(f"{where}: expected TIME+DURATION@ATTENUATION, e.g. '12:00+300s@0.9'")
        time_text, rest = (s.strip() for s in item.split("+"))
        duration_text, attenuation_text = (s.strip() for s in rest.split("@"))
        m = _TIME.match(time_text)
        if m is None:
            raise ValueError(f"{where}: time {time_text!r} is not HH:MM, HH:MM:SS or YYYY-MM-DDTHH:MM[:SS]")
        year, month, dom, hh, mm, ss = m.groups()
        try:
            on = date(int(year), int(month), int(dom)) if year else day
        except ValueError as exc:
            raise ValueError(f"{where}: date {time_text!r}: {exc}") from None
        hours, minutes, seconds = int(hh), int(mm), float(ss) if ss else 0.0
        if hours > 23 or minutes > 59 or seconds >= 60.0:
            raise ValueError(f"{where}: time {time_text!r} out of range (00:00 to 23:59:59)")
        start = datetime(on.year, on.month, on.day, tzinfo=tz) + timedelta(hours=hours, minutes=minutes,
                                                                            seconds=seconds)
        m = _DURATION.match(duration_text)
        if m is None:
            raise ValueError(f"{where}: duration {duration_text!r} needs a number and a unit s, m or h "
                             f"(e.g. 300s, 5m, 1.5h)")
        duration_s = float(m.group(1)) * _UNIT_S[m.group(2)]
        if not duration_s > 0:
            raise ValueError(f"{where}: duration must be > 0, got {duration_text!r}")
        try:
            attenuation = float(attenuation_text)
        except ValueError:
            raise ValueError(f"{where}: attenuation {attenuation_text!r} is not a number") from None
        if not 0.0 <= attenuation <= 1.0:
            raise ValueError(f"{where}: attenuation is the fraction of the direct beam removed, in [0, 1]; "
                             f"got {attenuation_text}")
        passages.append(CloudPassage(start, duration_s, attenuation))
    return tuple(passages)


class CloudSchedule:
    """Transmission of the direct beam over time: 1 in clear sky, the product of the passages' (1 - attenuation).

    Built from passages and an epoch; `transmission(t_s)` (seconds since the epoch) is a
    bisection in a precomputed piecewise-constant table. `start <= t < start + duration`
    is inside a passage.
    """

    def __init__(self, passages: Iterable[CloudPassage], epoch: DateTimeLike) -> None:
        passages = tuple(passages)
        for p in passages:
            if not isinstance(p, CloudPassage):
                raise ValueError(f"clouds must be CloudPassage items, got {p!r}")
        self.passages = passages
        epoch = to_utc(epoch)
        spans = [((p.start - epoch).total_seconds(), p.duration_s, 1.0 - p.attenuation) for p in passages]
        edges = sorted({t for s, d, _ in spans for t in (s, s + d)})
        self._edges = edges
        # Transmission on [edges[k], edges[k + 1]): product over the passages covering it.
        self._values = [1.0] + [math.prod([tr for s, d, tr in spans if s <= e < s + d]) for e in edges]
        self.epoch = epoch

    def transmission(self, t_s: float) -> float:
        """Fraction of the clear-sky direct beam getting through at `t_s` seconds after the epoch."""
        if not self._edges:
            return 1.0
        return self._values[bisect.bisect_right(self._edges, t_s)]


def as_clouds(clouds, start_utc: datetime, site: Site) -> tuple[CloudPassage, ...]:
    """Passages from None, a spec string (read on the start's local date at `site`) or CloudPassage items."""
    if clouds is None:
        return ()
    if isinstance(clouds, str):
        day = start_utc.astimezone(site.local_tz).date()
        return parse_clouds(clouds, day, site.utc_offset_h)
    try:
        items = tuple(clouds)
    except TypeError:
        raise ValueError(f"clouds must be None, a spec string or CloudPassage items, got {clouds!r}") from None
    for p in items:
        if not isinstance(p, CloudPassage):
            raise ValueError(f"clouds must be None, a spec string or CloudPassage items, got the item {p!r}")
    return items


__all__ = ["CHUNK_S", "CloudPassage", "CloudSchedule", "DEFAULT_START", "DEFAULT_TABLE_STEP_S", "MST", "Site",
           "SunTable", "TUCSON", "UTC", "as_clouds", "parse_clouds", "solar_position", "to_utc"]
