"""Magnetometer ellipsoid fit: a simulated hard/soft iron is recovered and the heading improves."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.errors import DataError
from mavahrs.evaluation.magcal import (
    MagFitSettings,
    fit_ellipsoid,
    magnetic_heading_error_rad,
    orientation_coverage,
)
from mavahrs.geometry.quaternion import conjugate, from_axis_angle, multiply, random_unit, rotate
from mavahrs.sensors.calibration import MagCalibration
from mavahrs.sensors.geomag import expected_field

# A real place: the field there from the World Magnetic Model, in magnetic NED (declination removed).
FIELD = expected_field(-35.36, 149.17, 600.0, 2026.0)
F_UT = FIELD.strength_ut
H_UT = F_UT * math.cos(FIELD.inclination_rad)
FIELD_MAG_NED = np.array([H_UT, 0.0, F_UT * math.sin(FIELD.inclination_rad)])

OFFSET_UT = np.array([23.0, -41.0, 12.5])  # hard iron (about 1 field strength)


def _soft_iron(rng: np.random.Generator, size: float = 0.12) -> np.ndarray:
    """A random symmetric positive-definite distortion, eigenvalues within 1 ± ~size."""
    a = rng.normal(size=(3, 3)) * size
    s = np.eye(3) + 0.5 * (a + a.T)
    assert np.all(np.linalg.eigvalsh(s) > 0.5)
    return s


def _body_field(q_body_to_ned: np.ndarray) -> np.ndarray:
    return rotate(conjugate(q_body_to_ned), np.broadcast_to(FIELD_MAG_NED, (len(q_body_to_ned), 3)))


def _distort(m_body: np.ndarray, s: np.ndarray, rng: np.random.Generator, noise_ut: float) -> np.ndarray:
    return m_body @ s.T + OFFSET_UT + rng.normal(scale=noise_ut, size=m_body.shape)


def _rms_deg(x: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(np.mean(x**2))))


def test_recovers_simulated_hard_and_soft_iron(rng: np.random.Generator) -> None:
    q = random_unit(1500, rng)
    truth = _body_field(q)
    s = _soft_iron(rng)
    raw = _distort(truth, s, rng, noise_ut=0.3)
    fit = fit_ellipsoid(raw, F_UT, strength_source="WMM")

    # The calibration itself (applied to the noise-free distorted field) is within 2 % of F everywhere.
    clean = truth @ s.T + OFFSET_UT
    err = np.linalg.norm(fit.apply(clean) - truth, axis=1)
    assert err.max() < 0.02 * F_UT, f"max error {err.max():.2f} µT"
    assert np.linalg.norm(np.array(fit.offset_ut) - OFFSET_UT) < 0.02 * F_UT
    np.testing.assert_allclose(np.array(fit.matrix) @ s, np.eye(3), atol=0.01)
    # Quality figures describe it: residual ≈ the noise, full coverage, no warnings.
    assert fit.residual_rms_ut == pytest.approx(0.3, rel=0.25)
    assert fit.residual_rms_percent == pytest.approx(100 * fit.residual_rms_ut / F_UT)
    assert fit.raw_residual_rms_ut > 10 * fit.residual_rms_ut
    assert fit.coverage > 0.95 and fit.direction_spread > 0.8
    assert fit.warnings == ()
    assert fit.samples == 1500 and fit.strength_source == "WMM"

    # The heading from the field, with the true tilt, drops from tens of degrees to the noise level.
    before = _rms_deg(magnetic_heading_error_rad(raw, q))
    after = _rms_deg(magnetic_heading_error_rad(fit.apply(raw), q))
    noise_floor = math.degrees(0.3 / H_UT)  # ≈ 0.6° for 0.3 µT noise on a ~27 µT horizontal field
    assert before > 20.0
    assert after < 2.0 * noise_floor + 0.3, (before, after)
    # The fitted calibration is exactly what the pipeline applies.
    cal = fit.to_calibration()
    assert isinstance(cal, MagCalibration)
    np.testing.assert_allclose(cal.apply(tuple(raw[7])), fit.apply(raw[7]), atol=1e-12)


def test_a_calibrated_sensor_fits_to_identity(rng: np.random.Generator) -> None:
    q = random_unit(800, rng)
    truth = _body_field(q)
    raw = truth + rng.normal(scale=0.2, size=truth.shape)
    fit = fit_ellipsoid(raw, F_UT)
    assert np.linalg.norm(fit.offset_ut) < 0.1
    np.testing.assert_allclose(fit.matrix, np.eye(3), atol=0.01)


def test_unknown_strength_scales_to_the_mean_radius(rng: np.random.Generator) -> None:
    q = random_unit(800, rng)
    truth = _body_field(q)
    s = np.diag([1.2, 1.0, 0.9])
    fit = fit_ellipsoid(truth @ s.T + OFFSET_UT, None)
    assert fit.strength_source == "fit"
    assert fit.field_strength_ut == pytest.approx(F_UT * (1.2 * 1.0 * 0.9) ** (1 / 3), rel=1e-3)
    # Shape is still right: corrected vectors are the truth up to one common scale.
    cor = fit.apply(truth @ s.T + OFFSET_UT)
    np.testing.assert_allclose(cor / fit.field_strength_ut, truth / F_UT, atol=1e-3)


def _yaw_with_tilt(n: int, max_tilt_rad: float, rng: np.random.Generator) -> np.ndarray:
    yaw = rng.uniform(-math.pi, math.pi, n)
    z = np.zeros(n)
    qy = np.stack([np.cos(yaw / 2), z, z, np.sin(yaw / 2)], axis=1)
    roll = from_axis_angle(np.stack([z + 1, z, z], axis=1), rng.uniform(-max_tilt_rad, max_tilt_rad, n))
    pitch = from_axis_angle(np.stack([z, z + 1, z], axis=1), rng.uniform(-max_tilt_rad, max_tilt_rad, n))
    return multiply(multiply(qy, pitch), roll)


def test_poor_orientation_coverage_is_refused(rng: np.random.Generator) -> None:
    q = _yaw_with_tilt(1500, math.radians(15.0), rng)  # flat turns only: soft iron unobservable vertically
    raw = _distort(_body_field(q), _soft_iron(rng), rng, 0.3)
    with pytest.raises(DataError, match="coverage|ellipsoid"):
        fit_ellipsoid(raw, F_UT)


def test_forced_fit_with_poor_coverage_warns(rng: np.random.Generator) -> None:
    q = _yaw_with_tilt(1500, math.radians(30.0), rng)
    raw = _distort(_body_field(q), _soft_iron(rng, 0.05), rng, 0.3)
    settings = MagFitSettings(min_coverage=0.5, warn_coverage=0.8)
    with pytest.raises(DataError, match="coverage"):
        fit_ellipsoid(raw, F_UT, settings=settings)
    fit = fit_ellipsoid(raw, F_UT, settings=settings, force=True)
    assert fit.coverage < 0.5
    assert any("forced" in w for w in fit.warnings)


def test_moderate_coverage_is_accepted_with_a_warning(rng: np.random.Generator) -> None:
    q = _yaw_with_tilt(2000, math.radians(50.0), rng)
    truth = _body_field(q)
    s = _soft_iron(rng, 0.08)
    fit = fit_ellipsoid(_distort(truth, s, rng, 0.3), F_UT)
    assert 0.35 <= fit.coverage < 0.6
    assert any("coverage" in w for w in fit.warnings)
    clean = truth @ s.T + OFFSET_UT
    assert np.linalg.norm(fit.apply(clean) - truth, axis=1).max() < 0.03 * F_UT


def test_disturbed_recording_warns_about_residual(rng: np.random.Generator) -> None:
    q = random_unit(1500, rng)
    raw = _distort(_body_field(q), np.eye(3), rng, 3.0)  # 3 µT noise ≈ 6 % of F
    fit = fit_ellipsoid(raw, F_UT)
    assert fit.residual_rms_percent > 3.0
    assert any("residual" in w for w in fit.warnings)


def test_invalid_input(rng: np.random.Generator) -> None:
    with pytest.raises(DataError, match="samples"):
        fit_ellipsoid(np.zeros((500, 3)), F_UT)  # all-zero rows are ignored
    raw = _body_field(random_unit(300, rng))
    raw[::3] = np.nan
    assert fit_ellipsoid(raw, F_UT).samples == 200
    with pytest.raises(ValueError):
        fit_ellipsoid(raw, -1.0)
    with pytest.raises(ValueError):
        MagFitSettings(min_coverage=0.9, warn_coverage=0.5)


def test_orientation_coverage(rng: np.random.Generator) -> None:
    assert orientation_coverage(rng.normal(size=(5000, 3))) == 1.0
    assert orientation_coverage(np.tile([0.0, 0.0, 1.0], (100, 1))) == pytest.approx(1 / 60)
    assert orientation_coverage(np.zeros((10, 3))) == 0.0
