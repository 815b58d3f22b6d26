r"""Connection strings, spelled exactly as pymavlink's ``mavlink_connection`` and MAVProxy accept them.

===========================  ==========================================================
``udpin:HOST:PORT``          listen for UDP on HOST:PORT; replies go to the last sender
``udp:HOST:PORT``            the same as ``udpin:`` (pymavlink's default direction)
``HOST:PORT``                the same as ``udpin:`` (as ``mavutil`` treats a bare address)
``udpout:HOST:PORT``         send UDP to HOST:PORT from an ephemeral port; read replies
``udpbcast:BCAST:PORT``      like ``udpout:`` to a broadcast address (``SO_BROADCAST``)
``tcp:HOST:PORT``            TCP client; reconnects when the server goes away
``tcpin:HOST:PORT``          TCP server on HOST:PORT; clients come and go
``/dev/ttyACM0``             a serial device (baud from ``--baud``, default 115200)
``/dev/ttyUSB0,921600``      a serial device with its baud rate (MAVProxy's ``,BAUD``)
``COM3`` / ``COM3,57600``    a Windows serial port
===========================  ==========================================================

IPv6 hosts are written in brackets: ``udpin:[::]:14550``.  Port 0 on an
``*in:`` string binds an ephemeral port (used by tests).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from mavahrs.errors import ConfigError

__all__ = ["Endpoint", "parse_connection_string", "DEFAULT_BAUD", "KINDS"]

#: pymavlink's ``mavlink_connection`` default.
DEFAULT_BAUD = 115200

#: Every endpoint kind, in the order of the table above.
KINDS = ("udpin", "udpout", "udpbcast", "tcp", "tcpin", "serial")

_PREFIXES = {
    "udpin:": "udpin",
    "udp:": "udpin",
    "udpout:": "udpout",
    "udpbcast:": "udpbcast",
    "tcp:": "tcp",
    "tcpin:": "tcpin",
}
_UNSUPPORTED = ("uds:", "unix:", "mcast:", "ws:", "wss:", "wsserver:", "csv:")
_COM_RE = re.compile(r"^(?:\\\\\.\\)?COM\d+$", re.IGNORECASE)
_EXAMPLES = "e.g. udpin:0.0.0.0:14550, udpout:127.0.0.1:14551, tcp:127.0.0.1:5760, /dev/ttyACM0,921600"


@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string.

    Attributes:
        kind: one of :data:`KINDS`.
        text: the string as the user gave it (for messages).
        host: address to bind (``*in``) or to reach (``udpout``, ``udpbcast``, ``tcp``).
        port: UDP/TCP port (0 for serial).
        device: serial device path or ``COMx`` name ("" for sockets).
        baud: serial baud rate in bit/s (0 for sockets).
    """

    kind: str
    text: str
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    @property
    def datagram(self) -> bool:
        return self.kind in ("udpin", "udpout", "udpbcast")

    @property
    def listens(self) -> bool:
        """True for endpoints that bind a local address (``udpin``, ``tcpin``)."""
        return self.kind in ("udpin", "tcpin")

    def __str__(self) -> str:
        if self.kind == "serial":
            return f"{self.device},{self.baud}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.kind}:{host}:{self.port}"


def _host_port(rest: str, text: str, allow_zero: bool) -> tuple[str, int]:
    m = re.fullmatch(r"\[([^\]]+)\]:(\d+)", rest) or re.fullmatch(r"([^:\[\]]+):(\d+)", rest)
    if not m:
        raise ConfigError(f"connection string {text!r}: expected HOST:PORT after the prefix ({_EXAMPLES})")
    host, port = m.group(1), int(m.group(2))
    if not (0 < port < 65536 or (allow_zero and port == 0)):
        raise ConfigError(f"connection string {text!r}: port {port} is outside 1…65535")
    return host, port


def _baud(value: str, text: str) -> int:
    try:
        baud = int(value)
    except ValueError:
        raise ConfigError(f"connection string {text!r}: baud rate {value!r} is not a whole number") from None
    if baud <= 0:
        raise ConfigError(f"connection string {text!r}: baud rate must be positive, got {baud}")
    return baud


def parse_connection_string(text: str, baud: int | None = None) -> Endpoint:
    """Parse ``text`` (see the module table).

    Args:
        text: the connection string.
        baud: serial baud rate from ``--baud``; a ``,BAUD`` suffix in ``text``
            takes precedence (it is the more specific of the two).

    Raises:
        ConfigError: the string is not a connection string this program can open.
    """
    s = text.strip()
    if not s:
        raise ConfigError(f"empty connection string ({_EXAMPLES})")
    lower = s.lower()
    for prefix, kind in _PREFIXES.items():
        if lower.startswith(prefix):
            host, port = _host_port(s[len(prefix) :], text, allow_zero=kind in ("udpin", "tcpin"))
            return Endpoint(kind=kind, text=text, host=host, port=port)
    for prefix in _UNSUPPORTED:
        if lower.startswith(prefix):
            raise ConfigError(f"connection string {text!r}: {prefix[:-1]} links are not supported ({_EXAMPLES})")
    device, sep, suffix = s.rpartition(",")
    if not sep:
        device = s
    if _COM_RE.match(device) or device.startswith(("/", ".")):
        b = _baud(suffix, text) if sep else (baud if baud is not None else DEFAULT_BAUD)
        if b <= 0:
            raise ConfigError(f"baud rate must be positive, got {b}")
        return Endpoint(kind="serial", text=text, device=device, baud=b)
    if ":" in s:  # mavutil: a bare HOST:PORT is UDP, listening
        word, _, rest = s.partition(":")
        if ":" in rest and re.fullmatch(r"[A-Za-z][A-Za-z0-9+.-]*", word) and not re.fullmatch(r"[0-9A-Fa-f]+", word):
            # PREFIX:HOST:PORT with a prefix this program does not know (a typo, or another tool's)
            known = ", ".join(p[:-1] for p in _PREFIXES)
            raise ConfigError(
                f"connection string {text!r}: {word!r} is no known prefix; known prefixes: {known} "
                f"(or a bare HOST:PORT, a serial device path; {_EXAMPLES})"
            )
        host, port = _host_port(s, text, allow_zero=True)
        return Endpoint(kind="udpin", text=text, host=host, port=port)
    raise ConfigError(f"connection string {text!r} is not a serial device path or a network address ({_EXAMPLES})")
