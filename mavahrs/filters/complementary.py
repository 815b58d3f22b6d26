r"""The complementary filter of Ermakov & Gogolev 2022 (002), eq. (22)–(29).

* Tilt from the accelerometer, eq. (22), written for **specific force** (the
  accelerometer points *up* at rest; a level FRD sensor reads (0, 0, −g)):
  roll = atan2(−f_y, −f_z), pitch = atan2(f_x, √(f_y² + f_z²)).  The paper's
  form atan2(a_y, a_z), atan2(−a_x, …) is for a sensor that reads +g on z.
* Heading from the tilt-compensated magnetometer, eq. (23):
  ψ = atan2(−m_E′, m_N′) with m′ the field levelled by roll and pitch.
* q_am from these Euler angles, eq. (24)–(25); q_ω = q ⊗ exp(ω·dt/2) from the
  previous fused estimate, eq. (26)–(28) (integrated exactly).
* Blend, eq. (29): q = (1 − α) q_ω + α q_am.  The paper's linear blend ignores
  that q and −q are the same rotation: the hemispheres are aligned first.
  Since (29) is linear, it equals ((1 − α)·1 + α Δ) ⊗ q_ω with
  Δ = q_am ⊗ q_ω*; Δ is split into a rotation about the NED vertical (heading,
  "twist") and one about a horizontal axis (tilt, "swing"), and (29) is applied
  to each with its own α, weighted by the gain schedule.  Without a
  magnetometer (or while it is rejected) the heading part is dropped, so the
  gyro's heading is kept — no Euler angle of q_ω is ever fed back.
* α is rate-independent: α = 1 − exp(−dt/τ).  The paper's α = 0.05 at 400 Hz
  is τ = −dt/ln(1 − α) ≈ 0.0487 s.
* Bias: the corrective rotation per step, expressed in body axes, is
  integrated into the gyro-bias estimate (a PI loop; the paper has none), plus
  the shared rest-phase estimator; accelerometer low-pass in the NED frame and
  GNSS acceleration compensation as in the other filters.

Details: ``docs/filters/complementary.md``.
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
from mavahrs.filters.kinematics import integrate_body_rate, ned_to_body, quat_multiply
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

__all__ = ["ComplementarySettings", "Complementary", "step", "paper_time_constant_s"]

# filter parameters, offsets from P_FILTER
_TAU_TILT = 0
_TAU_HEADING = 1
_KB = 2
_SPIN_FREEZE = 3
_BIAS_LIMIT = 4
_FORCE = 5  # the compensated force's block (gnss.CFP_LEN)
_ERR_LIMIT = _FORCE + CFP_LEN
_REST = 10
_N_PARAMS = _REST + RP_LEN

# filter state, offsets from S_FILTER
_CF = 0  # the compensated force: velocity derivative and navigation-frame low-pass (gnss.CF_LEN)
_LP = _CF + CF_LP  # its low-pass (prefilter.LP_LEN)
_RS = _CF + CF_LEN
_N_STATE = _RS + REST_LEN


def paper_time_constant_s(alpha: float = 0.05, rate_hz: float = 400.0) -> float:
    """The time constant τ equivalent to the paper's per-sample α at ``rate_hz``."""
    return -1.0 / (rate_hz * math.log(1.0 - alpha))


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
class ComplementarySettings(FilterSettings):
    """Complementary filter settings.

    Attributes:
        tilt_time_constant_s: τ of the tilt blend, s: α = 1 − exp(−dt/τ)
            (002 eq. (29); the paper's α = 0.05 at 400 Hz is τ ≈ 0.049 s,
            see :func:`paper_time_constant_s`).
        heading_time_constant_s: τ of the heading blend, s.
        bias_gain: gain of the bias integral, 1/s (b̂ ← b̂ − k·Cᵀr with r the
            corrective rotation of the step).  0 = no bias integral.
        spin_freeze_rad_s: the bias integral pauses above this rate.  0 = never.
        bias_limit_rad_s: the bias estimate is clamped to ± this per axis.
        integral_error_limit_rad: the tilt and heading errors whose corrections
            feed the bias integral are clipped to this angle (anti-windup).
            0 = off.
        gnss_acceleration: use f − Cᵀv̇ when a GNSS velocity is given.
        velocity_tau_s: low-pass time constant of v̇, s.
        velocity_max_age_s: a velocity older than this breaks the v̇ chain, s.
        accel_lowpass_s: accelerometer low-pass in the NED frame, s (0 = off).
        rest: gyro-bias estimation at rest.
        schedule: gain schedule (start-up boost, sensor trust).
    """

    tilt_time_constant_s: float = 2.0
    heading_time_constant_s: float = 2.0
    bias_gain: float = 0.02
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
        for name in ("tilt_time_constant_s", "heading_time_constant_s", "velocity_max_age_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"ComplementarySettings.{name} must be > 0 s, got {value!r}")
        for name in (
            "bias_gain",
            "spin_freeze_rad_s",
            "bias_limit_rad_s",
            "integral_error_limit_rad",
            "velocity_tau_s",
            "accel_lowpass_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"ComplementarySettings.{name} must be a finite number ≥ 0, got {value!r}")


@kernel
def _blend_with_identity(w, x, y, z, a):  # type: ignore[no-untyped-def]
    """Normalised (1 − a)·1 + a·d for a unit d with w ≥ 0 (002 eq. (29) on a correction)."""
    bw = (1.0 - a) + a * w
    bx, by, bz = a * x, a * y, a * z
    n = math.sqrt(bw * bw + bx * bx + by * by + bz * bz)
    return bw / n, bx / n, by / n, bz / n


@kernel
def step(state, params, row, out):  # type: ignore[no-untyped-def]
    """One complementary-filter update (module docstring: the equations)."""
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

    # q_ω from the previous fused estimate, eq. (26)–(28) (exact integration).
    integrate_body_rate(state, S_Q, gx, gy, gz, dt)
    n = math.sqrt(state[S_Q] ** 2 + state[S_Q + 1] ** 2 + state[S_Q + 2] ** 2 + state[S_Q + 3] ** 2)
    q0, q1, q2, q3 = state[S_Q] / n, state[S_Q + 1] / n, state[S_Q + 2] / n, state[S_Q + 3] / n

    # Specific force, GNSS-compensated (f − v̇) and low-passed in NED.
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
    use_tilt = accel_ok and w_a > 0.0
    use_heading = mag_ok and w_m > 0.0

    # Euler angles of q_ω (used where a measurement is missing)
    yaw_w = math.atan2(2.0 * (q0 * q3 + q1 * q2), 1.0 - 2.0 * (q2 * q2 + q3 * q3))
    if use_tilt:
        # eq. (22) for specific force
        roll = math.atan2(-ay, -az)
        pitch = math.atan2(ax, math.sqrt(ay * ay + az * az))
    else:
        roll = math.atan2(2.0 * (q0 * q1 + q2 * q3), 1.0 - 2.0 * (q1 * q1 + q2 * q2))
        pitch = math.asin(min(1.0, max(-1.0, 2.0 * (q0 * q2 - q3 * q1))))
    yaw = yaw_w
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    if use_heading:
        # eq. (23): level the field with roll and pitch, heading of its horizontal part
        mn_ = mx * cp + (my * sr + mz * cr) * sp
        me_ = my * cr - mz * sr
        if mn_ * mn_ + me_ * me_ > 1e-12 * (mx * mx + my * my + mz * mz):
            yaw = math.atan2(-me_, mn_)
        else:
            use_heading = False

    # q_am from Euler angles, eq. (24)–(25)
    hr, hp, hy = 0.5 * roll, 0.5 * pitch, 0.5 * yaw
    chr_, shr = math.cos(hr), math.sin(hr)
    chp, shp = math.cos(hp), math.sin(hp)
    chy, shy = math.cos(hy), math.sin(hy)
    a0 = chr_ * chp * chy + shr * shp * shy
    a1 = shr * chp * chy - chr_ * shp * shy
    a2 = chr_ * shp * chy + shr * chp * shy
    a3 = chr_ * chp * shy - shr * shp * chy

    # Δ = q_am ⊗ q_ω*, hemisphere aligned (the fix to eq. (29))
    d0, d1, d2, d3 = quat_multiply(a0, a1, a2, a3, q0, -q1, -q2, -q3)
    if d0 < 0.0:
        d0, d1, d2, d3 = -d0, -d1, -d2, -d3
    # heading part (twist about NED down) and tilt part (swing): Δ = T ⊗ S
    tn = math.sqrt(d0 * d0 + d3 * d3)
    if tn > 1e-9:
        t0, t3 = d0 / tn, d3 / tn
    else:
        t0, t3 = 1.0, 0.0
    s0, s1, s2, s3 = quat_multiply(t0, 0.0, 0.0, -t3, d0, d1, d2, d3)
    if s0 < 0.0:
        s0, s1, s2, s3 = -s0, -s1, -s2, -s3

    # eq. (29) per channel, α = 1 − exp(−dt/τ), boosted at start-up, weighted by trust
    elim = params[p + _ERR_LIMIT]
    c0, c1, c2, c3 = 1.0, 0.0, 0.0, 0.0
    gain = 0.0
    bn = be = bd = 0.0  # bias integrand: the corrections with clipped errors (anti-windup)
    if use_tilt:
        alpha = min(1.0, (1.0 - math.exp(-dt / params[p + _TAU_TILT])) * boost)
        gain = alpha * w_a
        c0, c1, c2, c3 = _blend_with_identity(s0, s1, s2, s3, gain)
        sv = math.sqrt(c1 * c1 + c2 * c2)
        if sv > 0.0:
            ang = 2.0 * math.atan2(sv, c0)
            err = 2.0 * math.atan2(math.sqrt(s1 * s1 + s2 * s2), s0)
            if elim > 0.0 and err > elim:
                ang *= elim / err
            bn, be = c1 / sv * ang, c2 / sv * ang
    if use_heading:
        alpha_m = min(1.0, (1.0 - math.exp(-dt / params[p + _TAU_HEADING])) * boost)
        h0, h1, h2, h3 = _blend_with_identity(t0, 0.0, 0.0, t3, alpha_m * w_m)
        ang = 2.0 * math.atan2(h3, h0)
        err = abs(2.0 * math.atan2(t3, t0))
        if elim > 0.0 and err > elim:
            ang *= elim / err
        bd = ang
        c0, c1, c2, c3 = quat_multiply(h0, h1, h2, h3, c0, c1, c2, c3)

    # q = Δ_c ⊗ q_ω
    n0, n1, n2_, n3 = quat_multiply(c0, c1, c2, c3, q0, q1, q2, q3)
    state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3] = n0, n1, n2_, n3

    # the corrective rotation (NED) also turns f̄_NED
    sv = math.sqrt(c1 * c1 + c2 * c2 + c3 * c3)
    if sv > 0.0:
        ang = 2.0 * math.atan2(sv, c0)
        nav_lowpass_rotate(state, S_FILTER + _LP, c1 / sv * ang, c2 / sv * ang, c3 / sv * ang)
    spin = math.sqrt(gx * gx + gy * gy + gz * gz)
    freeze = params[p + _SPIN_FREEZE]
    kb = params[p + _KB]
    if kb > 0.0 and boost <= 1.0 and not at_rest and (freeze <= 0.0 or spin < freeze):
        bx, by, bz = ned_to_body(q0, q1, q2, q3, bn, be, bd)
        lim = params[p + _BIAS_LIMIT]
        # b̂̇ = −k·Cᵀρ: in the steady state the correction ρ cancels the drift C(b − b̂)
        state[S_BIAS] = min(max(state[S_BIAS] - kb * bx, -lim), lim)
        state[S_BIAS + 1] = min(max(state[S_BIAS + 1] - kb * by, -lim), lim)
        state[S_BIAS + 2] = min(max(state[S_BIAS + 2] - kb * bz, -lim), lim)
    finish_step(state, out, gain, w_a, w_m)


class Complementary(AttitudeFilter):
    """The 2022 paper's complementary filter, hemisphere-safe.  See :class:`ComplementarySettings`."""

    name = "complementary"
    settings_type = ComplementarySettings
    step = step
    internal_len = _N_STATE

    @classmethod
    def filter_params(cls, settings: ComplementarySettings) -> np.ndarray:  # type: ignore[override]
        p = np.zeros(_N_PARAMS)
        p[_TAU_TILT] = settings.tilt_time_constant_s
        p[_TAU_HEADING] = settings.heading_time_constant_s
        p[_KB] = settings.bias_gain
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
