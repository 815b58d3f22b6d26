r"""The simulator's only I/O: links, real-time pacing and tlog writing.

Links: every pymavlink/MAVProxy connection string that
:func:`mavahrs.transports.open_transport` opens (``udpout:HOST:PORT``,
``udpin:HOST:PORT`` replying to the last sender, ``tcpin:HOST:PORT``, ``tcp:``,
a serial path ``/dev/ttyUSB0[,BAUD]``), plus ``pty`` / ``pty:LINK``: a
pseudo-terminal pair created here whose slave path is printed (and
symlinked to LINK) so a program can open it as a serial device.

Port 0 binds an ephemeral port; :func:`describe_link` gives the real one.
Every link survives its peer going away and coming back (UDP: nothing to do;
TCP: the next client is accepted; serial: reopened; pty: the slave may be
closed and reopened at will).

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
import time
import tty
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from firmware_sim.endpoint import Endpoint
from mavahrs.errors import TransportError
from mavahrs.protocol.tlog import tlog_record
from mavahrs.transports import DEFAULT_BAUD, Transport, TransportCounters, open_transport
from mavahrs.transports.base import WriteQueue

__all__ = [
    "PtyLink",
    "open_link",
    "describe_link",
    "write_tlog",
    "run_realtime",
    "PacingStats",
    "Blackout",
    "write_stats_json",
]

log = logging.getLogger(__name__)


# ====================================================================== links
def describe_link(t: Any) -> str:
    """``describe()`` plus the real bound port of a server/udp link (port 0 binds an ephemeral one)."""
    desc = str(t.describe())
    addr = getattr(t, "local_address", None)
    kind = getattr(getattr(t, "endpoint", None), "kind", "")
    if addr and kind in ("udpin", "tcpin"):
        return f"{kind}:{addr[0]}:{addr[1]}"
    return desc


class PtyLink:
    """A pseudo-terminal pair; the peer opens :attr:`slave_path` as a serial port.

    Follows :class:`mavahrs.transports.base.Transport`.  We hold only the
    master.  While no one has the slave open, reads fail with EIO: the link
    then offers no descriptor to wait on and probes every 50 ms in
    :meth:`maintain` (no busy loop), and writes go nowhere, as on a real port
    with nothing attached.
    """

    datagram = False

    def __init__(self, link_path: str | None = None, *, queue_bytes: int = 16384) -> None:
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
        self._pending: list[bytes] = []
        self.counters = TransportCounters()
        # like a UART's transmit buffer: rides out a reader that stalls briefly, then drops the oldest
        self._queue = WriteQueue(queue_bytes, self.counters)

    def fileno(self) -> int:
        return self.master if self.peer_open else -1

    def filenos(self) -> tuple[int, ...]:
        return (self.master,) if self.peer_open else ()

    def maintain(self, now_s: float) -> None:
        if not self.peer_open:
            self._pending.extend(self._read_raw())
        self._flush()

    def _flush(self) -> None:
        try:
            self._queue.flush(lambda mv: os.write(self.master, mv))
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            self._queue.clear()  # nobody has the slave open: the bytes go nowhere

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
                    if self.peer_open:
                        self.counters.disconnects += 1
                    self.peer_open = False
                    break
                raise
            if not data:
                break
            if not self.peer_open:
                self.counters.reconnects += 1
            self.peer_open = True
            out.append(data)
            self.counters.reads += 1
            self.counters.bytes_in += len(data)
        return out

    def read(self, timeout_s: float) -> bytes:
        """What the peer wrote (non-blocking apart from ``timeout_s``), ``b""`` if nothing."""
        if not self._pending and self.peer_open:
            if timeout_s > 0:
                select.select([self.master], [], [], timeout_s)
            self._pending.extend(self._read_raw())
        data = b"".join(self._pending)
        self._pending.clear()
        return data

    def write(self, data: bytes) -> None:
        self.counters.writes += 1
        self._queue.push(data)
        self._flush()

    def close(self) -> None:
        if self.link_path and os.path.islink(self.link_path):
            try:
                os.unlink(self.link_path)
            except OSError:
                pass
        os.close(self.master)

    def describe(self) -> str:
        return f"pty {self.slave_path}" + (f" (linked as {self.link_path})" if self.link_path else "")


def open_link(spec: str, *, baud: int = DEFAULT_BAUD) -> Transport:
    """Open a link from a pymavlink-style connection string, or ``pty`` / ``pty:LINK``.

    Everything but the pty is :func:`mavahrs.transports.open_transport`.

    Raises:
        TransportError: the link cannot be opened; ConfigError: not a connection string.
    """
    if spec == "pty" or spec.startswith("pty:"):
        return PtyLink(spec[4:] or None)
    return open_transport(spec, baud=baud, logger=log)


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
                parts.append(tlog_record(epoch + t_us, frame))
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


def _service_input(endpoint: Endpoint, link: Transport, tlog: BinaryIO | None, epoch: int, dark: bool) -> None:
    """Read everything that has arrived (non-blocking) and answer it."""
    for _ in range(256):  # bounded: a flood cannot starve the loop
        data = link.read(0.0)
        if not data:
            return
        if dark:
            continue
        if tlog is not None:
            tlog.write(tlog_record(epoch + endpoint.now_us, data))
        for reply in endpoint.receive(data, datagram=link.datagram):
            link.write(reply)
            if tlog is not None:
                tlog.write(tlog_record(epoch + endpoint.now_us, reply))


def run_realtime(
    endpoint: Endpoint,
    link: Transport,
    duration_s: float | None = None,
    *,
    should_stop: Callable[[], bool] = lambda: False,
    blackouts: Iterable[Blackout] = (),
    tlog: BinaryIO | None = None,
    max_late_s: float = 0.5,
    status_every_s: float = 0.0,
) -> PacingStats:
    """Stream in real time over ``link`` until ``duration_s`` of simulation (None = forever)
    or ``should_stop()``; also records everything sent and received into ``tlog`` if given.

    Input is answered as soon as it arrives (``select`` on the link until the
    next tick's deadline); each tick's frames go out in one write (one UDP
    datagram of whole frames).
    """
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
    next_maintain = start
    while (n is None or stats.ticks < n) and not should_stop():
        k = endpoint.tick
        deadline = t0 + (k - k_start) * period_s
        sim_t = k / rate
        dark = bool(outs) and any(b.covers(sim_t) for b in outs)
        while True:  # service input until the deadline (at least one look per tick)
            now = time.perf_counter()
            if now >= next_maintain:
                link.maintain(time.monotonic())
                next_maintain = now + 0.05
                _service_input(endpoint, link, tlog, epoch, dark)  # a link may hold input read by maintain()
            fds = link.filenos()
            timeout = deadline - now
            if fds:
                try:
                    ready = select.select(fds, [], [], max(timeout, 0.0))[0]
                except InterruptedError:
                    ready = []
            else:
                if timeout > 0:
                    time.sleep(min(timeout, 0.05))
                ready = [True]
            if ready:
                _service_input(endpoint, link, tlog, epoch, dark)
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
    counters = getattr(link, "counters", None)
    if counters is not None:
        stats.extra["link"] = dict(counters.__dict__)
    return stats


def write_stats_json(path: str | Path, endpoint: Endpoint, stats: PacingStats, link: str) -> None:
    """Write the run's counters (what was received, ACKed, sent; pacing) as JSON."""
    data = {"link": link, **endpoint.summary(), "pacing": {k: v for k, v in stats.__dict__.items()}}
    Path(path).write_text(json.dumps(data, indent=2, default=str), encoding="utf-8")
