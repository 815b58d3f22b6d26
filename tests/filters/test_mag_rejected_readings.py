"""The plain path's compass readings that the gain schedule rejects for their dip (``EskfSettings.mag_rejected_sigma_scale``).

A synthetic hand-held recording whose truth is known by construction: the sensor turns steadily about the vertical
(0.5 rad/s) with a slow roll/pitch wobble, and the gyro reads 1 % high on every axis (a raw MEMS gyro's scale
error: the heading drifts 0.29 °/s on the gyro alone, as BROAD's does in fast turns while its compass is rejected).
From 30 s on the earth field's dip is 7° steeper, its norm and azimuth unchanged (a place whose field dips
differently; on BROAD a compass read ≈ 10 ms late in a fast turn fails the same test): the schedule's dip test
(5°) rejects every reading from then on.  Without the setting the heading runs on the gyro alone (9.5° RMS over
60–100 s); with the readings fused at 5 × their σ it is held (5.6°).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mavahrs.evaluation.metrics import summarize
from mavahrs.filters import create
from mavahrs.filters.base import make_inputs
from mavahrs.filters.best import (
    BestSettings,
    best_eskf_settings,
    multirotor_eskf_settings,
    vehicle_eskf_settings,
)
from mavahrs.filters.layout import OUT_MAG_WEIGHT, OUT_Q
from mavahrs.geometry import quaternion as quat

RATE_HZ = 100
FIELD_UT = 50.0
DIP_RAD = np.radians(66.0)


def _recording(dip_change_deg: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = 100 * RATE_HZ
    dt = 1.0 / RATE_HZ
    t = np.arange(n) * dt
    w = np.stack([0.2 * np.sin(0.31 * t), 0.2 * np.sin(0.23 * t + 1.0), np.full(n, 0.5)], axis=1)
    w[t < 5.0] = 0.0  # a rest first
    q = quat.trajectory((1.0, 0.0, 0.0, 0.0), w, dt)
    dip = np.where(t < 30.0, DIP_RAD, DIP_RAD + np.radians(dip_change_deg))
    field_ned = FIELD_UT * np.stack([np.cos(dip), np.zeros(n), np.sin(dip)], axis=1)
    q_ned_to_body = quat.conjugate(q)
    rng = np.random.default_rng(seed)
    mag = quat.rotate(q_ned_to_body, field_ned) + rng.normal(0.0, 0.3, (n, 3))
    accel = quat.rotate(q_ned_to_body, np.array([0.0, 0.0, -9.80665])) + rng.normal(0.0, 0.05, (n, 3))
    gyro = 1.01 * w + rng.normal(0.0, 0.002, (n, 3))
    return make_inputs(gyro, accel, mag, dt_s=dt), q, t


def _run(rows: np.ndarray, scale: float) -> np.ndarray:
    s = BestSettings()
    return create("best", replace(s, eskf=replace(s.eskf, mag_rejected_sigma_scale=scale))).run(rows)


def _heading_rms(out: np.ndarray, q: np.ndarray, t: np.ndarray, a: float, b: float) -> float:
    sl = (t >= a) & (t < b)
    return summarize(out[sl, OUT_Q : OUT_Q + 4], q[sl]).heading_rms_deg


def test_readings_rejected_for_their_dip_still_hold_the_heading() -> None:
    assert best_eskf_settings().mag_rejected_sigma_scale == 5.0  # what ``best`` runs through the API
    for seed in (1, 2):
        rows, q, t = _recording(7.0, seed)
        on = create("best").run(rows)
        off = _run(rows, 0.0)
        # the schedule rejects every reading after the change (the dip test), on and off alike
        assert np.all(on[t >= 35.0, OUT_MAG_WEIGHT] < 0.5)
        # before it: the same output (the setting touches only rejected readings)
        np.testing.assert_array_equal(on[t < 30.0, OUT_Q : OUT_Q + 4], off[t < 30.0, OUT_Q : OUT_Q + 4])
        # the gyro alone drifts 0.29 °/s (9.5°); the inflated readings hold it (5.6°)
        assert _heading_rms(off, q, t, 60.0, 100.0) > 8.5
        assert _heading_rms(on, q, t, 60.0, 100.0) < 7.0


def test_nothing_changes_where_the_schedule_accepts_every_reading() -> None:
    rows, _, _ = _recording(0.0, 1)
    np.testing.assert_array_equal(_run(rows, 5.0), _run(rows, 0.0))


def test_it_is_the_plain_paths_only() -> None:
    # an autopilot's stream (and a declared multirotor) keeps its own compass handling: nothing rejected is fused
    assert vehicle_eskf_settings(best_eskf_settings()).mag_rejected_sigma_scale == 0.0
    assert multirotor_eskf_settings(best_eskf_settings()).mag_rejected_sigma_scale == 0.0
