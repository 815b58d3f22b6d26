r"""The virtual gyro-platform (003: "Виртуальная гироплатформа", "Влияние ускорений",
"Смещения нуля датчиков").

The orientation is C = C_body→NED.  Mahony applies the corrective rate to the
body; here it is applied to the *navigation frame*, as a gimballed platform's
torquers would:

    Ċ = C Ω − Ω′ C,        Ω = [ω×] (body rate), Ω′ = [ω′×] (NED).          (003)

* Levelling (the platform's accelerometers): with the specific force in NED
  f = C f_body, normalised, ω′_N = k_g f̂_E, ω′_E = −k_g f̂_N — 003 writes
  ω′_N = −g k_g ĝ_E, ω′_E = g k_g ĝ_N with ĝ = −f̂; here k_g already includes g
  (rad/s per unit tilt).  Sign check: a platform tilted by φ about north sees
  f̂_E = φ, and Ċ = … − Ω′C turns it back by −k_g φ (tested: it levels itself).
* Heading channel, separate: ω′_D = k_ψ · sin(heading error), the error taken
  from the magnetometer's horizontal field in NED (h_E / ‖h_h‖).
* GNSS velocity (IN_VEL): f − v̇ replaces f, so the vertical is undisturbed by
  the vehicle's acceleration (003: ω′_N = g k_g (f̂_E − v̇_E), …).
* Bias by compensation estimation (003): at steady state the corrective rate
  equals the drift, ω′ = C δω, so δω̂̇ = k_b Cᵀ ω′ (body axes).
* Acceleration gating, as in aircraft gyro-verticals: the gain schedule lowers
  k_g when ‖f‖ departs from g or the horizontal NED specific force is large,
  and the levelling is reduced while the turn rate (about the vertical)
  exceeds a limit.

The state is kept as the quaternion of C (same rotation); one step is
q ← exp(−ω′·dt/2) ⊗ q ⊗ exp(ω·dt/2), the exact solution of the equation
above for rates held constant over dt.  Details: ``docs/filters/gyroplatform.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mavahrs.filters import gains as _g
from mavahrs.filters.base import (
    P_FILTER,
    P_SCHED,
    S_BIAS,
    S_FILTER,
    S_Q,
    S_SCHED,
    AttitudeFilter,
    FilterSettings,
    add_flag,
    begin_step,
    finish_step,
)
from mavahrs.filters.gains import GainScheduleSettings, schedule_step
from mavahrs.filters.gnss import (
    CF_LEN,
    CF_LP,
    CFP_LEN,
    compensated_force_params,
    compensated_force_reset,
    compensated_force_step,
)
from mavahrs.filters.jit import kernel
from mavahrs.filters.kinematics import body_to_ned, integrate_body_rate, ned_to_body, rotate_nav
from mavahrs.filters.layout import (
    FLAG_ACCEL_INVALID,
    FLAG_MAG_INVALID,
    FLAG_STARTUP,
    IN_ACCEL,
    IN_GYRO,
    IN_MAG,
    IN_VEL,
    OUT_FLAGS,
)
from mavahrs.filters.prefilter import nav_lowpass_rotate
from mavahrs.filters.rest import REST_LEN, RP_LEN, RestBiasSettings, rest_reset, rest_step

__all__ = ["GyroPlatformSettings", "GyroPlatform", "step"]

# filter parameters, offsets from P_FILTER
_K_LEVEL = 0
_K_HEADING = 1
_KB_LEVEL = 2
_KB_HEADING = 3
_TURN_LIMIT = 4
_SPIN_FREEZE = 5
_BIAS_LIMIT = 6
_FORCE = 7  # the compensated force's block (gnss.CFP_LEN)
_ERR_LIMIT = _FORCE + CFP_LEN
_REST = 12
_N_PARAMS = _REST + RP_LEN

# filter state, offsets from S_FILTER
_CF = 0  # the compensated force: velocity derivative and navigation-frame low-pass (gnss.CF_LEN)
_LP = _CF + CF_LP  # its low-pass (prefilter.LP_LEN)
_RS = _CF + CF_LEN
_N_STATE = _RS + REST_LEN


def _default_schedule() -> GainScheduleSettings:
    return GainScheduleSettings(
        startup_gain_factor=10.0,
        startup_s=3.0,
        accel_norm_tolerance=0.2,
        recovery_s=1.0,
        rejection_timeout_s=10.0,
        mag_norm_tolerance=0.07,
        mag_dip_tolerance_rad=math.radians(7.0),
    )


@dataclass(frozen=True)
class GyroPlatformSettings(FilterSettings):
    """Virtual gyro-platform settings.

    Attributes:
        level_gain: k_g, levelling rate per unit horizontal specific force
            (≈ rad/s per rad of tilt), 1/s.  Tilt errors decay with τ ≈ 1/k_g.
        heading_gain: k_ψ of the magnetometer heading channel, 1/s.
        level_bias_gain: k_b of the bias estimate from the levelling rate,
            1/s² (δω̂̇ = k_b Cᵀ ω′).
        heading_bias_gain: the same for the heading channel's rate, 1/s².
        turn_rate_limit_rad_s: levelling is reduced (∝ (limit/rate)²) while
            the turn rate about the vertical exceeds this.  0 = off.
        spin_freeze_rad_s: the bias estimate pauses above this body rate.
            0 = never.
        bias_limit_rad_s: the bias estimate is clamped to ± this per axis.
        integral_error_limit_rad: the levelling and heading errors fed to the
            bias estimate are clipped to this magnitude (anti-windup).  0 = off.
        gnss_acceleration: level on f − v̇ when a GNSS velocity is given.
        velocity_tau_s: low-pass time constant of v̇, s.
        velocity_max_age_s: a velocity older than this breaks the v̇ chain, s.
        accel_lowpass_s: low-pass of f in the NED frame, s (0 = off).
        rest: gyro-bias estimation at rest.
        schedule: gain schedule (start-up boost, accelerometer/magnetometer
            trust, horizontal-force gating).
    """

    level_gain: float = 0.5
    heading_gain: float = 0.5
    level_bias_gain: float = 0.02
    heading_bias_gain: float = 0.02
    turn_rate_limit_rad_s: float = 0.0
    spin_freeze_rad_s: float = math.radians(20.0)
    bias_limit_rad_s: float = math.radians(5.0)
    integral_error_limit_rad: float = math.radians(2.0)
    gnss_acceleration: bool = True
    velocity_tau_s: float = 0.0
    velocity_max_age_s: float = 1.0
    accel_lowpass_s: float = 1.0
    rest: RestBiasSettings = field(default_factory=RestBiasSettings)
    schedule: GainScheduleSettings = field(default_factory=_default_schedule)

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (
            "level_gain",
            "heading_gain",
            "level_bias_gain",
            "heading_bias_gain",
            "turn_rate_limit_rad_s",
            "spin_freeze_rad_s",
            "bias_limit_rad_s",
            "integral_error_limit_rad",
            "velocity_tau_s",
            "accel_lowpass_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"GyroPlatformSettings.{name} must be a finite number ≥ 0, got {value!r}")
        if not (math.isfinite(self.velocity_max_age_s) and self.velocity_max_age_s > 0.0):
            raise ValueError(
                f"GyroPlatformSettings.velocity_max_age_s must be > 0 s, got {self.velocity_max_age_s!r}"
            )


@kernel
def step(state, params, row, out):  # type: ignore[no-untyped-def]
    """One gyro-platform update (module docstring: the equations)."""
    dt = begin_step(state, params, row, out)
    flags = int(out[OUT_FLAGS])
    if dt < 0.0:
        if flags & FLAG_STARTUP:
            compensated_force_reset(state, S_FILTER + _CF)
            rest_reset(state, S_FILTER + _RS)
        return
    p = P_FILTER
    accel_ok = (flags & FLAG_ACCEL_INVALID) == 0
    mag_ok = (flags & FLAG_MAG_INVALID) == 0
    at_rest = rest_step(
        state, S_FILTER + _RS, state, S_BIAS, row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2],
        row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2], accel_ok,
        row[IN_VEL], row[IN_VEL + 1], row[IN_VEL + 2], dt, params, p + _REST,
    )  # fmt: skip
    gx = row[IN_GYRO] - state[S_BIAS]
    gy = row[IN_GYRO + 1] - state[S_BIAS + 1]
    gz = row[IN_GYRO + 2] - state[S_BIAS + 2]
    q0, q1, q2, q3 = state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3]

    # Specific force, GNSS-compensated (f − v̇, 003) and low-passed in NED.
    ax, ay, az, accel_ok = compensated_force_step(state, S_FILTER + _CF, params, p + _FORCE, row, q0, q1, q2, q3,
                                                  accel_ok, dt)  # fmt: skip
    mx, my, mz = row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2]
    boost, w_a, w_m = schedule_step(
        state[S_SCHED : S_SCHED + _g.GS_LEN],
        params[P_SCHED : P_SCHED + _g.GP_LEN],
        q0, q1, q2, q3, gx, gy, gz, ax, ay, az, accel_ok, mx, my, mz, mag_ok, dt,
    )  # fmt: skip
    if boost > 1.0:
        add_flag(out, FLAG_STARTUP)

    # ---- levelling channel: ω′_N = k_g f̂_E, ω′_E = −k_g f̂_N --------------------------
    wn = we = wd = 0.0
    k_level = 0.0
    if accel_ok and w_a > 0.0:
        fn, fe, fd = body_to_ned(q0, q1, q2, q3, ax, ay, az)
        fnorm = math.sqrt(fn * fn + fe * fe + fd * fd)
        fn, fe, fd = fn / fnorm, fe / fnorm, fd / fnorm
        if fd > 0.0:
            # the platform is more than 90° off (f points below the horizon): keep full strength
            h = math.sqrt(fn * fn + fe * fe)
            if h > 1e-12:
                fn, fe = fn / h, fe / h
        k_level = params[p + _K_LEVEL] * boost * w_a
        turn_limit = params[p + _TURN_LIMIT]
        if turn_limit > 0.0 and boost <= 1.0:
            _tn, _te, turn = body_to_ned(q0, q1, q2, q3, gx, gy, gz)
            turn = abs(turn)
            if turn > turn_limit:
                r = turn_limit / turn
                k_level *= r * r  # gyro-vertical turn cut-out, smoothly
        wn = k_level * fe
        we = -k_level * fn

    # ---- heading channel: ω′_D from the magnetometer's horizontal heading error -------
    if mag_ok and w_m > 0.0:
        hn, he, _hd = body_to_ned(q0, q1, q2, q3, mx, my, mz)
        bh = math.sqrt(hn * hn + he * he)
        if bh > 1e-6 * math.sqrt(mx * mx + my * my + mz * mz):
            err = he / bh  # sin(heading error); the platform turns back by −ω′_D
            if hn < 0.0:
                err = 1.0 if he > 0.0 else -1.0
            wd = params[p + _K_HEADING] * boost * w_m * err

    # ---- Ċ = CΩ − Ω′C, exactly for constant rates over dt ---------------------------------
    integrate_body_rate(state, S_Q, gx, gy, gz, dt)
    rotate_nav(state, S_Q, -wn * dt, -we * dt, -wd * dt)
    nav_lowpass_rotate(state, S_FILTER + _LP, -wn * dt, -we * dt, -wd * dt)

    # ---- bias by compensation estimation: δω̂̇ = k_b Cᵀ ω′ ---------------------------
    spin = math.sqrt(gx * gx + gy * gy + gz * gz)
    freeze = params[p + _SPIN_FREEZE]
    if boost <= 1.0 and not at_rest and (freeze <= 0.0 or spin < freeze):
        # per unit error: the levelling and heading rates scaled to the bias gains
        kbl = params[p + _KB_LEVEL] / max(params[p + _K_LEVEL], 1e-12)
        kbh = params[p + _KB_HEADING] / max(params[p + _K_HEADING], 1e-12)
        elim = params[p + _ERR_LIMIT]
        if elim > 0.0:  # anti-windup: clip the error magnitudes
            el = math.sqrt(wn * wn + we * we) / max(k_level, 1e-12)
            if el > elim:
                kbl *= elim / el
            eh = abs(wd) / max(params[p + _K_HEADING] * boost * w_m, 1e-12)
            if eh > elim:
                kbh *= elim / eh
        bx, by, bz = ned_to_body(q0, q1, q2, q3, kbl * wn * dt, kbl * we * dt, kbh * wd * dt)
        lim = params[p + _BIAS_LIMIT]
        state[S_BIAS] = min(max(state[S_BIAS] + bx, -lim), lim)
        state[S_BIAS + 1] = min(max(state[S_BIAS + 1] + by, -lim), lim)
        state[S_BIAS + 2] = min(max(state[S_BIAS + 2] + bz, -lim), lim)
    finish_step(state, out, k_level, w_a, w_m)


class GyroPlatform(AttitudeFilter):
    """Virtual gyro-platform with separate levelling and heading channels.  See :class:`GyroPlatformSettings`."""

    name = "gyroplatform"
    settings_type = GyroPlatformSettings
    step = step
    internal_len = _N_STATE

    @classmethod
    def filter_params(cls, settings: GyroPlatformSettings) -> np.ndarray:  # type: ignore[override]
        p = np.zeros(_N_PARAMS)
        p[_K_LEVEL] = settings.level_gain
        p[_K_HEADING] = settings.heading_gain
        p[_KB_LEVEL] = settings.level_bias_gain
        p[_KB_HEADING] = settings.heading_bias_gain
        p[_TURN_LIMIT] = settings.turn_rate_limit_rad_s
        p[_SPIN_FREEZE] = settings.spin_freeze_rad_s
        p[_BIAS_LIMIT] = settings.bias_limit_rad_s
        p[_ERR_LIMIT] = settings.integral_error_limit_rad
        p[_FORCE : _FORCE + CFP_LEN] = compensated_force_params(
            settings.gnss_acceleration, settings.velocity_tau_s, settings.velocity_max_age_s, settings.accel_lowpass_s
        )
        p[_REST : _REST + RP_LEN] = settings.rest.to_params()
        return p

    def initial_internal(self) -> np.ndarray:
        s = np.zeros(_N_STATE)
        compensated_force_reset(s, _CF)
        rest_reset(s, _RS)
        return s
