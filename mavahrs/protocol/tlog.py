r"""Telemetry logs (``.tlog``): records of an 8-byte big-endian µs timestamp + one MAVLink frame.

This is the format MAVProxy, QGroundControl and Mission Planner write; the
timestamp is Unix time in microseconds (MAVProxy clears its two low bits to
carry a link number; nothing here depends on that).

Reading (:func:`iter_tlog`, :func:`read_tlog_messages`) returns exactly what
pymavlink's readers return — the same frames, in the same order, with the same
timestamps, also for truncated files and files with junk or corrupt bytes —
because it runs the byte-exact emulation of pymavlink's reader in
:mod:`mavahrs.protocol.fast_tlog` (compiled, so it is also fast).  The whole
file is read into memory (a one-hour 400 Hz log is about 100 MB).

Writing (:class:`TlogWriter`) is crash-tolerant: records are handed to the
operating system at least every ``flush_interval_s`` (time is passed in, never
read), so a killed process — even by SIGKILL — leaves a file readable up to
the last flush; :meth:`TlogWriter.close` also ``fsync``\ s.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Iterator, Sequence
from typing import Any, BinaryIO

__all__ = ["tlog_record", "iter_tlog", "read_tlog_messages", "TlogWriter"]

_TS = struct.Struct(">Q")


def tlog_record(t_us: int, frame: bytes | bytearray | memoryview) -> bytes:
    """One tlog record: ``t_us`` as 8 bytes big-endian, then ``frame``."""
    if not 0 <= t_us < 2**64:
        raise ValueError(f"tlog timestamp must be 0..2**64-1 µs, got {t_us!r}")
    return _TS.pack(int(t_us)) + bytes(frame)


def iter_tlog(
    file_or_path: str | os.PathLike[str] | BinaryIO | bytes | bytearray | memoryview,
) -> Iterator[tuple[int, bytes]]:
    """``(t_us, frame_bytes)`` for every decodable frame of a tlog, in file order.

    Exactly the frames (and timestamps) pymavlink's sequential reader
    (``mavutil.mavlogfile(path)`` + ``recv_msg()`` until it returns ``None``)
    returns that are not ``BAD_DATA``: known messages with a valid CRC and
    frames of message ids this dialect does not know.  Truncation and junk are
    tolerated the way pymavlink tolerates them (resynchronising on the next
    start marker; after a bad frame, scanning for a plausible timestamp).

    Args:
        file_or_path: a path, a binary file object (read to its end) or bytes.
    """
    from mavahrs.protocol.fast_tlog import scan_tlog

    scan = scan_tlog(file_or_path, None, mode="sequential")
    for j in range(len(scan)):
        yield int(scan.t_us[j]), scan.frame(j)


def read_tlog_messages(
    path: str | os.PathLike[str] | BinaryIO | bytes | bytearray | memoryview,
    types: Sequence[str] | str | None = None,
) -> Iterator[tuple[int, Any]]:
    """``(t_us, pymavlink message)`` for the messages of ``types`` in a tlog.

    The same messages, order and timestamps as pymavlink's
    ``mavutil.mavlink_connection(path)`` followed by ``recv_match(type=types)``
    until it returns ``None`` (``types=None``: ``recv_match()``, every message
    except ``BAD_DATA``).  Frames are decoded by
    :class:`~mavahrs.protocol.codec.MavCodec` (pymavlink's ardupilotmega
    MAVLink 2 dialect).  For bulk numeric work use
    :func:`mavahrs.protocol.fast_tlog.read_tlog_arrays`.
    """
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.protocol.fast_tlog import scan_tlog

    if isinstance(types, str):
        types = [types]
    scan = scan_tlog(path, None if types is None else list(types), mode="mmap")
    codec = MavCodec()
    for j in range(len(scan)):
        msg = codec.decode_frame(scan.frame(j))
        if msg is not None:  # always: the scan only returns frames that decode
            yield int(scan.t_us[j]), msg


class TlogWriter:
    """Appends tlog records; flushes at least every ``flush_interval_s``; ``close()`` fsyncs.

    Args:
        path_or_file: a path (opened for appending, created if missing, as
            MAVProxy does) or a binary file object the caller owns (flushed and
            fsynced on close, but not closed).
        flush_interval_s: the longest time (by the ``now_s`` values passed to
            :meth:`write`) records stay in this writer's buffer.
        max_buffer_bytes: flush earlier when this much is buffered (bounds
            memory at high message rates).
        fsync_on_flush: also ``fsync`` at every flush (survives power loss, costs
            SD-card wear); by default only :meth:`close` fsyncs — a flush
            already makes the data survive the process being killed.

    Write errors (a full disk) propagate as ``OSError``; the records buffered
    at that moment are dropped, so memory stays bounded if the caller carries on.
    """

    def __init__(
        self,
        path_or_file: str | os.PathLike[str] | BinaryIO,
        flush_interval_s: float = 1.0,
        *,
        max_buffer_bytes: int = 1 << 20,
        fsync_on_flush: bool = False,
    ) -> None:
        if not flush_interval_s >= 0:
            raise ValueError(f"flush_interval_s must be >= 0, got {flush_interval_s!r}")
        if isinstance(path_or_file, (str, os.PathLike)):
            self._file: Any = open(os.fspath(path_or_file), "ab")  # noqa: SIM115 - closed in close()
            self._owned = True
            self.path: str | None = os.fspath(path_or_file)
        else:
            self._file = path_or_file
            self._owned = False
            self.path = getattr(path_or_file, "name", None)
        self.flush_interval_s = float(flush_interval_s)
        self.max_buffer_bytes = int(max_buffer_bytes)
        self.fsync_on_flush = bool(fsync_on_flush)
        self._buf = bytearray()
        self._last_flush_s: float | None = None
        self.records = 0
        self.bytes_written = 0
        self.closed = False

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def write(self, t_us: int, frame: bytes | bytearray | memoryview, now_s: float) -> None:
        """Append one record; flush if ``now_s`` is ``flush_interval_s`` past the last flush."""
        if self.closed:
            raise ValueError("write to a closed TlogWriter")
        if not 0 <= t_us < 2**64:
            raise ValueError(f"tlog timestamp must be 0..2**64-1 µs, got {t_us!r}")
        self._buf += _TS.pack(int(t_us))
        self._buf += frame
        self.records += 1
        if self._last_flush_s is None:
            self._last_flush_s = now_s
        if now_s - self._last_flush_s >= self.flush_interval_s or len(self._buf) >= self.max_buffer_bytes:
            self.flush(now_s)

    def tick(self, now_s: float) -> None:
        """Flush if the interval has passed (call from a timer when no records arrive)."""
        if self._buf and self._last_flush_s is not None and now_s - self._last_flush_s >= self.flush_interval_s:
            self.flush(now_s)

    def flush(self, now_s: float | None = None) -> None:
        """Hand the buffered records to the operating system (and fsync if configured)."""
        if self.closed:
            return
        if now_s is not None:
            self._last_flush_s = now_s
        if self._buf:
            data = bytes(self._buf)
            self._buf.clear()  # dropped even if the write fails: memory stays bounded
            self._file.write(data)
            self.bytes_written += len(data)
        self._file.flush()
        if self.fsync_on_flush:
            self._fsync()

    def _fsync(self) -> None:
        try:
            fd = self._file.fileno()
        except (AttributeError, io.UnsupportedOperation):  # not a real file (BytesIO)
            return
        os.fsync(fd)

    def close(self) -> None:
        """Flush, fsync and (if this writer opened it) close the file."""
        if self.closed:
            return
        try:
            self.flush()
            self._fsync()
        finally:
            self.closed = True
            if self._owned:
                self._file.close()
