"""The compass heading's noise per reading, learnt by the ESKF from its own innovations (``EskfSettings.mag_noise_tau_s``).

The noise is read from the differences of consecutive heading innovations (each carried to the current
estimate by the filter's own corrections), so a slow heading error the estimate carries does not count as
noise.  Checked against the truth: the readings rotated with the simulator's true attitude scatter about
the field's azimuth by what the compass really measures (PX4 SITL 2.6–3.3°, independent from reading to
reading).  docs/accuracy.md, "PX4 calm-segment heading".
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_sim.__main__ import main as sim_main
from mavahrs.evaluation.loaders import load_any
from mavahrs.filters.best import Best, BestSettings
from mavahrs.filters.layout import IN_MAG
from mavahrs.replay import ReplaySettings, replay


def _c_body_to_ned(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1).reshape(-1, 3, 3)  # fmt: skip


def _reading_scatter_deg(path, lag_s: float) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """The new readings' azimuth in the true frame (the truth ``lag_s`` before the stamp), high-passed (5 s),
    where the vehicle turns slower than 10°/s and after 10 s: (1-σ, lag-1 correlation)."""
    rec = load_any(path)[0]
    t = np.cumsum(rec.dt_s)
    m = rec.mag_ut
    new = np.r_[True, np.any(m[1:] != m[:-1], axis=1)] & np.isfinite(m[:, 0]) & np.isfinite(rec.q_ref_body_to_ned[:, 0])
    idx = np.nonzero(new)[0]
    j = np.clip(np.searchsorted(t, t[idx] - lag_s), 0, len(t) - 1)
    b = np.einsum("nij,nj->ni", _c_body_to_ned(rec.q_ref_body_to_ned[j]), m[idx])
    az = np.arctan2(b[:, 1], b[:, 0])
    calm = (np.abs(rec.gyro_rad_s[idx, 2]) < math.radians(10.0)) & (t[idx] > 10.0)
    a = np.unwrap(az[calm])
    n = max(int(5.0 * len(idx) / (t[-1] - t[0])), 3)
    hp = (a - np.convolve(a, np.ones(n) / n, mode="same"))[n:-n]
    return math.degrees(float(np.std(hp))), float(np.corrcoef(hp[:-1], hp[1:])[0, 1])


def _learnt(res) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    f = Best(BestSettings())
    res.inputs.run_filter(f)
    sigma_rad, rho = f.mag_noise_rad()
    return math.degrees(sigma_rad), rho


def test_px4_sitl_compass_noise_learnt_as_its_scatter_against_the_truth(shared_data) -> None:  # type: ignore[no-untyped-def]
    """PX4 SITL: 14 readings/s, each ≈ 3° off the field's azimuth (independent); the fixed σ was 5° at ≤ 10 Hz.

    The compass is read 0.03 s before its stamps (its scatter against the truth is smallest there; the ESKF
    learns that delay too).  Learnt while ``best`` carries a +1…+2° heading error through the final hover
    (the z gyro bias learnt in the manoeuvres): the differences do not count it as noise.
    """
    path = shared_data / "px4_sitl" / "px4_aggressive.tlog"
    if not path.exists():
        pytest.skip(f"{path} not found (the shared PX4 SITL flight, ../shared/data/px4_sitl)")
    scatter_deg, rho_true = _reading_scatter_deg(path, 0.03)
    res = replay(path, ReplaySettings(filters=("best",)))
    sigma_deg, rho = _learnt(res)
    print(f"readings vs truth {scatter_deg:.2f}° (lag-1 {rho_true:+.2f}); learnt {sigma_deg:.2f}° (lag-1 {rho:.2f})")
    assert abs(rho_true) < 0.2  # the premise: independent readings
    assert 0.85 * scatter_deg < sigma_deg < 1.35 * scatter_deg, (sigma_deg, scatter_deg)
    assert rho < 0.3, rho


def test_a_noisier_compass_is_learnt_noisier(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """firmware_sim PX4 hover, then the same flight with white noise added to every magnetometer axis: the
    learnt variance grows by the added noise's heading variance (its horizontal share over the field's
    horizontal strength), so a noisy compass is trusted less and a clean one more."""
    path = tmp_path / "px4_hover.tlog"
    assert sim_main(["--tlog", str(path), "--fast", "-q", "--autopilot", "px4", "--scenario", "hover",
                     "--seed", "2", "--duration", "90"]) == 0  # fmt: skip
    res = replay(path, ReplaySettings(filters=("best",)))
    clean_deg, _ = _learnt(res)
    rows = res.inputs.rows
    mag = rows[:, IN_MAG : IN_MAG + 3].copy()
    h_ut = float(np.nanmedian(np.hypot(*load_any(path)[0].mag_ut[:, :2].T)))  # level hover: the horizontal field
    added_ut = 1.5
    noisy = mag + np.random.default_rng(7).normal(0.0, added_ut, mag.shape)
    try:
        rows[:, IN_MAG : IN_MAG + 3] = np.where(np.isfinite(mag), noisy, mag)
        noisy_deg, _ = _learnt(res)
    finally:
        rows[:, IN_MAG : IN_MAG + 3] = mag
    added_deg = math.degrees(added_ut / h_ut)  # the noise across the horizontal field, as heading
    grown_deg = math.sqrt(max(noisy_deg**2 - clean_deg**2, 0.0))
    print(f"clean {clean_deg:.2f}°, noisy {noisy_deg:.2f}°: grown by {grown_deg:.2f}° (added {added_deg:.2f}°)")
    assert noisy_deg > clean_deg
    assert 0.7 * added_deg < grown_deg < 1.4 * added_deg, (grown_deg, added_deg)
