r"""The configuration mavahrs recommends: ``filter="best"``.

It is the Madgwick filter (:mod:`mavahrs.filters.madgwick`) with the
extensions that measured best on the 16 BROAD trials in ``../shared/data/broad``
(Laidig et al. 2021; one parameter set for all trials, mean of the per-trial
RMS over the scored movement phases; ``scripts/bench_accuracy.py``,
``docs/accuracy.md``):

==========================  =========  ==========  ===============
9-axis, mean of 16 trials    total °   heading °   inclination °
==========================  =========  ==========  ===============
``best``                      1.98       1.80        0.72
VQF 2.x (causal, defaults)    2.46       2.30        0.71
``madgwick`` defaults         2.74       2.03        1.65
``ahrs`` Madgwick             5.3        —           2.4
==========================  =========  ==========  ===============

6-axis inclination: ``best`` 0.72°, VQF 0.71°.

What differs from the Madgwick defaults, and why (each a physical argument,
then checked on the trials; nothing is chosen per trial):

* the accelerometer enters the gradient through a second-order Butterworth
  low-pass (τ = 2 s) taken in the estimated NED frame: motion accelerations
  average out over a few seconds while rotations are followed without lag
  (VQF's quasi-inertial filter); β is then lowered to 0.01 (1.1°/s of
  correction) because the low-pass already removed the noise the larger β
  was chasing;
* the magnetometer corrects heading only, at its own slower β = 0.005
  (0.57°/s): the field in a room (and a calibration error) deflects the
  measured heading by several degrees in some orientations, which a slow,
  bounded-rate correction averages out, while a well-estimated gyro bias
  (rest phases) keeps the heading in between;
* the rest is the Madgwick default: rest-phase gyro bias, magnetometer
  rejected beyond 15 % norm / 15° dip from the learned reference (dip against
  the estimate's vertical), start-up boost.

Tuned on: the 16 BROAD trials only, on a coarse grid (τ ∈ {1, 2, 3, 4} s,
β ∈ {0.005 … 0.1}, β_heading ∈ {0.001 … 0.02}, rejection 10–30 % / 10–30°);
the optimum is flat (every neighbour of the chosen values is within 0.05°
total), so the rounded values are kept.
"""

from __future__ import annotations

from typing import Any

from mavahrs.filters.base import AttitudeFilter, FilterSettings
from mavahrs.filters.madgwick import Madgwick, MadgwickSettings

__all__ = ["best_settings", "create_best", "BEST_FILTER"]

#: the registry name of the filter ``"best"`` uses
BEST_FILTER = "madgwick"


def best_settings() -> MadgwickSettings:
    """The recommended settings (a new frozen dataclass; use ``dataclasses.replace`` to vary)."""
    return MadgwickSettings(
        beta_rad_s=0.01,
        zeta_rad_s=0.0005,
        accel_lowpass_s=2.0,
        accel_lowpass_order=2,
        mag_correction="heading",
        beta_heading_rad_s=0.005,
        large_error_tau_s=2.0,
        lowpass_norm_tolerance=0.05,
        gnss_acceleration=True,
        large_heading_error_tau_s=20.0,
    )


def create_best(settings: FilterSettings | None = None, **kwargs: Any) -> AttitudeFilter:
    """The recommended filter; ``settings`` (a :class:`MadgwickSettings`) overrides the recommendation.

    ``kwargs`` are passed to the filter's constructor (e.g. ``compiled=False``).
    """
    return Madgwick(best_settings() if settings is None else settings, **kwargs)
