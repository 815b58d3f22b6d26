"""The thrust axis as ESKF states (``EskfSettings.thrust_axis_sigma_rad``) against the simulator's truth.

A raw IMU declared a multirotor through the Python API (``best.set_multirotor()``):
``firmware_sim``'s raw preset (a constant gyro bias of up to 5 °/s per axis), the IMU
mounted x axis up, 200 Hz, no GNSS, no magnetometer, started in flight.  The
simulator's thrust is along the body z axis, so the true thrust axis in the IMU frame
is its x axis.  Measured (90 s, scored after 20 s), inclination RMS / axis error at the
end, with the axis as states against the running mean it replaced:
``aggressive`` seed 2 1.36° / 0.70° against 3.36° / 2.36°, ``hover`` seed 3 0.77° /
0.77° against 1.17° / 4.45°.  The bounds sit between the two: they catch a regression
to an axis learnt as truth, not a tuning.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.evaluation.metrics import summarize
from mavahrs.filters import create
from mavahrs.filters.layout import OUT_Q

RATE_HZ = 200
#: body → IMU: the IMU's x axis up (rotated 90° about the body's y axis)
Q_MOUNT = np.array([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])
#: the thrust axis (body z) in the IMU frame
TRUE_AXIS = np.array([1.0, 0.0, 0.0])


@pytest.mark.parametrize(
    ("scenario", "seed", "incl_bound_deg", "axis_bound_deg"),
    [("aggressive", 2, 2.2, 1.5), ("hover", 3, 1.0, 2.0)],
)
def test_the_thrust_axis_of_a_raw_imu_mounted_x_up_is_estimated(  # type: ignore[no-untyped-def]
    scenario: str, seed: int, incl_bound_deg: float, axis_bound_deg: float, raw_flight
) -> None:
    rows, q_ref, _ = raw_flight(scenario, seed)
    f = create("best")
    f.set_multirotor()  # type: ignore[attr-defined]
    assert f.settings.eskf.thrust_axis_sigma_rad > 0.0  # type: ignore[attr-defined]
    out = f.run(rows)
    scored = slice(RATE_HZ * 20, None)
    incl = summarize(out[scored, OUT_Q : OUT_Q + 4], q_ref[scored]).inclination_rms_deg
    axis = f.thrust_axis()  # type: ignore[attr-defined]
    assert axis is not None
    axis_err = math.degrees(math.acos(min(1.0, abs(float(np.dot(axis, TRUE_AXIS))))))
    assert incl < incl_bound_deg
    assert axis_err < axis_bound_deg


@pytest.mark.parametrize("vehicle_first", [False, True])
def test_an_autopilot_stream_keeps_the_running_mean_axis(vehicle_first: bool) -> None:
    # an autopilot's IMU is in the body frame: its path is unchanged (the running mean), whichever call comes first
    f = create("best", compiled=False)
    if vehicle_first:
        f.set_vehicle_stream()  # type: ignore[attr-defined]
        f.set_multirotor()  # type: ignore[attr-defined]
    else:
        f.set_multirotor()  # type: ignore[attr-defined]
        f.set_vehicle_stream()  # type: ignore[attr-defined]
    eskf = f.settings.eskf  # type: ignore[attr-defined]
    assert eskf.drag_coefficient_1_s > 0.0
    assert eskf.thrust_axis_sigma_rad == 0.0


def test_starting_the_axis_states_leaves_the_declinations_prior_alone(raw_flight) -> None:  # type: ignore[no-untyped-def]
    """The thrust axis's prior is set where the first drag period starts the states; the declination
    (the next error state) is never learnt without GNSS, so its σ stays the prior it started with."""
    from mavahrs.filters.base import S_FILTER
    from mavahrs.filters.best import multirotor_eskf_settings
    from mavahrs.filters.eskf import EskfSettings, declination_of

    rows, _, _ = raw_flight("hover", 3, seconds=10.0)
    settings = multirotor_eskf_settings(EskfSettings())
    assert settings.thrust_axis_sigma_rad > 0.0
    prior_deg = math.degrees(settings.declination_sigma_rad)
    f = create("eskf", settings)
    f.run(rows)
    assert f.thrust_axis() is not None  # type: ignore[attr-defined]
    _, sigma = declination_of(f._state, S_FILTER)  # type: ignore[attr-defined]
    assert math.degrees(sigma) == pytest.approx(prior_deg, rel=1e-6)
