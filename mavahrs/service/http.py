r"""The status page: a small read-only web server beside the daemon (``mavahrs run --http``).

The daemon's loop never waits for it.  The loop *publishes*: every timer tick
(``tick_hz``, 20 Hz by default) :class:`StatusPublisher` stores a
:class:`LiveSample` — a tuple of what it has at hand: our latest quaternion
and its sample time, the autopilot's last ATTITUDE message as received, and
when input and attitude output were last seen (about 5 µs) — and once a
second a status snapshot (rates, drops, CRC errors, gain, sensor trust and
rejection, gyro bias, GNSS, the IMU in use, the second-opinion comparison,
latency, uptime; a ``dict``).  Each is a new immutable object stored into
:class:`StatusBoard` with one reference assignment: the server thread reads
whichever is current, no lock, no queue, nothing the IMU path could block on.
Euler angles, the autopilot's quaternion and the differences are worked out
by the server's thread, only for the samples it sends (:func:`attitude_fields`).

:class:`StatusServer` runs aiohttp on its own thread and event loop
(``pip install 'mavahrs[http]'``; imported only when ``--http`` is given):

* ``/`` — the page (``mavahrs/service/web/``: HTML, CSS, JavaScript shipped in
  the package, no CDN), fed by ``/events`` (Server-Sent Events: the newest
  attitude at 11 Hz, the status once a second);
* ``/status.json`` — both snapshots (fields in docs/status-page.md);
* ``/metrics`` — the Prometheus text format (``prometheus_client``);
* ``/healthz`` — 200 while datagrams arrive from the autopilot link and
  attitudes go out (each within ``http_health_timeout_s``), 503 otherwise;
* ``/register_service`` — BlueOS's extension metadata.

Nothing served changes the vehicle or the daemon (GET and HEAD only).  With a
token (``--http-token``) every request except ``/healthz`` and
``/register_service`` must carry it (``Authorization: Bearer TOKEN`` or
``?token=TOKEN``; the page passes its own ``?token=`` on).
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any, NamedTuple

from mavahrs.errors import ConfigError

__all__ = [
    "StatusBoard",
    "StatusPublisher",
    "LiveSample",
    "attitude_fields",
    "StatusServer",
    "parse_http_address",
    "is_loopback",
    "register_service_info",
    "health",
    "metric_families",
    "MISSING_EXTRA_TEXT",
    "OPEN_TO_NETWORK_TEXT",
]

WEB_DIR = Path(__file__).resolve().parent / "web"
#: The error when ``--http`` is given and the optional web server is not installed.
MISSING_EXTRA_TEXT = (
    "--http needs the optional web server: pip install 'mavahrs[http]' (missing: {missing})"
)
#: The warning logged at start when the page listens beyond this machine without a token.
OPEN_TO_NETWORK_TEXT = (
    "status page on http://{where}/ is open to the network without a token: anyone who can reach "
    "this address can read the vehicle's attitude and link state (the page is read-only); set "
    "--http-token (daemon.http_token) or bind to 127.0.0.1"
)
_STATUS_PERIOD_S = 1.0  # status snapshot (and its Server-Sent Event) period
# How often an event stream sends the newest attitude: 11 Hz (the page wants ≥ 10 Hz).  Each event is a
# wake-up of the server's event loop and a socket write, about 0.2 ms of CPU on the test machine, which
# counts as the daemon's (~75 ms/s at 400 Hz input there): at 20 Hz one open page cost ~5 %.
_EVENT_PERIOD_S = 0.09
_R2D = 180.0 / math.pi
# How much of our published attitude the loop keeps for ``attitude.difference``: the autopilot's ATTITUDE is
# compared with ours at its own time_boot_ms, and arrives up to this late (the monitor's history_s alike).
_HISTORY_S = 2.0
# Our history is sampled at the loop's timer ticks (20 Hz); ours is interpolated between two ticks up to
# 2 × this apart, else the nearest within this (the rule of monitor.align_attitudes; a stalled loop: null).
_ALIGN_TOLERANCE_MS = 60.0


# --------------------------------------------------------------------------- addresses


def parse_http_address(text: str | int) -> tuple[str, int]:
    """``"8088"`` → ``("127.0.0.1", 8088)``; ``"0.0.0.0:8088"``, ``"[::]:8088"``, ``"HOST:PORT"``.

    Port 0 lets the system choose (the start-up line says which).

    Raises:
        ConfigError: not ``[HOST:]PORT`` with a port 0…65535.
    """
    s = str(text).strip()
    host = "127.0.0.1"
    port_text = s
    if s.startswith("["):  # [IPv6]:PORT
        end = s.find("]")
        if end < 0 or s[end + 1 : end + 2] != ":":
            raise ConfigError(f"--http {s!r}: expected [HOST:]PORT, e.g. 8088 or 0.0.0.0:8088 or [::1]:8088")
        host, port_text = s[1:end], s[end + 2 :]
    elif ":" in s:
        host, _, port_text = s.rpartition(":")
        if ":" in host:
            raise ConfigError(f"--http {s!r}: write an IPv6 address in brackets, e.g. [::1]:8088")
        host = host or "127.0.0.1"
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise ConfigError(f"--http {s!r}: the port must be a number 0…65535 (e.g. 8088 or 0.0.0.0:8088)")
    return host, port


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


# --------------------------------------------------------------------------- snapshots


class StatusBoard:
    """The snapshots the daemon publishes and the server reads.

    Each attribute is replaced as a whole (a new dict, never changed after);
    a reader takes the reference once and uses that snapshot.
    """

    def __init__(self) -> None:
        self.live: LiveSample | None = None
        self.status: Mapping[str, Any] | None = None


class LiveSample(NamedTuple):
    """What the daemon's loop publishes every tick (immutable; see :func:`attitude_fields`).

    Attributes:
        t_s: when, ``time.monotonic()`` s.
        started_s: when the daemon started, s (same clock).
        last_input_s: when input from the autopilot link was last seen (None: never).
        last_attitude_s: when an attitude last went out (None: never).
        time_boot_ms: the autopilot's time of the sample our estimate belongs to.
        q_body_to_ned: our latest estimate (None before the filter has one).
        autopilot_msg: the autopilot's last ATTITUDE / ATTITUDE_QUATERNION as received, or None.
        autopilot_rx_s: when it arrived, s.
        history: our estimates over the last ``_HISTORY_S`` as published at earlier ticks,
            ``((time_boot_ms, q_body_to_ned), …)`` oldest first, this tick's last: the autopilot's
            attitude is compared with ours at its own time (``attitude.difference``).
    """

    t_s: float
    started_s: float
    last_input_s: float | None
    last_attitude_s: float | None
    time_boot_ms: int | None
    q_body_to_ned: tuple[float, float, float, float] | None
    autopilot_msg: Any
    autopilot_rx_s: float
    history: tuple[tuple[int, tuple[float, float, float, float]], ...] = ()


def _euler_deg(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees, aerospace Z-Y-X, yaw 0…360."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll * _R2D, pitch * _R2D, (yaw * _R2D) % 360.0


def _finite(v: Any) -> Any:
    return v if not isinstance(v, float) or math.isfinite(v) else None


def _finite_fields(value: Any) -> Any:
    """Non-finite floats → None, through dicts and lists (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _finite_fields(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite_fields(v) for v in value]
    return _finite(value)


class StatusPublisher:
    """Builds the snapshots from the daemon's loop (its timer tick): cheap, allocation-light.

    Args:
        board: where the snapshots go.
        started_s: the daemon's start, ``time.monotonic()`` seconds.
    """

    def __init__(self, board: StatusBoard, started_s: float) -> None:
        self.board = board
        self.started_s = started_s
        self._datagrams = -1
        self._attitudes = -1
        self._last_input_s: float | None = None
        self._last_attitude_s: float | None = None
        self._next_status_s = 0.0
        self._history: deque[tuple[int, tuple[float, float, float, float]]] = deque()

    def tick(self, daemon: Any, now_s: float) -> None:
        """Publish a :class:`LiveSample`, and the status snapshot when due."""
        c = daemon.counters
        if c.datagrams_in != self._datagrams:
            self._datagrams = c.datagrams_in
            if c.datagrams_in:
                self._last_input_s = now_s
        if c.attitudes_out != self._attitudes:
            self._attitudes = c.attitudes_out
            if c.attitudes_out:
                self._last_attitude_s = now_s
        live = getattr(daemon.pipeline, "live_attitude", None)
        t_ms, q, ap_msg, ap_us = live() if live is not None else (None, None, None, 0)
        h = self._history
        if t_ms is None or q is None:
            h.clear()  # no attitude (yet, or the filter re-initialised): nothing to compare with
        elif not h or t_ms > h[-1][0]:
            h.append((t_ms, q))
            while t_ms - h[0][0] > 1000.0 * _HISTORY_S:
                h.popleft()
        elif t_ms < h[-1][0]:  # the autopilot rebooted (its clock went back): a new time axis
            h.clear()
            h.append((t_ms, q))
        self.board.live = LiveSample(
            now_s, self.started_s, self._last_input_s, self._last_attitude_s, t_ms, q, ap_msg, ap_us * 1e-6,
            tuple(h),
        )
        if now_s >= self._next_status_s:
            self._next_status_s = now_s + _STATUS_PERIOD_S
            self.board.status = self._status(daemon, now_s)

    def _status(self, daemon: Any, now_s: float) -> dict[str, Any]:
        from mavahrs.service.daemon import _jsonable

        fields = daemon.status_fields(now_s, window="http")
        p = daemon.last_pipeline_status
        c = daemon.counters
        mon = getattr(p, "monitor_state", None)
        out: dict[str, Any] = {
            "t_s": now_s,
            "uptime_s": now_s - self.started_s,
            **fields,
            "filter": getattr(p, "filter_name", None),
            "autopilot_profile": getattr(p, "autopilot_profile", None),
            "vehicle": list(p.vehicle) if getattr(p, "vehicle", None) else None,
            "initialised": getattr(p, "initialised", None),
            "accel_rejection_pct": getattr(p, "accel_rejection_pct", None),
            "mag_rejection_pct": getattr(p, "mag_rejection_pct", None),
            "gnss_velocity": getattr(p, "gnss_velocity", None),
            "samples_in": getattr(p, "samples_in", None),
            "samples_filtered": getattr(p, "samples_filtered", None),
            "second_opinion": None if mon is None else {
                "tilt_deg": _finite(mon.tilt_deg), "heading_deg": _finite(mon.heading_deg),
                "warning": mon.warning, "comparisons": mon.comparisons, "episodes": mon.episodes,
                **_second_opinion_extra(mon),
            },
            "datagrams_in": c.datagrams_in,
            "messages_in": c.messages_in,
            "attitudes_out": c.attitudes_out,
            "input_dropped": c.input_dropped,
            "master": daemon.settings.master,
        }
        out["pilot"] = _pilot(daemon, fields)
        return _jsonable(out)


def _pilot(daemon: Any, fields: dict[str, Any]) -> dict[str, Any] | None:
    """The pilot's fields (armed, mode, battery, altitude, speed, GNSS, field strength, recording, latency)."""
    from mavahrs.service.pilot import pilot_fields

    try:
        return pilot_fields(daemon, fields)
    except Exception:  # noqa: BLE001 - a malformed message must not take the page down
        return None


def _second_opinion_extra(mon: Any) -> dict[str, Any]:
    """The thresholds, the flight's phase and who is likely wrong (docs/status-page.md, ``second_opinion``)."""
    ev = getattr(mon, "evidence", None)
    return {
        "tilt_threshold_deg": _finite(getattr(mon, "tilt_threshold_deg", math.nan)),
        "heading_threshold_deg": _finite(getattr(mon, "heading_threshold_deg", math.nan)),
        "phase": getattr(mon, "phase", None),
        "cause": getattr(mon, "cause", "") or "",
        "trigger": getattr(mon, "trigger", "") or "",
        "evidence": ev.as_dict() if ev is not None else None,
        "evidence_text": ev.text() if ev is not None else "",
        "strip": _strip(getattr(mon, "strip", ())),
        "imu_late": int(getattr(mon, "imu_late", 0)),
        "judged": not getattr(mon, "held", False),
        "imu_rate_hz": _finite(getattr(mon, "imu_rate_hz", math.nan)),
        "held_comparisons": int(getattr(mon, "held_comparisons", 0)),
    }


def _strip(points: Any) -> dict[str, list[Any]]:
    """The strip chart's history as columns (``second_opinion.strip`` in docs/status-page.md)."""
    cols: dict[str, list[Any]] = {k: [] for k in (
        "t_s", "tilt_deg", "heading_deg", "tilt_threshold_deg", "heading_threshold_deg", "warning", "raised")}
    for t, tilt, hdg, t_thr, h_thr, warn, raised in points:
        cols["t_s"].append(round(t, 2))
        cols["tilt_deg"].append(_finite(round(tilt, 3)))
        cols["heading_deg"].append(_finite(round(hdg, 3)))
        cols["tilt_threshold_deg"].append(_finite(round(t_thr, 3)))
        cols["heading_threshold_deg"].append(_finite(round(h_thr, 3)))
        cols["warning"].append(bool(warn))
        cols["raised"].append(int(raised))
    return cols


class _AutopilotCache:
    """The autopilot's last message converted once (it arrives at 10 Hz or so; samples at 20 Hz)."""

    def __init__(self) -> None:
        self.msg: Any = None
        self.value: tuple[tuple[float, float, float, float], dict[str, Any]] | None = None

    def get(self, msg: Any) -> tuple[tuple[float, float, float, float], dict[str, Any]] | None:
        from mavahrs.service.monitor import attitude_of_message

        if msg is not self.msg:
            self.msg = msg
            ap = attitude_of_message(msg) if msg is not None else None
            self.value = None
            if ap is not None:
                t_ms, q = ap
                r, p, y = _euler_deg(q)
                self.value = (q, {"time_boot_ms": int(t_ms), "q": _scalar_positive(q), "roll_deg": r, "pitch_deg": p,
                                  "yaw_deg": y})
        return self.value


def _scalar_positive(q: Any) -> list[float]:
    """``q`` as a list with its scalar part ≥ 0: q and −q are the same rotation, and a reader comparing two
    attitudes element by element (ours against the autopilot's) should not see one of them negated."""
    v = [float(c) for c in q]
    return [-c for c in v] if v[0] < 0.0 else v


def attitude_fields(live: LiveSample, autopilot: _AutopilotCache | None = None) -> dict[str, Any]:
    """The ``attitude`` object of ``/status.json`` and the page's events (docs/status-page.md)."""
    q = live.q_body_to_ned
    att: dict[str, Any] = {
        "t_s": live.t_s,
        "uptime_s": live.t_s - live.started_s,
        "time_boot_ms": live.time_boot_ms,
        "q": _scalar_positive(q) if q is not None else None,
        "last_input_s": live.last_input_s,
        "last_attitude_s": live.last_attitude_s,
        "autopilot": None,
        "difference": None,
    }
    if q is not None:
        att["roll_deg"], att["pitch_deg"], att["yaw_deg"] = _euler_deg(q)
    ap = (autopilot or _AutopilotCache()).get(live.autopilot_msg)
    if ap is not None:
        ap_q, ap_fields = ap
        att["autopilot"] = {**ap_fields, "age_s": live.t_s - live.autopilot_rx_s}
        if q is not None:
            att["difference"] = _aligned_difference(live, ap_fields["time_boot_ms"], ap_q)
    return att


def _aligned_difference(
    live: LiveSample, ap_time_boot_ms: int, ap_q: tuple[float, float, float, float]
) -> dict[str, Any] | None:
    """Ours against the autopilot's attitude at the autopilot's own ``time_boot_ms`` (``attitude.difference``).

    Ours is taken from the published history at that time (interpolated, :func:`monitor.align_attitudes`'s
    rule), so neither the autopilot's message delay nor its 10 Hz rate shows as a difference (against our
    latest, an ATTITUDE 0.54 s old read −20° in a turn). The error e = q_ours ⊗ q_ap* split into
    tilt and signed heading (:func:`monitor.attitude_divergence_rad`). None when the history does not
    reach that time (an ATTITUDE older than ``_HISTORY_S``, or the loop stalled)."""
    import numpy as np

    from mavahrs.service.monitor import align_attitudes, attitude_divergence_rad

    hist = live.history or ((live.time_boot_ms, live.q_body_to_ned),)
    if hist[0][0] is None or hist[0][1] is None:
        return None
    t = np.array([h[0] for h in hist], dtype=np.float64)
    qs = np.array([h[1] for h in hist], dtype=np.float64)
    q = align_attitudes(t, qs, [float(ap_time_boot_ms)], tolerance_ms=_ALIGN_TOLERANCE_MS)[0]
    if not np.all(np.isfinite(q)):
        return None
    tilt, heading = attitude_divergence_rad(q.tolist(), ap_q)
    return {"time_boot_ms": int(ap_time_boot_ms), "tilt_deg": tilt * _R2D, "heading_deg": heading * _R2D}


def health(live: LiveSample | None, now_s: float, timeout_s: float) -> tuple[bool, str]:
    """``(healthy, why)``: input from the autopilot and attitudes out, both within ``timeout_s``.

    ``now_s`` is ``time.monotonic()``; a snapshot older than ``timeout_s`` (the daemon's loop
    stalled) is unhealthy too.
    """
    if live is None:
        return False, "starting"
    if now_s - live.t_s > timeout_s:
        return False, f"the daemon's loop has not published for {now_s - live.t_s:.1f} s"
    last_in = live.last_input_s
    if last_in is None:
        return False, "nothing received from the autopilot yet"
    if now_s - last_in > timeout_s:
        return False, f"nothing received from the autopilot for {now_s - last_in:.1f} s"
    last_out = live.last_attitude_s
    if last_out is None:
        return False, "no attitude sent yet"
    if now_s - last_out > timeout_s:
        return False, f"no attitude sent for {now_s - last_out:.1f} s"
    return True, "ok"


# --------------------------------------------------------------------------- documents


def register_service_info(version: str) -> dict[str, Any]:
    """BlueOS's extension metadata (``GET /register_service``): what its side bar shows."""
    return {
        "name": "mavahrs",
        "description": "Attitude estimate (artificial horizon, heading), MAVLink link and filter health",
        "icon": "mdi-airplane",
        "company": "mavahrs",
        "version": version,
        "webpage": "https://github.com/mavahrs/mavahrs",
        "api": "status.json",
        "new_page": False,
        "works_in_relative_paths": True,
    }


def metric_families(
    attitude: Mapping[str, Any] | None, status: Mapping[str, Any] | None, healthy: bool, version: str
) -> Iterator[Any]:
    """The ``/metrics`` families (``prometheus_client`` metric families) from the snapshots."""
    from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, InfoMetricFamily

    def gauge(name: str, doc: str, value: Any, unit: str = "") -> Any:
        g = GaugeMetricFamily(name, doc, unit=unit)
        g.add_metric([], _num(value))
        return g

    def counter(name: str, doc: str, value: Any) -> Any:
        return CounterMetricFamily(name, doc, value=_num(value))

    yield gauge("mavahrs_up", "1 while the autopilot link is alive and attitudes are sent (as /healthz)", healthy)
    s = status or {}
    a = attitude or {}
    yield InfoMetricFamily("mavahrs_build", "version and configuration", value={
        "version": version, "filter": str(s.get("filter") or ""), "master": str(s.get("master") or ""),
    })
    yield gauge("mavahrs_uptime_seconds", "time since the daemon started", a.get("uptime_s"))
    yield counter("mavahrs_datagrams_received", "reads from the autopilot link", s.get("datagrams_in"))
    yield counter("mavahrs_messages_received", "MAVLink messages decoded from the autopilot link", s.get("messages_in"))
    yield counter("mavahrs_attitudes_sent", "ATTITUDE_QUATERNION messages sent", s.get("attitudes_out"))
    yield counter("mavahrs_input_dropped", "reads dropped from the full input queue", s.get("input_dropped"))
    yield counter("mavahrs_crc_errors", "frames with a bad checksum", s.get("crc_errors"))
    yield counter("mavahrs_bad_data", "frames that could not be decoded", s.get("bad_data"))
    yield counter("mavahrs_sequence_gaps", "frames missing by sequence number", s.get("seq_gaps"))
    yield counter("mavahrs_imu_samples", "IMU messages accepted from the vehicle", s.get("samples_in"))
    yield counter("mavahrs_samples_filtered", "IMU samples run through the filter", s.get("samples_filtered"))
    drops = CounterMetricFamily("mavahrs_samples_dropped", "samples not filtered and reads dropped, by reason",
                                labels=["reason"])
    for reason, n in sorted((s.get("drops_by_reason") or {}).items()):
        drops.add_metric([str(reason)], _num(n))
    drops.add_metric(["link"], _num(s.get("link_drops")))
    yield drops
    rates = GaugeMetricFamily("mavahrs_rate_hertz", "messages per second", labels=["stage"])
    for stage, key in (("input", "in_hz"), ("filter", "filter_hz"), ("output", "out_hz")):
        rates.add_metric([stage], _num(s.get(key)))
    yield rates
    yield gauge("mavahrs_filter_gain", "the filter's correction gain (after boost and rejection)", s.get("gain"))
    trust = GaugeMetricFamily("mavahrs_sensor_trust_ratio", "trust in a sensor, 0…1", labels=["sensor"])
    trust.add_metric(["accelerometer"], _num(s.get("accel_weight")))
    trust.add_metric(["magnetometer"], _num(s.get("mag_weight")))
    yield trust
    rejected = GaugeMetricFamily("mavahrs_sensor_rejected", "1 while a sensor is rejected", labels=["sensor"])
    rejected.add_metric(["accelerometer"], _num(s.get("accel_rejected")))
    rejected.add_metric(["magnetometer"], _num(s.get("mag_rejected")))
    yield rejected
    share = GaugeMetricFamily("mavahrs_sensor_rejection_ratio", "share of samples with the sensor rejected since "
                              "the previous status, 0…1", labels=["sensor"])
    for sensor, key in (("accelerometer", "accel_rejection_pct"), ("magnetometer", "mag_rejection_pct")):
        v = _num(s.get(key))
        share.add_metric([sensor], v / 100.0 if math.isfinite(v) else v)
    yield share
    bias = GaugeMetricFamily("mavahrs_gyro_bias_radians_per_second", "gyro bias estimate", labels=["axis"])
    for axis, v in zip("xyz", s.get("bias_deg_s") or (None, None, None), strict=True):
        v = _num(v)
        bias.add_metric([axis], v / _R2D if math.isfinite(v) else v)
    yield bias
    yield gauge("mavahrs_gnss_velocity_in_use", "1 while GNSS velocity aids the filter",
                s.get("gnss_velocity") == "in use")
    yield gauge("mavahrs_imu_in_use", "the IMU instance in use (-1: none)",
                -1 if s.get("imu") is None else s.get("imu"))
    att = GaugeMetricFamily("mavahrs_attitude_degrees", "attitude estimate (Euler Z-Y-X)", labels=["angle"])
    for angle in ("roll", "pitch", "yaw"):
        att.add_metric([angle], _num(a.get(f"{angle}_deg")))
    yield att
    so = s.get("second_opinion") or {}
    div = GaugeMetricFamily("mavahrs_autopilot_divergence_degrees",
                            "difference from the autopilot's attitude, time-aligned", labels=["component"])
    div.add_metric(["tilt"], _num(so.get("tilt_deg")))
    div.add_metric(["heading"], _num(so.get("heading_deg")))
    yield div
    yield gauge("mavahrs_autopilot_divergence_alarm", "1 while the second-opinion warning is active",
                so.get("warning"))
    yield counter("mavahrs_autopilot_divergence_episodes", "second-opinion warnings raised", so.get("episodes"))
    lat = GaugeMetricFamily("mavahrs_processing_latency_seconds",
                            "datagram read → attitude sent, over the last status period", labels=["quantile"])
    for qname, key in (("0.5", "latency_p50_us"), ("0.99", "latency_p99_us"), ("1", "latency_max_us")):
        v = _num(s.get(key))
        lat.add_metric([qname], v * 1e-6 if math.isfinite(v) else v)
    yield lat


def _num(value: Any) -> float:
    if value is None:
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


# --------------------------------------------------------------------------- server


class StatusServer:
    """aiohttp on its own thread and event loop, serving the board's snapshots (see the module docstring).

    Args:
        board: the snapshots.
        host, port: where to listen (port 0: the system picks; see :attr:`port`).
        token: required on every request but ``/healthz`` and ``/register_service``; None = none.
        health_timeout_s: see :func:`health`.
        logger: for the start-up line, the open-to-the-network warning and errors.
    """

    def __init__(
        self,
        board: StatusBoard,
        host: str = "127.0.0.1",
        port: int = 8088,
        *,
        token: str | None = None,
        health_timeout_s: float = 1.0,
        logger: logging.Logger | None = None,
    ) -> None:
        missing = [m for m in ("aiohttp", "prometheus_client") if not _importable(m)]
        if missing:
            raise ConfigError(MISSING_EXTRA_TEXT.format(missing=", ".join(missing)))
        from mavahrs import __version__

        self.board = board
        self.host = host
        self.port = port
        self.token = token or None
        self.health_timeout_s = health_timeout_s
        self.log = logger or logging.getLogger("mavahrs.http")
        self.version = __version__
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop_event: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self.requests = 0
        self._cache: dict[str, tuple[Any, Any]] = {}
        self._autopilot = _AutopilotCache()

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def start(self) -> None:
        """Listen (in the server's thread) and return once listening.

        Raises:
            ConfigError: the address cannot be bound (in use, not this machine's, no permission):
                a local set-up mistake (exit code 2), not a lost autopilot link.
        """
        self._thread = threading.Thread(target=self._run, name="mavahrs-http", daemon=True)
        self._thread.start()
        self._ready.wait(30)
        if self._error is not None:
            self._thread.join(5)
            err = self._error
            raise ConfigError(
                f"status page: cannot listen on {self.host}:{self.port}: {getattr(err, 'strerror', None) or err} "
                "(--http: choose another port, or stop the program using it)"
            ) from err
        where = self.url.removeprefix("http://").rstrip("/")
        self.log.info("status page on %s%s", self.url, " (token required)" if self.token else "")
        if not is_loopback(self.host) and not self.token:
            self.log.warning(OPEN_TO_NETWORK_TEXT.format(where=where))

    def stop(self) -> None:
        """Close the listener and the open event streams, end the thread (idempotent)."""
        loop, ev = self._loop, self._stop_event
        if loop is not None and ev is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(ev.set)
            except RuntimeError:  # the loop has just closed
                pass
        if self._thread is not None:
            self._thread.join(10)
            self._thread = None

    # ------------------------------------------------------------------ thread
    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001 - reported to start() or logged, never the daemon's end
            if not self._ready.is_set():
                self._error = exc
            else:
                self.log.error("status page stopped: %s: %s", type(exc).__name__, exc)
        finally:
            self._ready.set()
            loop.close()

    async def _serve(self) -> None:
        from aiohttp import web

        self._stop_event = asyncio.Event()
        app = web.Application(middlewares=[self._guard])
        app.router.add_get("/", self._index)
        app.router.add_get("/index.html", self._index)
        app.router.add_static("/static/", WEB_DIR, follow_symlinks=False)
        app.router.add_get("/status.json", self._status_json)
        app.router.add_get("/metrics", self._metrics)
        app.router.add_get("/healthz", self._healthz)
        app.router.add_get("/register_service", self._register_service)
        app.router.add_get("/events", self._events)
        runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=1.0)
        await runner.setup()
        try:
            site = web.TCPSite(runner, self.host, self.port, reuse_address=True)
            await site.start()
            server = getattr(site, "_server", None)
            if server is not None and server.sockets:
                self.port = server.sockets[0].getsockname()[1]
            self._ready.set()
            await self._stop_event.wait()
        finally:
            await runner.cleanup()

    # ------------------------------------------------------------------ handlers
    def _authorised(self, request: Any) -> bool:
        if self.token is None or request.path in ("/healthz", "/register_service"):
            return True
        given = request.query.get("token")
        auth = request.headers.get("Authorization", "")
        if given is None and auth.startswith("Bearer "):
            given = auth[7:].strip()
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    @property
    def _guard(self) -> Any:
        from aiohttp import web

        @web.middleware
        async def guard(request: Any, handler: Any) -> Any:
            self.requests += 1
            if request.method not in ("GET", "HEAD"):
                return web.Response(status=405, text="read-only\n", headers={"Allow": "GET, HEAD"})
            if not self._authorised(request):
                return web.Response(
                    status=401, text="token required: ?token=TOKEN or Authorization: Bearer TOKEN\n",
                    headers={"WWW-Authenticate": 'Bearer realm="mavahrs"'},
                )
            response = await handler(request)
            response.headers.setdefault("Cache-Control", "no-store")
            response.headers.setdefault("X-Content-Type-Options", "nosniff")
            return response

        return guard

    async def _index(self, request: Any) -> Any:
        from aiohttp import web

        return web.FileResponse(WEB_DIR / "index.html")

    def _attitude(self, live: LiveSample | None) -> dict[str, Any] | None:
        """:func:`attitude_fields` of a sample, worked out once per sample (every client shares it)."""
        if live is None:
            return None
        cached = self._cache.get("attitude-fields")
        if cached is not None and cached[0] is live:
            return cached[1]
        fields = _finite_fields(attitude_fields(live, self._autopilot))
        self._cache["attitude-fields"] = (live, fields)
        return fields

    def _json(self, key: str, snapshot: Any) -> str:
        """The JSON text of a snapshot (a :class:`LiveSample` for ``"attitude"``), made once per snapshot."""
        cached = self._cache.get(key)
        if cached is not None and cached[0] is snapshot:
            return cached[1]
        value = self._attitude(snapshot) if key == "attitude" else snapshot
        text = json.dumps(value, separators=(",", ":"))
        self._cache[key] = (snapshot, text)
        return text

    async def _status_json(self, request: Any) -> Any:
        from aiohttp import web

        att, status = self.board.live, self.board.status
        ok, why = health(att, time.monotonic(), self.health_timeout_s)
        body = (
            f'{{"healthy":{"true" if ok else "false"},"health":{json.dumps(why)},'
            f'"version":{json.dumps(self.version)},"attitude":{self._json("attitude", att)},'
            f'"status":{self._json("status", status)}}}'
        )
        return web.Response(text=body, content_type="application/json")

    async def _metrics(self, request: Any) -> Any:
        from aiohttp import web
        from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

        live, status = self.board.live, self.board.status
        ok, _ = health(live, time.monotonic(), self.health_timeout_s)
        registry = CollectorRegistry(auto_describe=False)
        registry.register(_Families(metric_families(self._attitude(live), status, ok, self.version)))
        return web.Response(body=generate_latest(registry), headers={"Content-Type": CONTENT_TYPE_LATEST})

    async def _healthz(self, request: Any) -> Any:
        from aiohttp import web

        ok, why = health(self.board.live, time.monotonic(), self.health_timeout_s)
        return web.Response(status=200 if ok else 503, text=("ok" if ok else f"unhealthy: {why}") + "\n")

    async def _register_service(self, request: Any) -> Any:
        from aiohttp import web

        return web.json_response(register_service_info(self.version))

    async def _events(self, request: Any) -> Any:
        """Server-Sent Events: the newest ``attitude`` every 90 ms (11 Hz), ``status`` once a second."""
        from aiohttp import web

        resp = web.StreamResponse(headers={
            "Content-Type": "text/event-stream", "Cache-Control": "no-store", "X-Accel-Buffering": "no",
        })
        await resp.prepare(request)
        sent_att: Any = None
        sent_status: Any = None
        stop = self._stop_event
        assert stop is not None
        try:
            await resp.write(b"retry: 1000\n\n")
            while not stop.is_set():
                att, status = self.board.live, self.board.status
                chunks = []
                if status is not None and status is not sent_status:
                    sent_status = status
                    chunks.append(f"event: status\ndata: {self._json('status', status)}\n\n")
                if att is not None and att is not sent_att:
                    sent_att = att
                    ok, why = health(att, time.monotonic(), self.health_timeout_s)
                    chunks.append(
                        f"event: attitude\ndata: {{\"healthy\":{'true' if ok else 'false'},"
                        f"\"health\":{json.dumps(why)},\"attitude\":{self._json('attitude', att)}}}\n\n"
                    )
                if chunks:
                    await resp.write("".join(chunks).encode())
                await asyncio.sleep(_EVENT_PERIOD_S)  # (cheaper than a wait on the stop event with a timeout)
        except ConnectionResetError:  # the browser went away
            pass
        return resp


class _Families:
    """A one-shot ``prometheus_client`` collector over already built families."""

    def __init__(self, families: Iterator[Any]) -> None:
        self._families = list(families)

    def collect(self) -> Iterator[Any]:
        return iter(self._families)


def _importable(module: str) -> bool:
    import importlib

    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True
