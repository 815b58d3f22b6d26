"""GNSS position in the ESKF (``IN_POS``, ``EskfSettings.position_noise_m``) and the aided gyro-bias walk.

Synthetic hovers with a known attitude (level; the specific force is −g on the body z axis): the
truth is exact, so the tilt error is the estimate's inclination.
"""

from __future__ import annotations

import math

import numpy as np

from mavahrs.filters.best import VEHICLE_BIAS_WALK_RAD_S2
from mavahrs.filters.eskf import Eskf, EskfSettings
from mavahrs.filters.gains import G_M_S2
from mavahrs.filters.layout import IN_ACCEL, IN_DT, IN_GYRO, IN_POS, IN_VEL, IN_VEL_AGE, IN_WIDTH, OUT_Q

RATE_HZ = 400.0
FIX_HZ = 5.0


def _hover(duration_s: float, bias_rad_s, *, position: bool, vel_noise_m_s: float = 0.0, seed: int = 3) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Level hover at rest: gyro = the bias at each time (rad/s, body), GNSS velocity (and position) fixes of 0
    at 5 Hz, white velocity noise of the σ given."""
    n = int(duration_s * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    rows = np.full((n, IN_WIDTH), np.nan)
    rows[:, IN_DT] = 1.0 / RATE_HZ
    rows[0, IN_DT] = np.nan
    rows[:, IN_GYRO : IN_GYRO + 3] = bias_rad_s(t)
    rows[:, IN_ACCEL : IN_ACCEL + 3] = (0.0, 0.0, -G_M_S2)
    fix = np.arange(0, n, int(RATE_HZ / FIX_HZ))[1:]
    rng = np.random.default_rng(seed)
    rows[fix, IN_VEL : IN_VEL + 3] = rng.normal(0.0, vel_noise_m_s, (fix.size, 3)) if vel_noise_m_s else 0.0
    rows[fix, IN_VEL_AGE] = 0.0
    if position:
        rows[fix, IN_POS : IN_POS + 3] = 0.0
    return rows


def _inclination_deg(out: np.ndarray) -> np.ndarray:
    q = out[:, OUT_Q : OUT_Q + 4]
    return np.degrees(2.0 * np.arccos(np.clip(np.sqrt(q[:, 0] ** 2 + q[:, 3] ** 2), -1.0, 1.0)))


def test_position_fixes_hold_the_tilt_where_noisy_velocity_does_not() -> None:
    """An unknown constant gyro bias (0.3 °/s about x and y) with velocity fixes of 0.5 m/s noise: the
    position fixes (every fix at 0) pull the tilt in tighter than the same velocity fixes alone
    (fails without the position states: both runs would be the same)."""
    bias = math.radians(0.3)

    def gyro(t: np.ndarray) -> np.ndarray:
        return np.stack([np.full_like(t, bias), np.full_like(t, -bias), np.zeros_like(t)], 1)

    rms = {}
    for pos in (False, True):
        s = EskfSettings(velocity_noise_m_s=0.5, vertical_velocity_noise_m_s=0.5,
                         position_noise_m=0.1 if pos else 0.0, vertical_position_noise_m=0.1 if pos else 0.0)
        out = Eskf(s).run(_hover(40.0, gyro, position=pos, vel_noise_m_s=0.5))
        e = _inclination_deg(out)[int(5 * RATE_HZ) :]
        rms[pos] = float(np.sqrt(np.mean(e**2)))
    assert rms[True] < 0.7 * rms[False], rms


def test_position_state_follows_the_fixes_and_is_off_without_them() -> None:
    """Fixes at 0 while hovering at rest: the filter's position stays within centimetres of them; rows
    without IN_POS leave the position states out (the same output as before the column existed)."""
    from mavahrs.filters.base import S_FILTER
    from mavahrs.filters.eskf import _POS, _POS_ON

    f = Eskf(EskfSettings(position_noise_m=0.3))
    f.run(_hover(20.0, lambda t: np.zeros((t.size, 3)), position=True))
    k = S_FILTER + _POS
    assert f._state[S_FILTER + _POS_ON] == 1.0  # type: ignore[attr-defined]
    assert np.all(np.abs(f._state[k : k + 2]) < 0.05)  # type: ignore[attr-defined]
    rows = _hover(20.0, lambda t: np.zeros((t.size, 3)), position=False)
    a = Eskf(EskfSettings(position_noise_m=0.3)).run(rows)
    b = Eskf(EskfSettings(position_noise_m=0.0)).run(rows)
    assert np.array_equal(a, b, equal_nan=True)


def test_aided_bias_walk_follows_a_drifting_gyro() -> None:
    """A gyro bias ramping 0.001 °/s per second on every axis (ArduPilot SITL's SIM_DRIFT; a gyro warming
    up) in an aided hover: the ramp sustains a steady tilt error (≈ ramp / the bias loop's gain); with the
    vehicle's aided bias walk it is three quarters or less of the ESKF's default walk's (measured 0.14 vs
    0.20° RMS over the last minute; fails without ``bias_walk_aided_rad_s2``)."""
    ramp = math.radians(0.001)

    def gyro(t: np.ndarray) -> np.ndarray:
        return np.repeat((ramp * t)[:, None], 3, 1)

    rows = _hover(120.0, gyro, position=False, vel_noise_m_s=0.02)
    tail = slice(int(60 * RATE_HZ), None)
    slow = _inclination_deg(Eskf(EskfSettings()).run(rows))[tail]
    fast = _inclination_deg(Eskf(EskfSettings(bias_walk_aided_rad_s2=VEHICLE_BIAS_WALK_RAD_S2)).run(rows))[tail]
    assert np.sqrt(np.mean(fast**2)) < 0.75 * np.sqrt(np.mean(slow**2))
    assert np.max(fast) < 0.25
