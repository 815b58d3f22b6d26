"""The accelerometer's bias *considered* without states on a vehicle's stream (``EskfSettings.
accel_bias_consider_sigma_m_s2``, ``best.VEHICLE_ACCEL_BIAS_CONSIDER_SIGMA_M_S2``, off by default; issue 24,
docs/monitor.md round twenty-one): the error's sensitivity to a constant bias the filter does not estimate is carried beside P with the
filter's own Φ and gains, and only the published tilt σ takes it.  firmware_sim aggressive 11 draws a 0.17 m/s²
horizontal bias: on the straight legs after its banks our tilt stands ≈ 1° off, at a σ of 0.5° without it
(beyond 2σ on 5–10 % of the aided samples; main fails: no such setting).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("firmware_sim", reason="firmware_sim (the simulator with known truth) is not importable")


def _replay(path: Path):  # type: ignore[no-untyped-def]
    from mavahrs.replay import ReplaySettings, replay

    res = replay(path, ReplaySettings())
    return res, next(iter(res.tracks.values())).out.copy()


def test_the_considered_bias_changes_the_tilt_sigma_and_nothing_else(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    import mavahrs.filters.best as best
    from mavahrs.filters.layout import FLAG_VELOCITY_AIDED, OUT_FLAGS, OUT_GAIN, OUT_HEADING_SIGMA, OUT_Q
    from mavahrs.service.monitor import align_attitudes, divergence_series

    path = tmp_path / "aggressive_11.tlog"
    subprocess.run([sys.executable, "-m", "firmware_sim", "--fast", "--tlog", str(path), "--scenario", "aggressive",
                    "--duration", "80", "--seed", "11", "-q"], check=True, cwd=Path(__file__).parents[2])  # fmt: skip
    monkeypatch.setattr(best, "VEHICLE_ACCEL_BIAS_CONSIDER_SIGMA_M_S2", 0.05)  # firmware_sim's draw per axis
    res, with_bias = _replay(path)
    monkeypatch.setattr(best, "VEHICLE_ACCEL_BIAS_CONSIDER_SIGMA_M_S2", 0.0)
    _, without = _replay(path)
    # the estimate, its heading σ and its flags exactly as without it: the bias is in no gain
    for cols in (slice(OUT_Q, OUT_Q + 4), slice(OUT_HEADING_SIGMA, OUT_HEADING_SIGMA + 1), slice(OUT_FLAGS, OUT_FLAGS + 1)):
        np.testing.assert_array_equal(with_bias[:, cols], without[:, cols])
    aided = (with_bias[:, OUT_FLAGS].astype(np.int64) & FLAG_VELOCITY_AIDED) != 0
    s1, s0 = np.degrees(with_bias[aided, OUT_GAIN]), np.degrees(without[aided, OUT_GAIN])
    assert (s1 >= s0 - 1e-9).all(), "a considered bias can only add to the tilt's variance"
    # … and where our tilt error is large the σ holds it: the share of aided samples beyond 2σ
    t_s = res.inputs.t_us[aided] / 1e6
    t_tr, q_tr = res.references[next(k for k in res.references if k.endswith("truth"))]
    err, _ = divergence_series(t_s, with_bias[aided, OUT_Q : OUT_Q + 4], t_s,
                               align_attitudes(t_tr / 1e6, q_tr, t_s, tolerance_ms=30.0))
    ok = np.isfinite(err) & (t_s > 10.0)
    beyond0, beyond1 = float(np.mean(err[ok] > 2 * s0[ok])), float(np.mean(err[ok] > 2 * s1[ok]))
    assert beyond0 > 0.05, f"not the flight it was: our error beyond 2σ on {beyond0:.1%} without the bias"
    assert beyond1 < 0.01, f"our error beyond 2σ on {beyond1:.1%} of the aided samples with the bias considered"
