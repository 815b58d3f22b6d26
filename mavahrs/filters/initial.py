r"""Initial attitude from one accelerometer (+ magnetometer) sample.

The accelerometer measures specific force, so at rest it points **up**: the
body-frame direction of NED "down" is ``d = −a/‖a‖``.  With a magnetometer,
east is ``e = d × m`` and north ``n = e × d`` (TRIAD); the rows of
``C_body_to_ned`` are ``n, e, d``.  Without one, heading is set to zero
(roll and pitch from the 2022 paper's eq. (22), written for specific force).

:func:`triad_attitude` is the general TRIAD (Black 1964): two body-frame
vectors and the same two vectors in NED, the first matched exactly; the
filters use it with the specific force against ``v̇ − g`` (GNSS) when the
vehicle is not at rest.

:func:`align_tilt_to_force` is the check of a start: one sample of a raw IMU
on a vibrating multirotor can be 60–120° off (an aliased motor tone of tens of
m/s², clipped), while the specific force averaged over the first seconds in
the estimate's NED frame is gravity up to the vehicle's mean acceleration over
them (VQF's and the autopilots' practice of averaging the first samples; the
NED-frame average of Laidig & Seel 2023); a filter whose estimate disagrees
with that mean by far more than the mean's own error re-aligns its tilt to it.
"""

from __future__ import annotations

import math

from mavahrs.filters.jit import kernel
from mavahrs.filters.kinematics import ned_to_body, rotate_nav

__all__ = ["quat_from_matrix_rows", "initial_attitude", "align_heading_to_field", "triad_attitude", "align_tilt_to_force"]


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


@kernel
def align_heading_to_field(mx, my, mz, out, k):  # type: ignore[no-untyped-def]
    """Rotate ``q_body_to_ned`` at ``out[k:k+4]`` about NED down so that the field ``m`` (body) points north.

    The tilt is kept; the heading becomes the one :func:`initial_attitude` gives with the field (its
    horizontal projection, C m, along north: ψ = atan2(E, N) of C m, q ← exp(−ψ/2 · ê_D) ⊗ q).  Returns
    the rotation applied about down, rad (−ψ), or NaN (``out`` untouched) when the field is (nearly)
    vertical or zero: the heading is then not told by it.
    """
    q0, q1, q2, q3 = out[k], out[k + 1], out[k + 2], out[k + 3]
    hn = (1.0 - 2.0 * (q2 * q2 + q3 * q3)) * mx + 2.0 * (q1 * q2 - q0 * q3) * my + 2.0 * (q1 * q3 + q0 * q2) * mz
    he = 2.0 * (q1 * q2 + q0 * q3) * mx + (1.0 - 2.0 * (q1 * q1 + q3 * q3)) * my + 2.0 * (q2 * q3 - q0 * q1) * mz
    m = math.sqrt(mx * mx + my * my + mz * mz)
    if not (math.sqrt(hn * hn + he * he) > 1e-6 * m):
        return math.nan
    rot = -math.atan2(he, hn)
    c, s = math.cos(0.5 * rot), math.sin(0.5 * rot)
    # exp(rot/2 · ê_D) ⊗ q, ê_D = (0, 0, 1) in NED
    out[k], out[k + 1], out[k + 2], out[k + 3] = c * q0 - s * q3, c * q1 - s * q2, c * q2 + s * q1, c * q3 + s * q0
    return rot


@kernel
def triad_attitude(b1x, b1y, b1z, b2x, b2y, b2z, r1x, r1y, r1z, r2x, r2y, r2z, out, k):  # type: ignore[no-untyped-def]
    """Write ``q_body_to_ned`` with ``C b1 ∥ r1`` exactly and ``C b2`` in the plane of r1 and r2 to ``out[k:k+4]``.

    TRIAD: the orthonormal triads t1 = v1/‖v1‖, t2 = (v1 × v2)/‖v1 × v2‖,
    t3 = t1 × t2 of the body pair (b) and the NED pair (r) give
    ``C = Σᵢ t_i,r t_i,bᵀ``.  Returns False (``out`` untouched) when either
    pair is (nearly) parallel or a vector is zero.
    """
    nb1 = math.sqrt(b1x * b1x + b1y * b1y + b1z * b1z)
    nr1 = math.sqrt(r1x * r1x + r1y * r1y + r1z * r1z)
    if not (nb1 > 0.0 and nr1 > 0.0):
        return False
    t1bx, t1by, t1bz = b1x / nb1, b1y / nb1, b1z / nb1
    t1rx, t1ry, t1rz = r1x / nr1, r1y / nr1, r1z / nr1
    t2bx, t2by, t2bz = t1by * b2z - t1bz * b2y, t1bz * b2x - t1bx * b2z, t1bx * b2y - t1by * b2x
    t2rx, t2ry, t2rz = t1ry * r2z - t1rz * r2y, t1rz * r2x - t1rx * r2z, t1rx * r2y - t1ry * r2x
    nb2 = math.sqrt(t2bx * t2bx + t2by * t2by + t2bz * t2bz)
    nr2 = math.sqrt(t2rx * t2rx + t2ry * t2ry + t2rz * t2rz)
    if not (nb2 > 1e-3 * math.sqrt(b2x * b2x + b2y * b2y + b2z * b2z) and nr2 > 1e-3 * math.sqrt(
        r2x * r2x + r2y * r2y + r2z * r2z
    )):
        return False  # the second vector (nearly) along the first: no heading
    t2bx, t2by, t2bz = t2bx / nb2, t2by / nb2, t2bz / nb2
    t2rx, t2ry, t2rz = t2rx / nr2, t2ry / nr2, t2rz / nr2
    t3bx, t3by, t3bz = t1by * t2bz - t1bz * t2by, t1bz * t2bx - t1bx * t2bz, t1bx * t2by - t1by * t2bx
    t3rx, t3ry, t3rz = t1ry * t2rz - t1rz * t2ry, t1rz * t2rx - t1rx * t2rz, t1rx * t2ry - t1ry * t2rx
    quat_from_matrix_rows(
        t1rx * t1bx + t2rx * t2bx + t3rx * t3bx, t1rx * t1by + t2rx * t2by + t3rx * t3by,
        t1rx * t1bz + t2rx * t2bz + t3rx * t3bz,
        t1ry * t1bx + t2ry * t2bx + t3ry * t3bx, t1ry * t1by + t2ry * t2by + t3ry * t3by,
        t1ry * t1bz + t2ry * t2bz + t3ry * t3bz,
        t1rz * t1bx + t2rz * t2bx + t3rz * t3bx, t1rz * t1by + t2rz * t2by + t3rz * t3by,
        t1rz * t1bz + t2rz * t2bz + t3rz * t3bz,
        out, k,
    )  # fmt: skip
    return True


@kernel
def align_tilt_to_force(q_state, kq, mn, me, md, mx, my, mz, mag_ok):  # type: ignore[no-untyped-def]
    """Re-align ``q_state[kq:kq+4]`` so that the mean specific force ``(mn, me, md)`` (NED of that attitude)
    points up: (0, 0, −‖f̄‖).

    The smallest rotation taking f̄'s direction to (0, 0, −1), which keeps the heading; with a valid
    magnetometer sample instead TRIAD from the mean force in today's body axes (Cᵀf̄) and that field
    (:func:`initial_attitude`), since a tilt far off at the first sample made the first heading wrong too.
    Returns False (nothing changed) when the mean is zero or not finite.
    """
    m = math.sqrt(mn * mn + me * me + md * md)
    if not (m > 0.0 and math.isfinite(m)):
        return False
    if mag_ok:
        bx, by, bz = ned_to_body(q_state[kq], q_state[kq + 1], q_state[kq + 2], q_state[kq + 3], mn, me, md)
        initial_attitude(bx, by, bz, mx, my, mz, True, q_state, kq)
        return True
    # the measured down u = −f̄/‖f̄‖ to (0, 0, 1): about u × ẑ = (u_E, −u_N, 0) by the angle between them
    un, ue, ud = -mn / m, -me / m, -md / m
    s = math.sqrt(un * un + ue * ue)
    ang = math.atan2(s, ud)
    if s > 1e-12:
        rotate_nav(q_state, kq, ue / s * ang, -un / s * ang, 0.0)
    elif ud < 0.0:
        rotate_nav(q_state, kq, math.pi, 0.0, 0.0)  # exactly upside down: about north
    return True
