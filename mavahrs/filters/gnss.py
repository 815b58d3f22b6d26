r"""Vehicle acceleration from GNSS velocity, for acceleration-compensated levelling.

The accelerometer measures specific force f = a − g; with the true acceleration
a = v̇ known from GNSS velocity v (NED), ``f − v̇ = −g`` is an undisturbed
vertical reference whatever the vehicle does (003, "Влияние ускорений": the
gyro-platform's levelling uses f̂_NED − v̇).  This kernel differentiates the
velocity column of the input rows (``IN_VEL``, NaN = no fix) and low-passes
the result:

* on a valid fix: raw = (v − v_prev) / (time since the previous fix), and
  v̇ ← v̇ + (raw − v̇)·min(1, Δt/τ);
* fixes may arrive on every row (held or interpolated values) or only on some
  rows with NaN between them; a fix older than ``max_age_s`` breaks the chain
  and v̇ is invalid until two fixes are seen again.

With held values (one new velocity every GNSS period T and repeats between)
the low-pass of the resulting pulse train averages to Δv/T when τ ≳ T.

State block (``VD_LEN`` values at offset k): v_prev (3), v̇ (3), time since the
last fix (s; −1 = none yet), number of differences averaged so far.
"""

from __future__ import annotations

import math

from mavahrs.filters.jit import kernel

__all__ = ["VD_LEN", "velocity_derivative_reset", "velocity_derivative_step"]

VD_LEN = 8
_VPREV = 0
_VDOT = 3
_AGE = 6
_COUNT = 7


@kernel
def velocity_derivative_reset(s, k):  # type: ignore[no-untyped-def]
    """Forget all velocity history (also on re-initialisation)."""
    for i in range(VD_LEN):
        s[k + i] = 0.0
    s[k + _AGE] = -1.0


@kernel
def velocity_derivative_step(s, k, vn, ve, vd, dt, tau_s, max_age_s):  # type: ignore[no-untyped-def]
    """Advance by one row; return True when ``s[k+3:k+6]`` holds a usable v̇ (m/s², NED)."""
    fix = math.isfinite(vn) and math.isfinite(ve) and math.isfinite(vd)
    age = s[k + _AGE]
    if age >= 0.0:
        age += dt
    if not fix:
        if age > max_age_s or age < 0.0:
            velocity_derivative_reset(s, k)
            return False
        s[k + _AGE] = age
        return s[k + _COUNT] > 0.0
    if age > 0.0 and age <= max_age_s:
        w = age / tau_s if tau_s > 0.0 else 1.0
        if w > 1.0 or s[k + _COUNT] == 0.0:
            w = 1.0  # the first difference is taken as it is
        s[k + _VDOT] += ((vn - s[k + _VPREV]) / age - s[k + _VDOT]) * w
        s[k + _VDOT + 1] += ((ve - s[k + _VPREV + 1]) / age - s[k + _VDOT + 1]) * w
        s[k + _VDOT + 2] += ((vd - s[k + _VPREV + 2]) / age - s[k + _VDOT + 2]) * w
        s[k + _COUNT] += 1.0
    elif age > max_age_s:
        velocity_derivative_reset(s, k)
    s[k + _VPREV] = vn
    s[k + _VPREV + 1] = ve
    s[k + _VPREV + 2] = vd
    s[k + _AGE] = 0.0
    return s[k + _COUNT] > 0.0
