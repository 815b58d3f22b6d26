"""The plain path's body-offset learner (``EskfSettings.mag_body_offset_lag_s``): a magnet attached to the sensor.

A synthetic hand-held recording whose truth is known by construction: the sensor turns about all three axes,
the gyro reads 1 % high on every axis (a raw MEMS gyro's scale-factor error: the heading drifts while the compass
is out, as on BROAD's attached-magnet trials, +0.1 °/s), and from 40 s to 100 s a body-fixed field of
(−6, −2, 55) µT is added to the compass (BROAD trial 32's magnet at 1 cm).  The gain schedule rejects every
reading then (norm +40 %); without the learner the heading runs on the gyro alone and reaches 9.7° RMS over
70–100 s; with it the offset is fitted from the turns and the corrected readings hold it within 3.8°.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mavahrs.evaluation.metrics import summarize
from mavahrs.filters import create
from mavahrs.filters.base import make_inputs
from mavahrs.filters.best import BestSettings, best_eskf_settings, vehicle_eskf_settings
from mavahrs.filters.layout import OUT_Q
from mavahrs.geometry import quaternion as quat

RATE_HZ = 100
MAGNET_UT = np.array([-6.0, -2.0, 55.0])
FIELD_NED_UT = np.array([20.0, 0.0, 45.0])


def _recording() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = 120 * RATE_HZ
    dt = 1.0 / RATE_HZ
    t = np.arange(n) * dt
    w = np.stack([0.5 * np.sin(0.31 * t), 0.5 * np.sin(0.23 * t + 1.0), 0.7 * np.sin(0.17 * t + 2.0)], axis=1)
    w[t < 5.0] = 0.0  # a rest first
    q = quat.trajectory((1.0, 0.0, 0.0, 0.0), w, dt)
    q_ned_to_body = quat.conjugate(q)
    rng = np.random.default_rng(1)
    mag = quat.rotate(q_ned_to_body, FIELD_NED_UT) + rng.normal(0.0, 0.3, (n, 3))
    mag[(t >= 40.0) & (t < 100.0)] += MAGNET_UT
    accel = quat.rotate(q_ned_to_body, np.array([0.0, 0.0, -9.80665])) + rng.normal(0.0, 0.05, (n, 3))
    gyro = 1.01 * w + rng.normal(0.0, 0.002, (n, 3))
    return make_inputs(gyro, accel, mag, dt_s=dt), q, t


def _heading_rms(out: np.ndarray, q: np.ndarray, t: np.ndarray, a: float, b: float) -> float:
    sl = (t >= a) & (t < b)
    return summarize(out[sl, OUT_Q : OUT_Q + 4], q[sl]).heading_rms_deg


def test_an_attached_magnet_is_learnt_as_a_body_offset_and_the_compass_used_again() -> None:
    rows, q, t = _recording()
    out = create("best").run(rows)
    s = BestSettings()
    off = create("best", replace(s, eskf=replace(s.eskf, mag_body_offset_lag_s=0.0))).run(rows)
    # before the magnet: nothing changes (the schedule accepts the compass, the learner idles)
    np.testing.assert_array_equal(out[t < 40.0, OUT_Q : OUT_Q + 4], off[t < 40.0, OUT_Q : OUT_Q + 4])
    # the second half of the magnet's stretch: the gyro alone drifts (9.7°), the corrected compass holds it (3.8°)
    assert _heading_rms(off, q, t, 70.0, 100.0) > 7.0
    assert _heading_rms(out, q, t, 70.0, 100.0) < 5.5


def test_the_learner_is_the_plain_paths_only() -> None:
    # an autopilot's stream has its magnetometer model (the vehicle's own field); its output stays as it was
    assert best_eskf_settings().mag_body_offset_lag_s > 0.0
    assert vehicle_eskf_settings(best_eskf_settings()).mag_body_offset_lag_s == 0.0
