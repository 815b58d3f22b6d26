"""``mavahrs tune`` writes a TOML that ``mavahrs run --config`` reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mavahrs.cli import main


def _csv(tmp_path: Path, rng: np.random.Generator) -> Path:
    n, fs = 12000, 100
    t = np.arange(n) / fs
    temp = 25 + 10 * (1 - np.exp(-t / 40))
    gyro = 0.003 + np.outer(temp - 25, [4e-4, -3e-4, 2e-4]) + rng.normal(0, 0.002, (n, 3))
    acc = np.array([0.1, 0.2, -9.8]) + rng.normal(0, 0.02, (n, 3))
    data = np.column_stack([t, gyro, acc, temp])
    p = tmp_path / "rest.csv"
    np.savetxt(p, data, delimiter=",", comments="",
               header="time_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,"
               "temperature_c")  # fmt: skip
    return p


def test_tune_csv_to_toml(tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]) -> None:
    toml = tmp_path / "tuned.toml"
    assert main(["tune", str(_csv(tmp_path, rng)), "-o", str(toml)]) == 0
    out = capsys.readouterr().out
    assert "temp. slope" in out and "least squares" in out
    from mavahrs.config import load_run_config

    cfg = load_run_config(toml)
    np.testing.assert_allclose(cfg.pipeline.calibration.gyro_temperature.k_rad_s_per_c, [4e-4, -3e-4, 2e-4],
                               rtol=0.05)  # fmt: skip
    assert 0 < cfg.filter.beta_rad_s < 0.01


def test_tune_refuses_a_moving_recording(broad_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tune", str(broad_dir / "02_undisturbed_slow_rotation_B.mat")]) == 1
    assert "at rest" in capsys.readouterr().err


@pytest.mark.slow
def test_tune_a_simulator_tlog(
    sim_temperature_tlog: tuple[Path, tuple[float, float, float]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, tempco = sim_temperature_tlog
    toml = tmp_path / "t.toml"
    assert main(["tune", str(path), "-o", str(toml), "--gains", "ls"]) == 0
    assert "SIMSTATE" in capsys.readouterr().out  # the truth rates were used
    from mavahrs.config import load_run_config

    k = load_run_config(toml).pipeline.calibration.gyro_temperature.k_rad_s_per_c
    np.testing.assert_allclose(k, tempco, rtol=0.10)
