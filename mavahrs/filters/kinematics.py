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


#: below this rotation angle (rad) per step, :func:`quat_exp` uses its series (0.2 rad = 80 rad/s at 400 Hz)
SERIES_MAX_ANGLE = 0.2
# Taylor coefficients in h² of cos h and of sin(h)/(2h) (compile-time constants: multiplications, not divisions)
_COS = (1.0, -1.0 / 2.0, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0, -1.0 / 3628800.0)
_SINC = (0.5, -0.5 / 6.0, 0.5 / 120.0, -0.5 / 5040.0, 0.5 / 362880.0, -0.5 / 39916800.0)


@kernel
def quat_exp(rx, ry, rz):  # type: ignore[no-untyped-def]
    """Unit quaternion of the rotation vector ``r`` (axis × angle, rad), exactly.

    ``[cos(a/2), sin(a/2)/a · r]`` with ``a = ‖r‖``.  For the small angles of
    one filter step (a < ``SERIES_MAX_ANGLE``) both come from their Taylor
    series in ``h² = a²/4`` up to the h¹⁰ term: no square root, sine or cosine
    on every sample, and the first term left out is below 3e-21 there, far
    under the rounding of a double.
    """
    a2 = rx * rx + ry * ry + rz * rz
    if a2 < SERIES_MAX_ANGLE * SERIES_MAX_ANGLE:
        h2 = 0.25 * a2
        c = _COS[0] + h2 * (_COS[1] + h2 * (_COS[2] + h2 * (_COS[3] + h2 * (_COS[4] + h2 * _COS[5]))))
        k = _SINC[0] + h2 * (_SINC[1] + h2 * (_SINC[2] + h2 * (_SINC[3] + h2 * (_SINC[4] + h2 * _SINC[5]))))
    else:
        angle = math.sqrt(a2)
        c = math.cos(0.5 * angle)
        k = math.sin(0.5 * angle) / angle
    return c, k * rx, k * ry, k * rz


@kernel(inline=True)  # every sample of every filter: a call here cost more than its arithmetic
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
