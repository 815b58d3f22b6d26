"""The velocity-aided ESKF (``eskf``) and ``best``'s use of it, on synthetic flights with known truth.

A flight here is a rigid body whose attitude is a yaw ψ(t) (level) and whose
NED acceleration a(t) is given: gyro (0, 0, ψ̇), specific force Cᵀ(a − g),
field Cᵀ m with m = (20, 0, 45) µT, GNSS velocity ∫a at 10 Hz.  Level is the
hardest case for an accelerometer-only filter under sustained horizontal
acceleration: the specific force tilts by atan(‖a‖/g) while the body does not.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from mavahrs.evaluation.metrics import attitude_errors_rad
from mavahrs.filters import create
from mavahrs.filters.base import make_inputs
from mavahrs.filters.best import Best, BestSettings
from mavahrs.filters.eskf import Eskf, EskfSettings
from mavahrs.filters.layout import IN_MAG, IN_VEL, IN_VEL_AGE, OUT_Q

RATE_HZ = 200.0
G = 9.80665
M_NED = np.array([20.0, 0.0, 45.0])


def _flight(duration_s, accel_ned, yaw=lambda t: 0.0 * t, *, fix_hz=10.0, seed=1, noise=True):  # type: ignore[no-untyped-def]
    """(rows, q_true, t): rows with velocity fixes at ``fix_hz`` (NaN between), age 0."""
    n = int(duration_s * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    a = np.asarray(accel_ned(t), dtype=float).reshape(3, n).T
    v = np.cumsum(a, axis=0) / RATE_HZ
    psi = np.asarray(yaw(t), dtype=float) * np.ones(n)
    c, s = np.cos(psi), np.sin(psi)
    f_ned = a - np.array([0.0, 0.0, G])
    # Cᵀ x for C = Rz(ψ): (c x + s y, −s x + c y, z)
    f_body = np.stack([c * f_ned[:, 0] + s * f_ned[:, 1], -s * f_ned[:, 0] + c * f_ned[:, 1], f_ned[:, 2]], axis=1)
    m_body = np.stack([c * M_NED[0], -s * M_NED[0], np.full(n, M_NED[2])], axis=1)
    gyro = np.zeros((n, 3))
    gyro[:, 2] = np.gradient(psi, t)
    rng = np.random.default_rng(seed)
    if noise:
        gyro += rng.normal(scale=math.radians(0.2), size=(n, 3))
        f_body += rng.normal(scale=0.05, size=(n, 3))
        m_body += rng.normal(scale=0.3, size=(n, 3))
    vel = np.full((n, 3), np.nan)
    fix = np.arange(n) % int(RATE_HZ / fix_hz) == 0
    vel[fix] = v[fix]
    rows = make_inputs(gyro, f_body, m_body, dt_s=1.0 / RATE_HZ, velocity_ned_m_s=vel)
    q = np.stack([np.cos(psi / 2), np.zeros(n), np.zeros(n), np.sin(psi / 2)], axis=1)
    return rows, q, t


def _errors_deg(out: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    _, head, incl = attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], q)
    return np.degrees(incl), np.degrees(head)


def _north_then_east(t: np.ndarray) -> np.ndarray:
    """3 m/s² north for 10–25 s, −3 for 25–40 s, 3 east for 45–60 s, −3 for 60–75 s (80 s)."""
    a = np.zeros((3, t.size))
    a[0] = np.where((t >= 10) & (t < 25), 3.0, 0.0) - np.where((t >= 25) & (t < 40), 3.0, 0.0)
    a[1] = np.where((t >= 45) & (t < 60), 3.0, 0.0) - np.where((t >= 60) & (t < 75), 3.0, 0.0)
    return a


def test_velocity_aiding_holds_the_tilt_through_sustained_acceleration() -> None:
    """3 m/s² for 15 s at a time (the specific force 17° off the vertical): < 0.3° with the velocity.

    The same filter without velocity can only take the accelerometer for
    gravity (its fallback): several degrees off by the end of each leg.
    """
    rows, q, t = _flight(80.0, _north_then_east)
    incl, _ = _errors_deg(create("eskf").run(rows), q)
    assert incl[t > 5].max() < 0.3
    no_vel = rows.copy()
    no_vel[:, IN_VEL : IN_VEL + 3] = np.nan
    no_vel[:, IN_VEL_AGE] = np.nan
    incl_blind, _ = _errors_deg(create("eskf").run(no_vel), q)
    assert incl_blind[(t > 20) & (t < 25)].min() > 3.0


def test_a_receiver_fix_without_vertical_velocity_still_levels() -> None:
    """GPS_RAW_INT gives ground speed and course only: (vn, ve, NaN) — the vertical is not fused as zero."""
    rows, q, t = _flight(80.0, lambda t: _north_then_east(t) + np.array([[0.0], [0.0], [0.5]]) * np.sin(t))
    rows[:, IN_VEL + 2] = np.nan
    incl, _ = _errors_deg(create("eskf").run(rows), q)
    assert incl[t > 5].max() < 0.5


def test_a_late_fix_is_compared_at_its_own_time() -> None:
    """Fixes that arrive 200 ms after they were taken (a receiver's latency), in a 0.3–0.5 Hz weave at 4 m/s².

    With their age (``IN_VEL_AGE``) they are compared with the velocity of
    200 ms before: 0.03° RMS; taken as current, each carries 200 ms of
    acceleration as a tilt error: 0.7° RMS.
    """
    def weave(t: np.ndarray) -> np.ndarray:  # at rest for 5 s, then weaving north-south and east-west
        on = t >= 5.0
        return np.stack([on * 4.0 * np.sin(2 * np.pi * 0.5 * t), on * 4.0 * np.sin(2 * np.pi * 0.3 * t), 0.0 * t])

    rows, q, t = _flight(60.0, weave, fix_hz=5.0)
    lag = int(0.2 * RATE_HZ)
    late = rows.copy()
    late[:, IN_VEL : IN_VEL + 3] = np.nan
    late[lag:, IN_VEL : IN_VEL + 3] = rows[:-lag, IN_VEL : IN_VEL + 3]
    late[:, IN_VEL_AGE] = np.where(np.isfinite(late[:, IN_VEL]), 0.2, np.nan)
    incl, _ = _errors_deg(create("eskf").run(late), q)
    aged_rms = np.sqrt(np.mean(incl[t > 10] ** 2))
    assert aged_rms < 0.1
    unaged = late.copy()
    unaged[:, IN_VEL_AGE] = np.where(np.isfinite(late[:, IN_VEL]), 0.0, np.nan)
    incl_unaged, _ = _errors_deg(create("eskf").run(unaged), q)
    unaged_rms = np.sqrt(np.mean(incl_unaged[t > 10] ** 2))
    assert unaged_rms > 0.5 and unaged_rms > 10 * aged_rms


def test_acceleration_makes_heading_observable_without_a_magnetometer() -> None:
    """No magnetometer, the heading started 30° off: the first hard legs bring it within 2°."""
    rows, q, t = _flight(80.0, _north_then_east)
    rows[:, IN_MAG : IN_MAG + 3] = np.nan
    f = create("eskf")
    f.run(rows[:2])
    s = f.state
    h = math.radians(30.0) / 2
    s.q_body_to_ned = np.array([math.cos(h), 0.0, 0.0, math.sin(h)])
    f.state = s
    _, head = _errors_deg(f.run(rows[2:]), q[2:])
    assert head[0] > 29.0
    assert head[t[2:] > 50].max() < 2.0


def test_a_disturbed_magnetometer_is_not_followed_while_gnss_tells_the_heading() -> None:
    """From 30 s to 60 s a field 40° off and 30 % stronger (a magnet, motor current): heading within 3°."""
    rows, q, t = _flight(80.0, _north_then_east)
    bad = (t >= 30) & (t < 60)
    c, s = math.cos(math.radians(40)), math.sin(math.radians(40))
    m = rows[bad, IN_MAG : IN_MAG + 3].copy()
    rows[bad, IN_MAG] = 1.3 * (c * m[:, 0] - s * m[:, 1])
    rows[bad, IN_MAG + 1] = 1.3 * (s * m[:, 0] + c * m[:, 1])
    rows[bad, IN_MAG + 2] = 1.3 * m[:, 2]
    f = create("eskf")
    f.set_mag_reference(float(np.linalg.norm(M_NED)), math.atan2(M_NED[2], M_NED[0]))
    _, head = _errors_deg(f.run(rows), q)
    assert head[t > 5].max() < 3.0


def test_best_uses_the_velocity_aided_filter_and_hands_back_without_a_jump() -> None:
    """Fixes for 0–40 s, none after: the ESKF's attitude while aided, and no step when the aiding ends."""
    rows, q, t = _flight(60.0, _north_then_east)
    rows[t >= 40, IN_VEL : IN_VEL + 3] = np.nan
    rows[t >= 40, IN_VEL_AGE] = np.nan
    b = Best(BestSettings())
    out = b.run(rows)
    sub = BestSettings()
    eskf_out = Eskf(sub.eskf).run(rows)
    aided = (t > 6) & (t < 40)
    # the same attitude as the ESKF alone once both have converged (the seeding is then history: while
    # aided the magnetometer does not pull the tilt, so the GNSS velocity alone works a seeding difference
    # off; 0.06° at 5 s, 0.03° from 6 s)
    incl_b, _ = _errors_deg(out, q)
    incl_e, _ = _errors_deg(eskf_out, q)
    assert np.abs(incl_b[aided] - incl_e[aided]).max() < 0.05
    assert not b.using_velocity_aiding
    # the hand-over: no step between consecutive outputs beyond what the motion explains
    qo = out[:, OUT_Q : OUT_Q + 4]
    step = np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(qo[1:] * qo[:-1], axis=1)), 0, 1)))
    assert step[(t[1:] > 40) & (t[1:] < 48)].max() < 0.1


def test_the_ardupilot_profile_gives_best_its_ins_delay() -> None:
    """The pipeline hands the profile's IMU delay to ``best`` (ArduPilot: 20 Hz INS filter, 11.3 ms; PX4: 0),
    and makes it the ESKF without GNSS too (a vehicle's stream)."""
    from mavahrs.sensors.profiles import AP_INS_DELAY_S
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    for profile, delay in (("ardupilot", AP_INS_DELAY_S), ("px4", 0.0)):
        p = Pipeline(PipelineSettings(autopilot_profile=profile, source_system=1, source_component=1))
        f = p._filter
        assert isinstance(f, Best)
        assert f.settings.eskf.sensor_delay_s == pytest.approx(delay)
        assert f.settings.unaided_filter == "eskf"  # an autopilot's stream: the ESKF in every condition
    assert AP_INS_DELAY_S == pytest.approx(math.sqrt(2) / (2 * math.pi * 20.0))


def test_output_is_advanced_by_the_sensor_delay() -> None:
    """A steady 90°/s yaw with an 11 ms delay: the output leads the state by 90°/s × 11 ms ≈ 1°."""
    rows, q, t = _flight(10.0, lambda t: np.zeros((3, t.size)), yaw=lambda t: math.radians(90) * t, noise=False)
    plain = Eskf(EskfSettings()).run(rows)
    lead = Eskf(replace(EskfSettings(), sensor_delay_s=0.011)).run(rows)
    qa, qb = plain[-1, OUT_Q : OUT_Q + 4], lead[-1, OUT_Q : OUT_Q + 4]
    ang = math.degrees(2 * math.acos(min(1.0, abs(float(np.dot(qa, qb))))))
    assert ang == pytest.approx(90 * 0.011, rel=0.05)


def test_a_heading_gone_wrong_is_recovered_within_seconds_when_velocity_aided() -> None:
    """Velocity-aided at rest (no gravity updates then), the heading set 40° off with a small covariance:
    every magnetometer reading is refused by the gate, and after 2 s of refusals (elapsed time: readings
    come at 10 Hz) the attitude covariance re-opens and the heading comes back within 2° 6 s later."""
    rows, q, t = _flight(40.0, lambda t: np.zeros((3, t.size)))
    f = create("eskf")
    k = int(10 * RATE_HZ)
    f.run(rows[:k])
    s = f.state
    h = math.radians(40.0) / 2
    s.q_body_to_ned = np.array([math.cos(h), 0.0, 0.0, math.sin(h)])
    f.state = s
    _, head = _errors_deg(f.run(rows[k:]), q[k:])
    assert head[0] > 39.0
    assert head[int(6 * RATE_HZ) :].max() < 2.0
