r"""Sans-I/O MAVLink: bytes in → decoded messages out; messages in → bytes out.

No sockets, files or clocks here (time is never read), so every behaviour is
tested without I/O.  pymavlink's dialect module does the message packing,
unpacking and CRC; this layer adds what a companion service needs around it:

* two parsing modes — a **datagram** (UDP) is parsed on its own, so junk in one
  datagram never swallows the frames of the next; a **stream** (serial, TCP)
  keeps its partial frame between reads;
* resynchronisation after a corrupt frame: a frame whose CRC fails is
  re-scanned from its second byte, so a valid frame hidden behind a corrupt
  length byte is still found;
* counters per source system/component: packets, CRC errors and other bad
  data, sequence gaps;
* encoding with the codec's own system/component id and a running sequence
  number (``encode(msg) -> bytes``).

The ArduPilot dialect (``ardupilotmega``) is used: it is a superset of
``common`` and carries SIMSTATE, AHRS2 and friends.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["MavCodec", "SourceCounters", "CodecCounters", "mavlink", "MAVLinkMessage"]

MAVLinkMessage = mavlink.MAVLink_message

_MARKER_V1 = mavlink.PROTOCOL_MARKER_V1  # 0xFE
_MARKER_V2 = mavlink.PROTOCOL_MARKER_V2  # 0xFD


@dataclass
class SourceCounters:
    """What one source (system id, component id) has sent us."""

    packets: int = 0
    seq_gaps: int = 0  # messages missing according to the sequence numbers
    last_seq: int = -1


@dataclass
class CodecCounters:
    """Totals over the codec's life."""

    bytes_in: int = 0
    packets: int = 0
    crc_errors: int = 0
    bad_data: int = 0  # bytes skipped that were not part of a valid frame (runs counted)
    unknown_messages: int = 0
    packets_out: int = 0
    bytes_out: int = 0
    sources: dict[tuple[int, int], SourceCounters] = field(default_factory=dict)

    @property
    def seq_gaps(self) -> int:
        return sum(s.seq_gaps for s in self.sources.values())


class MavCodec:
    """One MAVLink endpoint's protocol state.

    Args:
        system_id: our system id for outgoing messages.
        component_id: our component id (191 = MAV_COMP_ID_ONBOARD_COMPUTER).
    """

    def __init__(self, system_id: int = 1, component_id: int = 191) -> None:
        self._mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._mav.robust_parsing = True
        self._stream_buf = bytearray()
        self.counters = CodecCounters()

    # ------------------------------------------------------------------ identity
    @property
    def system_id(self) -> int:
        return int(self._mav.srcSystem)

    @system_id.setter
    def system_id(self, value: int) -> None:
        self._mav.srcSystem = int(value)

    @property
    def component_id(self) -> int:
        return int(self._mav.srcComponent)

    @property
    def mav(self) -> Any:
        """The pymavlink ``MAVLink`` object, for its ``*_encode`` constructors and signing state."""
        return self._mav

    # ------------------------------------------------------------------ decoding
    def receive_datagram(self, data: bytes) -> list[Any]:
        """Decode one UDP datagram on its own; a partial frame at its end is dropped."""
        buf = bytearray(data)
        msgs = self._parse(buf, final=True)
        return msgs

    def receive_stream(self, data: bytes) -> list[Any]:
        """Decode bytes from a stream (serial/TCP); a partial frame waits for more bytes."""
        self._stream_buf.extend(data)
        msgs = self._parse(self._stream_buf, final=False)
        return msgs

    def _parse(self, buf: bytearray, final: bool) -> list[Any]:
        self.counters.bytes_in += len(buf) if final else 0
        out: list[Any] = []
        i = 0
        n = len(buf)
        skipped = 0
        while i < n:
            b = buf[i]
            if b != _MARKER_V1 and b != _MARKER_V2:
                i += 1
                skipped += 1
                continue
            if b == _MARKER_V2:
                if n - i < 3:
                    break
                length = buf[i + 1] + 12
                if buf[i + 2] & mavlink.MAVLINK_IFLAG_SIGNED:
                    length += mavlink.MAVLINK_SIGNATURE_BLOCK_LEN
            else:
                if n - i < 2:
                    break
                length = buf[i + 1] + 8
            if n - i < length:
                break  # incomplete frame
            frame = buf[i : i + length]
            try:
                if b == _MARKER_V2 and frame[2] & ~mavlink.MAVLINK_IFLAG_SIGNED:
                    raise mavlink.MAVError("invalid incompat_flags")
                msg = self._mav.decode(frame)
            except mavlink.MAVError as exc:
                # Not a valid frame here: count it and resynchronise one byte on.
                if "CRC" in str(exc.message if hasattr(exc, "message") else exc):
                    self.counters.crc_errors += 1
                i += 1
                skipped += 1
                continue
            except Exception:  # noqa: BLE001 - pymavlink can raise anything on hostile bytes
                i += 1
                skipped += 1
                continue
            if skipped:
                self.counters.bad_data += 1
                skipped = 0
            i += length
            if isinstance(msg, mavlink.MAVLink_unknown):
                self.counters.unknown_messages += 1
            self._count(msg)
            out.append(msg)
        if skipped:
            self.counters.bad_data += 1
        if final:
            del buf[:]
        else:
            self.counters.bytes_in += i
            del buf[:i]
            if len(buf) > 4096:  # never hold on to junk that cannot start a frame
                self.counters.bad_data += 1
                del buf[:-300]
        return out

    def _count(self, msg: Any) -> None:
        c = self.counters
        c.packets += 1
        hdr = msg._header
        key = (hdr.srcSystem, hdr.srcComponent)
        src = c.sources.get(key)
        if src is None:
            src = c.sources[key] = SourceCounters()
        if src.last_seq >= 0:
            gap = (hdr.seq - src.last_seq - 1) % 256
            if gap < 128:  # larger "gaps" are duplicates/reordering, not losses
                src.seq_gaps += gap
        src.last_seq = hdr.seq
        src.packets += 1

    # ------------------------------------------------------------------ encoding
    def encode(self, msg: Any, *, force_mavlink1: bool = False) -> bytes:
        """Pack ``msg`` with our ids and the next sequence number (signed if signing is set up)."""
        data = bytes(msg.pack(self._mav, force_mavlink1=force_mavlink1))
        self._mav.seq = (self._mav.seq + 1) % 256
        self.counters.packets_out += 1
        self.counters.bytes_out += len(data)
        return data

    def encode_many(self, msgs: Iterable[Any]) -> bytes:
        return b"".join(self.encode(m) for m in msgs)
