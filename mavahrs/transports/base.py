r"""The interface every link shares, and the bounded write queue of the stream links.

A :class:`Transport` moves bytes and nothing else (no MAVLink parsing):

* ``datagram`` — True for UDP: each ``read`` returns exactly one datagram, to be
  parsed on its own; False for serial/TCP streams;
* ``filenos()`` — the descriptors to wait on (``selectors``); empty while a
  link is down and reconnecting; ``fileno()`` is the first of them or −1;
* ``read(timeout_s)`` — waits (``select``, never busy polling) at most
  ``timeout_s`` and returns what arrived, ``b""`` on timeout;
* ``write(data)`` — never blocks for long: what cannot be sent now is queued in
  a bounded buffer (streams) or dropped (datagrams), and counted;
* ``maintain(now_s)`` — reconnection and queue flushing, called from the
  owner's timer (a few times per second);
* ``close()``, ``describe()`` and ``counters``.

A link that is down returns ``b""`` from ``read`` (after its timeout) and
counts writes as dropped: the service keeps running and the link comes back by
itself (:mod:`mavahrs.transports.reconnect`).  Only *opening* a link can raise
(:class:`~mavahrs.errors.TransportError`, one line a user can act on).
"""

from __future__ import annotations

import errno
import select
from collections import deque
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

__all__ = ["Transport", "TransportCounters", "WriteQueue", "wait_readable", "describe_os_error"]


@dataclass
class TransportCounters:
    """What a link has done (totals over its life).

    Attributes:
        bytes_in: bytes read.
        reads: successful reads (datagrams for UDP).
        bytes_out: bytes handed to the operating system.
        writes: write calls.
        writes_dropped: write calls (or queued chunks) thrown away because
            the link was down, had no peer yet, or its queue was full.
        bytes_dropped: bytes in those writes.
        disconnects: times the link was lost.
        reconnects: times it came back (``tcpin``: a client connected;
            ``udpin``: a new sender after silence — a restarted peer).
        ignored_reads: reads discarded (e.g. a second TCP client's input).
        kernel_dropped: datagrams the operating system threw away before we read them because
            the socket's receive buffer was full (UDP on Linux, from ``SO_RXQ_OVFL``; 0 where the
            platform does not tell) — the process was not scheduled for long enough.
    """

    bytes_in: int = 0
    reads: int = 0
    bytes_out: int = 0
    writes: int = 0
    writes_dropped: int = 0
    bytes_dropped: int = 0
    disconnects: int = 0
    reconnects: int = 0
    ignored_reads: int = 0
    kernel_dropped: int = 0


@runtime_checkable
class Transport(Protocol):
    """A byte link (see the module docstring)."""

    datagram: bool
    counters: TransportCounters

    def fileno(self) -> int: ...

    def filenos(self) -> tuple[int, ...]: ...

    def read(self, timeout_s: float) -> bytes: ...

    def write(self, data: bytes) -> None: ...

    def maintain(self, now_s: float) -> None: ...

    def close(self) -> None: ...

    def describe(self) -> str: ...


def wait_readable(fds: tuple[int, ...], timeout_s: float) -> list[int]:
    """The descriptors among ``fds`` that are readable within ``timeout_s`` (``poll``, no busy loop)."""
    if not fds:
        return []
    poller = select.poll()
    for fd in fds:
        poller.register(fd, select.POLLIN | select.POLLPRI | select.POLLERR | select.POLLHUP)
    ready = poller.poll(max(0.0, timeout_s) * 1000.0)
    return [fd for fd, _ in ready]


def describe_os_error(exc: BaseException) -> str:
    """A short, actionable reason for an ``OSError`` (no errno numbers, no tracebacks)."""
    code = getattr(exc, "errno", None)
    hints = {
        errno.EACCES: "permission denied (add the user to the 'dialout' group, or check the device's udev rule)",
        errno.EPERM: "permission denied",
        errno.EBUSY: "the port is busy (another program — MAVProxy, ModemManager, a second mavahrs — has it open)",
        errno.EAGAIN: "the port is locked by another program (MAVProxy, ModemManager, a second mavahrs?)",
        errno.ENOENT: "no such device (is it plugged in? see `ls /dev/serial/by-id/`)",
        errno.ENODEV: "no such device",
        errno.ENXIO: "no such device or address",
        errno.EADDRINUSE: "the address is already in use (another program listens on this port)",
        errno.EADDRNOTAVAIL: "the address is not one of this machine's",
        errno.ECONNREFUSED: "connection refused (nothing listens there yet)",
        errno.EHOSTUNREACH: "host unreachable",
        errno.ENETUNREACH: "network unreachable",
        errno.ETIMEDOUT: "timed out",
        errno.EIO: "input/output error (device unplugged?)",
        errno.EISDIR: "it is a directory, not a serial device",
        errno.ENOTTY: "not a serial device (a serial port is a terminal device such as /dev/ttyACM0 or /dev/serial0)",
    }
    if code in hints:
        return hints[code]
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return str(text)


class WriteQueue:
    """A bounded FIFO of outgoing chunks for a stream link (serial, TCP).

    When adding a chunk would exceed ``max_bytes``, the *oldest* whole chunks
    are dropped (never the partly sent head, which would corrupt a frame) and
    counted in ``counters``.  Memory stays bounded whatever the peer does.
    """

    def __init__(self, max_bytes: int, counters: TransportCounters) -> None:
        self.max_bytes = int(max_bytes)
        self._chunks: deque[bytes] = deque()
        self._head_sent = 0  # bytes of _chunks[0] already written
        self._bytes = 0
        self._counters = counters

    def __len__(self) -> int:
        return self._bytes - self._head_sent

    def push(self, data: bytes) -> None:
        c = self._counters
        if len(data) > self.max_bytes:
            c.writes_dropped += 1
            c.bytes_dropped += len(data)
            return
        self._chunks.append(data)
        self._bytes += len(data)
        while len(self) > self.max_bytes and len(self._chunks) > 1:
            # Drop the oldest chunk that has not started going out.
            idx = 1 if self._head_sent else 0
            old = self._chunks[idx]
            del self._chunks[idx]
            self._bytes -= len(old)
            c.writes_dropped += 1
            c.bytes_dropped += len(old)

    def flush(self, send: object) -> None:
        """Write queued bytes with ``send(memoryview) -> int`` until it would block.

        ``send`` raises ``BlockingIOError`` (or returns 0) when the OS buffer is
        full; other ``OSError`` propagate to the caller (link lost).
        """
        while self._chunks:
            head = self._chunks[0]
            try:
                n = send(memoryview(head)[self._head_sent :])  # type: ignore[operator]
            except (BlockingIOError, InterruptedError):
                return
            if not n:
                return
            self._counters.bytes_out += n
            self._head_sent += n
            if self._head_sent >= len(head):
                self._chunks.popleft()
                self._bytes -= len(head)
                self._head_sent = 0

    def clear(self) -> None:
        """Forget everything queued (the link was lost); counted as dropped."""
        if self._chunks:
            self._counters.writes_dropped += len(self._chunks)
            self._counters.bytes_dropped += len(self)
        self._chunks.clear()
        self._bytes = 0
        self._head_sent = 0
