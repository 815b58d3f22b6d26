"""PX4's EKF2 gyro bias taken back out of HIGHRES_IMU with SCALED_IMU (mavahrs.ingest.autopilot_bias).

A synthetic PX4 (HEARTBEAT autopilot 12) sends, for a known trajectory, the sensor's gyro (truth plus
a constant sensor bias) as SCALED_IMU (mrad/s, ``time_boot_ms`` = publication time truncated) and the
same samples less a known "EKF2" bias estimate as HIGHRES_IMU, as PX4's streams do.  The filter's
input rows must carry the sensor's gyro again — whichever way the two streams interleave, with a
bias reset, and not when SCALED_IMU is absent, stops, or carries garbage.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mavahrs.filters.layout import IN_GYRO
from mavahrs.ingest.autopilot_bias import AutopilotBiasSettings
from mavahrs.protocol.codec import MavCodec
from mavahrs.service.pipeline import Pipeline, PipelineSettings

G = 9.80665
SENSOR_BIAS = np.array([0.012, -0.021, 0.034])  # rad/s: what the gyro itself adds to the truth
EKF_BIAS = np.array([0.010, -0.018, 0.030])  # rad/s: EKF2's estimate, subtracted in HIGHRES_IMU
RESET_S = 10.0  # EKF2 resets its bias estimate to 0 here (in the tests that say so)
PUBLISH_US = 300  # vehicle_imu is published this long after its sample time


def _frames(ap, traj, *, scaled: str = "after", scaled_stop_s: float | None = None, reset: bool = False,
            nan_scaled_at: tuple[int, ...] = (), every: int = 8):  # fmt: skip
    """(now_us, frame) pairs: HEARTBEAT, HIGHRES_IMU at 400 Hz and SCALED_IMU at 50 Hz (every 8th sample).

    ``scaled``: ``after`` (its HIGHRES_IMU first, as on the PX4 SIH tlog), ``before`` (SCALED_IMU first)
    or ``late`` (20 ms after its HIGHRES_IMU).  Returns the frames and the sensor's gyro per sample.
    """
    c = ap.codec
    frames = [(int(traj.t_us[0]) - 10_000, ap.heartbeat())]
    sensor = traj.gyro_rad_s + SENSOR_BIAS
    t0 = int(traj.t_us[0])
    for k in range(len(traj.t_us)):
        t = int(traj.t_us[k])
        if k % 400 == 0 and k:
            frames.append((t, ap.heartbeat()))
        ekf = EKF_BIAS if not (reset and t - t0 >= RESET_S * 1e6) else np.zeros(3)
        hr = ap.highres_imu(t, traj.accel_m_s2[k], sensor[k] - ekf, [0.2, 0.0, 0.45])
        now = t + 3000
        items = [(now, hr)]
        if k % every == 0 and (scaled_stop_s is None or t - t0 < scaled_stop_s * 1e6):
            acc = [int(round(x)) for x in traj.accel_m_s2[k] / G * 1000.0]
            gy = [int(x * 1000.0) for x in sensor[k]]  # PX4 casts: truncated toward zero
            if k in nan_scaled_at:
                gy = [32767, 32767, 32767]  # saturated: no pair
            sc = c.encode(c.mav.scaled_imu_encode((t + PUBLISH_US) // 1000, *acc, *gy, 200, 0, 450, 0))
            lag = {"after": 1, "before": -1, "late": 20_000}[scaled]
            items.append((now + lag, sc))
        frames.extend(sorted(items, key=lambda x: x[0]))
    return frames, sensor


def _run(frames, **kw):
    """The pipeline (PX4 profile from the HEARTBEAT) on the frames; the gyro of every row the filter got."""
    pipe = Pipeline(PipelineSettings(filter_name="mahony", out_rate_hz=0.0, **kw))
    rows: list[tuple[int, np.ndarray]] = []
    pipe.sample_hook = lambda name, t, row, out: rows.append((t, row[IN_GYRO : IN_GYRO + 3].copy()))
    rx = MavCodec(0, 0)
    for now, data in frames:
        for msg in rx.receive_datagram(data):
            pipe.handle(msg, now)
    t = np.array([r[0] for r in rows])
    return pipe, t, np.array([r[1] for r in rows])


def _sensor_at(traj, sensor, t):
    return sensor[np.searchsorted(traj.t_us, t)]


@pytest.mark.parametrize("order", ["after", "before", "late"])
def test_highres_imu_gets_the_sensors_gyro_back_whichever_way_the_streams_interleave(trajectory, make_autopilot,
                                                                                      order) -> None:  # fmt: skip
    ap = make_autopilot(1, 1, autopilot=12)
    frames, sensor = _frames(ap, trajectory, scaled=order)
    pipe, t, gyro = _run(frames)
    assert len(t) == len(trajectory.t_us)  # every HIGHRES_IMU fed, no SCALED_IMU (it served the bias step)
    err = np.abs(gyro - _sensor_at(trajectory, sensor, t))
    settled = t - t[0] >= 1.0e6  # 25 pairs at 50 Hz, plus the late order's 20 ms
    # SCALED_IMU's 1 mrad/s steps (truncated; their middle taken): within 0.6 mrad/s (EKF2's bias: 10–30)
    assert err[settled].max() < 0.6e-3, err[settled].max(axis=0)
    c = pipe.status().counters
    assert c["autopilot_bias_pairs"] >= 0.95 * len(t) / 8 and c["autopilot_bias_unpaired"] <= 2
    assert c["autopilot_bias_applied"] >= 0.9 * len(t) and c["bias_twin_samples"] >= 0.95 * len(t) / 8


def test_without_scaled_imu_highres_imu_is_fed_exactly_as_before(trajectory, make_autopilot) -> None:
    ap = make_autopilot(1, 1, autopilot=12)
    frames_no_scaled, _ = _frames(ap, trajectory, scaled_stop_s=-1.0)
    _, t_on, g_on = _run(frames_no_scaled)
    _, t_off, g_off = _run(frames_no_scaled, autopilot_bias=AutopilotBiasSettings(enabled=False))
    assert np.array_equal(t_on, t_off) and np.array_equal(g_on, g_off)


def test_scaled_imu_stopping_holds_the_bias_then_leaves_highres_imu_as_it_comes(trajectory, make_autopilot) -> None:
    ap = make_autopilot(1, 1, autopilot=12)
    frames, sensor = _frames(ap, trajectory, scaled_stop_s=6.0)
    pipe, t, gyro = _run(frames)
    rel_s = (t - t[0]) / 1e6
    truth = _sensor_at(trajectory, sensor, t)
    held = (rel_s >= 1.0) & (rel_s < 6.0 + 4.9)  # the mean is held for hold_s (5 s) after the last pair
    assert np.abs(gyro[held] - truth[held]).max() < 0.6e-3
    after = rel_s > 6.0 + 5.1
    assert np.abs(gyro[after] - (truth[after] - EKF_BIAS)).max() < 1e-6  # as sent (float32): nothing added
    assert pipe.status().counters["autopilot_bias_not_applied"] >= after.sum()


def test_an_ekf2_bias_reset_restarts_the_mean_and_garbage_is_counted_not_used(trajectory, make_autopilot) -> None:
    ap = make_autopilot(1, 1, autopilot=12)
    frames, sensor = _frames(ap, trajectory, reset=True, nan_scaled_at=(800, 808, 4000))
    pipe, t, gyro = _run(frames)
    rel_s = (t - t[0]) / 1e6
    err = np.abs(gyro - _sensor_at(trajectory, sensor, t))
    assert np.isfinite(gyro).all()
    assert err[(rel_s >= 1.0) & (rel_s < RESET_S)].max() < 0.6e-3
    # after the reset the sensor's gyro again: the step is found from 25 outliers in a row (0.5 s), the new
    # mean trusted after 25 pairs (0.5 s); in between at most the step itself
    assert err[(rel_s >= RESET_S) & (rel_s < RESET_S + 1.2)].max() < np.abs(EKF_BIAS).max() + 1.0e-3
    assert err[rel_s >= RESET_S + 1.2].max() < 0.6e-3
    c = pipe.status().counters
    assert c["autopilot_bias_restarts"] == 1 and c["autopilot_bias_bad_values"] == 3
    assert c["autopilot_bias_outliers"] >= 25


def test_the_px4_profile_asks_for_scaled_imu_and_no_other_profile_does(make_autopilot) -> None:
    for autopilot, wanted in ((12, True), (3, False)):
        ap = make_autopilot(1, 1, autopilot=autopilot)
        pipe = Pipeline(PipelineSettings(filter_name="mahony"))
        rx = MavCodec(0, 0)
        for msg in rx.receive_datagram(ap.heartbeat()):
            pipe.handle(msg, 0)
        ids = set()
        for now in range(0, 5_000_000, 50_000):  # each request acknowledged (the requester asks one at a time)
            for o in pipe.tick(now):
                for m in rx.receive_datagram(o.frame):
                    if m.get_type() == "COMMAND_LONG" and int(m.command) == 511:  # MAV_CMD_SET_MESSAGE_INTERVAL
                        ids.add((int(m.param1), m.param2))
                        for ack in rx.receive_datagram(ap.command_ack(0)):
                            pipe.handle(ack, now + 1000)
        assert ((26, 20_000.0) in ids) == wanted, ids  # SCALED_IMU at 50 Hz


def test_replay_over_arrays_adds_back_the_same_bias_as_the_pipeline(shared_data: Path) -> None:
    """The PX4 SIH tlog: the compiled loop over the log (``prepare_inputs``) and the pipeline message by
    message feed the same gyro, and that gyro is HIGHRES_IMU plus SCALED_IMU − HIGHRES_IMU's mean."""
    from mavahrs.evaluation.tlogdata import prepare_inputs, read_tlog_data, run_pipelines

    path = shared_data / "px4_sitl" / "px4_aggressive.tlog"
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data/px4_sitl beside the checkout)")
    td = read_tlog_data(path)
    s = PipelineSettings()
    arrays = prepare_inputs(td, s, end_s=40.0)
    piped = run_pipelines(td, s, [("complementary", None)], start_s=None, end_s=40.0, decimal_year=None)[0]
    assert np.array_equal(arrays.t_us, piped.t_us)
    assert np.array_equal(arrays.rows[:, IN_GYRO : IN_GYRO + 3], piped.rows[:, IN_GYRO : IN_GYRO + 3])
    as_sent = prepare_inputs(td, PipelineSettings(autopilot_bias=AutopilotBiasSettings(enabled=False)), end_s=40.0)
    added = arrays.rows[:, IN_GYRO : IN_GYRO + 3] - as_sent.rows[:, IN_GYRO : IN_GYRO + 3]
    late = (arrays.t_us - arrays.t_us[0]) > 5e6
    # EKF2's gyro bias on that flight: a few 0.1 mrad/s to 1.5 mrad/s (docs/accuracy.md round five), never 0
    assert 0.0 < np.abs(added[late]).max() < 5e-3 and math.isfinite(float(np.abs(added).sum()))


@pytest.mark.slow
def test_the_daemons_path_against_firmware_sims_px4_pairs_scaled_imu_and_changes_nothing_there() -> None:
    """firmware_sim's PX4 sends HIGHRES_IMU without any EKF bias subtracted: the pipeline asks for SCALED_IMU,
    pairs it with HIGHRES_IMU (the same samples, SCALED_IMU sent later and truncated to mrad/s), recovers a bias
    of ≈ 0, feeds HIGHRES_IMU alone, and the attitude is the one without the step."""
    fs = pytest.importorskip("firmware_sim")
    from tests.service.test_pipeline import _fly_sim, _tilt_errors_deg

    sim = fs.SimSettings(scenario="hover", seed=4).for_autopilot("px4")  # vehicle_imu's interval mean, as PX4
    ep = fs.EndpointSettings(autopilot="px4", streams_hz=(("SIMSTATE", 50.0),))
    runs = {}
    for on in (True, False):
        fed: list = []
        ps = PipelineSettings(filter_name="best", out_rate_hz=50.0, autopilot_bias=AutopilotBiasSettings(enabled=on))
        pipe, _, att, truth, now = _fly_sim(20.0, sim, ep, ps, fed=fed)
        runs[on] = (pipe, fed, np.sqrt(np.mean(_tilt_errors_deg(att, truth, after_ms=5000) ** 2)))
    pipe, fed, tilt_on = runs[True]
    c = pipe.status().counters
    assert c["autopilot_bias_pairs"] > 40 * 12  # SCALED_IMU at 50 Hz for most of the 20 s
    assert c["autopilot_bias_unpaired"] + c["autopilot_bias_outliers"] <= 0.01 * c["autopilot_bias_pairs"]
    assert {name for name, _ in fed} == {"HIGHRES_IMU"}
    b = pipe._ab.bias_rad_s
    assert b is not None and max(abs(x) for x in b) < 0.3e-3  # no EKF bias in the simulator's HIGHRES_IMU
    assert abs(tilt_on - runs[False][2]) < 0.05, (tilt_on, runs[False][2])


def test_scaled_imu_at_a_low_rate_is_used_once_it_has_made_enough_pairs(trajectory, make_autopilot) -> None:
    """SCALED_IMU at 2 Hz: HIGHRES_IMU passes as sent until 25 pairs (12.5 s), then gets the sensor's gyro back."""
    ap = make_autopilot(1, 1, autopilot=12)
    frames, sensor = _frames(ap, trajectory, every=200)
    pipe, t, gyro = _run(frames)
    rel_s = (t - t[0]) / 1e6
    truth = _sensor_at(trajectory, sensor, t)
    before = rel_s < 11.9
    assert np.abs(gyro[before] - (truth[before] - EKF_BIAS)).max() < 1e-6
    after = rel_s >= 12.5
    assert np.abs(gyro[after] - truth[after]).max() < 0.6e-3
    assert len(t) == len(trajectory.t_us)  # SCALED_IMU never fed: it served the step from its first sample


def test_replay_of_a_px4_stream_with_scaled_imu_alone_starts_as_the_daemon_does(tmp_path: Path, sim_tlog_writer) -> None:
    """firmware_sim's PX4 streaming SCALED_IMU at 50 Hz and no HIGHRES_IMU: the daemon's pipeline lets SCALED_IMU
    serve the bias step alone for its first second (it waits for HIGHRES_IMU) and then feeds it; the compiled loop
    over the log (``prepare_inputs``) must feed the same samples.  Before px4h7 it skipped the step when the log had
    no HIGHRES_IMU and fed that first second too (6000 against the daemon's 5949 samples over 120 s: best's heading
    1.23 against 1.17° on aggressive 1, the two scores of one flight disagreeing)."""
    from mavahrs.evaluation.tlogdata import prepare_inputs, read_tlog_data, run_pipelines

    path = sim_tlog_writer(tmp_path / "px4_scaled_only.tlog", "--autopilot", "px4", "--scenario", "hover", "--seed", "3",
                           "--duration", "6", "--stream", "SCALED_IMU=50", "--stream", "HIGHRES_IMU=0")  # fmt: skip
    td = read_tlog_data(path)
    s = PipelineSettings()
    arrays = prepare_inputs(td, s)
    piped = run_pipelines(td, s, [("complementary", None)], start_s=None, end_s=None, decimal_year=None)[0]
    # the stream's samples: 50 Hz for 6 s, the first second (51 stamps, both ends in) serving only the bias step
    assert 240 <= piped.t_us.shape[0] <= 255, piped.t_us.shape
    assert np.array_equal(arrays.t_us, piped.t_us)
    assert np.array_equal(arrays.rows[:, IN_GYRO : IN_GYRO + 3], piped.rows[:, IN_GYRO : IN_GYRO + 3])
