"""A multirotor's hovering rest is not a landed one (issue 22, docs/accuracy.md sixteenth round).

A multirotor's specific force is its thrust, fixed in the body: in a hover the rest detector
sees the accelerometer steady while the vehicle slowly tilts back and forth, and the low-passed
gyro it fuses as the bias carries that wobble.  ``best`` declared a multirotor
(``set_multirotor()``) tells a hovering rest (the rotors' vibration in the accelerometer, a low
horizontal speed) and fuses its rate across the vertical with a per-rest constant wobble
(``EskfSettings.rest_wobble_sigma_rad_s``).  firmware_sim's raw preset (a gyro bias up to 5 °/s
per axis, the IMU x axis up, 200 Hz, no GNSS, no magnetometer, started in flight).
"""

from __future__ import annotations

from dataclasses import replace

from mavahrs.evaluation.metrics import summarize
from mavahrs.filters import create
from mavahrs.filters.best import (
    MULTIROTOR_REST_WOBBLE_SIGMA_RAD_S,
    BestSettings,
    MultirotorDetectSettings,
    best_eskf_settings,
)
from mavahrs.filters.layout import OUT_Q

RATE_HZ = 200


def _declared_inclination(rows, q_ref, **eskf) -> float:  # type: ignore[no-untyped-def]
    f = create("best", BestSettings(detect=MultirotorDetectSettings(enabled=False), eskf=replace(best_eskf_settings(), **eskf)))
    f.set_multirotor()  # type: ignore[attr-defined]
    out = f.run(rows)
    scored = slice(RATE_HZ * 20, None)
    return summarize(out[scored, OUT_Q : OUT_Q + 4], q_ref[scored]).inclination_rms_deg


def test_a_hovering_rest_does_not_learn_the_hovers_wobble_as_a_horizontal_bias(raw_flight) -> None:  # type: ignore[no-untyped-def]
    # hover 152 (not among the seeds the setting was chosen on): a rest at hover took the wobble for
    # the horizontal bias, 2.15° declared before; 0.42° with the hovering rest's wobble noise
    rows, q_ref, _ = raw_flight("hover", 152)
    assert _declared_inclination(rows, q_ref) < 1.0


def test_a_rest_in_a_steady_fast_dash_keeps_the_plain_zero_rate_update(raw_flight) -> None:  # type: ignore[no-untyped-def]
    # aggressive 123: its rests at 14–28 s are constant-attitude dashes (estimated 10–17 m/s), truly
    # still; the wobble noise on every rest (no speed gate) under-uses them, 1.11 → 1.31°
    rows, q_ref, _ = raw_flight("aggressive", 123)
    gated = _declared_inclination(rows, q_ref)
    # the same wobble noise set on the ESKF, with neither gate (the multirotor's defaults are then not applied)
    ungated = _declared_inclination(rows, q_ref, rest_wobble_sigma_rad_s=MULTIROTOR_REST_WOBBLE_SIGMA_RAD_S)
    assert gated < ungated - 0.1
