"""scripts/bench_broad_compass.py's measurements: known truths recovered, and what they say of BROAD's compass.

Synthetic (truth by construction): a sensor turning about all three axes reads an earth-fixed field through
a known hard/soft iron and misalignment, ``delay`` late.  The truth-fitted calibration recovers the
distortion and takes the perfect-attitude compass's azimuth error from degrees to noise; the delay
regression recovers the delay from the gyro and the readings alone.  BROAD (skipped without
../shared/data/broad): the figures docs/accuracy.md round four (branch smag) rests on.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from mavahrs.evaluation.datasets import Recording
from mavahrs.geometry.quaternion import conjugate, from_rotation_vector, multiply, normalize, rotate

RATE_HZ = 2000.0 / 7.0  # BROAD's
FINE = 10  # truth integrated at 10 × the sample rate, so a delay need not be a whole number of samples
FIELD_NED_UT = np.array([20.0, 1.0, 43.0])  # ≈ BROAD's: 47 µT, dip 65°
SOFT = np.array(
    [[1.04, 0.02, -0.01], [0.015, 0.97, 0.025], [-0.02, 0.01, 1.02]]
)  # soft iron and misalignment
HARD_UT = np.array([3.0, -2.0, 1.5])


@pytest.fixture(scope="module")
def bb(bench_script: Callable[[str], ModuleType]) -> ModuleType:
    return bench_script("bench_broad_compass")


def _turning_sensor(delay_s: float, seconds: float = 30.0, noise_ut: float = 0.1) -> Recording:
    """A sensor at rest 1.5 s, then turning about all axes (up to ≈ 200 °/s): gyro, q_body_to_ned, and the distorted field read late."""
    rng = np.random.default_rng(7)
    dt = 1.0 / (RATE_HZ * FINE)
    t = np.arange(round(seconds * RATE_HZ * FINE)) * dt
    freqs = np.array([[0.31, 0.73], [0.47, 0.59], [0.23, 0.91]])
    w = np.stack(
        [
            1.2 * np.sin(2 * np.pi * f[0] * t + k) + 0.8 * np.sin(2 * np.pi * f[1] * t)
            for k, f in enumerate(freqs)
        ],
        1,
    )
    w *= np.clip(t - 1.5, 0.0, 1.0)[
        :, None
    ]  # at rest for 1.5 s first, as a BROAD trial (its north is that rest's field)
    steps = from_rotation_vector(w * dt)
    q = np.empty((len(t), 4))
    q[0] = [1.0, 0.0, 0.0, 0.0]
    for i in range(1, len(t)):
        q[i] = multiply(q[i - 1], steps[i - 1])
        if i % 1000 == 0:
            q[i] = normalize(q[i])
    field_body = rotate(conjugate(q), np.broadcast_to(FIELD_NED_UT, (len(t), 3)))
    lag = round(delay_s / dt)
    idx = np.arange(0, len(t), FINE)
    idx = idx[idx >= lag]
    read = field_body[idx - lag] @ SOFT.T + HARD_UT + rng.normal(scale=noise_ut, size=(len(idx), 3))
    n = len(idx)
    return Recording(
        name="synthetic",
        dt_s=np.full(n, 1.0 / RATE_HZ),
        gyro_rad_s=w[idx],
        accel_m_s2=np.tile([0.0, 0.0, -9.81], (n, 1)),
        mag_ut=read,
        q_ref_body_to_ned=q[idx],
        scored=np.ones(n, dtype=bool),
    )


def test_truth_fitted_calibration_recovers_a_known_distortion_and_the_azimuth(bb: ModuleType) -> None:
    rec = _turning_sensor(delay_s=0.0)
    e_raw, mask = bb.azimuth_error_deg(rec, rec.mag_ut)
    truth_body = rotate(conjugate(rec.q_ref_body_to_ned), np.broadcast_to(FIELD_NED_UT, (rec.n, 3)))
    a, b = bb.fit_calibration_with_truth(rec.mag_ut, truth_body)
    assert np.abs(a - SOFT).max() < 0.005, a
    assert np.abs(b - HARD_UT).max() < 0.1, b
    # as the script fits BROAD (the field fitted too, from the rest's reading): the azimuth error down to noise
    a, b, f = bb.truth_calibration(rec, shift=0, fit_field=True)
    e_cal, mask_cal = bb.azimuth_error_deg(rec, bb.apply_calibration(rec.mag_ut, a, b), 0, f)
    assert bb.rms(e_raw, mask) > 2.0  # the distortion's azimuth error
    assert bb.rms(e_cal, mask_cal) < 0.3, bb.rms(e_cal, mask_cal)  # the readings' noise


@pytest.mark.parametrize("delay_ms", [0.0, 10.5])
def test_delay_regression_recovers_a_known_compass_delay_through_a_distortion(delay_ms: float, bb: ModuleType) -> None:
    rec = _turning_sensor(delay_s=delay_ms * 1e-3)
    got_ms = bb.compass_delay_s(rec.gyro_rad_s, rec.mag_ut, float(rec.dt_s[0])) * 1e3
    assert abs(got_ms - delay_ms) < 1.0, got_ms
    # against the truth the late compass is best matched that many samples back (10.5 ms = 3 samples)
    errs = {s: bb.rms(*bb.azimuth_error_deg(rec, rec.mag_ut, s)) for s in (0, -3)}
    assert (errs[-3] < errs[0]) == (delay_ms > 0), errs


@pytest.fixture(scope="module")
def broad(broad_dir: Path) -> dict[str, Recording]:
    from mavahrs.evaluation.datasets import find_broad_trials, load_broad_trial

    paths = {p.name[:2]: p for p in find_broad_trials(broad_dir)}
    if not {"02", "06", "30"} <= set(paths):
        pytest.skip(f"BROAD trials 02, 06, 30 not all in {broad_dir}")
    return {k: load_broad_trial(paths[k]) for k in ("02", "06", "30")}


def test_broad_compass_is_about_10_ms_behind_the_gyro(broad: dict[str, Recording], bb: ModuleType) -> None:
    for key, rec in broad.items():
        got_ms = bb.compass_delay_s(rec.gyro_rad_s, rec.mag_ut, float(rec.dt_s[0])) * 1e3
        assert 8.0 < got_ms < 13.0, (key, got_ms)
    rec = broad[
        "06"
    ]  # fast rotation: read 4 samples later against the reference, the azimuth error shrinks by a third
    e0 = bb.rms(*bb.azimuth_error_deg(rec, rec.mag_ut, 0))
    e4 = bb.rms(*bb.azimuth_error_deg(rec, rec.mag_ut, -4))
    assert e4 < 0.7 * e0, (e0, e4)


def test_broad_compass_is_calibrated_and_its_rest_norm_is_not_the_moving_one(
    broad: dict[str, Recording],
    bb: ModuleType,
) -> None:
    from mavahrs.evaluation.magcal import fit_ellipsoid

    rec = broad["02"]
    fit = fit_ellipsoid(rec.mag_ut[rec.scored], None)
    # an ellipsoid removes little: the raw readings' spread about a sphere is nearly the fitted one's
    assert fit.residual_rms_ut > 0.8 * fit.raw_residual_rms_ut, (fit.residual_rms_ut, fit.raw_residual_rms_ut)
    assert max(abs(x) for x in fit.offset_ut) < 1.0 and fit.axis_ratio < 1.1
    # trial 06 starts at rest where the field is ≈ 7 % weaker than where it moves (the schedule's norm reference)
    rest, moving = bb.rest_and_motion_norm_ut(broad["06"])
    assert moving / rest - 1.0 > 0.05, (rest, moving)


def _rolling_sensor(w_ned_rad_s: np.ndarray, lag_samples: int, seconds: float = 20.0) -> Recording:
    """A sensor turning at a constant rate about a fixed NED axis (exact attitudes), its compass ``lag_samples`` late."""
    n = round(seconds * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    q0 = from_rotation_vector(np.array([0.3, -0.2, 0.5]))
    q = multiply(from_rotation_vector(np.outer(t, w_ned_rad_s)), np.broadcast_to(q0, (n, 4)))
    field_body = rotate(conjugate(q), np.broadcast_to(FIELD_NED_UT, (n, 3)))
    mag = np.r_[np.repeat(field_body[:1], lag_samples, axis=0), field_body[: n - lag_samples]]
    scored = np.ones(n, dtype=bool)
    scored[: lag_samples + 1] = False
    return Recording(
        name="rolling",
        dt_s=np.full(n, 1.0 / RATE_HZ),
        gyro_rad_s=rotate(conjugate(q), np.broadcast_to(w_ned_rad_s, (n, 3))),
        accel_m_s2=np.tile([0.0, 0.0, -9.81], (n, 1)),
        mag_ut=mag,
        q_ref_body_to_ned=q,
        scored=scored,
    )


def test_a_late_reading_in_a_roll_about_north_is_off_by_the_roll_times_tan_dip_not_by_the_yaw_rate(bb: ModuleType) -> None:
    w_ned = np.array([2.6, 0.0, 0.7])  # 150 °/s about north, 40 °/s of yaw: trial 30's motion, in the mean
    rec = _rolling_sensor(w_ned, lag_samples=3)
    lag_s = 3.0 / RATE_HZ
    measured, _ = bb.late_azimuth_bias_deg(rec, 3)
    s = rec.scored
    predicted = np.degrees(
        lag_s * bb.late_azimuth_rate_rad_s(rec.q_ref_body_to_ned[s], rec.gyro_rad_s[s], rec.mag_ut[s]).mean()
    )
    yaw_only = np.degrees(lag_s * w_ned[2])
    # ω_D − tan(dip)·ω_N: 0.7 − 2.15 × 2.6 rad/s → −2.9° at 10.5 ms; the yaw rate alone says +0.4°
    assert measured < -2.5, measured
    assert abs(predicted - measured) < 0.05 * abs(measured), (predicted, measured)
    assert yaw_only > 0.0


def test_gyro_heading_drift_is_measured_against_the_reference_and_is_zero_with_the_true_bias(bb: ModuleType) -> None:
    rec = _rolling_sensor(np.array([0.0, 0.0, 1.0]), lag_samples=0)  # yawing at 57 °/s, body z along down
    err = np.radians([0.0, 0.0, 0.3])  # the gyro 0.3 °/s high about its z axis
    rec.gyro_rad_s = rec.gyro_rad_s + err
    drift = bb.gyro_heading_drift_deg_s(rec, np.zeros(3), window_s=5.0, gyro_shift=0)
    # body z is the sensor's down only up to q0's tilt (≈ 21°): the vertical share of the error, cos 21°·0.3
    down_z = rotate(rec.q_ref_body_to_ned[0], np.array([0.0, 0.0, 1.0]))[2]
    assert len(drift) == 3 and np.allclose(drift, 0.3 * down_z, atol=0.01), drift
    assert np.allclose(bb.gyro_heading_drift_deg_s(rec, err, window_s=5.0, gyro_shift=0), 0.0, atol=1e-3)


def test_broad_trial_30_rolls_about_north_so_its_late_compass_is_4_degrees_off_and_its_gyro_drifts(
    broad: dict[str, Recording],
    bb: ModuleType,
) -> None:
    """docs/accuracy.md round six (branch smag4): the stationary magnet's trial 30 turns 164 °/s about north in the
    mean; there the ≈ 10 ms late compass reads −4° of azimuth in every reading (its yaw-rate term has the
    other sign), and the gyro's heading drifts −0.18 °/s against the reference.  Trial 06 (fast rotation,
    no mean turn) has neither."""
    rec = broad["30"]
    measured, _ = bb.late_azimuth_bias_deg(rec, 3)
    q, ok = bb._reference(rec)
    s = ok & rec.scored
    lag_s = bb.compass_delay_s(rec.gyro_rad_s, rec.mag_ut, float(rec.dt_s[0]))
    predicted = np.degrees(lag_s * bb.late_azimuth_rate_rad_s(q[s], rec.gyro_rad_s[s], rec.mag_ut[s]).mean())
    yaw = lag_s * np.degrees(rotate(q[s], rec.gyro_rad_s[s])[:, 2].mean())
    assert measured < -3.0, measured
    assert abs(predicted - measured) < 0.15 * abs(measured), (predicted, measured)
    assert yaw > 0.0, yaw
    for key in ("02", "06"):
        assert abs(bb.late_azimuth_bias_deg(broad[key], 3)[0]) < 0.5, key

    def drift(r: Recording) -> np.ndarray:
        rest = round(1.0 / float(r.dt_s[0]))  # every BROAD trial starts at rest: its mean rate is the bias
        return bb.gyro_heading_drift_deg_s(r, r.gyro_rad_s[:rest].mean(axis=0))

    d30 = drift(rec)
    assert d30.mean() < -0.1 and (d30 < 0.0).all(), d30
    for key in ("02", "06"):
        assert abs(drift(broad[key]).mean()) < 0.05, key


# ------------------------------------------------------------------ round seven (branch smag5): whose drift


def _rest_motion_rest(gyro_scale_z: float, reference_drift_deg: float, motion_s: float = 20.0) -> Recording:
    """At rest 3 s, turning about all axes (up to ≈ 160 °/s) for ``motion_s``, at rest 3 s again (attitudes integrated
    with the gyro's own steps, so the reference's step is the true rate × dt): the compass reads the earth
    field with the true attitude; the gyro has a scale error ``gyro_scale_z`` on its z axis; the reference's
    heading drifts by ``reference_drift_deg`` over the motion (a reference that drifts with the turns)."""
    n = round((motion_s + 6.0) * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    env = np.clip(t - 3.0, 0.0, 1.0) * np.clip(3.0 + motion_s - t, 0.0, 1.0)
    w = np.stack(
        [
            np.sin(2 * np.pi * 0.37 * t),
            1.2 * np.sin(2 * np.pi * 0.29 * t + 1),
            0.8 + 2.0 * np.sin(2 * np.pi * 0.21 * t + 2),
        ],
        1,
    )
    w *= env[:, None]
    steps = from_rotation_vector(w / RATE_HZ)
    q = np.empty((n, 4))
    q[0] = from_rotation_vector(np.array([0.2, -0.1, 0.4]))
    for i in range(1, n):
        q[i] = normalize(multiply(q[i - 1], steps[i - 1]))
    drift = np.radians(reference_drift_deg) * np.clip((t - 3.0) / motion_s, 0.0, 1.0)
    q_ref = multiply(from_rotation_vector(np.outer(drift, [0.0, 0.0, 1.0])), q)
    scored = (t > 3.5) & (t < 2.5 + motion_s)
    return Recording(
        name="rest-motion-rest",
        dt_s=np.full(n, 1.0 / RATE_HZ),
        gyro_rad_s=w * np.array([1.0, 1.0, 1.0 + gyro_scale_z]),
        accel_m_s2=rotate(conjugate(q), np.broadcast_to([0.0, 0.0, -9.81], (n, 3))),
        mag_ut=rotate(conjugate(q), np.broadcast_to(FIELD_NED_UT, (n, 3))),
        q_ref_body_to_ned=q_ref,
        scored=scored,
    )


def test_rests_tell_a_drifting_gyro_from_a_drifting_reference(bb: ModuleType) -> None:
    gyro = bb.rest_to_rest(_rest_motion_rest(gyro_scale_z=0.01, reference_drift_deg=0.0), gyro_shift=0)
    assert len(gyro) == 2
    # the gyro drifts: the compass at the second rest agrees with the reference, the integrated gyro does not
    assert abs(gyro[1]["field_azimuth_deg"]) < 0.05, gyro
    assert abs(gyro[1]["gyro_heading_error_deg"]) > 1.0, gyro
    ref = bb.rest_to_rest(_rest_motion_rest(gyro_scale_z=0.0, reference_drift_deg=-5.0), gyro_shift=0)
    # the reference drifts: the compass read with it is off by the drift, the gyro off by the same, the other way
    assert abs(ref[1]["field_azimuth_deg"] + 5.0) < 0.1, ref
    assert abs(ref[1]["gyro_heading_error_deg"] - 5.0) < 0.1, ref


def test_gyro_model_fit_recovers_a_scale_error_growing_with_the_rate(bb: ModuleType) -> None:
    rec = _rest_motion_rest(gyro_scale_z=0.0, reference_drift_deg=0.0, motion_s=60.0)
    n_true = np.array([-2e-3, 1e-3, -3e-3])  # per rad/s: −0.4 / +0.2 / −0.6 % at 200 °/s
    rec.gyro_rad_s = (
        rec.gyro_rad_s + n_true * np.linalg.norm(rec.gyro_rad_s, axis=1)[:, None] * rec.gyro_rad_s
    )
    data = {"s": bb.gyro_window_errors(rec, window_s=2.0, gyro_shift=0)}
    keys = bb.GYRO_MODELS["scale ∝ |ω| (3)"]
    coef = bb.fit_gyro_model(data, keys, ("s",))
    assert np.allclose(coef, n_true, atol=3e-4), coef
    before = bb.window_heading_drift_deg_s(data, "s", 2.0)
    after = bb.window_heading_drift_deg_s(data, "s", 2.0, keys, coef)
    assert np.sqrt(np.mean(before**2)) > 0.2 and np.sqrt(np.mean(after**2)) < 0.02, (before, after)
    # the oracle gyro of an exact reference is the gyro itself
    exact = _rest_motion_rest(gyro_scale_z=0.0, reference_drift_deg=0.0)
    assert np.abs(bb.oracle_gyro(exact, gyro_shift=0) - exact.gyro_rad_s).max() < 1e-9


@pytest.fixture(scope="module")
def broad_rests(broad_dir: Path) -> dict[str, Recording]:
    from mavahrs.evaluation.datasets import find_broad_trials, load_broad_trial

    paths = {p.name[:2]: p for p in find_broad_trials(broad_dir)}
    if not {"06", "08", "30"} <= set(paths):
        pytest.skip(f"BROAD trials 06, 08, 30 not all in {broad_dir}")
    return {k: load_broad_trial(paths[k]) for k in ("06", "08", "30")}


def test_broad_reference_agrees_with_the_compass_at_rests_while_the_gyro_drifts(
    broad_rests: dict[str, Recording],
    bb: ModuleType,
) -> None:
    """docs/accuracy.md round seven (branch smag5): the heading drift of trials 08 / 30 is the gyro's.  At every
    rest the compass (an earth-fixed direction; at rest its delay plays no part) read with the reference is within
    0.5° of the first rest's, while the gyro integrated over each motion before it is 2–15° off, always negative
    (08 −26°, 30 −17° in all); trial 06 (no mean turn) within 1°."""
    for key, total in (("08", -20.0), ("30", -12.0)):
        rows = bb.rest_to_rest(broad_rests[key])
        assert len(rows) >= 4, (key, rows)
        assert all(abs(r["field_azimuth_deg"]) < 0.5 for r in rows), (key, rows)
        errors = [r["gyro_heading_error_deg"] for r in rows[1:]]
        assert all(e < -1.5 for e in errors) and sum(errors) < total, (key, errors)
    rows = bb.rest_to_rest(broad_rests["06"])
    assert all(abs(r["gyro_heading_error_deg"]) < 1.0 for r in rows), rows
