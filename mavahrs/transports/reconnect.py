r"""When to try again after a link is lost, and what to tell the user about it.

A lost serial device or TCP server is retried every ``interval_s`` (default
1 s) for ever; the loss is logged once (WARNING, with the reason), the
recovery once (INFO, with how long it took and how many attempts), and the
attempts in between are only counted, so an unplugged cable never floods the
log.
"""

from __future__ import annotations

import logging

__all__ = ["Reconnector"]


class Reconnector:
    """Retry schedule and log-once bookkeeping for one link.

    Args:
        what: the link's description, for messages.
        interval_s: seconds between attempts.
        logger: where the two messages go.
    """

    def __init__(self, what: str, interval_s: float = 1.0, logger: logging.Logger | None = None) -> None:
        if not interval_s > 0:
            raise ValueError(f"reconnect interval must be positive, got {interval_s!r}")
        self.what = what
        self.interval_s = float(interval_s)
        self._log = logger or logging.getLogger("mavahrs.transports")
        self.down = False
        self.attempts = 0  # attempts since the link went down
        self._lost_at_s = 0.0
        self._next_s = 0.0
        self._last_reason = ""

    def lost(self, now_s: float, reason: str) -> None:
        """The link just went down: log once and schedule the first retry."""
        if self.down:
            return
        self.down = True
        self.attempts = 0
        self._lost_at_s = now_s
        self._next_s = now_s + self.interval_s
        self._last_reason = reason
        self._log.warning("%s lost: %s; retrying every %.3g s", self.what, reason, self.interval_s)

    def due(self, now_s: float) -> bool:
        """True when an attempt should be made now."""
        return self.down and now_s >= self._next_s

    def failed(self, now_s: float, reason: str) -> None:
        """An attempt failed: count it (logged at DEBUG only) and schedule the next."""
        self.attempts += 1
        self._next_s = now_s + self.interval_s
        if reason != self._last_reason:
            self._log.debug("%s: still down (%s)", self.what, reason)
            self._last_reason = reason

    def restored(self, now_s: float) -> None:
        """An attempt succeeded: log once."""
        if not self.down:
            return
        self.attempts += 1
        self._log.info(
            "%s restored after %.1f s (%d attempt%s)",
            self.what,
            now_s - self._lost_at_s,
            self.attempts,
            "" if self.attempts == 1 else "s",
        )
        self.down = False
