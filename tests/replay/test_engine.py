"""Replay: the bulk engine equals the daemon's Pipeline, real logs replay, output tlog, streaming to a GCS."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from mavahrs.replay import (
    ReplaySettings,
    StreamSettings,
    compare,
    format_comparison,
    replay,
    stream,
    write_tlog,
)

LOGS = ("UAVLogViewer/vtol.tlog", "dronekit-python/flight.tlog", "ardusub_log_tools/small.tlog")


@pytest.mark.slow
def test_fast_engine_equals_the_pipeline(sim_hover_tlog: Path, tmp_path: Path) -> None:
    s = dict(filters=("madgwick", "mahony", "best"))  # best: told of the vehicle (a quadrotor) as the daemon tells it
    fast = replay(sim_hover_tlog, ReplaySettings(engine="fast", **s), csv_path=tmp_path / "fast.csv")
    ref = replay(sim_hover_tlog, ReplaySettings(engine="pipeline", **s), csv_path=tmp_path / "ref.csv")
    assert (tmp_path / "fast.csv").read_bytes() == (tmp_path / "ref.csv").read_bytes()
    assert fast.engine == "fast" and ref.engine == "pipeline"
    assert fast.inputs.n > 4000
    assert fast.inputs.vehicle_stream and fast.inputs.multirotor  # the simulator's HEARTBEAT: MAV_TYPE_QUADROTOR
    np.testing.assert_array_equal(fast.inputs.t_us, ref.inputs.t_us)
    np.testing.assert_array_equal(fast.inputs.rows, ref.inputs.rows)  # NaN positions must match too
    for name in s["filters"]:
        a, b = fast.tracks[name], ref.tracks[name]
        np.testing.assert_array_equal(a.out, b.out)
        np.testing.assert_array_equal(a.sent, b.sent)
        assert fast.frames(name) == ref.frames(name)  # byte for byte, sequence numbers included
    # against the simulator's truth the attitude is good (not a degenerate comparison)
    truth = [r for r in compare(fast) if r.filter == "mahony" and r.reference.endswith("truth")]
    assert truth and truth[0].inclination_rms_deg < 3.0


def test_output_tlog_as_the_daemon_sends(sim_hover_tlog: Path, tmp_path: Path) -> None:
    from pymavlink import mavutil

    res = replay(sim_hover_tlog, ReplaySettings(filters=("mahony",), pipeline=None, start_s=2.0, end_s=6.0))
    assert res.engine == "fast"
    out = tmp_path / "out.tlog"
    k = write_tlog(res, out)
    assert k == int(res.tracks["mahony"].sent.sum()) > 900
    conn = mavutil.mavlink_connection(str(out))
    last_raw = None
    n_att = 0
    while True:
        m = conn.recv_match(type=["RAW_IMU", "ATTITUDE_QUATERNION"])
        if m is None:
            break
        if m.get_type() == "RAW_IMU":
            last_raw = m
            continue
        n_att += 1
        assert m.get_srcSystem() == res.inputs.source[0] and m.get_srcComponent() == 191
        # inserted right after the IMU message it was computed from, stamped with its time
        assert last_raw is not None and m.time_boot_ms == last_raw.time_usec // 1000
        assert abs(np.linalg.norm([m.q1, m.q2, m.q3, m.q4]) - 1) < 1e-5
    conn.close()
    assert n_att == k


@pytest.mark.parametrize("log", LOGS)
def test_real_logs_replay_with_a_low_rate_warning(mavlink_logs_dir: Path, log: str, tmp_path: Path) -> None:
    res = replay(mavlink_logs_dir / log, ReplaySettings(filters=("mahony",)), csv_path=tmp_path / "r.csv")
    assert res.inputs.n > 100
    assert any("too slow for meaningful attitude filtering" in n for n in res.notes)
    rows = compare(res)
    assert any(r.reference == "autopilot ATTITUDE" for r in rows)
    assert "autopilot ATTITUDE" in format_comparison(rows)
    lines = (tmp_path / "r.csv").read_text().splitlines()
    assert len(lines) == res.inputs.n + 1 and lines[0].startswith("time_s,mahony_qw")
    if "ardusub" in log:  # all-zero SCALED_IMU2 (no second IMU) is never fed
        assert res.inputs.message == "RAW_IMU"
        assert any("all-zero" in n for n in res.notes)
    if "vtol" in log:  # SITL: SIMSTATE truth is compared with
        assert any(r.reference == "SIMSTATE truth" for r in rows)


def _pace_check_clock():
    class Clock:
        def __init__(self) -> None:
            self.t = 100.0
            self.sleeps: list[float] = []

        def monotonic(self) -> float:
            return self.t

        def sleep(self, s: float) -> None:
            self.sleeps.append(s)
            self.t += s

    return Clock()


def test_stream_paces_by_sample_time(sim_hover_tlog: Path) -> None:
    """With a fake clock: the n-th ATTITUDE_QUATERNION leaves at n/rate/speed seconds (no wall-clock test)."""
    res = replay(sim_hover_tlog, ReplaySettings(filters=("mahony",), end_s=4.0))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.01)
    port = sock.getsockname()[1]
    clock = _pace_check_clock()
    sends: list[float] = []
    from mavahrs.replay import engine as rp  # the module whose globals the engine reads

    orig = rp._open_udp_sender

    def spy(url: str):
        inner = orig(url)

        class S:
            def __call__(self, data: bytes) -> None:
                if data[7] | (data[8] << 8) | (data[9] << 16) == 31:
                    sends.append(clock.t)
                inner(data)

            def close(self) -> None:
                inner.close()

        return S()

    rp._open_udp_sender = spy
    try:
        n = stream(res, "mahony", StreamSettings(url=f"udpout:127.0.0.1:{port}", rate_hz=20.0, speed=2.0),
                   clock=clock)  # fmt: skip
    finally:
        rp._open_udp_sender = orig
        sock.close()
    assert n == len(sends) > 30
    steps = np.diff(sends)
    np.testing.assert_allclose(np.median(steps), 1 / 20 / 2, rtol=0.05)
    assert steps.max() < 2.5 / 40


def test_stream_to_a_pymavlink_ground_station(sim_hover_tlog: Path) -> None:
    """Real UDP: HEARTBEAT from component 1 as a quadrotor, ATTITUDE_QUATERNION at about the right pace."""
    from pymavlink import mavutil

    res = replay(sim_hover_tlog, ReplaySettings(filters=("mahony",), end_s=3.0))
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", dialect="ardupilotmega")
    settings = StreamSettings(url=f"udpout:127.0.0.1:{port}", system_id=77, rate_hz=25.0, speed=2.0,
                              max_duration_s=10.0)  # fmt: skip
    result: dict[str, int] = {}
    th = threading.Thread(target=lambda: result.setdefault("n", stream(res, "mahony", settings)), daemon=True)
    th.start()
    heartbeats, atts = [], []
    deadline = time.monotonic() + 15.0
    while th.is_alive() or time.monotonic() < deadline - 13:
        m = gcs.recv_match(blocking=True, timeout=0.5)
        if m is None:
            if not th.is_alive():
                break
            continue
        if m.get_type() == "HEARTBEAT":
            heartbeats.append(m)
        elif m.get_type() == "ATTITUDE_QUATERNION":
            atts.append((time.monotonic(), m))
        if time.monotonic() > deadline:
            break
    th.join(timeout=5)
    gcs.close()
    assert heartbeats and all(h.get_srcComponent() == 1 and h.get_srcSystem() == 77 for h in heartbeats)
    assert heartbeats[0].type == mavutil.mavlink.MAV_TYPE_QUADROTOR
    assert heartbeats[0].autopilot != mavutil.mavlink.MAV_AUTOPILOT_INVALID
    assert len(atts) == result["n"] > 20
    assert all(m.get_srcComponent() == 1 for _, m in atts)
    # pace: log time advances `speed` times faster than the wall clock (loose: shared CI machines)
    log_span = (atts[-1][1].time_boot_ms - atts[0][1].time_boot_ms) / 1000.0
    wall_span = atts[-1][0] - atts[0][0]
    assert 1.2 < log_span / wall_span < 3.5
    np.testing.assert_allclose(np.median(np.diff([m.time_boot_ms for _, m in atts])), 1000 / 25, rtol=0.1)


def test_an_interrupted_fast_replay_keeps_every_block_it_filtered(
    sim_hover_tlog: Path, tmp_path: Path, interrupt_replay: Callable[[int], None]
) -> None:
    """Ctrl-C in the middle of the bulk replay: the blocks handed to the CSV writer thread are all on disk, whole."""
    full = tmp_path / "full.csv"
    replay(sim_hover_tlog, ReplaySettings(filters=("madgwick",), engine="fast"), csv_path=full)
    interrupt_replay(3)
    part = tmp_path / "part.csv"
    with pytest.raises(KeyboardInterrupt):
        replay(sim_hover_tlog, ReplaySettings(filters=("madgwick",), engine="fast"), csv_path=part)
    lines = part.read_bytes().split(b"\n")
    assert lines[-1] == b""  # ends with a complete row
    assert len(lines) - 2 == 2000  # header + the two blocks filtered before the interruption
    assert lines[:-1] == full.read_bytes().split(b"\n")[: len(lines) - 1]


def test_a_log_with_an_autopilot_reboot_loads_through_the_pipeline(tmp_path: Path) -> None:
    """``evaluate``/``tune``/``plot`` read a log the bulk engine cannot mirror (a reboot) through the Pipeline."""
    import struct

    from mavahrs.evaluation.tlogdata import load_tlog_recording
    from mavahrs.protocol.codec import MavCodec, mavlink

    ap = MavCodec(system_id=1, component_id=1)
    out = bytearray()
    wall_us = 1_790_000_000 * 10**6

    def rec(msg: object) -> None:
        out.extend(struct.pack(">Q", wall_us))
        out.extend(ap.encode(msg))

    for _boot in range(2):  # the second boot's clock starts again near zero
        rec(mavlink.MAVLink_heartbeat_message(2, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3))
        for k in range(800):
            wall_us += 2500
            # level, still, compass north: 1 g up in the body's −z (mG), 0.2/0.4 G field
            rec(mavlink.MAVLink_raw_imu_message(1_000_000 + 2500 * k, 0, 0, -1000, 0, 0, 0, 200, 0, 400, 0, 0))
    path = tmp_path / "reboot.tlog"
    path.write_bytes(bytes(out))
    rec_ = load_tlog_recording(path, reference=False)
    # both boots are there (the first sample after the reboot waits for the next to confirm it)
    assert 1598 <= rec_.n <= 1600
    np.testing.assert_allclose(rec_.accel_m_s2[:, 2], -9.80665, rtol=1e-6)
    # one re-initialisation (dt NaN) at the reboot, the stream's 2.5 ms everywhere else
    gaps = np.flatnonzero(~np.isfinite(rec_.dt_s))
    assert gaps.tolist() == [800]
    np.testing.assert_allclose(np.delete(rec_.dt_s, gaps), 0.0025)
    ref = replay(path, ReplaySettings(filters=("madgwick",), engine="pipeline"))
    assert ref.inputs.n == rec_.n


def _receiver_fixes(path: Path) -> int:
    """Distinct GPS_RAW_INT fixes (3D, known speed) in a log, counted with pymavlink."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path))
    stamps = set()
    while (m := conn.recv_match(type="GPS_RAW_INT")) is not None:
        if m.fix_type >= 3 and m.vel != 65535:
            stamps.add(m.time_usec)
    conn.close()
    return len(stamps)


@pytest.mark.slow
@pytest.mark.parametrize("source", ["auto", "gps_raw_int"])
def test_engines_identical_with_gps_raw_int(shared_data: Path, source: str) -> None:
    """ArduCopter SITL at 400 Hz with GLOBAL_POSITION_INT and GPS_RAW_INT (each 5 Hz fix sent twice)."""
    import dataclasses

    from mavahrs.filters.layout import IN_VEL, IN_VEL_AGE
    from mavahrs.replay import format_velocity
    from mavahrs.service.pipeline import PipelineSettings

    log = shared_data / "sitl" / "arducopter_400hz_gps.tlog"
    if not log.exists():
        pytest.skip(f"{log} not found")
    ps = dataclasses.replace(PipelineSettings(), imu="0", velocity_source=source)
    s = dict(filters=("mahony",), pipeline=ps, start_s=60.0, end_s=70.0)
    fast = replay(log, ReplaySettings(engine="fast", **s))
    ref = replay(log, ReplaySettings(engine="pipeline", **s))
    assert fast.engine == "fast" and ref.engine == "pipeline"
    np.testing.assert_array_equal(fast.inputs.t_us, ref.inputs.t_us)
    np.testing.assert_array_equal(fast.inputs.rows, ref.inputs.rows)  # velocity, NaN vertical and age included
    np.testing.assert_array_equal(fast.tracks["mahony"].out, ref.tracks["mahony"].out)
    assert fast.inputs.velocity_fixes == ref.inputs.velocity_fixes
    rows = fast.inputs.rows
    fed = np.flatnonzero(~np.isnan(rows[:, IN_VEL]))
    assert fed.size > 40
    ages = rows[fed, IN_VEL_AGE]
    assert np.all(np.isnan(rows[np.isnan(rows[:, IN_VEL]), IN_VEL_AGE]))
    if source == "gps_raw_int":
        assert np.isnan(rows[fed, IN_VEL + 2]).all()  # the receiver gives no vertical
        fix_t = fast.inputs.t_us[fed] - np.round(ages * 1e6).astype(np.int64)
        assert np.unique(fix_t).size == fed.size  # each fix once: the repeats are not fed
        assert 0.05 < ages.min() and ages.max() < 0.3  # the receiver's fix is 50-300 ms old when it is sent
        n = _receiver_fixes(log)
        assert fast.inputs.velocity_fixes == {"GPS_RAW_INT": n}
        assert format_velocity(fast.inputs) == f"velocity: GPS_RAW_INT, {n} fixes (velocity_source gps_raw_int)"
    else:
        assert np.isfinite(rows[fed, IN_VEL + 2]).all()  # GLOBAL_POSITION_INT all along
        assert 0.0 <= ages.min() and ages.max() < 0.05
        n = fast.inputs.velocity_fixes["GLOBAL_POSITION_INT"]
        assert format_velocity(fast.inputs) == f"velocity: GLOBAL_POSITION_INT, {n} fixes (velocity_source auto)"


@pytest.mark.parametrize("source", ["auto", "gps_raw_int"])
def test_engines_identical_on_the_simulators_gps_raw_int(sim_gps_raw_tlog: Path, source: str) -> None:
    """firmware_sim's ArduPilot GPS_RAW_INT: fixes taken at 5 Hz, sent at 10 Hz 120-320 ms later, each twice."""
    from mavahrs.filters.layout import IN_VEL, IN_VEL_AGE
    from mavahrs.replay import format_velocity
    from mavahrs.service.pipeline import PipelineSettings

    s = dict(filters=("mahony",), pipeline=PipelineSettings(velocity_source=source))
    fast = replay(sim_gps_raw_tlog, ReplaySettings(engine="fast", **s))
    ref = replay(sim_gps_raw_tlog, ReplaySettings(engine="pipeline", **s))
    assert fast.engine == "fast" and ref.engine == "pipeline"
    np.testing.assert_array_equal(fast.inputs.rows, ref.inputs.rows)
    np.testing.assert_array_equal(fast.tracks["mahony"].out, ref.tracks["mahony"].out)
    assert fast.frames("mahony") == ref.frames("mahony")
    rows = fast.inputs.rows
    fed = np.flatnonzero(~np.isnan(rows[:, IN_VEL]))
    ages = rows[fed, IN_VEL_AGE]
    if source == "gps_raw_int":
        n = _receiver_fixes(sim_gps_raw_tlog)
        assert fed.size == n > 50 and np.isnan(rows[fed, IN_VEL + 2]).all()
        assert 0.12 <= ages.min() and ages.max() < 0.33
        assert format_velocity(ref.inputs) == f"velocity: GPS_RAW_INT, {n} fixes (velocity_source gps_raw_int)"
    else:  # GLOBAL_POSITION_INT arrives all along: GPS_RAW_INT stays unused
        assert set(fast.inputs.velocity_fixes) == {"GLOBAL_POSITION_INT", "GPS_RAW_INT", "GPS2_RAW"}
        assert fast.inputs.velocity_fixes["GPS_RAW_INT"] == 0 and np.isfinite(rows[fed, IN_VEL + 2]).all()


def test_the_second_opinion_judges_best_whatever_order_the_filters_are_listed(shared_data: Path) -> None:
    """``replay --filter all`` lists madgwick first, and the second opinion judged the first filter: on the clean
    ArduCopter SITL aggressive flight madgwick's unaided tilt raised three in-flight WARNINGs ([us?], "ours not
    GNSS-aided") where best, the daemon's default, raises none.  It judges best wherever best is replayed, and
    says which filter it judged."""
    from mavahrs.replay.engine import format_second_opinion

    path = shared_data / "sitl" / "arducopter_aggressive.tlog"
    if not path.is_file():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data beside the checkout)")
    both = replay(path, ReplaySettings(filters=("madgwick", "best")))
    alone = replay(path, ReplaySettings(filters=("best",)))
    text = format_second_opinion(both)
    assert text.startswith("second opinion (best) vs autopilot ATTITUDE: 0 in-flight"), text
    assert text == format_second_opinion(alone)
    madgwick = replay(path, ReplaySettings(filters=("madgwick",)))
    assert format_second_opinion(madgwick).startswith("second opinion (madgwick) vs autopilot ATTITUDE")
