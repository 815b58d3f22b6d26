r"""Bulk tlog reader for replay: the whole file at once, pymavlink's results at C-like speed.

A tlog is a sequence of records ``[8-byte big-endian µs timestamp][one MAVLink
frame]`` (MAVProxy, QGroundControl, Mission Planner).  This reader gives
*exactly* the messages, field values and timestamps that pymavlink's
``mavutil.mavlink_connection(path)`` + ``recv_match(type=types)`` returns —
including on truncated and corrupted files — because it does what pymavlink
does, byte for byte, in one compiled pass (numba, cached on disk):

1. **Index** (pymavlink ``mavmmaplog.init_arrays``): from offset 0, a record
   is "8 bytes, then a start marker"; its length comes from the frame header;
   where no marker follows, slide one byte.  No CRC check here.  The first
   record of each message type is also read through the parser (step 2) —
   pymavlink does this to learn instance fields, and its parser state carries
   over.  Records of instance-carrying types (RAW_IMU, HIGHRES_IMU, …) whose
   payload runs past the end stop the index.
2. **Read** (``mavmmaplog.recv_match`` → ``mavlogfile.recv_msg``): for each
   indexed record of a requested type (plus HEARTBEAT and PARAM_VALUE, which
   pymavlink always visits), seek there and run pymavlink's frame parser: read
   the 8-byte timestamp (after a failed frame, a timestamp more than 3 days
   from the last good one starts pymavlink's byte-by-byte scan for a plausible
   one), then the frame as the parser's ``bytes_needed`` asks, with its
   buffer carried over from earlier reads; decode: flags, CRC (X.25 with the
   message's CRC_EXTRA), zero-padding of trimmed MAVLink 2 payloads.  When the
   index is used up, pymavlink keeps reading sequentially to the end of file,
   and so does this.
3. **Decode** the fields of each wanted type in bulk: the payloads gathered
   into a zero-padded ``(n, wire_size)`` byte matrix and viewed through a
   numpy dtype built from the dialect's struct format and field order, so
   every numeric message type works the same way.

``read_tlog_arrays`` returns one numpy structured array per message type with
``t_us`` (the record's timestamp), ``sysid``, ``compid`` and the message's
fields (declaration order, as ``msg.to_dict()``).  The same emulation drives
:func:`mavahrs.protocol.tlog.read_tlog_messages` and
:func:`~mavahrs.protocol.tlog.iter_tlog`, which hand out pymavlink message
objects / raw frames instead.

Reference behaviour: pymavlink with the MAVLink 2 ``ardupilotmega`` dialect
(``MAVLINK20=1``, ``MAVLINK_DIALECT=ardupilotmega``), which is what mavahrs
decodes with.  pymavlink's defaults (dialect ``all``, MAVLink 1 module until a
MAVLink 2 frame is seen) decode MAVLink 1 logs without the extension fields
(``RAW_IMU.id``/``temperature``, …); those fields read 0 here.  Known
differences, all on corrupt input only, are listed in ``docs/protocol.md``.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, BinaryIO

import numpy as np

from mavahrs.errors import ConfigError
from mavahrs.filters.jit import HAVE_NUMBA, kernel
from mavahrs.protocol.codec import mavlink

if HAVE_NUMBA:
    import numba as _numba

    # Helpers called once or more per record: inlined into the caller, so no
    # per-call argument passing and array reference counting (~10x faster).
    _inline = _numba.njit(cache=True, inline="always", error_model="numpy")
else:  # pragma: no cover - exercised only where numba is absent
    _inline = kernel

__all__ = [
    "IMU_TYPES",
    "DEFAULT_TYPES",
    "TlogScan",
    "truncated_frame_at",
    "read_tlog_arrays",
    "decode_scan",
    "scan_tlog",
    "message_dtype",
    "load_bytes",
    "truncated_frame_at",
]

#: IMU message types mavahrs replays from
IMU_TYPES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
#: what ``read_tlog_arrays`` decodes by default: IMU, attitude/truth, GNSS, heartbeat, time
DEFAULT_TYPES = IMU_TYPES + (
    "ATTITUDE",
    "ATTITUDE_QUATERNION",
    "AHRS2",
    "SIMSTATE",
    "SIM_STATE",
    "HIL_STATE_QUATERNION",
    "GLOBAL_POSITION_INT",
    "GPS_RAW_INT",
    "HEARTBEAT",
    "SYSTEM_TIME",
)

_ID_HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
_ID_PARAM_VALUE = mavlink.MAVLINK_MSG_ID_PARAM_VALUE
_NAME_TO_CLASS = {cls.msgname: cls for cls in mavlink.mavlink_map.values()}

# result kinds of one pymavlink recv_msg
_NONE, _BAD, _OK, _UNKNOWN = 0, 1, 2, 3
# parser state (int64 vector)
(_FPOS, _BS, _BE, _EXP, _LAST_BAD, _HAVE_GOOD, _RES_START, _RES_LEN, _RES_ID, _SEG, _LASTPOS,
 _RES_IN_DATA) = range(12)  # fmt: skip
_ST_LEN = 12
_BUF_CAP = 4096
# stats vector
_S_EMITTED, _S_RAISES, _S_SCANS, _S_INDEXED, _S_BAD, _S_SIDE_NEEDED = range(6)
_N_STATS = 6
_THREE_DAYS_S = 3.0 * 24 * 60 * 60  # pymavlink mavlogfile.pre_message


def _dialect_tables() -> tuple[np.ndarray, np.ndarray]:
    """CRC_EXTRA (−1 = unknown id) and instance-field offset (−1 = none) per message id."""
    crc_extra = np.full(65536, -1, np.int16)
    inst = np.full(65536, -1, np.int16)
    for mid, cls in mavlink.mavlink_map.items():
        if mid >= 65536:  # pragma: no cover - no such id in the dialect today
            raise ImportError(f"message id {mid} does not fit the fast tlog reader's tables")
        crc_extra[mid] = cls.crc_extra
        if cls.instance_field is not None:
            inst[mid] = max(0, int(cls.instance_offset))
    crc_extra.flags.writeable = False
    inst.flags.writeable = False
    return crc_extra, inst


def _crc_table() -> np.ndarray:
    """Slicing-by-4 tables of CRC-16/MCRF4XX (MAVLink's X.25, reflected polynomial 0x8408).

    ``table[0]`` is the classic byte table; ``table[k][i]`` is the CRC register
    after byte ``i`` followed by ``k`` zero bytes, so four bytes are folded in
    with four independent lookups.
    """
    table = np.zeros((4, 256), np.uint16)
    for b in range(256):
        crc = b
        for _ in range(8):
            crc = (crc >> 1) ^ 0x8408 if crc & 1 else crc >> 1
        table[0, b] = crc
    for k in range(1, 4):
        for b in range(256):
            prev = int(table[k - 1, b])
            table[k, b] = (prev >> 8) ^ int(table[0, prev & 0xFF])
    table.flags.writeable = False
    return table


_CRC_EXTRA, _INSTANCE = _dialect_tables()
_CRC_TABLE = _crc_table()


# --------------------------------------------------------------------------- kernels
@_inline
def _x25_crc(buf, start, stop, extra, table):  # type: ignore[no-untyped-def]
    """CRC-16/MCRF4XX (MAVLink's X.25) over ``buf[start:stop]`` then the CRC_EXTRA byte (slicing-by-4)."""
    # int64 throughout: numba would unify int64 with uint64 table values to float64
    crc = np.int64(0xFFFF)
    i = start
    while i + 4 <= stop:
        x = crc ^ (np.int64(buf[i]) | (np.int64(buf[i + 1]) << 8))
        crc = (
            np.int64(table[3, x & 0xFF])
            ^ np.int64(table[2, (x >> 8) & 0xFF])
            ^ np.int64(table[1, buf[i + 2]])
            ^ np.int64(table[0, buf[i + 3]])
        )
        i += 4
    while i < stop:
        crc = (crc >> 8) ^ np.int64(table[0, (crc ^ np.int64(buf[i])) & 0xFF])
        i += 1
    return (crc >> 8) ^ np.int64(table[0, (crc ^ extra) & 0xFF])


@_inline
def _be64(data, p):  # type: ignore[no-untyped-def]
    v = np.uint64(0)
    for k in range(8):
        v = (v << np.uint64(8)) | np.uint64(data[p + k])
    return v


@_inline
def _parse(buf, st, crc_extra, table):  # type: ignore[no-untyped-def]
    """pymavlink ``MAVLink.__parse_char_legacy`` + ``decode`` outcome on the parser buffer."""
    bs = st[_BS]
    be = st[_BE]
    blen = be - bs
    header_len = 6
    if blen >= 1 and buf[bs] == 0xFD:
        header_len = 10
    if blen >= 1 and buf[bs] != 0xFE and buf[bs] != 0xFD:
        i = bs + 1
        while i < be and buf[i] != 0xFE and buf[i] != 0xFD:
            i += 1
        st[_BS] = i
        st[_EXP] = header_len + 2
        return _BAD  # "Bad prefix"
    magic = 0
    flags = 0
    if blen >= 3:
        magic = int(buf[bs])
        e = int(buf[bs + 1])
        flags = int(buf[bs + 2])
        if magic == 0xFD and (flags & 1) != 0:
            e += 13
        e += header_len + 2
        st[_EXP] = e
    e = st[_EXP]
    if e >= header_len + 2 and blen >= e:
        st[_BS] = bs + e
        st[_EXP] = header_len + 2
        st[_RES_IN_DATA] = 0
        return _decode(buf, bs, e, st, crc_extra, table)
    return _NONE


@_inline
def _decode(arr, bs, e, st, crc_extra, table):  # type: ignore[no-untyped-def]
    """pymavlink ``decode`` outcome for the complete candidate frame ``arr[bs:bs+e]``."""
    st[_RES_START] = bs
    st[_RES_LEN] = e
    st[_RES_ID] = -1
    magic = int(arr[bs])
    siglen = 0
    if magic == 0xFD:
        flags = int(arr[bs + 2])
        if (flags & 0xFE) != 0:
            return _BAD  # invalid incompat_flags
        msgid = int(arr[bs + 7]) | (int(arr[bs + 8]) << 8) | (int(arr[bs + 9]) << 16)
        if (flags & 1) != 0:
            siglen = 13
    else:
        msgid = int(arr[bs + 5])
    st[_RES_ID] = msgid
    if msgid >= 65536 or crc_extra[msgid] < 0:
        return _UNKNOWN  # pymavlink returns MAVLink_unknown without a CRC check
    cpos = bs + e - siglen - 2
    crc = int(arr[cpos]) | (int(arr[cpos + 1]) << 8)
    if crc != _x25_crc(arr, bs + 1, cpos, int(crc_extra[msgid]), table):
        return _BAD
    return _OK


@kernel
def _recv_msg(data, st, ts, tf, buf, crc_extra, table, stats):  # type: ignore[no-untyped-def]
    """pymavlink ``mavlogfile.recv_msg`` (pre_message, read bytes_needed, parse_char, post_message)."""
    n = data.shape[0]
    p = st[_FPOS]
    k = n - p
    if k > 8:
        k = 8
    if k < 0:
        k = 0
    if k == 8:
        raw = _be64(data, p)
        p += 8
        t = float(raw) * 1.0e-6
        if st[_HAVE_GOOD] == 1 and st[_LAST_BAD] == 1 and abs(t - tf[1]) > _THREE_DAYS_S:
            stats[_S_SCANS] += 1
            q = p - 8  # scan_timestamp: slide one byte at a time
            while True:
                raw = _be64(data, q)
                t = float(raw) * 1.0e-6
                if abs(t - tf[1]) <= _THREE_DAYS_S:
                    break
                if q + 8 >= n:
                    break
                q += 1
            p = q + 8
        ts[0] = raw
        tf[0] = t
    else:
        p += k
    st[_FPOS] = p
    # Fast path, same outcome: parser buffer empty and a whole frame starts here.
    # pymavlink would read bytes_needed (>= 8) bytes, learn the length, read
    # the rest and decode — the frame is these file bytes, nothing is left over.
    if st[_BE] == st[_BS] and p + 3 <= n and (data[p] == 0xFE or data[p] == 0xFD):
        if data[p] == 0xFD:
            hl = 10
            e = int(data[p + 1]) + 12
            if (data[p + 2] & 1) != 0:
                e += 13
        else:
            hl = 6
            e = int(data[p + 1]) + 8
        if st[_EXP] <= e and p + e <= n:
            st[_FPOS] = p + e
            st[_EXP] = hl + 2
            st[_RES_IN_DATA] = 1
            kind = _decode(data, p, e, st, crc_extra, table)
            if kind == _BAD:
                st[_LAST_BAD] = 1
                stats[_S_BAD] += 1
            else:
                st[_LAST_BAD] = 0
                st[_HAVE_GOOD] = 1
                tf[1] = tf[0]
            return kind
    while True:
        blen = st[_BE] - st[_BS]
        need = st[_EXP] - blen
        if need <= 0:
            need = 1
        k = n - st[_FPOS]
        if k > need:
            k = need
        if k < 0:
            k = 0
        if k > 0:
            if st[_BE] + k > buf.shape[0]:  # compact the buffer
                shift = st[_BS]
                for j in range(blen):
                    buf[j] = buf[shift + j]
                st[_BS] = 0
                st[_BE] = blen
                st[_SEG] = st[_SEG] - shift
                if st[_SEG] < 0:
                    st[_SEG] = 0
            fp = st[_FPOS]
            if blen == 0 or st[_LASTPOS] + 1 != fp:
                st[_SEG] = st[_BE]  # bytes from here on are contiguous in the file
            be = st[_BE]
            for j in range(k):
                buf[be + j] = data[fp + j]
            st[_BE] = be + k
            st[_FPOS] = fp + k
            st[_LASTPOS] = fp + k - 1
        kind = _parse(buf, st, crc_extra, table)
        if kind != _NONE:
            if kind == _BAD:
                st[_LAST_BAD] = 1
                stats[_S_BAD] += 1
            else:
                st[_LAST_BAD] = 0
                st[_HAVE_GOOD] = 1
                tf[1] = tf[0]
            return kind
        if k == 0:
            return _NONE


@_inline
def _emit(data, st, ts, buf, out_t, out_off, out_side, out_len, out_id, side, stats):  # type: ignore[no-untyped-def]
    """Record the frame just parsed: by file offset if contiguous in the file, else copied aside."""
    j = stats[_S_EMITTED]
    s = st[_RES_START]
    ln = st[_RES_LEN]
    out_t[j] = ts[0]
    out_len[j] = ln
    out_id[j] = st[_RES_ID]
    if st[_RES_IN_DATA] != 0:
        out_off[j] = s
        out_side[j] = 0
    elif s >= st[_SEG]:
        # buf[_SEG:_BE] are adjacent file bytes ending at _LASTPOS
        out_off[j] = st[_LASTPOS] - (st[_BE] - 1 - s)
        out_side[j] = 0
    else:
        used = stats[_S_SIDE_NEEDED]
        if used + ln <= side.shape[0]:
            for q in range(ln):
                side[used + q] = buf[s + q]
        out_off[j] = used
        out_side[j] = 1
        stats[_S_SIDE_NEEDED] = used + ln
    stats[_S_EMITTED] = j + 1


@_inline
def _copy_into(dst, src):  # type: ignore[no-untyped-def]
    """``dst[:] = src`` element by element (a whole-array assignment needs numba's runtime)."""
    for k in range(src.shape[0]):
        dst[k] = src[k]


def _emulate_scratch() -> tuple[Any, ...]:
    """The reader state and scratch arrays :func:`_emulate` works in (initialised by it)."""
    return (
        np.empty(_ST_LEN, np.int64), np.empty(_ST_LEN, np.int64),  # state, its initial copy
        np.empty(1, np.uint64),  # the current record's timestamp
        np.empty(2, np.float64), np.empty(2, np.float64),  # times, their initial copy
        np.empty(_BUF_CAP, np.uint8), np.empty(_BUF_CAP, np.uint8),  # frame buffer, its initial copy
        np.empty(65536, np.uint8), np.empty(65536, np.int16),  # types seen, instance field per type
    )  # fmt: skip


@kernel
def _emulate(  # type: ignore[no-untyped-def]
    data,
    crc_extra,
    crc_table,
    inst_tab,
    visit,
    want,
    want_unknown,
    index_pass,
    indexed_read,
    idx_off,
    idx_id,
    out_t,
    out_off,
    out_side,
    out_len,
    out_id,
    side,
    stats,
    st,
    st0,
    ts,
    tf,
    tf0,
    buf,
    buf0,
    seen,
    inst,
):
    """pymavlink's tlog reading: ``mavmmaplog`` index + ``recv_match(type=…)``, or plain ``mavlogfile``.

    One loop with a single ``_recv_msg`` call site (it is inlined; one copy
    keeps compilation short).  Phases: 0 index, 1 read indexed records,
    2 read sequentially to the end of file.  The reader's state and scratch
    arrays (``st`` … ``inst``, :func:`_emulate_scratch`) come from the caller
    and are initialised here: the kernel allocates nothing, so it runs without
    numba's reference counting (:func:`mavahrs.filters.jit.kernel`).
    """
    n = data.shape[0]
    st[:] = 0
    st[_EXP] = 8  # HEADER_LEN_V1 + 2
    st[_LASTPOS] = -2
    ts[:] = 0
    tf[:] = 0.0
    buf[:] = 0
    _copy_into(st0, st)
    _copy_into(tf0, tf)
    _copy_into(buf0, buf)
    ts0 = ts[0]
    seen[:] = 0
    inst[:] = -1
    nidx = 0
    r = 0
    ofs = 0
    # the record whose first-instance read is in progress
    p_type = np.int64(0)
    p_end = np.int64(0)
    p_mlen = np.int64(0)
    phase = 0 if (index_pass and n > 0) else (1 if indexed_read else 2)
    if phase != 0:
        stats[_S_INDEXED] = 0
    while True:
        if phase == 0:
            found = False
            while ofs + 8 + 6 < n:
                marker = data[ofs + 8]
                plen = np.int64(data[ofs + 9])
                mlen = plen + 8
                if marker == 0xFE:
                    mtype = np.int64(data[ofs + 13])
                    mlen += 8
                    data_ofs = 14
                elif marker == 0xFD:
                    if ofs + 8 + 10 > n:
                        break
                    mtype = np.int64(data[ofs + 15]) | (np.int64(data[ofs + 16]) << 8) | (np.int64(data[ofs + 17]) << 16)
                    mlen += 12
                    data_ofs = 18
                    if (data[ofs + 10] & 1) != 0:
                        mlen += 13
                else:
                    ofs += 1
                    continue
                if mtype >= 65536 or crc_extra[mtype] < 0:
                    ofs += mlen
                    continue
                if seen[mtype] == 0:  # pymavlink reads the first record of each type here
                    seen[mtype] = 1
                    p_type = mtype
                    p_end = ofs + data_ofs + plen
                    p_mlen = mlen
                    found = True
                    break
                if inst[mtype] >= 0 and ofs + data_ofs + plen > n:
                    ofs = n  # a truncated instance-carrying record ends the index
                    break
                idx_off[nidx] = ofs
                idx_id[nidx] = mtype
                nidx += 1
                ofs += mlen
            if not found:
                stats[_S_INDEXED] = nidx
                st[_FPOS] = 0  # _rewind
                phase = 1 if indexed_read else 2
                continue
            _copy_into(st0, st)
            _copy_into(tf0, tf)
            _copy_into(buf0, buf)
            ts0 = ts[0]
            st[_FPOS] = ofs
        elif phase == 1:
            while r < nidx and visit[idx_id[r]] == 0:
                r += 1
            if r >= nidx:
                phase = 2
                continue
            st[_FPOS] = idx_off[r]
            r += 1
        kind = _recv_msg(data, st, ts, tf, buf, crc_extra, crc_table, stats)
        if phase == 0:
            if kind == _NONE:
                # pymavlink raises here (AttributeError on None._instance_field);
                # carry on as if this read had not happened
                stats[_S_RAISES] += 1
                _copy_into(st, st0)
                ts[0] = ts0
                _copy_into(tf, tf0)
                _copy_into(buf, buf0)
            elif kind == _OK and inst_tab[st[_RES_ID]] >= 0:
                inst[p_type] = inst_tab[st[_RES_ID]]
            if inst[p_type] >= 0 and p_end > n:
                ofs = n  # truncated instance-carrying record ends the index
            else:
                idx_off[nidx] = ofs
                idx_id[nidx] = p_type
                nidx += 1
                ofs += p_mlen
            continue
        if kind == _NONE:
            break
        if (kind == _OK and want[st[_RES_ID]] != 0) or (kind == _UNKNOWN and want_unknown):
            _emit(data, st, ts, buf, out_t, out_off, out_side, out_len, out_id, side, stats)
    return stats[_S_EMITTED]


@kernel
def _gather_fields(data, side, out_off, out_side, sel, scan_t, field_src, field_dst, field_len, rec, t_col, sys_col, comp_col):  # type: ignore[no-untyped-def]  # noqa: E501
    """The payloads of the selected frames, field by field, straight into their records.

    ``rec`` is the output records as bytes (n, itemsize); field ``k`` takes
    ``field_len[k]`` bytes at ``field_src[k]`` of the payload (zero past the
    payload's end: MAVLink 2 trims trailing zeros) to ``field_dst[k]`` of the
    record.  ``t_col``, ``sys_col``, ``comp_col`` are the record's ``t_us``,
    ``sysid`` and ``compid`` columns.  Little-endian hosts only (the wire order).
    """
    for r in range(sel.shape[0]):
        j = sel[r]
        src = side if out_side[j] != 0 else data
        f = out_off[j]
        plen = int(src[f + 1])
        if src[f] == 0xFE:
            h = 6
            sys_col[r] = src[f + 3]
            comp_col[r] = src[f + 4]
        else:
            h = 10
            sys_col[r] = src[f + 5]
            comp_col[r] = src[f + 6]
        t_col[r] = scan_t[j]
        base = f + h
        for k in range(field_src.shape[0]):
            q0 = field_src[k]
            d0 = field_dst[k]
            for b in range(field_len[k]):
                q = q0 + b
                rec[r, d0 + b] = src[base + q] if q < plen else 0


# --------------------------------------------------------------------------- python side
@dataclass(frozen=True)
class TlogScan:
    """Frames pymavlink's tlog reader would return, located in ``data`` (or ``side``).

    Attributes:
        data: the file's bytes.
        side: bytes of frames that pymavlink assembled from non-adjacent file
            bytes (only in corrupt files).
        t_us: record timestamp of each frame (uint64, µs since the Unix epoch as written).
        offset: start of each frame in ``data`` (or in ``side`` where ``in_side``).
        in_side: whether the frame lives in ``side``.
        length: frame length in bytes.
        msgid: message id.
        indexed: records found by the index pass.
        pymavlink_raises: number of places where pymavlink itself raises
            (the first record of a type cut off by the end of file); this
            reader carries on as if that read had not happened.
        timestamp_scans: how often pymavlink's timestamp scan ran.
        bad_frames: frames that failed to decode (CRC, flags) or junk runs.
    """

    data: np.ndarray
    side: np.ndarray
    t_us: np.ndarray
    offset: np.ndarray
    in_side: np.ndarray
    length: np.ndarray
    msgid: np.ndarray
    indexed: int
    pymavlink_raises: int
    timestamp_scans: int
    bad_frames: int

    def __len__(self) -> int:
        return int(self.t_us.shape[0])

    def frame(self, j: int) -> bytes:
        src = self.side if self.in_side[j] else self.data
        o = int(self.offset[j])
        return bytes(src[o : o + int(self.length[j])])


def truncated_frame_at(scan: TlogScan, max_records: int = 1_000_000) -> int | None:
    """Where a frame cut off by the end of the file starts (byte offset), or None.

    From the end of the last frame the scan found, the records that follow are
    walked (8-byte timestamp, then a MAVLink 1 or 2 frame whose length its
    header gives); a frame reaching past the end of the file means the log was
    cut short (a copy interrupted, a recorder killed).  Junk (no frame start
    where one should be) ends the walk without a verdict.
    """
    data = scan.data
    n = int(data.shape[0])
    p = 0
    direct = np.flatnonzero(~scan.in_side)
    if direct.size:
        j = int(direct[-1])
        p = int(scan.offset[j]) + int(scan.length[j])
    for _ in range(max_records):
        if p >= n:
            return None
        if p + 9 > n:  # a timestamp (and frame start) cut short
            return p + 8 if p + 8 < n else p
        start = p + 8
        magic = int(data[start])
        if magic not in (0xFE, 0xFD):
            return None
        if start + 3 > n:
            return start
        need = int(data[start + 1]) + (8 if magic == 0xFE else 12)
        if magic == 0xFD and int(data[start + 2]) & 0x01:
            need += 13  # signed
        if start + need > n:
            return start
        p = start + need
    return None


def load_bytes(source: str | os.PathLike[str] | BinaryIO | bytes | bytearray | memoryview) -> np.ndarray:
    """A tlog's bytes as a read-only uint8 array (path, binary file object, or bytes)."""
    if isinstance(source, (bytes, bytearray, memoryview)):
        arr = np.frombuffer(bytes(source), np.uint8)
    elif isinstance(source, (str, os.PathLike)):
        arr = np.fromfile(os.fspath(source), np.uint8)
    else:
        arr = np.frombuffer(source.read(), np.uint8)
    arr.flags.writeable = False  # one array type for the compiled kernels, whatever the source
    return arr


def _type_ids(types: Iterable[str]) -> list[int]:
    ids = []
    for name in types:
        cls = _NAME_TO_CLASS.get(str(name).upper())
        if cls is None:
            raise ConfigError(f"unknown MAVLink message type {name!r} (not in the ardupilotmega dialect)")
        ids.append(int(cls.id))
    return ids


def scan_tlog(
    source: str | os.PathLike[str] | BinaryIO | bytes | bytearray | memoryview | np.ndarray,
    types: Sequence[str] | None = None,
    *,
    mode: str = "mmap",
) -> TlogScan:
    """Locate the frames pymavlink would return from a tlog.

    Args:
        source: path, binary file object, bytes, or a uint8 array of the file.
        types: message type names, as for ``recv_match(type=types)``; ``None``
            returns every decodable frame (known messages with a valid CRC and
            unknown message ids), as ``recv_match()`` without a type does.
        mode: ``"mmap"`` emulates ``mavutil.mavlink_connection(path)`` (pymavlink's
            ``mavmmaplog``: index, then read); ``"sequential"`` emulates
            ``mavutil.mavlogfile(path)`` + ``recv_msg()`` to the end.
    """
    if mode not in ("mmap", "sequential"):
        raise ConfigError(f"tlog scan mode must be 'mmap' or 'sequential', got {mode!r}")
    data = source if isinstance(source, np.ndarray) else load_bytes(source)
    data = np.ascontiguousarray(data, dtype=np.uint8)
    if data.flags.writeable:  # one array type for the compiled kernels (no second compilation)
        data = data.view()
        data.flags.writeable = False
    n = int(data.shape[0])
    visit = np.zeros(65536, np.uint8)
    want = np.zeros(65536, np.uint8)
    if types is None:
        want[_CRC_EXTRA >= 0] = 1
        want_unknown = True
        indexed_read = False
    else:
        ids = _type_ids(types)
        want[ids] = 1
        visit[ids] = 1
        visit[_ID_HEARTBEAT] = 1
        visit[_ID_PARAM_VALUE] = 1
        want_unknown = False
        indexed_read = mode == "mmap"
    index_pass = mode == "mmap"
    max_idx = n // 16 + 2  # a record is at least 16 bytes
    cap = max_idx + n // 8 + 16  # one per visited record + sequential tail frames (>= 8 bytes each)
    side_cap = 1 << 16
    while True:
        # np.empty: pages are only touched for what is used
        idx_off = np.empty(max_idx, np.int64)
        idx_id = np.empty(max_idx, np.int32)
        out_t = np.empty(cap, np.uint64)
        out_off = np.empty(cap, np.int64)
        out_side = np.empty(cap, np.uint8)
        out_len = np.empty(cap, np.int32)
        out_id = np.empty(cap, np.int32)
        side = np.empty(side_cap, np.uint8)
        stats = np.zeros(_N_STATS, np.int64)
        m = int(
            _emulate(
                data, _CRC_EXTRA, _CRC_TABLE, _INSTANCE, visit, want, want_unknown, index_pass, indexed_read,
                idx_off, idx_id, out_t, out_off, out_side, out_len, out_id, side, stats, *_emulate_scratch(),
            )
        )  # fmt: skip
        if stats[_S_SIDE_NEEDED] <= side_cap:
            break
        side_cap = int(stats[_S_SIDE_NEEDED])  # rare: corrupt file with many split frames; run again
    used_side = int(stats[_S_SIDE_NEEDED])
    return TlogScan(
        data=data,
        side=side[:used_side].copy(),
        t_us=out_t[:m].copy(),
        offset=out_off[:m].copy(),
        in_side=out_side[:m].astype(bool),
        length=out_len[:m].copy(),
        msgid=out_id[:m].copy(),
        indexed=int(stats[_S_INDEXED]),
        pymavlink_raises=int(stats[_S_RAISES]),
        timestamp_scans=int(stats[_S_SCANS]),
        bad_frames=int(stats[_S_BAD]),
    )


# --------------------------------------------------------------------------- dtypes
_STRUCT_TO_NUMPY = {
    "Q": "<u8", "q": "<i8", "I": "<u4", "i": "<i4", "H": "<u2", "h": "<i2",
    "B": "u1", "b": "i1", "f": "<f4", "d": "<f8", "c": "S1",
}  # fmt: skip
_TOKEN = re.compile(r"(\d*)([a-zA-Z])")


def _wire_dtype(cls: Any) -> np.dtype:
    """The packed little-endian payload layout of a message class, from its struct format."""
    fmt = cls.unpacker.format
    if isinstance(fmt, bytes):
        fmt = fmt.decode()
    if not fmt.startswith("<"):
        raise ValueError(f"{cls.msgname}: unexpected struct format {fmt!r}")
    tokens = _TOKEN.findall(fmt[1:])
    names = list(cls.ordered_fieldnames)
    if len(tokens) != len(names):
        raise ValueError(f"{cls.msgname}: {len(tokens)} struct fields for {len(names)} names")
    formats: list[Any] = []
    offsets = []
    off = 0
    for (count_s, ch), _name in zip(tokens, names, strict=True):
        count = int(count_s) if count_s else 1
        if ch == "s":
            formats.append(f"S{count}")
            size = count
        else:
            base = _STRUCT_TO_NUMPY.get(ch)
            if base is None:
                raise ValueError(f"{cls.msgname}: struct code {ch!r} not supported")
            formats.append(base if count == 1 else (base, (count,)))
            size = np.dtype(base).itemsize * count
        offsets.append(off)
        off += size
    if off != cls.unpacker.size:
        raise ValueError(f"{cls.msgname}: layout size {off} != struct size {cls.unpacker.size}")
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": off})



def _field_map(cls: Any, wire: np.dtype, dtype: np.dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(payload offset, record offset, bytes) of every message field, for :func:`_gather_fields`."""
    src, dst, size = [], [], []
    for f in cls.fieldnames:
        wdt, woff = wire.fields[f][:2]
        src.append(woff)
        dst.append(dtype.fields[f][1])
        size.append(wdt.itemsize)
    return np.array(src, np.int64), np.array(dst, np.int64), np.array(size, np.int64)


def _decode_direct(scan: TlogScan, sel: np.ndarray, cls: Any, wire: np.dtype, dtype: np.dtype) -> np.ndarray:
    """The records of the frames ``sel`` in one compiled pass (little-endian hosts)."""
    out = np.empty(sel.shape[0], dtype)
    src, dst, size = _field_map(cls, wire, dtype)
    rec = out.view(np.uint8).reshape(sel.shape[0], dtype.itemsize)
    _gather_fields(
        scan.data, scan.side, scan.offset, scan.in_side.view(np.uint8), sel, scan.t_us.view(np.int64),
        src, dst, size, rec, out["t_us"], out["sysid"], out["compid"],
    )  # fmt: skip
    return out

def message_dtype(name: str) -> np.dtype:
    """Structured dtype of ``read_tlog_arrays`` results for message type ``name``.

    Fields: ``t_us`` (int64, the tlog record's timestamp), ``sysid``, ``compid``
    (uint8), then the message's fields in declaration order with their wire
    types (arrays as sub-arrays, char arrays as ``S<n>`` bytes).
    """
    cls = _NAME_TO_CLASS.get(name.upper())
    if cls is None:
        raise ConfigError(f"unknown MAVLink message type {name!r} (not in the ardupilotmega dialect)")
    wire = _wire_dtype(cls)
    fields = [("t_us", "<i8"), ("sysid", "u1"), ("compid", "u1")]
    for f in cls.fieldnames:
        dt, _ = wire.fields[f][:2]
        fields.append((f, dt.base.newbyteorder("=") if dt.shape == () else (dt.base.newbyteorder("="), dt.shape)))
    return np.dtype(fields)


def _fields_from_messages(msgs: list[Any], t_us: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """The pymavlink fallback: a structured array from decoded message objects."""
    out = np.zeros(len(msgs), dtype)
    out["t_us"] = t_us.view(np.int64)
    names = [n for n in dtype.names if n not in ("t_us", "sysid", "compid")]
    for r, m in enumerate(msgs):
        out["sysid"][r] = m.get_srcSystem()
        out["compid"][r] = m.get_srcComponent()
        for f in names:
            v = getattr(m, f)
            out[f][r] = v.encode() if isinstance(v, str) else v
    return out


def read_tlog_arrays(
    source: str | os.PathLike[str] | BinaryIO | bytes | bytearray | memoryview | np.ndarray,
    types: Sequence[str] = DEFAULT_TYPES,
    *,
    engine: str = "fast",
) -> dict[str, np.ndarray]:
    """Decode the given message types of a tlog into numpy structured arrays.

    The messages, their order, field values and timestamps are exactly those of
    pymavlink's ``mavutil.mavlink_connection(path).recv_match(type=types)``
    (see the module docstring).

    Args:
        source: path, binary file object, bytes or uint8 array.
        types: message type names (``DEFAULT_TYPES``: IMU, attitude, simulator
            truth, GNSS, HEARTBEAT, SYSTEM_TIME).
        engine: ``"fast"`` (vectorised decoding) or ``"pymavlink"`` (each frame
            decoded by pymavlink through :class:`~mavahrs.protocol.codec.MavCodec`;
            same result, slower — used for types whose layout the fast path
            cannot express).

    Returns:
        ``{type name: structured array}`` for every requested type (empty
        arrays for types absent from the file); dtype from :func:`message_dtype`.
    """
    if engine not in ("fast", "pymavlink"):
        raise ConfigError(f"engine must be 'fast' or 'pymavlink', got {engine!r}")
    names = [str(t).upper() for t in types]
    _type_ids(names)
    return decode_scan(scan_tlog(source, names), names, engine=engine)


def scan_positions(scan: TlogScan, types: Sequence[str]) -> dict[str, np.ndarray]:
    """The positions (int64, frame order) of each type's frames in ``scan``; one count, then only the types present."""
    names = [str(t).upper() for t in types]
    ids = _type_ids(names)
    counts = None
    if scan.msgid.size and int(scan.msgid.max()) < 65536:
        counts = np.bincount(scan.msgid, minlength=65536)
    out: dict[str, np.ndarray] = {}
    for name, mid in zip(names, ids, strict=True):
        if counts is not None and counts[mid] == 0:
            out[name] = np.empty(0, np.int64)
        else:
            out[name] = np.flatnonzero(scan.msgid == mid).astype(np.int64)
    return out


def decode_scan(
    scan: TlogScan, types: Sequence[str], *, engine: str = "fast", positions: dict[str, np.ndarray] | None = None
) -> dict[str, np.ndarray]:
    """The fields of the given types from a :func:`scan_tlog` result (``read_tlog_arrays``'s second half).

    ``read_tlog_arrays(source, types)`` is ``decode_scan(scan_tlog(source, types), types)``;
    a caller that needs the scan too (frame order, raw frames) scans once and
    decodes from it.  The scan must be of the same ``types`` (``mode="mmap"``):
    which frames pymavlink returns depends on the types requested.
    ``positions``: :func:`scan_positions` of the same scan and types, if the
    caller has them.
    """
    if engine not in ("fast", "pymavlink"):
        raise ConfigError(f"engine must be 'fast' or 'pymavlink', got {engine!r}")
    names = [str(t).upper() for t in types]
    _type_ids(names)
    if positions is None:
        positions = scan_positions(scan, names)
    result: dict[str, np.ndarray] = {}
    for name in names:
        cls = _NAME_TO_CLASS[name]
        dtype = message_dtype(name)
        sel = positions[name]
        try:
            # the compiled copy writes the wire's little-endian bytes as they are: elsewhere, pymavlink
            wire = _wire_dtype(cls) if engine == "fast" and sys.byteorder == "little" else None
        except ValueError:
            wire = None
        if wire is None:
            from mavahrs.protocol.codec import MavCodec

            codec = MavCodec()
            msgs = [codec.decode_frame(scan.frame(int(j))) for j in sel]
            result[name] = _fields_from_messages(msgs, scan.t_us[sel], dtype)
            continue
        result[name] = _decode_direct(scan, sel, cls, wire, dtype)
    return result
