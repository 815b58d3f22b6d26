"""The daemon's tlog sink: regular flushing, readable after SIGKILL, a full disk stops only the log."""

from __future__ import annotations

import errno
import io
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from mavahrs.errors import ConfigError
from mavahrs.protocol.codec import MavCodec
from mavahrs.protocol.tlog import TlogWriter, iter_tlog
from mavahrs.service.sinks import TlogSink

REPO = Path(__file__).resolve().parents[2]


def _frames(n: int) -> list[bytes]:
    c = MavCodec(1, 191)
    return [
        c.encode(c.mav.attitude_quaternion_encode(i, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, [0, 0, 0, 0]))
        for i in range(n)
    ]


def test_records_reach_the_file_within_the_flush_interval(tmp_path: Path) -> None:
    path = tmp_path / "a.tlog"
    sink = TlogSink(path, flush_interval_s=1.0)
    frames = _frames(30)
    for i, f in enumerate(frames[:20]):
        sink.write(1_700_000_000_000_000 + i, f, now_s=100.0 + i * 0.01)
    sink.tick(101.0)  # a second after the first record, even with no new traffic
    on_disk = list(iter_tlog(path.read_bytes()))
    assert [fr for _, fr in on_disk] == frames[:20]
    assert on_disk[0][0] == 1_700_000_000_000_000
    for f in frames[20:]:
        sink.write(1_700_000_001_000_000, f, now_s=101.2)
    sink.close()  # flush + fsync
    assert [fr for _, fr in iter_tlog(path)] == frames
    assert sink.frames == 30 and sink.frames_lost == 0
    assert sink.state == "closed"  # closed as it should be: no "stopped: closed"
    sink.close()  # idempotent


_CHILD = textwrap.dedent(
    """
    import sys, time
    sys.path.insert(0, {repo!r})
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.service.sinks import TlogSink
    c = MavCodec(1, 191)
    sink = TlogSink({path!r}, flush_interval_s=0.05)
    n = 0
    last_flushed = 0
    while True:
        frame = c.encode(c.mav.attitude_quaternion_encode(n, 1.0, 0, 0, 0, 0, 0, 0, [0, 0, 0, 0]))
        before = sink._writer.bytes_written
        sink.write(1_700_000_000_000_000 + n, frame, time.monotonic())
        n += 1
        if sink._writer.bytes_written != before:
            print(sink._writer.bytes_written, flush=True)  # bytes now in the file
        time.sleep(0.0005)
    """
)


@pytest.mark.skipif(os.name != "posix", reason="SIGKILL")
def test_a_killed_process_leaves_a_readable_log_up_to_the_last_flush(tmp_path: Path) -> None:
    path = tmp_path / "killed.tlog"
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD.format(repo=str(REPO), path=str(path))],
        stdout=subprocess.PIPE,
        text=True,
    )
    flushed = 0
    try:
        deadline = time.monotonic() + 30
        flushes = 0
        while flushes < 5 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            flushed = int(line)
            flushes += 1
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        proc.stdout.close()
    assert flushes == 5, "the child never flushed"
    data = path.read_bytes()
    assert len(data) >= flushed  # everything flushed before the kill is there
    records = list(iter_tlog(data))
    assert len(records) * len(_frames(1)[0]) + 8 * len(records) >= flushed
    dec = MavCodec()
    times = [dec.receive_datagram(fr)[0].time_boot_ms for _, fr in records]
    assert times == list(range(len(times)))  # complete, in order, every one a valid frame


class FullDisk(io.RawIOBase):
    """A file that accepts ``capacity`` bytes, then fails every write with ENOSPC."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.data = bytearray()

    def writable(self) -> bool:
        return True

    def write(self, b: bytes) -> int:  # type: ignore[override]
        if len(self.data) + len(b) > self.capacity:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.data += b
        return len(b)


def test_a_full_disk_stops_the_log_once_and_nothing_else(caplog: pytest.LogCaptureFixture) -> None:
    disk = FullDisk(capacity=500)
    sink = TlogSink("full.tlog", flush_interval_s=0.1, writer=TlogWriter(disk, flush_interval_s=0.1))
    caplog.set_level(logging.ERROR, logger="mavahrs.service")
    frames = _frames(200)
    for i, f in enumerate(frames):
        sink.write(1_700_000_000_000_000 + i, f, now_s=i * 0.01)  # never raises
        sink.tick(i * 0.01)
    assert sink.stopped and sink.state == "stopped: No space left on device"
    assert sink.frames_lost > 0 and sink.frames + sink.frames_lost == 200
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "keeps running" in errors[0].getMessage()
    # what did fit on the "disk" is a valid tlog prefix
    assert [fr for _, fr in iter_tlog(bytes(disk.data))] == frames[: len(list(iter_tlog(bytes(disk.data))))]
    sink.close()  # no exception either


def test_an_unopenable_log_path_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot open log file"):
        TlogSink(tmp_path / "no" / "such" / "dir.tlog")


def test_an_empty_file_it_created_is_removed_at_close_and_said(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Ctrl-C before the autopilot is found: no frame came; the file the sink created goes, with one INFO line.
    A file that existed before (appended to, even if empty) and a file with frames are kept."""
    empty = tmp_path / "empty.tlog"
    with caplog.at_level(logging.INFO, logger="mavahrs.service"):
        sink = TlogSink(empty)
        assert empty.exists()
        sink.close()
    assert not empty.exists() and sink.removed_empty and sink.state == "nothing recorded: empty file removed"
    assert [r.getMessage() for r in caplog.records] == [
        f"nothing was recorded (stopped before any message arrived): removed the empty log file {empty}"
    ]
    earlier = tmp_path / "earlier.tlog"
    earlier.write_bytes(b"")
    sink = TlogSink(earlier)
    sink.close()
    assert earlier.exists() and sink.state == "closed"
    used = tmp_path / "used.tlog"
    sink = TlogSink(used)
    sink.write(1_700_000_000_000_000, _frames(1)[0], now_s=1.0)
    sink.close()
    assert used.stat().st_size > 0 and sink.state == "closed"
