"""GNSS position for the filter's ``IN_POS`` columns: NED metres from the first fix, in the filter's frame.

The ESKF fuses the position of each fix beside its velocity (:mod:`mavahrs.filters.eskf`): the
position is north, east, down in metres relative to an *origin*, the first fix a reader or the
pipeline used (its latitude, longitude and altitude), on a local tangent plane (equirectangular,
WGS-84 radii of curvature at the origin: Groves, "Principles of GNSS, Inertial, and Multisensor
Integrated Navigation Systems", 2nd ed., eqs. (2.105)–(2.106) and (2.119); within 1 cm over a few km,
far below a receiver's noise), rotated from true into the filter's magnetic NED by the declination
as the velocity is (:func:`mavahrs.sensors.geomag.rotate_true_to_magnetic`).  Down is −(alt − alt₀);
NaN where the altitude is not given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["PositionOrigin", "WGS84_A_M", "WGS84_E2"]

#: WGS-84 semi-major axis, m, and first eccentricity squared
WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3


@dataclass
class PositionOrigin:
    """The first fix's latitude, longitude (deg) and altitude (m); later fixes as NED metres from it.

    ``set`` fixes the origin (the first call wins until :meth:`reset`); ``ned`` / ``ned_arrays``
    convert.  Radii of curvature at the origin's latitude φ₀: R_N = a(1−e²)/(1−e² sin²φ₀)^{3/2}
    (meridian), R_E = a/(1−e² sin²φ₀)^{1/2} (prime vertical); north = Δφ (R_N + h₀), east =
    Δλ (R_E + h₀) cos φ₀.
    """

    lat0_deg: float | None = None
    lon0_deg: float = 0.0
    alt0_m: float = math.nan

    @property
    def known(self) -> bool:
        return self.lat0_deg is not None

    def reset(self) -> None:
        """Forget the origin (an autopilot reboot: the next fix is the new origin)."""
        self.lat0_deg = None

    def set(self, lat_deg: float, lon_deg: float, alt_m: float) -> None:
        """Take this fix as the origin if none is set yet."""
        if self.lat0_deg is None and math.isfinite(lat_deg) and math.isfinite(lon_deg):
            self.lat0_deg, self.lon0_deg, self.alt0_m = float(lat_deg), float(lon_deg), float(alt_m)

    def _scales(self) -> tuple[float, float]:
        phi = math.radians(self.lat0_deg or 0.0)
        w = 1.0 - WGS84_E2 * math.sin(phi) ** 2
        h0 = self.alt0_m if math.isfinite(self.alt0_m) else 0.0
        r_n = WGS84_A_M * (1.0 - WGS84_E2) / w**1.5 + h0
        r_e = (WGS84_A_M / math.sqrt(w) + h0) * math.cos(phi)
        return math.radians(r_n), math.radians(r_e)  # m per degree

    def ned(self, lat_deg: float, lon_deg: float, alt_m: float, declination_rad: float | None) -> tuple[float, float, float]:
        """(north, east, down) m of a fix from the origin (set from it if none), magnetic NED when
        ``declination_rad`` is given (true NED when None); NaN without a latitude and longitude."""
        self.set(lat_deg, lon_deg, alt_m)
        if self.lat0_deg is None or not (math.isfinite(lat_deg) and math.isfinite(lon_deg)):
            return math.nan, math.nan, math.nan  # no position in this fix
        k_n, k_e = self._scales()
        n = (lat_deg - self.lat0_deg) * k_n
        dlon = (lon_deg - self.lon0_deg + 180.0) % 360.0 - 180.0
        e = dlon * k_e
        d = -(alt_m - self.alt0_m) if math.isfinite(alt_m) and math.isfinite(self.alt0_m) else math.nan
        if declination_rad is not None and declination_rad != 0.0:
            c, s = math.cos(declination_rad), math.sin(declination_rad)
            n, e = c * n + s * e, -s * n + c * e
        return n, e, d

    def ned_arrays(self, lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], alt_m: NDArray[np.float64],
                   declination_rad: NDArray[np.float64] | float | None) -> NDArray[np.float64]:
        """:meth:`ned` over arrays (the origin from the first element if none is set): (M, 3)."""
        if lat_deg.shape[0] == 0:
            return np.zeros((0, 3))
        self.set(float(lat_deg[0]), float(lon_deg[0]), float(alt_m[0]))
        k_n, k_e = self._scales()
        n = (np.asarray(lat_deg, np.float64) - self.lat0_deg) * k_n
        e = ((np.asarray(lon_deg, np.float64) - self.lon0_deg + 180.0) % 360.0 - 180.0) * k_e
        d = -(np.asarray(alt_m, np.float64) - self.alt0_m)
        if declination_rad is not None:
            dr = np.asarray(declination_rad, np.float64)
            c, s = np.cos(dr), np.sin(dr)
            n, e = c * n + s * e, -s * n + c * e
        return np.stack([n, e, d], 1)
