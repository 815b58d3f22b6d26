r"""MAVLink IMU messages → SI values (the only place wire units appear).

:class:`Scaler` turns one decoded message (anything with the MAVLink field
names as attributes — pymavlink objects, or a ``SimpleNamespace`` in tests)
into SI values according to an :class:`~mavahrs.sensors.profiles.AutopilotProfile`:

* units: ``xacc_mg``·g/1000 → m/s², ``xgyro_mrad_s``/1000 → rad/s,
  ``xmag_mgauss``/10 → µT (1 mgauss = 0.1 µT), HIGHRES_IMU gauss·100 → µT;
* timestamps: ``time_usec`` as is, ``time_boot_ms``·1000;
* instance: RAW_IMU ``id`` (0 when absent), SCALED_IMU 0, SCALED_IMU2 1,
  SCALED_IMU3 2, HIGHRES_IMU ``id``;
* checks: an int16 field at ±32767 or a value at ≥ ``saturation_fraction``
  of the sensor's full scale is *saturated*; NaN/inf or an impossible
  magnitude is *invalid*; a magnetometer of exactly (0, 0, 0) is *absent*;
  HIGHRES_IMU ``fields_updated`` says which vectors are new (a message
  without new gyro data is not a sample: :meth:`Scaler.scale` returns None).

The hot path uses :meth:`Scaler.scale` (a plain tuple, no allocation beyond
it); :meth:`Scaler.to_sample` wraps the same values in an
:class:`~mavahrs.sensors.sample.ImuSample`, and with ``strict=True`` raises
:class:`~mavahrs.errors.ScalingError` instead of marking bad vectors.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import ConfigError, ScalingError
from mavahrs.filters.jit import kernel
from mavahrs.filters.layout import IN_ACCEL, IN_GYRO, IN_MAG, IN_WIDTH
from mavahrs.sensors.profiles import G_M_S2, INSTANCE_OF_MESSAGE, AutopilotProfile, MessageScale, get_profile
from mavahrs.sensors.sample import MAG, ImuSample, flag_names

__all__ = ["ScalingSettings", "Scaler", "Scaled", "to_sample", "S_IMU", "S_T_US", "S_GYRO", "S_ACCEL", "S_MAG",
           "S_TEMP", "S_SAT", "S_INVALID", "HIGHRES_ACCEL_BITS", "HIGHRES_GYRO_BITS", "HIGHRES_MAG_BITS",
           "scale_int_row", "scale_int_rows", "scale_float_row", "scale_float_rows", "scale_constants", "C_KG", "C_KA", "C_KM", "C_KOLD", "C_GSAT", "C_ASAT", "C_MAG_MAX", "C_GBAD", "C_ABAD",
           "C_LEN", "INVALID_SHIFT", "ZERO"]  # fmt: skip

#: Positions in the tuple :meth:`Scaler.scale` returns.
S_IMU, S_T_US, S_GYRO, S_ACCEL, S_MAG, S_TEMP, S_SAT, S_INVALID = 0, 1, 2, 5, 8, 11, 12, 13
#: ``(imu_id, t_us, gx, gy, gz, ax, ay, az, mx, my, mz, temperature_c|None, saturated, invalid)``
Scaled = tuple[int, int, float, float, float, float, float, float, float, float, float, "float | None", int, int]

HIGHRES_ACCEL_BITS = 0x007
HIGHRES_GYRO_BITS = 0x038
HIGHRES_MAG_BITS = 0x1C0

_NAN = math.nan
#: Smallest believable magnetic field norm, µT (Earth: 22–67 µT).
MAG_MIN_UT = 1.0

#: Positions in the constants array of :func:`scale_int_row` (:meth:`Scaler.scale_constants`): the units
#: (gyro, accel, mag, the legacy mag unit or NaN), the saturation limits (gyro, accel) and the largest
#: believable magnetic field norm, and (float fields) the limits beyond which a value is not a measurement.
C_KG, C_KA, C_KM, C_KOLD, C_GSAT, C_ASAT, C_MAG_MAX, C_GBAD, C_ABAD = range(9)
C_LEN = 9
#: :func:`scale_int_row`'s result: ``saturated | invalid << INVALID_SHIFT | ZERO`` (gyro and accelerometer all 0)
INVALID_SHIFT = 3
ZERO = 64


@kernel
def _mag_into(xm, ym, zm, c, row):  # type: ignore[no-untyped-def]
    """The magnetometer in µT into ``row``; the invalid bit (MAG) or 0.  Absent (all zero): NaN, not invalid."""
    if xm == 0.0 and ym == 0.0 and zm == 0.0:
        row[IN_MAG] = row[IN_MAG + 1] = row[IN_MAG + 2] = math.nan
        return 0
    km, k_old, mag_max = c[C_KM], c[C_KOLD], c[C_MAG_MAX]
    m0, m1, m2 = xm * km, ym * km, zm * km
    nrm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if k_old == k_old and nrm > mag_max:  # the legacy unit (gauss in an old HIGHRES_IMU)
        m0, m1, m2 = xm * k_old, ym * k_old, zm * k_old
        nrm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if not (MAG_MIN_UT <= nrm and nrm <= mag_max):  # also catches NaN/inf
        row[IN_MAG] = row[IN_MAG + 1] = row[IN_MAG + 2] = math.nan
        return 4
    row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2] = m0, m1, m2
    return 0


@kernel
def scale_int_row(xg, yg, zg, xa, ya, za, xm, ym, zm, c, row):  # type: ignore[no-untyped-def]
    """The scaling step of an integer-field IMU message (RAW_IMU, SCALED_IMU*): one sample, in SI.

    The one implementation of integer scaling: :class:`Scaler` calls it per
    message (the live pipeline), :func:`scale_int_rows` loops over it for a
    whole log (replay), and the daemon's fast lane calls it inside its
    compiled parse.  The raw int16 fields in, ``c`` the constants (``C_*``);
    written into ``row``'s gyro, accelerometer and magnetometer columns
    (:mod:`mavahrs.filters.layout`): value · unit, the magnetometer NaN when
    absent (all zero) or implausible, re-read with the legacy unit when its
    norm exceeds the limit in the profile's unit.  Returns the saturated bits (a raw
    component at the int16 limit, or a scaled one at the saturation limit),
    the invalid bits shifted by ``INVALID_SHIFT`` (an implausible
    magnetometer) and ``ZERO`` when gyro and accelerometer are all zero (an
    absent IMU instance).  Bits as :mod:`mavahrs.sensors.sample` (GYRO=1, ACCEL=2, MAG=4).
    """
    rg0, rg1, rg2 = float(xg), float(yg), float(zg)
    ra0, ra1, ra2 = float(xa), float(ya), float(za)
    kg, ka = c[C_KG], c[C_KA]
    g0, g1, g2 = rg0 * kg, rg1 * kg, rg2 * kg
    a0, a1, a2 = ra0 * ka, ra1 * ka, ra2 * ka
    row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2] = g0, g1, g2
    row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2] = a0, a1, a2
    s = 0
    if max(max(abs(rg0), abs(rg1)), abs(rg2)) >= 32767.0:
        s |= 1
    if max(max(abs(ra0), abs(ra1)), abs(ra2)) >= 32767.0:
        s |= 2
    if max(max(abs(g0), abs(g1)), abs(g2)) >= c[C_GSAT]:
        s |= 1
    if max(max(abs(a0), abs(a1)), abs(a2)) >= c[C_ASAT]:
        s |= 2
    if g0 == 0.0 and g1 == 0.0 and g2 == 0.0 and a0 == 0.0 and a1 == 0.0 and a2 == 0.0:
        s |= 64
    return s | (_mag_into(float(xm), float(ym), float(zm), c, row) << 3)


@kernel
def scale_float_row(xg, yg, zg, xa, ya, za, xm, ym, zm, updated, c, row):  # type: ignore[no-untyped-def]
    """The scaling step of a float-field IMU message (HIGHRES_IMU, ``fields_updated`` = ``updated``).

    As :func:`scale_int_row` (same result code, same columns): value · unit;
    a vector beyond ``C_GBAD``/``C_ABAD`` (or NaN/inf) invalid, else saturated at
    the saturation limit; the accelerometer NaN unless updated, the
    magnetometer NaN unless updated (and only then judged).  The caller drops a message
    without a new gyro (:data:`HIGHRES_GYRO_BITS`) before this step.
    """
    kg, ka = c[C_KG], c[C_KA]
    g0, g1, g2 = xg * kg, yg * kg, zg * kg
    row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2] = g0, g1, g2
    s = 0
    inv = 0
    m = max(max(abs(g0), abs(g1)), abs(g2))
    if not m < c[C_GBAD]:  # NaN/inf fail this too
        inv = 1
    elif m >= c[C_GSAT]:
        s = 1
    zero = g0 == 0.0 and g1 == 0.0 and g2 == 0.0
    if updated & HIGHRES_ACCEL_BITS == HIGHRES_ACCEL_BITS:
        a0, a1, a2 = xa * ka, ya * ka, za * ka
        row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2] = a0, a1, a2
        m = max(max(abs(a0), abs(a1)), abs(a2))
        if not m < c[C_ABAD]:
            inv |= 2
        elif m >= c[C_ASAT]:
            s |= 2
        zero = zero and a0 == 0.0 and a1 == 0.0 and a2 == 0.0
    else:
        row[IN_ACCEL] = row[IN_ACCEL + 1] = row[IN_ACCEL + 2] = math.nan
        zero = False
    if updated & HIGHRES_MAG_BITS == HIGHRES_MAG_BITS:
        inv |= _mag_into(xm, ym, zm, c, row)
    else:
        row[IN_MAG] = row[IN_MAG + 1] = row[IN_MAG + 2] = math.nan
    return s | (inv << 3) | (64 if zero else 0)


@kernel
def scale_float_rows(xg, yg, zg, xa, ya, za, xm, ym, zm, updated, c, rows, codes):  # type: ignore[no-untyped-def]
    """:func:`scale_float_row` over arrays of fields: ``rows[i]`` and ``codes[i]`` for message i."""
    for i in range(rows.shape[0]):
        codes[i] = scale_float_row(xg[i], yg[i], zg[i], xa[i], ya[i], za[i], xm[i], ym[i], zm[i], updated[i], c,
                                   rows[i])  # fmt: skip


@kernel
def scale_int_rows(xg, yg, zg, xa, ya, za, xm, ym, zm, c, rows, codes):  # type: ignore[no-untyped-def]
    """:func:`scale_int_row` over arrays of raw fields: ``rows[i]`` and ``codes[i]`` for message i."""
    for i in range(rows.shape[0]):
        codes[i] = scale_int_row(xg[i], yg[i], zg[i], xa[i], ya[i], za[i], xm[i], ym[i], zm[i], c, rows[i])


@dataclass(frozen=True)
class ScalingSettings:
    """Checks applied while scaling.

    Attributes:
        saturation_fraction: a reading at or above this fraction of the sensor's
            full scale counts as saturated (0–1].
        accel_range_g: accelerometer full scale, g; None = the profile's
            (16 g, the common MEMS setting on autopilots).
        gyro_range_deg_s: gyro full scale, °/s; None = the profile's (2000 °/s).
        implausible_factor: a vector component beyond this multiple of full
            scale is garbage (invalid), not saturation.
    """

    saturation_fraction: float = 0.98
    accel_range_g: float | None = None
    gyro_range_deg_s: float | None = None
    implausible_factor: float = 2.0

    def __post_init__(self) -> None:
        if not (0.0 < self.saturation_fraction <= 1.0):
            raise ConfigError(f"saturation_fraction must be in (0, 1], got {self.saturation_fraction!r}")
        for name in ("accel_range_g", "gyro_range_deg_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a positive number or None, got {v!r}")
        if not (math.isfinite(self.implausible_factor) and self.implausible_factor >= 1.0):
            raise ConfigError(f"implausible_factor must be ≥ 1, got {self.implausible_factor!r}")


class Scaler:
    """Scales IMU messages with one profile.  Cheap to call; holds no per-sample state."""

    def __init__(self, profile: AutopilotProfile | str, settings: ScalingSettings | None = None) -> None:
        self.profile = get_profile(profile) if isinstance(profile, str) else profile
        self.settings = settings or ScalingSettings()
        #: the last message scaled, in a filter input row (:mod:`mavahrs.filters.layout`): its gyro,
        #: accelerometer and magnetometer columns, as :meth:`scale` returns them (the next steps read it)
        self.row = np.full(IN_WIDTH, _NAN)
        self._fns: dict[str, Callable[[Any], Scaled | None]] = {}
        for name, ms in self.profile.messages.items():
            self._fns[name] = self._make(ms)

    # ------------------------------------------------------------------ public
    def handles(self, message: str) -> bool:
        return message in self._fns

    def scale(self, msg: Any) -> Scaled | None:
        """SI values of one IMU message, or None when it carries no new gyro sample.

        Raises:
            ScalingError: the message type is not an IMU message of this profile.
        """
        fn = self._fns.get(msg.get_type())
        if fn is None:
            raise ScalingError(f"{msg.get_type()} is not an IMU message the {self.profile.name} profile scales")
        return fn(msg)

    def to_sample(self, msg: Any, *, strict: bool = False) -> ImuSample | None:
        """The message as an :class:`ImuSample` (None: no new gyro data in a HIGHRES_IMU).

        With ``strict=True`` an invalid or saturated vector raises
        :class:`ScalingError` naming the message, the vector and its values.
        """
        v = self.scale(msg)
        if v is None:
            return None
        sat, inv = v[S_SAT], v[S_INVALID]
        if strict and (sat | inv):
            raise ScalingError(
                f"{msg.get_type()} (imu {v[S_IMU]}, t={v[S_T_US]} us): "
                + (f"invalid {flag_names(inv)} " if inv else "")
                + (f"saturated {flag_names(sat)} " if sat else "")
                + f"gyro={v[2:5]} rad/s accel={v[5:8]} m/s2 mag={v[8:11]} uT"
            )
        mag = None if math.isnan(v[S_MAG]) and not inv & MAG else (v[8], v[9], v[10])
        return ImuSample(
            t_us=v[S_T_US],
            gyro_rad_s=(v[2], v[3], v[4]),
            accel_m_s2=(v[5], v[6], v[7]),
            mag_ut=mag,
            temperature_c=v[S_TEMP],
            imu_id=v[S_IMU],
            source=msg.get_type(),
            saturated=sat,
            invalid=inv,
        )

    # ------------------------------------------------------------------ builders
    def _limits(self, ms: MessageScale) -> tuple[float, float]:
        s = self.settings
        accel_fs = s.accel_range_g * G_M_S2 if s.accel_range_g is not None else ms.accel_range_m_s2
        gyro_fs = math.radians(s.gyro_range_deg_s) if s.gyro_range_deg_s is not None else ms.gyro_range_rad_s
        return accel_fs, gyro_fs

    def scale_constants(self, ms: MessageScale) -> NDArray[np.float64]:
        """The constants :func:`scale_int_row` scales ``ms``'s integer fields with (``C_*`` order)."""
        return scale_constants(ms, self.settings)

    def _make(self, ms: MessageScale) -> Callable[[Any], Scaled | None]:
        tf, tk, kt = ms.time_field, ms.time_to_us, ms.temperature_to_c
        fixed_id = INSTANCE_OF_MESSAGE[ms.message]
        has_id = ms.message in ("RAW_IMU", "HIGHRES_IMU")
        c = self.scale_constants(ms)
        buf = self.row
        if ms.integer_fields:

            def scale_int(msg: Any) -> Scaled | None:
                code = scale_int_row(msg.xgyro, msg.ygyro, msg.zgyro, msg.xacc, msg.yacc, msg.zacc,
                                     msg.xmag, msg.ymag, msg.zmag, c, buf)  # fmt: skip
                gx, gy, gz, ax, ay, az, mx, my, mz = buf[IN_GYRO : IN_MAG + 3].tolist()
                temp = None
                if kt is not None:
                    raw_t = getattr(msg, "temperature", 0)
                    if raw_t:  # 0 = "not provided" (common.xml); 0 °C is sent as 1
                        temp = raw_t * kt
                imu = _instance(msg) if has_id else fixed_id
                return (imu, int(getattr(msg, tf)) * tk, gx, gy, gz, ax, ay, az, mx, my, mz, temp, code & 7,
                        (code >> INVALID_SHIFT) & 7)  # fmt: skip

            return scale_int

        def scale_float(msg: Any) -> Scaled | None:
            upd = msg.fields_updated
            if upd & HIGHRES_GYRO_BITS != HIGHRES_GYRO_BITS:
                return None  # no new gyro: not an IMU sample
            code = scale_float_row(float(msg.xgyro), float(msg.ygyro), float(msg.zgyro), float(msg.xacc),
                                   float(msg.yacc), float(msg.zacc), float(msg.xmag), float(msg.ymag),
                                   float(msg.zmag), int(upd), c, buf)  # fmt: skip
            gx, gy, gz, ax, ay, az, mx, my, mz = buf[IN_GYRO : IN_MAG + 3].tolist()
            imu = _instance(msg) if has_id else fixed_id
            return (imu, int(getattr(msg, tf)) * tk, gx, gy, gz, ax, ay, az, mx, my, mz, None, code & 7,
                    (code >> INVALID_SHIFT) & 7)  # fmt: skip

        return scale_float


def scale_constants(ms: MessageScale, settings: ScalingSettings) -> NDArray[np.float64]:
    """The constants of :func:`scale_int_row` for message ``ms`` with ``settings`` (``C_*`` order)."""
    accel_fs = settings.accel_range_g * G_M_S2 if settings.accel_range_g is not None else ms.accel_range_m_s2
    gyro_fs = math.radians(settings.gyro_range_deg_s) if settings.gyro_range_deg_s is not None else ms.gyro_range_rad_s
    frac = settings.saturation_fraction
    c = np.empty(C_LEN)
    c[C_KG], c[C_KA], c[C_KM] = ms.gyro_to_rad_s, ms.accel_to_m_s2, ms.mag_to_ut
    c[C_KOLD] = ms.mag_legacy_to_ut if ms.mag_legacy_to_ut is not None else _NAN
    c[C_GSAT], c[C_ASAT], c[C_MAG_MAX] = gyro_fs * frac, accel_fs * frac, ms.mag_plausible_max_ut
    c[C_GBAD], c[C_ABAD] = gyro_fs * settings.implausible_factor, accel_fs * settings.implausible_factor
    return c


def _instance(msg: Any) -> int:
    """The ``id`` extension field of RAW_IMU/HIGHRES_IMU (0 when absent).

    pymavlink message classes also have a class attribute ``id`` (the message
    id: 27, 105); a MAVLink 1 frame read from an old tlog lacks the extension,
    so ``msg.id`` falls through to it.  Instance ids are small: anything else
    means "not given".
    """
    i = getattr(msg, "id", 0)
    return i if isinstance(i, int) and 0 <= i < 16 else 0


def to_sample(msg: Any, profile: AutopilotProfile | str = "generic", *, strict: bool = False) -> ImuSample | None:
    """One-off convenience: scale ``msg`` with ``profile`` (see :meth:`Scaler.to_sample`)."""
    return Scaler(profile).to_sample(msg, strict=strict)
