r"""Asking the autopilot for the IMU stream, and keeping it coming (a pure state machine).

Autopilots send IMU messages at 2–10 Hz unless asked for more, and ground
stations and MAVProxy reset stream rates when they connect.  The
:class:`StreamRequester` therefore

1. on connect (first autopilot HEARTBEAT, reconnection, reboot) requests each
   wanted message with ``COMMAND_LONG(MAV_CMD_SET_MESSAGE_INTERVAL,
   param1 = message id, param2 = interval µs)`` — one command in flight at a
   time, so each COMMAND_ACK is matched to its request;
2. repeats the request every ``interval_s`` (default 10 s) at the rate the
   autopilot last accepted, and **at once** when the delivered rate collapses
   (below ``low_rate_fraction`` of the accepted rate over ``drop_window_s``,
   judged ``drop_grace_s`` after each request was acknowledged) or when another
   node is seen asking the autopilot for other rates (REQUEST_DATA_STREAM,
   SET_MESSAGE_INTERVAL): MAVProxy with ``--streamrate`` and ground stations
   reset every stream group, RAW_IMU included.  These quick re-requests are at
   least ``rerequest_min_s`` apart; when one does not bring the rate back the
   spacing doubles (up to ``interval_s``) and, after two in vain, a single
   warning says the autopilot or the link cannot deliver;
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
   ground station resetting stream rates faster than they can be restored);
   :meth:`StreamRequester.rate_settled` tells the pipeline when a message's
   rate has had time to take effect (its own low-rate warning waits for it).

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
    "MAV_DATA_STREAM_EXTRA1",
]

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_DATA_STREAM_RAW_SENSORS = 1
MAV_DATA_STREAM_EXTENDED_STATUS = 2  # ArduPilot: SYS_STATUS, GPS_RAW_INT, GPS2_RAW, …
MAV_DATA_STREAM_POSITION = 6
MAV_DATA_STREAM_EXTRA1 = 10  # ArduPilot: ATTITUDE, SIMSTATE, …
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
        attempts: unanswered sends before falling back to REQUEST_DATA_STREAM (a send
            followed by silence from the autopilot, nothing at all arriving, does not count).
        ladder_hz: rates tried, fastest first, after a DENIED (only those
            below the wanted rate are used).
        low_rate_fraction: warn when the delivered rate is below this fraction
            of the accepted rate.
        rate_grace_s: time after a request before the delivered rate is judged, s
            (slow check: data-stream mode, and the pipeline's own low-rate
            warning waits this long after the accepted rate last changed).
        rate_window_s: window over which the delivered rate is measured, s.
        rerequest_on_drop: ask again at once when the delivered rate falls
            below ``low_rate_fraction`` × the accepted rate, or when another
            node is seen changing the autopilot's stream rates (False: only the
            periodic re-request every ``interval_s``).
        drop_window_s: window of the quick delivered-rate check, s (a stream
            expecting fewer than 20 messages in it — e.g. GNSS at 10 Hz — is
            judged over ``rate_window_s`` instead, so that random loss on a
            radio link is not taken for a rate reset).
        drop_grace_s: time after a request's COMMAND_ACK (or the request, for
            REQUEST_DATA_STREAM) before the quick check judges the rate, s.
        rerequest_min_s: quick re-requests of one message are at least this
            far apart, s; doubled after each one that did not restore the rate
            (up to ``interval_s``), back to this once it is restored.
        foreign_request_delay_s: after seeing another node's
            REQUEST_DATA_STREAM / SET_MESSAGE_INTERVAL to the autopilot, ask
            again this much later (so ours arrives after theirs), s.
    """

    enabled: bool = True
    interval_s: float = 10.0
    ack_timeout_s: float = 1.0
    attempts: int = 3
    ladder_hz: tuple[float, ...] = (400.0, 250.0, 200.0, 100.0, 50.0, 20.0, 10.0)
    low_rate_fraction: float = 0.5
    rate_grace_s: float = 3.0
    rate_window_s: float = 2.0
    rerequest_on_drop: bool = True
    drop_window_s: float = 0.5
    drop_grace_s: float = 1.0
    rerequest_min_s: float = 1.0
    foreign_request_delay_s: float = 0.2

    def __post_init__(self) -> None:
        for name in ("interval_s", "ack_timeout_s", "rate_grace_s", "rate_window_s", "drop_window_s", "drop_grace_s",
                     "rerequest_min_s"):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"stream request setting {name} must be a positive number of seconds, got {v!r}")
        if self.attempts < 1:
            raise ConfigError(f"attempts must be ≥ 1, got {self.attempts}")
        if not self.ladder_hz or any(not (math.isfinite(r) and r > 0) for r in self.ladder_hz):
            raise ConfigError(f"ladder_hz must be positive rates, got {self.ladder_hz!r}")
        d = self.foreign_request_delay_s
        if not (math.isfinite(d) and d >= 0):
            raise ConfigError(f"foreign_request_delay_s must be ≥ 0 s, got {d!r}")
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


#: the quick rate check needs this many expected messages in its window, else the status window is used
_QUICK_MIN_MESSAGES = 20


class _Meter:
    """Arrival counter for one message: the status window and the quick-check window."""

    __slots__ = ("slow", "fast")

    def __init__(self, window_s: float, fast_window_s: float) -> None:
        self.slow = RateMeter(window_s)
        self.fast = RateMeter(fast_window_s)

    def add(self, now_us: int, n: int = 1) -> None:
        self.slow.add(now_us, n)
        self.fast.add(now_us, n)

    def rate(self, now_us: int) -> float:
        return self.slow.rate(now_us)

    @property
    def total(self) -> int:
        return self.slow.total

    def reset(self) -> None:
        self.slow.reset()
        self.fast.reset()


class _Want:
    __slots__ = ("name", "msg_id", "stream_id", "wanted_hz", "rates", "idx", "mode", "accepted_hz",
                 "due_us", "attempts", "requested_us", "detail", "meter", "denied_hz", "probe", "warn",
                 "judge_us", "next_quick_us", "backoff_us", "min_backoff_us", "quick_pending", "established",
                 "failures", "stuck_warned", "drop_seen_us", "drop_seen_arrivals")  # fmt: skip

    def __init__(self, name: str, msg_id: int, stream_id: int, wanted_hz: float, ladder: tuple[float, ...],
                 meter: _Meter, min_backoff_us: int) -> None:  # fmt: skip
        self.name, self.msg_id, self.stream_id = name, msg_id, stream_id
        self.warn = True
        self.meter = meter
        self.min_backoff_us = min_backoff_us
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
        self.requested_us: int | None = None  # when the current accepted rate was asked for (rate changes only)
        self.detail = "not requested yet"
        self.denied_hz: float | None = None
        self.probe = False
        self.reset_quick()

    def reset_quick(self) -> None:
        """Forget the quick re-request state (new rate, restart)."""
        self.judge_us: int | None = None  # quick check: judge the delivered rate from then on
        self.next_quick_us = 0  # no quick re-request before then
        self.backoff_us = self.min_backoff_us
        self.quick_pending = False  # a quick re-request went out and awaits judgement
        self.established = False  # delivered at the accepted rate since it was accepted
        self.failures = 0  # quick re-requests in a row that did not restore the rate
        self.stuck_warned = False
        self.drop_seen_us: int | None = None  # the rate collapsed then: a reset, or a link gone silent?
        self.drop_seen_arrivals = 0  # arrivals of all wanted messages by then

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
        self._drop_grace_us = int(s.drop_grace_s * 1e6)
        self._rerequest_min_us = int(s.rerequest_min_s * 1e6)
        self._foreign_delay_us = int(s.foreign_request_delay_s * 1e6)
        self._drop_window_us = int(s.drop_window_s * 1e6)
        self._rate_window_us = int(s.rate_window_s * 1e6)
        self._wants: dict[str, _Want] = {}
        self._inflight: _Want | None = None
        self._inflight_us = 0
        self._started = False
        self._sched_hint = False
        self._ds_due_us: int | None = None
        self.notices = Notices()
        #: per-message delivered-rate meters (the pipeline adds to them on arrival)
        self.meters: dict[str, _Meter] = {}
        self.commands_sent = 0
        self.data_stream_requests_sent = 0
        self.acks = 0
        #: quick re-requests after a collapse of the delivered rate
        self.rerequests = 0
        #: stream-rate requests by other nodes seen on the link (each answered by a re-request)
        self.foreign_requests = 0

    # ------------------------------------------------------------------ configuration
    def want(
        self, name: str, msg_id: int, rate_hz: float, stream_id: int = MAV_DATA_STREAM_RAW_SENSORS, *, warn_low_rate: bool = True
    ) -> None:
        """Ask for ``name`` at ``rate_hz`` (0 = stop asking; nothing is sent to stop it).

        ``warn_low_rate=False`` for messages that may legitimately not exist
        (a second or third IMU the board does not have): no warning, and no
        quick re-request unless the message did arrive at its rate before.
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
            s = self.settings
            meter = _Meter(s.rate_window_s, s.drop_window_s)
            w = self._wants[name] = _Want(name, msg_id, stream_id, rate_hz, s.ladder_hz, meter, self._rerequest_min_us)
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
                w.reset_quick()
            w.accepted_hz = rate
            w.attempts = 0
            w.detail = f"accepted at {rate:g} Hz"
            w.due_us = now_us + self._interval_us
            w.judge_us = now_us + self._grace_for(rate)  # the new rate takes effect from now
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

    def on_foreign_request(
        self,
        now_us: int,
        *,
        stream_id: int | None = None,
        message_id: int | None = None,
        interval_us: float | None = None,
        sender: str = "another node",
    ) -> bool:
        """Another node asked the autopilot for stream rates; ask again for what it changes.

        Args:
            now_us: the caller's clock.
            stream_id: a REQUEST_DATA_STREAM's ``req_stream_id`` (0 = all
                streams: MAVProxy's ``--streamrate``, ground stations).
            message_id: a SET_MESSAGE_INTERVAL's message id …
            interval_us: … and interval (a request for our own rate changes nothing).
            sender: who sent it, for the notice.

        Returns:
            True when a wanted message is affected (its request is repeated
            ``foreign_request_delay_s`` later, no sooner than the quick
            re-request spacing allows).
        """
        if not (self._started and self.settings.enabled and self.settings.rerequest_on_drop):
            return False
        hit: list[str] = []
        for w in self._wants.values():
            if stream_id is not None:
                affected = stream_id in (0, w.stream_id)  # 0 = MAV_DATA_STREAM_ALL
            else:
                ours = w.accepted_hz if w.accepted_hz is not None else w.rate_hz
                affected = message_id == w.msg_id and (
                    interval_us is None or abs(float(interval_us) - 1e6 / ours) > 1.0
                )
            if not affected:
                continue
            when = max(now_us + self._foreign_delay_us, w.next_quick_us)
            if w.mode == "command" and w.accepted_hz is not None:
                hit.append(w.name)
                if w.due_us is None or when < w.due_us:
                    w.due_us = when
                w.next_quick_us = when + w.backoff_us
            elif w.mode == "data_stream":
                hit.append(w.name)
                if self._ds_due_us is None or when < self._ds_due_us:
                    self._ds_due_us = when
        if hit:
            self.foreign_requests += 1
            what = f"REQUEST_DATA_STREAM({stream_id})" if stream_id is not None else f"SET_MESSAGE_INTERVAL({message_id})"
            self.notices.info(
                "foreign-request",
                f"{sender} sent {what} to the autopilot: requesting {', '.join(hit)} again",
                now_us,
            )
        return bool(hit)

    # ------------------------------------------------------------------ outputs
    def poll(self, now_us: int, heard_us: int | None = None) -> list[SetMessageInterval | RequestDataStream]:
        """Requests due now.

        ``heard_us``: when anything last arrived from the autopilot (µs, the
        caller's clock; None = not known). A SET_MESSAGE_INTERVAL that times
        out while the autopilot sent nothing at all since it went out (it
        rebooted, the radio dropped out, the cable was pulled) is sent again
        without counting as an unanswered try: silence is not the autopilot
        refusing the command, so it does not lead to REQUEST_DATA_STREAM.
        """
        if not self._started or not self.settings.enabled:
            return []
        out: list[SetMessageInterval | RequestDataStream] = []
        w = self._inflight
        if w is not None and now_us - self._inflight_us >= self._timeout_us:
            self._inflight = None
            if heard_us is not None and heard_us < self._inflight_us and not w.probe:
                w.attempts = max(0, w.attempts - 1)  # the link was silent: not an unanswered try
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
        self._check_rates(now_us)  # may make a quick re-request due now
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
        if w.accepted_hz is not None:
            w.judge_us = now_us + self._grace_for(w.accepted_hz)  # (again from the ACK)
        return SetMessageInterval(w.msg_id, w.name, int(round(1e6 / w.rate_hz)), min(conf, 255))

    def _fallback(self, w: _Want, now_us: int, why: str, quiet: bool = False) -> None:
        w.mode = "data_stream"
        w.accepted_hz = None
        w.attempts = 0
        w.requested_us = None
        w.reset_quick()
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
        quick = self.settings.rerequest_on_drop
        for w in self._wants.values():
            if w.mode == "command" and quick:
                if w.accepted_hz is not None:
                    self._check_drop(w, w.accepted_hz, now_us)
            elif w.mode == "command":
                self._check_slow(w, w.accepted_hz, now_us)
            elif w.mode == "data_stream":
                self._check_slow(w, w.wanted_hz, now_us)

    def _arrivals(self) -> int:
        return sum(w.meter.total for w in self._wants.values())

    def _quick_window(self, expected_hz: float) -> bool:
        """Whether a stream at ``expected_hz`` is judged over the quick window (else over the status window)."""
        return expected_hz * self.settings.drop_window_s >= _QUICK_MIN_MESSAGES

    def _grace_for(self, expected_hz: float) -> int:
        """µs after a request before the quick check judges: at least the window it is judged over (refilled)."""
        return self._drop_grace_us if self._quick_window(expected_hz) else max(self._drop_grace_us, self._rate_window_us)

    def _check_drop(self, w: _Want, expected: float, now_us: int) -> None:
        """The quick check: re-request at once when the delivered rate collapsed (with back-off).

        A collapse is acted on only once some wanted message has arrived after
        it: a stream rate reset by another program leaves the link carrying
        messages, slower; a link that falls silent (the autopilot or simulator
        stopped, a cable or radio lost) carries none, and asking it again is
        pointless (the heartbeat timeout reports a lost link).  When messages
        come back after a silence longer than the drop window, the rate is
        judged again once the window has refilled.
        """
        if w.judge_us is None or now_us < w.judge_us:
            return
        # the quick window holds 125 RAW_IMU at 250 Hz but 5 GLOBAL_POSITION_INT at 10 Hz: with 10 % of a
        # lossy radio's datagrams lost, 2 of 5 arriving (a "collapse") happens about once a minute; a slow
        # stream is judged over the status window instead (20 at 10 Hz: the same loss then never trips it)
        fast = self._quick_window(expected)
        got = (w.meter.fast if fast else w.meter.slow).rate(now_us)
        window_us = self._drop_window_us if fast else self._rate_window_us
        if got < self.settings.low_rate_fraction * expected:
            arrivals = self._arrivals()
            if w.drop_seen_us is None:
                w.drop_seen_us, w.drop_seen_arrivals = now_us, arrivals
                return
            if arrivals == w.drop_seen_arrivals:
                return  # nothing arrived since: a silent link, not a rate reset
            silent_us = now_us - w.drop_seen_us
            w.drop_seen_us = None
            if silent_us > window_us:  # back after a silence: judge once the meter has refilled
                w.judge_us = now_us + window_us
                return
        else:
            w.drop_seen_us = None
        if got >= self.settings.low_rate_fraction * expected:
            if w.stuck_warned:
                self.notices.info(f"rate-back:{w.name}", f"{w.name} arrives at {got:.0f} Hz again", now_us)
            w.quick_pending = False
            w.failures = 0
            w.stuck_warned = False
            w.backoff_us = self._rerequest_min_us
            w.established = True
            return
        if not (w.established or w.warn):
            return  # e.g. a second IMU the board does not have: nothing to chase
        if w.quick_pending:  # the last quick re-request did not bring the rate back
            w.quick_pending = False
            w.failures += 1
            w.backoff_us = min(2 * w.backoff_us, self._interval_us)
            if w.failures >= 2 and w.warn and not w.stuck_warned:
                w.stuck_warned = True
                self.notices.warning(
                    f"lowrate:{w.name}",
                    f"{w.name} arrives at {got:.0f} Hz, {expected:g} Hz accepted, and asking again did not help: "
                    "the link (baud rate, radio) may be too slow or lose data, the sender cannot keep up (busy or "
                    "stalled), or another program keeps resetting stream rates; "
                    f"asking again less and less often (down to once every {self.settings.interval_s:g} s)",
                    now_us,
                )
        if now_us < w.next_quick_us:
            return
        if w.failures == 0:
            self.notices.info(f"drop:{w.name}", self._drop_text(w.name, got, expected, window_us), now_us)
        w.quick_pending = True
        w.next_quick_us = now_us + w.backoff_us
        w.due_us = now_us
        w.judge_us = None  # judged again after the re-request is acknowledged
        self.rerequests += 1

    @staticmethod
    def _drop_text(name: str, got_hz: float, expected_hz: float, window_us: int) -> str:
        """What the quick check measured, and the causes it cannot tell apart, neutrally.

        A collapse with messages still arriving is what a stream-rate reset by another program gives
        (MAVProxy's ``--streamrate``), but also a sender that slows down — a simulator or autopilot
        stalled or busy — and a link losing data: the rate alone does not tell them apart.  (A stream
        request from another node that this link carries is said on its own, by
        :meth:`on_foreign_request`, which asks again at once.)
        """
        return (
            f"{name} fell to {got_hz:.0f} Hz over the last {window_us / 1e6:g} s ({expected_hz:g} Hz accepted; "
            "messages still arrive): the sender slowed down (autopilot or simulator busy or stalled), the link "
            "loses data, or another program reset the stream rates; requesting it again"
        )

    def _check_slow(self, w: _Want, expected: float | None, now_us: int) -> None:
        """The slow check (data-stream mode, or quick re-requests off): warn once a minute."""
        if not w.warn or expected is None or w.requested_us is None or now_us - w.requested_us < self._grace_us:
            return
        got = w.meter.rate(now_us)
        if got < self.settings.low_rate_fraction * expected:
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

    def rate_settled(self, name: str, now_us: int) -> bool:
        """Has the rate asked for ``name`` had time to take effect (``rate_grace_s`` after it was set)?

        True when nothing is asked for ``name`` (requests off, not started, not
        wanted): the rate is what the autopilot sends.  False while the request
        is unanswered, and for ``rate_grace_s`` after the accepted rate (or the
        REQUEST_DATA_STREAM fallback) took effect.  Periodic and quick
        re-requests at the same rate do not restart the grace.
        """
        w = self._wants.get(name)
        if w is None or not (self._started and self.settings.enabled):
            return True
        if w.mode == "command" and w.accepted_hz is None:
            return False
        return w.requested_us is not None and now_us - w.requested_us >= self._grace_us
