"""The bulk tlog reader gives exactly pymavlink's messages, fields and timestamps — clean or corrupt."""

from __future__ import annotations

import io
import random
import struct
from pathlib import Path

import numpy as np
import pytest

from mavahrs.errors import ConfigError
from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.protocol.fast_tlog import (
    DEFAULT_TYPES,
    message_dtype,
    read_tlog_arrays,
    scan_tlog,
)
from mavahrs.protocol.tlog import tlog_record

TYPES = list(DEFAULT_TYPES)


def _tlogs(mavlink_logs_dir: Path) -> list[Path]:
    paths = sorted(mavlink_logs_dir.glob("*/*.tlog"))
    assert paths, f"no .tlog under {mavlink_logs_dir}"
    return paths


@pytest.mark.slow
def test_real_logs_equal_pymavlink(mavlink_logs_dir, pymavlink_ref, arrays_match_messages):
    """Every message of the 14 types in the three real logs, field for field and in order."""
    seen = {}
    for path in _tlogs(mavlink_logs_dir):
        arrays = read_tlog_arrays(path, TYPES)
        ref = pymavlink_ref.mmap(path, TYPES)
        assert ref, path
        assert arrays_match_messages(arrays, ref, TYPES) is None, path
        for t in TYPES:
            seen[t] = seen.get(t, 0) + len(arrays[t])
    # the logs carry these (README of the data): the comparison was not vacuous
    assert seen["RAW_IMU"] == 2856 + 795 + 528 and seen["SIMSTATE"] == 889 and seen["HEARTBEAT"] > 1000


def test_real_log_with_corrupt_records(mavlink_logs_dir, pymavlink_ref):
    """flight.tlog has 1314 CRC-failed radio records and a truncated last record; counts as pymavlink."""
    path = mavlink_logs_dir / "dronekit-python" / "flight.tlog"
    scan = scan_tlog(path, ["RAW_IMU", "SCALED_IMU2", "RADIO_STATUS"])
    ref = pymavlink_ref.mmap(path, ["RAW_IMU", "SCALED_IMU2", "RADIO_STATUS"])
    assert len(scan) == len(ref) == 2856 + 2852 + 1370
    assert [int(i) for i in scan.msgid] == [m.get_msgId() for m in ref]
    assert [scan.frame(j) for j in range(len(scan))] == [bytes(m.get_msgbuf()) for m in ref]


def test_generated_400hz_log_equal_pymavlink(tmp_path, make_tlog, pymavlink_ref, arrays_match_messages):
    data = make_tlog(seconds=2.0, seed=4)
    path = tmp_path / "gen.tlog"
    path.write_bytes(data)
    arrays = read_tlog_arrays(path, TYPES)
    assert len(arrays["RAW_IMU"]) == 800 + 8  # 400 Hz MAVLink 2 + 2 Hz MAVLink 1
    assert len(arrays["ATTITUDE_QUATERNION"]) == 20 + 16  # incl. the signed ones
    assert arrays_match_messages(arrays, pymavlink_ref.mmap(path, TYPES), TYPES) is None
    # a type subset visits fewer records but must still agree
    sub = ["HIGHRES_IMU", "SIM_STATE", "SYSTEM_TIME"]
    assert arrays_match_messages(read_tlog_arrays(path, sub), pymavlink_ref.mmap(path, sub), sub) is None


def test_fuzzed_logs_equal_pymavlink(tmp_path, make_tlog, mutate_tlog, pymavlink_ref, arrays_match_messages):
    """Bit flips, truncation, junk with and without marker bytes, deletions, duplications.

    pymavlink itself raises on some corrupt files (the first record of a type
    cut off by the end of the file: AttributeError on ``None._instance_field``);
    the scan predicts exactly those, and this reader returns data instead.
    """
    base = make_tlog(seconds=0.3, seed=1)
    rng = random.Random(2024)
    kinds: dict[str, int] = {}
    raised = 0
    for it in range(40):
        kind, data = mutate_tlog(base, rng)
        path = tmp_path / f"f{it}.tlog"
        path.write_bytes(data)
        types = TYPES if it % 3 else rng.sample(TYPES, 4)
        scan = scan_tlog(path, types)
        try:
            ref = pymavlink_ref.mmap(path, types)
        except AttributeError:
            raised += 1
            assert scan.pymavlink_raises > 0, (it, kind)
            read_tlog_arrays(path, types)  # and we do not raise
            continue
        assert scan.pymavlink_raises == 0, (it, kind)
        err = arrays_match_messages(read_tlog_arrays(path, types), ref, types)
        assert err is None, (it, kind, err)
        kinds[kind] = kinds.get(kind, 0) + 1
    assert len(kinds) >= 6 and raised < 10  # the mutations were varied and mostly comparable


def test_pymavlink_engine_matches_fast_engine(make_tlog):
    data = make_tlog(seconds=0.5, seed=9)
    fast = read_tlog_arrays(data, TYPES + ["STATUSTEXT", "PARAM_VALUE"])
    slow = read_tlog_arrays(data, TYPES + ["STATUSTEXT", "PARAM_VALUE"], engine="pymavlink")
    for t, a in fast.items():
        assert a.dtype == slow[t].dtype
        assert a.tobytes() == slow[t].tobytes(), t
    assert fast["STATUSTEXT"]["text"][0] == b"hello world"
    assert fast["PARAM_VALUE"]["param_id"][0] == b"GYRO_X"


def _mavlink1_raw_imu(msg, seq: int, sysid: int, compid: int) -> bytes:
    """RAW_IMU as a MAVLink 1 frame from the C library: the 26 base-field bytes, no extensions.

    (pymavlink's own ``force_mavlink1`` keeps the extension bytes.)
    """
    cls = type(msg)
    payload = cls.unpacker.pack(*[getattr(msg, f) for f in cls.ordered_fieldnames])[:26]
    body = bytes([26, seq, sysid, compid, cls.id]) + payload
    crc = mavlink.x25crc(body)
    crc.accumulate(bytes([cls.crc_extra]))
    return b"\xfe" + body + struct.pack("<H", crc.crc)


def test_zero_trimmed_and_mavlink1_payloads_decode_as_pymavlink():
    c = MavCodec(7, 1)
    full = c.encode(c.mav.raw_imu_encode(5, 1, 2, 3, 4, 5, 6, 7, 8, 9, 1, 2500))
    trimmed = c.encode(c.mav.raw_imu_encode(6, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    v1 = _mavlink1_raw_imu(c.mav.raw_imu_encode(7, 1, 2, 3, 4, 5, 6, 7, 8, 9, 1, 2500), 3, 7, 1)
    assert len(trimmed) < len(full) and v1[0] == 0xFE and v1[1] == 26
    data = b"".join(tlog_record(100 + i, f) for i, f in enumerate([full, trimmed, v1]))
    a = read_tlog_arrays(data, ["RAW_IMU"])["RAW_IMU"]
    assert a["time_usec"].tolist() == [5, 6, 7]
    assert a["xacc"].tolist() == [1, 1, 1] and a["yacc"].tolist() == [2, 0, 2]
    assert a["temperature"].tolist() == [2500, 0, 0]  # trimmed zeros; MAVLink 1 has no extension fields
    assert a["t_us"].tolist() == [100, 101, 102] and set(a["sysid"]) == {7}
    ref = [c.decode_frame(f) for f in (full, trimmed, v1)]
    assert [m.temperature for m in ref] == [2500, 0, 0] and [m.zmag for m in ref] == [9, 0, 9]


def test_inputs_path_file_object_bytes_and_empty(tmp_path, make_tlog):
    data = make_tlog(seconds=0.1, seed=3)
    p = tmp_path / "x.tlog"
    p.write_bytes(data)
    a = read_tlog_arrays(p, ["RAW_IMU"])["RAW_IMU"]
    b = read_tlog_arrays(io.BytesIO(data), ["RAW_IMU"])["RAW_IMU"]
    c = read_tlog_arrays(str(p), ["RAW_IMU"])["RAW_IMU"]
    assert len(a) == 40 + 1 and a.tobytes() == b.tobytes() == c.tobytes()
    empty = read_tlog_arrays(b"", TYPES)
    assert all(len(v) == 0 and v.dtype == message_dtype(k) for k, v in empty.items())


def test_dtype_fields_follow_the_dialect():
    dt = message_dtype("ATTITUDE_QUATERNION")
    assert dt.names[:3] == ("t_us", "sysid", "compid")
    assert dt.names[3:] == ("time_boot_ms", "q1", "q2", "q3", "q4", "rollspeed", "pitchspeed", "yawspeed", "repr_offset_q")
    assert dt["repr_offset_q"].shape == (4,) and dt["time_boot_ms"] == np.uint32
    hb = message_dtype("heartbeat")  # declaration order, not wire order
    assert hb.names[3:] == ("type", "autopilot", "base_mode", "custom_mode", "system_status", "mavlink_version")
    with pytest.raises(ConfigError, match="NOT_A_MESSAGE"):
        read_tlog_arrays(b"", ["NOT_A_MESSAGE"])


@pytest.mark.parametrize("n", [0, 1, 7, 8, 15, 16, 17, 100])
def test_tiny_and_arbitrary_inputs_do_not_raise(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        read_tlog_arrays(data, TYPES)
        scan_tlog(data, None, mode="sequential")


def test_corrupt_first_record_of_a_type_at_end_returns_data(pymavlink_ref, tmp_path):
    """A documented difference: pymavlink raises; we return everything before the cut."""
    c = MavCodec(1, 1)
    recs = [tlog_record(1000 + i, c.encode(c.mav.raw_imu_encode(i, 0, 0, -1000, 0, 0, 0, 0, 0, 0))) for i in range(5)]
    last = tlog_record(2000, c.encode(c.mav.attitude_encode(1, 0.1, 0.2, 0.3, 0, 0, 0)))
    data = b"".join(recs) + last[:-5]
    p = tmp_path / "cut.tlog"
    p.write_bytes(data)
    with pytest.raises(AttributeError):
        pymavlink_ref.mmap(p, ["RAW_IMU"])
    scan = scan_tlog(p, ["RAW_IMU"])
    assert scan.pymavlink_raises == 1
    assert read_tlog_arrays(p, ["RAW_IMU"])["RAW_IMU"]["time_usec"].tolist() == [0, 1, 2, 3, 4]


def test_a_log_cut_inside_a_frame_is_found_where_the_frame_starts(shared_data) -> None:  # type: ignore[no-untyped-def]
    """``head -c N`` of a SITL log ends inside a frame: its start is reported; the whole log gives None."""
    from mavahrs.protocol.fast_tlog import scan_tlog, truncated_frame_at

    path = shared_data / "sitl" / "arducopter_gentle.tlog"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    data = np.fromfile(path, np.uint8)
    assert truncated_frame_at(scan_tlog(data, ["RAW_IMU"])) is None
    full = scan_tlog(data, None)
    ends = {int(o) + int(n) for o, n in zip(full.offset[~full.in_side], full.length[~full.in_side], strict=True)}
    for cut in (100_000, 250_001, 777_777):
        if cut in ends:
            continue
        at = truncated_frame_at(scan_tlog(data[:cut].copy(), ["RAW_IMU"]))
        assert at is not None and cut - 300 < at < cut, (cut, at)  # within one frame of the cut
