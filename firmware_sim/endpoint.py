r"""The flight controller's MAVLink behaviour, sans I/O: requests in, frames out.

One :class:`Endpoint` per link.  ``step()`` runs one scheduler-loop tick and
returns the frames due in it with their send times; ``receive(bytes)``
handles what the peer sent and returns the immediate replies.  No clock is
read here: time is the simulation's tick time.

ArduPilot behaviour modelled (``autopilot="ardupilot"``, the default):

* **Stream scheduling** in the telemetry task: a stream with interval ``T`` is
  due at ``t₀ + n·T`` and goes out in the first pass of the task at or after
  that time, so the average rate is exact while single intervals are whole
  pass periods (at 400 Hz, 250 Hz comes out as 5 ms, 5 ms, 2.5 ms, …).  The
  task runs every loop tick up to ``telemetry_rate_hz`` (400 Hz, ArduCopter's
  ``GCS::update_send``); at a faster ``SCHED_LOOP_RATE`` it runs every few
  ticks, and a stream due more often than that is **sent twice in one pass**:
  the same stamp and values again (ArduCopter at ``SCHED_LOOP_RATE`` 800 asked
  for RAW_IMU at 400 Hz keeps 2 ms and sends one message in five twice;
  the real one, whose passes slip now and then, about one in four).
* ``RAW_IMU.time_usec`` (and ``time_boot_ms`` elsewhere) is the **send time**
  (tick time plus a small, seeded jitter), not the sample time.
* **MAV_CMD_SET_MESSAGE_INTERVAL** (511): ``-1`` stops, ``0`` restores the
  default, other negatives are DENIED; an interval whose whole milliseconds
  satisfy ``interval_ms · 800 < loop_period_us`` is **DENIED** with a STATUSTEXT
  "Requested rate too fast. Increase SCHED_LOOP_RATE" — at the default 400 Hz
  loop the fastest accepted interval is 4 ms (250 Hz), at 800 Hz it is 2 ms.
  An accepted interval is kept in **whole milliseconds** (ArduPilot stores
  ``interval_ms``): 2500 µs (400 Hz) becomes 2000 µs, and reads back so.
* **MAV_CMD_REQUEST_MESSAGE** (512), **MAV_CMD_GET_MESSAGE_INTERVAL** (510),
  **MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES** (520): ACK + the message;
  other commands are ACKed UNSUPPORTED.  COMMAND_LONG and COMMAND_INT.
* **REQUEST_DATA_STREAM** sets the rate of a stream group (RAW_SENSORS:
  RAW_IMU, SCALED_IMU2/3; POSITION: GLOBAL_POSITION_INT; EXTRA1: ATTITUDE,
  SIMSTATE; EXTRA3: SYSTEM_TIME, BATTERY_STATUS; EXTENDED_STATUS: SYS_STATUS;
  ALL); like ArduPilot it sends no ACK.
* Without GNSS (``SimSettings.gnss = False``) GPS_RAW_INT and GLOBAL_POSITION_INT
  may be requested (ACKed) but are never sent.
* Defaults when nothing is requested: HEARTBEAT at 1 Hz and the groups above
  at ``default_stream_hz`` (ArduPilot's ``SRn_*`` parameters; 1 Hz like Plane
  and Rover, Copter's are 0).

``autopilot="px4"``: PX4-like defaults (HIGHRES_IMU 50 Hz, ATTITUDE,
ATTITUDE_QUATERNION …), any interval accepted and capped at the loop rate,
sample-time stamps, no REQUEST_DATA_STREAM.  ``ideal=True``: every tick's
fresh sample, sample-time stamps, no jitter, intervals down to one loop period
(400 Hz at the default loop).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from firmware_sim.encoder import Autopilot, FrameEncoder, WireBlock
from firmware_sim.simulation import Simulation
from mavahrs.protocol.codec import MavCodec, mavlink

__all__ = ["EndpointSettings", "Endpoint", "STREAMABLE", "PRESETS", "DENIED_TEXT", "EPOCH_2025_06_01_US", "GNSS_MESSAGES"]

DENIED_TEXT = "Requested rate too fast. Increase SCHED_LOOP_RATE"
EPOCH_2025_06_01_US = 1748736000 * 1_000_000

#: Messages the simulator can stream, by name → MAVLink id (in per-tick send order).
STREAMABLE: dict[str, int] = {
    "HEARTBEAT": mavlink.MAVLINK_MSG_ID_HEARTBEAT,
    "RAW_IMU": mavlink.MAVLINK_MSG_ID_RAW_IMU,
    "SCALED_IMU": mavlink.MAVLINK_MSG_ID_SCALED_IMU,
    "SCALED_IMU2": mavlink.MAVLINK_MSG_ID_SCALED_IMU2,
    "SCALED_IMU3": mavlink.MAVLINK_MSG_ID_SCALED_IMU3,
    "HIGHRES_IMU": mavlink.MAVLINK_MSG_ID_HIGHRES_IMU,
    "SIMSTATE": mavlink.MAVLINK_MSG_ID_SIMSTATE,
    "SIM_STATE": mavlink.MAVLINK_MSG_ID_SIM_STATE,
    "ATTITUDE": mavlink.MAVLINK_MSG_ID_ATTITUDE,
    "ATTITUDE_QUATERNION": mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    "GLOBAL_POSITION_INT": mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    "SYSTEM_TIME": mavlink.MAVLINK_MSG_ID_SYSTEM_TIME,
    "SYS_STATUS": mavlink.MAVLINK_MSG_ID_SYS_STATUS,
    "BATTERY_STATUS": mavlink.MAVLINK_MSG_ID_BATTERY_STATUS,
    "GPS_RAW_INT": mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,  # only when asked for: see _GpsReceiver
}
_ONE_SHOT_ONLY = {"AUTOPILOT_VERSION": mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION}
_NAME_BY_ID = {v: k for k, v in {**STREAMABLE, **_ONE_SHOT_ONLY}.items()}
# longest MAVLink 2 frame of each message (header 10 + payload + CRC 2), for the link budget
_MAX_FRAME = {name: 12 + mavlink.mavlink_map[mid].unpacker.size for name, mid in STREAMABLE.items()}

# ArduPilot stream groups (REQUEST_DATA_STREAM ids) → messages
_GROUPS: dict[int, tuple[str, ...]] = {
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: ("RAW_IMU", "SCALED_IMU2", "SCALED_IMU3"),
    mavlink.MAV_DATA_STREAM_POSITION: ("GLOBAL_POSITION_INT",),
    mavlink.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE", "SIMSTATE"),
    mavlink.MAV_DATA_STREAM_EXTRA3: ("SYSTEM_TIME", "BATTERY_STATUS"),
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS",),
}
#: GNSS messages, never sent with ``SimSettings.gnss = False``
GNSS_MESSAGES = ("GPS_RAW_INT", "GLOBAL_POSITION_INT")

#: Initial stream rates (Hz) by preset; "ardupilot"/"px4" = what the autopilot
#: sends unasked ("ardupilot" uses ``default_stream_hz`` for its groups),
#: "bench" = a recording setup (IMUs as fast as the autopilot allows, truth with
#: every sample), "none" = HEARTBEAT only.  ``"max"`` = the fastest accepted rate.
PRESETS: dict[str, dict[str, float | str]] = {
    "none": {"HEARTBEAT": 1.0},
    "px4": {
        "HEARTBEAT": 1.0, "HIGHRES_IMU": 50.0, "ATTITUDE": 20.0, "ATTITUDE_QUATERNION": 10.0,
        "GLOBAL_POSITION_INT": 5.0, "SYSTEM_TIME": 1.0, "SYS_STATUS": 1.0, "BATTERY_STATUS": 1.0,
    },
    "bench": {
        "HEARTBEAT": 1.0, "RAW_IMU": "max", "SCALED_IMU2": "max", "SIMSTATE": "max", "SIM_STATE": 10.0,
        "ATTITUDE": 50.0, "GLOBAL_POSITION_INT": 10.0, "SYSTEM_TIME": 1.0, "SYS_STATUS": 10.0,
        "BATTERY_STATUS": 10.0,
    },
}


@dataclass(frozen=True)
class EndpointSettings:
    """How the simulated autopilot talks.

    Attributes:
        autopilot: "ardupilot" or "px4" (HEARTBEAT identity, defaults, rate rules).
        system_id / component_id: our MAVLink ids (autopilot = component 1).
        ideal: idealised stream (sample-time stamps, no jitter, up to the loop rate).
        preset: initial rates: "default" (the autopilot's), "bench", "none".
        default_stream_hz: ArduPilot ``SRn_*`` rate for the default stream groups (Hz).
        streams_hz: extra initial rates by message name (Hz; 0 = off; ``math.inf`` = max),
            applied after the preset and checked like a SET_MESSAGE_INTERVAL.
        send_jitter_us: σ of the half-normal delay of the send time after the tick (µs).
        epoch_unix_us: UNIX time at boot, for SYSTEM_TIME and tlog stamps (µs).
        support_message_interval: False = an old autopilot that ACKs SET_MESSAGE_INTERVAL
            UNSUPPORTED (clients must fall back to REQUEST_DATA_STREAM).
        link_bytes_per_s: link capacity (bytes/s, e.g. baud/10); frames that do not fit are
            deferred to a later tick, as ArduPilot does; None = unlimited.
        telemetry_rate_hz: ArduPilot's telemetry task (``GCS::update_send``, 400 Hz in
            ArduCopter): streams go out in its passes, every loop tick up to this rate and every
            few ticks at a faster loop, where a stream due more often than the task runs is
            sent twice in one pass (an exact duplicate: same stamp, same values).  Not used
            with ``ideal`` or PX4.
        block_ticks: ticks simulated at a time (latency vs. throughput).
    """

    autopilot: str = "ardupilot"
    system_id: int = 1
    component_id: int = 1
    ideal: bool = False
    preset: str = "default"
    default_stream_hz: float = 1.0
    streams_hz: tuple[tuple[str, float], ...] = ()
    send_jitter_us: float = 40.0
    epoch_unix_us: int = EPOCH_2025_06_01_US
    support_message_interval: bool = True
    link_bytes_per_s: float | None = None
    block_ticks: int = 40
    telemetry_rate_hz: float = 400.0

    def __post_init__(self) -> None:
        Autopilot(self.autopilot)
        if not (1 <= self.system_id <= 255 and 0 <= self.component_id <= 255):
            raise ValueError("EndpointSettings: system_id must be 1–255 and component_id 0–255")
        if self.preset not in ("default", "bench", "none"):
            raise ValueError(f"EndpointSettings.preset must be default, bench or none, got {self.preset!r}")
        for name, hz in self.streams_hz:
            if name not in STREAMABLE:
                raise ValueError(f"unknown stream {name!r}; streamable: {', '.join(STREAMABLE)}")
            if not hz >= 0.0:
                raise ValueError(f"stream rate for {name} must be >= 0 Hz, got {hz!r}")
        if self.default_stream_hz < 0.0 or self.send_jitter_us < 0.0 or self.block_ticks < 1:
            raise ValueError("EndpointSettings: default_stream_hz, send_jitter_us must be >= 0, block_ticks >= 1")
        if self.link_bytes_per_s is not None and not self.link_bytes_per_s > 0.0:
            raise ValueError("EndpointSettings.link_bytes_per_s must be > 0 or None")
        if not (math.isfinite(self.telemetry_rate_hz) and self.telemetry_rate_hz > 0.0):
            raise ValueError(f"EndpointSettings.telemetry_rate_hz must be > 0, got {self.telemetry_rate_hz!r}")


@dataclass
class _Stream:
    name: str
    interval_us: int = -1  # -1 = off
    next_due_us: int = 0


class _GpsReceiver:
    """The GNSS receiver behind GPS_RAW_INT, as ArduPilot reports it.

    A fix (the reported velocity as ground speed and course, the position) is
    taken every ``PERIOD_US`` (5 Hz) and reaches the autopilot ``LATENCY_US``
    later; GPS_RAW_INT, streamed at its own rate (10 Hz on ArduPilot), carries
    the latest fix that has arrived, stamped ``time_usec`` = the time the fix
    was taken — so at 10 Hz each fix is sent twice with the same time stamp,
    as ArduCopter SITL does.  :meth:`observe` runs every tick while the stream
    is on.
    """

    PERIOD_US = 200_000
    LATENCY_US = 120_000

    def __init__(self) -> None:
        self._next_us: int | None = None
        self._taken: list[tuple[int, int, int, int, int, int]] = []
        self.fix: tuple[int, int, int, int, int, int] | None = None  # time_usec, lat, lon, alt mm, vel cm/s, cog cdeg

    def observe(self, w: WireBlock, i: int, tick_us: int) -> None:
        if self._next_us is None:
            self._next_us = (tick_us // self.PERIOD_US + 1) * self.PERIOD_US
        if tick_us >= self._next_us:
            vn, ve = w.vel_cm_s[i][0], w.vel_cm_s[i][1]
            cog = int(round(math.degrees(math.atan2(ve, vn)) * 100.0)) % 36000
            self._taken.append((tick_us, w.lat_e7[i], w.lon_e7[i], w.alt_mm[i], int(round(math.hypot(vn, ve))), cog))
            while self._next_us <= tick_us:
                self._next_us += self.PERIOD_US
        while self._taken and self._taken[0][0] + self.LATENCY_US <= tick_us:
            self.fix = self._taken.pop(0)


class Endpoint:
    """A simulated autopilot's MAVLink endpoint on one link (pure protocol logic)."""

    def __init__(self, sim: Simulation, settings: EndpointSettings | None = None) -> None:
        self.sim = sim
        self.settings = s = settings or EndpointSettings()
        self.autopilot = Autopilot(s.autopilot)
        self.codec = MavCodec(s.system_id, s.component_id)
        self.encoder = FrameEncoder(self.codec, self.autopilot)
        self.loop_period_us = 1e6 / sim.settings.loop_rate_hz
        ardupilot = self.autopilot.name == "ardupilot" and not s.ideal
        #: the telemetry task's period (µs): every tick unless the loop is faster than the task (ArduPilot)
        self.pass_period_us = max(self.loop_period_us, 1e6 / s.telemetry_rate_hz) if ardupilot else self.loop_period_us
        self._next_pass_us = 0.0
        self._rng = np.random.default_rng(np.random.SeedSequence([int(sim.settings.seed), 0xE4D]))
        self._streams = {name: _Stream(name) for name in STREAMABLE}
        self._defaults_us: dict[str, int] = {}
        self._block: WireBlock | None = None
        self._k = 0
        self._now_us = sim.tick_time_us(0)
        self._one_shots: list[str] = []
        self._tokens = 0.0
        self.stats: dict[str, Counter[str]] = {
            "received": Counter(), "commands": Counter(), "acks": Counter(), "sent": Counter(), "deferred": Counter(),
            "resent": Counter(),
        }
        self._gps = _GpsReceiver()
        self._produce = self._producers()
        self._init_defaults()

    # ------------------------------------------------------------------ rates
    @property
    def min_interval_us(self) -> int:
        """The shortest interval this autopilot accepts."""
        if self.settings.ideal or self.autopilot.name == "px4":
            return int(math.ceil(self.loop_period_us - 1e-6))
        ms = 1
        while ms * 800 < self.loop_period_us:  # ArduPilot: deny if interval_ms·800 < loop period (µs)
            ms += 1
        return ms * 1000

    def _init_defaults(self) -> None:
        s = self.settings
        if s.preset == "none":
            rates: Mapping[str, float | str] = PRESETS["none"]
        elif s.preset == "bench":
            rates = dict(PRESETS["bench"])
            if self.autopilot.name == "px4":
                rates = {**{k: v for k, v in rates.items() if k not in ("RAW_IMU", "SCALED_IMU2")}, "HIGHRES_IMU": "max"}
        elif self.autopilot.name == "px4":
            rates = PRESETS["px4"]
        else:
            hz = s.default_stream_hz
            rates = {"HEARTBEAT": 1.0}
            for group in _GROUPS.values():
                for name in group:
                    rates[name] = hz
        for name, hz in rates.items():
            self._defaults_us[name] = self._hz_to_interval(hz)
        for name, hz in s.streams_hz:
            self._defaults_us[name] = self._hz_to_interval(math.inf if math.isinf(hz) else hz)
        for name, interval in self._defaults_us.items():
            self._streams[name].interval_us = interval
            self._streams[name].next_due_us = self._now_us

    def _hz_to_interval(self, hz: float | str) -> int:
        if hz == "max" or (isinstance(hz, float) and math.isinf(hz)):
            return self.min_interval_us
        hz = float(hz)
        if hz <= 0.0:
            return -1
        interval = self._effective_interval(int(round(1e6 / hz)))
        return interval if interval > 0 else self.min_interval_us

    def _effective_interval(self, interval_us: int) -> int:
        """The interval actually used for a request, or 0 if it is refused."""
        if self.settings.ideal:
            return interval_us if interval_us >= self.min_interval_us else 0
        if self.autopilot.name == "px4":
            return max(interval_us, self.min_interval_us)
        interval_ms = interval_us // 1000  # ArduPilot keeps whole milliseconds
        if interval_ms * 800 < self.loop_period_us:  # … and checks them against the loop period
            return 0
        return interval_ms * 1000

    def interval_us(self, name: str) -> int:
        """Current interval of a stream (µs; −1 = off)."""
        return self._streams[name].interval_us

    # ------------------------------------------------------------------ time
    @property
    def tick(self) -> int:
        """Index of the next loop tick ``step()`` will run."""
        return self._k

    @property
    def now_us(self) -> int:
        """Time since boot of the last tick run (µs)."""
        return self._now_us

    def next_tick_time_us(self) -> int:
        return self.sim.tick_time_us(self._k)

    def _wire(self) -> tuple[WireBlock, int]:
        b = self._block
        if b is None or self._k >= b.k0 + len(b.t_us):
            b = self._block = WireBlock(self.sim.next_block(self.settings.block_ticks))
        return b, self._k - b.k0

    # ------------------------------------------------------------------ loop
    def step(self) -> list[tuple[int, bytes]]:
        """Run one loop tick; returns ``(send_time_us_since_boot, frame)`` pairs."""
        w, i = self._wire()
        tick_us = w.t_us[i]
        self._now_us = tick_us
        self._k += 1
        s = self.settings
        sample_stamps = s.ideal or self.autopilot.name == "px4"
        delay = 0 if sample_stamps else int(abs(self._rng.normal()) * s.send_jitter_us)
        delay = min(delay, int(self.loop_period_us) - 50) if delay > 0 else 0
        budget = None
        if s.link_bytes_per_s is not None:
            per_tick = s.link_bytes_per_s * self.loop_period_us * 1e-6
            self._tokens = min(self._tokens + per_tick, max(4.0 * per_tick, 600.0))
            budget = self._tokens
        out: list[tuple[int, bytes]] = []
        if self._streams["GPS_RAW_INT"].interval_us > 0:
            self._gps.observe(w, i, tick_us)
        period = self.pass_period_us
        in_pass = period <= self.loop_period_us or tick_us >= self._next_pass_us
        if in_pass and period > self.loop_period_us:
            nxt = self._next_pass_us + period
            self._next_pass_us = nxt if nxt > tick_us else tick_us + period  # (resynchronised after a start-up)
        for name, st in self._streams.items():
            if not in_pass or st.interval_us <= 0 or tick_us < st.next_due_us:
                continue
            if budget is not None and _MAX_FRAME[name] > budget:
                self.stats["deferred"][name] += 1
                continue  # no room on the link (checked before packing, as ArduPilot): retried next tick
            send_us = tick_us + delay + 8 * len(out)
            frame = self._produce[name](w, i, send_us, tick_us)
            if frame is None:
                st.next_due_us += st.interval_us
                continue
            if budget is not None:
                budget -= len(frame)
            out.append((send_us, frame))
            self.stats["sent"][name] += 1
            st.next_due_us += st.interval_us
            if st.next_due_us <= tick_us and st.interval_us < period:
                # due again within this pass (interval shorter than the task's period): ArduPilot sends it
                # again at once — the same stamp and the same sample, a new sequence number
                again = self._produce[name](w, i, send_us, tick_us)
                if again is not None and (budget is None or len(again) <= budget):
                    if budget is not None:
                        budget -= len(again)
                    out.append((send_us, again))
                    self.stats["sent"][name] += 1
                    self.stats["resent"][name] += 1
                    st.next_due_us += st.interval_us
            if st.next_due_us <= tick_us:  # fell behind (e.g. link full): resynchronise
                st.next_due_us = tick_us + st.interval_us
        for name in self._one_shots:
            frame = self._produce[name](w, i, tick_us + delay + 8 * len(out), tick_us)
            if frame is not None:
                out.append((tick_us + delay + 8 * len(out), frame))
                self.stats["sent"][name] += 1
        self._one_shots.clear()
        if budget is not None:
            self._tokens = budget
        return out

    def _producers(self) -> dict[str, Callable[[WireBlock, int, int, int], bytes | None]]:
        """name → f(wire block, row, send_us, tick_us) → frame (None = nothing to send)."""
        enc = self.encoder
        sample_stamps = self.settings.ideal or self.autopilot.name == "px4"

        def stamp(send_us: int, tick_us: int) -> int:
            return tick_us if sample_stamps else send_us

        def heartbeat(w: WireBlock, i: int, send_us: int, tick_us: int) -> bytes:
            flying = bool(w.blk.truth.thrust_m_s2[i] > 0.0)
            return enc.heartbeat(armed=flying, flying=flying)

        capacity = self.sim.settings.current.capacity_mah

        def remaining(w: WireBlock, i: int) -> int:
            return int(max(0.0, min(100.0, 100.0 * (1.0 - w.consumed_mah[i] / capacity))))

        gnss = self.sim.settings.gnss

        def gnss_only(f: Callable[[WireBlock, int, int, int], bytes | None]) -> Callable[[WireBlock, int, int, int], bytes | None]:
            # no receiver: the stream may be requested (and is ACKed) but nothing goes out
            return f if gnss else (lambda w, i, s, t: None)

        return {
            "HEARTBEAT": heartbeat,
            "RAW_IMU": lambda w, i, s, t: enc.raw_imu(w, i, stamp(s, t)),
            "SCALED_IMU": lambda w, i, s, t: enc.scaled_imu(0, w, i, stamp(s, t)),
            "SCALED_IMU2": lambda w, i, s, t: enc.scaled_imu(1, w, i, stamp(s, t)),
            "SCALED_IMU3": lambda w, i, s, t: enc.scaled_imu(2, w, i, stamp(s, t)),
            "HIGHRES_IMU": lambda w, i, s, t: enc.highres_imu(w, i, t),
            "SIMSTATE": lambda w, i, s, t: enc.simstate(w, i),
            "SIM_STATE": lambda w, i, s, t: enc.sim_state(w, i),
            "ATTITUDE": lambda w, i, s, t: enc.attitude(w, i, stamp(s, t)),
            "ATTITUDE_QUATERNION": lambda w, i, s, t: enc.attitude_quaternion(w, i, stamp(s, t)),
            "GLOBAL_POSITION_INT": gnss_only(lambda w, i, s, t: enc.global_position_int(w, i, stamp(s, t))),
            "SYSTEM_TIME": lambda w, i, s, t: enc.system_time(w, i, s, self.settings.epoch_unix_us),
            "SYS_STATUS": lambda w, i, s, t: enc.sys_status(w, i, remaining(w, i), gnss),
            "BATTERY_STATUS": lambda w, i, s, t: enc.battery_status(w, i, remaining(w, i)),
            "GPS_RAW_INT": gnss_only(lambda w, i, s, t: enc.gps_raw_int(*self._gps.fix) if self._gps.fix else None),
            "AUTOPILOT_VERSION": lambda w, i, s, t: enc.autopilot_version(self.settings.system_id),
        }

    # ------------------------------------------------------------------ input
    def receive(self, data: bytes, *, datagram: bool) -> list[bytes]:
        """Handle bytes from the peer; returns the frames to send back at once."""
        msgs = self.codec.receive_datagram(data) if datagram else self.codec.receive_stream(data)
        out: list[bytes] = []
        for msg in msgs:
            out.extend(self.handle(msg))
        return out

    def handle(self, msg: Any) -> list[bytes]:
        """Handle one decoded message; returns immediate replies."""
        kind = msg.get_type()
        self.stats["received"][kind] += 1
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            if not self._for_us(msg.target_system, msg.target_component):
                return []
            return self._command(msg)
        if kind == "REQUEST_DATA_STREAM":
            if self.autopilot.name == "ardupilot" and self._for_us(msg.target_system, msg.target_component):
                self._request_data_stream(msg)
            return []
        return []

    def _for_us(self, system: int, component: int) -> bool:
        s = self.settings
        return system in (0, s.system_id) and component in (0, s.component_id)

    def _ack(self, msg: Any, result: int) -> bytes:
        self.stats["acks"][_RESULT_NAMES.get(result, str(result))] += 1
        hdr = msg.get_header()
        return self.encoder.command_ack(msg.command, result, hdr.srcSystem, hdr.srcComponent)

    def _command(self, msg: Any) -> list[bytes]:
        cmd = int(msg.command)
        self.stats["commands"][_COMMAND_NAMES.get(cmd, str(cmd))] += 1
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_message_interval(msg)
        if cmd == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL:
            name = _NAME_BY_ID.get(int(msg.param1))
            if name is None or name not in self._streams:
                return [self._ack(msg, mavlink.MAV_RESULT_DENIED)]
            iv = self._streams[name].interval_us
            return [self._ack(msg, mavlink.MAV_RESULT_ACCEPTED), self.encoder.message_interval(STREAMABLE[name], iv)]
        if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
            name = _NAME_BY_ID.get(int(msg.param1))
            if name is None:
                return [self._ack(msg, mavlink.MAV_RESULT_FAILED)]
            self._one_shots.append(name)
            return [self._ack(msg, mavlink.MAV_RESULT_ACCEPTED)]
        if cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return [self._ack(msg, mavlink.MAV_RESULT_ACCEPTED), self.encoder.autopilot_version(self.settings.system_id)]
        return [self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)]

    def _set_message_interval(self, msg: Any) -> list[bytes]:
        if not self.settings.support_message_interval:
            return [self._ack(msg, mavlink.MAV_RESULT_UNSUPPORTED)]
        name = _NAME_BY_ID.get(int(msg.param1))
        if name is None or name not in self._streams:
            text = f"No ap_message for mavlink id ({int(msg.param1)})"
            return [self._ack(msg, mavlink.MAV_RESULT_DENIED), self.encoder.statustext(mavlink.MAV_SEVERITY_INFO, text)]
        requested = int(msg.param2)
        st = self._streams[name]
        if requested == -1:
            st.interval_us = -1
        elif requested == 0:
            st.interval_us = self._defaults_us.get(name, -1)
            st.next_due_us = self._now_us
        elif requested < -1:
            return [self._ack(msg, mavlink.MAV_RESULT_DENIED)]
        else:
            interval = self._effective_interval(requested)
            if interval == 0:
                return [
                    self._ack(msg, mavlink.MAV_RESULT_DENIED),
                    self.encoder.statustext(mavlink.MAV_SEVERITY_WARNING, DENIED_TEXT),
                ]
            if interval != st.interval_us:
                st.interval_us = interval
                st.next_due_us = self._now_us
        return [self._ack(msg, mavlink.MAV_RESULT_ACCEPTED)]

    def _request_data_stream(self, msg: Any) -> None:
        sid = int(msg.req_stream_id)
        rate = int(msg.req_message_rate) if msg.start_stop else 0
        groups = list(_GROUPS.values()) if sid == mavlink.MAV_DATA_STREAM_ALL else [_GROUPS.get(sid, ())]
        for group in groups:
            for name in group:
                st = self._streams[name]
                if rate <= 0:
                    st.interval_us = -1
                    continue
                interval_ms = max(1000 // rate, 1)
                st.interval_us = max(interval_ms * 1000, self.min_interval_us)
                st.next_due_us = self._now_us

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict[str, Any]:
        """Counters for tools and tests: what was received, commanded, ACKed, sent."""
        return {
            "ticks": self._k,
            "sim_time_s": self._k / self.sim.settings.loop_rate_hz,
            **{k: dict(v) for k, v in self.stats.items()},
            "intervals_us": {n: st.interval_us for n, st in self._streams.items() if st.interval_us > 0},
            "codec": {
                "packets_in": self.codec.counters.packets,
                "crc_errors": self.codec.counters.crc_errors,
                "bad_data": self.codec.counters.bad_data,
            },
        }


def _enum_names(enum: str) -> dict[int, str]:
    return {k: v.name for k, v in mavlink.enums[enum].items() if not v.name.endswith("_ENUM_END")}


_RESULT_NAMES = _enum_names("MAV_RESULT")
_COMMAND_NAMES = _enum_names("MAV_CMD")
