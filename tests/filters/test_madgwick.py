"""Madgwick filter: the gradient against finite differences, and behaviour against synthetic truth.

Synthetic recordings come from ``tests/filters/conftest.make_truth`` (smooth
attitude, ideal or noisy gyro/accelerometer/magnetometer, NED field with a 66°
dip).  Bounds are stated per test with the reason for their size.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from mavahrs.errors import ConfigError
from mavahrs.evaluation.metrics import attitude_errors_rad
from mavahrs.filters import create
from mavahrs.filters.base import make_inputs, run_many
from mavahrs.filters.best import best_settings
from mavahrs.filters.gains import GainScheduleSettings
from mavahrs.filters.layout import (
    FLAG_STARTUP,
    IN_ACCEL,
    IN_MAG,
    OUT_ACCEL_WEIGHT,
    OUT_BIAS,
    OUT_FLAGS,
    OUT_GAIN,
    OUT_MAG_WEIGHT,
    OUT_Q,
)
from mavahrs.filters.madgwick import (
    Madgwick,
    MadgwickSettings,
    beta_from_gyro_error,
    field_gradient,
    field_objective,
    gravity_gradient,
    gravity_objective,
    zeta_from_bias_drift,
)
from mavahrs.filters.rest import RestBiasSettings
from mavahrs.geometry.quaternion import conjugate, from_axis_angle, multiply, random_unit, rotate

RATE_HZ = 200.0
NO_SCHEDULE = GainScheduleSettings(
    startup_gain_factor=1.0,
    startup_s=0.0,
    accel_norm_tolerance=0.0,
    rejection_timeout_s=0.0,
    mag_norm_tolerance=0.0,
    mag_dip_tolerance_rad=0.0,
)
#: the report's filter and nothing else: constant β, no schedule, no rest detection, no ζ
PAPER = MadgwickSettings(zeta_rad_s=0.0, rest=RestBiasSettings(bias_tau_s=0.0), schedule=NO_SCHEDULE)


def _deg(x: np.ndarray) -> np.ndarray:
    return np.degrees(x)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _heading_deg(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """Signed heading error (deg) of the earth-frame error quaternion."""
    e = multiply(q_est, conjugate(q_true))
    return np.degrees(2.0 * np.arctan(e[:, 3] / e[:, 0]))


# ------------------------------------------------------------ objective and gradient


def _fd_gradient(fun, q: np.ndarray, h: float = 1e-6) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Central finite-difference gradient of ½‖fun(q)‖² over the four components."""
    g = np.zeros(4)
    for i in range(4):
        dq = np.zeros(4)
        dq[i] = h
        fp = np.asarray(fun(*(q + dq)))
        fm = np.asarray(fun(*(q - dq)))
        g[i] = (0.5 * fp @ fp - 0.5 * fm @ fm) / (2.0 * h)
    return g


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "interpreted"])
def test_gravity_gradient_matches_finite_differences(compiled: bool, rng: np.random.Generator) -> None:
    grad = gravity_gradient if compiled else gravity_gradient.py_func
    obj = gravity_objective.py_func
    for q in random_unit(50, rng):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        fd = _fd_gradient(lambda *qq, d=d: obj(*qq, *d), q)
        np.testing.assert_allclose(grad(*q, *d), fd, atol=1e-7)


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "interpreted"])
def test_field_gradient_matches_finite_differences(compiled: bool, rng: np.random.Generator) -> None:
    grad = field_gradient if compiled else field_gradient.py_func
    obj = field_objective.py_func
    for q in random_unit(50, rng):
        m = rng.normal(size=3)
        m /= np.linalg.norm(m)
        dip = rng.uniform(-1.4, 1.4)
        bx, bz = math.cos(dip), math.sin(dip)
        fd = _fd_gradient(lambda *qq, bx=bx, bz=bz, m=m: obj(*qq, bx, bz, *m), q)
        np.testing.assert_allclose(grad(*q, bx, bz, *m), fd, atol=1e-7)


def test_stacked_marg_gradient_is_sum_of_parts(rng: np.random.Generator) -> None:
    """eq. (31)–(32): the gradient of ½‖[f_g; f_b]‖² is J_gᵀf_g + J_bᵀf_b (checked numerically)."""
    for q in random_unit(20, rng):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        m = rng.normal(size=3)
        m /= np.linalg.norm(m)
        bx, bz = 0.4, 0.9

        def stacked(*qq: float, d: np.ndarray = d, bx: float = bx, bz: float = bz, m: np.ndarray = m) -> np.ndarray:
            return np.concatenate([gravity_objective.py_func(*qq, *d), field_objective.py_func(*qq, bx, bz, *m)])

        analytic = np.add(gravity_gradient(*q, *d), field_gradient(*q, bx, bz, *m))
        np.testing.assert_allclose(analytic, _fd_gradient(stacked, q), atol=1e-7)


def test_objectives_compare_rotated_references(rng: np.random.Generator) -> None:
    """f_g = Cᵀ·[0,0,1] − d̂ and f_b = Cᵀ·[b_x,0,b_z] − m̂ for q = q_body_to_ned (checked with geometry)."""
    for q in random_unit(20, rng):
        d = rng.normal(size=3)
        m = rng.normal(size=3)
        down_body = rotate(conjugate(q), [0.0, 0.0, 1.0])
        np.testing.assert_allclose(gravity_objective(*q, *d), down_body - d, atol=1e-12)
        b_body = rotate(conjugate(q), [0.3, 0.0, 0.8])
        np.testing.assert_allclose(field_objective(*q, 0.3, 0.8, *m), b_body - m, atol=1e-12)


def test_field_objective_vanishes_only_with_the_full_reference(rng: np.random.Generator) -> None:
    """With b of eq. (46) the objective is zero at the true attitude; the C code's b/2 is not."""
    q = random_unit(1, rng)[0]
    b = np.array([20.0, 0.0, 45.0]) / np.linalg.norm([20.0, 0.0, 45.0])
    m = rotate(conjugate(q), b)  # what the sensor reads, normalised
    h = rotate(q, m)  # eq. (45)
    bx, bz = math.hypot(h[0], h[1]), h[2]  # eq. (46)
    assert np.linalg.norm(field_objective(*q, bx, bz, *m)) < 1e-12
    assert np.linalg.norm(field_gradient(*q, bx, bz, *m)) < 1e-12
    # the widely copied code's reference is half as long: a spurious gradient at the truth
    assert np.linalg.norm(field_gradient(*q, bx / 2, bz / 2, *m)) > 0.5


def test_gains_from_sensor_specs() -> None:
    """eq. (50)–(51): β = √(3/4)·ω̃_β, ζ = √(3/4)·ω̃_ζ; the report's 0.033 ≈ 2.2°/s."""
    assert beta_from_gyro_error(math.radians(2.2)) == pytest.approx(0.0333, abs=5e-4)
    assert zeta_from_bias_drift(1.0) == pytest.approx(math.sqrt(0.75))
    with pytest.raises(ConfigError):
        beta_from_gyro_error(-1.0)
    with pytest.raises(ConfigError):
        zeta_from_bias_drift(float("nan"))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"beta_rad_s": -0.1},
        {"zeta_rad_s": float("inf")},
        {"mag_correction": "tilt"},
        {"accel_lowpass_order": 3},
        {"beta_heading_rad_s": -1.0},
        {"accel_lowpass_s": float("nan")},
        {"rest": 2.0},
        {"lowpass_norm_tolerance": -0.1},
        {"lowpass_norm_min_weight": 1.5},
        {"velocity_max_age_s": 0.0},
        {"gnss_fade_s": float("inf")},
        {"gnss_acceleration": "yes"},
        {"accel_lowpass_adapt_ratio": -1.0},
        {"accel_lowpass_max_s": 0.0},
        {"accel_lowpass_adapt_avg_s": float("nan")},
    ],
)
def test_invalid_settings_are_rejected(kwargs: dict) -> None:  # type: ignore[type-arg]
    with pytest.raises(ConfigError):
        MadgwickSettings(**kwargs)


# ------------------------------------------------------------ behaviour on synthetic truth


def test_level_resting_frd_accelerometer_gives_identity() -> None:
    """(0, 0, −9.81) with the field north and down gives [1, 0, 0, 0] (6- and 9-axis, paper settings)."""
    n = 400
    accel = np.tile([0.0, 0.0, -9.81], (n, 1))
    gyro = np.zeros((n, 3))
    mag = np.tile([20.0, 0.0, 45.0], (n, 1))
    for m in (None, mag):
        out = Madgwick(PAPER).run(make_inputs(gyro, accel, m, dt_s=0.005))
        np.testing.assert_allclose(out[-1, OUT_Q : OUT_Q + 4], [1.0, 0.0, 0.0, 0.0], atol=1e-6)


@pytest.mark.parametrize("mag", [True, False], ids=["MARG", "IMU"])
@pytest.mark.parametrize("mode", ["full", "heading"])
def test_paper_filter_converges_from_90_degrees(mag: bool, mode: str, synthetic) -> None:  # type: ignore[no-untyped-def]
    """The bare report filter (β = 0.041, no boost): from 90° off to < 1° within 60 s.

    The normalised gradient corrects at 2β = 4.7°/s, so 90° needs ≈ 20 s of
    tilt and the heading follows; 60 s leaves margin.  IMU form: inclination.
    """
    tr = synthetic(75.0, RATE_HZ, noise=True)
    f = Madgwick(replace(PAPER, mag_correction=mode))
    rows = tr.inputs(mag=mag)
    f.run(rows[:1])
    s = f.state
    s.q_body_to_ned = multiply(from_axis_angle([1.0, -0.5, 0.3], math.pi / 2), tr.q_body_to_ned[0])
    f.state = s
    out = f.run(rows[1:])
    total, _, incl = attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned[1:])
    err = _deg(total if mag else incl)
    assert err[0] > 85.0
    assert _rms(err[int(60 * RATE_HZ) :]) < 1.0


def test_zeta_learns_a_constant_gyro_bias(synthetic) -> None:  # type: ignore[no-untyped-def]
    """0.5°/s on every axis, slow continuous motion, rest detection off: ζ alone learns it.

    Defaults otherwise (ζ = 0.002, time constant β/ζ ≈ 20 s): within 0.1°/s
    after 150 s.  With ζ = 0 the same run learns nothing (so ζ is what works).
    """
    bias = np.radians([0.5, -0.5, 0.5])
    tr = synthetic(150.0, RATE_HZ, amplitude=0.3, gyro_bias_rad_s=tuple(bias), noise=True)
    no_rest = RestBiasSettings(bias_tau_s=0.0)
    out = Madgwick(MadgwickSettings(rest=no_rest)).run(tr.inputs())
    np.testing.assert_allclose(_deg(out[-1, OUT_BIAS : OUT_BIAS + 3]), _deg(bias), atol=0.1)
    off = Madgwick(MadgwickSettings(rest=no_rest, zeta_rad_s=0.0)).run(tr.inputs())
    np.testing.assert_allclose(off[-1, OUT_BIAS : OUT_BIAS + 3], 0.0, atol=1e-12)


def test_zeta_is_frozen_while_spinning_fast(synthetic) -> None:  # type: ignore[no-untyped-def]
    """Above ``zeta_spin_limit_rad_s`` the bias estimate does not move (INAV's freeze)."""
    tr = synthetic(40.0, RATE_HZ, amplitude=3.0, gyro_bias_rad_s=(0.01, 0.0, 0.0), noise=True)
    spin = np.linalg.norm(tr.gyro_rad_s, axis=1)
    assert spin.min() > 0.0
    s = MadgwickSettings(rest=RestBiasSettings(bias_tau_s=0.0), zeta_spin_limit_rad_s=1e-3)
    out = Madgwick(s).run(tr.inputs())
    np.testing.assert_allclose(out[:, OUT_BIAS : OUT_BIAS + 3], 0.0, atol=1e-12)


def test_rest_detection_learns_bias_quickly(synthetic) -> None:  # type: ignore[no-untyped-def]
    """At rest the gyro reads its bias: learned within 10 s (ζ = 0).

    Bound: the estimate is the gyro's recent mean, so it matches that mean to
    0.01°/s; the white noise (0.3°/s per sample) moves a few-second mean off
    the true bias by up to ≈ 0.03°/s, hence 0.05°/s against the truth.
    """
    bias = np.radians([0.4, -0.3, 0.7])
    tr = synthetic(10.0, RATE_HZ, rest=True, gyro_bias_rad_s=tuple(bias), noise=True)
    out = Madgwick(MadgwickSettings(zeta_rad_s=0.0)).run(tr.inputs())
    learned = _deg(out[-1, OUT_BIAS : OUT_BIAS + 3])
    np.testing.assert_allclose(learned, _deg(bias), atol=0.05)
    np.testing.assert_allclose(learned, _deg(tr.gyro_rad_s[-int(4 * RATE_HZ) :].mean(axis=0)), atol=0.01)


@pytest.mark.parametrize("settings", ["paper", "default", "best"])
def test_marg_heading_is_correct(settings: str, truth_9axis_noisy) -> None:  # type: ignore[no-untyped-def]
    """9-axis on 60 s of noisy synthetic motion: heading RMS < 0.5° after 10 s.

    The 6-axis run of the same data is given a 30° heading error at start and
    keeps it (heading is unobservable without the magnetometer), which shows
    the magnetometer is what makes the MARG heading right.
    """
    s = {"paper": PAPER, "default": MadgwickSettings(), "best": best_settings()}[settings]
    tr = truth_9axis_noisy
    out = Madgwick(s).run(tr.inputs(mag=True))
    k = int(10 * RATE_HZ)
    assert _rms(_heading_deg(out[k:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned[k:])) < 0.5
    f = Madgwick(s)
    rows = tr.inputs(mag=False)
    f.run(rows[:1])
    st = f.state
    st.q_body_to_ned = multiply(from_axis_angle([0.0, 0.0, 1.0], math.radians(30.0)), tr.q_body_to_ned[0])
    f.state = st
    out6 = f.run(rows[1:])
    assert abs(np.mean(_heading_deg(out6[-k:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned[-k:]))) > 25.0


def _disturbed(tr, start_s: float, length_s: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Inputs with the field 1.5× as strong and turned 40° about the body's vertical for a while."""
    rows = tr.inputs(mag=True)
    sl = slice(int(start_s * RATE_HZ), int((start_s + length_s) * RATE_HZ))
    q = tr.q_body_to_ned[sl]
    m_ned = rotate(q, rows[sl, IN_MAG : IN_MAG + 3])
    turned = rotate(from_axis_angle([0.0, 0.0, 1.0], math.radians(40.0)), m_ned) * 1.5
    rows[sl, IN_MAG : IN_MAG + 3] = rotate(conjugate(q), turned)
    return rows


@pytest.mark.parametrize("settings", ["default", "best"])
def test_magnetic_disturbance_is_rejected(settings: str, synthetic) -> None:  # type: ignore[no-untyped-def]
    """Field norm +50 % (and 40° off) for 10 s: rejected; heading moves < 0.5° meanwhile.

    While rejected only the gyro (0.3°/s white noise, bias learned) carries the
    heading: its random walk over 10 s is ≈ 0.05°.  Without rejection the same
    disturbance pulls the heading by more than 5° (the test could fail).
    """
    s = MadgwickSettings() if settings == "default" else best_settings()
    tr = synthetic(60.0, RATE_HZ, amplitude=0.5, noise=True)
    rows = _disturbed(tr, 30.0, 10.0)
    out = Madgwick(s).run(rows)
    a, b = int(30.0 * RATE_HZ), int(40.0 * RATE_HZ)
    heading = _heading_deg(out[:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned)
    assert np.all(out[a + 2 : b, OUT_MAG_WEIGHT] == 0.0)
    assert np.max(np.abs(heading[a:b] - heading[a - 1])) < 0.5
    assert np.all(out[b + int(3 * RATE_HZ) : b + int(5 * RATE_HZ), OUT_MAG_WEIGHT] > 0.99)  # re-accepted
    open_door = replace(s, schedule=replace(s.schedule, mag_norm_tolerance=0.0, mag_dip_tolerance_rad=0.0))
    out_open = Madgwick(open_door).run(rows)
    heading_open = _heading_deg(out_open[:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned)
    assert np.max(np.abs(heading_open[a:b] - heading_open[a - 1])) > 5.0


@pytest.mark.parametrize("form", ["IMU", "MARG-heading"])
def test_rejected_accelerometer_leaves_tilt_to_the_gyro(form: str, synthetic) -> None:  # type: ignore[no-untyped-def]
    """A 2 s burst of 8 m/s² horizontal acceleration (‖f‖ ≈ 1.28 g).

    With norm rejection on (12 % tolerance) the gravity part leaves the
    gradient and the tilt error grows < 0.1° (gyro only, 0.3°/s noise); with it
    off the raw accelerometer pulls the estimate towards the 39° tilted
    specific force (> 2°).  (In the stacked MARG form the magnetic part alone
    would still move the tilt: its gradient has a component ∝ h_z.)
    """
    tr = synthetic(30.0, RATE_HZ, amplitude=0.3, noise=True)
    rows = tr.inputs(mag=form != "IMU")
    sl = slice(int(20 * RATE_HZ), int(22 * RATE_HZ))
    rows[sl, IN_ACCEL : IN_ACCEL + 3] += rotate(conjugate(tr.q_body_to_ned[sl]), [8.0, 0.0, 0.0])
    res = {}
    for tol in (0.0, 0.12):
        sched = replace(NO_SCHEDULE, accel_norm_tolerance=tol, recovery_s=0.0)
        s = replace(PAPER, schedule=sched, mag_correction="heading")
        out = Madgwick(s).run(rows)
        incl = _deg(attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned)[2])
        res[tol] = float(np.max(incl[sl]) - incl[sl.start - 1])  # growth of the tilt error
        if tol > 0.0:
            assert np.all(out[sl, OUT_ACCEL_WEIGHT] == 0.0)
    assert res[0.12] < 0.1
    assert res[0.0] > 2.0


def test_heading_mode_keeps_the_magnetometer_out_of_tilt(synthetic) -> None:  # type: ignore[no-untyped-def]
    """A field 20° steeper than the configured reference tilts the stacked objective, not the heading one.

    Both without distortion compensation (b from the reference dip, 66°), so
    the stacked objective (eq. 31) can only be satisfied by tilting; the
    heading-only objective ignores the vertical component.
    """
    tr = synthetic(40.0, RATE_HZ, amplitude=0.5)
    rows = tr.inputs(mag=True)
    m_ned = rotate(tr.q_body_to_ned, rows[:, IN_MAG : IN_MAG + 3])
    steeper = rotate(from_axis_angle([0.0, 1.0, 0.0], math.radians(-20.0)), m_ned)
    rows[:, IN_MAG : IN_MAG + 3] = rotate(conjugate(tr.q_body_to_ned), steeper)
    reference = replace(NO_SCHEDULE, mag_reference_norm_ut=49.2, mag_reference_dip_rad=math.atan2(45.0, 20.0))
    k = int(20 * RATE_HZ)
    incl = {}
    for mode in ("full", "heading"):
        s = replace(PAPER, mag_correction=mode, distortion_compensation=False, schedule=reference)
        out = Madgwick(s).run(rows)
        incl[mode] = _rms(_deg(attitude_errors_rad(out[k:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned[k:])[2]))
    assert incl["heading"] < 0.1
    assert incl["full"] > 1.0


def test_accelerometer_lowpass_removes_motion_acceleration_tilt(synthetic) -> None:  # type: ignore[no-untyped-def]
    """1 Hz horizontal shaking of 3 m/s²: the quasi-inertial low-pass (τ = 2 s) cuts the tilt error ≥ 3×.

    The Butterworth cut-off is 0.11 Hz, so 1 Hz is attenuated ≈ 80×; the raw
    filter chases the ±17° swing of the specific force at 2β = 4.7°/s.
    """
    tr = synthetic(60.0, RATE_HZ, amplitude=0.5, noise=True)
    rows = tr.inputs(mag=True)
    t = tr.t_s[:, None]
    shake_ned = 3.0 * np.hstack([np.sin(2 * np.pi * t), np.cos(2 * np.pi * 1.1 * t), np.zeros_like(t)])
    rows[:, IN_ACCEL : IN_ACCEL + 3] += rotate(conjugate(tr.q_body_to_ned), shake_ned)
    k = int(15 * RATE_HZ)
    res = {}
    for tau in (0.0, 2.0):
        s = replace(PAPER, accel_lowpass_s=tau, mag_correction="heading")
        out = Madgwick(s).run(rows)
        res[tau] = _rms(_deg(attitude_errors_rad(out[k:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned[k:])[2]))
    assert res[2.0] < res[0.0] / 3.0


def test_adaptive_lowpass_lengthens_only_under_motion_acceleration(synthetic) -> None:  # type: ignore[no-untyped-def]
    """``accel_lowpass_adapt_ratio``: a slow 4 m sinusoidal path with little rotation: the 3 s low-pass
    blended in cuts the tilt error (measured 4.6° → 2.8° inclination RMS); pure rotation leaves ā/ω̄
    below the ratio, so the output is exactly the fixed 2 s filter's."""
    base = replace(best_settings(), lowpass_norm_tolerance=0.0, accel_lowpass_adapt_ratio=0.0)
    adaptive = replace(base, accel_lowpass_adapt_ratio=1.0, accel_lowpass_max_s=3.0)
    k = int(10 * RATE_HZ)
    translation = synthetic(90.0, RATE_HZ, amplitude=0.2, noise=True, linear_acceleration_m=4.0)
    rows = translation.inputs(mag=True)
    incl = {}
    for name, s in (("fixed", base), ("adaptive", adaptive)):
        out = Madgwick(s).run(rows)
        incl[name] = _rms(_deg(attitude_errors_rad(out[k:, OUT_Q : OUT_Q + 4], translation.q_body_to_ned[k:])[2]))
    assert incl["fixed"] > 3.0
    assert incl["adaptive"] < 0.75 * incl["fixed"], incl
    rotation = synthetic(60.0, RATE_HZ, amplitude=1.0, noise=True).inputs(mag=True)
    np.testing.assert_array_equal(Madgwick(adaptive).run(rotation), Madgwick(base).run(rotation))


@pytest.mark.parametrize("velocity", [False, True], ids=["no-velocity", "velocity"])
def test_lowpass_norm_weight_and_gnss_compensation(velocity: bool, synthetic) -> None:  # type: ignore[no-untyped-def]
    """A 4 m sinusoidal path (≈ 2.6 m/s² peaks, periods of 6–8 s) that the 2 s low-pass cannot average out.

    Without velocity, ``best`` without the manoeuvre weight is ≈ 4.5° off
    (inclination RMS); with it (‖f̄‖ beyond 5 % of g: 20 % of the gravity
    correction, reported as accel_weight) ≈ 2°, and the weight is below 0.5
    for most of the run.  With velocity, f − v̇ is the vertical: ≈ 0.3°
    either way, and the weight stays at 1 (the compensated f̄ has norm g).
    """
    tr = synthetic(90.0, RATE_HZ, noise=True, linear_acceleration_m=4.0)
    rows = tr.inputs(mag=True, velocity=velocity)
    k = int(10 * RATE_HZ)
    res = {}
    for tol in (0.0, 0.05):
        # the manoeuvre weight alone: the adaptive low-pass (which also follows it) off
        s = replace(best_settings(), lowpass_norm_tolerance=tol, accel_lowpass_adapt_ratio=0.0)
        out = Madgwick(s).run(rows)
        res[tol] = _rms(_deg(attitude_errors_rad(out[k:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned[k:])[2]))
        weight_low = float(np.mean(out[k:, OUT_ACCEL_WEIGHT] < 0.5))
        if tol == 0.0 or velocity:
            assert weight_low == 0.0
        else:
            assert weight_low > 0.5
    if velocity:
        assert res[0.0] < 0.5 and res[0.05] < 0.5
    else:
        assert res[0.0] > 3.0
        assert res[0.05] < 0.6 * res[0.0]


def test_gnss_compensation_off_ignores_velocity(synthetic) -> None:  # type: ignore[no-untyped-def]
    """``gnss_acceleration=False``: the velocity column changes nothing (the rest detector aside, off here)."""
    tr = synthetic(20.0, RATE_HZ, noise=True, linear_acceleration_m=4.0)
    s = replace(best_settings(), gnss_acceleration=False, rest=RestBiasSettings(bias_tau_s=0.0))
    a = Madgwick(s).run(tr.inputs(velocity=True))
    b = Madgwick(s).run(tr.inputs(velocity=False))
    np.testing.assert_array_equal(a[:, OUT_Q : OUT_Q + 4], b[:, OUT_Q : OUT_Q + 4])


def test_startup_flag_and_boost_after_initialisation(synthetic) -> None:  # type: ignore[no-untyped-def]
    """Defaults: ×10 β at start, ramping to β over 3 s; the STARTUP flag and the gain output show it."""
    tr = synthetic(5.0, RATE_HZ, noise=True)
    f = create("madgwick")
    out = f.run(tr.inputs())
    gain = out[:, OUT_GAIN]
    startup = (out[:, OUT_FLAGS].astype(int) & FLAG_STARTUP) != 0
    assert gain[2] == pytest.approx(10 * 0.041, rel=0.02)
    assert gain[int(1.5 * RATE_HZ)] == pytest.approx(5.5 * 0.041, rel=0.02)  # linear ramp, half way
    assert gain[-1] == pytest.approx(0.041, rel=1e-6)
    assert startup[: int(2.9 * RATE_HZ)].all() and not startup[int(3.1 * RATE_HZ) :].any()
    assert f.diagnostics.startup is False


@pytest.mark.slow  # the parallel driver loop is compiled per process (≈ 5 s)
def test_run_many_equals_run(synthetic) -> None:  # type: ignore[no-untyped-def]
    """The parallel sweep path gives the same quaternions as one filter at a time, and carries state."""
    tr = synthetic(10.0, RATE_HZ, noise=True)
    rows = tr.inputs()
    settings = [replace(best_settings(), beta_rad_s=b) for b in (0.005, 0.02, 0.1)]
    filters = [Madgwick(s) for s in settings]
    q = run_many(filters, rows[:1000])
    q2 = run_many(filters, rows[1000:])
    for s, qm, qm2 in zip(settings, q, q2, strict=True):
        out = Madgwick(s).run(rows)
        np.testing.assert_array_equal(qm, out[:1000, OUT_Q : OUT_Q + 4])
        np.testing.assert_array_equal(qm2, out[1000:, OUT_Q : OUT_Q + 4])
    with pytest.raises(TypeError):
        run_many([Madgwick(), create("mahony")], rows)


@pytest.mark.parametrize("order", [1, 2], ids=["first-order", "butterworth"])
def test_lowpass_start_averages_instead_of_holding_the_first_sample(order: int) -> None:
    """Vibration (σ = 2 m/s² per axis) at rest, and a 2 s gap: ``best``'s tilt is within 2° 1 s after each start.

    The attitude is initialised from one accelerometer sample, here several
    degrees off.  The NED low-pass (τ = 2 s) averages its first τ seconds, so
    the start-up gain pulls the attitude to the mean of the samples so far;
    a low-pass started from that first sample would agree with its error and
    hold it for about τ.
    """
    rate, n = 400.0, 400 * 24
    rng = np.random.default_rng(5)
    q_true = from_axis_angle(np.array([1.0, 0.0, 0.0]), math.radians(10.0))
    down_body = rotate(conjugate(q_true), np.array([0.0, 0.0, 9.80665]))
    field_body = rotate(conjugate(q_true), np.array([20.0, 0.0, 45.0]))
    accel = -down_body + rng.normal(scale=2.0, size=(n, 3))
    gyro = rng.normal(scale=math.radians(0.2), size=(n, 3))
    mag = field_body + rng.normal(scale=0.5, size=(n, 3))
    dt = np.full(n, 1.0 / rate)
    gap = int(12 * rate)
    dt[gap] = 2.0  # a link outage: the filter re-initialises from this sample
    out = Madgwick(replace(best_settings(), accel_lowpass_order=order)).run(make_inputs(gyro, accel, mag, dt_s=dt))
    incl = _deg(attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], np.tile(q_true, (n, 1)))[2])
    for start in (0, gap):
        first = incl[start + 1]
        settled = incl[start + int(1.0 * rate) : start + int(3.0 * rate)]
        assert first > 2.0, "the single-sample initialisation should be visibly off in this noise"
        assert settled.max() < 2.0, (start, first, settled.max())  # measured 0.4-0.7°; from the first sample: 8-15°
