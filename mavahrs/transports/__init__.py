"""Byte links to the autopilot and to the outputs: UDP, TCP and serial.

``open_transport("udpin:0.0.0.0:14550")`` parses a pymavlink/MAVProxy
connection string (:mod:`mavahrs.transports.url`) and opens the link; every
link follows the :class:`~mavahrs.transports.base.Transport` interface.
Only the standard library and pyserial are used (pyserial lazily).
"""

from __future__ import annotations

import logging

from mavahrs.transports.base import Transport, TransportCounters
from mavahrs.transports.url import DEFAULT_BAUD, Endpoint, parse_connection_string

__all__ = [
    "Transport",
    "TransportCounters",
    "Endpoint",
    "parse_connection_string",
    "open_transport",
    "DEFAULT_BAUD",
]


def open_transport(
    link: str | Endpoint,
    *,
    baud: int | None = None,
    reconnect_interval_s: float = 1.0,
    queue_bytes: int = 65536,
    max_clients: int = 8,
    logger: logging.Logger | None = None,
) -> Transport:
    """Open the link named by a connection string (or a parsed :class:`Endpoint`).

    Args:
        link: e.g. ``"udpin:0.0.0.0:14550"``, ``"tcp:127.0.0.1:5760"``, ``"/dev/ttyACM0,921600"``.
        baud: serial baud rate when the string has no ``,BAUD`` suffix.
        reconnect_interval_s: retry period for a lost serial device or TCP server.
        queue_bytes: bound of the write queue of stream links (per TCP client).
        max_clients: connections a ``tcpin:`` server accepts at once.

    Raises:
        ConfigError: the string is not a connection string.
        TransportError: the link cannot be opened (reason in the message).
    """
    endpoint = link if isinstance(link, Endpoint) else parse_connection_string(link, baud)
    kind = endpoint.kind
    if kind in ("udpin", "udpout", "udpbcast"):
        from mavahrs.transports.udp import UdpTransport

        return UdpTransport(endpoint, logger=logger)
    if kind == "tcp":
        from mavahrs.transports.tcp import TcpClient

        return TcpClient(endpoint, reconnect_interval_s=reconnect_interval_s, queue_bytes=queue_bytes, logger=logger)
    if kind == "tcpin":
        from mavahrs.transports.tcp import TcpServer

        return TcpServer(endpoint, max_clients=max_clients, queue_bytes=queue_bytes, logger=logger)
    from mavahrs.transports.serial import SerialTransport

    return SerialTransport(
        endpoint, reconnect_interval_s=reconnect_interval_s, queue_bytes=min(queue_bytes, 16384), logger=logger
    )
