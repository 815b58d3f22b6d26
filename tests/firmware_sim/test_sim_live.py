"""The simulator over real links (UDP socket, pty serial, TCP) with pymavlink as the client.

These run in real time (a few seconds each): marked slow, kept because they
are the only proof that the pacing and the transports deliver what the
endpoint schedules.  Rates are measured by arrival count over a wall-clock
window of a few seconds.
"""

from __future__ import annotations

import os
import socket
import time
import tty
from typing import Any

import pytest
from pymavlink import mavutil

from firmware_sim.endpoint import DENIED_TEXT

MAV = mavutil.mavlink
pytestmark = pytest.mark.slow


def _connect(spec: str, **kw: Any) -> Any:
    m = mavutil.mavlink_connection(spec, source_system=255, source_component=190, **kw)
    sock = getattr(m, "port", None)
    if isinstance(sock, socket.socket):  # a loaded test machine may stall us briefly: do not lose data
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    m.mav.heartbeat_send(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0)  # lets a udpin peer learn us
    hb = m.wait_heartbeat(timeout=20)
    assert hb is not None, "no HEARTBEAT from the simulator"
    assert hb.autopilot == MAV.MAV_AUTOPILOT_ARDUPILOTMEGA
    return m


def _request(m: Any, msg_id: int, hz: float) -> tuple[int, list[str]]:
    """SET_MESSAGE_INTERVAL; returns (ACK result, STATUSTEXTs seen meanwhile)."""
    m.mav.command_long_send(1, 1, MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 1e6 / hz, 0, 0, 0, 0, 0)
    texts: list[str] = []
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        msg = m.recv_match(type=["COMMAND_ACK", "STATUSTEXT"], blocking=True, timeout=0.5)
        if msg is None:
            continue
        if msg.get_type() == "STATUSTEXT":
            texts.append(msg.text)
        elif msg.command == MAV.MAV_CMD_SET_MESSAGE_INTERVAL:
            # the STATUSTEXT follows the ACK in the same burst
            more = m.recv_match(type="STATUSTEXT", blocking=True, timeout=0.3)
            if more is not None:
                texts.append(more.text)
            return int(msg.result), texts
    pytest.fail("no COMMAND_ACK for SET_MESSAGE_INTERVAL")


def _rates(m: Any, seconds: float) -> dict[str, float]:
    """Messages per second by type over ``seconds`` of the simulator's own clock.

    The clock is the newest ``time_usec`` / ``time_boot_ms`` received.  A starved simulator runs
    behind real time (it re-anchors its schedule, never skips samples) and a starved receiver reads
    late, so an arrival count per wall-clock second measures the machine's load, not the rates.
    """
    deadline = time.monotonic() + 0.3
    while time.monotonic() < deadline:  # let the new rates settle, drop the backlog
        m.recv_match(blocking=True, timeout=0.05)

    def clock_us(msg: Any) -> int | None:
        if hasattr(msg, "time_usec"):
            return int(msg.time_usec)
        if hasattr(msg, "time_boot_ms"):
            return int(msg.time_boot_ms) * 1000
        return None

    counts: dict[str, int] = {}
    t0_us = now_us = None
    give_up = time.monotonic() + 120.0  # only a simulator that stopped streaming reaches this
    while time.monotonic() < give_up:
        msg = m.recv_match(blocking=True, timeout=0.05)
        if msg is None:
            continue
        t_us = clock_us(msg)
        if t_us is not None:
            if t0_us is None:
                t0_us = now_us = t_us
                continue  # the window opens at the first stamped message
            now_us = max(now_us, t_us)
        if t0_us is None:
            continue
        if now_us - t0_us >= seconds * 1e6:
            break
        counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
    elapsed_s = ((now_us or 0) - (t0_us or 0)) / 1e6
    assert elapsed_s > 0, f"no timestamped message in {seconds} s of the simulator's clock"
    return {k: v / elapsed_s for k, v in counts.items()}


def _check_250_100_and_400_denied(m: Any) -> None:
    assert _request(m, MAV.MAVLINK_MSG_ID_RAW_IMU, 250.0)[0] == MAV.MAV_RESULT_ACCEPTED
    assert _request(m, MAV.MAVLINK_MSG_ID_HIGHRES_IMU, 100.0)[0] == MAV.MAV_RESULT_ACCEPTED
    rates = _rates(m, 2.5)
    assert rates.get("RAW_IMU", 0.0) == pytest.approx(250.0, rel=0.05), rates
    assert rates.get("HIGHRES_IMU", 0.0) == pytest.approx(100.0, rel=0.05), rates
    result, texts = _request(m, MAV.MAVLINK_MSG_ID_RAW_IMU, 400.0)
    assert result == MAV.MAV_RESULT_DENIED
    assert DENIED_TEXT in texts


def test_udp_set_message_interval_rates_and_denial(run_sim) -> None:  # type: ignore[no-untyped-def]
    with run_sim("--out", "udpin:127.0.0.1:0", "--duration", "0", "--scenario", "hover") as (proc, info):
        port = int(info["LINK"].rsplit(":", 1)[1])
        m = _connect(f"udpout:127.0.0.1:{port}")
        try:
            _check_250_100_and_400_denied(m)
        finally:
            m.close()
        # the peer goes away and a new one (another port) comes: it is served at once
        m2 = _connect(f"udpout:127.0.0.1:{port}")
        try:
            assert m2.recv_match(type="RAW_IMU", blocking=True, timeout=5) is not None
        finally:
            m2.close()
        assert proc.poll() is None


def test_pty_serial_rates_and_reopen(run_sim) -> None:  # type: ignore[no-untyped-def]
    with run_sim("--out", "pty", "--duration", "0", "--scenario", "hover") as (proc, info):
        path = info["PTY"]
        m = _connect(path, baud=921600)
        try:
            _check_250_100_and_400_denied(m)
        finally:
            m.close()
        m2 = _connect(path, baud=921600)  # the port is closed and opened again
        try:
            assert m2.recv_match(type="RAW_IMU", blocking=True, timeout=5) is not None
        finally:
            m2.close()
        assert proc.poll() is None


def test_loop_rate_800_accepts_and_delivers_400_hz(run_sim) -> None:  # type: ignore[no-untyped-def]
    with run_sim("--out", "udpin:127.0.0.1:0", "--duration", "0", "--loop-rate", "800") as (proc, info):
        m = _connect(f"udpout:127.0.0.1:{int(info['LINK'].rsplit(':', 1)[1])}")
        try:
            assert _request(m, MAV.MAVLINK_MSG_ID_RAW_IMU, 400.0)[0] == MAV.MAV_RESULT_ACCEPTED
            rates = _rates(m, 2.0)
            # 2 ms kept (whole ms), so 500 messages a second: 400 samples, one message in five sent twice
            assert rates.get("RAW_IMU", 0.0) == pytest.approx(500.0, rel=0.05), rates
        finally:
            m.close()


def test_tcp_server_serves_a_client_that_reconnects(run_sim) -> None:  # type: ignore[no-untyped-def]
    with run_sim("--out", "tcpin:127.0.0.1:0", "--duration", "0", "--preset", "bench") as (proc, info):
        port = int(info["LINK"].rsplit(":", 1)[1])
        for _ in range(2):
            m = _connect(f"tcp:127.0.0.1:{port}")
            try:
                assert m.recv_match(type="SIMSTATE", blocking=True, timeout=5) is not None
            finally:
                m.close()
            time.sleep(0.2)
        assert proc.poll() is None


def test_udpout_keeps_streaming_without_a_listener(run_sim) -> None:  # type: ignore[no-untyped-def]
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()  # nobody listens there now: sends are refused (ICMP) and must not stop the simulator
    with run_sim("--out", f"udpout:127.0.0.1:{port}", "--duration", "0", "--preset", "bench") as (proc, _):
        time.sleep(1.0)
        assert proc.poll() is None
        listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        listener.bind(("127.0.0.1", port))
        listener.settimeout(5.0)
        try:
            data, _ = listener.recvfrom(65535)  # the listener appears: data arrives
            assert data[:1] == b"\xfd"
        finally:
            listener.close()


def test_serial_device_path_at_a_baud_rate_carries_what_fits(run_sim) -> None:  # type: ignore[no-untyped-def]
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    master, slave = os.openpty()  # we play the companion on the master; the simulator opens the slave
    tty.setraw(slave)
    path = os.ttyname(slave)
    try:
        with run_sim("--out", path, "--baud", "57600", "--duration", "0", "--default-stream-hz", "0",
                     "--stream", "RAW_IMU=250") as (proc, info):
            assert path in info["LINK"]
            parser = dialect.MAVLink(None)
            parser.robust_parsing = True
            os.set_blocking(master, False)
            # counted over 2.5 s of the simulator's own clock (RAW_IMU's time_usec): the link's budget is per
            # simulated second, and a loaded machine runs the simulator slower than the wall clock (72 per wall
            # second at load 16-20); the wall-clock deadline only bounds a run that went wrong
            deadline = time.monotonic() + 120.0
            counts: dict[str, int] = {}
            imu_us: list[int] = []
            while not (len(imu_us) > 1 and imu_us[-1] - imu_us[0] >= 2_500_000):
                assert time.monotonic() < deadline and proc.poll() is None, (counts, imu_us[-1:])
                try:
                    data = os.read(master, 65536)
                except BlockingIOError:
                    time.sleep(0.01)
                    continue
                for msg in parser.parse_buffer(data) or []:
                    counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
                    if msg.get_type() == "RAW_IMU":
                        imu_us.append(int(msg.time_usec))
            rate = (len(imu_us) - 1) / ((imu_us[-1] - imu_us[0]) * 1e-6)
            # 57600 baud ≈ 5760 B/s: about 140 RAW_IMU (41 B) per second, not the 250 requested
            assert 100.0 < rate < 150.0, (rate, counts)
            assert proc.poll() is None
    finally:
        os.close(master)
        os.close(slave)
