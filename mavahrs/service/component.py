r"""What mavahrs answers, as an onboard MAVLink component, to requests addressed to it.

mavahrs is component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) of the vehicle's
system, or a vehicle of its own (``out_identity = "separate-vehicle"``).  It
implements none of the request–response microservices, so a ground station
that asks it something should learn so at once instead of retrying.  For a
request whose target is *this* component (its system id and component id,
not a broadcast) the answer is what the MAVLink specification gives a
component without that service:

* **Command protocol** (COMMAND_LONG, COMMAND_INT): ``COMMAND_ACK`` with
  ``MAV_RESULT_UNSUPPORTED`` (3) for the command — the command protocol's
  answer to a command the recipient does not implement; the sender stops
  resending at once.
* **File transfer protocol** (FILE_TRANSFER_PROTOCOL, "MAVLink FTP"): a NAK
  (opcode 129) to the request's opcode with error ``UnknownCommand`` (7),
  sequence number the request's + 1, same session, as the FTP payload format
  of mavlink.io/en/services/ftp.html.  MAVProxy's parameter download asks
  for ``@PARAM/param.pck`` over FTP first: MAVProxy 1.8.75 targeting
  component 191, unanswered, sent 8–11 OpenFileRO over 7–11 s and fell back
  to PARAM_REQUEST_LIST after 13 s in one set-up, not within 120 s in
  another; with the NAK it sent one and fell back 1.0 s later
  (tests/e2e/test_mavproxy_component.py, docs/daemon.md).
* **Parameter protocol** (PARAM_REQUEST_LIST, PARAM_REQUEST_READ, PARAM_SET):
  nothing.  mavahrs has no MAVLink parameters (its settings are a TOML
  file), and the parameter protocol says that "components with no
  parameters should ignore the request" (mavlink.io/en/services/parameter.html,
  *Read All Parameters*; the sender times out after its resends).  A
  PARAM_VALUE with ``param_count = 0`` is not an empty list to every ground
  station: MAVProxy 1.8.75 stores its ``param_id`` as a parameter and asks
  again anyway.  Such requests are counted (``param_requests_ignored``).

Broadcasts (target system or component 0) are never answered: on a shared
link the autopilot answers them, and a NAK or UNSUPPORTED from us would be
taken as the answer (MAVProxy's FTP client does not check who replies).  Our
own frames relayed back, and requests to other components, are ignored.

Pure: messages in, encoded frames out, with the pipeline's codec (our ids,
sequence numbers and, when on, signing); the daemon sends each answer on the
link the request came from.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

__all__ = ["ComponentResponder", "ResponderCounters", "REQUEST_TYPES", "FTP_OP_NAK", "FTP_ERR_UNKNOWN_COMMAND"]

#: MAV_RESULT_UNSUPPORTED: "Command is not supported (unknown)"
MAV_RESULT_UNSUPPORTED = 3
#: MAVLink FTP payload: opcode of a NAK, and the error "unknown command / opcode"
FTP_OP_NAK = 129
FTP_ERR_UNKNOWN_COMMAND = 7
#: FTP payload header: seq_number u16, session u8, opcode u8, size u8, req_opcode u8, burst_complete u8,
#: padding u8, offset u32; data follows (251 bytes in all)
_FTP_HEADER = struct.Struct("<HBBBBBBI")
_FTP_PAYLOAD_LEN = 251

#: the message types :meth:`ComponentResponder.answer` looks at (anything else: no answer, no cost)
REQUEST_TYPES = frozenset(
    {"COMMAND_LONG", "COMMAND_INT", "FILE_TRANSFER_PROTOCOL", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"}
)
_PARAM_REQUESTS = frozenset({"PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"})


@dataclass
class ResponderCounters:
    """Requests addressed to this component, by what was done.

    Attributes:
        commands_unsupported: COMMAND_LONG/COMMAND_INT answered with COMMAND_ACK(MAV_RESULT_UNSUPPORTED).
        ftp_naks: FILE_TRANSFER_PROTOCOL requests answered with a NAK (UnknownCommand).
        param_requests_ignored: PARAM_REQUEST_LIST/READ and PARAM_SET left unanswered (no parameters:
            the parameter protocol's rule).
    """

    commands_unsupported: int = 0
    ftp_naks: int = 0
    param_requests_ignored: int = 0


class ComponentResponder:
    """Answers requests addressed to the component whose ids ``codec`` encodes with (see the module's text).

    Args:
        codec: the encoding :class:`~mavahrs.protocol.codec.MavCodec` (the pipeline's): its
            ``system_id`` / ``component_id`` are read at every request (the system id is learnt from
            the autopilot's HEARTBEAT after start).
    """

    def __init__(self, codec: Any) -> None:
        self._codec = codec
        self.counters = ResponderCounters()

    def answer(self, msg: Any) -> list[bytes]:
        """The frames that answer ``msg`` (empty: none is due)."""
        kind = msg.get_type()
        if kind not in REQUEST_TYPES:
            return []
        codec = self._codec
        ours = (codec.system_id, codec.component_id)
        if (msg.target_system, msg.target_component) != ours:
            return []  # a broadcast, or for another component
        if (msg.get_srcSystem(), msg.get_srcComponent()) == ours:
            return []  # our own frame relayed back
        mav = codec.mav
        if kind in _PARAM_REQUESTS:
            self.counters.param_requests_ignored += 1
            return []
        if kind == "FILE_TRANSFER_PROTOCOL":
            if msg.target_network != 0:
                return []
            nak = self.ftp_nak(bytes(msg.payload))
            if nak is None:
                return []
            self.counters.ftp_naks += 1
            reply = mav.file_transfer_protocol_encode(0, msg.get_srcSystem(), msg.get_srcComponent(), list(nak))
            return [codec.encode(reply)]
        # COMMAND_LONG / COMMAND_INT
        self.counters.commands_unsupported += 1
        ack = mav.command_ack_encode(
            int(msg.command), MAV_RESULT_UNSUPPORTED, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )
        return [codec.encode(ack)]

    @staticmethod
    def ftp_nak(request_payload: bytes) -> bytes | None:
        """The FTP payload of a NAK(UnknownCommand) to ``request_payload`` (None: too short to be a request).

        Sequence number: the request's + 1 (mod 2¹⁶); session and request opcode: the request's;
        size 1, one data byte: the error code.  A NAK or ACK itself is never answered.
        """
        if len(request_payload) < _FTP_HEADER.size:
            return None
        seq, session, opcode = _FTP_HEADER.unpack_from(request_payload)[:3]
        if opcode >= 128:  # an ACK/NAK (someone's reply), not a request
            return None
        head = _FTP_HEADER.pack((seq + 1) & 0xFFFF, session, FTP_OP_NAK, 1, opcode, 0, 0, 0)
        return (head + bytes([FTP_ERR_UNKNOWN_COMMAND])).ljust(_FTP_PAYLOAD_LEN, b"\0")
