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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

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


class Timeline:
    """Timestamp bookkeeping for one IMU stream; see the module docstring."""

    def __init__(self, settings: TimelineSettings | None = None) -> None:
        self.settings = s = settings if settings is not None else TimelineSettings()
        self._max_gap_us = int(round(s.max_gap_s * 1e6))
        self._reboot_us = int(round(s.reboot_back_s * 1e6))
        self._jump_us = int(round(s.jump_confirm_s * 1e6))
        self._wrap = s.wrap_period_us
        self.counters = TimelineCounters()
        self.reset()

    def reset(self) -> None:
        """Forget the stream (counters are kept)."""
        self._last: int | None = None  # last accepted time, unwrapped
        self._last_key: object = None
        self._wrap_off = 0
        self._mono_off = 0
        self._last_mono: int | None = None
        self._last_now: int | None = None
        self._pending: int | None = None  # unwrapped candidate for a reboot / forward jump
        self._pending_back = False
        self._intervals: list[int] = []
        self._ring_i = 0
        self._since_median = 0
        self._median_us = 0
        self._jitter_us = 0.0

    # ------------------------------------------------------------------ public
    @property
    def interval_median_us(self) -> int:
        """Nominal interval (median of the recent ones), µs; 0 until enough samples."""
        return self._median_us

    @property
    def jitter_us(self) -> float:
        """Mean absolute deviation of recent intervals from their median, µs."""
        return self._jitter_us

    def push(self, t_raw_us: int, now_us: int | None = None, sample_key: object = None) -> TimelineEvent:
        """Classify one sample.

        Args:
            t_raw_us: the message's timestamp in µs (``time_usec``, or
                ``time_boot_ms * 1000``), as sent.
            now_us: optional receive time (any monotonic clock, µs); only used
                to place ``t_mono_us`` after a reboot.
            sample_key: optional value identifying the sample's data (e.g. a
                tuple of its raw fields): a repeated timestamp with the same key
                is a ``duplicate``, with a different key ``stale``.
        """
        c = self.counters
        c.samples += 1
        t_raw_us = int(t_raw_us)
        last = self._last
        if last is None:
            return self._start(FIRST, t_raw_us, now_us, sample_key)
        t = t_raw_us + self._wrap_off
        d = t - last
        if d <= -self._reboot_us and self._wrap is not None:
            dw = d + self._wrap
            if 0 < dw <= self._jump_us:  # just past the wrap point: unwrap
                self._wrap_off += self._wrap
                c.wraps += 1
                t += self._wrap
                d = dw
        pending = self._pending
        if pending is not None:
            self._pending = None
            if 0 < t - pending <= self._jump_us and (d <= 0 if self._pending_back else d > self._jump_us):
                c.held += 1
                if self._pending_back:  # confirmed: the autopilot rebooted
                    c.reordered -= 1  # the held-back sample was the new boot's first
                    c.reboots += 1
                    return self._start(REBOOT, t_raw_us, now_us, sample_key)
                c.jumps_rejected -= 1  # confirmed forward jump: a real gap
                return self._accept(GAP, t, d, now_us, sample_key)
        if d > 0:
            if d > self._jump_us:
                self._pending = t
                self._pending_back = False
                c.jumps_rejected += 1
                return TimelineEvent(HELD, t, 0.0, self._last_mono)
            return self._accept(GAP if d > self._max_gap_us else OK, t, d, now_us, sample_key)
        if d == 0:
            if sample_key is None or sample_key == self._last_key:
                c.duplicates += 1
                return TimelineEvent(DUPLICATE, t, 0.0, self._last_mono)
            c.stale += 1
            return TimelineEvent(STALE, t, 0.0, self._last_mono)
        c.reordered += 1
        if d <= -self._reboot_us:
            self._pending = t
            self._pending_back = True
        return TimelineEvent(REORDERED, t, 0.0, self._last_mono)

    # ------------------------------------------------------------------ internals
    def _start(self, kind: str, t_raw: int, now_us: int | None, key: object) -> TimelineEvent:
        """First sample, or first sample after a reboot: a new time base."""
        prev_mono = self._last_mono
        step = self._median_step(now_us, self._last_now)
        self.reset()
        t = t_raw
        if prev_mono is not None:
            self._mono_off = prev_mono + step - t
        self._last = t
        self._last_key = key
        self._last_mono = t + self._mono_off
        self._last_now = now_us
        self.counters.accepted += 1
        return TimelineEvent(kind, t, _NAN, self._last_mono)

    def _median_step(self, now_us: int | None, prev_now: int | None) -> int:
        if now_us is not None and prev_now is not None and now_us > prev_now:
            return int(now_us - prev_now)
        return max(1, self._median_us)

    def _accept(self, kind: str, t: int, d: int, now_us: int | None, key: object) -> TimelineEvent:
        c = self.counters
        c.accepted += 1
        last = self._last
        assert last is not None
        self._last = t
        self._last_key = key
        self._last_now = now_us
        mono = t + self._mono_off
        self._last_mono = mono
        if kind == GAP:
            c.gaps += 1
        med = self._median_us
        if med > 0 and d >= self.settings.lost_factor * med:
            c.lost_samples += int(round(d / med)) - 1
        if kind == OK:
            self._add_interval(d)
        return TimelineEvent(kind, t, (t - last) * 1e-6, mono)

    def _add_interval(self, d: int) -> None:
        iv = self._intervals
        w = self.settings.median_window
        if len(iv) < w:
            iv.append(d)
        else:
            iv[self._ring_i] = d
            self._ring_i = (self._ring_i + 1) % w
        self._since_median += 1
        # recompute every quarter window (and early on), not per sample: cheap on the live path
        if self._since_median >= max(1, w // 4) or (len(iv) < w and len(iv) in (4, 8, 16)):
            self._since_median = 0
            if len(iv) >= 4:
                srt = sorted(iv)
                m = srt[len(srt) // 2]
                self._median_us = m
                self._jitter_us = sum(abs(x - m) for x in iv) / len(iv)
