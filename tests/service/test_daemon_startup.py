"""A cold start: what the autopilot sent while the daemon was starting is old, and is not handled as live.

``build_daemon`` opens the links first (a busy port is reported before the filter
compiles) and then compiles the filter, which takes tens of seconds on a fresh
install; meanwhile the operating system queues the autopilot's datagrams.  Here
the real ``build_daemon`` and the real pipeline run, over real UDP sockets; the
autopilot streams its RAW_IMU into the bound port *while the filter is being
prepared* (the filter's ``warm_up`` sends them before it does its own work, so
the backlog is certain without waiting on a clock).  Then, once the daemon says
it is running, live samples follow with later boot times.  Checked: no attitude
sent on and no RAW_IMU recorded in ``--log`` comes from the backlog, and the
backlog is counted and said ("dropped N datagrams queued during start-up").
"""

from __future__ import annotations

import logging
import re
import socket
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from mavahrs.protocol.codec import MavCodec
from mavahrs.service.daemon import DaemonSettings, build_daemon

STALE = 120  # RAW_IMU queued during start-up (well within a default socket buffer)
STALE_START_US = 2_000_000  # their boot times: 2.0 s …
LIVE_START_US = 60_000_000  # live samples: from 60 s on (the daemon's start took "a minute")
RATE_US = 2500  # 400 Hz


class _Recorder(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[str] = []
        self.running = threading.Event()

    def emit(self, record: logging.LogRecord) -> None:
        msg = record.getMessage()
        self.lines.append(msg)
        if msg.startswith("mavahrs running"):
            self.running.set()


def _raw_imu(codec: MavCodec, t_us: int) -> bytes:
    return codec.encode(codec.mav.raw_imu_encode(t_us, 0, 0, -1000, 0, 0, 0, 200, 0, 400, 0, 3500))


def _heartbeat(codec: MavCodec) -> bytes:
    return codec.encode(codec.mav.heartbeat_encode(2, 3, 0, 0, 4))



def _keep_opened_links(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """The links the daemon opens, in order (``open_transport`` wrapped to keep each one)."""
    import mavahrs.transports as transports

    opened: list[Any] = []
    real_open = transports.open_transport

    def open_and_keep(*args: Any, **kw: Any) -> Any:
        link = real_open(*args, **kw)
        opened.append(link)
        return link

    monkeypatch.setattr(transports, "open_transport", open_and_keep)
    return opened

def test_datagrams_queued_during_a_cold_start_are_dropped_and_counted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.05)
    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap_codec = MavCodec(1, 1)
    opened = _keep_opened_links(monkeypatch)
    pipeline = Pipeline(PipelineSettings(out_rate_hz=0.0))  # one attitude per sample: every one is seen
    real_warm_up = pipeline.filter.warm_up
    addr: list[tuple[str, int]] = []

    def warm_up_while_the_autopilot_streams() -> None:
        addr.append(("127.0.0.1", opened[0].local_address[1]))  # the master link is open already
        ap.sendto(_heartbeat(ap_codec), addr[0])
        for k in range(STALE):
            ap.sendto(_raw_imu(ap_codec, STALE_START_US + k * RATE_US), addr[0])
        real_warm_up()

    pipeline.filter.warm_up = warm_up_while_the_autopilot_streams
    log = logging.getLogger("mavahrs.test.daemon-startup")
    log.setLevel(logging.INFO)
    log.propagate = False
    rec = _Recorder()
    log.addHandler(rec)
    tlog = tmp_path / "run.tlog"
    d = build_daemon(
        DaemonSettings(
            master="udpin:127.0.0.1:0", outputs=(f"udpout:127.0.0.1:{gcs.getsockname()[1]}",),
            status_interval_s=0.0, log_path=str(tlog), fast_lane=False,
        ),
        pipeline=pipeline, logger=log,
    )  # fmt: skip
    box: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: box.setdefault("result", d.run()), daemon=True)
    thread.start()
    live = 200
    attitudes: list[int] = []
    dec = MavCodec()
    try:
        assert rec.running.wait(60), rec.lines
        sent = 0
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(attitudes) < live:
            if sent < live:  # a heartbeat and a few samples per round, then what came back
                ap.sendto(_heartbeat(ap_codec), addr[0])
                for _ in range(10):
                    ap.sendto(_raw_imu(ap_codec, LIVE_START_US + sent * RATE_US), addr[0])
                    sent += 1
            try:
                data = gcs.recv(4096)
            except TimeoutError:
                continue
            attitudes += [m.time_boot_ms for m in dec.receive_datagram(data) if m.get_type() == "ATTITUDE_QUATERNION"]
    finally:
        d.stop()
        thread.join(10)
        log.removeHandler(rec)
        gcs.close()
        ap.close()
    assert box["result"].reason == "stopped"
    assert len(attitudes) >= live // 2, f"only {len(attitudes)} attitudes came back"
    stale = [t for t in attitudes if t < LIVE_START_US // 1000]
    assert not stale, f"{len(stale)} attitudes sent on from the start-up backlog (boot ms {stale[:5]} …)"

    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(tlog), dialect="ardupilotmega")
    imu_us = []
    while (m := mlog.recv_match(type="RAW_IMU")) is not None:
        imu_us.append(m.time_usec)
    mlog.close()
    assert imu_us and min(imu_us) >= LIVE_START_US, "the --log recording holds RAW_IMU of the backlog"

    dropped = box["result"].stats["counters"]["startup_dropped"]
    assert 0 < dropped <= STALE + 1
    said = [line for line in rec.lines if "queued during start-up" in line]
    assert len(said) == 1 and re.search(rf"\bdropped {dropped} datagrams queued during start-up", said[0]), rec.lines


def test_an_autopilot_that_went_silent_during_a_cold_start_is_not_called_no_mavlink(monkeypatch: pytest.MonkeyPatch) -> None:
    """A simulator that stopped while the filter compiled (minutes on a cold cache): its queued datagrams are
    dropped, nothing else comes, and the heartbeat time-out said '57708 bytes received but no valid MAVLink
    frame: is this a MAVLink stream?' — about a stream of valid MAVLink.  It says what happened instead."""
    from mavahrs.errors import TransportError
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    ap = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ap_codec = MavCodec(1, 1)
    opened = _keep_opened_links(monkeypatch)
    pipeline = Pipeline(PipelineSettings())
    real_warm_up = pipeline.filter.warm_up

    def warm_up_while_the_autopilot_streams_then_stops() -> None:
        to = ("127.0.0.1", opened[0].local_address[1])
        ap.sendto(_heartbeat(ap_codec), to)
        for k in range(STALE):
            ap.sendto(_raw_imu(ap_codec, STALE_START_US + k * RATE_US), to)
        real_warm_up()

    pipeline.filter.warm_up = warm_up_while_the_autopilot_streams_then_stops
    log = logging.getLogger("mavahrs.test.daemon-startup-silent")
    log.propagate = False
    d = build_daemon(DaemonSettings(master="udpin:127.0.0.1:0", status_interval_s=0.0, heartbeat_timeout_s=1.0,
                                    fast_lane=False), pipeline=pipeline, logger=log)  # fmt: skip
    try:
        with pytest.raises(TransportError) as err:
            d.run()
    finally:
        ap.close()
    said = str(err.value)
    assert "no valid MAVLink frame" not in said, said
    assert re.search(rf"all of them queued during start-up \({STALE + 1} datagrams, dropped as older than the "
                     r"filter\), none since: has the autopilot stopped sending\?", said), said  # fmt: skip


def test_a_taken_status_page_port_is_said_before_the_filter_compiles() -> None:
    """``--http`` on a port another program holds: the error comes before the (minutes-long, on a fresh install
    and a busy machine: 6 min measured) compile, as a busy autopilot port does."""
    pytest.importorskip("aiohttp")
    from mavahrs.errors import ConfigError
    from mavahrs.service.pipeline import Pipeline, PipelineSettings

    holder = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    holder.bind(("127.0.0.1", 0))
    holder.listen(1)
    pipeline = Pipeline(PipelineSettings())
    compiled: list[bool] = []
    pipeline.filter.warm_up = lambda: compiled.append(True)
    try:
        with pytest.raises(ConfigError, match="status page: cannot listen"):
            build_daemon(
                DaemonSettings(master="udpin:127.0.0.1:0", http=f"127.0.0.1:{holder.getsockname()[1]}"),
                pipeline=pipeline, logger=logging.getLogger("mavahrs.test.daemon-startup"),
            )
    finally:
        holder.close()
    assert compiled == []
