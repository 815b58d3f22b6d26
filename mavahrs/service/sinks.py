r"""Recording sinks for the daemon: a tlog that never takes the service down with it.

:class:`TlogSink` wraps :class:`mavahrs.protocol.tlog.TlogWriter` (the format:
8-byte big-endian Unix time in µs, then the MAVLink frame) and adds what a
long-running service needs:

* **flushed at least every** ``flush_interval_s`` (default 1 s), also when no
  traffic arrives (:meth:`TlogSink.tick` from the daemon's timer), so a crash
  — even ``SIGKILL`` — loses at most the last second; :meth:`close` flushes
  and ``fsync``\ s, which the daemon does on SIGINT/SIGTERM;
* **a full disk or any other write error stops the recording, not the
  service**: the error is logged once (ERROR, with the reason and how many
  frames were written), later writes are counted as ``frames_lost`` and the
  status line shows ``log stopped``;
* **no empty file left behind**: a file this sink created that is still empty
  when it closes (stopped before anything arrived — Ctrl-C while the daemon
  waits for the autopilot) is removed, and the removal is logged; a file that
  existed before (appended to) is always kept.
"""

from __future__ import annotations

import logging
import os
from typing import Any

from mavahrs.errors import ConfigError

__all__ = ["TlogSink"]


class TlogSink:
    """A tlog recording that survives crashes and full disks.

    Args:
        path: the ``.tlog`` file (appended to if it exists, as MAVProxy does).
        flush_interval_s: the longest time written data may stay in memory.
        writer: an already open writer with the interface of
            :class:`~mavahrs.protocol.tlog.TlogWriter` (``write(t_us, frame,
            now_s)``, ``tick(now_s)``, ``flush(now_s)``, ``close()``), e.g. one
            on a file object; by default a ``TlogWriter`` on ``path``.

    Raises:
        ConfigError: the file cannot be opened (directory missing, no permission).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        flush_interval_s: float = 1.0,
        *,
        writer: Any = None,
        logger: logging.Logger | None = None,
    ) -> None:
        if not flush_interval_s > 0:
            raise ConfigError(f"log flush interval must be positive, got {flush_interval_s!r} s")
        self.path = os.fspath(path)
        self.flush_interval_s = float(flush_interval_s)
        self._log = logger or logging.getLogger("mavahrs.service")
        #: created by this sink (not appended to): removed at close if nothing was written (see the module text)
        self._created = writer is None and not os.path.exists(self.path)
        self.removed_empty = False
        if writer is None:
            from mavahrs.protocol.tlog import TlogWriter

            try:
                writer = TlogWriter(self.path, flush_interval_s=self.flush_interval_s)
            except OSError as exc:
                raise ConfigError(f"cannot open log file {self.path}: {exc.strerror or exc}") from None
        self._writer = writer
        self.frames = 0
        self.bytes = 0
        self.frames_lost = 0
        self.stopped = False
        self.reason = ""

    @property
    def state(self) -> str:
        """``"ok"``, ``"closed"`` (closed and synced as it should be), ``"nothing recorded: empty file removed"``
        or ``"stopped: <reason>"`` (an error)."""
        if not self.stopped:
            return "ok"
        if self.removed_empty:
            return "nothing recorded: empty file removed"
        return "closed" if self.reason == "closed" else f"stopped: {self.reason}"

    def _fail(self, exc: OSError, what: str) -> None:
        self.stopped = True
        self.reason = exc.strerror or str(exc) or type(exc).__name__
        self._log.error(
            "recording to %s stopped (%s while %s) after %d frames; the service keeps running without a log",
            self.path,
            self.reason,
            what,
            self.frames,
        )
        try:
            self._writer.close()
        except Exception:  # noqa: BLE001 - the file is already broken; closing may fail too
            pass

    def write(self, t_us: int, frame: bytes, now_s: float) -> None:
        """Record one frame received or sent at Unix time ``t_us``; ``now_s`` is a monotonic clock."""
        if self.stopped:
            self.frames_lost += 1
            return
        try:
            self._writer.write(t_us, frame, now_s)
        except OSError as exc:
            self.frames_lost += 1
            self._fail(exc, "writing")
            return
        self.frames += 1
        self.bytes += 8 + len(frame)

    def tick(self, now_s: float) -> None:
        """Flush when ``flush_interval_s`` has passed since the last flush (call a few times per second)."""
        if self.stopped:
            return
        try:
            self._writer.tick(now_s)
        except OSError as exc:
            self._fail(exc, "flushing")

    def flush(self, now_s: float | None = None) -> None:
        """Hand everything written so far to the operating system."""
        if self.stopped:
            return
        try:
            self._writer.flush(now_s)
        except OSError as exc:
            self._fail(exc, "flushing")

    def close(self) -> None:
        """Flush, sync to disk and close (idempotent; errors are logged, never raised)."""
        if self.stopped:
            return
        try:
            self._writer.close()
        except OSError as exc:
            self._fail(exc, "closing")
            return
        self.stopped = True
        self.reason = "closed"
        if self._created and self.frames == 0:
            self._remove_if_empty()

    def _remove_if_empty(self) -> None:
        try:
            if os.path.getsize(self.path) != 0:
                return
            os.remove(self.path)
        except OSError:  # gone already, or not ours to remove: leave it
            return
        self.removed_empty = True
        self._log.info("nothing was recorded (stopped before any message arrived): removed the empty log file %s",
                       self.path)  # fmt: skip
