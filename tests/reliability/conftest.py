"""Shared tools of the reliability suite: daemon runners, a ground station, a crafted autopilot, truth.

* :class:`DaemonProcess` — ``python -m mavahrs run …`` as a user runs it
  (stderr collected by a thread, RSS from /proc, SIGTERM/SIGKILL);
* :class:`InProcessDaemon` — the same :func:`build_daemon` path in a thread,
  for tests that read the daemon's counters directly (real sockets);
* :class:`Collector` — a ground station receiving the daemon's output;
* :class:`CraftedAutopilot` — an ArduPilot stand-in built on :class:`MavCodec`
  that sends exactly the RAW_IMU/SCALED_IMU2/HEARTBEAT frames a test wants
  (any timestamp, any value, signed or not), for a known smooth motion;
* the fault relays themselves are library code: :mod:`mavahrs.transports.relay`.
"""

from __future__ import annotations

import json
import logging
import math
import os
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
from mavahrs.geometry.rotation import from_euler_rad, to_matrix
from mavahrs.protocol.codec import MavCodec

REPO = Path(__file__).resolve().parents[2]
G = 9.80665
MAG_NED_UT = np.array([22.0, 2.0, 42.0])
#: Linux's SO_RCVBUFFORCE (not in Python's socket module): a receive buffer beyond net.core.rmem_max (root)
_SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33) if sys.platform.startswith("linux") else None


# --------------------------------------------------------------------------- environment


@pytest.fixture(autouse=True)
def _restore_mavahrs_logger():
    """``main()`` configures the ``mavahrs`` logger (own handler, no propagation): undo it after each test."""
    logger = logging.getLogger("mavahrs")
    handlers, level, propagate = list(logger.handlers), logger.level, logger.propagate
    logger.propagate = True  # caplog sees the daemon's lines even after an earlier test ran main()
    yield
    logger.handlers[:] = handlers
    logger.setLevel(level)
    logger.propagate = propagate


def env() -> dict[str, str]:
    e = dict(os.environ)
    e["PYTHONPATH"] = str(REPO) + os.pathsep + e.get("PYTHONPATH", "")
    return e


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def filter_name() -> str:
    try:
        import mavahrs.filters.best  # noqa: F401
    except ModuleNotFoundError:
        return "mahony"
    return "best"


# --------------------------------------------------------------------------- daemon runners


class DaemonProcess:
    """``python -m mavahrs [--log-format json] run …`` with stderr collected by a thread."""

    def __init__(self, args: list[str], cwd: Path, *, json_log: bool = True) -> None:
        self.lines: list[str] = []
        pre = ["--log-format", "json"] if json_log else []
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mavahrs", *pre, "run", *args],
            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env(), cwd=cwd,
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    @property
    def log(self) -> str:
        return "\n".join(self.lines)

    def messages(self) -> list[dict[str, Any]]:
        out = []
        for line in list(self.lines):
            try:
                out.append(json.loads(line))
            except ValueError:
                out.append({"message": line})
        return out

    def statuses(self) -> list[dict[str, Any]]:
        return [m["status"] for m in self.messages() if "status" in m]

    def wait_for(self, text: str, timeout_s: float = 180.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(text in line for line in list(self.lines)):
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(f"daemon never said {text!r}:\n{self.log}")

    def rss_kb(self) -> int:
        with open(f"/proc/{self.proc.pid}/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
        raise AssertionError("no VmRSS")

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(30)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(5)
        return rc


class InProcessDaemon:
    """:func:`build_daemon` + ``Daemon.run`` in a thread: the real daemon, counters readable directly."""

    def __init__(self, gcs_port: int | None = None, *, pipeline: dict[str, Any] | None = None, **daemon: Any) -> None:
        from mavahrs.service.daemon import DaemonSettings, build_daemon
        from mavahrs.service.pipeline import PipelineSettings

        daemon.setdefault("master", "udpin:127.0.0.1:0")
        daemon.setdefault("status_interval_s", 0.0)
        daemon.setdefault("heartbeat_timeout_s", 0.0)
        if gcs_port is not None:
            daemon.setdefault("outputs", (f"udpout:127.0.0.1:{gcs_port}",))
        p = {"filter_name": filter_name(), "out_rate_hz": 0.0, "request_streams": False, **(pipeline or {})}
        self.daemon = build_daemon(DaemonSettings(**daemon), PipelineSettings(**p))
        self.result: Any = None
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        return int(self.daemon.master.local_address[1])

    @property
    def pipeline(self) -> Any:
        return self.daemon.pipeline

    def _run(self) -> None:
        try:
            self.result = self.daemon.run()
        except BaseException as exc:  # noqa: BLE001
            self.error = exc

    def stop(self) -> Any:
        self.daemon.stop()
        self._thread.join(60)  # a sample being filtered may first have to compile the kernel (numba)
        assert not self._thread.is_alive(), "daemon thread did not stop"
        if self.error is not None:
            raise self.error
        return self.result


class Collector:
    """A ground station: receives the daemon's output on a UDP port (a thread)."""

    def __init__(self, codec: MavCodec | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # a ground station that is late (a loaded machine) must not lose what the daemon sent: 4 MiB
        # (~10 s of 400 Hz attitudes); SO_RCVBUFFORCE (root) passes net.core.rmem_max, to which
        # SO_RCVBUF is capped (208 KiB by default on Linux)
        try:
            if _SO_RCVBUFFORCE is None:
                raise OSError("Linux only")
            self.sock.setsockopt(socket.SOL_SOCKET, _SO_RCVBUFFORCE, 4 << 20)
        except OSError:  # not Linux, or not root
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.codec = codec or MavCodec(drop_duplicates=False)
        self.messages: list[tuple[float, Any]] = []  # (wall-clock receipt time, message)
        self.frames: list[bytes] = []
        self._stop = False
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            now = time.time()
            msgs = self.codec.receive_datagram(data)
            with self._lock:
                self.frames.append(data)
                self.messages.extend((now, m) for m in msgs)

    def attitudes(self) -> list[Any]:
        with self._lock:
            return [m for _, m in self.messages if m.get_type() == "ATTITUDE_QUATERNION"]

    def wait_attitudes(self, n: int, timeout_s: float = 10.0) -> list[Any]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and len(self.attitudes()) < n:
            time.sleep(0.02)
        return self.attitudes()

    def wait_quiet(self, quiet_s: float = 0.3, timeout_s: float = 10.0) -> list[Any]:
        """Attitudes once nothing new arrived for ``quiet_s``."""
        deadline = time.monotonic() + timeout_s
        n, since = -1, time.monotonic()
        while time.monotonic() < deadline:
            k = len(self.attitudes())
            if k != n:
                n, since = k, time.monotonic()
            elif time.monotonic() - since >= quiet_s:
                break
            time.sleep(0.02)
        return self.attitudes()

    def close(self) -> None:
        self._stop = True
        self._thread.join(5)
        self.sock.close()


def start_sim(args: list[str], cwd: Path, **kw: Any) -> subprocess.Popen:
    """``python -m firmware_sim`` (idealised 400 Hz stream with SIMSTATE truth in the same datagram)."""
    kw.setdefault("stdout", subprocess.DEVNULL)
    return subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--ideal", "--stream", "SIMSTATE=400", "--stream", "RAW_IMU=400",
         "-q", *args],
        cwd=cwd, env=env(), text=True, **kw,
    )


# --------------------------------------------------------------------------- truth and errors


def truth_from_datagrams(datagrams: list[bytes]) -> dict[int, np.ndarray]:
    """RAW_IMU ``time_usec // 1000`` → SIMSTATE truth quaternion sent in the same datagram."""
    codec = MavCodec(drop_duplicates=False)
    truth: dict[int, np.ndarray] = {}
    for d in datagrams:
        imu = sim = None
        for m in codec.receive_datagram(d):
            kind = m.get_type()
            if kind == "RAW_IMU":
                imu = m
            elif kind == "SIMSTATE":
                sim = m
        if imu is not None and sim is not None:
            truth[imu.time_usec // 1000] = from_euler_rad(sim.roll, sim.pitch, sim.yaw)
    return truth


def imu_ms_in(datagrams: list[bytes]) -> list[int]:
    """``time_usec // 1000`` of every RAW_IMU that decodes from these datagrams, each parsed on its own."""
    out = []
    for d in datagrams:
        codec = MavCodec(drop_duplicates=False)
        out += [m.time_usec // 1000 for m in codec.receive_datagram(d) if m.get_type() == "RAW_IMU"]
    return out


def tilt_errors_deg(attitudes: dict[int, np.ndarray], truth: dict[int, np.ndarray], keys: list[int]) -> np.ndarray:
    """Inclination error per key (ms), degrees."""
    if not keys:
        return np.zeros(0)
    q_est = np.array([attitudes[k] for k in keys])
    q_ref = np.array([truth[k] for k in keys])
    _, _, tilt = attitude_errors_rad(q_est, q_ref)
    return np.degrees(tilt)


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else math.nan


def recovery_time_s(t_s: np.ndarray, err_deg: np.ndarray, start_s: float, bound_deg: float, hold_s: float = 1.0) -> float:
    """Seconds after ``start_s`` until the error is ≤ ``bound_deg`` and stays so for ``hold_s`` (inf: never)."""
    sel = t_s >= start_s
    t, e = t_s[sel], err_deg[sel]
    if not len(t):
        return math.inf
    bad = np.nonzero(e > bound_deg)[0]
    candidates = [0] + [int(i) + 1 for i in bad]
    for c in candidates:
        if c >= len(t):
            return math.inf
        later_bad = bad[bad >= c]
        horizon_ok = t[-1] - t[c] >= hold_s
        if (not len(later_bad) or t[later_bad[0]] - t[c] >= hold_s) and horizon_ok:
            return float(t[c] - start_s)
    return math.inf


# --------------------------------------------------------------------------- a crafted autopilot


class Motion:
    """A known smooth motion: roll swings ±15° around 20° at 0.5 Hz, pitch −10°, heading 30°, at rest otherwise."""

    ROLL0, ROLL_AMP, ROLL_HZ = math.radians(20.0), math.radians(15.0), 0.5
    PITCH, YAW = math.radians(-10.0), math.radians(30.0)

    def euler(self, t_s: float) -> tuple[float, float, float, float]:
        """(roll, pitch, yaw, roll rate) at ``t_s``, rad and rad/s."""
        w = 2 * math.pi * self.ROLL_HZ
        roll = self.ROLL0 + self.ROLL_AMP * math.sin(w * t_s)
        return roll, self.PITCH, self.YAW, self.ROLL_AMP * w * math.cos(w * t_s)

    def q(self, t_s: float) -> np.ndarray:
        r, p, y, _ = self.euler(t_s)
        return from_euler_rad(r, p, y)

    def sample(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(specific force m/s², body rates rad/s, field µT) in body axes."""
        r, p, y, dr = self.euler(t_s)
        c = to_matrix(from_euler_rad(r, p, y))  # body → NED
        return c.T @ np.array([0.0, 0.0, -G]), np.array([dr, 0.0, 0.0]), c.T @ MAG_NED_UT


class CraftedAutopilot:
    """An ArduPilot stand-in on a UDP socket: HEARTBEAT, RAW_IMU, SCALED_IMU2 exactly as asked.

    ``boot_us`` is the autopilot's clock at the motion's t = 0.  ``key`` signs
    every frame (MAVLink 2 signing, timestamps from wall time).
    """

    def __init__(
        self, port: int, *, system_id: int = 1, component_id: int = 1, key: bytes | None = None,
        link_id: int = 0, boot_us: int = 1_000_000,
    ) -> None:
        from mavahrs.protocol.signing import signing_timestamp_10us

        self.codec = MavCodec(system_id, component_id)
        if key is not None:
            self.codec.enable_signing(key, link_id, signing_timestamp_10us(time.time()))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.addr = ("127.0.0.1", port)
        self.motion = Motion()
        self.boot_us = boot_us
        self.sent: list[bytes] = []

    def send(self, frame: bytes) -> bytes:
        self.sock.sendto(frame, self.addr)
        self.sent.append(frame)
        return frame

    def heartbeat(self) -> bytes:
        return self.send(self.codec.encode(self.codec.mav.heartbeat_encode(2, 3, 0, 0, 4)))

    def raw_imu_frame(self, t_us: int, *, motion_t_s: float | None = None, override: dict[str, float] | None = None) -> bytes:
        """RAW_IMU stamped ``t_us`` of the motion at ``motion_t_s`` (default: (t_us − boot) s); ``override`` sets wire fields."""
        ts = (t_us - self.boot_us) * 1e-6 if motion_t_s is None else motion_t_s
        f, w, m = self.motion.sample(ts)
        fields = {
            "xacc": f[0] / G * 1000, "yacc": f[1] / G * 1000, "zacc": f[2] / G * 1000,
            "xgyro": w[0] * 1000, "ygyro": w[1] * 1000, "zgyro": w[2] * 1000,
            "xmag": m[0] * 10, "ymag": m[1] * 10, "zmag": m[2] * 10,
        }
        fields.update(override or {})
        v = [int(round(fields[k])) for k in ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")]
        v = [max(-32768, min(32767, x)) for x in v]
        return self.codec.encode(self.codec.mav.raw_imu_encode(int(t_us), *v, 0, 3500))

    def raw_imu(self, t_us: int, **kw: Any) -> bytes:
        return self.send(self.raw_imu_frame(t_us, **kw))

    def scaled_imu2_zero(self, t_us: int) -> bytes:
        """The all-zero SCALED_IMU2 of a board without a second IMU (ArduPilot sends it anyway)."""
        return self.send(self.codec.encode(self.codec.mav.scaled_imu2_encode(int(t_us) // 1000, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)))

    def highres_imu(self, t_us: int, values: list[float], fields_updated: int = 0x1FFF) -> bytes:
        """HIGHRES_IMU with raw float values (NaN/inf allowed): acc m/s², gyro rad/s, mag gauss."""
        return self.send(self.codec.encode(self.codec.mav.highres_imu_encode(
            int(t_us), *values, 1013.0, 0.0, 10.0, 20.0, fields_updated, 0)))

    def stream(self, t0_us: int, n: int, *, rate_hz: float = 400.0, pace_hz: float = 800.0, **kw: Any) -> list[int]:
        """Send ``n`` RAW_IMU from ``t0_us`` every 1/rate_hz, paced at ``pace_hz`` (faster than real time); their ms."""
        step = int(round(1e6 / rate_hz))
        out = []
        t_next = time.monotonic()
        for k in range(n):
            t = t0_us + k * step
            self.raw_imu(t, **kw)
            out.append(t // 1000)
            t_next += 1.0 / pace_hz
            if k % 8 == 7:
                d = t_next - time.monotonic()
                if d > 0:
                    time.sleep(d)
        return out

    def close(self) -> None:
        self.sock.close()


def attitude_map(attitudes: list[Any]) -> dict[int, np.ndarray]:
    return {m.time_boot_ms: np.array([m.q1, m.q2, m.q3, m.q4]) for m in attitudes}


def motion_truth(ap: CraftedAutopilot, keys_ms: list[int], boot_us: int | None = None) -> dict[int, np.ndarray]:
    boot = ap.boot_us if boot_us is None else boot_us
    return {k: ap.motion.q((k * 1000 - boot) * 1e-6) for k in keys_ms}


@pytest.fixture(scope="session")
def rt() -> Any:
    """The reliability tools above, for test modules (``--import-mode=importlib``: no ``from conftest import``)."""
    import types

    names = (
        "REPO", "G", "env", "free_udp_port", "filter_name", "DaemonProcess", "InProcessDaemon", "Collector",
        "start_sim", "truth_from_datagrams", "imu_ms_in", "tilt_errors_deg", "rms", "recovery_time_s", "Motion",
        "CraftedAutopilot", "attitude_map", "motion_truth",
    )
    g = globals()
    return types.SimpleNamespace(**{n: g[n] for n in names})
