r"""Mahony's nonlinear complementary filter: a PI controller on SO(3).

Ermakov & Gogolev 2022 (002), eq. (2)–(14); Mahony, Hamel & Pflimlin 2008;
with the features of INAV's implementation quoted in the 003 tutorial:

* error e = â × v̂_a + m̂ × v̂_m (002 eq. (10)): measured × predicted direction;
* corrected rate ω_c = ω − b̂ + K_P e, bias b̂̇ = −K_I e (Mahony 2008).  002's
  eq. (11) writes the integral with the opposite sign, which makes the bias
  loop unstable; the stable form is used (tested: a constant bias is learned);
* accelerometer weight from the shared gain schedule (INAV's "nearness" of
  ‖a‖ to g), bias integral frozen while the spin rate exceeds a limit (INAV:
  20°/s), start-up fast gains (schedule boost; INAV: K_P × 10 for 20 s);
* magnetometer correction for **heading only** (INAV): the field is rotated
  into NED, the heading error is taken from its horizontal part and applied
  about the NED vertical, rotated back to body axes;
* optional heading from GNSS course over ground when there is no
  magnetometer (fixed-wing flight: body x along the velocity);
* optional acceleration compensation from GNSS velocity: f − Cᵀv̇ instead of
  f (covers INAV's centrifugal term ω × v and the tangential acceleration).

The kinematics are integrated exactly, q ← q ⊗ exp(ω_c·dt/2), instead of
002's first-order eq. (12)–(13).  Convention: ``q_body_to_ned`` throughout
(002 and INAV write the conjugate; nothing is converted mid-equation since
the error is formed from rotated vectors).  Details: ``docs/filters/mahony.md``.
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
from mavahrs.filters.kinematics import body_to_ned, integrate_body_rate
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

__all__ = ["MahonySettings", "Mahony", "step"]

# filter parameters, offsets from P_FILTER
_KP_ACCEL = 0
_KP_MAG = 1
_KI_ACCEL = 2
_KI_MAG = 3
_SPIN_FREEZE = 4
_BIAS_LIMIT = 5
_COG = 6
_COG_SPEED = 7
_FORCE = 8  # the compensated force's block (gnss.CFP_LEN)
_ERR_LIMIT = _FORCE + CFP_LEN
_REST = 13  # rest-detector block (rest.RP_LEN)
_N_PARAMS = _REST + RP_LEN

# filter state, offsets from S_FILTER
_CF = 0  # the compensated force: velocity derivative and navigation-frame low-pass (gnss.CF_LEN)
_LP = _CF + CF_LP  # its low-pass (prefilter.LP_LEN)
_RS = _CF + CF_LEN  # rest detector (rest.REST_LEN)
_N_STATE = _RS + REST_LEN


def _default_schedule() -> GainScheduleSettings:
    return GainScheduleSettings(
        startup_gain_factor=10.0,
        startup_s=3.0,
        accel_norm_tolerance=0.2,
        spin_rate_rad_s=0.0,
        horizontal_tolerance=0.0,
        recovery_s=1.0,
        rejection_timeout_s=10.0,
        mag_norm_tolerance=0.07,
        mag_dip_tolerance_rad=math.radians(7.0),
    )


@dataclass(frozen=True)
class MahonySettings(FilterSettings):
    """Mahony filter settings (rate-independent; gains in rad/s per unit error).

    Attributes:
        kp_accel: K_P of the gravity error, 1/s (002: 0.5).  The tilt error
            decays with time constant ≈ 1/kp_accel.
        kp_mag: K_P of the heading error (magnetometer or GNSS course), 1/s.
        ki_accel: K_I of the gravity error, 1/s² (bias integral; 002: 1).
        ki_mag: K_I of the heading error, 1/s².
        spin_freeze_rad_s: the bias integral stops while the corrected rate
            exceeds this (INAV: 20°/s).  0 = never freeze.
        bias_limit_rad_s: the bias estimate is clamped to ± this per axis.
        integral_error_limit_rad: each error vector fed to the bias integral
            is clipped to this magnitude (≈ angle), so a large transient error
            (a bad start, a disturbance) does not wind the bias up.  0 = no clip.
        cog_heading: without a magnetometer, correct heading from the GNSS
            course over ground (body x assumed along the ground track, as on a
            fixed-wing aircraft).  Off by default.
        cog_min_speed_m_s: ground speed below which the course is ignored.
        gnss_acceleration: use f − Cᵀv̇ (v̇ from the velocity column) as the
            gravity reference when a GNSS velocity is given.
        velocity_tau_s: low-pass time constant of v̇, s (≥ the GNSS period).
        velocity_max_age_s: a velocity older than this breaks the v̇ chain, s.
        accel_lowpass_s: time constant of the accelerometer low-pass taken in
            the estimated NED frame (vibration and taps average out without
            lag under rotation; :mod:`mavahrs.filters.prefilter`), s.  0 = off.
        rest: gyro-bias estimation at rest (:mod:`mavahrs.filters.rest`);
            the PI integral is paused while at rest.
        schedule: gain schedule (start-up boost, accelerometer/magnetometer
            trust).
    """

    kp_accel: float = 0.5
    kp_mag: float = 0.5
    ki_accel: float = 0.02
    ki_mag: float = 0.02
    spin_freeze_rad_s: float = math.radians(20.0)
    bias_limit_rad_s: float = math.radians(5.0)
    integral_error_limit_rad: float = math.radians(2.0)
    cog_heading: bool = False
    cog_min_speed_m_s: float = 3.0
    gnss_acceleration: bool = True
    velocity_tau_s: float = 0.0
    velocity_max_age_s: float = 1.0
    accel_lowpass_s: float = 1.0
    rest: RestBiasSettings = field(default_factory=RestBiasSettings)
    schedule: GainScheduleSettings = field(default_factory=_default_schedule)

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (
            "kp_accel",
            "kp_mag",
            "ki_accel",
            "ki_mag",
            "spin_freeze_rad_s",
            "bias_limit_rad_s",
            "integral_error_limit_rad",
            "cog_min_speed_m_s",
            "velocity_tau_s",
            "accel_lowpass_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"MahonySettings.{name} must be a finite number ≥ 0, got {value!r}")
        if not (math.isfinite(self.velocity_max_age_s) and self.velocity_max_age_s > 0.0):
            raise ValueError(
                f"MahonySettings.velocity_max_age_s must be > 0 s, got {self.velocity_max_age_s!r}"
            )


@kernel
def step(state, params, row, out):  # type: ignore[no-untyped-def]
    """One Mahony update (see the module docstring for the equations)."""
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
    q0, q1, q2, q3 = state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3]
    at_rest = rest_step(
        state, S_FILTER + _RS, state, S_BIAS, row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2],
        row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2], accel_ok,
        row[IN_VEL], row[IN_VEL + 1], row[IN_VEL + 2], dt, params, p + _REST,
    )  # fmt: skip
    bx, by, bz = state[S_BIAS], state[S_BIAS + 1], state[S_BIAS + 2]
    gx = row[IN_GYRO] - bx
    gy = row[IN_GYRO + 1] - by
    gz = row[IN_GYRO + 2] - bz

    # GNSS acceleration compensation: gravity reference f − Cᵀ v̇, low-passed in NED.
    vn, ve = row[IN_VEL], row[IN_VEL + 1]
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

    # Down axis of NED in body axes = third row of C_body_to_ned.
    c20 = 2.0 * (q1 * q3 - q0 * q2)
    c21 = 2.0 * (q2 * q3 + q0 * q1)
    c22 = 1.0 - 2.0 * (q1 * q1 + q2 * q2)

    # ---- gravity error (002 eq. (8)–(10)) ----------------------------------------
    eax = eay = eaz = 0.0
    if accel_ok and w_a > 0.0:
        na = math.sqrt(ax * ax + ay * ay + az * az)
        ux, uy, uz = ax / na, ay / na, az / na  # measured "up" (specific force), eq. (2)
        # predicted up in body = −(c20, c21, c22); e = â × v̂_a = (c2 × â)
        eax = c21 * uz - c22 * uy
        eay = c22 * ux - c20 * uz
        eaz = c20 * uy - c21 * ux
        if ux * c20 + uy * c21 + uz * c22 > 0.0:
            # more than 90° off: |â × v̂| = sin(angle) shrinks; keep full strength
            en = math.sqrt(eax * eax + eay * eay + eaz * eaz)
            if en > 1e-12:
                eax, eay, eaz = eax / en, eay / en, eaz / en

    # ---- heading error: magnetometer (INAV, heading only) or GNSS course ---------
    e_d = 0.0  # heading error about NED down, rad-like (sin of the error)
    use_heading = False
    if mag_ok and w_m > 0.0:
        hn, he, _hd = body_to_ned(q0, q1, q2, q3, mx, my, mz)  # 002 eq. (3)
        bh = math.sqrt(hn * hn + he * he)  # eq. (4): reference (b_h, 0, h_d)
        if bh > 1e-6 * math.sqrt(mx * mx + my * my + mz * mz):
            # (h_N, h_E, 0) × (b_h, 0, 0) = (0, 0, −h_E·b_h); normalised by b_h² → −sin(error)
            e_d = -he / bh
            if hn < 0.0:
                e_d = -1.0 if he > 0.0 else 1.0
            use_heading = True
    elif not mag_ok and params[p + _COG] > 0.0:
        speed = math.sqrt(vn * vn + ve * ve) if (math.isfinite(vn) and math.isfinite(ve)) else 0.0
        if speed > params[p + _COG_SPEED]:
            c00 = 1.0 - 2.0 * (q2 * q2 + q3 * q3)
            c10 = 2.0 * (q1 * q2 + q0 * q3)
            hx = math.sqrt(c00 * c00 + c10 * c10)
            if hx > 0.1:
                # Premerlani & Bizard eq. 22–23: estimated heading (c00, c10) × course (vn, ve)
                sin_err = (c00 * ve - c10 * vn) / (hx * speed)
                cos_err = (c00 * vn + c10 * ve) / (hx * speed)
                e_d = sin_err if cos_err >= 0.0 else (1.0 if sin_err >= 0.0 else -1.0)
                use_heading = True
                w_m = 1.0
    emx = emy = emz = 0.0
    if use_heading:
        # rotate (0, 0, e_d) from NED back to body: e_d · (third row of C)
        emx, emy, emz = c20 * e_d, c21 * e_d, c22 * e_d

    # ---- PI correction (Mahony 2008; 002 eq. (11) with the stable sign) ---------
    kpa = params[p + _KP_ACCEL] * boost * w_a
    kpm = params[p + _KP_MAG] * boost * w_m
    dx = kpa * eax + kpm * emx
    dy = kpa * eay + kpm * emy
    dz = kpa * eaz + kpm * emz
    wx, wy, wz = gx + dx, gy + dy, gz + dz
    # the correction, seen as a rotation of the estimated NED frame, also turns f̄_NED
    rn, re, rd = body_to_ned(q0, q1, q2, q3, dx * dt, dy * dt, dz * dt)
    nav_lowpass_rotate(state, S_FILTER + _LP, rn, re, rd)
    spin = math.sqrt(gx * gx + gy * gy + gz * gz)
    freeze = params[p + _SPIN_FREEZE]
    if boost <= 1.0 and not at_rest and (freeze <= 0.0 or spin < freeze):
        kia = params[p + _KI_ACCEL] * w_a * dt
        kim = params[p + _KI_MAG] * w_m * dt
        elim = params[p + _ERR_LIMIT]
        if elim > 0.0:  # anti-windup: clip each error's magnitude
            ea = math.sqrt(eax * eax + eay * eay + eaz * eaz)
            if ea > elim:
                kia *= elim / ea
            if abs(e_d) > elim:
                kim *= elim / abs(e_d)
        lim = params[p + _BIAS_LIMIT]
        nb0 = bx - kia * eax - kim * emx  # b̂̇ = −K_I e
        nb1 = by - kia * eay - kim * emy
        nb2 = bz - kia * eaz - kim * emz
        state[S_BIAS] = min(max(nb0, -lim), lim)
        state[S_BIAS + 1] = min(max(nb1, -lim), lim)
        state[S_BIAS + 2] = min(max(nb2, -lim), lim)

    integrate_body_rate(state, S_Q, wx, wy, wz, dt)  # q ← q ⊗ exp(ω_c dt/2), exact eq. (12)–(14)
    finish_step(state, out, params[p + _KP_ACCEL] * boost * w_a, w_a, w_m)



class Mahony(AttitudeFilter):
    """Mahony PI filter on SO(3) with INAV's features.  See :class:`MahonySettings`."""

    name = "mahony"
    settings_type = MahonySettings
    step = step
    internal_len = _N_STATE

    @classmethod
    def filter_params(cls, settings: MahonySettings) -> np.ndarray:  # type: ignore[override]
        p = np.zeros(_N_PARAMS)
        p[_KP_ACCEL] = settings.kp_accel
        p[_KP_MAG] = settings.kp_mag
        p[_KI_ACCEL] = settings.ki_accel
        p[_KI_MAG] = settings.ki_mag
        p[_SPIN_FREEZE] = settings.spin_freeze_rad_s
        p[_BIAS_LIMIT] = settings.bias_limit_rad_s
        p[_ERR_LIMIT] = settings.integral_error_limit_rad
        p[_COG] = 1.0 if settings.cog_heading else 0.0
        p[_COG_SPEED] = settings.cog_min_speed_m_s
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
