"""A declared raw multirotor learns its accelerometer's bias across the thrust axis (issue 22, docs/accuracy.md
seventeenth round).

A multirotor's specific force across its thrust axis is its drag alone, so an uncalibrated accelerometer's
offset there reads as a tilt of offset/g wherever the vehicle flies; the body yawing under it is what tells
the two apart.  ``best`` declared a multirotor (``set_multirotor()``) carries that offset as two constant error
states across the thrust axis (``EskfSettings.accel_bias_across_thrust``).  firmware_sim's raw preset (a gyro
bias up to 5 °/s and an accelerometer offset σ 0.1 m/s² per axis, the IMU x axis up, 200 Hz, no GNSS, no
magnetometer, started in flight).
"""

from __future__ import annotations

import numpy as np
import pytest

from mavahrs.evaluation.metrics import summarize
from mavahrs.filters import create
from mavahrs.filters.base import S_FILTER
from mavahrs.filters.best import _SE, BestSettings, MultirotorDetectSettings
from mavahrs.filters.eskf import accel_bias_of, thrust_axis_of
from mavahrs.filters.layout import OUT_Q

RATE_HZ = 200  # conftest.RAW_RATE_HZ, the rate of :func:`raw_imu_flight`


def _true_accel_offset(scenario: str, seed: int) -> np.ndarray:
    """The accelerometer's turn-on offset firmware_sim draws for :func:`raw_imu_flight`'s IMU (IMU frame, m/s²)."""
    sim_mod = pytest.importorskip("firmware_sim.simulation")
    from firmware_sim.imu_model import ImuErrorSettings

    # the settings of tests/filters/conftest.py's raw_imu_flight
    sim = sim_mod.Simulation(sim_mod.SimSettings(
        scenario=scenario, seed=seed, start_in_motion=True, imu_mount_deg=(0.0, 90.0, 0.0),
        imu=ImuErrorSettings.raw(), gnss=False, mag_count=0, imu_count=1, loop_rate_hz=RATE_HZ,
    ))  # fmt: skip
    return np.asarray(sim.imus[0].accel_bias0_m_s2, dtype=float)


def test_a_hover_s_accelerometer_offset_across_the_thrust_is_learnt_not_taken_for_a_tilt(raw_flight) -> None:  # type: ignore[no-untyped-def]
    # hover 153 (not among the seeds the setting was chosen on): no rest all flight, an offset of 0.25 m/s²
    # across the thrust axis (1.5° of tilt); declared 1.76° before, 1.48° with the states
    rows, q_ref, _ = raw_flight("hover", 153)
    f = create("best", BestSettings(detect=MultirotorDetectSettings(enabled=False)))
    f.set_multirotor()  # type: ignore[attr-defined]
    out = f.run(rows)
    scored = slice(RATE_HZ * 20, None)
    assert summarize(out[scored, OUT_Q : OUT_Q + 4], q_ref[scored]).inclination_rms_deg < 1.6
    # the learnt offset has the simulator's across the learnt thrust axis in it (0.10 of its 0.255 m/s² at 90 s;
    # none without the states)
    k = _SE + S_FILTER
    b_hat, _sd = accel_bias_of(f.raw_state, k)  # type: ignore[attr-defined]
    t = thrust_axis_of(f.raw_state, k)  # type: ignore[attr-defined]
    assert t is not None and abs(float(t[0])) > 0.99  # the IMU's x axis is up
    b_true = _true_accel_offset("hover", 153)
    across_true = b_true - float(b_true @ t) * t
    n = float(np.linalg.norm(across_true))
    assert float(b_hat @ across_true) / n > 0.25 * n
