r"""Fault injection for onboard logs: ArduPilot DataFlash (``.BIN``) and PX4 ULog (``.ulg``), rewritten in place.

:func:`mavahrs.evaluation.faults.inject_faults` hands a ``.BIN`` or ``.ulg`` (chosen by content, as replay
chooses) to :func:`inject_dataflash` / :func:`inject_ulog`.  The faults and their time profiles are the
tlog's (:class:`~mavahrs.evaluation.faults.AttitudeFault`, :class:`~mavahrs.evaluation.faults.ImuFault`,
:class:`~mavahrs.evaluation.faults.FaultShape`), on the autopilot's boot clock: DataFlash ``TimeUS``, ULog
``timestamp_sample`` (the attitude's; ``timestamp`` where a topic has none), the clocks replay and audit read
these logs on.

Both formats fix every record's layout in the log itself (DataFlash FMT records, ULog format definitions),
so a rewritten field keeps its type and size: only the bytes of the rewritten fields of the rewritten records
differ from the original (a test compares every other byte).  Values are rounded to the field's type
(DataFlash ``c`` int16 centidegrees, ``C`` uint16 centidegrees 0…35999 for a yaw, floats as float32);
a value outside an integer field's range is clipped and counted.

DataFlash records rewritten by an :class:`AttitudeFault` (every one of them the autopilot logs):

* ``XKQ`` / ``NKQ`` (EKF3 / EKF2 quaternion, every core ``C``), and the older per-core ``XKQ1``/``XKQ2``,
  ``NKQ1``/``NKQ2``: ``Q1``–``Q4``, the sender's hemisphere kept;
* ``XKF1`` / ``NKF1`` (every core; and the older second core's ``XKF6`` / ``NKF6``): ``Roll``, ``Pitch``
  (int16 centidegrees), ``Yaw`` (uint16 centidegrees);
* ``ATT``: ``Roll``, ``Pitch``, ``Yaw`` (degrees, float; not ``DesRoll`` …, the controller's targets);
* ``AHR2`` (the secondary AHRS, DCM): ``Roll``/``Pitch``/``Yaw`` (centidegrees) and ``Q1``–``Q4``;
  ``DCM`` (DCM's own record): ``Roll``/``Pitch``/``Yaw`` (degrees).

``SIM`` (the simulator's truth) is left alone.  An :class:`ImuFault` adds its bias to the ``IMU``,
``GYR`` and ``ACC`` records of its instance (field ``I``): ``GyrX/Y/Z`` rad/s, ``AccX/Y/Z`` m/s².

ULog topics rewritten by an :class:`AttitudeFault`: ``vehicle_attitude`` (EKF2's attitude, the reference
replay and audit compare with) and ``estimator_attitude`` (each EKF2 instance's, when logged): ``q[0]``–
``q[3]``; ``vehicle_attitude_groundtruth`` (truth) and ``vehicle_local_position.heading`` are left alone.
An :class:`ImuFault` on instance N: ``vehicle_imu[N]`` (``delta_angle`` += bias × ``delta_angle_dt``,
``delta_velocity`` += bias × ``delta_velocity_dt``), ``sensor_gyro[N]`` / ``sensor_accel[N]`` (``x``/``y``/``z``)
and ``sensor_combined`` (``gyro_rad``, ``accelerometer_m_s2``) when N is the voted IMU (``sensor_selection``'s
device ids matched with ``vehicle_imu``'s; instance 0 when the log cannot tell).

The copy is written to a temporary file beside the output and renamed when complete.
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mavahrs.errors import DataError
from mavahrs.evaluation.faults import (
    AttitudeFault,
    ImuFault,
    InjectionReport,
    _euler_of_q,
    _q_of_euler,
    _shift,
    _shift_euler,
)

__all__ = ["inject_dataflash", "inject_ulog", "DATAFLASH_ATTITUDE_RECORDS", "ULOG_ATTITUDE_TOPICS", "imu_instance"]

#: DataFlash records that carry the autopilot's attitude (rewritten by an AttitudeFault)
DATAFLASH_ATTITUDE_RECORDS = ("XKQ", "NKQ", "XKQ1", "XKQ2", "NKQ1", "NKQ2", "XKF1", "NKF1", "XKF6", "NKF6", "ATT",
                              "AHR2", "DCM")  # fmt: skip
#: DataFlash records of one IMU instance (field ``I``), rewritten by an ImuFault
DATAFLASH_IMU_RECORDS = ("IMU", "GYR", "ACC")
#: ULog topics that carry the autopilot's attitude (``q[0..3]``)
ULOG_ATTITUDE_TOPICS = ("vehicle_attitude", "estimator_attitude")

#: the instance a MAVLink IMU message carries (ArduPilot: RAW_IMU the first IMU, SCALED_IMU2 the second …;
#: PX4's HIGHRES_IMU is the voted one, taken as instance 0)
_INSTANCE_OF_MESSAGE = {"RAW_IMU": 0, "SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2, "HIGHRES_IMU": 0}


def imu_instance(f: ImuFault) -> int:
    """The IMU instance an :class:`ImuFault` means in an onboard log: its ``instance``, else its message's."""
    return int(f.instance) if f.instance is not None else _INSTANCE_OF_MESSAGE[f.message]


# --------------------------------------------------------------------------- fields in a byte buffer


@dataclass
class _Field:
    offset: int  # from the record's payload start
    dtype: np.dtype
    scale: float = 1.0  # value = raw × scale

    @property
    def size(self) -> int:
        return int(self.dtype.itemsize)


def _read(buf: np.ndarray, starts: np.ndarray, f: _Field) -> np.ndarray:
    idx = (starts + f.offset)[:, None] + np.arange(f.size)
    return np.ascontiguousarray(buf[idx]).view(f.dtype).reshape(-1)


def _write(buf: np.ndarray, starts: np.ndarray, f: _Field, raw: np.ndarray) -> None:
    idx = (starts + f.offset)[:, None] + np.arange(f.size)
    buf[idx] = np.ascontiguousarray(np.asarray(raw).astype(f.dtype)).view(np.uint8).reshape(-1, f.size)


def _to_raw(f: _Field, values: np.ndarray, report: InjectionReport, *, yaw: bool = False) -> np.ndarray:
    """Values in the field's units → its stored type: ints rounded (a yaw in an unsigned field wrapped to
    0…360°), out-of-range ints clipped and counted."""
    v = np.asarray(values, np.float64) / f.scale
    if f.dtype.kind == "f":
        return v.astype(f.dtype)
    if yaw and f.dtype.kind == "u":
        full = round(360.0 / f.scale)
        return np.mod(np.rint(v), full).astype(f.dtype)
    info = np.iinfo(f.dtype)
    r = np.rint(v)
    out = (r < info.min) | (r > info.max)
    report.clipped += int(out.sum())
    return np.clip(r, info.min, info.max).astype(f.dtype)


@dataclass
class _RecordSet:
    """The records of one type (one topic instance): where their payloads start, their fields, their times."""

    name: str
    starts: np.ndarray  # byte offset of each record's payload (the first field)
    fields: dict[str, _Field]
    t_s: np.ndarray


def _note(report: InjectionReport, name: str, t_s: np.ndarray, hit: np.ndarray) -> None:
    if t_s.size:
        lo, hi = float(np.min(t_s)), float(np.max(t_s))
        report.seen_first_s = lo if not math.isfinite(report.seen_first_s) else min(report.seen_first_s, lo)
        report.seen_last_s = hi if not math.isfinite(report.seen_last_s) else max(report.seen_last_s, hi)
    n = int(hit.sum())
    if not n:
        return
    report.modified[name] = report.modified.get(name, 0) + n
    lo, hi = float(np.min(t_s[hit])), float(np.max(t_s[hit]))
    report.first_s = lo if not math.isfinite(report.first_s) else min(report.first_s, lo)
    report.last_s = hi if not math.isfinite(report.last_s) else max(report.last_s, hi)


# --------------------------------------------------------------------------- attitude and IMU edits


def _apply_attitude(buf: np.ndarray, rs: _RecordSet, faults: Sequence[AttitudeFault], report: InjectionReport,
                    quat: Sequence[str] | None, euler: Sequence[str] | None, euler_deg: bool = True) -> None:  # fmt: skip
    """Shift the attitude in ``rs``'s quaternion fields ``quat`` (w, x, y, z) and/or Euler fields ``euler``
    (roll, pitch, yaw; degrees) by the faults active at each record's time."""
    ks = np.stack([f.when.factors(rs.t_s) for f in faults], axis=1) if faults else np.zeros((rs.t_s.size, 0))
    hit = np.any(ks != 0.0, axis=1) if ks.shape[1] else np.zeros(rs.t_s.size, bool)
    idx = np.flatnonzero(hit)
    starts = rs.starts[idx]
    q_cols = [_read(buf, starts, rs.fields[c]).astype(np.float64) * rs.fields[c].scale for c in quat] if quat else None
    e_cols = [_read(buf, starts, rs.fields[c]).astype(np.float64) * rs.fields[c].scale for c in euler] if euler else None
    done = np.zeros(idx.size, bool)
    q_new = np.array(q_cols, np.float64).T.copy() if q_cols else None
    e_new = np.array(e_cols, np.float64).T.copy() if e_cols else None
    unit = math.pi / 180.0 if euler_deg else 1.0
    for j in range(idx.size):
        active = [(f, float(k)) for f, k in zip(faults, ks[idx[j]], strict=True) if k != 0.0]
        if q_new is not None:
            q = q_new[j]
            n = math.sqrt(float(q @ q))
            if math.isfinite(n) and n > 0.5:
                w, x, y, z = _shift(tuple(q), active)
                if w * q[0] + x * q[1] + y * q[2] + z * q[3] < 0.0:  # keep the sender's hemisphere
                    w, x, y, z = -w, -x, -y, -z
                q_new[j] = (w, x, y, z)
                done[j] = True
        if e_new is not None:
            r, p, yw = (float(v) * unit for v in e_new[j])
            if math.isfinite(r) and math.isfinite(p) and math.isfinite(yw):
                if all(not (f.tilt_deg or f.heading_deg) for f, _k in active):  # Euler offsets only: exact
                    for f, k in active:
                        r, p, yw = _shift_euler(r, p, yw, f, k)
                else:
                    r, p, yw = _euler_of_q(*_shift(_q_of_euler(r, p, yw), active))
                orig_yaw = float(e_new[j][2])
                yd = yw / unit
                if orig_yaw >= 0.0:  # a 0…360° yaw stays 0…360°
                    yd = yd % (360.0 if euler_deg else 2.0 * math.pi)
                e_new[j] = (r / unit, p / unit, yd)
                done[j] = True
    starts = starts[done]
    if q_new is not None and quat:
        for c, col in zip(quat, q_new[done].T, strict=True):
            _write(buf, starts, rs.fields[c], _to_raw(rs.fields[c], col, report))
    if e_new is not None and euler:
        for i, (c, col) in enumerate(zip(euler, e_new[done].T, strict=True)):
            _write(buf, starts, rs.fields[c], _to_raw(rs.fields[c], col, report, yaw=i == 2))
    full = np.zeros(rs.t_s.size, bool)
    full[idx[done]] = True
    _note(report, rs.name, rs.t_s, full)


def _apply_bias(buf: np.ndarray, rs: _RecordSet, groups: Sequence[tuple[Sequence[str], Sequence[Any], Any]],
                report: InjectionReport) -> None:  # fmt: skip
    """Per group (columns x, y, z; faults as (fault, bias, unit); an interval per record, s, or None):
    add ``k × bias × unit`` (× the interval: a delta angle or velocity) to the columns."""
    hit = np.zeros(rs.t_s.size, bool)
    for columns, faults, per_record_scale in groups:
        add = np.zeros((rs.t_s.size, 3))
        for f, bias, unit in faults:
            if any(bias):
                add += f.when.factors(rs.t_s)[:, None] * (np.asarray(bias, np.float64) * unit)[None, :]
        if per_record_scale is not None:
            add *= per_record_scale[:, None]
        rows = np.any(add != 0.0, axis=1)
        hit |= rows
        idx = np.flatnonzero(rows)
        if not idx.size:
            continue
        starts = rs.starts[idx]
        for a, c in enumerate(columns):
            if np.any(add[idx, a] != 0.0):
                fld = rs.fields[c]
                v = _read(buf, starts, fld).astype(np.float64) * fld.scale + add[idx, a]
                _write(buf, starts, fld, _to_raw(fld, v, report))
    _note(report, rs.name, rs.t_s, hit)


def _gyro_accel(faults: Iterable[ImuFault]) -> tuple[list[Any], list[Any]]:
    g = [(f, f.gyro_bias_deg_s, math.pi / 180.0) for f in faults]
    a = [(f, f.accel_bias_m_s2, 1.0) for f in faults]
    return g, a


# --------------------------------------------------------------------------- DataFlash


def _dataflash_sets(sc: Any, name: str) -> _RecordSet | None:
    from mavahrs.logs.dataflash import DTYPE_OF_FORMAT

    t = sc.types.get(name)
    if t is None:
        return None
    _, length, fmt, cols = sc.formats[t]
    if len(fmt) != len(cols):
        return None
    fields: dict[str, _Field] = {}
    off = 0
    for c, col in zip(fmt, cols, strict=True):
        spec = DTYPE_OF_FORMAT.get(c)
        if spec is None:
            return None
        dt = np.dtype(spec[0])
        fields[col] = _Field(off, dt, spec[1] if spec[1] is not None else 1.0)
        off += dt.itemsize
    if off != length - 3 or "TimeUS" not in fields:
        return None
    starts = sc.offsets[sc.ids == t].astype(np.int64) + 3
    tf = fields["TimeUS"]
    t_s = _read(sc.data, starts, tf).astype(np.float64) * 1e-6
    return _RecordSet(name, starts, fields, t_s)


def inject_dataflash(src: Path, dst: Path, faults: Sequence[AttitudeFault | ImuFault]) -> InjectionReport:
    """Copy the DataFlash log ``src`` to ``dst`` with ``faults`` rewritten in place (module docstring)."""
    from mavahrs.logs.dataflash import scan

    data = np.fromfile(src, np.uint8)
    sc = scan(data)
    if not sc.formats or not len(sc.offsets):
        raise DataError(f"{src}: no DataFlash records to copy")
    report = InjectionReport(records=int(len(sc.offsets)), format="dataflash")
    buf = data.copy()
    att = [f for f in faults if isinstance(f, AttitudeFault)]
    imu = [f for f in faults if isinstance(f, ImuFault)]
    if att:
        for name in DATAFLASH_ATTITUDE_RECORDS:
            rs = _dataflash_sets(sc, name)
            if rs is None:
                continue
            f = rs.fields
            quat = ("Q1", "Q2", "Q3", "Q4") if all(c in f for c in ("Q1", "Q2", "Q3", "Q4")) else None
            euler = ("Roll", "Pitch", "Yaw") if all(c in f for c in ("Roll", "Pitch", "Yaw")) else None
            if quat or euler:
                _apply_attitude(buf, rs, att, report, quat, euler)
    for name in DATAFLASH_IMU_RECORDS if imu else ():
        rs = _dataflash_sets(sc, name)
        if rs is None:
            continue
        inst = (_read(sc.data, rs.starts, rs.fields["I"]).astype(np.int64) if "I" in rs.fields
                else np.zeros(rs.t_s.size, np.int64))  # fmt: skip
        for n in sorted({imu_instance(f) for f in imu}):
            sel = inst == n
            mine = [f for f in imu if imu_instance(f) == n]
            part = _RecordSet(f"{name}[{n}]", rs.starts[sel], rs.fields, rs.t_s[sel])
            g, a = _gyro_accel(mine)
            groups = [(cols, faults_, None) for cols, faults_ in ((("GyrX", "GyrY", "GyrZ"), g), (("AccX", "AccY", "AccZ"), a))
                      if all(c in rs.fields for c in cols)]  # fmt: skip
            _apply_bias(buf, part, groups, report)
    _write_atomically(dst, buf)
    return report


# --------------------------------------------------------------------------- ULog

_ULOG_HEADER = 16
_ULOG_SIZES = {"int8_t": 1, "uint8_t": 1, "bool": 1, "char": 1, "int16_t": 2, "uint16_t": 2, "int32_t": 4,
               "uint32_t": 4, "int64_t": 8, "uint64_t": 8, "float": 4, "double": 8}  # fmt: skip
_ULOG_DTYPES = {"int8_t": "<i1", "uint8_t": "<u1", "bool": "<u1", "char": "<u1", "int16_t": "<i2", "uint16_t": "<u2",
                "int32_t": "<i4", "uint32_t": "<u4", "int64_t": "<i8", "uint64_t": "<u8", "float": "<f4",
                "double": "<f8"}  # fmt: skip
_ULOG_SYNC = bytes([0x2F, 0x73, 0x13, 0xA0, 0x25, 0x0C, 0xBB, 0x12])
_ULOG_TYPES = frozenset(b"BFIMPQADLCSOR")


def _ulog_format(text: str) -> tuple[str, list[tuple[str, int, str]]]:
    name, _, body = text.partition(":")
    out = []
    for part in body.split(";"):
        part = part.strip()
        if not part:
            continue
        typ, _, field = part.partition(" ")
        n = 0
        if "[" in typ:
            typ, _, rest = typ.partition("[")
            n = int(rest.rstrip("]"))
        out.append((typ, n, field.strip()))
    return name, out


def _ulog_fields(name: str, formats: dict[str, list[tuple[str, int, str]]], prefix: str = "",
                 out: dict[str, _Field] | None = None, start: int = 0) -> tuple[dict[str, _Field], int]:  # fmt: skip
    """Flattened fields (pyulog's names: ``q[0]``, ``a.b``) at their offsets from the payload start
    (after the 2-byte msg_id); padding counts."""
    fields: dict[str, _Field] = {} if out is None else out
    off = start
    for typ, n, field in formats[name]:
        count = max(n, 1)
        for i in range(count):
            nm = f"{prefix}{field}[{i}]" if n else f"{prefix}{field}"
            if typ in _ULOG_SIZES:
                fields[nm] = _Field(off, np.dtype(_ULOG_DTYPES[typ]))
                off += _ULOG_SIZES[typ]
            else:
                _, off = _ulog_fields(typ, formats, nm + ".", fields, off)
    return fields, off


def _ulog_walk(data: bytes, wanted: set[str]) -> tuple[dict[tuple[str, int], _RecordSet], int, int]:
    """The data records (``D``) of the ``wanted`` topics: (topic, multi_id) → record set (times not yet filled);
    the number of records walked; bytes skipped (a corrupted stretch, re-synchronised at the next sync record)."""
    n = len(data)
    pos = _ULOG_HEADER
    formats: dict[str, list[tuple[str, int, str]]] = {}
    subs: dict[int, tuple[str, int]] = {}
    where: dict[int, list[int]] = {}
    sizes: dict[int, list[int]] = {}
    done: list[tuple[tuple[str, int], list[int], list[int]]] = []
    records = 0
    skipped = 0
    head = struct.Struct("<HB").unpack_from
    msg_id_of = struct.Struct("<H").unpack_from
    while pos + 3 <= n:
        size, typ = head(data, pos)
        if typ not in _ULOG_TYPES or pos + 3 + size > n:
            if pos + 3 + size > n and typ in _ULOG_TYPES:
                break  # a record cut off by the end of the file: copied as it is
            nxt = data.find(_ULOG_SYNC, pos + 1)
            if nxt < 0:
                skipped += n - pos
                break
            skipped += nxt - 3 - pos if nxt - 3 > pos else 0
            pos = max(nxt - 3, pos + 1)
            continue
        body = pos + 3
        if typ == 0x44:  # 'D'
            mid = msg_id_of(data, body)[0]
            if mid in where:
                where[mid].append(body + 2)
                sizes[mid].append(size - 2)
        elif typ == 0x41:  # 'A'
            multi = data[body]
            mid = msg_id_of(data, body + 1)[0]
            name = data[body + 3 : body + size].split(b"\0", 1)[0].decode("ascii", "replace")
            if subs.get(mid) != (name, multi):  # a new subscription (or an id used again for another topic)
                if mid in where:
                    done.append((subs[mid], where.pop(mid), sizes.pop(mid)))
                subs[mid] = (name, multi)
                if name in wanted:
                    where[mid], sizes[mid] = [], []
        elif typ == 0x46:  # 'F'
            fname, fl = _ulog_format(data[body : body + size].decode("ascii", "replace"))
            formats[fname] = fl
        records += 1
        pos = body + size
    out: dict[tuple[str, int], _RecordSet] = {}
    for (name, multi), offs, lens in done + [(subs[mid], where[mid], sizes[mid]) for mid in where]:
        if name not in formats:
            continue
        try:
            fields, _length = _ulog_fields(name, formats)
        except (KeyError, ValueError):
            continue
        starts = np.asarray(offs, np.int64)
        sz = np.asarray(lens, np.int64)
        needed = max((f.offset + f.size for k, f in fields.items() if not k.startswith("_padding")), default=0)
        starts = starts[sz >= needed]  # a record too short for its format (corrupted): left alone
        key = (name, int(multi))
        if key in out:  # the same topic and instance subscribed again under a new id
            starts = np.concatenate([out[key].starts, starts])
        out[key] = _RecordSet(name if multi == 0 else f"{name}[{multi}]", starts, fields, np.zeros(0))
    return out, records, skipped


def _ulog_times(buf: np.ndarray, rs: _RecordSet, prefer_sample: bool) -> np.ndarray:
    t = _read(buf, rs.starts, rs.fields["timestamp"]).astype(np.int64)
    if prefer_sample and "timestamp_sample" in rs.fields:
        ts = _read(buf, rs.starts, rs.fields["timestamp_sample"]).astype(np.int64)
        t = np.where(ts > 0, ts, t)
    return t.astype(np.float64) * 1e-6


def _voted_instance(buf: np.ndarray, sets: dict[tuple[str, int], _RecordSet]) -> int:
    """The IMU instance sensor_combined carries: the vehicle_imu whose gyro_device_id sensor_selection names."""
    sel = sets.get(("sensor_selection", 0))
    if sel is None or not sel.starts.size or "gyro_device_id" not in sel.fields:
        return 0
    dev = int(_read(buf, sel.starts[:1], sel.fields["gyro_device_id"])[0])
    for (name, multi), rs in sets.items():
        if name == "vehicle_imu" and rs.starts.size and "gyro_device_id" in rs.fields:
            if int(_read(buf, rs.starts[:1], rs.fields["gyro_device_id"])[0]) == dev:
                return multi
    return 0


def inject_ulog(src: Path, dst: Path, faults: Sequence[AttitudeFault | ImuFault]) -> InjectionReport:
    """Copy the ULog ``src`` to ``dst`` with ``faults`` rewritten in place (module docstring)."""
    raw = src.read_bytes()
    att = [f for f in faults if isinstance(f, AttitudeFault)]
    imu = [f for f in faults if isinstance(f, ImuFault)]
    wanted = set(ULOG_ATTITUDE_TOPICS) if att else set()
    if imu:
        wanted |= {"vehicle_imu", "sensor_gyro", "sensor_accel", "sensor_combined", "sensor_selection"}
    sets, records, _skipped = _ulog_walk(raw, wanted)
    if records == 0:
        raise DataError(f"{src}: no ULog records to copy")
    buf = np.frombuffer(raw, np.uint8).copy()
    report = InjectionReport(records=records, format="ulog")
    q = ("q[0]", "q[1]", "q[2]", "q[3]")
    for (name, _multi), rs in sorted(sets.items()):
        if name in ULOG_ATTITUDE_TOPICS and all(c in rs.fields for c in q) and "timestamp" in rs.fields:
            rs.t_s = _ulog_times(buf, rs, prefer_sample=True)
            _apply_attitude(buf, rs, att, report, q, None)
    voted = _voted_instance(buf, sets) if imu else 0
    for n in sorted({imu_instance(f) for f in imu}):
        g, a = _gyro_accel([f for f in imu if imu_instance(f) == n])
        for (name, multi), rs in sorted(sets.items()):
            if "timestamp" not in rs.fields:
                continue
            if name == "vehicle_imu" and multi == n:
                rs.t_s = _ulog_times(buf, rs, prefer_sample=True)
                da = ("delta_angle[0]", "delta_angle[1]", "delta_angle[2]")
                dv = ("delta_velocity[0]", "delta_velocity[1]", "delta_velocity[2]")
                if all(c in rs.fields for c in da + dv + ("delta_angle_dt", "delta_velocity_dt")):
                    dta = _read(buf, rs.starts, rs.fields["delta_angle_dt"]).astype(np.float64) * 1e-6
                    dtv = _read(buf, rs.starts, rs.fields["delta_velocity_dt"]).astype(np.float64) * 1e-6
                    _apply_bias(buf, rs, [(da, g, dta), (dv, a, dtv)], report)
            elif name in ("sensor_gyro", "sensor_accel") and multi == n:
                rs.t_s = _ulog_times(buf, rs, prefer_sample=True)
                if all(c in rs.fields for c in ("x", "y", "z")):
                    _apply_bias(buf, rs, [(("x", "y", "z"), g if name == "sensor_gyro" else a, None)], report)
            elif name == "sensor_combined" and n == voted:
                rs.t_s = _ulog_times(buf, rs, prefer_sample=False)
                gc = ("gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]")
                ac = ("accelerometer_m_s2[0]", "accelerometer_m_s2[1]", "accelerometer_m_s2[2]")
                if all(c in rs.fields for c in gc + ac):
                    _apply_bias(buf, rs, [(gc, g, None), (ac, a, None)], report)
    _write_atomically(dst, buf)
    return report


# --------------------------------------------------------------------------- output


def _write_atomically(dst: Path, buf: np.ndarray) -> None:
    tmp = dst.with_name(f".{dst.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as out:
            out.write(memoryview(buf))
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)
