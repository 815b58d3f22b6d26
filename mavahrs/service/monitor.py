r"""A second opinion on the autopilot's attitude.

mavahrs estimates the attitude independently of the autopilot's own estimator
(ArduPilot's EKF, PX4's EKF2).  When the two disagree for a while, one of them
is wrong — an estimator divergence, a failing IMU or magnetometer — and that is
what a pilot wants to hear.  :class:`AttitudeMonitor` (pure: time is passed in,
no I/O) compares them:

* our estimates come in with :meth:`AttitudeMonitor.add_estimate`
  (``time_boot_ms`` of the IMU sample they were computed from, and the
  ``q_body_to_ned`` *as published*, i.e. after the declination correction);
* the autopilot's ATTITUDE (Euler roll/pitch/yaw) or ATTITUDE_QUATERNION come in
  with :meth:`AttitudeMonitor.handle`; each is aligned with our estimates by
  ``time_boot_ms`` (both are the autopilot's boot clock) — interpolated
  between the two estimates around it, or the nearest one within
  ``align_tolerance_ms``;
* the divergence is the earth-frame error ``e = q_ours ⊗ q_autopilot*`` split
  as in BROAD (Laidig et al. 2021): tilt ``2·acos√(e_w² + e_z²)`` and heading
  ``2·atan(e_z/e_w)`` (signed, degrees);
* :meth:`AttitudeMonitor.tick` publishes both as NAMED_VALUE_FLOAT
  (``AHRS_TILT``, ``AHRS_HDG``) at ``rate_hz``;
* a STATUSTEXT at WARNING severity is raised once per episode when the
  divergence stays above its threshold for ``trigger_s`` (autopilot time), and
  one at INFO when it has stayed below ``clear_fraction`` × threshold for
  ``clear_s`` (hysteresis).

The methods return pymavlink message objects; the caller (the pipeline)
encodes them with its codec.  :func:`divergence_series` is the same
computation on whole arrays, for replay plots, and :func:`monitor_series`
runs the monitor's state machine over arrays and lists its warnings.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.geometry.quaternion import slerp
from mavahrs.protocol.codec import mavlink

__all__ = [
    "MonitorSettings",
    "MonitorStatus",
    "AttitudeMonitor",
    "MonitorEvent",
    "MonitorSeries",
    "divergence_series",
    "align_attitudes",
    "monitor_series",
    "attitude_of_message",
    "attitude_divergence_rad",
    "WARNING_TEXT",
    "CLEARED_TEXT",
]

Array = NDArray[np.float64]

#: STATUSTEXT raised when the divergence has lasted ``trigger_s`` (formatted with the values, ≤ 50 chars).
WARNING_TEXT = "mavahrs: AP attitude differs: tilt {tilt:.0f} hdg {heading:.0f} deg"
#: STATUSTEXT sent when it has cleared.
CLEARED_TEXT = "mavahrs: AP attitude agrees again"

_STATUSTEXT_MAX = 50
_NAME_MAX = 10
_REBOOT_MS = 1000.0  # time going back by more than this = autopilot reboot
_MAX_PENDING = 64
_INTERVALS = 7  # autopilot attitude intervals kept for the typical one (median)


@dataclass(frozen=True)
class MonitorSettings:
    """How the autopilot's attitude is compared and when to complain.

    Attributes:
        enabled: compare at all.
        rate_hz: NAMED_VALUE_FLOAT publication rate, Hz (1–5; 0 = do not publish).
        tilt_threshold_deg: tilt divergence that counts as a disagreement, deg.
            Good estimators agree within 2–3° in normal flight; mavahrs's
            inclination error in aggressive flight is ≤ 3° (≤ 6° without GNSS).
        heading_threshold_deg: heading divergence that counts, deg (0 = never
            alarm on heading).  Magnetometer trouble gives 5–15°.
        trigger_s: the divergence must last this long (continuously, in the
            autopilot's time) before the WARNING, s.
        clear_s: it must stay below ``clear_fraction`` × threshold this long
            before the INFO "agrees again", s.
        clear_fraction: hysteresis factor on the thresholds for clearing.
        startup_grace_s: comparisons in the first seconds after our first
            estimate (or a :meth:`AttitudeMonitor.reset`) are published but do
            not count: both estimators may still be converging, s.
        align_tolerance_ms: the autopilot's sample is compared with our
            estimate at the same time: interpolated when our estimates around
            it are at most 2× this apart, else the nearest one within this, ms.
        max_gap_s: comparisons further apart than this — or than
            ``gap_intervals`` × the autopilot's typical attitude interval,
            whichever is longer — break "continuously", s.  (ATTITUDE at 1 Hz,
            as a ground station's stream rate may leave it, arrives every
            1.000 ± 0.003 s: a fixed 1 s would break every other step.)
        gap_intervals: see ``max_gap_s``; the typical interval is the median of
            the last few intervals between the autopilot's attitudes.
        history_s: how much of our estimate history is kept for alignment, s.
        autopilot_component_id: only attitudes from this component are
            compared (1 = MAV_COMP_ID_AUTOPILOT1; 0 = any).
        tilt_name: NAMED_VALUE_FLOAT name for the tilt divergence (≤ 10 chars).
        heading_name: NAMED_VALUE_FLOAT name for the heading divergence.
        receiver_velocity_only: judge the autopilot with an estimate aided
            only by the GNSS receiver's own velocity (GPS_RAW_INT, GPS2_RAW),
            never by GLOBAL_POSITION_INT, which is the autopilot EKF's output:
            the estimate the monitor judges is the pipeline's own, so this
            makes the pipeline's ``velocity_source = auto`` use GPS_RAW_INT,
            else GPS2_RAW (and rejects ``global_position_int``).  The
            published attitude is then receiver-aided as well.
    """

    enabled: bool = True
    rate_hz: float = 2.0
    tilt_threshold_deg: float = 10.0
    heading_threshold_deg: float = 25.0
    trigger_s: float = 2.0
    clear_s: float = 5.0
    clear_fraction: float = 0.7
    startup_grace_s: float = 10.0
    align_tolerance_ms: float = 50.0
    max_gap_s: float = 1.0
    gap_intervals: float = 2.5
    history_s: float = 2.0
    autopilot_component_id: int = 1
    tilt_name: str = "AHRS_TILT"
    heading_name: str = "AHRS_HDG"
    receiver_velocity_only: bool = False

    def __post_init__(self) -> None:
        if not (self.rate_hz == 0.0 or 1.0 <= self.rate_hz <= 5.0):
            raise ValueError(f"monitor rate_hz must be 1–5 Hz (or 0 = off), got {self.rate_hz!r}")
        for name in ("tilt_threshold_deg", "heading_threshold_deg", "trigger_s", "clear_s", "startup_grace_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"monitor setting {name} must be ≥ 0, got {v!r}")
        if not self.tilt_threshold_deg > 0:
            raise ValueError("monitor tilt_threshold_deg must be > 0")
        if not 0.0 < self.clear_fraction <= 1.0:
            raise ValueError(f"monitor clear_fraction must be in (0, 1], got {self.clear_fraction!r}")
        for name in ("align_tolerance_ms", "max_gap_s", "history_s", "gap_intervals"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"monitor setting {name} must be > 0, got {v!r}")
        for name in ("tilt_name", "heading_name"):
            v = getattr(self, name)
            if not 0 < len(v.encode()) <= _NAME_MAX:
                raise ValueError(f"monitor {name} {v!r} must be 1–{_NAME_MAX} bytes (NAMED_VALUE_FLOAT.name)")


@dataclass(frozen=True)
class MonitorStatus:
    """The monitor's state, for the status line.

    Attributes:
        tilt_deg: latest tilt divergence, deg (NaN before the first comparison).
        heading_deg: latest heading divergence, deg, signed.
        warning: a disagreement episode is active.
        comparisons: comparisons made.
        unmatched: autopilot attitudes with no estimate of ours near their time.
        episodes: warnings raised so far.
        velocity_source: the GNSS velocity aiding the estimate judged (the
            status line's short name: ``GPI``, ``GPS_RAW``, ``GPS2_RAW``,
            ``none``); "" = not told.
    """

    tilt_deg: float
    heading_deg: float
    warning: bool
    comparisons: int
    unmatched: int
    episodes: int
    velocity_source: str = ""

    def text(self) -> str:
        """E.g. ``AP cmp: tilt 0.8° hdg +1.2° (vel GPS_RAW)``: the divergence, and the velocity our side used."""
        if self.comparisons == 0:
            return "AP cmp: none"
        flag = " WARN" if self.warning else ""
        vel = f" (vel {self.velocity_source})" if self.velocity_source else ""
        return f"AP cmp: tilt {self.tilt_deg:.1f}° hdg {self.heading_deg:+.1f}°{flag}{vel}"


# --------------------------------------------------------------------------- scalar maths


def _euler_to_q(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Aerospace Z-Y-X Euler angles (rad) → q_body_to_ned."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )


def _divergence(a: Sequence[float], b: Sequence[float]) -> tuple[float, float]:
    """(tilt, heading) in rad of e = a ⊗ b*; heading signed (−π, π]."""
    na = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + a[3] * a[3])
    nb = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3])
    w = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]) / (na * nb)
    z = (-a[0] * b[3] - a[1] * b[2] + a[2] * b[1] + a[3] * b[0]) / (na * nb)
    if w < 0.0:
        w, z = -w, -z
    tilt = 2.0 * math.acos(min(1.0, math.sqrt(w * w + z * z)))
    heading = 2.0 * math.atan2(z, w)
    return tilt, heading


def attitude_divergence_rad(a: Sequence[float], b: Sequence[float]) -> tuple[float, float]:
    """(tilt, heading) of ``a`` relative to ``b`` (both ``q_body_to_ned``), rad; heading signed (−π, π]."""
    return _divergence(a, b)


def _nlerp(a: Sequence[float], b: Sequence[float], f: float) -> tuple[float, float, float, float]:
    """Normalised linear interpolation (slerp to < 0.1 % for the few-ms gaps here)."""
    if a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] < 0.0:
        b = (-b[0], -b[1], -b[2], -b[3])
    q = [a[i] + (b[i] - a[i]) * f for i in range(4)]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q[0] / n, q[1] / n, q[2] / n, q[3] / n


def attitude_of_message(msg: Any) -> tuple[float, tuple[float, float, float, float]] | None:
    """``(time_boot_ms, q_body_to_ned)`` of an ATTITUDE or ATTITUDE_QUATERNION; None otherwise.

    ATTITUDE_QUATERNION's ``repr_offset_q`` (a display offset for tailsitters)
    is ignored: ``q1..q4`` is the attitude of the autopilot's body frame.
    """
    kind = msg.get_type()
    if kind == "ATTITUDE":
        q = _euler_to_q(msg.roll, msg.pitch, msg.yaw)
    elif kind == "ATTITUDE_QUATERNION":
        q = (msg.q1, msg.q2, msg.q3, msg.q4)
    else:
        return None
    if not all(math.isfinite(v) for v in q) or (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]) < 0.25:
        return None
    return float(msg.time_boot_ms), q


# --------------------------------------------------------------------------- monitor


class AttitudeMonitor:
    """Compares our attitude with the autopilot's; see the module docstring.

    Per our estimate :meth:`add_estimate` costs an append (plus an alignment
    when an autopilot attitude is waiting for it); comparisons happen at the
    autopilot's ATTITUDE rate.
    """

    def __init__(self, settings: MonitorSettings | None = None) -> None:
        self.settings = settings if settings is not None else MonitorSettings()
        s = self.settings
        self._tilt_thr = math.radians(s.tilt_threshold_deg)
        self._hdg_thr = math.radians(s.heading_threshold_deg)
        self._tol_ms = s.align_tolerance_ms
        self._history_ms = 1000.0 * s.history_s
        self._period_us = int(round(1e6 / s.rate_hz)) if s.rate_hz > 0 else 0
        self._max_gap_ms = 1000.0 * s.max_gap_s
        self._tilt_name = s.tilt_name.encode()
        self._heading_name = s.heading_name.encode()
        #: when False (declination unknown, or no magnetometer), heading is published but never alarmed
        self.heading_valid = True
        #: the GNSS velocity aiding our estimate, as the owner (the pipeline) tells it; shown in the status
        self.velocity_source = ""
        self._comparisons = 0
        self._unmatched = 0
        self._episodes = 0
        self._next_publish_us: int | None = None
        self._quaternion_source = False
        self.reset()

    def reset(self) -> None:
        """Forget the alignment history and timers (e.g. after our filter re-initialised)."""
        self._estimates: deque[tuple[float, tuple[float, float, float, float]]] = deque()
        self._pending: deque[tuple[float, tuple[float, float, float, float]]] = deque()
        self._first_est_ms: float | None = None
        self._last_att_ms: float | None = None
        self._att_intervals: deque[float] = deque(maxlen=_INTERVALS)
        self._last_cmp_ms: float | None = None
        self._above_since_ms: float | None = None
        self._below_since_ms: float | None = None
        self._warning = False
        self._tilt = math.nan
        self._heading = math.nan
        self._fresh = False  # a comparison since the last publication

    # ------------------------------------------------------------------ inputs
    def add_estimate(self, t_boot_ms: float, q_body_to_ned: Sequence[float]) -> list[Any]:
        """Our published attitude at ``t_boot_ms``; returns STATUSTEXTs this resolves (usually none)."""
        if not self.settings.enabled:
            return []
        est = self._estimates
        t = float(t_boot_ms)
        if est and t < est[-1][0]:
            if t < est[-1][0] - _REBOOT_MS:
                self._restart()
            else:
                return []  # out of order: ignore
        q = (float(q_body_to_ned[0]), float(q_body_to_ned[1]), float(q_body_to_ned[2]), float(q_body_to_ned[3]))
        est.append((t, q))
        if self._first_est_ms is None:
            self._first_est_ms = t
        horizon = t - self._history_ms
        while est[0][0] < horizon:
            est.popleft()
        if self._pending and self._pending[0][0] <= t:
            return self._resolve()
        return []

    def handle(self, msg: Any, now_us: int) -> list[Any]:
        """An autopilot ATTITUDE / ATTITUDE_QUATERNION (others ignored); returns STATUSTEXTs."""
        if not self.settings.enabled:
            return []
        kind = msg.get_type()
        if kind not in ("ATTITUDE", "ATTITUDE_QUATERNION"):
            return []
        comp = self.settings.autopilot_component_id
        if comp and getattr(msg, "get_srcComponent", None) is not None and msg.get_srcComponent() != comp:
            return []
        if kind == "ATTITUDE_QUATERNION":
            self._quaternion_source = True
        elif self._quaternion_source:
            return []  # the same attitude twice: use the quaternion
        att = attitude_of_message(msg)
        if att is None:
            return []
        return self.add_autopilot(*att)

    def add_autopilot(self, t_boot_ms: float, q_body_to_ned: Sequence[float]) -> list[Any]:
        """The autopilot's attitude at ``t_boot_ms`` (what :meth:`handle` extracts); returns STATUSTEXTs."""
        if not self.settings.enabled:
            return []
        t = float(t_boot_ms)
        last = self._last_att_ms
        if last is not None and t < last - _REBOOT_MS:
            self._restart()
        elif last is not None and t > last:
            self._att_intervals.append(t - last)
        self._last_att_ms = t
        q = (float(q_body_to_ned[0]), float(q_body_to_ned[1]), float(q_body_to_ned[2]), float(q_body_to_ned[3]))
        self._pending.append((t, q))
        if len(self._pending) > _MAX_PENDING:  # our estimates stopped: drop the oldest
            self._pending.popleft()
            self._unmatched += 1
        return self._resolve()

    def tick(self, now_us: int) -> list[Any]:
        """NAMED_VALUE_FLOATs when due (``rate_hz``, only with a fresh comparison)."""
        if not (self.settings.enabled and self._period_us):
            return []
        nxt = self._next_publish_us
        if nxt is not None and now_us < nxt:
            return []
        if not self._fresh:
            return []
        self._fresh = False
        # Keep the cadence without bursts after a pause.
        self._next_publish_us = now_us + self._period_us if nxt is None or now_us - nxt > self._period_us else nxt + self._period_us
        t_ms = int(self._last_cmp_ms or 0) & 0xFFFFFFFF
        return [
            mavlink.MAVLink_named_value_float_message(t_ms, self._tilt_name, math.degrees(self._tilt)),
            mavlink.MAVLink_named_value_float_message(t_ms, self._heading_name, math.degrees(self._heading)),
        ]

    # ------------------------------------------------------------------ internals
    def _restart(self) -> None:
        warning, episodes = self._warning, self._episodes
        self.reset()
        self._warning, self._episodes = warning, episodes  # an episode outlives a reboot

    def _resolve(self) -> list[Any]:
        out: list[Any] = []
        est = self._estimates
        pending = self._pending
        while pending:
            t_a, q_a = pending[0]
            if not est or t_a > est[-1][0]:
                break  # wait for our estimate of that time
            pending.popleft()
            q_e = self._align(t_a)
            if q_e is None:
                self._unmatched += 1
                continue
            out.extend(self._compare(t_a, q_e, q_a))
        return out

    def _align(self, t: float) -> tuple[float, float, float, float] | None:
        est = self._estimates
        tol = self._tol_ms
        # Search backwards: the autopilot's sample is usually near our newest estimate.
        i = len(est) - 1
        while i > 0 and est[i - 1][0] > t:
            i -= 1
        t1, q1 = est[i]
        if t1 < t:  # t is beyond our last: nearest only (cannot happen from _resolve)
            return q1 if t - t1 <= tol else None
        if i == 0 or t1 == t:
            return q1 if t1 - t <= tol else None
        t0, q0 = est[i - 1]
        if t1 - t0 <= 2.0 * tol:
            return _nlerp(q0, q1, (t - t0) / (t1 - t0))
        if t - t0 <= tol and t - t0 <= t1 - t:
            return q0
        return q1 if t1 - t <= tol else None

    def _gap_ms(self) -> float:
        """Comparisons further apart than this are not "continuous" (see ``MonitorSettings.max_gap_s``)."""
        iv = self._att_intervals
        if not iv:
            return self._max_gap_ms
        typical = sorted(iv)[len(iv) // 2]
        return max(self._max_gap_ms, self.settings.gap_intervals * typical)

    def _compare(self, t_ms: float, q_est: Sequence[float], q_ap: Sequence[float]) -> list[Any]:
        s = self.settings
        tilt, heading = _divergence(q_est, q_ap)
        self._tilt, self._heading = tilt, heading
        self._comparisons += 1
        self._fresh = True
        gap = self._last_cmp_ms is not None and t_ms - self._last_cmp_ms > self._gap_ms()
        self._last_cmp_ms = t_ms
        if gap:
            self._above_since_ms = self._below_since_ms = None
        first = self._first_est_ms if self._first_est_ms is not None else t_ms
        if t_ms - first < 1000.0 * s.startup_grace_s:
            return []
        hdg_on = self.heading_valid and self._hdg_thr > 0.0
        above = tilt > self._tilt_thr or (hdg_on and abs(heading) > self._hdg_thr)
        k = s.clear_fraction
        below = tilt < k * self._tilt_thr and (not hdg_on or abs(heading) < k * self._hdg_thr)
        if above:
            self._below_since_ms = None
            if self._above_since_ms is None:
                self._above_since_ms = t_ms
        elif below:
            self._above_since_ms = None
            if self._below_since_ms is None:
                self._below_since_ms = t_ms
        else:  # between the clear and trigger thresholds: neither timer runs
            self._above_since_ms = self._below_since_ms = None
        if not self._warning and self._above_since_ms is not None and t_ms - self._above_since_ms >= 1000.0 * s.trigger_s:
            self._warning = True
            self._episodes += 1
            text = WARNING_TEXT.format(tilt=math.degrees(tilt), heading=math.degrees(heading))
            return [_statustext(mavlink.MAV_SEVERITY_WARNING, text)]
        if self._warning and self._below_since_ms is not None and t_ms - self._below_since_ms >= 1000.0 * s.clear_s:
            self._warning = False
            return [_statustext(mavlink.MAV_SEVERITY_INFO, CLEARED_TEXT)]
        return []

    # ------------------------------------------------------------------ outputs
    @property
    def last_comparison_ms(self) -> float:
        """Autopilot time of the latest comparison, ms (NaN before the first)."""
        return self._last_cmp_ms if self._last_cmp_ms is not None else math.nan

    @property
    def status(self) -> MonitorStatus:
        return MonitorStatus(
            tilt_deg=math.degrees(self._tilt),
            heading_deg=math.degrees(self._heading),
            warning=self._warning,
            comparisons=self._comparisons,
            unmatched=self._unmatched,
            episodes=self._episodes,
            velocity_source=self.velocity_source,
        )


def _statustext(severity: int, text: str) -> Any:
    return mavlink.MAVLink_statustext_message(severity, text.encode()[:_STATUSTEXT_MAX], 0, 0)


# --------------------------------------------------------------------------- arrays (replay)


def divergence_series(
    t_ms: ArrayLike,
    q_est: ArrayLike,
    t_att_ms: ArrayLike,
    q_autopilot: ArrayLike,
    *,
    tolerance_ms: float = 50.0,
) -> tuple[Array, Array]:
    """Tilt and heading divergence (deg) at each autopilot sample time.

    Args:
        t_ms: (N,) increasing times of our estimates, ms (autopilot boot clock).
        q_est: (N, 4) our ``q_body_to_ned`` (as published: true north).
        t_att_ms: (M,) times of the autopilot's attitudes, ms.
        q_autopilot: (M, 4) the autopilot's attitudes (see
            :func:`mavahrs.geometry.rotation.from_euler_rad` for ATTITUDE).
        tolerance_ms: as :attr:`MonitorSettings.align_tolerance_ms`.

    Returns:
        ``(tilt_deg, heading_deg)``, each (M,); NaN where no estimate of ours
        lies close enough.  Heading is signed (ours minus the autopilot's).
    """
    q_aligned = align_attitudes(t_ms, q_est, t_att_ms, tolerance_ms=tolerance_ms)
    qa = np.asarray(q_autopilot, dtype=np.float64).reshape(-1, 4)
    a = q_aligned / np.linalg.norm(q_aligned, axis=1, keepdims=True)
    b = qa / np.linalg.norm(qa, axis=1, keepdims=True)
    w = np.sum(a * b, axis=1)
    z = -a[:, 0] * b[:, 3] - a[:, 1] * b[:, 2] + a[:, 2] * b[:, 1] + a[:, 3] * b[:, 0]
    sign = np.where(w < 0.0, -1.0, 1.0)
    w, z = w * sign, z * sign
    tilt = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    heading = 2.0 * np.arctan2(z, w)
    return np.degrees(tilt), np.degrees(heading)


def align_attitudes(t_ms: ArrayLike, q: ArrayLike, t_query_ms: ArrayLike, *, tolerance_ms: float = 50.0) -> Array:
    """Attitudes ``q`` sampled at ``t_ms`` (increasing), evaluated at ``t_query_ms``.

    Interpolated (slerp) between the two samples around each query time when
    they are at most ``2·tolerance_ms`` apart, else the nearest sample within
    ``tolerance_ms``, else NaN — the alignment rule of :class:`AttitudeMonitor`.
    Returns (M, 4).
    """
    t = np.asarray(t_ms, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    ta = np.asarray(t_query_ms, dtype=np.float64)
    m = len(ta)
    q_aligned = np.full((m, 4), np.nan)
    if len(t):
        hi = np.searchsorted(t, ta, side="left")  # first sample at or after the query
        lo = hi - 1
        hi_c = np.clip(hi, 0, len(t) - 1)
        lo_c = np.clip(lo, 0, len(t) - 1)
        has_hi = hi < len(t)
        has_lo = lo >= 0
        exact = has_hi & (t[hi_c] == ta)
        bracket = has_hi & has_lo & ~exact & (t[hi_c] - t[lo_c] <= 2.0 * tolerance_ms)
        if np.any(bracket):
            f = (ta[bracket] - t[lo_c[bracket]]) / (t[hi_c[bracket]] - t[lo_c[bracket]])
            q_aligned[bracket] = slerp(q[lo_c[bracket]], q[hi_c[bracket]], f)
        d_lo = np.where(has_lo, ta - t[lo_c], np.inf)
        d_hi = np.where(has_hi, t[hi_c] - ta, np.inf)
        rest = ~bracket
        use_lo = rest & ~exact & (d_lo <= d_hi) & (d_lo <= tolerance_ms)
        use_hi = rest & (exact | ((d_hi < d_lo) & (d_hi <= tolerance_ms)))
        q_aligned[use_lo] = q[lo_c[use_lo]]
        q_aligned[use_hi] = q[hi_c[use_hi]]
    return q_aligned


@dataclass(frozen=True)
class MonitorEvent:
    """A STATUSTEXT the monitor raised: autopilot time (ms), severity, text."""

    t_ms: float
    severity: int
    text: str


@dataclass(frozen=True)
class MonitorSeries:
    """:func:`monitor_series` result: per autopilot sample divergence and the events."""

    t_ms: Array
    tilt_deg: Array
    heading_deg: Array
    events: tuple[MonitorEvent, ...]


def monitor_series(
    t_ms: ArrayLike,
    q_est: ArrayLike,
    t_att_ms: ArrayLike,
    q_autopilot: ArrayLike,
    settings: MonitorSettings | None = None,
    *,
    heading_valid: bool = True,
) -> MonitorSeries:
    """Run :class:`AttitudeMonitor` over whole arrays (replay): which warnings, when.

    Inputs as :func:`divergence_series`; samples are merged in time order, our
    estimate first on equal times.  The divergence columns come from
    :func:`divergence_series` (NaN where unmatched).
    """
    s = settings if settings is not None else MonitorSettings()
    mon = AttitudeMonitor(s)
    mon.heading_valid = heading_valid
    t = np.asarray(t_ms, dtype=np.float64)
    q = np.asarray(q_est, dtype=np.float64).reshape(-1, 4)
    ta = np.asarray(t_att_ms, dtype=np.float64)
    qa = np.asarray(q_autopilot, dtype=np.float64).reshape(-1, 4)
    events: list[MonitorEvent] = []
    i = j = 0
    n, m = len(t), len(ta)
    while i < n or j < m:
        if j >= m or (i < n and t[i] <= ta[j]):
            out = mon.add_estimate(t[i], q[i])
            i += 1
        else:
            out = mon.add_autopilot(ta[j], qa[j])
            j += 1
        for msg in out:
            events.append(MonitorEvent(mon.last_comparison_ms, int(msg.severity), _text(msg)))
    tilt, heading = divergence_series(t, q, ta, qa, tolerance_ms=s.align_tolerance_ms)
    return MonitorSeries(ta, tilt, heading, tuple(events))


def _text(msg: Any) -> str:
    text = msg.text
    return text.decode(errors="replace") if isinstance(text, bytes) else str(text)
