r"""The companion daemon's one loop: master link ↔ codec ↔ :class:`Pipeline` ↔ outputs.

Everything that touches the outside world at run time happens here (the
pipeline, codec, filters and scaling are pure).  One thread, one
``selectors`` wait over the master link, the output links and a wake-up
socket; no busy polling:

* **master readable** → read every datagram/chunk waiting (at most
  ``max_drain`` per wake) into a bounded inbox (``input_queue``; when a peer
  floods faster than we process, the *oldest* entries are dropped and counted
  as ``input_dropped``) → decode (one codec per link: datagrams on their own,
  streams as streams) → record in the tlog → ``Pipeline.handle`` → send what
  it returns: attitude to every ``--out`` (and to the master when the pipeline
  marks it), replies such as stream requests to the master;
* **an output readable** → drained (a GCS's heartbeats teach a ``udpin:``
  output where to send; nothing from outputs reaches the filter); a request
  addressed to our component — a command, an FTP request — is answered on
  that output as :mod:`mavahrs.service.component` says (the same for such
  requests arriving on the master link, answered there);
* **timer** (``tick_hz``, default 20 Hz) → ``Pipeline.tick`` (heartbeats,
  stream requests), link maintenance (reconnection, queued writes), log
  flushing, the no-heartbeat watchdog, the status line every
  ``status_interval_s``, ``--duration``.

Start-up: the links open before the filter compiles (a busy port is reported at
once), so what the master link queued meanwhile is old; it is read and thrown away
once the daemon is ready, counted (``startup_dropped``) and said in one line.

Processing latency — from the moment a datagram is read to the moment the
last ``sendto`` of the attitude computed from it returned — goes into a
preallocated ring (``latency_ring`` entries, nanoseconds), summarised in the
status line and in :meth:`Daemon.stats` (used by ``scripts/bench_live.py``).
Nothing is logged per message, and nothing here allocates numpy arrays.

Shutdown: SIGINT/SIGTERM (or :meth:`Daemon.stop` from another thread) ends
the loop at once; the tlog is flushed and synced, links closed, a summary
logged; ``run`` returns a :class:`DaemonResult`.  No heartbeat from an
autopilot within ``heartbeat_timeout_s`` of start raises
:class:`~mavahrs.errors.TransportError` with what was (not) received.
"""

from __future__ import annotations

import gc
import json
import logging
import math
import os
import resource
import selectors
import signal
import socket
import threading
import time
from array import array
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, is_dataclass
from typing import Any, NamedTuple

from mavahrs.errors import ConfigError, TransportError
from mavahrs.protocol.signing import signing_timestamp_10us
from mavahrs.service.stats import Notices

__all__ = ["DaemonSettings", "Daemon", "DaemonResult", "LatencyRing", "build_daemon", "format_status"]

_MSG_ID_ATTITUDE_QUATERNION = 31  # MAVLINK_MSG_ID_ATTITUDE_QUATERNION
_MAV_AUTOPILOT_INVALID = 8
_SIGNING_REPORT_US = 60_000_000  # dropped-by-signing warnings: at most once a minute


@dataclass(frozen=True)
class DaemonSettings:
    """How the daemon connects, records and reports.

    Attributes:
        master: connection string of the autopilot link (``udpin:0.0.0.0:14550``,
            ``tcp:HOST:PORT``, ``/dev/ttyACM0,921600``; see docs/daemon.md).
        baud: serial baud rate, bit/s, when ``master`` has no ``,BAUD`` suffix.
        outputs: connection strings the attitude is sent to (any number).
        log_path: tlog file recording everything in and out; None = no recording.
        log_flush_interval_s: longest time recorded data stays in memory, s.
        heartbeat_timeout_s: give up (exit code 3) when no autopilot HEARTBEAT
            arrives within this many seconds of start, s; 0 = wait for ever.
            Later silences are waited out and reported, never fatal.
        status_interval_s: seconds between status lines; 0 = none.
        tick_hz: timer rate for heartbeats, stream requests, reconnection
            and flushing, Hz.
        duration_s: stop after this many seconds (exit code 0); None = run
            until SIGINT/SIGTERM.
        reconnect_interval_s: retry period for a lost serial device / TCP server, s.
        input_queue: bound of the input queue, datagrams (or stream chunks);
            when a peer floods, the oldest are dropped and counted.
        max_drain: most reads taken from a link per wake-up.
        output_queue_bytes: bound of the write queue of each stream link, bytes.
        max_tcp_clients: connections a ``tcpin:`` link accepts.
        latency_ring: processing-latency samples kept for percentiles.
        stats_path: write a JSON summary (counters, latency, CPU) here at
            exit; None = don't.
        mag_model_path: keep the learnt magnetometer model (the compass's
            field per ampere of battery current and its offset;
            :mod:`mavahrs.filters.magfield`) in this small JSON file across
            restarts: read at start, written at exit once something was
            learnt.  One file per vehicle (the earth field is not kept: the
            WMM at the new position seeds it).  None = not kept.
        signing_key_path: MAVLink 2 signing key file (64 hex characters or a
            passphrase, key = SHA-256 of it as MAVProxy's ``signing setup``;
            must not be readable by other users); every frame we send is
            signed and signed input is verified (bad signatures and replays
            dropped and counted).  None = no signing.
        require_signing: also drop unsigned input (needs ``signing_key_path``).
        signing_link_id: the link id (0–255) written into our signatures.
        realtime_priority: 0 = normal scheduling; 1–99 = run the loop under
            the real-time policy SCHED_FIFO at this priority (needs root or
            CAP_SYS_NICE; under systemd use ``CPUSchedulingPolicy=fifo``
            instead, see contrib/mavahrs.service).  A woken peer or another
            program then cannot preempt the daemon between a datagram's
            receipt and the attitude's ``sendto`` (docs/daemon.md, measured
            live figures); the loop still blocks in ``select`` between
            datagrams.  Refused by the system: one warning, normal scheduling.
        fast_lane: answer steady-state RAW_IMU datagrams on a UDP master link
            from compiled code before the Python path runs, which then builds
            the same frame and checks it byte for byte
            (:mod:`mavahrs.service.fastlane`; a difference is logged, counted
            and switches the lane off).  False = the Python path only.
        http: serve the status page, ``/status.json``, ``/metrics``,
            ``/healthz`` and ``/register_service`` on ``[HOST:]PORT`` (host
            127.0.0.1 when omitted; needs ``pip install 'mavahrs[http]'``;
            docs/status-page.md).  None = no web server.
        http_token: a token every status-page request must carry (``?token=``
            or ``Authorization: Bearer``), except ``/healthz`` and
            ``/register_service``.  Without one, an address beyond this machine
            is served with a warning in the log.  None = no token.
        http_health_timeout_s: ``/healthz`` answers 503 when nothing came from
            the autopilot link, or no attitude went out, for this long, s.
    """

    master: str = "udpin:0.0.0.0:14550"
    baud: int = 115200
    outputs: tuple[str, ...] = ()
    log_path: str | None = None
    log_flush_interval_s: float = 1.0
    heartbeat_timeout_s: float = 10.0
    status_interval_s: float = 5.0
    tick_hz: float = 20.0
    duration_s: float | None = None
    reconnect_interval_s: float = 1.0
    input_queue: int = 256
    max_drain: int = 1024
    output_queue_bytes: int = 65536
    max_tcp_clients: int = 8
    latency_ring: int = 16384
    stats_path: str | None = None
    mag_model_path: str | None = None
    signing_key_path: str | None = None
    require_signing: bool = False
    signing_link_id: int = 0
    realtime_priority: int = 0
    fast_lane: bool = True
    http: str | None = None
    http_token: str | None = None
    http_health_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        def positive(name: str, value: float) -> None:
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"daemon.{name} must be a positive number, got {value!r}")

        def non_negative(name: str, value: float) -> None:
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"daemon.{name} must be zero or positive, got {value!r}")

        if not self.master:
            raise ValueError("daemon.master is required (e.g. udpin:0.0.0.0:14550 or /dev/ttyACM0,921600)")
        positive("baud", self.baud)
        positive("log_flush_interval_s", self.log_flush_interval_s)
        non_negative("heartbeat_timeout_s", self.heartbeat_timeout_s)
        non_negative("status_interval_s", self.status_interval_s)
        positive("tick_hz", self.tick_hz)
        if self.duration_s is not None:
            positive("duration_s", self.duration_s)
        positive("reconnect_interval_s", self.reconnect_interval_s)
        for name in ("input_queue", "max_drain", "output_queue_bytes", "max_tcp_clients", "latency_ring"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value > 0):
                raise ValueError(f"daemon.{name} must be a positive whole number, got {value!r}")
        if not isinstance(self.outputs, tuple):
            object.__setattr__(self, "outputs", tuple(self.outputs))
        if not (isinstance(self.signing_link_id, int) and 0 <= self.signing_link_id <= 255):
            raise ValueError(f"daemon.signing_link_id must be 0…255, got {self.signing_link_id!r}")
        rt = self.realtime_priority
        if isinstance(rt, bool) or not (isinstance(rt, int) and 0 <= rt <= 99):  # `true` in a TOML is no priority
            raise ValueError(f"daemon.realtime_priority must be 0 (normal) or 1…99 (SCHED_FIFO), got {self.realtime_priority!r}")
        if not isinstance(self.fast_lane, bool):
            raise ValueError(f"daemon.fast_lane must be true or false, got {self.fast_lane!r}")
        if self.http is not None:
            from mavahrs.service.http import parse_http_address

            parse_http_address(self.http)  # ConfigError with the accepted forms
        positive("http_health_timeout_s", self.http_health_timeout_s)


def _load_filter_kernel(pipeline: Any) -> None:
    """Compile (first run on a machine) or load the pipeline filter's step now, not on the first sample.

    Compiling takes seconds on a fresh install; on the first sample the input would pile up
    meanwhile and overflow the socket's buffer.  The step runs once on a copy of the state and
    a row of NaN (nothing changes in the filter).
    """
    f = getattr(pipeline, "filter", None)
    step, state, params = getattr(f, "_kernel", None), getattr(f, "_state", None), getattr(f, "_params", None)
    if step is None or state is None or params is None:
        return
    import numpy as np

    from mavahrs.filters.layout import IN_WIDTH, OUT_WIDTH

    step(np.array(state, dtype=np.float64), params, np.full(IN_WIDTH, np.nan), np.zeros(OUT_WIDTH))


class _Early(NamedTuple):
    """The fast lane's answer, sent like a pipeline ``Outgoing``."""

    frame: bytes
    to_master: bool
    to_outputs: bool


@dataclass
class DaemonCounters:
    """The loop's own counters (the pipeline and codec keep theirs).

    Attributes:
        datagrams_in: reads from the master link (datagrams or stream chunks).
        messages_in: MAVLink messages decoded from the master link.
        input_dropped: reads dropped from the input queue (flood: oldest first).
        attitudes_out: ATTITUDE_QUATERNION frames sent (to the outputs and/or the master).
        frames_to_master: frames sent back to the autopilot.
        frames_to_outputs: frames sent to the outputs (all kinds).
        output_reads_ignored: reads from output links (nothing in them reaches the filter; requests
            addressed to our component are answered, counted in ``requests_answered``).
        requests_answered: answers to requests addressed to our component (COMMAND_ACK UNSUPPORTED, FTP
            NAK: :mod:`mavahrs.service.component`), on the master link or an output.
        pipeline_errors: messages the pipeline failed on, and requests to our component that could not be
            answered (counted, logged rarely).
        fast_lane_answers: attitudes sent by the fast lane ahead of the Python path.
        fast_lane_mismatches: datagrams whose fast-lane answer the Python path did
            not confirm byte for byte (then the lane is switched off).
        fast_lane_chained: of ``fast_lane_answers``, those given in a chain over
            datagrams that had queued up (the process was not scheduled for a while).
        startup_dropped: what the master link had queued while the daemon was starting
            (links open before the filter compiles, so a busy port is reported at once):
            datagrams (UDP) or bytes (streams), thrown away unread by the filter — it is
            old data and would be handled as if it had just arrived.
    """

    datagrams_in: int = 0
    messages_in: int = 0
    input_dropped: int = 0
    attitudes_out: int = 0
    frames_to_master: int = 0
    frames_to_outputs: int = 0
    output_reads_ignored: int = 0
    requests_answered: int = 0
    pipeline_errors: int = 0
    fast_lane_answers: int = 0
    fast_lane_mismatches: int = 0
    fast_lane_chained: int = 0
    startup_dropped: int = 0


@dataclass(frozen=True)
class DaemonResult:
    """How a run ended.

    Attributes:
        reason: ``"signal"`` (SIGINT/SIGTERM), ``"duration"``, ``"stopped"`` (:meth:`Daemon.stop`).
        signal_name: the signal that stopped it, if any.
        run_s: seconds the loop ran.
        stats: the final :meth:`Daemon.stats` summary.
    """

    reason: str
    signal_name: str | None
    run_s: float
    stats: dict[str, Any] = field(default_factory=dict)


class LatencyRing:
    """Preallocated ring of latency samples (ns) with percentiles over any recent span."""

    def __init__(self, size: int) -> None:
        n = 1
        while n < size:
            n <<= 1
        self._mask = n - 1
        self._buf = array("q", bytes(8 * n))
        self.count = 0  # samples ever added
        self.max_ns = 0

    @property
    def capacity(self) -> int:
        return self._mask + 1

    def add(self, ns: int) -> None:
        self._buf[self.count & self._mask] = ns
        self.count += 1
        if ns > self.max_ns:
            self.max_ns = ns

    def values(self, since: int = 0) -> list[int]:
        """Samples added since the ``since``-th (at most the ring's capacity, oldest lost)."""
        start = max(since, self.count - self.capacity, 0)
        return [self._buf[i & self._mask] for i in range(start, self.count)]

    @staticmethod
    def summary_us(values: Sequence[int]) -> dict[str, float]:
        """``{"n", "p50_us", "p99_us", "max_us"}`` (nearest-rank percentiles)."""
        if not values:
            return {"n": 0, "p50_us": math.nan, "p99_us": math.nan, "max_us": math.nan}
        s = sorted(values)
        n = len(s)

        def pct(p: float) -> float:
            return s[min(n - 1, max(0, math.ceil(p / 100.0 * n) - 1))] / 1000.0

        return {"n": n, "p50_us": pct(50), "p99_us": pct(99), "max_us": s[-1] / 1000.0}


def _frame_msgid(frame: bytes) -> int:
    """The message id of a MAVLink 1/2 frame (−1 if it is neither)."""
    if len(frame) > 9 and frame[0] == 0xFD:
        return frame[7] | frame[8] << 8 | frame[9] << 16
    if len(frame) > 5 and frame[0] == 0xFE:
        return frame[5]
    return -1


def _status_dict(status: Any) -> dict[str, Any]:
    if status is None:
        return {}
    if is_dataclass(status) and not isinstance(status, type):
        return asdict(status)
    if isinstance(status, dict):
        return dict(status)
    return {k: v for k, v in vars(status).items() if not k.startswith("_")}


def _num(value: Any, fmt: str) -> str:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "-"
    return "-" if not math.isfinite(v) else format(v, fmt)


def format_status(fields: dict[str, Any], pipeline_line: str = "") -> str:
    """The one-line status text: the pipeline's line, then the link and loop fields."""
    parts = [pipeline_line] if pipeline_line else [
        f"in {_num(fields.get('in_hz'), '.0f')} Hz -> out {_num(fields.get('out_hz'), '.0f')} Hz"
    ]
    parts.append(f"crc {fields.get('crc_errors', 0)} bad {fields.get('bad_data', 0)} gaps {fields.get('seq_gaps', 0)}")
    if fields.get("duplicates") or fields.get("out_of_order"):
        parts[-1] += f" dup {fields.get('duplicates', 0)} ooo {fields.get('out_of_order', 0)}"
    if fields.get("signing"):
        parts.append(
            f"signed {fields.get('signed_ok', 0)} rejected {fields.get('signing_rejected', 0)}"
            f" (unsigned {fields.get('unsigned_rejected', 0)} badsig {fields.get('bad_signature', 0)}"
            f" replay {fields.get('replayed', 0)})"
        )
    if fields.get("link_drops"):
        parts.append(f"link drops {fields['link_drops']}")
    parts.append(
        f"latency p50 {_num(fields.get('latency_p50_us'), '.0f')} p99 {_num(fields.get('latency_p99_us'), '.0f')} us"
    )
    if fields.get("log") not in (None, "ok", "off"):
        parts.append(f"log {fields['log']}")
    if fields.get("link"):
        parts.append(str(fields["link"]))
    return " | ".join(parts)


class Daemon:
    """The service loop around an already built pipeline and already open links.

    Args:
        settings: :class:`DaemonSettings` (links are opened by :func:`build_daemon`).
        pipeline: object with ``handle(msg, now_us)``, ``tick(now_us)`` (lists of
            ``Outgoing``), ``status()`` and ``drain_notices()``.
        master: the autopilot link.
        outputs: the output links.
        codec: the decoding codec of the master link (a new ``MavCodec`` if None).
        sink: a :class:`~mavahrs.service.sinks.TlogSink` or None.
        logger: where status lines and notices go.
    """

    def __init__(
        self,
        settings: DaemonSettings,
        pipeline: Any,
        master: Any,
        outputs: Sequence[Any] = (),
        *,
        codec: Any = None,
        sink: Any = None,
        logger: logging.Logger | None = None,
    ) -> None:
        from mavahrs.protocol.codec import MavCodec, mavlink

        if codec is None:
            codec = MavCodec()
        self._heartbeat_type = mavlink.MAVLink_heartbeat_message
        self.settings = settings
        self.pipeline = pipeline
        self.master = master
        self.outputs = list(outputs)
        self.codec = codec
        self.sink = sink
        self.log = logger or logging.getLogger("mavahrs.daemon")
        self.counters = DaemonCounters()
        self._bytes_after_backlog = 0  # the master link's bytes_in once the start-up backlog was dropped
        from mavahrs.service.pilot import PilotInfo

        self.pilot = PilotInfo()  # the last messages the status page's pilot fields read (mavahrs.service.pilot)
        self._load_mag_model()
        self.latency = LatencyRing(settings.latency_ring)
        self._notices = Notices(repeat_s=60.0)
        self._inbox: deque[tuple[int, bytes]] = deque(maxlen=settings.input_queue)
        self._stop_reason: str | None = None
        self._signal_name: str | None = None
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._selector: selectors.BaseSelector | None = None
        self._registered: dict[int, tuple[int, ...]] = {}
        self._started_s = 0.0
        self._first_input_s: float | None = None
        self._cpu_at_first_input: float | None = None
        self._last_heartbeat_s: float | None = None
        self._heartbeats = 0
        self._link_silent = False
        self._last_status_s = 0.0
        self._status_line = ""
        self._master_reconnects = 0
        self.last_status: dict[str, Any] = {}
        self.last_pipeline_status: Any = None  # the pipeline's status object behind the last status_fields()
        self._status_latency_counts: dict[str, int] = {}  # latency samples at the previous status, per window
        self.http_server: Any = None  # a listening StatusServer (build_daemon), stopped by close()
        self.http_publisher: Any = None  # its StatusPublisher, ticked with the timer from run()
        self._decode: Callable[[bytes], list[Any]] = (
            codec.receive_datagram if master.datagram else codec.receive_stream
        )
        _load_filter_kernel(pipeline)
        self._lane: Any = None
        if settings.fast_lane and master.datagram:
            from mavahrs.service.fastlane import FastLane
            from mavahrs.service.pipeline import Pipeline

            if isinstance(pipeline, Pipeline):
                lane = FastLane(pipeline, receive_codec=codec)
                self._lane = lane if lane.usable else None
        self._lane_to_master = bool(getattr(getattr(pipeline, "settings", None), "send_to_master", True))
        # requests addressed to our component (commands, FTP): answered as a component without them
        encoder = getattr(pipeline, "codec", None)
        from mavahrs.service.component import REQUEST_TYPES, ComponentResponder

        self.responder: ComponentResponder | None = ComponentResponder(encoder) if encoder is not None else None
        self._request_classes = frozenset(
            cls for name in REQUEST_TYPES if (cls := getattr(mavlink, f"MAVLink_{name.lower()}_message", None))
        )
        self._output_codecs: dict[int, Any] = {}  # decoding codec of each output link (requests to us)
        self._param_request_said = False
        self._closed = False
        self._signing: tuple[int, bool] | None = None  # (link id, require) once enabled
        self._signing_reported = 0  # frames dropped by signing at the last warning
        self._signing_reported_us: int | None = None
        self._scheduling = "normal"  # set at run()
        # Last of the start-up (the filter is compiled, the fast lane built): what follows is live.
        self._drop_startup_backlog()

    # ------------------------------------------------------------------ control
    def stop(self, reason: str = "stopped") -> None:
        """End the loop soon (thread-safe and signal-safe)."""
        if self._stop_reason is None:
            self._stop_reason = reason
        try:
            self._wake_w.send(b"\0")
        except OSError:
            pass

    def stop_on_signal(self, signum: int) -> None:
        """End the loop soon because of a signal (its name goes in the stop line); before :meth:`run`, it
        makes :meth:`run` close everything and return at once."""
        self._signal_name = signal.Signals(signum).name
        self.stop("signal")

    def _on_signal(self, signum: int, frame: Any) -> None:
        self.stop_on_signal(signum)

    # ------------------------------------------------------------------ signing
    def enable_signing(self, key: bytes, *, link_id: int = 0, require: bool = False) -> None:
        """MAVLink 2 signing: sign every frame we send, verify what the master link sends.

        The master link's decoding codec verifies signatures (bad signatures
        and replays are dropped and counted; with ``require`` unsigned frames
        too), the pipeline's encoding codec signs.  Signing timestamps start at
        wall time and follow it (every tick), never going back.  The key is
        held by the codecs only and never logged.
        """
        encoder = getattr(self.pipeline, "codec", None)
        if encoder is None or not hasattr(encoder, "enable_signing"):
            raise ConfigError("MAVLink signing needs a pipeline with an encoding codec")
        self._lane = None  # the fast lane answers unsigned frames with unsigned ones only
        ts = signing_timestamp_10us(time.time())
        self.codec.enable_signing(key, link_id, ts, sign_outgoing=False, require_signing=require)
        encoder.enable_signing(key, link_id, ts, sign_outgoing=True)
        self._signing = (int(link_id), bool(require))

    def _signing_tick(self, now_us: int) -> None:
        """Keep signing timestamps at wall time; warn (at most once a minute) about dropped frames."""
        ts = signing_timestamp_10us(time.time())
        self.codec.advance_signing_time(ts)
        self.pipeline.codec.advance_signing_time(ts)
        cc = self.codec.counters
        rejected = cc.signing_rejected
        last = self._signing_reported_us
        if rejected > self._signing_reported and (last is None or now_us - last >= _SIGNING_REPORT_US):
            self.log.warning(
                "MAVLink signing: %d frames dropped since the previous report (%d in all: %d unsigned, "
                "%d with a wrong signature, %d replayed)",
                rejected - self._signing_reported, rejected, cc.unsigned_rejected, cc.bad_signature, cc.replayed,
            )
            self._signing_reported = rejected
            self._signing_reported_us = now_us

    # ------------------------------------------------------------------ sending
    def _send(self, out: Any, wall_us: int, now_s: float, *, log: bool = True) -> bool:
        """Send one pipeline ``Outgoing``; True when it was an ATTITUDE_QUATERNION (sent anywhere).

        ``log=False``: not into the ``--log`` tlog (the fast lane's frame is recorded when the
        pipeline confirms it, after the IMU message it answers)."""
        frame = out.frame
        c = self.counters
        sent = False
        if out.to_master:
            self.master.write(frame)
            c.frames_to_master += 1
            sent = True
        if out.to_outputs and self.outputs:
            for link in self.outputs:
                link.write(frame)
            c.frames_to_outputs += 1
            sent = True
        if log and self.sink is not None:
            self.sink.write(wall_us, frame, now_s)
        if sent and _frame_msgid(frame) == _MSG_ID_ATTITUDE_QUATERNION:
            c.attitudes_out += 1
            return True
        return False

    # ------------------------------------------------------------------ receiving
    def _drop_startup_backlog(self, max_s: float = 2.0) -> None:
        """Throw away what the master link queued while the daemon was starting, count it and say so.

        The links open first (a busy port or a missing device is reported before the filter
        compiles, which can take tens of seconds on a fresh install); meanwhile the operating
        system queues what the autopilot sends.  Handled now it would look live: hundreds of old
        samples arriving within a fraction of a second (in the ``--log`` recording and in the
        attitude sent on).  Reading it still teaches ``udpin`` its peer.
        """
        master, c = self.master, self.counters
        unit = "datagrams" if master.datagram else "bytes"
        end = time.monotonic() + max_s
        while time.monotonic() < end:
            data = master.read(0.0)
            if not data:
                break
            c.startup_dropped += 1 if master.datagram else len(data)
        self._bytes_after_backlog = master.counters.bytes_in  # what came before the daemon was ready
        if c.startup_dropped:
            self.log.info("dropped %d %s queued during start-up (older than the filter)", c.startup_dropped, unit)

    def _read_master(self) -> None:
        """The master link is readable: answer what came, then drain the rest through the bounded queue.

        The first read is processed at once (the usual case: one datagram per
        wake-up, answered before the read that finds the socket empty); what
        else is waiting is read in one go (at most ``max_drain``) into the
        bounded inbox — when a peer floods, the oldest entries fall out and are
        counted — and then processed, newest last.
        """
        master, inbox, c = self.master, self._inbox, self.counters
        data = master.read(0.0)
        if not data:
            return
        inbox.append((time.perf_counter_ns(), data))
        self._process_inbox()
        perf = time.perf_counter_ns
        maxlen = self.settings.input_queue
        for _ in range(self.settings.max_drain):
            data = master.read(0.0)
            if not data:
                break
            if len(inbox) == maxlen:
                c.input_dropped += 1  # the deque drops the oldest on append
            inbox.append((perf(), data))
        if inbox:
            self._process_inbox()

    def _process_inbox(self) -> None:
        inbox, c, handle, decode = self._inbox, self.counters, self.pipeline.handle, self._decode
        sink = self.sink
        observe = self.pilot.observe
        perf = time.perf_counter_ns
        hb_type = self._heartbeat_type
        chained: deque[bytes | None] = deque()  # answers already sent for the next datagrams (see below)
        while inbox:
            if not chained and len(inbox) > 1 and self._lane is not None:
                # Several datagrams waited (the process was not scheduled for a while): answer them
                # all from the lane first, each from the state the previous answer left, so that
                # the last one does not wait for the Python path of all before it.
                chained.extend(self._lane_call(self._lane.answer_queue, (d for _, d in inbox)) or ())
                for (t_rx_ns, _), early in zip(inbox, chained, strict=False):  # the chain is a prefix
                    if early is not None:
                        self._send(_Early(early, self._lane_to_master, True), 0, 0.0, log=False)
                        self.latency.add(perf() - t_rx_ns)
                        c.fast_lane_answers += 1
                        c.fast_lane_chained += 1
            t_rx_ns, data = inbox.popleft()
            c.datagrams_in += 1
            if chained:
                early = chained.popleft()  # answered (or found not due) by the chain above
            else:
                early = None
                if self._lane is not None:
                    early = self._lane_call(self._lane.answer, data)
                if early is not None:  # the attitude leaves now; the Python path below confirms it
                    self._send(_Early(early, self._lane_to_master, True), 0, 0.0, log=False)
                    self.latency.add(perf() - t_rx_ns)
                    c.fast_lane_answers += 1
            confirmed = False
            msgs = decode(data)
            if not msgs:
                if early is not None:
                    self._lane_mismatch("the datagram did not decode", early)
                continue
            now_s = time.monotonic()
            now_us = int(now_s * 1e6)
            wall_us = time.time_ns() // 1000
            if self._first_input_s is None:
                self._first_input_s = now_s
                self._cpu_at_first_input = _cpu_s()
            attitude = False
            for msg in msgs:
                c.messages_in += 1
                if sink is not None:
                    sink.write(wall_us, msg.get_msgbuf(), now_s)
                observe(msg)
                if type(msg) is hb_type and msg.autopilot != _MAV_AUTOPILOT_INVALID and not self._own(msg):
                    self._on_heartbeat(now_s)
                if type(msg) in self._request_classes:
                    for frame in self._answers(msg):
                        self._send(_Early(frame, True, False), wall_us, now_s)
                        c.requests_answered += 1
                try:
                    outgoing = handle(msg, now_us)
                except Exception as exc:  # noqa: BLE001 - one bad message must not stop the service
                    c.pipeline_errors += 1
                    self._notices.warning(
                        f"pipeline:{type(exc).__name__}",
                        f"could not process {msg.get_type()}: {exc}",
                        now_us,
                    )
                    continue
                for out in outgoing:
                    if early is not None and not confirmed and out.frame == early:
                        confirmed = True  # already sent: only recorded
                        if sink is not None:
                            sink.write(wall_us, out.frame, now_s)
                        continue
                    if self._send(out, wall_us, now_s):
                        attitude = True
            if early is not None and not confirmed:
                self._lane_mismatch("the pipeline built a different frame or none", early)
            elif attitude and early is None:
                self.latency.add(perf() - t_rx_ns)
            if self._lane is not None:
                self._lane.refresh()

    def _own(self, msg: Any) -> bool:
        """Our own message relayed back (a separate vehicle's HEARTBEAT names an autopilot: not the autopilot's)."""
        codec = getattr(self.pipeline, "codec", None)
        if codec is None:
            return False
        ours = (codec.system_id, codec.component_id)
        return (msg.get_srcSystem(), msg.get_srcComponent()) == ours and ours != getattr(self.pipeline, "source", None)

    def _lane_call(self, method: Any, arg: Any) -> Any:
        """A fast-lane call; an exception switches the lane off (the Python path answers), never the daemon."""
        try:
            return method(arg)
        except Exception as exc:  # noqa: BLE001 - never the daemon's end
            self._lane = None
            self.log.warning("fast lane failed (%s: %s); off for the rest of the run", type(exc).__name__, exc)
            return None

    def _lane_mismatch(self, why: str, frame: bytes) -> None:
        """The fast lane's answer was not confirmed: record it, count, say so, and switch the lane off."""
        self.counters.fast_lane_mismatches += 1
        if self.sink is not None:  # it was sent: the recording shows it
            self.sink.write(time.time_ns() // 1000, frame, time.monotonic())
        if self._lane is None:  # already off: a later answer of the same chain (said once)
            self.log.debug("fast lane: chained answer not confirmed either (%s)", why)
            return
        self._lane.disable()
        self._lane = None
        self.log.warning(
            "fast lane: an ATTITUDE_QUATERNION it sent was not confirmed by the pipeline (%s); the "
            "pipeline's own frames were sent too. Fast lane off for the rest of the run "
            "(daemon.fast_lane = false avoids it altogether)",
            why,
        )

    def _answers(self, msg: Any) -> list[bytes]:
        """The responder's answers to a request (see :mod:`mavahrs.service.component`); says once, the first
        time a ground station asks us for parameters, that there are none."""
        responder = self.responder
        if responder is None:
            return []
        ignored = responder.counters.param_requests_ignored
        try:
            frames = responder.answer(msg)
        except Exception as exc:  # noqa: BLE001 - a request we cannot answer must not stop the service
            self.counters.pipeline_errors += 1
            self._notices.warning(f"request:{type(exc).__name__}", f"could not answer {msg.get_type()}: {exc}",
                                  int(time.monotonic() * 1e6))  # fmt: skip
            return []
        if responder.counters.param_requests_ignored > ignored and not self._param_request_said:
            self._param_request_said = True
            self.log.info(
                "%s (system %d, component %d) asked this component for its parameters: mavahrs has no MAVLink "
                "parameters (its settings are --config/--set), and, as the parameter protocol says, does not "
                "answer (a ground station may keep asking: MAVProxy does every second or two; harmless)",
                msg.get_type(), msg.get_srcSystem(), msg.get_srcComponent(),
            )
        return frames

    def _drain_output(self, link: Any) -> None:
        """An output link is readable: read what came (nothing of it reaches the filter) and answer requests
        addressed to our component on that link (not when signing is required: an output's frames are
        not verified)."""
        answer = self.responder is not None and not (self._signing is not None and self._signing[1])
        for _ in range(self.settings.max_drain):
            data = link.read(0.0)
            if not data:
                break
            self.counters.output_reads_ignored += 1
            if answer:
                self._answer_output(link, data)

    def _answer_output(self, link: Any, data: bytes) -> None:
        codec = self._output_codecs.get(id(link))
        if codec is None:
            from mavahrs.protocol.codec import MavCodec

            codec = self._output_codecs[id(link)] = MavCodec()
        try:
            msgs = codec.receive_datagram(data) if link.datagram else codec.receive_stream(data)
        except Exception:  # noqa: BLE001 - whatever a ground station sends, never the daemon's end
            return
        for msg in msgs:
            if type(msg) not in self._request_classes:
                continue
            for frame in self._answers(msg):
                link.write(frame)
                self.counters.requests_answered += 1
                if self.sink is not None:
                    self.sink.write(time.time_ns() // 1000, frame, time.monotonic())

    def _on_heartbeat(self, now_s: float) -> None:
        self._heartbeats += 1
        if self._last_heartbeat_s is None:
            self.log.info("autopilot heartbeat received on %s", self.master.describe())
        elif self._link_silent:
            self.log.info(
                "autopilot heartbeat back on %s after %.1f s of silence",
                self.master.describe(),
                now_s - self._last_heartbeat_s,
            )
        self._link_silent = False
        self._last_heartbeat_s = now_s

    # ------------------------------------------------------------------ selector
    def _sync_registrations(self) -> None:
        sel = self._selector
        assert sel is not None
        for link in (self.master, *self.outputs):
            key = id(link)
            fds = tuple(link.filenos())
            old = self._registered.get(key, ())
            if fds == old:
                continue
            for fd in old:
                if fd not in fds:
                    try:
                        sel.unregister(fd)
                    except (KeyError, ValueError, OSError):
                        pass
            for fd in fds:
                if fd not in old:
                    try:
                        sel.register(fd, selectors.EVENT_READ, link)
                    except KeyError:  # a reused descriptor number still registered: replace
                        sel.unregister(fd)
                        sel.register(fd, selectors.EVENT_READ, link)
            self._registered[key] = fds

    # ------------------------------------------------------------------ timer
    def _tick(self, now_s: float) -> None:
        now_us = int(now_s * 1e6)
        wall_us = time.time_ns() // 1000
        try:
            outgoing = self.pipeline.tick(now_us)
        except Exception as exc:  # noqa: BLE001
            self.counters.pipeline_errors += 1
            self._notices.warning(f"tick:{type(exc).__name__}", f"pipeline timer failed: {exc}", now_us)
            outgoing = ()
        for out in outgoing:
            self._send(out, wall_us, now_s)
        if self._signing is not None:
            self._signing_tick(now_us)
        for link in (self.master, *self.outputs):
            link.maintain(now_s)
        if self.master.counters.reconnects != self._master_reconnects:
            self._master_reconnects = self.master.counters.reconnects
            reset = getattr(self.pipeline, "reset_link", None)
            if reset is not None:
                reset(now_us)
        self._sync_registrations()
        if self._lane is not None:
            self._lane.refresh()  # the timer's frames took sequence numbers; its checks may have changed state
        if self.sink is not None:
            self.sink.tick(now_s)
        for level, message in self.pipeline.drain_notices():
            self.log.log(level, "%s", message)
        said = getattr(self.pipeline, "drain_second_opinion", None)  # a stand-in pipeline may have none
        for level, message in said() if said is not None else ():
            self.log.log(level, "%s", message)
        for level, message in self._notices.drain():
            self.log.log(level, "%s", message)
        self._watchdog(now_s)
        if self.http_publisher is not None:
            try:
                self.http_publisher.tick(self, now_s)
            except Exception as exc:  # noqa: BLE001 - the status page never stops the daemon
                self._notices.warning(f"http:{type(exc).__name__}", f"status page snapshot failed: {exc}", now_us)
        s = self.settings
        if s.status_interval_s and now_s - self._last_status_s >= s.status_interval_s:
            self._last_status_s = now_s
            self.last_status = self.status_fields(now_s)
            self.log.info(
                "%s", format_status(self.last_status, self._status_line), extra={"status": _jsonable(self.last_status)}
            )
        if s.duration_s is not None and now_s - self._started_s >= s.duration_s:
            self.stop("duration")

    def _watchdog(self, now_s: float) -> None:
        timeout = self.settings.heartbeat_timeout_s
        if not timeout:
            return
        if self._last_heartbeat_s is None:
            if now_s - self._started_s >= timeout:
                raise TransportError(self._no_heartbeat_message(timeout))
            return
        silent_s = now_s - self._last_heartbeat_s
        if silent_s >= timeout and not self._link_silent:
            self._link_silent = True
            self.log.warning(
                "no heartbeat from the autopilot for %.0f s on %s; still listening", silent_s, self.master.describe()
            )

    def _no_heartbeat_message(self, timeout: float) -> str:
        m = self.master
        kind = getattr(getattr(m, "endpoint", None), "kind", "")
        bytes_in = m.counters.bytes_in
        cc = self.codec.counters
        where = m.describe()
        if bytes_in == 0:
            hint = {
                "udpin": "nothing received: is the autopilot or router sending to this address and port?",
                "udpout": "nothing received: is something listening there and answering?",
                "tcp": "nothing received",
                "tcpin": "no client connected and sent data",
                "serial": "nothing received: check the wiring and that this port runs MAVLink "
                "(ArduPilot SERIALn_PROTOCOL = 2)",
            }.get(kind, "nothing received")
        elif cc.packets == 0 and self.counters.startup_dropped and bytes_in <= self._bytes_after_backlog:
            # all of it had queued while the filter was prepared (minutes on a cold cache), none came since
            unit = "datagrams" if m.datagram else "bytes"
            hint = (f"{bytes_in} bytes received, all of them queued during start-up ({self.counters.startup_dropped} "
                    f"{unit}, dropped as older than the filter), none since: has the autopilot stopped sending?")  # fmt: skip
        elif cc.signing_rejected:  # valid frames, all refused by signing (until user8: "no valid MAVLink frame")
            total = cc.packets + cc.signing_rejected
            share = "all" if cc.packets == 0 else f"{cc.signing_rejected}"
            hint = (f"{total} MAVLink frames received, {share} dropped by MAVLink signing: {cc.unsigned_rejected} "
                    f"unsigned (--require-signing), {cc.bad_signature} with a wrong signature, {cc.replayed} "
                    "replayed; does the autopilot sign with this key?")  # fmt: skip
        elif cc.packets == 0:
            hint = (
                f"{bytes_in} bytes received but no valid MAVLink frame"
                + (": wrong baud rate?" if kind == "serial" else ": is this a MAVLink stream?")
            )
        else:
            hint = f"{cc.packets} MAVLink messages received but none was an autopilot HEARTBEAT"
        return f"no heartbeat from {where} within {timeout:g} s ({hint})"

    # ------------------------------------------------------------------ reporting
    def status_fields(self, now_s: float | None = None, *, window: str = "log") -> dict[str, Any]:
        """The status-line fields (also logged as JSON with ``--log-format json``).

        Rates, gain, accelerometer/magnetometer weights and rejection, bias and
        the IMU in use come from the pipeline; decoder counters (CRC errors,
        bad data, sequence gaps), the loop's drops and the processing latency
        (since the previous status) from here.  ``window``: the status line
        and the status page each have their own "since the previous status".
        """
        now_s = time.monotonic() if now_s is None else now_s
        now_us = int(now_s * 1e6)
        status = self.pipeline.status(now_us) if window == "log" else self.pipeline.status(now_us, window=window)
        self.last_pipeline_status = status
        p = _status_dict(status)
        cc = self.codec.counters
        latency = LatencyRing.summary_us(self.latency.values(self._status_latency_counts.get(window, 0)))
        self._status_latency_counts[window] = self.latency.count
        link_drops = self.counters.input_dropped + sum(
            link.counters.writes_dropped + link.counters.kernel_dropped for link in (self.master, *self.outputs)
        )
        drops = p.get("drops") or {}
        fields: dict[str, Any] = {
            "in_hz": p.get("input_rate_hz"),
            "filter_hz": p.get("filter_rate_hz"),
            "out_hz": p.get("output_rate_hz"),
            "drops": (sum(drops.values()) if isinstance(drops, dict) else 0) + link_drops,
            "drops_by_reason": dict(drops) if isinstance(drops, dict) else {},
            "exact_duplicates": int((p.get("counters") or {}).get("exact_duplicates", 0)),
            "link_drops": link_drops,
            "imu": p.get("imu_in_use"),
            "imu_reason": p.get("imu_reason"),
            "gain": p.get("gain"),
            "accel_weight": p.get("accel_weight"),
            "mag_weight": p.get("mag_weight"),
            "accel_rejected": p.get("accel_rejected"),
            "mag_rejected": p.get("mag_rejected"),
            "bias_deg_s": list(p["bias_deg_s"]) if p.get("bias_deg_s") is not None else None,
            "heading_reference": p.get("heading_reference"),
            "velocity": p.get("velocity"),
            "magnetometer": p.get("magnetometer"),
            "connected": p.get("connected"),
            "crc_errors": cc.crc_errors,
            "bad_data": cc.bad_data,
            "seq_gaps": cc.seq_gaps,
            "duplicates": cc.duplicates,
            "out_of_order": cc.out_of_order,
            "latency_p50_us": latency["p50_us"],
            "latency_p99_us": latency["p99_us"],
            "latency_max_us": latency["max_us"],
            "log": "off" if self.sink is None else self.sink.state,
        }
        if self._signing is not None:
            fields.update(_signing_counts(cc), signing="required" if self._signing[1] else "on")
        if self._link_silent:
            fields["link"] = "no heartbeat"
        self._status_line = status.line() if hasattr(status, "line") else ""
        return fields

    def stats(self) -> dict[str, Any]:
        """Totals for the whole run (written to ``stats_path``; used by bench_live.py)."""
        now = time.monotonic()
        cpu_now = _cpu_s()
        cc = self.codec.counters
        msgs = self.counters.datagrams_in
        busy_s = now - self._first_input_s if self._first_input_s is not None else 0.0
        cpu_s = cpu_now - self._cpu_at_first_input if self._cpu_at_first_input is not None else 0.0
        return {
            "run_s": now - self._started_s if self._started_s else 0.0,
            "input_s": busy_s,
            "cpu_s_since_first_input": cpu_s,
            "cpu_us_per_datagram": cpu_s * 1e6 / msgs if msgs else math.nan,
            "counters": asdict(self.counters),
            "codec": {
                "packets": cc.packets,
                "crc_errors": cc.crc_errors,
                "bad_data": cc.bad_data,
                "bytes_skipped": cc.bytes_skipped,
                "seq_gaps": cc.seq_gaps,
                "duplicates": cc.duplicates,
                "out_of_order": cc.out_of_order,
                "unknown_messages": cc.unknown_messages,
                "bytes_in": cc.bytes_in,
                **(_signing_counts(cc) if self._signing is not None else {}),
            },
            "signing": None if self._signing is None else {
                "link_id": self._signing[0], "require": self._signing[1],
            },
            "links": {link.describe(): asdict(link.counters) for link in (self.master, *self.outputs)},
            "latency": {**LatencyRing.summary_us(self.latency.values()), "count": self.latency.count,
                        "max_ever_us": self.latency.max_ns / 1000.0},
            "latency_ns": self.latency.values(),
            "heartbeats": self._heartbeats,
            "scheduling": self._scheduling,
            "log": None if self.sink is None else {
                "path": self.sink.path, "frames": self.sink.frames, "state": self.sink.state,
                "frames_lost": self.sink.frames_lost,
            },
            "pipeline": _jsonable(_status_dict(self.pipeline.status(int(now * 1e6)))),
        }

    # ------------------------------------------------------------------ run
    def run(self) -> DaemonResult:
        """Run until stopped; see the module docstring.

        Raises:
            TransportError: no autopilot heartbeat within ``heartbeat_timeout_s``.
        """
        s = self.settings
        in_main = threading.current_thread() is threading.main_thread()
        old_handlers: dict[int, Any] = {}
        if in_main:
            for sig in (signal.SIGINT, signal.SIGTERM):
                old_handlers[sig] = signal.signal(sig, self._on_signal)
        sel = self._selector = selectors.DefaultSelector()
        sel.register(self._wake_r.fileno(), selectors.EVENT_READ, None)
        self._sync_registrations()
        period = 1.0 / s.tick_hz
        if s.realtime_priority:
            refused = set_realtime_priority(s.realtime_priority)
            if refused:
                self.log.warning(
                    "cannot run under real-time scheduling (SCHED_FIFO priority %d): %s; running at normal "
                    "priority (needs root or CAP_SYS_NICE; under systemd set CPUSchedulingPolicy=fifo)",
                    s.realtime_priority, refused,
                )
        self._scheduling = scheduling_description()
        self._started_s = time.monotonic()
        if self.http_server is not None:
            from mavahrs.service.http import StatusPublisher

            self.http_publisher = StatusPublisher(self.http_server.board, self._started_s)
        self._last_status_s = self._started_s
        # Everything allocated so far (numba, numpy, pymavlink tables: hundreds of thousands of
        # objects) is permanent: keep the cyclic GC from walking it again in a full collection,
        # which would otherwise stall the loop for tens of milliseconds now and then.
        gc.collect()
        gc.freeze()
        self.log.info(
            "mavahrs running: master %s; outputs %s; log %s; scheduling %s%s",
            self.master.describe(),
            ", ".join(o.describe() for o in self.outputs) or "none",
            self.sink.path if self.sink is not None else "off",
            self._scheduling,
            "" if self._signing is None else
            f"; MAVLink signing on (link id {self._signing[0]}, unsigned input "
            f"{'rejected' if self._signing[1] else 'accepted'})",
        )
        if getattr(getattr(self.pipeline, "settings", None), "out_identity", "component") == "none":
            self.log.info("output identity none: no attitude and no HEARTBEAT are sent (the attitude shows in "
                          "the status line and in the --log recording only)")
        next_tick = self._started_s
        master = self.master
        try:
            while self._stop_reason is None:
                timeout = next_tick - time.monotonic()
                events = sel.select(timeout if timeout > 0 else 0)
                for key, _ in events:
                    link = key.data
                    if link is master:
                        self._read_master()
                    elif link is None:
                        try:
                            while self._wake_r.recv(64):
                                pass
                        except (BlockingIOError, InterruptedError):
                            pass
                    else:
                        self._drain_output(link)
                        if link.filenos() != self._registered.get(id(link)):
                            self._sync_registrations()
                    if link is master and master.filenos() != self._registered.get(id(master)):
                        self._sync_registrations()
                now = time.monotonic()
                if now >= next_tick:
                    self._tick(now)
                    next_tick += period
                    if next_tick < now:  # fell behind (suspend, overload): don't burst
                        next_tick = now + period
        finally:
            gc.unfreeze()
            for sig, handler in old_handlers.items():
                signal.signal(sig, handler)
            result_reason = self._stop_reason or "error"
            stats = self.stats()
            self.close()
        run_s = stats["run_s"]
        self.log.info(
            "mavahrs stopped (%s) after %.1f s: %d messages in, %d attitudes out, %d dropped by the input queue, log %s",
            self._signal_name or {"stopped": "on request"}.get(result_reason, result_reason),
            run_s,
            self.counters.messages_in,
            self.counters.attitudes_out,
            self.counters.input_dropped,
            "off" if self.sink is None else f"{self.sink.frames} frames ({self.sink.state})",
        )
        self._save_mag_model()
        if s.stats_path:
            try:
                with open(s.stats_path, "w", encoding="utf-8") as f:
                    json.dump(_jsonable(stats), f)
            except OSError as exc:
                self.log.error("cannot write statistics to %s: %s", s.stats_path, exc.strerror or exc)
        return DaemonResult(reason=result_reason, signal_name=self._signal_name, run_s=run_s, stats=stats)

    def _load_mag_model(self) -> None:
        """``mag_model_path``: start the filter's magnetometer model from the saved one (a bad file: logged, ignored)."""
        path = self.settings.mag_model_path
        f = getattr(self.pipeline, "filter", None)
        load = getattr(f, "load_mag_model", None)
        if not path or load is None or not os.path.exists(path):
            return
        try:
            with open(path, encoding="utf-8") as fh:
                saved = json.load(fh)
        except (OSError, ValueError) as exc:
            self.log.warning("magnetometer model %s not read (%s): learning from scratch", path, exc)
            return
        why = load(saved)
        if why is None:
            self.log.info("magnetometer model read from %s: %s µT/A", path, saved.get("motor_ut_per_a"))
        else:
            self.log.warning("magnetometer model %s not used (%s): learning from scratch", path, why)

    def _save_mag_model(self) -> None:
        path = self.settings.mag_model_path
        export = getattr(getattr(self.pipeline, "filter", None), "export_mag_model", None)
        if not path or export is None:
            return
        model = export()
        if model is None:
            return  # nothing learnt: the saved file (if any) stays as it is
        tmp = f"{path}.tmp"
        try:
            with open(tmp, "w", encoding="utf-8") as fh:
                json.dump(model, fh)
            os.replace(tmp, path)
        except OSError as exc:
            self.log.error("cannot write the magnetometer model to %s: %s", path, exc.strerror or exc)

    def close(self) -> None:
        """Flush and close the log, close the links (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self.http_server is not None:
            self.http_server.stop()
        if self.sink is not None:
            self.sink.close()
        for link in (self.master, *self.outputs):
            try:
                link.close()
            except OSError:
                pass
        if self._selector is not None:
            self._selector.close()
        self._wake_r.close()
        self._wake_w.close()


def _signing_counts(cc: Any) -> dict[str, int]:
    return {
        "signed_ok": cc.signed_ok,
        "signing_rejected": cc.signing_rejected,
        "unsigned_rejected": cc.unsigned_rejected,
        "bad_signature": cc.bad_signature,
        "replayed": cc.replayed,
    }


def set_realtime_priority(priority: int) -> str:
    """Put this process under SCHED_FIFO at ``priority`` (1–99); '' on success, else why not."""
    if not hasattr(os, "sched_setscheduler"):
        return "not supported on this system"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        return exc.strerror or str(exc)
    return ""


def scheduling_description() -> str:
    """This process's scheduling policy, e.g. ``normal`` or ``SCHED_FIFO priority 20``."""
    if not hasattr(os, "sched_getscheduler"):
        return "normal"
    policy = os.sched_getscheduler(0)
    names = {getattr(os, n): n for n in ("SCHED_FIFO", "SCHED_RR") if hasattr(os, n)}
    if policy in names:
        return f"{names[policy]} priority {os.sched_getparam(0).sched_priority}"
    return "normal"


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (int, str, bool)) or value is None:
        return value
    if hasattr(value, "tolist"):
        return _jsonable(value.tolist())
    return str(value)


def build_daemon(
    settings: DaemonSettings,
    pipeline_settings: Any = None,
    filter_settings: Any = None,
    *,
    pipeline: Any = None,
    logger: logging.Logger | None = None,
) -> Daemon:
    """Open the links and the log and build the pipeline: a :class:`Daemon` ready to ``run()``.

    Raises:
        ConfigError: a connection string, the log path or the signing key
            file is unusable (missing, empty, readable by other users).
        TransportError: a link cannot be opened (port busy, permission denied, …).
    """
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.service.sinks import TlogSink
    from mavahrs.transports import open_transport, parse_connection_string

    master_ep = parse_connection_string(settings.master, settings.baud)
    output_eps = [parse_connection_string(text, settings.baud) for text in settings.outputs]
    server = None
    if settings.http is not None:  # the optional extra is checked before anything opens (ConfigError)
        from mavahrs.service.http import StatusBoard, StatusServer, parse_http_address

        host, port = parse_http_address(settings.http)
        server = StatusServer(
            StatusBoard(), host, port, token=settings.http_token,
            health_timeout_s=settings.http_health_timeout_s, logger=logger,
        )
    signing_key = None
    if settings.require_signing and not settings.signing_key_path:
        raise ConfigError("--require-signing needs a key: --signing-key FILE (daemon.signing_key_path)")
    if settings.signing_key_path:  # before any link opens: a bad key file is a config error (exit 2)
        from mavahrs.protocol.signing import load_signing_key

        signing_key = load_signing_key(settings.signing_key_path)
    opened: list[Any] = []
    sink = None
    try:
        common = dict(
            reconnect_interval_s=settings.reconnect_interval_s,
            queue_bytes=settings.output_queue_bytes,
            max_clients=settings.max_tcp_clients,
        )
        master = open_transport(master_ep, **common)
        opened.append(master)
        for ep in output_eps:
            if ep.kind == "serial" and master_ep.kind == "serial" and ep.device == master_ep.device:
                raise ConfigError(f"output {ep.text} is the master device")
            opened.append(open_transport(ep, **common))
        if settings.log_path:
            sink = TlogSink(settings.log_path, settings.log_flush_interval_s)
        if pipeline is None:  # after the links: a busy port is reported before the filter compiles
            from mavahrs.sensors.geomag import decimal_year_from_unix_s
            from mavahrs.service.pipeline import Pipeline, PipelineSettings

            # today's date for the magnetic model until the autopilot sends SYSTEM_TIME (many never
            # do before a GNSS fix gives them the time: without a date there is no declination)
            today = decimal_year_from_unix_s(time.time())
            pipeline = Pipeline(pipeline_settings or PipelineSettings(), filter_settings, decimal_year=today)
        if server is not None:  # before the compile too: a taken port is said at once, not minutes later
            server.start()
        warm_up = getattr(getattr(pipeline, "filter", None), "warm_up", None)
        if warm_up is not None:  # compile/load the filter kernel before serving, not on the first sample
            warm_up()
    except BaseException:
        for link in opened:
            link.close()
        if sink is not None:
            sink.close()
        if server is not None:
            server.stop()
        raise
    # A decoding codec for the master link (the pipeline encodes with its own ids).
    daemon = Daemon(settings, pipeline, opened[0], opened[1:], codec=MavCodec(), sink=sink, logger=logger)
    daemon.http_server = server
    if signing_key is not None:
        try:
            daemon.enable_signing(signing_key, link_id=settings.signing_link_id, require=settings.require_signing)
        except BaseException:
            daemon.close()
            raise
    return daemon

