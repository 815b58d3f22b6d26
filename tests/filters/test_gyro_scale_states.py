"""The gyro's scale-factor errors as ESKF error states (``EskfSettings.gyro_scale_state_sigma``), on known truth.

A hand-held-like recording (:func:`conftest.make_truth`: smooth rotations of ±40–70° about every axis, a
sinusoidal translation, sensor noise) whose gyro reads ``(1 + s)·ω + b`` with a known per-axis scale error
s: the plain path's ESKF (``best_eskf_settings()``: the 2 s low-passed gravity measurement) with the states on
(σ 0.25 %; ``best`` keeps them off, ``best.BEST_GYRO_SCALE_SIGMA``: they cost an undeclared multirotor) learns the
scale of the axes the tilt sees and holds the inclination better than the same filter without the states.
Without the low-pass lag in the states' h (g·(J − LP[J])) the states learnt the lag as scale (BROAD 28:
0.99 → 1.72°; docs/accuracy.md, "Gyro scale-factor states").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mavahrs.evaluation.metrics import attitude_errors_rad
from mavahrs.filters.base import S_FILTER
from mavahrs.filters.best import best_eskf_settings, vehicle_eskf_settings
from mavahrs.filters.eskf import Eskf, gyro_scale_of
from mavahrs.filters.layout import OUT_Q

SCALE_SIGMA = 0.0025  # the prior measured on BROAD (docs/accuracy.md)
SCALE_TRUE = np.array([0.004, -0.004, 0.003])  # a MEMS gyro's residual scale error per axis


def _with_states():  # type: ignore[no-untyped-def]
    return replace(best_eskf_settings(), gyro_scale_state_sigma=SCALE_SIGMA)


def _recording(synthetic, seed: int, translation_m: float = 0.0):  # type: ignore[no-untyped-def]
    truth = synthetic(150.0, 200.0, amplitude=1.4, noise=True, linear_acceleration_m=translation_m, seed=seed)
    gyro_true = truth.gyro_rad_s - truth.gyro_bias_rad_s
    truth.gyro_rad_s = gyro_true * (1.0 + SCALE_TRUE) + np.radians([0.5, -0.3, 0.2])
    return truth


def _inclination_rms_deg(filt: Eskf, truth, after_s: float) -> float:  # type: ignore[no-untyped-def]
    q = filt.run(truth.inputs(mag=True))[:, OUT_Q : OUT_Q + 4]
    _, _, incl = attitude_errors_rad(q, truth.q_body_to_ned)
    keep = truth.t_s >= after_s
    return float(np.degrees(np.sqrt(np.mean(incl[keep] ** 2))))


def test_scale_states_learn_the_gyro_scale_and_hold_the_tilt_better(synthetic) -> None:  # type: ignore[no-untyped-def]
    """Rotation only: measured 0.14° against 0.29–0.30° without the states, x / y learnt 0.30 / −0.33 %."""
    for seed in (3, 4):
        truth = _recording(synthetic, seed)
        with_states = Eskf(_with_states())
        incl_states = _inclination_rms_deg(with_states, truth, after_s=60.0)
        learnt = gyro_scale_of(with_states.raw_state, S_FILTER)
        without = Eskf(replace(best_eskf_settings(), gyro_scale_state_sigma=0.0))
        incl_without = _inclination_rms_deg(without, truth, after_s=60.0)
        # the horizontal axes' scale (the body's x and y, level on average) is what the tilt sees
        assert np.all(np.abs(learnt[:2] - SCALE_TRUE[:2]) < 0.0015), (seed, learnt, SCALE_TRUE)
        assert incl_states < 0.7 * incl_without, (seed, incl_states, incl_without)


def test_slow_translation_does_not_make_the_states_cost(synthetic) -> None:  # type: ignore[no-untyped-def]
    """With a slow translation (0.1–0.2 Hz, which the 2 s low-pass passes) the tilt error is the acceleration's
    (≈ 0.7° either way: measured 0.696 / 0.684° against 0.702 / 0.688° without the states) and the states,
    which cannot tell it from a scale error in the rotation, must not make it worse."""
    for seed in (3, 4):
        truth = _recording(synthetic, seed, translation_m=0.5)
        incl_states = _inclination_rms_deg(Eskf(_with_states()), truth, after_s=60.0)
        without = Eskf(replace(best_eskf_settings(), gyro_scale_state_sigma=0.0))
        incl_without = _inclination_rms_deg(without, truth, after_s=60.0)
        assert incl_states <= incl_without + 0.05, (seed, incl_states, incl_without)


def test_a_vehicle_stream_keeps_the_states_off() -> None:
    assert vehicle_eskf_settings(_with_states()).gyro_scale_state_sigma == 0.0
