"""The sun's position by the NREL Solar Position Algorithm (SPA), over numpy arrays of instants.

Ibrahim Reda and Afshin Andreas, "Solar position algorithm for solar radiation applications", Solar
Energy 76 (2004) 577-589, and its corrigendum, Solar Energy 81 (2007) 838 (NREL/TP-560-34302): the
Earth's heliocentric position from the VSOP87 periodic terms of its tables A4.2, nutation from the 63
terms of table A4.3, then aberration, sidereal time, the topocentric parallax and Bennett's refraction.
Its stated uncertainty is +-0.0003 deg from year -2000 to 6000.

This is the plant's sun (hil_sim/sun.py): the truth the tracker's photocells see. Every operation
is the one pvlib-python's numpy SPA (`pvlib.solarposition.spa_python`, pvlib/spa.py, pvlib 0.16)
does, in its order, on numpy arrays and scalars of the same kinds, so the two agree to the bit
(tests/test_spa.py compares them over a year); the plant used pvlib until pvlib and pandas, a second
of import, were kept for the users who ask for them. The controller keeps its own, cheaper sun
(firmware_py/ephemeris.py: NOAA's low-accuracy algorithm in plain floats, 0.015 deg from this one),
as a real controller would: docs/Code_Overview.md says why the two are not one.

Conventions: time in POSIX seconds (UTC; leap seconds ignored as POSIX does); angles in degrees;
azimuth from north through east, 0..360; longitude east positive. Delta T (TT - UT1) is NASA's
polynomial for the instant's year and month (Espenak and Meeus, eclipse.gsfc.nasa.gov
SEcat5/deltatpoly.html, as pvlib takes it) unless given.
"""
from __future__ import annotations

from typing import NamedTuple, Optional, Union

import numpy as np

ArrayLike = Union[float, np.ndarray]
UNIX_EPOCH_JD = 2440587.5           # Julian day of 1970-01-01 00:00 UTC
J2000_JD = 2451545                  # Julian day of 2000-01-01 12:00 TT
ATMOS_REFRACT_DEG = 0.5667          # refraction at sunrise and sunset: below -(0.26667 + this), none applied

# The Earth's periodic terms (Reda and Andreas, table A4.2): rows (A, B, C) of A cos(B + C tau), tau in
# Julian ephemeris millennia; L heliocentric longitude, B latitude, R radius vector, each a series in tau.
L0 = (
    (175347046.0, 0.0, 0.0), (3341656.0, 4.6692568, 6283.07585), (34894.0, 4.6261, 12566.1517),
    (3497.0, 2.7441, 5753.3849), (3418.0, 2.8289, 3.5231), (3136.0, 3.6277, 77713.7715),
    (2676.0, 4.4181, 7860.4194), (2343.0, 6.1352, 3930.2097), (1324.0, 0.7425, 11506.7698),
    (1273.0, 2.0371, 529.691), (1199.0, 1.1096, 1577.3435), (990.0, 5.233, 5884.927), (902.0, 2.045, 26.298),
    (857.0, 3.508, 398.149), (780.0, 1.179, 5223.694), (753.0, 2.533, 5507.553), (505.0, 4.583, 18849.228),
    (492.0, 4.205, 775.523), (357.0, 2.92, 0.067), (317.0, 5.849, 11790.629), (284.0, 1.899, 796.298),
    (271.0, 0.315, 10977.079), (243.0, 0.345, 5486.778), (206.0, 4.806, 2544.314), (205.0, 1.869, 5573.143),
    (202.0, 2.458, 6069.777), (156.0, 0.833, 213.299), (132.0, 3.411, 2942.463), (126.0, 1.083, 20.775),
    (115.0, 0.645, 0.98), (103.0, 0.636, 4694.003), (102.0, 0.976, 15720.839), (102.0, 4.267, 7.114),
    (99.0, 6.21, 2146.17), (98.0, 0.68, 155.42), (86.0, 5.98, 161000.69), (85.0, 1.3, 6275.96),
    (85.0, 3.67, 71430.7), (80.0, 1.81, 17260.15), (79.0, 3.04, 12036.46), (75.0, 1.76, 5088.63),
    (74.0, 3.5, 3154.69), (74.0, 4.68, 801.82), (70.0, 0.83, 9437.76), (62.0, 3.98, 8827.39), (61.0, 1.82, 7084.9),
    (57.0, 2.78, 6286.6), (56.0, 4.39, 14143.5), (56.0, 3.47, 6279.55), (52.0, 0.19, 12139.55),
    (52.0, 1.33, 1748.02), (51.0, 0.28, 5856.48), (49.0, 0.49, 1194.45), (41.0, 5.37, 8429.24),
    (41.0, 2.4, 19651.05), (39.0, 6.17, 10447.39), (37.0, 6.04, 10213.29), (37.0, 2.57, 1059.38),
    (36.0, 1.71, 2352.87), (36.0, 1.78, 6812.77), (33.0, 0.59, 17789.85), (30.0, 0.44, 83996.85),
    (30.0, 2.74, 1349.87), (25.0, 3.16, 4690.48),
)
L1 = (
    (628331966747.0, 0.0, 0.0), (206059.0, 2.678235, 6283.07585), (4303.0, 2.6351, 12566.1517),
    (425.0, 1.59, 3.523), (119.0, 5.796, 26.298), (109.0, 2.966, 1577.344), (93.0, 2.59, 18849.23),
    (72.0, 1.14, 529.69), (68.0, 1.87, 398.15), (67.0, 4.41, 5507.55), (59.0, 2.89, 5223.69), (56.0, 2.17, 155.42),
    (45.0, 0.4, 796.3), (36.0, 0.47, 775.52), (29.0, 2.65, 7.11), (21.0, 5.34, 0.98), (19.0, 1.85, 5486.78),
    (19.0, 4.97, 213.3), (17.0, 2.99, 6275.96), (16.0, 0.03, 2544.31), (16.0, 1.43, 2146.17),
    (15.0, 1.21, 10977.08), (12.0, 2.83, 1748.02), (12.0, 3.26, 5088.63), (12.0, 5.27, 1194.45),
    (12.0, 2.08, 4694.0), (11.0, 0.77, 553.57), (10.0, 1.3, 6286.6), (10.0, 4.24, 1349.87), (9.0, 2.7, 242.73),
    (9.0, 5.64, 951.72), (8.0, 5.3, 2352.87), (6.0, 2.65, 9437.76), (6.0, 4.67, 4690.48),
)
L2 = (
    (52919.0, 0.0, 0.0), (8720.0, 1.0721, 6283.0758), (309.0, 0.867, 12566.152), (27.0, 0.05, 3.52),
    (16.0, 5.19, 26.3), (16.0, 3.68, 155.42), (10.0, 0.76, 18849.23), (9.0, 2.06, 77713.77), (7.0, 0.83, 775.52),
    (5.0, 4.66, 1577.34), (4.0, 1.03, 7.11), (4.0, 3.44, 5573.14), (3.0, 5.14, 796.3), (3.0, 6.05, 5507.55),
    (3.0, 1.19, 242.73), (3.0, 6.12, 529.69), (3.0, 0.31, 398.15), (3.0, 2.28, 553.57), (2.0, 4.38, 5223.69),
    (2.0, 3.75, 0.98),
)
L3 = (
    (289.0, 5.844, 6283.076), (35.0, 0.0, 0.0), (17.0, 5.49, 12566.15), (3.0, 5.2, 155.42), (1.0, 4.72, 3.52),
    (1.0, 5.3, 18849.23), (1.0, 5.97, 242.73),
)
L4 = (
    (114.0, 3.142, 0.0), (8.0, 4.13, 6283.08), (1.0, 3.84, 12566.15),
)
L5 = (
    (1.0, 3.14, 0.0),
)
B0 = (
    (280.0, 3.199, 84334.662), (102.0, 5.422, 5507.553), (80.0, 3.88, 5223.69), (44.0, 3.7, 2352.87),
    (32.0, 4.0, 1577.34),
)
B1 = (
    (9.0, 3.9, 5507.55), (6.0, 1.73, 5223.69),
)
R0 = (
    (100013989.0, 0.0, 0.0), (1670700.0, 3.0984635, 6283.07585), (13956.0, 3.05525, 12566.1517),
    (3084.0, 5.1985, 77713.7715), (1628.0, 1.1739, 5753.3849), (1576.0, 2.8469, 7860.4194),
    (925.0, 5.453, 11506.77), (542.0, 4.564, 3930.21), (472.0, 3.661, 5884.927), (346.0, 0.964, 5507.553),
    (329.0, 5.9, 5223.694), (307.0, 0.299, 5573.143), (243.0, 4.273, 11790.629), (212.0, 5.847, 1577.344),
    (186.0, 5.022, 10977.079), (175.0, 3.012, 18849.228), (110.0, 5.055, 5486.778), (98.0, 0.89, 6069.78),
    (86.0, 5.69, 15720.84), (86.0, 1.27, 161000.69), (65.0, 0.27, 17260.15), (63.0, 0.92, 529.69),
    (57.0, 2.01, 83996.85), (56.0, 5.24, 71430.7), (49.0, 3.25, 2544.31), (47.0, 2.58, 775.52),
    (45.0, 5.54, 9437.76), (43.0, 6.01, 6275.96), (39.0, 5.36, 4694.0), (38.0, 2.39, 8827.39),
    (37.0, 0.83, 19651.05), (37.0, 4.9, 12139.55), (36.0, 1.67, 12036.46), (35.0, 1.84, 2942.46),
    (33.0, 0.24, 7084.9), (32.0, 0.18, 5088.63), (32.0, 1.78, 398.15), (28.0, 1.21, 6286.6), (28.0, 1.9, 6279.55),
    (26.0, 4.59, 10447.39),
)
R1 = (
    (103019.0, 1.10749, 6283.07585), (1721.0, 1.0644, 12566.1517), (702.0, 3.142, 0.0), (32.0, 1.02, 18849.23),
    (31.0, 2.84, 5507.55), (25.0, 1.32, 5223.69), (18.0, 1.42, 1577.34), (10.0, 5.91, 10977.08),
    (9.0, 1.42, 6275.96), (9.0, 0.27, 5486.78),
)
R2 = (
    (4359.0, 5.7846, 6283.0758), (124.0, 5.579, 12566.152), (12.0, 3.14, 0.0), (9.0, 3.63, 77713.77),
    (6.0, 1.87, 5573.14), (3.0, 5.47, 18849.23),
)
R3 = (
    (145.0, 4.273, 6283.076), (7.0, 3.92, 12566.15),
)
R4 = (
    (4.0, 2.56, 6283.08),
)
# Nutation in longitude and obliquity (table A4.3): rows (Y0..Y4, a, b, c, d), the Y multipliers of the
# Moon's and the Sun's mean arguments X0..X4, delta psi += (a + b JCE) sin(arg), delta epsilon += (c + d JCE) cos(arg).
NUTATION = (
    (0, 0, 0, 0, 1, -171996.0, -174.2, 92025.0, 8.9), (-2, 0, 0, 2, 2, -13187.0, -1.6, 5736.0, -3.1),
    (0, 0, 0, 2, 2, -2274.0, -0.2, 977.0, -0.5), (0, 0, 0, 0, 2, 2062.0, 0.2, -895.0, 0.5),
    (0, 1, 0, 0, 0, 1426.0, -3.4, 54.0, -0.1), (0, 0, 1, 0, 0, 712.0, 0.1, -7.0, 0.0),
    (-2, 1, 0, 2, 2, -517.0, 1.2, 224.0, -0.6), (0, 0, 0, 2, 1, -386.0, -0.4, 200.0, 0.0),
    (0, 0, 1, 2, 2, -301.0, 0.0, 129.0, -0.1), (-2, -1, 0, 2, 2, 217.0, -0.5, -95.0, 0.3),
    (-2, 0, 1, 0, 0, -158.0, 0.0, 0.0, 0.0), (-2, 0, 0, 2, 1, 129.0, 0.1, -70.0, 0.0),
    (0, 0, -1, 2, 2, 123.0, 0.0, -53.0, 0.0), (2, 0, 0, 0, 0, 63.0, 0.0, 0.0, 0.0),
    (0, 0, 1, 0, 1, 63.0, 0.1, -33.0, 0.0), (2, 0, -1, 2, 2, -59.0, 0.0, 26.0, 0.0),
    (0, 0, -1, 0, 1, -58.0, -0.1, 32.0, 0.0), (0, 0, 1, 2, 1, -51.0, 0.0, 27.0, 0.0),
    (-2, 0, 2, 0, 0, 48.0, 0.0, 0.0, 0.0), (0, 0, -2, 2, 1, 46.0, 0.0, -24.0, 0.0),
    (2, 0, 0, 2, 2, -38.0, 0.0, 16.0, 0.0), (0, 0, 2, 2, 2, -31.0, 0.0, 13.0, 0.0),
    (0, 0, 2, 0, 0, 29.0, 0.0, 0.0, 0.0), (-2, 0, 1, 2, 2, 29.0, 0.0, -12.0, 0.0),
    (0, 0, 0, 2, 0, 26.0, 0.0, 0.0, 0.0), (-2, 0, 0, 2, 0, -22.0, 0.0, 0.0, 0.0),
    (0, 0, -1, 2, 1, 21.0, 0.0, -10.0, 0.0), (0, 2, 0, 0, 0, 17.0, -0.1, 0.0, 0.0),
    (2, 0, -1, 0, 1, 16.0, 0.0, -8.0, 0.0), (-2, 2, 0, 2, 2, -16.0, 0.1, 7.0, 0.0),
    (0, 1, 0, 0, 1, -15.0, 0.0, 9.0, 0.0), (-2, 0, 1, 0, 1, -13.0, 0.0, 7.0, 0.0),
    (0, -1, 0, 0, 1, -12.0, 0.0, 6.0, 0.0), (0, 0, 2, -2, 0, 11.0, 0.0, 0.0, 0.0),
    (2, 0, -1, 2, 1, -10.0, 0.0, 5.0, 0.0), (2, 0, 1, 2, 2, -8.0, 0.0, 3.0, 0.0),
    (0, 1, 0, 2, 2, 7.0, 0.0, -3.0, 0.0), (-2, 1, 1, 0, 0, -7.0, 0.0, 0.0, 0.0),
    (0, -1, 0, 2, 2, -7.0, 0.0, 3.0, 0.0), (2, 0, 0, 2, 1, -7.0, 0.0, 3.0, 0.0),
    (2, 0, 1, 0, 0, 6.0, 0.0, 0.0, 0.0), (-2, 0, 2, 2, 2, 6.0, 0.0, -3.0, 0.0),
    (-2, 0, 1, 2, 1, 6.0, 0.0, -3.0, 0.0), (2, 0, -2, 0, 1, -6.0, 0.0, 3.0, 0.0),
    (2, 0, 0, 0, 1, -6.0, 0.0, 3.0, 0.0), (0, -1, 1, 0, 0, 5.0, 0.0, 0.0, 0.0),
    (-2, -1, 0, 2, 1, -5.0, 0.0, 3.0, 0.0), (-2, 0, 0, 0, 1, -5.0, 0.0, 3.0, 0.0),
    (0, 0, 2, 2, 1, -5.0, 0.0, 3.0, 0.0), (-2, 0, 2, 0, 1, 4.0, 0.0, 0.0, 0.0),
    (-2, 1, 0, 2, 1, 4.0, 0.0, 0.0, 0.0), (0, 0, 1, -2, 0, 4.0, 0.0, 0.0, 0.0),
    (-1, 0, 1, 0, 0, -4.0, 0.0, 0.0, 0.0), (-2, 1, 0, 0, 0, -4.0, 0.0, 0.0, 0.0),
    (1, 0, 0, 0, 0, -4.0, 0.0, 0.0, 0.0), (0, 0, 1, 2, 0, 3.0, 0.0, 0.0, 0.0),
    (0, 0, -2, 2, 2, -3.0, 0.0, 0.0, 0.0), (-1, -1, 1, 0, 0, -3.0, 0.0, 0.0, 0.0),
    (0, 1, 1, 0, 0, -3.0, 0.0, 0.0, 0.0), (0, -1, 1, 2, 2, -3.0, 0.0, 0.0, 0.0),
    (2, -1, -1, 2, 2, -3.0, 0.0, 0.0, 0.0), (0, 0, 3, 2, 2, -3.0, 0.0, 0.0, 0.0),
    (2, -1, 0, 2, 2, -3.0, 0.0, 0.0, 0.0),
)

EARTH_L = (L0, L1, L2, L3, L4, L5)
EARTH_B = (B0, B1)
EARTH_R = (R0, R1, R2, R3, R4)


class SunPositions(NamedTuple):
    """Arrays in degrees, one value per instant."""
    apparent_zenith: np.ndarray     # topocentric, with refraction
    zenith: np.ndarray              # topocentric, geometric
    apparent_elevation: np.ndarray
    elevation: np.ndarray
    azimuth: np.ndarray             # from north through east, 0..360


def delta_t_s(year: np.ndarray, month: np.ndarray) -> np.ndarray:
    """TT - UT1 [s] for each (year, month), NASA's polynomials (Espenak and Meeus) for 1986 to 2149 and beyond.

    ValueError before 1986: the plant's clock starts in 2000 (SetClock's range), and the older polynomials
    are left out.
    """
    year = np.asarray(year)
    month = np.asarray(month)
    if np.any(year < 1986):
        raise ValueError(f"delta T is modelled from 1986 on, got the year {int(np.min(year))}")
    y = year + (month - 0.5) / 12
    deltat = np.where(year >= 2150, -20 + 32 * ((y - 1820) / 100) ** 2, 0)
    deltat = np.where((2050 <= year) & (year < 2150), -20 + 32 * ((y - 1820) / 100) ** 2 - 0.5628 * (2150 - y),
                      deltat)
    deltat = np.where((2005 <= year) & (year < 2050), 62.92 + 0.32217 * (y - 2000) + 0.005589 * (y - 2000) ** 2,
                      deltat)
    return np.where((1986 <= year) & (year < 2005),
                    63.86 + 0.3345 * (y - 2000) - 0.060374 * (y - 2000) ** 2 + 0.0017275 * (y - 2000) ** 3
                    + 0.000651814 * (y - 2000) ** 4 + 0.00002373599 * (y - 2000) ** 5, deltat)


def utc_year_month(unix_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The UTC calendar year and month (1..12) of each POSIX instant."""
    days = np.floor(np.asarray(unix_s, dtype=float) / 86400.0).astype("datetime64[D]")
    months = days.astype("datetime64[M]").astype(np.int64)
    return months // 12 + 1970, months % 12 + 1


def _series(terms, x: np.ndarray):
    """sum of A cos(B + C x) over the rows, in their order."""
    s = 0.
    for a, b, c in terms:
        s += a * np.cos(b + c * x)
    return s


def sun_positions(unix_s: np.ndarray, latitude_deg: float, longitude_deg: float, altitude_m: float,
                  pressure_hpa: float, temperature_c: float, delta_t: Optional[ArrayLike] = None) -> SunPositions:
    """The sun seen from the site at each POSIX instant of `unix_s` (a float64 array), by the SPA.

    `pressure_hpa` and `temperature_c` set the refraction (SPA eq. 42); `delta_t` TT - UT1 in seconds, a
    number or one per instant; None: `delta_t_s` of each instant's year and month.
    """
    unix_s = np.asarray(unix_s, dtype=np.float64)
    if delta_t is None:
        delta_t = delta_t_s(*utc_year_month(unix_s))
    lat, lon, elev = latitude_deg, longitude_deg, altitude_m
    # Julian days, centuries and millennia (eqs. 4-7).
    jd = unix_s * 1.0 / 86400 + UNIX_EPOCH_JD
    jde = jd + delta_t * 1.0 / 86400
    jc = (jd - J2000_JD) * 1.0 / 36525
    jce = (jde - J2000_JD) * 1.0 / 36525
    jme = jce * 1.0 / 10
    # The Earth's heliocentric longitude, latitude and radius vector (eqs. 9-12), geocentric (13-14).
    lo = [_series(terms, jme) for terms in EARTH_L]
    big_l = np.rad2deg((lo[0] + lo[1] * jme + lo[2] * jme**2 + lo[3] * jme**3 + lo[4] * jme**4
                        + lo[5] * jme**5) / 10**8) % 360
    la = [_series(terms, jme) for terms in EARTH_B]
    big_b = np.rad2deg((la[0] + la[1] * jme) / 10**8)
    ra = [_series(terms, jme) for terms in EARTH_R]
    r = (ra[0] + ra[1] * jme + ra[2] * jme**2 + ra[3] * jme**3 + ra[4] * jme**4) / 10**8
    theta = (big_l + 180.0) % 360
    beta = -1.0 * big_b
    # Nutation (eqs. 15-23): the mean elongation of the Moon, the anomalies of the Sun and the Moon, the Moon's
    # argument of latitude and the longitude of its ascending node.
    x0 = 297.85036 + 445267.111480 * jce - 0.0019142 * jce**2 + jce**3 / 189474
    x1 = 357.52772 + 35999.050340 * jce - 0.0001603 * jce**2 - jce**3 / 300000
    x2 = 134.96298 + 477198.867398 * jce + 0.0086972 * jce**2 + jce**3 / 56250
    x3 = 93.27191 + 483202.017538 * jce - 0.0036825 * jce**2 + jce**3 / 327270
    x4 = 125.04452 - 1934.136261 * jce + 0.0020708 * jce**2 + jce**3 / 450000
    delta_psi_sum = 0.0
    delta_eps_sum = 0.0
    for y0, y1, y2, y3, y4, a, b, c, d in NUTATION:
        arg = np.radians(y0 * x0 + y1 * x1 + y2 * x2 + y3 * x3 + y4 * x4)
        delta_psi_sum += (a + b * jce) * np.sin(arg)
        delta_eps_sum += (c + d * jce) * np.cos(arg)
    delta_psi = delta_psi_sum * 1.0 / 36000000
    delta_eps = delta_eps_sum * 1.0 / 36000000
    # The true obliquity of the ecliptic (eqs. 24-25), aberration (26), the apparent sun's longitude (27).
    u = 1.0 * jme / 10
    e0 = (84381.448 - 4680.93 * u - 1.55 * u**2 + 1999.25 * u**3 - 51.38 * u**4 - 249.67 * u**5 - 39.05 * u**6
          + 7.12 * u**7 + 27.87 * u**8 + 5.79 * u**9 + 2.45 * u**10)
    epsilon = e0 * 1.0 / 3600 + delta_eps
    lamd = theta + delta_psi + -20.4898 / (3600 * r)
    # Sidereal time at Greenwich (eqs. 28-29), the sun's geocentric right ascension and declination (30-31).
    v0 = (280.46061837 + 360.98564736629 * (jd - J2000_JD) + 0.000387933 * jc**2 - jc**3 / 38710000) % 360.0
    v = v0 + delta_psi * np.cos(np.radians(epsilon))
    epsilon_rad = np.radians(epsilon)
    lamd_rad = np.radians(lamd)
    alpha = np.degrees(np.arctan2(np.sin(lamd_rad) * np.cos(epsilon_rad)
                                  - np.tan(np.radians(beta)) * np.sin(epsilon_rad), np.cos(lamd_rad))) % 360
    beta_rad = np.radians(beta)
    delta = np.degrees(np.arcsin(np.sin(beta_rad) * np.cos(epsilon_rad)
                                 + np.cos(beta_rad) * np.sin(epsilon_rad) * np.sin(np.radians(lamd))))
    # The local hour angle (32), the topocentric parallax (33-38).
    h = (v + lon - alpha) % 360
    xi = 8.794 / (3600 * r)
    u_term = np.arctan(0.99664719 * np.tan(np.radians(lat)))
    x = np.cos(u_term) + elev / 6378140 * np.cos(np.radians(lat))
    y = 0.99664719 * np.sin(u_term) + elev / 6378140 * np.sin(np.radians(lat))
    xi_rad = np.radians(xi)
    h_rad = np.radians(h)
    delta_alpha = np.degrees(np.arctan2(-x * np.sin(xi_rad) * np.sin(h_rad),
                                        np.cos(np.radians(delta)) - x * np.sin(xi_rad) * np.cos(h_rad)))
    delta_rad = np.radians(delta)
    delta_prime = np.degrees(np.arctan2((np.sin(delta_rad) - y * np.sin(xi_rad)) * np.cos(np.radians(delta_alpha)),
                                        np.cos(delta_rad) - x * np.sin(xi_rad) * np.cos(np.radians(h))))
    h_prime = h - delta_alpha
    # The topocentric elevation (39-41), with refraction above the horizon (42-43), and azimuth (44-46).
    lat_rad = np.radians(lat)
    delta_prime_rad = np.radians(delta_prime)
    e0 = np.degrees(np.arcsin(np.sin(lat_rad) * np.sin(delta_prime_rad)
                              + np.cos(lat_rad) * np.cos(delta_prime_rad) * np.cos(np.radians(h_prime))))
    above = e0 >= -1.0 * (0.26667 + ATMOS_REFRACT_DEG)
    delta_e = ((pressure_hpa / 1010.0) * (283.0 / (273 + temperature_c))
               * 1.02 / (60 * np.tan(np.radians(e0 + 10.3 / (e0 + 5.11))))) * above
    e = e0 + delta_e
    h_prime_rad = np.radians(h_prime)
    gamma = np.degrees(np.arctan2(np.sin(h_prime_rad), np.cos(h_prime_rad) * np.sin(lat_rad)
                                  - np.tan(np.radians(delta_prime)) * np.cos(lat_rad))) % 360
    return SunPositions(90 - e, 90 - e0, e, e0, (gamma + 180) % 360)


__all__ = ["SunPositions", "delta_t_s", "sun_positions", "utc_year_month"]
