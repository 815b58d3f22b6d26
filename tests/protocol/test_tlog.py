"""tlog records, the crash-tolerant writer, and readers equal to pymavlink's."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mavahrs.protocol.codec import MavCodec
from mavahrs.protocol.tlog import TlogWriter, iter_tlog, read_tlog_messages, tlog_record

REPO = Path(__file__).resolve().parents[2]


def _frames(n: int) -> list[bytes]:
    c = MavCodec(1, 1)
    return [c.encode(c.mav.raw_imu_encode(2500 * i, i % 7, 0, -1000, 0, 0, 0, 0, 0, 0)) for i in range(n)]


def test_record_format():
    f = _frames(1)[0]
    rec = tlog_record(0x0102030405060708, f)
    assert rec[:8] == bytes([1, 2, 3, 4, 5, 6, 7, 8]) and rec[8:] == f
    with pytest.raises(ValueError):
        tlog_record(-1, f)


def test_writer_flushes_by_passed_time_not_by_clock(tmp_path):
    p = tmp_path / "a.tlog"
    frames = _frames(4)
    w = TlogWriter(p, flush_interval_s=1.0)
    w.write(1_000, frames[0], now_s=10.0)
    w.write(2_000, frames[1], now_s=10.5)
    assert p.stat().st_size == 0  # still buffered
    w.write(3_000, frames[2], now_s=11.0)  # one interval after the first write
    assert p.stat().st_size == 3 * (8 + len(frames[0]))
    w.write(4_000, frames[3], now_s=11.2)
    w.tick(11.9)
    assert p.stat().st_size == 3 * (8 + len(frames[0]))
    w.tick(12.0)
    assert [t for t, _ in iter_tlog(p)] == [1_000, 2_000, 3_000, 4_000]
    w.close()
    assert w.closed and w.records == 4
    with pytest.raises(ValueError):
        w.write(5_000, frames[0], now_s=13.0)


def test_writer_appends_bounds_memory_and_leaves_callers_file_open(tmp_path):
    p = tmp_path / "b.tlog"
    frames = _frames(50)
    with TlogWriter(p) as w:
        w.write(1, frames[0], 0.0)
    with TlogWriter(p, flush_interval_s=100.0, max_buffer_bytes=500) as w:  # appends, as MAVProxy does
        for i, f in enumerate(frames[1:], 2):
            w.write(i, f, 0.0)
            assert len(w._buf) < 500 + 8 + len(f)
    assert [t for t, _ in iter_tlog(p)] == list(range(1, 51))
    buf = io.BytesIO()
    w = TlogWriter(buf, flush_interval_s=0.0, fsync_on_flush=True)
    w.write(7, frames[0], 0.0)
    w.close()
    assert not buf.closed and buf.getvalue() == tlog_record(7, frames[0])


def test_writer_error_drops_buffer_and_propagates(tmp_path):
    class Full(io.BytesIO):
        def write(self, b):  # type: ignore[override]
            raise OSError(28, "No space left on device")

    w = TlogWriter(Full(), flush_interval_s=10.0)
    w.write(1, _frames(1)[0], 0.0)
    with pytest.raises(OSError, match="No space"):
        w.flush()
    assert len(w._buf) == 0


_CHILD = textwrap.dedent(
    """
    import sys, time
    sys.path.insert(0, {repo!r})
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.protocol.tlog import TlogWriter
    c = MavCodec(1, 1)
    w = TlogWriter({path!r}, flush_interval_s=1.0)
    for i in range(300):   # 300 records over 1.5 s of (passed-in) time: flushed at 1.0 s
        now_s = i * 0.005
        w.write(1_000_000 + i, c.encode(c.mav.raw_imu_encode(i, 0, 0, -1000, 0, 0, 0, 0, 0, 0)), now_s)
    print("ready", w.bytes_written, flush=True)
    time.sleep(60)
    """
)


def test_killed_process_leaves_readable_log_up_to_last_flush(tmp_path):
    p = tmp_path / "killed.tlog"
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD.format(repo=str(REPO), path=str(p))],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline().split()  # type: ignore[union-attr]
        assert line and line[0] == "ready", line
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=20)
    assert proc.returncode == -signal.SIGKILL
    flushed = int(line[1])
    assert p.stat().st_size == flushed > 0
    recs = list(iter_tlog(p))
    assert len(recs) == 201  # records 0..200: the flush came with the write at now_s = 1.0
    assert [t for t, _ in recs] == [1_000_000 + i for i in range(201)]
    msgs = [m for _, m in read_tlog_messages(p, ["RAW_IMU"])]
    assert [m.time_usec for m in msgs] == list(range(201))


def test_truncated_and_junk_tolerated(tmp_path, pymavlink_ref):
    frames = _frames(10)
    t0 = 1_700_000_000_000_000
    data = b"".join(tlog_record(t0 + i, f) for i, f in enumerate(frames))
    assert [t - t0 for t, _ in iter_tlog(data[:-3])] == list(range(9))  # cut inside the last frame
    junk = b"\x00\x11\x22" * 5
    cut = sum(8 + len(f) for f in frames[:3])  # between records 3 and 4
    mixed = data[:cut] + junk + data[cut:]
    got = [f for _, f in iter_tlog(io.BytesIO(mixed))]
    # pymavlink loses the record the junk runs into, then finds the next plausible timestamp
    assert got == frames[:3] + frames[4:]
    p = tmp_path / "j.tlog"
    p.write_bytes(mixed)
    assert got == [bytes(m.get_msgbuf()) for m in pymavlink_ref.seq(p)]


def test_iter_tlog_equals_pymavlink_sequential_reader(tmp_path, make_tlog, pymavlink_ref):
    data = make_tlog(seconds=1.0, seed=5)
    p = tmp_path / "g.tlog"
    p.write_bytes(data)
    ref = pymavlink_ref.seq(p)
    ours = list(iter_tlog(p))
    assert len(ours) == len(ref) > 400
    assert [(t * 1e-6, f) for t, f in ours] == [(m._timestamp, bytes(m.get_msgbuf())) for m in ref]
    # pymavlink's sequential reader mis-frames after a MAVLink 1 frame shorter than 4 payload bytes
    # that follows a MAVLink 2 frame (its parser reads 12 bytes ahead): PARAM_REQUEST_LIST here.
    # Reproduced, not repaired (docs/protocol.md); the record-walk count shows what was lost.
    records, o = 0, 0
    while o < len(data):
        o += 8 + data[o + 9] + (8 if data[o + 8] == 0xFE else 12 + (13 if data[o + 10] & 1 else 0))
        records += 1
    assert records - len(ours) == 1  # the frame after the PARAM_REQUEST_LIST


def test_read_tlog_messages_equals_recv_match(tmp_path, make_tlog, pymavlink_ref):
    data = make_tlog(seconds=0.5, seed=6)
    p = tmp_path / "m.tlog"
    p.write_bytes(data)
    for types in (["RAW_IMU", "ATTITUDE", "HEARTBEAT"], "SCALED_IMU2", None):
        ref = [m for m in pymavlink_ref.mmap(p, types) if m.get_type() != "BAD_DATA"]
        ours = list(read_tlog_messages(p, types))
        assert len(ours) == len(ref) > 0, types
        for (t, m), r in zip(ours, ref, strict=True):
            assert t * 1e-6 == r._timestamp and m.get_type() == r.get_type() and m.get_msgbuf() == r.get_msgbuf()
        if types == "SCALED_IMU2":
            assert [m.to_dict() for _, m in ours] == [r.to_dict() for r in ref]  # integer fields only


@pytest.mark.slow
def test_readers_equal_pymavlink_on_real_log(mavlink_logs_dir, pymavlink_ref):
    """flight.tlog: 1314 CRC-failed records and a truncated last record."""
    p = mavlink_logs_dir / "dronekit-python" / "flight.tlog"
    ref = pymavlink_ref.seq(p)
    ours = list(iter_tlog(p))
    assert len(ours) == len(ref) == 76791 - 1314
    assert all(t * 1e-6 == m._timestamp and f == bytes(m.get_msgbuf()) for (t, f), m in zip(ours, ref, strict=True))
    types = ["RAW_IMU", "GPS_RAW_INT"]
    ref = pymavlink_ref.mmap(p, types)
    ours2 = list(read_tlog_messages(p, types))
    assert [m.to_dict() for _, m in ours2] == [m.to_dict() for m in ref] and len(ref) == 2856 + 2858


def test_writer_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError):
        TlogWriter(tmp_path / "x.tlog", flush_interval_s=-1)
    w = TlogWriter(tmp_path / "y.tlog")
    with pytest.raises(ValueError):
        w.write(2**64, b"\xfe", 0.0)
    w.close()
    w.close()  # idempotent
    assert os.path.exists(tmp_path / "y.tlog")
