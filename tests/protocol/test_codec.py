"""MavCodec: framing, resynchronisation, counters and encoding, without any I/O."""

from __future__ import annotations

import os
import struct

import numpy as np

from mavahrs.protocol.codec import MAX_FRAME_LEN, MavCodec, frame_length, mavlink


def _imu(codec: MavCodec, t: int, zacc: int = -1000) -> bytes:
    return codec.encode(codec.mav.raw_imu_encode(t, 1, 2, zacc, 4, 5, 6, 7, 8, 9))


def _imus(n: int, sysid: int = 1, compid: int = 1) -> list[bytes]:
    src = MavCodec(sysid, compid)
    return [_imu(src, 1000 * i) for i in range(n)]


def test_encode_uses_ids_and_sequence_and_decodes_back():
    src = MavCodec(42, 191)
    frames = [_imu(src, t) for t in (1, 2, 3)]
    assert [f[4] for f in frames] == [0, 1, 2]  # MAVLink 2 seq byte
    assert all(f[5] == 42 and f[6] == 191 for f in frames)
    assert src.counters.packets_out == 3 and src.counters.bytes_out == sum(map(len, frames))
    dst = MavCodec()
    msgs = dst.receive_datagram(b"".join(frames))
    assert [m.time_usec for m in msgs] == [1, 2, 3] and msgs[0].zacc == -1000
    assert msgs[0].get_srcSystem() == 42 and msgs[0].get_srcComponent() == 191
    assert dst.counters.packets == 3 and dst.counters.sources[(42, 191)].packets == 3
    assert dst.counters.bytes_in == sum(map(len, frames)) and dst.counters.bad_data == 0


def test_mavlink1_and_zero_trimmed_frames():
    src = MavCodec(3, 4)
    v1 = src.encode(src.mav.heartbeat_encode(2, 3, 0, 0, 4), force_mavlink1=True)
    zero = src.encode(src.mav.raw_imu_encode(0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert v1[0] == 0xFE and zero[0] == 0xFD and zero[1] == 1  # payload trimmed to one byte
    msgs = MavCodec().receive_datagram(v1 + zero)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "RAW_IMU"]
    assert msgs[1].xacc == 0 and msgs[1].temperature == 0


def test_frame_length_from_header():
    f = _imus(1)[0]
    assert frame_length(f) == len(f)
    assert frame_length(f[:2]) == 0  # MAVLink 2 needs 3 header bytes for its flags
    assert frame_length(b"\xfe\x09") == 17


def test_junk_in_one_datagram_never_swallows_the_next():
    a, b = _imus(2)
    codec = MavCodec()
    # a datagram ending with a marker and a length byte promising a long frame
    assert codec.receive_datagram(b"\x00\x01" + a + b"\xfd\xff\x00\x01") != []
    assert [m.time_usec for m in codec.receive_datagram(b)] == [1000]
    assert codec.counters.bad_data == 2 and codec.counters.packets == 2


def test_partial_frame_at_end_of_datagram_is_dropped_not_kept():
    a, b = _imus(2)
    codec = MavCodec()
    assert codec.receive_datagram(b[:10]) == []
    assert [m.time_usec for m in codec.receive_datagram(a)] == [0]
    assert codec.counters.bytes_skipped == 10


def test_stream_keeps_partial_frame_across_reads():
    frames = _imus(3)
    blob = b"".join(frames)
    codec = MavCodec()
    got = []
    for k in range(0, len(blob), 7):
        got += codec.receive_stream(blob[k : k + 7])
    assert [m.time_usec for m in got] == [0, 1000, 2000]
    assert codec.counters.bad_data == 0


def test_resync_one_byte_on_finds_frame_behind_corrupt_length():
    a, b = _imus(2)
    bad = bytearray(a)
    bad[1] = 200  # length byte: the candidate now swallows frame b
    codec = MavCodec()
    msgs = codec.receive_datagram(bytes(bad) + b)
    assert [m.time_usec for m in msgs] == [1000]
    stream = MavCodec()
    got = []
    for byte in bytes(bad) + b:  # byte by byte: b is delivered without waiting for 200 more bytes
        got += stream.receive_stream(bytes([byte]))
    assert [m.time_usec for m in got] == [1000]


def test_crc_error_counted_once_per_corrupt_frame():
    frames = _imus(5)
    bad = bytearray(frames[2])
    bad[15] ^= 0x10  # payload bit flip
    codec = MavCodec()
    msgs = codec.receive_datagram(b"".join(frames[:2]) + bytes(bad) + b"".join(frames[3:]))
    assert [m.time_usec for m in msgs] == [0, 1000, 3000, 4000]
    assert codec.counters.crc_errors == 1 and codec.counters.bad_data == 1
    assert codec.counters.bytes_skipped == len(bad)
    # the lost frame shows as a sequence gap of the source
    assert codec.counters.sources[(1, 1)].seq_gaps == 1 and codec.counters.seq_gaps == 1


def test_sequence_gaps_duplicates_and_reordering_per_source():
    a = _imus(6, sysid=1)
    b = _imus(3, sysid=2)
    codec = MavCodec()
    order = [a[0], b[0], a[1], a[1], a[3], a[2], b[2], a[4], a[5]]
    msgs = [m for f in order for m in codec.receive_datagram(f)]
    src_a = codec.counters.sources[(1, 1)]
    src_b = codec.counters.sources[(2, 1)]
    assert src_a.duplicates == 1 and codec.counters.duplicates == 1  # exact repeat dropped
    assert src_a.out_of_order == 1  # a[2] after a[3]: delivered, and no longer counted missing
    assert src_a.seq_gaps == 0 and src_b.seq_gaps == 1  # b[1] really lost
    assert [m.time_usec for m in msgs if m.get_srcSystem() == 1] == [0, 1000, 3000, 2000, 4000, 5000]
    keep = MavCodec(drop_duplicates=False)
    assert len(keep.receive_datagram(a[0] + a[0])) == 2 and keep.counters.duplicates == 1


def test_a_stream_does_not_wait_behind_a_fake_frame_that_hides_a_real_one():
    """Junk ``FE 1F`` (a MAVLink 1 header, id 3: unknown, 39 bytes) covers a whole real frame and ends
    on a stray ``FD`` whose own fake frame runs past the data.  The real frames inside and after are
    decoded at once, in one read or split anywhere (found by the property test of chunking)."""
    src = MavCodec(3, 1)
    att = src.encode(src.mav.attitude_encode(0, 0, 0, 0, 0, 0, 0), force_mavlink1=True)
    hb = src.encode(src.mav.heartbeat_encode(0, 0, 0, 0, 0))
    data = b"\xfe\x1f" + att + b"\xfd" + hb
    assert [m.get_type() for m in MavCodec().receive_stream(data)] == ["ATTITUDE", "HEARTBEAT"]
    for cut in range(len(data) + 1):
        c = MavCodec()
        got = c.receive_stream(data[:cut]) + c.receive_stream(data[cut:])
        assert [m.get_type() for m in got if not isinstance(m, mavlink.MAVLink_unknown)] == ["ATTITUDE", "HEARTBEAT"], cut


def test_unknown_message_id_is_returned_but_never_swallows_a_valid_frame():
    # a genuine frame of an id the dialect lacks
    hdr = bytes([0xFD, 3, 0, 0, 0, 1, 1]) + (60000).to_bytes(3, "little") + b"\x01\x02\x03"
    unknown = hdr + b"\x00\x00"  # CRC cannot be checked without CRC_EXTRA
    codec = MavCodec()
    (m,) = codec.receive_datagram(unknown)
    assert isinstance(m, mavlink.MAVLink_unknown) and codec.counters.unknown_messages == 1
    # a stray marker in junk: "unknown id 0xABCDEF, 40 bytes" over a valid frame
    (good,) = _imus(1)
    fake = bytes([0xFD, 40, 0, 0, 0, 9, 9, 0xEF, 0xCD, 0xAB])
    codec = MavCodec()
    msgs = codec.receive_datagram(fake + good + b"\x00" * 20)
    assert [x.get_type() for x in msgs] == ["RAW_IMU"]
    stream = MavCodec()
    got = []
    for byte in fake + good + b"\x00" * 40:
        got += stream.receive_stream(bytes([byte]))
    assert [x.get_type() for x in got] == ["RAW_IMU"]
    assert (9, 9) not in stream.counters.sources  # junk does not invent sources


def test_bad_incompat_flags_are_bad_data():
    (f,) = _imus(1)
    bad = bytearray(f)
    bad[2] = 0x02  # unknown incompatibility flag: must be rejected
    codec = MavCodec()
    assert codec.receive_datagram(bytes(bad)) == []
    assert codec.counters.bad_data == 1 and codec.counters.crc_errors == 0


def test_stream_buffer_stays_bounded_under_junk_and_floods():
    codec = MavCodec()
    rnd = os.urandom(200_000)
    for k in range(0, len(rnd), 997):
        codec.receive_stream(rnd[k : k + 997])
        assert len(codec._stream_buf) < 2 * MAX_FRAME_LEN
    # a flood of endless "frame starts"
    for _ in range(1000):
        codec.receive_stream(b"\xfd\xff\x00" * 50)
        assert len(codec._stream_buf) < 2 * MAX_FRAME_LEN
    (good,) = _imus(1)
    got = codec.receive_stream(b"\x00" * 300 + good)
    # the flood's leftovers may pass as frames of unknown ids (those cannot be CRC-checked); the real one survives
    assert [m.get_type() for m in got if not isinstance(m, mavlink.MAVLink_unknown)] == ["RAW_IMU"]


def test_reset_stream_drops_partial_frame():
    (f,) = _imus(1)
    codec = MavCodec()
    assert codec.receive_stream(f[:20]) == []
    codec.reset_stream()
    assert codec.receive_stream(f[20:]) == []
    assert codec.counters.bytes_skipped >= 20


def test_decode_frame_is_strict():
    (f,) = _imus(1)
    codec = MavCodec()
    assert codec.decode_frame(f).get_type() == "RAW_IMU"
    assert codec.decode_frame(f + b"\x00") is None
    assert codec.decode_frame(b"\x00" + f) is None
    assert codec.decode_frame(f[:-1]) is None
    bad = bytearray(f)
    bad[12] ^= 1
    assert codec.decode_frame(bytes(bad)) is None
    assert codec.counters.packets == 0  # no bookkeeping


def test_signed_frame_accepted_without_key_like_pymavlink():
    src = MavCodec(1, 1)
    src.enable_signing(b"k" * 32, link_id=1, initial_timestamp_10us=1000)
    f = _imu(src, 5)
    assert f[2] & 1 and len(f) == frame_length(f)
    (m,) = MavCodec().receive_datagram(f)
    assert m.time_usec == 5


def test_system_id_settable_and_repr_without_secrets():
    c = MavCodec(1, 191)
    c.system_id = 7
    assert _imu(c, 1)[5] == 7 and c.component_id == 191
    c.enable_signing(bytes(range(32)))
    assert "signing=on" in repr(c) and bytes(range(32)).hex() not in repr(c)


def test_sequence_wraps_without_gaps():
    frames = _imus(600)  # the sequence byte wraps twice
    codec = MavCodec()
    msgs = [m for f in frames for m in codec.receive_datagram(f)]
    assert [m.time_usec for m in msgs] == [1000 * i for i in range(600)]
    assert codec.counters.seq_gaps == 0 and codec.counters.out_of_order == 0
    assert struct.unpack("<Q", frames[-1][10:18])[0] == 599_000


def _frame(msgid: int, payload: bytes, v2: bool, signed: bool, rng) -> bytes:
    cls = mavlink.mavlink_map[msgid]
    seq, sysid, compid = (int(x) for x in rng.integers(0, 256, 3))
    if v2:
        body = bytes([len(payload), 1 if signed else 0, int(rng.integers(0, 256)), seq, sysid, compid]) + msgid.to_bytes(3, "little")
    else:
        body = bytes([len(payload), seq, sysid, compid, msgid])
    crc = mavlink.x25crc(body + payload)
    crc.accumulate(bytes([cls.crc_extra]))
    out = (b"\xfd" if v2 else b"\xfe") + body + payload + struct.pack("<H", crc.crc)
    return out + rng.integers(0, 256, 13, dtype=np.uint8).tobytes() if signed else out


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (a != a and b != b)
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return type(a) is type(b) and a == b


def test_decode_identical_to_pymavlink_for_every_message_type(rng):
    """Every message of the dialect, random payloads (full, zero-trimmed, over-long), v1/v2, signed."""
    ref = mavlink.MAVLink(None)
    codec = MavCodec()
    checked = 0
    for msgid, cls in sorted(mavlink.mavlink_map.items()):
        size = cls.unpacker.size
        for trial in range(4):
            v2 = msgid > 255 or trial % 2 == 0
            plen = [size, int(rng.integers(1, size + 1)), min(255, size + 3), size][trial]
            payload = rng.integers(0, 256, plen, dtype=np.uint8).tobytes()
            frame = _frame(msgid, payload, v2, signed=v2 and trial == 3, rng=rng)
            want = ref.decode(bytearray(frame))
            got = codec.decode_frame(frame)
            assert got is not None and type(got) is type(want), cls.msgname
            for f in cls.fieldnames:
                assert _same(getattr(got, f), getattr(want, f)), (cls.msgname, f)
            h1, h2 = got.get_header(), want.get_header()
            assert (h1.msgId, h1.incompat_flags, h1.compat_flags, h1.mlen, h1.seq, h1.srcSystem, h1.srcComponent) == (
                h2.msgId, h2.incompat_flags, h2.compat_flags, h2.mlen, h2.seq, h2.srcSystem, h2.srcComponent)  # fmt: skip
            assert got.get_msgbuf() == want.get_msgbuf() and got.get_payload() == want.get_payload()
            assert got.get_crc() == want.get_crc() and got.get_signed() == want.get_signed()
            bad = bytearray(frame)
            bad[-14 if frame[2] & 1 and v2 else -1] ^= 0x40  # CRC byte
            assert codec.decode_frame(bytes(bad)) is None
            checked += 1
    assert checked == 4 * len(mavlink.mavlink_map)
