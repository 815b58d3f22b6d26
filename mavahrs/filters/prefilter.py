r"""Low-pass of the specific force in the navigation frame (vibration rejection).

Vibration and taps put large, fast, zero-mean accelerations on the
accelerometer.  Low-passing the body-frame vector would lag behind every
rotation; low-passing it in the earth frame does not, because there gravity
is constant (Laidig & Seel 2023, "VQF", section on the accelerometer
low-pass in the quasi-inertial frame).  Here the frame is the filter's own
estimated NED frame:

    f̄_NED ← f̄_NED + (C f − f̄_NED)·(1 − e^(−dt/τ)),

and every correction the filter applies to its estimate (a rotation of the
estimated NED frame) is applied to f̄_NED as well, so f̄ stays expressed in
the current estimate's frame (this is what VQF's separate "inertial frame"
achieves).  The filters then use ``Cᵀ f̄_NED`` in place of f, in their
corrections and in the gain schedule's norm / horizontal-force gating.
τ = 0 passes f through unchanged.

State block (``LP_LEN`` values at offset k): f̄_NED (3), 1.0 once started.
"""

from __future__ import annotations

import math

from mavahrs.filters.jit import kernel
from mavahrs.filters.kinematics import body_to_ned, ned_to_body

__all__ = ["LP_LEN", "nav_lowpass_reset", "nav_lowpass_step", "nav_lowpass_rotate"]

LP_LEN = 4


@kernel
def nav_lowpass_reset(s, k):  # type: ignore[no-untyped-def]
    for i in range(LP_LEN):
        s[k + i] = 0.0


@kernel
def nav_lowpass_step(s, k, q0, q1, q2, q3, fx, fy, fz, dt, tau_s):  # type: ignore[no-untyped-def]
    """Feed one (valid) specific-force sample; return the filtered one in body axes."""
    if tau_s <= 0.0:
        return fx, fy, fz
    fn, fe, fd = body_to_ned(q0, q1, q2, q3, fx, fy, fz)
    if s[k + 3] == 0.0:
        s[k], s[k + 1], s[k + 2], s[k + 3] = fn, fe, fd, 1.0
    else:
        a = 1.0 - math.exp(-dt / tau_s)
        s[k] += (fn - s[k]) * a
        s[k + 1] += (fe - s[k + 1]) * a
        s[k + 2] += (fd - s[k + 2]) * a
    return ned_to_body(q0, q1, q2, q3, s[k], s[k + 1], s[k + 2])


@kernel
def nav_lowpass_rotate(s, k, rn, re, rd):  # type: ignore[no-untyped-def]
    """Rotate the stored f̄_NED by the rotation vector r (rad, NED): the estimate's correction."""
    angle = math.sqrt(rn * rn + re * re + rd * rd)
    if angle < 1e-15 or s[k + 3] == 0.0:
        return
    ux, uy, uz = rn / angle, re / angle, rd / angle
    vx, vy, vz = s[k], s[k + 1], s[k + 2]
    c = math.cos(angle)
    sn = math.sin(angle)
    dot = (ux * vx + uy * vy + uz * vz) * (1.0 - c)
    # Rodrigues: v cos θ + (u × v) sin θ + u (u·v)(1 − cos θ)
    s[k] = vx * c + (uy * vz - uz * vy) * sn + ux * dot
    s[k + 1] = vy * c + (uz * vx - ux * vz) * sn + uy * dot
    s[k + 2] = vz * c + (ux * vy - uy * vx) * sn + uz * dot
