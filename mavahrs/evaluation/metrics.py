r"""Attitude error metrics (pure functions on arrays).

BROAD's definitions (Laidig et al. 2021; ``../shared/data/README.md``): with
the earth-frame error quaternion ``e = q_est ⊗ q_ref*`` (both body → the same
earth frame),

* total error        ``2·acos(|e_w|)``,
* heading error      ``2·atan(|e_z / e_w|)`` (rotation about the vertical),
* inclination error  ``2·acos(√(e_w² + e_z²))`` (the remaining tilt).

Heading and inclination depend only on the earth frame's vertical axis being
z (true for NED, ENU and NWU alike).  Per trial, the RMS over the scored
samples (NaN references ignored); groups are plain means of per-trial RMS.

The papers' per-angle figures come from the **body-frame** error quaternion
``q_ε = q_ref* ⊗ q_est`` (so ``q_est = q_ref ⊗ q_ε``): its aerospace Euler
angles are the roll, pitch and yaw errors about the sensor's own X, Y, Z axes,
which is how Madgwick 2010 (section 5) defines φ_ε, θ_ε, ψ_ε; unlike a
difference of Euler angles they have no wrap-around or gimbal-lock artefacts.
Madgwick 2010 Table 1 splits the RMS into rest (angular rate < 5°/s) and
motion (≥ 5°/s); the 2022 paper (Table 2) reports the mean and standard
deviation per angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.geometry.quaternion import conjugate, multiply
from mavahrs.geometry.rotation import to_euler_rad

__all__ = [
    "error_quaternion",
    "total_error_rad",
    "heading_error_rad",
    "inclination_error_rad",
    "attitude_errors_rad",
    "rms_deg",
    "AttitudeErrorSummary",
    "summarize",
    "body_error_quaternion",
    "euler_errors_rad",
    "motion_mask",
    "AngleStats",
    "angle_stats",
    "REST_RATE_THRESHOLD_RAD_S",
    "euler_deg",
]

#: Madgwick 2010, section 5.1: rest below 5°/s, motion at or above it.
REST_RATE_THRESHOLD_RAD_S = float(np.radians(5.0))

Array = NDArray[np.float64]


def _normalize_allow_nan(q: ArrayLike) -> Array:
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return q / n


def error_quaternion(q_est: ArrayLike, q_ref: ArrayLike) -> Array:
    """Earth-frame error ``e = q_est ⊗ q_ref*`` (NaN rows stay NaN)."""
    return multiply(_normalize_allow_nan(q_est), conjugate(_normalize_allow_nan(q_ref)))


# BROAD's definitions, total = 2·acos|e_w| and inclination = 2·acos√(e_w² + e_z²), written as
# the equal atan2 forms: acos near 1 resolves no angle below ~2e-8 rad (one rounding step of
# its argument), atan2 of the two parts is exact to rounding at every angle.


def total_error_rad(e: ArrayLike) -> Array:
    e = np.asarray(e)
    return 2.0 * np.arctan2(np.sqrt(e[..., 1] ** 2 + e[..., 2] ** 2 + e[..., 3] ** 2), np.abs(e[..., 0]))


def heading_error_rad(e: ArrayLike) -> Array:
    e = np.asarray(e)
    return 2.0 * np.arctan(np.abs(e[..., 3] / e[..., 0]))


def inclination_error_rad(e: ArrayLike) -> Array:
    e = np.asarray(e)
    return 2.0 * np.arctan2(np.sqrt(e[..., 1] ** 2 + e[..., 2] ** 2), np.sqrt(e[..., 0] ** 2 + e[..., 3] ** 2))


def attitude_errors_rad(q_est: ArrayLike, q_ref: ArrayLike) -> tuple[Array, Array, Array]:
    """(total, heading, inclination) error per sample, rad; NaN where the reference is NaN."""
    e = error_quaternion(q_est, q_ref)
    with np.errstate(invalid="ignore", divide="ignore"):
        return total_error_rad(e), heading_error_rad(e), inclination_error_rad(e)


def rms_deg(err_rad: ArrayLike, mask: ArrayLike | None = None) -> float:
    """RMS in degrees over ``mask`` (all samples if None), ignoring NaN."""
    err = np.asarray(err_rad, dtype=np.float64)
    if mask is not None:
        err = err[np.asarray(mask, dtype=bool)]
    err = err[np.isfinite(err)]
    if err.size == 0:
        return float("nan")
    return float(np.degrees(np.sqrt(np.mean(err**2))))


@dataclass(frozen=True)
class AttitudeErrorSummary:
    """RMS errors of one estimate against one reference, degrees."""

    total_rms_deg: float
    heading_rms_deg: float
    inclination_rms_deg: float
    samples: int


def summarize(q_est: ArrayLike, q_ref: ArrayLike, mask: ArrayLike | None = None) -> AttitudeErrorSummary:
    """BROAD's per-trial figures over the scored samples ``mask``."""
    total, heading, incl = attitude_errors_rad(q_est, q_ref)
    valid = np.isfinite(total)
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    return AttitudeErrorSummary(
        total_rms_deg=rms_deg(total, valid),
        heading_rms_deg=rms_deg(heading, valid),
        inclination_rms_deg=rms_deg(incl, valid),
        samples=int(valid.sum()),
    )




def body_error_quaternion(q_est: ArrayLike, q_ref: ArrayLike) -> Array:
    """Body-frame error ``q_ε = q_ref* ⊗ q_est`` (``q_est = q_ref ⊗ q_ε``), NaN rows stay NaN."""
    return multiply(conjugate(_normalize_allow_nan(q_ref)), _normalize_allow_nan(q_est))


def euler_errors_rad(q_est: ArrayLike, q_ref: ArrayLike) -> Array:
    """Signed roll, pitch, yaw errors (N, 3), rad, about the body axes.

    The aerospace Z-Y-X Euler angles of the body-frame error quaternion
    (estimate minus reference, each in (−π, π]); NaN where the reference is NaN.
    """
    e = body_error_quaternion(q_est, q_ref)
    e = np.where(e[..., :1] < 0.0, -e, e)  # the shortest rotation (q and −q are equal)
    bad = ~np.all(np.isfinite(e), axis=-1)
    safe = np.where(bad[..., None], np.array([1.0, 0.0, 0.0, 0.0]), e)
    out = to_euler_rad(safe)
    out[bad] = np.nan
    return out


def euler_deg(q_body_to_ned: ArrayLike) -> Array:
    """Aerospace roll, pitch, yaw (N, 3) in degrees, for people; NaN rows stay NaN."""
    q = np.atleast_2d(np.asarray(q_body_to_ned, dtype=np.float64))
    bad = ~(np.all(np.isfinite(q), axis=-1) & (np.linalg.norm(np.nan_to_num(q), axis=-1) > 0))
    safe = np.where(bad[..., None], np.array([1.0, 0.0, 0.0, 0.0]), q)
    out = np.degrees(to_euler_rad(safe))
    out[bad] = np.nan
    return out


def motion_mask(
    gyro_rad_s: ArrayLike,
    dt_s: ArrayLike,
    threshold_rad_s: float = REST_RATE_THRESHOLD_RAD_S,
    smoothing_s: float = 0.05,
) -> NDArray[np.bool_]:
    """True where the sensor moves: angular rate ≥ ``threshold_rad_s`` (Madgwick 2010 Table 1).

    The rate is the norm of the measured gyro averaged over a centred window of
    about ``smoothing_s`` (so that gyro noise does not flicker the split);
    non-finite gyro samples count as motion.  The rest mask is its complement.
    """
    gyro = np.asarray(gyro_rad_s, dtype=np.float64)
    rate = np.linalg.norm(gyro, axis=-1)
    finite = np.isfinite(rate)
    dt = np.broadcast_to(np.asarray(dt_s, dtype=np.float64), rate.shape)
    dt_ok = dt[np.isfinite(dt) & (dt > 0)]
    period = float(np.median(dt_ok)) if dt_ok.size else 0.0
    width = int(round(smoothing_s / period)) if period > 0 else 1
    if width > 1 and rate.size >= width:
        r = np.where(finite, rate, 0.0)
        kernel = np.ones(width)
        count = np.convolve(finite.astype(np.float64), kernel, mode="same")  # edges: fewer samples
        smooth = np.convolve(r, kernel, mode="same") / np.maximum(count, 1.0)
        rate = np.where(finite, smooth, np.inf)
    else:
        rate = np.where(finite, rate, np.inf)
    return np.asarray(rate >= threshold_rad_s)


@dataclass(frozen=True)
class AngleStats:
    """Per-angle error figures over a set of samples, degrees.

    Attributes:
        rms_deg: RMS of (roll, pitch, yaw) error.
        mean_deg: mean (signed) error, the 2022 paper's Table 2.
        sd_deg: standard deviation of the error around its mean.
        max_abs_deg: largest absolute error.
        samples: how many samples were scored.
    """

    rms_deg: tuple[float, float, float]
    mean_deg: tuple[float, float, float]
    sd_deg: tuple[float, float, float]
    max_abs_deg: tuple[float, float, float]
    samples: int


def angle_stats(euler_err_rad: ArrayLike, mask: ArrayLike | None = None) -> AngleStats:
    """RMS, mean, SD and max of per-angle errors (from :func:`euler_errors_rad`) over ``mask``."""
    err = np.degrees(np.asarray(euler_err_rad, dtype=np.float64).reshape(-1, 3))
    valid = np.all(np.isfinite(err), axis=1)
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    sel = err[valid]
    if sel.shape[0] == 0:
        nan3 = (float("nan"),) * 3
        return AngleStats(nan3, nan3, nan3, nan3, 0)

    def t(a: Array) -> tuple[float, float, float]:
        return (float(a[0]), float(a[1]), float(a[2]))

    return AngleStats(
        rms_deg=t(np.sqrt(np.mean(sel**2, axis=0))),
        mean_deg=t(np.mean(sel, axis=0)),
        sd_deg=t(np.std(sel, axis=0)),
        max_abs_deg=t(np.max(np.abs(sel), axis=0)),
        samples=int(sel.shape[0]),
    )
