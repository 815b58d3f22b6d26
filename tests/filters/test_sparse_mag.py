"""A magnetometer on a few rows only (PX4's HIGHRES_IMU field: NaN between readings) still holds the heading.

The gain schedule's magnetometer weight recovers after a rejected reading over ``recovery_s`` of the
magnetometer's own time: measured in rows, a reading every 18th sample made the 0.5 s recovery last
about 9 s, and an occasional dip outlier (vibration, a manoeuvre) left the heading on the gyro alone.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.filters import create
from mavahrs.filters.layout import IN_ACCEL, IN_DT, IN_GYRO, IN_MAG, IN_WIDTH, OUT_MAG_WEIGHT, OUT_Q

DT_S = 0.004  # 250 Hz IMU rows
MAG_EVERY = 18  # a reading on every 18th row (≈ 14 Hz)
OUTLIER_EVERY = 500  # every 2 s one reading whose dip is 10° off
BIAS_Z_RAD_S = math.radians(0.5)  # unobservable at rest but for the magnetometer


def _rows(duration_s: float = 60.0) -> np.ndarray:
    rng = np.random.default_rng(4)
    n = int(duration_s / DT_S)
    rows = np.full((n, IN_WIDTH), np.nan)
    rows[:, IN_DT] = DT_S
    rows[:, IN_GYRO : IN_GYRO + 3] = rng.normal(0.0, 0.002, (n, 3))
    rows[:, IN_GYRO + 2] += BIAS_Z_RAD_S
    rows[:, IN_ACCEL : IN_ACCEL + 3] = rng.normal(0.0, 0.05, (n, 3)) + (0.0, 0.0, -9.80665)
    dip = math.radians(60.0)
    field = 48.0 * np.array([math.cos(dip), 0.0, math.sin(dip)])  # level, heading 0: body = NED
    bad = math.radians(70.0)
    outlier = 48.0 * np.array([math.cos(bad), 0.0, math.sin(bad)])
    idx = np.arange(0, n, MAG_EVERY)
    rows[idx, IN_MAG : IN_MAG + 3] = field + rng.normal(0.0, 0.3, (len(idx), 3))
    out_idx = idx[(idx % OUTLIER_EVERY) < MAG_EVERY]
    rows[out_idx, IN_MAG : IN_MAG + 3] = outlier
    return rows


@pytest.mark.parametrize("name", ["eskf", "complementary", "mahony"])
def test_sparse_readings_keep_the_magnetometer_in_use(name: str) -> None:
    rows = _rows()
    out = create(name).run(rows)
    have = np.isfinite(rows[:, IN_MAG])
    late = have & (np.arange(len(rows)) * DT_S > 10.0)
    # between outliers 2 s apart the weight is back above ½ for most of the time (rows: ~0.05)
    assert np.mean(out[late, OUT_MAG_WEIGHT] >= 0.5) > 0.6
    q = out[:, OUT_Q : OUT_Q + 4]
    yaw = np.degrees(np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2)))
    keep = np.arange(len(rows)) * DT_S > 10.0
    # the gyro's 0.5 °/s left alone would take the heading 25° away over the 50 s
    assert np.sqrt(np.mean(yaw[keep] ** 2)) < 3.0
