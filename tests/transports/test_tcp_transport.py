"""TCP client/server over real loopback sockets: streams, reconnection, bounded queues."""

from __future__ import annotations

import socket
import time

import pytest

from mavahrs.errors import TransportError
from mavahrs.transports import open_transport, parse_connection_string
from mavahrs.transports.base import TransportCounters, WriteQueue
from mavahrs.transports.tcp import TcpClient, TcpServer


def _read_exactly(t, n: int, timeout_s: float = 3.0) -> bytes:
    out = b""
    deadline = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < deadline:
        out += t.read(0.1)
    return out


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def test_client_and_server_exchange_a_byte_stream() -> None:
    with open_transport("tcpin:127.0.0.1:0") as server:
        port = server.local_address[1]
        with open_transport(f"tcp:127.0.0.1:{port}") as client:
            assert isinstance(client, TcpClient) and client.connected and not client.datagram
            client.write(b"abc")
            client.write(b"def")
            assert _read_exactly(server, 6) == b"abcdef"  # accepts on the way, then reads
            assert isinstance(server, TcpServer) and server.client_count == 1
            server.write(b"xyz")
            assert _read_exactly(client, 3) == b"xyz"


def test_client_reconnects_after_the_server_restarts() -> None:
    port = _free_port()
    server = TcpServer(parse_connection_string(f"tcpin:127.0.0.1:{port}"))
    client = TcpClient(parse_connection_string(f"tcp:127.0.0.1:{port}"),
                       reconnect_interval_s=0.05)
    try:
        client.write(b"1")
        assert _read_exactly(server, 1) == b"1"
        server.close()  # the server goes away
        assert client.read(1.0) == b""
        assert not client.connected and client.counters.disconnects == 1
        client.write(b"lost")  # dropped while down, never raises
        assert client.counters.writes_dropped == 1
        server = TcpServer(parse_connection_string(f"tcpin:127.0.0.1:{port}"))
        deadline = time.monotonic() + 5.0
        while not client.connected and time.monotonic() < deadline:
            client.maintain(time.monotonic())
            server.read(0.02)
        assert client.connected and client.counters.reconnects == 1
        client.write(b"2")
        assert _read_exactly(server, 1) == b"2"
    finally:
        client.close()
        server.close()


def test_client_started_before_its_server_connects_later() -> None:
    port = _free_port()
    with open_transport(f"tcp:127.0.0.1:{port}", reconnect_interval_s=0.05) as client:
        assert not client.connected
        assert "not connected" in client.describe() and "refused" in client.describe()
        with open_transport(f"tcpin:127.0.0.1:{port}") as server:
            deadline = time.monotonic() + 5.0
            while not client.connected and time.monotonic() < deadline:
                client.read(0.05)  # read() drives reconnection when used on its own
                server.read(0.0)
            assert client.connected


def test_server_writes_to_every_client_and_reads_the_first() -> None:
    with open_transport("tcpin:127.0.0.1:0") as server:
        port = server.local_address[1]
        a = socket.create_connection(("127.0.0.1", port), timeout=2)
        b = socket.create_connection(("127.0.0.1", port), timeout=2)
        try:
            deadline = time.monotonic() + 3
            while server.client_count < 2 and time.monotonic() < deadline:
                server.read(0.05)
            assert server.client_count == 2
            server.write(b"attitude")
            assert a.recv(100) == b"attitude" and b.recv(100) == b"attitude"
            b.sendall(b"gcs noise")
            a.sendall(b"autopilot")
            got = _read_exactly(server, len(b"autopilot"))
            assert got == b"autopilot"
            b.close()
            deadline = time.monotonic() + 3
            while server.client_count > 1 and time.monotonic() < deadline:
                server.read(0.05)
            assert server.client_count == 1 and server.counters.disconnects == 1
        finally:
            a.close()
            b.close()


def test_a_reader_that_never_reads_cannot_grow_memory() -> None:
    with open_transport("tcpin:127.0.0.1:0", queue_bytes=65536) as server:
        port = server.local_address[1]
        lazy = socket.socket()
        lazy.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        lazy.connect(("127.0.0.1", port))
        try:
            deadline = time.monotonic() + 3
            while server.client_count < 1 and time.monotonic() < deadline:
                server.read(0.05)
            frame = b"\xfd" + b"q" * 999
            for _ in range(20000):  # 20 MB offered, far more than the socket buffers hold
                server.write(frame)
            c = server.counters
            assert c.writes_dropped > 0
            queued = server._clients[0].queue  # noqa: SLF001 - the bound is the point of the test
            assert len(queued) <= 65536
            assert c.bytes_out + c.bytes_dropped + len(queued) == 20000 * len(frame)
        finally:
            lazy.close()


def test_write_queue_drops_oldest_whole_chunks_but_never_the_partly_sent_head() -> None:
    c = TransportCounters()
    q = WriteQueue(10, c)
    sent: list[bytes] = []

    def send_two(mv: memoryview) -> int:
        sent.append(bytes(mv[:2]))
        if len(sent) > 1:
            raise BlockingIOError
        return 2

    q.push(b"AAAA")
    q.flush(send_two)  # "AA" out, then the buffer is "full"
    assert len(q) == 2
    q.push(b"BBBB")
    q.push(b"CCCC")  # 2 + 4 + 4 = 10: fits
    q.push(b"DDDD")  # over: B is dropped, not the partly sent A
    assert c.writes_dropped == 1 and c.bytes_dropped == 4
    out: list[bytes] = []
    q.flush(lambda mv: (out.append(bytes(mv)), len(mv))[1])
    assert b"".join(out) == b"AACCCCDDDD"
    q.push(b"X" * 11)  # larger than the whole bound: dropped at once
    assert c.writes_dropped == 2 and len(q) == 0


def test_busy_tcp_port_is_a_transport_error() -> None:
    with open_transport("tcpin:127.0.0.1:0") as server:
        port = server.local_address[1]
        with pytest.raises(TransportError, match="already in use"):
            open_transport(f"tcpin:127.0.0.1:{port}")
