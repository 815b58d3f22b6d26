r"""Madgwick's gradient-descent attitude filter (IMU and MARG forms).

S. Madgwick, "An efficient orientation filter for inertial and
inertial/magnetic sensor arrays", 2010 (``../shared/seeds/000``, digest in
``../shared/design/filters.md``).  Per sample: propagate with the gyro (eq.
11–13, integrated exactly), take one normalised gradient-descent step on the
objective of the gravity (eq. 25–26) and, with a magnetometer, the magnetic
field (eq. 29–32), ``q̇ = q̇_ω − β ∇f/‖∇f‖`` (eq. 20, 34, 42–44), with
magnetic distortion compensation (eq. 45–46) and gyro-bias drift compensation
ζ (eq. 47–49).

Convention: the equations are derived here directly for ``q_body_to_ned``
(NED earth frame, specific-force accelerometer): the objective compares the
predicted body-frame "down" ``C(q)ᵀ·[0,0,1]`` with the measured one ``−â``,
and the predicted field ``C(q)ᵀ·b`` with ``m̂``.  With this choice the
component formulas are exactly the report's (25), (26), (29), (30) with
``(q1, q2, q3, q4) → (w, x, y, z)`` (the report's kinematics (11) and
rotation (45) use its quaternion as the sensor→earth rotation), so no
conjugation is needed anywhere; ``docs/filters/madgwick.md`` has the
derivation.  The widely copied C code computes the reference ``b_x, b_z`` of
eq. (46) a factor of two too small (BROAD issue #1); this module does not, and
``tests/filters/test_madgwick.py`` checks every gradient against finite
differences of ½‖f‖².

Around the report's equations (all in :class:`MadgwickSettings`): the
shared gain schedule (start-up boost, magnetometer rejection by norm and dip,
:mod:`mavahrs.filters.gains`) and gyro-bias learning at detected rest
(:mod:`mavahrs.filters.rest`), both on by default; optionally the
accelerometer low-pass filtered in a quasi-inertial frame before it enters
the gradient (with a longer average blended in where motion acceleration
outweighs rotation), and a heading-only magnetometer objective (the horizontal field,
whose gradient is a pure rotation about the vertical) with its own β.  These
follow Laidig & Seel 2023 (VQF); ``mavahrs.filters.best`` uses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from mavahrs.errors import ConfigError
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
    vector_ok,
)
from mavahrs.filters.gains import G_M_S2, GainScheduleSettings, schedule_step
from mavahrs.filters.gnss import (
    GC_LEN,
    gnss_compensation_fresh,
    gnss_compensation_reset,
    gnss_compensation_step,
)
from mavahrs.filters.initial import triad_attitude
from mavahrs.filters.jit import kernel, pure_python
from mavahrs.filters.kinematics import body_to_ned, integrate_body_rate, ned_to_body, quat_multiply
from mavahrs.filters.layout import FLAG_STARTUP, IN_ACCEL, IN_GYRO, IN_MAG, IN_VEL, OUT_FLAGS
from mavahrs.filters.prefilter import (
    BW_LEN,
    LP_LEN,
    nav_lowpass_reset,
    nav_lowpass_rotate,
    ned_butterworth_step,
    vector_lowpass_step,
)
from mavahrs.filters.rest import REST_LEN, RP_LEN, RestBiasSettings, rest_reset, rest_step

__all__ = [
    "MadgwickSettings",
    "Madgwick",
    "default_schedule",
    "beta_from_gyro_error",
    "zeta_from_bias_drift",
    "gravity_objective",
    "gravity_gradient",
    "field_objective",
    "field_gradient",
    "step",
]

_MAG_MODES = ("full", "heading")


def beta_from_gyro_error(gyro_error_rad_s: float) -> float:
    """β from the gyro's mean zero-mean measurement error ω̃_β per axis (Madgwick 2010, eq. (50)).

    ``β = ‖½ q̂ ⊗ [0, ω̃, ω̃, ω̃]‖ = √(3/4)·ω̃_β``.
    """
    if not (math.isfinite(gyro_error_rad_s) and gyro_error_rad_s >= 0):
        raise ConfigError(f"gyro error must be a non-negative rate in rad/s, got {gyro_error_rad_s!r}")
    return math.sqrt(0.75) * gyro_error_rad_s


def zeta_from_bias_drift(bias_drift_rad_s2: float) -> float:
    """ζ from the gyro bias drift rate ω̃_ζ per axis, rad/s per s (Madgwick 2010, eq. (51))."""
    if not (math.isfinite(bias_drift_rad_s2) and bias_drift_rad_s2 >= 0):
        raise ConfigError(f"bias drift must be a non-negative rate in rad/s², got {bias_drift_rad_s2!r}")
    return math.sqrt(0.75) * bias_drift_rad_s2


def default_schedule() -> GainScheduleSettings:
    """The gain schedule Madgwick uses by default (measured on BROAD, ``docs/accuracy.md``).

    Start-up boost ×10 ramping down over 3 s (Madgwick 2010 §6 in spirit);
    no accelerometer-norm rejection (on BROAD every form of it made the tilt
    worse: fast rotation and translation then run on the gyro alone for too
    long); magnetometer rejected when its norm departs > 15 % or its dip
    > 15° from the learned reference, the dip measured against the
    estimate's vertical (motion accelerations cannot fake it).
    """
    return GainScheduleSettings(
        startup_gain_factor=10.0,
        startup_s=3.0,
        accel_norm_tolerance=0.0,
        spin_rate_rad_s=0.0,
        horizontal_tolerance=0.0,
        recovery_s=0.5,
        rejection_timeout_s=20.0,
        mag_norm_tolerance=0.15,
        mag_dip_tolerance_rad=math.radians(15.0),
        mag_learn_s=20.0,
        mag_dip_from_attitude=True,
    )


@dataclass(frozen=True)
class MadgwickSettings(FilterSettings):
    """Settings of :class:`Madgwick`; all rates and times are independent of the sample rate.

    The defaults are the report's filter (β = 0.041, stacked MARG objective,
    distortion compensation) made robust by rest-phase bias estimation and
    magnetometer rejection; ``mavahrs.filters.best`` turns on the extensions.

    Attributes:
        beta_rad_s: β of eq. (43), 1/s: the rate at which the estimate
            (a unit quaternion) is pulled along the normalised gradient; the
            attitude correction rate is 2β rad/s.  The report recommends
            0.033 (IMU) / 0.041 (MARG), i.e. ω̃_β ≈ 2.7°/s in eq. (50);
            :func:`beta_from_gyro_error` derives it from the gyro's error.
            0 = gyro only (no correction).
        zeta_rad_s: ζ of eq. (48), 1/s: gain of the gyro-bias drift
            compensation (eq. 47–49).  The report uses 0.015 (drifts up to
            ≈ 1°/s per second); :func:`zeta_from_bias_drift` derives it from
            the drift rate.  The bias then follows with time constant ≈ β/ζ
            (20 s at the defaults); larger values let motion-induced errors
            leak into the bias (measured on BROAD).  0 = no bias learning in
            motion (the rest-phase estimate below still works).
        zeta_spin_limit_rad_s: ζ is applied only while the corrected rate
            is below this (INAV freezes its bias integral above 20°/s): in
            fast turns scale-factor and timing errors look like a bias.
            0 = always.
        use_magnetometer: use the magnetometer when the sample has one (MARG
            form); False = IMU form always.
        mag_correction: ``"full"`` = the report's stacked objective (eq. 31–34;
            the magnetometer then also acts on roll and pitch), or
            ``"heading"`` = the magnetic objective on the horizontal field
            only (reference b = [1, 0, 0]), normalised separately with gain
            ``beta_heading_rad_s``: the magnetometer corrects heading only.
        beta_heading_rad_s: β of the heading correction in ``"heading"``
            mode, 1/s.  None = the same as ``beta_rad_s``.
        distortion_compensation: eq. (45)–(46): the magnetic reference b is
            the measured field's own horizontal/vertical split (a wrong dip
            then cannot tilt the estimate).  False = b from the learned
            reference dip of the gain schedule.
        accel_lowpass_s: time constant (s) of a low-pass filter applied to
            the accelerometer in the estimated NED frame, which every
            correction rotates along (the same as VQF's gyro-integrated
            quasi-inertial frame), before it enters the gradient: motion
            accelerations average out while rotations are followed without
            lag.  0 = the raw accelerometer (the report).
        accel_lowpass_order: 1 = first-order low-pass
            (:mod:`mavahrs.filters.prefilter`), 2 = second-order Butterworth
            with cut-off √2/(2π·τ) (VQF's choice; attenuates motion
            accelerations of a few tenths of a hertz ten times more).
        accel_lowpass_adapt_ratio: adaptive low-pass, off (0) by default.
            The low-pass trades two errors: the motion acceleration it
            leaves shrinks as τ grows, while the error of its stored average
            grows with τ and the rotation rate (the average is carried along
            by the gyro, whose scale and misalignment errors accumulate with
            the angle turned).  The best τ therefore grows as √(ā/ω̄), with ā
            the motion acceleration the low-pass removes (‖f − f̄‖, m/s²) and
            ω̄ the rotation rate (rad/s), each averaged over
            ``accel_lowpass_adapt_avg_s`` and held at detected rest.  With
            this ratio r > 0 (m/s² per rad/s), a second low-pass of time
            constant ``accel_lowpass_max_s`` runs beside the first and is
            blended in by λ = (τ_w − τ)/(τ_max − τ), τ_w =
            ``accel_lowpass_s``·√(ā/(r·ω̄)) clipped to [τ, τ_max]: translations
            get the longer average, rotations keep the short one.  (Two
            fixed filters, not one whose τ changes: a Butterworth whose
            coefficients change under it does not keep a constant input's
            norm, which the manoeuvre weight reads.)  Only motion that
            averages out gains from a longer average: λ is scaled by the
            averaged manoeuvre weight of ``lowpass_norm_tolerance`` and by
            the long average's own norm weight, so a sustained acceleration
            (‖f̄‖ ≠ g, a vehicle in a manoeuvre) keeps the short one.  Costs
            a second low-pass while on; off, the filter is unchanged.
        accel_lowpass_max_s: the long low-pass's time constant, s.
        accel_lowpass_adapt_avg_s: averaging time constant of ā, ω̄ and the
            manoeuvre weight, s.
        rest: gyro-bias estimation at detected rest
            (:mod:`mavahrs.filters.rest`); ``RestBiasSettings(bias_tau_s=0)``
            turns it off.
        bias_limit_rad_s: each component of the bias estimate is clipped to
            ±this, rad/s.  0 = no limit.
        large_error_tau_s: above a tilt error of 2β·τ the gravity step
            grows with the error, giving an exponential convergence with
            time constant τ (s) instead of the constant 2β rad/s of eq. (43),
            which takes minutes to undo a large error when β is small.
            0 = the report's constant rate.
        large_heading_error_tau_s: the same for the magnetometer's heading
            step (crossover 2β_heading·τ).  0 = constant rate.
        lowpass_norm_tolerance: manoeuvre weight: when the norm of the
            low-passed (GNSS-compensated) specific force f̄ departs from g
            by this fraction, the gravity correction falls to
            ``lowpass_norm_min_weight`` and the large-error speed-up to 0
            (linearly in between): a sustained acceleration — a
            multirotor's accelerometer reads thrust and drag, not gravity,
            while it accelerates — is not taken for a tilt error.
            0 = off (the report's filter).
        lowpass_norm_min_weight: the gravity correction's weight never
            falls below this (0–1), so that a mis-scaled accelerometer slows
            the correction down but never stops it.
        gnss_acceleration: with a GNSS velocity in the input rows
            (``velocity_ned_m_s``, ``IN_VEL``; NaN = no fix), subtract the
            vehicle's acceleration v̇ from the specific force in the
            estimated NED frame before the gradient (f − v̇, the 003
            tutorial's acceleration-compensated vertical; each low-passed
            separately): sustained manoeuvres then no longer tilt the
            estimate.  The horizontal part is used only while the
            magnetometer has corrected the heading within
            ``HEADING_HOLD_S`` (60 s), since it is rotated into body axes
            with the estimated heading; the vertical part always.  The
            first v̇ after a (re)initialisation re-aligns the estimate at
            once (TRIAD: f ↔ v̇ − g, m ↔ the reference field) and applies
            in full: a start from the accelerometer in a manoeuvre is
            tens of degrees off.  Without velocity nothing changes.
        velocity_tau_s: low-pass time constant of v̇, s (0 = the latest
            difference of fixes; :mod:`mavahrs.filters.gnss`).
        velocity_max_age_s: a fix older than this (NaN rows in between)
            breaks the v̇ chain, s; held (repeated) values are recognised.
        gnss_fade_s: the compensation fades out over this time when the
            fix is lost and back in when it returns, s (no jump in the
            gravity reference; the first v̇ after a (re)initialisation
            applies at once).  0 = switch at once.
        schedule: the shared gain schedule (:func:`default_schedule`).
    """

    beta_rad_s: float = 0.041
    zeta_rad_s: float = 0.002
    zeta_spin_limit_rad_s: float = math.radians(20.0)
    use_magnetometer: bool = True
    mag_correction: str = "full"
    beta_heading_rad_s: float | None = None
    distortion_compensation: bool = True
    accel_lowpass_s: float = 0.0
    accel_lowpass_order: int = 2
    accel_lowpass_adapt_ratio: float = 0.0
    accel_lowpass_max_s: float = 4.0
    accel_lowpass_adapt_avg_s: float = 5.0
    large_error_tau_s: float = 0.0
    large_heading_error_tau_s: float = 0.0
    lowpass_norm_tolerance: float = 0.0
    lowpass_norm_min_weight: float = 0.2
    gnss_acceleration: bool = True
    velocity_tau_s: float = 0.0
    velocity_max_age_s: float = 1.0
    gnss_fade_s: float = 1.0
    rest: RestBiasSettings = field(default_factory=RestBiasSettings)
    bias_limit_rad_s: float = math.radians(5.0)
    schedule: GainScheduleSettings = field(default_factory=default_schedule)

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("beta_rad_s", "zeta_rad_s", "zeta_spin_limit_rad_s", "accel_lowpass_s", "bias_limit_rad_s",
                     "large_error_tau_s", "large_heading_error_tau_s", "lowpass_norm_tolerance", "velocity_tau_s",
                     "gnss_fade_s", "accel_lowpass_adapt_ratio"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (
                isinstance(value, (int, float)) and math.isfinite(value) and value >= 0
            ):
                raise ConfigError(f"MadgwickSettings.{name} must be a finite number ≥ 0, got {value!r}")
        if self.beta_heading_rad_s is not None and not (
            isinstance(self.beta_heading_rad_s, (int, float))
            and math.isfinite(self.beta_heading_rad_s)
            and self.beta_heading_rad_s >= 0
        ):
            raise ConfigError(
                f"MadgwickSettings.beta_heading_rad_s must be a number ≥ 0 or None, got {self.beta_heading_rad_s!r}"
            )
        for name in ("accel_lowpass_max_s", "accel_lowpass_adapt_avg_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"MadgwickSettings.{name} must be a time > 0 s, got {value!r}")
        if not (isinstance(self.velocity_max_age_s, (int, float)) and math.isfinite(self.velocity_max_age_s)
                and self.velocity_max_age_s > 0):
            raise ConfigError(
                f"MadgwickSettings.velocity_max_age_s must be a time > 0 s, got {self.velocity_max_age_s!r}"
            )
        if not (isinstance(self.lowpass_norm_min_weight, (int, float)) and 0.0 <= self.lowpass_norm_min_weight <= 1.0):
            raise ConfigError(
                f"MadgwickSettings.lowpass_norm_min_weight must be in [0, 1], got {self.lowpass_norm_min_weight!r}"
            )
        if not isinstance(self.gnss_acceleration, bool):
            raise ConfigError(f"MadgwickSettings.gnss_acceleration must be True or False, got {self.gnss_acceleration!r}")
        if self.mag_correction not in _MAG_MODES:
            raise ConfigError(
                f"MadgwickSettings.mag_correction must be one of {_MAG_MODES}, got {self.mag_correction!r}"
            )
        if self.accel_lowpass_order not in (1, 2):
            raise ConfigError(
                f"MadgwickSettings.accel_lowpass_order must be 1 or 2, got {self.accel_lowpass_order!r}"
            )
        if not isinstance(self.rest, RestBiasSettings):
            raise ConfigError(f"MadgwickSettings.rest must be a RestBiasSettings, got {type(self.rest).__name__}")
        if not isinstance(self.schedule, GainScheduleSettings):
            raise ConfigError(
                f"MadgwickSettings.schedule must be a GainScheduleSettings, got {type(self.schedule).__name__}"
            )


# --- parameter block after P_FILTER --------------------------------------------
PM_BETA = 0
PM_ZETA = 1
PM_ZETA_SPIN = 2
PM_USE_MAG = 3
PM_HEADING_ONLY = 4
PM_BETA_HEADING = 5
PM_DISTORTION = 6
PM_ACC_TAU = 7
PM_ACC_ORDER = 8
PM_LARGE_TAU = 9
PM_LARGE_TAU_HEADING = 10
PM_BIAS_LIMIT = 11
PM_GNSS = 12
PM_VDOT_TAU = 13
PM_VEL_MAX_AGE = 14
PM_GNSS_FADE = 15
PM_NORM_TOL = 16
PM_NORM_MIN_WEIGHT = 17
PM_REST = 18  # rest detector block (rest.RP_LEN)
PM_ACC_ADAPT = PM_REST + RP_LEN  # adaptive low-pass: reference ratio ā/ω̄ (0 = off)
PM_ACC_TAU_MAX = PM_ACC_ADAPT + 1
PM_ACC_ADAPT_TAU = PM_ACC_ADAPT + 2
PM_LEN = PM_ACC_ADAPT + 3

# --- state block after S_FILTER --------------------------------------------------
FM_NAVLP = 0  # accelerometer low-pass in the estimated NED frame (prefilter.BW_LEN)
FM_REST = FM_NAVLP + BW_LEN  # rest detector (rest.REST_LEN)
FM_GNSS = FM_REST + REST_LEN  # GNSS acceleration compensation (gnss.GC_LEN)
FM_MAG_AGE = FM_GNSS + GC_LEN  # time since the magnetometer last corrected the heading, s
FM_VLP = FM_MAG_AGE + 1  # the subtracted GNSS acceleration, low-passed like the specific force (BW_LEN)
FM_ADAPT = FM_VLP + BW_LEN  # adaptive low-pass: ā, ω̄ and the averaged manoeuvre weight
FM_NAVLP2 = FM_ADAPT + 3  # adaptive low-pass: f̄ with the longest time constant (BW_LEN)
FM_VLP2 = FM_NAVLP2 + BW_LEN  # … and the GNSS acceleration with it (BW_LEN)
FM_LEN = FM_VLP2 + BW_LEN

#: the first GNSS v̇ this soon after a (re)initialisation re-aligns the estimate (TRIAD); a first fix
#: later than this meets an estimate that has converged, which one noisy sample would only disturb
REALIGN_WINDOW_S = 5.0
#: horizontal GNSS acceleration is rotated into body axes with the estimated heading: it is used
#: only while the magnetometer has corrected the heading within this many seconds
HEADING_HOLD_S = 60.0
_NEVER_S = 1e9
#: the adaptive low-pass takes slower rotation than this as this (rad/s): at rest ā/ω̄ is noise over noise
_ADAPT_MIN_RATE = 0.1


# --------------------------------------------------------------------------- objective functions


@kernel
def gravity_objective(q0, q1, q2, q3, dx, dy, dz):  # type: ignore[no-untyped-def]
    """f_g = C(q)ᵀ·[0,0,1] − d̂ for a measured body-frame down direction ``d̂ = −â`` (eq. (25))."""
    return (
        2.0 * (q1 * q3 - q0 * q2) - dx,
        2.0 * (q0 * q1 + q2 * q3) - dy,
        2.0 * (0.5 - q1 * q1 - q2 * q2) - dz,
    )


@kernel
def gravity_gradient(q0, q1, q2, q3, dx, dy, dz):  # type: ignore[no-untyped-def]
    """∇f = J_gᵀ f_g (eq. (20) with (25)–(26)): the gradient of ½‖f_g‖² over (w, x, y, z)."""
    f0, f1, f2 = gravity_objective(q0, q1, q2, q3, dx, dy, dz)
    # J_g rows: [−2y, 2z, −2w, 2x], [2x, 2w, 2z, 2y], [0, −4x, −4y, 0]   (eq. (26))
    return (
        -2.0 * q2 * f0 + 2.0 * q1 * f1,
        2.0 * q3 * f0 + 2.0 * q0 * f1 - 4.0 * q1 * f2,
        -2.0 * q0 * f0 + 2.0 * q3 * f1 - 4.0 * q2 * f2,
        2.0 * q1 * f0 + 2.0 * q2 * f1,
    )


@kernel
def field_objective(q0, q1, q2, q3, bx, bz, mx, my, mz):  # type: ignore[no-untyped-def]
    """f_b = C(q)ᵀ·[b_x, 0, b_z] − m̂ (eq. (29)); b in NED (b_z > 0: field dips downward)."""
    return (
        2.0 * bx * (0.5 - q2 * q2 - q3 * q3) + 2.0 * bz * (q1 * q3 - q0 * q2) - mx,
        2.0 * bx * (q1 * q2 - q0 * q3) + 2.0 * bz * (q0 * q1 + q2 * q3) - my,
        2.0 * bx * (q0 * q2 + q1 * q3) + 2.0 * bz * (0.5 - q1 * q1 - q2 * q2) - mz,
    )


@kernel
def field_gradient(q0, q1, q2, q3, bx, bz, mx, my, mz):  # type: ignore[no-untyped-def]
    """∇f = J_bᵀ f_b (eq. (20) with (29)–(30)).

    ``b_x`` and ``b_z`` are the reference components themselves — the C code's
    ``_2bx = √(h_x²+h_y²)`` used as 2·b_x is the factor-of-two error of the
    widely copied implementation (BROAD issue #1).
    """
    f0, f1, f2 = field_objective(q0, q1, q2, q3, bx, bz, mx, my, mz)
    # J_b (eq. (30)), rows d f_i / d(w, x, y, z):
    #   [−2bz·y,           2bz·z,            −4bx·y − 2bz·w,  −4bx·z + 2bz·x]
    #   [−2bx·z + 2bz·x,   2bx·y + 2bz·w,    2bx·x + 2bz·z,   −2bx·w + 2bz·y]
    #   [2bx·y,            2bx·z − 4bz·x,    2bx·w − 4bz·y,   2bx·x]
    return (
        -2.0 * bz * q2 * f0 + (-2.0 * bx * q3 + 2.0 * bz * q1) * f1 + 2.0 * bx * q2 * f2,
        2.0 * bz * q3 * f0 + (2.0 * bx * q2 + 2.0 * bz * q0) * f1 + (2.0 * bx * q3 - 4.0 * bz * q1) * f2,
        (-4.0 * bx * q2 - 2.0 * bz * q0) * f0 + (2.0 * bx * q1 + 2.0 * bz * q3) * f1
        + (2.0 * bx * q0 - 4.0 * bz * q2) * f2,
        (-4.0 * bx * q3 + 2.0 * bz * q1) * f0 + (-2.0 * bx * q0 + 2.0 * bz * q2) * f1 + 2.0 * bx * q1 * f2,
    )  # fmt: skip


# --------------------------------------------------------------------------- small kernels


@kernel
def _large_error_factor(theta, beta, tau, weight):  # type: ignore[no-untyped-def]
    """Gain multiplier ≥ 1 that turns the constant-rate step into θ/τ for errors θ > 2βτ.

    The normalised gradient corrects at 2β rad/s whatever the error; a large
    error (a bad start, a recovered disturbance) then takes minutes with a
    small β.  Above the crossover the correction becomes proportional, with
    time constant τ.  τ = 0 (or β = 0) keeps the report's behaviour.
    ``weight`` in [0, 1] scales the speed-up (0: the report's constant rate).
    Returns (multiplier, whether θ is beyond the crossover).
    """
    if tau <= 0.0 or beta <= 0.0:
        return 1.0, False
    k = theta / (2.0 * beta * tau)
    if k <= 1.0:
        return 1.0, False
    if weight < 1.0:
        k = 1.0 + weight * (k - 1.0)
    return k, True


@kernel(inline=True)
def _adaptive_blend(state, k, params, p, wx, wy, wz, dt, tau_acc, ratio):  # type: ignore[no-untyped-def]
    """The weight λ (0–1) of the long low-pass for this sample (``accel_lowpass_adapt_ratio``).

    The wanted time constant is τ·√(ā / (ratio·ω̄)), at least τ and at most
    ``accel_lowpass_max_s``; λ places it between the two, scaled by the averaged manoeuvre
    weight.  ``state[k]`` holds the averaged motion acceleration ā (m/s², updated after the
    low-pass), ``state[k+1]`` the averaged rotation rate ω̄ (rad/s, updated here; neither is
    updated at rest: ``dt`` = 0), ``state[k+2]`` the averaged manoeuvre weight (1 while
    ``lowpass_norm_tolerance`` is 0).
    """
    t_avg = params[p + PM_ACC_ADAPT_TAU]
    k_w = dt / t_avg if dt < t_avg else 1.0
    state[k + 1] += k_w * (math.sqrt(wx * wx + wy * wy + wz * wz) - state[k + 1])
    w_bar = state[k + 1] if state[k + 1] > _ADAPT_MIN_RATE else _ADAPT_MIN_RATE
    x = state[k] / (ratio * w_bar)
    tau_max = params[p + PM_ACC_TAU_MAX]
    if x <= 1.0 or tau_max <= tau_acc:
        return 0.0
    lam = (tau_acc * math.sqrt(x) - tau_acc) / (tau_max - tau_acc)
    return state[k + 2] * (lam if lam < 1.0 else 1.0)


@kernel(inline=True)
def _lowpass_pair(state, kf, kv, fn, fe, fd, an, ae, ad, gnss_lp, dt, tau, order2):  # type: ignore[no-untyped-def]
    """Advance the low-pass of f (at ``kf``) and, with ``gnss_lp``, of v̇ (at ``kv``); return both (v̄ = 0 without)."""
    if gnss_lp and state[kv + 3] == 0.0:
        # start as if fed zeros since f̄'s low-pass started: its phase (the time averaged so far,
        # or running) and its nominal step, so that both average over the same samples
        state[kv + 3] = state[kf + 3]
        state[kv + 7] = state[kf + 7]
    vn = ve = vd = 0.0
    if order2:
        fn, fe, fd = ned_butterworth_step(state, kf, fn, fe, fd, dt, tau)
        if gnss_lp:
            vn, ve, vd = ned_butterworth_step(state, kv, an, ae, ad, dt, tau)
    else:
        fn, fe, fd = vector_lowpass_step(state, kf, fn, fe, fd, dt, tau)
        if gnss_lp:
            vn, ve, vd = vector_lowpass_step(state, kv, an, ae, ad, dt, tau)
    return fn, fe, fd, vn, ve, vd


@kernel(inline=True)
def _long_lowpass_blend(state, f, params, p, fr0, fr1, fr2, an, ae, ad, gnss_lp, dt, lam,
                        fn, fe, fd, vn, ve, vd):  # type: ignore[no-untyped-def]  # fmt: skip
    """Advance the long low-passes (τ = ``accel_lowpass_max_s``) of f and v̇; return both blends, λ of the long."""
    g0, g1, g2, h0, h1, h2 = _lowpass_pair(
        state, f + FM_NAVLP2, f + FM_VLP2, fr0, fr1, fr2, an, ae, ad, gnss_lp, dt,
        params[p + PM_ACC_TAU_MAX], params[p + PM_ACC_ORDER] > 1.0,
    )  # fmt: skip
    ntol = params[p + PM_NORM_TOL]
    if ntol > 0.0 and lam > 0.0:
        # the long average is used only as far as its own norm says it is gravity (a sustained
        # acceleration stays in it longer than in the short one)
        ref = math.sqrt(h0 * h0 + h1 * h1 + (h2 - G_M_S2) * (h2 - G_M_S2)) if gnss_lp else G_M_S2
        wl = 1.0 - abs(math.sqrt(g0 * g0 + g1 * g1 + g2 * g2) / ref - 1.0) / ntol
        lam = lam * wl if wl > 0.0 else 0.0
    if gnss_lp:
        vn, ve, vd = vn + lam * (h0 - vn), ve + lam * (h1 - ve), vd + lam * (h2 - vd)
    return fn + lam * (g0 - fn), fe + lam * (g1 - fe), fd + lam * (g2 - fd), vn, ve, vd


@kernel
def _reset_internal(state, k):  # type: ignore[no-untyped-def]
    """Reset the filter-specific block at ``state[k:k + FM_LEN]`` (on (re)initialisation)."""
    nav_lowpass_reset(state, k + FM_NAVLP)
    nav_lowpass_reset(state, k + FM_NAVLP + LP_LEN)
    rest_reset(state, k + FM_REST)
    gnss_compensation_reset(state, k + FM_GNSS)
    state[k + FM_MAG_AGE] = _NEVER_S
    nav_lowpass_reset(state, k + FM_VLP)
    nav_lowpass_reset(state, k + FM_VLP + LP_LEN)
    state[k + FM_ADAPT] = 0.0
    state[k + FM_ADAPT + 1] = 0.0
    state[k + FM_ADAPT + 2] = 1.0
    for base in (FM_NAVLP2, FM_VLP2):
        nav_lowpass_reset(state, k + base)
        nav_lowpass_reset(state, k + base + LP_LEN)


# --------------------------------------------------------------------------- the step


@kernel
def step(state, params, row, out):  # type: ignore[no-untyped-def]
    """One Madgwick update of ``state`` by one input ``row``; writes ``out``."""
    dt = begin_step(state, params, row, out)
    if dt < 0.0:
        if int(out[OUT_FLAGS]) & FLAG_STARTUP:  # (re)initialised on this sample
            _reset_internal(state, S_FILTER)
        return
    f = S_FILTER
    p = P_FILTER
    beta = params[p + PM_BETA]
    zeta = params[p + PM_ZETA]
    limit = params[p + PM_BIAS_LIMIT]

    ax, ay, az = row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2]
    mx, my, mz = row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2]
    accel_ok = vector_ok(ax, ay, az)
    mag_ok = params[p + PM_USE_MAG] > 0.0 and vector_ok(mx, my, mz)

    # ---- gyro bias at rest (shared detector, optional) ------------------------
    at_rest = rest_step(
        state, f + FM_REST, state, S_BIAS, row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2],
        ax, ay, az, accel_ok, row[IN_VEL], row[IN_VEL + 1], row[IN_VEL + 2], dt, params, p + PM_REST,
    )  # fmt: skip

    wx = row[IN_GYRO] - state[S_BIAS]
    wy = row[IN_GYRO + 1] - state[S_BIAS + 1]
    wz = row[IN_GYRO + 2] - state[S_BIAS + 2]

    # ---- gyro propagation with the compensated rate (eq. (49), (11)–(13)) ----
    integrate_body_rate(state, S_Q, wx, wy, wz, dt)  # exact: q ⊗ exp(ω_c dt/2), stays unit
    # Predict first, then correct at the propagated attitude: the gradient then
    # compares the sample's measurements with the attitude at the same instant
    # (the report evaluates both terms at q_{t−1}; the difference is O(dt²)).
    q0, q1, q2, q3 = state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3]

    boost, w_a, w_m = schedule_step(
        state[S_SCHED : S_SCHED + _g.GS_LEN], params[P_SCHED : P_SCHED + _g.GP_LEN],
        q0, q1, q2, q3, wx, wy, wz, ax, ay, az, accel_ok, mx, my, mz, mag_ok, dt,
    )  # fmt: skip
    startup = boost > 1.0
    if startup:
        add_flag(out, FLAG_STARTUP)

    # ---- accelerometer: GNSS acceleration removed, low-passed in a quasi-inertial frame ----
    an = ae = ad = 0.0
    if params[p + PM_GNSS] > 0.0:
        # f − v̇ (003, "Влияние ускорений"): what is left is −g whatever the vehicle does.
        fresh = gnss_compensation_fresh(state, f + FM_GNSS)
        an, ae, ad = gnss_compensation_step(
            state, f + FM_GNSS, row[IN_VEL], row[IN_VEL + 1], row[IN_VEL + 2], dt,
            params[p + PM_VDOT_TAU], params[p + PM_VEL_MAX_AGE], params[p + PM_GNSS_FADE],
        )  # fmt: skip
        if (
            fresh and state[S_SCHED + _g.GS_T] < REALIGN_WINDOW_S and accel_ok and mag_ok
            and not gnss_compensation_fresh(state, f + FM_GNSS)
        ):
            # The first v̇ soon after the (re)initialisation, which took the accelerometer for gravity: in a
            # manoeuvre that is tens of degrees off, and converging from there with f − v̇ in the
            # estimate's (wrong) frame can diverge (the error it leaves, (E − I)·v̇, exceeds g when
            # braking hard). Re-align at once instead: TRIAD with f ↔ v̇ − g and m ↔ the reference
            # field (the learned dip); the low-passes restart in the new frame.
            dip = state[S_SCHED + _g.GS_MAG_DIP]
            if triad_attitude(
                ax, ay, az, mx, my, mz, an, ae, ad - G_M_S2, math.cos(dip), 0.0, math.sin(dip), state, S_Q
            ):
                q0, q1, q2, q3 = state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3]
                for i in range(BW_LEN):
                    state[f + FM_NAVLP + i] = 0.0
                    state[f + FM_VLP + i] = 0.0
                    state[f + FM_NAVLP2 + i] = 0.0
                    state[f + FM_VLP2 + i] = 0.0
                state[f + FM_MAG_AGE] = 0.0  # the heading is the magnetometer's now
        if state[f + FM_MAG_AGE] > HEADING_HOLD_S:
            an = ae = 0.0  # the horizontal part needs a heading reference to be put in body axes
    ux, uy, uz = ax, ay, az
    tau_acc = params[p + PM_ACC_TAU]
    adapt = params[p + PM_ACC_ADAPT] if tau_acc > 0.0 else 0.0
    lam = 0.0
    if adapt > 0.0:
        lam = _adaptive_blend(state, f + FM_ADAPT, params, p, wx, wy, wz, 0.0 if at_rest else dt, tau_acc, adapt)
    ntol = params[p + PM_NORM_TOL]
    # f̄ and the GNSS acceleration v̄ are low-passed separately and subtracted afterwards: f̄ is
    # kept in the estimate's NED frame (each correction rotates its state, below) while v̇ is
    # in the earth's; subtracted first, a correction would turn the subtracted v̇ too, which
    # after a re-initialisation mid-manoeuvre (corrections of tens of degrees) leaves
    # ‖v̄‖·angle of acceleration in f̄. Without GNSS v̄ = 0.
    vn_lp = ve_lp = vd_lp = 0.0
    fn = fe = fd = 0.0
    if accel_ok and (tau_acc > 0.0 or an != 0.0 or ae != 0.0 or ad != 0.0):
        fn, fe, fd = body_to_ned(q0, q1, q2, q3, ax, ay, az)
        # Every valid sample enters the average (leaving out the large ones
        # would bias it: motion accelerations are zero-mean only as a whole).
        if tau_acc > 0.0:
            gnss_lp = an != 0.0 or ae != 0.0 or ad != 0.0 or state[f + FM_VLP + 3] != 0.0
            fr0, fr1, fr2 = fn, fe, fd
            fn, fe, fd, vn_lp, ve_lp, vd_lp = _lowpass_pair(
                state, f + FM_NAVLP, f + FM_VLP, fn, fe, fd, an, ae, ad, gnss_lp, dt, tau_acc,
                params[p + PM_ACC_ORDER] > 1.0,
            )  # fmt: skip
            if adapt > 0.0:
                # the long low-pass runs beside it, blended in by λ: each is a fixed filter (a Butterworth
                # whose τ changes under it does not keep a constant input's norm, which ‖f̄‖ must)
                fn, fe, fd, vn_lp, ve_lp, vd_lp = _long_lowpass_blend(
                    state, f, params, p, fr0, fr1, fr2, an, ae, ad, gnss_lp, dt, lam, fn, fe, fd, vn_lp, ve_lp, vd_lp
                )
                if not at_rest:  # the motion acceleration the low-pass removed, averaged
                    d = math.sqrt((fr0 - fn) ** 2 + (fr1 - fe) ** 2 + (fr2 - fd) ** 2)
                    k_a = dt / params[p + PM_ACC_ADAPT_TAU] if dt < params[p + PM_ACC_ADAPT_TAU] else 1.0
                    state[f + FM_ADAPT] += k_a * (d - state[f + FM_ADAPT])
        else:
            vn_lp, ve_lp, vd_lp = an, ae, ad  # no low-pass
        ux, uy, uz = ned_to_body(q0, q1, q2, q3, fn - vn_lp, fe - ve_lp, fd - vd_lp)

    # ---- gradients -----------------------------------------------------------
    sg0 = sg1 = sg2 = sg3 = 0.0  # gravity part (unnormalised J_gᵀ f_g)
    ng = 0.0
    theta_g = 0.0
    norm_w = 1.0  # trust in the gravity direction from the norm of f̄ (manoeuvre detection)
    large_w = 1.0  # … and in the large-error speed-up
    tau_large = params[p + PM_LARGE_TAU]
    # the error angles feed only _large_error_factor, which ignores them while its τ is 0:
    # their acos/atan2 are skipped then (same results)
    want_theta_m = tau_large > 0.0 or params[p + PM_LARGE_TAU_HEADING] > 0.0
    if accel_ok and w_a > 0.0 and vector_ok(ux, uy, uz):
        n = math.sqrt(ux * ux + uy * uy + uz * uz)
        inv_n = 1.0 / n  # one division, three multiplications
        # Specific force points up at rest: measured down = −â.
        sg0, sg1, sg2, sg3 = gravity_gradient(q0, q1, q2, q3, -ux * inv_n, -uy * inv_n, -uz * inv_n)
        ng = math.sqrt(sg0 * sg0 + sg1 * sg1 + sg2 * sg2 + sg3 * sg3)
        if tau_large > 0.0:
            # tilt error: angle between the predicted and the measured down
            cos_t = -(2.0 * (q1 * q3 - q0 * q2) * ux + 2.0 * (q0 * q1 + q2 * q3) * uy
                      + (1.0 - 2.0 * (q1 * q1 + q2 * q2)) * uz) * inv_n  # fmt: skip
            theta_g = math.acos(min(max(cos_t, -1.0), 1.0))
        if ntol > 0.0 and not startup:
            # ‖f̄‖ ≠ g: the vehicle is accelerating, and f̄ is not the vertical (a multirotor's
            # accelerometer reads thrust and rotor drag in sustained tilted acceleration)
            ratio = n / G_M_S2
            if vn_lp != 0.0 or ve_lp != 0.0 or vd_lp != 0.0:
                # With the GNSS acceleration v̄: the low-passed specific force is v̄ − g, so its norm
                # must be ‖v̄ − g‖. Both norms are blind to the attitude, unlike ‖f̄ − v̄‖, which a
                # tilt error E makes ‖E(v̄ − g) − v̄‖ ≠ g: that would hold the gain low exactly while
                # a re-initialised estimate is wrong in a manoeuvre.
                ref = math.sqrt(vn_lp * vn_lp + ve_lp * ve_lp + (vd_lp - G_M_S2) * (vd_lp - G_M_S2))
                ratio = math.sqrt(fn * fn + fe * fe + fd * fd) / ref
            large_w = 1.0 - abs(ratio - 1.0) / ntol
            large_w = large_w if large_w > 0.0 else 0.0
            if adapt > 0.0:  # averaged like ā and ω̄: a τ that jumps every sample upsets the recursion
                k_w = dt / params[p + PM_ACC_ADAPT_TAU] if dt < params[p + PM_ACC_ADAPT_TAU] else 1.0
                state[f + FM_ADAPT + 2] += k_w * (large_w - state[f + FM_ADAPT + 2])
            norm_w = max(large_w, params[p + PM_NORM_MIN_WEIGHT])
    sm0 = sm1 = sm2 = sm3 = 0.0  # magnetic part (unnormalised J_bᵀ f_b)
    nm = 0.0
    theta_m = 0.0
    heading_only = params[p + PM_HEADING_ONLY] > 0.0
    if mag_ok and w_m > 0.0:
        inv_n = 1.0 / math.sqrt(mx * mx + my * my + mz * mz)
        mnx, mny, mnz = mx * inv_n, my * inv_n, mz * inv_n
        hx, hy, hz = body_to_ned(q0, q1, q2, q3, mnx, mny, mnz)  # eq. (45)
        hh = math.sqrt(hx * hx + hy * hy)
        if hh > 1e-6:
            if want_theta_m:
                theta_m = math.atan2(abs(hy), hx)  # heading error
            if heading_only:
                # Objective on the horizontal field only, b = [1, 0, 0]: its
                # gradient is a rotation about the vertical (heading) alone.
                bx, bz = 1.0, 0.0
                mnx, mny, mnz = ned_to_body(q0, q1, q2, q3, hx / hh, hy / hh, 0.0)
            elif params[p + PM_DISTORTION] > 0.0:
                bx, bz = hh, hz  # eq. (46): b = [√(h_x²+h_y²), 0, h_z]
            else:
                dip = state[S_SCHED + _g.GS_MAG_DIP]
                bx, bz = math.cos(dip), math.sin(dip)
            sm0, sm1, sm2, sm3 = field_gradient(q0, q1, q2, q3, bx, bz, mnx, mny, mnz)
            nm = math.sqrt(sm0 * sm0 + sm1 * sm1 + sm2 * sm2 + sm3 * sm3)
    w_a_used = w_a * norm_w if ng > 1e-12 else 0.0
    w_m_used = w_m if nm > 1e-12 else 0.0
    state[f + FM_MAG_AGE] = 0.0 if w_m_used > 0.0 else state[f + FM_MAG_AGE] + dt

    # ---- the correction direction q̇_ε (eq. (44)) and step (eq. (42)–(43)) ----
    e0 = e1 = e2 = e3 = 0.0  # error direction, unit norm per trusted sensor (for ζ)
    c0 = c1 = c2 = c3 = 0.0  # the applied correction rate β·q̇_ε
    gain = 0.0
    large = False  # an error beyond the large-error crossover (heading mode: the tilt's): not a drift
    if heading_only:
        beta_h = params[p + PM_BETA_HEADING]
        if w_a_used > 0.0:
            k = w_a_used / ng
            e0, e1, e2, e3 = k * sg0, k * sg1, k * sg2, k * sg3
            lf, large = _large_error_factor(theta_g, beta, tau_large, large_w)
            kb = beta * boost * lf
            c0, c1, c2, c3 = kb * e0, kb * e1, kb * e2, kb * e3
            gain = beta * boost * w_a_used
        if w_m_used > 0.0:
            k = w_m_used / nm
            e0 += k * sm0
            e1 += k * sm1
            e2 += k * sm2
            e3 += k * sm3
            lf, _large_h = _large_error_factor(theta_m, beta_h, params[p + PM_LARGE_TAU_HEADING], 1.0)
            kb = beta_h * boost * k * lf
            c0 += kb * sm0
            c1 += kb * sm1
            c2 += kb * sm2
            c3 += kb * sm3
    else:
        # Stacked objective (eq. (31)–(32)); rejected parts are left out.
        t0 = w_a_used * sg0 + w_m_used * sm0
        t1 = w_a_used * sg1 + w_m_used * sm1
        t2 = w_a_used * sg2 + w_m_used * sm2
        t3 = w_a_used * sg3 + w_m_used * sm3
        nt = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3)
        if nt > 1e-12:
            w = max(w_a_used, w_m_used)
            k = w / nt  # eq. (44), scaled by the trust in the remaining sensors
            e0, e1, e2, e3 = k * t0, k * t1, k * t2, k * t3
            lf, large = _large_error_factor(max(theta_g, theta_m * (w_m_used > 0.0)), beta, tau_large, large_w)
            kb = beta * boost * lf
            c0, c1, c2, c3 = kb * e0, kb * e1, kb * e2, kb * e3
            gain = beta * boost * w

    # ---- gyro bias drift compensation (eq. (47)–(48)), not while converging --
    # (start-up boost, or an error beyond the large-error crossover: neither is a drift)
    spin_limit = params[p + PM_ZETA_SPIN]
    if spin_limit > 0.0 and wx * wx + wy * wy + wz * wz > spin_limit * spin_limit:
        zeta = 0.0  # INAV: no bias learning while turning fast (scale errors look like bias)
    if zeta > 0.0 and not startup and not large:
        # ω_ε = 2 q* ⊗ q̇_ε (eq. (47)); its scalar part is the radial component, dropped.
        state[S_BIAS] += zeta * 2.0 * (q0 * e1 - q1 * e0 - q2 * e3 + q3 * e2) * dt  # eq. (48)
        state[S_BIAS + 1] += zeta * 2.0 * (q0 * e2 + q1 * e3 - q2 * e0 - q3 * e1) * dt
        state[S_BIAS + 2] += zeta * 2.0 * (q0 * e3 - q1 * e2 + q2 * e1 - q3 * e0) * dt
    if limit > 0.0:
        for i in range(3):
            state[S_BIAS + i] = min(max(state[S_BIAS + i], -limit), limit)

    # ---- eq. (42)–(43): q_est = q_ω − β q̇_ε Δt ---------------------------------
    n0, n1, n2, n3 = q0 - c0 * dt, q1 - c1 * dt, q2 - c2 * dt, q3 - c3 * dt
    if tau_acc > 0.0:
        # the correction, a rotation of the estimated NED frame r = 2·vec(q_new ⊗ q*), turns f̄_NED too
        nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
        _r0, r1, r2, r3 = quat_multiply(n0, n1, n2, n3, q0, -q1, -q2, -q3)
        r1, r2, r3 = r1 / nn, r2 / nn, r3 / nn
        nav_lowpass_rotate(state, f + FM_NAVLP, 2.0 * r1, 2.0 * r2, 2.0 * r3)
        nav_lowpass_rotate(state, f + FM_NAVLP + LP_LEN, 2.0 * r1, 2.0 * r2, 2.0 * r3)
        if adapt > 0.0:
            nav_lowpass_rotate(state, f + FM_NAVLP2, 2.0 * r1, 2.0 * r2, 2.0 * r3)
            nav_lowpass_rotate(state, f + FM_NAVLP2 + LP_LEN, 2.0 * r1, 2.0 * r2, 2.0 * r3)
    state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3] = n0, n1, n2, n3
    finish_step(state, out, gain, w_a * norm_w, w_m if mag_ok else 0.0)


# --------------------------------------------------------------------------- class


class Madgwick(AttitudeFilter):
    """Madgwick's gradient-descent filter; see the module docstring and ``docs/filters/madgwick.md``."""

    name: ClassVar[str] = "madgwick"
    settings_type: ClassVar[type[FilterSettings]] = MadgwickSettings
    step: ClassVar[Any] = step
    internal_len: ClassVar[int] = FM_LEN

    @classmethod
    def filter_params(cls, settings: Any) -> np.ndarray:
        s: MadgwickSettings = settings
        p = np.zeros(PM_LEN)
        p[PM_BETA] = s.beta_rad_s
        p[PM_ZETA] = s.zeta_rad_s
        p[PM_USE_MAG] = 1.0 if s.use_magnetometer else 0.0
        p[PM_HEADING_ONLY] = 1.0 if s.mag_correction == "heading" else 0.0
        p[PM_BETA_HEADING] = s.beta_rad_s if s.beta_heading_rad_s is None else s.beta_heading_rad_s
        p[PM_DISTORTION] = 1.0 if s.distortion_compensation else 0.0
        p[PM_ACC_TAU] = s.accel_lowpass_s
        p[PM_BIAS_LIMIT] = s.bias_limit_rad_s
        p[PM_ACC_ORDER] = s.accel_lowpass_order
        p[PM_LARGE_TAU] = s.large_error_tau_s
        p[PM_LARGE_TAU_HEADING] = s.large_heading_error_tau_s
        p[PM_ZETA_SPIN] = s.zeta_spin_limit_rad_s
        p[PM_GNSS] = 1.0 if s.gnss_acceleration else 0.0
        p[PM_VDOT_TAU] = s.velocity_tau_s
        p[PM_VEL_MAX_AGE] = s.velocity_max_age_s
        p[PM_GNSS_FADE] = s.gnss_fade_s
        p[PM_NORM_TOL] = s.lowpass_norm_tolerance
        p[PM_NORM_MIN_WEIGHT] = s.lowpass_norm_min_weight
        p[PM_REST : PM_REST + RP_LEN] = s.rest.to_params()
        p[PM_ACC_ADAPT] = s.accel_lowpass_adapt_ratio
        p[PM_ACC_TAU_MAX] = s.accel_lowpass_max_s
        p[PM_ACC_ADAPT_TAU] = s.accel_lowpass_adapt_avg_s
        return p

    def initial_internal(self) -> np.ndarray:
        s = np.zeros(FM_LEN)
        pure_python(_reset_internal)(s, 0)  # interpreted: no second compiled copy for Python's int argument
        return s
