r"""UDP links: ``udpin:`` (listen, reply to the last sender), ``udpout:`` and ``udpbcast:``.

One ``read`` returns one datagram, so the codec parses each on its own and
junk in one datagram never swallows the frames of the next.  Sockets are
non-blocking: a datagram that cannot be sent right now (socket buffer full,
no peer known yet, network down) is dropped and counted, never queued —
stale attitude is worth nothing.  Both directions work on every UDP link:
``udpout:`` reads the replies that come back to its ephemeral port, as
pymavlink's ``mavudp`` does, and ``udpin:`` learns its peer from what it
receives (a restarted peer on a new port is followed at once, and counted in
``counters.reconnects`` when it appears after half a second of silence, so
the service knows to ask it for its streams again).  Datagrams the kernel
drops at a full receive buffer (the process not scheduled for a while) are
counted too, in ``counters.kernel_dropped`` (Linux ``SO_RXQ_OVFL``: the
kernel's running drop count comes with each datagram read; while none arrives,
``maintain`` reads the same count from ``/proc/net/udp`` once a second, so
drops just before a stream stopped are counted too).
"""

from __future__ import annotations

import logging
import os
import socket
import struct
import sys
import time
from typing import Any

from mavahrs.errors import TransportError
from mavahrs.transports.base import TransportCounters, describe_os_error, wait_readable
from mavahrs.transports.url import Endpoint

__all__ = ["UdpTransport", "resolve"]

_MAX_DATAGRAM = 65535
#: Linux: the socket's running count of datagrams dropped at a full receive buffer comes with each read
_SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40) if sys.platform.startswith("linux") else None
_ANC_SIZE = socket.CMSG_SPACE(4) if hasattr(socket, "CMSG_SPACE") else 0
#: Linux: the kernel's socket tables, whose last column is the same running drop count
_PROC_UDP = ("/proc/net/udp", "/proc/net/udp6")
#: with no datagram for this long, the idle link's drop count is read from :data:`_PROC_UDP` (at most this often), s
IDLE_DROPS_READ_S = 1.0


def proc_udp_drops(inode: int) -> int | None:
    """The kernel's drop count of the UDP socket with this inode, from ``/proc/net/udp[6]``; None if not found."""
    key = str(inode)
    for path in _PROC_UDP:
        try:
            with open(path, encoding="ascii", errors="replace") as f:
                next(f, None)  # the header
                for line in f:
                    fields = line.split()
                    if len(fields) >= 13 and fields[9] == key:
                        return int(fields[-1])
        except (OSError, ValueError):
            continue
    return None


def resolve(host: str, port: int, what: str) -> tuple[int, Any]:
    """(address family, socket address) for ``host:port`` (UDP)."""
    try:
        infos = socket.getaddrinfo(host, port, 0, socket.SOCK_DGRAM)
    except OSError as exc:
        raise TransportError(f"{what}: cannot resolve host {host!r}: {describe_os_error(exc)}") from None
    family, _, _, _, addr = infos[0]
    return family, addr


class UdpTransport:
    """A UDP link for an ``udpin``, ``udpout`` or ``udpbcast`` :class:`Endpoint`.

    Raises:
        TransportError: the local address cannot be bound / the host not resolved.
    """

    datagram = True

    def __init__(self, endpoint: Endpoint, *, logger: logging.Logger | None = None) -> None:
        if endpoint.kind not in ("udpin", "udpout", "udpbcast"):
            raise ValueError(f"not a UDP endpoint: {endpoint}")
        self.endpoint = endpoint
        self.counters = TransportCounters()
        self._log = logger or logging.getLogger("mavahrs.transports")
        self._listen = endpoint.kind == "udpin"
        family, addr = resolve(endpoint.host, endpoint.port, endpoint.text)
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            if self._listen:
                sock.bind(addr)
                self.peer: Any = None
            else:
                if endpoint.kind == "udpbcast":
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
                self.peer = addr
        except OSError as exc:
            sock.close()
            verb = "listen on" if self._listen else "send to"
            raise TransportError(f"cannot {verb} {endpoint.text}: {describe_os_error(exc)}") from None
        self._rxq_ovfl = False
        if _SO_RXQ_OVFL is not None and _ANC_SIZE:
            try:
                sock.setsockopt(socket.SOL_SOCKET, _SO_RXQ_OVFL, 1)
                self._rxq_ovfl = True
            except OSError:
                pass  # not offered here: kernel drops stay uncounted (0)
        self._sock: socket.socket | None = sock
        self._fds = (sock.fileno(),)
        self._warned_send = False
        self._last_rx_s = 0.0
        self._last_data_s = time.monotonic()
        self._last_drops_read_s = self._last_data_s
        #: ``udpin``: a sender that appears after this much silence counts as a restarted peer, s
        self.restart_silence_s = 0.5

    # ------------------------------------------------------------------ info
    @property
    def local_address(self) -> tuple[str, int]:
        """The bound (host, port); for ``udpout`` known after the first send."""
        assert self._sock is not None
        name = self._sock.getsockname()
        return str(name[0]), int(name[1])

    def describe(self) -> str:
        """The endpoint as given; a listening socket bound to port 0 shows the port it got."""
        peer = "" if self.peer is None else f" (peer {self.peer[0]}:{self.peer[1]})"
        text = self.endpoint.text
        if self._listen and self._sock is not None and text.endswith(":0"):
            text = f"{text[:-1]}{self.local_address[1]}"
        return f"{text}{peer}"

    def fileno(self) -> int:
        return self._fds[0] if self._sock is not None else -1

    def filenos(self) -> tuple[int, ...]:
        return self._fds if self._sock is not None else ()

    # ------------------------------------------------------------------ I/O
    def read(self, timeout_s: float) -> bytes:
        """One datagram, or ``b""`` when none arrives within ``timeout_s``."""
        sock = self._sock
        if sock is None:
            return b""
        if timeout_s > 0 and not wait_readable(self._fds, timeout_s):
            return b""
        c = self.counters
        try:
            if self._rxq_ovfl:
                data, anc, _, addr = sock.recvmsg(_MAX_DATAGRAM, _ANC_SIZE)
                for level, kind, value in anc:
                    if level == socket.SOL_SOCKET and kind == _SO_RXQ_OVFL and len(value) >= 4:
                        # the kernel's running total when this datagram was queued (an idle link's read may be later)
                        c.kernel_dropped = max(c.kernel_dropped, struct.unpack("=I", value[:4])[0])
            else:
                data, addr = sock.recvfrom(_MAX_DATAGRAM)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as exc:  # e.g. ICMP errors reported on some platforms
            self._log.debug("%s: receive error: %s", self.endpoint.text, describe_os_error(exc))
            return b""
        now = time.monotonic()
        self._last_data_s = now
        if self._listen:
            if addr != self.peer:
                # A new sender after the previous one fell silent is a restarted peer: count it as a
                # reconnection (the service then asks for its streams again).  Two peers talking at
                # once are not: replies simply follow the last sender.
                if self.peer is not None and now - self._last_rx_s >= self.restart_silence_s:
                    c.reconnects += 1
                    self._log.info("%s: new peer %s:%s", self.endpoint.text, addr[0], addr[1])
                self.peer = addr  # reply to the last sender
            self._last_rx_s = now
        c.reads += 1
        c.bytes_in += len(data)
        return data

    def write(self, data: bytes) -> None:
        """Send one datagram now, or drop and count it."""
        c = self.counters
        c.writes += 1
        sock, peer = self._sock, self.peer
        if sock is None or peer is None:
            c.writes_dropped += 1
            c.bytes_dropped += len(data)
            return
        try:
            c.bytes_out += sock.sendto(data, peer)
        except OSError as exc:  # buffer full, network down, ICMP refusal: drop
            c.writes_dropped += 1
            c.bytes_dropped += len(data)
            if not self._warned_send and not isinstance(exc, BlockingIOError):
                self._warned_send = True
                self._log.warning(
                    "%s: cannot send (%s); dropping until it works again", self.endpoint.text, describe_os_error(exc)
                )
        else:
            self._warned_send = False

    def maintain(self, now_s: float) -> None:
        """No connection to keep; on an idle link (no datagram for :data:`IDLE_DROPS_READ_S`), the kernel's drop
        count read from ``/proc/net/udp`` once a second: the drops of a buffer that overflowed just before the
        stream stopped come with no datagram (``now_s``: ``time.monotonic()``)."""
        sock = self._sock
        if (
            sock is None
            or not self._rxq_ovfl
            or now_s - self._last_data_s < IDLE_DROPS_READ_S
            or now_s - self._last_drops_read_s < IDLE_DROPS_READ_S
        ):
            return
        self._last_drops_read_s = now_s
        try:
            drops = proc_udp_drops(os.fstat(sock.fileno()).st_ino)
        except OSError:
            return
        if drops is not None and drops > self.counters.kernel_dropped:
            self.counters.kernel_dropped = drops

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> UdpTransport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
