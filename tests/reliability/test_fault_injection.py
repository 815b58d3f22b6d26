"""The daemon against ``firmware_sim`` through a faulty link: UDP (loss, bit flips, junk, duplicates,
reordering, bursts, an outage) and a pty serial device (corrupted bytes, a vanishing device).

UDP: one simulator run feeds, through :class:`UdpFaultRelay`, two daemons at
once — one over a clean leg, one over a faulty leg — so the clean and faulty
runs see the very same flight (same seed, same bytes) and are compared sample
by sample.  The faulty leg carries the issue's mix (5 % of datagrams lost,
10 % with a flipped bit, 5 % followed by random junk) plus 2 % each of
truncated, duplicated and reordered datagrams, and, at stated times of the
flight's own clock, a 1 s corruption burst (half of all datagrams lost,
flipped, junk-laden), a stall of the faulty daemon (SIGSTOP until the kernel
has dropped STALL_DROPS datagrams at its full receive buffer, whatever the
buffer's size) and a 1.5 s outage; the flight is ended (SIGTERM to the
simulator) once that schedule is flown.

Checked against SIMSTATE truth (sent by the simulator in the same datagram as
each RAW_IMU, so every sample's truth is known from the relay's records):

* each daemon answers every intact IMU sample it received in order (a
  datagram whose RAW_IMU frame arrived undamaged and not behind a newer
  sample — a late sample cannot be fed to a causal filter and is dropped and
  counted as reordered) or counts it as dropped (kernel receive buffer, input
  queue, pipeline), with 1 % of slack, and answers most of them (≥ 50 %; the faulty daemon within 10 points of the clean one); the
  faulty daemon's count of kernel drops equals the kernel's own;
* its inclination RMS error is within 1° of the clean daemon's over the same
  samples under the steady mix (after start-up, outside the burst and its
  recovery time, before the outage: the outage re-initialises the faulty
  daemon's filter, after which the two no longer share a history);
* recovery: after the burst, the stall and the outage, the faulty daemon's
  inclination error is back within 1° of the clean daemon's on the same
  samples within RECOVERY_S (and stays so for 1 s);
* the counters (CRC errors, bad data, duplicates, out-of-order, lost samples,
  drops by reason) are in the daemon's status and statistics.

Serial: the same simulator through :class:`PtyFaultRelay` (chunks of the byte
stream flipped, cut short, followed by junk, lost); the device vanishes for
1.5 s and returns; checked: ≥ 99 % of the samples written intact answered,
inclination within the bound, recovery after the device returns, counters,
and — the daemon then killed with SIGKILL — a tlog readable up to the last
flush.

The scenario is ``hover``: on ``aggressive`` an accelerometer
re-initialisation after an outage mid-manoeuvre is 8–24° off for seconds
(docs/reliability.md, "Known limits"), so that flight cannot show whether a
*fault* left a lasting error.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mavahrs.transports.relay import FaultSettings, PtyFaultRelay, UdpFaultRelay

pytestmark = [pytest.mark.slow, pytest.mark.skipif(os.name != "posix", reason="subprocesses, ptys")]

SCENARIO = "hover"
#: the issue's fault mix, plus truncation, duplicates and reordering
MIX = FaultSettings(loss=0.05, bit_flip=0.10, junk=0.05, duplicate=0.02, reorder=0.02, truncate=0.02)
#: a noisy serial line: chunks of the byte stream corrupted, cut short, followed by junk, lost
PTY_MIX = FaultSettings(loss=0.02, bit_flip=0.05, truncate=0.02, junk=0.05)
BURST = FaultSettings(loss=0.5, bit_flip=0.5, junk=0.5, duplicate=0.1, reorder=0.1)
OUTAGE = FaultSettings(loss=1.0)
TILT_BOUND_DEG = 3.0  # the daemon's inclination accuracy bound on a simulated flight (issue 4: RMS ≤ 3°)
RECOVERY_S = 3.0  # stated recovery time after a fault clears
SETTLE_S = 3.0  # start-up convergence excluded from accuracy figures
STEADY_S = 4.0  # the steady mix compared between the two daemons, s of flight
STALL_DROPS = 100  # datagrams the kernel drops at the stalled daemon's full receive buffer (0.25 s of flight)


def _daemon_args(rt, port: int, gcs: int, stats: str) -> list[str]:
    return ["--master", f"udpin:127.0.0.1:{port}", "--out", f"udpout:127.0.0.1:{gcs}", "--filter", rt.filter_name(),
            "--out-rate", "0", "--status-interval", "1", "--heartbeat-timeout", "60", "--stats-json", stats]


def _answered_fraction(received_in_order: list[int], answered: dict[int, np.ndarray]) -> float:
    got = set(received_in_order)
    return len(got & set(answered)) / len(got)


def _kernel_udp_drops(port: int) -> int:
    """Datagrams the kernel dropped at a full receive buffer of the socket bound to ``port``."""
    total = 0
    with open("/proc/net/udp") as f:
        for line in f.readlines()[1:]:
            cols = line.split()
            if int(cols[1].split(":")[1], 16) == port:
                total += int(cols[-1])
    return total


def _udp_rx_queue_bytes(port: int) -> int:
    """Bytes waiting in the receive buffer of the socket bound to ``port``."""
    with open("/proc/net/udp") as f:
        for line in f.readlines()[1:]:
            cols = line.split()
            if int(cols[1].split(":")[1], 16) == port:
                return int(cols[4].split(":")[1], 16)
    return 0


def _counted_drops(stats: dict) -> int:
    """Datagrams a daemon says it dropped unanswered: kernel (full receive buffer), input queue, pipeline.

    The pipeline's ``reordered`` drops are left out: late samples are not in the in-order set anyway.
    """
    kernel = sum(int(link.get("kernel_dropped", 0)) for link in stats["links"].values())
    pipeline = sum(n for reason, n in stats["pipeline"]["drops"].items() if reason != "reordered")
    return kernel + int(stats["counters"]["input_dropped"]) + int(stats["counters"]["startup_dropped"]) + pipeline


def _in_order(ms_sequence: list[int]) -> list[int]:
    """Samples that arrived newer than everything before them (first copy only)."""
    out, newest = [], -1
    for ms in ms_sequence:
        if ms > newest:
            out.append(ms)
            newest = ms
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/net/udp and SO_RXQ_OVFL are Linux's")
def test_udp_faults_clean_vs_faulty_same_flight(rt, tmp_path: Path) -> None:
    port_clean, port_faulty = rt.free_udp_port(), rt.free_udp_port()
    gcs_clean, gcs_faulty = rt.Collector(), rt.Collector()
    clean = rt.DaemonProcess(_daemon_args(rt, port_clean, gcs_clean.port, "clean.json"), tmp_path)
    faulty = rt.DaemonProcess(_daemon_args(rt, port_faulty, gcs_faulty.port, "faulty.json"), tmp_path)
    # the flight's own clock, from the clean leg's RAW_IMU stamps: the faults are scheduled on it (a
    # loaded machine runs the simulator slower than real time, and wall-clock phases then squeeze
    # the steady window the comparison needs)
    flown_ms: list[int] = []

    def observe(leg: int, data: bytes) -> None:
        if leg == 0:
            for ms in rt.imu_ms_in([data]):
                if not flown_ms:
                    flown_ms.extend((ms, ms))
                flown_ms[1] = max(flown_ms[1], ms)

    relay = UdpFaultRelay(
        [(("127.0.0.1", port_clean), FaultSettings(), True), (("127.0.0.1", port_faulty), MIX, False)], seed=7,
        observer=observe,
    )
    relay.set_faults(1, MIX, "mix")
    # the daemon's receive buffer is the system's default (net.core.rmem_default): what a fresh socket gets
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        rcvbuf = probe.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    t_flight: dict[str, float] = {}
    sim = None
    try:
        clean.wait_for("mavahrs running")
        faulty.wait_for("mavahrs running")
        # a wall-clock bound only (the schedule follows the flight's clock): the stall below lasts until the
        # buffer overflows, at most its size over 400 datagrams/s of ≥ 134 bytes each (RAW_IMU + SIMSTATE)
        deadline = time.monotonic() + 240 + rcvbuf / (134 * 400)
        host, rport = relay.address
        # no --duration: the flight is ended below, once the schedule (which follows the stall) is flown
        sim = rt.start_sim(["--out", f"udpout:{host}:{rport}", "--scenario", SCENARIO, "--duration", "0",
                            "--seed", "11"], tmp_path)

        def flown_s() -> float:
            return (flown_ms[1] - flown_ms[0]) / 1000.0 if flown_ms else 0.0

        def fly_until(at_s: float) -> None:
            """Wait until the flight's clock reads ``at_s`` (seconds since its first sample)."""
            while flown_s() < at_s:
                assert sim.poll() is None, f"the simulator stopped at {flown_s():.2f} s of flight"
                assert time.monotonic() < deadline, f"the flight reached {flown_s():.2f} s only, not {at_s} s"
                time.sleep(0.005)

        fly_until(4.0)
        relay.set_faults(1, BURST, "burst")
        fly_until(5.0)
        # the faulty daemon not scheduled for a while (as on a loaded machine; SIGSTOP) until the kernel has
        # dropped STALL_DROPS datagrams at its full receive buffer — however large the buffer is — and those
        # drops must be counted (asserted below).  With the default 208 KiB: ~0.7 s to fill, ~1 s stalled.
        relay.set_faults(1, MIX, "stall")
        t_flight["stall"] = flown_s()
        dropped_before = _kernel_udp_drops(port_faulty)
        faulty.proc.send_signal(signal.SIGSTOP)
        try:
            while _kernel_udp_drops(port_faulty) - dropped_before < STALL_DROPS:
                assert sim.poll() is None and time.monotonic() < deadline, (
                    f"{flown_s() - t_flight['stall']:.1f} s of flight into the stall, the kernel dropped "
                    f"{_kernel_udp_drops(port_faulty) - dropped_before} datagrams (receive buffer {rcvbuf} B)")
                time.sleep(0.005)
        finally:
            faulty.proc.send_signal(signal.SIGCONT)
        t_flight["continued"] = flown_s()
        relay.set_faults(1, MIX, "mix")
        # the steady mix from the stall's recovery on, then the outage, then the mix until the end
        t_outage = t_flight["continued"] + RECOVERY_S + STEADY_S
        fly_until(t_outage)
        relay.set_faults(1, OUTAGE, "outage")
        fly_until(t_outage + 1.5)
        relay.set_faults(1, MIX, "mix")
        fly_until(t_outage + 1.5 + RECOVERY_S + 1.5)
        sim.send_signal(signal.SIGTERM)  # the simulator ends its flight (exit 0)
        assert sim.wait(60) == 0
        # the flight is over: wait until each daemon has answered the newest sample it received
        # (the event; a loaded machine can hold seconds of datagrams in the daemons' queues)
        deadline = time.monotonic() + 120
        for leg, gcs in ((0, gcs_clean), (1, gcs_faulty)):
            newest = max(rt.imu_ms_in([d for _, d in relay.sent(leg)]), default=None)
            while newest is not None and newest not in rt.attitude_map(gcs.attitudes()):
                if time.monotonic() > deadline:
                    break  # judged below: the answered fraction says what was missing
                time.sleep(0.05)
        # the kernel's drop count reaches a daemon with the next datagram it reads (a daemon late at the end
        # of the flight has drops not yet reported): one byte of junk to each, and wait until each has read
        # everything (its socket empty, the event)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as marker:
            for p in (port_clean, port_faulty):
                marker.sendto(b"\x00", ("127.0.0.1", p))
        deadline = time.monotonic() + 60
        while any(_udp_rx_queue_bytes(p) for p in (port_clean, port_faulty)) and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        if sim is not None and sim.poll() is None:
            sim.kill()
            sim.wait()
        kdrops = {n: _kernel_udp_drops(p) for n, p in (("clean_in", port_clean), ("faulty_in", port_faulty),
                                                       ("gcs_clean", gcs_clean.port), ("gcs_faulty", gcs_faulty.port))}
        rc_clean, rc_faulty = clean.stop(), faulty.stop()
        gcs_clean.close()
        gcs_faulty.close()
        relay.close()
    assert rc_clean == 0 and rc_faulty == 0, faulty.log
    assert "Traceback" not in clean.log + faulty.log

    recs = relay.records(1)
    truth = rt.truth_from_datagrams([r.original for r in recs])
    t_ms0 = min(truth)
    ans_clean = rt.attitude_map(gcs_clean.attitudes())
    ans_faulty = rt.attitude_map(gcs_faulty.attitudes())
    # what reached each daemon: RAW_IMU frames that decode from the datagrams as sent
    recv_clean = rt.imu_ms_in([d for _, d in relay.sent(0)])
    recv_faulty = rt.imu_ms_in([d for _, d in relay.sent(1)])
    in_order = _in_order(recv_faulty)
    frac_clean = _answered_fraction(_in_order(recv_clean), ans_clean)
    frac_faulty = _answered_fraction(in_order, ans_faulty)

    # fault windows in sample time, from the phase of each record
    def window(phase: str) -> tuple[float, float]:
        ms = [r_ms for r in recs if r.phase == phase for r_ms in rt.imu_ms_in([r.original])]
        return (min(ms) - t_ms0) / 1000.0, (max(ms) - t_ms0) / 1000.0

    bursts = {p: window(p) for p in ("burst", "stall", "outage")}
    # the comparison: the steady fault mix only (after start-up, before the outage, which
    # re-initialises the faulty daemon's filter and so gives it a different history from then on)
    excluded = [(0.0, SETTLE_S), (bursts["burst"][0], bursts["burst"][1] + RECOVERY_S),
                (bursts["stall"][0], bursts["stall"][1] + RECOVERY_S), (bursts["outage"][0], 1e9)]
    keys = sorted(
        k for k in set(ans_clean) & set(ans_faulty) & set(truth)
        if not any(a <= (k - t_ms0) / 1000.0 < b for a, b in excluded)
    )
    err_clean = rt.tilt_errors_deg(ans_clean, truth, keys)
    err_faulty = rt.tilt_errors_deg(ans_faulty, truth, keys)
    rms_clean, rms_faulty = rt.rms(err_clean), rt.rms(err_faulty)

    diff = rt.tilt_errors_deg(ans_faulty, ans_clean, keys)  # faulty vs clean daemon, same samples
    # recovery after each burst: until the faulty daemon's inclination error is back within 1° of the
    # clean daemon's on the same samples (the fault's effect is gone), and stays there for 1 s
    both = sorted(k for k in set(ans_clean) & set(ans_faulty) if k in truth)
    t_b = np.array([(k - t_ms0) / 1000.0 for k in both])
    excess = rt.tilt_errors_deg(ans_faulty, truth, both) - rt.tilt_errors_deg(ans_clean, truth, both)
    recovery = {p: rt.recovery_time_s(t_b, excess, b, 1.0) for p, (_, b) in bursts.items()}
    worst = {p: float(excess[(t_b >= a) & (t_b < b + RECOVERY_S)].max()) for p, (a, b) in bursts.items()}

    stats = json.loads((tmp_path / "faulty.json").read_text())
    codec, pipe = stats["codec"], stats["pipeline"]
    c = relay.counters(1)
    print(
        f"\nUDP faults: relay {c}\n answered clean {frac_clean:.2%} faulty {frac_faulty:.2%} of "
        f"{len(in_order)} intact in-order samples; tilt RMS clean {rms_clean:.2f}° faulty {rms_faulty:.2f}° "
        f"over {len(keys)} samples (difference RMS {rt.rms(diff):.2f}° max {diff.max():.2f}°); bursts {bursts}; "
        f"worst excess error {worst}; recovery {recovery}\n codec {codec}\n drops {pipe['drops']}"
        f"\n counters {pipe['counters']}\n receive buffer {rcvbuf} B; flight clock at the stall {t_flight}; "
        f"kernel drops {kdrops}; counted drops clean "
        f"{_counted_drops(json.loads((tmp_path / 'clean.json').read_text()))} faulty {_counted_drops(stats)}"
    )
    assert len(in_order) > 5000
    # On a loaded machine a daemon may not be scheduled for a while: then the kernel drops datagrams at
    # its full receive buffer, or its bounded input queue sheds the oldest.  Both are counted
    # (``links.*.kernel_dropped``, ``counters.input_dropped``, the pipeline's drops): the rule is that
    # nothing is lost *uncounted*, so every intact sample is answered or counted as dropped, and most
    # are answered (the stall above leaves ~98 % answered; a 2 s one 92 %).  How many a daemon gets to is
    # the machine's (at load 15-20 on 2 cores the *clean* daemon answered 87.5 %, all of the rest counted):
    # so "most" is a floor of one half for each, and the faults may cost the faulty daemon at most 10 points
    # more than the clean one loses on the same machine at the same time (its 1 s stall: 2 points).  Our own
    # ground stations must lose nothing (their buffers are large).
    assert kdrops["gcs_clean"] == 0 and kdrops["gcs_faulty"] == 0, kdrops
    for leg, frac, name in ((0, frac_clean, "clean.json"), (1, frac_faulty, "faulty.json")):
        n_intact = len(_in_order(recv_clean if leg == 0 else recv_faulty))
        counted = _counted_drops(json.loads((tmp_path / name).read_text()))
        unanswered = round((1.0 - frac) * n_intact)
        assert unanswered <= counted + 0.01 * n_intact, f"{name}: {unanswered} intact samples unanswered, {counted} counted"
        assert frac >= 0.50, f"{name}: only {frac:.2%} of the intact samples answered"
    assert frac_faulty >= frac_clean - 0.10, f"faulty {frac_faulty:.2%} answered, clean {frac_clean:.2%}"
    # the stall overflowed the faulty daemon's receive buffer: it counted exactly what the kernel dropped
    kernel_counted = sum(int(link.get("kernel_dropped", 0)) for link in stats["links"].values())
    assert kdrops["faulty_in"] >= STALL_DROPS and kernel_counted == kdrops["faulty_in"], (kernel_counted, kdrops)
    assert len(keys) > 1000  # the steady-mix window: 2.5 s or more of 400 Hz samples
    assert rms_clean <= TILT_BOUND_DEG
    assert abs(rms_faulty - rms_clean) <= 1.0, (rms_clean, rms_faulty)
    for phase, t_rec in recovery.items():
        assert t_rec <= RECOVERY_S, f"after the {phase}: {t_rec:.2f} s to recover"
    # every kind of fault is counted where a user sees it
    assert codec["crc_errors"] > 0 and codec["bad_data"] > 0
    assert codec["duplicates"] >= c.duplicates // 2 and codec["out_of_order"] > 0
    assert pipe["counters"]["lost_samples"] > 0
    assert pipe["drops"].get("reordered", 0) > 0
    last = faulty.statuses()[-1]
    assert last["crc_errors"] > 0 and last["bad_data"] > 0 and last["duplicates"] > 0 and last["out_of_order"] > 0


def test_pty_corrupted_bytes_and_a_vanishing_device_then_sigkill(rt, tmp_path: Path) -> None:
    """Serial: corrupted, truncated and junk-laden byte stream; the device vanishes for 1.5 s and returns;
    at the end the daemon is killed with SIGKILL and its tlog is still readable up to the last flush."""
    link = tmp_path / "ttyREL"
    relay = PtyFaultRelay(link, PTY_MIX, seed=3)
    relay.set_faults(PTY_MIX, "mix")
    gcs = rt.Collector()
    daemon = rt.DaemonProcess(
        ["--master", f"{link},921600", "--out", f"udpout:127.0.0.1:{gcs.port}", "--filter", rt.filter_name(),
         "--out-rate", "0", "--status-interval", "1", "--heartbeat-timeout", "60", "--log", "d.tlog"], tmp_path,
    )
    try:
        daemon.wait_for("mavahrs running")
        host, port = relay.address
        sim = rt.start_sim(["--out", f"udpout:{host}:{port}", "--scenario", SCENARIO, "--duration", "13",
                            "--seed", "5"], tmp_path)
        deadline = time.monotonic() + 180
        while relay.counters().datagrams == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(6.0)
        unplug_wall = time.time()
        relay.unplug()
        daemon.wait_for("lost", 10)
        time.sleep(1.5)
        relay.plug()
        plug_wall = time.time()
        daemon.wait_for("restored", 10)
        assert sim.wait(240) == 0
        time.sleep(0.5)
        kill_wall = time.time()
        rc = daemon.stop(signal.SIGKILL)
    finally:
        daemon.stop()
        gcs.close()
        relay.close()
    assert rc == -signal.SIGKILL
    assert "Traceback" not in daemon.log

    recs = relay.records()
    truth = rt.truth_from_datagrams([r.original for r in recs])
    t_ms0 = min(truth)
    answered = rt.attitude_map(gcs.attitudes())
    # intact: RAW_IMU in chunks written unmodified, away from the moments the device went and came back
    # (bytes in the pty when it closed are gone; bytes written before the daemon reopened may be too)
    quiet = [(unplug_wall - 0.3, plug_wall + 1.5)]
    intact = [
        ms for r in recs if not r.faults and r.sent and not any(a <= r.t_wall_s < b for a, b in quiet)
        for ms in rt.imu_ms_in([r.original])
    ]
    fraction = len(set(intact) & set(answered)) / len(intact)
    vanished = [ms for r in recs if "unplugged" in r.faults for ms in rt.imu_ms_in([r.original])]
    back_s = (max(vanished) - t_ms0) / 1000.0
    keys = sorted(k for k in answered if k in truth)
    t = np.array([(k - t_ms0) / 1000.0 for k in keys])
    err = rt.tilt_errors_deg(answered, truth, keys)
    steady = (t >= SETTLE_S) & ((t < back_s - 2.0) | (t >= back_s + RECOVERY_S))
    recovery = rt.recovery_time_s(t, err, back_s, TILT_BOUND_DEG)
    statuses = daemon.statuses()
    last = statuses[-1]
    c = relay.counters()
    print(f"\npty faults: relay {c}; answered {fraction:.2%} of {len(intact)} intact samples; tilt RMS "
          f"{rt.rms(err[steady]):.2f}° (max {err[steady].max():.2f}°); device gone {len(vanished)} samples, back at "
          f"{back_s:.2f} s, recovered in {recovery:.2f} s\n last status {last}")
    assert fraction >= 0.99, f"only {fraction:.2%} of the intact samples answered"
    assert rt.rms(err[steady]) <= TILT_BOUND_DEG
    assert recovery <= RECOVERY_S
    assert last["crc_errors"] > 0 and last["bad_data"] > 0 and last["seq_gaps"] > 0
    assert last["drops_by_reason"] == {} or set(last["drops_by_reason"]) <= {"reordered", "duplicate", "held_jump"}
    assert any("lost" in m["message"] and str(link) in m["message"] for m in daemon.messages())

    # SIGKILL: the tlog holds everything up to the last flush (≤ 1 s before the kill), readable by pymavlink
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(tmp_path / "d.tlog"), dialect="ardupilotmega")
    n, last_t = 0, 0.0
    try:
        while (msg := mlog.recv_msg()) is not None:
            n += 1
            last_t = msg._timestamp
    finally:
        mlog.close()
    assert n > 1000 and kill_wall - last_t <= 1.5, (n, kill_wall - last_t)
