"""The fault relays themselves (mavahrs.transports.relay): what they claim to do, they do, reproducibly."""

from __future__ import annotations

import os
import select
import socket
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from mavahrs.transports.relay import FaultSettings, LegCounters, PtyFaultRelay, UdpFaultRelay


def _sink() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)  # no kernel drops when this thread is late
    s.bind(("127.0.0.1", 0))
    s.settimeout(0.3)
    return s


class _Reader(threading.Thread):
    """Receives on a socket until it holds ``n`` datagrams and 0.3 s passed without one; ``n`` may be set once
    known (``None``: not yet).  ``timeout_s`` only bounds a run that went wrong."""

    def __init__(self, s: socket.socket, n: int | None, timeout_s: float = 120.0) -> None:
        super().__init__(daemon=True)
        self.s, self.n, self.timeout_s, self.got = s, n, timeout_s, []
        self.start()

    def run(self) -> None:
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            try:
                self.got.append(self.s.recv(65536))
            except TimeoutError:
                if self.n is not None and len(self.got) >= self.n:
                    break

    def result(self, n: int | None = None) -> list[bytes]:
        if n is not None:
            self.n = n
        self.join(self.timeout_s + 1)
        return self.got


#: datagrams on their way (sent, not yet read at the far end) at most: no socket buffer on the way can
#: overflow however late the relay's or a reader's thread runs (a sleep every 20 sends lost 180 at load 10)
WINDOW = 40


def _send_paced(send: Callable[[int], None], n: int, behind: Callable[[int], int]) -> None:
    """``send(i)`` for i in range(n), waiting — for the event, the far end catching up — whenever ``behind(i)``
    (how many of the first i have not arrived yet) exceeds :data:`WINDOW`."""
    deadline = time.monotonic() + 120
    for i in range(n):
        while behind(i) > WINDOW:
            assert time.monotonic() < deadline, f"the relay or a reader stopped after {i} of {n} datagrams"
            time.sleep(0.001)
        send(i)


def _relay_read(counters: Callable[[], LegCounters], n: int) -> LegCounters:
    """The leg's counters once the relay has read all ``n`` datagrams (the event; bounded for a failing run)."""
    deadline = time.monotonic() + 60
    while (c := counters()).datagrams < n:
        assert time.monotonic() < deadline, f"the relay read {c.datagrams} of {n} datagrams"
        time.sleep(0.005)
    return c


def _run_relay(faults: FaultSettings, n: int = 2000, seed: int = 1) -> tuple[list[bytes], list[bytes], UdpFaultRelay]:
    clean_sink, faulty_sink = _sink(), _sink()
    # a reordered datagram waits for its successor up to max_hold_s, then goes out alone: with the default 50 ms
    # a sender not scheduled for that long (load 17-23) made the order of two runs differ; 5 s is beyond any
    # stall of the sender here, and costs at most that once, for a last datagram held
    relay = UdpFaultRelay(
        [(clean_sink.getsockname(), FaultSettings(), False), (faulty_sink.getsockname(), faults, False)], seed=seed,
        max_hold_s=5.0,
    )
    src = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = [f"datagram {i:05d} ".encode() * 3 for i in range(n)]
    readers = _Reader(clean_sink, n), _Reader(faulty_sink, None)

    def behind(i: int) -> int:
        # the clean leg: sent, not yet read; the faulty one: not yet read by the relay, plus what it sent on
        # that has not arrived yet
        on_faulty_way = i - relay.counters(1).datagrams + len(relay.sent(1)) - len(readers[1].got)
        return max(i - len(readers[0].got), on_faulty_way)

    try:
        _send_paced(lambda i: src.sendto(sent[i], relay.address), n, behind)
        _relay_read(lambda: relay.counters(1), n)
        # what the faulty leg sends in all, from its records (a duplicate of a held datagram is not sent); the
        # last held one goes out after max_hold_s
        expected = sum(0 if "loss" in r.faults else 2 if "duplicate" in r.faults and "reorder" not in r.faults
                       else 1 for r in relay.records(1))  # fmt: skip
        clean, faulty = readers[0].result(), readers[1].result(expected)
    finally:
        relay.close()
        src.close()
        clean_sink.close()
        faulty_sink.close()
    assert clean == sent  # the clean leg is exact
    return sent, faulty, relay


def test_fault_rates_records_and_reproducibility() -> None:
    faults = FaultSettings(loss=0.1, bit_flip=0.1, truncate=0.05, junk=0.1, duplicate=0.05, reorder=0.05)
    sent, faulty, relay = _run_relay(faults)
    c = relay.counters(1)
    n = len(sent)
    assert c.datagrams == n
    for got, p in ((c.lost, 0.1), (c.junk, 0.1 * 0.9), (c.duplicates, 0.05 * 0.9), (c.reordered, 0.05 * 0.9)):
        assert abs(got - p * n) < 5 * (p * n) ** 0.5 + 5, (got, p * n)  # binomial, 5 sigma
    recs = relay.records(1)
    by_sent = [d for _, d in relay.sent(1)]
    assert by_sent == faulty  # what the records say went out is what arrived, in that order
    for r in recs:
        if not r.faults:
            assert r.sent == [r.original]
        if "loss" in r.faults:
            assert r.sent == []
        if "duplicate" in r.faults and "reorder" not in r.faults:
            assert len(r.sent) == 2 and r.sent[0] == r.sent[1]
        if "junk" in r.faults and "bit_flip" not in r.faults and "truncate" not in r.faults:
            assert r.sent[0].startswith(r.original) and len(r.sent[0]) > len(r.original)
        if r.faults == ("truncate",):
            assert r.original.startswith(r.sent[0]) and len(r.sent[0]) < len(r.original)
        if r.faults == ("bit_flip",):
            diff = [a ^ b for a, b in zip(r.original, r.sent[0], strict=True) if a != b]
            assert len(diff) == 1 and bin(diff[0]).count("1") == 1
    # a reordered datagram goes out right after its successor
    order = [i for i, _ in relay.sent(1)]
    for r in recs:
        if r.faults == ("reorder",) and r.index + 1 < n and not recs[r.index + 1].faults:
            j = order.index(r.index)
            assert order[j - 1] == r.index + 1
    # same seed, same faults
    _, faulty2, relay2 = _run_relay(faults)
    assert [r.faults for r in relay2.records(1)] == [r.faults for r in recs]
    assert faulty2 == faulty


def test_phases_switch_faults_at_run_time() -> None:
    sink = _sink()
    reader = _Reader(sink, 40)
    relay = UdpFaultRelay([(sink.getsockname(), FaultSettings(), False)], seed=0)
    src = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for phase, faults in (("a", FaultSettings()), ("outage", FaultSettings(loss=1.0)), ("b", FaultSettings())):
            relay.set_faults(0, faults, phase)
            for _ in range(20):
                src.sendto(b"x", relay.address)
            deadline = time.monotonic() + 5
            while relay.counters(0).datagrams < {"a": 20, "outage": 40, "b": 60}[phase] and time.monotonic() < deadline:
                time.sleep(0.01)
        got = reader.result()
    finally:
        relay.close()
        src.close()
        sink.close()
    recs = relay.records(0)
    assert [r.phase for r in recs] == ["a"] * 20 + ["outage"] * 20 + ["b"] * 20
    assert all(r.faults == ("loss",) for r in recs[20:40]) and len(got) == 40


def test_replies_get_faults_of_their_own_per_leg() -> None:
    """``reply_faults``: what a leg's target sends back is lost at its own rate; a leg without stays exact."""
    targets = [_sink(), _sink()]
    n = 2000
    relay = UdpFaultRelay(
        [(t.getsockname(), FaultSettings(), True) for t in targets], seed=3,
        reply_faults=[FaultSettings(loss=0.1)],
    )
    src = _sink()  # the upstream peer: its first datagram makes it the peer replies go to
    try:
        src.sendto(b"hello", relay.address)
        for t in targets:
            assert t.recv(100) == b"hello"
        got: dict[int, list[bytes]] = {}
        for leg, t in enumerate(targets):
            reader = _Reader(src, None)
            sent = [f"reply {leg} {i:05d}".encode() for i in range(n)]

            def behind(i: int, leg: int = leg, reader: _Reader = reader) -> int:
                return i - len(reader.got) - relay.reply_counters(leg).lost

            _send_paced(lambda i, t=t, leg=leg, sent=sent: t.sendto(sent[i], relay.leg_address(leg)), n, behind)
            c = _relay_read(lambda leg=leg: relay.reply_counters(leg), n)
            got[leg] = reader.result(n - c.lost)
        lossy, clean = relay.reply_counters(0), relay.reply_counters(1)
    finally:
        relay.close()
        src.close()
        for t in targets:
            t.close()
    assert got[1] == [f"reply 1 {i:05d}".encode() for i in range(n)] and clean.lost == 0
    assert lossy.datagrams == n and len(got[0]) == n - lossy.lost
    assert abs(lossy.lost - 0.1 * n) < 5 * (0.1 * n * 0.9) ** 0.5, lossy.lost  # binomial, 5 sigma
    kept = [int(d.split()[-1]) for d in got[0]]
    assert kept == sorted(kept) and len(set(kept)) == len(kept)  # only losses: no duplicates, no reordering
    with pytest.raises(ValueError, match="reply_faults has 2 entries for 1 legs"):
        UdpFaultRelay([(("127.0.0.1", 9), FaultSettings(), True)], reply_faults=[None, None])


def test_invalid_probabilities_are_refused() -> None:
    with pytest.raises(ValueError, match="loss"):
        FaultSettings(loss=1.5)
    with pytest.raises(ValueError, match="junk_max_bytes"):
        FaultSettings(junk_max_bytes=0)


@pytest.mark.skipif(os.name != "posix", reason="pseudo-terminals")
def test_pty_relay_carries_bytes_both_ways_and_the_device_vanishes_and_returns(tmp_path: Path) -> None:
    link = tmp_path / "ttyX"
    relay = PtyFaultRelay(link)
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.settimeout(2.0)

    def open_device() -> int:
        fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
        return fd

    def read_device(fd: int, n: int) -> bytes:
        out = b""
        deadline = time.monotonic() + 3
        while len(out) < n and time.monotonic() < deadline:
            if select.select([fd], [], [], 0.05)[0]:
                out += os.read(fd, 4096)
        return out

    try:
        fd = open_device()
        peer.sendto(b"hello ", relay.address)
        peer.sendto(b"device", relay.address)
        assert read_device(fd, 12) == b"hello device"
        os.write(fd, b"answer")
        assert peer.recv(100) == b"answer"
        relay.unplug()
        assert not os.path.lexists(link)
        poller = select.poll()  # the old device hangs up
        poller.register(fd, select.POLLIN)
        assert any(ev & select.POLLHUP for _, ev in poller.poll(2000))
        os.close(fd)
        peer.sendto(b"into the void", relay.address)
        time.sleep(0.1)
        relay.plug()
        fd = open_device()
        peer.sendto(b"again", relay.address)
        assert read_device(fd, 5) == b"again"
        os.close(fd)
        assert relay.counters().unplugged == 1 and relay.plugs == 2
        assert os.path.exists(os.readlink(link))  # a new pty behind the same name
        assert [r.faults for r in relay.records()] == [(), (), ("unplugged",), ()]
    finally:
        relay.close()
        peer.close()
    assert not os.path.lexists(link)
