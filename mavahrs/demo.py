r"""``mavahrs demo``: a simulated autopilot, the daemon and a ground-station view, on loopback UDP.

What runs (one command, nothing to configure):

* ``firmware_sim`` as a subprocess (``python -m firmware_sim``: a simulated
  ArduPilot flying a scenario, streaming RAW_IMU like a real one and the
  simulator's exact attitude as SIMSTATE) → ``udpout`` to
* the daemon (:class:`~mavahrs.service.daemon.Daemon`, exactly what
  ``mavahrs run`` runs, in a thread of this process), which asks the
  "autopilot" for the IMU stream, estimates the attitude and sends
  ATTITUDE_QUATERNION (component 191) to
* a ground-station view in the main thread (a UDP socket, like a GCS), which
  shows the attitude live next to the truth.

The daemon's pipeline is wrapped by :class:`TruthTap`, which only *looks* at
the messages: each SIMSTATE that arrives in the same datagram as a RAW_IMU
(the simulator sends one datagram per scheduler tick) is the exact truth at
that RAW_IMU's ``time_usec``, the timestamp the daemon's attitude carries as
``time_boot_ms``.  The final score compares the attitudes the ground station
received with that truth (:func:`score`), the tlog written by the daemon keeps
everything in and out (SIMSTATE included), and :func:`plot` draws truth,
estimate and error per angle.

``mavahrs`` never imports ``firmware_sim``: it is started as a program.
"""

from __future__ import annotations

import logging
import logging.handlers
import math
import queue
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mavahrs.errors import ConfigError, MavahrsError
from mavahrs.evaluation.metrics import AttitudeErrorSummary, attitude_errors_rad, summarize

__all__ = ["DemoSettings", "DemoResult", "TruthTap", "run_demo", "score", "plot", "format_summary", "SCENARIOS"]

#: the simulator's scenarios (``python -m firmware_sim --list-scenarios``), checked before starting
SCENARIOS = ("rest", "hover", "aggressive", "flips", "highg", "magnetic", "mag_anomaly", "vibration", "temperature")

_COMPONENT = 191  # MAV_COMP_ID_ONBOARD_COMPUTER: the daemon's output
_LOG = logging.getLogger("mavahrs.demo")


@dataclass(frozen=True)
class DemoSettings:
    """What ``mavahrs demo`` runs.

    Attributes:
        duration_s: simulated flight time, s.
        scenario: the simulator's flight (``aggressive``: sustained tilted
            acceleration, where the accelerometer does not point to gravity).
        filter_name: the daemon's attitude filter.
        outdir: directory for the tlog and the plot (created).
        seed: the simulator's seed (same seed, same flight).
        out_rate_hz: ATTITUDE_QUATERNION rate, Hz.
        settle_s: the first seconds of attitude output left out of the score
            (the filter's start-up convergence), s.
        status_interval_s: seconds between live status lines (on a terminal
            the line is redrawn in place; otherwise every 4th is printed).
        startup_timeout_s: give up when no attitude arrives this long after
            the simulator started, s.
        plot: draw the PNG (needs matplotlib, the ``plot`` extra).
    """

    duration_s: float = 20.0
    scenario: str = "aggressive"
    filter_name: str = "best"
    outdir: str = "mavahrs-demo"
    seed: int = 1
    out_rate_hz: float = 50.0
    settle_s: float = 3.0
    status_interval_s: float = 0.5
    startup_timeout_s: float = 60.0
    plot: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ConfigError(f"demo duration must be a positive number of seconds, got {self.duration_s!r}")
        if self.scenario not in SCENARIOS:
            raise ConfigError(f"unknown scenario {self.scenario!r}; choose one of {', '.join(SCENARIOS)}")
        if not (self.out_rate_hz >= 0 and self.settle_s >= 0 and self.status_interval_s > 0):
            raise ConfigError("demo: out_rate_hz and settle_s must be ≥ 0, status_interval_s > 0")


@dataclass
class DemoResult:
    """What a demo run produced.

    Attributes:
        summary: inclination/heading/total RMS vs truth after ``settle_s`` (None: nothing scored).
        imu_rate_hz: IMU (RAW_IMU) messages per second of autopilot time reaching the daemon.
        out_rate_hz: ATTITUDE_QUATERNION per second of sample time at the ground station.
        attitudes: ATTITUDE_QUATERNION messages the ground station received.
        truth_samples: exact truth samples paired with an IMU timestamp.
        tlog_path / plot_path: the files left behind (plot None if not drawn).
        interrupted: stopped by Ctrl-C before the end.
        flight_s: simulated seconds covered by the attitude output.
    """

    summary: AttitudeErrorSummary | None
    imu_rate_hz: float
    out_rate_hz: float
    attitudes: int
    truth_samples: int
    tlog_path: Path
    plot_path: Path | None
    interrupted: bool
    flight_s: float
    notes: list[str] = field(default_factory=list)


class TruthTap:
    """Wraps the daemon's pipeline; records the simulator's truth and the IMU rate on the way through.

    Runs in the daemon's thread; the main thread only reads the lists and the
    dict (appends and item assignment are atomic in CPython).  Per message it
    costs one type lookup; no numpy, no allocation beyond the stored tuples.
    """

    def __init__(self, pipeline: Any) -> None:
        self._pipeline = pipeline
        self._handle = pipeline.handle
        #: (time_boot_ms, roll_rad, pitch_rad, yaw_rad) in arrival order
        self.truth: list[tuple[int, float, float, float]] = []
        self.truth_by_ms: dict[int, tuple[float, float, float]] = {}
        self.imu_messages = 0
        self.imu_first_us: int | None = None
        self.imu_last_us: int | None = None
        self._last_imu: tuple[int, int] = (-1, 0)  # (daemon now_us, time_usec) of the last RAW_IMU

    def handle(self, msg: Any, now_us: int) -> Any:
        kind = msg.get_type()
        if kind == "RAW_IMU":
            t = int(msg.time_usec)
            self.imu_messages += 1
            if self.imu_first_us is None:
                self.imu_first_us = t
            self.imu_last_us = t
            self._last_imu = (now_us, t)
        elif kind == "SIMSTATE":
            seen_us, t = self._last_imu
            if seen_us == now_us:  # same datagram = same scheduler tick as that RAW_IMU
                t_ms = t // 1000
                rpy = (float(msg.roll), float(msg.pitch), float(msg.yaw))
                self.truth.append((t_ms, *rpy))
                self.truth_by_ms[t_ms] = rpy
        return self._handle(msg, now_us)

    def __getattr__(self, name: str) -> Any:  # tick, status, drain_notices, reset_link, …
        return getattr(self._pipeline, name)


# --------------------------------------------------------------------------- scoring


def _truth_arrays(truth: list[tuple[int, float, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    from mavahrs.geometry.rotation import from_euler_rad

    if not truth:
        return np.empty(0), np.empty((0, 4))
    a = np.asarray(truth, dtype=np.float64)
    order = np.argsort(a[:, 0], kind="stable")
    a = a[order]
    keep = np.ones(a.shape[0], dtype=bool)
    keep[1:] = np.diff(a[:, 0]) > 0  # one truth per millisecond
    a = a[keep]
    return a[:, 0] * 1000.0, from_euler_rad(a[:, 1], a[:, 2], a[:, 3])


def truth_at(truth: list[tuple[int, float, float, float]], t_ms: np.ndarray) -> np.ndarray:
    """The truth quaternion at each ``time_boot_ms`` (slerp between paired samples; NaN outside)."""
    from mavahrs.evaluation.tlogdata import interpolate_attitude

    t_ref_us, q_ref = _truth_arrays(truth)
    t_us = np.asarray(t_ms, dtype=np.float64) * 1000.0
    out = interpolate_attitude(t_ref_us, q_ref, t_us, max_gap_s=0.1)
    if t_ref_us.size:  # the same tick's truth where there is one (also at the very ends)
        i = np.clip(np.searchsorted(t_ref_us, t_us), 0, t_ref_us.size - 1)
        exact = t_ref_us[i] == t_us
        out[exact] = q_ref[i[exact]]
    return out


def score(
    t_ms: np.ndarray, q_est: np.ndarray, truth: list[tuple[int, float, float, float]], settle_s: float
) -> tuple[AttitudeErrorSummary | None, np.ndarray]:
    """RMS errors of the received attitudes against the truth, after the first ``settle_s``.

    Returns the summary (None when nothing could be scored) and the truth at ``t_ms``.
    """
    t_ms = np.asarray(t_ms, dtype=np.float64)
    q_ref = truth_at(truth, t_ms)
    if t_ms.size == 0:
        return None, q_ref
    mask = t_ms >= t_ms[0] + settle_s * 1000.0
    s = summarize(q_est, q_ref, mask)
    return (s if s.samples else None), q_ref


def plot(path: Path, t_ms: np.ndarray, q_est: np.ndarray, q_ref: np.ndarray, settings: DemoSettings) -> Path:
    """Truth, estimate and error per angle (``mavahrs.evaluation.plots.plot_attitude``)."""
    from mavahrs.evaluation.plots import plot_attitude

    t_s = (np.asarray(t_ms, dtype=np.float64) - float(t_ms[0])) / 1000.0
    return plot_attitude(
        path,
        t_s,
        {f"mavahrs ({settings.filter_name})": np.asarray(q_est)},
        reference_q=q_ref,
        reference_label="simulator truth (SIMSTATE)",
        title=f"mavahrs demo: '{settings.scenario}' scenario, {settings.filter_name} filter, "
        "attitude as received by the ground station",
    )


def format_summary(result: DemoResult, settings: DemoSettings) -> list[str]:
    """The closing lines: accuracy, rates, what the numbers mean, where the files are."""
    lines = []
    s = result.summary
    if s is None:
        lines.append("accuracy vs truth: nothing to score (no attitude after the settling time)")
    else:
        lines.append(
            f"accuracy vs truth: inclination RMS {s.inclination_rms_deg:.2f}°, heading RMS {s.heading_rms_deg:.2f}° "
            f"({s.samples} attitudes over {result.flight_s:.1f} s of flight; first {settings.settle_s:g} s left out)"
        )
    lines.append(
        f"rates: IMU in {result.imu_rate_hz:.1f} Hz (RAW_IMU), attitude out {result.out_rate_hz:.1f} Hz "
        f"(ATTITUDE_QUATERNION, component {_COMPONENT})"
    )
    if s is not None:
        lines.append(
            "meaning: inclination is the error of the estimated tilt (which way is down), heading the error of "
            "the compass direction; both are typical (RMS) errors against the simulator's exact attitude while "
            f"the drone flew '{settings.scenario}'" + _verdict(s, settings) + "."
        )
    lines.append(f"tlog: {result.tlog_path}  (everything in and out, with SIMSTATE truth; "
                 f"`mavahrs replay {result.tlog_path}` replays it)")
    if result.plot_path is not None:
        lines.append(f"plot: {result.plot_path}  (truth, estimate and error per angle)")
    return lines


def _verdict(s: AttitudeErrorSummary, settings: DemoSettings) -> str:
    if settings.scenario != "aggressive":
        return ""
    if s.inclination_rms_deg <= 3.0:
        return (", where sustained acceleration makes the accelerometer point away from gravity: "
                "within mavahrs's 3° tilt target for this scenario")
    return (", where sustained acceleration makes the accelerometer point away from gravity: "
            "above mavahrs's 3° tilt target for this scenario")


# --------------------------------------------------------------------------- running


def _warm_up(pipeline_settings: Any) -> None:
    """Compile the filter kernels before the flight (numba caches them on disk after the first time)."""
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.service.pipeline import Pipeline
    from mavahrs.warmup import synthetic_frames

    pipeline = Pipeline(pipeline_settings)
    rx = MavCodec()
    for t_us, frame in synthetic_frames(0.05):
        for msg in rx.receive_datagram(frame):
            pipeline.handle(msg, t_us)


class _GroundStation:
    """A UDP socket receiving the daemon's output, as a ground station would."""

    def __init__(self) -> None:
        from mavahrs.protocol.codec import MavCodec

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = int(self.sock.getsockname()[1])
        self._codec = MavCodec()
        self.t_ms: list[int] = []
        self.q: list[tuple[float, float, float, float]] = []
        self.heartbeats = 0

    def drain(self) -> None:
        for _ in range(4096):
            try:
                data = self.sock.recv(65535)
            except (BlockingIOError, InterruptedError):
                return
            for msg in self._codec.receive_datagram(data):
                if msg.get_srcComponent() != _COMPONENT:
                    continue
                kind = msg.get_type()
                if kind == "ATTITUDE_QUATERNION":
                    self.t_ms.append(int(msg.time_boot_ms))
                    self.q.append((float(msg.q1), float(msg.q2), float(msg.q3), float(msg.q4)))
                elif kind == "HEARTBEAT":
                    self.heartbeats += 1

    def close(self) -> None:
        self.sock.close()


class _Live:
    """The live status line: rates over the last ``window_s`` seconds, attitude, truth and error.

    The rates are counted over a window of several status lines, not since the last line:
    datagrams arrive in bursts on a busy machine (the simulator, the daemon and this loop share
    the cores), and 0.5 s between two lines read a 250 Hz stream as 200 then 293 Hz.
    """

    def __init__(
        self, tap: TruthTap, gcs: _GroundStation, *, window_s: float = 2.0,
        clock: Callable[[], float] | None = None,
    ) -> None:  # fmt: skip
        self.tap, self.gcs = tap, gcs
        self.window_s = float(window_s)
        self._clock = clock or time.monotonic
        self._history: deque[tuple[float, int, int]] = deque([(self._clock(), 0, 0)])

    def line(self, elapsed_s: float) -> str:
        now = self._clock()
        imu, out = self.tap.imu_messages, len(self.gcs.t_ms)
        # the reference: the newest earlier line at least window_s old (the oldest one until then)
        hist = self._history
        while len(hist) > 1 and hist[1][0] <= now - self.window_s:
            hist.popleft()
        t0, imu0, out0 = hist[0]
        hist.append((now, imu, out))
        dt = max(now - t0, 1e-6)
        text = f"{elapsed_s:5.1f} s | in {(imu - imu0) / dt:4.0f} Hz -> out {(out - out0) / dt:3.0f} Hz"
        if not out:
            return text + " | waiting for the first attitude"
        q = np.asarray(self.gcs.q[-1], dtype=np.float64)
        from mavahrs.evaluation.metrics import euler_deg

        r, p, y = euler_deg(q)[0]
        text += f" | roll {r:+6.1f}° pitch {p:+6.1f}° yaw {y % 360.0:5.1f}°"
        # The error of the newest attitude whose tick has a truth within 5 ms.  The output's
        # tick may carry no SIMSTATE (with both streams at 250 Hz on a 400 Hz loop their ticks
        # coincide in a pattern that depends on when each stream started), and the nearest truth
        # may be a later tick that has not arrived yet: older attitudes are tried too (the final
        # score interpolates instead).
        truth = None
        for j in range(1, min(len(self.gcs.t_ms), 25) + 1):
            t_ms = self.gcs.t_ms[-j]
            for k in range(6):
                truth = self.tap.truth_by_ms.get(t_ms - k) or self.tap.truth_by_ms.get(t_ms + k)
                if truth is not None:
                    break
            if truth is not None:
                q = np.asarray(self.gcs.q[-j], dtype=np.float64)
                break
        if truth is None:
            return text
        from mavahrs.geometry.rotation import from_euler_rad

        q_ref = from_euler_rad(*truth)
        _, heading, incl = attitude_errors_rad(q[None, :], q_ref[None, :])
        return text + f" | error vs truth: tilt {math.degrees(incl[0]):4.1f}° heading {math.degrees(heading[0]):4.1f}°"


def _sim_command(settings: DemoSettings, port: int) -> list[str]:
    return [
        sys.executable, "-m", "firmware_sim",
        "--out", f"udpout:127.0.0.1:{port}",
        "--scenario", settings.scenario,
        "--duration", f"{settings.duration_s:g}",
        "--seed", str(settings.seed),
        "--stream", "SIMSTATE=max",  # the truth with every scheduler tick that carries an IMU sample
        "-q",
    ]  # fmt: skip


def _stop_process(proc: subprocess.Popen[bytes], timeout_s: float = 5.0) -> None:
    if proc.poll() is not None:
        return
    try:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout_s)
    except OSError:
        pass


def run_demo(
    settings: DemoSettings,
    out: Callable[[str], None] = print,
    *,
    is_tty: bool | None = None,
) -> DemoResult:
    """Run the demo; print progress with ``out``; return the result (Ctrl-C ends early, still scored).

    Raises:
        ConfigError: bad settings or output directory.
        MavahrsError: the simulator or the daemon failed (the reason in the message).
    """
    from mavahrs.service.daemon import DaemonSettings, build_daemon
    from mavahrs.service.pipeline import PipelineSettings

    tty = sys.stdout.isatty() if is_tty is None else is_tty
    outdir = Path(settings.outdir)
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create the output directory {outdir}: {exc.strerror or exc}") from None
    tlog_path = outdir / f"{settings.scenario}.tlog"
    png_path = outdir / f"{settings.scenario}.png"
    # Each demo records a fresh tlog: the daemon's --log appends (as MAVProxy does, for a restarted
    # service), but a second demo appended to the first would read as one flight with a reboot.
    replaced = tlog_path.exists()
    if replaced:
        try:
            tlog_path.unlink()
        except OSError as exc:
            raise ConfigError(f"cannot replace the previous demo's tlog {tlog_path}: {exc.strerror or exc}") from None
    pipeline_settings = PipelineSettings(filter_name=settings.filter_name, out_rate_hz=settings.out_rate_hz)

    out(f"mavahrs demo: a simulated ArduPilot flies '{settings.scenario}' for {settings.duration_s:g} s; "
        f"mavahrs estimates its attitude with the '{settings.filter_name}' filter.")
    out("loading the filter …")  # seconds even on a warm cache on a busy machine: not a silent wait
    t_prep = time.monotonic()
    _warm_up(pipeline_settings)  # a cold cache compiles here (the command line says so: cli.common.COMPILE_NOTICE)
    if time.monotonic() - t_prep > 3.0:
        out(f"filter ready after {time.monotonic() - t_prep:.0f} s")

    gcs = _GroundStation()
    # While the demo runs, everything mavahrs logs (daemon, pipeline notices) comes through a queue
    # and is printed between status lines by the main thread.
    lib_log = logging.getLogger("mavahrs")
    saved_handlers, saved_level = list(lib_log.handlers), lib_log.level
    log_queue: queue.SimpleQueue[logging.LogRecord] = queue.SimpleQueue()
    handler = logging.handlers.QueueHandler(log_queue)
    lib_log.handlers = [handler]
    if lib_log.level == logging.NOTSET:
        lib_log.setLevel(logging.INFO)

    def restore_logging() -> None:
        lib_log.handlers = saved_handlers
        lib_log.setLevel(saved_level)
    daemon_settings = DaemonSettings(
        master="udpin:127.0.0.1:0",
        outputs=(f"udpout:127.0.0.1:{gcs.port}",),
        log_path=str(tlog_path),
        status_interval_s=0.0,  # the demo prints its own line
        heartbeat_timeout_s=0.0,  # the demo watches the start-up itself
    )
    try:
        daemon = build_daemon(daemon_settings, pipeline_settings)
    except BaseException:
        gcs.close()
        restore_logging()
        raise
    tap = TruthTap(daemon.pipeline)
    daemon.pipeline = tap
    port = daemon.master.local_address[1]
    failure: list[BaseException] = []

    def run_daemon() -> None:
        try:
            daemon.run()
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            failure.append(exc)

    thread = threading.Thread(target=run_daemon, name="mavahrs-daemon", daemon=True)
    thread.start()
    err_file = tempfile.TemporaryFile()
    cmd = _sim_command(settings, port)
    out(f"daemon: listening on udpin:127.0.0.1:{port}, attitude to udpout:127.0.0.1:{gcs.port} "
        f"(this program's ground-station view), recording {tlog_path}"
        + (" (overwriting the previous demo's tlog)" if replaced else " (a new file)"))
    out(f"simulator: {' '.join(['python', *cmd[1:]])}")
    sim = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err_file)
    live = _Live(tap, gcs)
    sel = selectors.DefaultSelector()
    sel.register(gcs.sock, selectors.EVENT_READ)
    started = time.monotonic()
    next_status = started + settings.status_interval_s
    n_status = 0
    interrupted = False
    status_shown = False
    notes: list[str] = []

    def show_logs() -> None:
        nonlocal status_shown
        while True:
            try:
                rec = log_queue.get_nowait()
            except queue.Empty:
                return
            if status_shown and tty:
                out("\r\033[K")
                status_shown = False
            level = "" if rec.levelno <= logging.INFO else f"{rec.levelname.lower()}: "
            out(f"  [mavahrs] {level}{rec.getMessage()}")

    try:
        sim_done_at: float | None = None
        while True:
            sel.select(0.1)
            gcs.drain()
            show_logs()
            now = time.monotonic()
            if failure:
                break
            if now >= next_status:
                next_status += settings.status_interval_s
                n_status += 1
                line = live.line(now - started)
                if tty:
                    out("\r\033[K" + line)
                    status_shown = True
                elif n_status % 4 == 0:
                    out(line)
            if sim_done_at is None and sim.poll() is not None:
                sim_done_at = now
            if sim_done_at is not None and now - sim_done_at > 0.5:
                break
            if not gcs.t_ms and now - started > settings.startup_timeout_s:
                notes.append(f"no attitude within {settings.startup_timeout_s:g} s")
                break
            if now - started > settings.duration_s * 4 + settings.startup_timeout_s:
                notes.append("the simulator ran far behind real time; stopped")
                break
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if status_shown and tty:
            out("\r\033[K")
            status_shown = False
        out("flight over: stopping the simulator and the daemon, scoring against the truth"
            + (" and drawing the plot" if settings.plot else "") + " …")
        _stop_process(sim)
        daemon.stop()
        thread.join(15.0)
        gcs.drain()
        show_logs()
        if status_shown and tty:
            out("\r\033[K")
        sel.close()
        gcs.close()
        restore_logging()
    err_file.seek(0)
    sim_err = err_file.read().decode("utf-8", "replace").strip()
    err_file.close()
    if failure:
        raise MavahrsError(f"the daemon stopped: {failure[0]}") from failure[0]
    if not gcs.t_ms:
        why = "; ".join(notes) or "no ATTITUDE_QUATERNION reached the ground-station view"
        code = sim.returncode
        detail = f" (simulator exit code {code}: {sim_err.splitlines()[-1]})" if code not in (0, None) and sim_err else ""
        raise MavahrsError(f"the demo produced no attitude: {why}{detail}")
    if sim.returncode not in (0, None, -signal.SIGINT) and not interrupted:
        notes.append(f"simulator exit code {sim.returncode}: {sim_err.splitlines()[-1] if sim_err else ''}")
    t_ms = np.asarray(gcs.t_ms, dtype=np.float64)
    q_est = np.asarray(gcs.q, dtype=np.float64)
    summary, q_ref = score(t_ms, q_est, tap.truth, settings.settle_s)
    flight_s = float(t_ms[-1] - t_ms[0]) / 1000.0 if t_ms.size > 1 else 0.0
    imu_span_s = ((tap.imu_last_us or 0) - (tap.imu_first_us or 0)) * 1e-6
    imu_hz = (tap.imu_messages - 1) / imu_span_s if imu_span_s > 0 else 0.0
    out_hz = (t_ms.size - 1) / flight_s if flight_s > 0 else 0.0
    plot_path = None
    if settings.plot:
        from mavahrs.evaluation.plots import PlotError

        try:
            plot_path = plot(png_path, t_ms, q_est, q_ref, settings)
        except PlotError as exc:
            notes.append(f"no plot: {exc}")
    return DemoResult(
        summary=summary,
        imu_rate_hz=imu_hz,
        out_rate_hz=out_hz,
        attitudes=int(t_ms.size),
        truth_samples=len(tap.truth),
        tlog_path=tlog_path,
        plot_path=plot_path,
        interrupted=interrupted,
        flight_s=flight_s,
        notes=notes,
    )
