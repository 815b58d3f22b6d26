r"""Scalar quaternion kernels shared by the filters (no allocation, numba-compatible).

Convention as everywhere in mavahrs: ``q = [w, x, y, z]`` is ``q_body_to_ned``,
Hamilton product, ``v_ned = q ⊗ v_body ⊗ q*`` (see
:mod:`mavahrs.geometry.quaternion`, whose array functions these mirror).

* :func:`integrate_body_rate` — the kinematic equation q̇ = ½ q ⊗ [0, ω]
  (Madgwick 2010, eq. (11)) solved exactly for a body rate held constant over
  dt: ``q ← q ⊗ exp(ω·dt/2)``;
* :func:`rotate_nav` — a rotation applied in the *navigation* frame,
  ``q ← exp(r/2) ⊗ q`` (the virtual gyro-platform's Ċ = CΩ − Ω′C, 003);
* :func:`body_to_ned` / :func:`ned_to_body` — rotate one vector.

The quaternion lives in a flat state array at offset ``k``.
"""

from __future__ import annotations

import math

from mavahrs.filters.jit import kernel

__all__ = [
    "quat_multiply",
    "quat_exp",
    "integrate_body_rate",
    "rotate_nav",
    "body_to_ned",
    "ned_to_body",
    "quat_angle",
]


@kernel
def quat_multiply(a0, a1, a2, a3, b0, b1, b2, b3):  # type: ignore[no-untyped-def]
    """Hamilton product ``a ⊗ b`` (Madgwick 2010, eq. (7)) as a 4-tuple."""
    return (
        a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
        a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
        a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
        a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
    )


@kernel
def quat_exp(rx, ry, rz):  # type: ignore[no-untyped-def]
    """Unit quaternion of the rotation vector ``r`` (axis × angle, rad), exactly."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    if angle < 1e-8:
        k = 0.5 - angle * angle / 48.0  # sin(a/2)/a, Taylor series
    else:
        k = math.sin(0.5 * angle) / angle
    return math.cos(0.5 * angle), k * rx, k * ry, k * rz


@kernel
def integrate_body_rate(state, k, wx, wy, wz, dt):  # type: ignore[no-untyped-def]
    """``q ← q ⊗ exp(ω·dt/2)`` in place: exact for ω constant over dt (Madgwick 2010, eq. (11))."""
    d0, d1, d2, d3 = quat_exp(wx * dt, wy * dt, wz * dt)
    q0, q1, q2, q3 = quat_multiply(state[k], state[k + 1], state[k + 2], state[k + 3], d0, d1, d2, d3)
    state[k], state[k + 1], state[k + 2], state[k + 3] = q0, q1, q2, q3


@kernel
def rotate_nav(state, k, rn, re, rd):  # type: ignore[no-untyped-def]
    """``q ← exp(r/2) ⊗ q`` in place: rotate the estimate by ``r`` (rad) about NED axes."""
    d0, d1, d2, d3 = quat_exp(rn, re, rd)
    q0, q1, q2, q3 = quat_multiply(d0, d1, d2, d3, state[k], state[k + 1], state[k + 2], state[k + 3])
    state[k], state[k + 1], state[k + 2], state[k + 3] = q0, q1, q2, q3


@kernel
def body_to_ned(q0, q1, q2, q3, x, y, z):  # type: ignore[no-untyped-def]
    """``C v`` with C = C_body_to_ned(q): a body vector expressed in NED."""
    return (
        (1.0 - 2.0 * (q2 * q2 + q3 * q3)) * x + 2.0 * (q1 * q2 - q0 * q3) * y + 2.0 * (q1 * q3 + q0 * q2) * z,
        2.0 * (q1 * q2 + q0 * q3) * x + (1.0 - 2.0 * (q1 * q1 + q3 * q3)) * y + 2.0 * (q2 * q3 - q0 * q1) * z,
        2.0 * (q1 * q3 - q0 * q2) * x + 2.0 * (q2 * q3 + q0 * q1) * y + (1.0 - 2.0 * (q1 * q1 + q2 * q2)) * z,
    )


@kernel
def ned_to_body(q0, q1, q2, q3, n, e, d):  # type: ignore[no-untyped-def]
    """``Cᵀ v``: an NED vector expressed in body axes."""
    return (
        (1.0 - 2.0 * (q2 * q2 + q3 * q3)) * n + 2.0 * (q1 * q2 + q0 * q3) * e + 2.0 * (q1 * q3 - q0 * q2) * d,
        2.0 * (q1 * q2 - q0 * q3) * n + (1.0 - 2.0 * (q1 * q1 + q3 * q3)) * e + 2.0 * (q2 * q3 + q0 * q1) * d,
        2.0 * (q1 * q3 + q0 * q2) * n + 2.0 * (q2 * q3 - q0 * q1) * e + (1.0 - 2.0 * (q1 * q1 + q2 * q2)) * d,
    )


@kernel
def quat_angle(q0, q1, q2, q3):  # type: ignore[no-untyped-def]
    """Rotation angle (rad, in [0, π]) of a unit quaternion; q and −q alike."""
    s = math.sqrt(q1 * q1 + q2 * q2 + q3 * q3)
    return 2.0 * math.atan2(s, abs(q0))
