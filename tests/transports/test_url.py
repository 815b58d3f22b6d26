"""Connection strings as pymavlink's ``mavlink_connection`` and MAVProxy spell them."""

from __future__ import annotations

import pytest

from mavahrs.errors import ConfigError
from mavahrs.transports.url import DEFAULT_BAUD, parse_connection_string


@pytest.mark.parametrize(
    ("text", "kind", "host", "port"),
    [
        ("udpin:0.0.0.0:14550", "udpin", "0.0.0.0", 14550),
        ("udp:127.0.0.1:14550", "udpin", "127.0.0.1", 14550),  # pymavlink: udp: listens by default
        ("127.0.0.1:14550", "udpin", "127.0.0.1", 14550),  # mavutil: bare address = UDP in
        ("udpout:10.0.0.2:14551", "udpout", "10.0.0.2", 14551),
        ("UDPOUT:localhost:14551", "udpout", "localhost", 14551),
        ("udpbcast:192.168.1.255:14550", "udpbcast", "192.168.1.255", 14550),
        ("tcp:127.0.0.1:5760", "tcp", "127.0.0.1", 5760),
        ("tcpin:0.0.0.0:5760", "tcpin", "0.0.0.0", 5760),
        ("udpin:[::1]:14550", "udpin", "::1", 14550),
        ("udpin:127.0.0.1:0", "udpin", "127.0.0.1", 0),  # ephemeral port for listeners
    ],
)
def test_network_strings(text: str, kind: str, host: str, port: int) -> None:
    ep = parse_connection_string(text)
    assert (ep.kind, ep.host, ep.port) == (kind, host, port)
    assert ep.datagram == kind.startswith("udp")
    assert parse_connection_string(str(ep)).kind == kind  # round trip through str()


@pytest.mark.parametrize(
    ("text", "baud", "device", "expected_baud"),
    [
        ("/dev/ttyACM0", None, "/dev/ttyACM0", DEFAULT_BAUD),
        ("/dev/ttyACM0", 921600, "/dev/ttyACM0", 921600),
        ("/dev/ttyUSB0,57600", None, "/dev/ttyUSB0", 57600),
        ("/dev/ttyUSB0,57600", 921600, "/dev/ttyUSB0", 57600),  # the suffix is more specific than --baud
        ("/dev/serial/by-id/usb-ArduPilot_fmuv3_1E0-if00", 115200, "/dev/serial/by-id/usb-ArduPilot_fmuv3_1E0-if00", 115200),
        ("COM3", None, "COM3", DEFAULT_BAUD),
        ("com12,230400", None, "com12", 230400),
        ("./ttyFAKE", 9600, "./ttyFAKE", 9600),
    ],
)
def test_serial_strings(text: str, baud: int | None, device: str, expected_baud: int) -> None:
    ep = parse_connection_string(text, baud)
    assert (ep.kind, ep.device, ep.baud) == ("serial", device, expected_baud)
    assert not ep.datagram


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("", "empty"),
        ("udpin:14550", "HOST:PORT"),
        ("udpout:127.0.0.1:0", "outside"),
        ("tcp:host:99999", "outside"),
        ("/dev/ttyUSB0,fast", "not a whole number"),
        ("/dev/ttyUSB0,0", "positive"),
        ("ttyUSB0", "not a serial device path"),
        ("ws:127.0.0.1:80", "not supported"),
    ],
)
def test_bad_strings_name_the_problem(text: str, needle: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_connection_string(text)
    msg = str(info.value)
    assert needle in msg
    assert "\n" not in msg
