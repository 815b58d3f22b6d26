"""The velocity's process noise from the specific force's slow error (``EskfSettings.slow_force_block_s``).

Known truth made here: a level, still IMU at 400 Hz whose accelerometer has white noise only, or white noise
and a slow tone on its vertical axis (a rotor's vibration aliased to 4 Hz).  White noise is what the measured
density already holds, so the slow-error term must add nothing (the Hadamard variance of block means of white
noise is σ²/n: IEEE Std 952-1997 annex C); the tone is an error that white noise does not describe, so the
velocity's variance must grow.  Bounds catch a regression (the excess not subtracted, or not added).
"""

from __future__ import annotations

import math

import numpy as np

from mavahrs.filters import create
from mavahrs.filters.base import S_FILTER, make_inputs
from mavahrs.filters.eskf import COVARIANCE_STATE, EskfSettings, N, slow_force_density_of
from mavahrs.filters.gains import G_M_S2

RATE_HZ = 400
SECONDS = 30.0


def _run(block_s: float, tone_m_s2: float):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(7)
    n = int(RATE_HZ * SECONDS)
    t = np.arange(n) / RATE_HZ
    accel = rng.normal(0.0, 0.05, (n, 3))
    accel[:, 2] += -G_M_S2 + tone_m_s2 * np.sin(2.0 * math.pi * 4.0 * t)
    gyro = rng.normal(0.0, 0.002, (n, 3))
    f = create("eskf", EskfSettings(slow_force_block_s=block_s))
    f.run(make_inputs(gyro, accel, None, dt_s=np.full(n, 1.0 / RATE_HZ)))
    return f


def _velocity_variance(block_s: float, tone_m_s2: float) -> float:
    p = _run(block_s, tone_m_s2).raw_state[S_FILTER + COVARIANCE_STATE : S_FILTER + COVARIANCE_STATE + N * N].reshape(N, N)
    return float(np.trace(p[3:6, 3:6]))


def test_white_accelerometer_noise_adds_no_slow_error() -> None:
    off = _velocity_variance(0.0, 0.0)
    on = _velocity_variance(0.1, 0.0)
    assert math.isclose(on, off, rel_tol=0.1)


def test_a_slow_tone_is_read_as_its_hadamard_variance() -> None:
    # a tone A sin(2π f₀ t): block means of length T have amplitude A·sinc(f₀T), their second difference
    # |1 − e^(−iωT)|² = 4 sin²(πf₀T) times that; ⅙ of its mean square, over three axes, times T
    a, f0, t_blk = 1.0, 4.0, 0.1
    amp = a * math.sin(math.pi * f0 * t_blk) / (math.pi * f0 * t_blk)
    expected = amp**2 / 2.0 * (4.0 * math.sin(math.pi * f0 * t_blk) ** 2) ** 2 / 6.0 / 3.0 * t_blk
    f = _run(t_blk, a)
    q = slow_force_density_of(f.raw_state, S_FILTER, f.params)
    assert math.isclose(q, expected, rel_tol=0.25)
    white = _run(t_blk, 0.0)
    assert slow_force_density_of(white.raw_state, S_FILTER, white.params) < 0.05 * expected
