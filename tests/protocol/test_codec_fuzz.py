"""Property tests: hostile bytes never raise; valid frames survive garbage; chunking does not matter.

Hypothesis ``max_examples`` is kept moderate so the file runs in well under 20 s.
"""

from __future__ import annotations

import os
import tempfile

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.protocol.fast_tlog import DEFAULT_TYPES, read_tlog_arrays, scan_tlog
from mavahrs.protocol.tlog import iter_tlog, tlog_record

FUZZ = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
TYPES = list(DEFAULT_TYPES)

i16 = st.integers(-32768, 32767)
u32 = st.integers(0, 2**32 - 1)
f32 = st.floats(width=32, allow_nan=False)


@st.composite
def messages(draw):
    """(kind, args, mavlink1) for a few message types with arbitrary field values."""
    kind = draw(st.sampled_from(["raw_imu", "scaled_imu2", "attitude", "heartbeat", "highres_imu"]))
    if kind == "raw_imu":
        args = [draw(st.integers(0, 2**64 - 1))] + draw(st.lists(i16, min_size=9, max_size=9))
    elif kind == "scaled_imu2":
        args = [draw(u32)] + draw(st.lists(i16, min_size=9, max_size=9))
    elif kind == "attitude":
        args = [draw(u32)] + draw(st.lists(f32, min_size=6, max_size=6))
    elif kind == "highres_imu":
        args = [draw(st.integers(0, 2**64 - 1))] + draw(st.lists(f32, min_size=13, max_size=13)) + [draw(st.integers(0, 65535))]
    else:
        args = [draw(st.integers(0, 255)) for _ in range(3)] + [draw(u32), draw(st.integers(0, 255))]
    return kind, args, draw(st.booleans())


def _encode(codec: MavCodec, spec) -> bytes:
    kind, args, v1 = spec
    return codec.encode(getattr(codec.mav, kind + "_encode")(*args), force_mavlink1=v1)


def _no_markers(b: bytes) -> bytes:
    return bytes(x if x not in (0xFD, 0xFE) else 0x55 for x in b)


def _known(msgs):
    return [m for m in msgs if not isinstance(m, mavlink.MAVLink_unknown)]


def _chunks(data: bytes, cuts: list[int]) -> list[bytes]:
    pos = sorted({c % (len(data) + 1) for c in cuts})
    out, prev = [], 0
    for p in pos + [len(data)]:
        out.append(data[prev:p])
        prev = p
    return out


@FUZZ
@given(st.binary(max_size=2000), st.lists(st.integers(0, 2000), max_size=20))
def test_arbitrary_bytes_never_raise(data, cuts):
    c = MavCodec()
    c.receive_datagram(data)
    for chunk in _chunks(data, cuts):
        c.receive_stream(chunk)
    assert len(c._stream_buf) <= len(data)
    scan_tlog(data, TYPES)
    scan_tlog(data, None, mode="sequential")
    read_tlog_arrays(data, TYPES)
    list(iter_tlog(data))


@FUZZ
@given(st.lists(messages(), min_size=1, max_size=8), st.lists(st.binary(max_size=80), min_size=9, max_size=9), st.booleans())
def test_frames_in_garbage_without_markers_all_recovered(specs, garbage, as_stream):
    src = MavCodec(3, 1)
    frames = [_encode(src, s) for s in specs]
    junk = [_no_markers(g) for g in garbage]
    data = b"".join(j + f for j, f in zip(junk, frames, strict=False)) + junk[-1]  # 9 pieces of junk for up to 8 frames
    c = MavCodec()
    msgs = c.receive_stream(data) if as_stream else c.receive_datagram(data)
    assert [m.get_msgbuf() for m in msgs] == frames
    assert c.counters.crc_errors == 0 and c.counters.packets == len(frames)


@FUZZ
@given(st.lists(messages(), min_size=1, max_size=8), st.lists(st.binary(max_size=80), min_size=9, max_size=9), st.booleans())
def test_frames_in_garbage_with_markers_all_recovered(specs, garbage, as_stream):
    """Garbage with start markers (fake headers, fake lengths) still loses no real frame.

    Frames of unknown message ids made up by the garbage may come out too (they
    cannot be CRC-checked); every known message is a real one.
    """
    src = MavCodec(3, 1)
    frames = [_encode(src, s) for s in specs]
    junk = [g if i % 2 else bytes([0xFD, 0x40, 0x01]) + g for i, g in enumerate(garbage)]
    data = b"".join(j + f for j, f in zip(junk, frames, strict=False)) + junk[-1]  # 9 pieces of junk for up to 8 frames
    c = MavCodec()
    msgs = c.receive_stream(data) if as_stream else c.receive_datagram(data)
    if as_stream:  # a trailing fake frame start may still be waiting for bytes
        msgs += c.receive_stream(b"\x00" * 600)
    assert [m.get_msgbuf() for m in _known(msgs)] == frames


@FUZZ
@given(
    st.lists(messages(), min_size=1, max_size=6),
    st.lists(st.binary(max_size=60), min_size=7, max_size=7),
    st.lists(st.integers(0, 3000), max_size=30),
)
def test_stream_chunking_does_not_change_the_messages(specs, garbage, cuts):
    src = MavCodec(3, 1)
    frames = [_encode(src, s) for s in specs]
    data = b"".join(g + f for g, f in zip(garbage, frames, strict=False)) + garbage[-1]  # more garbage than frames
    whole = MavCodec().receive_stream(data)
    c = MavCodec()
    parts = [m for chunk in _chunks(data, cuts) for m in c.receive_stream(chunk)]
    assert [m.get_msgbuf() for m in parts] == [m.get_msgbuf() for m in whole]
    assert [m.get_msgbuf() for m in _known(whole)] == frames


@FUZZ
@given(st.lists(messages(), min_size=1, max_size=10), st.lists(st.integers(1_600_000_000_000_000, 1_800_000_000_000_000), min_size=10, max_size=10))
def test_fast_reader_returns_exactly_the_records_written(specs, stamps):
    src = MavCodec(9, 1)
    frames = [_encode(src, s) for s in specs]
    # 10 stamps for up to 10 frames: the first len(frames) are used
    data = b"".join(tlog_record(t, f) for t, f in zip(stamps, frames, strict=False))
    arrays = read_tlog_arrays(data, ["RAW_IMU", "SCALED_IMU2", "ATTITUDE", "HEARTBEAT", "HIGHRES_IMU"])
    for kind in ("raw_imu", "scaled_imu2", "attitude", "heartbeat", "highres_imu"):
        want = [(t, s[1]) for t, s in zip(stamps, specs, strict=False) if s[0] == kind]
        got = arrays[kind.upper()]
        assert got["t_us"].tolist() == [t for t, _ in want]
        if kind in ("raw_imu", "scaled_imu2"):
            first = "time_usec" if kind == "raw_imu" else "time_boot_ms"
            assert got[first].tolist() == [a[0] for _, a in want]
            assert got["zgyro"].tolist() == [a[6] for _, a in want]
    assert [t for t, _ in iter_tlog(data)] == list(stamps[: len(frames)])


@st.composite
def corruptions(draw):
    """A list of edits of a tlog: bit flips, junk (with/without markers), deletions, a truncation."""
    ops = draw(
        st.lists(
            st.one_of(
                st.tuples(st.just("flip"), st.integers(0, 10**6), st.integers(0, 7)),
                st.tuples(st.just("junk"), st.integers(0, 10**6), st.binary(min_size=1, max_size=40)),
                st.tuples(st.just("delete"), st.integers(0, 10**6), st.integers(1, 40)),
            ),
            min_size=1,
            max_size=6,
        )
    )
    trunc = draw(st.one_of(st.none(), st.integers(0, 10**6)))
    return ops, trunc


def _apply(data: bytes, ops, trunc) -> bytes:
    b = bytearray(data)
    for op in ops:
        p = op[1] % (len(b) + 1)
        if op[0] == "flip" and p < len(b):
            b[p] ^= 1 << op[2]
        elif op[0] == "junk":
            b[p:p] = op[2]
        elif op[0] == "delete":
            del b[p : p + op[2]]
    if trunc is not None:
        del b[trunc % (len(b) + 1) :]
    return bytes(b)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(corruptions())
def test_fast_reader_equals_pymavlink_on_corrupted_logs(pymavlink_ref_module, make_tlog, arrays_match_messages, corruption):
    data = _apply(make_tlog(seconds=0.1, seed=2), *corruption)
    fd, path = tempfile.mkstemp(suffix=".tlog")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        scan = scan_tlog(data, TYPES)
        try:
            ref = pymavlink_ref_module.mmap(path, TYPES)
        except AttributeError:  # pymavlink's own crash on a cut-off first record; predicted
            assert scan.pymavlink_raises > 0
            return
        assert arrays_match_messages(read_tlog_arrays(data, TYPES), ref, TYPES) is None
        seq = pymavlink_ref_module.seq(path)
        assert [(t * 1e-6, f) for t, f in iter_tlog(data)] == [(m._timestamp, bytes(m.get_msgbuf())) for m in seq]
    finally:
        os.unlink(path)
