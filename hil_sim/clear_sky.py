"""The clear-sky beam at a site: the Ineichen-Perez model, with the inputs it needs, over numpy arrays.

The direct normal (DNI) and diffuse horizontal (DHI) irradiance under a cloudless sky, from the sun's
apparent zenith (hil_sim/spa.py), the air mass, the monthly Linke turbidity and the extraterrestrial
beam: P. Ineichen and R. Perez, "A new airmass independent formulation for the Linke turbidity
coefficient", Solar Energy 73 (2002) 151-157; the air mass of F. Kasten and A. T. Young, "Revised
optical air mass tables and approximation formula", Applied Optics 28 (1989) 4735-4738; the
extraterrestrial beam of J. W. Spencer, "Fourier series representation of the position of the sun",
Search 2 (1971) 172; the pressure of the standard atmosphere at an altitude.

As hil_sim/spa.py, every operation is pvlib-python's (pvlib 0.16: `clearsky.ineichen`,
`clearsky.lookup_linke_turbidity`, `atmosphere.alt2pres`, `get_relative_airmass('kastenyoung1989')`,
`get_absolute_airmass`, `irradiance.get_extra_radiation('spencer')`), in its order, so the beam is
pvlib's to the bit (tests/test_spa.py). The Linke turbidity is SoDa's worldwide monthly table
(J. Remund et al., "Worldwide Linke turbidity information", ISES Solar World Congress 2003), which
pvlib ships as a 100 MB HDF5 file: a site carries its twelve values (`hil_sim.sun.Site`, Tucson's
are written there); `lookup_monthly_turbidity_x20` reads them from pvlib's file for any other site.
"""
from __future__ import annotations

import calendar
from typing import Sequence

import numpy as np

SOLAR_CONSTANT_W_M2 = 1366.1        # pvlib's default for Spencer's extraterrestrial beam


def standard_pressure_pa(altitude_m: float) -> float:
    """The standard atmosphere's pressure at `altitude_m` [Pa] (pvlib `alt2pres`)."""
    return 100 * ((44331.514 - altitude_m) / 11880.516) ** (1 / 0.1902632)


def absolute_airmass(apparent_zenith_deg: np.ndarray, pressure_pa: float) -> np.ndarray:
    """Kasten and Young's relative air mass at the pressure `pressure_pa`; NaN with the sun below the horizon."""
    z = np.where(apparent_zenith_deg > 90, np.nan, apparent_zenith_deg)
    relative = 1.0 / (np.cos(np.radians(z)) + 0.50572 * ((6.07995 + (90 - z)) ** - 1.6364))
    return relative * pressure_pa / 101325.


def utc_day_of_year(unix_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(day of the year 1..366, whether the year is a leap year) of each POSIX instant, in UTC."""
    days = np.floor(np.asarray(unix_s, dtype=float) / 86400.0).astype(np.int64).astype("datetime64[D]")
    years = days.astype("datetime64[Y]")
    year = years.astype(np.int64) + 1970
    leap = (year % 4 == 0) & ((year % 100 != 0) | (year % 400 == 0))
    return (days - years.astype("datetime64[D]")).astype(np.int64) + 1, leap


def extraterrestrial_dni(day_of_year: np.ndarray) -> np.ndarray:
    """The beam above the atmosphere [W/m^2] on each day of the year (Spencer's Earth-Sun distance)."""
    b = (2. * np.pi / 365.) * (day_of_year - 1)
    return SOLAR_CONSTANT_W_M2 * (1.00011 + 0.034221 * np.cos(b) + 0.00128 * np.sin(b) + 0.000719 * np.cos(2 * b)
                                  + 7.7e-05 * np.sin(2 * b))


def _month_middles(year: int) -> np.ndarray:
    """The day of the year of each month's middle, with last December's and next January's at either end."""
    mdays = np.array(calendar.mdays[1:])
    ydays = 365
    if calendar.isleap(year):
        mdays[1] = mdays[1] + 1
        ydays = 366
    return np.concatenate([[-calendar.mdays[-1] / 2.0], np.cumsum(mdays) - np.array(mdays) / 2.,
                           [ydays + calendar.mdays[1] / 2.0]])


def linke_turbidity(day_of_year: np.ndarray, leap: np.ndarray, monthly_x20: Sequence[int]) -> np.ndarray:
    """The Linke turbidity on each day, interpolated between the months' middles from the twelve monthly
    values (`monthly_x20`: January to December, times 20, as SoDa's table stores them)."""
    lts = np.array(monthly_x20, dtype=np.uint8)
    lts_concat = np.concatenate([[lts[-1]], lts, [lts[0]]])
    in_leap = np.interp(day_of_year, _month_middles(2016), lts_concat)
    in_common = np.interp(day_of_year, _month_middles(2015), lts_concat)
    return np.where(leap, in_leap, in_common) / 20.


def ineichen(apparent_zenith_deg: np.ndarray, airmass: np.ndarray, turbidity: np.ndarray, altitude_m: float,
             dni_extra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(DNI, DHI) [W/m^2] of the clear sky (Ineichen and Perez, without Perez's enhancement factor); NaN where
    the air mass is (the sun below the horizon)."""
    with np.errstate(divide="ignore", invalid="ignore"):     # the sun on the horizon, cos zenith 0, as pandas did
        return _ineichen(apparent_zenith_deg, airmass, turbidity, altitude_m, dni_extra)


def _ineichen(apparent_zenith_deg, airmass, turbidity, altitude_m, dni_extra):
    cos_zenith = np.maximum(np.cos(np.radians(apparent_zenith_deg)), 0)
    tl = turbidity
    fh1 = np.exp(-altitude_m / 8000.)
    fh2 = np.exp(-altitude_m / 1250.)
    cg1 = 5.09e-05 * altitude_m + 0.868
    cg2 = 3.92e-05 * altitude_m + 0.0387
    ghi = np.exp(-cg2 * airmass * (fh1 + fh2 * (tl - 1)))
    ghi = cg1 * dni_extra * cos_zenith * tl / tl * np.fmax(ghi, 0)
    b = 0.664 + 0.163 / fh1
    bnci = dni_extra * np.fmax(b * np.exp(-0.09 * airmass * (tl - 1)), 0)
    bnci_2 = ghi * np.fmin(np.fmax((1 - (0.1 - 0.2 * np.exp(-tl)) / (0.1 + 0.882 / fh1)) / cos_zenith, 0), 1e20)
    dni = np.minimum(bnci, bnci_2)
    return dni, ghi - dni * cos_zenith


def lookup_monthly_turbidity_x20(latitude_deg: float, longitude_deg: float) -> tuple[int, ...]:
    """The twelve monthly Linke turbidities (times 20) of the site's cell in SoDa's table, from pvlib's copy of
    it: pvlib, pandas and h5py are imported here, for a site that does not carry its values (the `reference` extra:
    MissingExtra without it)."""
    from kernels.extras import require
    require("reference", "pvlib", "pandas", what="the Linke turbidity of a site without its own (pvlib's table)")
    import pandas as pd
    import pvlib
    months = pd.DatetimeIndex([f"2015-{m:02d}-15" for m in range(1, 13)], tz="UTC")
    values = pvlib.clearsky.lookup_linke_turbidity(months, latitude_deg, longitude_deg, interp_turbidity=False)
    return tuple(int(round(float(v) * 20)) for v in values)


__all__ = ["SOLAR_CONSTANT_W_M2", "absolute_airmass", "extraterrestrial_dni", "ineichen", "linke_turbidity",
           "lookup_monthly_turbidity_x20", "standard_pressure_pa", "utc_day_of_year"]
