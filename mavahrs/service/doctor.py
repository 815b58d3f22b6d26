r"""``mavahrs doctor``: what an autopilot link delivers, and what to change to get the IMU rate wanted.

Pure analysis, no I/O and no clock (``now_us`` is passed in; the command's
loop in :mod:`mavahrs.cli.doctor` does the talking): a :class:`LinkObserver`
is fed every decoded message, every request sent and the link's byte count;
:func:`diagnose` turns that into a :class:`DoctorReport`:

* the autopilot (HEARTBEAT: ArduPilot/PX4/…, vehicle type; AUTOPILOT_VERSION:
  firmware version, board ids) and the other components heard;
* each IMU message (RAW_IMU, SCALED_IMU/2/3, HIGHRES_IMU): its rate measured
  on the autopilot's own timestamps after the last rate change, the rate it
  arrives at here, whether its sensors are present (all-zero instances are
  boards without that IMU), the timestamp intervals (ArduPilot stamps RAW_IMU
  with the send time in its scheduler loop, so intervals come in steps of the
  loop period) and the arrival jitter;
* the magnetometer (present? field strength in µT, plausible for the Earth's
  25–65 µT field?), the accelerometer norm at rest;
* MAVLink 2 signing (signed frames seen?), link errors (CRC, lost messages by
  sequence number), the link's load against a serial baud rate;
* **recommendations**, concrete: the parameter and value (SCHED_LOOP_RATE,
  SRn_RAW_SENS / MAVn_RAW_SENS, SERIALn_BAUD, PX4 ``mavlink stream``), the baud
  rate that carries the wanted rate, what resets stream rates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mavahrs.errors import ConfigError

__all__ = [
    "DoctorSettings",
    "LinkFacts",
    "LinkObserver",
    "StreamReport",
    "AutopilotReport",
    "DoctorReport",
    "diagnose",
    "frame_bytes",
    "min_baud_for",
    "ardupilot_min_loop_rate_hz",
    "IMU_MESSAGES",
    "STANDARD_BAUDS",
]

IMU_MESSAGES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
#: serial rates flight controllers and companion computers commonly support, bit/s
STANDARD_BAUDS = (57600, 115200, 230400, 460800, 921600, 1500000, 2000000)
_MAV_AUTOPILOT = {3: "ArduPilot", 12: "PX4", 0: "generic", 8: "none (not an autopilot)"}
_ARDUPILOT, _PX4 = 3, 12
_MAV_TYPE_GCS = 6
_FW_TYPES = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}
_VEHICLE = {  # MAV_TYPE → (vehicle, ArduPilot firmware)
    1: ("fixed wing", "Plane"), 2: ("quadrotor", "Copter"), 3: ("coaxial", "Copter"), 4: ("helicopter", "Copter"),
    10: ("ground rover", "Rover"), 11: ("boat", "Rover"), 12: ("submarine", "Sub"), 13: ("hexarotor", "Copter"),
    14: ("octorotor", "Copter"), 15: ("tricopter", "Copter"), 19: ("VTOL", "Plane"), 20: ("VTOL", "Plane"),
    21: ("VTOL tiltrotor", "Plane"), 29: ("dodecarotor", "Copter"),
}  # fmt: skip
_G = 9.80665
_SIGNED = 0x01  # MAVLINK_IFLAG_SIGNED


def frame_bytes(message: str, signed: bool = False) -> int:
    """Bytes one MAVLink 2 frame of ``message`` takes on the wire (header 10 + payload + CRC 2 [+ signature 13])."""
    from mavahrs.protocol.codec import mavlink

    cls = mavlink.mavlink_map[getattr(mavlink, f"MAVLINK_MSG_ID_{message}")]
    return 10 + int(cls.unpacker.size) + 2 + (13 if signed else 0)


def min_baud_for(bytes_per_s: float) -> int:
    """The smallest standard baud rate whose 8N1 capacity (baud/10 bytes/s) carries ``bytes_per_s`` with 50 % headroom.

    The headroom is for what else shares the link in bursts (parameters, missions, logs, status text).
    """
    for baud in STANDARD_BAUDS:
        if baud / 10.0 >= 1.5 * bytes_per_s:
            return baud
    return STANDARD_BAUDS[-1]


def ardupilot_min_loop_rate_hz(rate_hz: float) -> float:
    """The SCHED_LOOP_RATE at which ArduPilot accepts a message interval for ``rate_hz``.

    ArduPilot keeps intervals in whole milliseconds and refuses (DENIED, "Requested
    rate too fast. Increase SCHED_LOOP_RATE") when ``interval_ms · 800 < loop period in µs``
    (GCS_MAVLINK::cap_message_interval): a message streams at most every 0.8 loop periods.
    """
    interval_ms = max(1, int(1000.0 / rate_hz))
    return 1e6 / (interval_ms * 800.0)


@dataclass(frozen=True)
class DoctorSettings:
    """What the doctor checks against.

    Attributes:
        rate_hz: the IMU rate wanted (what ``mavahrs run --rate`` asks for), Hz.
        request_streams: ask the autopilot for the IMU stream at ``rate_hz`` (as
            ``mavahrs run`` does); False = only watch what arrives.
        settle_s: time after a rate change before rates are measured, s.
        good_fraction: a delivered rate below this fraction of the wanted/accepted
            rate is reported as low.
    """

    rate_hz: float = 400.0
    request_streams: bool = True
    settle_s: float = 1.0
    good_fraction: float = 0.95

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ConfigError(f"doctor: rate must be a positive number of Hz, got {self.rate_hz!r}")
        if not (0 < self.good_fraction <= 1 and self.settle_s >= 0):
            raise ConfigError("doctor: good_fraction must be in (0, 1], settle_s ≥ 0")


@dataclass(frozen=True)
class LinkFacts:
    """What the command loop knows about the link itself.

    Attributes:
        description: the connection string (and peer).
        kind: ``serial``, ``udpin``, ``udpout``, ``tcp``, ``tcpin``, ….
        baud: serial baud rate, bit/s (None for network links).
        bytes_in: bytes received over the run.
        duration_s: how long the doctor listened, s.
        crc_errors / bad_data / seq_gaps: the decoder's counters.
        seq_gaps_by_source: lost messages per (system, component).
    """

    description: str
    kind: str
    baud: int | None
    bytes_in: int
    duration_s: float
    crc_errors: int = 0
    bad_data: int = 0
    seq_gaps: int = 0
    seq_gaps_by_source: Mapping[tuple[int, int], int] = field(default_factory=dict)


class _Series:
    """Arrivals of one IMU message from the autopilot."""

    __slots__ = ("rx_us", "t_us", "acc", "mag", "nonzero_imu", "frame_len", "fields_updated")

    def __init__(self) -> None:
        self.rx_us: list[int] = []
        self.t_us: list[int] = []
        self.acc: list[tuple[float, float, float]] = []
        self.mag: list[tuple[float, float, float]] = []
        self.nonzero_imu = 0
        self.frame_len = 0
        self.fields_updated = 0


class LinkObserver:
    """Collects what arrives (feed every decoded message with :meth:`on_message`)."""

    def __init__(self) -> None:
        self.autopilot: tuple[int, int] | None = None  # (system, component)
        self.heartbeat: Any = None
        self.components: dict[tuple[int, int], tuple[int, int]] = {}  # (sys, comp) → (MAV_TYPE, MAV_AUTOPILOT)
        self.version: Any = None
        self.series: dict[str, _Series] = {}
        self.messages = 0
        self.signed = 0
        self.mavlink1 = 0
        self.statustext: list[str] = []
        self.requests: list[tuple[int, str, float]] = []  # (now_us, message, rate_hz) sent
        self.acks: list[tuple[int, str, float, int]] = []  # (now_us, message, rate_hz, MAV_RESULT)
        self.data_stream_requests = 0
        self.first_us: int | None = None
        self.last_us: int | None = None
        self._pending: list[tuple[str, float]] = []

    # ------------------------------------------------------------------ inputs
    def on_request(self, message: str, rate_hz: float, now_us: int) -> None:
        """We sent SET_MESSAGE_INTERVAL for ``message`` at ``rate_hz``."""
        self.requests.append((now_us, message, rate_hz))
        self._pending.append((message, rate_hz))

    def on_data_stream_request(self, now_us: int) -> None:
        """We sent REQUEST_DATA_STREAM (the fallback)."""
        self.data_stream_requests += 1

    def on_message(self, msg: Any, now_us: int) -> None:
        if self.first_us is None:
            self.first_us = now_us
        self.last_us = now_us
        self.messages += 1
        hdr = msg.get_header()
        if getattr(hdr, "incompat_flags", 0) & _SIGNED:
            self.signed += 1
        buf = msg.get_msgbuf()
        if buf and buf[0] == 0xFE:
            self.mavlink1 += 1
        kind = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT":
            self.components[src] = (int(msg.type), int(msg.autopilot))
            if self.autopilot is None and int(msg.autopilot) != 8:  # not MAV_AUTOPILOT_INVALID
                self.autopilot = src
            if src == self.autopilot:
                self.heartbeat = msg
            return
        if self.autopilot is not None and src != self.autopilot:
            return
        if kind in IMU_MESSAGES:
            self._imu(kind, msg, now_us, len(buf))
        elif kind == "AUTOPILOT_VERSION":
            self.version = msg
        elif kind == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else bytes(msg.text).decode("ascii", "replace")
            self.statustext.append(text.rstrip("\x00"))
        elif kind == "COMMAND_ACK" and int(msg.command) == 511 and self._pending:
            message, rate = self._pending.pop(0)
            self.acks.append((now_us, message, rate, int(msg.result)))

    def _imu(self, kind: str, msg: Any, now_us: int, frame_len: int) -> None:
        s = self.series.get(kind)
        if s is None:
            s = self.series[kind] = _Series()
        t = int(msg.time_usec) if hasattr(msg, "time_usec") else int(msg.time_boot_ms) * 1000
        s.rx_us.append(now_us)
        s.t_us.append(t)
        acc = (float(msg.xacc), float(msg.yacc), float(msg.zacc))
        gyro = (float(msg.xgyro), float(msg.ygyro), float(msg.zgyro))
        s.acc.append(acc)
        s.mag.append((float(msg.xmag), float(msg.ymag), float(msg.zmag)))
        if any(acc) or any(gyro):
            s.nonzero_imu += 1
        s.frame_len = frame_len
        if kind == "HIGHRES_IMU":
            s.fields_updated |= int(msg.fields_updated)


# --------------------------------------------------------------------------- report


@dataclass(frozen=True)
class StreamReport:
    """One IMU message as measured.

    Attributes:
        message: its name.
        count: messages received.
        rate_hz: messages per second of the autopilot's clock, after the last rate change.
        rx_rate_hz: messages per second of this computer's clock over the same span.
        present: accelerometer/gyro not all zero (False: no such sensor on the board).
        interval_ms: (median, SD, min, max) of the timestamp intervals, ms.
        interval_steps_ms: the common interval values (≥ 5 % of intervals each), ms.
        arrival_jitter_ms: (p50, p99) of the arrival delay beyond the fastest message, ms.
        mag_ut: mean magnetic field strength, µT (None: no magnetometer data).
        accel_g: median accelerometer norm, g.
        frame_bytes: bytes per frame on the wire.
        requested_hz / accepted_hz: what we asked for and what the autopilot accepted (None: not asked / refused).
    """

    message: str
    count: int
    rate_hz: float
    rx_rate_hz: float
    present: bool
    interval_ms: tuple[float, float, float, float]
    interval_steps_ms: tuple[float, ...]
    arrival_jitter_ms: tuple[float, float]
    mag_ut: float | None
    accel_g: float | None
    frame_bytes: int
    requested_hz: float | None = None
    accepted_hz: float | None = None


@dataclass(frozen=True)
class AutopilotReport:
    """The autopilot heard on the link."""

    system: int
    component: int
    name: str  # ArduPilot, PX4, generic…
    vehicle: str
    firmware: str | None  # "4.5.7 official" from AUTOPILOT_VERSION, None = not received
    board: str | None


@dataclass
class DoctorReport:
    """Everything :func:`diagnose` found; :meth:`lines` formats it for people."""

    link: LinkFacts
    autopilot: AutopilotReport | None
    others: list[str]
    streams: list[StreamReport]
    primary: str | None
    magnetometer: str
    signing: str
    link_errors: str
    load: str
    notes: list[str]
    recommendations: list[str]

    def stream(self, name: str) -> StreamReport | None:
        return next((s for s in self.streams if s.message == name), None)

    def lines(self) -> list[str]:
        out = [f"link: {self.link.description}"]
        a = self.autopilot
        if a is None:
            out.append("autopilot: none heard (no HEARTBEAT from an autopilot)")
        else:
            fw = a.firmware or "firmware version not reported (no AUTOPILOT_VERSION)"
            out.append(f"autopilot: {a.name}, system {a.system} component {a.component}, {a.vehicle}; {fw}"
                       + (f"; board {a.board}" if a.board else ""))
        for o in self.others:
            out.append(f"also heard: {o}")
        if not self.streams:
            out.append("IMU messages: none received")
        for s in self.streams:
            tag = " (primary)" if s.message == self.primary else ""
            req = ""
            if s.requested_hz is not None:
                req = (f"; asked {s.requested_hz:g} Hz, accepted {s.accepted_hz:g} Hz" if s.accepted_hz is not None
                       else f"; asked {s.requested_hz:g} Hz, not accepted")
            if not s.present:
                out.append(f"  {s.message}{tag}: {s.rate_hz:.1f} Hz, accelerometer and gyro all zero "
                           "(no such IMU on this board)" + req)
                continue
            med, sd, lo, hi = s.interval_ms
            steps = ", ".join(f"{x:g}" for x in s.interval_steps_ms)
            out.append(
                f"  {s.message}{tag}: {s.rate_hz:.1f} Hz ({s.count} messages; arrives at {s.rx_rate_hz:.1f} Hz here)"
                + req
            )
            out.append(
                f"    timestamps: interval median {med:.2f} ms, SD {sd:.2f} ms, {lo:.2f}–{hi:.2f} ms"
                + (f" (steps {steps} ms)" if steps else "")
                + f"; arrival jitter p50 {s.arrival_jitter_ms[0]:.1f} ms, p99 {s.arrival_jitter_ms[1]:.1f} ms"
            )
        out.append(f"magnetometer: {self.magnetometer}")
        out.append(f"signing: {self.signing}")
        out.append(f"link errors: {self.link_errors}")
        out.append(f"link load: {self.load}")
        for n in self.notes:
            out.append(f"note: {n}")
        if self.recommendations:
            out.append("recommendations:")
            out.extend(f"  - {r}" for r in self.recommendations)
        else:
            out.append("recommendations: none, the link delivers what mavahrs needs")
        return out


def _stats(series: _Series, since_us: int) -> tuple[int, float, float, tuple[float, float, float, float],
                                                     tuple[float, ...], tuple[float, float]]:
    rx = np.asarray(series.rx_us, dtype=np.int64)
    t = np.asarray(series.t_us, dtype=np.int64)
    keep = rx >= since_us
    if keep.sum() < 3:  # too few after the last change: use everything
        keep = np.ones_like(keep)
    rx, t = rx[keep], t[keep]
    n = int(rx.size)
    span_t = float(t[-1] - t[0]) * 1e-6 if n > 1 else 0.0
    span_rx = float(rx[-1] - rx[0]) * 1e-6 if n > 1 else 0.0
    rate = (n - 1) / span_t if span_t > 0 else 0.0
    rx_rate = (n - 1) / span_rx if span_rx > 0 else 0.0
    if n < 3:
        return n, rate, rx_rate, (math.nan,) * 4, (), (math.nan, math.nan)  # type: ignore[return-value]
    dt_ms = np.diff(t) / 1000.0
    dt_ms = dt_ms[dt_ms > 0]
    if dt_ms.size == 0:
        return n, rate, rx_rate, (math.nan,) * 4, (), (math.nan, math.nan)  # type: ignore[return-value]
    interval = (float(np.median(dt_ms)), float(np.std(dt_ms)), float(dt_ms.min()), float(dt_ms.max()))
    # interval clusters (values within 0.3 ms of their neighbours): a scheduler loop's steps
    srt = np.sort(dt_ms)
    cuts = np.flatnonzero(np.diff(srt) > 0.3) + 1
    clusters = [c for c in np.split(srt, cuts) if c.size >= 0.05 * srt.size]
    covered = sum(c.size for c in clusters)
    steps: tuple[float, ...] = ()
    if 1 < len(clusters) <= 4 and covered >= 0.9 * srt.size:
        steps = tuple(float(np.round(np.median(c), 1)) for c in clusters)
    delay_ms = (rx - t) / 1000.0
    delay_ms = delay_ms - delay_ms.min()
    jitter = (float(np.percentile(delay_ms, 50)), float(np.percentile(delay_ms, 99)))
    return n, rate, rx_rate, interval, steps, jitter


def _scales(autopilot: int | None, message: str) -> tuple[float, float]:
    """(accel → g, mag → µT) factors of a message's integer/float fields."""
    if message == "HIGHRES_IMU":
        return 1.0 / _G, 100.0  # m/s², gauss
    return 1e-3, 0.1  # mG, mgauss (ArduPilot RAW_IMU, SCALED_IMU*)


def diagnose(obs: LinkObserver, link: LinkFacts, settings: DoctorSettings | None = None) -> DoctorReport:
    """Turn what was observed into a report with concrete recommendations."""
    s = settings or DoctorSettings()
    recs: list[str] = []
    notes: list[str] = []
    ap_id = obs.autopilot
    hb = obs.heartbeat
    autopilot_kind = int(hb.autopilot) if hb is not None else None
    autopilot = None
    if ap_id is not None and hb is not None:
        autopilot = AutopilotReport(
            system=ap_id[0], component=ap_id[1], name=_MAV_AUTOPILOT.get(autopilot_kind or 0, f"MAV_AUTOPILOT {autopilot_kind}"),
            vehicle=_vehicle(int(hb.type), autopilot_kind == _ARDUPILOT),
            firmware=_firmware(obs.version), board=_board(obs.version),
        )  # fmt: skip
    others = [
        _component_text(k, v) for k, v in sorted(obs.components.items()) if k != ap_id
    ]
    is_px4 = autopilot_kind == _PX4
    is_ap = autopilot_kind == _ARDUPILOT
    primary = "HIGHRES_IMU" if is_px4 else "RAW_IMU"

    # when did the primary's rate last change (our accepted request)?
    since = {name: (obs.first_us or 0) for name in IMU_MESSAGES}
    requested: dict[str, float] = {}
    accepted: dict[str, float | None] = {}
    denied: dict[str, list[float]] = {}
    for _t_us, message, rate in obs.requests:
        requested.setdefault(message, rate)
    for t_us, message, rate, result in obs.acks:
        if result == 0:
            accepted[message] = rate
            since[message] = t_us + int(s.settle_s * 1e6)
        elif result == 2:
            denied.setdefault(message, []).append(rate)
            accepted.setdefault(message, None)
        else:
            accepted.setdefault(message, None)

    streams: list[StreamReport] = []
    for name in IMU_MESSAGES:
        ser = obs.series.get(name)
        if ser is None:
            continue
        n, rate, rx_rate, interval, steps, jitter = _stats(ser, since[name])
        acc_k, mag_k = _scales(autopilot_kind, name)
        acc = np.asarray(ser.acc) * acc_k
        mag = np.asarray(ser.mag) * mag_k
        mag_norm = np.linalg.norm(mag, axis=1)
        has_mag = bool(np.any(mag_norm > 0)) and (name != "HIGHRES_IMU" or bool(ser.fields_updated & 0x1C0))
        streams.append(StreamReport(
            message=name, count=len(ser.rx_us), rate_hz=rate, rx_rate_hz=rx_rate, present=ser.nonzero_imu > 0,
            interval_ms=interval, interval_steps_ms=steps, arrival_jitter_ms=jitter,
            mag_ut=float(np.mean(mag_norm[mag_norm > 0])) if has_mag else None,
            accel_g=float(np.median(np.linalg.norm(acc, axis=1))) if ser.nonzero_imu else None,
            frame_bytes=ser.frame_len or frame_bytes(name),
            requested_hz=requested.get(name), accepted_hz=accepted.get(name),
        ))  # fmt: skip

    prim = next((x for x in streams if x.message == primary), None)
    if prim is None:  # an autopilot that sends another IMU message as its main one
        prim = next((x for x in streams if x.present), None)
        if prim is not None:
            primary = prim.message

    # ---------------------------------------------------------------- recommendations
    if ap_id is None:
        recs.append(_no_autopilot_hint(link, obs))
    if obs.autopilot is not None and obs.version is None:
        notes.append("no AUTOPILOT_VERSION answer to MAV_CMD_REQUEST_MESSAGE (old firmware, or commands do not "
                     "reach the autopilot: check that this link can send)")
    wanted = s.rate_hz
    fw_name = "ArduPilot" if is_ap else ("PX4" if is_px4 else "the autopilot")
    deny = denied.get(primary)
    if deny and is_ap:
        loop = ardupilot_min_loop_rate_hz(max(deny))
        got = accepted.get(primary)
        recs.append(
            f"ArduPilot refused {primary} at {max(deny):g} Hz (\"Requested rate too fast. Increase SCHED_LOOP_RATE\"): "
            f"it streams a message at most every 0.8 scheduler loops, in whole milliseconds. Set SCHED_LOOP_RATE to "
            f"at least {math.ceil(loop)} Hz (e.g. 800; the board's CPU must keep up) and reboot"
            + (f"; until then it streams {got:g} Hz." if got else ".")
        )
    elif deny:
        recs.append(f"{fw_name} refused {primary} at {', '.join(f'{d:g}' for d in deny)} Hz.")
    target = accepted.get(primary) or (wanted if s.request_streams else None)
    if prim is not None and prim.present:
        low = prim.rate_hz < s.good_fraction * (target if target else wanted)
        if low:
            recs.extend(_low_rate_hints(prim, primary, wanted, target, s, link, obs, is_ap, is_px4, accepted))
    elif ap_id is not None:
        recs.append(_no_imu_hint(primary, is_ap, is_px4, wanted))

    # magnetometer
    mag_text, mag_recs = _magnetometer(streams, primary, is_ap, is_px4)
    recs.extend(mag_recs)
    # signing
    if obs.messages == 0:
        signing = "nothing received"
    elif obs.signed == 0:
        signing = f"no signed frames among {obs.messages} (the link is not signed)"
    elif obs.signed == obs.messages:
        signing = f"all {obs.messages} frames signed (MAVLink 2 signing is on)"
        recs.append("the autopilot signs its messages: give mavahrs run the same key (daemon.signing_key_path) "
                    "so its commands are accepted when the autopilot requires signed input")
    else:
        signing = f"{obs.signed} of {obs.messages} frames signed"
    gcs_note = _ground_station_note(obs)
    if gcs_note:
        notes.append(gcs_note)
    if obs.mavlink1:
        notes.append(f"{obs.mavlink1} MAVLink 1 frames: the port runs MAVLink 1 (ArduPilot SERIALn_PROTOCOL = 1); "
                     "use 2 (MAVLink 2) for smaller frames and the message extensions")
    # link errors
    total = obs.messages + link.seq_gaps
    loss = 100.0 * link.seq_gaps / total if total else 0.0
    link_errors = f"{link.crc_errors} CRC errors, {link.bad_data} runs of bad bytes, {link.seq_gaps} messages lost ({loss:.2f} %)"
    if link.crc_errors > 0 or loss > 1.0:
        if link.kind == "serial":
            recs.append(f"{link.crc_errors} CRC errors and {loss:.1f} % lost messages on a serial link: check the wiring "
                        "and ground, a shorter cable, and that both ends use the same baud rate"
                        + (" (and that the link is not overloaded, see link load)" if link.baud else ""))
        else:
            recs.append(f"{loss:.1f} % of the messages are lost between the autopilot and here: a radio link or an "
                        "overloaded router in between; put mavahrs on the autopilot's own serial/USB port")
    load = _load(link, obs)
    return DoctorReport(link, autopilot, others, streams, primary, mag_text, signing, link_errors, load, notes, recs)


# --------------------------------------------------------------------------- pieces


def _vehicle(mav_type: int, ardupilot: bool) -> str:
    v = _VEHICLE.get(mav_type)
    if v is None:
        return f"MAV_TYPE {mav_type}"
    return f"{v[0]} (Ardu{v[1]})" if ardupilot else v[0]


def _firmware(version: Any) -> str | None:
    if version is None:
        return None
    v = int(version.flight_sw_version)
    major, minor, patch, kind = v >> 24 & 0xFF, v >> 16 & 0xFF, v >> 8 & 0xFF, v & 0xFF
    return f"firmware {major}.{minor}.{patch} {_FW_TYPES.get(kind, f'type {kind}')}"


def _board(version: Any) -> str | None:
    if version is None:
        return None
    vid, pid = int(version.vendor_id), int(version.product_id)
    if not (vid or pid):
        return None
    return f"USB {vid:04x}:{pid:04x}, uid {int(version.uid):016x}"


def _component_text(src: tuple[int, int], info: tuple[int, int]) -> str:
    mav_type, ap = info
    names = {6: "ground station", 18: "onboard controller", 26: "gimbal", 27: "ADS-B", 30: "camera"}
    what = names.get(mav_type, f"MAV_TYPE {mav_type}")
    extra = " (mavahrs run, or another companion program, is already on this link)" if src[1] == 191 else ""
    return f"system {src[0]} component {src[1]}: {what}{extra}"


def _ground_station_note(obs: LinkObserver) -> str | None:
    """A ground station's HEARTBEAT on the link: which QGroundControl draws mavahrs's attitude on its HUD."""
    gcs = sorted(src for src, (mav_type, _) in obs.components.items() if mav_type == _MAV_TYPE_GCS)
    if not gcs:
        return None
    who = ", ".join(f"system {s} component {c}" for s, c in gcs)
    return (
        f"a ground station is on this link ({who}); its HEARTBEAT does not say which program or version it is. "
        "QGroundControl 4.1 and older draws any component's ATTITUDE_QUATERNION of the vehicle on its HUD: there "
        "mavahrs run's attitude (component 191 of the vehicle) would replace the autopilot's. For such a ground "
        "station run mavahrs with --out-identity separate-vehicle (a vehicle of its own, system 42) or "
        "--out-identity none (QGroundControl 4.2 and later draws only the autopilot's attitude)"
    )


def _no_autopilot_hint(link: LinkFacts, obs: LinkObserver) -> str:
    if link.bytes_in == 0:
        if link.kind == "serial":
            return ("nothing received on the serial port: check the wiring (TX↔RX), the baud rate and that the port "
                    "runs MAVLink (ArduPilot SERIALn_PROTOCOL = 2, PX4 MAV_n_CONFIG)")
        if link.kind == "udpout":
            return "nothing received: nothing answers at that address (for a router, use udpin: and let it send to us)"
        if link.kind == "udpin":
            return (f"nothing received in {link.duration_s:g} s: check that the autopilot, mavlink-router or MAVProxy "
                    f"sends to this address and port ({link.description}; e.g. MAVProxy --out udp:THIS_IP:PORT, "
                    "mavlink-router [UdpEndpoint] Mode = Normal), that no firewall drops it, and that no other "
                    "program already listens on the port")  # fmt: skip
        return "nothing received: is the autopilot or router sending to this address and port?"
    if obs.messages == 0:
        return (f"{link.bytes_in} bytes but no MAVLink frame: wrong baud rate, or the port does not run MAVLink"
                if link.kind == "serial" else f"{link.bytes_in} bytes but no MAVLink frame: is this a MAVLink stream?")
    return "MAVLink messages but no autopilot HEARTBEAT: only ground stations or companions are on this link"


def _no_imu_hint(primary: str, is_ap: bool, is_px4: bool, wanted: float) -> str:
    if is_px4:
        return (f"no {primary} at all: in the PX4 shell (MAVLink console) run `mavlink stream -d /dev/ttyS2 -s "
                f"HIGHRES_IMU -r {wanted:g}` for a serial port (or `-u 14540` for UDP), or let mavahrs run request it")
    if is_ap:
        return (f"no {primary} at all: ArduPilot sends it in the RAW_SENSORS stream: set SRn_RAW_SENS (ArduPilot ≥ 4.7: "
                "MAVn_RAW_SENS) for this port above 0, or let mavahrs run request it with SET_MESSAGE_INTERVAL")
    return f"no IMU message at all: configure the autopilot to stream {primary} (or RAW_IMU/SCALED_IMU) on this port"


def _low_rate_hints(
    prim: StreamReport, primary: str, wanted: float, target: float | None, s: DoctorSettings, link: LinkFacts,
    obs: LinkObserver, is_ap: bool, is_px4: bool, accepted: Mapping[str, float | None],
) -> list[str]:
    out: list[str] = []
    got = prim.rate_hz
    expect = target if target else wanted
    # bandwidth: can this serial link carry the wanted rate?
    need_bps = wanted * prim.frame_bytes
    if link.baud:
        capacity = link.baud / 10.0
        used = link.bytes_in / link.duration_s if link.duration_s > 0 else 0.0
        if need_bps > 0.8 * capacity or used > 0.8 * capacity:
            baud = min_baud_for(need_bps + max(0.0, used - got * prim.frame_bytes))
            port = (f"ArduPilot SERIALn_BAUD = {baud // 1000}" if is_ap else f"PX4 SER_TELn_BAUD = {baud}"
                    if is_px4 else "the autopilot's serial port to that rate")
            out.append(
                f"{link.baud} baud carries at most {capacity / 1000:.1f} kB/s; {wanted:g} Hz {primary} alone needs "
                f"{need_bps / 1000:.1f} kB/s ({prim.frame_bytes} bytes per message) and the link already carries "
                f"{used / 1000:.1f} kB/s: use ≥ {baud} baud (set {port} and mavahrs run --baud {baud})"
            )
    if prim.requested_hz is None:  # we did not ask (doctor --no-request)
        if is_ap:
            out.append(
                f"{primary} arrives at {got:.1f} Hz: that is the RAW_SENSORS stream rate, set by SRn_RAW_SENS "
                f"(ArduPilot ≥ 4.7: MAVn_RAW_SENS) for this port or by a ground station's REQUEST_DATA_STREAM; "
                f"mavahrs run asks for {wanted:g} Hz with MAV_CMD_SET_MESSAGE_INTERVAL (and repeats it every 10 s)"
            )
        elif is_px4:
            out.append(
                f"{primary} arrives at {got:.1f} Hz (the MAVLink instance's mode sets it): mavahrs run asks for "
                f"{wanted:g} Hz with MAV_CMD_SET_MESSAGE_INTERVAL; to make it permanent add `mavlink stream -d "
                f"/dev/ttyS2 -s HIGHRES_IMU -r {wanted:g}` to the SD card's etc/extras.txt (serial port; `-u PORT` for UDP)"
            )
        else:
            out.append(f"{primary} arrives at {got:.1f} Hz: configure the autopilot to send it faster, or let "
                       "mavahrs run request it with MAV_CMD_SET_MESSAGE_INTERVAL")
        return out
    if accepted.get(primary) is None and not out:
        out.append(f"the autopilot did not accept SET_MESSAGE_INTERVAL for {primary}; "
                   + ("set SRn_RAW_SENS / MAVn_RAW_SENS instead" if is_ap else
                      f"run `mavlink stream -d /dev/ttyS2 -s HIGHRES_IMU -r {wanted:g}` in the PX4 shell" if is_px4 else
                      "configure its stream rates"))
        return out
    if not out:
        drop = _rate_drop(obs, primary, expect)
        if drop is not None:
            out.append(
                f"{primary} ran at {expect:g} Hz, then fell to about {drop[1]:.0f} Hz {drop[0]:.1f} s into the check. "
                "Either something else on the link reset the stream rates (MAVProxy --streamrate, Mission Planner or "
                "QGroundControl connecting: start MAVProxy with --streamrate=-1 and set the ground station not to "
                "request streams, or let mavahrs run re-request them, as it does at once), or the sender slowed "
                "down (autopilot or simulator busy or stalled), or the link loses data"
            )
        elif is_px4:
            out.append(
                f"{primary} arrives at {got:.1f} Hz of {expect:g} Hz accepted: PX4 lowers stream rates when the "
                "instance's data-rate budget (MAV_n_RATE, bytes/s) is used up (`mavlink status` shows rate mult < 1): "
                "raise MAV_n_RATE or the baud rate; HIGHRES_IMU also cannot be faster than the IMU integration rate "
                "(IMU_INTEG_RATE)"
            )
        else:
            out.append(
                f"{primary} arrives at {got:.1f} Hz of {expect:g} Hz accepted: the autopilot's CPU or the link "
                "cannot keep up (a radio, a slow USB hub, a busy router); connect mavahrs to the autopilot's own port"
            )
    return out


def _rate_drop(obs: LinkObserver, name: str, expect: float) -> tuple[float, float] | None:
    """(seconds into the run, rate) where the rate fell below half the accepted rate and stayed for ≥ 1 s."""
    ser = obs.series.get(name)
    if ser is None or len(ser.rx_us) < 10 or obs.first_us is None:
        return None
    rx = np.asarray(ser.rx_us, dtype=np.int64)
    start = max((t for t, m, _, r in obs.acks if r == 0 and m == name), default=obs.first_us)
    edges = np.arange(start, rx[-1], 1_000_000)
    if edges.size < 3:
        return None
    counts = np.histogram(rx, bins=edges)[0]
    ok = counts >= 0.8 * expect
    if not ok.any():
        return None
    first_ok = int(np.argmax(ok))
    for k in range(first_ok + 1, counts.size):
        if counts[k] < 0.5 * expect:
            return (float(edges[k] - obs.first_us) * 1e-6, float(counts[k]))
    return None


def _magnetometer(streams: Sequence[StreamReport], primary: str, is_ap: bool, is_px4: bool) -> tuple[str, list[str]]:
    if not any(x.present for x in streams):  # nothing to judge by: say nothing about the compass
        return "unknown: no IMU data received", []
    with_mag = [x for x in streams if x.mag_ut is not None]
    if not with_mag:
        hint = ("COMPASS_ENABLE = 1 and COMPASS_USE = 1 with a calibrated compass" if is_ap else
                "SYS_HAS_MAG = 1 and a calibrated magnetometer" if is_px4 else "a magnetometer")
        return ("absent: the IMU messages carry no magnetic field (all zero)", [
            f"no magnetometer data: the heading (yaw) will drift with the gyro bias (degrees per minute). Enable {hint}, "
            "or accept a drifting heading (inclination is unaffected)"
        ])  # fmt: skip
    parts = []
    recs = []
    for x in with_mag:
        parts.append(f"{x.message} {x.mag_ut:.1f} µT")
    main = next((x for x in with_mag if x.message == primary), with_mag[0])
    b = float(main.mag_ut or 0.0)
    text = "present: |B| " + ", ".join(parts) + " (the Earth's field is 25–65 µT)"
    if b > 100.0:
        recs.append(
            f"the magnetometer in {main.message} reads {b:.0f} µT, more than any place on Earth: a magnet or current "
            "nearby, an uncalibrated compass, or a unit mismatch (RAW_IMU/SCALED_IMU carry milligauss = 0.1 µT, "
            "HIGHRES_IMU gauss = 100 µT); recalibrate the compass and check the mounting"
        )
    elif b < 15.0:
        recs.append(
            f"the magnetometer in {main.message} reads only {b:.1f} µT (the Earth's field is 25–65 µT): a unit "
            "mismatch or a broken/disabled compass; check the compass calibration on the autopilot"
        )
    return text, recs


def _load(link: LinkFacts, obs: LinkObserver) -> str:
    if link.duration_s <= 0:
        return "-"
    bps = link.bytes_in / link.duration_s
    text = f"{bps / 1000:.1f} kB/s received"
    if link.baud:
        cap = link.baud / 10.0
        text += f" of {cap / 1000:.1f} kB/s that {link.baud} baud carries ({100.0 * bps / cap:.0f} %)"
    return text
