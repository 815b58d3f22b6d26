r"""Per-source timing of IMU samples from the messages' own timestamps (pure, no clock).

One :class:`Timeline` per IMU stream (instance).  Each sample's raw timestamp
— ``time_usec`` (64-bit µs) or ``time_boot_ms · 1000`` (32-bit ms, wraps after
2³² ms ≈ 49.7 days) — goes in; a :class:`TimelineEvent` comes out saying what
to do with the sample:

=============  ====================================================  ==========
kind           meaning                                               filter
=============  ====================================================  ==========
``first``      first sample of the stream                            initialise (``dt_s`` NaN)
``ok``         newer than the last, step ≤ ``max_gap_s``             update with ``dt_s``
``gap``        step > ``max_gap_s`` (link outage, slow stream)       re-initialise / coast
``duplicate``  same timestamp (and same data key, if given)          drop
``stale``      same timestamp, different data                        drop
``reordered``  older than the last sample (late, reordered)          drop
``reboot``     time went back > ``reboot_back_s``, confirmed         reset (``dt_s`` NaN)
``drop``       jump forward > ``jump_confirm_s``, held back until    drop
               the next sample confirms it
=============  ====================================================  ==========

Robustness rules:

* **wrap-around** of ``time_boot_ms`` is unwrapped transparently: a backward
  step that lands just after the 2³²-ms wrap point is a wrap (counted in
  ``wraps``), and ``t_us`` keeps increasing;
* **reboots need confirmation**: a sample far in the past is held back (reported
  ``reordered``) and the reboot is declared only when the next sample continues
  from it; if the old timeline continues instead, it was a stray late sample;
* **jumps forward** by more than ``jump_confirm_s`` likewise need the next
  sample to continue from the new time, so one corrupt timestamp cannot throw
  the filter into a re-initialisation;
* **jitter is not loss**: ArduPilot stamps RAW_IMU when its scheduler sends it
  (steps of one loop, 2.5 ms at 400 Hz), so intervals wobble around the
  nominal one.  Lost samples are counted only from the running median interval:
  an interval of ``k`` medians (rounded, from ``lost_factor`` medians on)
  counts ``k − 1`` lost samples.

``t_us`` is the sample's own (unwrapped) time in the autopilot's current boot —
what an output stamped with the IMU sample's time must carry; it restarts at
a reboot.  ``t_mono_us`` never goes back, across reboots too.

Exact re-sends of a message (same stamp and values, :mod:`mavahrs.ingest.resend`) are
dropped before a sample gets here.

The rules exist once, as one compiled step on state in two plain arrays
(:func:`timeline_step`; :func:`new_state` lays them out): the live pipeline
calls it per sample through :class:`Timeline`, the daemon's fast lane inside
its compiled parse (on a copy of the pipeline's state: plainly ``ok`` or the
Python path decides), and every log reader runs :func:`timeline_loop`, the
same step in a compiled loop over a log's samples
(:func:`mavahrs.ingest.arrays.timeline_over_arrays`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from mavahrs.filters.jit import kernel

__all__ = [
    "TIME_BOOT_MS_WRAP_US",
    "TimelineSettings",
    "TimelineEvent",
    "TimelineCounters",
    "Timeline",
    "FIRST",
    "OK",
    "GAP",
    "DUPLICATE",
    "STALE",
    "REORDERED",
    "REBOOT",
    "HELD",
    "DROP_KINDS",
    "KIND_NAMES",
    "new_state",
    "timeline_step",
    "timeline_loop",
    "NO_NOW",
    "KEY_MAX",
    "T_RAW_MAX",
]

#: ``time_boot_ms`` is a uint32 of milliseconds: it wraps after 2³² ms, here in µs
TIME_BOOT_MS_WRAP_US = (1 << 32) * 1000

FIRST = "first"
OK = "ok"
GAP = "gap"
DUPLICATE = "duplicate"
STALE = "stale"
REORDERED = "reordered"
REBOOT = "reboot"
HELD = "drop"
#: kinds whose sample must not reach the filter
DROP_KINDS = frozenset({DUPLICATE, STALE, REORDERED, HELD})
#: :func:`timeline_step`'s kind codes, the names above in this order
K_FIRST, K_OK, K_GAP, K_DUPLICATE, K_STALE, K_REORDERED, K_REBOOT, K_HELD = range(8)
KIND_NAMES = (FIRST, OK, GAP, DUPLICATE, STALE, REORDERED, REBOOT, HELD)

_NAN = math.nan


@dataclass(frozen=True)
class TimelineSettings:
    """Thresholds of :class:`Timeline`.

    Attributes:
        max_gap_s: a step longer than this (s) is a ``gap``: the filter should
            re-initialise or coast.  0.5 s keeps slow streams (2–4 Hz
            telemetry logs) usable while catching link outages.
        reboot_back_s: time going back by more than this (s) is a reboot
            candidate (confirmed by the next sample); a smaller step back is a
            late, ``reordered`` sample.
        jump_confirm_s: a step forward longer than this (s) is accepted only
            when the next sample continues from it (one corrupt timestamp is
            dropped instead of resetting the filter).
        wrap_period_us: the raw timestamp's wrap period, µs; the default is
            ``time_boot_ms``'s (2³² ms), harmless for 64-bit ``time_usec``
            streams (they never come near it).  ``None`` disables unwrapping.
        median_window: number of recent intervals whose median is the nominal
            interval (for lost-sample counting and ``interval_median_us``).
        lost_factor: intervals of at least this many medians count lost
            samples (``round(dt / median) − 1``); shorter ones are jitter.
    """

    max_gap_s: float = 0.5
    reboot_back_s: float = 1.0
    jump_confirm_s: float = 5.0
    wrap_period_us: int | None = TIME_BOOT_MS_WRAP_US
    median_window: int = 32
    lost_factor: float = 1.5

    def __post_init__(self) -> None:
        for name in ("max_gap_s", "reboot_back_s", "jump_confirm_s", "lost_factor"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"TimelineSettings.{name} must be a positive number, got {v!r}")
        if self.jump_confirm_s < self.max_gap_s:
            raise ValueError(
                f"TimelineSettings.jump_confirm_s ({self.jump_confirm_s} s) must be >= max_gap_s ({self.max_gap_s} s)"
            )
        if self.wrap_period_us is not None and self.wrap_period_us <= 0:
            raise ValueError(f"TimelineSettings.wrap_period_us must be positive or None, got {self.wrap_period_us!r}")
        if not 4 <= self.median_window <= 4096:
            raise ValueError(f"TimelineSettings.median_window must be 4..4096 samples, got {self.median_window!r}")


class TimelineEvent(NamedTuple):
    """What a sample is: ``kind`` (see the module table), its time and step.

    Attributes:
        kind: ``first``, ``ok``, ``gap``, ``duplicate``, ``stale``, ``reordered``, ``reboot``, ``drop``.
        t_us: the sample's time, unwrapped, in the autopilot's current boot, µs.
        dt_s: time since the previous accepted sample, s (NaN for ``first`` and
            ``reboot``, 0 for dropped samples).
        t_mono_us: monotonic time across reboots, µs (for a dropped sample: the
            last accepted sample's).
    """

    kind: str
    t_us: int
    dt_s: float
    t_mono_us: int


@dataclass
class TimelineCounters:
    """Counts over the timeline's life (dropped kinds are not ``accepted``)."""

    samples: int = 0
    accepted: int = 0
    duplicates: int = 0
    stale: int = 0
    reordered: int = 0
    gaps: int = 0
    reboots: int = 0
    wraps: int = 0
    #: forward jumps beyond ``jump_confirm_s`` that the next sample did not confirm (dropped)
    jumps_rejected: int = 0
    #: samples held back for confirmation that turned out genuine (first of a new boot or after a
    #: long jump): dropped all the same, the next sample is used
    held: int = 0
    #: samples missing according to the median interval (jitter excluded)
    lost_samples: int = 0


# --------------------------------------------------------------------------- the state, in two plain arrays
#: ``now_us`` not given (:meth:`Timeline.push` without a receive time)
NO_NOW = np.iinfo(np.int64).min
#: values a sample key holds at most (the pipeline's: gyro and accelerometer, 6)
KEY_MAX = 6
#: raw stamps are clipped to this (µs, 146 000 years): room for the unwrapping offsets in int64
T_RAW_MAX = 1 << 62

# int64 state: what the stream is at (T_*, all before T_COUNTERS), the counters (TimelineCounters' order),
# the settings, then the ring of recent intervals and room to sort it
(T_LAST, T_HAVE_LAST, T_WRAP_OFF, T_MONO_OFF, T_LAST_MONO, T_HAVE_MONO, T_LAST_NOW, T_PENDING, T_HAVE_PENDING,
 T_PENDING_BACK, T_RING_I, T_RING_N, T_SINCE_MEDIAN, T_MEDIAN, T_KEY_N) = range(15)  # fmt: skip
T_COUNTERS = 15
_N_COUNTERS = 11
(C_SAMPLES, C_ACCEPTED, C_DUPLICATES, C_STALE, C_REORDERED, C_GAPS, C_REBOOTS, C_WRAPS, C_JUMPS_REJECTED, C_HELD,
 C_LOST) = range(T_COUNTERS, T_COUNTERS + _N_COUNTERS)  # fmt: skip
T_MAX_GAP, T_REBOOT_BACK, T_JUMP, T_WRAP, T_WINDOW = range(T_COUNTERS + _N_COUNTERS, T_COUNTERS + _N_COUNTERS + 5)
T_RING = T_WINDOW + 1
# float64 state: the jitter, the lost-sample factor (a setting), the last accepted sample's key
F_JITTER, F_LOST_FACTOR, F_KEY = 0, 1, 2
F_LEN = F_KEY + KEY_MAX


def new_state(settings: TimelineSettings | None = None) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The state of a new stream, ``(int64 array, float64 array)``, with ``settings``' thresholds in it."""
    s = settings if settings is not None else TimelineSettings()
    st = np.zeros(T_RING + 2 * s.median_window, np.int64)
    fs = np.zeros(F_LEN)
    st[T_MAX_GAP] = int(round(s.max_gap_s * 1e6))
    st[T_REBOOT_BACK] = int(round(s.reboot_back_s * 1e6))
    st[T_JUMP] = int(round(s.jump_confirm_s * 1e6))
    st[T_WRAP] = 0 if s.wrap_period_us is None else s.wrap_period_us
    st[T_WINDOW] = s.median_window
    fs[F_LOST_FACTOR] = s.lost_factor
    _forget(st, fs)
    return st, fs


@kernel
def _forget(st, fs):  # type: ignore[no-untyped-def]
    """Forget the stream (a new time base); the counters and settings are kept."""
    st[:T_COUNTERS] = 0  # no last sample, offsets, pending sample, intervals or median
    st[T_LAST_NOW] = NO_NOW
    st[T_KEY_N] = -1
    fs[F_JITTER] = 0.0


@kernel
def _keep_key(st, fs, k0, k1, k2, k3, k4, k5, key_n):  # type: ignore[no-untyped-def]
    st[T_KEY_N] = key_n
    fs[F_KEY], fs[F_KEY + 1], fs[F_KEY + 2], fs[F_KEY + 3], fs[F_KEY + 4], fs[F_KEY + 5] = k0, k1, k2, k3, k4, k5


@kernel
def _start(st, fs, kind, t_raw, now, k0, k1, k2, k3, k4, k5, key_n):  # type: ignore[no-untyped-def]
    """First sample, or first sample after a reboot: a new time base."""
    have_prev = st[T_HAVE_MONO] != 0
    prev_mono = st[T_LAST_MONO]
    prev_now = st[T_LAST_NOW]
    if now != NO_NOW and prev_now != NO_NOW and now > prev_now:
        step = now - prev_now
    else:
        step = max(1, st[T_MEDIAN])
    _forget(st, fs)
    if have_prev:
        st[T_MONO_OFF] = prev_mono + step - t_raw
    st[T_LAST] = t_raw
    st[T_HAVE_LAST] = 1
    _keep_key(st, fs, k0, k1, k2, k3, k4, k5, key_n)
    mono = t_raw + st[T_MONO_OFF]
    st[T_LAST_MONO] = mono
    st[T_HAVE_MONO] = 1
    st[T_LAST_NOW] = now
    st[C_ACCEPTED] += 1
    return kind, t_raw, math.nan, mono


@kernel
def _add_interval(st, fs, d):  # type: ignore[no-untyped-def]
    w = st[T_WINDOW]
    n = st[T_RING_N]
    if n < w:
        st[T_RING + n] = d
        n += 1
        st[T_RING_N] = n
    else:
        i = st[T_RING_I]
        st[T_RING + i] = d
        st[T_RING_I] = (i + 1) % w
    st[T_SINCE_MEDIAN] += 1
    # recompute every quarter window (and early on), not per sample: cheap on the live path
    if st[T_SINCE_MEDIAN] >= max(1, w // 4) or (n < w and (n == 4 or n == 8 or n == 16)):
        st[T_SINCE_MEDIAN] = 0
        if n >= 4:
            srt = st[T_RING + w : T_RING + w + n]
            # an insertion sort of a copy, in place (numba's sort and whole-array copies need its
            # runtime): 32 intervals by default, every quarter window
            for i in range(n):
                v = st[T_RING + i]
                j = i
                while j > 0 and srt[j - 1] > v:
                    srt[j] = srt[j - 1]
                    j -= 1
                srt[j] = v
            m = srt[n // 2]
            st[T_MEDIAN] = m
            total = 0
            for j in range(n):
                total += abs(st[T_RING + j] - m)
            fs[F_JITTER] = total / n


@kernel
def _accept(st, fs, kind, t, d, now, k0, k1, k2, k3, k4, k5, key_n):  # type: ignore[no-untyped-def]
    st[C_ACCEPTED] += 1
    last = st[T_LAST]
    st[T_LAST] = t
    _keep_key(st, fs, k0, k1, k2, k3, k4, k5, key_n)
    st[T_LAST_NOW] = now
    mono = t + st[T_MONO_OFF]
    st[T_LAST_MONO] = mono
    if kind == K_GAP:
        st[C_GAPS] += 1
    med = st[T_MEDIAN]
    if med > 0 and d >= fs[F_LOST_FACTOR] * med:
        st[C_LOST] += round(d / med) - 1
    if kind == K_OK:
        _add_interval(st, fs, d)
    return kind, t, (t - last) * 1e-6, mono


@kernel
def timeline_step(st, fs, t_raw, now, k0, k1, k2, k3, k4, k5, key_n):  # type: ignore[no-untyped-def]
    """Classify one sample of the stream whose state is ``(st, fs)`` (:func:`new_state`); the state moves on.

    Args:
        t_raw: the message's timestamp in µs (``time_usec``, or
            ``time_boot_ms * 1000``), as sent (below ``2**62``).
        now: receive time (any monotonic clock, µs), or :data:`NO_NOW`; only
            used to place ``t_mono_us`` after a reboot.
        k0 … k5, key_n: the sample's data key (its first ``key_n`` values; the
            pipeline's: gyro and accelerometer), ``key_n`` −1 for none: a repeated
            timestamp with the same key is a ``duplicate``, with another ``stale``.

    Returns:
        ``(kind code, t_us, dt_s, t_mono_us)``: :data:`KIND_NAMES` ``[code]``
        and the rest as :class:`TimelineEvent`.
    """
    st[C_SAMPLES] += 1
    if st[T_HAVE_LAST] == 0:
        return _start(st, fs, K_FIRST, t_raw, now, k0, k1, k2, k3, k4, k5, key_n)
    t = t_raw + st[T_WRAP_OFF]
    d = t - st[T_LAST]
    wrap = st[T_WRAP]
    jump = st[T_JUMP]
    if d <= -st[T_REBOOT_BACK] and wrap != 0:
        dw = d + wrap
        if 0 < dw and dw <= jump:  # just past the wrap point: unwrap
            st[T_WRAP_OFF] += wrap
            st[C_WRAPS] += 1
            t += wrap
            d = dw
    if st[T_HAVE_PENDING] != 0:
        st[T_HAVE_PENDING] = 0
        back = st[T_PENDING_BACK] != 0
        since = t - st[T_PENDING]
        if 0 < since and since <= jump and ((d <= 0) if back else (d > jump)):
            st[C_HELD] += 1
            if back:  # confirmed: the autopilot rebooted
                st[C_REORDERED] -= 1  # the held-back sample was the new boot's first
                st[C_REBOOTS] += 1
                return _start(st, fs, K_REBOOT, t_raw, now, k0, k1, k2, k3, k4, k5, key_n)
            st[C_JUMPS_REJECTED] -= 1  # confirmed forward jump: a real gap
            return _accept(st, fs, K_GAP, t, d, now, k0, k1, k2, k3, k4, k5, key_n)
    if d > 0:
        if d > jump:
            st[T_PENDING] = t
            st[T_HAVE_PENDING] = 1
            st[T_PENDING_BACK] = 0
            st[C_JUMPS_REJECTED] += 1
            return K_HELD, t, 0.0, st[T_LAST_MONO]
        return _accept(st, fs, K_GAP if d > st[T_MAX_GAP] else K_OK, t, d, now, k0, k1, k2, k3, k4, k5, key_n)
    if d == 0:
        same = key_n < 0 or (
            key_n == st[T_KEY_N]
            and (key_n <= 0 or k0 == fs[F_KEY])
            and (key_n <= 1 or k1 == fs[F_KEY + 1])
            and (key_n <= 2 or k2 == fs[F_KEY + 2])
            and (key_n <= 3 or k3 == fs[F_KEY + 3])
            and (key_n <= 4 or k4 == fs[F_KEY + 4])
            and (key_n <= 5 or k5 == fs[F_KEY + 5])
        )
        if same:
            st[C_DUPLICATES] += 1
            return K_DUPLICATE, t, 0.0, st[T_LAST_MONO]
        st[C_STALE] += 1
        return K_STALE, t, 0.0, st[T_LAST_MONO]
    st[C_REORDERED] += 1
    if d <= -st[T_REBOOT_BACK]:
        st[T_PENDING] = t
        st[T_HAVE_PENDING] = 1
        st[T_PENDING_BACK] = 1
    return K_REORDERED, t, 0.0, st[T_LAST_MONO]


@kernel
def timeline_loop(st, fs, t_raw, now, gyro, accel, kind, t_us, dt_s):  # type: ignore[no-untyped-def]
    """:func:`timeline_step` over a stream's samples in order, keyed by their gyro and accelerometer as the
    pipeline keys them: ``kind[i]``, ``t_us[i]``, ``dt_s[i]`` what the step said of sample ``i``.

    ``t_raw``, ``now``: (N,) int64 (``now`` the receive times, or the stamps when there are none);
    ``gyro``, ``accel``: (N, 3) the scaled values.
    """
    for i in range(t_raw.shape[0]):
        g, a = gyro[i], accel[i]
        kind[i], t_us[i], dt_s[i], _mono = timeline_step(st, fs, min(t_raw[i], T_RAW_MAX), now[i], g[0], g[1],
                                                         g[2], a[0], a[1], a[2], 6)  # fmt: skip


class Timeline:
    """Timestamp bookkeeping for one IMU stream (see the module docstring): :func:`timeline_step` and its state."""

    __slots__ = ("settings", "st", "fs")

    def __init__(self, settings: TimelineSettings | None = None) -> None:
        self.settings = settings if settings is not None else TimelineSettings()
        #: the state (:func:`new_state`): the fast lane copies it, the loops start from it
        self.st, self.fs = new_state(self.settings)

    def reset(self) -> None:
        """Forget the stream (counters are kept)."""
        _forget(self.st, self.fs)

    # ------------------------------------------------------------------ public
    @property
    def counters(self) -> TimelineCounters:
        """Counts over the timeline's life (a copy)."""
        return TimelineCounters(*self.st[T_COUNTERS : T_COUNTERS + _N_COUNTERS].tolist())

    @property
    def interval_median_us(self) -> int:
        """Nominal interval (median of the recent ones), µs; 0 until enough samples."""
        return int(self.st[T_MEDIAN])

    @property
    def jitter_us(self) -> float:
        """Mean absolute deviation of recent intervals from their median, µs."""
        return float(self.fs[F_JITTER])

    @property
    def last_us(self) -> int | None:
        """The last accepted sample's time (unwrapped), µs; None before the first."""
        return int(self.st[T_LAST]) if self.st[T_HAVE_LAST] else None

    def push(self, t_raw_us: int, now_us: int | None = None, sample_key: object = None) -> TimelineEvent:
        """Classify one sample (:func:`timeline_step`).

        Args:
            t_raw_us: the message's timestamp in µs (``time_usec``, or
                ``time_boot_ms * 1000``), as sent.
            now_us: optional receive time (any monotonic clock, µs); only used
                to place ``t_mono_us`` after a reboot.
            sample_key: optional numbers identifying the sample's data (at most
                :data:`KEY_MAX`; the pipeline gives gyro and accelerometer): a
                repeated timestamp with the same key is a ``duplicate``, with a
                different key ``stale``.
        """
        t = int(t_raw_us)
        if t > T_RAW_MAX:
            t = T_RAW_MAX
        now = NO_NOW if now_us is None else int(now_us)
        if sample_key is None:
            r = timeline_step(self.st, self.fs, t, now, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1)
        else:
            k = tuple(sample_key)  # type: ignore[call-overload]
            n = len(k)
            if n != KEY_MAX:
                if n > KEY_MAX:
                    raise ValueError(f"a sample key holds at most {KEY_MAX} numbers, got {n}")
                k = tuple(float(x) for x in k) + (0.0,) * (KEY_MAX - n)
            r = timeline_step(self.st, self.fs, t, now, k[0], k[1], k[2], k[3], k[4], k[5], n)
        return TimelineEvent(KIND_NAMES[r[0]], r[1], r[2], r[3])


assert [f.name for f in fields(TimelineCounters)] == ["samples", "accepted", "duplicates", "stale", "reordered", "gaps",
                                                      "reboots", "wraps", "jumps_rejected", "held", "lost_samples"]  # fmt: skip
