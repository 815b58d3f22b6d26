"""``best`` through the plain Python API on a raw IMU, against the simulator's truth.

The way a research rig's log reaches ``create("best")``: nothing is known of the
source (no ``set_multirotor()``, no ``set_vehicle_stream()``), so ``best`` runs the
ESKF with the 2 s low-passed gravity measurement (:func:`best_eskf_settings`).
``firmware_sim``'s raw preset (a constant gyro bias drawn up to 5 °/s per axis, no
calibration), the IMU mounted x axis up, 200 Hz, no GNSS, no magnetometer, and a
start in flight (no rest period to learn the bias from).  Measured (seed 3, bias
(−3.6, −0.7, −5.0) °/s, 90 s): 1.79° inclination RMS after 20 s (VQF 9.31°, the
ESKF with a vehicle's models 1.28°), the bias on the two horizontal axes learnt
within 0.02 °/s.  The bounds (4°; 0.3 °/s, the issue's "a few tenths") catch a
regression — a bias not learnt in motion, a diverged tilt — not a tuning.

The same through the plain API on the ``aggressive`` scenario (sustained 30–45°
thrust tilts, which the 2 s low-passed gravity measurement holds as gravity), seed 2:
7.28° after 20 s with the generic hypothesis alone (VQF 12.98°; 21.0° before the plain
path held the bias estimate within a raw gyro's range, 6 °/s); since the plain path tells
a multirotor from the data (``MultirotorDetectSettings``) 1.34°, as declared.  The bound
(3°) catches the detection's regression.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavahrs.evaluation.metrics import summarize
from mavahrs.filters import create
from mavahrs.filters.layout import OUT_BIAS, OUT_Q

RATE_HZ = 200
#: body → IMU: the IMU's x axis up (rotated 90° about the body's y axis)
Q_MOUNT = np.array([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])


def test_best_through_the_plain_api_holds_the_tilt_of_a_raw_imu_started_in_flight(raw_flight) -> None:  # type: ignore[no-untyped-def]
    rows, q_ref, bias_rad_s = raw_flight("hover", 3)
    bias_dps = np.degrees(bias_rad_s)
    assert np.abs(bias_dps).max() > 3.0  # a raw gyro's bias: nothing subtracted beforehand

    f = create("best")  # the plain API: no set_multirotor(), no vehicle stream
    out = f.run(rows)
    scored = slice(RATE_HZ * 20, None)  # after 20 s of convergence from a start in flight
    incl = summarize(out[scored, OUT_Q : OUT_Q + 4], q_ref[scored]).inclination_rms_deg
    assert incl < 4.0
    # the horizontal axes' bias (IMU y and z with its x axis up) is learnt in motion; the vertical
    # one (x) is not observable without a heading reference and is not checked
    bias_err = np.abs(np.degrees(out[-1, OUT_BIAS + 1 : OUT_BIAS + 3]) - bias_dps[1:])
    assert bias_err.max() < 0.3


def test_an_undeclared_multirotor_in_sustained_thrust_tilts_does_not_learn_its_tilt_as_bias(raw_flight) -> None:  # type: ignore[no-untyped-def]
    rows, q_ref, bias = raw_flight("aggressive", 2)
    assert np.abs(np.degrees(bias)).max() > 2.0  # a raw gyro's bias
    f = create("best")  # the plain API: nothing says "multirotor"
    out = f.run(rows)
    scored = slice(RATE_HZ * 20, None)
    incl = summarize(out[scored, OUT_Q : OUT_Q + 4], q_ref[scored]).inclination_rms_deg
    assert incl < 3.0
    # taken for a multirotor from the data (test_best_detect.py), the output is the multirotor hypothesis's:
    # its bias estimate follows the true bias after 20 s on every axis, the vertical one too (within 0.53 °/s)
    assert f.multirotor_detection()["multirotor"] == 1.0  # type: ignore[attr-defined]
    err = np.abs(np.degrees(out[scored, OUT_BIAS : OUT_BIAS + 3]) - np.degrees(bias))
    assert err.max() < 1.0


def test_the_raw_bias_range_is_the_plain_apis_only() -> None:
    # an autopilot's stream (calibrated gyro) and a declared vehicle keep the ESKF's own bias limit
    from mavahrs.filters.eskf import EskfSettings

    f = create("best", compiled=False)
    assert math.isclose(f.settings.eskf.bias_limit_rad_s, math.radians(6.0))  # type: ignore[attr-defined]
    f.set_vehicle_stream()  # type: ignore[attr-defined]
    assert f.settings.eskf.bias_limit_rad_s == EskfSettings().bias_limit_rad_s  # type: ignore[attr-defined]
    g = create("best", compiled=False)
    g.set_multirotor()  # type: ignore[attr-defined]
    assert g.settings.eskf.bias_limit_rad_s == EskfSettings().bias_limit_rad_s  # type: ignore[attr-defined]


def test_a_declared_multirotor_starting_in_strong_vibration_does_not_diverge(raw_flight) -> None:  # type: ignore[no-untyped-def]
    # firmware_sim's ``vibration`` scenario (an aliased motor tone of tens of m/s²; the 16 g range never clips it on seeds 1–9) as a raw IMU
    # declared a multirotor: its first accelerometer sample is 76° from the truth here, and a filter that
    # starts from it diverged (81° inclination RMS after 20 s; seeds 1–6 31.7° mean).  The start check
    # (``EskfSettings.initial_average_s``: the estimate against the specific force averaged over 2 s, the tilt
    # re-aligned when they are more than 30° apart): 6.6° (VQF 12.6°).  The bound catches the divergence, not
    # a tuning.
    from mavahrs.evaluation.metrics import attitude_errors_rad
    from mavahrs.filters.layout import FLAG_STARTUP, OUT_FLAGS

    rows, q_ref, _ = raw_flight("vibration", 3)
    _, _, incl0 = attitude_errors_rad(create("eskf").run(rows[:2])[:, OUT_Q : OUT_Q + 4], q_ref[:2])
    assert math.degrees(incl0[0]) > 45.0  # the single sample is far off: the case this test is about
    f = create("best")
    f.set_multirotor()  # type: ignore[attr-defined]
    out = f.run(rows)
    window = int(RATE_HZ * f.settings.eskf.initial_average_s)  # type: ignore[attr-defined]
    flags = out[:, OUT_FLAGS].astype(np.int64)
    assert np.all(flags[1:window] & FLAG_STARTUP)  # the attitude is flagged as converging while averaging
    _, _, incl = attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], q_ref)
    # the tilt within 20° 1 s after the window: set from the average (the first tilt's σ 3°: 4.4° at the
    # window's end), or converged by the filter itself (raw15's 20° first tilt σ and 8 m/s² gravity noise: 76° → 44.7°
    # over the window, below the check's 45°, then 16.4° at 3 s; docs/accuracy.md, twenty-first round)
    assert math.degrees(float(incl[window + RATE_HZ])) < 20.0
    scored = slice(RATE_HZ * 20, None)
    assert summarize(out[scored, OUT_Q : OUT_Q + 4], q_ref[scored]).inclination_rms_deg < 15.0


@pytest.mark.parametrize("seed", [108, 119])
def test_a_declared_multirotor_in_strong_vibration_does_not_follow_a_drifting_velocity(raw_flight, seed: int) -> None:  # type: ignore[no-untyped-def]
    # firmware_sim's ``vibration`` as a raw IMU declared a multirotor: the aliased vibration drifts the velocity
    # 5–15 m/s off while its covariance claims 0.3–0.8 m/s (NEES 10²–10³), and the drag measurement, weighed by
    # that covariance, pulled the tilt with it: 16.2° / 27.0° inclination RMS after 20 s (the quadratic body drag:
    # 58.4° / 69.1°).  The drag noise matched to its innovations (``EskfSettings.drag_noise_match_s``): 7.5° / 12.5°
    # (docs/accuracy.md "Twelfth round").  The bound catches the divergence, not a tuning.
    rows, q_ref, _ = raw_flight("vibration", seed)
    f = create("best")
    f.set_multirotor()  # type: ignore[attr-defined]
    assert f.settings.eskf.drag_noise_match_s > 0.0  # type: ignore[attr-defined]
    out = f.run(rows)
    scored = slice(RATE_HZ * 20, None)
    assert summarize(out[scored, OUT_Q : OUT_Q + 4], q_ref[scored]).inclination_rms_deg < 15.0


def test_an_autopilot_stream_declared_a_multirotor_is_the_same_in_either_order(raw_flight) -> None:  # type: ignore[no-untyped-def]
    """``set_multirotor()`` then ``set_vehicle_stream()`` (a script, scripts/bench_estimator.py) gives the
    autopilot stream's multirotor, as the daemon's order does (the profile, then the HEARTBEAT's type): before,
    a raw IMU's drag models (k 0.4 /s, the body's quadratic drag, the noise matched to the innovations, the
    start's re-alignment) stayed on (ArduCopter SITL without GNSS 0.64 → 0.71° inclination mean).  The same
    settings, parameters and, on a flight, the same output."""
    rows = raw_flight("aggressive", 2, 30.0)[0]
    a = create("best")
    a.set_multirotor()  # type: ignore[attr-defined]
    a.set_sensor_delay(0.01125)  # type: ignore[attr-defined]
    a.set_vehicle_stream()  # type: ignore[attr-defined]
    b = create("best")
    b.set_sensor_delay(0.01125)  # type: ignore[attr-defined]
    b.set_vehicle_stream()  # type: ignore[attr-defined]
    b.set_multirotor()  # type: ignore[attr-defined]
    assert a.settings == b.settings
    assert a.settings.eskf.drag_quadratic_1_m == 0.0 and a.settings.eskf.drag_noise_match_s == 0.0  # type: ignore[attr-defined]
    out_a, out_b = a.run(rows), b.run(rows)
    np.testing.assert_array_equal(out_a[:, OUT_Q : OUT_Q + 4], out_b[:, OUT_Q : OUT_Q + 4])
