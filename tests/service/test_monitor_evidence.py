"""Who is likely wrong: the evidence the monitor attaches to a WARNING (magnetometer, GNSS velocity, our
confidence), on a synthetic flight whose truth is known, and on real ArduCopter SITL flights through
``mavahrs audit``'s path (faults injected in the autopilot's attitude with ``inject-fault``)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mavahrs.geometry.quaternion import conjugate, from_axis_angle, multiply, rotate
from mavahrs.geometry.rotation import from_euler_rad
from mavahrs.protocol.codec import mavlink
from mavahrs.service.monitor import (
    WARNING_TEXT,
    AttitudeMonitor,
    Evidence,
    MonitorSensors,
    MonitorSettings,
    monitor_series,
)

G = np.array([0.0, 0.0, 9.80665])
B_STRENGTH_UT, B_DIP_RAD = 50.0, math.radians(60.0)
B_NED = B_STRENGTH_UT * np.array([math.cos(B_DIP_RAD), 0.0, math.sin(B_DIP_RAD)])
ONSET_S = 30.0


def _flight(fault_on: str, mag_scale: float = 1.0, vel: bool = True) -> tuple:
    """60 s of manoeuvring (horizontal accelerations of ±3 m/s², yaw turning): estimates at 100 Hz, the
    autopilot at 50 Hz, GNSS velocity at 10 Hz.  A 2° earth-frame tilt step from 30 s on ``fault_on``
    (``ap`` / ``us`` / ``none``).  Returns monitor_series' arguments."""
    t = np.arange(0.0, 60.0, 0.01)
    a_ne = np.stack([3.0 * np.sin(0.6 * t), 3.0 * np.cos(0.45 * t), np.zeros_like(t)], axis=1)
    v_ne = np.stack([-3.0 / 0.6 * np.cos(0.6 * t), 3.0 / 0.45 * np.sin(0.45 * t)], axis=1)
    roll = np.arcsin(np.clip(a_ne[:, 1] / 9.8, -1, 1)) * 0.8
    pitch = -np.arcsin(np.clip(a_ne[:, 0] / 9.8, -1, 1)) * 0.8
    q_true = from_euler_rad(roll, pitch, 0.2 * t)
    f_body = rotate(conjugate(q_true), a_ne - G)
    m_body = mag_scale * rotate(conjugate(q_true), np.broadcast_to(B_NED, (len(t), 3)))
    fault = from_axis_angle([1.0, 0.0, 0.0], math.radians(2.0))
    q_faulted = q_true.copy()
    late = t >= ONSET_S
    q_faulted[late] = multiply(fault, q_true[late])
    q_est = q_faulted if fault_on == "us" else q_true
    q_ap_all = q_faulted if fault_on == "ap" else q_true
    t_ms = 1000.0 * t
    fix = (np.floor(t * 10.0) / 10.0)  # the 10 Hz fix each sample carries
    vel_fix = np.stack([-3.0 / 0.6 * np.cos(0.6 * fix), 3.0 / 0.45 * np.sin(0.45 * fix)], axis=1)
    assert np.allclose(vel_fix[::10], v_ne[::10])
    sensors = MonitorSensors(f_body, m_body, vel_fix if vel else None, 1000.0 * fix if vel else None,
                             mag_reference=[(0.0, B_STRENGTH_UT, B_DIP_RAD)])
    sigma = np.full(len(t), math.radians(0.3))
    return t_ms, q_est, t_ms[::2] + 5.0, q_ap_all[::2], sigma, sensors


def _warnings(fault_on: str, **kw: object) -> list:
    """The in-flight WARNING, then the same said again as new evidence comes (at most within 5 s): the last."""
    t_ms, q_est, t_ap, q_ap, sigma, sensors = _flight(fault_on, **kw)  # type: ignore[arg-type]
    res = monitor_series(t_ms, q_est, t_ap, q_ap, MonitorSettings(), tilt_sigma_rad=sigma, sensors=sensors)
    warns = [e for e in res.events if e.in_flight]
    if not warns:
        return []
    assert len(warns) == 1, res.events
    assert ONSET_S < warns[0].t_ms / 1000.0 < ONSET_S + 2.0
    said = [e for e in res.events if e.severity == mavlink.MAV_SEVERITY_WARNING]
    assert said[0] is warns[0] and all(e.update for e in said[1:])
    assert said[-1].t_ms - warns[0].t_ms < 5000.0
    return [said[-1]]


def test_gnss_velocity_says_the_autopilot_is_wrong() -> None:
    (w,) = _warnings("ap")
    ev = w.evidence
    assert ev is not None and ev.gnss_verdict == "AP" and ev.cause == "AP?", ev
    # 2° of tilt: g·sin 2° ≈ 0.34 m/s² of false acceleration, 1 m/s over a whole 3 s window; the verdict comes as
    # soon as the windows since the onset hold the verdict's least difference (the change test warns 0.25 s
    # after the onset, and the verdict is said again 1 s later at 0.43 m/s; 0.57 m/s without the change test)
    assert ev.gnss_blames_us < 0.2 and MonitorSettings().gnss_min_m_s <= ev.gnss_m_s < 1.2
    assert not ev.mag_disturbed and abs(ev.mag_norm_dev) < 0.01 and abs(ev.mag_dip_dev_deg) < 0.5
    assert ev.tilt_sigma_deg == pytest.approx(0.3)
    assert w.text.endswith(" [AP?]") and len(w.text.encode()) <= 50


def test_gnss_velocity_says_we_are_wrong() -> None:
    (w,) = _warnings("us")
    ev = w.evidence
    assert ev is not None and ev.gnss_verdict == "us" and ev.gnss_blames_us > 0.8, ev
    assert "us?" in w.text


def test_a_disturbed_magnetometer_is_named() -> None:
    (w,) = _warnings("ap", mag_scale=1.3)
    ev = w.evidence
    assert ev is not None and ev.mag_disturbed and ev.mag_norm_dev == pytest.approx(0.3, abs=0.01)
    assert ev.cause == "mag AP?" and w.text.endswith(" [mag AP?]")


def test_without_gnss_velocity_there_is_no_verdict_but_the_warning_comes() -> None:
    (w,) = _warnings("ap", vel=False)
    ev = w.evidence
    assert ev is not None and ev.gnss_verdict == "" and math.isnan(ev.gnss_m_s) and ev.cause == ""
    assert "[" not in w.text


def test_no_fault_no_warning_with_the_sensors_fed() -> None:
    assert _warnings("none") == []


def test_warning_text_always_fits_statustext() -> None:
    from mavahrs.service.monitor import PHASE_TEXT, _fit

    for tpl, phase in ((WARNING_TEXT, ""), (PHASE_TEXT, "touchdown")):
        for tilt, hdg in ((2.0, 0.5), (123.4, -179.9)):
            text = _fit(tpl, math.radians(tilt), math.radians(hdg), phase, "mag AP? IMU2?")
            assert len(text.encode()) <= 50, text
            assert text.startswith("mavahrs") and f"{tilt:.0f}" in text
    assert _fit(WARNING_TEXT, math.radians(2.0), 0.0, "", "mag AP? IMU2?").endswith("[mag AP? IMU2?]")


def test_evidence_reaches_the_live_status_and_survives_a_reset() -> None:
    mon = AttitudeMonitor(MonitorSettings())
    mon.set_mag_reference(B_STRENGTH_UT, B_DIP_RAD)
    mon.set_mag_offsets([3.0, 4.0, 0.0])
    mon.reset()
    t_ms, q_est, t_ap, q_ap, sigma, s = _flight("ap", mag_scale=1.3)
    acc, mag = np.asarray(s.accel_body_m_s2), np.asarray(s.mag_body_ut)
    vel, vt = np.asarray(s.vel_ne_m_s), np.asarray(s.vel_t_ms)
    texts = []
    j = 0
    for i in range(len(t_ms)):
        mon.add_sensors(t_ms[i], acc[i], mag[i], vel[i], vt[i])
        texts += [m.text for m in mon.add_estimate(t_ms[i], q_est[i], sigma[i])]
        while j < len(t_ap) and t_ap[j] <= t_ms[i]:
            texts += [m.text for m in mon.add_autopilot(t_ap[j], q_ap[j])]
            j += 1
    # the magnetometer is seen at once; the GNSS verdict once the velocity windows hold the fault: said again
    assert len(texts) == 2 and texts[0].endswith("[mag]") and texts[1].endswith("[mag AP?]"), texts
    st = mon.status
    assert st.warning and st.cause == "mag AP?" and isinstance(st.evidence, Evidence)
    assert st.evidence.mag_offset_ut == pytest.approx(5.0)
    d = st.evidence.as_dict()
    assert d["cause"] == "mag AP?" and d["gnss_verdict"] == "AP" and d["imu"] == ""
    assert "[mag AP?]" in st.text() and "magnetometer disturbed" in st.evidence.text()


# ---------------------------------------------------------------------------- real flights


@pytest.fixture(scope="module")
def sitl_rows(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    from mavahrs.evaluation.faults import AttitudeFault, FaultShape, inject_faults
    from mavahrs.fleet.audit import summarise_log

    tmp = tmp_path_factory.mktemp("evidence")
    rows = {}
    src = shared_data / "sitl/arducopter_gentle.tlog"
    copy = tmp / "tilt2.tlog"
    inject_faults(src, copy, [AttitudeFault(FaultShape("step", 100.0), tilt_deg=2.0, tilt_azimuth_deg=45.0)])
    rows["gentle_tilt2"] = summarise_log(copy)
    copy.unlink()
    rows["magnetic"] = summarise_log(shared_data / "sitl/arducopter_magnetic.tlog")
    return rows


def test_real_flight_tilt_fault_in_the_autopilot_is_blamed_on_it_by_the_gnss(sitl_rows: dict) -> None:
    row = sitl_rows["gentle_tilt2"]
    assert row.ok, row.error
    times = [float(x) for x in row.alarm_times_s.split(";") if x]
    assert times and 100.0 < times[0] <= 102.0, times
    assert row.alarm_causes.split(";")[0] == "AP?", row.alarm_causes


def test_real_magnetic_flight_warning_names_the_magnetometer(sitl_rows: dict) -> None:
    """The autopilot's EKF3 heading is 38° off after take-off, misled by the motor current's field."""
    row = sitl_rows["magnetic"]
    assert row.ok, row.error
    causes = [c for c in row.alarm_causes.split(";")]
    assert row.alarms >= 1 and len(causes) == row.alarms
    assert "mag" in causes[0].split(), row.alarm_causes


def test_the_flight_chart_has_the_thresholds_and_the_warning(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    from mavahrs.evaluation.plots import plot_second_opinion

    t_ms, q_est, t_ap, q_ap, sigma, sensors = _flight("ap")
    res = monitor_series(t_ms, q_est, t_ap, q_ap, MonitorSettings(), tilt_sigma_rad=sigma, sensors=sensors)
    thr = res.tilt_threshold_deg
    assert thr is not None and np.isfinite(thr).mean() > 0.9 and np.nanmin(thr) >= 1.0  # the 1° floor
    assert res.heading_threshold_deg is not None and np.nanmin(res.heading_threshold_deg) >= 3.0
    out = plot_second_opinion(tmp_path / "flight.png", res, title="synthetic")
    import matplotlib.image

    img = matplotlib.image.imread(str(out))[..., :3]
    red = np.all(np.abs(img * 255 - np.array([214, 39, 40])) < 20, axis=-1)  # tab:red, the WARNING line
    assert red.mean() > 0.0005


# ---------------------------------------------------------------------------- several IMUs


def _sim_tlog(path: Path, *extra: str) -> Path:
    import subprocess
    import sys

    subprocess.run([sys.executable, "-m", "firmware_sim", "--fast", "--tlog", str(path), "--scenario", "aggressive",
                    "--duration", "90", "--seed", "21", "-q", *extra], check=True, cwd=Path(__file__).parents[2])
    return path


def test_a_gyro_bias_step_on_one_of_two_imus_is_warned_and_that_imu_named(tmp_path: Path) -> None:
    """firmware_sim's second IMU (SCALED_IMU2, instance 1) gains a 2°/s gyro bias per axis at 30 s; our filter
    uses the first.  The IMU is named within the averaging window, the healthy flight names none."""
    from mavahrs.fleet.audit import summarise_log
    from mavahrs.service.monitor import IMU_TEXT  # noqa: F401  (the text the WARNING uses)

    faulty = summarise_log(_sim_tlog(tmp_path / "imu.tlog", "--imu-fault", "imu1:gyro_bias_dps=2:at=30"))
    assert faulty.ok, faulty.error
    times = [float(x) for x in faulty.alarm_times_s.split(";") if x]
    causes = faulty.alarm_causes.split(";")
    first = next(i for i, c in enumerate(causes) if "IMU2?" in c.split())
    assert 30.0 < times[first] < 30.0 + 10.0, (times, causes)
    assert all("IMU1?" not in c.split() for c in causes) and all(t > 30.0 for t in times), (times, causes)
    clean = summarise_log(_sim_tlog(tmp_path / "clean.tlog"))
    assert clean.ok and "IMU" not in clean.alarm_causes, clean.alarm_causes


def test_a_slow_heading_drift_is_not_learnt_as_normal() -> None:
    """The learnt widening takes only what lies within the error model's thresholds: a heading drift of
    0.2°/s is warned once past them (5.0°), not followed by a threshold learnt from it."""
    from mavahrs.geometry.quaternion import from_axis_angle as about

    t_ms, q_est, t_ap, q_ap, sigma, sensors = _flight("none")
    drift_deg = np.clip((t_ap / 1000.0 - 20.0) * 0.2, 0.0, None)
    q_drift = multiply(about([0.0, 0.0, 1.0], np.radians(drift_deg)), q_ap)
    res = monitor_series(t_ms, q_est, t_ap, q_drift, MonitorSettings(), tilt_sigma_rad=sigma, sensors=sensors)
    warns = [e for e in res.events if e.in_flight]
    assert warns, res.events
    at = (warns[0].t_ms / 1000.0 - 20.0) * 0.2
    assert 5.0 < at < 6.5, at  # past the threshold, 5.0° (heading_tolerance_floor), not a learnt one
    assert np.nanmax(res.heading_threshold_deg) < 5.1


# ---------------------------------------------------------------------------- the magnetometer model's word


def test_the_magnetometer_models_offsets_and_verdict_reach_the_evidence() -> None:
    """set_mag_offsets: the learnt offsets' size is in the evidence; the model's own "disturbed" names ``mag``
    with a disagreement even where the field strength and dip look as expected; None (model off) clears."""
    t_ms, q_est, t_ap, q_ap, sigma, sensors = _flight("ap")
    mon = AttitudeMonitor(MonitorSettings())
    mon.set_mag_offsets([3.0, 4.0, 0.0])
    ev = mon.evidence
    assert ev.mag_offset_ut == pytest.approx(5.0) and not ev.mag_disturbed
    assert "offsets 5 µT" in Evidence(mag_norm_dev=0.0, mag_dip_dev_deg=0.0, mag_offset_ut=5.0).text()
    mon.set_mag_offsets([3.0, 4.0, 0.0], disturbed=True)
    assert mon.evidence.mag_disturbed and mon.evidence.cause == "mag"
    mon.set_mag_offsets(None, disturbed=True)  # the model off: no word from it
    assert math.isnan(mon.evidence.mag_offset_ut) and not mon.evidence.mag_disturbed
    mon.set_mag_offsets([math.nan, 0.0, 0.0])
    assert math.isnan(mon.evidence.mag_offset_ut)


def test_the_pipeline_passes_the_magnetometer_models_state_to_the_monitor(autopilot) -> None:  # noqa: ANN001
    """The daemon's pipeline asks the filter's magnetometer model (its public summary) once a second and tells
    the monitor; a model still learning, or off (the default), tells it nothing."""
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    pipe = Pipeline(PipelineSettings(filter_name="mahony", out_rate_hz=0.0))
    rx = MavCodec(0, 0)
    for msg in rx.receive_datagram(autopilot.heartbeat()):
        pipe.handle(msg, 0)
    pipe.tick(10)
    mon = pipe._monitor
    assert math.isnan(mon.evidence.mag_offset_ut)  # mahony has no magnetometer model
    state = {"state": "disturbed", "offset_ut": [1.0, -2.0, 2.0]}
    pipe._filter.mag_model_state = lambda: state  # type: ignore[attr-defined]  # a model's public summary
    pipe.tick(500_000)  # within the second: not asked yet
    assert math.isnan(mon.evidence.mag_offset_ut)
    pipe.tick(1_100_000)
    assert mon.evidence.mag_offset_ut == pytest.approx(3.0) and mon.evidence.mag_disturbed
    state = {"state": "learning", "offset_ut": [1.0, -2.0, 2.0]}
    pipe.tick(2_200_000)
    assert math.isnan(mon.evidence.mag_offset_ut) and not mon.evidence.mag_disturbed


def test_the_daemons_pipeline_names_the_imu_with_a_gyro_bias_step() -> None:
    """The daemon's path: the real Pipeline fed live by firmware_sim's ArduPilot (RAW_IMU and SCALED_IMU2 at
    the loop rate, ATTITUDE at 50 Hz) whose second IMU (instance 1, SCALED_IMU2) gains 2°/s per axis at 12 s:
    a WARNING naming IMU2 after the step, within two of the check's averaging windows, and never IMU1."""
    fs = pytest.importorskip("firmware_sim")
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    step_s, sim_s = 12.0, 26.0
    bias = (math.radians(2.0),) * 3
    ss = fs.SimSettings(scenario="aggressive", seed=21, imu_fault=fs.ImuFault(instance=1, step_at_s=step_s,
                                                                              gyro_bias_step_rad_s=bias))
    ep = fs.Endpoint(fs.Simulation(ss), fs.EndpointSettings(preset="none", block_ticks=400, streams_hz=(
        ("RAW_IMU", math.inf), ("SCALED_IMU2", math.inf), ("ATTITUDE", 50.0), ("GLOBAL_POSITION_INT", 5.0),
        ("SYSTEM_TIME", 1.0))))  # fmt: skip
    pipe = Pipeline(PipelineSettings(out_rate_hz=50.0))
    rx, ours = MavCodec(255, 190), MavCodec(255, 190)
    texts: list[tuple[float, int, str]] = []
    for k in range(int(sim_s * ss.loop_rate_hz)):
        for t_us, frame in ep.step():
            for msg in rx.receive_datagram(frame):
                for o in pipe.handle(msg, t_us):
                    for m in ours.receive_datagram(o.frame):
                        if m.get_type() == "STATUSTEXT":
                            texts.append((t_us / 1e6, int(m.severity), str(m.text)))
        if k % 20 == 0:
            pipe.tick(ep.now_us)
    named = [(t, sev, x) for t, sev, x in texts if "IMU2 gyro off" in x]
    assert named and named[0][1] == mavlink.MAV_SEVERITY_WARNING and named[0][2].endswith("[IMU2?]"), texts
    assert step_s < named[0][0] < step_s + 2.0 * MonitorSettings().imu_window_s, texts  # two averaging windows
    assert not any("IMU1" in x for _, _, x in texts), texts


def _imu_texts_with_late_imu2(imu2_late_ms: float, imu2_bias_dps: float = 0.0) -> list[str]:
    """The monitor fed as a link delivers: the autopilot's ATTITUDE (50 Hz) and our estimate (the truth, no
    divergence) at once, two perfect 400 Hz gyros, IMU2's (plus a bias, deg/s) ``imu2_late_ms`` late (its
    stream's queue).  The vehicle yaws in spin-ups: 0 → 300 °/s in 2 s, held 3 s, down in 2 s, every 12 s.
    Returns the monitor's IMU STATUSTEXTs."""
    def yaw_rate(t: np.ndarray) -> np.ndarray:
        c = np.mod(t, 12.0)
        return np.radians(300.0) * np.clip(np.minimum(c / 2.0, (7.0 - c) / 2.0), 0.0, 1.0)

    dt, t_end = 0.0025, 60.0
    t = np.arange(0.0, t_end, dt)
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (yaw_rate(t[1:]) + yaw_rate(t[:-1])) * dt)])
    q = from_euler_rad(np.full_like(t, 0.05), np.full_like(t, -0.03), yaw)  # the body's yaw axis tilted a little
    w_body = rotate(conjugate(q), np.stack([np.zeros_like(t), np.zeros_like(t), yaw_rate(t)], axis=1))
    events: list[tuple[float, int, str, object]] = []  # (arrival ms, order, kind, payload)
    for k in range(len(t)):
        ms = 1000.0 * t[k]
        events.append((ms, 1, "IMU1", w_body[k]))
        events.append((ms + imu2_late_ms, 1, "IMU2", w_body[k] + math.radians(imu2_bias_dps)))
        if k % 8 == 0:
            events.append((ms, 0, "ATT", q[k]))
    events.sort(key=lambda e: (e[0], e[1]))
    mon = AttitudeMonitor(MonitorSettings())
    texts: list[str] = []
    for arrive_ms, _, kind, x in events:
        k_t = round(arrive_ms / 1000.0 / dt)
        if kind == "ATT":
            qq = tuple(float(v) for v in x)
            out = mon.add_autopilot(arrive_ms, qq) + mon.add_estimate(arrive_ms, qq, math.radians(0.3))
        else:
            t_ms = 1000.0 * t[min(k_t, len(t) - 1)] - (imu2_late_ms if kind == "IMU2" else 0.0)
            mon.add_imu_gyro(kind, t_ms, tuple(float(v) for v in x))
            out = mon.tick(int(1000 * arrive_ms)) if kind == "IMU1" and k_t % 40 == 0 else []
        texts += [str(m.text) for m in out if m.get_type() == "STATUSTEXT"]
    assert mon.status.comparisons > 0.8 * 50.0 * t_end, mon.status  # the monitor did compare the flight
    return [x for x in texts if "gyro off" in x]


def test_an_imu_whose_messages_arrive_late_is_not_named_in_yaw_spin_ups() -> None:
    """Two perfect gyros, the second's messages 100 ms behind the autopilot's ATTITUDE on the link, in yaw
    spin-ups of 150 °/s²: no IMU named (before: each interval was judged with the samples that *arrived* in
    it, so IMU2's gyro was compared with the turn rate 100 ms later — 15 °/s off through each spin-up — and
    it was named six times, "off by 1.5 dps"); the same IMU2 with a 3 °/s bias per axis is still named, late
    as it is."""
    assert _imu_texts_with_late_imu2(0.0) == []
    assert _imu_texts_with_late_imu2(100.0) == []
    named = _imu_texts_with_late_imu2(100.0, imu2_bias_dps=3.0)
    assert named and all("IMU2" in x for x in named), named


def test_late_imu_samples_are_counted_in_the_status() -> None:
    """The IMU check drops a gyro sample that comes after the interval it belongs to was judged (a resent or
    reordered message): counted, shown in the status (``imu_late``, status.json's ``second_opinion``), kept
    over a reset as the other counters are, and the sample not judged."""
    from mavahrs.service.http import _second_opinion_extra

    mon = AttitudeMonitor(MonitorSettings())
    q = (1.0, 0.0, 0.0, 0.0)
    resent = 0
    for k in range(3200):  # 8 s: IMU1 at 400 Hz, the autopilot's attitude and ours at 50 Hz, all in time order
        ms = 2.5 * k
        mon.add_imu_gyro("IMU1", ms, (0.0, 0.0, 0.0))
        if k % 8 == 0:
            mon.add_autopilot(ms, q)
            mon.add_estimate(ms, q, math.radians(0.3))
        if k % 400 == 399:  # once a second: a sample from half a second ago comes again
            mon.add_imu_gyro("IMU1", ms - 500.0, (0.0, 0.0, 1.0))
            resent += 1
    st = mon.status
    assert st.comparisons > 300 and st.imu_late == resent == 8, st
    assert _second_opinion_extra(st)["imu_late"] == resent
    assert mon._imus.errors_dps()["IMU1"] < 0.01  # the resent 57 °/s samples were not judged
    mon.reset()
    assert mon.status.imu_late == resent


@pytest.mark.parametrize("imu2_bias_dps", [0.0, 2.0])
def test_the_daemons_imu_check_with_slow_streams(imu2_bias_dps: float) -> None:
    """The daemon's path with the streams `mavahrs-sim` gave a live run: RAW_IMU at the loop rate, SCALED_IMU2
    at 50 Hz, ATTITUDE at 10 Hz (40° of a 400 °/s yaw spin between two), firmware_sim's aggressive flight
    (seed 3).  Both IMUs healthy: none named (before: one SCALED_IMU2 sample in 8, 6 Hz, against the 10 Hz
    attitude's small-angle rate named IMU2 "off by 2.0 dps" at 17 s, as the live run did); IMU2 with a 2 °/s
    bias per axis from 5 s: named."""
    fs = pytest.importorskip("firmware_sim")
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    sim_s = 40.0
    fault = fs.ImuFault(instance=1, step_at_s=5.0, gyro_bias_step_rad_s=(math.radians(imu2_bias_dps),) * 3)
    ss = fs.SimSettings(scenario="aggressive", seed=3, imu_fault=fault if imu2_bias_dps else None)
    ep = fs.Endpoint(fs.Simulation(ss), fs.EndpointSettings(preset="none", block_ticks=400, streams_hz=(
        ("RAW_IMU", 250.0), ("SCALED_IMU2", 50.0), ("ATTITUDE", 10.0), ("GLOBAL_POSITION_INT", 10.0),
        ("SYSTEM_TIME", 1.0))))  # fmt: skip
    pipe = Pipeline(PipelineSettings(out_rate_hz=50.0))
    rx, ours = MavCodec(255, 190), MavCodec(255, 190)
    texts: list[str] = []
    for k in range(int(sim_s * ss.loop_rate_hz)):
        for t_us, frame in ep.step():
            for msg in rx.receive_datagram(frame):
                for o in pipe.handle(msg, t_us):
                    texts += [str(m.text) for m in ours.receive_datagram(o.frame) if m.get_type() == "STATUSTEXT"]
        if k % 20 == 0:
            pipe.tick(ep.now_us)
    mon = pipe.status(ep.now_us).monitor_state
    assert mon is not None and mon.comparisons > 0.8 * 10.0 * sim_s, mon  # the monitor did judge the flight
    named = [x for x in texts if "gyro off" in x]
    if imu2_bias_dps:
        assert named and all("IMU2" in x for x in named), texts
    else:
        assert named == [], texts


def test_the_gnss_evidence_gives_no_verdict_it_cannot_support(tmp_path: Path) -> None:
    # firmware_sim's shared aggressive flight (seed 11): a correct WARNING at 55.8 s (the simulated autopilot
    # 1.5° off, ours 0.2°) was said with `us?`: the GNSS share 0.70 a second later, but its standard error, from
    # our miss across the difference (the raw specific force's own error in the manoeuvres), 0.41 — no verdict.
    # That warning is no longer raised since our tilt σ holds the gyro's scale-factor error in manoeuvres
    # (EskfSettings.gyro_scale_tilt_sigma, docs/monitor.md round eight); the rule is kept on aggressive 2's
    # correct WARNING at 146.6 s (the simulated autopilot 1.5° off in tilt), said with no verdict
    pytest.importorskip("firmware_sim", reason="firmware_sim (the simulator with known truth) is not importable")
    from mavahrs.fleet.audit import summarise_log

    path = tmp_path / "aggressive_2.tlog"
    subprocess.run([sys.executable, "-m", "firmware_sim", "--fast", "--tlog", str(path), "--scenario", "aggressive",
                    "--duration", "150", "--seed", "2", "-q"], check=True, cwd=Path(__file__).parents[2])  # fmt: skip
    row = summarise_log(path)
    assert row.ok, row.error
    times = [float(x) for x in row.alarm_times_s.split(";") if x]
    causes = row.alarm_causes.split(";") if times else []
    near = [c for t, c in zip(times, causes, strict=True) if 145.0 <= t <= 148.0]
    assert near, (times, causes)  # the warning itself stays
    assert all("us?" not in c for c in near), (times, causes)


def test_no_verdict_is_said_once_the_disagreement_is_gone(tmp_path: Path) -> None:
    # firmware_sim aggressive 41: a correct WARNING at 18.5 s (the simulated autopilot 1.2–1.3° off in tilt) stays
    # on until 29.6 s (clear_s after agreeing again); at 27.5 s, the two 0.3° apart and both within 0.2° of the
    # truth, the evidence said again `us?` (its GNSS windows still held the seconds of the disagreement): no
    # verdict is said again once the divergence is back within its thresholds.  That warning (grey by issue 24's
    # bar) is raised with the level CUSUM's reference at 0.5, not at the default 0.75 (docs/monitor.md round
    # twenty-two): the case is built with 0.5
    pytest.importorskip("firmware_sim", reason="firmware_sim (the simulator with known truth) is not importable")
    from mavahrs.fleet.audit import AuditSettings, summarise_log
    from mavahrs.replay import ReplaySettings
    from mavahrs.service.monitor import MonitorSettings
    from mavahrs.service.pipeline import PipelineSettings

    path = tmp_path / "aggressive_41.tlog"
    subprocess.run([sys.executable, "-m", "firmware_sim", "--fast", "--tlog", str(path), "--scenario", "aggressive",
                    "--duration", "32", "--seed", "41", "-q"], check=True, cwd=Path(__file__).parents[2])  # fmt: skip
    mon = MonitorSettings(cusum_reference=0.5)
    row = summarise_log(path, AuditSettings(replay=ReplaySettings(pipeline=PipelineSettings(monitor=mon))))
    assert row.ok, row.error
    times = [float(x) for x in row.alarm_times_s.split(";") if x]
    causes = row.alarm_causes.split(";")
    near = [c for t, c in zip(times, causes, strict=True) if 17.0 <= t <= 20.0]
    assert near, (times, causes)  # the warning itself stays
    assert all("us?" not in c for c in near), (times, causes)
