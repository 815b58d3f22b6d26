"""Counters, rate meters and rate-limited notices for the service layer (no clock: time is passed in).

* :class:`RateMeter` — events per second over a sliding window of whole
  windows (cheap: one integer add per event, arithmetic only on ``rate()``).
* :class:`Notices` — messages the daemon should log, once per *kind* and then
  at most once per ``repeat_s`` (with the number suppressed in between), so a
  flood of bad input never floods the log.

Both take time as an argument in microseconds and never read a clock.
"""

from __future__ import annotations

import logging
from collections import deque

__all__ = ["RateMeter", "Notices"]


class RateMeter:
    """Events per second over the last ``window_s``, in four fixed buckets (one add per event)."""

    def __init__(self, window_s: float = 2.0) -> None:
        if not window_s > 0:
            raise ValueError(f"window_s must be positive, got {window_s!r}")
        self._step_us = max(1, int(window_s * 1e6) // 4)
        self.total = 0
        self.reset()

    def reset(self) -> None:
        self._buckets: deque[tuple[int, int]] = deque()  # (bucket index, count), completed buckets
        self._idx: int | None = None  # current bucket
        self._count = 0
        self._first_us: int | None = None

    def add(self, now_us: int, n: int = 1) -> None:
        """Count ``n`` events at ``now_us``."""
        self.total += n
        idx = now_us // self._step_us
        if idx != self._idx:
            if self._idx is None:
                self._first_us = now_us
            else:
                self._buckets.append((self._idx, self._count))
                if len(self._buckets) > 4:
                    self._buckets.popleft()
            self._idx = idx
            self._count = 0
        self._count += n

    def rate(self, now_us: int) -> float:
        """Events/s over the last four whole buckets (at start-up: since the first event)."""
        if self._idx is None or self._first_us is None:
            return 0.0
        idx = now_us // self._step_us
        first_idx = self._first_us // self._step_us
        if idx == first_idx:  # still in the very first bucket
            span = now_us - self._first_us
            return self._count * 1e6 / span if span > 0 else 0.0
        lo = max(idx - 4, first_idx)
        count = sum(c for i, c in self._buckets if lo <= i < idx)
        if self._idx is not None and lo <= self._idx < idx:
            count += self._count
        if lo == first_idx:  # the first bucket started at the first event, not at its boundary
            span = idx * self._step_us - self._first_us
        else:
            span = (idx - lo) * self._step_us
        return count * 1e6 / span if span > 0 else 0.0


class Notices:
    """Collects one-line messages for the log, rate-limited per kind.

    Args:
        repeat_s: a kind already reported is reported again at most this often
            (the message then says how many were suppressed).
        max_pending: bound on undelivered notices (oldest dropped).
    """

    def __init__(self, repeat_s: float = 60.0, max_pending: int = 100) -> None:
        self._repeat_us = int(repeat_s * 1e6)
        self._last: dict[str, int] = {}
        self._suppressed: dict[str, int] = {}
        self._pending: deque[tuple[int, str]] = deque(maxlen=max_pending)

    def add(self, kind: str, level: int, message: str, now_us: int | None = None, *, once: bool = False) -> bool:
        """Queue ``message`` unless ``kind`` was reported recently (or ever, with ``once``)."""
        last = self._last.get(kind)
        if last is not None and (once or now_us is None or now_us - last < self._repeat_us):
            self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
            return False
        n = self._suppressed.pop(kind, 0)
        if n:
            message = f"{message} ({n} more since the last report)"
        self._last[kind] = now_us if now_us is not None else 0
        self._pending.append((level, message))
        return True

    def forget(self, kind: str) -> None:
        """Allow ``kind`` to be reported again at once (e.g. after it cleared)."""
        self._last.pop(kind, None)
        self._suppressed.pop(kind, None)

    def drain(self) -> list[tuple[int, str]]:
        out = list(self._pending)
        self._pending.clear()
        return out

    def info(self, kind: str, message: str, now_us: int | None = None, *, once: bool = False) -> bool:
        return self.add(kind, logging.INFO, message, now_us, once=once)

    def warning(self, kind: str, message: str, now_us: int | None = None, *, once: bool = False) -> bool:
        return self.add(kind, logging.WARNING, message, now_us, once=once)
