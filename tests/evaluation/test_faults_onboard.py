"""inject-fault on the onboard logs (ArduPilot .BIN, PX4 .ulg): the fault where and as large as asked, in place,
every other byte the original's, and the monitor (replay/audit) warns on the copy as on a faulted tlog.

On main (until inj1) inject-fault refused a .BIN or .ulg ("use the same flight's tlog")."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from mavahrs.evaluation.faults import AttitudeFault, FaultShape, ImuFault, inject_faults
from mavahrs.geometry.quaternion import conjugate, multiply
from mavahrs.geometry.rotation import from_euler_rad
from mavahrs.logs.dataflash import DTYPE_OF_FORMAT, decode, scan

BIN = "sitl/arducopter_onboard.BIN"  # ArduCopter SITL: airborne 46–249 s boot time (EV 28 / 18), IMUs 0 and 1
ULG = "px4_sitl/px4_aggressive.ulg"  # PX4 SITL (SIH), EKF2's vehicle_attitude at 250 Hz, one IMU
ONSET_S = 100.0


def _error_deg(q_old: np.ndarray, q_new: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The earth-frame error e = q_new ⊗ q_old* per row: its angle, degrees, and its unit axis (NED)."""
    e = multiply(q_new, conjugate(q_old))
    e = e * np.where(e[:, :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(e[:, 1:], axis=1)
    return np.degrees(2.0 * np.arctan2(s, e[:, 0])), e[:, 1:] / np.maximum(s, 1e-12)[:, None]


def _alarms(path: Path, start_s: float, end_s: float, causes: list[str] | None = None) -> list[float]:
    """The in-flight WARNING times (boot s) of ``mavahrs audit``'s monitor over a cut replay of ``path`` (their
    evidence into ``causes``)."""
    from mavahrs.fleet.audit import AuditSettings, summarise_log
    from mavahrs.replay import ReplaySettings
    from mavahrs.service.pipeline import PipelineSettings

    s = AuditSettings(replay=ReplaySettings(pipeline=PipelineSettings(), start_s=start_s, end_s=end_s))
    row = summarise_log(path, s)
    assert row.ok, row.error
    if causes is not None:
        causes += row.alarm_causes.split(";")
    return [float(x) for x in row.alarm_times_s.split(";") if x]


# --------------------------------------------------------------------------- DataFlash


def _field_bytes(sc, name: str, cols: tuple[str, ...], sel_t_s: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Byte positions of fields ``cols`` of every ``name`` record at TimeUS ≥ ``sel_t_s`` (from the FMT, independently
    of the injector's own layout code)."""
    t = sc.types[name]
    _, length, fmt, names = sc.formats[t]
    offs, o = {}, 0
    for c, n in zip(fmt, names, strict=True):
        offs[n] = (o, np.dtype(DTYPE_OF_FORMAT[c][0]).itemsize)
        o += offs[n][1]
    starts = sc.offsets[sc.ids == t].astype(np.int64) + 3
    tus = decode(sc, name)["TimeUS"].astype(np.int64)
    starts = starts[tus >= int(sel_t_s * 1e6)]
    return np.concatenate([((starts + offs[c][0])[:, None] + np.arange(offs[c][1])).ravel() for c in cols])


@pytest.fixture(scope="module")
def bin_tilt(shared_file: Callable[[str], Path], tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    src = shared_file(BIN)
    dst = tmp_path_factory.mktemp("bin") / "tilt2.BIN"
    report = inject_faults(src, dst, [AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0)])
    return src, dst, report


def test_bin_tilt_step_rewrites_every_attitude_record_in_place(bin_tilt) -> None:  # type: ignore[no-untyped-def]
    src, dst, report = bin_tilt
    a, b = scan(src), scan(dst)
    assert a.data.size == b.data.size and a.tail_bytes == b.tail_bytes == 19  # the cut-off last record too
    assert np.array_equal(a.ids, b.ids) and np.array_equal(a.offsets, b.offsets)
    assert set(report.modified) == {"XKQ", "XKF1", "ATT", "AHR2", "DCM"}
    assert 100.0 <= report.first_s < 100.05
    # every byte that differs is in an attitude field of a rewritten record, none before the onset
    allowed = np.zeros(a.data.size, bool)
    for name, cols in (("XKQ", ("Q1", "Q2", "Q3", "Q4")), ("XKF1", ("Roll", "Pitch", "Yaw")),
                       ("ATT", ("Roll", "Pitch", "Yaw")), ("DCM", ("Roll", "Pitch", "Yaw")),
                       ("AHR2", ("Roll", "Pitch", "Yaw", "Q1", "Q2", "Q3", "Q4"))):  # fmt: skip
        allowed[_field_bytes(a, name, cols, ONSET_S)] = True
    diff = a.data != b.data
    assert diff.any() and not (diff & ~allowed).any()
    # each record decodes to the faulted attitude: 2° of tilt about north, within the fields' rounding
    for name, kind, tol in (("XKQ", "q", 1e-4), ("AHR2", "q", 1e-4), ("ATT", "euler", 1e-4),
                            ("XKF1", "euler", 0.02), ("AHR2", "euler", 0.02), ("DCM", "euler", 1e-4)):  # fmt: skip
        old, new = decode(a, name), decode(b, name)
        after = old["TimeUS"] >= ONSET_S * 1e6
        assert np.array_equal(old["TimeUS"], new["TimeUS"])
        if kind == "q":
            qo, qn = (np.stack([d[k] for k in ("Q1", "Q2", "Q3", "Q4")], axis=1).astype(np.float64) for d in (old, new))
        else:
            qo, qn = (from_euler_rad(*(np.radians(d[k].astype(np.float64)) for k in ("Roll", "Pitch", "Yaw")))
                      for d in (old, new))  # fmt: skip
        ang, axis = _error_deg(qo[after], qn[after])
        assert np.allclose(ang, 2.0, atol=tol), (name, kind, np.abs(ang - 2.0).max())
        assert np.all(axis[:, 0] > 0.9999), name  # about north (azimuth 0)
        assert np.array_equal(qo[~after], qn[~after]), name
        if kind == "euler":
            assert np.all((new["Yaw"] >= 0) & (new["Yaw"] < 360)), name  # ArduPilot's 0–360° yaw stays so
    # the simulator's truth is not the autopilot's: untouched
    assert np.array_equal(decode(a, "SIM")["Q1"], decode(b, "SIM")["Q1"])


def test_bin_tilt_step_is_warned_within_2_s(bin_tilt) -> None:  # type: ignore[no-untyped-def]
    src, dst, _ = bin_tilt
    clean = _alarms(src, 30.0, 110.0)  # the log starts ~7 s boot time: replayed 37–117 s
    assert not [t for t in clean if t >= ONSET_S - 5.0], clean
    late = [t - ONSET_S for t in _alarms(dst, 30.0, 110.0) if t >= ONSET_S]
    assert late and 0.0 < late[0] <= 2.0, late  # 0.25 s measured


def test_bin_gyro_and_accel_bias_on_imu_instance_1(shared_file: Callable[[str], Path], tmp_path: Path) -> None:
    """The bias in IMU instance 1's records only; the monitor names that IMU (``IMU2?``, as on a tlog's
    SCALED_IMU2) though replay feeds instance 0 (until inj1 a .BIN gave the monitor no IMU but the fed one)."""
    src = shared_file(BIN)
    dst = tmp_path / "imu1.BIN"
    fault = ImuFault(when=FaultShape("step", ONSET_S, duration_s=30.0), gyro_bias_deg_s=(0.0, 0.0, 3.0),
                     accel_bias_m_s2=(0.0, -0.2, 0.0), instance=1)  # fmt: skip
    report = inject_faults(src, dst, [fault])
    a, b = scan(src), scan(dst)
    old, new = decode(a, "IMU"), decode(b, "IMU")
    assert set(np.unique(old["I"]).tolist()) == {0, 1}  # two IMUs: the bias is on the second only
    t = old["TimeUS"] * 1e-6
    on = (old["I"] == 1) & (t >= ONSET_S) & (t < ONSET_S + 30.0)
    assert report.modified == {"IMU[1]": int(on.sum())} and on.sum() > 11000
    d_gz = new["GyrZ"].astype(np.float64) - old["GyrZ"]
    d_ay = new["AccY"].astype(np.float64) - old["AccY"]
    assert np.allclose(d_gz[on], math.radians(3.0), atol=2e-6) and np.allclose(d_ay[on], -0.2, atol=1e-5)
    assert not d_gz[~on].any() and not d_ay[~on].any()
    for k in ("GyrX", "GyrY", "AccX", "AccZ", "T", "TimeUS", "I"):
        assert np.array_equal(old[k], new[k]), k
    allowed = np.zeros(a.data.size, bool)
    allowed[_field_bytes(a, "IMU", ("GyrZ", "AccY"), ONSET_S)] = True
    diff = a.data != b.data
    assert diff.any() and not (diff & ~allowed).any()
    causes: list[str] = []
    times = _alarms(dst, 30.0, 110.0, causes)  # the original over this cut: no WARNING (the tilt test)
    assert len(times) == 1 and ONSET_S < times[0] <= ONSET_S + 10.0 and "IMU2?" in causes[0], (times, causes)


def test_the_cli_copies_a_bin_atomically(shared_file: Callable[[str], Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """The CLI takes a .BIN by its content (whatever its name), says what it rewrote; an error while writing
    leaves neither the copy nor its temporary file."""
    import os

    from mavahrs.cli import main

    src = shared_file(BIN)
    out = tmp_path / "copy.log"
    capsys.readouterr()
    assert main(["inject-fault", str(src), str(out), "--at", "100", "--heading", "6"]) == 0
    said = capsys.readouterr().out
    assert "rewritten in place:" in said and "XKQ" in said and "from 100.0" in said, said
    assert out.stat().st_size == src.stat().st_size

    def fail(*_a: object, **_k: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", fail)
    bad = tmp_path / "bad.BIN"
    assert main(["inject-fault", str(src), str(bad), "--at", "100", "--heading", "6"]) == 1
    assert not bad.exists() and not list(tmp_path.glob(".*tmp"))


# --------------------------------------------------------------------------- ULog


def _ulog_field_bytes(path: Path, topic: str, fields: tuple[str, ...], field_offsets: dict[str, tuple[int, int]],
                      t_from_s: float) -> np.ndarray:  # fmt: skip
    """Byte positions of ``fields`` in the ``topic`` data records with timestamp_sample ≥ ``t_from_s``: the
    file's records walked here (3-byte header, 'A' subscriptions, 'D' data)."""
    data = path.read_bytes()
    pos, ids, out = 16, set(), []
    while pos + 3 <= len(data):
        size, typ = struct.unpack_from("<HB", data, pos)
        body = pos + 3
        if typ == ord("A") and data[body + 3 : body + size].split(b"\0")[0].decode() == topic:
            ids.add(struct.unpack_from("<H", data, body + 1)[0])
        elif typ == ord("D") and struct.unpack_from("<H", data, body)[0] in ids:
            p = body + 2
            ts = struct.unpack_from("<Q", data, p + field_offsets["timestamp_sample"][0])[0]
            if ts >= t_from_s * 1e6:
                out += [p + field_offsets[f][0] + k for f in fields for k in range(field_offsets[f][1])]
        pos = body + size
    return np.asarray(out, np.int64)


def _ulog(path: Path):  # type: ignore[no-untyped-def]
    from pyulog import ULog

    return ULog(str(path))


def test_ulg_tilt_step_in_place_and_warned_within_2_s(shared_file: Callable[[str], Path], tmp_path: Path) -> None:
    from pyulog.core import ULog as _U

    src = shared_file(ULG)
    dst = tmp_path / "tilt2.ulg"
    report = inject_faults(src, dst, [AttitudeFault(FaultShape("step", ONSET_S), tilt_deg=2.0, tilt_azimuth_deg=90.0)])
    assert set(report.modified) == {"vehicle_attitude"} and 100.0 <= report.first_s < 100.01
    a, b = _ulog(src), _ulog(dst)
    assert not b.file_corruption
    da = {(d.name, d.multi_id): d for d in a.data_list}
    db = {(d.name, d.multi_id): d for d in b.data_list}
    assert da.keys() == db.keys()
    for key, d in da.items():  # every other topic and field as it was
        for k, v in d.data.items():
            if key == ("vehicle_attitude", 0) and k.startswith("q["):
                continue
            assert np.array_equal(v, db[key].data[k], equal_nan=True), (key, k)
    va_o, va_n = da[("vehicle_attitude", 0)].data, db[("vehicle_attitude", 0)].data
    qo = np.stack([va_o[f"q[{i}]"] for i in range(4)], axis=1).astype(np.float64)
    qn = np.stack([va_n[f"q[{i}]"] for i in range(4)], axis=1).astype(np.float64)
    after = va_o["timestamp_sample"] >= ONSET_S * 1e6
    ang, axis = _error_deg(qo[after], qn[after])
    assert after.sum() > 39000 and np.allclose(ang, 2.0, atol=1e-3), np.abs(ang - 2.0).max()
    assert np.all(axis[:, 1] > 0.9999)  # about east (azimuth 90°)
    assert np.array_equal(qo[~after], qn[~after]) and np.all(np.sum(qo * qn, axis=1) > 0)  # hemisphere kept
    # the bytes: only vehicle_attitude's q of the records from the onset differ (their layout from pyulog's fields)
    offs, o = {}, 0
    for f in da[("vehicle_attitude", 0)].field_data:
        size = _U._UNPACK_TYPES[f.type_str][1]
        offs[f.field_name] = (o, size)
        o += size
    allowed = np.zeros(src.stat().st_size, bool)
    allowed[_ulog_field_bytes(src, "vehicle_attitude", tuple(f"q[{i}]" for i in range(4)), offs, ONSET_S)] = True
    raw_a = np.fromfile(src, np.uint8)
    raw_b = np.fromfile(dst, np.uint8)
    diff = raw_a != raw_b
    assert raw_a.size == raw_b.size and diff.any() and not (diff & ~allowed).any()
    # the reader reads the copy, and the monitor warns within 2 s (none on the original over the same cut)
    clean = _alarms(src, 60.0, 110.0)
    assert not [t for t in clean if t >= ONSET_S - 5.0], clean
    late = [t - ONSET_S for t in _alarms(dst, 60.0, 110.0) if t >= ONSET_S]
    assert late and 0.0 < late[0] <= 2.0, late


def test_ulg_gyro_bias_on_the_voted_imu(shared_file: Callable[[str], Path], tmp_path: Path) -> None:
    """The .ulg's only IMU (instance 0, the voted one): sensor_combined (what replay feeds), vehicle_imu's delta
    angles (bias × their interval), sensor_gyro."""
    src = shared_file(ULG)
    dst = tmp_path / "gyro0.ulg"
    fault = ImuFault(when=FaultShape("step", ONSET_S), gyro_bias_deg_s=(3.0, 0.0, 0.0), instance=0)
    report = inject_faults(src, dst, [fault])
    assert set(report.modified) == {"sensor_combined", "vehicle_imu", "sensor_gyro"}, report.modified
    a, b = ({(d.name, d.multi_id): d.data for d in _ulog(p).data_list} for p in (src, dst))
    for topic, col, t_col, per_s in (("sensor_combined", "gyro_rad[0]", "timestamp", None),
                                     ("sensor_gyro", "x", "timestamp_sample", None),
                                     ("vehicle_imu", "delta_angle[0]", "timestamp_sample", "delta_angle_dt")):  # fmt: skip
        o, n = a[(topic, 0)], b[(topic, 0)]
        after = o[t_col] >= ONSET_S * 1e6
        want = math.radians(3.0) * (o[per_s] * 1e-6 if per_s else 1.0)
        d = n[col].astype(np.float64) - o[col]
        assert np.allclose(d[after], (want[after] if per_s else want), atol=1e-5), topic
        assert not d[~after].any(), topic
        for k in o:
            if k != col:
                assert np.array_equal(o[k], n[k], equal_nan=True), (topic, k)
