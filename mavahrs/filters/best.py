r"""The configuration mavahrs recommends: ``filter="best"`` (also the daemon's default filter).

It is the Madgwick filter (:mod:`mavahrs.filters.madgwick`) with the
extensions that measured best on the 16 BROAD trials in ``../shared/data/broad``
(Laidig et al. 2021; one parameter set for all trials, mean of the per-trial
RMS over the scored movement phases; ``scripts/bench_accuracy.py``) *and* on
``firmware_sim`` flights replayed through the daemon's pipeline, with and
without GLOBAL_POSITION_INT (``scripts/bench_sim_accuracy.py``); the tables
are in ``docs/accuracy.md``:

==============================  ====================  =====================
                                BROAD 9-axis          ``aggressive`` flight
                                total / incl. °       incl. ° GPS / no GPS
==============================  ====================  =====================
``best``                        1.88 / 0.72           0.8 / 3.2
VQF 2.x (causal, defaults)      2.46 / 0.71           9.1 (no velocity input)
``mahony`` defaults             2.14 / 0.75           0.8 / 5.9
``ahrs`` Madgwick / imufusion   5.3 / 2.4             10.7 (imufusion)
==============================  ====================  =====================

What differs from the Madgwick defaults, and why (each a physical argument,
then checked on the data; nothing is chosen per trial or per flight):

* the accelerometer enters the gradient through a second-order Butterworth
  low-pass (τ = 2 s) taken in the estimated NED frame: motion accelerations
  average out over a few seconds while rotations are followed without lag
  (VQF's quasi-inertial filter); β is then lowered to 0.01 (1.1°/s of
  correction) because the low-pass already removed the noise the larger β
  was chasing;
* with a GNSS velocity (the daemon feeds GLOBAL_POSITION_INT), the vehicle's
  acceleration v̇ is subtracted before that low-pass (f − v̇, the 003
  tutorial's acceleration-compensated vertical): a multirotor's
  accelerometer reads thrust and drag, not gravity, for as long as it
  accelerates, and no amount of averaging removes a sustained acceleration;
* without velocity, the norm of the low-passed specific force tells a
  manoeuvre: beyond 5 % from g the gravity correction falls to 20 % and the
  large-error speed-up is off (a sustained tilted acceleration looks exactly
  like a large tilt error); on BROAD this changes nothing (its low-passed
  norm stays within a few per cent of g);
* the magnetometer corrects heading only, at its own slower β = 0.005
  (0.57°/s): the field in a room (and a calibration error) deflects the
  measured heading by several degrees in some orientations, which a slow,
  bounded-rate correction averages out, while a well-estimated gyro bias
  keeps the heading in between;
* large errors (a bad start) converge exponentially (τ 2 s tilt, 20 s
  heading) instead of at the constant 2β rate; ζ = 0.0005 learns a bias in
  motion slowly (time constant β/ζ = 20 s), not while the error is large;
* the rest-phase gyro bias accepts at most 1°/s: a hovering vehicle turning
  slowly is otherwise taken for a sensor at rest with a bias (the rate of
  the turn) when no GNSS speed rules it out; autopilots calibrate the gyro
  at boot, so what is left to learn is well below that;
* the rest is the Madgwick default: magnetometer rejected beyond 15 % norm /
  15° dip from the learned reference (dip against the estimate's vertical),
  start-up boost.

Tuned on: the 16 BROAD trials (coarse grid over τ, β, β_heading, rejection
tolerances, ζ; the optimum is flat, the rounded values are kept) and
``firmware_sim`` flights (seeds 1–3, six scenarios; 4–6 for ``aggressive``):
the norm tolerance, the rest-rate limit and ζ, each checked not to change
BROAD by more than 0.01°.
"""

from __future__ import annotations

import math
from typing import Any

from mavahrs.filters.base import AttitudeFilter, FilterSettings
from mavahrs.filters.madgwick import Madgwick, MadgwickSettings
from mavahrs.filters.rest import RestBiasSettings

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
        large_heading_error_tau_s=20.0,
        lowpass_norm_tolerance=0.05,
        lowpass_norm_min_weight=0.2,
        gnss_acceleration=True,
        rest=RestBiasSettings(rate_limit_rad_s=math.radians(1.0)),
    )


def create_best(settings: FilterSettings | None = None, **kwargs: Any) -> AttitudeFilter:
    """The recommended filter; ``settings`` (a :class:`MadgwickSettings`) overrides the recommendation.

    ``kwargs`` are passed to the filter's constructor (e.g. ``compiled=False``).
    """
    return Madgwick(best_settings() if settings is None else settings, **kwargs)
