"""Gain tuning from a stationary recording (Selezneva & Kumarin eq. (1)–(5); Madgwick 2010 eq. (50)–(51))."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.datasets import Recording
from mavahrs.evaluation.tuning import SPEC_FACTOR, least_squares_gain, tune

K_TRUE = np.radians([0.02, -0.03, 0.01])  # rad/s per °C
SIGMA = math.radians(0.1)  # gyro white noise per sample, rad/s


def _bench(
    rng: np.random.Generator, *, mag: bool = True, temperature: bool = True, n_s: int = 300, sigma: float = SIGMA
) -> Recording:
    """A board at rest warming up: gyro = b0 + k·(T − 27) + white noise; temperature quantised to 0.01 °C."""
    fs = 100
    n = fs * n_s
    t = np.arange(n) / fs
    temp = 20 + 15 * (1 - np.exp(-t / 100.0))
    gyro = np.radians([0.5, -0.2, 0.1]) + np.outer(temp - 27, K_TRUE) + rng.normal(0, sigma, (n, 3))
    acc = np.array([0.5, -0.3, -9.7]) + rng.normal(0, 0.02, (n, 3))
    m = np.array([20.0, 3.0, 40.0]) + rng.normal(0, 0.3, (n, 3)) if mag else None
    extra: dict[str, object] = {"time_s": t}
    if temperature:
        extra["temperature_c"] = np.round(temp * 100) / 100
    return Recording("bench", np.full(n, 1 / fs), gyro, acc, m, np.full((n, 4), np.nan), np.ones(n, bool), extra=extra)


def test_least_squares_gain_is_eq_5() -> None:
    v = np.array([[1.0, 0.0], [0.0, 2.0]])
    w = 3.0 * v
    assert least_squares_gain(v, w) == pytest.approx(3.0)
    assert math.isnan(least_squares_gain(np.zeros((2, 2)), w))


@pytest.mark.parametrize("mag", [True, False])
def test_temperature_model_noise_and_gains_are_recovered(rng: np.random.Generator, mag: bool) -> None:
    r = tune(_bench(rng, mag=mag))
    assert r.temperature_model and r.axes == (9 if mag else 6)
    np.testing.assert_allclose(r.k_rad_s_per_c, K_TRUE, rtol=0.03)
    np.testing.assert_allclose(r.noise_sd_rad_s, SIGMA, rtol=0.03)
    # spec formula with ω̃_β = mean |noise| per axis = σ·√(2/π) (Madgwick 2010, eq. (50))
    assert r.beta_spec == pytest.approx(SPEC_FACTOR * SIGMA * math.sqrt(2 / math.pi), rel=0.03)
    # the least-squares estimates land within 20 % of the spec formulas
    assert r.beta_ls == pytest.approx(r.beta_spec, rel=0.2)
    assert r.zeta_ls == pytest.approx(r.zeta_spec, rel=0.2)
    assert r.zeta_spec > 0


def test_without_temperature_the_bias_drift_is_fitted_in_time(rng: np.random.Generator) -> None:
    r = tune(_bench(rng, temperature=False))
    assert not r.temperature_model and "no temperature" in r.notes[0]
    assert "calibration.gyro_temperature" not in r.to_toml()


def test_motion_is_refused(rng: np.random.Generator) -> None:
    rec = _bench(rng, n_s=60)
    rec.gyro_rad_s[1000:3000, 2] += 1.0  # someone turned the board
    from mavahrs.errors import DataError

    with pytest.raises(DataError, match="at rest"):
        tune(rec)


def test_toml_is_read_by_the_daemon_config(rng: np.random.Generator, tmp_path: Path) -> None:
    r = tune(_bench(rng))
    path = tmp_path / "tuned.toml"
    path.write_text(r.to_toml(gains="ls"))
    from mavahrs.config import load_run_config

    cfg = load_run_config(path)
    assert cfg.pipeline.filter_name == "madgwick"
    gt = cfg.pipeline.calibration.gyro_temperature
    np.testing.assert_allclose(gt.k_rad_s_per_c, r.k_rad_s_per_c, rtol=1e-6)
    assert gt.t0_c == pytest.approx(r.t0_c, abs=1e-4)
    assert cfg.filter.beta_rad_s == pytest.approx(r.beta_ls, rel=1e-5)
    assert cfg.filter.zeta_rad_s == pytest.approx(r.zeta_ls, rel=1e-5)


@pytest.mark.slow
def test_simulator_temperature_recording(sim_temperature_tlog: tuple[Path, tuple[float, float, float]]) -> None:
    """Issue 5: the configured tempco within 10 %, β and ζ within 20 % of the spec-formula values."""
    from mavahrs.evaluation.tlogdata import load_tlog_recording

    path, tempco = sim_temperature_tlog
    rec = load_tlog_recording(path, reference=False)
    r = tune(rec)
    assert r.temperature_model
    np.testing.assert_allclose(r.k_rad_s_per_c, tempco, rtol=0.10)
    assert r.beta_ls == pytest.approx(r.beta_spec, rel=0.2)
    assert r.zeta_ls == pytest.approx(r.zeta_spec, rel=0.2)


def test_one_set_of_gains_over_several_recordings(rng: np.random.Generator) -> None:
    """The least-squares gains of several recordings fit all their samples at once: the per-recording sums
    tr(VᵀW) and tr(VᵀV) add up; the spec figures are averaged by samples."""
    from mavahrs.evaluation.tuning import combine, least_squares_terms

    quiet, noisy = tune(_bench(rng, n_s=120)), tune(_bench(rng, n_s=60, sigma=3.0 * SIGMA))
    both = combine([quiet, noisy])
    num = quiet.beta_ls_terms[0] + noisy.beta_ls_terms[0]
    den = quiet.beta_ls_terms[1] + noisy.beta_ls_terms[1]
    assert both.beta_ls == num / den and both.beta_ls_terms == (num, den)
    # the pooled fit lies between the two and leans to the recording with the larger tr(VᵀV)
    assert quiet.beta_ls < both.beta_ls < noisy.beta_ls
    assert noisy.beta_ls == pytest.approx(3.0 * quiet.beta_ls, rel=0.15)
    w = quiet.samples / (quiet.samples + noisy.samples)
    assert both.beta_spec == pytest.approx(w * quiet.beta_spec + (1 - w) * noisy.beta_spec, rel=1e-12)
    assert both.samples == quiet.samples + noisy.samples and not both.temperature_model
    assert both.notes[0].startswith("one set of gains over 2 recordings (bench, bench): least-squares terms summed")
    assert combine([quiet]) is quiet
    # pooling equals one least-squares fit over the stacked (V, W) of both
    v1, w1, v2, w2 = (rng.normal(size=(50, 4)) for _ in range(4))
    a, b = least_squares_terms(v1, w1), least_squares_terms(v2, w2)
    assert (a[0] + b[0]) / (a[1] + b[1]) == pytest.approx(least_squares_gain(np.vstack([v1, v2]), np.vstack([w1, w2])))


def test_a_temperature_column_without_values_is_no_temperature(rng: np.random.Generator) -> None:
    """PX4's HIGHRES_IMU carries no IMU temperature: the recording's column is all NaN."""
    rec = _bench(rng, n_s=60, temperature=False)
    rec.extra["temperature_c"] = np.full(rec.gyro_rad_s.shape[0], np.nan)
    r = tune(rec)
    assert not r.temperature_model and r.samples > 5000
    assert r.notes[0] == "no temperature in the recording: bias drift fitted against time, no temperature model"
