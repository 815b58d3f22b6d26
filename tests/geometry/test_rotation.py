"""Rotation matrices, Bar-Itzhack extraction and aerospace Euler angles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.geometry import quaternion as qm
from mavahrs.geometry.rotation import (
    from_euler_rad,
    from_matrix,
    from_matrix_bar_itzhack,
    to_euler_rad,
    to_matrix,
)

N = 500


def test_matrix_round_trip_and_orthogonality(rng: np.random.Generator) -> None:
    q = qm.random_unit(N, rng)
    c = to_matrix(q)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", c, c), np.tile(np.eye(3), (N, 1, 1)), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(c), 1.0, atol=1e-14)
    back = from_matrix(c)
    assert np.all(back[:, 0] >= 0)
    np.testing.assert_allclose(back, qm.align_hemisphere(q, back), atol=1e-14)
    np.testing.assert_allclose(from_matrix_bar_itzhack(c), back, atol=1e-12)
    # single (3, 3) matrix in, (4,) out; 180° rotations (trace = −1) too
    for axis in np.eye(3):
        q180 = qm.from_axis_angle(axis, math.pi)
        assert qm.angle_between(from_matrix(to_matrix(q180)), q180) < 1e-7
        assert qm.angle_between(from_matrix_bar_itzhack(to_matrix(q180)), q180) < 1e-7


def test_bar_itzhack_beats_the_naive_extraction_on_noisy_matrices(rng: np.random.Generator) -> None:
    """Madgwick 2010 eq. (56)–(57): the optimal fit is closer to the truth than Shepperd on a noisy C."""
    q = qm.random_unit(N, rng)
    noisy = to_matrix(q) + rng.normal(scale=0.05, size=(N, 3, 3))
    naive = np.degrees(qm.angle_between(from_matrix(noisy), q))
    optimal = np.degrees(qm.angle_between(from_matrix_bar_itzhack(noisy), q))
    assert optimal.mean() < 0.8 * naive.mean()
    assert np.mean(optimal < naive) > 0.6
    # and it is the closest rotation in the Frobenius sense (orthogonal Procrustes via SVD)
    u, _, vt = np.linalg.svd(noisy)
    d = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= d[:, None]
    procrustes = from_matrix(u @ vt)
    np.testing.assert_allclose(qm.angle_between(from_matrix_bar_itzhack(noisy), procrustes), 0.0, atol=1e-6)


def test_euler_conventions() -> None:
    """Aerospace Z-Y-X: yaw about down, pitch about the new right axis, roll about forward."""
    np.testing.assert_allclose(to_matrix(from_euler_rad(0, 0, math.pi / 2)) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(to_matrix(from_euler_rad(0, 0.3, 0)) @ [1, 0, 0], [math.cos(0.3), 0, -math.sin(0.3)], atol=1e-15)
    np.testing.assert_allclose(to_matrix(from_euler_rad(0.3, 0, 0)) @ [0, 1, 0], [0, math.cos(0.3), math.sin(0.3)], atol=1e-15)
    e = np.array([0.1, -0.2, 2.5])
    composed = qm.multiply(
        qm.multiply(qm.from_axis_angle([0, 0, 1], e[2]), qm.from_axis_angle([0, 1, 0], e[1])),
        qm.from_axis_angle([1, 0, 0], e[0]),
    )
    np.testing.assert_allclose(from_euler_rad(*e), composed, atol=1e-15)


def test_euler_round_trip(rng: np.random.Generator) -> None:
    e = np.stack(
        [rng.uniform(-math.pi, math.pi, N), rng.uniform(-math.pi / 2, math.pi / 2, N), rng.uniform(-math.pi, math.pi, N)],
        axis=-1,
    )
    back = to_euler_rad(from_euler_rad(e[:, 0], e[:, 1], e[:, 2]))
    np.testing.assert_allclose(back, e, atol=1e-9)
    q = qm.random_unit(N, rng)
    e2 = to_euler_rad(q)
    assert np.all(np.abs(e2[:, 1]) <= math.pi / 2)
    np.testing.assert_allclose(qm.angle_between(from_euler_rad(*e2.T), q), 0.0, atol=1e-7)


@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9, -math.pi / 2 + 3e-8, math.pi / 2 - 1e-6])
def test_euler_round_trip_near_gimbal_lock(pitch: float, rng: np.random.Generator) -> None:
    """At ±90° pitch roll and yaw are one angle; the returned triple must still be the same rotation."""
    roll, yaw = rng.uniform(-math.pi, math.pi, size=(2, 100))
    q = from_euler_rad(roll, np.full(100, pitch), yaw)
    e = to_euler_rad(q)
    np.testing.assert_allclose(e[:, 1], pitch, atol=1e-6)
    assert np.all(np.abs(e) <= math.pi + 1e-12)
    err_deg = np.degrees(qm.angle_between(from_euler_rad(e[:, 0], e[:, 1], e[:, 2]), q))
    assert err_deg.max() < 1e-5
