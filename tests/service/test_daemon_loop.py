"""The daemon loop over real UDP sockets, with a small stand-in pipeline (fast, deterministic).

The end-to-end behaviour with the real Pipeline and firmware_sim is in
test_daemon_e2e.py; here the loop's own duties are checked: routing (master ↔
outputs), bounded input under a flood, the no-heartbeat exit, silence
reporting, per-message error containment, stop/duration, latency recording.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from typing import Any, NamedTuple

import pytest

from mavahrs.errors import TransportError
from mavahrs.protocol.codec import MavCodec
from mavahrs.service.daemon import Daemon, DaemonSettings, LatencyRing
from mavahrs.transports import open_transport


class Out(NamedTuple):
    frame: bytes
    to_master: bool
    to_outputs: bool


class FakePipeline:
    """RAW_IMU → one ATTITUDE_QUATERNION to the outputs; tick → HEARTBEAT to master and outputs."""

    def __init__(self, fail_on: int | None = None) -> None:
        self.codec = MavCodec(1, 191)
        self.handled = 0
        self.ticks = 0
        self.fail_on = fail_on
        self.resets = 0

    def handle(self, msg: Any, now_us: int) -> list[Out]:
        self.handled += 1
        if self.fail_on is not None and self.handled == self.fail_on:
            raise RuntimeError("boom")
        if msg.get_type() != "RAW_IMU":
            return []
        q = self.codec.mav.attitude_quaternion_encode(msg.time_usec // 1000, 1, 0, 0, 0, 0, 0, 0, [0, 0, 0, 0])
        return [Out(self.codec.encode(q), False, True)]

    def tick(self, now_us: int) -> list[Out]:
        self.ticks += 1
        if self.ticks % 20:
            return []
        hb = self.codec.mav.heartbeat_encode(18, 8, 0, 0, 4)
        return [Out(self.codec.encode(hb), True, True)]

    def status(self, now_us: int | None = None) -> dict[str, Any]:
        return {"input_rate_hz": 0.0, "drops": {}}

    def drain_notices(self) -> list[tuple[int, str]]:
        return []

    def reset_link(self, now_us: int) -> None:
        self.resets += 1


class Autopilot:
    """A UDP socket playing the autopilot: heartbeats and RAW_IMU to the daemon's udpin."""

    def __init__(self, port: int) -> None:
        self.codec = MavCodec(1, 1)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(0.05)
        self.addr = ("127.0.0.1", port)
        self.t_us = 0

    def heartbeat(self) -> None:
        self.sock.sendto(self.codec.encode(self.codec.mav.heartbeat_encode(2, 3, 0, 0, 4)), self.addr)

    def imu(self, n: int = 1) -> None:
        for _ in range(n):
            self.t_us += 2500
            m = self.codec.mav.raw_imu_encode(self.t_us, 0, 0, -1000, 0, 0, 0, 200, 0, 400, 0, 0)
            self.sock.sendto(self.codec.encode(m), self.addr)

    def received(self) -> list[Any]:
        dec = MavCodec()
        out = []
        while True:
            try:
                out += dec.receive_datagram(self.sock.recv(4096))
            except TimeoutError:
                return out

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def gcs():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(0.05)
    yield s
    s.close()


def _daemon(gcs: socket.socket | None, pipeline: Any = None, **kw: Any) -> Daemon:
    settings = DaemonSettings(
        master="udpin:127.0.0.1:0",
        outputs=(f"udpout:127.0.0.1:{gcs.getsockname()[1]}",) if gcs else (),
        status_interval_s=0.0,
        **kw,
    )
    master = open_transport(settings.master)
    outputs = [open_transport(o) for o in settings.outputs]
    return Daemon(settings, pipeline or FakePipeline(), master, outputs)


def _start(d: Daemon) -> tuple[threading.Thread, dict[str, Any]]:
    box: dict[str, Any] = {}

    def target() -> None:
        try:
            box["result"] = d.run()
        except Exception as exc:  # noqa: BLE001
            box["error"] = exc

    t = threading.Thread(target=target, daemon=True)
    t.start()
    return t, box


def _drain(sock: socket.socket, seconds: float, attitudes: int | None = None) -> list[Any]:
    """Messages arriving within ``seconds`` (sooner once ``attitudes`` ATTITUDE_QUATERNION came, plus 0.1 s)."""
    dec = MavCodec()
    out: list[Any] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            out += dec.receive_datagram(sock.recv(4096))
        except TimeoutError:
            pass
        if attitudes is not None and sum(m.get_type() == "ATTITUDE_QUATERNION" for m in out) >= attitudes:
            end = min(end, time.monotonic() + 0.1)
            attitudes = None
    return out


def test_attitude_goes_to_outputs_and_heartbeats_to_both(gcs: socket.socket) -> None:
    d = _daemon(gcs)
    ap = Autopilot(d.master.local_address[1])
    thread, box = _start(d)
    try:
        ap.heartbeat()
        for _ in range(40):
            ap.imu(5)
            time.sleep(0.01)
        got = _drain(gcs, 5.0, attitudes=200)
        # until a heartbeat (tick 20 of the fake pipeline) has reached both sides, however loaded the machine
        to_ap: list[Any] = []
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and not (
                any(m.get_type() == "HEARTBEAT" for m in got) and any(m.get_type() == "HEARTBEAT" for m in to_ap)):
            got += _drain(gcs, 0.1)
            to_ap += ap.received()
    finally:
        d.stop()
        thread.join(5)
        ap.close()
    assert box["result"].reason == "stopped"
    types = [m.get_type() for m in got]
    assert types.count("ATTITUDE_QUATERNION") == 200  # one per sample, none lost on loopback
    assert "HEARTBEAT" in types and "HEARTBEAT" in [m.get_type() for m in to_ap]
    assert "ATTITUDE_QUATERNION" not in [m.get_type() for m in to_ap]  # to_master=False honoured
    assert d.counters.attitudes_out == 200 and d.latency.count == 200
    stats = box["result"].stats
    assert stats["latency"]["n"] == 200 and stats["latency"]["p50_us"] > 0
    assert stats["heartbeats"] == 1


def test_a_flood_is_bounded_and_drops_the_oldest(gcs: socket.socket) -> None:
    d = _daemon(gcs, input_queue=64, max_drain=1024)
    ap = Autopilot(d.master.local_address[1])
    try:
        ap.heartbeat()
        ap.imu(200)  # three times what the queue holds, all waiting in the socket buffer
        time.sleep(0.2)
        d._read_master()  # noqa: SLF001 - one wake-up of the loop
        assert d.master.counters.reads == 201
        # the first datagram (the heartbeat) is answered at once, the 200 behind it are drained
        # through the queue of 64: the 136 oldest fall out
        assert d.counters.input_dropped == 200 - 64
        assert d.counters.datagrams_in == 1 + 64
        got = [m for m in _drain(gcs, 0.3) if m.get_type() == "ATTITUDE_QUATERNION"]
        # the newest samples survived: the last one sent is the last one answered
        assert got[-1].time_boot_ms == ap.t_us // 1000
        assert len(got) == 64
    finally:
        d.close()
        ap.close()


def test_no_heartbeat_is_a_transport_error_saying_what_arrived(gcs: socket.socket) -> None:
    d = _daemon(gcs, heartbeat_timeout_s=0.3)
    port = d.master.local_address[1]  # the port udpin:…:0 got: the address to send to
    with pytest.raises(TransportError) as info:
        d.run()
    assert f"no heartbeat from udpin:127.0.0.1:{port} within 0.3 s (nothing received" in str(info.value)

    d = _daemon(gcs, heartbeat_timeout_s=0.5)
    port = d.master.local_address[1]
    junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    thread, box = _start(d)
    try:
        for _ in range(5):
            junk.sendto(b"\x01\x02 this is not mavlink", ("127.0.0.1", port))
            time.sleep(0.02)
        thread.join(5)
    finally:
        junk.close()
    assert isinstance(box.get("error"), TransportError)
    assert "bytes received but no valid MAVLink frame" in str(box["error"])

    # valid but unsigned frames with --require-signing: said as such (until user8 "no valid MAVLink frame")
    d = _daemon(gcs, heartbeat_timeout_s=0.5)
    d.enable_signing(bytes(range(32)), require=True)
    ap = Autopilot(d.master.local_address[1])
    thread, box = _start(d)
    try:
        for _ in range(5):
            ap.heartbeat()
            time.sleep(0.02)
        thread.join(5)
    finally:
        ap.close()
    assert isinstance(box.get("error"), TransportError)
    said = str(box["error"])
    assert "MAVLink frames received, all dropped by MAVLink signing: " in said and "unsigned (--require-signing)" in said
    assert "does the autopilot sign with this key?" in said and "no valid MAVLink frame" not in said, said


def test_silence_after_heartbeats_is_reported_not_fatal(gcs: socket.socket, caplog: pytest.LogCaptureFixture) -> None:
    d = _daemon(gcs, heartbeat_timeout_s=0.3)
    ap = Autopilot(d.master.local_address[1])
    caplog.set_level(logging.INFO, logger="mavahrs.daemon")
    thread, box = _start(d)
    try:
        ap.heartbeat()
        # silence longer than the timeout: wait for the daemon to say so (a loaded machine may take a while to
        # wake the loop; the deadline is only reached if it never does)
        deadline = time.monotonic() + 60.0
        while "no heartbeat from the autopilot" not in caplog.text and time.monotonic() < deadline:
            time.sleep(0.05)
        assert thread.is_alive()
        assert "autopilot heartbeat received" in caplog.text, caplog.text  # the silence came after a heartbeat
        deadline = time.monotonic() + 60.0
        while "heartbeat back" not in caplog.text and time.monotonic() < deadline:
            ap.heartbeat()
            time.sleep(0.1)
    finally:
        d.stop()
        thread.join(5)
        ap.close()
    assert box["result"].reason == "stopped"
    text = caplog.text
    assert "no heartbeat from the autopilot" in text and "still listening" in text
    assert "heartbeat back" in text


def test_an_exception_in_the_pipeline_is_counted_and_the_loop_goes_on(gcs: socket.socket) -> None:
    pipeline = FakePipeline(fail_on=3)
    d = _daemon(gcs, pipeline=pipeline)
    ap = Autopilot(d.master.local_address[1])
    thread, box = _start(d)
    try:
        ap.heartbeat()
        ap.imu(10)
        got = _drain(gcs, 5.0, attitudes=9)
    finally:
        d.stop()
        thread.join(5)
        ap.close()
    assert d.counters.pipeline_errors == 1
    assert [m.get_type() for m in got].count("ATTITUDE_QUATERNION") == 9


def test_duration_ends_the_run() -> None:
    d = _daemon(None, duration_s=0.3, heartbeat_timeout_s=0.0)
    result = d.run()
    # the lower bound is the claim; the upper one only catches a run that does not end (a loaded
    # machine took 4 s for this 0.3 s run)
    assert result.reason == "duration" and 0.25 <= result.run_s < 30.0


def test_latency_ring_percentiles_and_wrap() -> None:
    ring = LatencyRing(5)  # rounded up to 8
    assert ring.capacity == 8
    for v in range(1, 21):
        ring.add(v * 1000)
    assert ring.values() == [v * 1000 for v in range(13, 21)]  # the last 8
    assert ring.values(since=18) == [19000, 20000]
    s = LatencyRing.summary_us(list(range(1, 101)))
    assert (s["n"], s["p50_us"], s["p99_us"], s["max_us"]) == (100, 0.05, 0.099, 0.1)
    assert ring.max_ns == 20000


class _FullDisk:
    """A binary file that takes ``capacity`` bytes, then fails every write with ENOSPC."""

    def __init__(self, capacity: int) -> None:
        self.capacity, self.size = capacity, 0

    def write(self, b: bytes) -> int:
        import errno
        import os

        if self.size + len(b) > self.capacity:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.size += len(b)
        return len(b)

    def flush(self) -> None:
        pass


def test_a_full_disk_stops_the_log_and_nothing_else(gcs: socket.socket, caplog: pytest.LogCaptureFixture) -> None:
    from mavahrs.protocol.tlog import TlogWriter
    from mavahrs.service.sinks import TlogSink

    d = _daemon(gcs)
    d.sink = TlogSink("full.tlog", flush_interval_s=0.05, writer=TlogWriter(_FullDisk(2000), flush_interval_s=0.05))
    ap = Autopilot(d.master.local_address[1])
    caplog.set_level(logging.ERROR)
    thread, box = _start(d)
    try:
        ap.heartbeat()
        for _ in range(20):  # 200 samples: what the receiving socket buffers without a reader
            ap.imu(10)
            time.sleep(0.01)
        got = _drain(gcs, 5.0, attitudes=200)
        fields = d.status_fields()
    finally:
        d.stop()
        thread.join(5)
        ap.close()
    assert box["result"].reason == "stopped"
    assert [m.get_type() for m in got].count("ATTITUDE_QUATERNION") == 200  # every sample still answered
    assert d.sink.stopped and fields["log"] == "stopped: No space left on device"
    assert d.sink.frames_lost > 0
    assert sum("recording to full.tlog stopped" in r.getMessage() for r in caplog.records) == 1


def test_the_real_daemon_points_true_north_without_system_time(gcs: socket.socket) -> None:
    """A GNSS position alone (no SYSTEM_TIME, as an autopilot before its first time fix) gives true north.

    ``build_daemon`` gives the pipeline today's date for the magnetic model, so
    the declination at the reported position (Canberra, about 12.7° east) is
    applied from the first position on: a level vehicle whose compass points
    to magnetic north publishes a yaw equal to the declination.
    """
    import math

    from mavahrs.sensors.geomag import decimal_year_from_unix_s, expected_field
    from mavahrs.service.daemon import build_daemon

    lat, lon = -35.363262, 149.165237
    want_deg = expected_field(lat, lon, 584.0, decimal_year_from_unix_s(time.time())).declination_deg
    d = build_daemon(DaemonSettings(
        master="udpin:127.0.0.1:0", outputs=(f"udpout:127.0.0.1:{gcs.getsockname()[1]}",), status_interval_s=0.0,
    ))  # fmt: skip
    ap = Autopilot(d.master.local_address[1])
    thread, box = _start(d)
    try:
        ap.heartbeat()
        time.sleep(0.05)
        pos = ap.codec.mav.global_position_int_encode(1000, int(lat * 1e7), int(lon * 1e7), 584000, 0, 0, 0, 0, 0)
        ap.sock.sendto(ap.codec.encode(pos), ap.addr)
        for _ in range(40):
            ap.imu(5)
            time.sleep(0.01)
        # 0.5 s of samples at the default output rate (50 Hz): 25 attitudes
        got = [m for m in _drain(gcs, 5.0, attitudes=25) if m.get_type() == "ATTITUDE_QUATERNION"]
    finally:
        d.stop()
        thread.join(5)
        ap.close()
    assert box["result"].reason == "stopped"
    assert len(got) >= 20
    m = got[-1]
    yaw_deg = math.degrees(math.atan2(2 * (m.q1 * m.q4 + m.q2 * m.q3), 1 - 2 * (m.q3**2 + m.q4**2)))
    assert abs(want_deg) > 5  # the test means something only where the declination is large
    assert yaw_deg == pytest.approx(want_deg, abs=1.0)


# ---------------------------------------------------------------------------- pipeline.out_identity
# QGroundControl before 4.2 draws any component's ATTITUDE_QUATERNION of the vehicle's system on its
# HUD (docs/ecosystem.md#qgroundcontrol): there the default (component 191 of the vehicle) would
# replace the autopilot's attitude; `separate-vehicle` sends as a vehicle of its own, `none` nothing.
FIXED_WING, ARDUPILOT, GENERIC, INVALID, ONBOARD_CONTROLLER = 1, 3, 0, 8, 18  # MAV_TYPE_*, MAV_AUTOPILOT_*


def _fly_identity(
    gcs: socket.socket, pipeline: Any, log: Any = None, echo: Any = None
) -> tuple[Daemon, list[Any], list[Any]]:
    """The real daemon and pipeline, a level ArduPilot plane at 400 Hz: (daemon, at the GCS, at the autopilot).

    It flies for at least 1.5 s and until the pipeline has made 50 estimates (a loaded machine
    runs the loop slower; a deadline of 60 s only a real failure reaches), with the plane's
    HEARTBEAT at 0 s and 1 s, exactly twice.
    """
    from mavahrs.service.daemon import build_daemon

    d = build_daemon(DaemonSettings(
        master="udpin:127.0.0.1:0", outputs=(f"udpout:127.0.0.1:{gcs.getsockname()[1]}",), status_interval_s=0.0,
        log_path=str(log) if log else None,
    ), pipeline)  # fmt: skip
    ap = Autopilot(d.master.local_address[1])
    plane = ap.codec.encode(ap.codec.mav.heartbeat_encode(FIXED_WING, ARDUPILOT, 0, 0, 4))
    thread, box = _start(d)
    try:
        start = time.monotonic()
        heartbeats = 0
        while time.monotonic() < start + 1.5 or d.pipeline.outputs_sent < 50:
            assert time.monotonic() < start + 60, f"{d.pipeline.outputs_sent} estimates in 60 s"
            if heartbeats < 2 and time.monotonic() >= start + heartbeats:
                ap.sock.sendto(plane, ap.addr)
                heartbeats += 1
            ap.imu(8)
            if echo is not None:
                ap.sock.sendto(echo(), ap.addr)
            time.sleep(0.02)
        # until the daemon has estimated everything it received (its count still for 0.3 s; the deadline is
        # only reached by a stuck daemon), then what it sent
        seen, still_since, deadline = -1, time.monotonic(), time.monotonic() + 30.0
        while time.monotonic() - still_since < 0.3 and time.monotonic() < deadline:
            if d.pipeline.outputs_sent != seen:
                seen, still_since = d.pipeline.outputs_sent, time.monotonic()
            time.sleep(0.02)
        at_gcs = _drain(gcs, 0.3)
        at_ap = ap.received()
    finally:
        d.stop()
        thread.join(5)
        ap.close()
    assert box["result"].reason == "stopped"
    return d, at_gcs, at_ap


def _senders(msgs: list[Any], kind: str) -> set[tuple[int, int]]:
    return {(m.get_srcSystem(), m.get_srcComponent()) for m in msgs if m.get_type() == kind}


def test_out_identity_default_is_component_191_of_the_vehicle(gcs: socket.socket) -> None:
    from mavahrs.service.pipeline import PipelineSettings

    _, at_gcs, at_ap = _fly_identity(gcs, PipelineSettings(filter_name="mahony"))
    assert _senders(at_gcs, "ATTITUDE_QUATERNION") == {(1, 191)}
    assert _senders(at_ap, "ATTITUDE_QUATERNION") == {(1, 191)}  # routed on by the autopilot
    assert {(m.type, m.autopilot) for m in at_gcs if m.get_type() == "HEARTBEAT"} == {(ONBOARD_CONTROLLER, INVALID)}


def test_out_identity_separate_vehicle_is_a_system_of_its_own(gcs: socket.socket) -> None:
    from mavahrs.service.pipeline import PipelineSettings

    _, at_gcs, at_ap = _fly_identity(gcs, PipelineSettings(filter_name="mahony", out_identity="separate-vehicle"))
    assert sum(m.get_type() == "ATTITUDE_QUATERNION" for m in at_gcs) >= 40  # 50 Hz for about 1.5 s
    for msgs in (at_gcs, at_ap):
        assert _senders(msgs, "ATTITUDE_QUATERNION") == {(42, 1)}
        assert _senders(msgs, "HEARTBEAT") == {(42, 1)}
        # nothing claims the autopilot's system: its HUD keeps the autopilot's attitude
        assert all(m.get_srcSystem() != 1 for m in msgs if m.get_type() != "COMMAND_LONG")
    # a vehicle to a ground station (the autopilot's vehicle type), not an onboard controller
    assert {(m.type, m.autopilot) for m in at_gcs if m.get_type() == "HEARTBEAT"} == {(FIXED_WING, GENERIC)}
    requests = [m for m in at_ap if m.get_type() == "COMMAND_LONG"]
    assert requests and all((m.target_system, m.target_component) == (1, 1) for m in requests)


def test_out_identity_separate_vehicle_with_a_chosen_system_id(gcs: socket.socket) -> None:
    from mavahrs.service.pipeline import PipelineSettings

    settings = PipelineSettings(filter_name="mahony", out_identity="separate-vehicle", system_id=7)
    _, at_gcs, _ = _fly_identity(gcs, settings)
    assert _senders(at_gcs, "ATTITUDE_QUATERNION") == {(7, 1)}


def test_out_identity_none_sends_nothing_but_records_the_attitude(gcs: socket.socket, tmp_path: Any) -> None:
    from mavahrs.protocol.tlog import read_tlog_messages
    from mavahrs.service.pipeline import PipelineSettings

    log = tmp_path / "flight.tlog"
    d, at_gcs, at_ap = _fly_identity(gcs, PipelineSettings(filter_name="mahony", out_identity="none"), log)
    assert at_gcs == []
    assert {m.get_type() for m in at_ap} == {"COMMAND_LONG"}  # the stream requests only
    assert d.counters.attitudes_out == 0 and d.counters.frames_to_outputs == 0
    assert d.pipeline.outputs_sent >= 40  # estimated all the same …
    assert len(list(read_tlog_messages(log, "ATTITUDE_QUATERNION"))) == d.pipeline.outputs_sent  # … and recorded


def test_a_separate_vehicles_own_heartbeat_relayed_back_is_not_the_autopilots(gcs: socket.socket) -> None:
    """A router that echoes our HEARTBEAT (MAV_AUTOPILOT_GENERIC, system 42) must not keep the autopilot 'alive'."""
    from mavahrs.service.pipeline import PipelineSettings

    ours = MavCodec(42, 1)
    echoes: list[bytes] = []

    def echo() -> bytes:  # each with the next sequence number, as relayed frames have
        echoes.append(ours.encode(ours.mav.heartbeat_encode(FIXED_WING, GENERIC, 0, 0, 4)))
        return echoes[-1]

    d, _, _ = _fly_identity(gcs, PipelineSettings(filter_name="mahony", out_identity="separate-vehicle"), echo=echo)
    assert len(echoes) > 40
    assert d._heartbeats == 2  # noqa: SLF001 - the plane's, at 0 s and 1 s; none of the echoes
    assert d.pipeline.source == (1, 1)
    assert "other_autopilot_heartbeats" not in d.pipeline.status().counters


def test_start_and_stop_lines_read_well(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The start line shows the port a ``udpin:…:0`` master got; the stop line says why and how the log ended."""
    from mavahrs.service.sinks import TlogSink

    records: list[logging.LogRecord] = []
    log = logging.getLogger("mavahrs.test.daemon-lines")
    log.setLevel(logging.INFO)
    log.propagate = False
    handler = logging.Handler()
    handler.emit = records.append  # type: ignore[method-assign]
    log.addHandler(handler)
    settings = DaemonSettings(master="udpin:127.0.0.1:0", status_interval_s=0.0)
    master = open_transport(settings.master)
    port = master.local_address[1]
    sink = TlogSink(tmp_path / "d.tlog", 1.0)
    d = Daemon(settings, FakePipeline(), master, [], sink=sink, logger=log)
    thread, box = _start(d)
    time.sleep(0.3)
    d.stop()
    thread.join(5)
    log.removeHandler(handler)
    assert box["result"].reason == "stopped"
    lines = [r.getMessage() for r in records]
    assert lines[0].startswith(f"mavahrs running: master udpin:127.0.0.1:{port}; outputs none; log {tmp_path / 'd.tlog'}")
    assert lines[-1].startswith("mavahrs stopped (on request) after ")
    # nothing arrived: the empty file the run created is removed (the sink logs that on its own logger)
    assert lines[-1].endswith(" s: 0 messages in, 0 attitudes out, 0 dropped by the input queue, log 0 frames (nothing recorded: "
                              "empty file removed)")  # fmt: skip
    assert not (tmp_path / "d.tlog").exists()
