r"""Serial links (``/dev/ttyACM0,921600``, ``COM3``) that survive unplug and replug.

pyserial opens and configures the port (raw mode, baud rate, an exclusive
``flock`` so two programs never read the same autopilot); reading and writing
then go straight to the descriptor, non-blocking, after ``poll`` says it is
ready — no busy polling and no pyserial read loop per byte.

* Opening fails with one line a user can act on: *permission denied* (the
  ``dialout`` group), *busy* (MAVProxy or ModemManager holds it), *no such
  device*.  The caller turns it into an exit code.
* A device that vanishes (USB unplugged, pty master closed: ``EIO``/``ENXIO``,
  or a hang-up — readable with no data) closes the port, is logged once, and is
  reopened every ``reconnect_interval_s`` by :meth:`SerialTransport.maintain`
  until it is back (a udev ``/dev/serial/by-id/…`` link is the stable name to
  use).  Writes while it is away are dropped and counted.
* Writes go through a bounded queue (oldest frames dropped when the line
  cannot keep up with what we send).
"""

from __future__ import annotations

import errno
import logging
import os
import select
import time
from typing import Any

from mavahrs.errors import TransportError
from mavahrs.transports.base import TransportCounters, WriteQueue, describe_os_error
from mavahrs.transports.reconnect import Reconnector
from mavahrs.transports.url import Endpoint

__all__ = ["SerialTransport", "open_serial_port"]

_READ = 4096


def _errno_of(exc: BaseException) -> int | None:
    code = getattr(exc, "errno", None)
    if code is None and exc.args and isinstance(exc.args[0], int):
        code = exc.args[0]
    if code is None:  # pyserial wraps the OSError text
        text = str(exc)
        if "Permission denied" in text:
            code = errno.EACCES
        elif "No such file" in text:
            code = errno.ENOENT
        elif "exclusively lock" in text or "Resource temporarily unavailable" in text:
            code = errno.EAGAIN
        elif "Inappropriate ioctl" in text:  # "Could not configure port: (25, …)": a file that is not a tty
            code = errno.ENOTTY
    return code


def open_serial_port(device: str, baud: int, *, exclusive: bool = True) -> Any:
    """Open and configure a serial port with pyserial (non-blocking).

    Raises:
        TransportError: with the reason (permission denied, busy, no such device).
    """
    import serial  # pyserial; imported here so that the command line starts fast

    port = serial.Serial()
    port.port = device
    port.baudrate = baud
    port.timeout = 0
    port.write_timeout = 0
    if os.name == "posix":
        port.exclusive = exclusive
    try:
        port.open()
    except (serial.SerialException, OSError, ValueError) as exc:
        code = _errno_of(exc)
        reason = describe_os_error(OSError(code, str(exc))) if code is not None else str(exc).splitlines()[0]
        raise TransportError(f"cannot open serial port {device}: {reason}") from None
    return port


class SerialTransport:
    """A serial :class:`Endpoint` (see the module docstring).

    Raises:
        TransportError: the port cannot be opened the first time.
    """

    datagram = False

    def __init__(
        self,
        endpoint: Endpoint,
        *,
        reconnect_interval_s: float = 1.0,
        queue_bytes: int = 16384,
        exclusive: bool = True,
        logger: logging.Logger | None = None,
    ) -> None:
        if endpoint.kind != "serial":
            raise ValueError(f"not a serial endpoint: {endpoint}")
        self.endpoint = endpoint
        self.counters = TransportCounters()
        self._log = logger or logging.getLogger("mavahrs.transports")
        self._exclusive = exclusive
        self._queue = WriteQueue(queue_bytes, self.counters)
        self._reconnect = Reconnector(f"serial port {endpoint.device}", reconnect_interval_s, self._log)
        self._port: Any = open_serial_port(endpoint.device, endpoint.baud, exclusive=exclusive)
        self._fd = self._port_fd(self._port)
        self._poller = self._new_poller(self._fd)
        self._empty_reads = 0
        self.last_error = ""
        self._closed_for_good = False

    @staticmethod
    def _new_poller(fd: int) -> Any:
        poller = select.poll()
        if fd >= 0:
            poller.register(fd, select.POLLIN | select.POLLPRI | select.POLLERR | select.POLLHUP)
        return poller

    @staticmethod
    def _port_fd(port: Any) -> int:
        fd = getattr(port, "fd", None)
        return int(fd) if isinstance(fd, int) and fd >= 0 else -1

    # ------------------------------------------------------------------ info
    @property
    def connected(self) -> bool:
        return self._port is not None

    def describe(self) -> str:
        state = "" if self._port is not None else f" (lost: {self.last_error}; reopening)"
        return f"{self.endpoint.device} at {self.endpoint.baud} baud{state}"

    def fileno(self) -> int:
        return self._fd if self._port is not None else -1

    def filenos(self) -> tuple[int, ...]:
        return (self._fd,) if self._port is not None and self._fd >= 0 else ()

    # ------------------------------------------------------------------ connection
    def _lose(self, reason: str) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001 - the device is gone; closing may fail any way
                pass
            self.counters.disconnects += 1
        self._fd = -1
        self._queue.clear()
        self.last_error = reason
        self._reconnect.lost(time.monotonic(), reason)

    def maintain(self, now_s: float) -> None:
        """Reopen a lost device (once per interval); flush the write queue."""
        if self._port is not None:
            if len(self._queue):
                self._flush()
            return
        if self._closed_for_good or not self._reconnect.due(now_s):
            return
        try:
            port = open_serial_port(self.endpoint.device, self.endpoint.baud, exclusive=self._exclusive)
        except TransportError as exc:
            self.last_error = str(exc).rpartition(": ")[2]
            self._reconnect.failed(now_s, self.last_error)
            return
        self._port = port
        self._fd = self._port_fd(port)
        self._poller = self._new_poller(self._fd)
        self._empty_reads = 0
        self.counters.reconnects += 1
        self._reconnect.restored(now_s)

    def _flush(self) -> None:
        fd = self._fd
        if fd < 0:
            return
        try:
            self._queue.flush(lambda mv: os.write(fd, mv))
        except OSError as exc:
            self._lose(describe_os_error(exc))

    # ------------------------------------------------------------------ I/O
    def read(self, timeout_s: float) -> bytes:
        """Bytes that arrived within ``timeout_s``; ``b""`` on timeout or while the device is away."""
        if self._port is None:
            deadline = time.monotonic() + max(0.0, timeout_s)
            while self._port is None:
                now = time.monotonic()
                self.maintain(now)
                if self._port is None:
                    if now >= deadline:
                        return b""
                    time.sleep(min(0.05, deadline - now))
        if self._fd < 0:  # no descriptor (Windows): let pyserial wait
            return self._read_pyserial(timeout_s)
        poller = self._poller
        ready = poller.poll(max(0.0, timeout_s) * 1000.0)
        if not ready:
            return b""
        events = ready[0][1]
        try:
            data = os.read(self._fd, _READ)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as exc:  # EIO/ENXIO: unplugged
            self._lose(describe_os_error(exc))
            return b""
        if not data:
            if events & (select.POLLHUP | select.POLLERR | select.POLLNVAL):
                self._log.debug("%s: poll events %#x and no data", self.endpoint.device, events)
                self._lose("device disconnected (hang-up)")
                return b""
            # Readable but nothing read: a spurious wake-up (ptys have them) — unless it keeps
            # happening, which means another program is reading the same port.
            self._empty_reads += 1
            if self._empty_reads >= 1000:
                self._lose("the device reports data but returns none (another program reading this port?)")
            return b""
        self._empty_reads = 0
        self.counters.reads += 1
        self.counters.bytes_in += len(data)
        return data

    def _read_pyserial(self, timeout_s: float) -> bytes:
        port = self._port
        try:
            port.timeout = max(0.0, timeout_s)
            data = bytes(port.read(max(1, port.in_waiting)))
        except Exception as exc:  # noqa: BLE001 - pyserial raises SerialException/OSError on unplug
            self._lose(str(exc).splitlines()[0] if str(exc) else "device disconnected")
            return b""
        if data:
            self.counters.reads += 1
            self.counters.bytes_in += len(data)
        return data

    def write(self, data: bytes) -> None:
        c = self.counters
        c.writes += 1
        if self._port is None:
            c.writes_dropped += 1
            c.bytes_dropped += len(data)
            return
        self._queue.push(bytes(data))
        if self._fd >= 0:
            self._flush()
        else:
            try:
                self._queue.flush(self._port.write)
            except Exception as exc:  # noqa: BLE001
                self._lose(str(exc).splitlines()[0] if str(exc) else "device disconnected")

    def close(self) -> None:
        self._closed_for_good = True
        port, self._port = self._port, None
        self._fd = -1
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001
                pass

    def __enter__(self) -> SerialTransport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
