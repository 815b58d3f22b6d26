"""Heading-offset and body-misalignment fits (Madgwick 2010, eq. (58)–(65))."""

from __future__ import annotations

import numpy as np
import pytest

from mavahrs.evaluation.alignment import fit_alignment, fit_body_misalignment
from mavahrs.evaluation.metrics import summarize
from mavahrs.geometry.quaternion import conjugate, from_rotation_vector, multiply, random_unit
from mavahrs.geometry.rotation import from_euler_rad


@pytest.fixture
def motion(rng: np.random.Generator) -> np.ndarray:
    return random_unit(2000, rng)


def test_heading_offset_is_recovered(motion: np.ndarray, rng: np.random.Generator) -> None:
    q_h = from_euler_rad(0.0, 0.0, np.radians(57.0))
    noise = from_rotation_vector(rng.normal(scale=np.radians(1.0), size=(motion.shape[0], 3)))
    q_est = multiply(multiply(q_h, motion), noise)
    a = fit_alignment(q_est, motion, mode="heading")
    assert abs(a.heading_offset_deg - 57.0) < 0.2
    assert summarize(q_est, a.apply(motion)).heading_rms_deg < 1.5
    assert summarize(q_est, motion).heading_rms_deg > 50


def test_heading_and_body_are_recovered_together(motion: np.ndarray) -> None:
    q_h = from_euler_rad(0.0, 0.0, np.radians(-120.0))
    q_b = from_rotation_vector(np.radians([2.0, -3.0, 1.5]))
    q_est = multiply(multiply(q_h, motion), q_b)
    ref = motion.copy()
    ref[::7] = np.nan  # dropouts are ignored
    a = fit_alignment(q_est, ref, mode="heading+body")
    assert abs(a.heading_offset_deg + 120.0) < 1e-3
    np.testing.assert_allclose(np.abs(np.dot(a.q_body, q_b)), 1.0, atol=1e-8)
    assert summarize(q_est, a.apply(ref)).total_rms_deg < 1e-3


def test_body_misalignment_alone_uses_bar_itzhack_mean(motion: np.ndarray) -> None:
    q_b = from_rotation_vector(np.radians([0.0, 4.0, 0.0]))
    q_est = multiply(motion, q_b)
    q = fit_body_misalignment(q_est, motion)
    assert abs(abs(float(np.dot(q, q_b))) - 1.0) < 1e-10
    # and it is the rotation q_ref* ⊗ q_est
    e = multiply(conjugate(motion[0]), q_est[0])
    assert abs(abs(float(np.dot(e, q))) - 1.0) < 1e-10


def test_none_and_bad_mode() -> None:
    q = np.array([[1.0, 0, 0, 0]])
    assert fit_alignment(q, q, mode="none").mode == "none"
    with pytest.raises(ValueError, match="alignment"):
        fit_alignment(q, q, mode="sideways")
