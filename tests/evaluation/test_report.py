"""Scoring filters against references: BROAD (independent check), RepoIMU, documented CSV."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.datasets import Recording, load_csv, load_repoimu_csv, write_csv_recording
from mavahrs.evaluation.loaders import load_any
from mavahrs.evaluation.report import evaluate_recordings, format_report, resolve_filter_names
from mavahrs.geometry.quaternion import from_rotation_vector, multiply
from mavahrs.geometry.rotation import to_matrix

TRIAL = "02_undisturbed_slow_rotation_B.mat"


def _broad_rmse_independent(mat: Path, q_est_ned: np.ndarray) -> dict[str, float]:
    """BROAD's error definition written from the dataset README with scipy, in BROAD's own ENU frame."""
    from scipy.io import loadmat
    from scipy.spatial.transform import Rotation

    d = loadmat(str(mat))
    q_ref = d["opt_quat"]  # IMU → ENU, scalar first, NaN rows
    movement = d["movement"].ravel() == 1
    # NED → ENU: left-multiply by [0, √½, √½, 0] (README); scipy wants scalar last.
    r_ned2enu = Rotation.from_quat([np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0])
    r_est = r_ned2enu * Rotation.from_quat(q_est_ned[:, [1, 2, 3, 0]])
    ok = np.all(np.isfinite(q_ref), axis=1) & movement
    r_ref = Rotation.from_quat(q_ref[ok][:, [1, 2, 3, 0]])
    e = (r_est[ok] * r_ref.inv()).as_quat()  # x, y, z, w
    w, z = e[:, 3], e[:, 2]
    total = 2 * np.arccos(np.clip(np.abs(w), 0, 1))
    heading = 2 * np.arctan(np.abs(z / w))
    incl = 2 * np.arccos(np.clip(np.sqrt(w**2 + z**2), 0, 1))
    rms = lambda x: float(np.degrees(np.sqrt(np.mean(x**2))))  # noqa: E731
    return {"total_rms_deg": rms(total), "heading_rms_deg": rms(heading), "inclination_rms_deg": rms(incl)}


def test_broad_trial_matches_an_independent_calculation(broad_dir: Path) -> None:
    import mavahrs

    mat = broad_dir / TRIAL
    recs = load_any(mat)
    report = evaluate_recordings(recs, ["mahony"], input_name=str(mat))
    got = json.loads(report.to_json())["filters"]["mahony"]
    assert got["alignment"] == "none"
    from scipy.io import loadmat

    d = loadmat(str(mat))
    q = mavahrs.estimate(d["imu_gyr"], d["imu_acc"], d["imu_mag"], dt_s=7 / 2000, filter="mahony")
    want = _broad_rmse_independent(mat, q)
    for key, value in want.items():
        assert abs(got[key] - value) < 0.01, (key, got[key], value)
    assert 0.1 < got["total_rms_deg"] < 10  # a working filter, not a degenerate comparison
    # per-angle table present and consistent: rest + motion samples = scored samples
    assert got["rest_samples"] + got["motion_samples"] == got["samples"]
    for a in ("roll", "pitch", "yaw"):
        for kind in ("rms_rest_deg", "rms_motion_deg", "mean_deg", "sd_deg"):
            assert np.isfinite(got[f"{a}_{kind}"])
    text = format_report(report)
    assert "mahony" in text and "alignment: none" in text


@pytest.fixture(scope="module")
def repoimu_dir(shared_data: Path) -> Path:
    p = shared_data / "repoimu_tstick"
    if not p.exists():
        pytest.skip(f"RepoIMU data not found at {p}")
    return p


def test_repoimu_heading_offset_is_fitted_and_clipping_flagged(repoimu_dir: Path) -> None:
    rec = load_repoimu_csv(repoimu_dir / "TStick_Test02_Trial1.csv")
    assert not rec.heading_referenced and rec.extra["gyro_clipped_samples"] == 0
    rep = evaluate_recordings([rec], ["mahony"]).recordings[0]
    s = rep.scores["mahony"]
    assert s.alignment.mode == "heading"
    assert 30 < abs(s.alignment.heading_offset_deg) < 90  # README: ≈ 60°, varies per trial
    assert s.total_rms_deg < 5
    both = evaluate_recordings([rec], ["mahony"], alignment="heading+body").recordings[0].scores["mahony"]
    assert both.total_rms_deg < s.total_rms_deg and 0.5 < both.alignment.body_misalignment_deg < 6
    clipped = load_repoimu_csv(repoimu_dir / "TStick_Test05_Trial1.csv")
    assert clipped.extra["gyro_clipped_samples"] > 1000
    static = load_repoimu_csv(repoimu_dir / "TStick_Test01_Static.csv")
    rep = evaluate_recordings([static], ["mahony"]).recordings[0]
    assert not rep.scores and "no reference" in rep.notes[0]


def _synthetic(rng: np.random.Generator, n: int = 3000) -> Recording:
    """A level sensor turning slowly about its vertical: exact gyro, accel, mag and reference."""
    dt = 0.01
    rate = np.zeros((n, 3))
    rate[:, 2] = 0.3 * np.sin(np.arange(n) * dt)
    q = np.empty((n, 4))
    q[0] = [1.0, 0, 0, 0]
    for i in range(1, n):
        q[i] = multiply(q[i - 1], from_rotation_vector(rate[i] * dt))
    from mavahrs.geometry.quaternion import conjugate, rotate

    g_body = rotate(conjugate(q), np.array([0.0, 0.0, -9.80665]))
    m_body = rotate(conjugate(q), np.array([20.0, 0.0, 45.0]))
    return Recording("syn", np.full(n, dt), rate, g_body, m_body, q, np.ones(n, bool))


def test_documented_csv_round_trip_and_noisy_matrix_reference(tmp_path: Path, rng: np.random.Generator) -> None:
    rec = _synthetic(rng)
    path = tmp_path / "rec.csv"
    write_csv_recording(path, rec)
    back = load_csv(path)
    np.testing.assert_allclose(back.gyro_rad_s, rec.gyro_rad_s, atol=1e-8)
    np.testing.assert_allclose(np.abs(np.sum(back.q_ref_body_to_ned * rec.q_ref_body_to_ned, axis=1)), 1, atol=1e-7)
    # reference given as a noisy, non-orthogonal matrix → Bar-Itzhack
    m = to_matrix(rec.q_ref_body_to_ned) + rng.normal(scale=0.002, size=(rec.n, 3, 3))
    cols = ["time_s", "gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s", "accel_x_m_s2", "accel_y_m_s2",
            "accel_z_m_s2"] + [f"r{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)]  # fmt: skip
    t = np.arange(rec.n) * 0.01
    data = np.hstack([t[:, None], rec.gyro_rad_s, rec.accel_m_s2, m.reshape(rec.n, 9)])
    p2 = tmp_path / "matrix.csv"
    np.savetxt(p2, data, delimiter=",", header=",".join(cols), comments="")
    r2 = load_csv(p2)
    err = np.degrees(2 * np.arccos(np.clip(np.abs(np.sum(r2.q_ref_body_to_ned * rec.q_ref_body_to_ned, 1)), 0, 1)))
    assert err.max() < 0.5
    rep = evaluate_recordings([back], ["mahony"]).recordings[0].scores["mahony"]
    assert rep.total_rms_deg < 1.0


def test_filter_names() -> None:
    names = resolve_filter_names(["all"])
    assert "mahony" in names and len(set(names)) == len(names)
    with pytest.raises(ValueError, match="unknown filter"):
        resolve_filter_names(["kalman"])

