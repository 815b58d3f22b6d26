"""GNSS velocity for the filter's ``IN_VEL`` columns: which message, decoded how, and how old.

Three MAVLink messages carry a velocity:

==================  =====================================  ===============================
message             velocity                               fix time stamp
==================  =====================================  ===============================
GLOBAL_POSITION_INT vx, vy, vz (cm/s, true NED) — the      ``time_boot_ms``
                    autopilot EKF's own output; no fix
                    while lat = lon = 0
GPS_RAW_INT         ``vel`` (ground speed, cm/s) along     ``time_usec``: µs since boot
                    ``cog`` (course over ground, cdeg):    (ArduPilot, PX4), or UNIX time
                    (vel·cos cog, vel·sin cog, NaN) — the  (the MAVLink definition allows
                    receiver's own, independent of the     it; told apart by magnitude:
                    EKF; vertical not given (NaN =         then the fix is taken to be
                    unknown, not zero); needs a 3D fix     as old as the sample, age 0)
GPS2_RAW            the same for a second receiver         ``time_usec``, the same
==================  =====================================  ===============================

:class:`VelocitySelector` (pure: the caller's clock is passed in) takes these
messages as they arrive and says which fix to feed, following the
``velocity_source`` setting:

* ``auto`` — GLOBAL_POSITION_INT while it is arriving (a valid fix seen in the
  last :data:`SILENCE_US`), else GPS_RAW_INT, else GPS2_RAW.  The sources are
  never mixed: a lower one is used only once every preferred one has been
  silent for 2 s, so a source is abandoned only after it went silent; a
  preferred source that comes back is taken again from its first fix.  The
  autopilot's profile may change that order
  (:attr:`~mavahrs.sensors.profiles.AutopilotProfile.velocity_order`, given
  with :meth:`VelocitySelector.set_auto_order`): PX4's GLOBAL_POSITION_INT
  velocity is EKF2's output, three times the receiver's error on PX4's SITL
  flight, so on PX4 ``auto`` takes GPS_RAW_INT first (:data:`PX4_AUTO_ORDER`).
* ``global_position_int`` / ``gps_raw_int`` / ``gps2_raw`` — that message only.
* ``none`` — no velocity.

With ``receiver_only`` (the second-opinion monitor's ``receiver_velocity_only``)
``auto`` means GPS_RAW_INT, else GPS2_RAW: an estimate independent of the
autopilot's EKF.

Each fix fed also gives its position (``lat``, ``lon``, ``alt`` of the same message: the receiver's
for GPS_RAW_INT / GPS2_RAW, the autopilot EKF's for GLOBAL_POSITION_INT, as for the velocity), as
NED metres from the first fix fed since the start or the last :meth:`VelocitySelector.reset`, in
the same frame as the velocity (:class:`~mavahrs.sensors.position.PositionOrigin`):
:attr:`VelocitySelector.position_ned` after a fix is returned, for the filter's ``IN_POS``.

A fix whose time stamp equals the last one used from that message is a repeat
and is not fed again (ArduPilot sends each GPS_RAW_INT fix twice at 10 Hz); one
older than it (by less than 2 s: a reordered message) neither.  The row the
fix goes into (the next sample fed) also gets its age, :func:`fix_age_s`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from mavahrs.sensors.geomag import rotate_true_to_magnetic
from mavahrs.sensors.position import PositionOrigin

__all__ = [
    "VELOCITY_SOURCES",
    "SOURCE_MESSAGES",
    "LABELS",
    "SILENCE_US",
    "AUTO_ORDER",
    "PX4_AUTO_ORDER",
    "VelocityFix",
    "VelocitySelector",
    "decode_fix",
    "fix_age_s",
    "source_messages",
]

#: values of the ``velocity_source`` setting
VELOCITY_SOURCES = ("auto", "global_position_int", "gps_raw_int", "gps2_raw", "none")
#: setting value → message, for the named sources
SOURCE_MESSAGES = {"global_position_int": "GLOBAL_POSITION_INT", "gps_raw_int": "GPS_RAW_INT", "gps2_raw": "GPS2_RAW"}
#: the preference order of ``auto``
AUTO_ORDER = ("GLOBAL_POSITION_INT", "GPS_RAW_INT", "GPS2_RAW")
#: … on PX4: the receiver first, EKF2's velocity (GLOBAL_POSITION_INT) when no receiver message arrives
PX4_AUTO_ORDER = ("GPS_RAW_INT", "GLOBAL_POSITION_INT", "GPS2_RAW")
#: ``auto`` with ``receiver_only``: the GNSS receivers' own velocity
RECEIVER_ORDER = ("GPS_RAW_INT", "GPS2_RAW")
#: short names for the status line and the replay header
LABELS = {"GLOBAL_POSITION_INT": "GPI", "GPS_RAW_INT": "GPS_RAW", "GPS2_RAW": "GPS2_RAW"}
#: a source with no valid fix for this long has gone silent, µs of the caller's clock
SILENCE_US = 2_000_000
#: time stamps at least this large are UNIX time (2000-01-01), not time since boot (no boot lasts 30 years)
UNIX_TIME_MIN_US = 946_684_800_000_000
#: a fix older than the last one used by less than this is a reordered message (dropped); by more, a new clock
_REORDER_US = 2_000_000
_UINT16_MAX = 65535
_GPS_FIX_TYPE_3D = 3
_CDEG_TO_RAD = math.pi / 18000.0


def source_messages(source: str, receiver_only: bool = False, auto_order: tuple[str, ...] = AUTO_ORDER) -> tuple[str, ...]:
    """The messages a ``velocity_source`` setting may use, in order of preference.

    ``auto_order``: what ``auto`` means (the autopilot profile's ``velocity_order``).
    """
    if source == "none":
        return ()
    if source == "auto":
        return RECEIVER_ORDER if receiver_only else auto_order
    try:
        return (SOURCE_MESSAGES[source],)
    except KeyError:
        raise ValueError(f"velocity_source must be one of {', '.join(VELOCITY_SOURCES)}, got {source!r}") from None


@dataclass(frozen=True, slots=True)
class VelocityFix:
    """One decoded velocity, true NED.

    Attributes:
        message: the MAVLink message it came from.
        vn_m_s, ve_m_s, vd_m_s: velocity north, east, down, m/s (true north);
            ``vd_m_s`` NaN when the message has no vertical velocity.
        stamp_us: the message's time stamp as sent, µs (duplicate detection).
        fix_time_us: the fix time on the autopilot's boot clock, µs; None when
            its time stamp is on another clock (UNIX time) or absent: the fix
            is then taken to be as old as the sample it is fed with.
        lat_deg, lon_deg, alt_m: the same fix's position (WGS-84 degrees,
            altitude above mean sea level, m; NaN when not given).
    """

    message: str
    vn_m_s: float
    ve_m_s: float
    vd_m_s: float
    stamp_us: int
    fix_time_us: int | None
    lat_deg: float = math.nan
    lon_deg: float = math.nan
    alt_m: float = math.nan


def decode_fix(msg: Any) -> VelocityFix | str:
    """The velocity of a GLOBAL_POSITION_INT / GPS_RAW_INT / GPS2_RAW, or why there is none.

    Returns the fix, or a reason: ``"no_fix"`` (GLOBAL_POSITION_INT at lat =
    lon = 0, or less than a 3D fix), ``"unknown_velocity"`` (ground speed
    UINT16_MAX, or a moving course UINT16_MAX).
    """
    kind = msg.get_type()
    if kind == "GLOBAL_POSITION_INT":
        if msg.lat == 0 and msg.lon == 0:
            return "no_fix"  # autopilots send zeros until they have a position
        t = int(msg.time_boot_ms) * 1000
        return VelocityFix(kind, msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01, t, t, *_lat_lon_alt(msg))
    if msg.fix_type < _GPS_FIX_TYPE_3D:
        return "no_fix"
    vel, cog = int(msg.vel), int(msg.cog)
    if vel == _UINT16_MAX:
        return "unknown_velocity"
    if cog == _UINT16_MAX:
        if vel:
            return "unknown_velocity"  # moving, direction unknown
        cog = 0  # standing still: the vector is zero whatever the course
    speed = vel * 0.01
    c = cog * _CDEG_TO_RAD
    stamp = int(msg.time_usec)
    fix_t = stamp if 0 < stamp < UNIX_TIME_MIN_US else None
    return VelocityFix(kind, speed * math.cos(c), speed * math.sin(c), math.nan, stamp, fix_t, *_lat_lon_alt(msg))


def _lat_lon_alt(msg: Any) -> tuple[float, float, float]:
    """The message's ``lat``, ``lon`` (degE7) and ``alt`` (mm above mean sea level) in degrees and metres
    (NaN for a field the message does not carry)."""
    lat, lon, alt = (getattr(msg, k, None) for k in ("lat", "lon", "alt"))
    if lat is None or lon is None:
        return math.nan, math.nan, math.nan
    return lat * 1e-7, lon * 1e-7, alt * 1e-3 if alt is not None else math.nan


def fix_age_s(sample_t_us: int, fix_time_us: int | None) -> float:
    """``IN_VEL_AGE``: sample time − fix time, s (0 when the fix time is on another clock)."""
    return 0.0 if fix_time_us is None else (sample_t_us - fix_time_us) * 1e-6


@dataclass
class _SourceState:
    last_valid_us: int | None = None  # caller's clock, last valid fix (repeats included): "arriving"
    last_stamp_us: int | None = None  # time stamp of the last fix used
    used: int = 0


@dataclass
class VelocitySelector:
    """Which velocity fix to feed; see the module docstring.

    Args:
        source: the ``velocity_source`` setting.
        receiver_only: ``auto`` uses only the receivers' messages.
        auto_order: the order of preference of ``auto`` (:data:`AUTO_ORDER`; PX4:
            :data:`PX4_AUTO_ORDER`).

    Attributes:
        counters: fixes not fed, by reason (``no_fix``, ``unknown_velocity``,
            ``repeated``, ``reordered``, ``standby`` = a valid fix of a source
            not in use).
        position_ned: the position of the last fix :meth:`offer` returned,
            (north, east, down) m from the first fix fed (the origin), in the
            velocity's frame.
    """

    source: str = "auto"
    receiver_only: bool = False
    auto_order: tuple[str, ...] = AUTO_ORDER
    counters: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.messages = source_messages(self.source, self.receiver_only, self.auto_order)
        self._states = {m: _SourceState() for m in self.messages}
        self.current: str | None = None
        self.switches = 0
        self.origin = PositionOrigin()
        self.position_ned: tuple[float, float, float] = (math.nan, math.nan, math.nan)

    def set_auto_order(self, order: tuple[str, ...]) -> None:
        """What ``auto`` prefers, once the autopilot's profile is known (its ``velocity_order``).

        The sources' states and counts are kept; only the order (and, for ``auto``, the
        messages) change.  No effect on a named source or ``receiver_only``.
        """
        self.auto_order = tuple(order)
        messages = source_messages(self.source, self.receiver_only, self.auto_order)
        self._states = {m: self._states.get(m) or _SourceState() for m in messages}
        self.messages = messages

    def reset(self) -> None:
        """Forget the sources' time stamps (autopilot reboot); the counts stay."""
        for st in self._states.values():
            st.last_valid_us = st.last_stamp_us = None
        self.current = None
        self.origin.reset()

    def used(self, message: str) -> int:
        """Fixes of ``message`` fed so far."""
        st = self._states.get(message)
        return st.used if st is not None else 0

    def in_use(self, now_us: int) -> str | None:
        """The message currently feeding the filter (None: none arriving)."""
        cur = self.current
        if cur is None:
            return None
        last = self._states[cur].last_valid_us
        return cur if last is not None and now_us - last <= SILENCE_US else None

    def offer(self, msg: Any, now_us: int, declination_rad: float | None) -> tuple[VelocityFix, float, float, float] | None:
        """A velocity message arrived at ``now_us``: the fix and (vn, ve, vd) in magnetic NED to feed, or None.

        ``declination_rad``: rotate true north into the filter's magnetic
        frame by this (None: not known yet, fed as it is).
        """
        st = self._states.get(msg.get_type())
        if st is None:
            return None
        fix = decode_fix(msg)
        if isinstance(fix, str):
            self._count(fix)
            return None
        st.last_valid_us = now_us
        if self._preferred(now_us) != fix.message:
            self._count("standby")
            return None
        last = st.last_stamp_us
        if last is not None and fix.stamp_us <= last:
            if fix.stamp_us == last:
                self._count("repeated")
                return None
            if last - fix.stamp_us < _REORDER_US:
                self._count("reordered")
                return None
        if self.current != fix.message:
            if self.current is not None:
                self.switches += 1
            self.current = fix.message
        st.last_stamp_us = fix.stamp_us
        st.used += 1
        vn, ve = fix.vn_m_s, fix.ve_m_s
        if declination_rad is not None:
            vn, ve = rotate_true_to_magnetic(vn, ve, declination_rad)
        self.position_ned = self.origin.ned(fix.lat_deg, fix.lon_deg, fix.alt_m, declination_rad)
        return fix, vn, ve, fix.vd_m_s

    def _preferred(self, now_us: int) -> str | None:
        """The most preferred source with a valid fix within the silence limit."""
        for m in self.messages:
            last = self._states[m].last_valid_us
            if last is not None and now_us - last <= SILENCE_US:
                return m
        return None

    def _count(self, key: str) -> None:
        self.counters[key] = self.counters.get(key, 0) + 1
