"""Simulator recordings for the evaluation, replay and tuning tests (written once per session)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

#: The gyro temperature coefficient configured for the temperature recording, rad/s per °C.
TEMPCO_RAD_S_PER_C = (math.radians(0.03), math.radians(-0.025), math.radians(0.02))


def write_sim_tlog(path: Path, *args: str, imu_changes: dict[str, object] | None = None) -> Path:
    """``python -m firmware_sim --tlog PATH --fast ARGS`` in-process, optionally changing the IMU model."""
    fs_main = pytest.importorskip("firmware_sim.__main__")
    from firmware_sim.endpoint import Endpoint
    from firmware_sim.simulation import Simulation
    from firmware_sim.streamer import write_tlog

    parser = fs_main.build_parser()
    ns = parser.parse_args(["--tlog", str(path), "--fast", "-q", *args])
    sim, ep = fs_main.settings_from_args(ns)
    if imu_changes:
        sim = replace(sim, imu=replace(sim.imu, **imu_changes))
    write_tlog(Endpoint(Simulation(sim), ep), str(path), ns.duration)
    return path


@pytest.fixture(scope="session")
def sim_hover_tlog(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 s of hover from the simulator: RAW_IMU + a live SCALED_IMU2 at 250 Hz, SIMSTATE truth."""
    return write_sim_tlog(
        tmp_path_factory.mktemp("sim") / "hover.tlog", "--scenario", "hover", "--duration", "20", "--seed", "3"
    )


@pytest.fixture(scope="session")
def sim_temperature_tlog(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, tuple[float, float, float]]:
    """The simulator's ``temperature`` scenario (warm-up 10 → 50 °C, τ 40 s) with a known gyro tempco:
    (tlog path, the configured coefficient in rad/s per °C)."""
    path = write_sim_tlog(
        tmp_path_factory.mktemp("sim") / "temperature.tlog",
        "--scenario", "temperature", "--duration", "120", "--seed", "5", "--imus", "1",
        imu_changes={"gyro_temp_coeff_rad_s_per_c": TEMPCO_RAD_S_PER_C},
    )  # fmt: skip
    return path, TEMPCO_RAD_S_PER_C


def make_synthetic_recording(n_s: float = 60.0, fs: float = 100.0, seed: int = 7):
    """A sensor turning about all axes (smooth random rates, 0.3 rad/s scale) with exact gyro,
    accelerometer (specific force) and magnetometer and its true attitude as the reference; rests
    for the first and last 5 s."""
    import numpy as np

    from mavahrs.evaluation.datasets import Recording
    from mavahrs.geometry.quaternion import conjugate, from_rotation_vector, multiply, rotate

    rng = np.random.default_rng(seed)
    n = int(n_s * fs)
    dt = 1.0 / fs
    t = np.arange(n) * dt
    rate = np.zeros((n, 3))
    for k in range(3):
        for _ in range(3):
            f, ph, a = rng.uniform(0.05, 0.4), rng.uniform(0, 2 * np.pi), rng.uniform(0.1, 0.4)
            rate[:, k] += a * np.sin(2 * np.pi * f * t + ph)
    rate[(t < 5) | (t > n_s - 5)] = 0.0
    q = np.empty((n, 4))
    q[0] = [1.0, 0, 0, 0]
    steps = from_rotation_vector(rate * dt)
    for i in range(1, n):
        q[i] = multiply(q[i - 1], steps[i])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    accel = rotate(conjugate(q), np.array([0.0, 0.0, -9.80665]))
    mag = rotate(conjugate(q), np.array([20.0, 0.0, 45.0]))
    return Recording("synthetic", np.full(n, dt), rate, accel, mag, q, np.ones(n, bool), extra={"time_s": t})


@pytest.fixture(scope="session")
def synthetic_recording():
    return make_synthetic_recording()
