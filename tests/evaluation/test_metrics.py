"""Per-angle errors, rest/motion masks and statistics (the papers' definitions)."""

from __future__ import annotations

import numpy as np

from mavahrs.evaluation.metrics import (
    angle_stats,
    attitude_errors_rad,
    body_error_quaternion,
    euler_deg,
    euler_errors_rad,
    motion_mask,
    summarize,
)
from mavahrs.geometry.quaternion import multiply, random_unit
from mavahrs.geometry.rotation import from_euler_rad


def test_euler_errors_are_the_body_rotation_between_estimate_and_reference(rng: np.random.Generator) -> None:
    q_ref = random_unit(200, rng)
    err = np.radians(rng.uniform(-20, 20, size=(200, 3)))
    q_err = from_euler_rad(err[:, 0], err[:, 1], err[:, 2])
    q_est = multiply(q_ref, q_err)  # q_est = q_ref ⊗ q_ε
    np.testing.assert_allclose(euler_errors_rad(q_est, q_ref), err, atol=1e-9)
    # sign of q does not matter
    np.testing.assert_allclose(euler_errors_rad(-q_est, q_ref), err, atol=1e-9)
    e = body_error_quaternion(q_est, q_ref)
    np.testing.assert_allclose(np.abs(e), np.abs(q_err), atol=1e-12)


def test_nan_reference_rows_stay_nan(rng: np.random.Generator) -> None:
    q = random_unit(5, rng)
    ref = q.copy()
    ref[2] = np.nan
    e = euler_errors_rad(q, ref)
    assert np.isnan(e[2]).all() and np.isfinite(e[[0, 1, 3, 4]]).all()
    assert np.isnan(euler_deg(ref)[2]).all()
    s = angle_stats(e)
    assert s.samples == 4 and max(s.rms_deg) < 1e-9


def test_angle_stats_mean_sd_rms() -> None:
    e = np.zeros((4, 3))
    e[:, 0] = np.radians([1.0, 3.0, 1.0, 3.0])  # mean 2, SD 1, RMS √5
    s = angle_stats(e)
    np.testing.assert_allclose(s.mean_deg[0], 2.0)
    np.testing.assert_allclose(s.sd_deg[0], 1.0)
    np.testing.assert_allclose(s.rms_deg[0], np.sqrt(5.0))
    np.testing.assert_allclose(s.max_abs_deg[0], 3.0)
    assert angle_stats(e, np.zeros(4, bool)).samples == 0


def test_motion_mask_splits_at_5_deg_per_s() -> None:
    n = 1000
    gyro = np.zeros((n, 3))
    gyro[500:, 2] = np.radians(6.0)
    gyro[:500, 0] = np.radians(4.0)
    m = motion_mask(gyro, 0.01)
    assert not m[:480].any() and m[520:].all()


def test_summarize_matches_broad_definitions_on_a_pure_heading_error(rng: np.random.Generator) -> None:
    q_ref = random_unit(50, rng)
    q_h = from_euler_rad(0.0, 0.0, np.radians(10.0))  # 10° about the earth vertical
    q_est = multiply(q_h, q_ref)
    s = summarize(q_est, q_ref)
    assert abs(s.heading_rms_deg - 10.0) < 1e-9 and s.inclination_rms_deg < 1e-6
    total, _, _ = attitude_errors_rad(q_est, q_ref)
    np.testing.assert_allclose(np.degrees(total), 10.0)
