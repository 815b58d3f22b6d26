r"""Velocity-aided error-state Kalman filter: attitude, NED velocity and gyro bias.

The autopilot's way of using GNSS for attitude (ArduPilot's EKF3, PX4's
EKF2; Solà, "Quaternion kinematics for the error-state Kalman filter", 2017,
§5–7): the gyro propagates the attitude, the specific force rotated into NED
and integrated with gravity propagates a velocity, and each GNSS velocity fix
corrects both through their covariance.  A tilt error δθ turns part of
gravity into a horizontal acceleration, δv̇ = −[f_NED]× δθ, so after a few
fixes the velocity residual *is* the tilt error, measured over the fix
interval without differentiating the velocity; while the vehicle accelerates
horizontally the same residual measures the heading too.  This replaces the
differentiated, low-passed v̇ of :mod:`mavahrs.filters.gnss` (a derivative of
a 10 Hz signal, whose noise and delay set the accuracy of the compensated
gravity reference) with the integral form of the 003 tutorial's acceleration
compensation: the gyro-platform's levelling equation ``v̇ = C f + g`` (003,
"Влияние ускорений") closed through a Kalman gain instead of a fixed one.

Nominal state: ``q_body_to_ned`` (common prefix), ``v_ned`` (m/s), gyro bias
``b`` (common prefix, rad/s).  Error state (9): δθ (rotation in NED,
``q_true = exp(δθ/2) ⊗ q``), δv, δb.  Per IMU sample, over dt:

* q ← q ⊗ exp((ω − b)·dt/2);  v ← v + (C f + g)·dt  (Madgwick 2010 eq. (11)
  solved exactly; 003's velocity equation);
* P ← Φ P Φᵀ + Q·dt with Φ = I + F·dt,  F: δθ̇ = −C δb,  δv̇ = −[C f]× δθ
  (Solà eq. 270, global error);
* a velocity fix (``IN_VEL``, any of its components; a NaN component — the
  vertical from GPS_RAW_INT — is not fused): innovation against the INS
  velocity *at the fix's own time* (``IN_VEL_AGE``, plus the IMU data's delay
  ``sensor_delay_s``), read from a short history, one scalar update per
  component with a χ² gate;
* the magnetometer, at most ``mag_rate_hz`` and only when the shared gain
  schedule trusts it (norm and dip near the reference): one scalar update of
  the horizontal field's angle from magnetic north, H = [m_D/m_H, 0, −1, 0…]
  (a tilt error about north moves the horizontal projection by m_D/m_H
  times as much), gated; while velocity-aided (and the tilt known to its
  initial σ) the tilt is a *considered* state there (Schmidt 1966: in H, so
  its variance enters the innovation's and the heading's correlation with
  it is kept, but it is never corrected by the magnetometer), so that the
  heading variance does not shrink below what the tilt's uncertainty lets a
  magnetometer tell;
* without velocity aiding (no fix yet, or none for ``aiding_timeout_s``), the
  accelerometer's direction as a gravity measurement, its noise scaled by
  the schedule's accelerometer trust: the filter is then an accelerometer +
  magnetometer AHRS like the others, with a zero-velocity pseudo-measurement
  and, on a multirotor (``drag_coefficient_1_s``), the rotor-drag
  measurement: the specific force across the thrust axis = −k × the
  body-frame velocity (Leishman et al. 2014), which makes the velocity, hence
  the tilt, observable without GNSS (:mod:`mavahrs.filters.best` says where
  ``best`` uses it).

Each update's δx is injected at once (q ← exp(δθ/2) ⊗ q, v += δv, b += δb)
and the error state returns to zero.  The output is the attitude advanced by
``sensor_delay_s`` with the current rate, q ⊗ exp(ω·τ/2): an autopilot's
IMU messages carry low-passed rates (ArduPilot: INS_GYRO_FILTER, a 20 Hz
second-order filter, ≈ 11 ms of delay), so the integrated attitude trails the
vehicle by that much; the state itself is not advanced.  On an autopilot's
stream (``output_half_step``) the advance is ``sensor_delay_s`` − dt/2: the
step above applies each sample's rate over the interval before it, which
leads a point-sampled rate by ½ E[dt²] / E[dt].  Details and the
measured choices: ``docs/filters/eskf.md``.
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
from mavahrs.filters.gains import G_M_S2, GainScheduleSettings, schedule_step
from mavahrs.filters.initial import align_tilt_to_force
from mavahrs.filters.jit import kernel
from mavahrs.filters.kinematics import integrate_body_rate, quat_multiply
from mavahrs.filters.layout import (
    FLAG_ACCEL_INVALID,
    FLAG_HEADING_ALIGNED,
    FLAG_MAG_INVALID,
    FLAG_STARTUP,
    FLAG_VELOCITY_AIDED,
    IN_ACCEL,
    IN_CURRENT,
    IN_GYRO,
    IN_MAG,
    IN_POS,
    IN_VEL,
    IN_VEL_AGE,
    OUT_ACCEL_WEIGHT,
    OUT_FLAGS,
    OUT_HEADING_SIGMA,
    OUT_Q,
)
from mavahrs.filters.magfield import (
    MAG_DISTURBED,
    MAG_TRUSTED,
    MF_HEAD_SIGMA,
    MF_LEN,
    MF_P,
    MF_STEP_T,
    MF_STEPS,
    MF_T,
    MF_TO_HVAR,
    MF_TRUST,
    MF_X,
    MP_B0,
    MP_HFACTOR,
    MP_LEN,
    MagFieldSettings,
    export_model,
    import_model,
    mag_model_reset,
    mag_model_summary,
    mag_model_update,
    mag_ref_rotate,
    mag_refs_drop,
    mag_status,
    magfield_params,
)
from mavahrs.filters.magfield import (
    NX as MF_NX,
)
from mavahrs.filters.prefilter import (
    BW_LEN,
    LP_LEN,
    lowpass_coefficient,
    nav_lowpass_rotate,
    ned_butterworth_step,
)
from mavahrs.filters.rest import REST_LEN, RP_LEN, RestBiasSettings, rest_reset, rest_step

__all__ = [
    "EskfSettings", "Eskf", "step", "eskf_aided", "eskf_reopen_attitude", "HISTORY_LEN", "DELAY_PARAM", "DRAG_PARAM",
    "MULTIROTOR_DRAG_1_S", "MULTIROTOR_AXIS_SIGMA_RAD", "thrust_axis_of", "declination_of", "mag_delay_of", "mag_noise_of",
    "heading_walk_of",
    "START_DONE_STATE", "gyro_scale_of", "accel_bias_of", "ACCEL_BIAS_STATE", "slow_force_density_of",
    "OUTPUT_HALF_STEP_MAX_S",
]  # fmt: skip

N = 21  # error-state size: δθ (0–2), δv (3–5), δb (6–8), δα (9–10: the thrust axis, see thrust_axis_sigma_rad),
#        δD (11: the declination's error against the WMM, see declination_sigma_rad), δp (12–14: the GNSS position),
#        δs (15–17: the gyro's scale-factor errors, see gyro_scale_state_sigma), δb_a (18–20: the accelerometer's
#        bias, body frame, see accel_bias_sigma_m_s2)
_I_DECL = 11  # index of the declination error in the error state
_I_POS = 12  # index of the position error (3) in the error state
_I_SCALE = 15  # index of the gyro scale-factor errors (3) in the error state
_I_ABIAS = 18  # index of the accelerometer-bias errors (3, body frame) in the error state
#: rotor-drag coefficient of a multirotor, 1/s (see ``EskfSettings.drag_coefficient_1_s``)
MULTIROTOR_DRAG_1_S = 0.5
#: prior 1-σ of the thrust-axis states (a raw IMU declared a multirotor; ``EskfSettings.thrust_axis_sigma_rad``):
#: a start in forward flight puts the first mean specific force ≈ atan(k·v/g) ≈ 10° off the axis at 4 m/s
MULTIROTOR_AXIS_SIGMA_RAD = math.radians(15.0)
#: s: the longest step whose half the output is moved back by (``EskfSettings.output_half_step``): a longer gap is
#: not a sampling interval the rate stood for (the filters re-initialise only beyond ``max_gap_s``)
OUTPUT_HALF_STEP_MAX_S = 0.05
HISTORY_LEN = 192  # INS velocity history (entries of t, vn, ve, vd): 0.48 s at 400 Hz

#: variances the attitude covariance is re-opened to after persistent rejection, rad²
_REOPEN_TILT = (math.pi / 4.0) ** 2
_REOPEN_HEADING = (math.pi / 2.0) ** 2
#: initial velocity variance of a multirotor (it may start in flight), (m/s)²
_P0_VEL_FLYING = 5.0**2
#: … and when velocity aiding (re)starts
_RESTART_TILT = math.radians(20.0) ** 2
_RESTART_HEADING = math.radians(45.0) ** 2
#: the heading variance at or above which it is unknown (magfield.HEADING_UNKNOWN_SIGMA_DEG), rad²
_UNKNOWN_HEADING_VAR = math.radians(30.0) ** 2
#: the magnetometer model's field-per-ampere variance below which it is known, (µT/A)²
_KNOWN_MOTOR_VAR = 0.06**2
#: … or its own heading σ (the corrected reading's east uncertainty over F_H, magfield ``MF_HEAD_SIGMA``) at or
#: below which its corrected reading may reset an unknown heading, rad (a model learnt in this flight
#: by its pair updates: 8–9° on firmware_sim mag_anomaly 3 s after take-off, the offset's prior 3 µT of it)
_RESET_MODEL_SIGMA_RAD = math.radians(10.0)
#: the model's motor field, µT², at or above which its corrected reading may reset an unknown heading
_MIN_MOTOR_FIELD_UT2 = 3.0**2
#: how long the corrected reading must have fitted the WMM's norm and dip before it resets an unknown heading, s
_RESET_FIT_S = 0.2
#: how far the corrected reading's dip may be off the WMM's for a heading reset, rad
_FIT_DIP_RAD = math.radians(3.0)
#: yaw rate, rad/s, whose mean square shrinks the compass's learnt delay towards 0 (no turns: nothing learnt)
_LAG_RATE0_RAD_S = math.radians(10.0)

# filter parameters, offsets from P_FILTER
_Q_GYRO = 0  # gyro noise density², rad²/s
_Q_ACCEL = 1  # accelerometer noise density², (m/s²)²·s
_Q_BIAS = 2  # bias random walk², rad²/s³
_R_VEL_H = 3  # horizontal velocity noise², (m/s)²
_R_VEL_V = 4  # vertical velocity noise², (m/s)²
_R_HEADING = 5  # magnetic heading noise², rad²
_R_GRAVITY = 6  # gravity-direction noise (unaided), (m/s²)²
_GATE = 7  # χ gate (σ)
_AID_TIMEOUT = 8  # s
_DELAY = 9  # s
_MAG_PERIOD = 10  # s between magnetometer updates
_P0_TILT = 11  # initial tilt σ², rad²
_P0_HEADING = 12  # initial heading σ², rad²
_P0_BIAS = 13  # initial bias σ², (rad/s)²
_BIAS_LIMIT = 14  # rad/s per axis
_VEL_RESET = 15  # s of rejected velocity before the velocity is reset to the fix
_MAG_STALE = 16  # s: assumed age spread of a magnetometer reading (heading noise grows with the yaw rate)
_REJECT_RESET = 17  # s of rejected attitude measurements before the attitude covariance is re-opened
_VEL_GATE = 18  # χ gate of the velocity fixes (σ)
_NOISE_TAU = 19  # s: time constant of the measured sensor noise (0: fixed noise densities)
_R_ZV = 20  # zero-velocity pseudo-measurement noise² while not aided, (m/s)² (0: off)
_ZV_PERIOD = 21  # s between zero-velocity pseudo-measurements
_REALIGN_SIN = 22  # sin of the gravity innovation angle beyond which it is not fused as a small error
_REALIGN_S = 23  # s that large an innovation persists before the tilt is re-aligned
_GRAV_TAU = 24  # s: NED low-pass of the specific force used as the gravity measurement (0: raw)
_ADAPT_TAU = 25  # s: averaging time of the gravity innovation's mean square, the adaptive noise (0: off)
_R_MODEL_MAX = 26  # rad²: a reading whose model heading variance exceeds this gives no heading
_MIN_BODY = 27  # µT²: a learnt body field below this is not removed (the reading is used as it is)
_REOPEN_ON_STEP = 28  # 1: a disturbance re-opens the heading variance
_MAGF_P = 29  # the magnetometer model's parameters (:mod:`mavahrs.filters.magfield`, MP_LEN)
_DRAG_K = _MAGF_P + MP_LEN  # rotor-drag coefficient, 1/s (0: no drag measurement)
_R_DRAG = _DRAG_K + 1  # drag measurement noise², (m/s²)²
_THRUST_TAU = _DRAG_K + 2  # s: averaging time of the body-frame thrust-axis estimate
_R_REST_RATE = _DRAG_K + 3  # zero-rate measurement noise² at detected rest, (rad/s)² (0: off)
_R_REST_VEL = _DRAG_K + 4  # zero-velocity measurement noise² at detected rest, (m/s)²
_REST_P = _DRAG_K + 5  # the rest detector's parameters (:mod:`mavahrs.filters.rest`, RP_LEN)
_AXIS_P0 = _REST_P + RP_LEN  # initial variance of the thrust-axis states, rad² (0: the axis is a running mean)
_AXIS_Q = _AXIS_P0 + 1  # their random walk², rad²/s
_Q_SCALE = _AXIS_Q + 1  # gyro scale-factor error as rate-proportional noise: 2 σ_sf² τ, s (× ω² → rad²/s)
_Q_CROSS = _AXIS_Q + 2  # … cross-axis (misalignment) error: 2 σ_ma² τ, s
_DECL_P0 = _AXIS_Q + 3  # prior variance of the declination's error against the WMM, rad² (0: WMM exact)
_INIT_AVG = _DECL_P0 + 1  # s: the start window the specific force is averaged over (0: no check of the start)
_INIT_COS = _INIT_AVG + 1  # cos of the angle between that mean and the estimate's up beyond which the tilt re-aligns
_R_POS_H = _INIT_COS + 1  # horizontal GNSS position noise², m² (0: the position is not fused)
_R_POS_V = _INIT_COS + 2  # vertical position noise², m² (0: not fused)
_POS_GATE = _INIT_COS + 3  # χ gate of the position fixes (σ)
_Q_POS = _INIT_COS + 4  # position random walk², m²/s (the receiver's slow wander)
_Q_BIAS_AIDED = _INIT_COS + 5  # bias random walk² while velocity-aided, rad²/s³ (0: _Q_BIAS)
_MAG_DELAY = _INIT_COS + 6  # s: the magnetometer reading's delay behind the IMU stamps (the heading read is that old)
_MAG_LEARN_TAU = _MAG_DELAY + 1  # s: averaging time of the compass's learnt delay (0: ``_MAG_DELAY`` as set)
_REST_CHECK_VAR = _MAG_DELAY + 2  # (rad/s)²: a rest is checked and fused only on axes whose bias variance is within this (0: all)
_MAG_NOISE_TAU = _MAG_DELAY + 3  # s: averaging time of the compass's learnt noise (0: ``_R_HEADING`` as set)
_MAG_NOISE_MIN = _MAG_DELAY + 4  # rad²: the learnt per-reading heading noise is held at or above this …
_MAG_NOISE_MAX = _MAG_DELAY + 5  # rad²: … and at or below this
_SCALE_P0 = _MAG_DELAY + 6  # prior variance of each gyro axis's scale-factor error (0: not estimated)
_SCALE_Q = _MAG_DELAY + 7  # their random walk², 1/s
_SCALE_LIM = _MAG_DELAY + 8  # bound of each estimated scale-factor error (a fraction)
_DRAG_RESET = _MAG_DELAY + 9  # s of rejected drag measurements before the velocity's variance is re-opened (0: never)
_ABIAS_P0 = _MAG_DELAY + 10  # steady-state variance of each accelerometer-bias state, (m/s²)² (0: not estimated)
_ABIAS_TAU = _MAG_DELAY + 11  # s: their Gauss–Markov correlation time (0: constant)
_ABIAS_VIB = _MAG_DELAY + 12  # the accelerometer bias's variance per measured per-sample specific-force variance (c²)
_ABIAS_AIDED = _MAG_DELAY + 13  # 1: the accelerometer-bias states are estimated only while velocity-aided
_Q_SCALE_TILT = _MAG_DELAY + 14  # σ_sf² of the gyro's scale-factor error as the tilt's coherent process noise (0: off)
_SCALE_TILT_TAU = _MAG_DELAY + 15  # s: the memory of the angle turned that term accumulates over
_HWALK_TAU = _MAG_DELAY + 16  # s: averaging time of the heading's learnt extra random walk (0: off, :func:`_heading_walk_step`)
_HWALK_MAX = _MAG_DELAY + 17  # rad²/s: the largest extra heading random-walk density it may reach
_HWALK_WIN = _MAG_DELAY + 18  # s: the window the compass's heading innovations are averaged over for it
_DRAG_C = _MAG_DELAY + 19  # the body's quadratic drag coefficient, 1/m (0: the rotor drag's linear term alone)
_DRAG_NIS_TAU = _MAG_DELAY + 20  # s: averaging time of the drag innovations' excess over h P hᵀ (0: R as set)
_SLOW_BLOCK = _MAG_DELAY + 21  # s: block length of the specific force's slow-error estimate (0: off, ``slow_force_block_s``)
_SLOW_TAU = _MAG_DELAY + 22  # s: averaging time of its block-mean Hadamard variance
_HALF_STEP = _MAG_DELAY + 23  # 1: the output's advance is ``_DELAY`` less half the step (``output_half_step``)
_BOFF_LAG = _MAG_DELAY + 24  # s: the body-offset learner's pair interval (0: off, ``mag_body_offset_lag_s``)
_BOFF_MIN_TURN = _MAG_DELAY + 25  # its least eigenvalue of Σ (I − R)ᵀ(I − R) before the offset is used
_BOFF_RESID = _MAG_DELAY + 26  # the largest share of Σ yᵀy a used fit leaves unexplained (its residual over the pairs')
_BOFF_SIGMA = _MAG_DELAY + 27  # µT²: the largest variance of the fitted offset along its worst axis that is used
_REST_WOBBLE_VAR = _MAG_DELAY + 28  # (rad/s)²: variance of the mean rate across the vertical a hovering rest may hide (0: none)
_REST_HOVER_VIB = _MAG_DELAY + 29  # m/s²: a rest is a hovering one only where the accelerometer's vibration RMS exceeds this (0: not asked)
_REST_HOVER_SPEED = _MAG_DELAY + 30  # m/s: … and the horizontal speed is below this (0: not asked)
_MAG_REJ_SCALE = _MAG_DELAY + 31  # a reading the schedule rejects, its norm within tolerance: fused at σ × this (0: not)
_ABIAS_ACROSS = _MAG_DELAY + 32  # (m/s²)²: the accelerometer-bias states start across the thrust axis only, this variance (0: isotropic)
_ABIAS_SPEED = _MAG_DELAY + 33  # m/s: the accelerometer-bias states are estimated only below this horizontal speed (0: always)
#: (m/s²)²: the accelerometer's bias *considered* without states (``accel_bias_consider_sigma_m_s2``; 0: not)
_CONS_P0 = _MAG_DELAY + 34
#: s: the gyro-bias bound acts on an axis only once its estimate has been beyond it this long (0: at once)
_BIAS_HOLD = _MAG_DELAY + 35
#: (rad/s)²: the gyro bias's plausible range as a pseudo-measurement b = 0 of this variance (0: none)
_BPRIOR_VAR = _MAG_DELAY + 36
#: s: … fused on an axis only once its estimate has been beyond that σ this long (< 0: on every axis, always)
_BPRIOR_AFTER = _MAG_DELAY + 37
#: s: … its information spread over this long: R = σ² · this / dt per sample (0: σ² per sample)
_BPRIOR_SPREAD = _MAG_DELAY + 38
#: rad: the largest attitude correction one scalar update may make (``max_attitude_step_rad``; 0: unbounded)
_ATT_STEP = _MAG_DELAY + 39
#: s: … only this long after the attitude covariance was re-opened (``max_attitude_step_window_s``; 0: always)
_ATT_STEP_WIN = _MAG_DELAY + 40
_N_PARAMS = _MAG_DELAY + 41
#: offset of ``sensor_delay_s`` in the filter's own parameter block (for :meth:`Eskf.set_sensor_delay`)
DELAY_PARAM = _DELAY
#: offset of ``drag_coefficient_1_s`` in the filter's own parameter block
DRAG_PARAM = _DRAG_K
#: offset of ``drag_quadratic_1_m`` in the filter's own parameter block
DRAG_QUADRATIC_PARAM = _DRAG_C

# filter state, offsets from S_FILTER
_V = 0  # INS velocity, NED (3)
_P = 3  # covariance, row-major N×N
_CLK = _P + N * N  # time since (re)initialisation, s
_LAST_FIX = _CLK + 1  # clock time of the last fused velocity fix (−1: not aided)
_LAST_MAG = _CLK + 2  # clock time of the last magnetometer update
_VREJ = _CLK + 3  # how long every velocity fix has been rejected, s
_PREV_VEL = _CLK + 4  # the previous row's velocity (3): a held value is not a new fix
_PREV_MAG = _CLK + 7  # the previous row's magnetometer (3): a repeated reading is not a new one
_GREJ = _CLK + 10  # clock time since when every gravity / heading measurement was rejected (−1: none)
_PERIOD = _CLK + 11  # interval between the last two changes of the velocity, s (0: not known)
_VIB = _CLK + 12  # running mean of ½‖Δω‖², ½‖Δf‖² between samples (2): the sensors' noise now
_PREV_IMU = _CLK + 14  # the previous sample's gyro and specific force (6; NaN: none)
_HPOS = _CLK + 20  # next history slot
_HCOUNT = _CLK + 21  # filled history slots
_LAST_ZV = _CLK + 22  # clock time of the last zero-velocity pseudo-measurement
_DX = _CLK + 23  # accumulated error-state correction (N)
_PH = _DX + N  # scratch: P·hᵀ (N)
_H = _PH + N  # scratch: h (N)
_C = _H + N  # scratch: C_body_to_ned (9)
_M = _C + 9  # scratch: −[f_NED]× (9)
_A = _M + 9  # scratch: Φ·P (N×N)
_HIST = _A + N * N  # INS velocity history, HISTORY_LEN × (t, vn, ve, vd)
_BIG = _HIST + 4 * HISTORY_LEN  # clock time since when the gravity innovation has been large (−1: not)
_GLP = _BIG + 1  # NED Butterworth low-pass of the specific force (BW_LEN)
_GMS = _GLP + BW_LEN  # running mean square of the horizontal gravity innovation, (m/s²)²
_MAGF = _GMS + 1  # the magnetometer model (:mod:`mavahrs.filters.magfield`, MF_LEN)
_MSCR = _MAGF + MF_LEN  # scratch of the model: corrected field + heading variance (4), h (8), P·h (8)
_MSTEPS = _MSCR + 20  # the model's disturbance count last seen
_TAX = _MSTEPS + 1  # running mean of the drag-corrected specific force's direction, body (3): the thrust axis
_FSUM = _TAX + 3  # integral of the specific force (body, 3) and the time (1) since the last drag update
_REST = _FSUM + 4  # the rest detector (:mod:`mavahrs.filters.rest`, REST_LEN)
_RSCR = _REST + REST_LEN  # scratch of the detector's own bias follower (3; not used as the bias)
_LAST_REST = _RSCR + 3  # clock time of the last zero-rate / zero-velocity update at rest
_GW = _LAST_REST + 1  # the low-passed gravity measurement's trust, smoothed as the sample's (0 … 1)
_TREF = _GW + 1  # the body axis (0, 1, 2) the thrust axis's error basis is built from (states mode)
_DECL = _TREF + 1  # learnt declination correction: the field's azimuth in the filter's (WMM-magnetic) frame, rad
_START = _DECL + 1  # the start window: ∫ f_NED dt in the estimate's frame (3), the time (1)
_STARTED = _START + 4  # 1: the start window is over (or there is none)
_FIT_T = _STARTED + 1  # clock since when the model's corrected readings fit the WMM while the heading is unknown (0: not)
_POS = _FIT_T + 1  # INS position, NED from the GNSS origin (3), m
_POS_ON = _POS + 3  # 1: the horizontal position is started from a fix (0: not)
_POS_ON_V = _POS + 4  # 1: the vertical position is started from a fix (0: not)
_PREJ_T = _POS + 5  # clock time since when every position fix has been rejected (−1: none)
_PREV_POS = _POS + 6  # the previous row's position (3): a held value is not a new fix
_MLAG = _POS + 9  # the compass's learnt delay behind the IMU's attitude, s, and the running mean of r_D² in turns (2)
#: the compass's learnt noise (``mag_noise_tau_s``, :func:`_mag_noise_step`): ½⟨Δ₁ψ²⟩, ½⟨Δ₂ψ²⟩ (2); the last two
#: readings' heading innovations, carried to the current estimate (2); the clock time of the last (1); its
#: innovation's sensitivity to the tilt (δθ_N, δθ_E: 2); the process noise's share of the heading innovation
#: accumulated since the last reading and over the interval before (2)
_MNOISE = _MLAG + 2
_GSCALE = _MNOISE + 9  # the gyro's estimated scale-factor errors s (3): ω = (reading − bias) / (1 + s) per axis
_JS = _GSCALE + 3  # J = ∫ C diag(ω) dt and K = ∫ C dt, NED, one LP_LEN block per body axis (6 × 4; slot 3 unused)
_JLP = _JS + 6 * LP_LEN  # J and K low-passed as the gravity measurement is (6 Butterworth blocks, 6 × BW_LEN)
_JG = _JLP + 6 * BW_LEN  # J − LP[J], K − LP[K] (2 × 3 × 3, column per body axis): the low-passed tilt's
#                          sensitivity to δs and δb
_ASUM = _JG + 18  # the start window's ∫ f dt in the body frame (3) and its time (1): the thrust axis's prior
_DREJ = _ASUM + 4  # clock time since when every drag measurement has been rejected (−1: none)
_DSTAT = _DREJ + 1  # drag periods attempted, rejected (both components failed the gate), velocity re-openings (3)
_ABIAS = _DSTAT + 3  # the accelerometer's estimated bias, body frame (3), m/s²: f = reading − b_a
_CLP = _ABIAS + 3  # C_body_to_ned's columns low-passed as the gravity measurement is (3 Butterworth blocks, 3 × BW_LEN)
_RANG = _CLP + 3 * BW_LEN  # angle turned about each body axis, |ω_i| integrated with memory τ (3), rad: the tilt's
#                            scale-factor noise (:func:`_scale_noise_tilt`)
#: the heading's extra random-walk density learnt from the compass's innovations, rad²/s (:func:`_heading_walk_step`),
#: the running mean of those innovations' window means' normalised square ψ̄²/S̄ (a diagnostic: 1 when consistent),
#: the window's sums of ψ, (P hᵀ)_ψ, h P hᵀ and r (4), its readings (1), its start and last reading's clock time (2)
_HWALK = _RANG + 3
_DNIS = _HWALK + 9  # running mean of the drag innovations' y² − h P hᵀ, (m/s²)², and their count (2; ``_DRAG_NIS_TAU``)
#: the specific force's slow error (``slow_force_block_s``): this block's ∫ f_NED dt (3) and time (1) and samples (1),
#: the previous block's mean (3), blocks completed (1), the running mean of ‖f̄ₖ − 2f̄ₖ₋₁ + f̄ₖ₋₂‖²/18 (the Hadamard
#: variance per axis) and of the white noise's share of it (2), (m/s²)², the block mean before the previous (3)
_SLOW = _DNIS + 2
#: the body-offset learner (``mag_body_offset_lag_s``): the pair's earlier reading (3), its C_body_to_ned (9) and
#: clock time (1; 0: none), Σ (I − R)ᵀ(I − R) (6: xx, xy, xz, yy, yz, zz), Σ (I − R)ᵀ y (3), Σ yᵀy (1) and the pairs
#: (1), the offset (3) and 1 while it is valid (1)
_BOFF = _SLOW + 14
_BOFF_A = _BOFF + 13
_BOFF_B = _BOFF_A + 11
_REST_N = _BOFF_B + 4  # zero-rate updates fused since the detector's hovering rest began (``_rest_rate_update``)
_REST_VIB = _REST_N + 1  # the accelerometer's mean square deviation from the rest detector's low-pass, 1 s mean, (m/s²)²
_ABIAS_HELD = _REST_N + 2  # 1 while the accelerometer-bias states are only considered this step (above their speed)
#: the error state's sensitivity to a constant accelerometer bias the filter does not estimate (N × 3, row-major:
#: ∂δx/∂b_a; ``accel_bias_consider_sigma_m_s2``), a measurement's own sensitivity to it (3, scratch, 0 unless the
#: measurement reads the bias) and 1 while it is carried
_SENS = _REST_N + 3
_SENS_HB = _SENS + 3 * N
_SENS_ON = _SENS_HB + 3
#: how long each axis's gyro-bias estimate has been beyond the bound without a break (3) and beyond the prior's
#: σ (3), s (``bias_limit_hold_s``, ``bias_prior_sigma_rad_s``)
_BOUT = _SENS_ON + 1
_T_OPEN = _BOUT + 6  # clock time the attitude covariance was last re-opened (−1e9: not since the start)
_BNOW = _T_OPEN + 1  # the bound on one update's attitude correction in force this sample, rad (0: none)
_N_STATE = _T_OPEN + 2
#: offset of the "start window over" flag in the ESKF's own state (a state set by hand ends the window)
START_DONE_STATE = _STARTED
#: offset of the magnetometer model's block in the ESKF's own state (status, the saved model)
MAG_MODEL_STATE = _MAGF
#: offset of the gravity low-pass (:func:`mavahrs.filters.prefilter.ned_butterworth_step`) in the ESKF's state
GRAVITY_LOWPASS_STATE = _GLP
#: offsets in the ESKF's own state read by ``best``'s multirotor detection (:mod:`mavahrs.filters.best`): the NED
#: velocity, the error covariance (row-major N×N), the thrust axis (body, 3), its error basis's body axis, and the
#: measured per-sample noise (gyro, specific force)
VELOCITY_STATE = _V
COVARIANCE_STATE = _P
THRUST_AXIS_STATE = _TAX
THRUST_AXIS_REF_STATE = _TREF
MEASURED_NOISE_STATE = _VIB
#: offset of the drag measurement's counts (periods tried, periods rejected, velocity re-openings) in the ESKF's state
DRAG_STATS_STATE = _DSTAT
#: offset of the accelerometer's estimated bias (body, 3) in the ESKF's own state
ACCEL_BIAS_STATE = _ABIAS
#: the error-state size
ERROR_STATE_LEN = N


@dataclass(frozen=True)
class EskfSettings(FilterSettings):
    """Settings of :class:`Eskf` (noise densities are rate-independent).

    Attributes:
        gyro_noise_rad_s: gyro white-noise density, rad/s/√Hz (the attitude's
            random walk between corrections; also covers the sampling and
            low-pass errors of an autopilot's telemetry IMU stream).
        gyro_scale_sigma: 1-σ of each gyro axis's scale-factor error, a fraction
            (ICM-42688-P's datasheet: ±0.5 % initial tolerance; ArduPilot does
            not calibrate it; firmware_sim draws σ 0.2 %): in a fast yaw it is
            a heading error no noise density covers (a 720° spin at 0.3 %:
            2.2°).  Process noise of the heading proportional to the rate
            (:func:`_rate_noise`: its down component; the tilt, which every
            GNSS fix observes, is left as it was), so the heading's variance
            grows in fast yaw.
            0 = not modelled.  0.3 % (with ``gyro_scale_tau_s`` 1.5 s) measured
            on ten firmware_sim flights (aggressive 1–4, flips 1, hover 1–2,
            magnetic 1–3): our heading beyond 2σ 6.9 → 0.2 % of the aided
            airborne time, heading RMS 0.75 → 0.60°, tilt 0.38 → 0.38°; five
            more seeds not looked at: 5.5 → 0.0 %, 0.54 → 0.44°
            (``docs/monitor.md``).
        gyro_cross_axis_sigma: 1-σ of each off-diagonal (misalignment,
            cross-axis sensitivity) element, a fraction; 0 = not modelled (the
            default: 0.1 % raised the flips flight's heading RMS 0.71 → 0.79°
            and its tilt, the rate about a flip's axis entering the heading
            variance; 0.2 %: 1.02°).
        gyro_scale_tau_s: the correlation time those errors are taken to
            have, s: their white-noise equivalent density is 2 σ² τ ω², so the
            variance after a manoeuvre of T s is ≈ (σ ω)² · 2τT, (σ·angle)² for
            a T of 2τ (the errors are constants; a manoeuvre's length is what τ
            stands for).
        gyro_scale_tilt_sigma: 1-σ of each gyro axis's scale-factor error as
            the *tilt's* process noise, coherent over a manoeuvre
            (:func:`_scale_noise_tilt`: the variance of s·angle, the angle
            turned about each body axis kept with memory ``gyro_scale_tilt_memory_s``);
            0 = the tilt gets none.  0.3 %, as ``gyro_scale_sigma``: firmware_sim's
            post-flip tilt errors (1–1.5° after a 360° flip) come from its drawn
            scale factors (σ 0.2 %), and our tilt σ rose only 0.53 → 0.75° there
            (docs/monitor.md, round eight).
        gyro_scale_tilt_memory_s: how long an angle turned keeps adding to that
            term, s: the time the GNSS fixes take to correct the tilt error it
            left (firmware_sim flips 61 after its 360° flip: 1.38° → 0.49° in
            0.65 s, an e-fold of 0.6 s).  0.5 s; with ``gyro_scale_tau_s``'s 1.5 s
            (and 0.7 s) the steady rotation of firmware_sim aggressive 1 raised
            our tilt σ 0.47 → 0.78° (0.67°) and delayed its 2° tilt step 0.5 →
            3.4 s (3.2 s); 0.5 s: σ 0.63°, 0.6 s (docs/monitor.md, round eight).
        accel_noise_m_s2: accelerometer white-noise density, m/s²/√Hz (the
            INS velocity's random walk).
        bias_walk_rad_s2: gyro-bias random walk, rad/s per √s (how fast the
            bias may wander: ArduPilot's simulator drifts about 2 mrad/s over
            two minutes).
        velocity_noise_m_s: 1-σ noise of a horizontal GNSS velocity fix, m/s.
        vertical_velocity_noise_m_s: 1-σ noise of the vertical velocity, m/s.
        heading_noise_rad: 1-σ noise of one magnetometer heading, rad.
        gravity_noise_m_s2: 1-σ noise of the accelerometer as a gravity
            measurement while not velocity-aided, m/s² (divided by the
            schedule's accelerometer trust).
        gate_sigma: a magnetometer or gravity innovation beyond this many σ
            is rejected.
        velocity_gate_sigma: … a velocity innovation (each component).
        measured_noise_tau_s: the gyro and accelerometer noise densities
            are raised to what the stream shows (½ the mean square
            difference of consecutive samples × dt, averaged over this time
            constant, s): vibration aliased into a 100–400 Hz telemetry
            stream is noise the fixed densities do not cover.  0 = fixed.
        aiding_timeout_s: no velocity fix fused for this long = not aided
            (the gravity measurement takes over; the next fix restarts the
            velocity).
        sensor_delay_s: delay of the IMU data behind its time stamps, s
            (ArduPilot's RAW_IMU: its 20 Hz INS filters, ≈ 0.011 s).  Fixes
            are compared with the INS velocity this much later, and the
            output attitude is advanced by it.  0 = none.
        mag_rate_hz: magnetometer updates per second at most (ArduPilot
            reads its compass at 10 Hz and repeats the value in between).
        initial_tilt_rad, initial_heading_rad: 1-σ uncertainty of the
            initial attitude from the accelerometer (+ magnetometer).
        initial_average_s: the start is checked against the specific force
            averaged over this long, s, after the (re)initialisation, in the
            estimate's NED frame (the sum turns with every correction, as the
            gravity low-pass does): the mean is gravity up to the vehicle's mean
            acceleration over the window, while the first sample, which the
            filter starts from, is a raw IMU's on a vibrating multirotor
            60–120° off (firmware_sim ``vibration``: one clipped, aliased motor
            tone of tens of m/s²; the 2 s mean 3–12°).  If the estimate's up
            and the mean differ by more than ``initial_realign_rad`` at the
            window's end, the tilt is re-aligned to the mean
            (:func:`mavahrs.filters.initial.align_tilt_to_force`; TRIAD with
            the magnetometer), the gyro bias learnt from the wrong start
            forgotten and the filter restarted (covariance, velocity, clock);
            otherwise nothing changes.  The output is flagged
            ``FLAG_STARTUP`` until then.  0 = no check (the default; ``best``
            sets 2 s, :func:`mavahrs.filters.best.best_eskf_settings`).
        initial_realign_rad: that angle, rad: beyond what the window mean's
            own error (a multirotor's mean acceleration over 2 s: 4–16° on
            firmware_sim's ``aggressive`` and ``hover`` flights) and a good
            start's error explain.
        initial_bias_rad_s: 1-σ uncertainty of the initial gyro bias.
        bias_limit_rad_s: the bias estimate is clamped to ± this per axis.
        bias_limit_hold_s: … only on an axis whose estimate has been beyond
            it for this long without a break, s (0 = at once, the default):
            a second-long excursion is followed, a lasting one cut.
        bias_prior_sigma_rad_s: the gyro bias's plausible range as a Gaussian
            prior, rad/s (0 = none, the default): the pseudo-measurement
            b = 0 with this σ, on an axis whose estimate has been beyond it
            for ``bias_prior_after_s`` (a soft bound).
        bias_prior_after_s: that time, s (< 0: on every axis at every sample,
            the prior held throughout).
        bias_prior_spread_s: the prior's information per sample spread over
            this long, s: R = σ² × this / dt (0 = σ² at every sample).
        velocity_reset_s: every fix rejected for this long resets the INS
            velocity to the fix (as autopilot EKFs do).
        max_attitude_step_rad: the largest attitude correction one scalar
            measurement update may make, rad (0 = unbounded; the compass's
            heading, an angle measured as such, is never bounded): beyond it
            the update's noise is inflated until the correction is this
            large, and the covariance updated with that noise (the
            error-state model is a small-angle one).
        max_attitude_step_window_s: the bound acts only this long after the
            attitude covariance was last re-opened (a rejection reset, a
            re-alignment, an aiding restart), s (0 = always).
        mag_staleness_s: how old a magnetometer reading may be when it
            arrives, s (ArduPilot repeats a 10 Hz compass reading in every IMU
            message): the heading noise grows by yaw rate × this, so readings
            taken in a fast yaw count less.  A reading is fused when it
            changes (at most ``mag_rate_hz``), or after 1 s of repeats.
        mag_delay_s: the magnetometer reading's delay behind the IMU stamps,
            s: the heading it reads is compared with the attitude that much
            earlier (the heading now less yaw rate × (this − ``sensor_delay_s``),
            the IMU's own delay being in the attitude already).  0 = none (the
            default: a raw IMU's compass read with its gyro); a vehicle's stream
            sets none and learns it (``mag_learn_tau_s``).
        mag_learn_tau_s: the compass's delay (behind the IMU's attitude) is
            learnt from its readings, averaged over this long, s (0 =
            ``mag_delay_s`` as set): the heading innovation without a delay,
            ψ₀, is r_D·L + e for a reading L s old at yaw rate r_D and a heading
            error e that does not follow the yaw rate; L moves by
            ψ·r_D / (⟨r_D²⟩ + (10°/s)²) with ψ the innovation with L applied
            (normalised least mean squares: at its fixed point nothing in the
            innovation follows the yaw rate), only while turning faster than
            10°/s, at most one compass period, innovations beyond the gate not
            counted.
        mag_noise_tau_s: the compass heading's noise per reading is learnt
            from its own innovations, averaged over this long, s (0 =
            ``heading_noise_rad`` as set; a vehicle's stream: 30 s,
            ``best.VEHICLE_MAG_NOISE_TAU_S``): half the mean square
            difference of consecutive heading innovations (each carried to the
            current estimate by the filter's corrections, less the gyro noise
            between them) is the readings' noise alone, not a slow heading
            error the estimate carries; the second difference gives their
            lag-1 correlation ρ, and the variance per reading is
            σ²(1 + ρ)/(1 − ρ) (:func:`_mag_noise_step`).  Learnt only from
            readings used as they are (not a model-corrected one), with no
            disturbance flagged, turning slower than 10°/s; it starts at
            ``heading_noise_rad``.  PX4 SITL: readings 3.0° off the truth,
            learnt 2.9°; ArduCopter SITL 0.1–0.2°, held at the floor.
        mag_noise_min_rad, mag_noise_max_rad: the learnt noise is held within
            these, rad (1° and 20°: a compass's heading is not trusted beyond
            what its unmodelled errors — the WMM's, the tilt's projection —
            allow, nor dropped entirely).
        rejection_reset_s: every gravity and heading measurement rejected
            by the gate for this long re-opens the attitude covariance (the
            estimate is what is wrong: a bad start, a state set by hand).
        unaided_velocity_noise_m_s: without velocity aiding, a zero-velocity
            pseudo-measurement of this 1-σ noise, m/s, every
            ``unaided_velocity_period_s`` (an autopilot EKF's no-GNSS mode):
            the INS velocity's drift tells the tilt and bias error.  0 = off.
        unaided_velocity_period_s: s between those pseudo-measurements.
        realign_innovation_rad: without velocity aiding, a gravity
            innovation (angle between the measured and the predicted
            specific-force direction) beyond this is not fused as a small
            error: with ‖f‖ within the schedule's norm tolerance (5 % of g) a
            motion acceleration explains at most acos(1/1.05) ≈ 18°, an
            estimate drifted in a long manoeuvre some more, so an angle
            beyond 45° held for ``realign_after_s`` is an attitude error (a
            bad start, a state set by hand): the attitude covariance is
            re-opened, uncorrelated with the bias, and the accelerometer
            re-aligns the tilt (the bias is not learnt from it).  Fused as a
            small error it would be learnt as a gyro bias (a 90° start error:
            36° left after a minute).  20° re-aligned on in-flight errors:
            ArduCopter SITL without GNSS 1.41 → 2.58° inclination.
        realign_after_s: how long, s.
        gravity_lowpass_s: without velocity aiding, the gravity measurement
            is the specific force low-passed in the estimated NED frame
            (second-order Butterworth of this time constant, s; the
            Madgwick ``best`` configuration's and VQF's quasi-inertial
            low-pass, :mod:`mavahrs.filters.prefilter`), not the sample: a
            motion acceleration is correlated over seconds, so the single
            sample's error is not the white noise the update assumes.
            Its trust is the norm gate on the low-passed vector, which
            recovers after a rejection over the schedule's ``recovery_s``
            less τ (a short average is re-trusted as the sample is).
            0 = the raw sample.  ``best`` on a vehicle uses 0.1 s (a raw IMU's
            rotor vibration averaged out), nothing known of the source 2 s.
        adaptive_gravity_tau_s: the gravity measurement's noise variance is
            raised to the mean square of its own innovation, averaged over
            this time constant, s (adaptive measurement noise from the
            innovation, Mehra 1972 / Sage–Husa): sustained manoeuvres make
            the accelerometer count less for as long as they last.  0 = off.
        drag_coefficient_1_s: a multirotor's rotor drag (Leishman, Macdonald,
            Beard & McLain 2014, "Quad-rotor state estimation: the
            contribution of drag", eqs. (9)–(10); PX4 EKF2's and ArduPilot
            EKF3's drag fusion): the specific force across the thrust axis
            is −k × the body-frame velocity relative to the air (no wind
            assumed), k in 1/s.  Fused without velocity aiding every
            ``unaided_velocity_period_s`` (the specific force averaged over
            that period, two components across the thrust axis) it makes the
            velocity, hence the tilt, observable without GNSS.  Momentum
            theory sizes it: a rotor turning the air it ingests sideways at
            the induced velocity v_i gives k = g/(2 v_i) (≈ 1.3 /s at a disc
            loading of 35 N/m²); open rotors turn a fraction of it (ArduPilot's
            SITL copter: ``mdrag_coef``, the ratio to a ducted rotor) — the
            default 0.5 /s is that ratio ≈ 0.4.  0 = off (not a multirotor,
            or flying is not known); the pipeline sets it from a multirotor's
            HEARTBEAT (:meth:`Eskf.set_multirotor`).
        drag_noise_m_s2: 1-σ noise of one averaged drag measurement, m/s²
            (ArduPilot's EK3_DRAG_M_NSE default, 0.5; covers the model's error:
            wind, a k off by a factor of two at low speed).
        drag_reset_s: every drag measurement rejected by the χ gate for this
            long re-opens the velocity's variance to a start in flight's
            (5 m/s) and clears its correlations (an autopilot's reset of a
            rejected aiding source), s; 0 = never (the velocity and, through
            its correlations, the tilt then go on unobserved).
        thrust_axis_tau_s: the thrust axis (across which drag acts) is the
            running mean of the specific force's body-frame direction over
            this time constant, s: any IMU mounting (unless
            ``thrust_axis_sigma_rad`` makes it states).
        thrust_axis_sigma_rad: > 0: the thrust axis is two states of the
            error state instead (small angles across it, in the IMU frame),
            starting from the first drag period's mean specific-force
            direction with this 1-σ uncertainty, rad, and corrected by the drag
            measurement (∂h/∂α = the thrust's specific force: in hover the
            force across the axis is the axis error, in flight the filter
            weighs it against the velocity through their covariance), so the
            filter knows how little it knows of the axis early on instead of
            averaging a start in forward flight into it as truth.  ``best``
            sets it for a multirotor declared through the Python API (a raw
            IMU, any mounting; :meth:`mavahrs.filters.best.Best.set_multirotor`).
            0 = the running mean of ``thrust_axis_tau_s`` (the default; an
            autopilot's stream, whose IMU is in the body frame).
        thrust_axis_walk_rad_s: the thrust-axis states' random walk, rad/√s.
        declination_sigma_rad: 1-σ prior of the World Magnetic Model's
            declination error, rad: the local field's azimuth in the filter's
            frame (GNSS velocities are rotated by the WMM's declination) is a
            state (11) that starts at 0 with this σ; the compass heading reads
            ψ_field − D, so while GNSS velocity makes the heading observable
            (horizontal accelerations) the difference is learnt, and without
            GNSS the prior holds (the compass alone cannot tell D from the
            heading).  ArduPilot's SITL at Toulouse has a field ≈ 0.6° off
            the WMM-2025 declination; ArduPilot's table is interpolated on a
            grid.  0 = the WMM's declination taken as exact.
        rest: the rest detector (:mod:`mavahrs.filters.rest`: gyro and
            accelerometer steady within 2°/s and 0.5 m/s² of their 0.5 s
            low-passes for 1.5 s, the low-passed rate below
            ``rate_limit_rad_s``; its own bias follower is not used).
            Without velocity aiding, at detected rest the low-passed gyro is
            fused as a measurement of the bias (the true rate is zero) every
            ``unaided_velocity_period_s``, and the rotor-drag measurement is
            not (a vehicle on the ground is held by its legs; hovering still
            it reads no airflow to speak of).  The rate limit is 6°/s (a raw
            MEMS gyro's bias: up to ≈ 5°/s per axis);
            ``RestBiasSettings(bias_tau_s=0)`` turns it off.  A low-passed
            rate farther than 3 σ (the bias covariance) from the bias
            estimate is a slow steady turn, not rest (a hover's yaw).
            (ArduCopter SITL as a raw IMU: 1.94 → 1.86° mean inclination;
            ``docs/accuracy.md``.)
        rest_rate_noise_rad_s: 1-σ noise of the low-passed gyro as a
            bias measurement at rest, rad/s (0 = no rest updates).
        rest_check_sigma_rad_s: a detected rest is taken only where the bias is
            known well enough for the 3 σ check to tell a slow steady turn
            from it: at least one axis's bias 1-σ within this, rad/s, and every
            axis passing the check against its own σ (then fused on all three;
            0: no axis needs to be known).  The axes not yet known that well are
            checked too, as they are fused: firmware_sim raw ``hover`` seed 21's
            9.5 °/s steady yaw was fused unchecked as the vertical axis's bias
            (σ 1.8 °/s, 6σ off; 7.3 °/s wrong with σ 0.1 °/s after), 1.16 →
            0.66°.  Where the bias is hardly known the
            check passes any slow turn and one rest update takes the turn for
            the bias: a multirotor hovering in a slow turn is as still as rest
            to the detector (firmware_sim's raw ``hover``: the accelerometer
            within 0.08 m/s² of its low-pass, the gyro 0.3–0.5 °/s), and raw
            ``hover`` seed 5 declared a multirotor measured 5.37° (0.71°
            with this at 0.5 °/s).  Set by ``best``'s multirotor hypothesis.
        rest_wobble_sigma_rad_s: in a *hovering* rest, the rate across the
            vertical that the rest may hide, rad/s (1-σ, one constant per rest:
            the n-th update fuses only its information increment, so a rest
            carries at most that of its mean; 0 = off, the default).  A
            multirotor's specific force is its thrust, fixed in the body, so a
            hover's slow tilting wobble moves nothing the detector sees.  ``best``'s
            multirotor 0.3 °/s (firmware_sim raw ``hover`` 135 3.07 → 1.40°).
        rest_hover_vibration_m_s2: a rest is a hovering one only where the
            accelerometer's vibration (RMS of its deviation from the detector's
            0.5 s low-pass, 1 s mean) exceeds this, m/s² (the rotors run; 0 = not
            asked).  ``best``'s multirotor 0.04 (firmware_sim: landed
            0.017–0.034, flying ≥ 0.048).
        rest_hover_speed_m_s: … and only where the INS horizontal speed is below
            this, m/s (0 = not asked).  ``best``'s multirotor 5 (a steady dash's
            constant attitude is a true rest).
        rest_velocity_noise_m_s: 1-σ noise of a zero velocity fused at rest,
            m/s; 0 = not fused (the default: SITL's hover is as still as a
            landed vehicle and drifts; 0.05 m/s measured 1.94 → 2.07°).
        schedule: the shared schedule: only its magnetometer rejection (norm,
            dip) and accelerometer trust are used; no start-up boost (the
            covariance converges the filter).  With ``mag_model`` enabled the
            magnetometer is judged by the model instead of the norm and dip.
        mag_model: the magnetometer's body offset and earth field learnt in
            flight, and the trust in each reading
            (:class:`mavahrs.filters.magfield.MagFieldSettings`).
        position_noise_m: 1-σ noise of a horizontal GNSS position fix
            (``IN_POS``), m: the position is three more error states (12–14,
            δṗ = δv), started from the first fix while velocity-aided and
            corrected by each later one at the fix's own time (the INS
            position then = now less the velocity history's integral since,
            :func:`_history_displacement`).  A tilt error δ shows as ½·g·δ·t²
            of position drift: at hover the position holds the tilt where
            the velocity's noise lets it wander.  0 = not fused (the default:
            on ArduCopter SITL's onboard .BIN, whose GNSS has no noise, 0.1–1 m
            measured 0.216 → 0.218–0.221° inclination, and 0.117 → 0.118°
            with the vehicle's bias walk: the velocity fixes already hold the
            INS velocity within mm/s, so the position adds next to nothing;
            the gap to EKF3 was the gyro bias's drift,
            ``best.VEHICLE_BIAS_WALK_RAD_S2``; docs/filters/eskf.md).
        vertical_position_noise_m: … of the vertical (GNSS altitude), m;
            0 = not fused.
        position_gate_sigma: a position innovation beyond this many σ is
            rejected (every one for ``velocity_reset_s``: the position
            restarts from the next fix).
        position_walk_m_s: random walk of the position states, m/√s (a
            receiver's slow wander, which white noise alone does not cover).
        bias_walk_aided_rad_s2: the gyro-bias random walk while velocity-aided,
            rad/s per √s (0 = ``bias_walk_rad_s2`` throughout): the GNSS
            velocity observes the tilt and (in horizontal accelerations) the
            heading well enough to follow a drifting bias.  Not without GNSS,
            where a faster walk only lets the accelerometer's manoeuvre errors
            into the bias (ArduCopter SITL without GNSS, 2e-4 throughout:
            0.56–0.79 → 0.55–0.80° inclination, gentle heading 0.38 →
            0.51°).  Tried: the faster walk on the bias's horizontal (NED)
            components only, the heading's kept: at 2e-4 the magnetic flight's
            heading 0.61 → 0.58° but the aggressive one's 0.33 → 0.45° and the
            .BIN's inclination 0.117 → 0.129° (SITL drifts every axis).
            ``best`` on a vehicle sets it (``best.VEHICLE_BIAS_WALK_RAD_S2``).
        gyro_scale_state_sigma: prior 1-σ of each gyro axis's scale-factor
            error as an error state (a fraction; 0 = not estimated, the
            default): the reading is (1 + s)·ω + b per axis, the rate used
            ω̂ = (reading − b̂)/(1 + ŝ), and δθ̇ = −C δb − C diag(ω̂) δs
            (Groves 2013, §14.2.7: gyro scale-factor states; Farrell 2008,
            §11.4).  What the gravity measurement sees of a rotation's
            integrated error is learnt as scale where it follows the rate
            and as bias where it does not.  The estimate is bounded by 3σ.
            ``best`` through the Python API sets it
            (``best.BEST_GYRO_SCALE_SIGMA``; docs/accuracy.md, "Gyro
            scale-factor states").
        gyro_scale_state_walk_1_s: random walk of those states, 1/√s
            (temperature; 0 = constant).
        accel_bias_sigma_m_s2: 1-σ of each accelerometer axis's bias as an
            error state (body frame, error states 18–20; 0 = not estimated,
            the default), m/s²: the reading is f + b_a, the specific force
            used everywhere f̂ = reading − b̂_a, and δv̇ = −[C f]× δθ − C δb_a
            (Groves 2013, §14.2.6: accelerometer-bias states; ArduPilot EKF3
            and PX4 EKF2 carry the same three as delta-velocity biases).  The
            gravity measurement reads LP[C] δb_a beside the tilt (the rows
            C_N, C_E of C_body_to_ned low-passed as the measurement is), the
            rotor-drag measurement e_cᵀ δb_a beside the
            velocity across the thrust axis, the velocity fixes it through
            the velocity's propagation.  A body-fixed bias is told from a tilt
            error only as the body turns under it (yaw), or along the thrust
            axis through the vertical velocity.  First-order Gauss–Markov of
            correlation time ``accel_bias_tau_s``: ḃ_a = −b_a/τ + w, the
            prediction b̂_a ← (1 − dt/τ) b̂_a, Φ's rows 1 − dt/τ, Q = 2σ²/τ
            (Gelb 1974, table 4.4-1; steady-state variance σ²).  The estimate
            is bounded by 3σ per axis.
        accel_bias_tau_s: their correlation time, s (0 = a random constant
            of prior σ: no decay, no process noise).
        accel_bias_vibration_ratio: c: the states' steady-state variance is
            σ² + c² σ_f², σ_f² the specific force's per-sample variance as
            measured (``measured_noise_tau_s``): the aliased rotor vibration of
            a raw IMU leaves slowly varying offsets that grow with it (0 =
            σ alone; needs ``accel_bias_tau_s`` > 0).
        accel_bias_aided_only: the states are estimated only while
            velocity-aided (GNSS): without aiding b̂_a is held as learnt (still
            subtracted), its process noise stopped and its correlations with
            the rest cleared, and neither the gravity nor the drag measurement
            reads it (the bias across gravity is then told from a tilt only
            by the body's turns, and a motion acceleration or a drag-model
            error is learnt as bias: see docs/accuracy.md).
        accel_bias_across_thrust: the accelerometer-bias states start across
            the thrust axis only (with the thrust-axis states, when they
            start: P_ba = σ²(I − t tᵀ), the estimate's part along t dropped):
            along the thrust the bias is one with the unknown thrust, which
            nothing but the zero-velocity pseudo-measurement observes, and an
            along-axis state there took the start's errors (firmware_sim raw
            ``aggressive`` 101: 0.28 m/s² learnt for −0.05).  A constant bias
            (``accel_bias_tau_s`` 0) stays in that span; with τ > 0 the
            process noise is isotropic.  ``best`` declared a multirotor
            through the API sets it (docs/accuracy.md, seventeenth round).
        accel_bias_live_speed_m_s: the accelerometer-bias states are
            estimated only while the INS horizontal speed is below this, m/s
            (0 = at any speed); above it they are *considered* (Schmidt
            1966): their uncertainty enters every innovation's variance and
            their correlations are kept, but neither b̂_a nor its own variance
            is updated: a drag model's misfit grows with the speed, a
            body-fixed offset does not (docs/accuracy.md, eighteenth round).
        accel_bias_consider_sigma_m_s2: 1-σ per axis of a constant
            accelerometer bias the filter does *not* estimate (no states, the
            estimate and every gain as without it), m/s²; 0 = off (the
            default).  The error's sensitivity to it, S = ∂δx/∂b_a (N × 3), is
            carried beside P with the filter's own Φ and gains (Maybeck 1979,
            §6.11: S ← Φ S − C dt in the velocity's rows, S ← S − K (h S + h_b)
            at each update, h_b the gravity measurement's C_N / C_E), and the
            published tilt σ is √(P_θN + P_θE + σ_b² ‖S_θN,θE‖²): a body-fixed
            bias stands in the tilt b/g wherever the body does not turn under
            it (a hover, a straight leg), less just after turns, which the
            velocity fixes see it through — where the published σ without it
            was short.  ``best`` keeps it off on a vehicle's stream
            (``best.VEHICLE_ACCEL_BIAS_CONSIDER_SIGMA_M_S2``: measured at 0.05,
            not kept; docs/monitor.md round twenty-one).
        heading_walk_tau_s: the heading's process noise is raised to what the
            compass's own heading innovations show (covariance matching, Sage &
            Husa 1969 / Myers & Tapley 1976; :func:`_heading_walk_step`): per
            window of readings (``heading_walk_window_s``) an extra heading
            random-walk density q_x moves by K̄²(ψ̄² − S̄)/τ, ψ̄ the window's mean
            innovation, S̄ = ⟨hPhᵀ⟩ + ⟨r⟩/M its predicted variance, K̄ the
            heading's gain for it, τ this time, s; so where the
            heading error wanders more than the gyro noise lets P say (PX4's
            HIGHRES_IMU, EKF2's moving bias subtracted) the heading σ opens and
            the compass corrects faster, and where the innovations are within
            S (ArduCopter SITL) q_x stays 0.  Learnt from the readings the
            compass's noise is learnt from (as they are, no disturbance flagged,
            turning < 10°/s), each ψ̄² at most gate² × S̄.  τ is how soon the
            excess a window shows is taken into P (with a window of T the
            variance grows by ≈ (T/τ)·K̄²(ψ̄² − S̄) over the next window).
            0 = off (the default; ``best`` on a vehicle's stream: 3 s,
            ``best.VEHICLE_HEADING_WALK_TAU_S``).
        heading_walk_max_rad_s: the largest extra heading random walk it may
            reach, rad/√s: 0.01 (0.57°/√s), twice the largest yaw random walk
            measured on an autopilot's stream here (gyro against the truth, bias
            removed: ArduCopter SITL 400 Hz 0.30°/√s, PX4 SIH 0.24–0.26°/√s;
            docs/accuracy.md), the density 2σ_b²τ_b of a bias wandering
            σ_b 0.13°/s with a 10 s correlation.
        heading_walk_window_s: the compass's heading innovations are averaged
            over windows of this long, s, for it: the mean of M readings has
            the compass's noise r/M (a single reading's r, (3°)² on PX4 SIH,
            hides a slow 2° error), so the window is long enough for r/M to
            come down to the innovation's own predicted variance hPhᵀ (PX4
            SIH: ≈ 14 readings fused in 2 s, (3.5°)²/14 ≈ (0.9°)² against
            hPhᵀ ≈ (0.8–0.9°)²) and short against the heading error's own
            time (the compass's correction takes ≈ 4 s at 10 Hz and σ 3°),
            and a window is not broken off by a turn as often as a longer one
            (PX4 SIH, windows of 1 / 2 / 3 / 5 s with τ 3–10 s: docs/accuracy.md).
        drag_quadratic_1_m: c, the body's bluff drag beside the rotors'
            momentum drag in the drag measurement, 1/m: D = (k + c‖v‖) v
            (ArduPilot EKF3's EK3_DRAG_BCOEF_X/Y and PX4 EKF2's
            EKF2_BCOEF_X/Y beside their *_MCOEF: c = ρ/(2B), B the
            ballistic coefficient in kg/m²); 0 = the linear term alone
            (default; ``best``'s raw multirotor sets
            ``best.MULTIROTOR_BODY_DRAG_1_M``).
        drag_noise_match_s: the drag measurement's noise matched to its
            innovations (covariance matching: Mehra 1972; Mohamed & Schwarz
            1999): the mean of y² − h P hᵀ over this time, s (the mean since
            the start while shorter), is the measurement's variance when
            larger than ``drag_noise_m_s2``², for the innovations within the
            χ gate of the nominal R (one beyond it is still rejected: a state
            error, not noise).  A vibrating raw IMU's 0.1 s mean force and
            its velocity, which h P hᵀ trusts, are then weighed as they fit,
            not as the covariance claims (0 = R as set, default;
            ``best``'s raw multirotor sets ``best.MULTIROTOR_DRAG_NOISE_MATCH_S``).
        slow_force_block_s: the velocity's process noise also carries the
            specific force's slow error (aliased vibration, rectification):
            the Hadamard variance of the NED specific force's means over
            blocks of this length T, σ²_H(T) = ⅙⟨(f̄ₖ − 2f̄ₖ₋₁ + f̄ₖ₋₂)²⟩ per
            axis, less what the measured white noise gives there (σ²_w / n
            for n samples a block; white noise of density q has σ²_H(T) =
            σ²_A(T) = q / T, IEEE Std 952-1997 annex C), is a density
            q_slow = T · excess added to the accelerometer's (0 = off,
            default).  Second differences leave out an acceleration that
            changes steadily over the three blocks; quicker real changes
            count as error.
        slow_force_tau_s: the averaging time of that variance, s.
        output_half_step: the published attitude is advanced by
            ``sensor_delay_s`` − dt/2 rather than ``sensor_delay_s`` (dt the
            step, at most 0.05 s; a negative advance moves it back).  Each step applies the sample's rate over the interval
            before it, q ← q ⊗ exp(ω_k dt_k / 2) (right rectangle), so for a
            rate *sampled* at the stamp the integrated attitude leads the
            truth by ½ E[dt²] / E[dt] (the sum exceeds the integral by
            ½ Σ ω̇ dt²): 2.2 ms on a 250 Hz RAW_IMU, 10 ms at 50 Hz
            (docs/monitor.md rounds thirteen and fourteen).  The state is
            not moved.  For an autopilot's stream (point samples of a
            low-passed rate: :func:`mavahrs.filters.best.vehicle_eskf_settings`
            sets it); off by default: a raw IMU's sample that is already
            the interval's mean (BROAD) has no lead (BROAD 0.66 → 0.86°
            inclination with it).
        mag_body_offset_lag_s: the body-offset learner, plain path only (no
            effect with ``mag_model`` on): while the gain schedule rejects the
            compass, a body-fixed offset b (a magnet on the sensor) is fitted
            by least squares from pairs of readings this far apart, s,
            ``m_i − R m_j = (I − R) b`` with ``R = C_iᵀ C_j`` the rotation the
            gyro measured between them (neither heading nor tilt needed: the
            estimate's error is common to both); once the fit is valid (the
            three settings below) the reading less b is fused when it passes
            the schedule's norm and dip test (the dip from the estimate's
            attitude); the fit is forgotten when the schedule accepts the raw
            reading again.  0 = off (default;
            :func:`mavahrs.filters.best.best_eskf_settings` sets 0.5 s,
            ``vehicle_eskf_settings`` 0).
            BROAD attached-magnet trials 1.73 → 1.02° heading
            (docs/accuracy.md, round three bmag2).
        mag_body_offset_min_turn: the fit is used once the least eigenvalue
            of Σ (I − R)ᵀ(I − R) over its pairs reaches this (a 90° turn about
            one axis adds 2 on the two axes across it: the turns must span
            two axes).
        mag_body_offset_residual_fraction: … and its residual is at most this
            share of the pairs' Σ‖m_i − R m_j‖² (an earth-fixed disturbance
            changes with the place, not with the body, and does not fit:
            BROAD's stationary magnet leaves 0.5 unexplained, a clean
            compass's calibration remainder 0.7–1, the attached magnet
            0.05–0.1).
        mag_body_offset_sigma_ut: … and the offset's standard error along its
            worst axis (the residual per pair over that eigenvalue), µT, is
            within this.
        mag_rejected_sigma_scale: plain path only (no effect with
            ``mag_model`` on): a reading the gain schedule rejects (its weight
            below 0.5: the dip test, or the 0.5 s recovery after it) but whose
            norm is within the schedule's ``mag_norm_tolerance`` of its
            reference is fused all the same, its heading σ multiplied by this
            (the gate as usual); a reading whose norm is off (a magnet on the
            sensor: the body-offset learner's case) stays out.  In fast turns a
            raw IMU's compass fails the dip test (BROAD's reads ≈ 10 ms late)
            while the gyro's heading drifts 0.2–0.3 °/s.  0 = such readings
            are not fused (default; ``best_eskf_settings`` sets 5,
            ``vehicle_eskf_settings`` 0).  BROAD heading 1.58 → 1.32°
            (docs/accuracy.md, round five smag3).
    """

    gyro_noise_rad_s: float = 0.003
    gyro_scale_sigma: float = 0.003
    gyro_cross_axis_sigma: float = 0.0
    gyro_scale_tau_s: float = 1.5
    accel_noise_m_s2: float = 0.1
    bias_walk_rad_s2: float = 5e-5
    velocity_noise_m_s: float = 0.1
    vertical_velocity_noise_m_s: float = 0.15
    heading_noise_rad: float = math.radians(5.0)
    gravity_noise_m_s2: float = 3.0
    gate_sigma: float = 3.0
    velocity_gate_sigma: float = 5.0
    measured_noise_tau_s: float = 1.0
    aiding_timeout_s: float = 3.0
    sensor_delay_s: float = 0.0
    mag_rate_hz: float = 10.0
    initial_tilt_rad: float = math.radians(3.0)
    initial_heading_rad: float = math.radians(20.0)
    initial_average_s: float = 0.0
    initial_realign_rad: float = math.radians(30.0)
    initial_bias_rad_s: float = math.radians(3.0)
    bias_limit_rad_s: float = math.radians(10.0)
    bias_limit_hold_s: float = 0.0
    bias_prior_sigma_rad_s: float = 0.0
    bias_prior_after_s: float = 0.0
    bias_prior_spread_s: float = 0.0
    velocity_reset_s: float = 5.0
    max_attitude_step_rad: float = 0.0
    max_attitude_step_window_s: float = 0.0
    mag_staleness_s: float = 0.1
    rejection_reset_s: float = 2.0
    unaided_velocity_noise_m_s: float = 10.0
    unaided_velocity_period_s: float = 0.1
    realign_innovation_rad: float = math.radians(45.0)
    realign_after_s: float = 0.5
    gravity_lowpass_s: float = 0.0
    adaptive_gravity_tau_s: float = 0.0
    drag_coefficient_1_s: float = 0.0
    drag_noise_m_s2: float = 0.5
    drag_reset_s: float = 0.0
    thrust_axis_tau_s: float = 60.0
    thrust_axis_sigma_rad: float = 0.0
    thrust_axis_walk_rad_s: float = 1e-4
    declination_sigma_rad: float = math.radians(1.5)
    rest: RestBiasSettings = field(
        default_factory=lambda: RestBiasSettings(bias_tau_s=1.0, rate_limit_rad_s=math.radians(6.0))
    )
    rest_rate_noise_rad_s: float = math.radians(0.1)
    rest_velocity_noise_m_s: float = 0.0
    rest_check_sigma_rad_s: float = 0.0
    rest_wobble_sigma_rad_s: float = 0.0
    rest_hover_vibration_m_s2: float = 0.0
    rest_hover_speed_m_s: float = 0.0
    schedule: GainScheduleSettings = field(
        default_factory=lambda: GainScheduleSettings(
            startup_gain_factor=1.0,
            startup_s=0.0,
            accel_norm_tolerance=0.05,
            spin_rate_rad_s=0.0,
            horizontal_tolerance=0.0,
            rejection_timeout_s=0.0,
            mag_norm_tolerance=0.08,
            mag_dip_tolerance_rad=math.radians(5.0),
        )
    )
    mag_model: MagFieldSettings = field(default_factory=MagFieldSettings)
    position_noise_m: float = 0.0
    vertical_position_noise_m: float = 0.0
    position_gate_sigma: float = 5.0
    position_walk_m_s: float = 0.0
    bias_walk_aided_rad_s2: float = 0.0
    mag_delay_s: float = 0.0
    mag_learn_tau_s: float = 0.0
    mag_noise_tau_s: float = 0.0
    mag_noise_min_rad: float = math.radians(1.0)
    mag_noise_max_rad: float = math.radians(20.0)
    gyro_scale_state_sigma: float = 0.0
    gyro_scale_state_walk_1_s: float = 0.0
    accel_bias_sigma_m_s2: float = 0.0
    accel_bias_tau_s: float = 0.0
    accel_bias_vibration_ratio: float = 0.0
    accel_bias_aided_only: bool = False
    accel_bias_across_thrust: bool = False
    accel_bias_live_speed_m_s: float = 0.0
    accel_bias_consider_sigma_m_s2: float = 0.0
    gyro_scale_tilt_sigma: float = 0.003
    gyro_scale_tilt_memory_s: float = 0.5
    heading_walk_tau_s: float = 0.0
    heading_walk_max_rad_s: float = 0.01
    heading_walk_window_s: float = 2.0
    drag_quadratic_1_m: float = 0.0
    drag_noise_match_s: float = 0.0
    slow_force_block_s: float = 0.0
    slow_force_tau_s: float = 5.0
    output_half_step: bool = False
    mag_body_offset_lag_s: float = 0.0
    mag_body_offset_min_turn: float = 2.0
    mag_body_offset_residual_fraction: float = 0.2
    mag_body_offset_sigma_ut: float = 2.5
    mag_rejected_sigma_scale: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in (
            "gyro_noise_rad_s", "accel_noise_m_s2", "bias_walk_rad_s2", "velocity_noise_m_s",
            "vertical_velocity_noise_m_s", "heading_noise_rad", "gravity_noise_m_s2", "gate_sigma", "velocity_gate_sigma",
            "aiding_timeout_s", "mag_rate_hz", "initial_tilt_rad", "initial_heading_rad",
            "initial_bias_rad_s", "bias_limit_rad_s", "velocity_reset_s", "realign_innovation_rad",
            "initial_realign_rad",
        ):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"EskfSettings.{name} must be a finite number > 0, got {value!r}")
        if not (math.isfinite(self.drag_coefficient_1_s) and 0.0 <= self.drag_coefficient_1_s <= 10.0):
            raise ValueError(f"EskfSettings.drag_coefficient_1_s must be in [0, 10] 1/s, got {self.drag_coefficient_1_s!r}")
        if not isinstance(self.rest, RestBiasSettings):
            raise ValueError(f"EskfSettings.rest must be a RestBiasSettings, got {type(self.rest).__name__}")
        for name in ("rest_rate_noise_rad_s", "rest_velocity_noise_m_s", "rest_check_sigma_rad_s", "rest_wobble_sigma_rad_s", "rest_hover_vibration_m_s2", "rest_hover_speed_m_s", "thrust_axis_sigma_rad", "thrust_axis_walk_rad_s",
                     "gyro_scale_sigma", "gyro_cross_axis_sigma", "gyro_scale_tau_s", "declination_sigma_rad",
                     "position_noise_m", "vertical_position_noise_m", "position_walk_m_s", "bias_walk_aided_rad_s2",
                     "mag_delay_s", "mag_learn_tau_s", "mag_noise_tau_s", "drag_reset_s", "mag_rejected_sigma_scale",
                     "gyro_scale_state_sigma", "gyro_scale_state_walk_1_s",
                     "accel_bias_sigma_m_s2", "accel_bias_tau_s", "accel_bias_vibration_ratio", "gyro_scale_tilt_sigma",
                     "accel_bias_consider_sigma_m_s2", "bias_limit_hold_s", "bias_prior_sigma_rad_s", "max_attitude_step_rad",
                     "max_attitude_step_window_s",
                     "bias_prior_spread_s",
                     "gyro_scale_tilt_memory_s", "heading_walk_tau_s", "heading_walk_max_rad_s",
                     "heading_walk_window_s", "drag_quadratic_1_m", "drag_noise_match_s", "slow_force_block_s",
                     "slow_force_tau_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"EskfSettings.{name} must be a finite number ≥ 0, got {value!r}")
        for name in ("drag_noise_m_s2", "thrust_axis_tau_s", "position_gate_sigma"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"EskfSettings.{name} must be a finite number > 0, got {value!r}")
        if not (math.isfinite(self.initial_average_s) and 0.0 <= self.initial_average_s <= 10.0):
            raise ValueError(f"EskfSettings.initial_average_s must be in [0, 10] s, got {self.initial_average_s!r}")
        if not math.isfinite(self.bias_prior_after_s):
            raise ValueError(f"EskfSettings.bias_prior_after_s must be finite, got {self.bias_prior_after_s!r}")
        if not (math.isfinite(self.realign_after_s) and self.realign_after_s >= 0.0):
            raise ValueError(f"EskfSettings.realign_after_s must be ≥ 0 s, got {self.realign_after_s!r}")
        if not (math.isfinite(self.mag_noise_min_rad) and 0.0 < self.mag_noise_min_rad <= self.mag_noise_max_rad
                and math.isfinite(self.mag_noise_max_rad)):
            raise ValueError("EskfSettings.mag_noise_min_rad must be > 0 and ≤ mag_noise_max_rad (finite), got "
                             f"{self.mag_noise_min_rad!r}, {self.mag_noise_max_rad!r}")
        if not (math.isfinite(self.sensor_delay_s) and 0.0 <= self.sensor_delay_s <= 0.1):
            raise ValueError(f"EskfSettings.sensor_delay_s must be in [0, 0.1] s, got {self.sensor_delay_s!r}")


# --------------------------------------------------------------------------- kernels


@kernel
def mag_noise_reset(s, k, params):  # type: ignore[no-untyped-def]
    """The compass's learnt noise back to its prior (``heading_noise_rad``, white) and no reading held."""
    kn = k + _MNOISE
    s[kn] = s[kn + 1] = params[P_FILTER + _R_HEADING]
    s[kn + 2] = s[kn + 3] = math.nan
    s[kn + 4] = -1.0e9
    s[kn + 5] = s[kn + 6] = 0.0
    s[kn + 7] = s[kn + 8] = 0.0


@kernel
def _mag_noise_step(s, k, params, psi, cn, ce, learn, clk):  # type: ignore[no-untyped-def]
    """The compass's heading noise per reading, learnt from its own innovations; returns it, rad².

    The heading innovation ψ_k = n_k + e_k is the reading's noise n plus the estimate's heading error e.
    The error moves between readings by the gyro's white noise (q·Δt on the heading and, through the
    field's dip, (h_N² + h_E²)·q·Δt via the tilt, plus the rate noise of the scale factor: accumulated per
    sample and subtracted, Q₁ since the last reading, Q₂ since the one before: (0.05°)² at PX4's 14 Hz,
    ≈ 1–2° on firmware_sim's vibrating stream) and by the filter's own corrections, which are known: ψ of
    the previous readings is carried to the current estimate by each injected δx (ψ ← ψ − h·δx,
    :func:`_mag_noise_carry`).  So the differences of consecutive innovations, less Q, are the noise's
    alone, whatever slow error the estimate carries (a bias learnt
    in a manoeuvre: a slow error that would inflate ⟨ψ²⟩ − hPhᵀ, Mehra 1972's estimate, and so slow
    the compass that should remove it).  For noise of variance σ² and lag-1 correlation ρ (AR(1)):
    D₁ = ½⟨(ψ_k − ψ_{k−1})² − Q₁⟩ = σ²(1 − ρ), D₂ = ½⟨(ψ_k − ψ_{k−2})² − Q₂⟩ = σ²(1 − ρ²), so ρ = D₂/D₁ − 1, and
    the variance per reading that makes a white-noise update as informative as those readings really
    are is the noise's spectral density at 0 times the reading interval, σ²(1 + ρ)/(1 − ρ)
    = D₁(1 + ρ)/(1 − ρ)² (Box & Jenkins: the variance of the mean of n AR(1) values ≈ σ²(1+ρ)/(1−ρ)/n):
    the reading rate is accounted for, independent readings at 14 Hz counting fully, a 10 Hz compass
    repeated or smoothed into every sample counting as what it is.  ρ within [0, 0.9].  D₁, D₂ are
    averaged over ``mag_noise_tau_s`` (per reading: weight Δt/τ), each term at most gate² × its mean
    (one spike does not set it), only while ``learn`` (the reading trusted as it is, no disturbance
    flagged, turning slower than 10°/s: the compass's timing is not its noise); the result is held within
    ``mag_noise_min_rad`` … ``mag_noise_max_rad``.  Pairs more than 1 s (2 s) apart are not counted.
    """
    p = P_FILTER
    kn = k + _MNOISE
    gate2 = params[p + _GATE] * params[p + _GATE]
    dt_r = clk - s[kn + 4]
    q1 = s[kn + 7]  # the process noise's share of the change since the last reading …
    q2 = q1 + s[kn + 8]  # … and since the one before
    if learn and dt_r <= 1.0 and s[kn + 2] == s[kn + 2]:
        a = min(dt_r / params[p + _MAG_NOISE_TAU], 1.0)
        d = psi - s[kn + 2]
        d = math.atan2(math.sin(d), math.cos(d))
        s[kn] = max(s[kn] + a * (min(0.5 * d * d, gate2 * s[kn]) - 0.5 * q1 - s[kn]), 1.0e-12)
        if s[kn + 3] == s[kn + 3]:
            d = psi - s[kn + 3]
            d = math.atan2(math.sin(d), math.cos(d))
            s[kn + 1] = max(s[kn + 1] + a * (min(0.5 * d * d, gate2 * s[kn + 1]) - 0.5 * q2 - s[kn + 1]), 1.0e-12)
    s[kn + 8] = q1
    s[kn + 7] = 0.0
    # the readings held move back by one; pairs across a gap are not pairs
    s[kn + 3] = s[kn + 2] if dt_r <= 1.0 else math.nan
    s[kn + 2] = psi
    s[kn + 4] = clk
    s[kn + 5] = cn
    s[kn + 6] = ce
    d1 = s[kn]
    rho = min(max(s[kn + 1] / d1 - 1.0, 0.0), 0.9) if d1 > 0.0 else 0.0
    r = d1 * (1.0 + rho) / ((1.0 - rho) * (1.0 - rho))
    return min(max(r, params[p + _MAG_NOISE_MIN]), params[p + _MAG_NOISE_MAX])


@kernel(inline=True)
def _mag_noise_carry(s, k, dx0, dx1, dx2, dx_decl):  # type: ignore[no-untyped-def]
    """The held readings' innovations carried to the estimate after an injected correction: ψ ← ψ − h·δx with
    h = (∂ψ/∂δθ_N, ∂ψ/∂δθ_E, −1, …, 1 at the declination) (the tilt's sensitivity as of the last reading)."""
    kn = k + _MNOISE
    c = s[kn + 5] * dx0 + s[kn + 6] * dx1 - dx2 + dx_decl
    s[kn + 2] -= c
    s[kn + 3] -= c


@kernel
def _heading_walk_step(s, k, params, y, sv, r, learn, clk):  # type: ignore[no-untyped-def]
    """The heading's extra random-walk density, learnt from the compass's heading innovations (covariance matching).

    One reading's innovation ψ (predicted variance S = hP⁻hᵀ + r) is dominated by the compass's own noise r
    (PX4 SIH: 3° per reading against a heading σ of 0.5°), so a slow heading error of 2° changes ψ² by less
    than r's uncertainty.  The mean of the M readings of a window of ``heading_walk_window_s`` is the heading
    error's mean plus noise of variance r̄/M (r the learnt variance per reading, σ²(1 + ρ)/(1 − ρ), is what
    makes r/M the variance of the mean of M correlated readings: :func:`_mag_noise_step`): ψ̄ = Σψ/M of predicted
    variance S̄ = ⟨hP⁻hᵀ⟩ + ⟨r⟩/M (⟨hP⁻hᵀ⟩ bounds the variance of the error's mean from above, and the filter's
    own corrections within the window only lower it: the estimate is conservative).  As one measurement of the
    heading error, its gain on the heading is K̄ = ⟨(P⁻hᵀ)_ψ⟩ / S̄.  With the heading's process noise Q·T over
    a window, Myers & Tapley (1976, eq. 23; Sage & Husa 1969) estimate it as the mean of what the corrections
    show less what the covariance predicted: Q̂·T = ⟨Δx Δxᵀ + P⁺ − Φ P⁺₋ Φᵀ⟩ = Q·T + ⟨K̄² (ψ̄² − S̄)⟩.  So the
    heading's extra density q_x (added to P_DD every sample, above the gyro's noise and the rate noise) moves
    per window by

        q_x ← q_x + (T/τ) · K̄² (ψ̄² − S̄) / T = q_x + K̄² (ψ̄² − S̄) / τ

    (the Sage–Husa recursion with weight T/τ, τ ``heading_walk_tau_s``): it stays where the window means are as
    large as S̄ predicts, grows while the heading error wanders more than the covariance says, and shrinks
    back when it is smaller (its own feedback: more q_x, more P, larger S̄).  Each ψ̄² is at most gate² × S̄;
    q_x is held within 0 (today's process noise: a clean gyro keeps it) and ``heading_walk_max_rad_s``².  The
    running mean of ψ̄²/S̄ (weight T/τ) is kept beside it: 1 when the heading's σ is consistent.  A window
    ends at a reading not to learn from (``learn`` False: a model-corrected reading, a disturbance, a turn)
    or more than 1 s after the last one, and is then not used.  ``y``, ``sv``: the innovation and its
    variance as :func:`_innovation` returns them (P hᵀ in scratch), ``r`` the reading's noise in it.
    """
    p = P_FILTER
    kw = k + _HWALK
    if not learn or clk - s[kw + 8] > 1.0:
        s[kw + 6] = 0.0  # the window is not used: a new one starts at the next reading to learn from
        s[kw + 7] = clk
        s[kw + 8] = clk
        if not learn:
            return
    if s[kw + 6] == 0.0:
        s[kw + 2] = s[kw + 3] = s[kw + 4] = s[kw + 5] = 0.0
        s[kw + 7] = clk
    s[kw + 8] = clk
    s[kw + 2] += y
    s[kw + 3] += s[k + _PH + 2]
    s[kw + 4] += sv - r
    s[kw + 5] += r
    s[kw + 6] += 1.0
    tw = clk - s[kw + 7]
    if tw < params[P_FILTER + _HWALK_WIN]:
        return
    m = s[kw + 6]
    ybar = s[kw + 2] / m
    sbar = s[kw + 4] / m + s[kw + 5] / (m * m)
    s[kw + 6] = 0.0
    if not (sbar > 0.0):
        return
    tau = params[p + _HWALK_TAU]
    gate2 = params[p + _GATE] * params[p + _GATE]
    kbar = s[kw + 3] / m / sbar
    e2 = min(ybar * ybar, gate2 * sbar)
    q = s[kw] + kbar * kbar * (e2 - sbar) / tau
    s[kw] = min(max(q, 0.0), params[p + _HWALK_MAX])
    s[kw + 1] += min(tw / tau, 1.0) * (ybar * ybar / sbar - s[kw + 1])


@kernel
def eskf_reset(s, k, params):  # type: ignore[no-untyped-def]
    """Initial covariance and an empty history (after the attitude's (re)initialisation)."""
    p = P_FILTER
    for i in range(_MAGF):
        s[k + i] = 0.0
    for i in range(_MSCR, _N_STATE):
        s[k + i] = 0.0
    km = k + _MAGF
    if not (s[km + MF_P] > 0.0):  # nothing learnt yet (a re-initialisation keeps the magnetometer model)
        mag_model_reset(s, km, params[p + _MAGF_P : p + _MAGF_P + MP_LEN])
    s[km + MF_T] = 0.0  # the clock restarts
    s[km + MF_STEP_T] = -1.0e9
    kp = k + _P
    s[kp + 0] = s[kp + N + 1] = params[p + _P0_TILT]
    s[kp + 2 * N + 2] = params[p + _P0_HEADING]
    for i in range(6, 9):
        s[kp + i * N + i] = params[p + _P0_BIAS]
    # the declination starts from the WMM's (the pipeline rotates GNSS velocities by it) with its prior σ;
    # a re-initialisation aligns the heading with the compass again and so starts it afresh too
    s[kp + _I_DECL * N + _I_DECL] = params[p + _DECL_P0]
    for i in range(_I_SCALE, _I_SCALE + 3):  # the gyro's scale-factor errors (0: not estimated; ŝ restarts at 0)
        s[kp + i * N + i] = params[p + _SCALE_P0]
    for i in range(_I_ABIAS, _I_ABIAS + 3):  # the accelerometer's bias (0: not estimated; b̂_a restarts at 0)
        s[kp + i * N + i] = params[p + _ABIAS_P0]
    if params[p + _DRAG_K] > 0.0:
        # a multirotor may start in flight: its velocity is unknown (the drag measurement tells it)
        for i in range(3, 6):
            s[kp + i * N + i] = _P0_VEL_FLYING
    rest_reset(s, k + _REST)
    s[k + _REST_N] = 0.0
    s[k + _REST_VIB] = 0.0
    s[k + _LAST_FIX] = -1.0
    s[k + _PREJ_T] = -1.0
    for i in range(3):
        s[k + _PREV_POS + i] = math.nan
    s[k + _LAST_MAG] = -1.0e9
    s[k + _GREJ] = -1.0
    s[k + _DREJ] = -1.0
    s[k + _T_OPEN] = -1.0e9
    s[k + _BIG] = -1.0
    for i in range(3):
        s[k + _PREV_VEL + i] = math.nan
    for i in range(6):
        s[k + _PREV_IMU + i] = math.nan
    s[k + _STARTED] = 0.0 if params[p + _INIT_AVG] > 0.0 else 1.0
    mag_noise_reset(s, k, params)


@kernel
def eskf_reopen_attitude(s, k, params, big_tilt, big_heading):  # type: ignore[no-untyped-def]
    """Attitude covariance re-opened (at least its initial values, or the variances given), uncorrelated."""
    kp = k + _P
    s[k + _T_OPEN] = s[k + _CLK]
    s[k + _BNOW] = params[P_FILTER + _ATT_STEP]
    for i in range(3):
        for j in range(N):
            s[kp + i * N + j] = 0.0
            s[kp + j * N + i] = 0.0
    s[kp + 0] = s[kp + N + 1] = max(params[P_FILTER + _P0_TILT], big_tilt)
    s[kp + 2 * N + 2] = max(params[P_FILTER + _P0_HEADING], big_heading)
    # the low-passed gravity reference was built in a frame now doubted: it is built again from
    # the samples to come (averaged over its τ, then filtered), in the frame the attitude goes to
    s[k + _GLP + 3] = 0.0
    for m in range(6):  # … and so are the scale and bias states' sensitivities (J and K, see step)
        s[k + _JLP + m * BW_LEN + 3] = 0.0
    for m in range(3):  # … and the accelerometer bias's (LP[C], see step)
        s[k + _CLP + m * BW_LEN + 3] = 0.0


@kernel
def _restart_velocity(s, k, vn, ve, vd, r_h, r_v):  # type: ignore[no-untyped-def]
    """Velocity := the fix (unknown components 0 with a large variance), uncorrelated with the rest."""
    kp = k + _P
    for i in range(3, 6):
        for j in range(N):
            s[kp + i * N + j] = 0.0
            s[kp + j * N + i] = 0.0
    s[k + _V] = vn if math.isfinite(vn) else 0.0
    s[k + _V + 1] = ve if math.isfinite(ve) else 0.0
    s[k + _V + 2] = vd if math.isfinite(vd) else 0.0
    s[kp + 3 * N + 3] = r_h if math.isfinite(vn) else 100.0
    s[kp + 4 * N + 4] = r_h if math.isfinite(ve) else 100.0
    s[kp + 5 * N + 5] = r_v if math.isfinite(vd) else 100.0
    s[k + _HCOUNT] = 0.0
    s[k + _VREJ] = 0.0


@kernel(inline=True)
def _drag_reopen_velocity(s, k):  # type: ignore[no-untyped-def]
    """Every drag measurement rejected for ``drag_reset_s``: the velocity is no longer known.

    As an autopilot resets a rejected aiding source (ArduPilot EKF3's velocity reset after a rejection
    timeout), the velocity's variance is re-opened to a start in flight's (``_P0_VEL_FLYING``) and its
    correlations with the rest cleared, so that the next drag measurement passes the gate and pulls the
    velocity back instead of the attitude following a velocity that has random-walked unobserved.
    """
    kp = k + _P
    for i in range(3, 6):
        for j in range(N):
            s[kp + i * N + j] = 0.0
            s[kp + j * N + i] = 0.0
        s[kp + i * N + i] = _P0_VEL_FLYING


@kernel
def _propagate_covariance(s, k, dt, q_gyro, q_accel, q_bias, q_axis, q_pos, pos_on, scale_on, q_scale, wx, wy, wz,
                          abias_on, phi_a, q_abias):  # type: ignore[no-untyped-def]
    """P ← Φ P Φᵀ + Q·dt, Φ = I + F·dt (blocks δθ̇ = −C δb − C diag(ω) δs, δv̇ = M δθ − C δb_a with M = −[f]×,
    δṗ = δv, δḃ_a = −δb_a/τ_a; scratch C, M).

    The thrust-axis states (9, 10) are constant (Φ's identity rows), their random walk ``q_axis``; so is
    the declination error (11), without a walk (the WMM's error does not change over a flight).  The
    position's rows and columns (12–14) are left at 0 while no position is started (``pos_on`` False):
    they cost nothing then, and a start sets them from the fix.  The gyro's scale-factor errors (15–17),
    with ω the rate used this sample, are constant but for ``q_scale``; left at 0 unless ``scale_on``.  The
    accelerometer's bias (18–20, body frame) is a first-order Gauss–Markov process: its rows of Φ are
    ``phi_a`` = 1 − dt/τ_a (1: constant), its noise ``q_abias`` = 2σ_a²/τ_a; left at 0 unless ``abias_on``.
    """
    kp = k + _P
    ka = k + _A
    kc = k + _C
    km = k + _M
    n = N if abias_on else (_I_ABIAS if scale_on else (_I_SCALE if pos_on else _I_POS))
    # A = Φ P
    for j in range(n):
        for i in range(3):
            acc = 0.0
            for m in range(3):
                acc += s[kc + 3 * i + m] * s[kp + (6 + m) * N + j]
            if scale_on:
                acc += s[kc + 3 * i] * wx * s[kp + _I_SCALE * N + j]
                acc += s[kc + 3 * i + 1] * wy * s[kp + (_I_SCALE + 1) * N + j]
                acc += s[kc + 3 * i + 2] * wz * s[kp + (_I_SCALE + 2) * N + j]
            s[ka + i * N + j] = s[kp + i * N + j] - dt * acc
            acc = 0.0
            for m in range(3):
                acc += s[km + 3 * i + m] * s[kp + m * N + j]
            if abias_on:  # … − C δb_a
                for m in range(3):
                    acc -= s[kc + 3 * i + m] * s[kp + (_I_ABIAS + m) * N + j]
            s[ka + (3 + i) * N + j] = s[kp + (3 + i) * N + j] + dt * acc
            s[ka + (6 + i) * N + j] = s[kp + (6 + i) * N + j]
        for r in range(9, _I_POS):
            s[ka + r * N + j] = s[kp + r * N + j]
        if pos_on:
            for i in range(3):  # δṗ = δv
                s[ka + (_I_POS + i) * N + j] = s[kp + (_I_POS + i) * N + j] + dt * s[kp + (3 + i) * N + j]
        elif scale_on or abias_on:
            for r in range(_I_POS, _I_SCALE):
                s[ka + r * N + j] = s[kp + r * N + j]
        if scale_on or abias_on:
            for r in range(_I_SCALE, _I_ABIAS):
                s[ka + r * N + j] = s[kp + r * N + j]
        if abias_on:
            for r in range(_I_ABIAS, N):
                s[ka + r * N + j] = phi_a * s[kp + r * N + j]
    # P = A Φᵀ
    for i in range(n):
        for j in range(3):
            acc = 0.0
            for m in range(3):
                acc += s[ka + i * N + 6 + m] * s[kc + 3 * j + m]
            if scale_on:
                acc += s[ka + i * N + _I_SCALE] * s[kc + 3 * j] * wx
                acc += s[ka + i * N + _I_SCALE + 1] * s[kc + 3 * j + 1] * wy
                acc += s[ka + i * N + _I_SCALE + 2] * s[kc + 3 * j + 2] * wz
            s[kp + i * N + j] = s[ka + i * N + j] - dt * acc
            acc = 0.0
            for m in range(3):
                acc += s[ka + i * N + m] * s[km + 3 * j + m]
            if abias_on:
                for m in range(3):
                    acc -= s[ka + i * N + _I_ABIAS + m] * s[kc + 3 * j + m]
            s[kp + i * N + 3 + j] = s[ka + i * N + 3 + j] + dt * acc
            s[kp + i * N + 6 + j] = s[ka + i * N + 6 + j]
        for j in range(9, _I_POS):
            s[kp + i * N + j] = s[ka + i * N + j]
        if pos_on:
            for j in range(3):
                s[kp + i * N + _I_POS + j] = s[ka + i * N + _I_POS + j] + dt * s[ka + i * N + 3 + j]
        elif scale_on or abias_on:
            for j in range(_I_POS, _I_SCALE):
                s[kp + i * N + j] = s[ka + i * N + j]
        if scale_on or abias_on:
            for j in range(_I_SCALE, _I_ABIAS):
                s[kp + i * N + j] = s[ka + i * N + j]
        if abias_on:
            for j in range(_I_ABIAS, N):
                s[kp + i * N + j] = phi_a * s[ka + i * N + j]
    for i in range(3):
        s[kp + i * N + i] += q_gyro * dt
        s[kp + (3 + i) * N + 3 + i] += q_accel * dt
        s[kp + (6 + i) * N + 6 + i] += q_bias * dt
    if q_pos > 0.0:
        for i in range(_I_POS, _I_SCALE):
            if s[kp + i * N + i] > 0.0:  # (a position not started stays at 0)
                s[kp + i * N + i] += q_pos * dt
    if q_axis > 0.0:
        for i in range(9, _I_DECL):
            s[kp + i * N + i] += q_axis * dt
    if scale_on and q_scale > 0.0:
        for i in range(_I_SCALE, _I_ABIAS):
            s[kp + i * N + i] += q_scale * dt
    if abias_on and q_abias > 0.0:
        for i in range(_I_ABIAS, N):
            s[kp + i * N + i] += q_abias * dt
    # keep P symmetric against round-off
    for i in range(n):
        for j in range(i + 1, n):
            a = 0.5 * (s[kp + i * N + j] + s[kp + j * N + i])
            s[kp + i * N + j] = a
            s[kp + j * N + i] = a


@kernel(inline=True)
def _accel_bias_variance(s, k, params):  # type: ignore[no-untyped-def]
    """The accelerometer-bias states' steady-state variance, (m/s²)²: σ_a² (``accel_bias_sigma_m_s2``) plus
    c² × the specific force's measured per-sample variance (``accel_bias_vibration_ratio``; ``_VIB``): a
    vibrating raw IMU's aliased vibration leaves a slowly varying offset that grows with the vibration."""
    p = P_FILTER
    return params[p + _ABIAS_P0] + params[p + _ABIAS_VIB] * s[k + _VIB + 1]


@kernel(inline=True)
def _accel_bias_gate_ok(s, k, params):  # type: ignore[no-untyped-def]
    """The accelerometer-bias states may be estimated now: the INS horizontal speed is below
    ``accel_bias_live_speed_m_s`` (0: at any speed)."""
    lim = params[P_FILTER + _ABIAS_SPEED]
    return lim <= 0.0 or s[k + _V] * s[k + _V] + s[k + _V + 1] * s[k + _V + 1] < lim * lim


@kernel(inline=True)
def _accel_bias_decouple(s, k):  # type: ignore[no-untyped-def]
    """The accelerometer-bias states' correlations with the rest cleared (their variances kept): held, not
    estimated (``accel_bias_aided_only`` while not aided)."""
    kp = k + _P
    for i in range(_I_ABIAS, N):
        for j in range(N):
            if j != i:
                s[kp + i * N + j] = 0.0
                s[kp + j * N + i] = 0.0


@kernel(inline=True)
def _rate_noise(s, k, dt, wx, wy, wz, q_sf, q_ma):  # type: ignore[no-untyped-def]
    """The gyro's scale-factor and cross-axis errors as process noise of the heading, proportional to the rate.

    An error matrix E (scale σ_sf on the diagonal, misalignment σ_ma off it) turns the body rate ω into a
    rate error E ω, body axis i's variance σ_sf² ω_i² + σ_ma² (‖ω‖² − ω_i²); taken as a first-order
    Gauss–Markov error of correlation time τ its white-noise equivalent density is 2 σ² τ (Gelb 1974, table
    4.4-1; the integrated error's variance 2 σ² τ T for T ≫ τ), and in the NED error state δθ̇ = C (E ω).
    Only its down component is added, to the heading's variance: P_DD += Σ_i C_Di² q_i dt (scratch C =
    C_body_to_ned; ``q_sf`` = 2 σ_sf² τ, ``q_ma`` = 2 σ_ma² τ, s).  The tilt's share is left out: every
    GNSS velocity fix observes the tilt, so a rate error there is corrected within a second (the tilt's
    share, coherent over a manoeuvre, is :func:`_scale_noise_tilt`'s), and the tilt σ is already conservative (firmware_sim: error 0.3° RMS at σ 0.5°); added, it raised the tilt σ in
    every manoeuvre and delayed the monitor's 2° tilt step (PX4 SITL aggressive 1.2 → 4.8 s).  The heading
    is observed only by the magnetometer and by horizontal acceleration: a fast yaw's scale error stays.
    """
    kc = k + _C
    w2 = wx * wx + wy * wy + wz * wz
    d0 = (q_sf - q_ma) * wx * wx + q_ma * w2
    d1 = (q_sf - q_ma) * wy * wy + q_ma * w2
    d2 = (q_sf - q_ma) * wz * wz + q_ma * w2
    c0, c1, c2 = s[kc + 6], s[kc + 7], s[kc + 8]
    s[k + _P + 2 * N + 2] += (c0 * c0 * d0 + c1 * c1 * d1 + c2 * c2 * d2) * dt


@kernel(inline=True)
def _scale_noise_tilt(s, k, dt, wx, wy, wz, var_sf, tau):  # type: ignore[no-untyped-def]
    """The gyro's scale-factor error as process noise of the tilt, coherent over a manoeuvre.

    A constant scale error s_i on body axis i turns an angle a_i turned about it into an attitude error
    s_i·a_i: after a 360° flip at σ_sf 0.3 %, 1.1° — coherent, not the √T growth of a white noise (a flip of
    0.4 s at 930 °/s would get (σ_sf ω)²·2τT, 3.0° of σ, from :func:`_rate_noise`'s density, which is why that
    term leaves the tilt out).  Here each axis's angle turned is kept with a memory of τ (a_i ← a_i e^(−Δt/τ) +
    |ω_i| Δt, τ ``gyro_scale_tilt_memory_s``: what the GNSS fixes have not yet corrected) and the variance grows as that of s_i·a_i does,
    d(σ_sf² a_i²) = 2 σ_sf² a_i |ω_i| Δt: (σ_sf·angle)² after a manoeuvre short against τ, and 2 σ_sf² τ ω_i²
    per second in a long steady one (the Gauss–Markov density of :func:`_rate_noise`; Gelb 1974, table
    4.4-1).  Mapped to NED, δθ̇ = C (E ω), and added to the tilt block only (N, E: P_ab += Σ_i C_ai C_bi q_i;
    the heading has :func:`_rate_noise`); ``var_sf`` = σ_sf², ``tau`` s.  firmware_sim flips 61 (σ 0.2 % drawn):
    our tilt 1.4° off after the flip at 32.5 s, 0.15° with the scale errors drawn at 0, unchanged without
    cross-axis, vibration or saturation (docs/monitor.md, round eight).
    """
    ka = k + _RANG
    f = math.exp(-dt / tau) if tau > 0.0 else 0.0
    ux, uy, uz = abs(wx) * dt, abs(wy) * dt, abs(wz) * dt
    s[ka] = s[ka] * f + ux
    s[ka + 1] = s[ka + 1] * f + uy
    s[ka + 2] = s[ka + 2] * f + uz
    q0 = 2.0 * var_sf * s[ka] * ux
    q1 = 2.0 * var_sf * s[ka + 1] * uy
    q2 = 2.0 * var_sf * s[ka + 2] * uz
    kc = k + _C
    kp = k + _P
    pnn = s[kc] * s[kc] * q0 + s[kc + 1] * s[kc + 1] * q1 + s[kc + 2] * s[kc + 2] * q2
    pee = s[kc + 3] * s[kc + 3] * q0 + s[kc + 4] * s[kc + 4] * q1 + s[kc + 5] * s[kc + 5] * q2
    pne = s[kc] * s[kc + 3] * q0 + s[kc + 1] * s[kc + 4] * q1 + s[kc + 2] * s[kc + 5] * q2
    s[kp] += pnn
    s[kp + N + 1] += pee
    s[kp + 1] += pne
    s[kp + N] += pne


@kernel
def _boff_reset(s, k):  # type: ignore[no-untyped-def]
    """Forget the body-offset learner's pairs and offset (the raw reading is accepted again)."""
    for i in range(_BOFF, _BOFF_B + 4):
        s[k + i] = 0.0


@kernel
def _boff_step(s, k, params, mx, my, mz, clk):  # type: ignore[no-untyped-def]
    """The body-offset learner (``mag_body_offset_lag_s``), on a reading the schedule rejects: with the
    reading held one lag before, ``m_i − R m_j = (I − R) b`` with ``R = C_iᵀ C_j`` the rotation the gyro
    measured between them (the estimate's attitude error, common to both, cancels: neither heading nor tilt
    is needed), fitted by least squares over the rejected stretch; the offset is valid once the turns make
    every axis observable (least eigenvalue of Σ (I − R)ᵀ(I − R) ≥ ``_BOFF_MIN_TURN``) and the fit explains all
    but ``_BOFF_RESID`` of the pairs' Σ yᵀy (an earth-fixed disturbance changes with the place, not with the
    body: it does not fit; a clean compass's pairs are its calibration remainder and noise, no offset) and the
    offset's standard error along its worst axis (the residual per pair over that eigenvalue) is within ``_BOFF_SIGMA``.  Returns True when the offset is valid."""
    kb = k + _BOFF
    kc = k + _C
    tj = s[kb + 12]
    if tj <= 0.0:  # the first reading of a stretch: the pair's earlier reading
        s[kb], s[kb + 1], s[kb + 2] = mx, my, mz
        for i in range(9):
            s[kb + 3 + i] = s[kc + i]
        s[kb + 12] = max(clk, 1e-9)
    elif clk - tj >= params[P_FILTER + _BOFF_LAG]:
        # R = C_iᵀ C_j (body j → NED → body i), y = m_i − R m_j
        r = s[k + _A : k + _A + 9]  # the Φ·P scratch, free after the propagation
        for a in range(3):
            for b in range(3):
                r[3 * a + b] = (
                    s[kc + a] * s[kb + 3 + b] + s[kc + 3 + a] * s[kb + 6 + b] + s[kc + 6 + a] * s[kb + 9 + b]
                )
        y0 = mx - (r[0] * s[kb] + r[1] * s[kb + 1] + r[2] * s[kb + 2])
        y1 = my - (r[3] * s[kb] + r[4] * s[kb + 1] + r[5] * s[kb + 2])
        y2 = mz - (r[6] * s[kb] + r[7] * s[kb + 1] + r[8] * s[kb + 2])
        # G = I − R; GᵀG = 2I − R − Rᵀ, Gᵀy = y − Rᵀy
        ka = k + _BOFF_A
        s[ka] += 2.0 - 2.0 * r[0]
        s[ka + 1] += -r[1] - r[3]
        s[ka + 2] += -r[2] - r[6]
        s[ka + 3] += 2.0 - 2.0 * r[4]
        s[ka + 4] += -r[5] - r[7]
        s[ka + 5] += 2.0 - 2.0 * r[8]
        s[ka + 6] += y0 - (r[0] * y0 + r[3] * y1 + r[6] * y2)
        s[ka + 7] += y1 - (r[1] * y0 + r[4] * y1 + r[7] * y2)
        s[ka + 8] += y2 - (r[2] * y0 + r[5] * y1 + r[8] * y2)
        s[ka + 9] += y0 * y0 + y1 * y1 + y2 * y2
        s[ka + 10] += 1.0
        s[kb], s[kb + 1], s[kb + 2] = mx, my, mz  # this reading is the next pair's earlier one
        for i in range(9):
            s[kb + 3 + i] = s[kc + i]
        s[kb + 12] = max(clk, 1e-9)
        # the least eigenvalue of the symmetric Σ GᵀG (closed form, Smith 1961)
        a00, a01, a02, a11, a12, a22 = s[ka], s[ka + 1], s[ka + 2], s[ka + 3], s[ka + 4], s[ka + 5]
        q = (a00 + a11 + a22) / 3.0
        p1 = a01 * a01 + a02 * a02 + a12 * a12
        p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1
        pp = math.sqrt(p2 / 6.0)
        lam_min = q
        if pp > 1e-12:
            b00, b11, b22 = (a00 - q) / pp, (a11 - q) / pp, (a22 - q) / pp
            b01, b02, b12 = a01 / pp, a02 / pp, a12 / pp
            det_b = b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02)
            hr = min(max(0.5 * det_b, -1.0), 1.0)
            phi = math.acos(hr) / 3.0
            lam_min = q + 2.0 * pp * math.cos(phi + 2.0 * math.pi / 3.0)
        det = a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02) + a02 * (a01 * a12 - a11 * a02)
        kv = k + _BOFF_B
        s[kv + 3] = 0.0
        if lam_min >= params[P_FILTER + _BOFF_MIN_TURN] and det > 0.0:
            c00 = a11 * a22 - a12 * a12
            c01 = a02 * a12 - a01 * a22
            c02 = a01 * a12 - a02 * a11
            c11 = a00 * a22 - a02 * a02
            c12 = a01 * a02 - a00 * a12
            c22 = a00 * a11 - a01 * a01
            r0, r1, r2 = s[ka + 6], s[ka + 7], s[ka + 8]
            bx = (c00 * r0 + c01 * r1 + c02 * r2) / det
            by = (c01 * r0 + c11 * r1 + c12 * r2) / det
            bz = (c02 * r0 + c12 * r1 + c22 * r2) / det
            ss = s[ka + 9] - (bx * r0 + by * r1 + bz * r2)
            s[kv], s[kv + 1], s[kv + 2] = bx, by, bz
            # … and its standard error along the worst axis, from the residual per pair, within ``_BOFF_SIGMA``
            var_b = max(ss, 0.0) / (s[ka + 10] * lam_min)
            if ss <= params[P_FILTER + _BOFF_RESID] * s[ka + 9] and var_b <= params[P_FILTER + _BOFF_SIGMA]:
                s[kv + 3] = 1.0
    return s[k + _BOFF_B + 3] > 0.0


@kernel(inline=True)
def _n_active(s, k):  # type: ignore[no-untyped-def]
    """The error state's size in use: without the gyro scale-factor states (or the accelerometer-bias states)
    their rows and columns of P (and of P hᵀ, δx) stay 0, and the scalar updates' loops leave them out (the
    daemon's per-sample cost).  Any of the three bias variances counts: started across a thrust axis that is
    exactly a body axis (``accel_bias_across_thrust``), that axis's own variance is 0 while the others are not."""
    kb = k + _P + _I_ABIAS * N + _I_ABIAS
    if s[kb] > 0.0 or s[kb + N + 1] > 0.0 or s[kb + 2 * N + 2] > 0.0:
        return N
    return _I_ABIAS if s[k + _P + _I_SCALE * N + _I_SCALE] > 0.0 else _I_SCALE


@kernel(inline=True)
def _innovation(s, k, y, r):  # type: ignore[no-untyped-def]
    """For a scalar update, h in scratch: P hᵀ into scratch (``_PH``) and (innovation less what this
    sample's corrections already explain, its variance h P hᵀ + r)."""
    kp = k + _P
    kh = k + _H
    kph = k + _PH
    kdx = k + _DX
    n = _n_active(s, k)
    hs = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += s[kp + i * N + j] * s[kh + j]
        s[kph + i] = acc
        hs += s[kh + i] * s[kdx + i]
    y -= hs  # what the corrections already found this sample explain
    sv = r
    for i in range(n):
        sv += s[kh + i] * s[kph + i]
    return y, sv


@kernel(inline=True)
def _rest_is_hovering(s, k, params, p):  # type: ignore[no-untyped-def]
    """A detected rest is a hovering one (the rotors run, the vehicle hardly moves through the air).

    The rotors run where the accelerometer's vibration (RMS of its deviation from the detector's
    0.5 s low-pass, averaged over 1 s: ``_REST_VIB``) exceeds ``rest_hover_vibration_m_s2`` (0: not
    asked); the vehicle hovers where the INS velocity's horizontal speed (the drag model's
    airspeed without wind) is below ``rest_hover_speed_m_s`` (0: not asked).
    """
    v_min = params[p + _REST_HOVER_VIB]
    if v_min > 0.0 and not (s[k + _REST_VIB] > v_min * v_min):
        return False
    v_max = params[p + _REST_HOVER_SPEED]
    if v_max > 0.0:
        vn, ve = s[k + _V], s[k + _V + 1]
        if not (vn * vn + ve * ve < v_max * v_max):
            return False
    return True


@kernel
def _rest_rate_update(s, k, params, p):  # type: ignore[no-untyped-def]
    r"""The low-passed gyro ω̄ at detected rest as a measurement of the bias: ω̄ = b + ω_wob + e.

    ``e`` is the low-pass's white noise (R = ``rest_rate_noise_rad_s``²).  ``ω_wob`` is the
    rate across the vertical a *hovering* rest may hide: a multirotor's specific force is its
    thrust, fixed in the body, so a hover's slow tilting wobble moves nothing the detector sees,
    and its 0.5 s low-pass carries it as a bias.  In a hovering rest (``_rest_is_hovering``) the
    measurement is split on the body-frame vertical u (the detector's low-passed specific force,
    normalised) and two axes e₁, e₂ across it; along u z_u = uᵀ(ω̄ − b̂) with R, across it
    z_i = e_iᵀ(ω̄ − b̂) with ω_wob one constant over the rest (variance σ_w² =
    ``rest_wobble_sigma_rad_s``²) while e is white, so a rest of n updates carries across the
    vertical at most the information of its mean, 1 / (σ_w² + R/n) (colored measurement noise:
    Gelb 1974 §4.6, here the constant's limit): the n-th update fuses the increment
    R_n = 1 / (1/(σ_w² + R/n) − 1/(σ_w² + R/(n−1))), the first σ_w² + R, the next ones almost
    nothing.  Otherwise (σ_w = 0, or a rest not hovering) all three axes with R every update (as
    before).  Returns True when anything was fused.
    """
    r = params[p + _R_REST_RATE]
    q_wob = params[p + _REST_WOBBLE_VAR]
    updated = False
    if q_wob <= 0.0 or not _rest_is_hovering(s, k, params, p):
        for c in range(3):
            for i in range(N):
                s[k + _H + i] = 0.0
            s[k + _H + 6 + c] = 1.0
            if _scalar_update(s, k, s[k + _REST + c] - s[S_BIAS + c], r, 1.0e6, s[k + _BNOW]):
                updated = True
        return updated
    # the body-frame vertical from the detector's low-passed specific force
    ux, uy, uz = s[k + _REST + 3], s[k + _REST + 4], s[k + _REST + 5]
    nu = math.sqrt(ux * ux + uy * uy + uz * uz)
    if not (nu > 0.0):
        return False
    ux, uy, uz = ux / nu, uy / nu, uz / nu
    # e1 ⟂ u from the body axis least aligned with u, e2 = u × e1
    if abs(ux) <= abs(uy) and abs(ux) <= abs(uz):
        ax_, ay_, az_ = 1.0, 0.0, 0.0
    elif abs(uy) <= abs(uz):
        ax_, ay_, az_ = 0.0, 1.0, 0.0
    else:
        ax_, ay_, az_ = 0.0, 0.0, 1.0
    d = ax_ * ux + ay_ * uy + az_ * uz
    e1x, e1y, e1z = ax_ - d * ux, ay_ - d * uy, az_ - d * uz
    n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x, e1y, e1z = e1x / n1, e1y / n1, e1z / n1
    e2x, e2y, e2z = uy * e1z - uz * e1y, uz * e1x - ux * e1z, ux * e1y - uy * e1x
    # this hovering rest's update count (restarts when the detector's rest ends)
    s[k + _REST_N] += 1.0
    n_upd = s[k + _REST_N]
    info_h = 1.0 / (q_wob + r / n_upd)
    if n_upd > 1.0:
        info_h -= 1.0 / (q_wob + r / (n_upd - 1.0))
    for a in range(3):
        if a < 2 and not (info_h > 0.0):
            continue
        if a == 0:
            hx, hy, hz, ra = e1x, e1y, e1z, 1.0 / info_h
        elif a == 1:
            hx, hy, hz, ra = e2x, e2y, e2z, 1.0 / info_h
        else:
            hx, hy, hz, ra = ux, uy, uz, r
        for i in range(N):
            s[k + _H + i] = 0.0
        s[k + _H + 6] = hx
        s[k + _H + 7] = hy
        s[k + _H + 8] = hz
        y = (hx * (s[k + _REST] - s[S_BIAS]) + hy * (s[k + _REST + 1] - s[S_BIAS + 1])
             + hz * (s[k + _REST + 2] - s[S_BIAS + 2]))  # fmt: skip
        if _scalar_update(s, k, y, ra, 1.0e6, s[k + _BNOW]):
            updated = True
    return updated


@kernel(inline=True)
def _sensitivity_update(s, k, n, inv, first):  # type: ignore[no-untyped-def]
    """A scalar update's effect on the error's sensitivity to the bias the filter does not estimate
    (``accel_bias_consider_sigma_m_s2``; Maybeck 1979, §6.11, sensitivity analysis): S ← S − K (h S + h_b), K the
    filter's own gain P hᵀ/S (in scratch: P hᵀ, h; ``inv`` = 1/S), h_b the measurement's own sensitivity to the bias
    (``_SENS_HB``, 0 for all but the gravity measurement); rows below ``first`` get no gain (the tilt *considered* by
    the heading)."""
    ks = k + _SENS
    kh = k + _H
    kph = k + _PH
    for j in range(3):
        hs = s[k + _SENS_HB + j]
        for i in range(n):
            hs += s[kh + i] * s[ks + 3 * i + j]
        if hs != 0.0:
            for i in range(first, n):
                s[ks + 3 * i + j] -= s[kph + i] * inv * hs


@kernel(inline=True)
def _propagate_sensitivity(s, k, dt, n, pos_on, scale_on, wx, wy, wz, abias_on, phi_a):  # type: ignore[no-untyped-def]
    """S ← Φ S + Γ dt for the error's sensitivity to a constant accelerometer bias b the filter does not estimate
    (``accel_bias_consider_sigma_m_s2``): Φ as :func:`_propagate_covariance`'s, Γ the bias's way into the
    velocity, δv̇ = … − C b (the rows of the velocity, the position and the attitude in this order: each
    block from the old values of the one before)."""
    ks = k + _SENS
    kc = k + _C
    km = k + _M
    for j in range(3):
        if pos_on:
            for i in range(3):
                s[ks + 3 * (_I_POS + i) + j] += dt * s[ks + 3 * (3 + i) + j]
        for i in range(3):
            acc = -s[kc + 3 * i + j]
            for m in range(3):
                acc += s[km + 3 * i + m] * s[ks + 3 * m + j]
            if abias_on:
                for m in range(3):
                    acc -= s[kc + 3 * i + m] * s[ks + 3 * (_I_ABIAS + m) + j]
            s[ks + 3 * (3 + i) + j] += dt * acc
        for i in range(3):
            acc = 0.0
            for m in range(3):
                acc += s[kc + 3 * i + m] * s[ks + 3 * (6 + m) + j]
            if scale_on:
                acc += s[kc + 3 * i] * wx * s[ks + 3 * _I_SCALE + j]
                acc += s[kc + 3 * i + 1] * wy * s[ks + 3 * (_I_SCALE + 1) + j]
                acc += s[kc + 3 * i + 2] * wz * s[ks + 3 * (_I_SCALE + 2) + j]
            s[ks + 3 * i + j] -= dt * acc
        if abias_on:
            for i in range(_I_ABIAS, n):
                s[ks + 3 * i + j] *= phi_a


@kernel
def _scalar_update(s, k, y, r, gate, bound):  # type: ignore[no-untyped-def]
    """One scalar measurement: innovation ``y`` (before this update's δx), h in scratch, noise ``r``.

    Returns False (and changes nothing) when the innovation fails the χ gate.  ``bound`` > 0: the attitude
    part of the correction is at most this, rad (``max_attitude_step_rad``): beyond it the innovation's
    variance is raised until it is (the noise inflated, R' = S' − h P hᵀ; the covariance updated with the
    same S', so it shrinks only by what that weaker measurement tells).
    """
    kp = k + _P
    kph = k + _PH
    kdx = k + _DX
    y, sv = _innovation(s, k, y, r)
    if not (sv > 0.0) or y * y > gate * gate * sv:
        return False
    if bound > 0.0:
        d = abs(y) * math.sqrt(s[kph] * s[kph] + s[kph + 1] * s[kph + 1] + s[kph + 2] * s[kph + 2])
        if d > bound * sv:
            sv = d / bound
    n = _n_active(s, k)
    inv = 1.0 / sv
    if s[k + _SENS_ON] > 0.0:
        _sensitivity_update(s, k, n, inv, 0)
    if s[k + _ABIAS_HELD] > 0.0 and n > _I_ABIAS:
        # the accelerometer-bias states considered (Schmidt): gain 0 on their rows, their own block kept
        for i in range(n):
            if not _I_ABIAS <= i < _I_ABIAS + 3:
                s[kdx + i] += s[kph + i] * inv * y
        for i in range(n):
            ki = s[kph + i] * inv
            for j in range(n):
                if not (_I_ABIAS <= i < _I_ABIAS + 3 and _I_ABIAS <= j < _I_ABIAS + 3):
                    s[kp + i * N + j] -= ki * s[kph + j]
        return True
    for i in range(n):
        s[kdx + i] += s[kph + i] * inv * y
    for i in range(n):
        ki = s[kph + i] * inv
        for j in range(n):
            s[kp + i * N + j] -= ki * s[kph + j]
    return True


@kernel
def _heading_update(s, k, y, r, gate):  # type: ignore[no-untyped-def]
    """The magnetometer's heading, h = [h_N, h_E, −1, 0…] in scratch, with the tilt *considered*
    (Schmidt 1966): the tilt's uncertainty enters the innovation's variance and the heading keeps its
    correlation with the tilt, but the gain on the tilt rows is 0 and the tilt's own covariance block
    is left as it is (the magnetometer never moves the tilt).  Returns False (and changes nothing) when
    the innovation fails the χ gate.
    """
    kp = k + _P
    kph = k + _PH
    kdx = k + _DX
    y, sv = _innovation(s, k, y, r)
    if not (sv > 0.0) or y * y > gate * gate * sv:
        return False
    n = _n_active(s, k)
    inv = 1.0 / sv
    if s[k + _SENS_ON] > 0.0:
        _sensitivity_update(s, k, n, inv, 2)
    for i in range(2, n):
        s[kdx + i] += s[kph + i] * inv * y
    # Joseph form with the gain 0 on the tilt rows: P − K uᵀ − u Kᵀ + K S Kᵀ, u = P hᵀ, K = u/S off the
    # tilt: the standard update everywhere but in the tilt's own block, which keeps its value
    for i in range(n):
        ki = s[kph + i] * inv
        for j in range(n):
            if i >= 2 or j >= 2:
                s[kp + i * N + j] -= ki * s[kph + j]
    return True


@kernel
def _history_velocity(s, k, t, out3):  # type: ignore[no-untyped-def]
    """The INS velocity at clock time ``t`` from the history (linear between entries); False if not held."""
    n = min(int(s[k + _HCOUNT]), HISTORY_LEN)
    pos = int(s[k + _HPOS])
    if n <= 0 or not 0 <= pos < HISTORY_LEN:
        return False
    newest = (pos - 1) % HISTORY_LEN
    kh = k + _HIST
    if t >= s[kh + 4 * newest]:
        for i in range(3):
            out3[i] = s[k + _V + i]
        return True
    later = newest
    for back in range(1, n):
        idx = (newest - back) % HISTORY_LEN
        te = s[kh + 4 * idx]
        if te <= t:
            tl = s[kh + 4 * later]
            w = (t - te) / (tl - te) if tl > te else 0.0
            for i in range(3):
                out3[i] = s[kh + 4 * idx + 1 + i] + w * (s[kh + 4 * later + 1 + i] - s[kh + 4 * idx + 1 + i])
            return True
        later = idx
    return False


@kernel(inline=True)
def _drag_update_prepare(s, k, params, ax, ay, az, dt):  # type: ignore[no-untyped-def]
    """Thrust axis (running mean of the drag-corrected specific force's body direction); the force's integral.

    The drag-corrected force f + k·v_b (v_b = Cᵀ v) is the thrust alone: its direction does not swing
    with the vehicle's sustained body-frame velocity as the raw force's does (forward flight).
    """
    kc = k + _C
    k_drag = params[P_FILTER + _DRAG_K]
    vn, ve, vd = s[k + _V], s[k + _V + 1], s[k + _V + 2]
    bx = ax + k_drag * (s[kc + 0] * vn + s[kc + 3] * ve + s[kc + 6] * vd)
    by = ay + k_drag * (s[kc + 1] * vn + s[kc + 4] * ve + s[kc + 7] * vd)
    bz = az + k_drag * (s[kc + 2] * vn + s[kc + 5] * ve + s[kc + 8] * vd)
    n = math.sqrt(bx * bx + by * by + bz * bz)
    kt = k + _TAX
    s[k + _FSUM] += ax * dt
    s[k + _FSUM + 1] += ay * dt
    s[k + _FSUM + 2] += az * dt
    s[k + _FSUM + 3] += dt
    if not n > 0.0 or params[P_FILTER + _AXIS_P0] > 0.0:  # (states: the axis is estimated by the updates)
        return
    t2 = s[kt] * s[kt] + s[kt + 1] * s[kt + 1] + s[kt + 2] * s[kt + 2]
    # the mean since the start while shorter than the time constant (no weight on the first sample alone)
    w = 1.0 if t2 == 0.0 else min(dt / min(params[P_FILTER + _THRUST_TAU], max(s[k + _CLK], dt)), 1.0)
    s[kt] += (bx / n - s[kt]) * w
    s[kt + 1] += (by / n - s[kt + 1]) * w
    s[kt + 2] += (bz / n - s[kt + 2]) * w


@kernel(inline=True)
def _axis_basis(tx, ty, tz, ref):  # type: ignore[no-untyped-def]
    """Unit axis t and two unit body axes across it: e1 = the body axis ``ref`` made orthogonal to t, e2 = t × e1."""
    tn = math.sqrt(tx * tx + ty * ty + tz * tz)
    tx, ty, tz = tx / tn, ty / tn, tz / tn
    ax, ay, az = (1.0, 0.0, 0.0) if ref == 0 else ((0.0, 1.0, 0.0) if ref == 1 else (0.0, 0.0, 1.0))
    d = ax * tx + ay * ty + az * tz
    e1x, e1y, e1z = ax - d * tx, ay - d * ty, az - d * tz
    en = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x, e1y, e1z = e1x / en, e1y / en, e1z / en
    return tx, ty, tz, e1x, e1y, e1z, ty * e1z - tz * e1y, tz * e1x - tx * e1z, tx * e1y - ty * e1x


#: the thrust axis's error basis (``best``'s multirotor detection projects on the same axes)
axis_basis = _axis_basis


@kernel(inline=True)
def _least_aligned(tx, ty, tz):  # type: ignore[no-untyped-def]
    """The body axis (0, 1, 2) least aligned with t."""
    if abs(tx) <= abs(ty) and abs(tx) <= abs(tz):
        return 0
    return 1 if abs(ty) <= abs(tz) else 2


@kernel(inline=True)
def _axis_start(s, k, tx, ty, tz, p0, pa):  # type: ignore[no-untyped-def]
    """The thrust-axis states start at the unit body vector t, variance ``p0``, uncorrelated with the rest.

    ``pa`` > 0 (``accel_bias_across_thrust``): the accelerometer-bias states start afresh across t only,
    P_ba = pa (I − t tᵀ), uncorrelated with the rest, and the estimate loses its part along t.
    """
    kt = k + _TAX
    s[kt], s[kt + 1], s[kt + 2] = tx, ty, tz
    s[k + _TREF] = _least_aligned(tx, ty, tz)
    kp = k + _P
    for i in range(9, _I_DECL):  # the two axis states only (the declination, 11, keeps its own prior)
        for j in range(N):
            s[kp + i * N + j] = 0.0
            s[kp + j * N + i] = 0.0
        s[kp + i * N + i] = p0
    if pa > 0.0:
        ka = k + _ABIAS
        along = s[ka] * tx + s[ka + 1] * ty + s[ka + 2] * tz
        s[ka] -= along * tx
        s[ka + 1] -= along * ty
        s[ka + 2] -= along * tz
        for i in range(_I_ABIAS, _I_ABIAS + 3):
            for j in range(N):
                s[kp + i * N + j] = 0.0
                s[kp + j * N + i] = 0.0
        for i in range(3):
            ti = tx if i == 0 else (ty if i == 1 else tz)
            for j in range(3):
                tj = tx if j == 0 else (ty if j == 1 else tz)
                s[kp + (_I_ABIAS + i) * N + _I_ABIAS + j] = pa * ((1.0 if i == j else 0.0) - ti * tj)


@kernel
def _axis_start_check(s, k, params):  # type: ignore[no-untyped-def]
    """At the end of the start window: a thrust axis (states) farther from the window's mean specific force
    (body frame) than ``initial_realign_rad`` restarts from that mean's direction with its prior σ.

    The axis starts from the first 0.1 s mean; a vibrating raw IMU's is 60–75° off its thrust axis
    (firmware_sim raw ``vibration`` 23 / 31; their 2 s means 12° / 10.5°), beyond the prior's σ 15°:
    every later drag innovation then failed the gate and the axis stayed 75–105° off all flight.  The
    same check the attitude's start gets (the mean against the estimate, ``initial_average_s``).
    """
    kt = k + _TAX
    tx, ty, tz = s[kt], s[kt + 1], s[kt + 2]
    tn = math.sqrt(tx * tx + ty * ty + tz * tz)
    ta = s[k + _ASUM + 3]
    p0 = params[P_FILTER + _AXIS_P0]
    if not (p0 > 0.0 and tn > 0.5 and ta > 0.0):
        return
    mx, my, mz = s[k + _ASUM] / ta, s[k + _ASUM + 1] / ta, s[k + _ASUM + 2] / ta
    m = math.sqrt(mx * mx + my * my + mz * mz)
    if not m > 0.5 * G_M_S2:
        return
    if (mx * tx + my * ty + mz * tz) < params[P_FILTER + _INIT_COS] * m * tn:
        _axis_start(s, k, mx / m, my / m, mz / m, p0, params[P_FILTER + _ABIAS_ACROSS])


@kernel
def _drag_update(s, k, params, k_drag):  # type: ignore[no-untyped-def]
    """Rotor drag: the mean specific force across the thrust axis = −k × the body velocity across it.

    With ``v_b = Cᵀ v`` and a body axis e across the thrust axis, u = C e (NED):
    h = −k uᵀv, ∂h/∂δv = −k uᵀ, ∂h/∂δθ = −k (u × v)ᵀ (q_true = exp(δθ/2) ⊗ q: v_b,true = v_b + Cᵀ(v × δθ)).
    Leishman et al. 2014, eqs. (9)–(10).  With the thrust axis as states (``thrust_axis_sigma_rad``):
    t_true = t + α₁e₁ + α₂e₂ turns e_c to e_c − α_c t, so h_c = −k e_cᵀv_b + α_c tᵀ(f + k v_b) and
    ∂h_c/∂α_c = tᵀ(f + k v_b) (the thrust's specific force, ≈ g in hover); the axis starts as the
    first period's mean specific-force direction with σ = ``thrust_axis_sigma_rad``.
    Returns True if a component was fused.
    """
    kt = k + _TAX
    tx, ty, tz = s[kt], s[kt + 1], s[kt + 2]
    tn = math.sqrt(tx * tx + ty * ty + tz * tz)
    cnt = s[k + _FSUM + 3]
    fx, fy, fz = s[k + _FSUM] / cnt, s[k + _FSUM + 1] / cnt, s[k + _FSUM + 2] / cnt
    for i in range(4):
        s[k + _FSUM + i] = 0.0
    p0 = params[P_FILTER + _AXIS_P0]
    states = p0 > 0.0
    if states and tn == 0.0:
        # the prior: this period's mean specific-force direction (the thrust's, but for drag and
        # accelerations: a start in forward flight is ≈ 10° off, within the prior's σ); checked against
        # the start window's body-frame mean once that is over (``_axis_start_check``)
        fn_ = math.sqrt(fx * fx + fy * fy + fz * fz)
        if not fn_ > 0.5 * G_M_S2:
            return False
        tx, ty, tz = fx / fn_, fy / fn_, fz / fn_
        _axis_start(s, k, tx, ty, tz, p0, params[P_FILTER + _ABIAS_ACROSS])
        tn = 1.0
    if not tn > 0.5:  # no steady thrust direction (tumbling, or not yet learnt)
        return False
    ref = int(s[k + _TREF]) if states else _least_aligned(tx, ty, tz)
    tx, ty, tz, e1x, e1y, e1z, e2x, e2y, e2z = _axis_basis(tx, ty, tz, ref)
    kc = k + _C
    vn, ve, vd = s[k + _V], s[k + _V + 1], s[k + _V + 2]
    r = params[P_FILTER + _R_DRAG]
    # the body's quadratic drag beside the rotors' linear one: D = (k + c‖v‖) v (EKF3's ballistic coefficient
    # beside its momentum drag); its Jacobian on v is M = (k + c‖v‖) I + c v vᵀ/‖v‖ (symmetric)
    c_q = params[P_FILTER + _DRAG_C]
    v_norm = math.sqrt(vn * vn + ve * ve + vd * vd)
    k_eff = k_drag + c_q * v_norm
    c_v = c_q / v_norm if v_norm > 1e-6 else 0.0
    thrust = 0.0
    if states:  # tᵀ(f + D_b), D_b = Cᵀ D
        utn = s[kc + 0] * tx + s[kc + 1] * ty + s[kc + 2] * tz
        ute = s[kc + 3] * tx + s[kc + 4] * ty + s[kc + 5] * tz
        utd = s[kc + 6] * tx + s[kc + 7] * ty + s[kc + 8] * tz
        thrust = fx * tx + fy * ty + fz * tz + k_eff * (utn * vn + ute * ve + utd * vd)
    fused = False
    for c in range(2):
        if c == 0:
            ex, ey, ez = e1x, e1y, e1z
        else:
            ex, ey, ez = e2x, e2y, e2z
        un = s[kc + 0] * ex + s[kc + 1] * ey + s[kc + 2] * ez
        ue = s[kc + 3] * ex + s[kc + 4] * ey + s[kc + 5] * ez
        ud = s[kc + 6] * ex + s[kc + 7] * ey + s[kc + 8] * ez
        uv = un * vn + ue * ve + ud * vd
        y = (fx * ex + fy * ey + fz * ez) + k_eff * uv
        # w = M u: h = −uᵀD, ∂h/∂δv = −wᵀ, ∂h/∂δθ = −(w × v)ᵀ (w = k u without the quadratic term)
        wn = k_eff * un + c_v * uv * vn
        we = k_eff * ue + c_v * uv * ve
        wd = k_eff * ud + c_v * uv * vd
        for i in range(N):
            s[k + _H + i] = 0.0
        s[k + _H + 0] = -(we * vd - wd * ve)
        s[k + _H + 1] = -(wd * vn - wn * vd)
        s[k + _H + 2] = -(wn * ve - we * vn)
        s[k + _H + 3] = -wn
        s[k + _H + 4] = -we
        s[k + _H + 5] = -wd
        if states:
            s[k + _H + 9 + c] = thrust
        if ((params[P_FILTER + _ABIAS_P0] > 0.0 or params[P_FILTER + _ABIAS_VIB] > 0.0)
                and params[P_FILTER + _ABIAS_AIDED] == 0.0):  # the mean force (less b̂_a) holds δb_a: ∂h_c/∂δb_a = e_cᵀ
            s[k + _H + _I_ABIAS] = ex
            s[k + _H + _I_ABIAS + 1] = ey
            s[k + _H + _I_ABIAS + 2] = ez
        r_c = r
        tau_nis = params[P_FILTER + _DRAG_NIS_TAU]
        if tau_nis > 0.0:
            # covariance matching (Mehra 1972; Mohamed & Schwarz 1999): E[y²] = h P hᵀ + R, so the innovations'
            # mean square beyond h P hᵀ is the measurement's variance as it is; R is at least that.  Under a raw
            # IMU's aliased vibration P_vv claimed σ 0.3–0.8 m/s against 5–15 m/s errors (docs/accuracy.md,
            # "Twelfth round"): h P hᵀ, which carries the velocity's uncertainty through ∂h/∂v = −(M u)ᵀ, cannot
            # tell that; the innovations do
            # Every innovation counts in the mean (under vibration the large ones are the noise), but one beyond
            # the χ gate of the nominal R is still rejected: a state error (a velocity 20 m/s off) is not taken
            # for noise and fused, its rejections re-open the velocity (``drag_reset_s``) as before
            yy, sv0 = _innovation(s, k, y, 0.0)
            gate = params[P_FILTER + _VEL_GATE]
            # the mean since the start while fewer than τ/T innovations were seen, then exponential over τ
            s[k + _DNIS + 1] += 1.0
            w_n = min(max(params[P_FILTER + _ZV_PERIOD] / tau_nis, 1.0 / s[k + _DNIS + 1]), 1.0)
            s[k + _DNIS] += (yy * yy - sv0 - s[k + _DNIS]) * w_n
            if not (sv0 + r > 0.0) or yy * yy > gate * gate * (sv0 + r):
                continue
            r_c = max(r, s[k + _DNIS])
        if _scalar_update(s, k, y, r_c, params[P_FILTER + _VEL_GATE], s[k + _BNOW]):
            fused = True
    return fused


@kernel
def _history_displacement(s, k, t, out3):  # type: ignore[no-untyped-def]
    """∫ v dt from clock time ``t`` to now over the INS velocity history (trapezoid between entries),
    into ``out3``: the INS position at ``t`` is the position now less this.  False if ``t`` is older than
    the history holds (``out3`` then holds the newest velocity × the time, an estimate)."""
    n = min(int(s[k + _HCOUNT]), HISTORY_LEN)
    pos = int(s[k + _HPOS])
    for i in range(3):
        out3[i] = 0.0
    if n <= 0 or not 0 <= pos < HISTORY_LEN:
        return False
    kh = k + _HIST
    later = (pos - 1) % HISTORY_LEN
    tl = s[kh + 4 * later]
    if t >= tl:
        return True
    for _back in range(1, n):
        idx = (later - 1) % HISTORY_LEN
        te = s[kh + 4 * idx]
        if te <= t:  # the part of [te, tl] after t: v interpolated at t, trapezoid to tl
            w = (t - te) / (tl - te) if tl > te else 0.0
            for i in range(3):
                vt = s[kh + 4 * idx + 1 + i] + w * (s[kh + 4 * later + 1 + i] - s[kh + 4 * idx + 1 + i])
                out3[i] += 0.5 * (vt + s[kh + 4 * later + 1 + i]) * (tl - t)
            return True
        for i in range(3):
            out3[i] += 0.5 * (s[kh + 4 * idx + 1 + i] + s[kh + 4 * later + 1 + i]) * (tl - te)
        later = idx
        tl = te
    for i in range(3):  # older than the history: the oldest velocity over the rest
        out3[i] += s[kh + 4 * later + 1 + i] * (tl - t)
    return False


@kernel
def _position_start(s, k, c, value, r):  # type: ignore[no-untyped-def]
    """Position component ``c`` := ``value``, variance ``r``, uncorrelated with the rest."""
    kp = k + _P
    i = _I_POS + c
    for j in range(N):
        s[kp + i * N + j] = 0.0
        s[kp + j * N + i] = 0.0
    s[kp + i * N + i] = r
    s[k + _POS + c] = value


@kernel
def _position_off(s, k):  # type: ignore[no-untyped-def]
    """No position: its rows and columns of P to 0 (the next fix starts it again)."""
    kp = k + _P
    for i in range(_I_POS, _I_SCALE):
        for j in range(N):
            s[kp + i * N + j] = 0.0
            s[kp + j * N + i] = 0.0
    s[k + _POS_ON] = 0.0
    s[k + _POS_ON_V] = 0.0
    s[k + _PREJ_T] = -1.0


@kernel
def _position_fix(s, k, params, pn, pe, pd, t_fix, clk):  # type: ignore[no-untyped-def]
    """A GNSS position fix (``IN_POS``) taken at clock time ``t_fix``: started, or fused against the INS
    position at that time (now less the history's displacement since), one scalar update per component
    with the position gate.  Returns True if a component was fused.

    h = ∂(p_fix − p_INS)/∂δx = 1 at δp_c (12 + c): a tilt error δ accelerates the INS by g·δ, so the
    position residual grows as ½ g δ t² (Groves 2013, §14.2.2: position-aided INS), a low-frequency tilt
    reference the velocity's noise does not give at hover.
    """
    p = P_FILTER
    r_h, r_v = params[p + _R_POS_H], params[p + _R_POS_V]
    d3 = s[k + _H : k + _H + 3]  # borrow scratch h[0:3] for the displacement
    _history_displacement(s, k, t_fix, d3)
    dn, de, dd = d3[0], d3[1], d3[2]
    fused = False
    tried = False
    gate = params[p + _POS_GATE]
    if r_h > 0.0 and math.isfinite(pn) and math.isfinite(pe):
        if s[k + _POS_ON] == 0.0:
            _position_start(s, k, 0, pn + dn, r_h)
            _position_start(s, k, 1, pe + de, r_h)
            s[k + _POS_ON] = 1.0
        else:
            tried = True
            y0, y1 = pn - (s[k + _POS] - dn), pe - (s[k + _POS + 1] - de)
            for c in range(2):
                for i in range(N):
                    s[k + _H + i] = 0.0
                s[k + _H + _I_POS + c] = 1.0
                if _scalar_update(s, k, y0 if c == 0 else y1, r_h, gate, s[k + _BNOW]):
                    fused = True
    if r_v > 0.0 and math.isfinite(pd):
        if s[k + _POS_ON_V] == 0.0:
            _position_start(s, k, 2, pd + dd, r_v)
            s[k + _POS_ON_V] = 1.0
        else:
            tried = True
            y2 = pd - (s[k + _POS + 2] - dd)
            for i in range(N):
                s[k + _H + i] = 0.0
            s[k + _H + _I_POS + 2] = 1.0
            if _scalar_update(s, k, y2, r_v, gate, s[k + _BNOW]):
                fused = True
    if fused or not tried:
        s[k + _PREJ_T] = -1.0
    elif s[k + _PREJ_T] < 0.0:
        s[k + _PREJ_T] = clk
    elif clk - s[k + _PREJ_T] > params[p + _VEL_RESET]:
        # every position fix refused for that long (a receiver's jump, a new origin): start again from the next
        _position_off(s, k)
    return fused


@kernel
def _heading_reset_from_model(s, k, params, scr, amps, clk):  # type: ignore[no-untyped-def]
    """The heading set from the model's corrected reading while it is unknown (σ ≥ 30°, a start in a
    ground anomaly) and the model's field per ampere is known (every σ ≤ 0.06 µT/A: a model loaded
    from an earlier flight, or learnt), or the model's own heading σ is ≤ 10° (learnt in this flight by
    its pair updates; the heading variance is then set to that σ × ``heading_sigma_factor``): once the corrected reading's norm and dip have fitted the WMM's
    (5 %, 3°) for 1 s while the motors' field is ≥ 3 µT (the vehicle in the air, out of the anomaly), the heading is rotated to it and its variance
    set to the heading noise (ArduPilot's EKF3 resets its yaw to the compass after take-off for the
    same reason).  firmware_sim ``mag_anomaly``: with a model saved from another flight the corrected
    readings point within 1° of the field's azimuth 2–3 s after take-off (docs/accuracy.md)."""
    p = P_FILTER
    kp = k + _P
    km = k + _MAGF
    ref_norm = params[P_SCHED + _g.GP_MAG_REF_NORM]
    ok = s_pos(s[kp + 2 * N + 2]) >= _UNKNOWN_HEADING_VAR and ref_norm > 0.0 and math.isfinite(amps)  # ±inf: not known, as NaN
    if ok:  # the model explains a field of note (the motors run): on the ground at rest the reading is the raw one
        kx = km + MF_X
        bx, by, bz = amps * s[kx + 3], amps * s[kx + 4], amps * s[kx + 5]
        ok = bx * bx + by * by + bz * bz >= _MIN_MOTOR_FIELD_UT2
    known = True
    for i in range(3, 6):
        known = known and s_pos(s[km + MF_P + i * MF_NX + i]) <= _KNOWN_MOTOR_VAR
    ok = ok and (known or s[km + MF_HEAD_SIGMA] <= _RESET_MODEL_SIGMA_RAD)
    kc = k + _C
    mx, my, mz = scr[0], scr[1], scr[2]
    hn = s[kc + 0] * mx + s[kc + 1] * my + s[kc + 2] * mz
    he = s[kc + 3] * mx + s[kc + 4] * my + s[kc + 5] * mz
    hd = s[kc + 6] * mx + s[kc + 7] * my + s[kc + 8] * mz
    bh = math.sqrt(hn * hn + he * he)
    if ok:
        norm = math.sqrt(bh * bh + hd * hd)
        ok = abs(norm / ref_norm - 1.0) <= 0.05 and abs(math.atan2(hd, bh) - params[P_SCHED + _g.GP_MAG_REF_DIP]) <= _FIT_DIP_RAD
    if not ok:
        s[k + _FIT_T] = 0.0
        return
    if s[k + _FIT_T] <= 0.0:
        s[k + _FIT_T] = clk
        return
    if clk - s[k + _FIT_T] < _RESET_FIT_S:
        return
    s[k + _FIT_T] = 0.0
    psi = math.atan2(he, hn) - s[k + _DECL]
    psi = math.atan2(math.sin(psi), math.cos(psi))
    # ψ ≈ −δθ_D: rotate the estimate about down by −ψ (the error state's injection, q ← δq ⊗ q)
    h = -0.5 * psi
    a0, a1, a2, a3 = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3] = quat_multiply(math.cos(h), 0.0, 0.0, math.sin(h), a0, a1, a2, a3)
    # the heading noise, or what the model leaves unknown of the field across (×``heading_sigma_factor``)
    hv = (params[p + _MAGF_P + MP_HFACTOR] * s[km + MF_HEAD_SIGMA]) ** 2
    _heading_moved(s, k, params, -psi, params[p + _R_HEADING] if known else max(params[p + _R_HEADING], hv))


@kernel
def _heading_moved(s, k, params, rot, var):  # type: ignore[no-untyped-def]
    """What the filter holds in NED follows a heading set anew (the attitude rotated by ``rot`` rad about
    down, q ← exp(rot/2 ê_D) ⊗ q, by the caller), and the heading's variance is ``var``, uncorrelated."""
    p = P_FILTER
    kp = k + _P
    km = k + _MAGF
    if params[p + _GRAV_TAU] > 0.0:
        nav_lowpass_rotate(s, k + _GLP, 0.0, 0.0, rot)
        nav_lowpass_rotate(s, k + _GLP + BW_LEN // 2, 0.0, 0.0, rot)
    for j in range(N):
        s[kp + 2 * N + j] = 0.0
        s[kp + j * N + 2] = 0.0
    s[kp + 2 * N + 2] = var
    # the model's held attitudes move with the frame (the take-off fit's reference: its anomaly's direction),
    # the pair references were held in the former heading and are dropped
    mag_ref_rotate(s, km, 0.0, 0.0, rot, s[k + _DECL], s[k + _DECL])
    mag_refs_drop(s, km)
    s[k + _MNOISE + 2] = s[k + _MNOISE + 3] = math.nan  # … and so were the readings held for the learnt noise


@kernel
def step(state, params, row, out):  # type: ignore[no-untyped-def]
    """One ESKF update (see the module docstring for the equations)."""
    b0, b1, b2, b3 = state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3]
    dt = begin_step(state, params, row, out)
    flags = int(out[OUT_FLAGS])
    k = S_FILTER
    if dt < 0.0:
        if flags & FLAG_STARTUP:
            eskf_reset(state, k, params)
        return
    p = P_FILTER
    if flags & FLAG_HEADING_ALIGNED:
        # the first magnetometer reading after a start without one set the heading (begin_step): the
        # rotation it made about down, from q_after ⊗ q_beforeᶜ = exp(rot/2 ê_D); the heading's variance
        # that of a start with the reading (``initial_heading_rad``)
        rot = 2.0 * math.atan2(
            -state[S_Q] * b3 + state[S_Q + 3] * b0 - state[S_Q + 1] * b2 + state[S_Q + 2] * b1,
            state[S_Q] * b0 + state[S_Q + 1] * b1 + state[S_Q + 2] * b2 + state[S_Q + 3] * b3,
        )
        _heading_moved(state, k, params, rot, params[p + _P0_HEADING])
    accel_ok = (flags & FLAG_ACCEL_INVALID) == 0
    mag_ok = (flags & FLAG_MAG_INVALID) == 0
    # the reading is (1 + s)·ω + b per axis (s = 0 unless gyro_scale_state_sigma)
    gx = (row[IN_GYRO] - state[S_BIAS]) / (1.0 + state[k + _GSCALE])
    gy = (row[IN_GYRO + 1] - state[S_BIAS + 1]) / (1.0 + state[k + _GSCALE + 1])
    gz = (row[IN_GYRO + 2] - state[S_BIAS + 2]) / (1.0 + state[k + _GSCALE + 2])
    q0, q1, q2, q3 = state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3]
    ax, ay, az = row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2]
    abias_on = params[p + _ABIAS_P0] > 0.0 or params[p + _ABIAS_VIB] > 0.0
    phi_a = 1.0
    # estimated now (``accel_bias_aided_only``: only while a velocity fix was fused within the aiding timeout;
    # otherwise b̂_a is held, subtracted as learnt, and its states decoupled from the rest)
    abias_live = abias_on and (
        params[p + _ABIAS_AIDED] == 0.0
        or (state[k + _LAST_FIX] >= 0.0 and state[k + _CLK] + dt - state[k + _LAST_FIX] <= params[p + _AID_TIMEOUT])
    )
    # … and *considered* only (Schmidt 1966: in every innovation's variance, correlations kept, b̂_a and its own
    # variance not updated) above ``accel_bias_live_speed_m_s``
    state[k + _ABIAS_HELD] = 1.0 if abias_live and not _accel_bias_gate_ok(state, k, params) else 0.0
    if abias_on and not abias_live:
        _accel_bias_decouple(state, k)
    if abias_on:
        # the reading is f + b_a: every model below (velocity, gravity, drag, thrust axis) uses f = reading − b̂_a;
        # b̂_a a first-order Gauss–Markov process, its prediction decays as e^(−dt/τ_a)
        tau_a = params[p + _ABIAS_TAU]
        if tau_a > 0.0 and abias_live:
            phi_a = max(1.0 - dt / tau_a, 0.0)
            for i in range(3):
                state[k + _ABIAS + i] *= phi_a
        ax -= state[k + _ABIAS]
        ay -= state[k + _ABIAS + 1]
        az -= state[k + _ABIAS + 2]
    mx, my, mz = row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2]
    boost, w_a, w_m = schedule_step(
        state[S_SCHED : S_SCHED + _g.GS_LEN],
        params[P_SCHED : P_SCHED + _g.GP_LEN],
        q0, q1, q2, q3, gx, gy, gz, ax, ay, az, accel_ok, mx, my, mz, mag_ok, dt,
    )  # fmt: skip
    if boost > 1.0:
        add_flag(out, FLAG_STARTUP)

    # ---- C = C_body_to_ned(q), f in NED ---------------------------------------------------
    kc = k + _C
    state[kc + 0] = 1.0 - 2.0 * (q2 * q2 + q3 * q3)
    state[kc + 1] = 2.0 * (q1 * q2 - q0 * q3)
    state[kc + 2] = 2.0 * (q1 * q3 + q0 * q2)
    state[kc + 3] = 2.0 * (q1 * q2 + q0 * q3)
    state[kc + 4] = 1.0 - 2.0 * (q1 * q1 + q3 * q3)
    state[kc + 5] = 2.0 * (q2 * q3 - q0 * q1)
    state[kc + 6] = 2.0 * (q1 * q3 - q0 * q2)
    state[kc + 7] = 2.0 * (q2 * q3 + q0 * q1)
    state[kc + 8] = 1.0 - 2.0 * (q1 * q1 + q2 * q2)
    fn = fe = fd = 0.0
    if accel_ok:
        fn = state[kc + 0] * ax + state[kc + 1] * ay + state[kc + 2] * az
        fe = state[kc + 3] * ax + state[kc + 4] * ay + state[kc + 5] * az
        fd = state[kc + 6] * ax + state[kc + 7] * ay + state[kc + 8] * az
    km = k + _M  # M = −[f]×
    state[km + 0] = 0.0
    state[km + 1] = fd
    state[km + 2] = -fe
    state[km + 3] = -fd
    state[km + 4] = 0.0
    state[km + 5] = fn
    state[km + 6] = fe
    state[km + 7] = -fn
    state[km + 8] = 0.0

    # ---- propagate ---------------------------------------------------------------------------
    state[k + _CLK] += dt
    clk = state[k + _CLK]
    win = params[p + _ATT_STEP_WIN]
    state[k + _BNOW] = params[p + _ATT_STEP] if win <= 0.0 or clk - state[k + _T_OPEN] < win else 0.0
    aided = state[k + _LAST_FIX] >= 0.0 and clk - state[k + _LAST_FIX] <= params[p + _AID_TIMEOUT]
    if accel_ok and state[k + _STARTED] == 0.0:  # the start window's mean specific force (initial_average_s)
        state[k + _START] += fn * dt
        state[k + _START + 1] += fe * dt
        state[k + _START + 2] += fd * dt
        state[k + _START + 3] += dt
        state[k + _ASUM] += ax * dt  # … and in the body frame, where a thrust fixed in the body keeps its direction
        state[k + _ASUM + 1] += ay * dt
        state[k + _ASUM + 2] += az * dt
        state[k + _ASUM + 3] += dt
    if state[k + _POS_ON] > 0.0 or state[k + _POS_ON_V] > 0.0:  # p ← p + v dt + ½ (f + g) dt²
        hd = 0.5 * dt if accel_ok else 0.0
        state[k + _POS] += (state[k + _V] + hd * fn) * dt
        state[k + _POS + 1] += (state[k + _V + 1] + hd * fe) * dt
        state[k + _POS + 2] += (state[k + _V + 2] + hd * (fd + G_M_S2)) * dt
    if accel_ok:  # also while not aided: a restart needs the velocity change since a late fix's time
        state[k + _V] += fn * dt
        state[k + _V + 1] += fe * dt
        state[k + _V + 2] += (fd + G_M_S2) * dt
    q_gyro, q_accel = params[p + _Q_GYRO], params[p + _Q_ACCEL]
    tau_n = params[p + _NOISE_TAU]
    if tau_n > 0.0:
        # noise as measured: half the mean square difference between consecutive samples is the
        # per-sample variance of what is white in them (noise, aliased vibration); times dt, a density
        kq = k + _PREV_IMU
        if accel_ok and state[kq] == state[kq]:
            dgx, dgy, dgz = row[IN_GYRO] - state[kq], row[IN_GYRO + 1] - state[kq + 1], row[IN_GYRO + 2] - state[kq + 2]
            dax, day, daz = ax - state[kq + 3], ay - state[kq + 4], az - state[kq + 5]
            w = min(dt / tau_n, 1.0)
            state[k + _VIB] += (0.5 * (dgx * dgx + dgy * dgy + dgz * dgz) / 3.0 - state[k + _VIB]) * w
            state[k + _VIB + 1] += (0.5 * (dax * dax + day * day + daz * daz) / 3.0 - state[k + _VIB + 1]) * w
        state[kq], state[kq + 1], state[kq + 2] = row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2]
        state[kq + 3], state[kq + 4], state[kq + 5] = (ax, ay, az) if accel_ok else (math.nan, math.nan, math.nan)
        q_gyro = max(q_gyro, state[k + _VIB] * dt)
        q_accel = max(q_accel, state[k + _VIB + 1] * dt)
    t_blk = params[p + _SLOW_BLOCK]
    if t_blk > 0.0 and accel_ok:
        # the specific force's slow error: the Hadamard variance of its block means beyond the white noise's share
        # (second differences: a manoeuvre's acceleration changing steadily over a block pair is not counted)
        ks = k + _SLOW
        state[ks] += fn * dt
        state[ks + 1] += fe * dt
        state[ks + 2] += (fd + G_M_S2) * dt
        state[ks + 3] += dt
        state[ks + 4] += 1.0
        if state[ks + 3] >= t_blk:
            m0, m1, m2 = state[ks] / state[ks + 3], state[ks + 1] / state[ks + 3], state[ks + 2] / state[ks + 3]
            if state[ks + 8] > 1.0:
                d0 = m0 - 2.0 * state[ks + 5] + state[ks + 11]
                d1 = m1 - 2.0 * state[ks + 6] + state[ks + 12]
                d2 = m2 - 2.0 * state[ks + 7] + state[ks + 13]
                w = min(state[ks + 3] / params[p + _SLOW_TAU], 1.0)
                if (state[ks + 8] - 1.0) * w < 1.0:  # the mean since the start while shorter than τ
                    w = 1.0 / (state[ks + 8] - 1.0)
                state[ks + 9] += ((d0 * d0 + d1 * d1 + d2 * d2) / 18.0 - state[ks + 9]) * w
                state[ks + 10] += (state[k + _VIB + 1] / state[ks + 4] - state[ks + 10]) * w
            state[ks + 11], state[ks + 12], state[ks + 13] = state[ks + 5], state[ks + 6], state[ks + 7]
            state[ks + 5], state[ks + 6], state[ks + 7] = m0, m1, m2
            state[ks + 8] += 1.0
            state[ks], state[ks + 1], state[ks + 2], state[ks + 3], state[ks + 4] = 0.0, 0.0, 0.0, 0.0, 0.0
        if state[ks + 8] > 2.0:
            q_accel += max(state[ks + 9] - state[ks + 10], 0.0) * t_blk
    # the thrust-axis states' random walk once they exist (their variance is 0 until the axis is first set)
    q_axis = params[p + _AXIS_Q] if state[k + _P + 9 * N + 9] > 0.0 else 0.0
    q_bias = params[p + _Q_BIAS_AIDED] if aided and params[p + _Q_BIAS_AIDED] > 0.0 else params[p + _Q_BIAS]
    _propagate_covariance(state, k, dt, q_gyro, q_accel, q_bias, q_axis, params[p + _Q_POS],
                          state[k + _POS_ON] > 0.0 or state[k + _POS_ON_V] > 0.0,
                          params[p + _SCALE_P0] > 0.0, params[p + _SCALE_Q], gx, gy, gz,
                          abias_live, phi_a, _accel_bias_variance(state, k, params) * 2.0 / params[p + _ABIAS_TAU]
                          if params[p + _ABIAS_TAU] > 0.0 else 0.0)
    state[k + _SENS_ON] = 1.0 if params[p + _CONS_P0] > 0.0 else 0.0
    if params[p + _CONS_P0] > 0.0:
        _propagate_sensitivity(state, k, dt, N if abias_live else _I_ABIAS,
                               state[k + _POS_ON] > 0.0 or state[k + _POS_ON_V] > 0.0, params[p + _SCALE_P0] > 0.0,
                               gx, gy, gz, abias_live, phi_a)
    q_sf, q_ma = params[p + _Q_SCALE], params[p + _Q_CROSS]
    p_dd = state[k + _P + 2 * N + 2]
    if q_sf > 0.0 or q_ma > 0.0:
        _rate_noise(state, k, dt, gx, gy, gz, q_sf, q_ma)
    if params[p + _Q_SCALE_TILT] > 0.0:
        _scale_noise_tilt(state, k, dt, gx, gy, gz, params[p + _Q_SCALE_TILT], params[p + _SCALE_TILT_TAU])
    if params[p + _HWALK_TAU] > 0.0:  # the heading's extra random walk learnt from the compass (:func:`_heading_walk_step`)
        state[k + _P + 2 * N + 2] += state[k + _HWALK] * dt
    if params[p + _MAG_NOISE_TAU] > 0.0:
        # the white part of the heading innovation's change since the last compass reading: the gyro's noise
        # (on the heading and, through the field's dip, the tilt) and its rate noise (:func:`_mag_noise_step`)
        kn = k + _MNOISE
        state[kn + 7] += q_gyro * dt * (1.0 + state[kn + 5] ** 2 + state[kn + 6] ** 2) + state[k + _P + 2 * N + 2] - p_dd
    integrate_body_rate(state, S_Q, gx, gy, gz, dt)
    # history of the INS velocity (the state after this sample, at its time)
    pos = int(state[k + _HPOS])
    if not 0 <= pos < HISTORY_LEN:  # a state set from outside: never index beyond the history
        pos = 0
    kh = k + _HIST + 4 * pos
    state[kh] = clk
    state[kh + 1] = state[k + _V]
    state[kh + 2] = state[k + _V + 1]
    state[kh + 3] = state[k + _V + 2]
    state[k + _HPOS] = (pos + 1) % HISTORY_LEN
    if state[k + _HCOUNT] < HISTORY_LEN:
        state[k + _HCOUNT] += 1.0

    for i in range(N):
        state[k + _DX + i] = 0.0
    updated = False
    gate = params[p + _GATE]
    # how long each axis's bias estimate has been beyond the bound and beyond the prior's σ (without a break)
    lim_b = params[p + _BIAS_LIMIT]
    sd_prior = math.sqrt(params[p + _BPRIOR_VAR])
    for i in range(3):
        b_abs = abs(state[S_BIAS + i])
        state[k + _BOUT + i] = state[k + _BOUT + i] + dt if b_abs > lim_b else 0.0
        state[k + _BOUT + 3 + i] = state[k + _BOUT + 3 + i] + dt if b_abs > sd_prior else 0.0

    # ---- velocity fix ------------------------------------------------------------------------
    vn, ve, vd = row[IN_VEL], row[IN_VEL + 1], row[IN_VEL + 2]
    any_fix = math.isfinite(vn) or math.isfinite(ve) or math.isfinite(vd)
    held = (
        any_fix
        and (vn == state[k + _PREV_VEL] or not (math.isfinite(vn) or math.isfinite(state[k + _PREV_VEL])))
        and (ve == state[k + _PREV_VEL + 1] or not (math.isfinite(ve) or math.isfinite(state[k + _PREV_VEL + 1])))
        and (vd == state[k + _PREV_VEL + 2] or not (math.isfinite(vd) or math.isfinite(state[k + _PREV_VEL + 2])))
    )
    state[k + _PREV_VEL] = vn
    state[k + _PREV_VEL + 1] = ve
    state[k + _PREV_VEL + 2] = vd
    if held and aided:
        # the last fix repeated on every row: unchanged for 1.5 fix periods (0.5 s before the period
        # is known) it is a new fix with the same velocity (a steady velocity)
        period = state[k + _PERIOD]
        held = clk - state[k + _LAST_FIX] <= (1.5 * period if period > 0.0 else 0.5)
    elif any_fix and aided:
        state[k + _PERIOD] = clk - state[k + _LAST_FIX]
    r_h = params[p + _R_VEL_H]
    r_v = params[p + _R_VEL_V]
    age = row[IN_VEL_AGE]
    if not (math.isfinite(age) and age > 0.0):
        age = 0.0
    t_fix = clk - age + params[p + _DELAY]
    if any_fix and not held:
        if not aided:
            # the fix was taken ``age`` ago: carry it to now with the INS's own velocity change since
            vh = state[k + _H : k + _H + 3]
            if age > 0.0 and _history_velocity(state, k, t_fix, vh):
                vn += state[k + _V] - vh[0]
                ve += state[k + _V + 1] - vh[1]
                vd += state[k + _V + 2] - vh[2]
            _restart_velocity(state, k, vn, ve, vd, r_h, r_v)
            _position_off(state, k)
            # the first fixes tell the tilt within a second even from far off: let them
            eskf_reopen_attitude(state, k, params, _RESTART_TILT, _RESTART_HEADING)
            state[k + _LAST_FIX] = clk
            state[k + _PERIOD] = 0.0
        else:
            vh = state[k + _H : k + _H + 3]  # borrow scratch h[0:3] for the historic velocity
            if _history_velocity(state, k, t_fix, vh):
                y0, y1, y2 = vn - vh[0], ve - vh[1], vd - vh[2]
                accepted = False
                for c in range(3):
                    y = y0 if c == 0 else (y1 if c == 1 else y2)
                    if not math.isfinite(y):
                        continue
                    for i in range(N):
                        state[k + _H + i] = 0.0
                    state[k + _H + 3 + c] = 1.0
                    if _scalar_update(state, k, y, r_h if c < 2 else r_v, params[p + _VEL_GATE], state[k + _BNOW]):
                        accepted = True
                        updated = True
                if accepted:
                    state[k + _LAST_FIX] = clk
                    state[k + _VREJ] = 0.0
                else:
                    state[k + _VREJ] += dt if state[k + _VREJ] > 0.0 else 1e-9
                    if clk - state[k + _LAST_FIX] > params[p + _VEL_RESET]:
                        _restart_velocity(state, k, vn, ve, vd, r_h, r_v)
                        _position_off(state, k)
                        state[k + _LAST_FIX] = clk
    aided = state[k + _LAST_FIX] >= 0.0 and clk - state[k + _LAST_FIX] <= params[p + _AID_TIMEOUT]

    # ---- position fix (same fix, same time as the velocity's) ---------------------------------
    pn, pe, pd = row[IN_POS], row[IN_POS + 1], row[IN_POS + 2]
    new_pos = (math.isfinite(pn) or math.isfinite(pd)) and not (
        (pn == state[k + _PREV_POS] or not (math.isfinite(pn) or math.isfinite(state[k + _PREV_POS])))
        and (pe == state[k + _PREV_POS + 1] or not (math.isfinite(pe) or math.isfinite(state[k + _PREV_POS + 1])))
        and (pd == state[k + _PREV_POS + 2] or not (math.isfinite(pd) or math.isfinite(state[k + _PREV_POS + 2])))
    )
    state[k + _PREV_POS] = pn
    state[k + _PREV_POS + 1] = pe
    state[k + _PREV_POS + 2] = pd
    if not aided:
        if state[k + _POS_ON] > 0.0 or state[k + _POS_ON_V] > 0.0:
            _position_off(state, k)  # restarted with the velocity aiding
    elif (new_pos or (any_fix and not held)) and (math.isfinite(pn) or math.isfinite(pd)):
        if _position_fix(state, k, params, pn, pe, pd, t_fix, clk):
            updated = True

    # ---- at rest while not aided: the rate and the velocity are zero ------------------------
    at_rest = False
    if not aided and params[p + _R_REST_RATE] > 0.0:
        at_rest = rest_step(
            state, k + _REST, state, k + _RSCR, row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2],
            ax, ay, az, accel_ok, math.nan, math.nan, math.nan, dt, params, p + _REST_P,
        )  # fmt: skip
        if accel_ok and params[p + _REST_HOVER_VIB] > 0.0:  # the rotors' vibration: deviation from the 0.5 s low-pass
            dax, day, daz = ax - state[k + _REST + 3], ay - state[k + _REST + 4], az - state[k + _REST + 5]
            state[k + _REST_VIB] += (dax * dax + day * day + daz * daz - state[k + _REST_VIB]) * lowpass_coefficient(dt, 1.0)
        n_known = 0
        if not at_rest:
            state[k + _REST_N] = 0.0
        if at_rest:
            # a low-passed rate the bias cannot explain is a slow steady turn (a hover's yaw), not rest:
            # each axis within 3 σ of the bias estimate (its covariance plus the measurement's noise);
            # with rest_check_sigma_rad_s only the axes whose bias is known well enough for that check to
            # tell a slow turn, and at least one of them (before that a still stretch is not taken for rest)
            # (an axis whose bias is not yet known that well is still checked against its own σ, since it
            # is fused too: a hover's steady yaw beyond 3 σ of its prior is a turn, not rest)
            kp = k + _P
            v_max = params[p + _REST_CHECK_VAR]
            for c in range(3):
                pb = s_pos(state[kp + (6 + c) * N + 6 + c])
                if not (v_max > 0.0 and pb > v_max):
                    n_known += 1
                d = state[k + _REST + c] - state[S_BIAS + c]
                if d * d > 9.0 * (pb + params[p + _R_REST_RATE]):
                    at_rest = False
            if n_known == 0:
                at_rest = False
        if at_rest and clk - state[k + _LAST_REST] >= params[p + _ZV_PERIOD]:
            # the low-passed gyro is the bias (Madgwick's and VQF's rest phase, here as a measurement of
            # the bias state: its covariance with the tilt corrects that too); optionally the velocity is zero
            state[k + _LAST_REST] = clk
            if _rest_rate_update(state, k, params, p):
                updated = True
            for c in range(3 if params[p + _R_REST_VEL] > 0.0 else 0):
                for i in range(N):
                    state[k + _H + i] = 0.0
                state[k + _H + 3 + c] = 1.0
                if _scalar_update(state, k, -state[k + _V + c], params[p + _R_REST_VEL], 1.0e6, state[k + _BNOW]):
                    updated = True

    # ---- gravity direction while not aided -------------------------------------------------
    tried = False  # an attitude measurement was offered this sample
    passed = False  # … and accepted
    r_zv = params[p + _R_ZV]
    if not aided and r_zv > 0.0 and clk - state[k + _LAST_ZV] >= params[p + _ZV_PERIOD]:
        # without velocity aiding a vehicle's velocity is zero on average (an autopilot's EKF without GNSS
        # fuses zero velocity or a constant position the same way): the INS velocity's drift is the tilt
        # and bias error, through their covariance with the velocity
        state[k + _LAST_ZV] = clk
        for c in range(3):
            for i in range(N):
                state[k + _H + i] = 0.0
            state[k + _H + 3 + c] = 1.0
            if _scalar_update(state, k, -state[k + _V + c], r_zv, 1.0e6, state[k + _BNOW]):
                updated = True
    k_drag = params[p + _DRAG_K]
    if k_drag > 0.0 and accel_ok:
        _drag_update_prepare(state, k, params, ax, ay, az, dt)
        if aided:  # velocity-aided: the fixes tell the velocity; the sum restarts
            for i in range(4):
                state[k + _FSUM + i] = 0.0
        elif at_rest:  # no airflow to speak of, or held by its legs: the sum restarts
            for i in range(4):
                state[k + _FSUM + i] = 0.0
        elif state[k + _FSUM + 3] >= params[p + _ZV_PERIOD]:  # the specific force averaged over that period
            state[k + _DSTAT] += 1.0
            if _drag_update(state, k, params, k_drag):
                updated = True
                state[k + _DREJ] = -1.0
            elif state[k + _TAX] != 0.0 or state[k + _TAX + 1] != 0.0 or state[k + _TAX + 2] != 0.0:
                state[k + _DSTAT + 1] += 1.0
                if state[k + _DREJ] < 0.0:
                    state[k + _DREJ] = clk  # a streak of rejections starts
                elif params[p + _DRAG_RESET] > 0.0 and clk - state[k + _DREJ] > params[p + _DRAG_RESET]:
                    _drag_reopen_velocity(state, k)
                    state[k + _DSTAT + 2] += 1.0
                    state[k + _DREJ] = -1.0
    gn, ge, gd = fn, fe, fd  # the gravity measurement, NED
    tau_g = params[p + _GRAV_TAU]
    if tau_g > 0.0 and params[p + _SCALE_P0] > 0.0:
        # the low-passed measurement holds the tilt errors of the last seconds, not this sample's: with
        # δθ(τ) = δθ(t) + ∫_τ^t C diag(ω) dt' δs (+ the bias's share), its error is δθ(t) + G δs with
        # G = J − LP[J], J = ∫ C diag(ω) dt (the low-pass has unit gain at DC), so h carries g·G on δs
        for m in range(6):
            wm = gx if m == 0 else (gy if m == 1 else (gz if m == 2 else 1.0))
            kj = k + _JS + m * LP_LEN
            for i in range(3):
                state[kj + i] += state[k + _C + 3 * i + m % 3] * wm * dt
            jn, je, jd = ned_butterworth_step(state, k + _JLP + m * BW_LEN, state[kj], state[kj + 1], state[kj + 2],
                                              dt, tau_g)
            kg = k + _JG + 9 * (m // 3) + m % 3
            state[kg] = state[kj] - jn
            state[kg + 3] = state[kj + 1] - je
            state[kg + 6] = state[kj + 2] - jd
    if tau_g > 0.0 and accel_ok:
        gn, ge, gd = ned_butterworth_step(state, k + _GLP, fn, fe, fd, dt, tau_g)
    # the accelerometer bias in the gravity measurement: LP[C f̂] = LP[C f] + LP[C] δb_a, so h on δb_a is the
    # low-passed C's north and east rows (= C for the raw sample; a slow bias, the body turning under it)
    cl_n0, cl_n1, cl_n2 = state[kc + 0], state[kc + 1], state[kc + 2]
    cl_e0, cl_e1, cl_e2 = state[kc + 3], state[kc + 4], state[kc + 5]
    if abias_on and tau_g > 0.0 and accel_ok:
        cl_n0, cl_e0, _d = ned_butterworth_step(state, k + _CLP, state[kc + 0], state[kc + 3], state[kc + 6], dt, tau_g)
        cl_n1, cl_e1, _d = ned_butterworth_step(state, k + _CLP + BW_LEN, state[kc + 1], state[kc + 4], state[kc + 7],
                                                dt, tau_g)
        cl_n2, cl_e2, _d = ned_butterworth_step(state, k + _CLP + 2 * BW_LEN, state[kc + 2], state[kc + 5],
                                                state[kc + 8], dt, tau_g)
    w_g = w_a
    na = math.sqrt(gn * gn + ge * ge + gd * gd)
    if tau_g > 0.0 and accel_ok:
        # the low-passed vector's norm tells a sustained manoeuvre (the sample's is mostly vibration)
        tol = params[P_SCHED + _g.GP_ACCEL_NORM_TOL]
        w_g = 1.0 - abs(na / G_M_S2 - 1.0) / tol if tol > 0.0 else 1.0
        if w_g < 0.0:
            w_g = 0.0
        # as the sample's trust (gains.schedule_step) it drops at once and recovers over the schedule's
        # recovery time, of which the low-pass itself takes τ: a short average (a vehicle's 0.1 s) is
        # re-trusted as the sample was, the 2 s one as it was before (without this the 0.1 s average
        # measured ArduCopter SITL without GNSS 0.62 → 0.74°; with it 0.63°)
        w_prev = state[k + _GW]
        rec = params[P_SCHED + _g.GP_RECOVERY_S] - tau_g
        if w_g > w_prev and rec > 0.0:
            w_g = w_prev + (w_g - w_prev) * min(dt / rec, 1.0)
        state[k + _GW] = w_g
        since = clk - state[k + _LAST_FIX] - params[p + _AID_TIMEOUT]
        if state[k + _LAST_FIX] >= 0.0 and 0.0 <= since < tau_g:
            # just after the velocity aiding ended the reference still holds the accelerations of
            # the aided flight, which the fixes explained: its trust rises as they leave it
            w_g *= since / tau_g
    tau_r = params[p + _ADAPT_TAU]
    if tau_r > 0.0 and not aided and accel_ok and na > 0.0:
        # every sample, gated or not: a manoeuvre the gate refuses still tells how far off f runs
        y2 = 0.5 * (gn * gn + ge * ge) * (G_M_S2 / na) ** 2
        state[k + _GMS] += (y2 - state[k + _GMS]) * min(dt / tau_r, 1.0)
    if not aided and accel_ok and w_g > 0.0:
        if na > 0.0:
            sc = G_M_S2 / na  # the direction only
            r_g = max(params[p + _R_GRAVITY], state[k + _GMS]) / (w_g * w_g)
            # a large innovation is an attitude error, not an acceleration (see realign_innovation_rad):
            # not fused as a small one (it would be learnt as a bias); held, the tilt is re-aligned
            big = gd > 0.0 or gn * gn + ge * ge > (params[p + _REALIGN_SIN] * na) ** 2
            if not big:
                state[k + _BIG] = -1.0
            elif state[k + _BIG] < 0.0:
                state[k + _BIG] = clk
            elif clk - state[k + _BIG] >= params[p + _REALIGN_S]:
                eskf_reopen_attitude(state, k, params, _REOPEN_TILT, _REOPEN_HEADING)
                big = False
            # f_NED(est) − (0, 0, −g) = [f]× δθ: rows (0, g, 0 …) and (−g, 0, 0 …)
            for i in range(N):
                state[k + _H + i] = 0.0
            state[k + _H + 1] = G_M_S2
            if tau_g > 0.0 and params[p + _SCALE_P0] > 0.0:
                for m in range(3):
                    state[k + _H + _I_SCALE + m] = G_M_S2 * state[k + _JG + 3 + m]
                    state[k + _H + 6 + m] = G_M_S2 * state[k + _JG + 9 + 3 + m]
            if abias_live:  # f = f_true + δb_a: its north component reads LP[C]_N·δb_a
                state[k + _H + _I_ABIAS] = cl_n0
                state[k + _H + _I_ABIAS + 1] = cl_n1
                state[k + _H + _I_ABIAS + 2] = cl_n2
            for m in range(3):  # … and so does it a bias the filter does not estimate (its sensitivity, if carried)
                state[k + _SENS_HB + m] = state[kc + m]
            tried = True
            if not big and _scalar_update(state, k, gn * sc, r_g, gate, state[k + _BNOW]):
                updated = passed = True
            for i in range(N):
                state[k + _H + i] = 0.0
            state[k + _H + 0] = -G_M_S2
            if tau_g > 0.0 and params[p + _SCALE_P0] > 0.0:
                for m in range(3):
                    state[k + _H + _I_SCALE + m] = -G_M_S2 * state[k + _JG + m]
                    state[k + _H + 6 + m] = -G_M_S2 * state[k + _JG + 9 + m]
            if abias_live:  # … its east component LP[C]_E·δb_a
                state[k + _H + _I_ABIAS] = cl_e0
                state[k + _H + _I_ABIAS + 1] = cl_e1
                state[k + _H + _I_ABIAS + 2] = cl_e2
            for m in range(3):
                state[k + _SENS_HB + m] = state[kc + 3 + m]
            if not big and _scalar_update(state, k, ge * sc, r_g, gate, state[k + _BNOW]):
                updated = passed = True
            for m in range(3):
                state[k + _SENS_HB + m] = 0.0

    # ---- magnetometer heading ----------------------------------------------------------------
    new_mag = mx != state[k + _PREV_MAG] or my != state[k + _PREV_MAG + 1] or mz != state[k + _PREV_MAG + 2]
    state[k + _PREV_MAG] = mx
    state[k + _PREV_MAG + 1] = my
    state[k + _PREV_MAG + 2] = mz
    since = clk - state[k + _LAST_MAG]
    model_on = params[p + _MAGF_P] > 0.0
    use_mag = True
    r_model = 0.0
    if model_on and mag_ok and since >= params[p + _MAG_PERIOD] and (new_mag or since >= 1.0):
        # the learnt model judges the reading and corrects it (its offset); disturbed: no heading
        scr = state[k + _MSCR : k + _MSCR + 20]
        was_disturbed = state[k + _MAGF + MF_TRUST] == MAG_DISTURBED
        # the model's earth field is (F_H, 0, F_D) in the local magnetic frame: the attitude rotated by the
        # learnt declination correction (into the Φ·P scratch, free after the propagation)
        ka = k + _A
        cd, sd = math.cos(state[k + _DECL]), math.sin(state[k + _DECL])
        for j in range(3):
            state[ka + j] = cd * state[kc + j] + sd * state[kc + 3 + j]
            state[ka + 3 + j] = cd * state[kc + 3 + j] - sd * state[kc + j]
            state[ka + 6 + j] = state[kc + 6 + j]
        trust = mag_model_update(
            state, k + _MAGF, params[p + _MAGF_P : p + _MAGF_P + MP_LEN], state[ka : ka + 9], mx, my, mz,
            row[IN_CURRENT], s_pos(state[k + _P + 2 * N + 2]),
            params[p + _MAG_STALE] * math.sqrt(gx * gx + gy * gy + gz * gz), params[P_SCHED + _g.GP_MAG_REF_NORM],
            params[P_SCHED + _g.GP_MAG_REF_DIP], clk, scr[0:4], scr[4:12], scr[12:20],
            state[k + _V] if aided else math.nan, state[k + _V + 1] if aided else math.nan,
            state[k + _V + 2] if aided else math.nan,
        )  # fmt: skip
        bx, by, bz = mx - scr[0], my - scr[1], mz - scr[2]  # the body field the model removes
        hv_fit = state[k + _MAGF + MF_TO_HVAR]
        if hv_fit > 0.0 and s_pos(state[k + _P + 2 * N + 2]) < _UNKNOWN_HEADING_VAR:
            # the take-off fit fused early, still near the ground, the heading known (set by
            # :func:`_heading_reset_from_model` or held): the corrected reading, the fitted anomaly faded to the
            # height taken out, weighed by the fit's own σ (magfield ``MF_TO_HVAR``); the model's gate, which
            # leaves that anomaly in, calls it disturbed, and the raw reading carries the anomaly
            mx, my, mz, r_model = scr[0], scr[1], scr[2], hv_fit
            use_mag = True
            w_m = 1.0
        elif w_m >= 0.5:
            # the reading's norm and dip are the WMM's (the schedule): used as it is, gated by the ESKF
            # as without the model (a model that misfits here is more likely wrong than the compass: a
            # heading gone wrong looks like this, and persistent refusals re-open the attitude,
            # ``rejection_reset_s``); the model's corrected reading serves the readings the schedule
            # rejects (the vehicle's own field)
            use_mag = True
        elif bx * bx + by * by + bz * bz >= params[p + _MIN_BODY]:
            # the vehicle's own field matters: the corrected reading, weighed by what is known of it;
            # disturbed, or the offset across the field still too uncertain to tell a heading: none
            mx, my, mz, r_model = scr[0], scr[1], scr[2], scr[3]
            # … and not while the learnt offset b₀ is beyond 3σ of its prior (a calibrated compass's
            # remainder): an earth-fixed disturbance in a steady hover fits a body offset until the vehicle
            # turns, and was learnt as one within the 3 s hold (firmware_sim ``magnetic`` seed 13: a 35 µT
            # structure taken for an offset of (6, 10, 21) µT, "trusted", heading 36–41° off)
            kx = k + _MAGF + MF_X
            b0 = state[kx] * state[kx] + state[kx + 1] * state[kx + 1] + state[kx + 2] * state[kx + 2]
            b0_max = 1.5 * params[p + _MAGF_P + MP_B0]
            use_mag = trust != MAG_DISTURBED and r_model <= params[p + _R_MODEL_MAX] and b0 <= b0_max * b0_max
            w_m = 1.0
        else:  # nothing of note learnt: the reading as it is, gated by the schedule as without the model
            use_mag = trust != MAG_DISTURBED
        steps = state[k + _MAGF + MF_STEPS]
        if steps != state[k + _MSTEPS]:
            # the field no longer fits what was learnt: the heading it gave may be wrong too (a start in a
            # ground anomaly); gyro and GNSS take over with an open heading variance
            state[k + _MSTEPS] = steps
            # (once per episode: re-opened on every reading, GNSS noise would walk the heading)
            if (
                params[p + _REOPEN_ON_STEP] > 0.0 and not was_disturbed
                and s_pos(state[k + _P + 2 * N + 2]) < params[p + _R_MODEL_MAX]
            ):  # fmt: skip
                eskf_reopen_attitude(state, k, params, 0.0, params[p + _R_MODEL_MAX])
        _heading_reset_from_model(state, k, params, scr, row[IN_CURRENT], clk)
        if not use_mag:
            state[k + _LAST_MAG] = clk
    if model_on:
        tr = state[k + _MAGF + MF_TRUST]
        w_out = 1.0 if tr == MAG_TRUSTED else (0.0 if tr == MAG_DISTURBED else 0.5)
    else:
        w_out = w_m
    if (
        params[p + _BOFF_LAG] > 0.0 and not model_on and mag_ok and since >= params[p + _MAG_PERIOD]
        and (new_mag or since >= 1.0)
    ):  # fmt: skip
        # the body-offset learner (``mag_body_offset_lag_s``, plain path): while the schedule rejects the reading,
        # a body-fixed offset (a magnet on the sensor) is learnt from turns and, once valid, the reading less
        # it serves when it passes the schedule's norm and dip test (the dip from the estimate's attitude)
        if w_m >= 0.5:
            if state[k + _BOFF + 12] > 0.0:
                _boff_reset(state, k)
        elif _boff_step(state, k, params, mx, my, mz, clk):
            kv = k + _BOFF_B
            cx, cy, cz = mx - state[kv], my - state[kv + 1], mz - state[kv + 2]
            cn = math.sqrt(cx * cx + cy * cy + cz * cz)
            ref_n = state[S_SCHED + _g.GS_MAG_NORM]
            if cn > 0.0 and ref_n > 0.0:
                sd = (state[kc + 6] * cx + state[kc + 7] * cy + state[kc + 8] * cz) / cn
                dip_c = math.asin(min(max(sd, -1.0), 1.0))
                ntol = params[P_SCHED + _g.GP_MAG_NORM_TOL]
                dtol = params[P_SCHED + _g.GP_MAG_DIP_TOL]
                if abs(cn / ref_n - 1.0) <= ntol and abs(dip_c - state[S_SCHED + _g.GS_MAG_DIP]) <= dtol:
                    mx, my, mz = cx, cy, cz
                    w_m = 1.0
    infl = 1.0
    if (
        params[p + _MAG_REJ_SCALE] > 0.0 and not model_on and mag_ok and w_m < 0.5
        and since >= params[p + _MAG_PERIOD] and (new_mag or since >= 1.0)
    ):  # fmt: skip
        # ``mag_rejected_sigma_scale`` (plain path): a reading the schedule rejects for its dip (or while its
        # weight recovers) but whose norm is the reference's is fused all the same, its σ inflated: in fast turns
        # a raw IMU's compass fails the dip test (a late reading, the tilt's error) while the gyro's heading drifts
        # (BROAD: 0.2–0.3 °/s); a reading whose norm is off (a magnet on the sensor) stays out
        nn = math.sqrt(mx * mx + my * my + mz * mz)
        ref_n = state[S_SCHED + _g.GS_MAG_NORM]
        if ref_n > 0.0 and abs(nn / ref_n - 1.0) <= params[P_SCHED + _g.GP_MAG_NORM_TOL]:
            infl = params[p + _MAG_REJ_SCALE]
            w_m = 1.0
    if use_mag and mag_ok and w_m >= 0.5 and since >= params[p + _MAG_PERIOD] and (new_mag or since >= 1.0):
        hn = state[kc + 0] * mx + state[kc + 1] * my + state[kc + 2] * mz
        he = state[kc + 3] * mx + state[kc + 4] * my + state[kc + 5] * mz
        bh = math.sqrt(hn * hn + he * he)
        if bh > 0.05 * math.sqrt(mx * mx + my * my + mz * mz):
            # the estimate's heading error: the field's azimuth in the filter's frame less the learnt
            # declination correction (WMM magnetic north = 0); ψ ≈ −δθ_D + δD
            # a reading L s older than the IMU's attitude (its delay behind the stamps less the IMU's own)
            # was taken r_D·L of yaw ago: rotated with today's attitude it reads the heading + r_D·L
            rate_d = state[kc + 6] * gx + state[kc + 7] * gy + state[kc + 8] * gz
            psi0 = math.atan2(he, hn) - state[k + _DECL]
            psi0 = math.atan2(math.sin(psi0), math.cos(psi0))
            lag = max(params[p + _MAG_DELAY] - params[p + _DELAY], 0.0)
            tau_m = params[p + _MAG_LEARN_TAU]
            if tau_m > 0.0:
                # learnt from the readings themselves: the innovation with the delay L applied is
                # ψ ≈ r_D·(L_true − L) + e (the heading error e varies slowly, not with the yaw rate), so L moves
                # by ψ·r_D / (⟨r_D²⟩ + r₀²) (normalised least mean squares, r₀ 10°/s; its fixed point has no
                # innovation left that follows the yaw rate, what the heading estimate absorbs included),
                # at most one compass period; only in turns (|r_D| ≥ r₀: at rest it holds) and not from
                # innovations beyond the gate (a disturbance, not the delay)
                kl = k + _MLAG
                lag = state[kl]
                psi_l = psi0 - rate_d * lag
                r2 = rate_d * rate_d
                if r2 >= _LAG_RATE0_RAD_S**2 and psi_l * psi_l <= gate * gate * params[p + _R_HEADING]:
                    a = min(min(since, 1.0) / tau_m, 1.0)
                    state[kl + 1] += a * (r2 - state[kl + 1])
                    lag += a * psi_l * rate_d / (state[kl + 1] + _LAG_RATE0_RAD_S**2)
                    state[kl] = min(max(lag, 0.0), params[p + _MAG_PERIOD])
                lag = state[kl]
            psi = psi0 - rate_d * lag
            psi = math.atan2(math.sin(psi), math.cos(psi))
            for i in range(N):
                state[k + _H + i] = 0.0
            if aided and state[k + _P + 2 * N + 2] < params[p + _P0_HEADING] and r_model == 0.0:
                # the declination is learnt only while GNSS velocity holds the heading (otherwise nothing
                # tells it from the heading), the heading is not re-opened (a large error would spill
                # into it through the linearised updates: 2.6° after a 90° error set by hand, unaided),
                # and from readings as they are (a model's corrected reading carries what is left of the
                # vehicle's field: arducopter_magnetic 0.63 → 0.79° when it was learnt from those too)
                state[k + _H + _I_DECL] = 1.0
            # ψ ≈ −δθ_D + (m_D/m_H)(δθ_N cos ψ + δθ_E sin ψ): the field is projected with our tilt, so a
            # tilt error δ moves the heading read by m_D/m_H·δ (×2 at a dip of 65°), in every reading
            # alike.  Fused as independent 10 Hz readings of the heading alone, they take the heading σ
            # below that, and while velocity-aided the GNSS velocity then puts the heading error taken
            # for certain into the tilt at the first horizontal acceleration.  So, aided and once the
            # tilt is known to its initial σ, the tilt is *considered* (Schmidt, :func:`_heading_update`):
            # in H, never corrected.  Otherwise H is the heading's alone (the magnetometer never moves the
            # tilt itself): considered from the start of the aiding (tilt σ 20°), the heading stayed
            # open and its correlations took the tilt 1.6° off over the next 15 s at rest
            # (test_held_velocity_works_like_nan_between_fixes); without aiding, the considered tilt
            # cost 0.03–0.06° of inclination on firmware_sim's flights without GNSS, where no velocity
            # turns a heading error into tilt
            state[k + _H + 2] = -1.0
            kp = k + _P
            consider = aided and max(state[kp], state[kp + N + 1]) <= params[p + _P0_TILT]
            cdip = (state[kc + 6] * mx + state[kc + 7] * my + state[kc + 8] * mz) / bh
            if consider:
                state[k + _H + 0] = cdip * hn / bh
                state[k + _H + 1] = cdip * he / bh
            r_head = params[p + _R_HEADING]
            # the compass's own noise and the heading's process noise are learnt only from readings used as
            # they are, no disturbance flagged, not in a turn
            learn = (
                r_model == 0.0 and rate_d * rate_d < _LAG_RATE0_RAD_S**2
                and (not model_on or state[k + _MAGF + MF_TRUST] != MAG_DISTURBED)
            )  # fmt: skip
            if params[p + _MAG_NOISE_TAU] > 0.0:
                # the compass's own noise per reading, learnt from its innovations (:func:`_mag_noise_step`)
                r_head = _mag_noise_step(state, k, params, psi, cdip * hn / bh, cdip * he / bh, learn, clk)
            # a reading held between compass reads is up to its period old: while turning, its
            # heading trails by rate × age
            stale = params[p + _MAG_STALE] * rate_d
            r_m = (r_head + stale * stale) / (w_m * w_m) * (infl * infl) + r_model
            if params[p + _HWALK_TAU] > 0.0:
                # the heading's process noise from the innovations against their predicted variance
                y_h, s_h = _innovation(state, k, psi, r_m)
                _heading_walk_step(state, k, params, y_h, s_h, r_m, learn and s_h > 0.0, clk)
            tried = True
            if consider:
                ok = _heading_update(state, k, psi, r_m, gate)
            else:
                ok = _scalar_update(state, k, psi, r_m, gate, 0.0)  # (the heading read as an angle: no bound)
            if ok:
                updated = passed = True
            state[k + _LAST_MAG] = clk
    if tried:
        if passed:
            state[k + _GREJ] = -1.0
        elif state[k + _GREJ] < 0.0:
            state[k + _GREJ] = clk  # a streak of rejections starts
        elif clk - state[k + _GREJ] > params[p + _REJECT_RESET]:
            # consistently refused (elapsed time: the magnetometer is offered at 10 Hz, not every sample):
            # the estimate, not every sensor, is wrong (a bad start, a state set from outside, a heading
            # pulled off after a restart): re-open the attitude covariance
            eskf_reopen_attitude(state, k, params, _REOPEN_TILT, _REOPEN_HEADING)
            state[k + _GREJ] = -1.0

    # ---- the gyro bias's plausible range: the pseudo-measurement b = 0 (bias_prior_sigma_rad_s) --------------
    if params[p + _BPRIOR_VAR] > 0.0 and dt > 0.0:
        after = params[p + _BPRIOR_AFTER]
        r_b = params[p + _BPRIOR_VAR] * max(params[p + _BPRIOR_SPREAD], dt) / dt
        for i in range(3):
            if after < 0.0 or (after >= 0.0 and state[k + _BOUT + 3 + i] >= after and state[k + _BOUT + 3 + i] > 0.0):
                for j in range(N):
                    state[k + _H + j] = 0.0
                state[k + _H + 6 + i] = 1.0
                if _scalar_update(state, k, -state[S_BIAS + i], r_b, 1.0e9, state[k + _BNOW]):
                    updated = True

    # ---- inject ------------------------------------------------------------------------------
    if updated:
        kdx = k + _DX
        rx, ry, rz = state[kdx], state[kdx + 1], state[kdx + 2]
        ang = math.sqrt(rx * rx + ry * ry + rz * rz)
        if ang > 0.0:
            h = 0.5 * ang
            sh = math.sin(h) / ang
            e0, e1, e2, e3 = math.cos(h), rx * sh, ry * sh, rz * sh
            a0, a1, a2, a3 = state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3]
            state[S_Q], state[S_Q + 1], state[S_Q + 2], state[S_Q + 3] = quat_multiply(
                e0, e1, e2, e3, a0, a1, a2, a3
            )
            if tau_g > 0.0:  # the stored NED vectors move with the estimate's frame
                nav_lowpass_rotate(state, k + _GLP, rx, ry, rz)
                nav_lowpass_rotate(state, k + _GLP + BW_LEN // 2, rx, ry, rz)
                if abias_on:
                    for m in range(3):
                        nav_lowpass_rotate(state, k + _CLP + m * BW_LEN, rx, ry, rz)
                        nav_lowpass_rotate(state, k + _CLP + m * BW_LEN + BW_LEN // 2, rx, ry, rz)
            if state[k + _STARTED] == 0.0:  # … and so does the start window's sum
                nav_lowpass_rotate(state, k + _START, rx, ry, rz)
        if aided or r_zv > 0.0 or k_drag > 0.0 or at_rest:
            for i in range(3):
                state[k + _V + i] += state[kdx + 3 + i]
        if state[k + _POS_ON] > 0.0:
            state[k + _POS] += state[kdx + _I_POS]
            state[k + _POS + 1] += state[kdx + _I_POS + 1]
        if state[k + _POS_ON_V] > 0.0:
            state[k + _POS + 2] += state[kdx + _I_POS + 2]
        lim = params[p + _BIAS_LIMIT]
        hold = params[p + _BIAS_HOLD]
        for i in range(3):
            b = state[S_BIAS + i] + state[kdx + 6 + i]
            if hold <= 0.0 or state[k + _BOUT + i] >= hold:  # (bias_limit_hold_s: a lasting excursion only)
                b = min(max(b, -lim), lim)
            state[S_BIAS + i] = b
        if abias_on:  # the accelerometer's bias, bounded by 3σ (``accel_bias_sigma_m_s2``, the vibration's share)
            lim_a = 3.0 * math.sqrt(_accel_bias_variance(state, k, params))
            for i in range(3):
                ba = state[k + _ABIAS + i] + state[kdx + _I_ABIAS + i]
                state[k + _ABIAS + i] = min(max(ba, -lim_a), lim_a)
        lim_s = params[p + _SCALE_LIM]
        if lim_s > 0.0:
            for i in range(3):
                sc = state[k + _GSCALE + i] + state[kdx + _I_SCALE + i]
                state[k + _GSCALE + i] = min(max(sc, -lim_s), lim_s)
        # the declination correction (bounded by 5σ of its prior: a disturbed compass taken for it is undone)
        lim_d = 5.0 * math.sqrt(params[p + _DECL_P0])
        d_old = state[k + _DECL]
        state[k + _DECL] = min(max(state[k + _DECL] + state[kdx + _I_DECL], -lim_d), lim_d)
        if params[p + _MAG_NOISE_TAU] > 0.0:  # the compass readings held for the learnt noise follow the correction
            _mag_noise_carry(state, k, rx, ry, rz, state[k + _DECL] - d_old)
        if params[p + _MAGF_P] > 0.0:  # the magnetometer model's pair reference moves with the frame
            mag_ref_rotate(state, k + _MAGF, rx, ry, rz, d_old, state[k + _DECL])
        kt = k + _TAX
        if params[p + _AXIS_P0] > 0.0 and state[k + _P + 9 * N + 9] > 0.0:
            # the thrust axis moved across itself: t ← (t + α₁e₁ + α₂e₂)/‖·‖
            tx, ty, tz, e1x, e1y, e1z, e2x, e2y, e2z = _axis_basis(
                state[kt], state[kt + 1], state[kt + 2], int(state[k + _TREF]))
            a1, a2 = state[kdx + 9], state[kdx + 10]
            tx, ty, tz = tx + a1 * e1x + a2 * e2x, ty + a1 * e1y + a2 * e2y, tz + a1 * e1z + a2 * e2z
            tn = math.sqrt(tx * tx + ty * ty + tz * tz)
            state[kt], state[kt + 1], state[kt + 2] = tx / tn, ty / tn, tz / tn

    if state[k + _STARTED] == 0.0:
        if state[k + _START + 3] >= params[p + _INIT_AVG]:
            # the start window is over: the estimate's up against the mean specific force over it
            state[k + _STARTED] = 1.0
            _axis_start_check(state, k, params)
            mn, me, md = state[k + _START], state[k + _START + 1], state[k + _START + 2]
            m = math.sqrt(mn * mn + me * me + md * md)
            if m > 0.0 and -md < params[p + _INIT_COS] * m:
                # farther off than the mean's own error explains: the first sample was wrong (vibration);
                # the tilt from the mean, the bias learnt from the wrong start forgotten, the filter restarted
                if align_tilt_to_force(state, S_Q, mn, me, md, row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2], mag_ok):
                    for i in range(3):
                        state[S_BIAS + i] = 0.0
                    eskf_reset(state, k, params)
                    state[k + _STARTED] = 1.0
        else:
            add_flag(out, FLAG_STARTUP)
    kp = k + _P
    tilt_var = s_pos(state[kp + 0]) + s_pos(state[kp + N + 1])
    if params[p + _CONS_P0] > 0.0:  # … and what the bias the filter does not estimate puts into the tilt: σ_b² ‖S_θh‖²
        ks = k + _SENS
        for j in range(6):
            tilt_var += params[p + _CONS_P0] * state[ks + j] * state[ks + j]
    tilt_sigma = math.sqrt(max(tilt_var, 0.0))
    finish_step(state, out, tilt_sigma, 1.0 if aided else w_a, w_out)
    out[OUT_HEADING_SIGMA] = math.sqrt(s_pos(state[kp + 2 * N + 2]))
    if aided:
        add_flag(out, FLAG_VELOCITY_AIDED)
    # output: advanced by the IMU data's delay (the state is not), less half the right-rectangle step's lead
    # (``output_half_step``: the step's sum leads the integral by ½ dt per sample for a sampled rate)
    tau = params[p + _DELAY]
    if params[p + _HALF_STEP] > 0.0:
        tau -= 0.5 * min(dt, OUTPUT_HALF_STEP_MAX_S)
    if tau != 0.0:
        hx, hy, hz = 0.5 * gx * tau, 0.5 * gy * tau, 0.5 * gz * tau
        o0, o1, o2, o3 = quat_multiply(out[OUT_Q], out[OUT_Q + 1], out[OUT_Q + 2], out[OUT_Q + 3],
                                       1.0, hx, hy, hz)  # fmt: skip
        n = math.sqrt(o0 * o0 + o1 * o1 + o2 * o2 + o3 * o3)
        out[OUT_Q], out[OUT_Q + 1], out[OUT_Q + 2], out[OUT_Q + 3] = o0 / n, o1 / n, o2 / n, o3 / n
    if not aided:
        out[OUT_ACCEL_WEIGHT] = w_a


@kernel
def eskf_aided(s, params):  # type: ignore[no-untyped-def]
    """True while a velocity fix was fused within ``aiding_timeout_s`` (``s``/``params``: a whole ESKF's)."""
    last = s[S_FILTER + _LAST_FIX]
    return last >= 0.0 and s[S_FILTER + _CLK] - last <= params[P_FILTER + _AID_TIMEOUT]


def declination_of(state: np.ndarray, k: int) -> tuple[float, float]:
    """The learnt declination correction and its 1-σ, rad, of an ESKF state whose own block starts at ``k``
    (the local field's azimuth east of the WMM's magnetic north; ``EskfSettings.declination_sigma_rad``)."""
    var = float(state[k + _P + _I_DECL * N + _I_DECL])
    return float(state[k + _DECL]), math.sqrt(var) if var > 0.0 else 0.0


def mag_delay_of(state: np.ndarray, k: int, params: np.ndarray) -> float:
    """The compass reading's delay behind the IMU's attitude the heading update uses, s, of an ESKF state whose
    own block starts at ``k`` (learnt: ``EskfSettings.mag_learn_tau_s``; else ``mag_delay_s`` less ``sensor_delay_s``)."""
    p = P_FILTER
    if params[p + _MAG_LEARN_TAU] > 0.0:
        return float(state[k + _MLAG])
    return max(float(params[p + _MAG_DELAY] - params[p + _DELAY]), 0.0)


def heading_walk_of(state: np.ndarray, k: int) -> tuple[float, float]:
    """The heading's extra random walk learnt from the compass's innovations, rad/√s, and the running mean of
    their windows' normalised square ψ̄²/S̄ (1: the heading's σ consistent), of an ESKF state whose own block starts at
    ``k`` (``EskfSettings.heading_walk_tau_s``; 0 and 0 while off or nothing learnt; :func:`_heading_walk_step`)."""
    return math.sqrt(max(float(state[k + _HWALK]), 0.0)), float(state[k + _HWALK + 1])


def mag_noise_of(state: np.ndarray, k: int, params: np.ndarray) -> tuple[float, float]:
    """The compass heading's noise per reading the update uses, rad, and the learnt lag-1 correlation of the
    readings, of an ESKF state whose own block starts at ``k`` (learnt: ``EskfSettings.mag_noise_tau_s``, as
    :func:`_mag_noise_step` computes it; else ``heading_noise_rad`` and 0)."""
    p = P_FILTER
    if not params[p + _MAG_NOISE_TAU] > 0.0:
        return math.sqrt(float(params[p + _R_HEADING])), 0.0
    d1, d2 = float(state[k + _MNOISE]), float(state[k + _MNOISE + 1])
    rho = min(max(d2 / d1 - 1.0, 0.0), 0.9) if d1 > 0.0 else 0.0
    r = d1 * (1.0 + rho) / (1.0 - rho) ** 2
    return math.sqrt(min(max(r, float(params[p + _MAG_NOISE_MIN])), float(params[p + _MAG_NOISE_MAX]))), rho


def thrust_axis_of(state: np.ndarray, k: int) -> np.ndarray | None:
    """The thrust axis held in an ESKF state whose own block starts at ``k`` (unit, IMU frame), or None."""
    t = np.array(state[k + _TAX : k + _TAX + 3], dtype=float)
    n = float(np.linalg.norm(t))
    return t / n if n > 0.0 else None


def gyro_scale_of(state: np.ndarray, k: int) -> np.ndarray:
    """The gyro's estimated scale-factor errors (per axis, a fraction: reading = (1 + s)·ω + b) held in an
    ESKF state whose own block starts at ``k`` (0 where not estimated)."""
    return np.array(state[k + _GSCALE : k + _GSCALE + 3], dtype=float)


def slow_force_density_of(state: np.ndarray, k: int, params: np.ndarray) -> float:
    """The specific force's slow-error density added to the velocity's process noise, (m/s²)²·s per axis
    (``EskfSettings.slow_force_block_s``; 0 while off or fewer than three blocks are in).  ``k``: the ESKF's
    ``S_FILTER`` offset; ``params`` the whole parameter vector."""
    t_blk = float(params[P_FILTER + _SLOW_BLOCK])
    ks = k + _SLOW
    if not (t_blk > 0.0 and state[ks + 8] > 2.0):
        return 0.0
    return max(float(state[ks + 9] - state[ks + 10]), 0.0) * t_blk


def accel_bias_of(state: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The estimated accelerometer bias (body frame, m/s²) and its 1-σ per axis, of an ESKF state whose own block
    starts at ``k`` (zeros while ``accel_bias_sigma_m_s2`` is 0)."""
    kp = k + _P + _I_ABIAS * N + _I_ABIAS
    sig = np.sqrt(np.maximum([state[kp], state[kp + N + 1], state[kp + 2 * N + 2]], 0.0))
    return state[k + _ABIAS : k + _ABIAS + 3].copy(), sig


@kernel
def s_pos(x):  # type: ignore[no-untyped-def]
    """x if positive, else 0."""
    return x if x > 0.0 else 0.0


class Eskf(AttitudeFilter):
    """Velocity-aided error-state Kalman filter.  See :class:`EskfSettings` and the module docstring."""

    name = "eskf"
    settings_type = EskfSettings
    step = step
    internal_len = _N_STATE

    @classmethod
    def filter_params(cls, settings: EskfSettings) -> np.ndarray:  # type: ignore[override]
        p = np.zeros(_N_PARAMS)
        p[_Q_GYRO] = settings.gyro_noise_rad_s**2
        p[_Q_ACCEL] = settings.accel_noise_m_s2**2
        p[_Q_BIAS] = settings.bias_walk_rad_s2**2
        p[_R_VEL_H] = settings.velocity_noise_m_s**2
        p[_R_VEL_V] = settings.vertical_velocity_noise_m_s**2
        p[_R_HEADING] = settings.heading_noise_rad**2
        p[_R_GRAVITY] = settings.gravity_noise_m_s2**2
        p[_GATE] = settings.gate_sigma
        p[_VEL_GATE] = settings.velocity_gate_sigma
        p[_NOISE_TAU] = settings.measured_noise_tau_s
        p[_AID_TIMEOUT] = settings.aiding_timeout_s
        p[_DELAY] = settings.sensor_delay_s
        p[_MAG_PERIOD] = 1.0 / settings.mag_rate_hz
        p[_P0_TILT] = settings.initial_tilt_rad**2
        p[_P0_HEADING] = settings.initial_heading_rad**2
        p[_P0_BIAS] = settings.initial_bias_rad_s**2
        p[_BIAS_LIMIT] = settings.bias_limit_rad_s
        p[_VEL_RESET] = settings.velocity_reset_s
        p[_ATT_STEP] = settings.max_attitude_step_rad
        p[_ATT_STEP_WIN] = settings.max_attitude_step_window_s
        p[_MAG_STALE] = settings.mag_staleness_s
        p[_MAG_DELAY] = settings.mag_delay_s
        p[_MAG_LEARN_TAU] = settings.mag_learn_tau_s
        p[_MAG_NOISE_TAU] = settings.mag_noise_tau_s
        p[_MAG_NOISE_MIN] = settings.mag_noise_min_rad**2
        p[_MAG_NOISE_MAX] = settings.mag_noise_max_rad**2
        p[_REJECT_RESET] = settings.rejection_reset_s
        p[_R_ZV] = settings.unaided_velocity_noise_m_s**2
        p[_ZV_PERIOD] = settings.unaided_velocity_period_s
        p[_REALIGN_SIN] = math.sin(min(settings.realign_innovation_rad, 0.5 * math.pi))
        p[_REALIGN_S] = settings.realign_after_s
        p[_GRAV_TAU] = settings.gravity_lowpass_s
        p[_ADAPT_TAU] = settings.adaptive_gravity_tau_s
        p[_MAGF_P : _MAGF_P + MP_LEN] = magfield_params(settings.mag_model)
        p[_R_MODEL_MAX] = settings.mag_model.max_heading_sigma_rad**2
        p[_MIN_BODY] = settings.mag_model.min_body_field_ut**2
        p[_REOPEN_ON_STEP] = 1.0 if settings.mag_model.reopen_heading else 0.0
        p[_DRAG_K] = settings.drag_coefficient_1_s
        p[_R_DRAG] = settings.drag_noise_m_s2**2
        p[_THRUST_TAU] = settings.thrust_axis_tau_s
        p[_AXIS_P0] = settings.thrust_axis_sigma_rad**2
        p[_AXIS_Q] = settings.thrust_axis_walk_rad_s**2
        p[_Q_SCALE] = 2.0 * settings.gyro_scale_sigma**2 * settings.gyro_scale_tau_s
        p[_Q_CROSS] = 2.0 * settings.gyro_cross_axis_sigma**2 * settings.gyro_scale_tau_s
        p[_DECL_P0] = settings.declination_sigma_rad**2
        p[_INIT_AVG] = settings.initial_average_s
        p[_INIT_COS] = math.cos(min(settings.initial_realign_rad, math.pi))
        p[_R_REST_RATE] = settings.rest_rate_noise_rad_s**2
        p[_REST_CHECK_VAR] = settings.rest_check_sigma_rad_s**2
        p[_REST_WOBBLE_VAR] = settings.rest_wobble_sigma_rad_s**2
        p[_REST_HOVER_VIB] = settings.rest_hover_vibration_m_s2
        p[_REST_HOVER_SPEED] = settings.rest_hover_speed_m_s
        p[_R_REST_VEL] = settings.rest_velocity_noise_m_s**2
        p[_REST_P : _REST_P + RP_LEN] = settings.rest.to_params()
        p[_R_POS_H] = settings.position_noise_m**2
        p[_R_POS_V] = settings.vertical_position_noise_m**2
        p[_POS_GATE] = settings.position_gate_sigma
        p[_Q_POS] = settings.position_walk_m_s**2
        p[_Q_BIAS_AIDED] = settings.bias_walk_aided_rad_s2**2
        p[_SCALE_P0] = settings.gyro_scale_state_sigma**2
        p[_SCALE_Q] = settings.gyro_scale_state_walk_1_s**2
        p[_SCALE_LIM] = 3.0 * settings.gyro_scale_state_sigma
        p[_DRAG_RESET] = settings.drag_reset_s
        p[_ABIAS_P0] = settings.accel_bias_sigma_m_s2**2
        p[_ABIAS_TAU] = settings.accel_bias_tau_s
        p[_ABIAS_VIB] = settings.accel_bias_vibration_ratio**2
        p[_ABIAS_AIDED] = 1.0 if settings.accel_bias_aided_only else 0.0
        p[_ABIAS_ACROSS] = settings.accel_bias_sigma_m_s2**2 if settings.accel_bias_across_thrust else 0.0
        p[_ABIAS_SPEED] = settings.accel_bias_live_speed_m_s
        p[_CONS_P0] = settings.accel_bias_consider_sigma_m_s2**2
        p[_BIAS_HOLD] = settings.bias_limit_hold_s
        p[_BPRIOR_VAR] = settings.bias_prior_sigma_rad_s**2
        p[_BPRIOR_AFTER] = settings.bias_prior_after_s
        p[_BPRIOR_SPREAD] = settings.bias_prior_spread_s
        p[_Q_SCALE_TILT] = settings.gyro_scale_tilt_sigma**2
        p[_SCALE_TILT_TAU] = settings.gyro_scale_tilt_memory_s
        p[_HWALK_TAU] = settings.heading_walk_tau_s
        p[_HWALK_MAX] = settings.heading_walk_max_rad_s**2
        p[_HWALK_WIN] = settings.heading_walk_window_s
        p[_DRAG_C] = settings.drag_quadratic_1_m
        p[_HALF_STEP] = 1.0 if settings.output_half_step else 0.0
        p[_DRAG_NIS_TAU] = settings.drag_noise_match_s
        p[_SLOW_BLOCK] = settings.slow_force_block_s
        p[_SLOW_TAU] = settings.slow_force_tau_s
        p[_BOFF_LAG] = settings.mag_body_offset_lag_s
        p[_BOFF_MIN_TURN] = settings.mag_body_offset_min_turn
        p[_BOFF_RESID] = settings.mag_body_offset_residual_fraction
        p[_BOFF_SIGMA] = settings.mag_body_offset_sigma_ut**2
        p[_MAG_REJ_SCALE] = settings.mag_rejected_sigma_scale
        return p

    def set_multirotor(self, drag_coefficient_1_s: float | None = None) -> None:
        """The vehicle is a multirotor: the rotor-drag measurement on (``EskfSettings.drag_coefficient_1_s``).

        ``None`` keeps a coefficient already set, else the multirotor default 0.5 /s; 0 turns it off.
        """
        from dataclasses import replace

        k = drag_coefficient_1_s
        if k is None:
            k = self._settings.drag_coefficient_1_s or MULTIROTOR_DRAG_1_S
        self._settings = replace(self._settings, drag_coefficient_1_s=float(k))
        self._params[P_FILTER + _DRAG_K] = self._settings.drag_coefficient_1_s

    def thrust_axis(self) -> np.ndarray | None:
        """The thrust axis the drag measurement uses: a unit vector in the IMU frame (None: not yet learnt)."""
        return thrust_axis_of(self._state, S_FILTER)

    def set_sensor_delay(self, delay_s: float) -> None:
        """The IMU data's delay behind its time stamps, s (see ``EskfSettings.sensor_delay_s``)."""
        from dataclasses import replace

        self._settings = replace(self._settings, sensor_delay_s=float(delay_s))
        self._params[P_FILTER + _DELAY] = self._settings.sensor_delay_s

    def initial_internal(self) -> np.ndarray:
        s = np.zeros(_N_STATE)
        eskf_reset(s, 0, self._params)
        return s

    def mag_delay_s(self) -> float:
        """The compass reading's delay behind the IMU's attitude the heading update uses, s (:func:`mag_delay_of`)."""
        return mag_delay_of(self._state, S_FILTER, self._params)

    def mag_noise_rad(self) -> tuple[float, float]:
        """The compass heading's noise per reading and its lag-1 correlation (:func:`mag_noise_of`)."""
        return mag_noise_of(self._state, S_FILTER, self._params)

    def heading_walk_rad_s(self) -> tuple[float, float]:
        """The heading's learnt extra random walk, rad/√s, and the compass innovations' mean ψ̄²/S̄ (:func:`heading_walk_of`)."""
        return heading_walk_of(self._state, S_FILTER)

    def declination_correction_rad(self) -> float:
        """The learnt declination correction: the local field's azimuth east of the WMM's magnetic north, rad."""
        return declination_of(self._state, S_FILTER)[0]

    def mag_status(self) -> dict[str, object]:
        """The magnetometer's state for the status page (:func:`magfield.mag_status`): the learnt model's
        summary when it is on, else the schedule's trust in the last reading; the learnt declination."""
        k = S_FILTER + _MAGF
        model = mag_model_summary(self._state[k : k + MF_LEN]) if self._settings.mag_model.enabled else None  # type: ignore[attr-defined]
        return mag_status(model, self._out, *declination_of(self._state, S_FILTER))

    def mag_model_state(self) -> dict[str, object] | None:
        """The learnt magnetometer model (state, offsets, earth field; :func:`mag_model_summary`), None when off."""
        if not self._settings.mag_model.enabled:  # type: ignore[attr-defined]
            return None
        k = S_FILTER + _MAGF
        return mag_model_summary(self._state[k : k + MF_LEN])

    def export_mag_model(self) -> dict[str, object] | None:
        """The learnt magnetometer model to keep across a restart (:func:`magfield.export_model`)."""
        if not self._settings.mag_model.enabled:  # type: ignore[attr-defined]
            return None
        k = S_FILTER + _MAGF
        return export_model(self._state[k : k + MF_LEN])

    def load_mag_model(self, saved: object) -> str | None:
        """Start from a saved model (:func:`magfield.import_model`); return why not, None when taken."""
        if not self._settings.mag_model.enabled:  # type: ignore[attr-defined]
            return "the magnetometer model is off"
        k = S_FILTER + _MAGF
        return import_model(self._state[k : k + MF_LEN], self._settings.mag_model, saved)  # type: ignore[attr-defined]
