"""Virtual gyro-platform (003): signs of the levelling law, separate channels, gating, GNSS, BROAD."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mavahrs.evaluation.metrics import attitude_errors_rad
from mavahrs.filters import create
from mavahrs.filters.base import make_inputs
from mavahrs.filters.gyroplatform import GyroPlatformSettings
from mavahrs.filters.layout import OUT_ACCEL_WEIGHT, OUT_GAIN, OUT_Q
from mavahrs.filters.rest import RestBiasSettings
from mavahrs.geometry.quaternion import (
    conjugate,
    from_axis_angle,
    from_rotation_vector,
    multiply,
    rotate,
)
from mavahrs.geometry.rotation import from_euler_rad

G = 9.80665
MAG_NED = np.array([20.0, 0.0, 45.0])
RATE_HZ = 200.0
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


def _plain(**kw: object) -> GyroPlatformSettings:
    """The paper's equations only: no start-up boost, no low-pass, no bias estimation."""
    base = GyroPlatformSettings()
    sched = dataclasses.replace(base.schedule, startup_s=0.0)
    return dataclasses.replace(
        base,
        schedule=sched,
        accel_lowpass_s=0.0,
        level_bias_gain=0.0,
        heading_bias_gain=0.0,
        rest=RestBiasSettings(bias_tau_s=0.0),
        **kw,
    )


def _rows(q_true: np.ndarray, gyro: np.ndarray, f_ned: np.ndarray, mag: bool) -> np.ndarray:
    n = gyro.shape[0]
    q_inv = conjugate(q_true)
    accel = rotate(q_inv, np.broadcast_to(f_ned, (n, 3)))
    m = rotate(q_inv, np.broadcast_to(MAG_NED, (n, 3))) if mag else None
    return make_inputs(gyro, accel, m, dt_s=1.0 / RATE_HZ)


def _start_from(settings: GyroPlatformSettings, rows: np.ndarray, q_start: np.ndarray) -> np.ndarray:
    f = create("gyroplatform", settings)
    f.run(rows[:1])
    s = f.state
    s.q_body_to_ned = q_start
    f.state = s
    return f.run(rows[1:])


def _static(n: int, mag: bool = False) -> np.ndarray:
    return _rows(LEVEL, np.zeros((n, 3)), np.array([0.0, 0.0, -G]), mag)


def test_one_step_applies_the_levelling_law_in_the_navigation_frame() -> None:
    """q ← exp(−ω′dt/2) ⊗ q with ω′_N = k f̂_E, ω′_E = −k f̂_N (003), checked to rounding."""
    k = 0.7
    settings = _plain(level_gain=k)
    q_est = from_axis_angle([1.0, 0.5, 0.0], math.radians(8.0))
    rows = _static(2)
    out = _start_from(settings, rows, q_est)
    f = rotate(q_est, np.array([0.0, 0.0, -G]))
    f /= np.linalg.norm(f)
    omega = np.array([k * f[1], -k * f[0], 0.0])
    expected = multiply(from_rotation_vector(-omega / RATE_HZ), q_est)
    np.testing.assert_allclose(out[0, OUT_Q : OUT_Q + 4], expected, atol=1e-12)


@pytest.mark.parametrize("axis", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, -0.8, 0.0]], ids=["N", "E", "NE"])
def test_the_platform_levels_itself(axis: list[float]) -> None:
    """θ̇ = −k sin θ: tan(θ/2) = tan(θ₀/2)·e^(−kt) — the tilt decays, it does not grow."""
    k = 0.5
    rows = _static(int(RATE_HZ / k) + 1)
    theta0 = math.radians(20.0)
    out = _start_from(_plain(level_gain=k), rows, from_axis_angle(axis, theta0))
    _, _, incl = attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], LEVEL)
    assert np.all(np.diff(incl) < 0)
    expected = 2 * math.atan(math.tan(theta0 / 2) * math.exp(-1.0))
    assert incl[-1] == pytest.approx(expected, rel=0.01)


def test_heading_channel_is_separate_from_levelling() -> None:
    """A 30° heading error is removed by ω′_D alone; the tilt never moves."""
    k = 0.5
    rows = _static(int(RATE_HZ / k) + 1, mag=True)
    psi0 = math.radians(30.0)
    out = _start_from(_plain(heading_gain=k), rows, from_axis_angle([0.0, 0.0, 1.0], psi0))
    _, heading, incl = attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], LEVEL)
    assert incl.max() < 1e-9
    expected = 2 * math.atan(math.tan(psi0 / 2) * math.exp(-1.0))
    assert heading[-1] == pytest.approx(expected, rel=0.01)


def test_turn_rate_gating_cuts_levelling_in_a_turn() -> None:
    n = int(6 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    rate = math.radians(90.0)
    q = from_euler_rad(np.zeros(n), np.zeros(n), rate * t)
    gyro = np.tile([0.0, 0.0, rate], (n, 1))
    rows = _rows(q, gyro, np.array([0.0, 0.0, -G]), mag=False)
    s = GyroPlatformSettings(turn_rate_limit_rad_s=math.radians(30.0))
    gated = create("gyroplatform", s).run(rows)
    free = create("gyroplatform").run(rows)
    after = t > s.schedule.startup_s + 0.5
    np.testing.assert_allclose(gated[after, OUT_GAIN], s.level_gain / 9.0, rtol=1e-6)
    np.testing.assert_allclose(free[after, OUT_GAIN], s.level_gain, rtol=1e-6)


def test_horizontal_specific_force_gating() -> None:
    """A sustained 0.3 g northward acceleration: gated, the platform stays level; ungated, it tilts.

    The accelerometer low-pass is off here: the gate sees the filtered force,
    so with a 1 s low-pass it closes only after the platform has begun to tilt
    (documented in docs/filters/gyroplatform.md).
    """
    n = int(12 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    f_ned = np.tile([0.0, 0.0, -G], (n, 1))
    f_ned[t >= 5.0, 0] = 0.3 * G
    rows = make_inputs(np.zeros((n, 3)), f_ned, None, dt_s=1.0 / RATE_HZ)  # level: body = NED
    base = GyroPlatformSettings(accel_lowpass_s=0.0)
    gated_s = dataclasses.replace(base, schedule=dataclasses.replace(base.schedule, horizontal_tolerance=0.25))
    gated = create("gyroplatform", gated_s).run(rows)
    free = create("gyroplatform", base).run(rows)
    _, _, incl_gated = attitude_errors_rad(gated[:, OUT_Q : OUT_Q + 4], LEVEL)
    _, _, incl_free = attitude_errors_rad(free[:, OUT_Q : OUT_Q + 4], LEVEL)
    assert np.degrees(incl_gated[-1]) < 1.0
    assert np.degrees(incl_free[-1]) > 5.0
    assert np.all(gated[t > 6.0, OUT_ACCEL_WEIGHT] == 0.0)


def test_gnss_acceleration_compensation(gnss_inclination) -> None:  # type: ignore[no-untyped-def]
    """f − v̇ replaces f (003): the vertical no longer follows the vehicle's acceleration."""
    with_v, without_v = gnss_inclination("gyroplatform")
    assert with_v < 0.3 and without_v > 2.0, (with_v, without_v)


@pytest.mark.slow
def test_broad_accuracy(broad_mean) -> None:  # type: ignore[no-untyped-def]
    """Defaults on the 16 BROAD trials: measured 2.13° total / 0.75° inclination (9-axis), 0.75° (6-axis)."""
    total, _, incl = broad_mean("gyroplatform")
    assert total < 3.0 and incl < 1.0, (total, incl)
    _, _, incl6 = broad_mean("gyroplatform", six_axis=True)
    assert incl6 < 1.0, incl6


def test_settings_are_validated() -> None:
    with pytest.raises(ValueError, match="level_gain"):
        GyroPlatformSettings(level_gain=float("nan"))
    with pytest.raises(ValueError, match="turn_rate_limit_rad_s"):
        GyroPlatformSettings(turn_rate_limit_rad_s=-1.0)
