"""``best`` under sustained tilted acceleration: the simulator's ``aggressive`` flight, and GNSS compensation.

A multirotor's accelerometer reads thrust and rotor drag, not gravity, while it
accelerates: in ``firmware_sim``'s ``aggressive`` scenario (dashes with 30–45°
of tilt for seconds, hard braking) its direction is ≈ 22° RMS away from
gravity.  Issue 4 asks the daemon's default filter (``best``) for ≤ 3°
inclination RMS there with GLOBAL_POSITION_INT and ≤ 6° without it
(imufusion and VQF reach 10–12°).  The flight is replayed through the daemon's
pipeline (:func:`mavahrs.replay.replay`, bit-identical to
:class:`~mavahrs.service.pipeline.Pipeline`), with GLOBAL_POSITION_INT and
with every GLOBAL_POSITION_INT removed from the same log.

The synthetic tests isolate the compensation itself: a level vehicle
accelerating north at 3 m/s² for 20 s, GNSS velocity at 10 Hz.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.metrics import attitude_errors_rad, summarize
from mavahrs.filters import create
from mavahrs.filters.base import make_inputs
from mavahrs.filters.layout import IN_VEL, OUT_Q

G_M_S2 = 9.80665
GLOBAL_POSITION_INT = 33


# ------------------------------------------------------------------ the simulator flight


@pytest.fixture(scope="module")
def aggressive_flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """45 s of ``aggressive`` flight (seed 1), 400 Hz RAW_IMU + SIMSTATE, 10 Hz GLOBAL_POSITION_INT; and without it."""
    fs_main = pytest.importorskip("firmware_sim.__main__")
    from mavahrs.protocol.fast_tlog import scan_tlog
    from mavahrs.protocol.tlog import tlog_record

    folder = tmp_path_factory.mktemp("aggressive")
    with_gps, without = folder / "aggressive.tlog", folder / "aggressive_nogps.tlog"
    rc = fs_main.main([
        "--tlog", str(with_gps), "--fast", "-q", "--scenario", "aggressive", "--duration", "45", "--seed", "1",
        "--declination-deg", "0", "--loop-rate", "800", "--stream", "RAW_IMU=400", "--stream", "SIMSTATE=400",
        "--stream", "SCALED_IMU2=0",
    ])  # fmt: skip
    assert rc == 0
    scan = scan_tlog(with_gps, None, mode="sequential")
    keep = [j for j in range(len(scan)) if scan.msgid[j] != GLOBAL_POSITION_INT]
    assert len(keep) < len(scan)  # there was GNSS to remove
    without.write_bytes(b"".join(tlog_record(int(scan.t_us[j]), scan.frame(j)) for j in keep))
    return with_gps, without


def _replayed_best(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The daemon's ``best`` replayed on ``path``: (truth times µs, its attitude at them (NaN: none), the truth)."""
    from mavahrs.replay import ReplaySettings, attitude_at_reference, replay
    from mavahrs.sensors.geomag import MagneticFieldSettings
    from mavahrs.service.pipeline import PipelineSettings

    ps = PipelineSettings(out_rate_hz=0.0, magnetic=MagneticFieldSettings(declination_deg=0.0))
    res = replay(path, ReplaySettings(filters=("best",), pipeline=ps))
    (truth,) = [k for k in res.references if "truth" in k]
    t_ref, q_ref = res.references[truth]
    return t_ref, attitude_at_reference(res, "best", truth), q_ref


def _replayed_inclination_deg(path: Path) -> tuple[float, float]:
    """(inclination RMS, heading RMS) of the daemon's ``best`` on ``path`` against SIMSTATE truth, degrees."""
    _t, q, q_ref = _replayed_best(path)
    ok = np.all(np.isfinite(q), axis=1)
    assert ok.sum() > 0.9 * len(q)
    s = summarize(q[ok], q_ref[ok])
    return s.inclination_rms_deg, s.heading_rms_deg


@pytest.mark.slow  # simulating the 45 s flight takes ≈ 5–10 s
def test_best_meets_issue_4_on_aggressive_flight(aggressive_flight: tuple[Path, Path]) -> None:
    """Inclination RMS ≤ 3° with GLOBAL_POSITION_INT, ≤ 6° without (issue 4); heading stays a few degrees.

    Measured (``docs/accuracy.md``): ≈ 0.9° / 2.4° on this flight; over six
    120 s flights the worst seed is 1.1° / 4.7°.  The run without GNSS must
    be clearly worse than with it, which shows the velocity is what helps.
    """
    with_gps, without = aggressive_flight
    incl_gps, head_gps = _replayed_inclination_deg(with_gps)
    incl_nogps, head_nogps = _replayed_inclination_deg(without)
    assert incl_gps <= 3.0
    assert incl_nogps <= 6.0
    assert incl_nogps > 1.5 * incl_gps
    assert head_gps < 4.0 and head_nogps < 6.0


def _replayed_inclination_series(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(time since the first truth sample, s; inclination error of the daemon's ``best``, °) at the truth's times."""
    t_ref, q, q_ref = _replayed_best(path)
    err = np.full(len(q), np.nan)
    ok = np.all(np.isfinite(q), axis=1)
    err[ok] = np.degrees(attitude_errors_rad(q[ok], q_ref[ok])[2])
    return (t_ref - t_ref[0]) * 1e-6, err


@pytest.mark.parametrize(("seed", "outage_s"), [(1, 12.0), (5, 9.0)])
def test_an_outage_mid_manoeuvre_is_recovered_with_gnss(
    tmp_path: Path, seed: int, outage_s: float
) -> None:
    """A 1.5 s link outage in the ``aggressive`` flight: with GNSS, back near the uninterrupted run in 3 s.

    After the outage the filter re-initialises from the accelerometer, which in
    a manoeuvre reads thrust and drag, not gravity (here 20–45° off). With
    GLOBAL_POSITION_INT, the first v̇ after the re-initialisation (0.1–0.2 s
    later) re-aligns the estimate by TRIAD (f ↔ v̇ − g, m ↔ the reference
    field) and the compensation applies in full at once. Measured: 1–3 s after
    the outage 3.3° / 5.0° inclination RMS, 3–5 s after it 2.0° / 2.3°
    (uninterrupted 0.5–1.5°). Before, the filter converged on f − v̇ taken in its
    own wrong frame: 17° / 32°, then 14° / 28° (two of the worst of 28 outages
    over 7 seeds in ``docs/reliability.md``).
    """
    fs_main = pytest.importorskip("firmware_sim.__main__")
    series = []
    for blackout in (None, f"{outage_s}:1.5"):
        path = tmp_path / f"aggressive_{blackout or 'clean'}.tlog"
        args = [
            "--tlog", str(path), "--fast", "-q", "--scenario", "aggressive", "--duration", "20", "--seed", str(seed),
            "--declination-deg", "0", "--stream", "RAW_IMU=400", "--stream", "SIMSTATE=50", "--stream", "SCALED_IMU2=0",
        ]  # fmt: skip
        assert fs_main.main(args + (["--blackout", blackout] if blackout else [])) == 0
        series.append(_replayed_inclination_series(path))
    (t0, clean), (t, cut) = series
    end = outage_s + 1.5

    def rms(tt: np.ndarray, e: np.ndarray, a: float, b: float) -> float:
        sel = (tt >= end + a) & (tt < end + b) & np.isfinite(e)
        assert sel.sum() > 40
        return float(np.sqrt(np.mean(e[sel] ** 2)))

    assert rms(t, cut, 1.0, 3.0) <= rms(t0, clean, 1.0, 3.0) + 6.0
    assert rms(t, cut, 3.0, 5.0) <= rms(t0, clean, 3.0, 5.0) + 2.5


# ------------------------------------------------------------------ the compensation on synthetic data


RATE_HZ = 200.0


def _accelerating_north(velocity: str, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Level, facing north; 3 m/s² north from 10 s to 30 s of 40 s; noisy IMU; GNSS velocity at 10 Hz.

    ``velocity``: ``"nan"`` — a fix every 20th row, NaN between (what the
    daemon's pipeline feeds); ``"held"`` — the last fix repeated on every row;
    ``"none"`` — no velocity.  Returns (input rows, true q_body_to_ned).
    """
    n = int(40 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    a_north = np.where((t >= 10.0) & (t < 30.0), 3.0, 0.0)
    v_north = np.cumsum(a_north) / RATE_HZ
    rng = np.random.default_rng(seed)
    gyro = rng.normal(scale=math.radians(0.3), size=(n, 3))
    accel = np.stack([a_north, np.zeros(n), np.full(n, -G_M_S2)], axis=1) + rng.normal(scale=0.05, size=(n, 3))
    mag = np.tile([20.0, 0.0, 45.0], (n, 1)) + rng.normal(scale=0.3, size=(n, 3))
    vel = None
    if velocity != "none":
        fix = np.arange(n) % 20 == 0
        vel = np.full((n, 3), np.nan)
        vel[fix] = np.stack([v_north, np.zeros(n), np.zeros(n)], axis=1)[fix]
        if velocity == "held":
            idx = np.maximum.accumulate(np.where(fix, np.arange(n), 0))
            vel = vel[idx]
    rows = make_inputs(gyro, accel, mag, dt_s=1.0 / RATE_HZ, velocity_ned_m_s=vel)
    return rows, np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))


def _inclination_deg(rows: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    out = create("best").run(rows)
    return np.degrees(attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], q_true)[2])


def test_gnss_compensation_keeps_tilt_under_sustained_acceleration() -> None:
    """17° of apparent tilt (3 m/s² for 20 s): < 1° with the velocity, > 5° without it.

    Without velocity the low-passed specific force points 17° off the vertical
    for 20 s; the manoeuvre weight slows the drift (≈ 10° at the end) but
    cannot stop it.  With velocity, f − v̇ is the vertical again; what is
    left (≈ 0.5°) are the two steps of the acceleration, which a 10 Hz
    velocity sees up to 0.1 s late, and noise.
    """
    rows, q = _accelerating_north("nan")
    with_vel = _inclination_deg(rows, q)
    without = _inclination_deg(_accelerating_north("none")[0], q)
    moving = slice(int(10 * RATE_HZ), int(32 * RATE_HZ))
    assert np.max(with_vel[moving]) < 1.0
    assert np.max(without[moving]) > 5.0
    assert np.mean(with_vel[moving]) < 0.1 * np.mean(without[moving])


@pytest.mark.parametrize("boost", [10.0, 1.0])
def test_a_restart_mid_acceleration_is_realigned_on_the_first_velocity(boost: float) -> None:
    """A 2 s gap at 20 s, in the middle of 3 m/s² north: the accelerometer start is 17° off.

    With the velocity, the first v̇ after the restart (two fixes, ≤ 0.1 s later) re-aligns the
    estimate by TRIAD: 0.5 s after the gap the tilt is within 1.5° — with the start-up boost and
    without it (``startup_gain_factor=1``: the re-alignment is bound to the time since the
    restart, not to the boost). Without the velocity it is still > 8° off then.
    """
    from dataclasses import replace

    from mavahrs.filters.best import best_settings

    rows, q = _accelerating_north("nan")
    gap = int(20 * RATE_HZ)
    rows[gap, 0] = 2.0  # IN_DT: a 2 s step, beyond max_gap_s: the filter re-initialises on this row
    s = best_settings()
    s = replace(s, schedule=replace(s.schedule, startup_gain_factor=boost))
    out = create("madgwick", s).run(rows)
    incl = np.degrees(attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], q)[2])
    assert incl[gap] > 10.0  # the restart itself: the accelerometer's direction
    assert np.max(incl[gap + int(0.5 * RATE_HZ) : gap + int(3.0 * RATE_HZ)]) < 1.5
    no_vel = rows.copy()
    no_vel[:, IN_VEL : IN_VEL + 3] = np.nan
    out = create("madgwick", s).run(no_vel)
    incl = np.degrees(attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], q)[2])
    assert incl[gap + int(0.5 * RATE_HZ)] > 8.0


def test_held_velocity_works_like_nan_between_fixes() -> None:
    """A fix repeated on every row gives the same attitudes as NaN between fixes, to 0.05°.

    Repeats carry no news: differencing them row by row would give v̇ = 0 on
    19 rows of 20 and a 20× spike on the change.  The only difference is
    when the acceleration stops: an unchanged held value is taken as a new
    fix after 1.5 fix periods instead of 1, and at rest (no change yet to
    learn the fix period from) only after ``velocity_max_age_s``: the first
    difference after the start is then up to 10× too small.  Hence 0.5°.
    """
    rows, q = _accelerating_north("nan")
    incl_nan = _inclination_deg(rows, q)
    incl_held = _inclination_deg(_accelerating_north("held")[0], q)
    assert np.max(np.abs(incl_held - incl_nan)) < 0.5
    assert np.max(incl_held) < 1.0


def test_losing_the_fix_fades_the_compensation_out() -> None:
    """GNSS lost at 20 s, mid-acceleration: compensation held for ``velocity_max_age_s``, then faded out.

    One second after the loss the tilt is still right (the last v̇ is still
    valid); five seconds after it the filter is on its way to the
    uncompensated specific force (17° off), as it must: ≈ 1.9° then (the
    manoeuvre weight, ‖f̄‖ beyond 3 % of g, slows it down; 2.7° at 5 %).
    """
    rows, q = _accelerating_north("nan")
    lost = int(20 * RATE_HZ)
    rows[lost:, IN_VEL : IN_VEL + 3] = np.nan
    incl = _inclination_deg(rows, q)
    assert incl[lost - 1] < 0.3
    assert incl[lost + int(1.0 * RATE_HZ)] < 0.3
    assert incl[lost + int(5.0 * RATE_HZ)] > 1.5


def test_compensation_kernel_starts_in_full_then_fades_out_and_in_linearly() -> None:
    """``gnss_compensation_step``: the first valid v̇ after a reset applies in full; later losses fade.

    Velocity fixes every 0.1 s (NaN between) of a 2 m/s² north acceleration
    for 5 s, none for 2 s, then fixes again for 3 s: the output is 2 m/s² from
    the second fix on (nothing to keep from jumping after a reset), holds while
    the last fix is younger than ``max_age_s``, then falls by exactly
    2·dt/fade_s per row to 0; when the fixes come back it rises by the same
    step per row from the second new fix on.
    """
    from mavahrs.filters.gnss import (
        GC_LEN,
        gnss_compensation_fresh,
        gnss_compensation_reset,
        gnss_compensation_step,
    )
    from mavahrs.filters.jit import pure_python

    # the interpreted kernels (the compiled ones are inlined into the steps; compiling standalone
    # copies just for this test would cost seconds on a cold cache; both agree: test_contract)
    gnss_compensation_reset = pure_python(gnss_compensation_reset)
    gnss_compensation_step = pure_python(gnss_compensation_step)
    gnss_compensation_fresh = pure_python(gnss_compensation_fresh)
    dt, fade, max_age = 0.01, 0.5, 0.305  # the chain breaks 31 rows after the last fix
    s = np.zeros(GC_LEN)
    gnss_compensation_reset(s, 0)
    n = 1000
    out = np.zeros(n)
    fresh = np.zeros(n, dtype=bool)
    for i in range(n):
        t = i * dt
        v = 2.0 * t if (i % 10 == 0 and (t < 5.0 or t >= 7.0)) else math.nan
        out[i] = gnss_compensation_step(s, 0, v, 0.0, 0.0, dt, 0.0, max_age, fade)[0]
        fresh[i] = gnss_compensation_fresh(s, 0)
    assert np.all(out[:10] == 0.0) and np.all(fresh[:10])  # one fix: no difference yet
    first = 10  # the second fix gives v̇ = 2, in full at once
    assert not fresh[first:].any()
    np.testing.assert_allclose(out[first:490], 2.0, rtol=1e-9)
    last_fix = 490
    start_fade = last_fix + 31
    np.testing.assert_allclose(out[last_fix:start_fade], 2.0, rtol=1e-9)
    fading = out[start_fade - 1 : start_fade + int(fade / dt)]
    np.testing.assert_allclose(np.diff(fading), -2.0 * dt / fade, rtol=1e-6, atol=1e-12)
    assert np.all(out[start_fade + int(fade / dt) : 710] == 0.0)
    again = 710  # fixes from row 700 on: the second gives v̇ again, and the weight ramps up
    ramp = out[again : again + int(fade / dt)]
    np.testing.assert_allclose(np.diff(ramp), 2.0 * dt / fade, rtol=1e-9)
    np.testing.assert_allclose(out[again + int(fade / dt) :], 2.0, rtol=1e-9)
