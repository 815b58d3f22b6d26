r"""A fault-injecting relay for testing a MAVLink link: loss, bit flips, junk, duplicates, reordering, outages.

Radios corrupt bytes, networks lose and reorder datagrams, relays send
frames twice, cables shake loose.  These relays put such faults between an
autopilot (or ``firmware_sim``) and the program under test, reproducibly
(seeded), and record what they did so a test can tell intact samples from
damaged ones:

* :class:`UdpFaultRelay` — listens for UDP datagrams from the upstream peer
  (the autopilot sends to :attr:`UdpFaultRelay.address`) and forwards each
  datagram to one or more *legs*, each its own socket towards its own target
  with its own :class:`FaultSettings` (so one leg can stay clean while another
  is damaged: the same bytes, a paired comparison).  Replies arriving on a leg
  with ``reply=True`` go back to the upstream peer, unchanged or, with the
  relay's ``reply_faults``, with faults of their own (a lossy link both ways).
* :class:`PtyFaultRelay` — a UDP-to-serial bridge: datagrams from upstream are
  written, with faults, into a pseudo-terminal whose slave side is reachable
  at a fixed path (a symlink, as udev's ``/dev/serial/by-id/…``); what the
  program writes to the "serial port" goes back upstream.  :meth:`unplug` and
  :meth:`plug` make the device vanish and return.

The fault model (per datagram, or per chunk on the pty) is MAVLink-agnostic:
drop it (``loss``), flip one random bit (``bit_flip``), cut it short
(``truncate``), append 1…
``junk_max_bytes`` random bytes after it (``junk``), send it twice
(``duplicate``), or hold it back and send it after the next one
(``reorder``).  :meth:`set_faults` switches the faults of a leg at run time
(bursts, outages: ``FaultSettings(loss=1.0)``), with a *phase* label that is
recorded with every datagram.

Threads: each relay runs one thread with one ``selectors`` wait (no busy
polling), stopped by :meth:`close`.  Only loopback use is intended; the
relays are test tools, not part of the service.
"""

from __future__ import annotations

import os
import random
import selectors
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

__all__ = ["FaultSettings", "RelayRecord", "LegCounters", "UdpFaultRelay", "PtyFaultRelay"]

_RCVBUF_BYTES = 4 << 20  # a relay must not add losses of its own when its thread is late
_REPLY_SEED = 1_000_003  # offset of a leg's reply-direction seed from its forward seed


def _udp_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RCVBUF_BYTES)
    except OSError:
        pass
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


@dataclass(frozen=True)
class FaultSettings:
    """What a relay does to each datagram (probabilities 0…1, drawn independently).

    Attributes:
        loss: the datagram is dropped.
        bit_flip: one random bit of the datagram is flipped.
        truncate: only a random-length prefix of the datagram is sent (a
            frame cut short: UDP a short datagram; pty the rest of the frame
            never comes and the next datagram's bytes follow).
        junk: 1…``junk_max_bytes`` random bytes are sent right after it
            (UDP: appended to the same datagram; pty: after the chunk).
        junk_max_bytes: the most junk bytes added at once.
        duplicate: the datagram is sent twice.
        reorder: the datagram is held back and sent right after the next one.
    """

    loss: float = 0.0
    bit_flip: float = 0.0
    truncate: float = 0.0
    junk: float = 0.0
    junk_max_bytes: int = 64
    duplicate: float = 0.0
    reorder: float = 0.0

    def __post_init__(self) -> None:
        for name in ("loss", "bit_flip", "truncate", "junk", "duplicate", "reorder"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"FaultSettings.{name} must be a probability 0…1, got {v!r}")
        if self.junk_max_bytes < 1:
            raise ValueError(f"FaultSettings.junk_max_bytes must be ≥ 1, got {self.junk_max_bytes!r}")

    @property
    def clean(self) -> bool:
        return not (self.loss or self.bit_flip or self.truncate or self.junk or self.duplicate or self.reorder)


@dataclass
class RelayRecord:
    """One upstream datagram and what one leg did with it.

    Attributes:
        index: its position among the upstream datagrams (0, 1, …).
        t_wall_s: when it arrived (``time.time()``).
        original: its bytes as the upstream peer sent them.
        phase: the phase label in force (:meth:`UdpFaultRelay.set_faults`).
        faults: what was done: ``"loss"``, ``"bit_flip"``, ``"truncate"``, ``"junk"``,
            ``"duplicate"``, ``"reorder"``, ``"unplugged"`` (pty); empty = intact.
        sent: the bytes actually sent, in order (none if lost; two entries if
            duplicated); a reordered datagram's entry is filled when it goes out.
    """

    index: int
    t_wall_s: float
    original: bytes
    phase: str
    faults: tuple[str, ...] = ()
    sent: list[bytes] = field(default_factory=list)


@dataclass
class LegCounters:
    """Totals of one leg (kept also when records are not)."""

    datagrams: int = 0
    lost: int = 0
    bit_flips: int = 0
    truncated: int = 0
    junk: int = 0
    duplicates: int = 0
    reordered: int = 0
    unplugged: int = 0
    write_errors: int = 0
    replies: int = 0


class _FaultState:
    """A leg's seeded fault draws and its held-back (reordered) datagram."""

    def __init__(self, faults: FaultSettings, seed: int | None, record: bool) -> None:
        self.faults = faults
        self.phase = "start"
        self.rng = random.Random(seed)
        self.held: tuple[bytes, RelayRecord | None] | None = None
        self.held_since = 0.0
        self.counters = LegCounters()
        self.records: list[RelayRecord] | None = [] if record else None
        #: (record index, bytes) in the order they were sent (with ``record``)
        self.sent_log: list[tuple[int, bytes]] = []

    def apply(self, data: bytes, now_s: float) -> list[tuple[bytes, RelayRecord | None]]:
        """The (bytes, record) pairs to send now for one upstream datagram, in order."""
        f, rng, c = self.faults, self.rng, self.counters
        c.datagrams += 1
        rec = RelayRecord(c.datagrams - 1, time.time(), data, self.phase) if self.records is not None else None
        if rec is not None:
            self.records.append(rec)  # type: ignore[union-attr]
        done: list[str] = []
        out: list[tuple[bytes, RelayRecord | None]] = []
        if f.clean:
            out.append((data, rec))
        elif f.loss and rng.random() < f.loss:
            c.lost += 1
            done.append("loss")
        else:
            b = bytearray(data)
            if f.bit_flip and b and rng.random() < f.bit_flip:
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
                c.bit_flips += 1
                done.append("bit_flip")
            if f.truncate and len(b) > 1 and rng.random() < f.truncate:
                del b[rng.randrange(1, len(b)):]
                c.truncated += 1
                done.append("truncate")
            if f.junk and rng.random() < f.junk:
                b += rng.randbytes(rng.randint(1, f.junk_max_bytes))
                c.junk += 1
                done.append("junk")
            first = bytes(b)
            copies = [first]
            if f.duplicate and rng.random() < f.duplicate:
                copies.append(first)
                c.duplicates += 1
                done.append("duplicate")
            if f.reorder and self.held is None and rng.random() < f.reorder:
                c.reordered += 1
                done.append("reorder")
                self.held = (first, rec)  # duplicates of a held datagram are not sent
                self.held_since = now_s
            else:
                out.extend((cp, rec) for cp in copies)
        if self.held is not None and "reorder" not in done:
            out.append(self.held)  # the held one goes out after this one
            self.held = None
        if rec is not None:
            rec.faults = tuple(done)
        return out

    def overdue(self, now_s: float, max_hold_s: float) -> list[tuple[bytes, RelayRecord | None]]:
        if self.held is not None and now_s - self.held_since >= max_hold_s:
            held, self.held = self.held, None
            return [held]
        return []


class _Leg:
    def __init__(
        self, target: tuple[str, int], faults: FaultSettings, seed: int | None, reply: bool, record: bool,
        observer: Callable[[bytes], None] | None = None, reply_faults: FaultSettings | None = None,
    ) -> None:
        self.target = target
        self.observer = observer
        self.reply = reply
        self.sock = _udp_socket()
        self.state = _FaultState(faults, seed, record)
        #: faults on the way back (target → upstream peer); its own draws, no records
        reply_seed = None if seed is None else seed + _REPLY_SEED
        self.reply_state = _FaultState(reply_faults or FaultSettings(), reply_seed, False)

    def send(self, items: list[tuple[bytes, RelayRecord | None]]) -> None:
        for data, rec in items:
            if self.observer is not None:
                self.observer(data)  # before sending: the answer may come back before sendto returns
            try:
                self.sock.sendto(data, self.target)
            except OSError:
                self.state.counters.write_errors += 1
                continue
            if rec is not None:
                rec.sent.append(data)
                self.state.sent_log.append((rec.index, data))


def _leg_observer(observer: Callable[[int, bytes], None] | None, leg: int) -> Callable[[bytes], None] | None:
    if observer is None:
        return None

    def observe(data: bytes) -> None:
        observer(leg, data)

    return observe


class UdpFaultRelay:
    """Upstream UDP peer → faults → one or more targets; see the module docstring.

    Args:
        legs: ``(target (host, port), FaultSettings, reply)`` per leg; ``reply``
            forwards what the target sends back to the upstream peer.
        seed: base seed (leg ``i`` uses ``seed + i``); same seed, same faults
            for the same datagram sequence.
        record: keep a :class:`RelayRecord` per datagram and leg (memory grows
            with the run: tests only; counters are always kept).
        max_hold_s: a reordered datagram waits at most this long for a successor, s.
        observer: called as ``observer(leg, data)`` from the relay's thread with
            every datagram a leg is about to send (e.g. to follow a long run
            without records; called before ``sendto``, so an answer cannot
            overtake it).
        reply_faults: per leg (by index; missing or None = clean), the faults
            applied to what the leg's target sends back (legs with ``reply``),
            drawn with their own seed; see :meth:`reply_counters`.
    """

    def __init__(
        self,
        legs: list[tuple[tuple[str, int], FaultSettings, bool]],
        *,
        seed: int | None = 0,
        record: bool = True,
        max_hold_s: float = 0.05,
        observer: Callable[[int, bytes], None] | None = None,
        reply_faults: Sequence[FaultSettings | None] = (),
    ) -> None:
        if len(reply_faults) > len(legs):
            raise ValueError(f"reply_faults has {len(reply_faults)} entries for {len(legs)} legs")
        self._up = _udp_socket()
        self._legs = [
            _Leg(target, faults, None if seed is None else seed + i, reply, record, _leg_observer(observer, i),
                 reply_faults[i] if i < len(reply_faults) else None)
            for i, (target, faults, reply) in enumerate(legs)
        ]
        self._peer: tuple[str, int] | None = None
        self._max_hold_s = max_hold_s
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="udp-fault-relay", daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        """Where the upstream peer sends (``udpout:HOST:PORT``)."""
        host, port = self._up.getsockname()[:2]
        return host, port

    def leg_address(self, leg: int = 0) -> tuple[str, int]:
        """The source address a leg's target sees."""
        host, port = self._legs[leg].sock.getsockname()[:2]
        return host, port

    def set_faults(self, leg: int, faults: FaultSettings, phase: str) -> None:
        """Switch a leg's faults from the next datagram on; ``phase`` labels the records."""
        with self._lock:
            st = self._legs[leg].state
            st.faults = faults
            st.phase = phase

    def records(self, leg: int = 0) -> list[RelayRecord]:
        with self._lock:
            recs = self._legs[leg].state.records
            return list(recs) if recs is not None else []

    def sent(self, leg: int = 0) -> list[tuple[int, bytes]]:
        """(record index, bytes) of everything the leg sent, in sending order (with ``record``)."""
        with self._lock:
            return list(self._legs[leg].state.sent_log)

    def counters(self, leg: int = 0) -> LegCounters:
        with self._lock:
            c = self._legs[leg].state.counters
            return LegCounters(**vars(c))

    def reply_counters(self, leg: int = 0) -> LegCounters:
        """Totals of the leg's reply direction (``datagrams``: replies that reached the relay)."""
        with self._lock:
            c = self._legs[leg].reply_state.counters
            return LegCounters(**vars(c))

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._up, selectors.EVENT_READ, None)
        for leg in self._legs:
            sel.register(leg.sock, selectors.EVENT_READ, leg)
        try:
            while not self._stop.is_set():
                for key, _ in sel.select(0.02):
                    leg = key.data
                    if leg is None:
                        self._from_upstream()
                    else:
                        self._from_leg(leg)
                now = time.monotonic()
                with self._lock:
                    for leg in self._legs:
                        leg.send(leg.state.overdue(now, self._max_hold_s))
                        self._reply(leg, leg.reply_state.overdue(now, self._max_hold_s))
        finally:
            sel.close()

    def _from_upstream(self) -> None:
        for _ in range(1024):
            try:
                data, addr = self._up.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            self._peer = addr
            now = time.monotonic()
            with self._lock:
                for leg in self._legs:
                    leg.send(leg.state.apply(data, now))

    def _from_leg(self, leg: _Leg) -> None:
        for _ in range(1024):
            try:
                data = leg.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            if leg.reply and self._peer is not None:
                leg.state.counters.replies += 1
                with self._lock:
                    self._reply(leg, leg.reply_state.apply(data, time.monotonic()))

    def _reply(self, leg: _Leg, items: list[tuple[bytes, RelayRecord | None]]) -> None:
        if self._peer is None:
            return
        for data, _ in items:
            try:
                self._up.sendto(data, self._peer)
            except OSError:
                leg.reply_state.counters.write_errors += 1

    def close(self) -> None:
        """Stop the thread and close the sockets (idempotent)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5)
        self._up.close()
        for leg in self._legs:
            leg.sock.close()

    def __enter__(self) -> UdpFaultRelay:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PtyFaultRelay:
    """Upstream UDP → faults → a pty "serial device" at ``link``; the device's output → upstream.

    Args:
        link: path of the symlink the program under test opens as its serial port.
        faults: applied per upstream datagram (one chunk of the byte stream).
        seed: seed of the fault draws.
        record: keep a :class:`RelayRecord` per datagram.
    """

    def __init__(
        self, link: str | os.PathLike[str], faults: FaultSettings = FaultSettings(), *, seed: int | None = 0,
        record: bool = True, max_hold_s: float = 0.05,
    ) -> None:
        self.link = os.fspath(link)
        self._up = _udp_socket()
        self._peer: tuple[str, int] | None = None
        self._state = _FaultState(faults, seed, record)
        self._max_hold_s = max_hold_s
        self._lock = threading.Lock()
        self._master = -1
        self._idle_until = 0.0
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._stop = threading.Event()
        self.plugs = 0
        self.plug()
        self._thread = threading.Thread(target=self._run, name="pty-fault-relay", daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._up.getsockname()[:2]
        return host, port

    @property
    def plugged(self) -> bool:
        return self._master >= 0

    def plug(self) -> None:
        """Create a new pty (raw mode) and point ``link`` at its slave side."""
        import tty

        with self._lock:
            if self._master >= 0:
                return
            master, slave = os.openpty()
            tty.setraw(slave)
            name = os.ttyname(slave)
            os.close(slave)  # the program under test opens it by name
            os.set_blocking(master, False)
            tmp = f"{self.link}.new"
            if os.path.lexists(tmp):
                os.unlink(tmp)
            os.symlink(name, tmp)
            os.replace(tmp, self.link)
            self._master = master
            self.plugs += 1
        self._wake()

    def unplug(self) -> None:
        """The device vanishes: the pty closes (the reader sees a hang-up) and ``link`` disappears."""
        with self._lock:
            if self._master < 0:
                return
            os.close(self._master)
            self._master = -1
            if os.path.lexists(self.link):
                os.unlink(self.link)
        self._wake()

    def set_faults(self, faults: FaultSettings, phase: str) -> None:
        with self._lock:
            self._state.faults = faults
            self._state.phase = phase

    def records(self) -> list[RelayRecord]:
        with self._lock:
            return list(self._state.records or [])

    def sent(self) -> list[tuple[int, bytes]]:
        """(record index, bytes) written to the pty, in order (with ``record``)."""
        with self._lock:
            return list(self._state.sent_log)

    def counters(self) -> LegCounters:
        with self._lock:
            return LegCounters(**vars(self._state.counters))

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except OSError:
            pass

    def _write(self, items: list[tuple[bytes, RelayRecord | None]]) -> None:
        for data, rec in items:
            if self._master < 0:
                continue
            try:
                n = os.write(self._master, data)
            except OSError:  # buffer full (nobody reading) or hang-up
                self._state.counters.write_errors += 1
                continue
            if rec is not None:
                rec.sent.append(data[:n])
                self._state.sent_log.append((rec.index, data[:n]))

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._up, selectors.EVENT_READ, "up")
        sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        registered = -1
        try:
            while not self._stop.is_set():
                with self._lock:
                    master = self._master
                if time.monotonic() < self._idle_until:
                    master = -1  # hung up (no reader on the slave side): don't spin on POLLHUP
                if master != registered:
                    if registered >= 0:
                        try:
                            sel.unregister(registered)
                        except (KeyError, ValueError, OSError):
                            pass
                    if master >= 0:
                        sel.register(master, selectors.EVENT_READ, "pty")
                    registered = master
                for key, _ in sel.select(0.02):
                    if key.data == "up":
                        self._from_upstream()
                    elif key.data == "wake":
                        try:
                            while self._wake_r.recv(64):
                                pass
                        except (BlockingIOError, InterruptedError):
                            pass
                    else:
                        self._from_pty()
                with self._lock:
                    self._write(self._state.overdue(time.monotonic(), self._max_hold_s))
        finally:
            sel.close()

    def _from_upstream(self) -> None:
        for _ in range(1024):
            try:
                data, addr = self._up.recvfrom(65536)
            except (BlockingIOError, InterruptedError, OSError):
                return
            self._peer = addr
            with self._lock:
                if self._master < 0:
                    st = self._state
                    st.counters.datagrams += 1
                    st.counters.unplugged += 1
                    if st.records is not None:
                        st.records.append(RelayRecord(st.counters.datagrams - 1, time.time(), data, st.phase, ("unplugged",)))
                    continue
                self._write(self._state.apply(data, time.monotonic()))

    def _from_pty(self) -> None:
        with self._lock:
            master = self._master
            if master < 0:
                return
            try:
                data = os.read(master, 65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # EIO: nobody has the slave open (yet)
                self._idle_until = time.monotonic() + 0.05
                return
        if data and self._peer is not None:
            self._state.counters.replies += 1
            try:
                self._up.sendto(data, self._peer)
            except OSError:
                pass

    def close(self) -> None:
        self._stop.set()
        self._wake()
        if self._thread.is_alive():
            self._thread.join(5)
        self.unplug()
        self._up.close()
        self._wake_r.close()
        self._wake_w.close()

    def __enter__(self) -> PtyFaultRelay:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
