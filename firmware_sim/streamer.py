r"""The simulator's only I/O: links, real-time pacing and tlog writing.

Connection strings as pymavlink writes them:

* ``udpout:HOST:PORT`` — send to HOST:PORT (we are the client); replies come
  back to our ephemeral port;
* ``udpin:HOST:PORT`` — listen; send to the last peer heard from;
* ``tcpin:HOST:PORT`` — listen; one client at a time, a new one replaces the old;
* a serial device path (``/dev/ttyUSB0``, ``COM3``) at ``baud``;
* ``pty`` or ``pty:LINK`` — create a pseudo-terminal pair; the slave's path
  is printed (and symlinked to LINK) so a program can open it as a serial port.

Port 0 binds an ephemeral port; :meth:`Link.describe` gives the real one.
Every link survives its peer going away and coming back (UDP: nothing to do;
TCP: accept the next client; serial: reopen; pty: the slave may be closed
and reopened at will).

Real time: tick ``k`` is due at ``t₀ + k / loop_rate`` on ``time.perf_counter``
(absolute deadlines, no drift); input is serviced with ``select`` until the
deadline; a late loop runs at once, so late frames leave in a burst.  Beyond
``max_late_s`` behind (the process was stopped), the schedule is re-anchored
rather than bursting seconds of data.  Fast mode writes a ``.tlog`` as fast
as the simulation runs.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import select
import socket
import struct
import time
import tty
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mavahrs.errors import TransportError
from firmware_sim.endpoint import Endpoint

__all__ = [
    "Link",
    "UdpOutLink",
    "UdpInLink",
    "TcpInLink",
    "SerialLink",
    "PtyLink",
    "open_link",
    "tlog_record",
    "write_tlog",
    "run_realtime",
    "PacingStats",
    "Blackout",
    "write_stats_json",
]

log = logging.getLogger(__name__)


def tlog_record(t_unix_us: int, frame: bytes) -> bytes:
    """One tlog record: 8-byte big-endian UNIX time (µs) + the frame (MAVProxy's format)."""
    return struct.pack(">Q", t_unix_us) + frame


# ====================================================================== links
class Link:
    """A bidirectional byte link.  ``datagram``: reads return whole datagrams."""

    datagram = False

    def fileno_list(self) -> list[int]:
        return []

    def read(self) -> list[bytes]:
        """What has arrived (non-blocking); each item a datagram or a stream chunk."""
        return []

    def write(self, data: bytes) -> None:
        raise NotImplementedError

    def poll(self) -> None:
        """Periodic housekeeping (reconnect attempts); cheap."""

    def close(self) -> None:
        pass

    def describe(self) -> str:
        raise NotImplementedError

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _split_host_port(rest: str, spec: str) -> tuple[str, int]:
    host, sep, port = rest.rpartition(":")
    if not sep or not port.isdigit():
        raise TransportError(f"bad connection string {spec!r}: expected HOST:PORT after the scheme")
    return host or "0.0.0.0", int(port)


class _UdpBase(Link):
    datagram = True

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
        self.sock.setblocking(False)
        self.dropped_writes = 0

    def fileno_list(self) -> list[int]:
        return [self.sock.fileno()]

    def _recv_all(self) -> list[tuple[bytes, Any]]:
        out = []
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # ICMP port unreachable from an earlier send, etc.
                break
            out.append((data, addr))
        return out

    def _send(self, data: bytes, addr: Any) -> None:
        try:
            self.sock.sendto(data, addr)
        except OSError:  # peer gone / buffer full: a real radio link loses it too
            self.dropped_writes += 1

    def close(self) -> None:
        self.sock.close()


class UdpOutLink(_UdpBase):
    """``udpout:HOST:PORT``: we send to the peer, and read what comes back."""

    def __init__(self, host: str, port: int) -> None:
        super().__init__()
        self.addr = (host, port)
        try:
            self.sock.bind(("0.0.0.0" if host not in ("127.0.0.1", "localhost") else "127.0.0.1", 0))
        except OSError as exc:
            raise TransportError(f"udpout:{host}:{port}: cannot bind a local port: {exc}") from exc

    def read(self) -> list[bytes]:
        return [d for d, _ in self._recv_all()]

    def write(self, data: bytes) -> None:
        self._send(data, self.addr)

    def describe(self) -> str:
        return f"udpout:{self.addr[0]}:{self.addr[1]} (from port {self.sock.getsockname()[1]})"


class UdpInLink(_UdpBase):
    """``udpin:HOST:PORT``: listen; reply to whoever spoke last."""

    def __init__(self, host: str, port: int) -> None:
        super().__init__()
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            raise TransportError(f"udpin:{host}:{port}: cannot bind ({exc.strerror}); is the port in use?") from exc
        self.peer: Any = None

    def read(self) -> list[bytes]:
        got = self._recv_all()
        if got:
            self.peer = got[-1][1]
        return [d for d, _ in got]

    def write(self, data: bytes) -> None:
        if self.peer is not None:
            self._send(data, self.peer)

    def describe(self) -> str:
        host, port = self.sock.getsockname()
        return f"udpin:{host}:{port}"


class TcpInLink(Link):
    """``tcpin:HOST:PORT``: a TCP server with one client at a time."""

    def __init__(self, host: str, port: int) -> None:
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.server.bind((host, port))
        except OSError as exc:
            self.server.close()
            raise TransportError(f"tcpin:{host}:{port}: cannot bind ({exc.strerror}); is the port in use?") from exc
        self.server.listen(2)
        self.server.setblocking(False)
        self.client: socket.socket | None = None
        self.dropped_writes = 0
        self.new_client = False

    def fileno_list(self) -> list[int]:
        fds = [self.server.fileno()]
        if self.client is not None:
            fds.append(self.client.fileno())
        return fds

    def _drop_client(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None

    def read(self) -> list[bytes]:
        try:
            conn, _ = self.server.accept()
        except (BlockingIOError, InterruptedError):
            pass
        else:
            self._drop_client()
            conn.setblocking(False)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.client = conn
            self.new_client = True
        out: list[bytes] = []
        while self.client is not None:
            try:
                data = self.client.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self._drop_client()
                break
            if not data:
                self._drop_client()
                break
            out.append(data)
        return out

    def write(self, data: bytes) -> None:
        if self.client is None:
            return
        try:
            sent = self.client.send(data)
            if sent < len(data):  # a full socket buffer: the frames are lost, as on a slow link
                self.dropped_writes += 1
        except (BlockingIOError, InterruptedError):
            self.dropped_writes += 1
        except OSError:
            self._drop_client()

    def close(self) -> None:
        self._drop_client()
        self.server.close()

    def describe(self) -> str:
        host, port = self.server.getsockname()
        return f"tcpin:{host}:{port}"


class SerialLink(Link):
    """A serial device through pyserial; reopened after an unplug."""

    def __init__(self, path: str, baud: int) -> None:
        import serial  # pyserial, a core dependency

        self._serial_mod = serial
        self.path = path
        self.baud = baud
        self.port: Any = None
        self._next_try = 0.0
        self.dropped_writes = 0
        self._open(raise_errors=True)

    def _open(self, raise_errors: bool = False) -> None:
        try:
            self.port = self._serial_mod.Serial(self.path, self.baud, timeout=0, write_timeout=0)
        except (OSError, self._serial_mod.SerialException) as exc:
            self.port = None
            if raise_errors:
                raise TransportError(f"{self.path}: cannot open serial port: {exc}") from exc
            self._next_try = time.monotonic() + 1.0

    def fileno_list(self) -> list[int]:
        return [self.port.fileno()] if self.port is not None else []

    def poll(self) -> None:
        if self.port is None and time.monotonic() >= self._next_try:
            self._open()

    def _lost(self, exc: BaseException) -> None:
        log.warning("%s: serial port lost (%s); retrying every second", self.path, exc)
        try:
            self.port.close()
        except Exception:  # noqa: BLE001 - already broken
            pass
        self.port = None
        self._next_try = time.monotonic() + 1.0

    def read(self) -> list[bytes]:
        if self.port is None:
            return []
        try:
            n = self.port.in_waiting
            return [self.port.read(n)] if n else []
        except (OSError, self._serial_mod.SerialException) as exc:
            self._lost(exc)
            return []

    def write(self, data: bytes) -> None:
        if self.port is None:
            return
        try:
            self.port.write(data)
        except self._serial_mod.SerialTimeoutException:
            self.dropped_writes += 1
        except (OSError, self._serial_mod.SerialException) as exc:
            self._lost(exc)

    def close(self) -> None:
        if self.port is not None:
            self.port.close()

    def describe(self) -> str:
        return f"{self.path} @ {self.baud} baud"


class PtyLink(Link):
    """A pseudo-terminal pair; the peer opens :attr:`slave_path` as a serial port.

    We hold only the master.  While no one has the slave open, reads fail with
    EIO: the link then polls every 50 ms instead of selecting (no busy loop)
    and writes go nowhere, as on a real port with nothing attached.
    """

    def __init__(self, link_path: str | None = None) -> None:
        self.master, slave = os.openpty()
        self.slave_path = os.ttyname(slave)
        tty.setraw(slave)  # no echo, no CR/LF translation: bytes stay bytes
        os.close(slave)
        os.set_blocking(self.master, False)
        self.link_path = link_path
        if link_path:
            try:
                if os.path.islink(link_path):
                    os.unlink(link_path)
                os.symlink(self.slave_path, link_path)
            except OSError as exc:
                os.close(self.master)
                raise TransportError(f"pty: cannot create the link {link_path}: {exc}") from exc
        self.peer_open = False
        self._next_probe = 0.0
        self._pending: list[bytes] = []
        self.dropped_writes = 0

    def fileno_list(self) -> list[int]:
        return [self.master] if self.peer_open else []

    def poll(self) -> None:
        now = time.monotonic()
        if not self.peer_open and now >= self._next_probe:
            self._next_probe = now + 0.05
            self._pending.extend(self._read_raw())

    def _read_raw(self) -> list[bytes]:
        out = []
        while True:
            try:
                data = os.read(self.master, 65536)
            except BlockingIOError:
                self.peer_open = True
                break
            except OSError as exc:
                if exc.errno == errno.EIO:  # nobody has the slave open
                    self.peer_open = False
                    break
                raise
            if not data:
                break
            self.peer_open = True
            out.append(data)
        return out

    def read(self) -> list[bytes]:
        pending, self._pending = self._pending, []
        if not self.peer_open:
            return pending
        return pending + self._read_raw()

    def write(self, data: bytes) -> None:
        try:
            os.write(self.master, data)
        except BlockingIOError:
            self.dropped_writes += 1  # peer not reading: the bytes are lost
        except OSError as exc:
            if exc.errno not in (errno.EIO, errno.EAGAIN):
                raise
            self.dropped_writes += 1

    def close(self) -> None:
        if self.link_path and os.path.islink(self.link_path):
            try:
                os.unlink(self.link_path)
            except OSError:
                pass
        os.close(self.master)

    def describe(self) -> str:
        return f"pty {self.slave_path}" + (f" (linked as {self.link_path})" if self.link_path else "")


def open_link(spec: str, *, baud: int = 115200) -> Link:
    """Open a link from a pymavlink-style connection string (see the module doc)."""
    scheme, sep, rest = spec.partition(":")
    if spec == "pty" or scheme == "pty":
        return PtyLink(rest or None)
    if sep and scheme in ("udpout", "udp", "udpin", "tcpin"):
        host, port = _split_host_port(rest, spec)
        if scheme == "udpout":
            return UdpOutLink(host, port)
        if scheme in ("udpin", "udp"):
            return UdpInLink(host, port)
        return TcpInLink(host, port)
    if spec.startswith("/") or spec.upper().startswith("COM"):
        path, _, b = spec.partition(",")
        return SerialLink(path, int(b) if b.isdigit() else baud)
    raise TransportError(
        f"unknown connection {spec!r}: use udpout:HOST:PORT, udpin:HOST:PORT, tcpin:HOST:PORT, a serial path or pty"
    )


# ====================================================================== running
@dataclass(frozen=True)
class Blackout:
    """A link outage: nothing is sent or received from ``start_s`` for ``duration_s`` (simulation time)."""

    start_s: float
    duration_s: float

    def covers(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.start_s + self.duration_s


@dataclass
class PacingStats:
    ticks: int = 0
    late_ticks: int = 0  # ticks run after their deadline by more than one loop period
    max_late_s: float = 0.0
    reanchors: int = 0
    frames: int = 0
    bytes: int = 0
    wall_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)


def _n_ticks(endpoint: Endpoint, duration_s: float | None) -> int | None:
    if duration_s is None or duration_s <= 0:
        return None
    return int(round(duration_s * endpoint.sim.settings.loop_rate_hz))


def write_tlog(
    endpoint: Endpoint,
    out: BinaryIO | str | Path,
    duration_s: float,
    *,
    blackouts: Iterable[Blackout] = (),
) -> PacingStats:
    """Run ``duration_s`` of simulation as fast as possible into a tlog."""
    n = _n_ticks(endpoint, duration_s)
    if n is None:
        raise ValueError("a tlog needs a positive duration")
    stats = PacingStats()
    epoch = endpoint.settings.epoch_unix_us
    outs = list(blackouts)
    rate = endpoint.sim.settings.loop_rate_hz
    t0 = time.perf_counter()
    own = not hasattr(out, "write")
    fh: BinaryIO = open(out, "wb") if own else out  # type: ignore[arg-type, assignment]
    try:
        parts: list[bytes] = []
        for _ in range(n):
            k = endpoint.tick
            frames = endpoint.step()
            if outs and any(b.covers(k / rate) for b in outs):
                continue
            for t_us, frame in frames:
                parts.append(struct.pack(">Q", epoch + t_us))
                parts.append(frame)
                stats.frames += 1
                stats.bytes += len(frame)
            if len(parts) > 4096:
                fh.write(b"".join(parts))
                parts.clear()
        fh.write(b"".join(parts))
        fh.flush()
    finally:
        if own:
            fh.close()
    stats.ticks = n
    stats.wall_s = time.perf_counter() - t0
    return stats


def run_realtime(
    endpoint: Endpoint,
    link: Link,
    duration_s: float | None = None,
    *,
    should_stop: Callable[[], bool] = lambda: False,
    blackouts: Iterable[Blackout] = (),
    tlog: BinaryIO | None = None,
    max_late_s: float = 0.5,
    status_every_s: float = 0.0,
) -> PacingStats:
    """Stream in real time over ``link`` until ``duration_s`` of simulation (None = forever)
    or ``should_stop()``; also records everything sent and received into ``tlog`` if given."""
    n = _n_ticks(endpoint, duration_s)
    rate = endpoint.sim.settings.loop_rate_hz
    period_s = 1.0 / rate
    stats = PacingStats()
    outs = list(blackouts)
    epoch = endpoint.settings.epoch_unix_us
    start = time.perf_counter()
    t0 = start
    k_start = endpoint.tick
    next_status = start + status_every_s if status_every_s > 0 else float("inf")
    next_poll = start
    while (n is None or stats.ticks < n) and not should_stop():
        k = endpoint.tick
        deadline = t0 + (k - k_start) * period_s
        sim_t = k / rate
        dark = bool(outs) and any(b.covers(sim_t) for b in outs)
        # service input until the deadline (at least one non-blocking look per tick)
        while True:
            now = time.perf_counter()
            if now >= next_poll:
                link.poll()
                next_poll = now + 0.05
            timeout = deadline - now
            fds = link.fileno_list()
            if fds:
                try:
                    ready, _, _ = select.select(fds, [], [], max(timeout, 0.0))
                except InterruptedError:
                    ready = []
            else:
                if timeout > 0:
                    time.sleep(min(timeout, 0.05))
                ready = []
            if ready or not fds:
                for data in link.read():
                    if dark:
                        continue
                    if tlog is not None:
                        tlog.write(tlog_record(epoch + endpoint.now_us, data))
                    for reply in endpoint.receive(data, datagram=link.datagram):
                        link.write(reply)
                        if tlog is not None:
                            tlog.write(tlog_record(epoch + endpoint.now_us, reply))
            if time.perf_counter() >= deadline:
                break
        late = time.perf_counter() - deadline
        if late > period_s:
            stats.late_ticks += 1
            stats.max_late_s = max(stats.max_late_s, late)
            if late > max_late_s:  # stopped or starved: re-anchor instead of bursting seconds of data
                t0 += late
                stats.reanchors += 1
                log.warning("fell %.2f s behind real time; re-anchoring the schedule", late)
        frames = endpoint.step()
        stats.ticks += 1
        if frames and not dark:
            data = b"".join(f for _, f in frames)
            link.write(data)
            stats.frames += len(frames)
            stats.bytes += len(data)
            if tlog is not None:
                for t_us, f in frames:
                    tlog.write(tlog_record(epoch + t_us, f))
        if time.perf_counter() >= next_status:
            next_status += status_every_s
            log.info(
                "t=%.1f s  frames=%d  late ticks=%d (max %.1f ms)",
                sim_t, stats.frames, stats.late_ticks, stats.max_late_s * 1e3,
            )
    stats.wall_s = time.perf_counter() - start
    stats.extra["dropped_writes"] = getattr(link, "dropped_writes", 0)
    return stats


def write_stats_json(path: str | Path, endpoint: Endpoint, stats: PacingStats, link: str) -> None:
    """Write the run's counters (what was received, ACKed, sent; pacing) as JSON."""
    data = {"link": link, **endpoint.summary(), "pacing": {k: v for k, v in stats.__dict__.items()}}
    Path(path).write_text(json.dumps(data, indent=2, default=str), encoding="utf-8")
