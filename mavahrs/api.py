"""The one-call public API: :func:`estimate`."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.filters import create
from mavahrs.filters.base import FilterSettings, make_inputs
from mavahrs.filters.layout import OUT_Q

__all__ = ["estimate"]


def estimate(
    gyro_rad_s: ArrayLike,
    accel_m_s2: ArrayLike,
    mag_ut: ArrayLike | None = None,
    *,
    dt_s: float | ArrayLike,
    filter: str = "madgwick",  # noqa: A002 - the documented keyword
    settings: FilterSettings | None = None,
    velocity_ned_m_s: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Estimate the attitude of a whole recording.

    Args:
        gyro_rad_s: (N, 3) angular rate, rad/s, in the sensor's own axes.
        accel_m_s2: (N, 3) specific force, m/s² (at rest it points up: a level
            FRD sensor reads about (0, 0, −9.81)).
        mag_ut: (N, 3) magnetic field, µT, or ``None`` for 6-axis estimation.
        dt_s: sample interval(s), s: a float or an (N,) array (the first
            value is the interval before the first sample; it is not used).
        filter: one of ``mavahrs.filters.NAMES`` or ``"best"``.
        settings: that filter's settings dataclass; defaults if ``None``.
        velocity_ned_m_s: optional (N, 3) GNSS velocity in NED, NaN rows where
            there is no fix (used by filters that compensate acceleration).

    Returns:
        (N, 4) scalar-first quaternions rotating body (sensor) vectors into NED.
    """
    inputs = make_inputs(gyro_rad_s, accel_m_s2, mag_ut, dt_s=dt_s, velocity_ned_m_s=velocity_ned_m_s)
    n = inputs.shape[0]
    for name, arr in (("accel_m_s2", accel_m_s2), ("mag_ut", mag_ut), ("velocity_ned_m_s", velocity_ned_m_s)):
        if arr is not None and np.atleast_2d(np.asarray(arr)).shape != (n, 3):
            raise ValueError(f"{name} must have shape ({n}, 3) like gyro_rad_s, got {np.shape(arr)}")
    out = create(filter, settings).run(inputs)
    return out[:, OUT_Q : OUT_Q + 4].copy()
