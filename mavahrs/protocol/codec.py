r"""Sans-I/O MAVLink: bytes in → decoded messages out; messages in → bytes out.

No sockets, files or clocks here (time is never read), so every behaviour is
tested without I/O.  pymavlink's dialect module does the message packing and
unpacking; this layer adds what a companion service needs around it:

* two parsing modes — a **datagram** (UDP) is parsed on its own, so junk in one
  datagram never swallows the frames of the next; a **stream** (serial, TCP)
  keeps its partial frame between reads (at most one frame, < 300 bytes);
* resynchronisation: a candidate frame that fails (CRC, bad flags, truncated)
  is re-scanned from its second byte, so a valid frame hidden behind a
  corrupt length byte is still found.  A frame with a message id this dialect
  does not know cannot be CRC-checked; it is accepted (as pymavlink's
  ``MAVLink_unknown``) only if no CRC-valid known frame starts inside it, so a
  stray marker byte in junk never swallows the real frames behind it;
* MAVLink 1 and 2 frames, zero-trimmed MAVLink 2 payloads, signed frames;
* counters (:class:`CodecCounters`): CRC errors, other bad data, per source
  (system id, component id) packets, sequence gaps, duplicates and
  out-of-order frames; exact duplicates (a relay sending a frame twice) are
  dropped;
* optional MAVLink 2 signing (:meth:`MavCodec.enable_signing`): every
  outgoing MAVLink 2 frame signed; incoming signatures verified (bad
  signatures and replays dropped and counted) and, with
  ``require_signing=True``, unsigned frames dropped too;
* encoding with the codec's own system/component id and a running sequence
  number (``encode(msg) -> bytes``).

The ArduPilot dialect (``ardupilotmega``, MAVLink 2 module) is used: it is a
superset of ``common`` and carries SIMSTATE, AHRS2 and friends.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mavahrs.protocol.signing import (
    SIGNATURE_LEN,
    SignatureCheck,
    SignatureVerifier,
    validate_key,
)

__all__ = [
    "MavCodec",
    "SourceCounters",
    "CodecCounters",
    "mavlink",
    "MAVLinkMessage",
    "frame_length",
]

MAVLinkMessage = mavlink.MAVLink_message

_MARKER_V1 = mavlink.PROTOCOL_MARKER_V1  # 0xFE
_MARKER_V2 = mavlink.PROTOCOL_MARKER_V2  # 0xFD
_IFLAG_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED  # 0x01
_MARKERS = re.compile(rb"[\xfd\xfe]")
_MAP = mavlink.mavlink_map
_HEADER = mavlink.MAVLink_header
_CRC16 = getattr(mavlink, "mcrf4xx", None)  # fastcrc's X.25 (a pymavlink requirement); None = not installed


def _lean_table() -> MappingProxyType[int, tuple[Any, Any, int, tuple[int, ...], bytes]]:
    """Messages decoded without pymavlink's generic ``decode``: no arrays, no strings.

    ``decode`` handles those with the same few steps (CRC with CRC_EXTRA,
    zero-pad, unpack, reorder to declaration order, construct, set header);
    doing them here directly halves the per-message cost.  Tested identical to
    pymavlink's ``decode`` for every such message.
    """
    table = {}
    if _CRC16 is not None:
        for mid, cls in _MAP.items():
            fmt = cls.unpacker.format
            fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
            if sum(cls.lengths) == len(cls.lengths) and "s" not in fmt and "c" not in fmt:
                table[mid] = (cls, cls.unpacker, cls.unpacker.size, tuple(cls.orders), bytes((cls.crc_extra,)))
    return MappingProxyType(table)


_LEAN = _lean_table()
#: the longest frame: MAVLink 2 header 10 + payload 255 + CRC 2 + signature 13
MAX_FRAME_LEN = 10 + 255 + 2 + SIGNATURE_LEN


def frame_length(buf: bytes | bytearray, i: int = 0) -> int:
    """Length of the frame starting at ``buf[i]`` from its header, or 0 if the header is incomplete.

    ``buf[i]`` must be a start marker (0xFE or 0xFD).
    """
    n = len(buf) - i
    if buf[i] == _MARKER_V2:
        if n < 3:
            return 0
        return buf[i + 1] + 12 + (SIGNATURE_LEN if buf[i + 2] & _IFLAG_SIGNED else 0)
    if n < 2:
        return 0
    return buf[i + 1] + 8


@dataclass
class SourceCounters:
    """What one source (system id, component id) has sent us."""

    packets: int = 0
    #: messages missing according to the sequence numbers (net of late arrivals)
    seq_gaps: int = 0
    #: exact repeats of the previous frame (same bytes), dropped
    duplicates: int = 0
    #: frames whose sequence number is behind the newest one seen (delivered anyway)
    out_of_order: int = 0
    last_seq: int = -1


@dataclass
class CodecCounters:
    """Totals over the codec's life.

    ``bad_data`` counts runs of skipped bytes (one corrupt frame or one burst of
    junk counts once); ``bytes_skipped`` counts the bytes themselves.
    ``crc_errors`` counts candidate frames of a known message whose CRC failed,
    not counting candidates inside an already failed frame (so one corrupted
    frame counts once).
    """

    bytes_in: int = 0
    packets: int = 0
    crc_errors: int = 0
    bad_data: int = 0
    bytes_skipped: int = 0
    unknown_messages: int = 0
    duplicates: int = 0
    packets_out: int = 0
    bytes_out: int = 0
    #: signing (only with :meth:`MavCodec.enable_signing`): valid signed frames accepted
    signed_ok: int = 0
    #: unsigned frames dropped because ``require_signing`` is set
    unsigned_rejected: int = 0
    #: signed frames whose signature does not match our key (dropped)
    bad_signature: int = 0
    #: signed frames whose timestamp did not increase on their (link, system, component) stream (dropped)
    replayed: int = 0
    sources: dict[tuple[int, int], SourceCounters] = field(default_factory=dict)

    @property
    def seq_gaps(self) -> int:
        return sum(s.seq_gaps for s in self.sources.values())

    @property
    def out_of_order(self) -> int:
        return sum(s.out_of_order for s in self.sources.values())

    @property
    def signing_rejected(self) -> int:
        """All frames dropped by signing checks."""
        return self.unsigned_rejected + self.bad_signature + self.replayed


class _SigningState:
    """Outgoing signing parameters (the key itself lives in pymavlink's ``MAVLinkSigning``)."""

    __slots__ = ("verifier", "require", "sign_outgoing")

    def __init__(self, verifier: SignatureVerifier, require: bool, sign_outgoing: bool) -> None:
        self.verifier = verifier
        self.require = require
        self.sign_outgoing = sign_outgoing

    def __repr__(self) -> str:  # never show the key
        return f"<signing require={self.require} sign_outgoing={self.sign_outgoing} key=***>"


class MavCodec:
    """One MAVLink endpoint's protocol state.

    Args:
        system_id: our system id for outgoing messages.
        component_id: our component id (191 = MAV_COMP_ID_ONBOARD_COMPUTER).
        drop_duplicates: drop a frame that repeats the previous frame of the same
            source byte for byte (a duplicating relay); counted either way.
    """

    def __init__(self, system_id: int = 1, component_id: int = 191, *, drop_duplicates: bool = True) -> None:
        # Encoder: our ids, sequence number and (optionally) the signing key.
        self._mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._mav.robust_parsing = True
        # Decoder: never holds a key, so pymavlink's own signature handling is
        # bypassed; signatures are verified here (see _accept).
        self._dec = mavlink.MAVLink(None)
        self._stream_buf = bytearray()
        self._drop_duplicates = drop_duplicates
        self._last_frame: dict[tuple[int, int], bytes] = {}
        self._signing: _SigningState | None = None
        self.counters = CodecCounters()

    def __repr__(self) -> str:
        return (
            f"MavCodec(system_id={self.system_id}, component_id={self.component_id}, "
            f"signing={'on' if self._signing else 'off'})"
        )

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
        """The pymavlink ``MAVLink`` object, for its ``*_encode`` constructors and sequence number."""
        return self._mav

    # ------------------------------------------------------------------ signing
    def enable_signing(
        self,
        key: bytes,
        link_id: int = 0,
        initial_timestamp_10us: int = 0,
        *,
        sign_outgoing: bool = True,
        require_signing: bool = False,
    ) -> None:
        """Sign outgoing MAVLink 2 frames and verify incoming signatures.

        Args:
            key: the 32-byte secret (see :func:`mavahrs.protocol.signing.load_signing_key`).
            link_id: our link id (0–255) written into every signature.
            initial_timestamp_10us: the signing timestamp to start from, in 10 µs
                units since 2015-01-01 UTC; the caller passes wall time once
                (:func:`mavahrs.protocol.signing.signing_timestamp_10us`), this
                codec never reads a clock.  It then increases by one per signed
                frame; :meth:`advance_signing_time` keeps it near wall time.
            sign_outgoing: sign what :meth:`encode` produces (MAVLink 1 frames
                cannot be signed and are sent unsigned).
            require_signing: drop every unsigned incoming frame
                (``counters.unsigned_rejected``).  Signed frames are always
                verified once a key is set: bad signatures and replays
                (timestamp not increasing per link/system/component) are
                dropped and counted either way.
        """
        key = validate_key(key)
        if not 0 <= int(link_id) <= 255:
            raise ValueError(f"signing link id must be 0..255, got {link_id!r}")
        if not 0 <= int(initial_timestamp_10us) < 2**48:
            raise ValueError(f"signing timestamp must be 0..2**48-1 (10 µs units), got {initial_timestamp_10us!r}")
        s = self._mav.signing
        s.secret_key = key
        s.link_id = int(link_id)
        s.timestamp = int(initial_timestamp_10us)
        s.sign_outgoing = bool(sign_outgoing)
        s.allow_unsigned_callback = None
        self._signing = _SigningState(
            SignatureVerifier(key, initial_timestamp_10us=int(initial_timestamp_10us)),
            require=bool(require_signing),
            sign_outgoing=bool(sign_outgoing),
        )

    def disable_signing(self) -> None:
        """Stop signing and verifying (the key is forgotten)."""
        s = self._mav.signing
        s.secret_key = None
        s.sign_outgoing = False
        s.link_id = 0
        s.timestamp = 0
        self._signing = None

    @property
    def signing_enabled(self) -> bool:
        return self._signing is not None

    @property
    def signing_timestamp_10us(self) -> int:
        """The timestamp the next signed frame will carry (0 when signing is off)."""
        return int(self._mav.signing.timestamp) if self._signing else 0

    def advance_signing_time(self, timestamp_10us: int) -> None:
        """Move the signing timestamp forward to ``timestamp_10us`` (never backwards).

        Call it now and then with wall time so the timestamp does not lag far
        behind (receivers accept a new stream only within a minute of their
        own time).  Also raises the floor for accepting new incoming streams.
        """
        if self._signing is None:
            return
        s = self._mav.signing
        s.timestamp = max(int(s.timestamp), int(timestamp_10us))
        self._signing.verifier.advance(int(timestamp_10us))

    # ------------------------------------------------------------------ decoding
    def receive_datagram(self, data: bytes | bytearray | memoryview) -> list[Any]:
        """Decode one UDP datagram on its own; a partial frame at its end is dropped."""
        self.counters.bytes_in += len(data)
        buf = data if isinstance(data, bytearray) else bytearray(data)
        out: list[Any] = []
        self._parse(buf, final=True, out=out)
        return out

    def receive_stream(self, data: bytes | bytearray | memoryview) -> list[Any]:
        """Decode bytes from a stream (serial/TCP); a partial frame waits for more bytes."""
        self.counters.bytes_in += len(data)
        buf = self._stream_buf
        buf += data
        out: list[Any] = []
        used = self._parse(buf, final=False, out=out)
        del buf[:used]
        return out

    def reset_stream(self) -> None:
        """Forget a partial frame (after a reconnect, the old bytes do not continue)."""
        if self._stream_buf:
            self.counters.bad_data += 1
            self.counters.bytes_skipped += len(self._stream_buf)
        self._stream_buf = bytearray()

    def decode_frame(self, frame: bytes | bytearray) -> Any | None:
        """Decode exactly one complete frame (no resync, no counters, no signing checks).

        Returns the pymavlink message (``MAVLink_unknown`` for ids this dialect
        lacks) or ``None`` if the bytes are not one valid frame.
        """
        buf = frame if isinstance(frame, bytearray) else bytearray(frame)
        if not buf or (buf[0] != _MARKER_V1 and buf[0] != _MARKER_V2):
            return None
        if frame_length(buf) != len(buf):
            return None
        msg, _ = self._decode_at(buf, 0, len(buf))
        return msg

    def _decode_at(self, buf: bytearray, i: int, flen: int) -> tuple[Any | None, int]:
        """Decode the candidate ``buf[i:i+flen]``: (message or None, why: 0 ok, 1 CRC, 2 other, 3 unknown id)."""
        if buf[i] == _MARKER_V2:
            flags = buf[i + 2]
            if flags & ~_IFLAG_SIGNED & 0xFF:
                return None, 2
            msgid = buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16)
            hl = 10
            siglen = SIGNATURE_LEN if flags & _IFLAG_SIGNED else 0
        else:
            flags = 0
            msgid = buf[i + 5]
            hl = 6
            siglen = 0
        lean = _LEAN.get(msgid)
        if lean is not None:  # same steps as pymavlink's decode, without its generic overhead
            cls, unpacker, size, orders, extra = lean
            msgbuf = buf[i : i + flen]
            end = flen - siglen - 2
            crc = msgbuf[end] | (msgbuf[end + 1] << 8)
            if _CRC16(extra, _CRC16(bytes(msgbuf[1:end]), 0xFFFF)) != crc:
                return None, 1
            payload = msgbuf[hl:end]
            if len(payload) < size:
                payload += bytes(size - len(payload))
            t = unpacker.unpack_from(payload)
            try:
                m = cls(*[t[o] for o in orders])
            except Exception:  # noqa: BLE001 - as pymavlink: a message that cannot be built is bad data
                return None, 2
            m._signed = False
            m._msgbuf = msgbuf
            m._payload = msgbuf[6:end]  # sic: pymavlink's offset for both versions
            m._crc = crc
            if hl == 10:
                m._header = _HEADER(msgid, flags, msgbuf[3], msgbuf[1], msgbuf[4], msgbuf[5], msgbuf[6])
            else:
                m._header = _HEADER(msgid, 0, 0, msgbuf[1], msgbuf[2], msgbuf[3], msgbuf[4])
            return m, 0
        try:
            msg = self._dec.decode(buf[i : i + flen])
        except mavlink.MAVError as exc:
            return None, 1 if "CRC" in str(getattr(exc, "message", exc)) else 2
        except Exception:  # noqa: BLE001 - hostile bytes must never raise out of the decoder
            return None, 2
        return msg, 0 if msgid in _MAP else 3

    def _valid_known_frame_in(self, buf: bytearray, start: int, stop: int) -> int:
        """Index of the first complete, CRC-valid frame of a known message starting in [start, stop), or -1."""
        m = _MARKERS.search(buf, start, stop)
        n = len(buf)
        while m is not None:
            j = m.start()
            flen = frame_length(buf, j)
            if flen and j + flen <= n:
                _, why = self._decode_at(buf, j, flen)
                if why == 0:
                    return j
            m = _MARKERS.search(buf, j + 1, stop)
        return -1

    def _incomplete_candidate_in(self, buf: bytearray, start: int, stop: int) -> bool:
        """Whether a start marker in [start, stop) begins a frame that runs past the end of ``buf``."""
        n = len(buf)
        m = _MARKERS.search(buf, start, stop)
        while m is not None:
            j = m.start()
            flen = frame_length(buf, j)
            if flen == 0 or j + flen > n:
                return True
            m = _MARKERS.search(buf, j + 1, stop)
        return False

    def _parse(self, buf: bytearray, final: bool, out: list[Any]) -> int:
        """Decode frames from ``buf`` into ``out``; returns the number of bytes consumed."""
        c = self.counters
        n = len(buf)
        i = 0
        skip_start = -1  # start of the current run of skipped bytes
        shadow_end = 0  # end of the last failed candidate (CRC failures inside it are not counted)
        while i < n:
            b = buf[i]
            if b != _MARKER_V1 and b != _MARKER_V2:
                m = _MARKERS.search(buf, i + 1)
                j = m.start() if m is not None else n
                if skip_start < 0:
                    skip_start = i
                i = j
                continue
            flen = frame_length(buf, i)
            if flen == 0 or i + flen > n:  # incomplete candidate
                if not final and self._valid_known_frame_in(buf, i + 1, n) < 0:
                    break  # wait for the rest of the frame
                if skip_start < 0:
                    skip_start = i
                i += 1
                continue
            msg, why = self._decode_at(buf, i, flen)
            # An unknown id cannot be CRC-checked: a CRC-valid known frame starting inside it wins;
            # with none yet, a candidate inside that is still incomplete is waited for.
            hides_real = why == 3 and self._valid_known_frame_in(buf, i + 1, i + flen) >= 0
            if why == 3 and not hides_real and not final and self._incomplete_candidate_in(buf, i + 1, i + flen):
                break
            if msg is None or hides_real:
                if why == 1 and i >= shadow_end:
                    c.crc_errors += 1
                shadow_end = max(shadow_end, i + flen)
                if skip_start < 0:
                    skip_start = i
                i += 1
                continue
            if skip_start >= 0:
                c.bad_data += 1
                c.bytes_skipped += i - skip_start
                skip_start = -1
            if why == 3:
                c.unknown_messages += 1
            self._accept(buf, i, flen, msg, out, why != 3)
            i += flen
        if skip_start >= 0:
            c.bad_data += 1
            c.bytes_skipped += i - skip_start
        return i if not final else n

    def _accept(self, buf: bytearray, i: int, flen: int, msg: Any, out: list[Any], known: bool) -> None:
        """Signing checks, sequence/duplicate bookkeeping; append ``msg`` to ``out`` if it passes.

        A frame of an unknown message (not CRC-checkable) only counts towards
        the sequence bookkeeping of a source already seen with a known
        message, so stray markers in junk do not invent sources.
        """
        c = self.counters
        v2 = buf[i] == _MARKER_V2
        signed = v2 and bool(buf[i + 2] & _IFLAG_SIGNED)
        if v2:
            seq, sysid, compid = buf[i + 4], buf[i + 5], buf[i + 6]
        else:
            seq, sysid, compid = buf[i + 2], buf[i + 3], buf[i + 4]
        sig = self._signing
        if sig is not None:
            if signed:
                check = sig.verifier.check(buf, i, flen, sysid, compid)
                if check is SignatureCheck.BAD_SIGNATURE:
                    c.bad_signature += 1
                    return
                if check is SignatureCheck.REPLAYED:
                    c.replayed += 1
                    return
                c.signed_ok += 1
                msg._signed = True
                msg._link_id = buf[i + flen - SIGNATURE_LEN]
                # Our next outgoing timestamp is at least the newest valid one seen (as pymavlink does).
                s = self._mav.signing
                s.timestamp = max(int(s.timestamp), sig.verifier.last_timestamp)
            elif sig.require:
                c.unsigned_rejected += 1
                return
        key = (sysid, compid)
        src = c.sources.get(key)
        if src is None:
            if not known:
                c.packets += 1
                out.append(msg)
                return
            src = c.sources[key] = SourceCounters()
        last = src.last_seq
        if last >= 0:
            ahead = (seq - last) % 256
            if ahead == 0:
                frame = bytes(buf[i : i + flen])
                if frame == self._last_frame.get(key):
                    src.duplicates += 1
                    c.duplicates += 1
                    if self._drop_duplicates:
                        return
                self._last_frame[key] = frame
            elif ahead < 128:
                src.seq_gaps += ahead - 1
                src.last_seq = seq
                self._last_frame[key] = bytes(buf[i : i + flen])
            else:  # behind the newest: late (reordered) frame; it was counted as missing
                src.out_of_order += 1
                if src.seq_gaps > 0:
                    src.seq_gaps -= 1
        else:
            src.last_seq = seq
            self._last_frame[key] = bytes(buf[i : i + flen])
        src.packets += 1
        c.packets += 1
        out.append(msg)

    # ------------------------------------------------------------------ encoding
    def encode(self, msg: Any, *, force_mavlink1: bool = False) -> bytes:
        """Pack ``msg`` with our ids and the next sequence number (signed if signing is on)."""
        data = bytes(msg.pack(self._mav, force_mavlink1=force_mavlink1))
        self._mav.seq = (self._mav.seq + 1) % 256
        self.counters.packets_out += 1
        self.counters.bytes_out += len(data)
        return data

    def encode_many(self, msgs: Iterable[Any]) -> bytes:
        return b"".join(self.encode(m) for m in msgs)
