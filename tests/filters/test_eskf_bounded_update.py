"""The attitude part of one ESKF measurement update, bounded (``EskfSettings.max_attitude_step_rad``; issue 22/24,
docs/accuracy.md "One update that moves the attitude far").

The error-state model is a small-angle one: with the attitude covariance freshly re-opened (45° per tilt axis) a
velocity residual the attitude did not cause — the INS velocity integrated with a wrong attitude before — is read
as a tilt error, and one fix moved the tilt by 47–80° (firmware_sim ``aggressive`` 3 after 30 s at 4 Hz IMU).
Beyond the bound the update's noise is inflated until the correction is the bound, and the covariance updated with
that noise.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from mavahrs.evaluation.metrics import attitude_errors_rad
from mavahrs.filters import eskf as e
from mavahrs.filters.base import S_FILTER, S_Q, make_inputs
from mavahrs.filters.eskf import Eskf, EskfSettings
from mavahrs.filters.layout import OUT_Q

N = e.N
K = S_FILTER
G = 9.80665
RATE_HZ = 200


def _update(p: np.ndarray, h: np.ndarray, y: float, r: float, bound: float) -> tuple[bool, np.ndarray, np.ndarray]:
    """The compiled scalar update on a bare state holding the covariance ``p``: (passed, δx, P after)."""
    s = np.zeros(S_FILTER + e._N_STATE)
    s[K + e._P : K + e._P + N * N] = p.ravel()
    s[K + e._H : K + e._H + N] = h
    ok = e._scalar_update(s, K, y, r, 5.0, bound)
    return bool(ok), s[K + e._DX : K + e._DX + N].copy(), s[K + e._P : K + e._P + N * N].reshape(N, N).copy()


def _open_covariance() -> tuple[np.ndarray, np.ndarray]:
    """A covariance as just after a re-opening (tilt σ 45°, heading σ 5°, velocity σ 0.3 m/s) one IMU step
    into flight at hover (δv̇ = g·[δθ_E, −δθ_N, 0]), and h of the north velocity."""
    p = np.zeros((N, N))
    p[0, 0] = p[1, 1] = math.radians(45.0) ** 2
    p[2, 2] = math.radians(5.0) ** 2
    for i in range(3, 9):
        p[i, i] = 0.3**2 if i < 6 else math.radians(0.5) ** 2
    dt = 0.05
    phi = np.eye(N)
    phi[3, 1] = G * dt  # δv_N from δθ_E
    phi[4, 0] = -G * dt  # δv_E from δθ_N
    p = phi @ p @ phi.T
    h = np.zeros(N)
    h[3] = 1.0
    return p, h


def test_a_correction_beyond_the_bound_is_the_bound_with_the_noise_inflated_to_match() -> None:
    p, h = _open_covariance()
    y, r = 0.6, 0.1**2  # a 0.6 m/s north residual
    ok, dx0, p0 = _update(p, h, y, r, 0.0)
    s = h @ p @ h + r
    k = p @ h / s
    assert ok and np.allclose(dx0, k * y) and np.allclose(p0, p - np.outer(k, p @ h))  # the plain Kalman update
    assert np.linalg.norm(dx0[:3]) > math.radians(30.0)  # linearised: the tilt moved by tens of degrees
    bound = 0.2
    ok, dx, p1 = _update(p, h, y, r, bound)
    assert ok
    assert np.linalg.norm(dx[:3]) == pytest.approx(bound, rel=1e-12)
    # the same update with the noise inflated to R' ≥ R: the state and the covariance both follow from S'
    s1 = np.linalg.norm((p @ h)[:3]) * abs(y) / bound
    assert s1 - h @ p @ h > r
    k1 = p @ h / s1
    assert np.allclose(dx, k1 * y, rtol=1e-12, atol=0.0)
    assert np.allclose(p1, p - np.outer(k1, p @ h), rtol=1e-12, atol=1e-18)
    # less information than the plain update takes: the bounded covariance is the larger one, and positive definite
    assert np.all(np.linalg.eigvalsh(p1 - p0) >= -1e-15)
    assert np.all(np.linalg.eigvalsh(p1[:9, :9]) > 0.0)


def test_a_correction_within_the_bound_and_a_gated_one_are_as_before() -> None:
    p, h = _open_covariance()
    _, dx0, p0 = _update(p, h, 0.02, 0.1**2, 0.0)
    _, dx1, p1 = _update(p, h, 0.02, 0.1**2, 0.2)
    assert np.linalg.norm(dx0[:3]) < 0.2
    assert dx1.tobytes() == dx0.tobytes() and p1.tobytes() == p0.tobytes()
    ok, dx, p2 = _update(p, h, 50.0, 0.1**2, 0.2)  # beyond the 5σ gate: nothing changes
    assert not ok and not dx.any() and p2.tobytes() == p.tobytes()


def _hover_rows(seconds: float, fix_hz: float = 5.0, seed: int = 3) -> np.ndarray:
    """A vehicle holding still, level, heading north (the truth: the identity), its sensors noisy, GNSS velocity 0."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE_HZ)
    gyro = rng.normal(0.0, 0.003, (n, 3))
    accel = np.array([0.0, 0.0, -G]) + rng.normal(0.0, 0.05, (n, 3))
    mag = np.array([20.0, 0.0, 45.0]) + rng.normal(0.0, 0.3, (n, 3))
    vel = np.full((n, 3), np.nan)
    every = int(RATE_HZ / fix_hz)
    vel[::every] = rng.normal(0.0, 0.05, (n, 3))[::every]
    return make_inputs(gyro, accel, mag, dt_s=np.full(n, 1.0 / RATE_HZ), velocity_ned_m_s=vel)


@pytest.mark.parametrize("seed", [3, 4])
def test_a_velocity_residual_after_a_re_opening_moves_the_tilt_only_by_the_bound(seed: int) -> None:
    """Level and still (the truth), velocity-aided for 10 s; then the attitude covariance re-opened (as after
    persistent rejection) with the INS velocity 2 m/s off north (integrated with a wrong attitude before): the next
    fixes read that residual as tilt.  Unbounded (main) the tilt goes 57–58° off (20° RMS over the next 10 s);
    bounded by 11.5° per update at most 19–22° (one fix's three components; 11–12° RMS) — so it is with the bound
    acting only for 5 s after the re-opening (``max_attitude_step_window_s``, as on an autopilot's stream), and not
    with a window that has closed before the first fix."""
    rows = _hover_rows(20.0, seed=seed)
    truth = np.tile([1.0, 0.0, 0.0, 0.0], (len(rows), 1))
    worst, rms = [], []
    for bound, window in ((0.0, 0.0), (math.radians(11.5), 0.0), (math.radians(11.5), 5.0), (math.radians(11.5), 0.001)):
        f = Eskf(replace(EskfSettings(), max_attitude_step_rad=bound, max_attitude_step_window_s=window))
        first = f.run(rows[: 10 * RATE_HZ])
        _, _, incl = attitude_errors_rad(first[:, OUT_Q : OUT_Q + 4], truth[: 10 * RATE_HZ])
        assert np.degrees(incl[-RATE_HZ:]).max() < 0.5
        s = f._state
        e.eskf_reopen_attitude(s, K, f._params, e._REOPEN_TILT, e._REOPEN_HEADING)
        s[K + e._V] += 2.0
        for i in range(e.HISTORY_LEN):  # the history the fixes are compared with holds the same velocity
            s[K + e._HIST + 4 * i + 1] += 2.0
        out = f.run(rows[10 * RATE_HZ :])
        _, _, incl = attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], truth[10 * RATE_HZ :])
        worst.append(float(np.degrees(incl.max())))
        rms.append(float(np.degrees(np.sqrt(np.mean(incl**2)))))
        assert np.isclose(np.linalg.norm(f._state[S_Q : S_Q + 4]), 1.0)
    assert worst[0] > 45.0, f"unbounded {worst[0]:.1f}°: the case shows nothing"
    assert worst[1] < 30.0 and rms[1] < rms[0], (worst, rms)
    assert worst[2] < 30.0 and rms[2] < rms[0], (worst, rms)
    assert worst[3] > 45.0, (worst, rms)


def test_the_bound_is_set_on_an_autopilot_s_stream_only() -> None:
    """On by default only where it was measured to help (the daemon's vehicle stream); a raw IMU through the API
    keeps main's unbounded update (BROAD as a raw IMU 1.10 → 1.73° with it: its large start corrections are right)."""
    from mavahrs.filters import create
    from mavahrs.filters.best import VEHICLE_MAX_ATTITUDE_STEP_RAD, VEHICLE_MAX_ATTITUDE_STEP_WINDOW_S

    assert EskfSettings().max_attitude_step_rad == 0.0
    raw = create("best")
    assert raw.settings.eskf.max_attitude_step_rad == 0.0  # type: ignore[attr-defined]
    raw.set_multirotor()  # type: ignore[attr-defined]
    assert raw.settings.eskf.max_attitude_step_rad == 0.0  # type: ignore[attr-defined]
    assert VEHICLE_MAX_ATTITUDE_STEP_RAD > 0.0 and VEHICLE_MAX_ATTITUDE_STEP_WINDOW_S > 0.0
    for declared_first in (False, True):
        f = create("best")
        if declared_first:
            f.set_multirotor()  # type: ignore[attr-defined]
        f.set_vehicle_stream()  # type: ignore[attr-defined]
        f.set_multirotor()  # type: ignore[attr-defined]
        assert f.settings.eskf.max_attitude_step_rad == VEHICLE_MAX_ATTITUDE_STEP_RAD  # type: ignore[attr-defined]
        assert f.settings.eskf.max_attitude_step_window_s == VEHICLE_MAX_ATTITUDE_STEP_WINDOW_S  # type: ignore[attr-defined]
