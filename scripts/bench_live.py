#!/usr/bin/env python3
r"""Live latency and CPU of ``mavahrs run`` over loopback at 400 Hz, against a bare pymavlink echo server.

One run, three processes, the same traffic at the same time:

* this script plays the autopilot: HEARTBEAT at 1 Hz and RAW_IMU at
  ``--rate`` Hz (default 400) to both servers, the echo server's copy of each
  sample half a period after the daemon's (``--stagger``; so that the two
  servers never work at the same moment: a companion computer runs one
  daemon, not a twin competing for its cores), and it timestamps every reply;
* ``mavahrs run --master udpin:… --out-rate 0`` — the daemon (the attitude
  goes back on the master link, to us);
* a bare pymavlink echo server (``mavutil.mavlink_connection("udpin:…")``,
  ``recv_match(blocking=True)``, ``attitude_quaternion_send`` of a constant):
  the cheapest thing that receives a MAVLink sample and answers it.

Measured over ``--duration`` seconds after ``--warmup``:

* the daemon's own processing latency — from the moment it read the
  datagram to the moment the ``sendto`` of the attitude returned
  (timestamped inside the daemon, its latency ring, via ``--stats-json``):
  p50, p99, max;
* the same span inside the bare echo server (return of its ``recvfrom`` to
  return of its ``sendto``), as a control: the least work a MAVLink answer
  takes, with the same wake-ups and the VM's same steal time (reported, not
  judged);
* the end-to-end round trip seen by the sender for both servers, and the
  daemon's overhead over the echo (p50, p99) — the machine's scheduling noise
  is in both, so compare, do not quote absolutes alone;
* CPU per message of both servers (user+system from ``/proc/PID/stat`` over
  the window, divided by the samples answered in it).

Targets (issue 4): processing p50 ≤ 200 µs and p99 ≤ 1 ms; end-to-end p50
overhead over the echo ≤ 0.2 ms; daemon CPU per message ≤ 1.5× the echo's.
The exit code is 1 when a target is missed (2 on a setup error).

Scheduling: ``--realtime-priority N`` runs both servers under SCHED_FIFO at
priority N (the daemon with its own ``--realtime-priority``, the echo server
switching itself), as ``contrib/mavahrs.service`` can deploy the daemon; 0 (the
default) runs both under normal scheduling.  On a 2-core machine the three
processes of this benchmark share two cores, and under normal scheduling the
reader woken by a ``sendto`` often runs on the sender's core before the
``sendto`` returns: that wait is part of the processing latency measured.
Sending both servers their copy at the same instant (``--no-stagger``, the
method before 2026-12-01) adds the two servers' competition for the cores: in
back-to-back runs of ``best`` here, p50 280 against 216 µs staggered, p99 976
against 405 µs.
``--realtime-priority`` needs root or CAP_SYS_NICE; refused, it is a setup
error (exit 2), never a silent normal-priority run.

CPU placement (``--pin``, the default where this process may use two CPUs
or more): this script — the stand-in for the flight controller and the
ground station, which are other machines in a real installation — runs on
the first CPU it may use, both servers on the others.  Left to the scheduler
(``--no-pin``), this script often runs on the daemon's CPU: under normal
scheduling the ``sendto`` that answers it wakes it there, it preempts the
daemon, and the daemon's ``sendto`` returns only after this script has read
the reply and gone back to waiting — its work, counted as the daemon's
processing.  Back to back for ``best`` on the 2-core test machine
(2026-12-01): processing p50 138 µs placed, 213 µs with everything on one
CPU, 266 µs left to the scheduler.  The placement is the same for both
servers, so the echo comparison stays fair; the JSON records it.

The status page (``--with-page``): the daemon also serves ``--http`` and a
headless Chromium (the distribution's ``chromium`` and ``chromedriver``,
through selenium) keeps the page open for the whole run, receiving its live
attitude (20 Hz) and status (1 Hz) events; the browser — a ground station's,
in a real installation — runs on this script's CPU.  Run once with and once
without to see what serving the page costs the daemon (latency, CPU per
message); the report adds the page's attitude update rate over the window.

Usage::

    python3 scripts/bench_live.py                      # the default filter (best)
    python3 scripts/bench_live.py --filter all         # every filter in turn
    python3 scripts/bench_live.py --filter madgwick --duration 30 --json out.json
    sudo python3 scripts/bench_live.py --filter all --realtime-priority 20
    python3 scripts/bench_live.py --with-page          # the same with the status page open in a browser
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

TARGETS = {
    "processing_p50_us": 200.0,
    "processing_p99_us": 1000.0,
    "e2e_p50_overhead_us": 200.0,
    "cpu_ratio": 1.5,
}


# --------------------------------------------------------------------------- the bare echo server


def echo_server(port: int, idle_exit_s: float, realtime_priority: int = 0, stats_path: str | None = None) -> int:
    """A bare pymavlink echo: RAW_IMU in → ATTITUDE_QUATERNION with its time_boot_ms out.

    With ``stats_path`` it also times its own processing the way the daemon does (from the return of
    the datagram's ``recvfrom`` to the return of the answer's ``sendto``) and writes the list (ns) there
    as JSON on exit: the same span for the least work a MAVLink answer takes, as a control for the
    machine's own scheduling noise.
    """
    from pymavlink import mavutil

    if realtime_priority:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(realtime_priority))
        except OSError as exc:
            print(f"ECHO REFUSED real-time scheduling: {exc.strerror or exc}", flush=True)
            return 2
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=191)
    perf = time.perf_counter_ns
    received = [0]  # when the last datagram's recvfrom returned (one frame per datagram here)
    latency_ns: list[int] = []
    if stats_path:
        recv = conn.recv

        def timed_recv(n: int | None = None) -> Any:
            data = recv(n)
            if data:
                received[0] = perf()
            return data

        conn.recv = timed_recv  # type: ignore[method-assign]
    print("ECHO READY", flush=True)
    last = time.monotonic()
    stop = {"flag": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__("flag", True))
    zero = [0.0, 0.0, 0.0, 0.0]
    while not stop["flag"]:
        msg = conn.recv_match(type="RAW_IMU", blocking=True, timeout=0.5)
        if msg is None:
            if time.monotonic() - last > idle_exit_s:
                break
            continue
        last = time.monotonic()
        conn.mav.attitude_quaternion_send(msg.time_usec // 1000, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, zero)
        if stats_path:
            latency_ns.append(perf() - received[0])
    if stats_path:
        Path(stats_path).write_text(json.dumps(latency_ns))
    return 0


# --------------------------------------------------------------------------- helpers


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (``/proc/PID/stat``)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks


def _thread_cpu_ns(pid: int) -> dict[int, int]:
    """CPU time (ns, /proc/PID/task/TID/schedstat) of each thread of a process."""
    out: dict[int, int] = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                out[int(tid)] = int(f.read().split()[0])
        except (OSError, ValueError, IndexError):
            pass
    return out


def _cpu_times() -> tuple[int, int] | None:
    """(all ticks, steal ticks) of the machine from ``/proc/stat``; None where it is not readable.

    Steal is the time the hypervisor ran something else while this VM's CPUs had work:
    the measure of how much the virtual machine itself stalled during the window."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            fields = [int(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    if len(fields) < 8:
        return None
    return sum(fields[:8]), fields[7]


def _pct(values: list[float], p: float) -> float:
    if not values:
        return math.nan
    s = sorted(values)
    return s[min(len(s) - 1, max(0, math.ceil(p / 100.0 * len(s)) - 1))]


def _free_port(kind: int = socket.SOCK_DGRAM) -> int:
    s = socket.socket(socket.AF_INET, kind)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


_PAGE_UPDATES = "return Number(document.body.dataset.attitudeUpdates)"


def _open_page(url: str) -> Any:
    """Headless Chromium showing ``url`` (selenium + the system chromedriver); RuntimeError if unavailable."""
    from mavahrs.evaluation.browser import BrowserUnavailable, start_chromium

    try:
        page = start_chromium("--window-size=1100,800", scratch_prefix="bench_live_chromium_")
    except BrowserUnavailable as exc:
        raise RuntimeError(f"--with-page: {exc}") from exc
    page.get(url)
    deadline = time.monotonic() + 30
    while page.execute_script(_PAGE_UPDATES) < 10:
        if time.monotonic() > deadline:
            page.quit()
            raise RuntimeError(f"the status page at {url} shows no live data")
        time.sleep(0.1)
    return page


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


class Peer:
    """One server seen from the sender: its socket, what was sent when, the round trips."""

    def __init__(self, name: str, port: int) -> None:
        self.name = name
        self.addr = ("127.0.0.1", port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.sent_ns: dict[int, int] = {}  # time_boot_ms → send time
        self.rtt_us: list[float] = []
        self.answered = 0
        self.answered_in_window = 0

    def drain(self, codec: Any, measuring: bool) -> None:
        while True:
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                return
            t = time.perf_counter_ns()
            for msg in codec.receive_datagram(data):
                if msg.get_type() != "ATTITUDE_QUATERNION":
                    continue
                sent = self.sent_ns.pop(msg.time_boot_ms, None)
                if sent is None:
                    continue
                self.answered += 1
                if measuring:
                    self.answered_in_window += 1
                    self.rtt_us.append((t - sent) / 1000.0)


def _wait_until(due_ns: int, fds: list[int], peers: list[Peer], codec: Any, measuring: bool) -> None:
    """Wait for ``due_ns`` (perf_counter), receiving replies meanwhile (no busy loop)."""
    while True:
        now = time.perf_counter_ns()
        if now >= due_ns:
            return
        ready, _, _ = select.select(fds, [], [], (due_ns - now) / 1e9)
        for p in peers:
            if p.sock.fileno() in ready:
                p.drain(codec, measuring)


# --------------------------------------------------------------------------- one benchmark


def _placement(pin: bool) -> tuple[set[int], set[int]] | None:
    """(this script's CPU, the servers' CPUs), or None when not pinning or fewer than two CPUs are usable."""
    if not pin or not hasattr(os, "sched_setaffinity"):
        return None
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) < 2:
        return None
    return {cpus[0]}, set(cpus[1:])


def bench_one(
    filter_name: str, rate_hz: float, warmup_s: float, duration_s: float, verbose: bool, realtime_priority: int = 0,
    stagger: bool = True, pin: bool = True, with_page: bool = False,
) -> dict[str, Any]:
    """One filter: the daemon and the echo server on the same stream; ``realtime_priority`` > 0: both SCHED_FIFO.

    ``stagger``: the echo's copy of each sample leaves half a period after the daemon's (False: both
    in the same instant, the order alternating: the servers then compete for the cores).
    ``with_page``: the daemon serves the status page and a headless browser shows it throughout.
    """
    from mavahrs.protocol.codec import MavCodec

    placement = _placement(pin)
    own_cpus = os.sched_getaffinity(0) if placement is not None else None

    def on_server_cpus() -> None:  # in the child, before exec
        if placement is not None:
            os.sched_setaffinity(0, placement[1])

    tmp = Path(tempfile.mkdtemp(prefix="bench_live_"))
    stats_path = tmp / "daemon.json"
    echo_stats_path = tmp / "echo.json"
    d_port, e_port = _free_port(), _free_port()
    ring = int(rate_hz * (duration_s + warmup_s + 5)) + 1024
    http_port = _free_port(socket.SOCK_STREAM) if with_page else None
    daemon = subprocess.Popen(
        [sys.executable, "-m", "mavahrs", "run", "--master", f"udpin:127.0.0.1:{d_port}", "--filter", filter_name,
         "--out-rate", "0", "--no-stream-requests", "--heartbeat-timeout", "0", "--status-interval", "0",
         "--stats-json", str(stats_path), "--set", f"daemon.latency_ring={ring}", "-q",
         "--realtime-priority", str(realtime_priority),
         *(["--http", f"127.0.0.1:{http_port}"] if http_port else [])],
        env=_env(), stderr=None if verbose else subprocess.DEVNULL, preexec_fn=on_server_cpus,
    )
    echo = subprocess.Popen(
        [sys.executable, __file__, "--echo-server", str(e_port), "--realtime-priority", str(realtime_priority),
         "--echo-stats", str(echo_stats_path)],
        env=_env(), stdout=subprocess.PIPE, text=True, preexec_fn=on_server_cpus,
    )
    if placement is not None:
        os.sched_setaffinity(0, placement[0])
    page: Any = None
    page_updates: float | None = None
    try:
        assert echo.stdout is not None
        said = echo.stdout.readline().strip()
        if said != "ECHO READY":
            raise RuntimeError(f"the echo server did not start ({said or 'no answer'})")
        codec = MavCodec(1, 1)
        peers = [Peer("mavahrs", d_port), Peer("echo", e_port)]
        heartbeat = codec.encode(codec.mav.heartbeat_encode(2, 3, 0, 0, 4))  # ArduPilot quadrotor
        # wait for the daemon: heartbeats and a few samples until it answers (numba start-up)
        deadline = time.monotonic() + 120
        t_us = 1_000_000
        while time.monotonic() < deadline and peers[0].answered == 0:
            if daemon.poll() is not None:
                raise RuntimeError(f"mavahrs run exited with code {daemon.returncode}")
            for p in peers:
                p.sock.sendto(heartbeat, p.addr)
                t_us += 2500
                frame = codec.encode(codec.mav.raw_imu_encode(t_us, 0, 0, -1000, 0, 0, 0, 200, 0, 400, 0, 0))
                p.sent_ns[t_us // 1000] = time.perf_counter_ns()
                p.sock.sendto(frame, p.addr)
            time.sleep(0.1)
            for p in peers:
                p.drain(codec, False)
        if peers[0].answered == 0:
            raise RuntimeError("mavahrs run never answered")
        if http_port:  # the browser inherits this script's CPU (placement[0]), like the sender
            page = _open_page(f"http://127.0.0.1:{http_port}/")
            for p in peers:
                p.drain(codec, False)
            updates0, t_page0 = page.execute_script(_PAGE_UPDATES), time.monotonic()
        # paced stream: warm-up, then the measured window
        period_ns = int(1e9 / rate_hz)
        start = time.perf_counter_ns()
        n_warm = int(warmup_s * rate_hz)
        n_total = n_warm + int(duration_s * rate_hz)
        cpu0: dict[str, float] = {}
        machine0: tuple[int, int] | None = None
        fds = [p.sock.fileno() for p in peers]
        next_hb = start
        for k in range(n_total):
            due = start + k * period_ns
            measuring = k >= n_warm
            if k == n_warm:
                cpu0 = {"mavahrs": _cpu_s(daemon.pid), "echo": _cpu_s(echo.pid)}
                threads0, t_threads0 = _thread_cpu_ns(daemon.pid), time.monotonic()
                machine0 = _cpu_times()
                for p in peers:
                    p.answered_in_window = 0
            _wait_until(due, fds, peers, codec, measuring)
            if due >= next_hb:
                next_hb += 1_000_000_000
                for p in peers:
                    p.sock.sendto(heartbeat, p.addr)
            t_us += 2500
            frame = codec.encode(codec.mav.raw_imu_encode(t_us, 10, -20, -1000, 1, 2, 3, 200, 0, 400, 0, 0))
            if stagger:
                d_peer, e_peer = peers
                d_peer.sent_ns[t_us // 1000] = time.perf_counter_ns()
                d_peer.sock.sendto(frame, d_peer.addr)
                _wait_until(due + period_ns // 2, fds, peers, codec, measuring)
                e_peer.sent_ns[t_us // 1000] = time.perf_counter_ns()
                e_peer.sock.sendto(frame, e_peer.addr)
            else:
                order = peers if k % 2 == 0 else peers[::-1]
                for p in order:
                    p.sent_ns[t_us // 1000] = time.perf_counter_ns()
                    p.sock.sendto(frame, p.addr)
            for p in peers:
                if len(p.sent_ns) > 4096:  # unanswered samples: forget the oldest
                    for key in sorted(p.sent_ns)[:1024]:
                        del p.sent_ns[key]
        # let the last replies arrive, then read the CPU counters
        end = time.perf_counter_ns() + 200_000_000
        while time.perf_counter_ns() < end:
            ready, _, _ = select.select(fds, [], [], 0.05)
            for p in peers:
                if p.sock.fileno() in ready:
                    p.drain(codec, True)
        cpu1 = {"mavahrs": _cpu_s(daemon.pid), "echo": _cpu_s(echo.pid)}
        threads1, t_threads1 = _thread_cpu_ns(daemon.pid), time.monotonic()
        machine1 = _cpu_times()
        # the daemon's loop (its main thread, TID = PID) and its other threads (the status page's server)
        spent = {tid: ns - threads0.get(tid, 0) for tid, ns in threads1.items()}
        span_s = max(1e-9, t_threads1 - t_threads0)
        daemon_threads = {
            "loop": spent.pop(daemon.pid, 0) / 1e6 / span_s,
            "other": sum(spent.values()) / 1e6 / span_s,
        }
        n_window = n_total - n_warm
        if page is not None:
            page_updates = (page.execute_script(_PAGE_UPDATES) - updates0) / (time.monotonic() - t_page0)
    finally:
        if page is not None:
            page.quit()
        for proc in (daemon, echo):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in (daemon, echo):
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if echo.stdout is not None:
            echo.stdout.close()
        if own_cpus is not None:
            os.sched_setaffinity(0, own_cpus)
    try:
        stats = json.loads(stats_path.read_text())
        try:
            echo_ns = json.loads(echo_stats_path.read_text())
        except (OSError, ValueError):
            echo_ns = []
    finally:
        shutil.rmtree(tmp, ignore_errors=True)  # the two statistics files: read, not kept
    wanted = f"SCHED_FIFO priority {realtime_priority}" if realtime_priority else "normal"
    if stats.get("scheduling", "normal") != wanted:
        raise RuntimeError(f"mavahrs run ran under {stats.get('scheduling')!r} scheduling, not {wanted!r}")
    processing = [ns / 1000.0 for ns in stats["latency_ns"]][-n_window:]  # the window's samples (the last ones)
    echo_processing = [ns / 1000.0 for ns in echo_ns][-n_window:]
    d, e = peers
    result: dict[str, Any] = {
        "filter": filter_name,
        "scheduling": wanted,
        "stagger": stagger,
        "with_page": with_page,
        # CPU of the daemon's threads over the window, ms per second
        "daemon_threads_ms_per_s": daemon_threads,
        "page_attitude_updates_hz": page_updates,
        "cpus": None if placement is None else {"sender": sorted(placement[0]), "servers": sorted(placement[1])},
        "rate_hz": rate_hz,
        "window_s": duration_s,
        "samples_sent": n_window,
        "answered": {"mavahrs": d.answered_in_window, "echo": e.answered_in_window},
        "processing_us": {
            "p50": _pct(processing, 50), "p90": _pct(processing, 90), "p99": _pct(processing, 99),
            "max": max(processing) if processing else math.nan, "n": len(processing),
            "over_1ms": sum(1 for v in processing if v > 1000.0),
        },
        # the bare echo's own receipt -> sendto span in the same window (a control: the least work an
        # answer takes, with the same wake-ups and the same steal); not judged
        "echo_processing_us": {
            "p50": _pct(echo_processing, 50), "p99": _pct(echo_processing, 99),
            "max": max(echo_processing) if echo_processing else math.nan, "n": len(echo_processing),
            "over_1ms": sum(1 for v in echo_processing if v > 1000.0),
        },
        "rtt_us": {
            p.name: {"p50": _pct(p.rtt_us, 50), "p99": _pct(p.rtt_us, 99), "max": max(p.rtt_us or [math.nan])}
            for p in peers
        },
        "cpu_us_per_msg": {
            p.name: (cpu1[p.name] - cpu0[p.name]) * 1e6 / max(1, p.answered_in_window) for p in peers
        },
        "daemon_counters": stats["counters"],
        # share of the machine's CPU time the hypervisor took away during the window (VMs only)
        "steal_pct": (
            100.0 * (machine1[1] - machine0[1]) / max(1, machine1[0] - machine0[0])
            if machine0 is not None and machine1 is not None else None
        ),
    }
    result["e2e_overhead_us"] = {
        "p50": result["rtt_us"]["mavahrs"]["p50"] - result["rtt_us"]["echo"]["p50"],
        "p99": result["rtt_us"]["mavahrs"]["p99"] - result["rtt_us"]["echo"]["p99"],
    }
    echo_cpu = result["cpu_us_per_msg"]["echo"]
    result["cpu_ratio"] = result["cpu_us_per_msg"]["mavahrs"] / echo_cpu if echo_cpu > 0 else math.inf
    result["checks"] = {
        "processing_p50_us": result["processing_us"]["p50"] <= TARGETS["processing_p50_us"],
        "processing_p99_us": result["processing_us"]["p99"] <= TARGETS["processing_p99_us"],
        "e2e_p50_overhead_us": result["e2e_overhead_us"]["p50"] <= TARGETS["e2e_p50_overhead_us"],
        "cpu_ratio": result["cpu_ratio"] <= TARGETS["cpu_ratio"],
        "answered_99pct": d.answered_in_window >= 0.99 * n_window,
    }
    return result


def _report(r: dict[str, Any]) -> str:
    p, rt, o, c = r["processing_us"], r["rtt_us"], r["e2e_overhead_us"], r["cpu_us_per_msg"]
    nan = {"p50": math.nan, "p99": math.nan, "max": math.nan, "n": 0, "over_1ms": 0}
    ep = r.get("echo_processing_us", nan)
    k = r.get("daemon_counters", {})
    ok = lambda name: "ok" if r["checks"][name] else "MISSED"  # noqa: E731
    return "\n".join(
        [
            f"filter {r['filter']} ({r['scheduling']} scheduling): {r['samples_sent']} samples at {r['rate_hz']:g} Hz "
            f"over {r['window_s']:g} s; answered mavahrs {r['answered']['mavahrs']}, echo {r['answered']['echo']}"
            + (f"; sender on CPU {r['cpus']['sender']}, servers on {r['cpus']['servers']}" if r.get("cpus") else ""),
            f"  processing (in daemon, receipt -> sendto returned): p50 {p['p50']:.0f} us "
            f"[{ok('processing_p50_us')} <= 200], p99 {p['p99']:.0f} us [{ok('processing_p99_us')} <= 1000], "
            f"max {p['max']:.0f} us; p90 {p['p90']:.0f} us, {p['over_1ms']} of {p['n']} over 1 ms",
            f"  the bare echo's own receipt -> sendto (control, not judged): p50 {ep['p50']:.0f} us, "
            f"p99 {ep['p99']:.0f} us, max {ep['max']:.0f} us, {ep['over_1ms']} of {ep['n']} over 1 ms",
            f"  round trip seen by the sender: mavahrs p50 {rt['mavahrs']['p50']:.0f} / p99 {rt['mavahrs']['p99']:.0f} us; "
            f"bare echo p50 {rt['echo']['p50']:.0f} / p99 {rt['echo']['p99']:.0f} us",
            f"  end-to-end overhead over the echo: p50 {o['p50']:.0f} us [{ok('e2e_p50_overhead_us')} <= 200], "
            f"p99 {o['p99']:.0f} us",
            f"  CPU per message: mavahrs {c['mavahrs']:.0f} us, echo {c['echo']:.0f} us, ratio {r['cpu_ratio']:.2f} "
            f"[{ok('cpu_ratio')} <= 1.5]"
            + (f"; the VM's steal time {r['steal_pct']:.1f} % of the CPUs" if r.get("steal_pct") is not None else ""),
            f"  fast lane: {k.get('fast_lane_answers', 0)} of {k.get('attitudes_out', 0)} attitudes "
            f"({k.get('fast_lane_chained', 0)} chained over queued datagrams), "
            f"{k.get('fast_lane_mismatches', 0)} mismatches",
        ]
        + [f"  daemon CPU by thread: loop {r['daemon_threads_ms_per_s']['loop']:.1f} ms/s, other threads "
           f"{r['daemon_threads_ms_per_s']['other']:.2f} ms/s"]
        + ([f"  status page open in headless Chromium throughout: {r['page_attitude_updates_hz']:.1f} attitude "
            "updates/s on the page"] if r.get("with_page") else [])
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--filter", action="append", default=None, metavar="NAME",
                    help="filter to run (repeatable; 'all' = every filter and best; default best)")
    ap.add_argument("--rate", type=float, default=400.0, help="RAW_IMU rate, Hz (default 400)")
    ap.add_argument("--warmup", type=float, default=3.0, help="seconds before measuring (default 3)")
    ap.add_argument("--duration", type=float, default=20.0, help="measured seconds (default 20)")
    ap.add_argument("--json", metavar="FILE", help="write the results as JSON")
    ap.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                    help="run the daemon and the echo server under SCHED_FIFO at priority N (1-99; needs root "
                    "or CAP_SYS_NICE); 0 = normal scheduling (default)")
    ap.add_argument("--no-stagger", dest="stagger", action="store_false",
                    help="send each sample to both servers at the same instant (order alternating) instead of the "
                    "echo's copy half a period later: the servers then compete for the cores")
    ap.add_argument("--no-pin", dest="pin", action="store_false",
                    help="leave CPU placement to the scheduler instead of this script on the first usable CPU "
                    "and both servers on the others")
    ap.add_argument("--with-page", action="store_true",
                    help="the daemon serves --http and headless Chromium keeps the status page open throughout "
                    "(needs selenium, chromium, chromedriver)")
    ap.add_argument("-v", "--verbose", action="store_true", help="show the daemon's log")
    ap.add_argument("--echo-server", type=int, metavar="PORT", help=argparse.SUPPRESS)
    ap.add_argument("--echo-stats", metavar="FILE", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.echo_server is not None:
        return echo_server(args.echo_server, idle_exit_s=30.0, realtime_priority=args.realtime_priority,
                           stats_path=args.echo_stats)
    if not 0 <= args.realtime_priority <= 99:
        ap.error("--realtime-priority must be 0…99")
    if not sys.platform.startswith("linux"):
        print("bench_live.py reads /proc: Linux only", file=sys.stderr)
        return 2
    names = args.filter or ["best"]
    if "all" in names:
        from mavahrs.filters import NAMES

        names = ["best", *NAMES]
    results = []
    for name in names:
        try:
            r = bench_one(name, args.rate, args.warmup, args.duration, args.verbose, args.realtime_priority,
                          args.stagger, args.pin, args.with_page)
        except RuntimeError as exc:
            print(f"bench_live: {name}: {exc}", file=sys.stderr)
            return 2
        print(_report(r), flush=True)
        results.append(r)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    missed = [f"{r['filter']}:{k}" for r in results for k, ok in r["checks"].items() if not ok]
    if missed:
        print("targets missed: " + ", ".join(missed), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
