"""The filter contract, checked for every registered filter and for ``"best"``.

Each test runs on synthetic truth (``conftest.make_truth``) where the true
attitude is known exactly; the bounds are stated in the tests and hold with
margin for filters tuned for real data (BROAD), not only for this case.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

import mavahrs
from mavahrs.evaluation.metrics import attitude_errors_rad
from mavahrs.filters import NAMES, create
from mavahrs.filters.base import make_inputs
from mavahrs.filters.layout import (
    FLAG_ACCEL_INVALID,
    FLAG_DT_INVALID,
    FLAG_GYRO_INVALID,
    FLAG_MAG_INVALID,
    FLAG_NOT_INITIALISED,
    FLAG_REINITIALISED,
    IN_ACCEL,
    IN_DT,
    IN_GYRO,
    IN_MAG,
    IN_VEL,
    OUT_ACCEL_WEIGHT,
    OUT_BIAS,
    OUT_FLAGS,
    OUT_MAG_WEIGHT,
    OUT_Q,
)
from mavahrs.geometry.quaternion import from_axis_angle, multiply

RATE_HZ = 200.0


#: every registered filter and "best": a filter module that fails to import fails its tests (never a skip)
FILTERS: list[str] = [*NAMES, "best"]


def _flags(out: np.ndarray) -> np.ndarray:
    return out[:, OUT_FLAGS].astype(np.int64)


def _errors_deg(out: np.ndarray, q_true: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    total, heading, incl = attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], q_true)
    return np.degrees(total), np.degrees(heading), np.degrees(incl)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope="module")
def short_truth(synthetic):  # type: ignore[no-untyped-def]
    """5 s of noisy 9-axis data with GNSS velocity and a few invalid rows."""
    tr = synthetic(5.0, RATE_HZ, noise=True, linear_acceleration_m=2.0)
    rows = tr.inputs(velocity=True)
    rows[300:310, IN_ACCEL : IN_ACCEL + 3] = np.nan
    rows[400:405, IN_MAG : IN_MAG + 3] = 0.0
    rows[500:520, IN_VEL : IN_VEL + 3] = np.nan
    rows[600, IN_DT] = 0.0
    rows[601, IN_DT] = np.nan
    rows[700, IN_GYRO] = np.inf
    return rows


# ---------------------------------------------------------------- one implementation


@pytest.mark.parametrize("name", FILTERS)
def test_batch_equals_per_sample_interpreted(name: str, short_truth: np.ndarray) -> None:
    """``run`` (compiled loop) and ``update`` (interpreted kernel) agree to 1e-9."""
    rows = short_truth
    batch = create(name).run(rows)
    f = create(name, compiled=False)
    q = np.empty((rows.shape[0], 4))
    for i, r in enumerate(rows):
        q[i] = f.update(
            r[IN_GYRO : IN_GYRO + 3],
            r[IN_ACCEL : IN_ACCEL + 3],
            r[IN_MAG : IN_MAG + 3],
            dt_s=r[IN_DT],
            velocity_ned_m_s=r[IN_VEL : IN_VEL + 3],
        )
    np.testing.assert_allclose(q, batch[:, OUT_Q : OUT_Q + 4], rtol=0, atol=1e-9)
    # the diagnostics of the last sample agree too
    d = f.diagnostics
    assert d.flags == int(batch[-1, OUT_FLAGS])
    np.testing.assert_allclose(d.gyro_bias_rad_s, batch[-1, OUT_BIAS : OUT_BIAS + 3], atol=1e-9)


@pytest.mark.parametrize("name", FILTERS)
def test_split_batch_with_state_carried_equals_one_batch(name: str, short_truth: np.ndarray) -> None:
    rows = short_truth
    whole = create(name).run(rows)
    f = create(name)
    first = f.run(rows[:457])
    second = f.run(rows[457:])
    np.testing.assert_array_equal(np.vstack([first, second]), whole)
    # the same through a state copy into a fresh filter
    g = create(name)
    g.run(rows[:457])
    h = create(name)
    h.state = g.state
    np.testing.assert_array_equal(h.run(rows[457:]), whole[457:])


@pytest.mark.parametrize("name", FILTERS)
def test_state_round_trip_and_reset(name: str, short_truth: np.ndarray) -> None:
    f = create(name)
    fresh = create(name).raw_state
    out = f.run(short_truth)
    s = f.state
    assert s.initialised
    np.testing.assert_array_equal(s.q_body_to_ned, out[-1, OUT_Q : OUT_Q + 4])
    np.testing.assert_array_equal(s.gyro_bias_rad_s, out[-1, OUT_BIAS : OUT_BIAS + 3])
    g = create(name)
    g.state = s
    np.testing.assert_array_equal(g.raw_state, f.raw_state)
    s.q_body_to_ned[:] = 0.0  # the getter returns a copy
    np.testing.assert_array_equal(f.state.q_body_to_ned, out[-1, OUT_Q : OUT_Q + 4])
    f.reset()
    np.testing.assert_array_equal(f.raw_state, fresh)
    assert not f.state.initialised
    assert f.diagnostics.flags & FLAG_NOT_INITIALISED
    np.testing.assert_array_equal(f.run(short_truth), create(name).run(short_truth))


# ---------------------------------------------------------------- convergence and bias


@pytest.mark.parametrize("mag", [True, False], ids=["9axis", "6axis"])
@pytest.mark.parametrize("name", FILTERS)
def test_converges_from_90_degree_error(name: str, mag: bool, synthetic) -> None:  # type: ignore[no-untyped-def]
    """State set 90° off after start-up: RMS error < 1° over 45–60 s later.

    9-axis: total error; 6-axis: inclination (heading is unobservable).
    """
    tr = synthetic(70.0, RATE_HZ, noise=True)
    rows = tr.inputs(mag=mag)
    k = int(10 * RATE_HZ)
    f = create(name)
    f.run(rows[:k])
    s = f.state
    s.q_body_to_ned = multiply(from_axis_angle([1.0, 1.0, 0.2], math.pi / 2), s.q_body_to_ned)
    f.state = s
    out = f.run(rows[k:])
    total, _, incl = _errors_deg(out, tr.q_body_to_ned[k:])
    assert (total if mag else incl)[0] > 80.0
    window = slice(int(45 * RATE_HZ), int(60 * RATE_HZ))
    err = (total if mag else incl)[window]
    assert _rms(err) < 1.0, f"{name}: RMS error {_rms(err):.2f}° 45–60 s after a 90° error"


@pytest.mark.parametrize("name", FILTERS)
def test_learns_constant_gyro_bias(name: str, synthetic) -> None:  # type: ignore[no-untyped-def]
    """A constant 0.5°/s bias on every axis is learned to 0.1°/s within 120 s (slow motion, 9-axis)."""
    bias = np.radians([0.5, -0.5, 0.5])
    tr = synthetic(120.0, RATE_HZ, amplitude=0.2, gyro_bias_rad_s=tuple(bias), noise=True)
    out = create(name).run(tr.inputs())
    learned = out[-1, OUT_BIAS : OUT_BIAS + 3]
    np.testing.assert_allclose(np.degrees(learned), np.degrees(bias), atol=0.1)
    total, _, _ = _errors_deg(out[-int(10 * RATE_HZ) :], tr.q_body_to_ned[-int(10 * RATE_HZ) :])
    assert _rms(total) < 1.0


# ---------------------------------------------------------------- invalid inputs


@pytest.mark.parametrize("name", FILTERS)
def test_invalid_vectors_skip_only_their_correction(name: str, synthetic) -> None:  # type: ignore[no-untyped-def]
    tr = synthetic(30.0, RATE_HZ)
    rows = tr.inputs()
    blocks = {
        "accel_nan": (slice(2400, 2600), IN_ACCEL, np.nan),
        "accel_zero": (slice(3000, 3200), IN_ACCEL, 0.0),
        "mag_nan": (slice(3600, 3800), IN_MAG, np.nan),
        "mag_zero": (slice(4200, 4400), IN_MAG, 0.0),
    }
    for sl, col, value in blocks.values():
        rows[sl, col : col + 3] = value
    rows[4800:4805, IN_GYRO + 1] = np.nan
    out = create(name).run(rows)
    flags = _flags(out)
    accel_bad = np.zeros(len(rows), bool)
    mag_bad = np.zeros(len(rows), bool)
    accel_bad[2400:2600] = accel_bad[3000:3200] = True
    mag_bad[3600:3800] = mag_bad[4200:4400] = True
    np.testing.assert_array_equal((flags & FLAG_ACCEL_INVALID) != 0, accel_bad)
    np.testing.assert_array_equal((flags & FLAG_MAG_INVALID) != 0, mag_bad)
    gyro_bad = (flags & FLAG_GYRO_INVALID) != 0
    assert gyro_bad[4800:4805].all() and gyro_bad.sum() == 5
    # the accelerometer's correction is skipped, the magnetometer's is not (and vice versa)
    assert np.all(out[accel_bad, OUT_ACCEL_WEIGHT] == 0.0)
    assert np.all(out[mag_bad, OUT_MAG_WEIGHT] == 0.0)
    assert np.mean(out[accel_bad, OUT_MAG_WEIGHT] > 0.5) > 0.9
    assert np.mean(out[mag_bad, OUT_ACCEL_WEIGHT] > 0.5) > 0.9
    # meanwhile the attitude keeps integrating the gyro: it follows the moving truth
    total, _, _ = _errors_deg(out, tr.q_body_to_ned)
    assert np.all(np.isfinite(out[:, OUT_Q : OUT_Q + 4]))
    assert total[2000:4795].max() < 0.5
    # a non-finite gyro sample is not integrated: the attitude holds
    held = np.tile(out[4799, OUT_Q : OUT_Q + 4], (5, 1))
    np.testing.assert_allclose(out[4800:4805, OUT_Q : OUT_Q + 4], held, rtol=0, atol=1e-12)
    assert total[-200:].max() < 0.5


@pytest.mark.parametrize("name", FILTERS)
def test_bad_dt_is_skipped(name: str, synthetic) -> None:  # type: ignore[no-untyped-def]
    tr = synthetic(10.0, RATE_HZ)
    rows = tr.inputs()
    bad = [1000, 1001, 1500]
    rows[1000, IN_DT] = 0.0
    rows[1001, IN_DT] = -0.005
    rows[1500, IN_DT] = np.nan
    out = create(name).run(rows)
    flags = _flags(out)
    for i in bad:
        assert flags[i] & FLAG_DT_INVALID
        np.testing.assert_allclose(out[i, OUT_Q : OUT_Q + 4], out[i - 1, OUT_Q : OUT_Q + 4], rtol=0, atol=1e-12)
    assert ((flags & FLAG_DT_INVALID) != 0).sum() == len(bad)
    total, _, _ = _errors_deg(out, tr.q_body_to_ned)
    assert total[-200:].max() < 0.5


@pytest.mark.parametrize("name", FILTERS)
def test_large_gap_reinitialises(name: str, synthetic) -> None:  # type: ignore[no-untyped-def]
    tr = synthetic(20.0, RATE_HZ)
    rows = tr.inputs()
    f = create(name)
    max_gap = f.settings.max_gap_s
    rows[2000, IN_DT] = max_gap * 5.0
    out = f.run(rows)
    flags = _flags(out)
    assert flags[2000] & FLAG_REINITIALISED
    assert ((flags & FLAG_REINITIALISED) != 0).sum() == 1
    total, _, _ = _errors_deg(out[2000:2001], tr.q_body_to_ned[2000:2001])
    assert total[0] < 0.5  # initialised from that sample's accelerometer + magnetometer


@pytest.mark.parametrize("mag", [True, False], ids=["9axis", "6axis"])
@pytest.mark.parametrize("name", FILTERS)
def test_level_at_rest_is_identity(name: str, mag: bool) -> None:
    """Level FRD at rest, (0, 0, −9.81) m/s² and a north field with 66° dip: q = [1, 0, 0, 0]."""
    n = 2000
    q = mavahrs.estimate(
        np.zeros((n, 3)),
        np.tile([0.0, 0.0, -9.81], (n, 1)),
        np.tile([20.0, 0.0, 45.0], (n, 1)) if mag else None,
        dt_s=1.0 / RATE_HZ,
        filter=name,
    )
    q = q * np.sign(q[:, :1])
    np.testing.assert_allclose(q, np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), atol=1e-9)


# ---------------------------------------------------------------- accuracy and API


@pytest.mark.parametrize("name", FILTERS)
def test_accuracy_on_synthetic_truth(name: str, truth_9axis_noisy) -> None:  # type: ignore[no-untyped-def]
    """Noisy 60 s: 9-axis total RMS < 1°, 6-axis inclination RMS < 1° (after 10 s)."""
    tr = truth_9axis_noisy
    after = slice(int(10 * RATE_HZ), None)
    out9 = create(name).run(tr.inputs(mag=True))
    total, _, _ = _errors_deg(out9[after], tr.q_body_to_ned[after])
    out6 = create(name).run(tr.inputs(mag=False))
    _, _, incl = _errors_deg(out6[after], tr.q_body_to_ned[after])
    assert _rms(total) < 1.0, f"{name} 9-axis total RMS {_rms(total):.2f}°"
    assert _rms(incl) < 1.0, f"{name} 6-axis inclination RMS {_rms(incl):.2f}°"


@pytest.mark.parametrize("name", FILTERS)
def test_estimate_equals_batch(name: str, truth_9axis_noisy) -> None:  # type: ignore[no-untyped-def]
    tr = truth_9axis_noisy
    sl = slice(0, 3000)
    q = mavahrs.estimate(tr.gyro_rad_s[sl], tr.accel_m_s2[sl], tr.mag_ut[sl], dt_s=tr.dt_s[sl], filter=name)
    assert q.shape == (3000, 4)
    batch = create(name).run(make_inputs(tr.gyro_rad_s[sl], tr.accel_m_s2[sl], tr.mag_ut[sl], dt_s=tr.dt_s[sl]))
    np.testing.assert_array_equal(q, batch[:, OUT_Q : OUT_Q + 4])


def test_a_filter_module_that_fails_to_import_fails_the_contract(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A broken import of a filter module is a failure of its contract tests, not a skip."""
    code = (
        "import sys; sys.modules['mavahrs.filters.mahony'] = None\n"  # import mavahrs.filters.mahony → ImportError
        "import pytest\n"
        f"sys.exit(pytest.main([{__file__!r}, '-q', '-n', '0', '-p', 'no:cacheprovider', '-rs',\n"
        "                      '-k', 'test_bad_dt_is_skipped and mahony']))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"},
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr  # 1: tests failed (0 would be: skipped)
    assert "1 failed" in proc.stdout, proc.stdout
    assert "ImportError" in proc.stdout or "ModuleNotFoundError" in proc.stdout, proc.stdout
