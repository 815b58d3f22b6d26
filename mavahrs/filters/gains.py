r"""The gain schedule shared by every filter: start-up boost and sensor rejection.

Madgwick 2010, section 6 ("dynamic gains"), and the 003 tutorial's section on
accelerations: a filter converges fast when its correction gain is high, and
is misled by motion acceleration (or a nearby magnet) when it trusts the
accelerometer (or magnetometer) too much.  This schedule produces, per sample,

* ``boost`` ≥ 1 — a start-up multiplier that ramps linearly from
  ``startup_gain_factor`` to 1 over ``startup_s`` after (re)initialisation;
* ``accel_weight`` in [0, 1] — trust in the accelerometer: 1 when ‖a‖ ≈ g,
  the spin rate is low and the horizontal specific force in NED is small
  (INAV's accelerometer-nearness weight, the aircraft gyro-vertical's gating);
  it drops at once and recovers with time constant ``recovery_s``;
* ``mag_weight`` in [0, 1] — trust in the magnetometer: 0 when the field's
  norm or dip angle departs from the reference (configured, or learned while
  the field looks consistent).

A rejection that lasts longer than ``rejection_timeout_s`` is forced to end
(weights back to 1), so that a wrong attitude estimate — which also makes the
horizontal specific force look large — cannot lock itself in.

The filters multiply their own gains by these factors.  The schedule's state
lives in the filter state array (``GS_*`` offsets from ``SCHEDULE_STATE``), so
it is read, set and reset with the filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mavahrs.filters.jit import kernel

__all__ = ["GainScheduleSettings", "schedule_step", "schedule_reset", "GS_LEN", "GP_LEN"]

G_M_S2 = 9.80665

# --- parameter block (float64), in this order -------------------------------
GP_STARTUP_FACTOR = 0
GP_STARTUP_S = 1
GP_ACCEL_NORM_TOL = 2
GP_SPIN_RATE = 3
GP_HORIZONTAL_TOL = 4
GP_RECOVERY_S = 5
GP_REJECT_TIMEOUT_S = 6
GP_MAG_NORM_TOL = 7
GP_MAG_DIP_TOL = 8
GP_MAG_REF_NORM = 9
GP_MAG_REF_DIP = 10
GP_MAG_LEARN_S = 11
GP_MAG_DIP_FROM_ATTITUDE = 12
GP_LEN = 13

# --- state block (float64) ----------------------------------------------------
GS_T = 0  # time since (re)initialisation, s
GS_ACCEL_W = 1  # smoothed accelerometer weight
GS_MAG_W = 2  # smoothed magnetometer weight
GS_MAG_NORM = 3  # reference field norm, µT (0 = not yet known)
GS_MAG_DIP = 4  # reference dip angle, rad (positive: field points below horizon)
GS_ACCEL_REJECT_T = 5  # how long the accelerometer has been (mostly) rejected, s
GS_MAG_REJECT_T = 6  # how long the magnetometer has been rejected, s
GS_MAG_LAST_T = 7  # GS_T of the last valid magnetometer sample (−1: none yet)
GS_LEN = 8


@dataclass(frozen=True)
class GainScheduleSettings:
    """Dynamic gains common to all filters.  0 disables the feature it names.

    Attributes:
        startup_gain_factor: multiplier on the filter's correction gain right
            after initialisation, ramping linearly to 1 (Madgwick 2010 §6 uses
            β = 2.5 for 10 s; INAV uses ×10 K_P).  1 = no boost.
        startup_s: duration of the start-up ramp, s.  0 = no boost.
        accel_norm_tolerance: relative departure of ‖a‖ from g at which the
            accelerometer weight reaches 0 (weight 1 − |‖a‖/g − 1|/tol).
            INAV: 0.25 on ‖a‖² ≈ 0.12 on ‖a‖.  0 = no norm gating.
        spin_rate_rad_s: spin rate above which the accelerometer weight
            falls (to half at 2×, inverse-square beyond).  0 = no gating.
        horizontal_tolerance: horizontal specific force in NED, as a fraction
            of g, at which the weight reaches 0 (manoeuvring).  0 = off.
        recovery_s: time constant with which a weight returns towards 1
            after a rejection, s.  0 = instantly.
        rejection_timeout_s: a rejection lasting longer than this is ended
            (weights forced to 1) so a wrong estimate cannot lock itself in.
            0 = never.
        mag_norm_tolerance: relative departure of ‖m‖ from the reference
            norm beyond which the magnetometer is rejected.  0 = off.
        mag_dip_tolerance_rad: departure of the dip angle from the reference
            beyond which the magnetometer is rejected, rad.  0 = off.
        mag_reference_norm_ut: expected field strength, µT (e.g. from the
            World Magnetic Model).  0 = learn it from the data.
        mag_reference_dip_rad: expected dip (inclination), rad, positive
            downward (northern hemisphere).  Used when the norm is given.
        mag_learn_s: time constant of the reference learning, s.
        mag_dip_from_attitude: measure the field's dip against the vertical
            of the attitude estimate instead of the (trusted) accelerometer.
            The estimate is not disturbed by motion accelerations, so fast
            translation and spinning do not fake a dip change; the
            accelerometer needs no converged estimate.  False = accelerometer.
    """

    startup_gain_factor: float = 10.0
    startup_s: float = 3.0
    accel_norm_tolerance: float = 0.15
    spin_rate_rad_s: float = 0.0
    horizontal_tolerance: float = 0.0
    recovery_s: float = 0.5
    rejection_timeout_s: float = 10.0
    mag_norm_tolerance: float = 0.1
    mag_dip_tolerance_rad: float = math.radians(10.0)
    mag_reference_norm_ut: float = 0.0
    mag_reference_dip_rad: float = 0.0
    mag_learn_s: float = 20.0
    mag_dip_from_attitude: bool = False

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"gain schedule setting {name} must be finite, got {value!r}")
            if name != "mag_reference_dip_rad" and value < 0:
                raise ValueError(f"gain schedule setting {name} must be ≥ 0, got {value!r}")
        if self.startup_gain_factor < 1.0:
            raise ValueError(
                f"startup_gain_factor must be ≥ 1 (1 = no boost), got {self.startup_gain_factor}"
            )

    def to_params(self) -> np.ndarray:
        p = np.zeros(GP_LEN)
        p[GP_STARTUP_FACTOR] = self.startup_gain_factor
        p[GP_STARTUP_S] = self.startup_s
        p[GP_ACCEL_NORM_TOL] = self.accel_norm_tolerance
        p[GP_SPIN_RATE] = self.spin_rate_rad_s
        p[GP_HORIZONTAL_TOL] = self.horizontal_tolerance
        p[GP_RECOVERY_S] = self.recovery_s
        p[GP_REJECT_TIMEOUT_S] = self.rejection_timeout_s
        p[GP_MAG_NORM_TOL] = self.mag_norm_tolerance
        p[GP_MAG_DIP_TOL] = self.mag_dip_tolerance_rad
        p[GP_MAG_REF_NORM] = self.mag_reference_norm_ut
        p[GP_MAG_REF_DIP] = self.mag_reference_dip_rad
        p[GP_MAG_LEARN_S] = self.mag_learn_s
        p[GP_MAG_DIP_FROM_ATTITUDE] = 1.0 if self.mag_dip_from_attitude else 0.0
        return p


@kernel
def schedule_reset(gs, gp):  # type: ignore[no-untyped-def]
    """Start the schedule afresh (called on (re)initialisation)."""
    gs[GS_T] = 0.0
    gs[GS_ACCEL_W] = 1.0
    gs[GS_MAG_W] = 1.0
    gs[GS_MAG_NORM] = gp[GP_MAG_REF_NORM]
    gs[GS_MAG_DIP] = gp[GP_MAG_REF_DIP]
    gs[GS_ACCEL_REJECT_T] = 0.0
    gs[GS_MAG_REJECT_T] = 0.0
    gs[GS_MAG_LAST_T] = -1.0


@kernel
def _smooth(previous, target, dt, tau):  # type: ignore[no-untyped-def]
    if target <= previous or tau <= 0.0:
        return target  # drop at once (or no smoothing)
    k = dt / tau
    if k > 1.0:
        k = 1.0
    return previous + (target - previous) * k


@kernel(inline=True)  # every sample; inlined into the steps (see filters/jit.py)
def schedule_step(gs, gp, q0, q1, q2, q3, gx, gy, gz, ax, ay, az, accel_ok, mx, my, mz, mag_ok, dt):  # type: ignore[no-untyped-def]
    """Advance the schedule by one sample; return ``(boost, accel_weight, mag_weight)``.

    ``q`` is the current ``q_body_to_ned`` estimate, ``a`` the specific force
    (m/s²) and ``m`` the field (µT) in body axes; ``accel_ok``/``mag_ok`` say
    whether those vectors are valid this sample.
    """
    gs[GS_T] += dt
    t = gs[GS_T]
    boost = 1.0
    startup = gp[GP_STARTUP_S]
    if startup > 0.0 and t < startup:
        boost = 1.0 + (gp[GP_STARTUP_FACTOR] - 1.0) * (1.0 - t / startup)
    in_startup = boost > 1.0

    # ---- accelerometer trust -------------------------------------------------
    w_a = 0.0
    if accel_ok:
        w_a = 1.0
        a_norm = math.sqrt(ax * ax + ay * ay + az * az)
        tol = gp[GP_ACCEL_NORM_TOL]
        if tol > 0.0:
            w_a = min(w_a, 1.0 - abs(a_norm / G_M_S2 - 1.0) / tol)
        spin_limit = gp[GP_SPIN_RATE]
        if spin_limit > 0.0:
            spin = math.sqrt(gx * gx + gy * gy + gz * gz)
            if spin > spin_limit:
                r = spin_limit / spin
                w_a = min(w_a, r * r)
        htol = gp[GP_HORIZONTAL_TOL]
        if htol > 0.0:
            # Horizontal specific force in NED: rows 0 and 1 of C_body_to_ned.
            fn = (1 - 2 * (q2 * q2 + q3 * q3)) * ax + 2 * (q1 * q2 - q0 * q3) * ay + 2 * (q1 * q3 + q0 * q2) * az
            fe = 2 * (q1 * q2 + q0 * q3) * ax + (1 - 2 * (q1 * q1 + q3 * q3)) * ay + 2 * (q2 * q3 - q0 * q1) * az
            h = math.sqrt(fn * fn + fe * fe) / G_M_S2
            w_a = min(w_a, 1.0 - h / htol)
        if w_a < 0.0:
            w_a = 0.0
        if in_startup:
            w_a = 1.0  # converge first: no rejection while boosted
        w_a = _smooth(gs[GS_ACCEL_W], w_a, dt, gp[GP_RECOVERY_S])
        if w_a < 0.5:
            gs[GS_ACCEL_REJECT_T] += dt
        else:
            gs[GS_ACCEL_REJECT_T] = 0.0
        timeout = gp[GP_REJECT_TIMEOUT_S]
        if timeout > 0.0 and gs[GS_ACCEL_REJECT_T] > timeout:
            w_a = 1.0
            gs[GS_ACCEL_REJECT_T] = 0.0
        gs[GS_ACCEL_W] = w_a

    # ---- magnetometer trust --------------------------------------------------
    w_m = 0.0
    if mag_ok:
        w_m = 1.0
        # the magnetometer's own interval: a stream whose readings come on a few rows only (PX4: a
        # HIGHRES_IMU field every 4th–20th sample, NaN between) recovers and times out in seconds, not
        # in samples (per-row dt made the 0.5 s recovery last ~10 s there: heading on the gyro alone)
        dt_m = dt if gs[GS_MAG_LAST_T] < 0.0 else t - gs[GS_MAG_LAST_T]
        gs[GS_MAG_LAST_T] = t
        m_norm = math.sqrt(mx * mx + my * my + mz * mz)
        # dip: angle of m below the horizontal plane; down = −a/‖a‖ in body axes
        # (from the accelerometer when valid, else from the attitude).
        if accel_ok and w_a > 0.5 and gp[GP_MAG_DIP_FROM_ATTITUDE] == 0.0:
            a_norm = math.sqrt(ax * ax + ay * ay + az * az)
            s = -(mx * ax + my * ay + mz * az) / (m_norm * a_norm)  # down d̂ = −â
        else:
            dx = 2 * (q1 * q3 - q0 * q2)
            dy = 2 * (q2 * q3 + q0 * q1)
            dz = 1 - 2 * (q1 * q1 + q2 * q2)
            s = (mx * dx + my * dy + mz * dz) / m_norm
        if s > 1.0:
            s = 1.0
        elif s < -1.0:
            s = -1.0
        dip = math.asin(s)
        if gs[GS_MAG_NORM] <= 0.0:
            gs[GS_MAG_NORM] = m_norm  # first valid sample sets the reference
            gs[GS_MAG_DIP] = dip
        ref_n = gs[GS_MAG_NORM]
        ntol = gp[GP_MAG_NORM_TOL]
        dtol = gp[GP_MAG_DIP_TOL]
        consistent = True
        if ntol > 0.0 and abs(m_norm / ref_n - 1.0) > ntol:
            consistent = False
        if dtol > 0.0 and abs(dip - gs[GS_MAG_DIP]) > dtol:
            consistent = False
        if not consistent and not in_startup:
            w_m = 0.0
        w_m = _smooth(gs[GS_MAG_W], w_m, dt_m, gp[GP_RECOVERY_S])
        if w_m < 0.5:
            gs[GS_MAG_REJECT_T] += dt_m
        else:
            gs[GS_MAG_REJECT_T] = 0.0
        timeout = gp[GP_REJECT_TIMEOUT_S]
        forced = False
        if timeout > 0.0 and gs[GS_MAG_REJECT_T] > 3.0 * timeout:
            # A field that stays different for long is the new normal
            # (moved to another place, or the reference was learned in a
            # disturbance): adopt it.
            gs[GS_MAG_NORM] = m_norm
            gs[GS_MAG_DIP] = dip
            gs[GS_MAG_REJECT_T] = 0.0
            w_m = 1.0
            forced = True
        gs[GS_MAG_W] = w_m
        learn = gp[GP_MAG_LEARN_S]
        if (consistent or forced) and learn > 0.0 and gp[GP_MAG_REF_NORM] <= 0.0 and w_a > 0.5:
            k = dt_m / learn
            if k > 1.0:
                k = 1.0
            gs[GS_MAG_NORM] += (m_norm - gs[GS_MAG_NORM]) * k
            gs[GS_MAG_DIP] += (dip - gs[GS_MAG_DIP]) * k
    return boost, w_a, w_m
