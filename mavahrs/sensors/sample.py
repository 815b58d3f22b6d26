"""One IMU sample in SI units, and how it is written into a filter input row.

:class:`ImuSample` is the readable form (replay, tests, tools).  The live
daemon's hot path skips it and writes the same values straight into a
preallocated filter row (:func:`write_row`), so that no object is allocated
per message; both go through :func:`write_row`, so they cannot disagree.

Bit flags (``saturated`` and ``invalid``) name the affected vector:
:data:`GYRO`, :data:`ACCEL`, :data:`MAG`.  ``invalid`` means the vector is
unusable (NaN/inf, impossible magnitude, or absent); the filter then skips
only the correction that vector feeds (its column is written as NaN).
``saturated`` means at least one axis is at its sensor or wire limit: the
value is kept for the gyro (the best there is, but the attitude will lag) and
dropped for the accelerometer and magnetometer (a clipped vector points the
wrong way).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mavahrs.filters.jit import kernel
from mavahrs.filters.layout import IN_ACCEL, IN_DT, IN_GYRO, IN_MAG, IN_POS, IN_VEL, IN_VEL_AGE, IN_WIDTH

__all__ = ["ImuSample", "GYRO", "ACCEL", "MAG", "Vector3", "write_row", "blank_unusable", "blank_unusable_rows", "new_row", "flag_names"]

#: Flag bits for ``ImuSample.saturated`` / ``ImuSample.invalid``.
GYRO = 1
ACCEL = 2
MAG = 4

Vector3 = tuple[float, float, float]
_NAN = math.nan


def flag_names(flags: int) -> str:
    """``"gyro+accel"`` style text for a flag set ("" when none)."""
    return "+".join(name for bit, name in ((GYRO, "gyro"), (ACCEL, "accel"), (MAG, "mag")) if flags & bit)


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU reading, SI units, in the axes the message uses (FRD body for autopilots).

    Attributes:
        t_us: sample timestamp from the message, µs (since autopilot boot).
        gyro_rad_s: angular rate, rad/s.
        accel_m_s2: specific force (level at rest ≈ (0, 0, −9.81)), m/s².
        mag_ut: magnetic field, µT; None when the message carries none
            (or HIGHRES_IMU says it is not new).
        temperature_c: IMU temperature, °C; None when not reported.
        imu_id: IMU instance (0 = RAW_IMU/SCALED_IMU, 1 = SCALED_IMU2,
            2 = SCALED_IMU3, HIGHRES_IMU ``id``).
        source: MAVLink message name it came from.
        saturated: GYRO/ACCEL/MAG bits at their limit.
        invalid: GYRO/ACCEL/MAG bits unusable (NaN/inf/out of range/absent).
    """

    t_us: int
    gyro_rad_s: Vector3
    accel_m_s2: Vector3
    mag_ut: Vector3 | None
    temperature_c: float | None
    imu_id: int
    source: str
    saturated: int = 0
    invalid: int = 0

    @property
    def is_zero(self) -> bool:
        """Accelerometer and gyro exactly zero: an absent instance (no such IMU)."""
        return not any(self.gyro_rad_s) and not any(self.accel_m_s2)

    def to_row(self, row: NDArray[np.float64] | None = None, *, dt_s: float = _NAN) -> NDArray[np.float64]:
        """The filter input row for this sample (velocity, its age and the position NaN); fills ``row`` if given."""
        if row is None:
            row = new_row()
        g, a = self.gyro_rad_s, self.accel_m_s2
        m = self.mag_ut if self.mag_ut is not None else (_NAN, _NAN, _NAN)
        write_row(row, dt_s, g[0], g[1], g[2], a[0], a[1], a[2], m[0], m[1], m[2], self.saturated, self.invalid)
        row[IN_VEL : IN_VEL + 3] = _NAN
        row[IN_VEL_AGE] = _NAN
        row[IN_POS : IN_POS + 3] = _NAN
        return row


def new_row() -> NDArray[np.float64]:
    """A fresh filter input row, all NaN."""
    return np.full(IN_WIDTH, _NAN)


def write_row(
    row: NDArray[np.float64],
    dt_s: float,
    gx: float, gy: float, gz: float,
    ax: float, ay: float, az: float,
    mx: float, my: float, mz: float,
    saturated: int = 0,
    invalid: int = 0,
) -> None:  # fmt: skip
    """Write one sample into a filter input row (velocity columns untouched).

    Invalid vectors, and saturated accelerometer/magnetometer vectors, are
    written as NaN so the filter skips just that correction.
    """
    row[IN_DT] = dt_s
    row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2] = gx, gy, gz
    row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2] = ax, ay, az
    row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2] = mx, my, mz
    if saturated or invalid:
        blank_unusable(row, saturated, invalid)


@kernel
def blank_unusable(row, saturated, invalid):  # type: ignore[no-untyped-def]
    """The rule for flagged vectors, once: an invalid vector, or a saturated accelerometer or
    magnetometer, becomes NaN in the row (the filter then skips just that correction; a saturated
    gyro is still integrated: it is the best there is).  Per sample from :func:`write_row`, over a
    log's rows by :func:`blank_unusable_rows`."""
    bad = invalid | (saturated & (ACCEL | MAG))
    if bad & GYRO:
        row[IN_GYRO] = row[IN_GYRO + 1] = row[IN_GYRO + 2] = math.nan
    if bad & ACCEL:
        row[IN_ACCEL] = row[IN_ACCEL + 1] = row[IN_ACCEL + 2] = math.nan
    if bad & MAG:
        row[IN_MAG] = row[IN_MAG + 1] = row[IN_MAG + 2] = math.nan


@kernel
def blank_unusable_rows(rows, saturated, invalid):  # type: ignore[no-untyped-def]
    """:func:`blank_unusable` over every row with a flag."""
    for i in range(rows.shape[0]):
        if saturated[i] or invalid[i]:
            blank_unusable(rows[i], saturated[i], invalid[i])
