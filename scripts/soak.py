#!/usr/bin/env python3
r"""Bounded soak test of ``mavahrs run``: hours of 400 Hz input with periodic faults (not part of the unit suite).

    nice python3 scripts/soak.py                          # 30 minutes (the issue's soak)
    nice python3 scripts/soak.py --duration 120 --json out/soak.json

Set-up (all on loopback, every process real)::

    firmware_sim (400 Hz RAW_IMU + SIMSTATE truth, --loop-rate 800)
        └─udp─▶ UdpFaultRelay (mild loss/corruption always, bursts on schedule) ─udp─▶ mavahrs run ─udp─▶ collector

Faults, repeated every ``--fault-period`` seconds (default 60), at these
offsets into each period: a corruption burst (10 s, 3 s long), a simulator
restart with its clock back at zero — an autopilot reboot (20 s), a silence
(30 s, 3 s), a restart with its clock far ahead — a timestamp jump (45 s).
Between them the relay keeps a mild mix (1 % loss, 1 % bit flips, 0.5 %
junk, 0.5 % duplicates, 0.5 % reordering).

Measured:

* start-up: seconds from the simulator's start to the first answer (the
  soak proper starts there: a first sample may still wait for a filter
  kernel to compile, and what the kernel drops meanwhile is start-up, not
  steady state);
* samples: every RAW_IMU the relay delivered intact and in order, and
  whether an ATTITUDE_QUATERNION for it came back within 3 s (``lost``
  otherwise; a sample within 1 s after a fault event is counted apart, as
  ``lost_near_fault``: the daemon legitimately drops the first sample after a
  reboot or a jump until the next one confirms it);
* memory: the daemon's RSS every 5 s; start (after ``--warmup``) and end,
  and the growth slope (least squares over the run after warm-up, MB/h);
* latency: end to end (relay ``sendto`` → attitude received, this process's
  clock) percentiles over the first and the last 5 minutes; the daemon's own
  processing latency (its status lines: p50/p99 per status interval) over the
  same spans (median of the per-interval values);
* the daemon's CPU time per answered sample (from /proc, first vs last
  span): unlike latency, it does not depend on what else the machine runs,
  so it tells a slowing daemon from a busy machine (the 1-minute load
  average is recorded beside it);
* inclination error against SIMSTATE (first vs last span; not in the first
  30 s of start-up convergence, not within 5 s after a fault);
* a series of 30-s bins with all of the above (``series`` in the JSON);
* the daemon's counters at exit (``--stats-json``).

Exit code 1 when the RSS grew by more than ``--max-rss-growth-mb`` or its
slope exceeds ``--max-rss-slope-mb-h``, when more than ``--max-lost`` of the
intact samples (away from faults) went unanswered, or the daemon died; 0
otherwise; 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from array import array
from collections import OrderedDict, deque
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mavahrs.protocol.codec import MavCodec  # noqa: E402
from mavahrs.transports.relay import FaultSettings, UdpFaultRelay  # noqa: E402

MILD = FaultSettings(loss=0.01, bit_flip=0.01, junk=0.005, duplicate=0.005, reorder=0.005)
BURST = FaultSettings(loss=0.3, bit_flip=0.3, truncate=0.1, junk=0.3, duplicate=0.05, reorder=0.05)
SILENCE = FaultSettings(loss=1.0)
PENDING_TIMEOUT_S = 3.0
NEAR_FAULT_S = 1.0


def _env() -> dict[str, str]:
    e = dict(os.environ)
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    return e


def _percentiles(values: Any) -> dict[str, float]:
    v = sorted(values)
    if not v:
        return {"n": 0, "p50_ms": math.nan, "p99_ms": math.nan, "max_ms": math.nan}

    def pct(p: float) -> float:
        return v[min(len(v) - 1, max(0, math.ceil(p / 100 * len(v)) - 1))] * 1e3

    return {"n": len(v), "p50_ms": pct(50), "p99_ms": pct(99), "max_ms": v[-1] * 1e3}


def _median(values: list[float]) -> float:
    v = sorted(x for x in values if x is not None and math.isfinite(x))
    return v[len(v) // 2] if v else math.nan


def _slope_per_hour(points: list[tuple[float, float]]) -> float:
    if len(points) < 3:
        return math.nan
    n = len(points)
    mt = sum(t for t, _ in points) / n
    mv = sum(v for _, v in points) / n
    den = sum((t - mt) ** 2 for t, _ in points)
    return sum((t - mt) * (v - mv) for t, v in points) / den * 3600.0 if den else math.nan


def _tilt_deg(q: tuple[float, ...], r: tuple[float, ...]) -> float:
    """Inclination error: angle between the estimated and true body-frame 'down' directions, deg."""

    def down_in_body(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
        # third row of the body→NED rotation matrix = NED z expressed in body axes
        return (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))

    a, b = down_in_body(*q), down_in_body(*r)
    c = max(-1.0, min(1.0, sum(i * j for i, j in zip(a, b, strict=True)) / (math.sqrt(sum(i * i for i in a)) * math.sqrt(sum(i * i for i in b)))))
    return math.degrees(math.acos(c))


def _q_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


class Tracker:
    """Follows every intact in-order sample from the relay to the daemon's answer (bounded memory)."""

    def __init__(self, window_s: float) -> None:
        self.lock = threading.Lock()
        self.codec = MavCodec(drop_duplicates=False)
        self.pending: OrderedDict[int, tuple[float, tuple[float, ...] | None]] = OrderedDict()
        self.newest = -1
        self.intact = 0
        self.answered = 0
        self.lost = 0
        self.lost_near_fault = 0
        self.late_answers = 0
        self.fault_times: deque[float] = deque(maxlen=64)
        self.window_s = window_s
        self.t_start = time.monotonic()
        self.error_warmup_s = 30.0  # start-up convergence is not the soak's business
        self.first_lat = array("d")
        self.first_err = array("d")
        self.last: deque[tuple[float, float, float]] = deque()  # (t, latency, tilt error or nan)
        self.bin_s = 30.0
        #: per bin of sending time: [intact, answered, lost, lost near fault, latencies, squared errors sum, errors]
        self.bins: dict[int, list[Any]] = {}

    def _bin(self, t: float) -> list[Any]:
        i = int((t - self.t_start) // self.bin_s)
        b = self.bins.get(i)
        if b is None:
            b = self.bins[i] = [0, 0, 0, 0, array("d"), 0.0, 0]
        return b

    def reset(self, t_start: float) -> None:
        """Forget everything counted so far (the measurement starts at ``t_start``)."""
        with self.lock:
            self.pending.clear()
            self.intact = self.answered = self.lost = self.lost_near_fault = self.late_answers = 0
            self.first_lat = array("d")
            self.first_err = array("d")
            self.last.clear()
            self.bins.clear()
            self.t_start = t_start

    def fault(self) -> None:
        with self.lock:
            self.fault_times.append(time.monotonic())

    def _near_fault(self, t: float) -> bool:
        return any(-0.2 <= t - f <= NEAR_FAULT_S for f in self.fault_times)

    def on_sent(self, leg: int, data: bytes) -> None:
        now = time.monotonic()
        imu = sim = None
        for m in self.codec.receive_datagram(data):
            k = m.get_type()
            if k == "RAW_IMU":
                imu = m
            elif k == "SIMSTATE":
                sim = m
        if imu is None:
            return
        ms = imu.time_usec // 1000
        with self.lock:
            if self.newest >= 0 and abs(ms - self.newest) > 1000:  # a reboot, a jump or a silence: a fault
                self.fault_times.append(now)
            if ms < self.newest - 1000:  # the clock went back: a new simulator session
                self.newest = -1
            if ms <= self.newest:
                return  # a duplicate or a late (reordered) sample: not expected to be answered
            self.newest = ms
            truth = _q_from_euler(sim.roll, sim.pitch, sim.yaw) if sim is not None else None
            self.pending[ms] = (now, truth)
            self.intact += 1
            self._bin(now)[0] += 1

    def on_attitude(self, m: Any, now: float) -> None:
        with self.lock:
            entry = self.pending.pop(m.time_boot_ms, None)
            if entry is None:
                self.late_answers += 1
                return
            self.answered += 1
            sent, truth = entry
            lat = now - sent
            err = math.nan
            if (truth is not None and sent - self.t_start >= self.error_warmup_s
                    and not any(-0.2 <= sent - f <= 5.0 for f in self.fault_times)):
                err = _tilt_deg((m.q1, m.q2, m.q3, m.q4), truth)
            b = self._bin(sent)
            b[1] += 1
            b[4].append(lat)
            if err == err:
                b[5] += err * err
                b[6] += 1
            if sent - self.t_start <= self.window_s:
                self.first_lat.append(lat)
                if err == err:
                    self.first_err.append(err)
            self.last.append((sent, lat, err))
            while self.last and self.last[0][0] < now - self.window_s:
                self.last.popleft()

    def sweep(self) -> None:
        now = time.monotonic()
        with self.lock:
            while self.pending:
                ms, (sent, _) = next(iter(self.pending.items()))
                if now - sent < PENDING_TIMEOUT_S:
                    break
                self.pending.popitem(last=False)
                if self._near_fault(sent):
                    self.lost_near_fault += 1
                    self._bin(sent)[3] += 1
                else:
                    self.lost += 1
                    self._bin(sent)[2] += 1


class Collector(threading.Thread):
    def __init__(self, tracker: Tracker) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.tracker = tracker
        self.codec = MavCodec(drop_duplicates=False)
        self.stop = False

    def run(self) -> None:
        while not self.stop:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            now = time.monotonic()
            for m in self.codec.receive_datagram(data):
                if m.get_type() == "ATTITUDE_QUATERNION":
                    self.tracker.on_attitude(m, now)


class Daemon:
    def __init__(self, port: int, gcs_port: int, workdir: Path, filter_name: str, status_s: float) -> None:
        self.stats_path = workdir / "soak_daemon_stats.json"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mavahrs", "--log-format", "json", "run", "--master", f"udpin:127.0.0.1:{port}",
             "--out", f"udpout:127.0.0.1:{gcs_port}", "--filter", filter_name, "--out-rate", "0",
             "--heartbeat-timeout", "120", "--status-interval", str(status_s), "--stats-json", str(self.stats_path)],
            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=_env(), cwd=workdir,
        )
        self.statuses: list[tuple[float, dict[str, Any]]] = []
        self.warnings: deque[str] = deque(maxlen=200)
        self.tracebacks = 0
        self.running = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            if "Traceback" in line:
                self.tracebacks += 1
            try:
                rec = json.loads(line)
            except ValueError:
                self.warnings.append(line.strip())
                continue
            if "status" in rec:
                self.statuses.append((time.monotonic(), rec["status"]))
            elif rec.get("level") in ("WARNING", "ERROR"):
                self.warnings.append(rec.get("message", ""))
            if "mavahrs running" in rec.get("message", ""):
                self.running.set()

    def cpu_s(self) -> float:
        """User + system CPU time of the daemon process so far, s."""
        try:
            with open(f"/proc/{self.proc.pid}/stat", encoding="ascii") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            return math.nan

    def rss_mb(self) -> float:
        try:
            with open(f"/proc/{self.proc.pid}/status", encoding="ascii") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        return int(line.split()[1]) / 1024.0
        except OSError:
            pass
        return math.nan

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            return self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()
        finally:
            self._reader.join(5)


class Simulator:
    """firmware_sim, restartable with a chosen boot offset (its clock at start)."""

    def __init__(self, relay_port: int, workdir: Path, scenario: str, seed: int) -> None:
        self.relay_port, self.workdir, self.scenario, self.seed = relay_port, workdir, scenario, seed
        self.proc: subprocess.Popen | None = None
        self.started_at = 0.0
        self.boot_offset_s = 0.0
        self.restarts = 0

    def start(self, boot_offset_s: float = 0.0) -> None:
        self.boot_offset_s = boot_offset_s
        self.seed += 1
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "firmware_sim", "--out", f"udpout:127.0.0.1:{self.relay_port}", "--ideal",
             "--loop-rate", "800", "--stream", "RAW_IMU=400", "--stream", "SIMSTATE=400", "--scenario",
             self.scenario, "--duration", "0", "--seed", str(self.seed), "--boot-offset-s", f"{boot_offset_s:.3f}", "-q"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env(), cwd=self.workdir,
        )
        self.started_at = time.monotonic()

    def clock_s(self) -> float:
        return self.boot_offset_s + time.monotonic() - self.started_at

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def restart(self, boot_offset_s: float) -> None:
        self.stop()
        self.restarts += 1
        self.start(boot_offset_s)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=1800.0, help="soak length, s (default 1800)")
    p.add_argument("--json", metavar="FILE", help="write the result here")
    p.add_argument("--filter", default="best", help="filter (default best)")
    p.add_argument("--scenario", default="hover", help="firmware_sim scenario (default hover)")
    p.add_argument("--seed", type=int, default=100, help="first simulator seed (default 100)")
    p.add_argument("--fault-period", type=float, default=60.0, help="seconds per fault cycle (default 60)")
    p.add_argument("--window", type=float, default=300.0, help="first/last span compared, s (default 300; "
                   "at most a third of the duration)")
    p.add_argument("--warmup", type=float, default=30.0, help="seconds before the RSS baseline (default 30)")
    p.add_argument("--max-rss-growth-mb", type=float, default=25.0, help="fail above this RSS growth, MB (default 25)")
    p.add_argument("--max-rss-slope-mb-h", type=float, default=20.0, help="fail above this RSS slope, MB/h (default 20)")
    p.add_argument("--max-lost", type=float, default=0.001,
                   help="fail when more than this share of intact samples (away from faults) is unanswered (default 0.001)")
    p.add_argument("--workdir", default=None, help="where the daemon writes its statistics (default: a temp dir)")
    args = p.parse_args(argv)
    if args.duration <= 0 or args.fault_period < 50:
        p.error("--duration must be positive and --fault-period at least 50 s")
    return args


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    # SIGTERM (kill, a CI timeout) unwinds like Ctrl-C: the simulator and the daemon are stopped too
    signal.signal(signal.SIGTERM, _interrupt)
    import tempfile

    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="mavahrs-soak-"))
    workdir.mkdir(parents=True, exist_ok=True)
    window = min(args.window, args.duration / 3.0)
    tracker = Tracker(window)
    collector = Collector(tracker)
    collector.start()
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    daemon = Daemon(port, collector.port, workdir, args.filter, status_s=10.0)
    if not daemon.running.wait(120):
        print("the daemon did not start", file=sys.stderr)
        daemon.stop()
        return 3
    relay = UdpFaultRelay([(("127.0.0.1", port), MILD, True)], seed=args.seed, record=False, observer=tracker.on_sent)
    relay.set_faults(0, MILD, "mild")
    sim = Simulator(relay.address[1], workdir, args.scenario, args.seed)
    faults: dict[str, int] = {"burst": 0, "reboot": 0, "silence": 0, "time_jump": 0}
    rss: list[tuple[float, float]] = []
    cpu: list[tuple[float, float, float]] = []  # (t, daemon CPU s, load average 1 min)
    # Start-up (first samples may still wait for compiled kernels) is measured apart: the soak
    # proper starts at the first answer.
    t_launch = time.monotonic()
    sim.start(0.0)
    while tracker.answered == 0 and time.monotonic() - t_launch < 600 and daemon.proc.poll() is None:
        time.sleep(0.05)
    startup_s = time.monotonic() - t_launch
    t0 = time.monotonic()
    tracker.reset(t0)
    events = [(10.0, "burst"), (13.0, "end_burst"), (20.0, "reboot"), (30.0, "silence"), (33.0, "end_silence"),
              (45.0, "time_jump")]
    next_rss = t0
    cycle_start = t0
    ev_i = 0
    dead = False
    try:
        while time.monotonic() - t0 < args.duration:
            now = time.monotonic()
            if now >= next_rss:
                rss.append((now - t0, daemon.rss_mb()))
                cpu.append((now - t0, daemon.cpu_s(), os.getloadavg()[0]))
                next_rss += 5.0
            tracker.sweep()
            if daemon.proc.poll() is not None:
                dead = True
                break
            if ev_i < len(events) and now - cycle_start >= events[ev_i][0]:
                kind = events[ev_i][1]
                if kind == "burst":
                    relay.set_faults(0, BURST, "burst")
                    faults["burst"] += 1
                elif kind in ("end_burst", "end_silence"):
                    relay.set_faults(0, MILD, "mild")
                    tracker.fault()
                elif kind == "silence":
                    relay.set_faults(0, SILENCE, "silence")
                    faults["silence"] += 1
                elif kind == "reboot":
                    sim.restart(0.0)
                    faults["reboot"] += 1
                    tracker.fault()
                elif kind == "time_jump":
                    sim.restart(sim.clock_s() + 600.0)
                    faults["time_jump"] += 1
                    tracker.fault()
                ev_i += 1
            if ev_i >= len(events) and now - cycle_start >= args.fault_period:
                cycle_start += args.fault_period
                ev_i = 0
            time.sleep(0.05)
    finally:
        sim.stop()
        time.sleep(PENDING_TIMEOUT_S + 0.5)
        tracker.sweep()
        rss.append((time.monotonic() - t0, daemon.rss_mb()))
        rc = daemon.stop()
        relay.close()
        collector.stop = True
        collector.join(5)
        collector.sock.close()
    elapsed = time.monotonic() - t0

    try:
        dstats = json.loads(daemon.stats_path.read_text())
    except (OSError, ValueError):
        dstats = {}
    base = [(t, v) for t, v in rss if t >= args.warmup and v == v] or [(t, v) for t, v in rss if v == v]
    rss_start, rss_end = (base[0][1], base[-1][1]) if base else (math.nan, math.nan)
    slope = _slope_per_hour(base)
    last_lat = array("d", (lat for _, lat, _ in tracker.last))
    last_err = [e for _, _, e in tracker.last if e == e]
    first_status = [s for t, s in daemon.statuses if t - t0 <= window]
    last_status = [s for t, s in daemon.statuses if t - t0 >= elapsed - window]
    relay_c = relay.counters(0)
    intact = tracker.intact
    series = []
    for i in sorted(tracker.bins):
        n_in, n_ans, n_lost, n_near, lats, sq, n_err = tracker.bins[i]
        t_lo, t_hi = i * tracker.bin_s, (i + 1) * tracker.bin_s
        in_bin = [(t, c, la) for t, c, la in cpu if t_lo <= t <= t_hi]
        cpu_us = ((in_bin[-1][1] - in_bin[0][1]) * 1e6 / n_ans) if len(in_bin) >= 2 and n_ans else math.nan
        rss_bin = [v for t, v in rss if t_lo <= t <= t_hi]
        st = [s for t, s in daemon.statuses if t_lo <= t - t0 < t_hi]
        pl = _percentiles(lats)
        series.append({
            "t_s": t_lo, "intact": n_in, "answered": n_ans, "lost": n_lost, "lost_near_fault": n_near,
            "e2e_p50_ms": pl["p50_ms"], "e2e_p99_ms": pl["p99_ms"],
            "daemon_p50_us": _median([s.get("latency_p50_us") for s in st]),
            "daemon_p99_us": _median([s.get("latency_p99_us") for s in st]),
            "daemon_cpu_us_per_sample": cpu_us,
            "rss_mb": rss_bin[-1] if rss_bin else math.nan,
            "load_1min": in_bin[-1][2] if in_bin else math.nan,
            "tilt_rms_deg": math.sqrt(sq / n_err) if n_err else math.nan,
        })

    def span_mean(key: str, first: bool) -> float:
        sel = [r[key] for r in series if (r["t_s"] + tracker.bin_s <= window if first else r["t_s"] >= elapsed - window)]
        sel = [v for v in sel if v == v]
        return sum(sel) / len(sel) if sel else math.nan

    away = max(1, intact - tracker.lost_near_fault)
    result = {
        "duration_s": round(elapsed, 1),
        "startup_to_first_answer_s": round(startup_s, 1),
        "rate_hz": 400,
        "scenario": args.scenario,
        "filter": args.filter,
        "window_s": window,
        "samples": {
            "intact_delivered": intact,
            "answered": tracker.answered,
            "lost": tracker.lost,
            "lost_share": tracker.lost / away,
            "lost_near_fault": tracker.lost_near_fault,
            "answers_without_pending_sample": tracker.late_answers,
        },
        "faults_injected": {**faults, "relay": {k: v for k, v in vars(relay_c).items() if k != "replies"}},
        "rss_mb": {"start": rss_start, "end": rss_end, "growth": rss_end - rss_start, "slope_mb_per_h": slope,
                   "max": max((v for _, v in rss if v == v), default=math.nan), "samples": len(rss)},
        "latency_end_to_end": {"first": _percentiles(tracker.first_lat), "last": _percentiles(last_lat)},
        "latency_daemon_us": {
            "first": {"p50": _median([s.get("latency_p50_us") for s in first_status]),
                      "p99": _median([s.get("latency_p99_us") for s in first_status])},
            "last": {"p50": _median([s.get("latency_p50_us") for s in last_status]),
                     "p99": _median([s.get("latency_p99_us") for s in last_status])},
        },
        "daemon_cpu_us_per_sample": {"first": span_mean("daemon_cpu_us_per_sample", True),
                                     "last": span_mean("daemon_cpu_us_per_sample", False)},
        "load_average_1min": {"first": span_mean("load_1min", True), "last": span_mean("load_1min", False)},
        "tilt_error_deg": {
            "first_rms": math.sqrt(sum(e * e for e in tracker.first_err) / len(tracker.first_err)) if tracker.first_err else math.nan,
            "last_rms": math.sqrt(sum(e * e for e in last_err) / len(last_err)) if last_err else math.nan,
        },
        "daemon": {
            "exit_code": rc,
            "died_early": dead,
            "tracebacks": daemon.tracebacks,
            "counters": dstats.get("counters"),
            "codec": dstats.get("codec"),
            "pipeline_drops": (dstats.get("pipeline") or {}).get("drops"),
            "pipeline_counters": (dstats.get("pipeline") or {}).get("counters"),
        },
        "simulator_restarts": sim.restarts,
        "series": series,
    }
    problems = []
    if dead or rc != 0 or daemon.tracebacks:
        problems.append(f"daemon ended badly (exit {rc}, died early {dead}, tracebacks {daemon.tracebacks})")
    if not rss_end - rss_start <= args.max_rss_growth_mb:
        problems.append(f"RSS grew {rss_end - rss_start:.1f} MB (> {args.max_rss_growth_mb})")
    if len(base) >= 3 and elapsed >= 600 and not slope <= args.max_rss_slope_mb_h:
        problems.append(f"RSS slope {slope:.1f} MB/h (> {args.max_rss_slope_mb_h})")
    if not tracker.lost / away <= args.max_lost:
        problems.append(f"{tracker.lost} of {away} intact samples unanswered (> {args.max_lost:.2%})")
    if intact == 0:
        problems.append("no samples reached the daemon")
    result["problems"] = problems
    result["ok"] = not problems
    text = json.dumps(result, indent=2, default=lambda v: None if isinstance(v, float) and not math.isfinite(v) else str(v))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(text + "\n")
    e2e = result["latency_end_to_end"]
    dl = result["latency_daemon_us"]
    print(
        f"soak {elapsed:.0f} s at 400 Hz ({args.scenario}, {args.filter}; first answer {startup_s:.1f} s after the "
        f"simulator started): {intact} intact samples delivered, "
        f"{tracker.answered} answered, {tracker.lost} lost (+{tracker.lost_near_fault} right after a fault); "
        f"faults {faults}, relay {relay_c.lost} lost / {relay_c.bit_flips} flipped / {relay_c.truncated} truncated / "
        f"{relay_c.junk} junk / {relay_c.duplicates} duplicated / {relay_c.reordered} reordered datagrams\n"
        f"RSS {rss_start:.1f} → {rss_end:.1f} MB (slope {slope:+.2f} MB/h); end-to-end latency p50/p99 first "
        f"{e2e['first']['p50_ms']:.2f}/{e2e['first']['p99_ms']:.2f} ms, last {e2e['last']['p50_ms']:.2f}/"
        f"{e2e['last']['p99_ms']:.2f} ms; daemon p50/p99 first {dl['first']['p50']:.0f}/{dl['first']['p99']:.0f} µs, "
        f"last {dl['last']['p50']:.0f}/{dl['last']['p99']:.0f} µs; daemon CPU per sample first "
        f"{result['daemon_cpu_us_per_sample']['first']:.0f} µs, last {result['daemon_cpu_us_per_sample']['last']:.0f} µs "
        f"(load average {result['load_average_1min']['first']:.1f} / {result['load_average_1min']['last']:.1f}); tilt RMS first "
        f"{result['tilt_error_deg']['first_rms']:.2f}° last {result['tilt_error_deg']['last_rms']:.2f}°\n"
        + ("OK" if not problems else "FAILED: " + "; ".join(problems))
    )
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
