"""The scalar kernels' series paths equal the closed forms they replace, compiled and interpreted."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.filters.jit import pure_python
from mavahrs.filters.kinematics import SERIES_MAX_ANGLE, integrate_body_rate, quat_exp
from mavahrs.filters.prefilter import lowpass_coefficient

KERNELS = [pytest.param(lambda k: k, id="compiled"), pytest.param(pure_python, id="interpreted")]


def _closed_form(rx: float, ry: float, rz: float) -> tuple[float, float, float, float]:
    a = math.sqrt(rx * rx + ry * ry + rz * rz)
    if a == 0.0:
        return 1.0, 0.0, 0.0, 0.0
    k = math.sin(0.5 * a) / a
    return math.cos(0.5 * a), k * rx, k * ry, k * rz


@pytest.mark.parametrize("wrap", KERNELS)
def test_quat_exp_equals_sin_cos_on_both_sides_of_the_series_limit(wrap: object) -> None:
    f = wrap(quat_exp)  # type: ignore[operator]
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([[0.0, 1e-300, 1e-12, 1e-6], rng.uniform(0.0, 2.0 * SERIES_MAX_ANGLE, 196)])
    angles[10] = SERIES_MAX_ANGLE * (1 - 1e-12)  # just inside the series' range
    angles[11] = SERIES_MAX_ANGLE  # the closed form from here on
    for axis, angle in zip(axes, angles, strict=True):
        r = axis * angle
        got = np.array(f(*r))
        want = np.array(_closed_form(*r))
        np.testing.assert_allclose(got, want, rtol=0, atol=4e-16)
        assert abs(np.linalg.norm(got) - 1.0) < 4e-16


@pytest.mark.parametrize("wrap", KERNELS)
def test_integration_over_a_long_spin_equals_the_closed_form_steps(wrap: object) -> None:
    """10 000 steps of 1 rad/s about a fixed axis at 400 Hz: the series steps give what the sin/cos steps
    give, and both the analytic exp(ω t / 2) up to the products' rounding (the norm drifts by 5e-13)."""
    from mavahrs.filters.kinematics import quat_multiply

    f = wrap(integrate_body_rate)  # type: ignore[operator]
    axis = np.array([0.6, -0.48, 0.64])
    state = np.array([1.0, 0.0, 0.0, 0.0])
    ref = state.copy()
    for _ in range(10_000):
        f(state, 0, axis[0], axis[1], axis[2], 0.0025)
        ref[:] = quat_multiply.py_func(*ref, *_closed_form(*(axis * 0.0025)))
    np.testing.assert_allclose(state, ref, rtol=0, atol=1e-15)
    want = _closed_form(*(axis * 25.0))
    np.testing.assert_allclose(state, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("wrap", KERNELS)
def test_lowpass_coefficient_equals_expm1(wrap: object) -> None:
    f = wrap(lowpass_coefficient)  # type: ignore[operator]
    for dt in (1e-9, 1e-4, 0.0025, 0.00999, 0.01, 0.04, 1.0, 30.0):
        for tau in (0.5, 2.0):
            want = -math.expm1(-dt / tau)
            # the series (dt/τ < 0.02) is exact to rounding; beyond it 1 − exp cancels (the old formula)
            rel = 3e-16 if dt / tau < 0.02 else 1e-14
            assert f(dt, tau) == pytest.approx(want, rel=rel, abs=0.0), (dt, tau)
    assert f(0.0025, 0.0) == 1.0  # τ = 0 passes the input through


@pytest.mark.parametrize("wrap", KERNELS)
def test_triad_recovers_the_rotation_from_two_vector_pairs(wrap: object) -> None:
    """``triad_attitude``: b = Cᵀ r for random rotations and vectors gives back C; the first pair exactly.

    With noise on the second body vector only, the first vector still maps
    exactly (TRIAD trusts it), and the rotation moves by about the noise angle.
    Parallel or zero vectors are refused (False, output untouched).
    """
    from mavahrs.filters.initial import triad_attitude
    from mavahrs.geometry.quaternion import angle_between, conjugate, random_unit, rotate

    triad = wrap(triad_attitude)  # type: ignore[operator]
    rng = np.random.default_rng(5)
    qs = random_unit(100, rng)
    out = np.zeros(4)
    for q in qs:
        r1 = rng.normal(size=3) * 5.0
        r2 = rng.normal(size=3) * 40.0
        b1, b2 = rotate(conjugate(q), r1), rotate(conjugate(q), r2)
        assert triad(*b1, *b2, *r1, *r2, out, 0)
        assert min(np.abs(out - q).max(), np.abs(out + q).max()) < 1e-12
        noisy = b2 + rng.normal(size=3) * 0.02 * np.linalg.norm(b2)
        assert triad(*b1, *noisy, *r1, *r2, out, 0)
        mapped = rotate(out, b1)
        np.testing.assert_allclose(mapped / np.linalg.norm(mapped), r1 / np.linalg.norm(r1), atol=1e-12)
        assert 0.0 < angle_between(out, q) < math.radians(10.0)
    out[:] = 7.0
    assert not triad(1.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, -9.8, 20.0, 0.0, 40.0, out, 0)  # body pair parallel
    assert not triad(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -9.8, 0.0, 0.0, 40.0, out, 0)  # NED pair parallel
    assert not triad(0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -9.8, 20.0, 0.0, 40.0, out, 0)  # a zero vector
    assert np.all(out == 7.0)
