"""The sample chain's compiled steps, each one implementation called per sample and looped over a log.

Scaling (:func:`~mavahrs.sensors.scaling.scale_int_row`), the rule for flagged vectors
(:func:`~mavahrs.sensors.sample.blank_unusable`) and calibration
(:func:`~mavahrs.sensors.calibration.calibrate_row`), against values computed by hand; the
batch forms are the same step in a loop, so they are checked on the same hand-computed rows.
"""

from __future__ import annotations

import math

import numpy as np

from mavahrs.filters.layout import IN_ACCEL, IN_GYRO, IN_MAG, IN_WIDTH
from mavahrs.sensors.calibration import (
    CalibrationSettings,
    Calibrator,
    GyroTemperatureModel,
    MagCalibration,
    calibrate_rows,
)
from mavahrs.sensors.profiles import get_profile
from mavahrs.sensors.sample import ACCEL, GYRO, MAG, blank_unusable_rows
from mavahrs.sensors.scaling import (
    INVALID_SHIFT,
    ZERO,
    ScalingSettings,
    scale_constants,
    scale_int_row,
    scale_int_rows,
)

G = 9.80665
AP_RAW = get_profile("ardupilot").scale_for("RAW_IMU")


def _scaled(raw: tuple[int, ...], ms=AP_RAW) -> tuple[np.ndarray, int]:  # type: ignore[no-untyped-def]
    row = np.full(IN_WIDTH, -1.0)
    code = scale_int_row(*raw, scale_constants(ms, ScalingSettings()), row)
    return row, int(code)


def test_raw_imu_scales_to_si_by_hand() -> None:
    # ArduPilot RAW_IMU: accel mg, gyro mrad/s, mag mGauss (0.1 µT)
    row, code = _scaled((100, -200, 300, 10, -20, -1000, 200, 30, -400))
    np.testing.assert_allclose(row[IN_GYRO : IN_GYRO + 3], (0.1, -0.2, 0.3), rtol=1e-15)
    np.testing.assert_allclose(row[IN_ACCEL : IN_ACCEL + 3], (0.01 * G, -0.02 * G, -G), rtol=1e-15)
    np.testing.assert_allclose(row[IN_MAG : IN_MAG + 3], (20.0, 3.0, -40.0), rtol=1e-15)
    assert code == 0


def test_flags_saturation_implausible_mag_absent_mag_and_an_absent_instance() -> None:
    row, code = _scaled((32767, 0, 0, 0, 0, -1000, 200, 30, -400))  # gyro at the int16 limit
    assert code & 7 == GYRO and row[IN_GYRO] == 32.767
    row, code = _scaled((0, 0, 0, 0, 0, -16 * 1000, 200, 30, -400))  # 16 g: at the profile's full scale
    assert code & 7 == ACCEL
    row, code = _scaled((1, 0, 0, 0, 0, -1000, 30000, 0, 0))  # 3000 µT: not the Earth's field
    assert (code >> INVALID_SHIFT) & 7 == MAG and np.all(np.isnan(row[IN_MAG : IN_MAG + 3]))
    row, code = _scaled((1, 0, 0, 0, 0, -1000, 0, 0, 0))  # no compass: absent, not invalid
    assert code == 0 and np.all(np.isnan(row[IN_MAG : IN_MAG + 3]))
    _, code = _scaled((0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert code & ZERO


def test_the_batch_form_is_the_step_over_each_message() -> None:
    raws = np.array([(100, -200, 300, 10, -20, -1000, 200, 30, -400), (32767, 0, 0, 0, 0, -1000, 30000, 0, 0),
                     (0, 0, 0, 0, 0, 0, 0, 0, 0)], np.int16)  # fmt: skip
    rows = np.empty((3, IN_WIDTH))
    codes = np.empty(3, np.int64)
    scale_int_rows(*(raws[:, j] for j in range(9)), scale_constants(AP_RAW, ScalingSettings()), rows, codes)
    np.testing.assert_allclose(rows[0, IN_ACCEL : IN_ACCEL + 3], (0.01 * G, -0.02 * G, -G), rtol=1e-15)
    assert codes.tolist() == [0, GYRO | (MAG << INVALID_SHIFT), ZERO]


def test_flagged_vectors_become_nan_a_saturated_gyro_stays() -> None:
    rows = np.ones((4, IN_WIDTH))
    sat = np.array([0, GYRO, ACCEL, 0], np.int64)
    inv = np.array([0, 0, 0, GYRO | MAG], np.int64)
    blank_unusable_rows(rows, sat, inv)
    assert np.all(rows[0] == 1.0) and np.all(rows[1] == 1.0)  # a saturated gyro is still integrated
    assert np.all(np.isnan(rows[2, IN_ACCEL : IN_ACCEL + 3])) and rows[2, IN_GYRO] == 1.0
    assert np.all(np.isnan(rows[3, IN_GYRO : IN_GYRO + 3])) and np.all(np.isnan(rows[3, IN_MAG : IN_MAG + 3]))
    assert np.all(rows[3, IN_ACCEL : IN_ACCEL + 3] == 1.0)


def test_calibration_by_hand() -> None:
    cal = Calibrator(CalibrationSettings(
        axis_remap="+y-x+z",
        gyro_temperature=GyroTemperatureModel((0.01, -0.02, 0.005), (1e-3, 2e-3, -3e-3), 30.0),
        mag=MagCalibration((5.0, -3.0, 12.0), ((2.0, 0.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, 1.0))),
    ))  # fmt: skip
    rows = np.zeros((2, IN_WIDTH))
    rows[:, IN_GYRO : IN_GYRO + 3] = (0.1, 0.2, 0.3)
    rows[:, IN_ACCEL : IN_ACCEL + 3] = (1.0, 2.0, 3.0)
    rows[:, IN_MAG : IN_MAG + 3] = (15.0, 7.0, 52.0)
    calibrate_rows(rows, np.array([40.0, math.nan]), cal.constants)
    # gyro at 40 °C: b = b0 + k·10 = (0.02, 0.0, -0.025); unknown temperature: b0
    g40 = (0.1 - 0.02, 0.2 - 0.0, 0.3 + 0.025)
    g_unknown = (0.1 - 0.01, 0.2 + 0.02, 0.3 - 0.005)
    m = (2.0 * 10.0, 0.5 * 10.0, 40.0)
    # "+y-x+z": body x = sensor y, body y = −sensor x
    for i, g in ((0, g40), (1, g_unknown)):
        np.testing.assert_allclose(rows[i, IN_GYRO : IN_GYRO + 3], (g[1], -g[0], g[2]), atol=1e-15)
        np.testing.assert_allclose(rows[i, IN_ACCEL : IN_ACCEL + 3], (2.0, -1.0, 3.0), atol=1e-15)
        np.testing.assert_allclose(rows[i, IN_MAG : IN_MAG + 3], (m[1], -m[0], m[2]), atol=1e-12)
    one = np.zeros(IN_WIDTH)
    one[IN_GYRO : IN_MAG + 3] = (0.1, 0.2, 0.3, 1.0, 2.0, 3.0, 15.0, 7.0, 52.0)
    cal.apply_row(one, 40.0)  # the pipeline's call: the same step
    np.testing.assert_array_equal(one, rows[0])
