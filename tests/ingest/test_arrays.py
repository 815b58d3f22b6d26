"""The sample chain over arrays (mavahrs.ingest.arrays) is the per-sample step run over the samples.

VQF's rule for the batch path, checked step by step: ``_timeline`` against
:class:`~mavahrs.protocol.timeline.Timeline` pushed one sample at a time (the pipeline's call),
and :meth:`PreparedInputs.run_filter` against the filter's own per-row update.  Every log reader
(tlog, DataFlash, ULog) builds its rows with these functions; the compiled steps themselves
(scaling, row, calibration) are tested against hand-computed values in ``test_chain.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from mavahrs.filters import create
from mavahrs.filters.layout import IN_ACCEL, IN_DT, IN_GYRO, IN_MAG, IN_WIDTH, OUT_WIDTH
from mavahrs.ingest.arrays import _GAP_DT_S, FastPathUnsupported, PreparedInputs, _timeline
from mavahrs.protocol.timeline import DROP_KINDS, GAP, Timeline
from mavahrs.service.pipeline import PipelineSettings


def _stream(rng: np.random.Generator, n: int = 3000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = 1_000_000 + np.arange(n, dtype=np.int64) * 2500
    g = rng.normal(0.0, 0.1, (n, 3))
    a = rng.normal(0.0, 0.1, (n, 3)) + (0.0, 0.0, -9.81)
    return t, g, a


def _per_sample(t, g, a, s):  # type: ignore[no-untyped-def]
    """What the pipeline's timeline decides, one sample at a time (Pipeline: raw time, receive time, values)."""
    tl = Timeline(s.timeline)
    keep = np.ones(t.size, bool)
    dt = np.full(t.size, np.nan)
    for i in range(t.size):
        ev = tl.push(int(t[i]), int(t[i]), (*g[i].tolist(), *a[i].tolist()))
        if ev.kind in DROP_KINDS:
            keep[i] = False
            continue
        dt[i] = max(ev.dt_s, _GAP_DT_S) if ev.kind == GAP else ev.dt_s
    return keep, dt


def test_timeline_over_arrays_is_the_timeline_per_sample(rng: np.random.Generator) -> None:
    s = PipelineSettings()
    t, g, a = _stream(rng)
    # a clean stream: the shortcut (every sample ok, dt = Δt)
    np.testing.assert_array_equal(_timeline(t, t, g, a, s)[0], _per_sample(t, g, a, s)[0])
    np.testing.assert_allclose(_timeline(t, t, g, a, s)[1][1:], _per_sample(t, g, a, s)[1][1:])
    # re-sent samples (same stamp and values), a step back, a 3 s gap: the per-sample loop over the Timeline
    t2, g2, a2 = t.copy(), g.copy(), a.copy()
    for i in (100, 101, 900):
        t2[i + 1], g2[i + 1], a2[i + 1] = t2[i], g2[i], a2[i]
    t2[1500] = t2[1499] - 5000
    t2[2000:] += 3_000_000
    keep, dt = _timeline(t2, t2, g2, a2, s)
    ref_keep, ref_dt = _per_sample(t2, g2, a2, s)
    np.testing.assert_array_equal(keep, ref_keep)
    np.testing.assert_array_equal(np.isnan(dt), np.isnan(ref_dt))
    np.testing.assert_allclose(dt[keep][1:], ref_dt[keep][1:])
    assert (~keep).sum() >= 4 and dt[2000] == _GAP_DT_S  # the drops, and the gap as a re-initialising dt


def test_a_reboot_needs_the_per_message_pipeline(rng: np.random.Generator) -> None:
    t, g, a = _stream(rng)
    t[2000:] -= t[2000] - 10_000  # the autopilot's clock starts again
    with pytest.raises(FastPathUnsupported, match="rebooted"):
        _timeline(t, t, g, a, PipelineSettings())


def test_run_filter_is_the_per_row_update(rng: np.random.Generator) -> None:
    n = 2000
    rows = np.full((n, IN_WIDTH), np.nan)
    rows[:, IN_DT] = 0.0025
    rows[0, IN_DT] = np.nan
    rows[:, IN_GYRO : IN_GYRO + 3] = rng.normal(0, 0.2, (n, 3))
    rows[:, IN_ACCEL : IN_ACCEL + 3] = rng.normal(0, 0.2, (n, 3)) + (0.0, 0.0, -9.81)
    rows[::4, IN_MAG : IN_MAG + 3] = (22.0, 0.0, 42.0)
    t = np.arange(n, dtype=np.int64) * 2500
    prep = PreparedInputs(rows=rows, t_us=t, frame_pos=np.arange(n), tlog_us=t, temperature_c=np.full(n, np.nan),
                          declination_rad=np.zeros(n), message="IMU", instance=0, source=(1, 1), profile="ardupilot",
                          mag_reference_events=[(0, 47.0, 1.09), (1200, 48.0, 1.1)])  # fmt: skip
    for name in ("madgwick", "mahony"):
        batch = prep.run_filter(create(name))
        f = create(name)
        one = np.empty((n, OUT_WIDTH))
        for i in range(n):
            for k, norm, dip in prep.mag_reference_events:
                if k == i:
                    f.set_mag_reference(norm, dip)
            f.run(rows[i : i + 1], one[i : i + 1])
        np.testing.assert_allclose(batch, one, rtol=0, atol=1e-12, equal_nan=True, err_msg=name)
