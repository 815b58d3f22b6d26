"""mavahrs between real MAVProxy instances, headless on loopback, as on a companion computer.

One session (module fixture), four programs::

    firmware_sim ──udp──▶ MAVProxy "router" (--streamrate=4) ──udp──▶ mavahrs run ──udp──▶ MAVProxy "gcs"
    (ArduPilot)           ◀── replies, our output forwarded ──          (--log)            (--streamrate=-1)

Checked:

* the ground-station MAVProxy receives ATTITUDE_QUATERNION from component 191
  (and our HEARTBEAT as an onboard controller) and writes them to its tlog;
* the router MAVProxy forwards mavahrs's SET_MESSAGE_INTERVAL commands and
  output to the autopilot, and the autopilot accepted them;
* mavahrs's own tlog reads back with pymavlink's ``mavlogdump.py``, message for
  message;
* MAVProxy with a non-negative ``--streamrate`` resets every stream rate with
  REQUEST_DATA_STREAM(ALL) every 15 s (ArduPilot applies it to RAW_IMU too):
  mavahrs sees the delivered rate collapse and wins the IMU rate back within
  a second or two (not at its next periodic request, 10 s later).
"""

from __future__ import annotations

import csv
import io
import json
import math
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytestmark = [pytest.mark.slow, pytest.mark.skipif(sys.platform == "win32", reason="process groups, signals")]

RAW_RATE_HZ = 250.0  # what the simulated ArduPilot (400 Hz loop) accepts for RAW_IMU
REREQUEST_S = 10.0  # mavahrs's stream_request_interval_s default
AFTER_RESET_S = 5.0  # session length after MAVProxy's reset: mavahrs's fast re-request (~0.5 s) + measuring window


def _messages(path: Path, types: set[str] | None = None) -> list[tuple[float, str, int, int, Any]]:
    """(tlog time s, type, source system, source component, message) of a tlog (a growing one too)."""
    from pymavlink import mavutil

    if not path.is_file():
        return []
    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    out = []
    try:
        while (m := log.recv_match()) is not None:
            kind = m.get_type()
            if types is None or kind in types:
                out.append((float(m._timestamp), kind, m.get_srcSystem(), m.get_srcComponent(), m))
    finally:
        log.close()
    return out


def _timeline(router_tlog: Path) -> tuple[float | None, list[float]]:
    """(first SET_MESSAGE_INTERVAL from mavahrs, MAVProxy's REQUEST_DATA_STREAM times), tlog seconds."""
    msgs = _messages(router_tlog, {"COMMAND_LONG", "REQUEST_DATA_STREAM"})
    first = next((t for t, k, s, c, m in msgs if k == "COMMAND_LONG" and c == 191 and int(m.command) == 511), None)
    resets = [t for t, k, s, c, m in msgs if k == "REQUEST_DATA_STREAM" and s == 255 and int(m.req_message_rate) > 0]
    return first, resets


def _udp_rcvbuf_errors() -> int | None:
    """Datagrams this machine's kernel dropped because a receiver's socket buffer was full (``/proc/net/snmp``,
    Udp RcvbufErrors), None where it cannot be read."""
    try:
        rows = [line.split() for line in Path("/proc/net/snmp").read_text().splitlines() if line.startswith("Udp:")]
        return int(rows[1][rows[0].index("RcvbufErrors")])
    except (OSError, ValueError, IndexError):
        return None


@pytest.fixture(scope="module")
def session(processes: Any, mavproxy: str, free_udp_port: Callable[[], int]) -> dict[str, Any]:
    w = processes.workdir
    a, b, c = free_udp_port(), free_udp_port(), free_udp_port()
    rcvbuf_errors_before = _udp_rcvbuf_errors()
    processes.start("router", [
        sys.executable, mavproxy, f"--master=udpin:127.0.0.1:{a}", f"--out=udpout:127.0.0.1:{b}",
        "--daemon", "--streamrate=4", "--logfile=router.tlog", f"--state-basedir={w / 'router'}",
    ])  # fmt: skip
    processes.start("gcs", [
        sys.executable, mavproxy, f"--master=udpin:127.0.0.1:{c}",
        "--daemon", "--streamrate=-1", "--logfile=gcs.tlog", f"--state-basedir={w / 'gcs'}",
    ])  # fmt: skip
    processes.start("mavahrs", [
        sys.executable, "-m", "mavahrs", "run", "--master", f"udpin:127.0.0.1:{b}", "--out", f"udpout:127.0.0.1:{c}",
        "--log", str(w / "mavahrs.tlog"), "--status-interval", "5", "--duration", "150", "--heartbeat-timeout", "0",
    ])  # fmt: skip
    processes.start("sim", [
        sys.executable, "-m", "firmware_sim", "--out", f"udpout:127.0.0.1:{a}", "--scenario", "hover",
        "--duration", "0", "-q", "--stats-json", str(w / "sim.json"),
    ])  # fmt: skip
    router_tlog = w / "router" / "router.tlog"
    deadline = time.monotonic() + 120.0
    first, resets = None, []
    while time.monotonic() < deadline:
        time.sleep(2.0)
        for name in ("mavahrs", "sim", "router", "gcs"):
            assert processes.procs[name].poll() is None, f"{name} exited early:\n{processes.output(name)[-3000:]}"
        first, resets = _timeline(router_tlog)
        later = [t for t in resets if first is not None and t > first + 2.0]
        if later and time.time() > later[0] + AFTER_RESET_S:
            break
    rc = processes.stop("mavahrs", signal.SIGTERM)
    processes.stop("sim", signal.SIGINT)
    processes.stop("router", signal.SIGTERM)
    processes.stop("gcs", signal.SIGTERM)
    rcvbuf_errors_after = _udp_rcvbuf_errors()
    return {
        "rcvbuf_drops": None if rcvbuf_errors_before is None or rcvbuf_errors_after is None
        else rcvbuf_errors_after - rcvbuf_errors_before,
        "dir": w,
        "mavahrs_rc": rc,
        "mavahrs_out": processes.output("mavahrs"),
        "first_request": first,
        "resets": resets,
        "router": router_tlog,
        "gcs": w / "gcs" / "gcs.tlog",
        "mavahrs": w / "mavahrs.tlog",
        "sim": json.loads((w / "sim.json").read_text()) if (w / "sim.json").is_file() else {},
    }


@pytest.mark.reaches_off_loopback  # MAVProxy itself tries 4 off-loopback connects (blocked by the namespace; not yet traced)
def test_ground_station_mavproxy_logs_our_attitude(session: dict[str, Any]) -> None:
    assert session["mavahrs_rc"] == 0, session["mavahrs_out"][-3000:]
    msgs = _messages(session["gcs"], {"ATTITUDE_QUATERNION", "HEARTBEAT"})
    att = [(t, m) for t, k, s, c, m in msgs if k == "ATTITUDE_QUATERNION" and (s, c) == (1, 191)]
    hb = [m for t, k, s, c, m in msgs if k == "HEARTBEAT" and (s, c) == (1, 191)]
    assert len(att) > 200, f"{len(att)} ATTITUDE_QUATERNION from 1/191 in the ground station's tlog"
    # every attitude mavahrs sent (its own tlog records what it sends) reached the ground station — but the
    # last second's: MAVProxy writes its tlog through a buffer that a SIGTERM does not flush (a CI run lost
    # exactly the last 0.5 s, 25 attitudes, all sent before the ground station was stopped)
    sent_all = [int(m.time_boot_ms) for t, k, s, c, m in _messages(session["mavahrs"], {"ATTITUDE_QUATERNION"})
                if c == 191]  # fmt: skip
    sent = {t for t in sent_all if t <= max(sent_all) - 1000}
    received = {int(m.time_boot_ms) for _, m in att}
    assert len(sent) > 200 and received
    # what the ground station logged up to its last record: a tail beyond it is MAVProxy's unflushed buffer
    # (more than the last second's when a saturated machine leaves it behind), bounded at 10 s
    inside = {t for t in sent if t <= max(received)}
    assert len(inside) >= len(sent) - 500, (len(inside), len(sent))
    # inside, on a saturated machine the ground station (Python) can fall seconds behind and its socket buffer
    # overflow: that loss is the kernel's, counted in RcvbufErrors, not ours; anything beyond 1 % the kernel
    # did not count as a full buffer fails (stress-ng at 2 CPUs once: 12 of 946 lost)
    lost = len(inside - received)
    kernel_drops = session["rcvbuf_drops"] or 0
    assert lost <= max(0.01 * len(inside), kernel_drops), (lost, len(inside), session["rcvbuf_drops"])
    q = np.array([[m.q1, m.q2, m.q3, m.q4] for _, m in att])
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)
    t_ms = np.array([m.time_boot_ms for _, m in att])
    assert np.all(np.diff(t_ms) > 0)  # stamped with the IMU samples' time, in order
    assert hb and all(int(m.type) == 18 and int(m.autopilot) == 8 for m in hb)  # ONBOARD_CONTROLLER, AUTOPILOT_INVALID


def test_router_mavproxy_forwards_our_commands_and_output(session: dict[str, Any]) -> None:
    msgs = _messages(session["router"], {"COMMAND_LONG", "COMMAND_ACK", "ATTITUDE_QUATERNION"})
    ours = [m for t, k, s, c, m in msgs if k == "COMMAND_LONG" and (s, c) == (1, 191) and int(m.command) == 511]
    assert ours and int(ours[0].param1) == 27  # SET_MESSAGE_INTERVAL for RAW_IMU
    acks = [int(m.result) for t, k, s, c, m in msgs if k == "COMMAND_ACK" and (s, c) == (1, 1) and int(m.command) == 511
            and int(m.target_component) == 191]  # fmt: skip
    assert 2 in acks and 0 in acks  # 400 Hz DENIED, then a lower rate ACCEPTED
    assert sum(1 for t, k, s, c, m in msgs if k == "ATTITUDE_QUATERNION" and (s, c) == (1, 191)) > 100
    sim = session["sim"]
    assert sim["received"].get("COMMAND_LONG", 0) >= len(ours) and sim["received"].get("REQUEST_DATA_STREAM", 0) >= 1


def test_mavahrs_tlog_reads_back_with_mavlogdump(session: dict[str, Any], mavlogdump: str) -> None:
    path = session["mavahrs"]
    r = subprocess.run(
        [sys.executable, mavlogdump, "--types", "ATTITUDE_QUATERNION,RAW_IMU,SIMSTATE", "--show-source", str(path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.splitlines()
    dumped = {k: sum(1 for x in lines if f": {k} {{" in x) for k in ("ATTITUDE_QUATERNION", "RAW_IMU", "SIMSTATE")}
    ours = sum(1 for x in lines if ": ATTITUDE_QUATERNION {" in x and "srcComponent=191" in x)
    direct = _messages(path, {"ATTITUDE_QUATERNION", "RAW_IMU", "SIMSTATE"})
    assert dumped == {k: sum(1 for _, kind, *_ in direct if kind == k) for k in dumped}
    assert ours == dumped["ATTITUDE_QUATERNION"] > 200 and dumped["RAW_IMU"] > 1000
    # CSV export, as people feed it to spreadsheets
    r = subprocess.run([sys.executable, mavlogdump, "--format", "csv", "--types", "ATTITUDE_QUATERNION", str(path)],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    rows = list(csv.DictReader(io.StringIO(r.stdout)))
    assert len(rows) == dumped["ATTITUDE_QUATERNION"]
    q = [[float(row[f"ATTITUDE_QUATERNION.q{i}"]) for i in range(1, 5)] for row in rows]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)


def _raw_imu_times(session: dict[str, Any]) -> np.ndarray:
    return np.array([t for t, k, s, c, m in _messages(session["mavahrs"], {"RAW_IMU"}) if (s, c) == (1, 1)])


def _rate(t: np.ndarray, start: float, end: float) -> float:
    return float(np.sum((t >= start) & (t < end))) / (end - start)


def _reset_after_request(session: dict[str, Any]) -> float:
    first, resets = session["first_request"], session["resets"]
    assert first is not None, "mavahrs never sent SET_MESSAGE_INTERVAL through MAVProxy"
    later = [t for t in resets if t > first + 2.0]
    assert later, f"MAVProxy sent no REQUEST_DATA_STREAM after mavahrs's request (resets at {resets})"
    return later[0]


def _recovery_s(session: dict[str, Any]) -> tuple[float, float]:
    """(seconds from MAVProxy's reset until RAW_IMU is back at ≥ 80 % of its rate before, that rate)."""
    reset = _reset_after_request(session)
    t = _raw_imu_times(session)
    # (from 1 s after mavahrs's first request at the earliest: before it, MAVProxy's start-up reset holds 4 Hz)
    before = _rate(t, max(reset - 4.0, session["first_request"] + 1.0), reset - 0.2)
    # the simulator runs in real time on a shared machine: judge against what it delivered just before
    assert before > 0.6 * RAW_RATE_HZ, f"RAW_IMU at {before:.0f} Hz before the reset, {RAW_RATE_HZ:g} Hz accepted"
    # mavahrs restores the rate within ~0.5 s now: look for the dip in 0.2 s windows after the reset (the
    # frames pass through MAVProxy, which may lag on a loaded machine)
    dip = min(_rate(t, reset + 0.05 * k, reset + 0.05 * k + 0.2) for k in range(60))
    assert dip < 0.2 * before, "the reset did not lower the rate: nothing tested"
    for k in range(int(AFTER_RESET_S * 4)):
        start = reset + 0.25 * k
        if start + 1.0 > t[-1]:
            break
        if _rate(t, start, start + 1.0) >= 0.8 * before:
            return start - reset, before
    return math.inf, before


def test_mavproxy_stream_rate_reset_is_undone_within_3_s(session: dict[str, Any]) -> None:
    # mavahrs re-requests as soon as the delivered rate collapses (0.5 s window), not at its next periodic request
    recovery_s, before = _recovery_s(session)
    assert recovery_s <= 3.0, (recovery_s, before, session["mavahrs_out"][-3000:])
    assert "RAW_IMU fell to" in session["mavahrs_out"]
