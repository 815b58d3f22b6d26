"""firmware_sim's PX4 IMU messages are ``vehicle_imu``'s interval mean, not ArduPilot's low-passed snapshot.

PX4's HIGHRES_IMU and SCALED_IMU send ``vehicle_imu``'s Δθ / Δt: the mean of the calibrated sensor samples over
the integration interval, stamped with its last sample (``streams/HIGHRES_IMU.hpp``); PX4's IMU_GYRO_CUTOFF
filters the controllers' rate only.  Until px4h7 firmware_sim's PX4 applied ArduPilot's 20 Hz INS low-pass: its
gyro trailed the stamp by 12 ms (PX4 SITL: 2 ms), which the PX4 profile (delay 0) does not compensate, and that
made the 50 Hz SCALED_IMU look better than the 400 Hz HIGHRES_IMU (docs/accuracy.md round seven).
"""

from __future__ import annotations

import numpy as np

from firmware_sim.__main__ import build_parser, settings_from_args
from firmware_sim.fleet import fleet_sim_settings, mixed_fleet
from firmware_sim.imu_model import ImuErrorSettings
from firmware_sim.simulation import SimSettings, Simulation


def _settings(*args: str):
    return settings_from_args(build_parser().parse_args(list(args)))[0]


def test_the_px4_command_line_sends_the_interval_mean_without_the_ins_low_pass() -> None:
    px4 = _settings("--autopilot", "px4")
    assert px4.imu_sample == "interval_mean" and px4.imu.gyro_lowpass_hz == 0.0 and px4.imu.accel_lowpass_hz == 0.0
    ap = _settings()
    assert ap.imu_sample == "snapshot" and ap.imu.gyro_lowpass_hz == 20.0 and ap.imu.accel_lowpass_hz == 20.0
    assert _settings("--autopilot", "px4", "--gyro-lowpass-hz", "30").imu.gyro_lowpass_hz == 30.0  # as given


def _blocks(sim: Simulation, sizes: list[int]):
    blks = [sim.next_block(n) for n in sizes]
    t = np.concatenate([b.truth.t_s for b in blks])
    gyro = np.concatenate([b.gyro_rad_s[0] for b in blks])
    true = np.concatenate([b.truth.gyro_rad_s for b in blks])
    return t, gyro, true


def _best_lag_ms(t, gyro, true) -> float:
    """The lag (ms) by which the reported gyro best matches the true rate: gyro(t) ≈ true(t − lag)."""
    lags = np.arange(-3.0, 20.01, 0.25)
    k = t > 1.0
    rms = [np.sqrt(np.mean([(gyro[k, a] - np.interp(t[k] - lag * 1e-3, t, true[:, a])) ** 2 for a in range(3)]))
           for lag in lags]  # fmt: skip
    return float(lags[int(np.argmin(rms))])


def test_the_interval_mean_trails_its_stamp_by_half_an_interval_whatever_the_block_sizes() -> None:
    ideal = ImuErrorSettings.ideal(lowpass=False)
    px4 = SimSettings(scenario="aggressive", seed=1, imu=ideal, imu_sample="interval_mean")
    t, gyro, true = _blocks(Simulation(px4), [1, 7, 400, 1, 1192])  # 4 s in odd blocks
    t1, gyro1, _ = _blocks(Simulation(px4), [1601])
    assert np.array_equal(t, t1) and np.allclose(gyro, gyro1, rtol=0.0, atol=1e-12)
    # the mean of the 3 sensor samples ending at the tick (1200 Hz): (3 − 1)/2 samples = 0.83 ms behind
    assert 0.25 <= _best_lag_ms(t, gyro, true) <= 1.5
    snap = SimSettings(scenario="aggressive", seed=1, imu=ImuErrorSettings.ideal(lowpass=True))
    assert 8.0 <= _best_lag_ms(*_blocks(Simulation(snap), [1601])) <= 14.0  # ArduPilot's 20 Hz low-pass


def test_the_simulated_fleet_s_px4_vehicles_send_what_the_px4_command_line_sends() -> None:
    """The fleet's PX4 flights (every fifth) had ArduPilot's 20 Hz snapshot: 12 ms of gyro lag behind a profile of 0."""
    fleet = mixed_fleet(10)
    px4 = [fleet_sim_settings(log) for log in fleet if log.autopilot == "px4"]
    ap = [fleet_sim_settings(log) for log in fleet if log.autopilot != "px4"]
    assert px4 and ap
    cli = _settings("--autopilot", "px4")
    for s in px4:
        assert (s.imu_sample, s.imu.gyro_lowpass_hz, s.imu.accel_lowpass_hz) == (
            cli.imu_sample, cli.imu.gyro_lowpass_hz, cli.imu.accel_lowpass_hz)
    assert all(s.imu_sample == "snapshot" and s.imu.gyro_lowpass_hz == 20.0 for s in ap)
