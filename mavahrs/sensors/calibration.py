r"""Applying calibrations: gyro temperature bias, magnetometer hard/soft iron, axis remap.

Pure functions of the settings — the models are *fitted* elsewhere
(``mavahrs tune`` fits the gyro temperature model, issue 5 item 4;
``mavahrs calibrate-mag`` the magnetometer, issue 9 item 2) and only applied
here, in this order, in the axes the message uses:

1. gyro: ω ← ω − b(T), with the per-axis linear model
   b(T) = b₀ + k·(T − T₀) (rad/s), when the message carries the IMU
   temperature (otherwise b(T₀) = b₀ is used);
2. magnetometer: m ← M·(m − o) (hard-iron offset o in µT, soft-iron matrix M)
   — skipped when the autopilot already calibrated the magnetometer (the
   scaling profile says so), unless ``force_mag_calibration`` is set;
3. a fixed sensor→body axis remap (one of the 24 proper ones in
   :mod:`mavahrs.geometry.frames`, e.g. ``"-x-y+z"`` = yaw 180°) applied to
   all three vectors.  Autopilots already send body (FRD) axes, so the
   default is the identity.

:class:`Calibrator` works in place on a filter input row with scalar Python
arithmetic (no numpy temporaries) for the daemon's hot path, and on an
:class:`~mavahrs.sensors.sample.ImuSample` for everything else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import ConfigError
from mavahrs.filters.jit import kernel
from mavahrs.filters.layout import IN_ACCEL, IN_GYRO, IN_MAG, IN_WIDTH
from mavahrs.geometry.frames import remap_matrix
from mavahrs.sensors.sample import ImuSample, Vector3

__all__ = ["GyroTemperatureModel", "MagCalibration", "CalibrationSettings", "Calibrator", "calibrate_row", "calibrate_rows"]

Matrix3 = tuple[Vector3, Vector3, Vector3]
_IDENTITY: Matrix3 = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def _vec3(name: str, v: object) -> Vector3:
    try:
        t = tuple(float(x) for x in v)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be three numbers, got {v!r}") from None
    if len(t) != 3 or not all(math.isfinite(x) for x in t):
        raise ConfigError(f"{name} must be three finite numbers, got {v!r}")
    return t  # type: ignore[return-value]


@dataclass(frozen=True)
class GyroTemperatureModel:
    """Per-axis linear gyro bias vs temperature: b(T) = b₀ + k·(T − T₀).

    Attributes:
        b0_rad_s: bias at the reference temperature, rad/s (x, y, z).
        k_rad_s_per_c: slope, rad/s per °C (x, y, z).
        t0_c: reference temperature, °C.
    """

    b0_rad_s: Vector3 = (0.0, 0.0, 0.0)
    k_rad_s_per_c: Vector3 = (0.0, 0.0, 0.0)
    t0_c: float = 25.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "b0_rad_s", _vec3("b0_rad_s", self.b0_rad_s))
        object.__setattr__(self, "k_rad_s_per_c", _vec3("k_rad_s_per_c", self.k_rad_s_per_c))
        if not math.isfinite(self.t0_c):
            raise ConfigError(f"t0_c must be finite, got {self.t0_c!r}")

    def bias_rad_s(self, temperature_c: float | None) -> Vector3:
        """b(T); b₀ when the temperature is unknown."""
        b, k = self.b0_rad_s, self.k_rad_s_per_c
        if temperature_c is None or not math.isfinite(temperature_c):
            return b
        d = temperature_c - self.t0_c
        return (b[0] + k[0] * d, b[1] + k[1] * d, b[2] + k[2] * d)


@dataclass(frozen=True)
class MagCalibration:
    """Hard- and soft-iron correction m_cal = M·(m_raw − offset).

    Attributes:
        offset_ut: hard-iron offset, µT, sensor axes.
        matrix: soft-iron 3×3 matrix (rows), dimensionless.
    """

    offset_ut: Vector3 = (0.0, 0.0, 0.0)
    matrix: Matrix3 = _IDENTITY

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset_ut", _vec3("offset_ut", self.offset_ut))
        try:
            rows = tuple(_vec3(f"matrix row {i}", r) for i, r in enumerate(self.matrix))
        except TypeError:
            raise ConfigError(f"matrix must be 3 rows of 3 numbers, got {self.matrix!r}") from None
        if len(rows) != 3:
            raise ConfigError(f"matrix must be 3 rows of 3 numbers, got {self.matrix!r}")
        if abs(float(np.linalg.det(np.array(rows)))) < 1e-9:
            raise ConfigError("magnetometer soft-iron matrix is singular")
        object.__setattr__(self, "matrix", rows)

    def apply(self, m: Vector3) -> Vector3:
        o, M = self.offset_ut, self.matrix
        x, y, z = m[0] - o[0], m[1] - o[1], m[2] - o[2]
        return (
            M[0][0] * x + M[0][1] * y + M[0][2] * z,
            M[1][0] * x + M[1][1] * y + M[1][2] * z,
            M[2][0] * x + M[2][1] * y + M[2][2] * z,
        )


@dataclass(frozen=True)
class CalibrationSettings:
    """What to correct before the filter.

    Attributes:
        axis_remap: sensor→body remap name (``"+x+y+z"`` = none), see
            :data:`mavahrs.geometry.frames.AXIS_REMAPS`.
        gyro_temperature: gyro bias model, or None (no correction).
        mag: magnetometer calibration, or None.
        force_mag_calibration: apply ``mag`` even when the autopilot says its
            magnetometer is already calibrated (normally that would correct
            it twice).
    """

    axis_remap: str = "+x+y+z"
    gyro_temperature: GyroTemperatureModel | None = None
    mag: MagCalibration | None = None
    force_mag_calibration: bool = False

    def __post_init__(self) -> None:
        try:
            remap_matrix(self.axis_remap)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None


@dataclass
class Calibrator:
    """Applies :class:`CalibrationSettings` to samples or rows.

    Args:
        settings: the calibrations.
        mag_already_calibrated: the message's magnetometer was calibrated by
            the autopilot (from the scaling profile); the user's ``mag``
            calibration is then skipped unless forced.
    """

    settings: CalibrationSettings = field(default_factory=CalibrationSettings)
    mag_already_calibrated: bool = False

    def __post_init__(self) -> None:
        s = self.settings
        m = remap_matrix(s.axis_remap)
        self._remap: Matrix3 | None = None
        if s.axis_remap != "+x+y+z":
            self._remap = tuple(tuple(float(v) for v in row) for row in m)  # type: ignore[assignment]
        self._gyro = s.gyro_temperature
        self._mag = s.mag if (s.mag is not None and (s.force_mag_calibration or not self.mag_already_calibrated)) else None
        self.active = self._remap is not None or self._gyro is not None or self._mag is not None
        self.constants = _constants(self._gyro, self._mag, self._remap)

    @property
    def mag_calibration_applied(self) -> bool:
        """True when the user's magnetometer calibration is in use."""
        return self._mag is not None

    def apply_row(self, row: NDArray[np.float64], temperature_c: float | None) -> None:
        """Correct the gyro/accel/mag columns of a filter input row in place (:func:`calibrate_row`)."""
        calibrate_row(row, _NAN if temperature_c is None else float(temperature_c), self.constants)

    def apply_rows(self, rows: NDArray[np.float64], temperature_c: NDArray[np.float64]) -> None:
        """:meth:`apply_row` over every row (``temperature_c`` NaN where unknown)."""
        calibrate_rows(rows, temperature_c, self.constants)

    def apply(self, sample: ImuSample) -> ImuSample:
        """A corrected copy of ``sample`` (the same step, :func:`calibrate_row`, on a row of it)."""
        if not self.active:
            return sample
        row = np.full(IN_WIDTH, _NAN)
        row[IN_GYRO : IN_GYRO + 3] = sample.gyro_rad_s
        row[IN_ACCEL : IN_ACCEL + 3] = sample.accel_m_s2
        if sample.mag_ut is not None:
            row[IN_MAG : IN_MAG + 3] = sample.mag_ut
        self.apply_row(row, sample.temperature_c)
        g, a, m = row[IN_GYRO : IN_GYRO + 3].tolist(), row[IN_ACCEL : IN_ACCEL + 3].tolist(), row[IN_MAG : IN_MAG + 3].tolist()
        return replace(sample, gyro_rad_s=tuple(g), accel_m_s2=tuple(a), mag_ut=tuple(m) if sample.mag_ut is not None else None)


#: Positions in :attr:`Calibrator.constants`: flags (gyro model, mag calibration, axis remap present), the gyro
#: model (b₀ 3, k 3, T₀), the magnetometer's offset (3) and matrix (3×3, row-major), the remap (3×3)
K_HAS_GYRO, K_HAS_MAG, K_HAS_REMAP, K_B0, K_K, K_T0, K_OFFSET, K_MATRIX, K_REMAP = 0, 1, 2, 3, 6, 9, 10, 13, 22
K_LEN = 31
_NAN = math.nan


def _constants(gyro: GyroTemperatureModel | None, mag: MagCalibration | None, remap: Matrix3 | None) -> NDArray[np.float64]:
    k = np.zeros(K_LEN)
    if gyro is not None:
        k[K_HAS_GYRO] = 1.0
        k[K_B0 : K_B0 + 3], k[K_K : K_K + 3], k[K_T0] = gyro.b0_rad_s, gyro.k_rad_s_per_c, gyro.t0_c
    if mag is not None:
        k[K_HAS_MAG] = 1.0
        k[K_OFFSET : K_OFFSET + 3] = mag.offset_ut
        k[K_MATRIX : K_MATRIX + 9] = np.asarray(mag.matrix, dtype=np.float64).reshape(9)
    if remap is not None:
        k[K_HAS_REMAP] = 1.0
        k[K_REMAP : K_REMAP + 9] = np.asarray(remap, dtype=np.float64).reshape(9)
    return k


@kernel
def calibrate_row(row, temperature_c, k):  # type: ignore[no-untyped-def]
    """The calibration step of one filter input row, in place: the one implementation.

    ``k`` = :attr:`Calibrator.constants`.  Gyro: minus b(T) = b₀ + k·(T − T₀)
    (b₀ when ``temperature_c`` is NaN); magnetometer: M·(m − offset); then
    every vector through the axis remap.  The pipeline calls it per sample
    (:meth:`Calibrator.apply_row`), replay over a log's rows (:func:`calibrate_rows`).
    """
    if k[K_HAS_GYRO] != 0.0:
        known = temperature_c == temperature_c
        d = temperature_c - k[K_T0]
        for i in range(3):
            b = k[K_B0 + i] + k[K_K + i] * d if known else k[K_B0 + i]
            row[IN_GYRO + i] -= b
    if k[K_HAS_MAG] != 0.0:
        v0 = row[IN_MAG] - k[K_OFFSET]
        v1 = row[IN_MAG + 1] - k[K_OFFSET + 1]
        v2 = row[IN_MAG + 2] - k[K_OFFSET + 2]
        for i in range(3):
            row[IN_MAG + i] = k[K_MATRIX + 3 * i] * v0 + k[K_MATRIX + 3 * i + 1] * v1 + k[K_MATRIX + 3 * i + 2] * v2
    if k[K_HAS_REMAP] != 0.0:
        for base in (IN_GYRO, IN_ACCEL, IN_MAG):
            v0, v1, v2 = row[base], row[base + 1], row[base + 2]
            for i in range(3):
                row[base + i] = k[K_REMAP + 3 * i] * v0 + k[K_REMAP + 3 * i + 1] * v1 + k[K_REMAP + 3 * i + 2] * v2


@kernel
def calibrate_rows(rows, temperature_c, k):  # type: ignore[no-untyped-def]
    """:func:`calibrate_row` over every row."""
    for i in range(rows.shape[0]):
        calibrate_row(rows[i], temperature_c[i], k)
