r"""Quaternion algebra: pure functions on ``numpy`` arrays.

Convention (the one used everywhere in mavahrs, and by MAVLink's
ATTITUDE_QUATERNION):

* scalar first, ``q = [w, x, y, z]``;
* Hamilton product (``i*j = k``);
* an attitude quaternion ``q_body_to_ned`` rotates body vectors into the earth
  frame: ``v_ned = q ⊗ [0, v_body] ⊗ q*``.  ``[1, 0, 0, 0]`` is level, facing north.

Madgwick's report writes the conjugate, :math:`{}^S_E\hat q` (earth relative to
sensor); filters convert once at their boundary (Madgwick 2010, eq. (1)–(9)).

Every function accepts a single quaternion of shape ``(4,)`` or a stack of
shape ``(N, 4)`` and returns the same leading shape.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "IDENTITY",
    "multiply",
    "conjugate",
    "normalize",
    "rotate",
    "from_rotation_vector",
    "to_rotation_vector",
    "integrate",
    "trajectory",
    "from_axis_angle",
    "angle_between",
    "align_hemisphere",
    "slerp",
    "random_unit",
]

Array = NDArray[np.float64]

IDENTITY: Array = np.array([1.0, 0.0, 0.0, 0.0])
IDENTITY.setflags(write=False)


def _as_float(q: ArrayLike) -> Array:
    return np.asarray(q, dtype=np.float64)


def multiply(p: ArrayLike, q: ArrayLike) -> Array:
    """Hamilton product ``p ⊗ q`` (Madgwick 2010, eq. (7))."""
    p = _as_float(p)
    q = _as_float(q)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def conjugate(q: ArrayLike) -> Array:
    """``q*``: the inverse rotation of a unit quaternion (Madgwick 2010, eq. (5))."""
    out = np.array(q, dtype=np.float64, copy=True)
    out[..., 1:] *= -1.0
    return out


def normalize(q: ArrayLike) -> Array:
    """Scale to unit norm.  Raises ``ValueError`` on a zero or non-finite quaternion."""
    q = _as_float(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n == 0.0):
        raise ValueError("cannot normalise a zero or non-finite quaternion")
    return q / n


def rotate(q_a_to_b: ArrayLike, v_a: ArrayLike) -> Array:
    """Rotate vectors from frame a to frame b: ``v_b = q ⊗ [0, v_a] ⊗ q*``.

    Uses the equivalent rotation-matrix form (no intermediate quaternions).
    Broadcasts ``(4,)``/``(N,4)`` against ``(3,)``/``(N,3)``.
    """
    q = _as_float(q_a_to_b)
    v = _as_float(v_a)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def from_axis_angle(axis: ArrayLike, angle_rad: ArrayLike) -> Array:
    """Rotation of ``angle_rad`` about the unit ``axis`` (Madgwick 2010, eq. (1))."""
    axis = _as_float(axis)
    angle = _as_float(angle_rad)[..., None]
    n = np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * angle
    return np.concatenate([np.cos(half), np.sin(half) * axis / n], axis=-1)


def from_rotation_vector(rotvec_rad: ArrayLike) -> Array:
    """Exact exponential map: rotation vector (axis × angle, rad) to quaternion."""
    r = _as_float(rotvec_rad)
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a with its Taylor series near zero (no division by zero).
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half), k * r], axis=-1)


def to_rotation_vector(q: ArrayLike) -> Array:
    """Logarithmic map: unit quaternion to rotation vector (rad), angle in [0, π]."""
    q = _as_float(q)
    q = np.where(q[..., :1] < 0.0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    small = s < 1e-12
    k = np.where(small, 2.0, angle / np.where(small, 1.0, s))
    return k * q[..., 1:]


def integrate(q_body_to_ned: ArrayLike, gyro_rad_s: ArrayLike, dt_s: ArrayLike) -> Array:
    """Propagate an attitude by a body rate held constant over ``dt_s``.

    Exact solution of q̇ = ½ q ⊗ [0, ω] (Madgwick 2010, eq. (11)) for constant
    ω: ``q ⊗ exp(ω·dt/2)``, rather than the first-order step of eq. (12)–(13).
    """
    dt = _as_float(dt_s)
    rotvec = _as_float(gyro_rad_s) * dt[..., None] if dt.ndim else _as_float(gyro_rad_s) * dt
    return normalize(multiply(q_body_to_ned, from_rotation_vector(rotvec)))


def trajectory(q0_body_to_ned: ArrayLike, gyro_rad_s: ArrayLike, dt_s: float) -> Array:
    """(N, 4) attitudes from ``q0`` by N − 1 steps of :func:`integrate` with the body rates ``gyro_rad_s[:-1]``
    (row i held from sample i to i + 1; the last rate is not used): a truth built from known rates."""
    w = _as_float(gyro_rad_s)
    steps = from_rotation_vector(w * float(dt_s))
    q = np.empty((w.shape[0], 4))
    q[0] = normalize(q0_body_to_ned)
    for i in range(1, w.shape[0]):
        q[i] = normalize(multiply(q[i - 1], steps[i - 1]))
    return q


def angle_between(p: ArrayLike, q: ArrayLike) -> Array:
    """Smallest rotation angle (rad) between two attitudes; q and −q are equal."""
    d = np.abs(np.sum(normalize(p) * normalize(q), axis=-1))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))


def align_hemisphere(q: ArrayLike, reference: ArrayLike) -> Array:
    """Return ``q`` or ``−q``, whichever is closer to ``reference`` (same rotation).

    Needed before any linear blend of quaternions (the 2022 paper's eq. (29)).
    """
    q = _as_float(q)
    dot = np.sum(q * _as_float(reference), axis=-1, keepdims=True)
    return np.where(dot < 0.0, -q, q)


def slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> Array:
    """Spherical linear interpolation from ``q0`` (t=0) to ``q1`` (t=1), shortest path."""
    q0 = normalize(q0)
    q1 = align_hemisphere(normalize(q1), q0)
    t = _as_float(t)[..., None]
    dot = np.clip(np.sum(q0 * q1, axis=-1, keepdims=True), -1.0, 1.0)
    theta = np.arccos(dot)
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-9
    safe = np.where(near, 1.0, sin_theta)
    a = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    b = np.where(near, t, np.sin(t * theta) / safe)
    return normalize(a * q0 + b * q1)


def random_unit(n: int, rng: np.random.Generator) -> Array:
    """``n`` attitudes drawn uniformly over SO(3) (normalised Gaussian 4-vectors)."""
    q = rng.normal(size=(n, 4))
    return normalize(q)
