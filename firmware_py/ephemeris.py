"""The controller's own ephemeris: where the sun is, and how fast it moves, at a site and a UTC instant.

The solar tracker's feed-forward (`firmware_py/tracker/logic.py`) needs the sun's azimuth and
elevation rates, and telemetry reports the sun's position and the pointing error. A
controller carries no full SPA (the plant's, `hil_sim/spa.py`, over numpy, costs 3 ms an
instant; docs/Code_Overview.md says why the two suns are not one), so this is the NOAA solar
position algorithm, in plain floats: the equations of NOAA's Solar Calculator spreadsheets (NOAA Global Monitoring
Laboratory, "NOAA_Solar_Calculations_day.xls", after Jean Meeus, "Astronomical
Algorithms", 1991, chapters 24-25, low-accuracy solar coordinates). NOAA states them
accurate to within about a minute of arc (0.017 deg) for 1800-2100; `protocol` limits the
clock (SetClock) to 2000-2099. Against the NREL SPA (Reda and Andreas 2004, the plant's
sun, `hil_sim/spa.py`) at Tucson, hourly through 2026 with the sun above the horizon (4422
positions, the site's 928.8 hPa and 12 C), the two directions differ by at most 0.0147 deg
(elevation at most 0.0133 deg; azimuth up to 0.036 deg, near the zenith, where a degree of
azimuth is a small angle on the sky); over the June solstice the tests bound it (azimuth
0.02, elevation 0.01 deg: tests/test_tracker_control.py). On the SPA paper's own example
(2003-10-17 12:30:30 UTC-7, 39.742476 N 105.1786 W, 820 mbar, 11 C: zenith 50.11162 deg,
azimuth 194.34024 deg) it is within 0.005 deg.

What it leaves out, each far below the tracker's needs (its photocells' deadband is about
0.2 deg): the difference between UT and TT (delta T, 69 s in 2026: the sun moves 0.0008 deg
of longitude in it), nutation in longitude beyond NOAA's one term, and the topocentric
parallax (at most 8.8 arcsec, 0.0024 deg).

Refraction: the apparent elevation is the true one plus Bennett's refraction scaled for
the site's pressure and air temperature, as the SPA applies it (Reda and Andreas 2004,
eq. 42: (P/1010) (283/(273+T)) 1.02 / (60 tan(e + 10.3/(e + 5.11))) deg), while the
sun is above -0.8333 deg (its upper limb on a standard horizon); with pressure 0 no
refraction is applied. This is the direction the photocells see the sun in.

Conventions: azimuth from north through east (clockwise seen from above), 0..360 deg;
elevation above the horizon, deg; longitude east positive; time in POSIX seconds (UTC,
leap seconds ignored as POSIX does). Nothing here reads a clock: every instant is given.

Cost: about 15 us for one position; `sun_rates` takes two more. The tracker computes them
once a second and extrapolates in between (the rates change by less than 1e-5 deg/s in a
second).
"""
from __future__ import annotations

import math
from typing import NamedTuple

from protocol.units import DEG

UNIX_EPOCH_JD = 2440587.5        # Julian day of 1970-01-01 00:00 UTC
J2000_JD = 2451545.0             # Julian day of 2000-01-01 12:00 TT
RATE_STEP_S = 30.0               # half-width of the central difference in `sun_rates`


class SunPosition(NamedTuple):
    azimuth_deg: float           # from north through east, 0..360
    elevation_deg: float         # apparent (refracted), above the horizon
    true_elevation_deg: float    # geometric, without refraction
    declination_deg: float
    equation_of_time_min: float
    hour_angle_deg: float        # negative before local solar noon


def julian_day(unix_s: float) -> float:
    return unix_s / 86400.0 + UNIX_EPOCH_JD


def refraction_deg(true_elevation_deg: float, pressure_hpa: float = 1010.0, temperature_c: float = 10.0) -> float:
    """Bennett's refraction at `true_elevation_deg`, scaled to pressure and temperature (SPA eq. 42)."""
    e = true_elevation_deg
    if pressure_hpa <= 0.0 or e < -0.8333:
        return 0.0
    return (pressure_hpa / 1010.0) * (283.0 / (273.0 + temperature_c)) * 1.02 / (
        60.0 * math.tan((e + 10.3 / (e + 5.11)) * DEG))


def sun_position(unix_s: float, latitude_deg: float, longitude_deg: float, pressure_hpa: float = 1010.0,
                 temperature_c: float = 10.0) -> SunPosition:
    """The sun seen from (latitude, longitude) at POSIX time `unix_s` (NOAA's algorithm, see the module doc)."""
    jc = (julian_day(unix_s) - J2000_JD) / 36525.0                    # Julian centuries since J2000
    l0 = (280.46646 + jc * (36000.76983 + jc * 0.0003032)) % 360.0     # geometric mean longitude
    m = 357.52911 + jc * (35999.05029 - 0.0001537 * jc)               # geometric mean anomaly
    e = 0.016708634 - jc * (0.000042037 + 0.0000001267 * jc)          # Earth's orbital eccentricity
    m_r = m * DEG
    c = (math.sin(m_r) * (1.914602 - jc * (0.004817 + 0.000014 * jc))
         + math.sin(2 * m_r) * (0.019993 - 0.000101 * jc) + math.sin(3 * m_r) * 0.000289)  # equation of centre
    true_long = l0 + c
    omega = (125.04 - 1934.136 * jc) * DEG                             # longitude of the Moon's node
    app_long = true_long - 0.00569 - 0.00478 * math.sin(omega)         # apparent longitude
    mean_obliq = 23.0 + (26.0 + (21.448 - jc * (46.815 + jc * (0.00059 - jc * 0.001813))) / 60.0) / 60.0
    obliq = (mean_obliq + 0.00256 * math.cos(omega)) * DEG
    lam = app_long * DEG
    decl = math.asin(math.sin(obliq) * math.sin(lam))
    y = math.tan(obliq / 2.0) ** 2
    l0_r = l0 * DEG
    eot_min = 4.0 / DEG * (y * math.sin(2 * l0_r) - 2 * e * math.sin(m_r)
                           + 4 * e * y * math.sin(m_r) * math.cos(2 * l0_r)
                           - 0.5 * y * y * math.sin(4 * l0_r) - 1.25 * e * e * math.sin(2 * m_r))
    minutes_utc = (unix_s % 86400.0) / 60.0
    true_solar_min = (minutes_utc + eot_min + 4.0 * longitude_deg) % 1440.0
    hour_angle = true_solar_min / 4.0 - 180.0                          # -180..180, 0 at solar noon
    lat = latitude_deg * DEG
    h = hour_angle * DEG
    cos_zen = math.sin(lat) * math.sin(decl) + math.cos(lat) * math.cos(decl) * math.cos(h)
    zen = math.acos(max(-1.0, min(1.0, cos_zen)))
    # azimuth from north through east: atan2 of the east and north components of the sun's direction
    az = math.atan2(-math.cos(decl) * math.sin(h),
                    math.cos(lat) * math.sin(decl) - math.sin(lat) * math.cos(decl) * math.cos(h))
    azimuth = (az / DEG) % 360.0
    true_el = 90.0 - zen / DEG
    return SunPosition(azimuth, true_el + refraction_deg(true_el, pressure_hpa, temperature_c), true_el,
                       decl / DEG, eot_min, hour_angle)


def wrap180(angle_deg: float) -> float:
    """An angle in degrees wrapped to [-180, 180)."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def sun_rates(unix_s: float, latitude_deg: float, longitude_deg: float, pressure_hpa: float = 1010.0,
              temperature_c: float = 10.0) -> tuple[float, float]:
    """(azimuth rate, elevation rate) of the apparent sun [deg/s], by a central difference over +-30 s.

    The truncation error of the difference is below 1e-8 deg/s away from the zenith (the
    rates' second derivatives are tiny over a minute); refraction is included, so near the
    horizon the elevation rate is that of the refracted sun the photocells see.
    """
    a = sun_position(unix_s - RATE_STEP_S, latitude_deg, longitude_deg, pressure_hpa, temperature_c)
    b = sun_position(unix_s + RATE_STEP_S, latitude_deg, longitude_deg, pressure_hpa, temperature_c)
    span = 2.0 * RATE_STEP_S
    return wrap180(b.azimuth_deg - a.azimuth_deg) / span, (b.elevation_deg - a.elevation_deg) / span
