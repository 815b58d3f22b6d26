"""The timing of ``best``'s published attitude on an autopilot's stream, against firmware_sim's truth.

The ESKF applies each gyro sample's rate over the interval *before* it (right rectangle): for a rate sampled at
its stamp the integrated attitude leads the truth by ½ E[dt²] / E[dt], 10 ms on a 50 Hz RAW_IMU stream.  On an
autopilot's stream the output is moved back by half the step (``EskfSettings.output_half_step``, set by
:func:`mavahrs.filters.best.vehicle_eskf_settings`); a raw IMU through the API keeps its output as it was (BROAD's
samples act as the interval's mean).  docs/monitor.md rounds thirteen and fourteen.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavahrs.filters.best import (
    BestSettings,
    best_eskf_settings,
    multirotor_eskf_settings,
    vehicle_eskf_settings,
)
from mavahrs.filters.layout import OUT_Q
from mavahrs.replay import ReplaySettings, replay
from mavahrs.service.monitor import align_attitudes, divergence_series


def test_the_half_step_is_on_for_a_vehicles_stream_only() -> None:
    assert vehicle_eskf_settings(best_eskf_settings()).output_half_step
    assert not best_eskf_settings().output_half_step
    assert not BestSettings().eskf.output_half_step  # the plain path (a raw IMU, BROAD)
    assert not BestSettings().multirotor_eskf.output_half_step  # … and its multirotor hypothesis
    assert not multirotor_eskf_settings(best_eskf_settings()).output_half_step  # set_multirotor() through the API


def test_the_tilt_is_on_time_with_a_50_hz_autopilot_stream(tmp_path: Path) -> None:
    sim = pytest.importorskip("firmware_sim.__main__", reason="firmware_sim (the simulator with known truth) is not importable")
    path = tmp_path / "aggressive_3_raw50.tlog"
    # perfect sensors (the gyro's low-pass kept: the profile's 11.25 ms delay), RAW_IMU at 50 Hz: the step's lead 10 ms
    assert sim.main(["--tlog", str(path), "--fast", "-q", "--scenario", "aggressive", "--seed", "3", "--duration", "40",
                     "--no-sensor-errors", "--stream", "RAW_IMU=50"]) == 0  # fmt: skip
    res = replay(path, ReplaySettings(filters=("best",)))
    truth = next(k for k in res.references if k.endswith("truth"))
    t_tr, q_tr = res.references[truth]
    t_us = res.inputs.t_us.astype(np.float64)
    q = res.tracks["best"].out[:, OUT_Q : OUT_Q + 4]
    keep = t_us > t_us[0] + 20e6  # converged
    t_ms = t_us[keep] / 1000.0
    rms = {}
    for shift_ms in range(-15, 16):  # the truth δ later: our output leads by the δ that fits best
        q_t = align_attitudes(t_tr / 1000.0, q_tr, t_ms + shift_ms, tolerance_ms=30.0)
        tilt, _hdg = divergence_series(t_ms, q[keep], t_ms, q_t)
        rms[shift_ms] = float(np.sqrt(np.nanmean(tilt**2)))
    best = min(rms, key=rms.__getitem__)
    print(f"tilt RMS by truth shift: best {best:+d} ms ({rms[best]:.3f}°), at 0 {rms[0]:.3f}°")
    assert abs(best) <= 2, (best, rms)  # +10 ms with the right-rectangle step's lead (measured: 0.506° at 0)
    assert rms[0] < 0.35, rms[0]  # 0.276° measured
