"""Quaternion algebra: Hamilton product, rotation, exact integration, hemispheres, slerp."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.geometry import quaternion as qm
from mavahrs.geometry.rotation import to_matrix

N = 200


@pytest.fixture
def qs(rng: np.random.Generator) -> np.ndarray:
    return qm.random_unit(N, rng)


def test_hamilton_units() -> None:
    one, i, j, k = np.eye(4)
    np.testing.assert_array_equal(qm.multiply(i, j), k)
    np.testing.assert_array_equal(qm.multiply(j, k), i)
    np.testing.assert_array_equal(qm.multiply(k, i), j)
    np.testing.assert_array_equal(qm.multiply(j, i), -k)  # not commutative
    for u in (i, j, k):
        np.testing.assert_array_equal(qm.multiply(u, u), -one)
    np.testing.assert_array_equal(qm.multiply(qm.multiply(i, j), k), -one)  # i j k = −1


def test_product_properties(qs: np.ndarray, rng: np.random.Generator) -> None:
    p, q, r = qs, np.roll(qs, 1, axis=0), np.roll(qs, 2, axis=0)
    np.testing.assert_allclose(qm.multiply(qm.multiply(p, q), r), qm.multiply(p, qm.multiply(q, r)), atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(qm.multiply(p, q), axis=-1), 1.0, atol=1e-14)  # norm multiplies
    np.testing.assert_allclose(qm.conjugate(qm.multiply(p, q)), qm.multiply(qm.conjugate(q), qm.conjugate(p)), atol=1e-15)
    np.testing.assert_allclose(qm.multiply(p, qm.conjugate(p)), np.tile(qm.IDENTITY, (N, 1)), atol=1e-15)
    np.testing.assert_allclose(qm.multiply(qm.IDENTITY, p), p, atol=0)
    # (4,) broadcasts against (N, 4)
    np.testing.assert_allclose(qm.multiply(p[0], q), np.array([qm.multiply(p[0], x) for x in q]), atol=0)


def test_rotate_equals_matrix_product(qs: np.ndarray, rng: np.random.Generator) -> None:
    v = rng.normal(size=(N, 3))
    np.testing.assert_allclose(qm.rotate(qs, v), np.einsum("nij,nj->ni", to_matrix(qs), v), atol=1e-13)
    # and equals the sandwich product q ⊗ [0, v] ⊗ q*
    pure = np.concatenate([np.zeros((N, 1)), v], axis=-1)
    sandwich = qm.multiply(qm.multiply(qs, pure), qm.conjugate(qs))
    np.testing.assert_allclose(sandwich[:, 0], 0.0, atol=1e-13)
    np.testing.assert_allclose(qm.rotate(qs, v), sandwich[:, 1:], atol=1e-13)
    # composition: rotate by p then q == rotate by q ⊗ p
    p = np.roll(qs, 1, axis=0)
    np.testing.assert_allclose(qm.rotate(qs, qm.rotate(p, v)), qm.rotate(qm.multiply(qs, p), v), atol=1e-13)


def test_rotate_convention_body_to_ned() -> None:
    """90° yaw (about down): body forward points east."""
    q_yaw90 = qm.from_axis_angle([0.0, 0.0, 1.0], math.pi / 2)
    np.testing.assert_allclose(qm.rotate(q_yaw90, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)


def test_rotation_vector_round_trip(rng: np.random.Generator) -> None:
    r = rng.normal(size=(N, 3))
    r *= (rng.uniform(0, math.pi * 0.999, N) / np.linalg.norm(r, axis=-1))[:, None]
    np.testing.assert_allclose(qm.to_rotation_vector(qm.from_rotation_vector(r)), r, atol=1e-12)
    tiny = np.array([1e-12, -2e-12, 3e-13])
    np.testing.assert_allclose(qm.to_rotation_vector(qm.from_rotation_vector(tiny)), tiny, rtol=1e-9)
    np.testing.assert_allclose(qm.from_rotation_vector(np.zeros(3)), qm.IDENTITY, atol=0)


def test_integrate_is_exact_for_a_constant_rate(qs: np.ndarray, rng: np.random.Generator) -> None:
    """One step of dt equals many small steps (and the closed form q ⊗ exp(ω dt / 2))."""
    omega = rng.normal(scale=3.0, size=(N, 3))
    dt = 0.37
    one = qm.integrate(qs, omega, dt)
    many = qs
    for _ in range(1000):
        many = qm.integrate(many, omega, dt / 1000)
    np.testing.assert_allclose(qm.align_hemisphere(many, one), one, atol=1e-12)
    angle = np.linalg.norm(omega, axis=-1) * dt
    axis = omega / np.linalg.norm(omega, axis=-1, keepdims=True)
    closed = qm.multiply(qs, qm.from_axis_angle(axis, angle))
    np.testing.assert_allclose(one, closed, atol=1e-13)
    # the first-order step of Madgwick eq. (12)–(13) is not exact: the exact one differs from it
    first_order = qm.normalize(qs + 0.5 * qm.multiply(qs, np.concatenate([np.zeros((N, 1)), omega], -1)) * dt)
    assert np.max(qm.angle_between(first_order, one)) > 1e-3
    # per-sample dt array
    dts = rng.uniform(0.001, 0.1, N)
    np.testing.assert_allclose(
        qm.integrate(qs, omega, dts), np.array([qm.integrate(q, w, d) for q, w, d in zip(qs, omega, dts, strict=True)]), atol=1e-15
    )


def test_normalize_rejects_zero_and_nan() -> None:
    np.testing.assert_allclose(qm.normalize([2.0, 0, 0, 0]), qm.IDENTITY)
    with pytest.raises(ValueError):
        qm.normalize([0.0, 0, 0, 0])
    with pytest.raises(ValueError):
        qm.normalize([np.nan, 0, 0, 1])


def test_align_hemisphere_and_angle_between(qs: np.ndarray) -> None:
    ref = np.roll(qs, 1, axis=0)
    a = qm.align_hemisphere(-qs, ref)
    assert np.all(np.sum(a * ref, axis=-1) >= 0)
    np.testing.assert_allclose(np.abs(a), np.abs(qs), atol=0)  # same rotation, sign chosen
    np.testing.assert_allclose(qm.angle_between(qs, -qs), 0.0, atol=1e-7)
    q90 = qm.from_axis_angle([0, 1, 0], math.pi / 2)
    assert qm.angle_between(qm.IDENTITY, q90) == pytest.approx(math.pi / 2)


def test_slerp_endpoints_midpoint_and_shortest_path(qs: np.ndarray) -> None:
    p, q = qs, np.roll(qs, 1, axis=0)
    np.testing.assert_allclose(qm.slerp(p, q, np.zeros(N)), p, atol=1e-12)
    np.testing.assert_allclose(qm.slerp(p, q, np.ones(N)), qm.align_hemisphere(q, p), atol=1e-12)
    mid = qm.slerp(p, q, np.full(N, 0.5))
    np.testing.assert_allclose(qm.angle_between(p, mid), qm.angle_between(mid, q), atol=1e-9)
    np.testing.assert_allclose(2 * qm.angle_between(p, mid), qm.angle_between(p, q), atol=1e-9)
    # constant angular speed along the path
    ts = np.linspace(0, 1, 11)
    path = qm.slerp(np.tile(p[0], (11, 1)), np.tile(q[0], (11, 1)), ts)
    np.testing.assert_allclose(qm.angle_between(path[0], path), ts * qm.angle_between(p[0], q[0]), atol=1e-9)
    # nearly equal endpoints do not divide by zero
    near = qm.normalize(p[0] + 1e-12)
    assert np.all(np.isfinite(qm.slerp(p[0], near, 0.5)))


def test_random_unit_is_unit_and_seeded() -> None:
    a = qm.random_unit(5, np.random.default_rng(1))
    b = qm.random_unit(5, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(np.linalg.norm(a, axis=-1), 1.0)


def test_trajectory_integrates_known_body_rates() -> None:
    """A constant yaw rate for 2 s from level: yaw = rate × elapsed on every row; then a roll rate after a
    yaw of 90° turns about the body's x axis (body rates: q ⊗ Δq), not the earth's."""
    dt, rate = 0.01, 0.5
    w = np.zeros((201, 3))
    w[:, 2] = rate
    q = qm.trajectory(qm.IDENTITY, w, dt)
    assert q.shape == (201, 4)
    yaw = 2.0 * np.arctan2(q[:, 3], q[:, 0])
    np.testing.assert_allclose(yaw, rate * dt * np.arange(201), atol=1e-9)
    w2 = np.zeros((101, 3))
    w2[:, 0] = np.pi / 2  # 1 s of roll at 90°/s after a yaw of 90°
    q90 = qm.from_axis_angle([0.0, 0.0, 1.0], np.pi / 2)
    end = qm.trajectory(q90, w2, 0.01)[-1]
    np.testing.assert_allclose(qm.rotate(end, [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0], atol=1e-9)
