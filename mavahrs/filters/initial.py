r"""Initial attitude from one accelerometer (+ magnetometer) sample.

The accelerometer measures specific force, so at rest it points **up**: the
body-frame direction of NED "down" is ``d = −a/‖a‖``.  With a magnetometer,
east is ``e = d × m`` and north ``n = e × d`` (TRIAD); the rows of
``C_body_to_ned`` are ``n, e, d``.  Without one, heading is set to zero
(roll and pitch from the 2022 paper's eq. (22), written for specific force).
"""

from __future__ import annotations

import math

from mavahrs.filters.jit import kernel

__all__ = ["quat_from_matrix_rows", "initial_attitude"]


@kernel
def quat_from_matrix_rows(c00, c01, c02, c10, c11, c12, c20, c21, c22, out, k):  # type: ignore[no-untyped-def]
    """Write the unit quaternion of rotation matrix C (v_ned = C v_body) to ``out[k:k+4]``.

    Shepperd's method: picks the largest of w², x², y², z² for accuracy.
    """
    tr = c00 + c11 + c22
    if tr >= c00 and tr >= c11 and tr >= c22:
        s = 2.0 * math.sqrt(max(1.0 + tr, 1e-300))
        w, x, y, z = 0.25 * s, (c21 - c12) / s, (c02 - c20) / s, (c10 - c01) / s
    elif c00 >= c11 and c00 >= c22:
        s = 2.0 * math.sqrt(max(1.0 + c00 - c11 - c22, 1e-300))
        w, x, y, z = (c21 - c12) / s, 0.25 * s, (c01 + c10) / s, (c02 + c20) / s
    elif c11 >= c22:
        s = 2.0 * math.sqrt(max(1.0 + c11 - c00 - c22, 1e-300))
        w, x, y, z = (c02 - c20) / s, (c01 + c10) / s, 0.25 * s, (c12 + c21) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 + c22 - c00 - c11, 1e-300))
        w, x, y, z = (c10 - c01) / s, (c02 + c20) / s, (c12 + c21) / s, 0.25 * s
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(w * w + x * x + y * y + z * z)
    out[k] = w / n
    out[k + 1] = x / n
    out[k + 2] = y / n
    out[k + 3] = z / n


@kernel
def initial_attitude(ax, ay, az, mx, my, mz, use_mag, out, k):  # type: ignore[no-untyped-def]
    """Write ``q_body_to_ned`` from a specific-force (and field) sample to ``out[k:k+4]``.

    The vectors must be finite and non-zero (the caller checks).  If the field
    is parallel to gravity the heading falls back to zero.
    """
    a = math.sqrt(ax * ax + ay * ay + az * az)
    dx, dy, dz = -ax / a, -ay / a, -az / a
    if use_mag:
        ex = dy * mz - dz * my
        ey = dz * mx - dx * mz
        ez = dx * my - dy * mx
        en = math.sqrt(ex * ex + ey * ey + ez * ez)
        if en > 1e-9 * math.sqrt(mx * mx + my * my + mz * mz):
            ex, ey, ez = ex / en, ey / en, ez / en
            nx = ey * dz - ez * dy
            ny = ez * dx - ex * dz
            nz = ex * dy - ey * dx
            quat_from_matrix_rows(nx, ny, nz, ex, ey, ez, dx, dy, dz, out, k)
            return
    # Tilt only, yaw = 0: roll = atan2(−f_y, −f_z), pitch = atan2(f_x, √(f_y²+f_z²)).
    roll = math.atan2(-ay, -az)
    pitch = math.atan2(ax, math.sqrt(ay * ay + az * az))
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    out[k] = cr * cp
    out[k + 1] = sr * cp
    out[k + 2] = cr * sp
    out[k + 3] = -sr * sp
