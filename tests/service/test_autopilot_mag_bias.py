"""PX4's EKF2 magnetometer bias taken back out of HIGHRES_IMU with SCALED_IMU and CAL_MAG* (ingest.autopilot_mag_bias).

A synthetic PX4 (HEARTBEAT autopilot 12) answers PARAM_REQUEST_READ with a known, non-identity compass
calibration and sends, for a known trajectory, the compass's raw readings (100 Hz; the calibration's inverse of
the true body field) as SCALED_IMU at 50 Hz (the latest reading, milligauss truncated toward zero, as
``streams/SCALED_IMU.hpp``), and HIGHRES_IMU at 400 Hz whose field, updated at ≈ 14 Hz, is the mean of the
calibrated readings since the previous update less a known "EKF2" bias (``vehicle_magnetometer`` −
``mag_bias``).  The filter's input rows must carry the calibrated field without EKF2's bias — and the field as
sent where the calibration is unknown, ambiguous or the twin stream carries garbage.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from mavahrs.filters.layout import IN_MAG
from mavahrs.ingest.autopilot_bias import AutopilotBiasSettings
from mavahrs.protocol.codec import MavCodec
from mavahrs.sensors.px4_mag_calibration import mag_calibration, missing_names, param_value
from mavahrs.service.pipeline import Pipeline, PipelineSettings

EKF_MAG_BIAS_UT = np.array([1.5, -2.5, 0.8])  # EKF2's estimate, subtracted from HIGHRES_IMU's field
OFF_GAUSS = np.array([0.06, -0.04, 0.03])  # CAL_MAG0_XOFF… (hard iron)
SCALE = np.array([[1.05, 0.02, -0.01], [0.02, 0.96, 0.015], [-0.01, 0.015, 1.02]])  # CAL_MAG0_*SCALE, *ODIAG
RESET_S = 10.0
#: EKF2's estimate after a reset at RESET_S: a step beyond the outlier gate (10 µT), which restarts the mean
#: (a step within it the mean follows with its τ)
EKF_MAG_BIAS_STEP_UT = np.array([1.5, 12.0, 0.8])


def _params(**over: float) -> dict[str, tuple[float, int]]:
    """name → (value, MAV_PARAM_TYPE) of a PX4 with one calibrated internal compass."""
    p: dict[str, tuple[float, int]] = {
        "CAL_MAG0_ID": (197388, 6), "CAL_MAG0_ROT": (-1, 6), "CAL_MAG1_ID": (0, 6), "CAL_MAG2_ID": (0, 6),
        "CAL_MAG3_ID": (0, 6), "CAL_MAG_COMP_TYP": (0, 6), "SENS_BOARD_ROT": (0, 6),
        "SENS_BOARD_X_OFF": (0.0, 9), "SENS_BOARD_Y_OFF": (0.0, 9), "SENS_BOARD_Z_OFF": (0.0, 9),
    }  # fmt: skip
    for i, ax in enumerate("XYZ"):
        p[f"CAL_MAG0_{ax}OFF"] = (float(OFF_GAUSS[i]), 9)
        p[f"CAL_MAG0_{ax}SCALE"] = (float(SCALE[i, i]), 9)
    p["CAL_MAG0_XODIAG"], p["CAL_MAG0_YODIAG"], p["CAL_MAG0_ZODIAG"] = (SCALE[0, 1], 9), (SCALE[0, 2], 9), (SCALE[1, 2], 9)
    for k, v in over.items():
        p[k] = (v, 6 if k.endswith(("_ID", "_ROT", "_TYP")) else 9)
    return p


def _param_frame(ap, name: str, value: float, ptype: int) -> bytes:
    if ptype == 6:  # PX4 sends an integer's bytes in the float
        value = struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return ap.codec.encode(ap.codec.mav.param_value_encode(name.encode(), value, ptype, 900, 0))


def _frames(ap, traj, *, params: dict | None, reset: bool = False, garbage_every: int = 0):
    """(now_us, frame, kind) in arrival order; ``params`` answered after 1 s (None: never)."""
    c = ap.codec
    t0 = int(traj.t_us[0])
    raw = (np.linalg.inv(SCALE) @ traj.mag_ut.T).T + OFF_GAUSS * 100.0  # what the compass reads, µT
    out = [(t0 - 10_000, ap.heartbeat())]
    if params is not None:
        out += [(t0 + 1_000_000 + 100 * i, _param_frame(ap, n, *vt)) for i, (n, vt) in enumerate(sorted(params.items()))]
    since: list[np.ndarray] = []
    latest = raw[0]
    n_scaled = 0
    for k in range(len(traj.t_us)):
        t = int(traj.t_us[k])
        if k % 400 == 0 and k:
            out.append((t, ap.heartbeat()))
        if k % 4 == 0:  # a compass reading (100 Hz): calibrated into vehicle_magnetometer's mean
            latest = raw[k]
            since.append(traj.mag_ut[k])
        fields = 0x3F
        mag = [0.0, 0.0, 0.0]
        if k % 28 == 27:  # vehicle_magnetometer published (≈ 14 Hz): HIGHRES_IMU's field, less EKF2's bias
            ekf = EKF_MAG_BIAS_UT if not (reset and t - t0 >= RESET_S * 1e6) else EKF_MAG_BIAS_STEP_UT
            mag = list((np.mean(since, axis=0) - ekf) / 100.0)
            since = []
            fields |= 0x1C0
        out.append((t + 3000, ap.highres_imu(t, traj.accel_m_s2[k], traj.gyro_rad_s[k], mag, fields)))
        if k % 8 == 4:  # SCALED_IMU at 50 Hz: the latest raw reading, milligauss truncated toward zero
            n_scaled += 1
            mg = [int(x * 10.0) for x in latest]
            if garbage_every and n_scaled % garbage_every == 0:
                mg = [32767, -32768, 32767]
            gy = [int(x * 1000.0) for x in traj.gyro_rad_s[k]]
            acc = [int(round(x)) for x in traj.accel_m_s2[k] / 9.80665 * 1000.0]
            out.append((t + 3001, c.encode(c.mav.scaled_imu_encode((t + 300) // 1000, *acc, *gy, *mg, 0))))
    return sorted(out, key=lambda x: x[0])


def _run(ap, frames, **kw):
    """The pipeline on the frames (its ticks every 50 ms); the field of every row the filter got, and what it sent."""
    pipe = Pipeline(PipelineSettings(filter_name="mahony", out_rate_hz=0.0, **kw))
    rows: list[tuple[int, np.ndarray]] = []
    pipe.sample_hook = lambda name, t, row, out: rows.append((t, row[IN_MAG : IN_MAG + 3].copy()))
    rx = MavCodec(0, 0)
    sent: list = []
    next_tick = frames[0][0]
    for now, data in frames:
        while now >= next_tick:
            for o in pipe.tick(next_tick):
                sent += [(next_tick, m) for m in rx.receive_datagram(o.frame)]
            next_tick += 50_000
        for msg in rx.receive_datagram(data):
            pipe.handle(msg, now)
    t = np.array([r[0] for r in rows])
    m = np.array([r[1] for r in rows])
    new = np.isfinite(m[:, 0])
    return pipe, t[new], m[new], sent


def _truth_mean_field(traj, t_us):
    """The calibrated field HIGHRES_IMU's update at ``t_us`` averaged (without EKF2's bias)."""
    out = []
    for t in t_us:
        k = int(np.searchsorted(traj.t_us, t))
        lo = k - 27
        out.append(traj.mag_ut[[j for j in range(lo, k + 1) if j % 4 == 0]].mean(axis=0))
    return np.array(out)


def test_highres_imus_field_gets_ekf2s_mag_bias_taken_back_out(trajectory, make_autopilot) -> None:
    ap = make_autopilot(1, 1, autopilot=12)
    pipe, t, mag, sent = _run(ap, _frames(ap, trajectory, params=_params()))
    truth = _truth_mean_field(trajectory, t)
    rel = (t - int(trajectory.t_us[0])) / 1e6  # the stream's clock (HIGHRES_IMU's first field comes 68 ms in)
    early = rel < 0.9  # before the calibration arrived: as sent
    assert np.abs(mag[early] - (truth[early] - EKF_MAG_BIAS_UT)).max() < 1e-4
    late = rel > 5.0
    err = mag[late] - truth[late]
    assert np.abs(err.mean(axis=0)).max() < 0.1, err.mean(axis=0)  # EKF2's 1.5 / −2.5 / 0.8 µT gone
    assert np.abs(err).max() < 0.4
    c = pipe.status().counters
    assert c["autopilot_mag_bias_pairs"] > 200 and c["autopilot_mag_bias_outliers"] == 0
    asked = {m.param_id for _, m in sent if m.get_type() == "PARAM_REQUEST_READ"}
    assert {"CAL_MAG0_ID", "CAL_MAG_COMP_TYP", "SENS_BOARD_ROT"} <= asked
    # answered after 1 s: no request after that (the ticks every 50 ms would otherwise ask once a second)
    assert max(now for now, m in sent if m.get_type() == "PARAM_REQUEST_READ") < int(trajectory.t_us[0]) + 1_100_000


def test_without_the_calibration_highres_imus_field_is_fed_as_sent_and_the_requests_stop(trajectory, make_autopilot) -> None:
    ap = make_autopilot(1, 1, autopilot=12)
    pipe, t, mag, sent = _run(ap, _frames(ap, trajectory, params=None))
    truth = _truth_mean_field(trajectory, t)
    assert np.abs(mag - (truth - EKF_MAG_BIAS_UT)).max() < 1e-4
    rounds = {now for now, m in sent if m.get_type() == "PARAM_REQUEST_READ"}
    assert len(rounds) == 10  # once a second, ten times, then said once
    assert pipe.status().counters["autopilot_mag_bias_applied"] == 0


@pytest.mark.parametrize(
    "over",
    [
        {"CAL_MAG1_ID": 197644, "CAL_MAG1_XOFF": 0.0},  # a second compass calibrated differently: which is SCALED_IMU's?
        {"CAL_MAG0_ROT": 2},  # an external compass rotated by yaw 90°: not modelled
        {"SENS_BOARD_ROT": 4},  # the board rotated: not modelled
        {"CAL_MAG_COMP_TYP": 2},  # power compensation: not modelled
    ],
)
def test_a_calibration_the_step_cannot_apply_leaves_the_field_as_sent(trajectory, make_autopilot, over) -> None:
    ap = make_autopilot(1, 1, autopilot=12)
    p = _params(**over)
    if "CAL_MAG1_ID" in over:  # the second slot's other values as the first's
        for k, v in _params().items():
            if k.startswith("CAL_MAG0_") and k not in ("CAL_MAG0_ID", "CAL_MAG0_XOFF"):
                p.setdefault(k.replace("CAL_MAG0_", "CAL_MAG1_"), v)
    pipe, t, mag, _ = _run(ap, _frames(ap, trajectory, params=p))
    truth = _truth_mean_field(trajectory, t)
    assert np.abs(mag - (truth - EKF_MAG_BIAS_UT)).max() < 1e-4
    assert pipe.status().counters["autopilot_mag_bias_uncalibrated"] > 0
    assert any("not modelled" in text or "not known" in text for _, text in pipe.drain_notices())


def test_garbage_is_counted_not_used_and_an_ekf2_reset_restarts_the_mean(trajectory, make_autopilot) -> None:
    ap = make_autopilot(1, 1, autopilot=12)
    pipe, t, mag, _ = _run(ap, _frames(ap, trajectory, params=_params(), reset=True, garbage_every=7))
    truth = _truth_mean_field(trajectory, t)
    rel = (t - int(trajectory.t_us[0])) / 1e6  # the stream's clock (HIGHRES_IMU's first field comes 68 ms in)
    for lo, hi in ((5.0, RESET_S), (RESET_S + 6.0, 20.0)):  # settled before and after EKF2's step (+/− its bias)
        w = (rel > lo) & (rel < hi)
        assert np.abs((mag[w] - truth[w]).mean(axis=0)).max() < 0.15
    c = pipe.status().counters
    assert c["autopilot_mag_bias_outliers"] > 0 and c["autopilot_mag_bias_restarts"] >= 1


def test_px4s_calibration_from_its_parameters() -> None:
    """PX4's ``R·S·(m − o)``: the matrix and offset as CAL_MAG0_* give them, integers decoded byte-wise."""
    p = {k: param_value(struct.unpack("<f", struct.pack("<i", int(v)))[0], t) if t == 6 else v for k, (v, t) in _params().items()}
    assert p["CAL_MAG0_ROT"] == -1 and p["CAL_MAG0_ID"] == 197388
    cal, reason = mag_calibration(p)
    assert cal is not None, reason
    raw = np.array([30.0, -12.0, 41.0])
    assert np.allclose(cal[3:].reshape(3, 3) @ (raw - cal[:3]), SCALE @ (raw - OFF_GAUSS * 100.0))
    del p["CAL_MAG0_YSCALE"]
    assert mag_calibration(p)[0] is None and missing_names(p) == ["CAL_MAG0_YSCALE"]


def test_replay_over_arrays_takes_out_the_same_mag_bias_as_the_pipeline(shared_data: Path) -> None:
    """The PX4 SIH tlog (its ground station's parameter list carries CAL_MAG*): the compiled loop over the log and
    the pipeline message by message feed the same field, and that field differs from HIGHRES_IMU's by EKF2's bias
    (≈ 1.3 µT on y at 40 s on that flight: docs/accuracy.md, round eight)."""
    from mavahrs.evaluation.tlogdata import prepare_inputs, read_tlog_data, run_pipelines

    path = shared_data / "px4_sitl" / "px4_aggressive.tlog"
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data/px4_sitl beside the checkout)")
    td = read_tlog_data(path)
    s = PipelineSettings()
    arrays = prepare_inputs(td, s, end_s=50.0)
    piped = run_pipelines(td, s, [("complementary", None)], start_s=None, end_s=50.0, decimal_year=None)[0]
    assert np.array_equal(arrays.t_us, piped.t_us)
    a, b = arrays.rows[:, IN_MAG : IN_MAG + 3], piped.rows[:, IN_MAG : IN_MAG + 3]
    assert np.array_equal(np.isnan(a), np.isnan(b)) and np.nanmax(np.abs(a - b)) == 0.0
    as_sent = prepare_inputs(td, PipelineSettings(autopilot_bias=AutopilotBiasSettings(mag_enabled=False)), end_s=50.0)
    added = a - as_sent.rows[:, IN_MAG : IN_MAG + 3]
    rel = (arrays.t_us - arrays.t_us[0]) / 1e6
    w = (rel > 36.0) & (rel < 44.0) & np.isfinite(added[:, 1])
    assert 0.7 < float(np.mean(added[w, 1])) < 2.5  # EKF2's y bias there: 1.2–1.5 µT
