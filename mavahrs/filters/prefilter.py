r"""Low-pass of the specific force in the navigation frame (motion-acceleration and vibration rejection).

Vibration and taps put large, fast, zero-mean accelerations on the
accelerometer.  Low-passing the body-frame vector would lag behind every
rotation; low-passing it in the earth frame does not, because there gravity
is constant (Laidig & Seel 2023, "VQF", section on the accelerometer
low-pass in the quasi-inertial frame).  Here the frame is the filter's own
estimated NED frame: the vector f_NED = C f is low-passed, and every
correction the filter applies to its estimate (a rotation of the estimated
NED frame) is applied to the filter's state as well
(:func:`nav_lowpass_rotate`), so the state stays expressed in the current
estimate's frame (this is what VQF's separate "inertial frame" achieves).
The filters then use ``Cᵀ f̄_NED`` in place of f.  τ = 0 passes f through.

Start (and restart after a re-initialisation): for the first τ seconds both
filters output the time-weighted mean of the samples so far, then continue
from it in their steady state (VQF does the same).  Starting a low-pass from
its first sample instead would hold that one sample's noise and vibration —
and, since the attitude was initialised from the same sample, agree with its
error — for about τ: after a 1.5 s link outage in a simulated hover, the
re-initialised ``best`` filter (τ = 2 s) stayed 1.1° worse than the
uninterrupted run for 1.5 s and 0.4° worse 4 s later.  The phase is kept in
the block's fourth value: 0 not started, −t while averaging (t seconds
averaged), 1 running.

Two filters, both on NED vectors:

* first order, :func:`vector_lowpass_step` (on any vector):
  ``f̄ ← f̄ + (f − f̄)·(1 − e^(−dt/τ))`` (:func:`lowpass_coefficient`);
  state block ``LP_LEN`` values: f̄_NED (3), the phase (below);
* second-order Butterworth, :func:`ned_butterworth_step`, cut-off
  f_c = √2/(2π τ) (VQF's choice; it attenuates motion accelerations of a few
  tenths of a hertz ten times more than the first-order filter); state block
  ``BW_LEN`` = two ``LP_LEN`` blocks (the two delay vectors of direct form II
  transposed), each rotated by :func:`nav_lowpass_rotate`.

:func:`nav_lowpass_step` is the first-order filter with body-frame input and
output (rotation into NED and back included).
"""

from __future__ import annotations

import math

from mavahrs.filters.jit import kernel
from mavahrs.filters.kinematics import body_to_ned, ned_to_body

__all__ = [
    "LP_LEN",
    "BW_LEN",
    "lowpass_coefficient",
    "nav_lowpass_reset",
    "nav_lowpass_step",
    "nav_lowpass_rotate",
    "vector_lowpass_step",
    "ned_butterworth_step",
]

LP_LEN = 4
BW_LEN = 2 * LP_LEN


# Taylor coefficients of 1 − e^(−x) = x − x²/2 + x³/6 − … (compile-time constants)
_EXPM1 = (1.0, -1.0 / 2.0, 1.0 / 6.0, -1.0 / 24.0, 1.0 / 120.0, -1.0 / 720.0, 1.0 / 5040.0)
_SERIES_MAX_X = 0.02


@kernel
def lowpass_coefficient(dt, tau_s):  # type: ignore[no-untyped-def]
    """Discrete first-order low-pass coefficient ``1 − e^(−dt/τ)``; 1 (pass through) for τ ≤ 0.

    For dt/τ < 0.02 (every sample of a 400 Hz stream with τ ≥ 0.125 s) from its
    Taylor series to the x⁷ term: the first term left out is below 7e-17 of the
    result, so this is as exact as ``exp`` (more so than ``1 − exp``, which
    cancels) and, on every sample of a rest detector, cheaper.
    """
    if tau_s <= 0.0:
        return 1.0
    x = dt / tau_s
    if 0.0 <= x < _SERIES_MAX_X:
        e = _EXPM1
        return x * (e[0] + x * (e[1] + x * (e[2] + x * (e[3] + x * (e[4] + x * (e[5] + x * e[6]))))))
    return 1.0 - math.exp(-x)


@kernel
def nav_lowpass_reset(s, k):  # type: ignore[no-untyped-def]
    """Forget the filter state (one ``LP_LEN`` block; call twice for a Butterworth block)."""
    for i in range(LP_LEN):
        s[k + i] = 0.0


@kernel(inline=True)
def _average_step(s, k, fn, fe, fd, dt, tau_s):  # type: ignore[no-untyped-def]
    """The start phase: fold one sample into the time-weighted mean ``s[k:k+3]``.

    Returns True while the mean still covers less than τ (``s[k+3]`` = −seconds
    averaged); False once τ is covered (the caller then starts its recursion
    from the mean and sets ``s[k+3]`` = 1).
    """
    elapsed = dt - s[k + 3]  # s[k+3] is 0 (nothing yet) or −(seconds averaged so far)
    w = dt / elapsed
    s[k] += (fn - s[k]) * w  # the first sample: w = 1
    s[k + 1] += (fe - s[k + 1]) * w
    s[k + 2] += (fd - s[k + 2]) * w
    if elapsed < tau_s:
        s[k + 3] = -elapsed
        return True
    return False


@kernel
def vector_lowpass_step(s, k, fn, fe, fd, dt, tau_s):  # type: ignore[no-untyped-def]
    """First-order low-pass of one vector (any fixed frame); returns the filtered vector (the input for τ ≤ 0).

    The first τ seconds are averaged (module docstring).
    """
    if tau_s <= 0.0:
        return fn, fe, fd
    if s[k + 3] <= 0.0:
        if not _average_step(s, k, fn, fe, fd, dt, tau_s):
            s[k + 3] = 1.0
    else:
        a = lowpass_coefficient(dt, tau_s)
        s[k] += (fn - s[k]) * a
        s[k + 1] += (fe - s[k + 1]) * a
        s[k + 2] += (fd - s[k + 2]) * a
    return s[k], s[k + 1], s[k + 2]


@kernel
def nav_lowpass_step(s, k, q0, q1, q2, q3, fx, fy, fz, dt, tau_s):  # type: ignore[no-untyped-def]
    """Feed one (valid) body-frame specific-force sample; return the filtered one in body axes."""
    if tau_s <= 0.0:
        return fx, fy, fz
    fn, fe, fd = body_to_ned(q0, q1, q2, q3, fx, fy, fz)
    yn, ye, yd = vector_lowpass_step(s, k, fn, fe, fd, dt, tau_s)
    return ned_to_body(q0, q1, q2, q3, yn, ye, yd)


@kernel(inline=True)
def _butterworth_coefficients(dt, tau_s):  # type: ignore[no-untyped-def]
    """(b0, a1, a2) of the second-order Butterworth of cut-off √2/(2πτ) at step ``dt`` (b1 = 2·b0, b2 = b0)."""
    # bilinear transform of f_c = √2/(2πτ): C = tan(π f_c dt); capped below π/2 so a
    # long step (up to max_gap_s) passes the sample through instead of wrapping tan
    c = math.tan(min(math.sqrt(0.5) * dt / tau_s, 1.5))
    d = c * c + math.sqrt(2.0) * c + 1.0
    return c * c / d, 2.0 * (c * c - 1.0) / d, (1.0 - math.sqrt(2.0) * c + c * c) / d


@kernel(inline=True)  # every sample; inlined into the steps (see filters/jit.py)
def ned_butterworth_step(s, k, fn, fe, fd, dt, tau_s):  # type: ignore[no-untyped-def]
    """Second-order Butterworth low-pass of one NED vector; returns the filtered NED vector.

    Cut-off f_c = √2/(2π τ) (Laidig & Seel 2023, VQF's accelerometer filter),
    bilinear transform, direct form II transposed.  The two state vectors
    ``s[k:k+3]`` and ``s[k+4:k+7]`` are linear combinations of past NED
    vectors, so rotating both with every correction
    (:func:`nav_lowpass_rotate` on ``k`` and ``k + LP_LEN``) keeps them in the
    current estimate's frame; ``s[k+3]`` is the phase (module docstring: the
    first τ seconds are averaged in ``s[k:k+3]``) and ``s[k+7]`` holds the
    nominal step (s) the coefficients are computed from.
    """
    if tau_s <= 0.0:
        return fn, fe, fd
    if s[k + 3] <= 0.0:  # the start: the mean of the samples so far
        s[k + 7] = dt if s[k + 3] == 0.0 else s[k + 7] + 0.05 * (dt - s[k + 7])
        if _average_step(s, k, fn, fe, fd, dt, tau_s):
            return s[k], s[k + 1], s[k + 2]
        # τ averaged: the recursion goes on from the mean, in its steady state
        mn, me, md = s[k], s[k + 1], s[k + 2]
        b0, _a1, a2 = _butterworth_coefficients(s[k + 7], tau_s)
        s[k], s[k + 1], s[k + 2], s[k + 3] = mn * (1.0 - b0), me * (1.0 - b0), md * (1.0 - b0), 1.0
        s[k + 4], s[k + 5], s[k + 6] = mn * (b0 - a2), me * (b0 - a2), md * (b0 - a2)
        return mn, me, md
    # The coefficients follow a smoothed nominal step (kept in s[k+7]), not each
    # sample's dt: the two state vectors of this form are only meaningful for the
    # coefficients that built them, so coefficients that jump with every dt (send-time
    # jitter, a stream that changes rate) make the recursion diverge.  A step more than
    # 3x away from the nominal one (a gap, a new stream rate) restarts the filter in
    # the steady state of this sample.
    nominal = s[k + 7]
    restart = dt > 3.0 * nominal or dt < nominal / 3.0
    if restart:
        nominal = dt
    else:
        nominal += 0.05 * (dt - nominal)
    b0, a1, a2 = _butterworth_coefficients(nominal, tau_s)
    if restart:  # start in the steady state of this sample
        s[k], s[k + 1], s[k + 2], s[k + 3] = fn * (1.0 - b0), fe * (1.0 - b0), fd * (1.0 - b0), 1.0
        s[k + 4], s[k + 5], s[k + 6] = fn * (b0 - a2), fe * (b0 - a2), fd * (b0 - a2)
    s[k + 7] = nominal  # > 0 once started (nav_lowpass_rotate's "started" test)
    yn = b0 * fn + s[k]
    ye = b0 * fe + s[k + 1]
    yd = b0 * fd + s[k + 2]
    s[k] = 2.0 * b0 * fn - a1 * yn + s[k + 4]
    s[k + 1] = 2.0 * b0 * fe - a1 * ye + s[k + 5]
    s[k + 2] = 2.0 * b0 * fd - a1 * yd + s[k + 6]
    s[k + 4] = b0 * fn - a2 * yn
    s[k + 5] = b0 * fe - a2 * ye
    s[k + 6] = b0 * fd - a2 * yd
    return yn, ye, yd


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
