r"""Vehicle acceleration from GNSS velocity, for acceleration-compensated levelling.

The accelerometer measures specific force f = a − g; with the true acceleration
a = v̇ known from GNSS velocity v (NED), ``f − v̇ = −g`` is an undisturbed
vertical reference whatever the vehicle does (003, "Влияние ускорений": the
gyro-platform's levelling uses f̂_NED − v̇).  :func:`velocity_derivative_step`
differentiates the velocity column of the input rows (``IN_VEL``, NaN = no
fix) and low-passes the result:

* on a new fix: raw = (v − v_prev) / (time since the previous fix), and
  v̇ ← v̇ + (raw − v̇)·min(1, Δt/τ);
* fixes may arrive on every row (interpolated values), only on some rows with
  NaN between them (what the daemon's pipeline does with GLOBAL_POSITION_INT
  at 5–10 Hz), or *held*: the last fix repeated on every row until the next.
  A value exactly equal to the one on the row before is taken as held (no
  new information), so a held 10 Hz stream gives nearly the same v̇ as the
  NaN form instead of a zero difference on every row and a spike on the
  change.  A held value that stays unchanged for longer than 1.5 times the
  interval between the last two changes (or ``max_age_s`` before that is
  known) is a new fix with the same velocity (a steady velocity: v̇ = 0).
  After NaN rows an equal value is always a new fix;
* a fix older than ``max_age_s`` (NaN rows only) breaks the chain and v̇ is
  invalid until two fixes are seen again.

With held values the low-pass of the resulting pulse train averages to Δv/T
when τ ≳ T.

State block (``VD_LEN`` values at offset k): v_prev (3), v̇ (3), time since the
last fix (s; −1 = none yet), number of differences averaged so far, 1.0 when
the previous row had a velocity, the interval between the last two changes
of the held value (s; 0 = not known).

:func:`gnss_compensation_step` turns that into the acceleration a filter
subtracts, with a weight that ramps linearly between 0 and 1 over
``fade_s`` as the velocity comes and goes, so losing or regaining the fix
never makes the gravity reference jump (state block ``GC_LEN`` values: the
``VD_LEN`` block, the last valid v̇ (3), the weight; after a reset the first
valid v̇ applies in full at once).

:func:`compensated_force_step` is the gravity reference of the complementary, gyro-platform and Mahony
filters: the accelerometer's specific force less v̇ (in body axes, when the filter's
``gnss_acceleration`` is on and v̇ is usable) and then low-passed in NED
(:func:`mavahrs.filters.prefilter.nav_lowpass_step`).  State block ``CF_LEN`` values: the ``VD_LEN``
block, then the low-pass's (at ``CF_LP``); parameter block ``CFP_LEN`` values (:func:`compensated_force_params`).
"""

from __future__ import annotations

import math

from mavahrs.filters.jit import kernel
from mavahrs.filters.kinematics import ned_to_body
from mavahrs.filters.layout import IN_ACCEL, IN_VEL
from mavahrs.filters.prefilter import LP_LEN, nav_lowpass_reset, nav_lowpass_step

__all__ = [
    "VD_LEN",
    "GC_LEN",
    "velocity_derivative_reset",
    "velocity_derivative_step",
    "gnss_compensation_reset",
    "gnss_compensation_step",
    "gnss_compensation_fresh",
    "CF_LP",
    "CF_LEN",
    "CFP_LEN",
    "compensated_force_params",
    "compensated_force_reset",
    "compensated_force_step",
]

VD_LEN = 10
_VPREV = 0
_VDOT = 3
_AGE = 6
_COUNT = 7
_PREV_ROW = 8
_PERIOD = 9

GC_LEN = VD_LEN + 4
_HELD = VD_LEN  # the last valid v̇ (3)
_WEIGHT = VD_LEN + 3  # compensation weight, 0 … 1; _FRESH: none since the reset
_FRESH = -1.0


@kernel
def velocity_derivative_reset(s, k):  # type: ignore[no-untyped-def]
    """Forget all velocity history (also on re-initialisation)."""
    for i in range(VD_LEN):
        s[k + i] = 0.0
    s[k + _AGE] = -1.0


@kernel(inline=True)  # every sample; inlined into the steps (see filters/jit.py)
def velocity_derivative_step(s, k, vn, ve, vd, dt, tau_s, max_age_s):  # type: ignore[no-untyped-def]
    """Advance by one row; return True when ``s[k+3:k+6]`` holds a usable v̇ (m/s², NED).

    A fix without a vertical (``vd`` NaN: a receiver's ground speed and
    course) gives a horizontal v̇ with 0 vertical acceleration.
    """
    if not math.isfinite(vd) and math.isfinite(vn) and math.isfinite(ve):
        vd = 0.0
    fix = math.isfinite(vn) and math.isfinite(ve) and math.isfinite(vd)
    age = s[k + _AGE]
    if age >= 0.0:
        age += dt
    prev_row = s[k + _PREV_ROW] > 0.0
    s[k + _PREV_ROW] = 1.0 if fix else 0.0
    if not fix:
        if age > max_age_s or age < 0.0:
            velocity_derivative_reset(s, k)
            return False
        s[k + _AGE] = age
        return s[k + _COUNT] > 0.0
    same = age >= 0.0 and vn == s[k + _VPREV] and ve == s[k + _VPREV + 1] and vd == s[k + _VPREV + 2]
    held = same and prev_row  # the row before had this very value: a held fix
    if held:
        limit = 1.5 * s[k + _PERIOD] if s[k + _PERIOD] > 0.0 else max_age_s
        if age <= min(limit, max_age_s):
            s[k + _AGE] = age  # nothing new yet
            return s[k + _COUNT] > 0.0
    if age > 0.0 and (age <= max_age_s or held):
        if not same:
            s[k + _PERIOD] = age
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
    s[k + _PREV_ROW] = 1.0
    return s[k + _COUNT] > 0.0


@kernel
def gnss_compensation_reset(s, k):  # type: ignore[no-untyped-def]
    """Forget the velocity history and the compensation (weight −1: none since the reset)."""
    velocity_derivative_reset(s, k)
    for i in range(3):
        s[k + _HELD + i] = 0.0
    s[k + _WEIGHT] = _FRESH


@kernel
def gnss_compensation_fresh(s, k):  # type: ignore[no-untyped-def]
    """True from a reset until the first valid v̇ (no compensation since the filter's (re)initialisation)."""
    return s[k + _WEIGHT] < 0.0


@kernel(inline=True)  # every sample; inlined into the steps (see filters/jit.py)
def gnss_compensation_step(s, k, vn, ve, vd, dt, tau_s, max_age_s, fade_s):  # type: ignore[no-untyped-def]
    """Advance by one row; return the NED acceleration (m/s²) to subtract from the specific force.

    ``weight · v̇``: the weight moves linearly towards 1 while v̇ is valid and
    towards 0 while it is not, at ``dt / fade_s`` per row (``fade_s`` ≤ 0:
    at once); while invalid, the last valid v̇ is faded out.  The first valid
    v̇ after a reset (the filter's (re)initialisation) applies in full at once:
    there is no gravity reference yet to keep from jumping, and a filter
    re-initialised in a manoeuvre converges on f − v̇ from the start instead
    of on f for the fade time.
    """
    fix = math.isfinite(vn) and math.isfinite(ve)  # a vertical is optional (velocity_derivative_step)
    if not fix and s[k + _WEIGHT] <= 0.0 and s[k + _AGE] < 0.0:
        # no fix now, none since the last reset (the block is in its reset state) and nothing
        # left to fade out: what the steps below would do, without doing it (a log without GNSS)
        return 0.0, 0.0, 0.0
    valid = velocity_derivative_step(s, k, vn, ve, vd, dt, tau_s, max_age_s)
    if valid:
        s[k + _HELD] = s[k + _VDOT]
        s[k + _HELD + 1] = s[k + _VDOT + 1]
        s[k + _HELD + 2] = s[k + _VDOT + 2]
    step = dt / fade_s if fade_s > 0.0 else 1.0
    w = s[k + _WEIGHT]
    if w < 0.0:  # nothing since the reset
        w = 1.0 if valid else _FRESH
        s[k + _WEIGHT] = w
        return (s[k + _HELD], s[k + _HELD + 1], s[k + _HELD + 2]) if valid else (0.0, 0.0, 0.0)
    w = min(w + step, 1.0) if valid else max(w - step, 0.0)
    s[k + _WEIGHT] = w
    return w * s[k + _HELD], w * s[k + _HELD + 1], w * s[k + _HELD + 2]


CF_LP = VD_LEN  # the low-pass block (prefilter.LP_LEN) of the compensated force
CF_LEN = VD_LEN + LP_LEN
_CFP_COMP, _CFP_VDOT_TAU, _CFP_MAX_AGE, _CFP_LP_TAU = range(4)
CFP_LEN = 4


def compensated_force_params(gnss_acceleration: bool, velocity_tau_s: float, velocity_max_age_s: float,
                             accel_lowpass_s: float) -> tuple[float, float, float, float]:  # fmt: skip
    """The parameter block (``CFP_LEN`` values) of :func:`compensated_force_step` from a filter's settings."""
    return 1.0 if gnss_acceleration else 0.0, velocity_tau_s, velocity_max_age_s, accel_lowpass_s


@kernel
def compensated_force_reset(s, k):  # type: ignore[no-untyped-def]
    """Forget the velocity history and the low-pass (the filter's (re)initialisation)."""
    velocity_derivative_reset(s, k)
    nav_lowpass_reset(s, k + CF_LP)


@kernel(inline=True)  # every sample; inlined into the steps (see filters/jit.py)
def compensated_force_step(s, k, params, kp, row, q0, q1, q2, q3, accel_ok, dt):  # type: ignore[no-untyped-def]
    """Advance by one input ``row`` at attitude ``q`` (body to NED); return the gravity reference (body axes, m/s²)
    and whether it is usable (``accel_ok``: the accelerometer's; false also when f − v̇ is no direction).

    The specific force less v̇ (rotated into body axes) where ``params[kp]`` (GNSS compensation) is on and v̇
    usable, then low-passed in NED with ``params[kp + 3]`` (s; 0: not).  v̇ follows ``row``'s velocity every
    row, with ``params[kp + 1]`` (τ, s) and ``params[kp + 2]`` (the largest fix age, s).
    """
    ax, ay, az = row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2]
    have_vdot = velocity_derivative_step(
        s, k, row[IN_VEL], row[IN_VEL + 1], row[IN_VEL + 2], dt, params[kp + _CFP_VDOT_TAU], params[kp + _CFP_MAX_AGE]
    )
    if accel_ok and have_vdot and params[kp + _CFP_COMP] > 0.0:
        j = k + _VDOT
        cx, cy, cz = ned_to_body(q0, q1, q2, q3, s[j], s[j + 1], s[j + 2])
        ax, ay, az = ax - cx, ay - cy, az - cz
        n2 = ax * ax + ay * ay + az * az
        accel_ok = n2 > 0.0 and math.isfinite(n2)
    if accel_ok:
        ax, ay, az = nav_lowpass_step(s, k + CF_LP, q0, q1, q2, q3, ax, ay, az, dt, params[kp + _CFP_LP_TAU])
    return ax, ay, az, accel_ok
