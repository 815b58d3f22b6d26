r"""TCP links: ``tcp:HOST:PORT`` (client, reconnects) and ``tcpin:HOST:PORT`` (server).

Both are byte streams (the codec parses them as streams).  Writes go through
a bounded :class:`~mavahrs.transports.base.WriteQueue` per connection: a slow
or stalled reader never blocks the service and never grows its memory — the
oldest queued frames are dropped and counted instead.

* ``tcp:`` — the first connection attempt waits up to ``connect_timeout_s``;
  if it fails, or the server goes away later, the link retries every
  ``reconnect_interval_s`` with a non-blocking connect (finished in
  :meth:`TcpClient.maintain`), logging the loss and the recovery once.
* ``tcpin:`` — accepts up to ``max_clients`` connections; writes go to every
  client; reads return what the *first* connected client sends (an
  autopilot on a master link), other clients' input is read and discarded
  (counted as ``ignored_reads``).
"""

from __future__ import annotations

import errno
import logging
import select
import socket
import time
from typing import Any

from mavahrs.errors import TransportError
from mavahrs.transports.base import TransportCounters, WriteQueue, describe_os_error, wait_readable
from mavahrs.transports.reconnect import Reconnector
from mavahrs.transports.url import Endpoint

__all__ = ["TcpClient", "TcpServer"]

_RECV = 65536


def _resolve(host: str, port: int, what: str, passive: bool = False) -> tuple[int, Any]:
    try:
        infos = socket.getaddrinfo(
            host, port, 0, socket.SOCK_STREAM, 0, socket.AI_PASSIVE if passive else 0
        )
    except OSError as exc:
        raise TransportError(f"{what}: cannot resolve host {host!r}: {describe_os_error(exc)}") from None
    family, _, _, _, addr = infos[0]
    return family, addr


def _tune(sock: socket.socket) -> None:
    sock.setblocking(False)
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    except OSError:
        pass


class TcpClient:
    """``tcp:HOST:PORT``: a TCP client that keeps reconnecting.

    Raises:
        TransportError: only when the host name cannot be resolved.
    """

    datagram = False

    def __init__(
        self,
        endpoint: Endpoint,
        *,
        reconnect_interval_s: float = 1.0,
        connect_timeout_s: float = 2.0,
        queue_bytes: int = 65536,
        logger: logging.Logger | None = None,
    ) -> None:
        if endpoint.kind != "tcp":
            raise ValueError(f"not a tcp: endpoint: {endpoint}")
        self.endpoint = endpoint
        self.counters = TransportCounters()
        self._log = logger or logging.getLogger("mavahrs.transports")
        self._family, self._addr = _resolve(endpoint.host, endpoint.port, endpoint.text)
        self._queue = WriteQueue(queue_bytes, self.counters)
        self._reconnect = Reconnector(endpoint.text, reconnect_interval_s, self._log)
        self._sock: socket.socket | None = None  # connected
        self._pending: socket.socket | None = None  # non-blocking connect in progress
        self._closed = False
        self.last_error = ""
        try:
            sock = socket.create_connection(self._addr[:2], timeout=connect_timeout_s)
        except OSError as exc:
            self.last_error = describe_os_error(exc)
            self._reconnect.lost(time.monotonic(), self.last_error)
        else:
            _tune(sock)
            self._sock = sock

    # ------------------------------------------------------------------ info
    @property
    def connected(self) -> bool:
        return self._sock is not None

    def describe(self) -> str:
        if self._sock is not None:
            return self.endpoint.text
        return f"{self.endpoint.text} (not connected: {self.last_error or 'connecting'})"

    def fileno(self) -> int:
        return self._sock.fileno() if self._sock is not None else -1

    def filenos(self) -> tuple[int, ...]:
        return (self._sock.fileno(),) if self._sock is not None else ()

    # ------------------------------------------------------------------ connection
    def _lose(self, reason: str) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            self.counters.disconnects += 1
        self._queue.clear()
        self.last_error = reason
        self._reconnect.lost(time.monotonic(), reason)

    def maintain(self, now_s: float) -> None:
        """Start or finish a reconnection attempt (non-blocking); flush the write queue."""
        if self._closed:
            return
        if self._sock is not None:
            self._flush()
            return
        if self._pending is not None:
            _, writable, _ = select.select([], [self._pending], [], 0)
            if not writable:
                if self._reconnect.due(now_s):  # took a whole interval: give up on this attempt
                    self._pending.close()
                    self._pending = None
                    self._reconnect.failed(now_s, "timed out")
                return
            err = self._pending.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
            sock, self._pending = self._pending, None
            if err:
                sock.close()
                self.last_error = describe_os_error(OSError(err, ""))
                self._reconnect.failed(now_s, self.last_error)
                return
            _tune(sock)
            self._sock = sock
            self.counters.reconnects += 1
            self._reconnect.restored(now_s)
            return
        if self._reconnect.due(now_s):
            sock = socket.socket(self._family, socket.SOCK_STREAM)
            sock.setblocking(False)
            rc = sock.connect_ex(self._addr)
            if rc in (0, errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EALREADY):
                self._pending = sock
                if rc == 0:
                    self.maintain(now_s)
            else:
                sock.close()
                self.last_error = describe_os_error(OSError(rc, ""))
                self._reconnect.failed(now_s, self.last_error)

    def _flush(self) -> None:
        sock = self._sock
        if sock is None:
            return
        try:
            self._queue.flush(sock.send)
        except OSError as exc:
            self._lose(describe_os_error(exc))

    # ------------------------------------------------------------------ I/O
    def read(self, timeout_s: float) -> bytes:
        """Bytes that arrived within ``timeout_s`` (``b""`` on timeout or while reconnecting)."""
        deadline = time.monotonic() + max(0.0, timeout_s)
        while True:
            sock = self._sock
            if sock is None:
                now = time.monotonic()
                self.maintain(now)
                if self._sock is None:
                    if now >= deadline:
                        return b""
                    wait = min(deadline - now, 0.05)
                    if self._pending is not None:
                        select.select([], [self._pending], [], wait)
                    else:
                        time.sleep(wait)
                    continue
                sock = self._sock
            remaining = deadline - time.monotonic()
            if remaining > 0 and not wait_readable((sock.fileno(),), remaining):
                return b""
            try:
                data = sock.recv(_RECV)
            except (BlockingIOError, InterruptedError):
                return b""
            except OSError as exc:
                self._lose(describe_os_error(exc))
                return b""
            if not data:
                self._lose("connection closed by the peer")
                return b""
            self.counters.reads += 1
            self.counters.bytes_in += len(data)
            return data

    def write(self, data: bytes) -> None:
        c = self.counters
        c.writes += 1
        if self._sock is None:
            c.writes_dropped += 1
            c.bytes_dropped += len(data)
            return
        self._queue.push(bytes(data))
        self._flush()

    def close(self) -> None:
        self._closed = True
        for s in (self._sock, self._pending):
            if s is not None:
                s.close()
        self._sock = self._pending = None

    def __enter__(self) -> TcpClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Client:
    __slots__ = ("sock", "addr", "queue")

    def __init__(self, sock: socket.socket, addr: Any, queue: WriteQueue) -> None:
        self.sock, self.addr, self.queue = sock, addr, queue


class TcpServer:
    """``tcpin:HOST:PORT``: a TCP server; clients may connect and leave at any time.

    Raises:
        TransportError: the address cannot be bound (in use, not local, …).
    """

    datagram = False

    def __init__(
        self,
        endpoint: Endpoint,
        *,
        max_clients: int = 8,
        queue_bytes: int = 65536,
        logger: logging.Logger | None = None,
    ) -> None:
        if endpoint.kind != "tcpin":
            raise ValueError(f"not a tcpin: endpoint: {endpoint}")
        self.endpoint = endpoint
        self.counters = TransportCounters()
        self.max_clients = int(max_clients)
        self._queue_bytes = int(queue_bytes)
        self._log = logger or logging.getLogger("mavahrs.transports")
        family, addr = _resolve(endpoint.host, endpoint.port, endpoint.text, passive=True)
        sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(addr)
            sock.listen(max(1, self.max_clients))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise TransportError(f"cannot listen on {endpoint.text}: {describe_os_error(exc)}") from None
        self._listener: socket.socket | None = sock
        self._clients: list[_Client] = []
        self._fds: tuple[int, ...] = (sock.fileno(),)

    # ------------------------------------------------------------------ info
    @property
    def local_address(self) -> tuple[str, int]:
        assert self._listener is not None
        name = self._listener.getsockname()
        return str(name[0]), int(name[1])

    @property
    def client_count(self) -> int:
        return len(self._clients)

    def describe(self) -> str:
        return f"{self.endpoint.text} ({len(self._clients)} client{'' if len(self._clients) == 1 else 's'})"

    def fileno(self) -> int:
        return self._fds[0] if self._fds else -1

    def filenos(self) -> tuple[int, ...]:
        return self._fds

    def _refresh_fds(self) -> None:
        if self._listener is None:
            self._fds = ()
        else:
            self._fds = (self._listener.fileno(), *(c.sock.fileno() for c in self._clients))

    # ------------------------------------------------------------------ clients
    def _accept(self) -> None:
        assert self._listener is not None
        while True:
            try:
                sock, addr = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. EMFILE: keep serving the clients we have
                self._log.warning("%s: cannot accept a client: %s", self.endpoint.text, describe_os_error(exc))
                return
            if len(self._clients) >= self.max_clients:
                self._log.warning(
                    "%s: refusing client %s: already %d clients", self.endpoint.text, addr, self.max_clients
                )
                sock.close()
                continue
            _tune(sock)
            self._clients.append(_Client(sock, addr, WriteQueue(self._queue_bytes, self.counters)))
            self.counters.reconnects += 1
            self._log.info("%s: client %s connected", self.endpoint.text, addr[:2])
            self._refresh_fds()

    def _drop(self, client: _Client, reason: str) -> None:
        client.queue.clear()
        client.sock.close()
        self._clients.remove(client)
        self.counters.disconnects += 1
        self._log.info("%s: client %s left (%s)", self.endpoint.text, client.addr[:2], reason)
        self._refresh_fds()

    # ------------------------------------------------------------------ I/O
    def read(self, timeout_s: float) -> bytes:
        """What the first client sent within ``timeout_s``; accepts new clients on the way."""
        if self._listener is None:
            return b""
        deadline = time.monotonic() + max(0.0, timeout_s)
        while True:
            ready = wait_readable(self._fds, max(0.0, deadline - time.monotonic()))
            if not ready:
                return b""
            result = b""
            for fd in ready:
                if fd == self._fds[0]:
                    self._accept()
                    continue
                client = next((c for c in self._clients if c.sock.fileno() == fd), None)
                if client is None:
                    continue
                try:
                    data = client.sock.recv(_RECV)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError as exc:
                    self._drop(client, describe_os_error(exc))
                    continue
                if not data:
                    self._drop(client, "closed by the peer")
                    continue
                if client is self._clients[0] and not result:
                    self.counters.reads += 1
                    self.counters.bytes_in += len(data)
                    result = data
                else:
                    self.counters.ignored_reads += 1
            if result or time.monotonic() >= deadline:
                return result

    def write(self, data: bytes) -> None:
        c = self.counters
        c.writes += 1
        if not self._clients:
            c.writes_dropped += 1
            c.bytes_dropped += len(data)
            return
        chunk = bytes(data)
        for client in list(self._clients):
            client.queue.push(chunk)
            try:
                client.queue.flush(client.sock.send)
            except OSError as exc:
                self._drop(client, describe_os_error(exc))

    def maintain(self, now_s: float) -> None:
        for client in list(self._clients):
            if len(client.queue):
                try:
                    client.queue.flush(client.sock.send)
                except OSError as exc:
                    self._drop(client, describe_os_error(exc))

    def close(self) -> None:
        for client in self._clients:
            client.sock.close()
        self._clients.clear()
        if self._listener is not None:
            self._listener.close()
            self._listener = None
        self._refresh_fds()

    def __enter__(self) -> TcpServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
