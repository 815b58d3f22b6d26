"""The papers' studies (Madgwick 2010 Fig. 10–12; Ermakov & Gogolev 2022 Table 2) and their plots."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.studies import beta_study, bias_study, compare_study, decimate, rate_study


def test_decimation_keeps_the_integrated_angle(synthetic_recording) -> None:
    rec = synthetic_recording
    d = decimate(rec, 7, "average")
    n = (rec.n // 7) * 7
    np.testing.assert_allclose(
        (d.gyro_rad_s * d.dt_s[:, None]).sum(0), (rec.gyro_rad_s[:n] * rec.dt_s[:n, None]).sum(0), atol=1e-9
    )
    np.testing.assert_allclose(d.dt_s, 0.07)
    np.testing.assert_array_equal(d.q_ref_body_to_ned, rec.q_ref_body_to_ned[6:n:7])
    p = decimate(rec, 7, "pick")
    np.testing.assert_array_equal(p.gyro_rad_s, rec.gyro_rad_s[6:n:7])
    with pytest.raises(ValueError):
        decimate(rec, 0)


@pytest.mark.slow
def test_beta_sweep_has_an_optimum_above_zero(synthetic_recording) -> None:
    res = beta_study([synthetic_recording], values=(0.0, 0.02, 0.1, 0.5), axes=(9,))
    curve = res.data["curves"]["9D all"]
    assert res.data["field"] == "beta_rad_s" and curve.shape == (4,)
    assert np.all(np.isfinite(curve))
    assert curve[1] < 1.0  # exact sensors: small error at a small β
    assert "β" in res.title or "beta" in res.title
    assert len(res.rows) == 4 and len(res.columns) == 4


def test_rate_sweep_skips_rates_above_the_recording(synthetic_recording) -> None:
    res = rate_study([synthetic_recording], rates_hz=(2, 10, 100, 512), axes=(6,))
    rates = [row[0] for row in res.rows]
    assert rates == [2.0, 10.0, 100.0]
    assert any("512" in n for n in res.notes)
    err = res.data["curves"]["6D all"]
    assert err[-1] < 1.0 and err[0] > err[-1]  # slower sampling, larger error


def test_bias_tracking_follows_the_injected_drift(synthetic_recording) -> None:
    res = bias_study(synthetic_recording, duration_s=55.0)
    d = res.data
    t, inj, est = d["t"], d["injected_deg_s"], d["estimate_deg_s"]
    late = t > 40
    # ζ switched on at 10 s: the estimate follows +0.2/−0.2 °/s per second within a small lag
    assert np.all(np.abs(est[late, :2] - inj[late, :2]) < 0.25 * np.abs(inj[late, :2]).max())
    assert np.abs(est[t < 5, :2]).max() < 0.2  # ζ = 0 at first: nothing learned
    assert res.rows[-1][0].startswith("t ≥")


@pytest.mark.slow
def test_compare_study_and_plots(synthetic_recording, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    from mavahrs.evaluation.plots import plot_attitude, plot_study

    res = compare_study(synthetic_recording, filters=("mahony", "madgwick", "complementary"))
    assert [r[0] for r in res.rows] == ["mahony", "madgwick", "complementary"]
    assert all(np.isfinite(r[1:]).all() for r in res.rows)
    paths = [plot_study(res, tmp_path / "cmp.png")]
    paths.append(plot_study(beta_study([synthetic_recording], values=(0.0, 0.1), axes=(6, 9)), tmp_path / "b.png"))
    paths.append(plot_study(bias_study(synthetic_recording, duration_s=20.0), tmp_path / "bias.png"))
    from mavahrs.evaluation.report import run_filter

    out = run_filter(synthetic_recording, "mahony")
    t = np.arange(synthetic_recording.n) * 0.01
    paths.append(plot_attitude(tmp_path / "att.png", t, {"mahony": out},
                               reference_q=synthetic_recording.q_ref_body_to_ned))  # fmt: skip
    for p in paths:
        assert p.stat().st_size > 10_000 and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_study_tables_serialise(synthetic_recording) -> None:
    import json

    res = rate_study([dataclasses.replace(synthetic_recording)], rates_hz=(50,), axes=(9,))
    assert json.loads(json.dumps(res.to_dict()))["study"] == "rate"
    assert "Fig. 11" in res.format()
