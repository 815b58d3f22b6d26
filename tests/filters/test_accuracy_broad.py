"""Accuracy on the real BROAD trials in ../shared/data/broad (skipped when the data is absent).

BROAD's scoring (Laidig et al. 2021): per trial the RMS error over the scored
movement phase, then the plain mean over the 16 trials; one setting for all
trials.  Bounds, in degrees:

* issue 2: ``best`` ≤ 3.0 total and ≤ 1.0 inclination (9-axis); the default
  ``madgwick`` better than the ``ahrs`` package's Madgwick (5.3 / 2.4);
* regression bounds with ≈ 15 % margin over what was measured when the
  settings were chosen (``docs/accuracy.md``: best 1.88 / 0.72, 6-axis 0.72; with the adaptive
  low-pass 1.88 / 0.70, 6-axis 0.70;
  madgwick 2.77 / 1.66, 6-axis 1.80), below VQF's 2.46 total.
"""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # 16 real trials (≈ 900 k samples) per filter: a few seconds each


def test_best_meets_the_issue_bounds_9axis(broad_mean) -> None:  # type: ignore[no-untyped-def]
    total, heading, incl = broad_mean("best")
    assert total <= 3.0 and incl <= 1.0, f"best: {total:.2f}° total, {incl:.2f}° inclination"
    assert total <= 2.2 and heading <= 2.0 and incl <= 0.85, (total, heading, incl)


def test_best_inclination_6axis(broad_mean) -> None:  # type: ignore[no-untyped-def]
    _, _, incl = broad_mean("best", six_axis=True)
    assert incl <= 0.85, f"best 6-axis inclination {incl:.2f}°"


def test_default_madgwick_beats_the_ahrs_package(broad_mean) -> None:  # type: ignore[no-untyped-def]
    total, _, incl = broad_mean("madgwick")
    assert total < 5.3 and incl < 2.4, f"madgwick defaults: {total:.2f}° total, {incl:.2f}° inclination"
    assert total <= 3.2 and incl <= 1.9, (total, incl)
    _, _, incl6 = broad_mean("madgwick", six_axis=True)
    assert incl6 < 2.4 and incl6 <= 2.1, incl6


def test_attached_magnet_trials_reject_the_magnetometer(broad_trials) -> None:  # type: ignore[no-untyped-def]
    """A magnet 1–3 cm from the IMU: heading stays within 2.5° RMS (VQF: 7.7° and 3.4°)."""
    from mavahrs.evaluation.metrics import summarize
    from mavahrs.filters import create
    from mavahrs.filters.base import make_inputs
    from mavahrs.filters.layout import OUT_MAG_WEIGHT, OUT_Q

    trials = [r for r in broad_trials if "attached_magnet" in r.groups]
    if not trials:
        pytest.skip("no attached-magnet trials in ../shared/data/broad")
    for rec in trials:
        out = create("best").run(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut, dt_s=rec.dt_s))
        s = summarize(out[:, OUT_Q : OUT_Q + 4], rec.q_ref_body_to_ned, rec.scored)
        assert s.heading_rms_deg < 2.5, f"{rec.name}: heading {s.heading_rms_deg:.2f}°"
        rejected = np.mean(out[rec.scored, OUT_MAG_WEIGHT] < 0.5)
        assert rejected > 0.2, f"{rec.name}: magnetometer rejected only {rejected:.0%} of the scored samples"


def test_attached_magnet_is_learnt_as_a_body_offset(broad_trials) -> None:  # type: ignore[no-untyped-def]
    """The plain path's body-offset learner (``EskfSettings.mag_body_offset_lag_s``): while the magnet is on, the
    offset is fitted from the turns and the compass used again.  Heading 0.85° / 1.19° on trials 32 / 34; without
    the learner the gyro alone drifts (1.71° / 1.76°, VQF 7.7° / 3.3°); issue 23's bound 1.59° for the mean."""
    from mavahrs.evaluation.metrics import summarize
    from mavahrs.filters import create
    from mavahrs.filters.base import make_inputs
    from mavahrs.filters.layout import OUT_Q

    trials = [r for r in broad_trials if "attached_magnet" in r.groups]
    if not trials:
        pytest.skip("no attached-magnet trials in ../shared/data/broad")
    headings = []
    for rec in trials:
        out = create("best").run(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut, dt_s=rec.dt_s))
        headings.append(summarize(out[:, OUT_Q : OUT_Q + 4], rec.q_ref_body_to_ned, rec.scored).heading_rms_deg)
    assert max(headings) < 1.45 and np.mean(headings) < 1.3, headings


def test_compass_readings_rejected_for_their_dip_are_still_fused(broad_trials) -> None:  # type: ignore[no-untyped-def]
    """The plain path fuses a reading the gain schedule rejects with its norm in tolerance at 5 × its σ
    (``EskfSettings.mag_rejected_sigma_scale``): in fast turns BROAD's compass (≈ 10 ms late) fails the dip test
    while the gyro's heading drifts 0.2–0.3 °/s.  Heading, mean of the 16 trials, 1.58 → 1.32°; stationary magnet
    (28 / 30) 1.92 → 1.48°, trial 30 2.43 → 1.61°; without the setting these bounds fail (docs/accuracy.md round
    five, smag3)."""
    from mavahrs.evaluation.metrics import summarize
    from mavahrs.filters import create
    from mavahrs.filters.base import make_inputs
    from mavahrs.filters.layout import OUT_Q

    if len(broad_trials) < 16:
        pytest.skip("not every BROAD trial in ../shared/data/broad")
    heading = {}
    for rec in broad_trials:
        out = create("best").run(make_inputs(rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut, dt_s=rec.dt_s))
        heading[rec.name[:2]] = summarize(
            out[:, OUT_Q : OUT_Q + 4], rec.q_ref_body_to_ned, rec.scored
        ).heading_rms_deg
    assert np.mean(list(heading.values())) < 1.45, heading
    assert (heading["28"] + heading["30"]) / 2 < 1.7 and heading["30"] < 2.0, heading
    assert (heading["32"] + heading["34"]) / 2 < 1.1, heading  # the attached magnet no worse (1.02°)


def test_translation_trials_accelerations_do_not_reach_the_tilt(broad_trials) -> None:  # type: ignore[no-untyped-def]
    """BROAD's translation trials (hand-held, |f| − g up to 10 m/s²): ``best``'s inclination is bounded,
    and its gravity measurement never makes it worse than the gyro alone (the same ESKF with the
    accelerometer weighted 140× less, σ 100 m/s²) by more than 0.15°.

    Measured (docs/accuracy.md, "Translation trials"): best 0.28–0.69°, gyro alone 0.21–0.73°, best
    − gyro alone −0.35 … +0.07°; a gravity reference low-passed 1 s instead of 2 s lets the fast
    translation in (trial 15: 0.91° against 0.66° for the gyro alone) and fails here.
    """
    from dataclasses import replace

    from mavahrs.evaluation.metrics import summarize
    from mavahrs.filters import create
    from mavahrs.filters.base import make_inputs
    from mavahrs.filters.best import best_eskf_settings
    from mavahrs.filters.eskf import Eskf
    from mavahrs.filters.layout import OUT_Q

    trials = [r for r in broad_trials if "translation" in r.groups]
    if not trials:
        pytest.skip("no translation trials in ../shared/data/broad")
    gyro_alone = replace(best_eskf_settings(), gravity_noise_m_s2=100.0)
    incl = []
    for rec in trials:
        inputs = make_inputs(rec.gyro_rad_s, rec.accel_m_s2, rec.mag_ut, dt_s=rec.dt_s)
        best = summarize(create("best").run(inputs)[:, OUT_Q : OUT_Q + 4], rec.q_ref_body_to_ned, rec.scored)
        alone = summarize(
            Eskf(gyro_alone).run(inputs)[:, OUT_Q : OUT_Q + 4], rec.q_ref_body_to_ned, rec.scored
        )
        assert best.inclination_rms_deg <= 0.9, f"{rec.name}: {best.inclination_rms_deg:.2f}°"
        assert best.inclination_rms_deg <= alone.inclination_rms_deg + 0.15, (
            f"{rec.name}: best {best.inclination_rms_deg:.2f}° against the gyro alone {alone.inclination_rms_deg:.2f}°"
        )
        incl.append(best.inclination_rms_deg)
    assert float(np.mean(incl)) <= 0.55, f"translation trials: mean inclination {np.mean(incl):.2f}°"
