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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.geometry.quaternion import conjugate, multiply

__all__ = [
    "error_quaternion",
    "total_error_rad",
    "heading_error_rad",
    "inclination_error_rad",
    "attitude_errors_rad",
    "rms_deg",
    "AttitudeErrorSummary",
    "summarize",
]

Array = NDArray[np.float64]


def _normalize_allow_nan(q: ArrayLike) -> Array:
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return q / n


def error_quaternion(q_est: ArrayLike, q_ref: ArrayLike) -> Array:
    """Earth-frame error ``e = q_est ⊗ q_ref*`` (NaN rows stay NaN)."""
    return multiply(_normalize_allow_nan(q_est), conjugate(_normalize_allow_nan(q_ref)))


def total_error_rad(e: ArrayLike) -> Array:
    e = np.asarray(e)
    return 2.0 * np.arccos(np.clip(np.abs(e[..., 0]), 0.0, 1.0))


def heading_error_rad(e: ArrayLike) -> Array:
    e = np.asarray(e)
    return 2.0 * np.arctan(np.abs(e[..., 3] / e[..., 0]))


def inclination_error_rad(e: ArrayLike) -> Array:
    e = np.asarray(e)
    return 2.0 * np.arccos(np.clip(np.sqrt(e[..., 0] ** 2 + e[..., 3] ** 2), 0.0, 1.0))


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


