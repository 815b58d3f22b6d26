"""Raw-IMU, magnetic-anomaly and IMU-fault scenarios: each option's effect against the known truth."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from firmware_sim.__main__ import build_parser, main, settings_from_args
from firmware_sim.imu_model import ImuErrorSettings, MagSettings
from firmware_sim.simulation import ImuFault, MagAnomaly, SimSettings, Simulation
from firmware_sim.vehicle import G
from mavahrs.geometry import quaternion as quat
from mavahrs.geometry.rotation import from_euler_rad, to_matrix


def _tlog(tmp_path: Path, *args: str, duration: float = 4.0) -> dict[str, list]:
    """Write a --fast tlog with ``args`` and return its messages by type (in order)."""
    path = tmp_path / "sim.tlog"
    assert main(["--tlog", str(path), "--fast", "-q", "--duration", str(duration), *args]) == 0
    out: dict[str, list] = defaultdict(list)
    mlog = mavutil.mavlink_connection(str(path))
    try:
        while (m := mlog.recv_match()) is not None:
            out[m.get_type()].append(m)
    finally:
        mlog.close()
    path.unlink()
    return out


def _gyro_rad_s(msgs: list, highres: bool = False) -> np.ndarray:
    if highres:
        return np.array([[m.xgyro, m.ygyro, m.zgyro] for m in msgs])
    return np.array([[m.xgyro, m.ygyro, m.zgyro] for m in msgs]) * 1e-3


def _accel_m_s2(msgs: list) -> np.ndarray:
    return np.array([[m.xacc, m.yacc, m.zacc] for m in msgs]) * (G / 1000.0)


def _true_rates(msgs: list) -> np.ndarray:
    return np.array([[m.xgyro, m.ygyro, m.zgyro] for m in msgs])


def _settings(*args: str) -> SimSettings:
    return settings_from_args(build_parser().parse_args(["--tlog", "x.tlog", "--fast", *args]))[0]


# ---------------------------------------------------------------------------------------- gyro bias
def test_fixed_gyro_bias_is_in_the_stream(tmp_path: Path) -> None:
    msgs = _tlog(tmp_path, "--scenario", "hover", "--seed", "2", "--gyro-bias-dps", "3,-2,1.5")
    raw, sim2, truth = msgs["RAW_IMU"], msgs["SCALED_IMU2"], msgs["SIMSTATE"]
    assert len(raw) == len(truth) == len(sim2) > 500  # the bench preset sends all three in the same ticks
    for imu in (raw, sim2):
        err_dps = np.degrees((_gyro_rad_s(imu) - _true_rates(truth)).mean(axis=0))
        np.testing.assert_allclose(err_dps, [3.0, -2.0, 1.5], atol=0.15)


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_raw_preset_streams_the_uncalibrated_bias_drawn_from_the_seed(tmp_path: Path, autopilot: str) -> None:
    args = ("--scenario", "rest", "--seed", "4", "--imu-preset", "raw", "--autopilot", autopilot)
    drawn_dps = np.degrees(Simulation(_settings(*args)).imus[0].gyro_bias0_rad_s)
    assert np.all(np.abs(drawn_dps) <= 5.0) and np.abs(drawn_dps).max() > 1.0
    msgs = _tlog(tmp_path, *args, duration=3.0)
    imu = msgs["HIGHRES_IMU"] if autopilot == "px4" else msgs["RAW_IMU"]
    err_dps = np.degrees(_gyro_rad_s(imu, highres=autopilot == "px4").mean(axis=0))  # at rest the truth is 0
    np.testing.assert_allclose(err_dps, drawn_dps, atol=0.1)
    # the calibrated default: only the residual bias is left
    calibrated = np.degrees(Simulation(_settings("--scenario", "rest", "--seed", "4")).imus[0].gyro_bias0_rad_s)
    assert np.abs(calibrated).max() < 0.5


def test_raw_preset_bias_bounded_and_different_per_seed_and_imu() -> None:
    biases = []
    for seed in range(6):
        sim = Simulation(SimSettings(scenario="rest", seed=seed, imu=ImuErrorSettings.raw()))
        biases.extend(np.degrees(imu.gyro_bias0_rad_s) for imu in sim.imus)
    b = np.array(biases)
    assert np.all(np.abs(b) <= 5.0)
    assert np.abs(b).max() > 3.5  # uniform in ±5: the largest of 36 draws is near the bound
    assert len({tuple(np.round(r, 6)) for r in b}) == len(b)


# ---------------------------------------------------------------------------------------- mounting
@pytest.mark.parametrize("mount_deg", [(0.0, 90.0, 0.0), (30.0, -20.0, 135.0)])
def test_mounted_imu_measures_in_its_own_axes(tmp_path: Path, mount_deg: tuple[float, float, float]) -> None:
    text = ",".join(str(v) for v in mount_deg)
    msgs = _tlog(tmp_path, "--scenario", "rest", "--seed", "1", "--imu-mount-deg", text, duration=2.0)
    c_imu_to_body = to_matrix(from_euler_rad(*np.radians(mount_deg)))
    truth_body = np.array([[m.xacc, m.yacc, m.zacc] for m in msgs["SIMSTATE"]]).mean(axis=0)
    assert truth_body[2] < -9.7  # the truth stays the body's: level, specific force up
    acc = _accel_m_s2(msgs["RAW_IMU"]).mean(axis=0)
    np.testing.assert_allclose(acc, c_imu_to_body.T @ truth_body, atol=0.2)  # accel bias σ 0.05 m/s², scale 0.2 %
    if mount_deg == (0.0, 90.0, 0.0):  # "x up": the x axis reads +1 g at rest
        assert acc[0] > 9.6 and abs(acc[1]) < 0.4 and abs(acc[2]) < 0.4


def test_mounted_imu_gyro_in_flight_is_the_rotated_body_rate() -> None:
    mount = (0.0, 90.0, 0.0)
    sim = Simulation(SimSettings(scenario="aggressive", seed=3, start_in_motion=True, imu_mount_deg=mount,
                                 imu=ImuErrorSettings.ideal()))
    blk = sim.next_block(1600)
    c = to_matrix(from_euler_rad(*np.radians(mount)))
    expected = blk.truth.gyro_rad_s @ c  # rows: Cᵀ ω
    assert np.abs(blk.truth.gyro_rad_s).max() > 0.5  # it manoeuvres
    np.testing.assert_allclose(blk.gyro_rad_s[0], expected, atol=1e-9)
    np.testing.assert_allclose(blk.gyro_rad_s[0][:, 0], -blk.truth.gyro_rad_s[:, 2], atol=1e-9)  # x up: x = −z_body


# ---------------------------------------------------------------------------------------- start in motion
def test_start_in_motion_has_no_rest_period(tmp_path: Path) -> None:
    sim = Simulation(SimSettings(scenario="hover", seed=5, start_in_motion=True))
    blk = sim.next_block(400)
    tr = blk.truth
    assert tr.thrust_m_s2[0] > 0.5 * G  # rotors spinning from the first tick
    assert np.linalg.norm(tr.vel_ned_m_s[0, :2]) >= 2.0 and -tr.pos_ned_m[0, 2] == pytest.approx(10.0)
    rest = Simulation(SimSettings(scenario="hover", seed=5)).next_block(400)
    assert np.all(rest.truth.thrust_m_s2 == 0.0) and np.all(rest.truth.vel_ned_m_s == 0.0)
    # motor vibration from t = 0: the raw accelerometer (no low-pass) scatters around the truth
    raw = Simulation(SimSettings(scenario="hover", seed=5, start_in_motion=True,
                                 imu=ImuErrorSettings(gyro_lowpass_hz=0.0, accel_lowpass_hz=0.0))).next_block(100)
    assert np.std(raw.accel_m_s2[0][:, 2] - raw.truth.accel_m_s2[:, 2]) > 0.5
    msgs = _tlog(tmp_path, "--scenario", "hover", "--seed", "5", "--start-in-motion", duration=1.0)
    hb = msgs["HEARTBEAT"][0]
    assert hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_start_in_motion_refused_for_rest() -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--tlog", "x.tlog", "--fast", "--scenario", "rest", "--start-in-motion"])
    assert exc.value.code == 2


# ---------------------------------------------------------------------------------------- no GNSS
def test_no_gnss_sends_no_gnss_messages(tmp_path: Path) -> None:
    args = ("--scenario", "hover", "--stream", "GPS_RAW_INT=10", "--stream", "GLOBAL_POSITION_INT=10")
    with_gnss = _tlog(tmp_path, *args, duration=2.0)
    assert with_gnss["GLOBAL_POSITION_INT"] and with_gnss["GPS_RAW_INT"]
    without = _tlog(tmp_path, *args, "--no-gnss", duration=2.0)
    assert not without["GLOBAL_POSITION_INT"] and not without["GPS_RAW_INT"]
    assert len(without["RAW_IMU"]) == len(with_gnss["RAW_IMU"]) > 0 and without["SIMSTATE"]
    assert not without["SYS_STATUS"][0].onboard_control_sensors_present & mavutil.mavlink.MAV_SYS_STATUS_SENSOR_GPS


# ---------------------------------------------------------------------------------------- magnetic anomaly
def test_anomaly_decays_with_height_and_motor_field_scales_with_current() -> None:
    s = SimSettings(scenario="mag_anomaly", seed=1, mag=MagSettings.ideal(), imu=ImuErrorSettings.ideal())
    sim = Simulation(s)
    blk = sim.next_block(400 * 24)  # 10 s on the ground, then the climb to 25 m
    fresh = blk.mag_fresh[0]
    q = blk.truth.q_body_to_ned[fresh]
    mag = blk.mag_ut[0][fresh]
    current = blk.current_a[fresh]
    height = -blk.truth.pos_ned_m[fresh, 2]
    earth_body = quat.rotate(quat.conjugate(q), np.broadcast_to(s.earth_field.ned_ut(), (q.shape[0], 3)))
    resid = mag - earth_body
    anomaly = sim.mag_anomaly
    assert anomaly == MagAnomaly((8.0, -6.0, 12.0), 5.0)
    # the motor part: body field per amp times the simulated current
    motor = current[:, None] * np.array([0.4, -0.3, 0.8])[None, :]
    anomaly_ned = quat.rotate(q, resid - motor)
    scale = (5.0 / (np.maximum(height, 0.0) + 5.0)) ** 3
    np.testing.assert_allclose(anomaly_ned, scale[:, None] * np.array([8.0, -6.0, 12.0]), atol=0.3)
    ground, high = height < 0.05, height > 20.0
    assert ground.sum() > 500 and high.sum() > 50
    assert np.linalg.norm(anomaly_ned[ground].mean(axis=0)) > 15.0
    assert np.linalg.norm(anomaly_ned[high], axis=1).max() < 0.02 * 15.6 + 0.3
    # the motor field: regress what is left after the anomaly on the current (slope = µT/A, no offset)
    left = resid - quat.rotate(quat.conjugate(q), scale[:, None] * np.array([8.0, -6.0, 12.0]))
    air = ~ground
    assert current[air].max() - current[air].min() > 3.0  # the current varies in the climb
    design = np.column_stack([current[air], np.ones(air.sum())])
    coef, *_ = np.linalg.lstsq(design, left[air], rcond=None)
    np.testing.assert_allclose(coef[0], [0.4, -0.3, 0.8], atol=0.02)
    np.testing.assert_allclose(coef[1], 0.0, atol=0.3)


def test_mag_anomaly_current_on_the_wire(tmp_path: Path) -> None:
    msgs = _tlog(tmp_path, "--scenario", "mag_anomaly", "--seed", "1", duration=13.0)
    sys_status, battery = msgs["SYS_STATUS"], msgs["BATTERY_STATUS"]
    assert len(sys_status) == len(battery) > 100
    cur_a = np.array([m.current_battery for m in sys_status]) * 0.01
    np.testing.assert_array_equal([m.current_battery for m in battery], [m.current_battery for m in sys_status])
    assert np.all(cur_a[:90] == pytest.approx(0.4))  # on the ground, disarmed: avionics only
    assert 10.0 < np.median(cur_a[-20:]) < 30.0  # climbing: ~15 A × (thrust/g)^1.5
    consumed = [m.current_consumed for m in battery]
    assert consumed[-1] > consumed[0] and all(b >= a for a, b in zip(consumed, consumed[1:], strict=False))
    # the compass on the ground carries the anomaly: compare with the same flight without it
    plain = _tlog(tmp_path, "--scenario", "mag_anomaly", "--seed", "1", "--mag-anomaly-ut", "0,0,0", duration=2.0)
    n = len(plain["RAW_IMU"])
    with_anomaly = np.array([[m.xmag, m.ymag, m.zmag] for m in msgs["RAW_IMU"][:n]], dtype=float)
    without = np.array([[m.xmag, m.ymag, m.zmag] for m in plain["RAW_IMU"]], dtype=float)
    diff_ut = (with_anomaly - without).mean(axis=0) * 0.1
    assert np.linalg.norm(diff_ut) == pytest.approx(np.linalg.norm([8.0, -6.0, 12.0]), abs=0.6)


# ---------------------------------------------------------------------------------------- IMU fault
def test_imu_fault_steps_the_gyro_bias_of_imu1_only(tmp_path: Path) -> None:
    msgs = _tlog(tmp_path, "--scenario", "hover", "--seed", "6", "--imu-fault", "imu1:gyro_bias_dps=2:at=2")
    truth = _true_rates(msgs["SIMSTATE"])
    t_s = np.array([m.time_boot_ms for m in msgs["SCALED_IMU2"]]) * 1e-3
    before, after = t_s < 1.99, t_s > 2.05
    for name, step in (("RAW_IMU", 0.0), ("SCALED_IMU2", 2.0)):
        err_dps = np.degrees(_gyro_rad_s(msgs[name]) - truth)
        change = err_dps[after].mean(axis=0) - err_dps[before].mean(axis=0)
        np.testing.assert_allclose(change, [step] * 3, atol=0.15, err_msg=name)
    # the step comes at the tick of 2 s: the known bias jumps there, IMU 0's does not
    sim = Simulation(_settings("--scenario", "hover", "--seed", "6", "--imu-fault", "imu1:gyro_bias_dps=2:at=2"))
    blk = sim.next_block(1200)
    k = int(np.argmax(blk.truth.t_s >= 2.0))
    jump = np.degrees(blk.gyro_bias_rad_s[:, k] - blk.gyro_bias_rad_s[:, k - 1])
    np.testing.assert_allclose(jump[1], [2.0] * 3, atol=0.01)
    np.testing.assert_allclose(jump[0], [0.0] * 3, atol=0.01)


def test_imu_fault_option_parsing() -> None:
    sim = _settings("--imu-fault", "imu1:gyro_bias_dps=1,-2,3:accel_bias_m_s2=0.5:at=30")
    f = sim.imu_fault
    assert f == ImuFault(instance=1, step_at_s=30.0,
                         gyro_bias_step_rad_s=tuple(math.radians(v) for v in (1.0, -2.0, 3.0)),  # type: ignore[arg-type]
                         accel_bias_step_m_s2=(0.5, 0.5, 0.5))
    both = _settings("--imu-fault", "imu1:gyro_bias_dps=2:at=5", "--imu2-freeze-at", "9")
    assert both.imu_fault is not None and both.imu_fault.freeze_at_s == 9.0 and both.imu_fault.step_at_s == 5.0


@pytest.mark.parametrize(
    "value",
    ["imu1:gyro_bias_dps=2", "imu5:gyro_bias_dps=2:at=1", "imu1:bias=2:at=1", "imu1:gyro_bias_dps=1,2:at=1",
     "imu1:at=3", "imu2:gyro_bias_dps=2:at=1"],
)
def test_bad_imu_fault_exits_2(value: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--tlog", "x.tlog", "--fast", "--imus", "2", "--imu-fault", value])
    assert exc.value.code == 2
    assert "imu" in capsys.readouterr().err


def test_help_documents_the_scenario_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    for text in ("--gyro-bias-dps", "deg/s", "--imu-preset", "--imu-mount-deg", "--start-in-motion", "--no-gnss",
                 "--mag-anomaly-ut", "--mag-anomaly-height-m", "--mag-motor-ut-per-a", "uT/A", "--imu-fault",
                 "--hover-current-a", "mag_anomaly"):
        assert text in out, text
