"""The DataFlash reader (mavahrs.logs.dataflash) and the format dispatch (mavahrs.logs.sniff/read_log).

Against pymavlink's ``DFReader`` (the reference for the format) on the shared SITL log
``../shared/data/sitl/arducopter_onboard.BIN``, and on DataFlash logs written here
(``tests/conftest.py``: ``write_dataflash``, a synthetic 400 Hz flight whose IMU is the exact
derivative of its SIM truth): truncated, corrupted, empty, text, and a newer firmware's unknown
message formats.  Bounds on the scores against the synthetic truth are about twice what is
measured today; a mistimed or mis-signed column measures tens of degrees.
"""

from __future__ import annotations

import csv
import struct
from pathlib import Path

import numpy as np
import pytest

from mavahrs.errors import DataError
from mavahrs.filters.layout import IN_ACCEL, IN_DT, IN_GYRO, IN_MAG, IN_POS, IN_VEL, IN_VEL_AGE
from mavahrs.logs import FORMATS, read_log, sniff, unsupported_message
from mavahrs.logs.dataflash import decode, read_dataflash, scan

SHARED_BIN = "sitl/arducopter_onboard.BIN"


def _shared(shared_data: Path, rel: str) -> Path:
    path = shared_data / rel
    if not path.exists():
        pytest.skip(f"reference data not found at {path} (expected ../shared/data beside the checkout)")
    return path


def _dfreader(path: Path):  # type: ignore[no-untyped-def]
    dfr = pytest.importorskip("pymavlink.DFReader")
    return dfr.DFReader_binary(str(path), zero_time_base=False)


def _instance0(fl: dict[str, np.ndarray]) -> np.ndarray:
    return fl["TimeUS"]


# --------------------------------------------------------------------------- format by content


def test_sniff_chooses_the_format_by_content_not_by_name(dataflash_log, tmp_path: Path) -> None:
    path, _ = dataflash_log
    renamed = tmp_path / "flight.tlog"  # a DataFlash log under a telemetry log's name
    renamed.write_bytes(path.read_bytes()[:4096])
    assert sniff(path) == "dataflash" and sniff(renamed) == "dataflash"
    ulg = tmp_path / "x.BIN"
    ulg.write_bytes(b"ULog\x01\x12\x35\x01" + bytes(8))
    assert sniff(ulg) == "ulog"
    tlog = tmp_path / "x.ulg"
    tlog.write_bytes(struct.pack(">Q", 1_700_000_000_000_000) + b"\xfd\x09" + bytes(20))
    assert sniff(tlog) == "tlog"
    text = tmp_path / "notes.BIN"
    text.write_text("FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n")  # a log as text, not a log
    empty = tmp_path / "empty.BIN"
    empty.write_bytes(b"")
    assert sniff(text) is None and sniff(empty) is None and sniff(tmp_path / "missing.BIN") is None


def test_read_log_names_the_supported_formats_for_anything_else(tmp_path: Path) -> None:
    text = tmp_path / "notes.BIN"
    text.write_text("not a log\n" * 20)
    with pytest.raises(DataError) as err:
        read_log(text)
    msg = str(err.value)
    assert str(text) in msg and all(name in msg for name in FORMATS.values())
    assert msg == unsupported_message(text)
    empty = tmp_path / "empty.BIN"
    empty.write_bytes(b"")
    with pytest.raises(DataError, match="empty file"):
        read_log(empty)
    with pytest.raises(DataError, match="empty file"):
        read_dataflash(empty)


def test_read_log_dispatches_by_content(dataflash_log, tmp_path: Path) -> None:
    path, _ = dataflash_log
    odd = tmp_path / "flight.dat"
    odd.write_bytes(path.read_bytes())
    li = read_log(odd)
    assert li.format == "dataflash" and li.inputs.t_us.size > 7000


# --------------------------------------------------------------------------- a log written here


def test_synthetic_log_reads_every_imu_sample_on_the_log_clock(dataflash_log) -> None:
    path, fl = dataflash_log
    li = read_dataflash(path)
    prep = li.inputs
    t_true = _instance0(fl)
    # instance 0 fed, every sample from the first compass record on (MAG is 50 µs after the first IMU record)
    assert prep.instance == 0 and prep.message == "IMU"
    np.testing.assert_array_equal(prep.t_us, t_true[1:])
    assert 399.9 < prep.rate_hz() < 400.1
    np.testing.assert_allclose(prep.rows[1:, IN_DT], 1.0 / 400.0, rtol=1e-9)
    # float32 in the log: the values as written, to float32 precision
    np.testing.assert_allclose(prep.rows[:, IN_GYRO : IN_GYRO + 3], fl["gyro_rad_s"][1:], atol=1e-6)
    np.testing.assert_allclose(prep.rows[:, IN_ACCEL : IN_ACCEL + 3], fl["accel_m_s2"][1:], atol=1e-5)
    # the compass in the row at or after its record (50 µs later: the next IMU row), mGauss → µT
    has_mag = np.flatnonzero(np.all(np.isfinite(prep.rows[:, IN_MAG : IN_MAG + 3]), axis=1))
    assert has_mag.size == 200 - 1 or has_mag.size == 200
    k = has_mag[3]
    j = int(np.searchsorted(t_true, prep.t_us[k])) - 1  # the IMU sample the MAG record followed
    np.testing.assert_allclose(prep.rows[k, IN_MAG : IN_MAG + 3], fl["mag_ut"][j], atol=0.06)  # integer mGauss
    assert li.parameters["INS_GYRO_FILTER"] == 20.0 and li.parameters["SCHED_LOOP_RATE"] == 400.0
    assert not li.truncated and prep.notes == []
    t_sim, q_sim = li.references["SIM truth"]
    np.testing.assert_array_equal(t_sim, t_true[::16].astype(np.float64))
    np.testing.assert_allclose(np.abs(np.sum(q_sim * fl["q_body_to_ned"][::16], axis=1)), 1.0, atol=1e-6)
    header = "\n".join(li.found)
    assert "instances 0 (400 Hz), 1 (400 Hz); fed: instance 0, 400 Hz" in header
    assert "INS_GYRO_FILTER 20 Hz" in header and "truth: SIM" in header and "XKQ core 0" in header


def test_synthetic_log_agrees_with_dfreader(dataflash_log) -> None:
    path, _ = dataflash_log
    r = _dfreader(path)
    sc = scan(path)
    for tid, (name, *_rest) in sc.formats.items():
        assert sc.count(name) == r.counts[tid], name
    imu = decode(sc, "IMU")
    assert imu is not None
    k = 0
    while k < 500:
        m = r.recv_match(type="IMU")
        for col in ("TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ", "T"):
            assert imu[col][k] == pytest.approx(getattr(m, col), rel=1e-7, abs=1e-9), (k, col)
        k += 1


def test_a_truncated_log_is_read_to_its_last_whole_record(dataflash_log, tmp_path: Path) -> None:
    path, fl = dataflash_log
    data = path.read_bytes()
    whole = read_dataflash(path).inputs
    cut = tmp_path / "cut.BIN"
    cut.write_bytes(data[: len(data) * 3 // 5 + 7])  # inside a record
    li = read_dataflash(cut)
    assert li.truncated
    assert any(n.startswith("truncated: the log ends inside a record") for n in li.inputs.notes)
    n = li.inputs.t_us.size
    assert 0.55 * whole.t_us.size < n < 0.65 * whole.t_us.size
    np.testing.assert_array_equal(li.inputs.t_us, whole.t_us[:n])
    np.testing.assert_array_equal(li.inputs.rows[:, IN_GYRO : IN_GYRO + 3], whole.rows[:n, IN_GYRO : IN_GYRO + 3])


def test_a_log_cut_before_its_parameters_says_so_not_nan(shared_data: Path, tmp_path: Path) -> None:
    """The SITL .BIN's first 3000 bytes (an IMU record, no PARM yet): the header line said
    "(INS_GYRO_FILTER nan Hz, SCHED_LOOP_RATE nan)" until user8; with the parameters it names them."""
    data = _shared(shared_data, "sitl/arducopter_onboard.BIN").read_bytes()
    cut = tmp_path / "head.BIN"
    cut.write_bytes(data[:3000])
    imu = [f for f in read_dataflash(cut).found if f.startswith("IMU:")]
    assert imu and imu[0].endswith("(no INS_GYRO_FILTER or SCHED_LOOP_RATE in the log)") and "nan" not in imu[0], imu
    small = read_dataflash(_shared(shared_data, "mavlink_logs/ardusub_log_tools/small.BIN"))
    imu = [f for f in small.found if f.startswith("IMU:")]
    assert imu[0].endswith("(INS_GYRO_FILTER 20 Hz, SCHED_LOOP_RATE 200)"), imu
    fast = [n for n in small.inputs.notes if "IMU_FAST" in n]
    assert fast and fast[0].endswith("LOG_BITMASK's IMU_FAST bit"), fast  # no stray ")" after it


def test_a_corrupted_stretch_costs_only_its_own_records(dataflash_log, tmp_path: Path) -> None:
    path, fl = dataflash_log
    data = bytearray(path.read_bytes())
    whole = read_dataflash(path).inputs
    rng = np.random.default_rng(7)
    a = len(data) // 2
    data[a : a + 900] = rng.integers(0, 256, 900, dtype=np.uint8).tobytes()  # ~20 records' worth
    bad = tmp_path / "bad.BIN"
    bad.write_bytes(bytes(data))
    li = read_dataflash(bad)
    sc = scan(bad)
    assert sc.skipped_bytes >= 800 and sc.skipped_stretches >= 1
    assert any("not DataFlash records (corrupted or padding): skipped" in n for n in li.inputs.notes)
    lost = whole.t_us.size - li.inputs.t_us.size
    assert 0 < lost < 40  # the records in the stretch, no more
    assert set(li.inputs.t_us.tolist()) <= set(whole.t_us.tolist())
    # the samples after the stretch still carry the values written at their times
    tail = li.inputs.t_us > whole.t_us[whole.t_us.size * 3 // 4]
    k = np.searchsorted(fl["TimeUS"], li.inputs.t_us[tail])
    np.testing.assert_allclose(li.inputs.rows[tail, IN_GYRO : IN_GYRO + 3], fl["gyro_rad_s"][k], atol=1e-6)


def test_a_newer_firmwares_unknown_messages_are_skipped(tmp_path: Path, write_df) -> None:
    """A FMT with format characters this reader does not know, records of it, and records of a type with no
    FMT at all: the known messages are read as in the same log without them."""

    def newer(w) -> None:  # type: ignore[no-untyped-def]
        # type 140 "NEWM": 'X' and 'Y' are not format characters (yet); length 3 + 8 + 4
        w.buf += b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", 140, 15, b"NEWM", b"QXY", b"TimeUS,A,B")
        for k in range(50):
            w.buf += b"\xa3\x95\x8c" + struct.pack("<Q", 4_000_000 + k) + b"\x01\x02\x03\x04"
        w.buf += b"\xa3\x95\xc8" + bytes(range(40))  # type 200: never described by a FMT

    plain, _ = write_df(tmp_path / "plain.BIN", duration_s=5.0)
    newer_log, _ = write_df(tmp_path / "newer.BIN", duration_s=5.0, extra=newer)
    a, b = read_dataflash(plain), read_dataflash(newer_log)
    np.testing.assert_array_equal(a.inputs.t_us, b.inputs.t_us)
    np.testing.assert_array_equal(a.inputs.rows, b.inputs.rows)
    sc = scan(newer_log)
    assert sc.count("NEWM") == 50 and decode(sc, "NEWM") is None
    assert sc.skipped_bytes == 43  # the FMT-less record: its header and payload


def test_logs_without_imu_or_without_fmt_say_so(tmp_path: Path, df_writer) -> None:
    w = df_writer()
    w.fmt(131, "PARM", "QNff", "TimeUS,Name,Value,Default")
    w.rec("PARM", 1000, b"SYSID_THISMAV", 1.0, 1.0)
    no_imu = tmp_path / "no_imu.BIN"
    no_imu.write_bytes(bytes(w.buf))
    with pytest.raises(DataError, match="no IMU records .LOG_BITMASK must include IMU."):
        read_log(no_imu)
    headless = tmp_path / "headless.BIN"  # records, but the FMT records cut away: nothing says their lengths
    headless.write_bytes(b"\xa3\x95\x80" + bytes(bytes(w.buf)[300:]))
    with pytest.raises(DataError, match="no DataFlash FMT records"):
        read_dataflash(headless)


def test_the_timeline_step_over_the_imu_records(tmp_path: Path, df_writer) -> None:
    """The sample chain's timeline (the pipeline's step, an onboard log's settings) on known TimeUS: a record
    logged twice, a lone stamp 0.7 s ahead, a 1 s logger dropout (at rest, level: every record alike)."""
    from mavahrs.ingest.arrays import _GAP_DT_S

    w = df_writer()
    w.fmt(129, "IMU", "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
    t = (5_000_000 + 2500 * np.arange(2000)).tolist()
    t = t[:1500] + [x + 1_000_000 for x in t[1500:]]  # the logger lost 1 s: the clock stays ahead
    stamps = t[:501] + [t[500]] + t[501:]  # record 500 logged twice
    stamps[stamps.index(t[1200])] = t[1200] + 700_001  # a damaged stamp, 0.7 s ahead of both neighbours
    for x in stamps:
        w.rec("IMU", x, 0, 0.0, 0.0, 0.0, 0.0, 0.0, -9.80665, 0, 0, 25.0, 1, 1, 400, 400)
    path = tmp_path / "stamps.BIN"
    path.write_bytes(bytes(w.buf))
    inp = read_dataflash(path).inputs
    assert inp.counts["dropped_timeline"] == 3  # the repeat, the damaged one, the dropout's first
    assert inp.n == 2001 - 3 and np.all(np.diff(inp.t_us) > 0)
    assert t[1200] + 700_001 not in inp.t_us.tolist() and t[1500] not in inp.t_us.tolist()
    dt = inp.rows[:, IN_DT]
    gap = int(np.flatnonzero(inp.t_us == t[1501])[0])
    assert dt[gap] == _GAP_DT_S  # the dropout re-initialises the filters, at its second sample
    assert dt[int(np.flatnonzero(inp.t_us == t[1201])[0])] == pytest.approx(0.005)  # from the last one used


# --------------------------------------------------------------------------- the shared SITL log


@pytest.fixture(scope="module")
def shared_bin(shared_data: Path) -> Path:
    return _shared(shared_data, SHARED_BIN)


def test_shared_log_agrees_with_dfreader(shared_bin: Path) -> None:
    r = _dfreader(shared_bin)
    sc = scan(shared_bin)
    # the log is cut off inside its last record: DFReader counts that record, this reader does not
    assert sc.tail_bytes == 19
    cut = int(sc.data[sc.data.size - sc.tail_bytes + 2])
    for tid, (name, *_rest) in sc.formats.items():
        assert sc.count(name) == r.counts[tid] - (tid == cut), name
    imu = decode(sc, "IMU")
    assert imu is not None
    for k in range(2000):
        m = r.recv_match(type="IMU")
        for col in ("TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ", "T"):
            assert imu[col][k] == pytest.approx(getattr(m, col), rel=1e-7, abs=1e-9), (k, col)
    r.rewind()
    params: dict[str, float] = {}
    while (m := r.recv_match(type="PARM")) is not None:
        params[m.Name] = m.Value
    li = read_dataflash(shared_bin, end_s=5.0)
    assert li.parameters == pytest.approx(params)
    # an ArduCopter quad (MSG "ArduCopter V4…", FRAME_CLASS 1): filters are told so, as by the daemon
    assert li.inputs.vehicle_stream and li.inputs.multirotor
    xkq = decode(sc, "XKQ")
    assert xkq is not None
    r.rewind()
    m = r.recv_match(type="XKQ")
    assert (xkq["TimeUS"][0], xkq["Q1"][0], xkq["Q4"][0]) == pytest.approx((m.TimeUS, m.Q1, m.Q4))



def test_shared_log_fills_the_position_column_from_the_first_fix(shared_bin: Path) -> None:
    """``IN_POS`` beside every velocity fed: NED metres from the first fix used (the origin), which the
    simulator's own position (SIM Lat/Lng, 120 ms earlier: the receiver's lag) confirms within 0.1 m."""
    from mavahrs.sensors.position import PositionOrigin

    li = read_dataflash(shared_bin)
    rows = li.inputs.rows
    has_pos = np.isfinite(rows[:, IN_POS])
    assert np.array_equal(has_pos, np.isfinite(rows[:, IN_VEL]))  # the same fix's rows
    assert has_pos.sum() > 1000
    first = rows[np.flatnonzero(has_pos)[0], IN_POS : IN_POS + 3]
    assert np.allclose(first, 0.0)
    pos = rows[has_pos, IN_POS : IN_POS + 3]
    assert np.ptp(pos[:, 0]) > 50.0 and np.ptp(pos[:, 1]) > 50.0  # the flight's legs (≈ 100 m × 250 m)
    # against the truth: the simulator's position at the fix time, rotated into the rows' magnetic frame
    sc = scan(shared_bin)
    sim, gps = decode(sc, "SIM"), decode(sc, "GPS")
    assert sim is not None and gps is not None
    ok = gps["Status"] >= 3
    o = PositionOrigin()
    o.set(float(gps["Lat"][ok][0]), float(gps["Lng"][ok][0]), float(gps["Alt"][ok][0]))
    t_row = li.inputs.t_us[has_pos] - rows[has_pos, IN_VEL_AGE] * 1e6 - 20_000  # fix time (IN_VEL_AGE) + the lag left over
    d = li.inputs.declination_rad[has_pos]
    true_ned = o.ned_arrays(sim["Lat"], sim["Lng"], sim["Alt"], None)
    n_t = np.interp(t_row, sim["TimeUS"], true_ned[:, 0])
    e_t = np.interp(t_row, sim["TimeUS"], true_ned[:, 1])
    n_m, e_m = np.cos(d) * n_t + np.sin(d) * e_t, -np.sin(d) * n_t + np.cos(d) * e_t
    assert np.sqrt(np.mean((pos[:, 0] - n_m) ** 2 + (pos[:, 1] - e_m) ** 2)) < 0.1


# --------------------------------------------------------------------------- replay X.BIN --filter all --csv


def _csv_times(path: Path) -> np.ndarray:
    with path.open() as fh:
        rd = csv.reader(fh)
        head = next(rd)
        assert head[0] == "time_s"
        return np.array([float(r[0]) for r in rd])


def _table(out: str) -> dict[tuple[str, str], tuple[float, float]]:
    """The replay's comparison table: (filter, reference) → (heading, inclination RMS °)."""
    rows = {}
    lines = out.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split()[:2] == ["filter", "vs"])
    for line in lines[start + 2 :]:
        parts = line.split()
        if len(parts) >= 9 and parts[-7].isdigit():
            filt, ref = parts[0], " ".join(parts[1:-7])
            rows[(filt, ref)] = (float(parts[-5]), float(parts[-4]))
    return rows


def test_replay_all_filters_csv_a_row_per_imu_sample(dataflash_log, tmp_path: Path, capsys) -> None:
    from mavahrs.cli import main
    from mavahrs.filters import NAMES

    path, fl = dataflash_log
    out_csv = tmp_path / "all.csv"
    assert main(["replay", str(path), "--filter", "all", "--csv", str(out_csv), "--no-progress"]) == 0
    out = capsys.readouterr().out
    t = _csv_times(out_csv)
    np.testing.assert_allclose(t, fl["TimeUS"][1:] / 1e6, atol=5e-7)  # time_s = TimeUS / 1e6, every sample
    assert 399.9 < (t.size - 1) / (t[-1] - t[0]) < 400.1
    assert "format: ArduPilot DataFlash log (.BIN)" in out and "fed: instance 0, 400 Hz" in out
    table = _table(out)
    for name in NAMES:
        assert (name, "SIM truth") in table, name
    head, incl = table[("mahony", "SIM truth")]
    assert incl < 0.15 and head < 0.1  # measured 0.05° / 0.02°; a truth 2 samples late measures 0.1°+
    head, incl = table[("best", "SIM truth")]  # the ESKF without GNSS, as the daemon runs best on an autopilot
    assert incl < 0.5 and head < 0.3  # measured 0.25° / 0.12°


@pytest.mark.slow
def test_replay_the_shared_log_at_the_loop_rate_scored_against_sim(shared_bin: Path, tmp_path: Path, capsys) -> None:
    from mavahrs.cli import main

    out_csv = tmp_path / "bin.csv"
    assert main(["replay", str(shared_bin), "--filter", "all", "--csv", str(out_csv), "--end", "60",
                 "--no-progress"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    t = _csv_times(out_csv)
    sc = scan(shared_bin)
    imu = decode(sc, "IMU")
    assert imu is not None
    t0 = imu["TimeUS"][imu["I"] == 0] / 1e6
    inside = t0[(t0 >= t[0]) & (t0 <= t[-1])]
    assert t.size >= inside.size - 2  # a row per instance-0 IMU sample in the replayed span
    assert np.isin(np.round(t * 1e6), np.round(inside * 1e6)).all()  # on the log's own clock, TimeUS / 1e6
    assert 399.0 < (t.size - 1) / (t[-1] - t[0]) < 401.0
    table = _table(out)
    assert ("best", "SIM truth") in table and ("best", "autopilot EKF3") in table
    assert table[("best", "SIM truth")][1] < 0.6  # inclination; measured 0.2–0.3° over the first minute


# --------------------------------------------------------------------------- battery, vibration, parameters, cores


def test_battery_vibration_and_parameters_are_read(dataflash_log, write_df, tmp_path: Path) -> None:
    path, fl = dataflash_log
    li = read_dataflash(path)
    bat, vib = li.series["battery"], li.series["vibration"]
    assert bat["t_us"].size == 200 and np.all(bat["current_a"] == np.float32(12.5))
    np.testing.assert_allclose(bat["voltage_v"], 16.0 - 1e-5 * 40 * np.arange(200), atol=1e-5)
    assert set(vib) >= {"t_us", "imu", "x_m_s2", "y_m_s2", "z_m_s2", "clips"} and vib["z_m_s2"][0] == np.float32(4.0)
    header = "\n".join(li.found)
    assert "BAT: 10 Hz, current 12.5–12.5 A (mean 12.5)" in header and "VIBE: IMU 0 peak 4.0 m/s², 0 clips" in header
    assert np.all(li.inputs.declination_rad == 0.0)  # COMPASS_DEC 0, no GPS: none
    # COMPASS_DEC (radians) is the declination when there is no GPS fix for the magnetic model
    dec, _ = write_df(tmp_path / "dec.BIN", duration_s=4.0, params={"COMPASS_DEC": 0.1})
    li = read_dataflash(dec)
    np.testing.assert_allclose(li.inputs.declination_rad, 0.1, rtol=1e-6)
    assert "declination: COMPASS_DEC 5.73° (no GPS fix for the magnetic model)" in li.found
    # IMU logged below the loop rate is said
    slow, _ = write_df(tmp_path / "slow.BIN", duration_s=4.0, params={"SCHED_LOOP_RATE": 800.0})
    assert any("below the loop rate (SCHED_LOOP_RATE 800)" in n for n in read_dataflash(slow).inputs.notes)


def test_ekf3_per_core_from_xkf1_and_the_batch_sampler(write_df, df_writer, tmp_path: Path) -> None:
    """An older firmware's EKF3 (XKF1 Euler angles, no XKQ), two cores; ISBH/ISBD bursts of the batch sampler."""
    from mavahrs.geometry.rotation import to_euler_rad

    def extra(w) -> None:  # type: ignore[no-untyped-def]
        w.fmt(140, "XKF1", "QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH")
        w.fmt(141, "ISBH", "QHBBHHQf", "TimeUS,N,type,instance,mul,smp_cnt,SampleUS,smp_rate")
        w.fmt(142, "ISBD", "QHHaaa", "TimeUS,N,seqno,x,y,z")

    path, fl = write_df(tmp_path / "old.BIN", duration_s=6.0, extra=extra)
    # rewrite: drop the XKQ records, add XKF1 for cores 0 and 1 (core 1 = core 0 + 2° roll) and two bursts
    sc = scan(path)
    xkq = sc.types["XKQ"]
    keep = bytearray()
    ends = [*sc.offsets[1:].tolist(), sc.data.size]
    for t, a, b in zip(sc.ids.tolist(), sc.offsets.tolist(), ends, strict=True):
        if t != xkq:
            keep += sc.data[a:b].tobytes()
    w = df_writer()
    w.buf = bytearray()
    w.types["XKF1"] = (140, "QBccCfffffffccce")
    w.types["ISBH"] = (141, "QHBBHHQf")
    w.types["ISBD"] = (142, "QHHaaa")
    eul = np.degrees(to_euler_rad(fl["q_body_to_ned"]))
    for k in range(0, fl["TimeUS"].size, 40):
        r, p, y = eul[k]
        for core, dr in ((0, 0.0), (1, 2.0)):
            w.rec("XKF1", int(fl["TimeUS"][k]) + 5, core, int(round((r + dr) * 100)), int(round(p * 100)),
                  int(round((y % 360.0) * 100)), *([0.0] * 7), 0, 0, 0, 0)  # fmt: skip
    for burst in range(2):
        t = int(fl["TimeUS"][0]) + 1_000_000 * (burst + 1)
        w.rec("ISBH", t, burst, 1, 0, 1, 32, t, 1000.0)
        w.rec("ISBD", t + 1, burst, 0, *([0] * 96))
    log = tmp_path / "xkf1.BIN"
    log.write_bytes(bytes(keep) + bytes(w.buf))
    li = read_dataflash(log)
    assert "autopilot EKF3" in li.references and "autopilot EKF3 core 1" in li.references
    header = "\n".join(li.found)
    assert "autopilot EKF3 (XKF1 core 0, 10 Hz)" in header and "autopilot EKF3 core 1 (XKF1 core 1, 10 Hz)" in header
    from mavahrs.geometry.quaternion import angle_between

    t0, q0 = li.references["autopilot EKF3"]
    t1, q1 = li.references["autopilot EKF3 core 1"]
    k = np.searchsorted(fl["TimeUS"], t0.astype(np.int64) - 5)
    assert np.degrees(np.max(angle_between(q0, fl["q_body_to_ned"][k]))) < 0.02  # centidegrees
    np.testing.assert_allclose(np.degrees(angle_between(q0, q1)), 2.0, atol=0.02)
    bs = li.series["batch_sampler"]
    assert bs["t_us"].size == 2 and np.all(bs["rate_hz"] == 1000.0) and np.all(bs["sensor"] == 1)
    assert "batch sampler (ISBH/ISBD): 2 bursts, 2 data records (gyro 0 at 1000 Hz): raw bursts" in header


def test_shared_log_battery_vibration_and_ekf3_cores(shared_bin: Path) -> None:
    li = read_dataflash(shared_bin, end_s=60.0)
    assert "autopilot EKF3" in li.references and "autopilot EKF3 core 1" in li.references
    bat = li.series["battery"]
    assert 9.0 < 1e6 * (bat["t_us"].size - 1) / (bat["t_us"][-1] - bat["t_us"][0]) < 11.0
    assert np.nanmax(bat["current_a"]) > 1.0  # a hovering copter draws current
    vib = li.series["vibration"]
    assert set(np.unique(vib["imu"]).tolist()) == {0, 1}
    assert li.parameters["SCHED_LOOP_RATE"] == 400.0 and li.parameters["INS_GYRO_FILTER"] == 20.0
    assert "COMPASS_DEC" in li.parameters


def test_the_imu_selector_step_fails_over_from_a_frozen_imu(tmp_path: Path, df_writer) -> None:
    """The pipeline's IMU selector (its compiled step, looped over the records in time order) on a log whose IMU 0
    repeats one value from 2 s on while IMU 1 keeps measuring: the reader feeds IMU 0 until the freeze is
    recognised (``freeze_s`` 0.5 s, judged every 20 ms), IMU 1 from then on, and the per-sample
    :class:`ImuSelector` over the same records decides exactly the same."""
    from mavahrs.sensors.imu_select import ImuSelector
    from mavahrs.sensors.scaling import S_SAT

    w = df_writer()
    w.fmt(129, "IMU", "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz")
    rng = np.random.default_rng(3)
    n = 2400  # 6 s at 400 Hz
    t = 5_000_000 + 2500 * np.arange(n)
    recs = []
    for i in range(n):
        for inst in (0, 1):
            g = rng.normal(0.0, 0.01, 3)
            a = rng.normal(0.0, 0.05, 3) + (0.0, 0.0, -9.80665)
            if inst == 0 and t[i] >= 7_000_000:
                g, a = (0.01, 0.02, 0.03), (0.1, 0.2, -9.7)
            v = (int(t[i]), inst, *map(float, g), *map(float, a))
            recs.append(v)
            w.rec("IMU", *v, 0, 0, 25.0, 1, 1, 400, 400)
    path = tmp_path / "frozen.BIN"
    path.write_bytes(bytes(w.buf))
    inp = read_dataflash(path).inputs
    assert any("switched between instances [0, 1]" in x for x in inp.notes)
    sel = ImuSelector()
    fed = []
    for tt, inst, *va in recs:
        v = np.float32(va).astype(np.float64).tolist()  # as logged (float32)
        sample = (inst, tt, *v, np.nan, np.nan, np.nan, None, 0, 0)
        assert sample[S_SAT] == 0
        if sel.observe("IMU", sample):  # type: ignore[arg-type]
            fed.append((tt, inst))
    switch = next(tt for tt, inst in fed if inst == 1)
    assert 7_500_000 <= switch <= 7_600_000  # freeze_s after the freeze began, at the next evaluation
    # the reader feeds what the per-sample selector feeds (less the samples before the first compass, none here)
    assert inp.t_us.tolist() == [tt for tt, _ in fed]
    assert np.all(inp.rows[inp.t_us >= switch, IN_ACCEL + 2] != np.float32(-9.7))
