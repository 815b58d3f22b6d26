r"""The Earth's magnetic field where the vehicle is, and true-north attitudes.

A magnetometer points to *magnetic* north; MAVLink, ArduPilot and PX4 report
yaw from *true* north.  The angle between them, the declination D (positive
east: magnetic north lies D east of true north), is 12° or more in many places,
so an uncorrected 9-axis filter is wrong in heading by D whatever its quality.

This module gives

* :func:`expected_field` — declination, inclination and strength of the main
  field from the **World Magnetic Model** at a position and date, through the
  ``pygeomag`` package (a pure-Python port of NOAA's WMM C code that bundles
  the coefficient files WMM2010 … WMM2025, so it works offline and dates back
  to 2010 for replaying old logs);
* :func:`apply_declination` / :func:`apply_declination_wxyz` — turn a
  ``q_body_to_ned`` referenced to magnetic north (what the filters estimate)
  into one referenced to true north: ``q_true = R_z(D) ⊗ q_mag``;
  :func:`rotate_true_to_magnetic` — the inverse rotation for NED vectors the
  filters consume (GNSS velocity is true-north referenced);
* :class:`MagneticFieldSettings` — manual declination / field / position for
  vehicles without GPS;
* :class:`DeclinationSource` — stateful but pure (no clock, no I/O): consumes
  GLOBAL_POSITION_INT, GPS_RAW_INT, HOME_POSITION and SYSTEM_TIME messages and
  recomputes the WMM field only when the vehicle has moved more than
  ``update_distance_km`` (or the date changed by a month), not per sample.

The WMM is a model of the core field: its stated global RMS error is about
0.3–0.4° in declination away from the magnetic poles (NOAA, WMM2025 report);
local crustal anomalies and the vehicle's own field are not in it.  Heights
are taken as metres above the WGS-84 ellipsoid; MAVLink gives mean sea level,
and the difference (geoid, < 110 m) changes the field by a few nT — negligible.
See ``docs/navigation.md``.
"""

from __future__ import annotations

import datetime as _dt
import logging
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.filters.gains import GainScheduleSettings

__all__ = [
    "ExpectedField",
    "expected_field",
    "field_from_angles",
    "apply_declination",
    "apply_declination_wxyz",
    "rotate_true_to_magnetic",
    "decimal_year_from_unix_s",
    "distance_km",
    "MagneticFieldSettings",
    "DeclinationSource",
    "WMM_FIRST_YEAR",
    "WMM_END_YEAR",
]

_log = logging.getLogger(__name__)
#: (model, date) pairs already warned about as outside the model's span (:func:`expected_field`)
_WARNED_OUTSIDE: set[tuple[str, float]] = set()

Array = NDArray[np.float64]

#: Years covered by the coefficient files bundled with pygeomag.
WMM_FIRST_YEAR = 2010.0
WMM_END_YEAR = 2030.0

_NT_PER_UT = 1000.0
_EARTH_RADIUS_KM = 6371.0088  # IUGG mean radius, for distances between fixes


@dataclass(frozen=True)
class ExpectedField:
    """The geomagnetic main field at one place and time.

    Attributes:
        declination_rad: D, angle from true north to the horizontal field,
            positive east.
        inclination_rad: I (dip), angle of the field below the horizontal,
            positive downward (northern hemisphere).
        strength_ut: total intensity F, µT.
        north_east_down_ut: the field vector in (true) NED, µT.
        source: where it came from, e.g. ``"WMM-2025"`` or ``"manual"``.
        within_model_lifespan: False when the date lies outside the bundled
            models (2010–2030) and the nearest model was extrapolated.
    """

    declination_rad: float
    inclination_rad: float
    strength_ut: float
    north_east_down_ut: tuple[float, float, float]
    source: str = "manual"
    within_model_lifespan: bool = True

    @property
    def declination_deg(self) -> float:
        return math.degrees(self.declination_rad)

    @property
    def inclination_deg(self) -> float:
        return math.degrees(self.inclination_rad)


def field_from_angles(
    declination_rad: float, inclination_rad: float, strength_ut: float, source: str = "manual"
) -> ExpectedField:
    """Build an :class:`ExpectedField` from D, I and F (e.g. set by hand)."""
    h = strength_ut * math.cos(inclination_rad)
    ned = (h * math.cos(declination_rad), h * math.sin(declination_rad), strength_ut * math.sin(inclination_rad))
    return ExpectedField(float(declination_rad), float(inclination_rad), float(strength_ut), ned, source)


def expected_field(lat_deg: float, lon_deg: float, alt_m: float, decimal_year: float) -> ExpectedField:
    """Main field from the World Magnetic Model at a position and date.

    Args:
        lat_deg: geodetic latitude, −90 … 90.
        lon_deg: longitude, east positive (−180 … 360; wrapped).
        alt_m: height above the WGS-84 ellipsoid, m (−1 km … 850 km).
        decimal_year: e.g. 2026.5 (see :func:`decimal_year_from_unix_s`).
            The model whose 5-year span holds the date is used; outside
            2010–2030 the nearest model is extrapolated and the result says
            ``within_model_lifespan=False``.

    Raises:
        ValueError: a non-finite or out-of-range argument.
    """
    from pygeomag import GeoMag  # light, pure Python; imported here to keep import time low

    for name, value in (("lat_deg", lat_deg), ("lon_deg", lon_deg), ("alt_m", alt_m), ("decimal_year", decimal_year)):
        if not math.isfinite(value):
            raise ValueError(f"expected_field: {name} must be finite, got {value!r}")
    if not -90.0 <= lat_deg <= 90.0:
        raise ValueError(f"expected_field: latitude {lat_deg}° is outside −90 … 90°")
    if not -1000.0 <= alt_m <= 850_000.0:
        raise ValueError(f"expected_field: altitude {alt_m} m is outside the WMM's −1 km … 850 km")
    lon = (lon_deg + 180.0) % 360.0 - 180.0
    within = WMM_FIRST_YEAR <= decimal_year < WMM_END_YEAR
    base_year = min(max(decimal_year, WMM_FIRST_YEAR), WMM_END_YEAR - 1e-6)
    model = GeoMag(base_year=int(base_year))
    result = model.calculate(
        glat=float(lat_deg), glon=lon, alt=alt_m / 1000.0, time=float(decimal_year),
        allow_date_outside_lifespan=not within,
    )  # fmt: skip
    if not within and (str(model.model), round(decimal_year, 1)) not in _WARNED_OUTSIDE:
        # once per model and date in a process: every filter of a replay has its own pipeline and field
        _WARNED_OUTSIDE.add((str(model.model), round(decimal_year, 1)))
        _log.warning(
            "date %.2f lies outside the World Magnetic Model's %g–%g span: extrapolating %s",
            decimal_year, WMM_FIRST_YEAR, WMM_END_YEAR, model.model,
        )  # fmt: skip
    return ExpectedField(
        declination_rad=math.radians(result.d),
        inclination_rad=math.radians(result.i),
        strength_ut=result.f / _NT_PER_UT,
        north_east_down_ut=(result.x / _NT_PER_UT, result.y / _NT_PER_UT, result.z / _NT_PER_UT),
        source=str(model.model),
        within_model_lifespan=within,
    )


# --------------------------------------------------------------------------- true north


def apply_declination(q_body_to_ned: ArrayLike, declination_rad: ArrayLike) -> Array:
    """Re-reference attitudes from magnetic to true north: ``R_z(D) ⊗ q``.

    ``q_body_to_ned`` is ``(4,)`` or ``(N, 4)`` with its earth frame's x axis
    on magnetic north; ``declination_rad`` a scalar or ``(N,)`` (positive
    east).  The result's yaw is the input's yaw + D; roll and pitch are
    unchanged.  NaN rows stay NaN.
    """
    q = np.asarray(q_body_to_ned, dtype=np.float64)
    half = 0.5 * np.asarray(declination_rad, dtype=np.float64)
    c = np.cos(half)
    s = np.sin(half)
    w, x, y, z = np.moveaxis(q, -1, 0)
    # [c, 0, 0, s] ⊗ q (Hamilton product with a pure z rotation)
    return np.stack([c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w], axis=-1)


def apply_declination_wxyz(
    w: float, x: float, y: float, z: float, declination_rad: float
) -> tuple[float, float, float, float]:
    """Scalar :func:`apply_declination` for the live path (no numpy per message)."""
    c = math.cos(0.5 * declination_rad)
    s = math.sin(0.5 * declination_rad)
    return c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w


def rotate_true_to_magnetic(
    north: float, east: float, declination_rad: float
) -> tuple[float, float]:
    """Horizontal components of a true-NED vector in the magnetic-NED frame.

    The filters' earth frame is magnetic NED, GNSS velocity is true NED: feed
    the filter ``R_z(−D)·v`` (down is unchanged).
    """
    c = math.cos(declination_rad)
    s = math.sin(declination_rad)
    return c * north + s * east, -s * north + c * east


# --------------------------------------------------------------------------- helpers


def decimal_year_from_unix_s(unix_s: float) -> float:
    """UTC Unix time (s) → decimal year (2026.0 = 1 January 2026, 00:00 UTC)."""
    t = _dt.datetime.fromtimestamp(unix_s, tz=_dt.timezone.utc)
    start = _dt.datetime(t.year, 1, 1, tzinfo=_dt.timezone.utc)
    end = _dt.datetime(t.year + 1, 1, 1, tzinfo=_dt.timezone.utc)
    return t.year + (t - start).total_seconds() / (end - start).total_seconds()


def _model_day(decimal_year: float | None) -> float | None:
    """A date (decimal year) rounded to 1/1024 year (≈ 8.6 h), for the model.

    The field changes by a few nT a month, so that resolution loses nothing; and the daemon (its
    start time) and a replay of its log (the first record's time) then compute the very same model
    though their clocks are a fraction of a second apart: the attitudes replay bit for bit (the
    first GNSS re-alignment uses the model's dip).  Dyadic, so whole years stay exact.
    """
    if decimal_year is None or not math.isfinite(decimal_year):
        return decimal_year
    return round(decimal_year * 1024.0) / 1024.0


def distance_km(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float) -> float:
    """Great-circle distance (haversine, spherical Earth), km."""
    p1 = math.radians(lat1_deg)
    p2 = math.radians(lat2_deg)
    dp = p2 - p1
    dl = math.radians(lon2_deg - lon1_deg)
    a = math.sin(0.5 * dp) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(0.5 * dl) ** 2
    return 2.0 * _EARTH_RADIUS_KM * math.asin(min(1.0, math.sqrt(a)))


# --------------------------------------------------------------------------- settings


def _check_optional(name: str, value: float | None, lo: float, hi: float) -> None:
    if value is None:
        return
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ValueError(f"magnetic field setting {name} must be within {lo} … {hi}, got {value!r}")


@dataclass(frozen=True)
class MagneticFieldSettings:
    """Where the expected field and the declination come from.

    Every value left ``None`` comes from the World Magnetic Model at the
    vehicle's position (GLOBAL_POSITION_INT, GPS_RAW_INT with a fix,
    HOME_POSITION) — or at the position given here when there is no GPS.

    Attributes:
        true_north: reference output attitudes to true north (apply the
            declination).  False: outputs stay referenced to magnetic north.
        declination_deg: fixed declination, degrees, positive east; overrides
            the model.  ``None`` = from the model (0 until a position is known).
        inclination_deg: fixed inclination (dip), degrees, positive down.
        strength_ut: fixed total field strength, µT.
        latitude_deg: fixed position for vehicles without GPS, degrees
            (with ``longitude_deg``); position messages take precedence.
        longitude_deg: fixed longitude, degrees east.
        altitude_m: fixed altitude, m (default 0).
        decimal_year: fixed date for the model (e.g. 2018.6 to replay an old
            log without SYSTEM_TIME).  ``None`` = SYSTEM_TIME from the
            autopilot, else the date the caller supplies (today, live).
        update_distance_km: recompute the model when the vehicle has moved
            further than this from where it was last computed, km.
            Declination changes by ≲ 0.1° per 10 km outside polar regions.
        seed_gain_schedule: start the filters' magnetic-disturbance rejection
            from the model's strength and inclination instead of learning
            them from the first samples.
    """

    true_north: bool = True
    declination_deg: float | None = None
    inclination_deg: float | None = None
    strength_ut: float | None = None
    latitude_deg: float | None = None
    longitude_deg: float | None = None
    altitude_m: float | None = None
    decimal_year: float | None = None
    update_distance_km: float = 5.0
    seed_gain_schedule: bool = True

    def __post_init__(self) -> None:
        _check_optional("declination_deg", self.declination_deg, -180.0, 180.0)
        _check_optional("inclination_deg", self.inclination_deg, -90.0, 90.0)
        _check_optional("strength_ut", self.strength_ut, 1.0, 200.0)
        _check_optional("latitude_deg", self.latitude_deg, -90.0, 90.0)
        _check_optional("longitude_deg", self.longitude_deg, -180.0, 360.0)
        _check_optional("altitude_m", self.altitude_m, -1000.0, 850_000.0)
        _check_optional("decimal_year", self.decimal_year, 1900.0, 2100.0)
        if (self.latitude_deg is None) != (self.longitude_deg is None):
            raise ValueError("magnetic field settings: give both latitude_deg and longitude_deg, or neither")
        if not (math.isfinite(self.update_distance_km) and self.update_distance_km > 0):
            raise ValueError(f"update_distance_km must be > 0 km, got {self.update_distance_km!r}")


# --------------------------------------------------------------------------- live source

_E7 = 1e-7
_MONTH_YEARS = 1.0 / 12.0
_MIN_UNIX_S = 1262304000.0  # 2010-01-01: earlier SYSTEM_TIME means "no GPS time yet"


class DeclinationSource:
    """The expected field and declination for the live pipeline (pure: no clock, no I/O).

    Feed it every message from the autopilot with :meth:`handle` (it ignores
    what it does not use; a position message costs a few float operations);
    it recomputes the World Magnetic Model only when the position moved more
    than ``update_distance_km`` or the date changed by more than a month.

    Args:
        settings: manual values and update policy.
        decimal_year: the date to use until the autopilot sends SYSTEM_TIME
            (the daemon passes today's date; replay the log's date).  Ignored
            when ``settings.decimal_year`` is set.
    """

    def __init__(self, settings: MagneticFieldSettings | None = None, decimal_year: float | None = None) -> None:
        self._settings = settings if settings is not None else MagneticFieldSettings()
        s = self._settings
        self._year: float | None = s.decimal_year if s.decimal_year is not None else _model_day(decimal_year)
        self._year_locked = s.decimal_year is not None
        self._position: tuple[float, float, float] | None = None  # last position seen
        self._position_source = ""
        self._computed_at: tuple[float, float, float, float] | None = None  # lat, lon, alt, year of the model
        self._model: ExpectedField | None = None
        self._field: ExpectedField | None = None
        self._declination_rad = 0.0
        self._changes = 0
        self._logged: tuple[str, str, str] | None = None  # the field as last logged (rounded text)
        #: log the field at INFO (False: DEBUG only — e.g. the further pipelines of a multi-filter replay,
        #: which compute the same field as the first)
        self.announce = True
        if s.latitude_deg is not None and s.longitude_deg is not None:
            self._position = (s.latitude_deg, s.longitude_deg, s.altitude_m or 0.0)
            self._position_source = "settings"
        self._refresh(force=True)

    # ------------------------------------------------------------------ inputs
    def handle(self, msg: Any) -> bool:
        """Use a position or time message; return True when the expected field changed."""
        kind = msg.get_type()
        if kind == "GLOBAL_POSITION_INT":
            return self._position_from_e7(msg.lat, msg.lon, msg.alt * 1e-3, kind)
        if kind in ("GPS_RAW_INT", "GPS2_RAW"):
            if msg.fix_type < 2:  # GPS_FIX_TYPE_2D_FIX
                return False
            return self._position_from_e7(msg.lat, msg.lon, msg.alt * 1e-3, kind)
        if kind == "HOME_POSITION":
            if self._position is not None and self._position_source not in ("settings", "HOME_POSITION"):
                return False  # a live fix is better than the home position
            return self._position_from_e7(msg.latitude, msg.longitude, msg.altitude * 1e-3, kind)
        if kind == "SYSTEM_TIME":
            unix_s = msg.time_unix_usec * 1e-6
            if unix_s < _MIN_UNIX_S:
                return False
            return self.set_decimal_year(decimal_year_from_unix_s(unix_s))
        return False

    def set_position(self, lat_deg: float, lon_deg: float, alt_m: float = 0.0, source: str = "caller") -> bool:
        """Set the vehicle's position; return True when the expected field changed."""
        if not (math.isfinite(lat_deg) and math.isfinite(lon_deg) and -90.0 <= lat_deg <= 90.0):
            return False
        if not math.isfinite(alt_m) or not -1000.0 <= alt_m <= 850_000.0:
            alt_m = 0.0
        self._position = (lat_deg, lon_deg, alt_m)
        self._position_source = source
        return self._refresh()

    def set_decimal_year(self, decimal_year: float) -> bool:
        """Set the date (ignored when the settings fix it); True when the field changed."""
        if self._year_locked or not math.isfinite(decimal_year):
            return False
        self._year = _model_day(decimal_year)
        return self._refresh()

    def _position_from_e7(self, lat_e7: int, lon_e7: int, alt_m: float, source: str) -> bool:
        if lat_e7 == 0 and lon_e7 == 0:
            return False  # ArduPilot/PX4 send zeros before the first fix
        return self.set_position(lat_e7 * _E7, lon_e7 * _E7, alt_m, source)

    # ------------------------------------------------------------------ model
    def _refresh(self, force: bool = False) -> bool:
        s = self._settings
        model = self._model
        if self._position is not None and self._year is not None:
            lat, lon, alt = self._position
            stale = self._computed_at is None
            if not stale:
                lat0, lon0, _alt0, year0 = self._computed_at  # type: ignore[misc]
                stale = (
                    distance_km(lat0, lon0, lat, lon) > s.update_distance_km
                    or abs(self._year - year0) > _MONTH_YEARS
                )
            if stale:
                try:
                    model = expected_field(lat, lon, alt, self._year)
                except ValueError as exc:  # out-of-range input: keep what we had
                    _log.warning("cannot compute the magnetic field at %.5f, %.5f: %s", lat, lon, exc)
                    return False
                self._computed_at = (lat, lon, alt, self._year)
        changed = force or model is not self._model
        if not changed:
            return False
        self._model = model
        self._field = self._combine(model)
        if not s.true_north:
            declination = 0.0
        elif s.declination_deg is not None:
            declination = math.radians(s.declination_deg)
        elif model is not None:
            declination = model.declination_rad
        else:
            declination = 0.0
        self._declination_rad = declination
        self._changes += 1
        if model is not None:
            self._log_field(model)
        return True

    def _log_field(self, model: ExpectedField) -> None:
        """Log the field when its shown (rounded) value changes; a recomputation that rounds the same is DEBUG.

        The daemon computes the field with today's date until the autopilot
        sends its own (SYSTEM_TIME), and again when the vehicle moves: a few
        hundredths of a degree apart, which the log would otherwise show as
        two contradicting lines.
        """
        shown = (f"{model.declination_deg:.1f}", f"{model.inclination_deg:.1f}", f"{model.strength_ut:.1f}")
        level = logging.DEBUG if shown == self._logged or not self.announce else logging.INFO
        self._logged = shown
        lat, lon = self._computed_at[0], self._computed_at[1]  # type: ignore[index]
        _log.log(level, "magnetic field from %s at %.4f, %.4f: declination %s°, inclination %s°, %s µT",
                 model.source, lat, lon, *shown)  # fmt: skip

    def _combine(self, model: ExpectedField | None) -> ExpectedField | None:
        """Model values with the manual ones substituted; None when incomplete."""
        s = self._settings
        d = s.declination_deg
        i = s.inclination_deg
        f = s.strength_ut
        if model is None:
            if d is None or i is None or f is None:
                return None
            return field_from_angles(math.radians(d), math.radians(i), f, "manual")
        if d is None and i is None and f is None:
            return model
        return field_from_angles(
            math.radians(d) if d is not None else model.declination_rad,
            math.radians(i) if i is not None else model.inclination_rad,
            f if f is not None else model.strength_ut,
            f"{model.source}+manual",
        )

    # ------------------------------------------------------------------ outputs
    @property
    def settings(self) -> MagneticFieldSettings:
        return self._settings

    @property
    def declination_rad(self) -> float:
        """The declination to apply to outputs (0 when unknown or ``true_north`` is off)."""
        return self._declination_rad

    @property
    def field(self) -> ExpectedField | None:
        """The expected field (model with manual overrides), or None while unknown."""
        return self._field

    @property
    def known(self) -> bool:
        """True when outputs are truly referenced to true north (or magnetic on request)."""
        s = self._settings
        return (not s.true_north) or s.declination_deg is not None or self._model is not None

    @property
    def changes(self) -> int:
        """How many times the field/declination has been (re)computed."""
        return self._changes

    def mag_reference(self) -> tuple[float, float] | None:
        """``(strength_ut, inclination_rad)`` for the filter's magnetometer rejection
        (:meth:`~mavahrs.filters.base.AttitudeFilter.set_mag_reference`), or None
        when the field is unknown or ``seed_gain_schedule`` is off."""
        f = self._field
        if f is None or not self._settings.seed_gain_schedule:
            return None
        return f.strength_ut, f.inclination_rad

    def gain_schedule(self, base: GainScheduleSettings) -> GainScheduleSettings:
        """``base`` with the magnetometer reference (norm, dip) from the expected field.

        Unchanged when the field is unknown or ``seed_gain_schedule`` is off.
        """
        ref = self.mag_reference()
        if ref is None:
            return base
        return replace(base, mag_reference_norm_ut=ref[0], mag_reference_dip_rad=ref[1])

    def status(self) -> str:
        """One short phrase for the status line, e.g. ``"true north (WMM-2025 D=+12.3°)"``."""
        s = self._settings
        if not s.true_north:
            return "magnetic north"
        if s.declination_deg is not None:
            return f"true north (manual D={s.declination_deg:+.1f}°)"
        if self._model is not None:
            return f"true north ({self._model.source} D={self._model.declination_deg:+.1f}°)"
        if self._position is not None and self._year is None:
            return "magnetic north (declination unknown: no date)"
        return "magnetic north (declination unknown: no position)"
