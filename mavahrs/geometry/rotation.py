r"""Rotation matrices and aerospace Euler angles ↔ quaternions.

Matrices are direction-cosine matrices ``C_body_to_ned`` with
``v_ned = C @ v_body``.  Euler angles are aerospace Z-Y-X: yaw ψ about down,
then pitch θ about the new right axis, then roll φ about forward; radians.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.geometry.quaternion import normalize

__all__ = [
    "euler_to_q_scalar",
    "to_matrix",
    "from_matrix",
    "from_matrix_bar_itzhack",
    "to_euler_rad",
    "from_euler_rad",
]

Array = NDArray[np.float64]


def to_matrix(q_body_to_ned: ArrayLike) -> Array:
    """Quaternion to rotation matrix ``C`` (``v_ned = C v_body``), shape (..., 3, 3)."""
    q = normalize(q_body_to_ned)
    w, x, y, z = np.moveaxis(q, -1, 0)
    c = np.empty(q.shape[:-1] + (3, 3))
    c[..., 0, 0] = 1 - 2 * (y * y + z * z)
    c[..., 0, 1] = 2 * (x * y - w * z)
    c[..., 0, 2] = 2 * (x * z + w * y)
    c[..., 1, 0] = 2 * (x * y + w * z)
    c[..., 1, 1] = 1 - 2 * (x * x + z * z)
    c[..., 1, 2] = 2 * (y * z - w * x)
    c[..., 2, 0] = 2 * (x * z - w * y)
    c[..., 2, 1] = 2 * (y * z + w * x)
    c[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return c


def from_matrix(c_body_to_ned: ArrayLike) -> Array:
    """Exact rotation matrix to quaternion (Shepperd's method, w ≥ 0).

    For a matrix that is not exactly orthogonal, use
    :func:`from_matrix_bar_itzhack`, which returns the optimal fit.
    """
    c = np.asarray(c_body_to_ned, dtype=np.float64)
    flat = c.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for i, m in enumerate(flat):
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        cand = np.array([tr, m[0, 0], m[1, 1], m[2, 2]])
        k = int(np.argmax(cand))
        if k == 0:
            s = 2.0 * np.sqrt(1.0 + tr)
            q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        elif k == 1:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        elif k == 2:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
        qa = np.array(q)
        out[i] = qa if qa[0] >= 0 else -qa
    out = normalize(out)
    return out.reshape(c.shape[:-2] + (4,))


def from_matrix_bar_itzhack(c_body_to_ned: ArrayLike) -> Array:
    """Optimal quaternion from a noisy rotation matrix (Bar-Itzhack 2000).

    Madgwick 2010, eq. (56)–(57): the quaternion is the eigenvector of the
    symmetric 4×4 matrix K (built from C) with the largest eigenvalue.  The
    report writes K for the earth-to-sensor matrix; here it is written for
    ``C_body_to_ned`` directly, so no conjugation is needed.
    """
    c = np.asarray(c_body_to_ned, dtype=np.float64)
    flat = c.reshape(-1, 3, 3)
    # K in the (x, y, z, w) ordering of Bar-Itzhack, for C = R(q) with v' = C v.
    m = flat
    k = np.empty((flat.shape[0], 4, 4))
    k[:, 0, 0] = m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2]
    k[:, 1, 1] = m[:, 1, 1] - m[:, 0, 0] - m[:, 2, 2]
    k[:, 2, 2] = m[:, 2, 2] - m[:, 0, 0] - m[:, 1, 1]
    k[:, 3, 3] = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    k[:, 0, 1] = k[:, 1, 0] = m[:, 1, 0] + m[:, 0, 1]
    k[:, 0, 2] = k[:, 2, 0] = m[:, 2, 0] + m[:, 0, 2]
    k[:, 1, 2] = k[:, 2, 1] = m[:, 2, 1] + m[:, 1, 2]
    k[:, 0, 3] = k[:, 3, 0] = m[:, 2, 1] - m[:, 1, 2]
    k[:, 1, 3] = k[:, 3, 1] = m[:, 0, 2] - m[:, 2, 0]
    k[:, 2, 3] = k[:, 3, 2] = m[:, 1, 0] - m[:, 0, 1]
    k /= 3.0
    _, vecs = np.linalg.eigh(k)
    v = vecs[:, :, -1]  # eigenvector of the largest eigenvalue
    q = np.stack([v[:, 3], v[:, 0], v[:, 1], v[:, 2]], axis=-1)
    q = np.where(q[:, :1] < 0, -q, q)
    return normalize(q).reshape(c.shape[:-2] + (4,))


def to_euler_rad(q_body_to_ned: ArrayLike) -> Array:
    """Aerospace Z-Y-X Euler angles ``[roll_rad, pitch_rad, yaw_rad]``, shape (..., 3).

    Madgwick 2010, eq. (7)–(9) written for the body→earth quaternion; yaw in (−π, π].
    """
    q = normalize(q_body_to_ned)
    w, x, y, z = np.moveaxis(q, -1, 0)
    c21 = 2.0 * (w * x + y * z)  # cos θ sin φ
    c22 = 1.0 - 2.0 * (x * x + y * y)  # cos θ cos φ
    roll = np.arctan2(c21, c22)
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    # Gimbal lock (|θ| = 90° to within 1e-7 rad): roll and yaw are one angle and
    # the formulas above divide rounding noise by rounding noise.  Report
    # roll = 0 and the whole rotation about the vertical as yaw (ψ − φ at
    # θ = +90°, ψ + φ at θ = −90°), so that from_euler_rad reproduces q.
    lock = np.hypot(c21, c22) < 1e-7
    if np.any(lock):
        up = 2.0 * (w * y - z * x) > 0.0
        half = np.arctan2(x, w)
        lock_yaw = np.where(up, -2.0 * half, 2.0 * half)
        lock_yaw = np.arctan2(np.sin(lock_yaw), np.cos(lock_yaw))  # wrap to (−π, π]
        roll = np.where(lock, 0.0, roll)
        pitch = np.where(lock, np.where(up, 0.5 * np.pi, -0.5 * np.pi), pitch)
        yaw = np.where(lock, lock_yaw, yaw)
    return np.stack([roll, pitch, yaw], axis=-1)


def from_euler_rad(roll_rad: ArrayLike, pitch_rad: ArrayLike, yaw_rad: ArrayLike) -> Array:
    """Quaternion ``q_body_to_ned`` from aerospace Z-Y-X Euler angles (2022 paper, eq. (24)–(25))."""
    hr = 0.5 * np.asarray(roll_rad, dtype=np.float64)
    hp = 0.5 * np.asarray(pitch_rad, dtype=np.float64)
    hy = 0.5 * np.asarray(yaw_rad, dtype=np.float64)
    cr, sr = np.cos(hr), np.sin(hr)
    cp, sp = np.cos(hp), np.sin(hp)
    cy, sy = np.cos(hy), np.sin(hy)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def euler_to_q_scalar(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[float, float, float, float]:
    """One set of aerospace Z-Y-X Euler angles (rad) → q_body_to_ned, scalar first, in plain floats.

    :func:`from_euler_rad` for a single attitude without numpy's per-call cost (the monitor, the fault injector).
    """
    cr, sr = math.cos(0.5 * roll_rad), math.sin(0.5 * roll_rad)
    cp, sp = math.cos(0.5 * pitch_rad), math.sin(0.5 * pitch_rad)
    cy, sy = math.cos(0.5 * yaw_rad), math.sin(0.5 * yaw_rad)
    return (
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )
