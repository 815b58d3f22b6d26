"""Timeline: per-sample timing from message timestamps (wrap, reboot, duplicates, reordering, gaps, jitter)."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavahrs.ingest.timeline import (
    DROP_KINDS,
    TIME_BOOT_MS_WRAP_US,
    Timeline,
    TimelineSettings,
)


def _run(ts, tl=None, **kw):
    tl = tl or Timeline()
    return tl, [tl.push(t, **kw) for t in ts]


def test_steady_stream_passes_through_exactly():
    ts = [5_000_000 + 2500 * i for i in range(400)]
    tl, ev = _run(ts)
    assert ev[0].kind == "first" and math.isnan(ev[0].dt_s)
    assert all(e.kind == "ok" for e in ev[1:])
    assert [e.t_us for e in ev] == ts and [e.t_mono_us for e in ev] == ts
    assert all(e.dt_s == (ts[i + 1] - ts[i]) * 1e-6 for i, e in enumerate(ev[1:]))
    assert tl.interval_median_us == 2500 and tl.jitter_us == 0
    c = tl.counters
    assert (c.samples, c.accepted, c.lost_samples, c.gaps) == (400, 400, 0, 0)


def test_ardupilot_send_time_jitter_is_not_loss():
    # 50 Hz stream stamped on a 400 Hz scheduler: intervals 17.5 / 20 / 22.5 ms
    steps = [20_000, 17_500, 22_500, 20_000, 20_000, 22_500, 17_500] * 20
    ts = [0]
    for s in steps:
        ts.append(ts[-1] + s)
    tl, ev = _run(ts)
    assert {e.kind for e in ev[1:]} == {"ok"}
    assert tl.counters.lost_samples == 0 and tl.interval_median_us == 20_000 and tl.jitter_us > 0
    # one interval of two nominal periods: one sample lost; three: two
    tl.push(ts[-1] + 40_000)
    tl.push(ts[-1] + 40_000 + 60_000)
    assert tl.counters.lost_samples == 3


def test_loss_at_400hz_counted_from_the_median():
    ts = [2500 * i for i in range(100)] + [2500 * 100 + 2500, 2500 * 103]  # a 5 ms step then a 5 ms step
    tl, ev = _run(ts)
    assert tl.counters.lost_samples == 2 and ev[-1].dt_s == 0.005


def test_duplicates_and_stale_timestamps_dropped():
    tl = Timeline()
    tl.push(1000)
    tl.push(3500, sample_key=(1, 2))
    assert tl.push(3500, sample_key=(1, 2)).kind == "duplicate"
    assert tl.push(3500).kind == "duplicate"  # no data key: same time is a duplicate
    e = tl.push(3500, sample_key=(9, 9))
    assert e.kind == "stale" and e.dt_s == 0.0 and e.kind in DROP_KINDS
    assert tl.push(6000).dt_s == 0.0025  # dt from the last accepted sample
    assert (tl.counters.duplicates, tl.counters.stale, tl.counters.accepted) == (2, 1, 3)


def test_reordered_samples_dropped_and_counted():
    tl, ev = _run([0, 2500, 7500, 5000, 10_000])
    assert [e.kind for e in ev] == ["first", "ok", "ok", "reordered", "ok"]
    assert ev[3].t_mono_us == 7500  # a dropped sample reports the last accepted time
    assert ev[4].dt_s == 0.0025 and tl.counters.reordered == 1


def test_gap_reported_with_its_length():
    ts = [2500 * i for i in range(10)]
    tl, ev = _run(ts + [22_500 + 600_000, 22_500 + 602_500])
    assert [e.kind for e in ev[9:]] == ["ok", "gap", "ok"]
    assert ev[10].dt_s == 0.6 and tl.counters.gaps == 1
    assert tl.counters.lost_samples == 239  # 600 ms of 2.5 ms samples, minus the one that arrived


def test_time_boot_ms_wraps_transparently():
    w = TIME_BOOT_MS_WRAP_US
    raw = [w - 40_000, w - 20_000, 0, 20_000, 40_000]  # time_boot_ms·1000 going through 2^32 ms
    tl, ev = _run(raw)
    assert [e.kind for e in ev] == ["first", "ok", "ok", "ok", "ok"]
    assert [e.t_us for e in ev] == [w - 40_000, w - 20_000, w, w + 20_000, w + 40_000]
    assert all(e.dt_s == 0.02 for e in ev[1:]) and tl.counters.wraps == 1 and tl.counters.reboots == 0
    # without unwrapping configured, the same is a reboot (confirmed by the second sample)
    tl2, ev2 = _run(raw, Timeline(TimelineSettings(wrap_period_us=None)))
    assert [e.kind for e in ev2] == ["first", "ok", "reordered", "reboot", "ok"]


def test_reboot_confirmed_by_next_sample_and_monotonic_time_continues():
    before = [600_000_000 + 2500 * i for i in range(10)]
    after = [1_000_000 + 2500 * i for i in range(5)]
    tl, ev = _run(before + after)
    kinds = [e.kind for e in ev]
    assert kinds[10] == "reordered" and kinds[11] == "reboot" and kinds[12:] == ["ok"] * 3
    assert math.isnan(ev[11].dt_s) and ev[11].t_us == after[1]  # the autopilot's own new time
    mono = [e.t_mono_us for e in ev if e.kind not in DROP_KINDS]
    assert all(b > a for a, b in itertools.pairwise(mono))
    assert ev[11].t_mono_us == before[-1] + 2500  # one median interval after the last sample
    c = tl.counters
    assert (c.reboots, c.reordered, c.held, c.accepted) == (1, 0, 1, 14)


def test_reboot_monotonic_time_uses_receive_time_when_given():
    tl = Timeline()
    for i in range(10):
        tl.push(600_000_000 + 2500 * i, now_us=10_000_000 + 2500 * i)
    tl.push(1_000_000, now_us=13_000_000)
    e = tl.push(1_002_500, now_us=13_002_500)
    assert e.kind == "reboot" and e.t_mono_us == 600_000_000 + 2500 * 9 + (13_002_500 - 10_022_500)


def test_stray_old_sample_is_not_a_reboot():
    ts = [600_000_000 + 2500 * i for i in range(10)]
    tl, ev = _run(ts + [100_000_000] + [ts[-1] + 2500, ts[-1] + 5000])
    assert [e.kind for e in ev[10:]] == ["reordered", "ok", "ok"]
    assert tl.counters.reboots == 0 and tl.counters.reordered == 1


def test_single_corrupt_future_timestamp_is_held_and_dropped():
    ts = [2500 * i for i in range(10)]
    tl, ev = _run(ts + [10**12, 25_000, 27_500])
    assert [e.kind for e in ev[10:]] == ["drop", "ok", "ok"]
    assert ev[11].dt_s == 0.0025 and tl.counters.jumps_rejected == 1 and tl.counters.gaps == 0


def test_confirmed_forward_jump_is_a_gap():
    ts = [2500 * i for i in range(10)]
    tl, ev = _run(ts + [30_000_000, 30_002_500, 30_005_000])
    assert [e.kind for e in ev[10:]] == ["drop", "gap", "ok"]
    assert ev[11].dt_s == (30_002_500 - 22_500) * 1e-6
    assert tl.counters.jumps_rejected == 0 and tl.counters.gaps == 1 and tl.counters.held == 1


@pytest.mark.parametrize(
    "kw",
    [{"max_gap_s": 0}, {"reboot_back_s": -1}, {"jump_confirm_s": 0.1, "max_gap_s": 0.5}, {"median_window": 2},
     {"wrap_period_us": 0}, {"lost_factor": float("nan")}],
)  # fmt: skip
def test_settings_validated(kw):
    with pytest.raises(ValueError):
        TimelineSettings(**kw)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.integers(min_value=0, max_value=2**40), min_size=1, max_size=80), st.booleans())
def test_any_timestamps_give_consistent_events(ts, sorted_input):
    if sorted_input:
        ts = sorted(ts)
    tl = Timeline()
    last_mono = None
    epoch_last = None
    for t in ts:
        e = tl.push(t)
        assert e.kind in {"first", "ok", "gap", "duplicate", "stale", "reordered", "reboot", "drop"}
        if e.kind in DROP_KINDS:
            assert e.dt_s == 0.0
            continue
        if last_mono is not None:
            assert e.t_mono_us > last_mono
        last_mono = e.t_mono_us
        if e.kind in ("first", "reboot"):
            assert math.isnan(e.dt_s)
        else:
            assert e.dt_s > 0 and e.t_us > epoch_last
            assert e.dt_s == (e.t_us - epoch_last) * 1e-6
        epoch_last = e.t_us
    c = tl.counters
    assert c.samples == len(ts)
    assert c.accepted + c.duplicates + c.stale + c.reordered + c.jumps_rejected + c.held == c.samples
