"""Serial links over a real pseudo-terminal pair, including a device that vanishes and returns.

The "device" is the pty's slave side reached through a symlink, as udev's
``/dev/serial/by-id/…`` links are: unplugging closes the master (the slave then
reports EIO / hang-up) and removes the link; replugging creates a new pty and
points the link at it.
"""

from __future__ import annotations

import errno
import os
import time
from pathlib import Path

import pytest

from mavahrs.errors import TransportError
from mavahrs.transports import open_transport, parse_connection_string
from mavahrs.transports.serial import SerialTransport, _errno_of, open_serial_port

pytestmark = pytest.mark.skipif(os.name != "posix", reason="needs POSIX pseudo-terminals")


class FakeDevice:
    """A pty whose slave is reachable at a fixed path (a symlink)."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.master = -1
        self.plug()

    def plug(self) -> None:
        master, slave = os.openpty()
        name = os.ttyname(slave)
        os.close(slave)  # the transport opens it by name
        self.master = master
        if self.link.is_symlink():
            self.link.unlink()
        self.link.symlink_to(name)

    def unplug(self) -> None:
        os.close(self.master)
        self.master = -1
        self.link.unlink()

    def read(self, n: int, timeout_s: float = 3.0) -> bytes:
        out = b""
        deadline = time.monotonic() + timeout_s
        while len(out) < n and time.monotonic() < deadline:
            import select

            r, _, _ = select.select([self.master], [], [], 0.05)
            if r:
                out += os.read(self.master, 4096)
        return out

    def close(self) -> None:
        if self.master >= 0:
            os.close(self.master)
            self.master = -1


@pytest.fixture
def device(tmp_path: Path):
    dev = FakeDevice(tmp_path / "ttyFAKE")
    yield dev
    dev.close()


def _read(t, n: int, timeout_s: float = 3.0) -> bytes:
    out = b""
    deadline = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < deadline:
        out += t.read(0.05)
    return out


def test_bytes_flow_both_ways(device: FakeDevice) -> None:
    with open_transport(f"{device.link},921600") as t:
        assert isinstance(t, SerialTransport) and not t.datagram
        assert "921600 baud" in t.describe()
        os.write(device.master, b"\xfd\x09hello")
        assert _read(t, 7) == b"\xfd\x09hello"
        t.write(b"heartbeat")
        assert device.read(9) == b"heartbeat"
        assert t.read(0.0) == b""  # nothing more: timeout, not a disconnect
        assert t.connected


def test_device_that_vanishes_and_returns_is_reopened(device: FakeDevice) -> None:
    t = SerialTransport(parse_connection_string(str(device.link)),
                        reconnect_interval_s=0.05)
    try:
        os.write(device.master, b"before")
        assert _read(t, 6) == b"before"
        device.unplug()
        assert t.read(1.0) == b""  # EIO / hang-up: the link is lost, no exception
        assert not t.connected and t.filenos() == () and t.counters.disconnects == 1
        assert "lost" in t.describe()
        t.write(b"while away")  # dropped and counted, never raises
        assert t.counters.writes_dropped == 1
        t.maintain(time.monotonic() + 1.0)  # device still missing: the attempt fails quietly
        assert not t.connected
        device.plug()
        t.maintain(time.monotonic() + 2.0)
        assert t.connected and t.counters.reconnects == 1
        os.write(device.master, b"after")
        assert _read(t, 5) == b"after"
        t.write(b"back")
        assert device.read(4) == b"back"
    finally:
        t.close()


def test_read_alone_reopens_the_device(device: FakeDevice) -> None:
    t = SerialTransport(parse_connection_string(str(device.link)),
                        reconnect_interval_s=0.05)
    try:
        device.unplug()
        assert t.read(0.2) == b""
        device.plug()
        deadline = time.monotonic() + 3.0
        while not t.connected and time.monotonic() < deadline:
            assert t.read(0.05) == b""
        assert t.connected
        os.write(device.master, b"again")  # (opening a port flushes what came before)
        assert _read(t, 5) == b"again"
    finally:
        t.close()


def test_port_held_by_another_program_is_busy(device: FakeDevice) -> None:
    holder = open_serial_port(str(device.link), 57600, exclusive=True)
    try:
        with pytest.raises(TransportError) as info:
            open_transport(str(device.link))
        msg = str(info.value)
        assert "cannot open serial port" in msg and "locked by another program" in msg and "\n" not in msg
    finally:
        holder.close()


def test_missing_device_says_so(tmp_path: Path) -> None:
    with pytest.raises(TransportError) as info:
        open_transport(str(tmp_path / "ttyNOPE"))
    assert "no such device" in str(info.value)


@pytest.mark.parametrize("kind", ["directory", "regular file", "/dev/null"])
def test_a_path_that_is_no_serial_device_says_what_it_is(tmp_path: Path, kind: str) -> None:
    """`--master` naming a folder or a plain file: one plain line (until user8 pyserial's "[Errno 21] could
    not open port …: [Errno 21] Is a directory: '…'" and "Could not configure port: (25, 'Inappropriate ioctl
    for device')")."""
    path = {"directory": tmp_path, "regular file": tmp_path / "notes.txt", "/dev/null": Path("/dev/null")}[kind]
    if kind == "regular file":
        path.write_text("not a port")
    with pytest.raises(TransportError) as info:
        open_transport(str(path))
    msg = str(info.value)
    want = "it is a directory, not a serial device" if kind == "directory" else "not a serial device (a serial port"
    assert msg.startswith(f"cannot open serial port {path}: {want}"), msg
    assert "Errno" not in msg and "ioctl" not in msg and "\n" not in msg


def test_permission_denied_names_the_dialout_group(device: FakeDevice) -> None:
    """As an unprivileged user (a forked child drops root), a 0600 root-owned tty is refused."""
    import serial  # noqa: F401 - imported before the fork so that the child needs no file access

    target = os.path.realpath(device.link)
    os.chmod(target, 0o600)
    if os.geteuid() != 0:
        os.chmod(target, 0o000)
        with pytest.raises(TransportError) as info:
            open_transport(str(device.link))
        message = str(info.value)
    else:
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:  # child: become "nobody", try, report, exit without cleanup
            try:
                os.close(r)
                os.setgid(65534)
                os.setuid(65534)
                try:
                    open_transport(str(device.link))
                    text = "opened"
                except TransportError as exc:
                    text = str(exc)
                os.write(w, text.encode())
            finally:
                os._exit(0)
        os.close(w)
        message = b""
        while chunk := os.read(r, 4096):
            message += chunk
        os.close(r)
        os.waitpid(pid, 0)
        message = message.decode()
    assert "permission denied" in message and "dialout" in message and "\n" not in message


@pytest.mark.parametrize(
    ("text", "code"),
    [
        ("[Errno 13] could not open port /dev/ttyS0: [Errno 13] Permission denied: '/dev/ttyS0'", errno.EACCES),
        ("could not open port /dev/ttyX: [Errno 2] No such file or directory: '/dev/ttyX'", errno.ENOENT),
        ("Could not exclusively lock port /dev/ttyS0: [Errno 11] Resource temporarily unavailable", errno.EAGAIN),
    ],
)
def test_pyserial_messages_map_to_reasons(text: str, code: int) -> None:
    assert _errno_of(Exception(text)) == code
