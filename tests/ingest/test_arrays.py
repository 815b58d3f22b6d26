"""The sample chain over arrays (mavahrs.ingest.arrays): the per-sample steps run over a log's samples.

The timeline over a log (:func:`timeline_over_arrays`, the compiled loop over the timeline step the
pipeline calls per sample) on known input: a clean clock, re-sent and restamped samples, a late
sample, a lone corrupt stamp far ahead, a confirmed jump, a gap, a ``time_boot_ms`` wrap and a reboot
(those two need the per-message pipeline); :meth:`PreparedInputs.run_filter` against the filter's own
per-row update.  Every log reader (tlog, DataFlash, ULog) builds its rows with these functions; the
compiled steps themselves (scaling, row, calibration) are tested against hand-computed values in
``test_chain.py``, the timeline step in ``test_timeline.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from mavahrs.filters import create
from mavahrs.filters.layout import IN_ACCEL, IN_DT, IN_GYRO, IN_MAG, IN_WIDTH, OUT_WIDTH
from mavahrs.ingest.arrays import _GAP_DT_S, FastPathUnsupported, PreparedInputs, timeline_over_arrays
from mavahrs.ingest.timeline import KIND_NAMES, TIME_BOOT_MS_WRAP_US, new_state, timeline_loop
from mavahrs.service.pipeline import PipelineSettings

S = PipelineSettings()


def _samples(stamps: list[int], values: list[int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stamps (µs) and, per sample, a gyro x value (the sample's identity: same value, same data)."""
    t = np.array(stamps, np.int64)
    g = np.zeros((t.size, 3))
    g[:, 0] = np.arange(t.size) if values is None else values
    a = np.tile((0.0, 0.0, -9.80665), (t.size, 1))
    return t, g, a


def test_a_clean_clock_passes_every_sample_with_its_interval() -> None:
    t, g, a = _samples([1_000_000 + 2500 * i + (500 if i % 3 == 0 else 0) for i in range(2000)])
    keep, dt = timeline_over_arrays(t, t, g, a, S.timeline)
    assert keep.all() and np.isnan(dt[0])
    np.testing.assert_array_equal(dt[1:], np.diff(t) * 1e-6)  # exactly (t - t_prev) · 1e-6


def test_drops_and_gaps_on_known_stamps() -> None:
    ms = 1000
    stamps = [10 * ms, 12 * ms, 14 * ms, 14 * ms, 14 * ms, 16 * ms, 15 * ms, 10_018 * ms, 18 * ms, 20 * ms,
              3_020 * ms, 3_022 * ms, 9_022 * ms, 9_024 * ms, 9_026 * ms]  # fmt: skip
    values = [0, 1, 2, 2, 9, 3, 4, 5, 6, 7, 8, 10, 11, 12, 13]  # sample 3 re-sent as it was, 4 other values
    t, g, a = _samples(stamps, values)
    want = ["first", "ok", "ok", "duplicate", "stale", "ok", "reordered", "drop", "ok", "ok", "gap", "ok", "drop",
            "gap", "ok"]  # fmt: skip
    kind, tt, dts = np.empty(t.size, np.int64), np.empty(t.size, np.int64), np.empty(t.size)
    timeline_loop(*new_state(S.timeline), t, t, g, a, kind, tt, dts)
    assert [KIND_NAMES[k] for k in kind] == want
    keep, dt = timeline_over_arrays(t, t, g, a, S.timeline)
    assert keep.tolist() == [k not in ("duplicate", "stale", "reordered", "drop") for k in want]
    assert np.isnan(dt[~keep]).all() and np.isnan(dt[0])
    # the lone stamp 10 s ahead is held and dropped: the next sample's dt is from the last accepted one
    assert dt[8] == pytest.approx(0.002) and dt[5] == pytest.approx(0.002) and dt[9] == pytest.approx(0.002)
    # a 3 s gap, and a 6 s jump the next sample confirms: both reach the filters as a re-initialising dt
    assert dt[10] == _GAP_DT_S and dt[13] == _GAP_DT_S and dt[11] == pytest.approx(0.002)


def test_a_time_boot_ms_wrap_and_a_reboot_need_the_per_message_pipeline() -> None:
    w = TIME_BOOT_MS_WRAP_US
    t, g, a = _samples([w - 40_000, w - 20_000, 0, 20_000, 40_000])
    with pytest.raises(FastPathUnsupported, match="wrap-around"):
        timeline_over_arrays(t, t, g, a, S.timeline)
    t, g, a = _samples([600_000_000 + 2500 * i for i in range(10)] + [1_000_000 + 2500 * i for i in range(5)])
    with pytest.raises(FastPathUnsupported, match="rebooted"):
        timeline_over_arrays(t, t, g, a, S.timeline)


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
