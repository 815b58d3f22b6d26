"""A synthetic recording with exact sensors and truth, for the evaluation tests."""

from __future__ import annotations

import pytest


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
