"""From MAVLink IMU messages to calibrated SI samples: scaling profiles, IMU selection, calibration.

* :mod:`~mavahrs.sensors.sample` — :class:`ImuSample` and the filter-row writer;
* :mod:`~mavahrs.sensors.profiles` — per-autopilot units/calibration facts, with sources;
* :mod:`~mavahrs.sensors.scaling` — :class:`Scaler`: message → SI values, saturation/validity;
* :mod:`~mavahrs.sensors.imu_select` — :class:`ImuSelector`: which instance feeds the filter;
* :mod:`~mavahrs.sensors.calibration` — gyro temperature bias, mag hard/soft iron, axis remap;
* :mod:`~mavahrs.sensors.geomag` — World Magnetic Model, declination, true north.
"""

from __future__ import annotations

from mavahrs.sensors.calibration import CalibrationSettings, Calibrator, GyroTemperatureModel, MagCalibration
from mavahrs.sensors.imu_select import ImuSelector, ImuSelectSettings
from mavahrs.sensors.profiles import (
    PROFILES,
    AutopilotProfile,
    MessageScale,
    get_profile,
    profile_for_autopilot,
)
from mavahrs.sensors.sample import ImuSample
from mavahrs.sensors.scaling import Scaler, ScalingSettings, to_sample

__all__ = [
    "ImuSample",
    "AutopilotProfile",
    "MessageScale",
    "PROFILES",
    "get_profile",
    "profile_for_autopilot",
    "Scaler",
    "ScalingSettings",
    "to_sample",
    "ImuSelector",
    "ImuSelectSettings",
    "CalibrationSettings",
    "Calibrator",
    "GyroTemperatureModel",
    "MagCalibration",
]
