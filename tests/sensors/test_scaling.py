"""Scaling of every IMU message and profile against hand-computed values."""

from __future__ import annotations

import math

import pytest

from mavahrs.errors import ScalingError
from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.sensors.profiles import (
    G_M_S2,
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    MAV_AUTOPILOT_PX4,
    PROFILES,
    get_profile,
    profile_for_autopilot,
)
from mavahrs.sensors.sample import ACCEL, GYRO, MAG, new_row
from mavahrs.sensors.scaling import Scaler, ScalingSettings, to_sample

ALL_BITS = 0x1FF


def raw_imu(t=123456, acc=(10, -20, -1000), gyro=(100, -200, 300), mag=(200, 0, 450), id=0, temp=3512):
    return mavlink.MAVLink_raw_imu_message(t, *acc, *gyro, *mag, id, temp)


def scaled(n, t_ms=1234, acc=(0, 0, -1000), gyro=(1, 2, 3), mag=(-100, 50, 400), temp=0):
    cls = {1: mavlink.MAVLink_scaled_imu_message, 2: mavlink.MAVLink_scaled_imu2_message,
           3: mavlink.MAVLink_scaled_imu3_message}[n]  # fmt: skip
    return cls(t_ms, *acc, *gyro, *mag, temp)


def highres(acc=(0.1, -0.2, -9.8), gyro=(0.01, 0.02, -0.03), mag=(0.2, 0.0, 0.45), bits=ALL_BITS, t=5_000_000, id=0):
    return mavlink.MAVLink_highres_imu_message(t, *acc, *gyro, *mag, 1013.0, 0.0, 12.0, 31.5, bits, id)


def test_ardupilot_raw_imu_hand_computed():
    v = Scaler("ardupilot").to_sample(raw_imu())
    assert v.t_us == 123456 and v.imu_id == 0 and v.source == "RAW_IMU"
    assert v.accel_m_s2 == pytest.approx((0.0980665, -0.196133, -9.80665))  # mG · 9.80665/1000
    assert v.gyro_rad_s == pytest.approx((0.1, -0.2, 0.3))  # mrad/s / 1000
    assert v.mag_ut == pytest.approx((20.0, 0.0, 45.0))  # mgauss / 10
    assert v.temperature_c == pytest.approx(35.12)  # cdegC / 100
    assert v.saturated == 0 and v.invalid == 0


def test_level_at_rest_is_minus_g_on_z():
    """MAVLink carries specific force: a level vehicle at rest reads z ≈ −1000 mG → −g."""
    v = Scaler("ardupilot").to_sample(raw_imu(acc=(0, 0, -1000)))
    assert v.accel_m_s2[2] == pytest.approx(-G_M_S2)


@pytest.mark.parametrize("n,imu", [(1, 0), (2, 1), (3, 2)])
@pytest.mark.parametrize("profile", ["ardupilot", "px4", "generic"])
def test_scaled_imu_instances_and_units(n, imu, profile):
    v = Scaler(profile).to_sample(scaled(n, temp=2550))
    assert v.imu_id == imu
    assert v.t_us == 1_234_000  # time_boot_ms · 1000
    assert v.accel_m_s2 == pytest.approx((0.0, 0.0, -G_M_S2))
    assert v.gyro_rad_s == pytest.approx((0.001, 0.002, 0.003))
    assert v.mag_ut == pytest.approx((-10.0, 5.0, 40.0))
    assert v.temperature_c == pytest.approx(25.5)


def test_temperature_zero_means_not_provided():
    assert Scaler("ardupilot").to_sample(scaled(2, temp=0)).temperature_c is None
    assert Scaler("ardupilot").to_sample(scaled(2, temp=1)).temperature_c == pytest.approx(0.01)


@pytest.mark.parametrize("profile", ["ardupilot", "px4", "generic"])
def test_highres_imu_si_and_gauss(profile):
    v = Scaler(profile).to_sample(highres(id=1))
    assert v.imu_id == 1 and v.t_us == 5_000_000
    assert v.accel_m_s2 == pytest.approx((0.1, -0.2, -9.8))
    assert v.gyro_rad_s == pytest.approx((0.01, 0.02, -0.03))
    assert v.mag_ut == pytest.approx((20.0, 0.0, 45.0))  # gauss · 100
    assert v.temperature_c is None  # HIGHRES_IMU temperature is the barometer's


def test_highres_fields_updated():
    s = Scaler("px4")
    assert s.scale(highres(bits=0x007 | 0x1C0)) is None  # no new gyro: not a sample
    v = s.to_sample(highres(bits=0x038 | 0x1C0))  # gyro + mag, accel not new
    assert all(math.isnan(a) for a in v.accel_m_s2) and v.mag_ut is not None
    v = s.to_sample(highres(bits=0x03F))  # mag not new
    assert v.mag_ut is None
    row = v.to_row()
    assert math.isnan(row[7]) and row[4] == pytest.approx(0.1)


def test_ardupilot_highres_legacy_mag_units_rescaled():
    """ArduPilot before PR #32286 sent HIGHRES_IMU mag as mgauss×1000."""
    legacy = highres(mag=(200_000.0, 0.0, 450_000.0))
    assert Scaler("ardupilot").to_sample(legacy).mag_ut == pytest.approx((20.0, 0.0, 45.0))
    v = Scaler("generic").to_sample(legacy)  # no such fallback: implausible → invalid
    assert v.invalid & MAG


def test_px4_raw_imu_accel_in_mm_s2():
    v = Scaler("px4").to_sample(raw_imu(acc=(0, 0, -9807)))
    assert v.accel_m_s2[2] == pytest.approx(-9.807)


def test_raw_imu_id_field_and_mavlink1_frames():
    assert Scaler("ardupilot").to_sample(raw_imu(id=2)).imu_id == 2
    # a MAVLink 1 frame has no id extension; pymavlink then exposes the class's message id (27)
    c = MavCodec(1, 1)
    frame = c.encode(raw_imu(id=0), force_mavlink1=True)
    (msg,) = MavCodec(2, 2).receive_datagram(frame)
    assert Scaler("ardupilot").to_sample(msg).imu_id == 0


def test_saturation_int16_and_full_scale():
    s = Scaler("ardupilot")
    assert s.to_sample(raw_imu(gyro=(32767, 0, 0))).saturated == GYRO
    assert s.to_sample(raw_imu(gyro=(0, -32768, 0))).saturated == GYRO
    assert s.to_sample(raw_imu(acc=(16000, 0, -1000))).saturated == ACCEL  # 16 g ≥ 98 % of 16 g
    assert s.to_sample(raw_imu(acc=(15000, 0, -1000))).saturated == 0  # 15 g < 15.68 g
    # a configured 8 g accelerometer saturates earlier
    s8 = Scaler("ardupilot", ScalingSettings(accel_range_g=8.0))
    assert s8.to_sample(raw_imu(acc=(7900, 0, -1000))).saturated == ACCEL
    # gyro full scale 2000 °/s = 34.9 rad/s: HIGHRES_IMU 35 rad/s is saturated, 5× is garbage
    assert Scaler("px4").to_sample(highres(gyro=(35.0, 0, 0))).saturated == GYRO
    assert Scaler("px4").to_sample(highres(gyro=(175.0, 0, 0))).invalid == GYRO


def test_nan_inf_marked_not_raised_unless_strict():
    s = Scaler("px4")
    v = s.to_sample(highres(acc=(math.nan, 0.0, -9.8)))
    assert v.invalid == ACCEL
    v = s.to_sample(highres(gyro=(0.0, math.inf, 0.0)))
    assert v.invalid == GYRO
    v = s.to_sample(highres(mag=(math.nan, 0.1, 0.4)))
    assert v.invalid == MAG
    with pytest.raises(ScalingError, match="invalid accel"):
        s.to_sample(highres(acc=(math.nan, 0.0, -9.8)), strict=True)
    with pytest.raises(ScalingError, match="saturated gyro"):
        Scaler("ardupilot").to_sample(raw_imu(gyro=(32767, 0, 0)), strict=True)


def test_invalid_and_saturated_vectors_become_nan_in_the_row():
    s = Scaler("px4")
    row = s.to_sample(highres(acc=(math.nan, 0.0, -9.8))).to_row(dt_s=0.0025)
    assert row[0] == 0.0025
    assert all(math.isnan(x) for x in row[4:7])  # accel correction skipped
    assert row[1:4].tolist() == pytest.approx([0.01, 0.02, -0.03])  # gyro kept
    row = Scaler("ardupilot").to_sample(raw_imu(acc=(16000, 0, -1000))).to_row(new_row())
    assert all(math.isnan(x) for x in row[4:7])  # saturated accel dropped
    row = Scaler("ardupilot").to_sample(raw_imu(gyro=(32767, 0, 0))).to_row()
    assert row[1] == pytest.approx(32.767)  # saturated gyro kept (best available)


def test_mag_all_zero_is_absent_not_invalid():
    v = Scaler("ardupilot").to_sample(raw_imu(mag=(0, 0, 0)))
    assert v.mag_ut is None and v.invalid == 0


def test_mag_implausible_norm_invalid():
    v = Scaler("ardupilot").to_sample(raw_imu(mag=(30000, 30000, 0)))  # 4243 µT
    assert v.invalid == MAG


def test_profile_from_heartbeat_and_calibration_facts():
    assert profile_for_autopilot(MAV_AUTOPILOT_ARDUPILOTMEGA).name == "ardupilot"
    assert profile_for_autopilot(MAV_AUTOPILOT_PX4).name == "px4"
    assert profile_for_autopilot(0).name == "generic"
    ap, px4 = get_profile("ardupilot"), get_profile("px4")
    assert ap.messages["RAW_IMU"].mag_calibrated  # ArduPilot sends the calibrated field
    assert not px4.messages["SCALED_IMU"].mag_calibrated  # PX4 SCALED_IMU mag is the raw sensor_mag
    assert px4.messages["HIGHRES_IMU"].sample_time and not ap.messages["RAW_IMU"].sample_time
    for p in PROFILES.values():
        for ms in p.messages.values():
            assert ms.source, f"{p.name}/{ms.message} has no source"


def test_unknown_message_and_profile():
    with pytest.raises(ScalingError):
        Scaler("ardupilot").scale(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3))
    with pytest.raises(ValueError, match="unknown autopilot profile"):
        Scaler("betaflight")


def test_to_sample_convenience_default_generic():
    assert to_sample(raw_imu()).gyro_rad_s == pytest.approx((0.1, -0.2, 0.3))


def test_real_tlogs_scale_to_gravity(mavlink_logs_dir):
    """Real ArduPilot RAW_IMU (dronekit flight, SITL vtol, ArduSub): |a| ≈ g, z ≈ −g near level."""
    from pymavlink import mavutil

    for rel in ("dronekit-python/flight.tlog", "UAVLogViewer/vtol.tlog", "ardusub_log_tools/small.tlog"):
        conn = mavutil.mavlink_connection(str(mavlink_logs_dir / rel), dialect="ardupilotmega")
        s = Scaler("ardupilot")
        norms = []
        while len(norms) < 20:
            msg = conn.recv_match(type="RAW_IMU")
            if msg is None:
                break
            v = s.to_sample(msg)
            norms.append(math.sqrt(sum(a * a for a in v.accel_m_s2)))
            assert v.imu_id == 0
        conn.close()
        assert len(norms) == 20
        assert sum(norms) / len(norms) == pytest.approx(G_M_S2, rel=0.1), rel
