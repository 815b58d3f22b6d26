"""UDP links over real loopback sockets: datagram boundaries, last-sender replies, drops."""

from __future__ import annotations

import socket
import sys
import time

import pytest

from mavahrs.errors import TransportError
from mavahrs.transports import open_transport
from mavahrs.transports.udp import IDLE_DROPS_READ_S, UdpTransport


@pytest.fixture
def listener():
    t = open_transport("udpin:127.0.0.1:0")
    assert isinstance(t, UdpTransport)
    yield t
    t.close()


def test_udpout_to_udpin_keeps_datagrams_whole_and_replies_reach_the_sender(listener: UdpTransport) -> None:
    port = listener.local_address[1]
    with open_transport(f"udpout:127.0.0.1:{port}") as out:
        assert out.datagram and listener.datagram
        out.write(b"\xfe first")
        out.write(b"\xfd second")
        assert listener.read(2.0) == b"\xfe first"  # one datagram per read, never merged
        assert listener.read(2.0) == b"\xfd second"
        assert listener.read(0.0) == b""
        listener.write(b"reply")  # goes to the last sender: the udpout socket
        assert out.read(2.0) == b"reply"
        assert listener.counters.reads == 2 and listener.counters.bytes_in == len(b"\xfe first\xfd second")
        assert out.counters.bytes_in == 5


def test_udpin_follows_a_restarted_peer_on_a_new_port(listener: UdpTransport) -> None:
    port = listener.local_address[1]
    a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        a.settimeout(2.0)
        b.settimeout(2.0)
        a.sendto(b"from a", ("127.0.0.1", port))
        assert listener.read(2.0) == b"from a"
        listener.write(b"to a")
        assert a.recv(100) == b"to a"
        a.close()  # the peer "restarts" on another port
        assert listener.counters.reconnects == 0
        listener.restart_silence_s = 0.0  # (in the service: after 0.5 s of silence)
        b.sendto(b"from b", ("127.0.0.1", port))
        assert listener.read(2.0) == b"from b"
        assert listener.counters.reconnects == 1  # a restarted peer is reported
        listener.write(b"to b")
        assert b.recv(100) == b"to b"
        assert listener.describe().endswith(f"(peer 127.0.0.1:{b.getsockname()[1]})")
    finally:
        a.close()
        b.close()


def test_udpin_without_a_peer_drops_and_counts(listener: UdpTransport) -> None:
    listener.write(b"x" * 10)
    listener.write(b"y" * 5)
    c = listener.counters
    assert (c.writes, c.writes_dropped, c.bytes_dropped, c.bytes_out) == (2, 2, 15, 0)


def test_read_times_out_with_empty_bytes(listener: UdpTransport) -> None:
    assert listener.read(0.05) == b""
    assert listener.read(0.0) == b""


def test_sending_to_a_closed_port_never_raises() -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with open_transport(f"udpout:127.0.0.1:{port}") as out:
        for _ in range(5):
            out.write(b"hello")  # ICMP port unreachable must not turn into an exception
        assert out.read(0.05) == b""
        assert out.counters.writes == 5


def test_binding_a_busy_port_is_a_one_line_transport_error(listener: UdpTransport) -> None:
    port = listener.local_address[1]
    with pytest.raises(TransportError) as info:
        open_transport(f"udpin:127.0.0.1:{port}")
    assert "already in use" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.reaches_off_loopback  # the resolver asks its name server (nothing leaves the tests' namespace)
def test_unresolvable_host_is_a_transport_error() -> None:
    with pytest.raises(TransportError, match="cannot resolve"):
        open_transport("udpout:no-such-host.invalid:14550")


def test_closed_transport_has_no_descriptors(listener: UdpTransport) -> None:
    assert listener.filenos() == (listener.fileno(),)
    listener.close()
    assert listener.filenos() == () and listener.fileno() == -1 and listener.read(0.0) == b""


def test_two_peers_talking_at_once_are_not_restarts(listener: UdpTransport) -> None:
    port = listener.local_address[1]
    a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for _ in range(5):
            a.sendto(b"a", ("127.0.0.1", port))
            b.sendto(b"b", ("127.0.0.1", port))
            assert listener.read(2.0) == b"a" and listener.read(2.0) == b"b"
        assert listener.counters.reconnects == 0  # no silence in between: not a restart
        assert listener.peer[1] == b.getsockname()[1]
    finally:
        a.close()
        b.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_RXQ_OVFL is Linux's")
def test_datagrams_the_kernel_drops_at_a_full_receive_buffer_are_counted(listener: UdpTransport) -> None:
    """A process not scheduled for a while: its socket buffer fills and the kernel drops the rest."""
    sock = listener._sock
    assert sock is not None
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # the kernel's minimum: a few datagrams
    # the buffer the kernel actually gave (it doubles the request and has its own floor): every datagram
    # takes at least its payload from it, so this many overflow it on any machine
    rcvbuf = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    payload = 200
    sent = 2 * rcvbuf // payload + 20
    port = listener.local_address[1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(sent):  # nothing reads meanwhile
            s.sendto(i.to_bytes(2, "little") * (payload // 2), ("127.0.0.1", port))
        got = 0
        while listener.read(0.2):
            got += 1
        assert 0 < got < sent, (got, sent, rcvbuf)
        # the kernel stamps its running drop count on each datagram it queues: the next one tells.  Read
        # up to it (the event), not up to a pause: on a loaded machine a datagram can reach the socket late
        s.sendto(b"next", ("127.0.0.1", port))
        while (data := listener.read(10.0)) != b"next":
            assert data, "the marker datagram never arrived"
            got += 1
    assert listener.counters.reads == got + 1
    assert listener.counters.kernel_dropped == sent - got > 0  # every datagram either read or counted


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_RXQ_OVFL and /proc/net/udp are Linux's")
def test_drops_just_before_a_stream_stops_are_counted_on_the_idle_link(listener: UdpTransport) -> None:
    """The buffer overflows and then nothing more comes: no datagram brings the count, the idle link reads it."""
    sock = listener._sock
    assert sock is not None
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    rcvbuf = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    payload = 200
    sent = 2 * rcvbuf // payload + 20
    port = listener.local_address[1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(sent):  # the stream's last burst, unread; then it stops
            s.sendto(i.to_bytes(2, "little") * (payload // 2), ("127.0.0.1", port))
    got = 0
    while listener.read(0.2):  # everything the buffer held: each brings the count from when it was queued
        got += 1
    assert 0 < got < sent, (got, sent, rcvbuf)
    before = listener.counters.kernel_dropped
    assert before < sent - got  # the drops after the last queued datagram are not known yet
    listener.maintain(time.monotonic())  # not idle long enough yet: the link is left alone
    assert listener.counters.kernel_dropped == before
    listener.maintain(time.monotonic() + IDLE_DROPS_READ_S)  # idle: the kernel's table is read
    assert listener.counters.kernel_dropped == sent - got  # every datagram either read or counted
