r"""Asking the autopilot for the IMU stream, and keeping it coming (a pure state machine).

Autopilots send IMU messages at 2–10 Hz unless asked for more, and ground
stations and MAVProxy reset stream rates when they connect.  The
:class:`StreamRequester` therefore

1. on connect (first autopilot HEARTBEAT, reconnection, reboot) requests each
   wanted message with ``COMMAND_LONG(MAV_CMD_SET_MESSAGE_INTERVAL,
   param1 = message id, param2 = interval µs)`` — one command in flight at a
   time, so each COMMAND_ACK is matched to its request;
2. repeats the request every ``interval_s`` (default 10 s) at the rate the
   autopilot last accepted;
3. on ``DENIED`` steps down a ladder of rates (400 → 250 → 200 → 100 → 50 …)
   to the fastest one the autopilot accepts.  ArduPilot refuses intervals its
   scheduler cannot keep (``GCS_MAVLINK::set_message_interval``: DENIED when
   ``cap_message_interval`` — at most 0.8 × SCHED_LOOP_RATE — would raise the
   interval, with STATUSTEXT "Requested rate for message ID … too fast.
   Increase SCHED_LOOP_RATE"); this is said once, naming SCHED_LOOP_RATE, and
   the daemon carries on at the lower rate;
4. falls back to ``REQUEST_DATA_STREAM`` (MAV_DATA_STREAM_RAW_SENSORS for IMU
   messages, POSITION for GLOBAL_POSITION_INT) when the command goes
   unanswered ``attempts`` times or is answered UNSUPPORTED/FAILED, and keeps
   trying the command once per interval in case the autopilot was busy;
5. measures the delivered rate of each wanted message and warns when it is
   far below what was accepted (baud rate too low, a radio in the path, or a
   ground station resetting stream rates).

It produces :class:`SetMessageInterval` / :class:`RequestDataStream` requests
(the pipeline encodes them) and notices (the daemon logs them).  Time is
passed in (``now_us``, the daemon's monotonic clock); nothing here reads a
clock or does I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from mavahrs.errors import ConfigError
from mavahrs.service.stats import Notices, RateMeter

__all__ = [
    "StreamRequestSettings",
    "StreamRequester",
    "SetMessageInterval",
    "RequestDataStream",
    "StreamState",
    "MAV_CMD_SET_MESSAGE_INTERVAL",
    "MAV_DATA_STREAM_RAW_SENSORS",
    "MAV_DATA_STREAM_POSITION",
]

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_DATA_STREAM_RAW_SENSORS = 1
MAV_DATA_STREAM_POSITION = 6
_ACCEPTED, _TEMP_REJECTED, _DENIED, _UNSUPPORTED, _FAILED, _IN_PROGRESS = 0, 1, 2, 3, 4, 5
_RESULT_NAMES = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED", 4: "FAILED",
                 5: "IN_PROGRESS", 6: "CANCELLED"}  # fmt: skip


@dataclass(frozen=True)
class StreamRequestSettings:
    """How the IMU stream is requested.

    Attributes:
        enabled: send requests at all (False: take what the autopilot sends).
        interval_s: re-send every request this often, s (ground stations
            reset stream rates when they connect).
        ack_timeout_s: a SET_MESSAGE_INTERVAL without COMMAND_ACK after this
            long is sent again, s.
        attempts: unanswered sends before falling back to REQUEST_DATA_STREAM.
        ladder_hz: rates tried, fastest first, after a DENIED (only those
            below the wanted rate are used).
        low_rate_fraction: warn when the delivered rate is below this fraction
            of the accepted rate.
        rate_grace_s: time after a request before the delivered rate is judged, s.
        rate_window_s: window over which the delivered rate is measured, s.
    """

    enabled: bool = True
    interval_s: float = 10.0
    ack_timeout_s: float = 1.0
    attempts: int = 3
    ladder_hz: tuple[float, ...] = (400.0, 250.0, 200.0, 100.0, 50.0, 20.0, 10.0)
    low_rate_fraction: float = 0.5
    rate_grace_s: float = 3.0
    rate_window_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("interval_s", "ack_timeout_s", "rate_grace_s", "rate_window_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"stream request setting {name} must be a positive number of seconds, got {v!r}")
        if self.attempts < 1:
            raise ConfigError(f"attempts must be ≥ 1, got {self.attempts}")
        if not self.ladder_hz or any(not (math.isfinite(r) and r > 0) for r in self.ladder_hz):
            raise ConfigError(f"ladder_hz must be positive rates, got {self.ladder_hz!r}")
        if not 0 < self.low_rate_fraction <= 1:
            raise ConfigError(f"low_rate_fraction must be in (0, 1], got {self.low_rate_fraction!r}")


class SetMessageInterval(NamedTuple):
    """Send COMMAND_LONG(MAV_CMD_SET_MESSAGE_INTERVAL, message_id, interval_us)."""

    message_id: int
    message: str
    interval_us: int
    confirmation: int


class RequestDataStream(NamedTuple):
    """Send REQUEST_DATA_STREAM(stream_id, rate_hz, start_stop=1)."""

    stream_id: int
    rate_hz: int


@dataclass(frozen=True)
class StreamState:
    """One wanted message, for the status line.

    Attributes:
        message: message name.
        wanted_hz: the configured rate.
        requested_hz: the rate last asked for.
        accepted_hz: the rate the autopilot accepted (None: not (yet) accepted).
        delivered_hz: measured arrival rate.
        mode: ``command`` (SET_MESSAGE_INTERVAL), ``data_stream`` (fallback)
            or ``off``.
        detail: what happened last (e.g. "DENIED at 400 Hz").
    """

    message: str
    wanted_hz: float
    requested_hz: float
    accepted_hz: float | None
    delivered_hz: float
    mode: str
    detail: str


class _Want:
    __slots__ = ("name", "msg_id", "stream_id", "wanted_hz", "rates", "idx", "mode", "accepted_hz",
                 "due_us", "attempts", "requested_us", "detail", "meter", "denied_hz", "probe", "warn")  # fmt: skip

    def __init__(self, name: str, msg_id: int, stream_id: int, wanted_hz: float, ladder: tuple[float, ...], window_s: float):
        self.name, self.msg_id, self.stream_id = name, msg_id, stream_id
        self.warn = True
        self.meter = RateMeter(window_s)
        self.set_rate(wanted_hz, ladder)

    def set_rate(self, wanted_hz: float, ladder: tuple[float, ...]) -> None:
        self.wanted_hz = wanted_hz
        self.rates = (wanted_hz,) + tuple(r for r in sorted(ladder, reverse=True) if r < wanted_hz)
        self.restart()

    def restart(self) -> None:
        self.idx = 0
        self.mode = "command"
        self.accepted_hz: float | None = None
        self.due_us: int | None = None  # None = as soon as possible
        self.attempts = 0
        self.requested_us: int | None = None
        self.detail = "not requested yet"
        self.denied_hz: float | None = None
        self.probe = False

    @property
    def rate_hz(self) -> float:
        return self.rates[min(self.idx, len(self.rates) - 1)]


class StreamRequester:
    """Keeps the wanted messages streaming at the fastest rate the autopilot accepts."""

    def __init__(self, settings: StreamRequestSettings | None = None) -> None:
        self.settings = settings or StreamRequestSettings()
        s = self.settings
        self._timeout_us = int(s.ack_timeout_s * 1e6)
        self._interval_us = int(s.interval_s * 1e6)
        self._grace_us = int(s.rate_grace_s * 1e6)
        self._wants: dict[str, _Want] = {}
        self._inflight: _Want | None = None
        self._inflight_us = 0
        self._started = False
        self._sched_hint = False
        self._ds_due_us: int | None = None
        self.notices = Notices()
        #: per-message delivered-rate meters (the pipeline adds to them on arrival)
        self.meters: dict[str, RateMeter] = {}
        self.commands_sent = 0
        self.data_stream_requests_sent = 0
        self.acks = 0

    # ------------------------------------------------------------------ configuration
    def want(
        self, name: str, msg_id: int, rate_hz: float, stream_id: int = MAV_DATA_STREAM_RAW_SENSORS, *, warn_low_rate: bool = True
    ) -> None:
        """Ask for ``name`` at ``rate_hz`` (0 = stop asking; nothing is sent to stop it).

        ``warn_low_rate=False`` for messages that may legitimately not exist
        (a second or third IMU the board does not have).
        """
        w = self._wants.get(name)
        if rate_hz <= 0:
            if w is not None:
                del self._wants[name]
                self.meters.pop(name, None)
                if self._inflight is w:
                    self._inflight = None
            return
        if w is None:
            w = self._wants[name] = _Want(name, msg_id, stream_id, rate_hz, self.settings.ladder_hz, self.settings.rate_window_s)
            self.meters[name] = w.meter
        elif w.wanted_hz != rate_hz:
            w.set_rate(rate_hz, self.settings.ladder_hz)
            if self._inflight is w:
                self._inflight = None
        w.warn = warn_low_rate

    def start(self) -> None:
        """(Re)start from the wanted rates: connect, reconnect or autopilot reboot."""
        self._started = True
        self._inflight = None
        self._ds_due_us = None
        for w in self._wants.values():
            w.restart()
            w.meter.reset()

    def stop(self) -> None:
        """Stop sending (link lost); :meth:`start` resumes."""
        self._started = False
        self._inflight = None

    # ------------------------------------------------------------------ inputs
    def on_command_ack(self, command: int, result: int, now_us: int) -> None:
        """A COMMAND_ACK from the autopilot."""
        if command != MAV_CMD_SET_MESSAGE_INTERVAL:
            return
        w = self._inflight
        if w is None:
            return  # not ours (or arrived after we gave up)
        self.acks += 1
        self._inflight = None
        rate = w.rate_hz
        rname = _RESULT_NAMES.get(result, str(result))
        if result == _ACCEPTED:
            if w.mode == "data_stream":
                self.notices.info(f"cmd-back:{w.name}", f"autopilot now accepts SET_MESSAGE_INTERVAL for {w.name}", now_us)
                w.mode = "command"
            if w.accepted_hz != rate:
                w.requested_us = now_us
            w.accepted_hz = rate
            w.attempts = 0
            w.detail = f"accepted at {rate:g} Hz"
            w.due_us = now_us + self._interval_us
            if w.denied_hz is not None:
                self.notices.warning(
                    f"stepdown:{w.name}",
                    f"autopilot refused {w.name} at {w.denied_hz:g} Hz; streaming at {rate:g} Hz instead. "
                    + self._more_hint(),
                    now_us,
                    once=True,
                )
            return
        if result == _DENIED:
            w.denied_hz = w.denied_hz or rate
            w.detail = f"DENIED at {rate:g} Hz"
            w.attempts = 0
            if w.idx + 1 < len(w.rates):
                w.idx += 1
                w.due_us = now_us
            else:
                self._fallback(w, now_us, f"autopilot refused {w.name} at every rate down to {rate:g} Hz")
            return
        if result in (_TEMP_REJECTED, _IN_PROGRESS):
            w.detail = f"{rname} at {rate:g} Hz"
            w.due_us = now_us + self._timeout_us
            return
        # UNSUPPORTED, FAILED, anything else: the command cannot do this
        w.detail = f"{rname} at {rate:g} Hz"
        self._fallback(w, now_us, f"SET_MESSAGE_INTERVAL for {w.name} answered {rname}")

    def on_statustext(self, text: str, now_us: int) -> None:
        """A STATUSTEXT from the autopilot (ArduPilot names SCHED_LOOP_RATE when it refuses a rate)."""
        if "SCHED_LOOP_RATE" in text:
            self._sched_hint = True

    # ------------------------------------------------------------------ outputs
    def poll(self, now_us: int) -> list[SetMessageInterval | RequestDataStream]:
        """Requests due now."""
        if not self._started or not self.settings.enabled:
            return []
        out: list[SetMessageInterval | RequestDataStream] = []
        w = self._inflight
        if w is not None and now_us - self._inflight_us >= self._timeout_us:
            self._inflight = None
            if w.probe:
                w.probe = False  # a single try while in data-stream mode
            elif w.attempts >= self.settings.attempts:
                self._fallback(w, now_us, f"no COMMAND_ACK to SET_MESSAGE_INTERVAL for {w.name} after {w.attempts} tries")
                # an autopilot that never answers will not answer the next ones either: don't make each wait
                for other in self._wants.values():
                    if other is not w and other.mode == "command" and other.accepted_hz is None:
                        self._fallback(other, now_us, "the autopilot does not answer SET_MESSAGE_INTERVAL", quiet=True)
            else:
                w.due_us = now_us
        if self._inflight is None:
            for w in self._wants.values():
                if w.mode == "command" and (w.due_us is None or now_us >= w.due_us):
                    out.append(self._send_command(w, now_us))
                    break
        # data-stream fallback: one request per stream at the highest wanted rate, every interval
        ds = [w for w in self._wants.values() if w.mode == "data_stream"]
        if ds and (self._ds_due_us is None or now_us >= self._ds_due_us):
            rates: dict[int, float] = {}
            for w in ds:
                rates[w.stream_id] = max(rates.get(w.stream_id, 0.0), w.wanted_hz)
            for sid, r in sorted(rates.items()):
                out.append(RequestDataStream(sid, max(1, min(65535, int(round(r))))))
                self.data_stream_requests_sent += 1
            for w in ds:
                if w.requested_us is None:
                    w.requested_us = now_us
            self._ds_due_us = now_us + self._interval_us
            # and try the command once more, in case the autopilot was only busy
            if self._inflight is None:
                w = ds[0]
                w.probe = True
                out.append(self._send_command(w, now_us, probe=True))
        self._check_rates(now_us)
        return out

    def _send_command(self, w: _Want, now_us: int, probe: bool = False) -> SetMessageInterval:
        conf = 0 if probe else w.attempts
        if not probe:
            w.attempts += 1
        self._inflight = w
        self._inflight_us = now_us
        self.commands_sent += 1
        if w.requested_us is None:
            w.requested_us = now_us
        return SetMessageInterval(w.msg_id, w.name, int(round(1e6 / w.rate_hz)), min(conf, 255))

    def _fallback(self, w: _Want, now_us: int, why: str, quiet: bool = False) -> None:
        w.mode = "data_stream"
        w.accepted_hz = None
        w.attempts = 0
        w.requested_us = None
        w.detail = why
        self._ds_due_us = None  # send the data-stream request now
        if quiet:
            return
        stream = "RAW_SENSORS" if w.stream_id == MAV_DATA_STREAM_RAW_SENSORS else str(w.stream_id)
        self.notices.warning(
            f"fallback:{w.name}",
            f"{why}; falling back to REQUEST_DATA_STREAM ({stream}, {w.wanted_hz:g} Hz)",
            now_us,
        )

    def _more_hint(self) -> str:
        if self._sched_hint:
            return "The autopilot asks to increase SCHED_LOOP_RATE (ArduPilot streams at most 0.8 × SCHED_LOOP_RATE)."
        return "On ArduPilot, increase SCHED_LOOP_RATE to allow more (messages stream at most 0.8 × SCHED_LOOP_RATE)."

    def _check_rates(self, now_us: int) -> None:
        frac = self.settings.low_rate_fraction
        for w in self._wants.values():
            expected = w.accepted_hz if w.mode == "command" else (w.wanted_hz if w.mode == "data_stream" else None)
            if not w.warn or expected is None or w.requested_us is None or now_us - w.requested_us < self._grace_us:
                continue
            got = w.meter.rate(now_us)
            if got < frac * expected:
                how = "accepted" if w.mode == "command" else "requested with REQUEST_DATA_STREAM"
                self.notices.warning(
                    f"lowrate:{w.name}",
                    f"{w.name} arrives at {got:.0f} Hz, {expected:g} Hz {how}: the link (baud rate, radio) "
                    "may be too slow, or another ground station resets stream rates",
                    now_us,
                )

    # ------------------------------------------------------------------ reporting
    def drain_notices(self) -> list[tuple[int, str]]:
        return self.notices.drain()

    def states(self, now_us: int) -> tuple[StreamState, ...]:
        """What each wanted message is doing."""
        out = []
        for w in self._wants.values():
            mode = w.mode if (self._started and self.settings.enabled) else "off"
            out.append(StreamState(w.name, w.wanted_hz, w.rate_hz, w.accepted_hz, w.meter.rate(now_us), mode, w.detail))
        return tuple(out)

    def accepted_hz(self, name: str) -> float | None:
        w = self._wants.get(name)
        return None if w is None else w.accepted_hz

