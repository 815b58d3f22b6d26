r"""Rest detection and gyro-bias estimation at rest.

At rest the true angular rate is zero (Earth rotation, 0.004°/s, is far below
MEMS bias), so the gyro's reading *is* its bias.  This is the most direct
bias measurement there is (Madgwick's x-io Fusion "offset" stage, and VQF's
rest phase, Laidig & Seel 2023, use it).  The detector:

* low-passes gyro and accelerometer with time constant ``tau_s``;
* calls the sensor *at rest* when, for at least ``min_time_s`` without a
  break, gyro and accelerometer stay within ``gyro_threshold`` and
  ``accel_threshold`` of their low-passes (steady readings) and the
  low-passed rate is below ``rate_limit`` (a bias can be no larger; this
  keeps a slow steady turn from being taken for a bias);
* while at rest, moves the bias estimate towards the low-passed gyro with
  time constant ``bias_tau_s``.

State block (``REST_LEN`` values at offset k): gyro low-pass (3),
accelerometer low-pass (3), time at rest so far (s), 1.0 once started.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mavahrs.filters.jit import kernel
from mavahrs.filters.prefilter import lowpass_coefficient

__all__ = ["RestBiasSettings", "REST_LEN", "RP_LEN", "rest_reset", "rest_step"]

REST_LEN = 8
RP_LEN = 7  # parameter block length (RestBiasSettings.to_params order)


@dataclass(frozen=True)
class RestBiasSettings:
    """Gyro-bias estimation while the sensor is at rest.

    Attributes:
        bias_tau_s: time constant with which the bias estimate follows the
            low-passed gyro at rest, s.  0 = rest estimation off.
        filter_tau_s: low-pass time constant of the rest detector, s.
        gyro_threshold_rad_s: largest gyro deviation from its low-pass at rest.
        accel_threshold_m_s2: largest accelerometer deviation from its
            low-pass at rest.
        rate_limit_rad_s: largest low-passed rate still taken for a bias.
        min_time_s: readings must stay steady this long before rest is declared.
        max_speed_m_s: with a GNSS velocity, a ground speed above this rules
            rest out (a steady slow turn in cruise would otherwise look like a
            bias).
    """

    bias_tau_s: float = 2.0
    filter_tau_s: float = 0.5
    gyro_threshold_rad_s: float = math.radians(2.0)
    accel_threshold_m_s2: float = 0.5
    rate_limit_rad_s: float = math.radians(3.0)
    min_time_s: float = 1.5
    max_speed_m_s: float = 0.5

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"RestBiasSettings.{name} must be a finite number ≥ 0, got {value!r}")

    def to_params(self) -> np.ndarray:
        """The parameter block ``rest_step`` reads (``RP_LEN`` values)."""
        return np.array(
            [
                self.filter_tau_s,
                self.gyro_threshold_rad_s,
                self.accel_threshold_m_s2,
                self.rate_limit_rad_s,
                self.min_time_s,
                self.bias_tau_s,
                self.max_speed_m_s,
            ]
        )


@kernel
def rest_reset(s, k):  # type: ignore[no-untyped-def]
    for i in range(REST_LEN):
        s[k + i] = 0.0


@kernel(inline=True)  # every sample; inlined into the steps (see filters/jit.py)
def rest_step(s, k, bias, kb, gx, gy, gz, ax, ay, az, accel_ok, vn, ve, vd, dt, rp, kp):  # type: ignore[no-untyped-def]
    """Advance the detector; while at rest update ``bias[kb:kb+3]``.  Returns True at rest.

    ``g`` is the raw gyro (rad/s), ``a`` the specific force (m/s²), ``v`` the
    GNSS velocity (NED, m/s; NaN = none);
    ``rp[kp:kp+RP_LEN]`` the parameters (:meth:`RestBiasSettings.to_params`).
    A ``bias_tau_s`` of 0 disables the detector (always returns False).
    """
    tau_s = rp[kp]
    gyro_threshold = rp[kp + 1]
    accel_threshold = rp[kp + 2]
    rate_limit = rp[kp + 3]
    min_time_s = rp[kp + 4]
    bias_tau_s = rp[kp + 5]
    max_speed = rp[kp + 6]
    if bias_tau_s <= 0.0:
        return False
    if s[k + 7] == 0.0:
        s[k], s[k + 1], s[k + 2] = gx, gy, gz
        if accel_ok:
            s[k + 3], s[k + 4], s[k + 5] = ax, ay, az
        s[k + 6] = 0.0
        s[k + 7] = 1.0
        return False
    c = lowpass_coefficient(dt, tau_s)
    s[k] += (gx - s[k]) * c
    s[k + 1] += (gy - s[k + 1]) * c
    s[k + 2] += (gz - s[k + 2]) * c
    still = accel_ok
    if accel_ok:
        s[k + 3] += (ax - s[k + 3]) * c
        s[k + 4] += (ay - s[k + 4]) * c
        s[k + 5] += (az - s[k + 5]) * c
        dax, day, daz = ax - s[k + 3], ay - s[k + 4], az - s[k + 5]
        still = dax * dax + day * day + daz * daz < accel_threshold * accel_threshold
    dgx, dgy, dgz = gx - s[k], gy - s[k + 1], gz - s[k + 2]
    steady = dgx * dgx + dgy * dgy + dgz * dgz < gyro_threshold * gyro_threshold
    slow = s[k] * s[k] + s[k + 1] * s[k + 1] + s[k + 2] * s[k + 2] < rate_limit * rate_limit
    vz = vd if math.isfinite(vd) else 0.0  # a receiver's fix has no vertical: its ground speed still tells
    moving = math.isfinite(vn) and math.isfinite(ve) and (vn * vn + ve * ve + vz * vz > max_speed * max_speed)
    if still and steady and slow and not moving:
        s[k + 6] += dt
    else:
        s[k + 6] = 0.0
    if s[k + 6] < min_time_s:
        return False
    w = dt / bias_tau_s
    if w > 1.0:
        w = 1.0
    bias[kb] += (s[k] - bias[kb]) * w
    bias[kb + 1] += (s[k + 1] - bias[kb + 1]) * w
    bias[kb + 2] += (s[k + 2] - bias[kb + 2]) * w
    return True
