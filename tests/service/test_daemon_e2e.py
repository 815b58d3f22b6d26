"""``mavahrs run`` against ``firmware_sim`` over real UDP sockets and a pty serial pair.

Both programs run as subprocesses, as a user runs them.  The simulator streams
RAW_IMU at 400 Hz (``--ideal``: sample-time stamps, one fresh sample per
400 Hz loop tick) and SIMSTATE truth in the same tick (the same datagram); the
daemon records everything in and out (``--log``), so the truth of every
answered sample is found in its own tlog.  Checked:

* ≥ 99 % of the IMU samples that reached the daemon produce an
  ATTITUDE_QUATERNION (``--out-rate 0``), from component 191 with the
  vehicle's system id, stamped with the sample's ``time_boot_ms``;
* the attitude matches SIMSTATE within the filter's accuracy on the
  ``aggressive`` scenario (inclination and heading RMS);
* the simulator saw our HEARTBEATs and COMMAND_LONG SET_MESSAGE_INTERVAL;
* 2 s of silence (``--blackout``) and a simulator restart (new process, new
  port or a new pty behind the same link name) are recovered from;
* SIGTERM ends the daemon with exit code 0 and a complete tlog.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mavahrs.evaluation.metrics import attitude_errors_rad
from mavahrs.geometry.rotation import from_euler_rad
from mavahrs.protocol.codec import MavCodec

pytestmark = [pytest.mark.slow, pytest.mark.skipif(os.name != "posix", reason="subprocesses, ptys")]

REPO = Path(__file__).resolve().parents[2]
RATE_HZ = 400
# Accuracy bounds on the aggressive scenario (issue 4: inclination RMS ≤ 3° with GNSS velocity);
# heading: the magnetometer with the World Magnetic Model declination, after convergence.
TILT_RMS_DEG = 3.0
HEADING_RMS_DEG = 6.0
SETTLE_S = 3.0  # convergence after start and after a gap (start-up gain boost)


def _filter_name() -> str:
    try:
        import mavahrs.filters.best  # noqa: F401
    except ModuleNotFoundError:
        return "mahony"
    return "best"


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class Daemon:
    """``python -m mavahrs run …`` with its stderr collected by a thread."""

    def __init__(self, args: list[str], cwd: Path) -> None:
        self.lines: list[str] = []
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mavahrs", "run", *args],
            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=_env(), cwd=cwd,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, text: str, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(text in line for line in self.lines):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(f"daemon never said {text!r}:\n" + "\n".join(self.lines))

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            rc = self.proc.wait(30)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(5)
        return rc

    @property
    def log(self) -> str:
        return "\n".join(self.lines)


class Collector:
    """A ground station: receives the daemon's output on a UDP port (a thread)."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # a late ground station (a loaded machine) must not lose what the daemon sent: 4 MiB, past
        # net.core.rmem_max with SO_RCVBUFFORCE where allowed (root; Linux's option 33)
        try:
            if not sys.platform.startswith("linux"):
                raise OSError("SO_RCVBUFFORCE is Linux's")
            self.sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_RCVBUFFORCE", 33), 4 << 20)
        except OSError:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.messages: list[tuple[float, Any]] = []  # (wall-clock receipt time, message)
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        codec = MavCodec()
        while not self._stop:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            now = time.time()
            self.messages.extend((now, m) for m in codec.receive_datagram(data))

    def close(self) -> None:
        self._stop = True
        self._thread.join(5)
        self.sock.close()


def _sim(args: list[str], cwd: Path, **kw: Any) -> subprocess.Popen:
    kw.setdefault("stdout", subprocess.DEVNULL)
    return subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--ideal", "--stream", f"SIMSTATE={RATE_HZ}", "-q", *args],
        cwd=cwd, env=_env(), text=True, **kw,
    )


def _session(t_wall_s: float, boundaries: tuple[float, ...]) -> int:
    """Which simulator run a wall-clock time belongs to (``boundaries``: start times of runs 1, 2, …)."""
    return sum(t_wall_s >= b for b in boundaries)


def _read_daemon_tlog(
    path: Path, boundaries: tuple[float, ...]
) -> tuple[dict[tuple[int, int], np.ndarray], list[tuple[int, int]], int]:
    """From the daemon's tlog (read with pymavlink, as other tools read it): truth quaternion per
    (session, time_ms) from the SIMSTATE sent in the same tick (same datagram, same record time)
    as each RAW_IMU, the (session, time_ms) of every RAW_IMU received, and the frames we sent."""
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    imu_keys: list[tuple[int, int]] = []
    truth: dict[tuple[int, int], np.ndarray] = {}
    sent = 0
    pending: tuple[float, int, int] | None = None  # (record time, session, imu ms) waiting for its SIMSTATE
    try:
        while True:
            msg = mlog.recv_msg()
            if msg is None:
                break
            if msg.get_srcComponent() == 191:
                sent += 1
                continue
            kind = msg.get_type()
            if kind == "RAW_IMU":
                key = (_session(msg._timestamp, boundaries), msg.time_usec // 1000)
                imu_keys.append(key)
                pending = (msg._timestamp, *key)
            elif kind == "SIMSTATE" and pending is not None and pending[0] == msg._timestamp:
                truth[pending[1:]] = from_euler_rad(msg.roll, msg.pitch, msg.yaw)
                pending = None
    finally:
        mlog.close()
    return truth, imu_keys, sent


def _attitudes(
    messages: list[tuple[float, Any]], boundaries: tuple[float, ...]
) -> list[tuple[int, int, np.ndarray, int, int]]:
    """(session, time_boot_ms, q, system id, component id) of every ATTITUDE_QUATERNION received."""
    return [
        (_session(t, boundaries), m.time_boot_ms, np.array([m.q1, m.q2, m.q3, m.q4]), m.get_srcSystem(),
         m.get_srcComponent())
        for t, m in messages
        if m.get_type() == "ATTITUDE_QUATERNION"
    ]


def _check_session(
    session: int,
    imu_keys: list[tuple[int, int]],
    attitudes: list[tuple[int, int, np.ndarray, int, int]],
    truth: dict[tuple[int, int], np.ndarray],
    exclude_ms: tuple[tuple[float, float], ...] = (),
    check_heading: bool = True,
) -> dict[str, float]:
    received = {ms for s, ms in imu_keys if s == session}
    answered = {ms: q for s, ms, q, _, _ in attitudes if s == session}
    assert received, f"session {session}: no IMU samples reached the daemon"
    fraction = len(received & set(answered)) / len(received)
    missing = sorted(received - set(answered))
    assert fraction >= 0.99, (
        f"session {session}: only {fraction:.2%} of {len(received)} samples answered; "
        f"missing {len(missing)}: {missing[:8]} … {missing[-3:]} (samples {min(received)}…{max(received)} ms)"
    )
    t0 = min(received)
    keys = [
        ms for ms in sorted(answered)
        if (session, ms) in truth
        and ms - t0 >= SETTLE_S * 1000
        and not any(a <= ms - t0 < b for a, b in exclude_ms)
    ]
    with_truth = sum(1 for ms in answered if (session, ms) in truth)
    assert len(keys) > RATE_HZ, (
        f"session {session}: too few samples with truth to compare ({len(keys)}; {with_truth} of "
        f"{len(answered)} answered have truth; samples from {t0} to {max(received)} ms)"
    )
    q_est = np.array([answered[k] for k in keys])
    q_ref = np.array([truth[(session, k)] for k in keys])
    _, heading, tilt = attitude_errors_rad(q_est, q_ref)
    tilt_rms = float(np.degrees(np.sqrt(np.mean(tilt**2))))
    heading_rms = float(np.degrees(np.sqrt(np.mean(heading**2))))
    assert tilt_rms <= TILT_RMS_DEG, f"session {session}: inclination RMS {tilt_rms:.2f}°"
    if check_heading:
        assert heading_rms <= HEADING_RMS_DEG, f"session {session}: heading RMS {heading_rms:.2f}°"
    return {"fraction": fraction, "tilt_rms_deg": tilt_rms, "heading_rms_deg": heading_rms, "n": len(keys)}


def _sim_saw_us(stats_path: Path) -> None:
    stats = json.loads(stats_path.read_text())
    received = stats["received"]
    assert received.get("HEARTBEAT", 0) >= 2, received
    assert received.get("COMMAND_LONG", 0) >= 1, received
    assert stats["commands"].get("MAV_CMD_SET_MESSAGE_INTERVAL", 0) >= 1, stats["commands"]
    assert received.get("ATTITUDE_QUATERNION", 0) > 0  # our output also goes back to the autopilot link


def test_udp_400hz_accuracy_silence_and_restart(tmp_path: Path) -> None:
    port = _free_udp_port()
    gcs = Collector()
    daemon = Daemon(
        ["--master", f"udpin:127.0.0.1:{port}", "--out", f"udpout:127.0.0.1:{gcs.port}", "--filter", _filter_name(),
         "--out-rate", "0", "--log", "daemon.tlog", "--status-interval", "2", "--heartbeat-timeout", "60",
         "--stats-json", "daemon.json"],
        tmp_path,
    )
    try:
        daemon.wait_for("mavahrs running")
        # session 0: 12 s of aggressive flight with 2 s of silence from 5 s
        sim = _sim(["--out", f"udpout:127.0.0.1:{port}", "--scenario", "aggressive", "--duration", "12",
                    "--seed", "1", "--blackout", "5:2", "--stats-json", "sim1.json"], tmp_path)
        assert sim.wait(90) == 0
        # the answers are put in sessions by when they arrive: wait until the daemon has answered the flight's
        # end (its last samples, 11.99 s on the flight's clock; a loaded machine answers them seconds late)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any(
            m.get_type() == "ATTITUDE_QUATERNION" and m.time_boot_ms >= 11950 for _, m in list(gcs.messages)
        ):
            time.sleep(0.05)
        # session 1: the simulator restarts (new process, new source port, clock from zero)
        boundaries = (time.time(),)
        sim = _sim(["--out", f"udpout:127.0.0.1:{port}", "--scenario", "aggressive", "--duration", "6",
                    "--seed", "2", "--stats-json", "sim2.json"], tmp_path)
        assert sim.wait(60) == 0
        time.sleep(0.3)
    finally:
        rc = daemon.stop()
        gcs.close()
    print(daemon.log)  # shown by pytest when a check below fails
    assert rc == 0, daemon.log
    assert "mavahrs stopped (SIGTERM)" in daemon.log and "Traceback" not in daemon.log

    truth, imu_keys, sent = _read_daemon_tlog(tmp_path / "daemon.tlog", boundaries)
    attitudes = _attitudes(gcs.messages, boundaries)
    assert {(sysid, compid) for _, _, _, sysid, compid in attitudes} == {(1, 191)}
    assert sent >= len(attitudes)  # the tlog holds what went out, too
    silence_end_ms = 7000.0  # the blackout covers simulation time 5…7 s
    s0 = _check_session(0, imu_keys, attitudes, truth, exclude_ms=((5000.0, silence_end_ms + SETTLE_S * 1000),))
    s1 = _check_session(1, imu_keys, attitudes, truth)
    # after the silence: answered again, and accurate again on its own
    after = _check_session(0, imu_keys, attitudes, truth, exclude_ms=((0.0, silence_end_ms + SETTLE_S * 1000),))
    assert after["n"] >= RATE_HZ, "the stream did not come back after the silence"
    _sim_saw_us(tmp_path / "sim1.json")
    _sim_saw_us(tmp_path / "sim2.json")  # stream requests and heartbeats resumed after the restart
    stats = json.loads((tmp_path / "daemon.json").read_text())
    # the daemon keeps up with 400 Hz; on a loaded machine, not scheduled for longer than its input queue
    # holds (256 datagrams), it sheds the oldest — counted, and within the 1 % the answered fraction allows
    assert stats["counters"]["pipeline_errors"] == 0
    assert stats["counters"]["input_dropped"] <= 0.01 * stats["counters"]["datagrams_in"], stats["counters"]
    # the simulator's stream (two IMUs, GNSS, a silence, a restart) goes mostly through the fast lane,
    # and the Python path confirmed every one of its answers
    c = stats["counters"]
    assert c["fast_lane_mismatches"] == 0 and c["fast_lane_answers"] >= 0.5 * c["attitudes_out"], c
    print(f"\nUDP e2e: session 0 {s0}, after the silence {after}, session 1 {s1}, latency {stats['latency']}, "
          f"fast lane {c['fast_lane_answers']} of {c['attitudes_out']} attitudes")


_FILTER_RATE = re.compile(r"→ filter (\d+) Hz")


def test_a_radio_dropout_is_not_taken_for_an_autopilot_ignoring_the_requests(tmp_path: Path) -> None:
    """13 s of silence (longer than the 10 s re-request interval) within the heartbeat timeout: the unanswered
    requests are re-sent, not counted as refused (no fall-back to REQUEST_DATA_STREAM, which before this
    fix came 3 s into the silence); the autopilot's ATTITUDE rate is measured like the IMU's."""
    port = _free_udp_port()
    daemon = Daemon(
        ["--master", f"udpin:127.0.0.1:{port}", "--filter", _filter_name(), "--status-interval", "1",
         "--heartbeat-timeout", "60", "--set", "pipeline.heartbeat_timeout_s=30", "--stats-json", "daemon.json"],
        tmp_path,
    )
    sim = None
    try:
        daemon.wait_for("mavahrs running")
        sim = _sim(["--out", f"udpout:127.0.0.1:{port}", "--scenario", "hover", "--duration", "0", "--seed", "1",
                    "--blackout", "6:13"], tmp_path)
        daemon.wait_for("no IMU messages from the autopilot", timeout_s=90)  # the silence has begun
        n_silent = len(daemon.lines)
        deadline = time.monotonic() + 60
        flowing = 0  # status lines with the IMU stream back at its accepted rate, after the silence
        while flowing < 3 and time.monotonic() < deadline:
            time.sleep(0.2)
            flowing = sum(m is not None and int(m.group(1)) >= 200
                          for m in map(_FILTER_RATE.search, daemon.lines[n_silent:]))
        assert flowing >= 3, daemon.log
    finally:
        rc = daemon.stop()
        if sim is not None:
            sim.terminate()
            sim.wait(30)
    print(daemon.log)
    assert rc == 0 and "Traceback" not in daemon.log
    assert "REQUEST_DATA_STREAM" not in daemon.log  # silence is not a refusal
    streams = {st["message"]: st for st in json.loads((tmp_path / "daemon.json").read_text())["pipeline"]["streams"]}
    assert streams["RAW_IMU"]["mode"] == "command", streams
    assert streams["ATTITUDE"]["accepted_hz"] == 10.0 and streams["ATTITUDE"]["delivered_hz"] >= 5.0, streams


def test_pty_serial_400hz_and_device_replug(tmp_path: Path) -> None:
    link = tmp_path / "ttySIM"
    gcs = Collector()

    def start_sim(scenario: str, duration: str, seed: str, stats: str) -> subprocess.Popen:
        sim = _sim(["--out", f"pty:{link}", "--scenario", scenario, "--duration", duration,
                    "--seed", seed, "--stats-json", stats], tmp_path, stdout=subprocess.PIPE)
        assert sim.stdout is not None
        line = sim.stdout.readline()
        assert line.startswith("PTY "), line
        return sim

    # The daemon can only open the pty once it exists, and its start-up time varies, so it joins
    # this run at an unknown moment: the vehicle is on the ground then (a join in the air would
    # measure start-up convergence, not the link); the flight is the second run.
    sim = start_sim("rest", "0", "3", "sim1.json")  # runs until stopped
    daemon = Daemon(
        ["--master", f"{link},921600", "--out", f"udpout:127.0.0.1:{gcs.port}", "--filter", _filter_name(),
         "--out-rate", "0", "--log", "daemon.tlog", "--status-interval", "2", "--heartbeat-timeout", "60"],
        tmp_path,
    )
    try:
        daemon.wait_for("using IMU")
        # a flight of 6 s answered, on the flight's own clock (a loaded machine runs the simulator and the
        # daemon slower than real time) …
        deadline = time.monotonic() + 120
        while True:
            stamps = [m.time_boot_ms for _, m in list(gcs.messages) if m.get_type() == "ATTITUDE_QUATERNION"]
            if stamps and max(stamps) - min(stamps) >= 6000:
                break
            assert time.monotonic() < deadline and sim.poll() is None, (stamps[:1], stamps[-1:], daemon.log)
            time.sleep(0.05)
        sim.send_signal(signal.SIGTERM)  # … then the "device" goes away (the simulator closes the pty)
        assert sim.wait(30) == 0
        sim.stdout.close()
        daemon.wait_for(f"serial port {link} lost")
        boundaries = (time.time(),)
        sim = start_sim("aggressive", "6", "4", "sim2.json")  # … and comes back behind the same name
        assert sim.wait(60) == 0
        sim.stdout.close()
        time.sleep(0.3)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
        rc = daemon.stop()
        gcs.close()
    print(daemon.log)  # shown by pytest when a check below fails
    assert rc == 0, daemon.log
    assert "restored" in daemon.log, daemon.log
    truth, imu_keys, _ = _read_daemon_tlog(tmp_path / "daemon.tlog", boundaries)
    attitudes = _attitudes(gcs.messages, boundaries)
    s0 = _check_session(0, imu_keys, attitudes, truth)
    s1 = _check_session(1, imu_keys, attitudes, truth)
    _sim_saw_us(tmp_path / "sim1.json")
    _sim_saw_us(tmp_path / "sim2.json")
    print(f"\npty e2e: session 0 {s0}, session 1 {s1}")
