"""Applying the gyro temperature model, magnetometer calibration and axis remap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.errors import ConfigError
from mavahrs.filters.layout import IN_ACCEL, IN_GYRO, IN_MAG
from mavahrs.sensors.calibration import CalibrationSettings, Calibrator, GyroTemperatureModel, MagCalibration
from mavahrs.sensors.sample import ImuSample

SAMPLE = ImuSample(
    t_us=0, gyro_rad_s=(0.1, 0.1, 0.1), accel_m_s2=(1.0, 2.0, -9.0), mag_ut=(30.0, 5.0, 12.0),
    temperature_c=35.0, imu_id=0, source="RAW_IMU",
)  # fmt: skip
GYRO_MODEL = GyroTemperatureModel(b0_rad_s=(0.01, 0.0, 0.0), k_rad_s_per_c=(0.001, 0.0, -0.002), t0_c=25.0)
MAG_CAL = MagCalibration(offset_ut=(10.0, -5.0, 2.0), matrix=((2.0, 0, 0), (0, 1.0, 0), (0, 0, 0.5)))


def test_gyro_temperature_bias_linear_model():
    assert GYRO_MODEL.bias_rad_s(35.0) == pytest.approx((0.02, 0.0, -0.02))
    assert GYRO_MODEL.bias_rad_s(None) == (0.01, 0.0, 0.0)  # unknown temperature: b0
    out = Calibrator(CalibrationSettings(gyro_temperature=GYRO_MODEL)).apply(SAMPLE)
    assert out.gyro_rad_s == pytest.approx((0.08, 0.1, 0.12))
    assert out.accel_m_s2 == SAMPLE.accel_m_s2 and out.mag_ut == SAMPLE.mag_ut


def test_mag_hard_soft_iron():
    out = Calibrator(CalibrationSettings(mag=MAG_CAL)).apply(SAMPLE)
    assert out.mag_ut == pytest.approx((40.0, 10.0, 5.0))  # M·(m − o)


def test_mag_calibration_not_applied_twice():
    cal = Calibrator(CalibrationSettings(mag=MAG_CAL), mag_already_calibrated=True)
    assert not cal.mag_calibration_applied
    assert cal.apply(SAMPLE).mag_ut == SAMPLE.mag_ut
    forced = Calibrator(CalibrationSettings(mag=MAG_CAL, force_mag_calibration=True), mag_already_calibrated=True)
    assert forced.apply(SAMPLE).mag_ut == pytest.approx((40.0, 10.0, 5.0))


def test_axis_remap_after_calibration():
    s = CalibrationSettings(axis_remap="-x-y+z", mag=MAG_CAL)  # yaw 180°
    out = Calibrator(s).apply(SAMPLE)
    assert out.gyro_rad_s == pytest.approx((-0.1, -0.1, 0.1))
    assert out.accel_m_s2 == pytest.approx((-1.0, -2.0, -9.0))
    assert out.mag_ut == pytest.approx((-40.0, -10.0, 5.0))  # calibrated in sensor axes, then remapped


def test_row_path_equals_sample_path():
    s = CalibrationSettings(axis_remap="+y-x+z", gyro_temperature=GYRO_MODEL, mag=MAG_CAL)
    cal = Calibrator(s)
    row = SAMPLE.to_row(dt_s=0.01)
    cal.apply_row(row, SAMPLE.temperature_c)
    ref = cal.apply(SAMPLE)
    assert row[IN_GYRO : IN_GYRO + 3] == pytest.approx(ref.gyro_rad_s)
    assert row[IN_ACCEL : IN_ACCEL + 3] == pytest.approx(ref.accel_m_s2)
    assert row[IN_MAG : IN_MAG + 3] == pytest.approx(ref.mag_ut)
    # body x = sensor +y, body y = sensor −x
    assert ref.accel_m_s2 == pytest.approx((2.0, -1.0, -9.0))


def test_nothing_configured_is_inactive_and_identity():
    cal = Calibrator()
    assert not cal.active
    assert cal.apply(SAMPLE) is SAMPLE
    row = SAMPLE.to_row()
    before = row.copy()
    cal.apply_row(row, 20.0)
    np.testing.assert_array_equal(np.nan_to_num(row, nan=-1), np.nan_to_num(before, nan=-1))


def test_absent_mag_stays_absent():
    s = ImuSample(0, (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), None, None, 0, "RAW_IMU")
    out = Calibrator(CalibrationSettings(axis_remap="-x-y+z", mag=MAG_CAL)).apply(s)
    assert out.mag_ut is None
    row = s.to_row()
    Calibrator(CalibrationSettings(mag=MAG_CAL)).apply_row(row, None)
    assert all(math.isnan(x) for x in row[IN_MAG : IN_MAG + 3])


@pytest.mark.parametrize(
    "make",
    [
        lambda: CalibrationSettings(axis_remap="+x+x+z"),
        lambda: MagCalibration(matrix=((1, 0, 0), (0, 1, 0), (0, 0, 0))),
        lambda: MagCalibration(offset_ut=(1.0, 2.0)),
        lambda: GyroTemperatureModel(b0_rad_s=(0.0, math.nan, 0.0)),
    ],
)
def test_invalid_settings_rejected(make):
    with pytest.raises(ConfigError):
        make()
