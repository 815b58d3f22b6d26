"""``mavahrs tune`` writes a TOML that ``mavahrs run --config`` reads."""

from __future__ import annotations

import math
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
    # the default writes flight settings: the temperature model, no bench gains, the default filter
    assert cfg.pipeline.filter_name == "best" and cfg.filter is None
    assert "Madgwick gains fitted at rest, NOT written" in toml.read_text()


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


def test_tune_on_a_rest_log_warns_that_bench_gains_are_not_fit_to_fly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import subprocess
    import sys
    import warnings

    from mavahrs.config import load_run_config

    rest = tmp_path / "rest.tlog"
    subprocess.run([sys.executable, "-m", "firmware_sim", "--tlog", str(rest), "--fast", "-q", "--scenario", "rest",
                    "--duration", "30", "--seed", "1"], check=True, timeout=120)  # fmt: skip
    toml = tmp_path / "bench.toml"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's "Mean of empty slice" & co. are bugs here, not output
        assert main(["tune", str(rest), "-o", str(toml), "--gains", "spec"]) == 0
    err = capsys.readouterr().err
    cfg = load_run_config(toml)
    beta = cfg.filter.beta_rad_s
    assert 0 < beta < 0.005 and cfg.pipeline.filter_name == "madgwick"
    minutes = round(math.radians(10.0) / beta / 60)
    # the simulator's rest flight holds the IMU at one temperature: no temperature model, and the warning
    # must not send the user to --gains flight for one (it mentioned "this recording's gyro temperature model",
    # and --gains flight on this log writes nothing and fails)
    assert cfg.pipeline.calibration.gyro_temperature is None
    assert "wrote " + str(toml) + ": no temperature model (no spread);" in err
    warning = (
        f"β = {beta:.3g} rad/s (spec) measures the gyro's noise at rest: the filter would take {minutes} min to "
        "correct a 10° attitude error (flight gain 0.041 rad/s: 4 s). Fine on a bench, not fit to fly with: for "
        "flight run without these gains (the filters' own flight gains); this recording gives no gyro temperature "
        "model (its IMU temperature did not spread), so --gains flight would write nothing from it: record a "
        "warm-up at rest for one"
    )
    assert f" WARNING {warning}\n" in err
    assert "this recording's gyro temperature model" not in err
    assert f"# NOT FIT TO FLY WITH: {warning}." in toml.read_text().splitlines()
    assert "(spec, NOT fit to fly with); use: mavahrs run --config" in err
    assert "site-packages" not in err and "RuntimeWarning" not in err
    # … and where the recording has a temperature model (a warm-up at rest), the advice is --gains flight
    assert main(["tune", str(_csv(tmp_path, np.random.default_rng(3))), "-o", str(tmp_path / "warm.toml"),
                 "--gains", "spec"]) == 0  # fmt: skip
    assert "for flight use --gains flight (the default), which keeps this recording's gyro temperature model" in (
        capsys.readouterr().err
    )


def _keys(table: dict) -> set[str]:  # type: ignore[type-arg]
    out: set[str] = set()
    for k, v in table.items():
        out.add(k)
        if isinstance(v, dict):
            out |= _keys(v)
    return out


def test_the_readmes_tune_examples_write_what_they_say(
    tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each README `mavahrs tune …  # comment`, run on recordings at rest: β in the comment if and only
    if the file holds gains, "temperature model" if and only if it holds one (the README promised β and ζ
    from a command that by default writes none, and asked for "a log that moves like your flights",
    which tune refuses)."""
    import re

    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    examples = re.findall(r"^mavahrs tune (.+?)\s+# (.+)$", readme, flags=re.M)
    assert len(examples) >= 2, examples
    rest = _csv(tmp_path, rng)
    for k, (args, comment) in enumerate(examples):
        toml = tmp_path / f"ex{k}.toml"
        argv: list[str] = []
        words = args.split()
        i = 0
        while i < len(words):
            w = words[i]
            if w in ("-o", "--output"):
                argv += [w, str(toml)]
                i += 2
                continue
            if w == "--dask":  # one process here: the same fit (tests/fleet runs it on Dask)
                i += 1
                continue
            argv.append(str(rest) if w.endswith((".tlog", ".csv")) else w)
            i += 1
        assert main(["tune", *argv]) == 0, (args, capsys.readouterr().err)
        capsys.readouterr()
        keys = _keys(tomllib.loads(toml.read_text()))
        assert ("β" in comment) == any("beta" in key for key in keys), (args, comment, keys)
        assert ("temperature model" in comment) == ("gyro_temperature" in keys), (args, comment, keys)
    assert "moves like your flights" not in readme
    assert main(["tune", "--help"]) == 0
    assert "at rest" in " ".join(capsys.readouterr().out.split())


def test_tune_refuses_a_log_cut_short_and_writes_nothing(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The first 100 kB of the SITL flight (on the ground before arming: the simulated gyro reads exactly
    zero) gave all-zero bias and noise and β = nan, written as ``beta_rad_s = nan``."""
    log = shared_data / "sitl" / "arducopter_aggressive.tlog"
    if not log.is_file():
        pytest.skip(f"{log} not found")
    cut = tmp_path / "cut.tlog"
    with open(log, "rb") as f:
        cut.write_bytes(f.read(100_000))
    for gains in ("flight", "spec", "ls"):
        toml = tmp_path / f"{gains}.toml"
        assert main(["tune", str(cut), "--gains", gains, "-o", str(toml)]) == 1
        cap = capsys.readouterr()
        assert not toml.exists()
        lines = cap.err.strip().splitlines()
        assert len(lines) == 1 and "not enough rest data to estimate" in lines[0], cap.err
        assert "nan" not in cap.out


def test_tune_writes_no_file_without_settings(tmp_path: Path, rng: np.random.Generator,
                                              capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """At rest without a temperature spread, --gains flight has nothing to write: exit 1, no file."""
    n, fs = 6000, 100
    t = np.arange(n) / fs
    gyro = 0.003 + rng.normal(0, 0.002, (n, 3))
    acc = np.array([0.1, 0.2, -9.8]) + rng.normal(0, 0.02, (n, 3))
    p = tmp_path / "flat.csv"
    np.savetxt(p, np.column_stack([t, gyro, acc, np.full(n, 25.0)]), delimiter=",", comments="",
               header="time_s,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,"
               "temperature_c")  # fmt: skip
    toml = tmp_path / "empty.toml"
    assert main(["tune", str(p), "-o", str(toml)]) == 1
    err = capsys.readouterr().err
    assert not toml.exists() and "nothing to write" in err
    assert main(["tune", str(p), "--gains", "ls", "-o", str(toml)]) == 0  # bench gains are settings
    assert "beta_rad_s" in toml.read_text()


def test_tune_over_several_warm_ups_says_why_it_writes_no_temperature_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each warm-up at rest has its own temperature model; one set of gains over several writes none, and says
    why. (Until user6 the file and the warning said the recordings' temperature "did not spread", and the
    printed "drift in time" was +0.000000 on every axis: the mean of a slope no recording had fitted.)"""
    import json

    logs = []
    for seed in (1, 2):
        folder = tmp_path / f"warm{seed}"
        folder.mkdir()
        logs.append(str(_csv(folder, np.random.default_rng(seed))))
    assert main(["tune", logs[0], "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["temperature_model"] is True  # alone, each has one
    toml = tmp_path / "bench.toml"
    assert main(["tune", *logs, "--gains", "ls", "-o", str(toml)]) == 0
    out, err = capsys.readouterr()
    text = toml.read_text()
    for said in (out, err, text):
        assert "did not spread" not in said and "no usable temperature spread" not in said, said
    assert "drift in time" not in out and "temp. slope     per recording" in out
    assert ("# No temperature model: one set of gains over 2 recordings, and the gyro bias differs per power-up "
            "(`mavahrs tune LOG` fits each recording's own model).") in text.splitlines()  # fmt: skip
    assert "with a gyro temperature model from one recording (`mavahrs tune LOG`)" in err
    assert "no temperature model (per recording: tune each alone)" in err
    # the default, --gains flight, writes only a temperature model: nothing over several recordings, and why
    flight = tmp_path / "flight.toml"
    assert main(["tune", *logs, "-o", str(flight)]) == 1
    err = capsys.readouterr().err
    assert not flight.exists()
    assert "one set of gains over 2 recordings, and the gyro bias differs per power-up" in err
    assert "tune each recording alone for its model" in err and "did not spread" not in err


def test_tune_over_several_logs_says_each_logs_magnetic_model_only_when_asked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One INFO line per recording ("magnetic field from WMM-2025 at …") is noise over several, as in `audit`:
    kept for one recording and with -v."""
    import subprocess
    import sys

    logs = []
    for seed in (1, 2):
        log = tmp_path / f"warm{seed}.tlog"
        subprocess.run([sys.executable, "-m", "firmware_sim", "--tlog", str(log), "--fast", "-q", "--scenario",
                        "temperature", "--duration", "20", "--seed", str(seed)], check=True, timeout=120)  # fmt: skip
        logs.append(str(log))
    assert main(["tune", logs[0]]) == 0
    assert capsys.readouterr().err.count("magnetic field from WMM") == 1
    assert main(["tune", *logs, "--gains", "ls"]) == 0
    err = capsys.readouterr().err
    assert "magnetic field from WMM" not in err and " WARNING β = " in err  # the warning stays
    assert main(["-v", "tune", *logs, "--gains", "ls"]) == 0
    assert capsys.readouterr().err.count("magnetic field from WMM") == 2
