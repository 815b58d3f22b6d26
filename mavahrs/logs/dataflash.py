r"""ArduPilot DataFlash logs (``.BIN``) as filter inputs, read with numpy over the log's own FMT records.

A DataFlash log is a sequence of records ``A3 95 <type> <payload>``; the
log describes itself: a ``FMT`` record (type 128) gives each type's length,
name, field format characters and column names.  :func:`scan` walks the
records once (a compiled loop that learns each length from the FMT records as
it meets them, and resynchronises byte by byte on anything that is not a
record: a corrupted stretch costs the bytes it spans, not the rest of the
log); :func:`decode` then reads every record of one type at once with
``np.frombuffer``-style views through a structured dtype built from its FMT
(format characters as pymavlink's ``DFReader.FORMAT_TO_STRUCT`` maps them,
with its multipliers: ``c``/``C``/``e``/``E`` × 0.01, ``L`` × 1e-7).

Why not pymavlink's ``DFReader``: it is the reference for the format and
reads the same values (a test compares them), but it builds one Python object
per message; a replay needs ~200 000 IMU messages per ten minutes of a
400 Hz log, for every IMU.  ``scripts/bench_dataflash.py`` measures both on
the same file in the same run (the numpy reader, and replaying with it, against a
plain ``DFReader`` ``recv_match`` loop over the message types replay reads).

What :func:`read_dataflash` takes from the log (units from its FMTU records;
ArduPilot's body frame is FRD, its earth frame NED, angles in degrees, yaw
0–360 from true north):

* ``IMU`` (field ``I`` = instance): ``TimeUS`` the sample time on the
  autopilot's boot clock; ``GyrX/Y/Z`` rad/s and ``AccX/Y/Z`` m/s², already
  calibrated, board-rotated and low-pass filtered (``INS_GYRO_FILTER`` /
  ``INS_ACCEL_FILTER``), i.e. what the EKF gets and what RAW_IMU would send;
  ``T`` °C.  The instance fed is chosen by the pipeline's own IMU selector, its
  compiled step (:func:`~mavahrs.sensors.imu_select.select_step`) run over every
  instance's records in time order (``--imu`` fixes one).
* ``MAG`` (``I``, the compass instance; ``Health``): ``MagX/Y/Z`` mGauss
  (× 0.1 → µT), with offsets and motor compensation applied (as RAW_IMU's
  ``xmag``); put into the first IMU row at or after its time, NaN elsewhere.
* ``GPS`` (``Status`` ≥ 3 = 3D fix): ``Spd`` m/s ground speed, ``GCrs`` deg
  course over ground, ``VZ`` m/s down → NED velocity (true north, rotated
  into the filter's magnetic frame as the pipeline does), ``Lat/Lng/Alt`` for
  the magnetic model and, as NED metres from the first fix used (magnetic
  frame, :class:`~mavahrs.sensors.position.PositionOrigin`), the filter's
  ``IN_POS`` beside the velocity, and ``GWk/GMS`` for its date.  The record's ``TimeUS`` is
  when the autopilot got the fix; the receiver's own lag (``GPS_DELAY_MS`` /
  ``GPS1_DELAY_MS``, else the driver's) comes on top and is not added, as for
  GPS_RAW_INT's ``time_usec`` in a tlog.
* references: ``XKQ`` (EKF3's quaternion, body→NED, scalar first; an older
  firmware's ``XKF1`` Euler angles when there is no XKQ), core 0 as
  ``autopilot EKF3`` and each further core (one per IMU) as ``autopilot EKF3
  core N``, ``ATT`` (Roll/Pitch/Yaw deg) as ``autopilot ATT``,
  ``AHR2`` (DCM, quaternion) as ``autopilot DCM``; in SITL ``SIM``
  (the simulator's true attitude, quaternion Q1–Q4, about 25 Hz) as
  ``SIM truth``, and ``SIM2`` (true NED velocity at the loop rate) counted in
  ``found``.
* ``PARM``: every parameter (last value wins); ``SYSID_THISMAV`` is the
  system id of the frames replay would send; ``INS_GYRO_FILTER`` gives the
  IMU data's delay (below), ``SCHED_LOOP_RATE`` is checked against the fed
  rate (a note when the IMU was logged slower), ``COMPASS_DEC`` (rad) is the
  declination when no GPS fix gives the magnetic model a position.
* ``BAT`` (``Curr`` A, ``Volt`` V, first battery), ``VIBE`` (per IMU, m/s²,
  clip count) and the batch sampler's ``ISBH``/``ISBD`` headers go to
  :attr:`~mavahrs.logs.LogInputs.series` and the replay header; none feeds
  the filters (ISBD holds raw bursts, not a continuous stream).  With two or more live IMU instances every
  instance's gyro goes to the series ``imu_gyro``, for the second-opinion monitor to name the IMU that is off
  (:func:`mavahrs.fleet.audit.onboard_imu_gyros`), as a tlog's RAW_IMU / SCALED_IMU2 do.

A log cut off in the middle of a record is read up to its last whole record
and flagged (:attr:`~mavahrs.logs.LogInputs.truncated`); bytes that are not
records are skipped and counted.  An unknown message type is skipped by its
FMT length, so a newer firmware's log is read as far as its known types go.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import DataError, empty_window_error
from mavahrs.filters.jit import kernel
from mavahrs.ingest.arrays import select_over_arrays
from mavahrs.logs import LogInputs

__all__ = ["DataflashScan", "scan", "decode", "read_dataflash", "DTYPE_OF_FORMAT"]

Array = NDArray[np.float64]
_NAN = math.nan
_FMT_TYPE = 128
_FMT_LEN = 89  # 3-byte header + Type B, Length B, Name 4s, Format 16s, Columns 64s

#: DataFlash format character → (numpy dtype, multiplier or None): pymavlink's DFReader.FORMAT_TO_STRUCT
DTYPE_OF_FORMAT: dict[str, tuple[Any, float | None]] = {
    "a": (("<i2", (32,)), None), "b": ("<i1", None), "B": ("<u1", None), "g": ("<f2", None),
    "h": ("<i2", None), "H": ("<u2", None), "i": ("<i4", None), "I": ("<u4", None), "f": ("<f4", None),
    "n": ("S4", None), "N": ("S16", None), "Z": ("S64", None), "c": ("<i2", 0.01), "C": ("<u2", 0.01),
    "e": ("<i4", 0.01), "E": ("<u4", 0.01), "L": ("<i4", 1e-7), "d": ("<f8", None), "M": ("<u1", None),
    "q": ("<i8", None), "Q": ("<u8", None),
}  # fmt: skip


@kernel
def _walk(data, lengths, ids, offs, stats, fill):  # type: ignore[no-untyped-def]
    """Walk the records: ``A3 95 type``, each type's length from its FMT record (``lengths``, 0 = unknown).

    A record counts when it fits in the file and is followed by another
    header (or the end): anything else is skipped one byte at a time (a
    corrupted stretch).  ``stats``: records, bytes skipped, bytes of an
    incomplete last record, stretches skipped.  With ``fill`` the type and
    offset of each record go into ``ids``/``offs``.
    """
    n = data.shape[0]
    p = 0
    k = 0
    skipped = 0
    tail = 0
    stretches = 0
    in_bad = False
    while p + 3 <= n:
        ok = data[p] == 0xA3 and data[p + 1] == 0x95
        length = 0
        if ok:
            length = lengths[data[p + 2]]
            ok = length >= 3
        if ok and p + length > n:  # a record cut off by the end of the file
            tail = n - p
            break
        if ok:
            q = p + length
            ok = q + 2 > n or (data[q] == 0xA3 and data[q + 1] == 0x95)
        if not ok:
            if not in_bad:
                stretches += 1
                in_bad = True
            skipped += 1
            p += 1
            continue
        in_bad = False
        t = data[p + 2]
        if t == 128 and length >= 5:
            new_len = data[p + 4]
            if new_len >= 3:
                lengths[data[p + 3]] = new_len
        if fill:
            ids[k] = t
            offs[k] = p
        k += 1
        p += length
    if p + 3 > n and p < n and tail == 0:
        tail = n - p  # fewer than 3 bytes left: the start of a record
    stats[0] = k
    stats[1] = skipped
    stats[2] = tail
    stats[3] = stretches


@dataclass
class DataflashScan:
    """Where the records of a DataFlash log are.

    Attributes:
        data: the file's bytes.
        ids, offsets: per record, its type and its offset in ``data`` (file order).
        formats: type → (name, length, format characters, column names), from the FMT records.
        skipped_bytes: bytes that were not part of a record (corruption, padding).
        skipped_stretches: how many separate stretches of them.
        tail_bytes: bytes of an incomplete last record (the log was cut off), 0 when complete.
    """

    data: NDArray[np.uint8]
    ids: NDArray[np.uint8]
    offsets: NDArray[np.int64]
    formats: dict[int, tuple[str, int, str, tuple[str, ...]]]
    skipped_bytes: int
    skipped_stretches: int
    tail_bytes: int

    @property
    def types(self) -> dict[str, int]:
        """Message name → type id."""
        return {v[0]: k for k, v in self.formats.items()}

    def count(self, name: str) -> int:
        t = self.types.get(name)
        return 0 if t is None else int(np.count_nonzero(self.ids == t))


def _text(b: bytes) -> str:
    return b.split(b"\0", 1)[0].decode("ascii", "replace").strip()


def scan(data: NDArray[np.uint8] | bytes | str | Path) -> DataflashScan:
    """Locate every record of a DataFlash log (bytes, array or path)."""
    if isinstance(data, (str, Path)):
        arr = np.fromfile(data, np.uint8)
    elif isinstance(data, (bytes, bytearray, memoryview)):
        arr = np.frombuffer(data, np.uint8)
    else:
        arr = data
    arr = np.ascontiguousarray(arr, dtype=np.uint8)
    lengths = np.zeros(256, np.int64)
    lengths[_FMT_TYPE] = _FMT_LEN
    stats = np.zeros(4, np.int64)
    _walk(arr, lengths.copy(), np.zeros(1, np.uint8), np.zeros(1, np.int64), stats, False)
    k = int(stats[0])
    ids = np.zeros(k, np.uint8)
    offs = np.zeros(k, np.int64)
    _walk(arr, lengths, ids, offs, stats, True)
    formats: dict[int, tuple[str, int, str, tuple[str, ...]]] = {}
    for o in offs[ids == _FMT_TYPE].tolist():
        rec = arr[o + 3 : o + _FMT_LEN].tobytes()
        if len(rec) < _FMT_LEN - 3:
            continue
        t, length = rec[0], rec[1]
        name, fmt, cols = _text(rec[2:6]), _text(rec[6:22]), _text(rec[22:86])
        formats[t] = (name, int(length), fmt, tuple(c.strip() for c in cols.split(",")) if cols else ())
    return DataflashScan(arr, ids, offs, formats, int(stats[1]), int(stats[3]), int(stats[2]))


def _dtype(fmt: str, cols: Sequence[str]) -> tuple[np.dtype, dict[str, float]] | None:
    """The structured dtype of a FMT (None when a character is unknown or names and characters disagree)."""
    if len(fmt) != len(cols):
        return None
    fields = []
    mult: dict[str, float] = {}
    seen: set[str] = set()
    for c, name in zip(fmt, cols, strict=True):
        spec = DTYPE_OF_FORMAT.get(c)
        if spec is None or not name or name in seen:
            return None
        seen.add(name)
        fields.append((name, spec[0]))
        if spec[1] is not None:
            mult[name] = spec[1]
    return np.dtype(fields), mult


def decode(sc: DataflashScan, name: str) -> dict[str, np.ndarray] | None:
    """Every record of message ``name`` as columns (multipliers applied: float64), or None if absent.

    Returns None also when the log's FMT for it cannot be read (an unknown
    format character): the message is then skipped, as a newer firmware's
    unknown message is.
    """
    t = sc.types.get(name)
    if t is None:
        return None
    _, length, fmt, cols = sc.formats[t]
    got = _dtype(fmt, cols)
    if got is None or got[0].itemsize != length - 3:
        return None
    dt, mult = got
    offs = sc.offsets[sc.ids == t]
    raw = sc.data[(offs + 3)[:, None] + np.arange(length - 3)]
    rec = np.ascontiguousarray(raw).view(dt).reshape(-1)
    out: dict[str, np.ndarray] = {}
    for c in dt.names or ():
        v = rec[c]
        out[c] = v.astype(np.float64) * mult[c] if c in mult else v
    return out


# --------------------------------------------------------------------------- filter inputs


def _parameters(sc: DataflashScan) -> dict[str, float]:
    p = decode(sc, "PARM")
    if p is None:
        return {}
    names = [_text(bytes(x)) for x in p["Name"].tolist()]
    return {k: float(v) for k, v in zip(names, p["Value"].astype(np.float64).tolist(), strict=True)}


def _rate_hz(t_us: np.ndarray) -> float:
    if t_us.shape[0] < 2:
        return 0.0
    span = float(t_us[-1] - t_us[0])
    return (t_us.shape[0] - 1) / span * 1e6 if span > 0 else 0.0


def _gps_unix_s(week: np.ndarray, ms: np.ndarray) -> np.ndarray:
    """GPS week and ms of week → UNIX time, s (18 leap seconds since 1980, as since 2017)."""
    return 315964800.0 + week.astype(np.float64) * 604800.0 + ms.astype(np.float64) * 1e-3 - 18.0


def _select_imu(imu: dict[str, np.ndarray], settings: Any, sat: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Which IMU records feed the filter: the pipeline's IMU selector (its compiled step,
    :func:`~mavahrs.ingest.arrays.select_over_arrays`) over every instance's records in time order."""
    sel_s = settings.selection_settings
    inst = imu["I"].astype(np.int64)
    t = imu["TimeUS"].astype(np.int64)
    g = np.stack([imu["GyrX"], imu["GyrY"], imu["GyrZ"]], axis=1).astype(np.float64)
    a = np.stack([imu["AccX"], imu["AccY"], imu["AccZ"]], axis=1).astype(np.float64)
    zero = np.all(g == 0.0, axis=1) & np.all(a == 0.0, axis=1)
    live = sorted({int(i) for i in np.unique(inst[~zero]).tolist()})
    notes: list[str] = []
    for i in sorted(set(np.unique(inst).tolist()) - set(live)):
        notes.append(f"IMU instance {i} logs all-zero accelerometer and gyro (no such IMU): not used")
    fixed = sel_s.fixed
    if fixed is not None and fixed not in live:
        raise DataError(f"IMU instance {fixed} has no usable data (instances: {live or 'none'})")
    if not live:
        raise DataError("every IMU instance logs all-zero accelerometer and gyro")
    order = np.argsort(t, kind="stable")
    feed_sorted, _ = select_over_arrays(sel_s, np.zeros(t.shape[0], np.int64), inst[order], t[order], g[order],
                                        a[order], np.asarray(sat, np.bool_)[order])  # fmt: skip
    feed = np.zeros(t.shape[0], bool)
    feed[order] = feed_sorted
    fed = sorted(set(inst[feed].tolist()))
    if len(fed) > 1:
        notes.append(f"the IMU selector switched between instances {fed} during the log (fail-over)")
    return feed, notes


def _gps_lag_us(params: dict[str, float]) -> tuple[int, str]:
    """How much older than its record a GPS fix is, µs, and why: the autopilot's own ``GPS1_DELAY_MS``
    (``GPS_DELAY_MS`` before 4.6) when set, else in a simulator log the simulated lag (``SIM_GPS1_LAG_MS``,
    ``SIM_GPS_LAG_MS``), else 0 (the receiver's lag unknown: the record's time is taken)."""
    for k in ("GPS1_DELAY_MS", "GPS_DELAY_MS"):
        v = params.get(k)
        if v is not None and math.isfinite(v) and v > 0:
            return int(v * 1000), k
    for k in ("SIM_GPS1_LAG_MS", "SIM_GPS_LAG_MS"):
        v = params.get(k)
        if v is not None and math.isfinite(v) and v > 0:
            return int(v * 1000), f"{k} (the simulator's receiver lag)"
    return 0, "no GPS1_DELAY_MS set; the receiver's own lag is unknown"


#: the filters wait this long at most for the first compass sample, µs of log time
_MAG_WAIT_US = 2_000_000


def _mag_samples(mag: dict[str, np.ndarray] | None, params: dict[str, float]) -> tuple[Any, Any, int, Any] | None:
    """The primary compass's healthy samples: (TimeUS, (K, 3) µT, instance, every record's instance)."""
    if mag is None or mag["TimeUS"].shape[0] == 0:
        return None
    mi = mag["I"].astype(np.int64) if "I" in mag else np.zeros(mag["TimeUS"].shape[0], np.int64)
    m_insts = np.unique(mi).tolist()
    primary = int(params.get("COMPASS_PRIMARY", m_insts[0]))
    primary = primary if primary in m_insts else int(m_insts[0])
    ok = mi == primary
    if "Health" in mag:
        ok &= mag["Health"] != 0
    tm = mag["TimeUS"][ok].astype(np.int64)
    v = np.stack([mag["MagX"][ok], mag["MagY"][ok], mag["MagZ"][ok]], axis=1).astype(np.float64) * 0.1
    return tm, v, primary, mi


def _clean_reference(t: np.ndarray, q: np.ndarray) -> tuple[Array, Array] | None:
    good = np.isfinite(t) & np.all(np.isfinite(q), axis=1) & (np.linalg.norm(q, axis=1) > 0.5)
    if not good.any():
        return None
    t, q = t[good].astype(np.float64), q[good].astype(np.float64)
    order = np.argsort(t, kind="stable")
    t, q = t[order], q[order]
    again = np.zeros(t.shape[0], bool)
    again[1:] = t[1:] == t[:-1]
    t, q = t[~again], q[~again]
    return t, q / np.linalg.norm(q, axis=1, keepdims=True)


def _references(sc: DataflashScan, found: list[str]) -> dict[str, tuple[Array, Array]]:
    """The autopilot's attitudes and, in SITL, the simulator's, name → (TimeUS, q_body_to_ned)."""
    from mavahrs.geometry.rotation import from_euler_rad

    refs: dict[str, tuple[Array, Array]] = {}
    lines = []

    def quat(m: dict[str, np.ndarray]) -> np.ndarray:
        return np.stack([m["Q1"], m["Q2"], m["Q3"], m["Q4"]], axis=1).astype(np.float64)

    # EKF3, one core per IMU: core 0 is "autopilot EKF3", the others "autopilot EKF3 core N"; the quaternion
    # (XKQ) where logged, else the Euler angles of XKF1 (older firmware)
    xkq = decode(sc, "XKQ")
    xkf1 = decode(sc, "XKF1")
    for src, what in ((xkq, "XKQ"), (xkf1, "XKF1")):
        if src is None or src["TimeUS"].shape[0] == 0 or any(k.startswith("autopilot EKF3") for k in refs):
            continue
        cores = src["C"].astype(np.int64) if "C" in src else np.zeros(src["TimeUS"].shape[0], np.int64)
        for c in np.unique(cores).tolist():
            sel = cores == c
            if what == "XKQ":
                q = quat(src)[sel]
            else:
                q = from_euler_rad(*(np.radians(src[k][sel].astype(np.float64)) for k in ("Roll", "Pitch", "Yaw")))
            got = _clean_reference(src["TimeUS"][sel], q)
            if got is None:
                continue
            name = "autopilot EKF3" if c == 0 else f"autopilot EKF3 core {c}"
            refs[name] = got
            lines.append(f"{name} ({what} core {c}, {_rate_hz(got[0]):.0f} Hz)")
    att = decode(sc, "ATT")
    if att is not None and att["TimeUS"].shape[0]:
        r = np.radians(att["Roll"].astype(np.float64))
        p = np.radians(att["Pitch"].astype(np.float64))
        y = np.radians(att["Yaw"].astype(np.float64))
        got = _clean_reference(att["TimeUS"], from_euler_rad(r, p, y))
        if got is not None:
            refs["autopilot ATT"] = got
            lines.append(f"autopilot ATT ({_rate_hz(got[0]):.0f} Hz)")
    ahr2 = decode(sc, "AHR2")
    if ahr2 is not None and ahr2["TimeUS"].shape[0] and "Q1" in ahr2:
        got = _clean_reference(ahr2["TimeUS"], quat(ahr2))
        if got is not None:
            refs["autopilot DCM"] = got
            lines.append(f"autopilot DCM (AHR2, {_rate_hz(got[0]):.0f} Hz)")
    sim = decode(sc, "SIM")
    if sim is not None and sim["TimeUS"].shape[0]:
        if "Q1" in sim:
            q = quat(sim)
        else:
            q = from_euler_rad(*(np.radians(sim[k].astype(np.float64)) for k in ("Roll", "Pitch", "Yaw")))
        got = _clean_reference(sim["TimeUS"], q)
        if got is not None:
            refs["SIM truth"] = got
            lines.append(f"truth: SIM, the simulator's attitude ({_rate_hz(got[0]):.0f} Hz)")
    n2 = sc.count("SIM2")
    if n2:
        lines.append(f"SIM2 (the simulator's true velocity): {n2} records")
    if lines:
        found.append("references: " + "; ".join(lines))
    else:
        found.append("references: none (no XKQ, XKF1, ATT, AHR2 or SIM)")
    return refs


#: ISBH ``type``: the batch sampler's sensor (AP_InertialSensor::IMU_SENSOR_TYPE)
_ISB_SENSOR = {0: "accel", 1: "gyro"}


def _series(sc: DataflashScan, found: list[str]) -> dict[str, dict[str, np.ndarray]]:
    """Battery (BAT), vibration (VIBE) and the batch sampler's headers (ISBH/ISBD), for the header and callers.

    None of them feeds the filters: the battery current is there for a magnetometer's current compensation
    (ArduPilot's ``COMPASS_MOT*``), VIBE is the autopilot's own vibration figure (beside the one computed
    from the fed IMU samples), and the batch sampler logs raw bursts (``INS_LOG_BAT_*``), not a continuous
    stream.
    """
    out: dict[str, dict[str, np.ndarray]] = {}
    bat = decode(sc, "BAT")
    if bat is not None and bat["TimeUS"].shape[0]:
        inst = bat["Inst"] if "Inst" in bat else bat.get("I", np.zeros(bat["TimeUS"].shape[0], np.uint8))
        first = inst == np.min(inst)
        cur = bat["Curr"][first].astype(np.float64) if "Curr" in bat else np.full(int(first.sum()), _NAN)
        volt = bat["Volt"][first].astype(np.float64) if "Volt" in bat else np.full(int(first.sum()), _NAN)
        out["battery"] = {"t_us": bat["TimeUS"][first].astype(np.int64), "current_a": cur, "voltage_v": volt}
        ok = np.isfinite(cur)
        span = f"current {np.min(cur[ok]):.1f}–{np.max(cur[ok]):.1f} A (mean {np.mean(cur[ok]):.1f})" if ok.any() else "no current"
        found.append(f"BAT: {_rate_hz(out['battery']['t_us']):.0f} Hz, {span}, "
                     f"{np.nanmin(volt):.1f}–{np.nanmax(volt):.1f} V (battery {int(np.min(inst))})")  # fmt: skip
    vibe = decode(sc, "VIBE")
    if vibe is not None and vibe["TimeUS"].shape[0]:
        imu_col = vibe["IMU"] if "IMU" in vibe else np.zeros(vibe["TimeUS"].shape[0], np.uint8)
        clip = vibe["Clip"] if "Clip" in vibe else vibe.get("Clip0", np.zeros(vibe["TimeUS"].shape[0]))
        out["vibration"] = {"t_us": vibe["TimeUS"].astype(np.int64), "imu": imu_col.astype(np.int64),
                            "x_m_s2": vibe["VibeX"].astype(np.float64), "y_m_s2": vibe["VibeY"].astype(np.float64),
                            "z_m_s2": vibe["VibeZ"].astype(np.float64), "clips": clip.astype(np.int64)}  # fmt: skip
        parts = []
        for i in np.unique(imu_col).tolist():
            sel = imu_col == i
            peak = max(float(np.max(vibe[k][sel])) for k in ("VibeX", "VibeY", "VibeZ"))
            parts.append(f"IMU {int(i)} peak {peak:.1f} m/s², {int(np.max(clip[sel]))} clips")
        found.append(f"VIBE: {'; '.join(parts)}")
    isbh = decode(sc, "ISBH")
    if isbh is not None and isbh["TimeUS"].shape[0]:
        out["batch_sampler"] = {"t_us": isbh["TimeUS"].astype(np.int64), "sensor": isbh["type"].astype(np.int64),
                                "instance": isbh["instance"].astype(np.int64),
                                "rate_hz": isbh["smp_rate"].astype(np.float64),
                                "samples": isbh["smp_cnt"].astype(np.int64)}  # fmt: skip
        kinds = sorted({(_ISB_SENSOR.get(int(k), str(int(k))), int(i), float(r)) for k, i, r in
                        zip(isbh["type"], isbh["instance"], isbh["smp_rate"], strict=True)})  # fmt: skip
        found.append(f"batch sampler (ISBH/ISBD): {isbh['TimeUS'].shape[0]} bursts, {sc.count('ISBD')} data records ("
                     + ", ".join(f"{k} {i} at {r:.0f} Hz" for k, i, r in kinds)
                     + "): raw bursts, not fed to the filters")  # fmt: skip
    arm = decode(sc, "ARM")
    state = _flight_state(arm, decode(sc, "EV"))
    out.update(state)
    said = [f"armed from {'ARM' if arm is not None else 'EV'}"] if "armed" in state else []
    said += ["landed from EV"] if "landed" in state else []
    if said:
        found.append(f"flight phase: {', '.join(said)}")
    return out


#: ArduPilot's LogEvent ids (AP_Logger/LogStructure.h): armed, disarmed, landed, no longer landed
_EV_ARMED, _EV_DISARMED, _EV_LAND_COMPLETE, _EV_NOT_LANDED = 10, 11, 18, 28
_MAV_MODE_FLAG_SAFETY_ARMED = 128
_LANDED_STATE_ON_GROUND, _LANDED_STATE_IN_AIR = 1, 2  # MAV_LANDED_STATE


def _flight_state(arm: dict[str, np.ndarray] | None, ev: dict[str, np.ndarray] | None) -> dict[str, dict[str, np.ndarray]]:
    """The flight's phase as the autopilot logged it, as the MAVLink fields the second-opinion monitor reads.

    ``armed``: ``t_us``, ``base_mode`` (HEARTBEAT's ``MAV_MODE_FLAG_SAFETY_ARMED``: 128 armed, 0 not), from the
    ARM records (``ArmState``), else the EV events ARMED / DISARMED.  ``landed``: ``t_us``, ``landed_state``
    (EXTENDED_SYS_STATE's: 1 on the ground, 2 in the air) from the EV events LAND_COMPLETE / NOT_LANDED.
    Each starts at time 0 with the state before its first change (a first "armed" means it was disarmed
    before; a first "landed", that it was flying): the log says nothing until then.
    """
    out: dict[str, dict[str, np.ndarray]] = {}

    def with_start(t: np.ndarray, v: np.ndarray, before: int) -> dict[str, np.ndarray]:
        return {"t_us": np.concatenate([[0], t]).astype(np.int64), "v": np.concatenate([[before], v]).astype(np.int64)}

    ids = ev["Id"].astype(np.int64) if ev is not None and "Id" in ev else np.zeros(0, np.int64)
    t_ev = ev["TimeUS"].astype(np.int64) if ev is not None else np.zeros(0, np.int64)
    if arm is not None and "ArmState" in arm and arm["TimeUS"].shape[0]:
        t, armed = arm["TimeUS"].astype(np.int64), arm["ArmState"].astype(np.int64) != 0
    else:
        sel = (ids == _EV_ARMED) | (ids == _EV_DISARMED)
        t, armed = t_ev[sel], ids[sel] == _EV_ARMED
    if t.shape[0]:
        mode = np.where(armed, _MAV_MODE_FLAG_SAFETY_ARMED, 0)
        d = with_start(t, mode, 0 if armed[0] else _MAV_MODE_FLAG_SAFETY_ARMED)
        out["armed"] = {"t_us": d["t_us"], "base_mode": d["v"]}
    sel = (ids == _EV_LAND_COMPLETE) | (ids == _EV_NOT_LANDED)
    if np.any(sel):
        landed = ids[sel] == _EV_LAND_COMPLETE
        st = np.where(landed, _LANDED_STATE_ON_GROUND, _LANDED_STATE_IN_AIR)
        d = with_start(t_ev[sel], st, _LANDED_STATE_IN_AIR if landed[0] else _LANDED_STATE_ON_GROUND)
        out["landed"] = {"t_us": d["t_us"], "landed_state": d["v"]}
    return out


def read_dataflash(
    path: str | Path, settings: Any = None, *, start_s: float | None = None, end_s: float | None = None
) -> LogInputs:
    """A DataFlash log's filter inputs, references and parameters (see the module docstring).

    Args:
        settings: the pipeline's settings (``PipelineSettings``; defaults if None): IMU
            selection, timeline, calibration, magnetic model, velocity source.
        start_s, end_s: use only IMU samples in this window, seconds from the log's first
            time-stamped record.

    Raises:
        DataError: not a DataFlash log, no IMU records, nothing usable.
    """
    from mavahrs.filters.layout import IN_DT, IN_MAG, IN_POS, IN_VEL, IN_VEL_AGE
    from mavahrs.ingest.arrays import PreparedInputs, _velocity_setting, onboard_timeline, si_rows
    from mavahrs.sensors.calibration import Calibrator
    from mavahrs.sensors.geomag import DeclinationSource, decimal_year_from_unix_s, rotate_true_to_magnetic
    from mavahrs.sensors.position import PositionOrigin
    from mavahrs.sensors.profiles import get_profile
    from mavahrs.sensors.velocity import fix_age_s
    from mavahrs.service.pipeline import PipelineSettings

    p = Path(path)
    s = settings if settings is not None else PipelineSettings()
    data = np.fromfile(p, np.uint8)
    if data.size == 0:
        raise DataError(f"{p}: empty file")
    sc = scan(data)
    if not sc.formats:
        raise DataError(f"{p}: no DataFlash FMT records: not an ArduPilot DataFlash log, or corrupted from its start")
    found: list[str] = []
    notes: list[str] = []
    truncated = sc.tail_bytes > 0
    if truncated:
        notes.append(f"truncated: the log ends inside a record ({sc.tail_bytes} bytes of it); read up to the "
                     "last whole record")  # fmt: skip
    if sc.skipped_bytes:
        notes.append(f"{sc.skipped_bytes} bytes in {sc.skipped_stretches} stretches are not DataFlash records "
                     "(corrupted or padding): skipped")  # fmt: skip
    imu = decode(sc, "IMU")
    if imu is None or imu["TimeUS"].shape[0] == 0:
        what = "no IMU records" if "IMU" not in sc.types else "IMU records unreadable"
        raise DataError(f"{p}: {what} (LOG_BITMASK must include IMU); {len(sc.offsets)} records of "
                        f"{len(sc.formats)} types read")  # fmt: skip
    if "I" not in imu:
        imu["I"] = np.zeros(imu["TimeUS"].shape[0], np.uint8)
    # a corrupted time stamp: one record whose TimeUS jumps away from both neighbours (file order) by > 1 s
    tt = imu["TimeUS"].astype(np.int64)
    if tt.size > 2:
        spike = np.zeros(tt.size, bool)
        dp, dn = tt[1:-1] - tt[:-2], tt[2:] - tt[1:-1]
        spike[1:-1] = ((dp > 1_000_000) & (dn < -1_000_000)) | ((dp < -1_000_000) & (dn > 1_000_000))
        if spike.any():
            imu = {k: v[~spike] for k, v in imu.items()}
            notes.append(f"{int(spike.sum())} IMU records with a corrupted TimeUS (away from both neighbours "
                         "by more than 1 s): dropped")  # fmt: skip
    params = _parameters(sc)
    profile = get_profile("ardupilot")
    ms = profile.scale_for("RAW_IMU")
    t_all = imu["TimeUS"].astype(np.int64)
    # the log's start: its first time-stamped record (FMT records carry no time)
    firsts = [int(t_all.min())]
    for name in ("PARM", "GPS", "ATT", "MAG", "BARO"):
        t = sc.types.get(name)
        if t is not None and np.any(sc.ids == t):
            o = int(sc.offsets[sc.ids == t][0])
            firsts.append(int(np.frombuffer(sc.data[o + 3 : o + 11].tobytes(), "<u8")[0]))
    t0 = min(firsts)
    insts = np.unique(imu["I"]).tolist()
    rates = ", ".join(f"{int(i)} ({_rate_hz(t_all[imu['I'] == i]):.0f} Hz)" for i in insts)
    # --- the scaling and row steps as for RAW_IMU (the ardupilot profile's full scales; values already SI)
    g_all = np.stack([imu["GyrX"], imu["GyrY"], imu["GyrZ"]], axis=1).astype(np.float64)
    a_all = np.stack([imu["AccX"], imu["AccY"], imu["AccZ"]], axis=1).astype(np.float64)
    rows_all, sat_all, _inv = si_rows(g_all, a_all, ms, s.scaling)
    sat = sat_all != 0
    lo = -(2**62) if start_s is None else t0 + int(start_s * 1e6)
    hi = 2**62 if end_s is None else t0 + int(end_s * 1e6)
    window = (t_all >= lo) & (t_all <= hi)
    if not window.any():
        raise empty_window_error(p, start_s, end_s, (int(t_all.min()) - t0) * 1e-6, (int(t_all.max()) - t0) * 1e-6)
    sub = {k: v[window] for k, v in imu.items()}
    feed, sel_notes = _select_imu(sub, s, sat[window])
    notes += sel_notes
    idx = np.flatnonzero(feed)
    if np.unique(sub["I"][idx]).size > 1:
        # a fail-over: the instances' records in time order (the timeline runs over them as one stream); one
        # instance's records stay in the log's order, and the timeline step judges their stamps as it judges
        # a link's (a record behind the last one used, or a lone one far ahead, is dropped)
        idx = idx[np.argsort(sub["TimeUS"][idx], kind="stable")]
    t_us = sub["TimeUS"][idx].astype(np.int64)
    gyro, accel = g_all[window][idx], a_all[window][idx]
    finite = np.all(np.isfinite(gyro), axis=1) & np.all(np.isfinite(accel), axis=1)
    if not finite.all():  # not samples (a damaged record): not timed either
        idx, t_us, gyro, accel = idx[finite], t_us[finite], gyro[finite], accel[finite]
    keep, dt = onboard_timeline(p, t_us, gyro, accel, s.timeline)
    idx, t_us, gyro, accel, dt = idx[keep], t_us[keep], gyro[keep], accel[keep], dt[keep]
    mag = decode(sc, "MAG")
    mag_sel = _mag_samples(mag, params)
    if mag_sel is not None and mag_sel[0].size and t_us.size and mag_sel[0][0] > t_us[0]:
        # a tlog's RAW_IMU carries the compass in every message; here it arrives on its own, 10–100 ms after
        # the first IMU records: the filters start with it (an initialisation without it would take the
        # heading as 0 and spend the first seconds converging from there)
        first = int(np.searchsorted(t_us, mag_sel[0][0], side="left"))
        if first < t_us.size and t_us[first] - t_us[0] <= _MAG_WAIT_US:
            idx, t_us, gyro, accel, dt = idx[first:], t_us[first:], gyro[first:], accel[first:], dt[first:]
    if t_us.size == 0:
        raise DataError(f"{p}: no IMU sample would reach the filter")
    dt[0] = _NAN  # the first sample fed initialises the filters
    m = t_us.shape[0]
    chosen = int(np.bincount(sub["I"][idx].astype(np.int64)).argmax())
    loop = params.get("SCHED_LOOP_RATE")
    fed_hz = _rate_hz(t_us)
    if loop is not None and math.isfinite(loop) and loop > 0 and fed_hz < 0.95 * loop:
        notes.append(f"IMU logged at {fed_hz:.0f} Hz, below the loop rate (SCHED_LOOP_RATE {loop:g}): the log "
                     "holds every IMU sample only with LOG_BITMASK's IMU_FAST bit")  # fmt: skip
    known = [f"{k} {params[k]:g}{unit}" for k, unit in (("INS_GYRO_FILTER", " Hz"), ("SCHED_LOOP_RATE", ""))
             if k in params]  # fmt: skip
    found.append(f"IMU: instances {rates}; fed: instance {chosen}, {_rate_hz(t_us):.0f} Hz "
                 f"({', '.join(known) or 'no INS_GYRO_FILTER or SCHED_LOOP_RATE in the log'})")  # fmt: skip
    rows = rows_all[np.flatnonzero(window)[idx]]  # gyro, accelerometer, flagged vectors blanked (si_rows)
    rows[:, IN_DT] = dt
    temp = sub["T"][idx].astype(np.float64) if "T" in sub else np.full(m, _NAN)
    # --- compass: the primary instance's healthy samples into the next fed row
    if mag is not None and mag_sel is not None:
        tm, v, primary, mi = mag_sel
        m_insts = np.unique(mi).tolist()
        j = np.searchsorted(t_us, tm, side="left")
        inside = (j < m) & (tm >= t_us[0])
        rows[j[inside], IN_MAG : IN_MAG + 3] = v[inside]  # later samples before the same row overwrite
        m_rates = ", ".join(f"{i} ({_rate_hz(mag['TimeUS'][mi == i]):.0f} Hz)" for i in m_insts)
        found.append(f"MAG: instances {m_rates}; used: {primary} (mGauss × 0.1 → µT)")
    else:
        found.append("MAG: none (the filters run without a magnetometer)")
    # --- GNSS: the magnetic model's position and date, the velocity
    gps = decode(sc, "GPS")
    decimal_year = None
    gps_ok = np.zeros(0, bool)
    if gps is not None and gps["TimeUS"].shape[0]:
        if "I" in gps:
            g0 = gps["I"] == 0
            gps = {k: v[g0] for k, v in gps.items()}
        gps_ok = gps["Status"] >= 3
        dated = gps_ok & (gps.get("GWk", np.zeros(gps_ok.shape)) > 0)
        if dated.any():
            k = int(np.flatnonzero(dated)[0])
            decimal_year = float(decimal_year_from_unix_s(float(_gps_unix_s(gps["GWk"][k : k + 1],
                                                                             gps["GMS"][k : k + 1])[0])))  # fmt: skip
    decl = DeclinationSource(s.magnetic, decimal_year=decimal_year)
    decl_at = np.full(m, decl.declination_rad)
    mag_events: list[tuple[int, float, float]] = []
    ref0 = decl.mag_reference()
    if ref0 is not None:
        mag_events.append((0, float(ref0[0]), float(ref0[1])))
    vsrc = str(s.effective_velocity_source)
    use_vel = vsrc != "none"
    fixes = 0
    lag_us, lag_why = _gps_lag_us(params)
    if gps is not None and gps_ok.any():
        tg = gps["TimeUS"].astype(np.int64)
        last_stamp = None
        origin = PositionOrigin()
        steps: list[tuple[int, float]] = []
        for k in np.flatnonzero(gps_ok).tolist():
            i = int(np.searchsorted(t_us, tg[k], side="left"))
            changed = decl.set_position(float(gps["Lat"][k]), float(gps["Lng"][k]), float(gps["Alt"][k]), "GPS")
            if changed:
                ref = decl.mag_reference()
                if ref is not None:
                    mag_events.append((min(i, m), float(ref[0]), float(ref[1])))
                steps.append((i, decl.declination_rad))
            stamp = int(gps["GMS"][k]) if "GMS" in gps else int(tg[k])
            if not use_vel or i >= m or stamp == last_stamp:
                continue
            last_stamp = stamp
            spd, crs = float(gps["Spd"][k]), math.radians(float(gps["GCrs"][k]))
            vn, ve = spd * math.cos(crs), spd * math.sin(crs)
            f = decl.field
            if f is not None:
                vn, ve = rotate_true_to_magnetic(vn, ve, f.declination_rad)
            rows[i, IN_VEL : IN_VEL + 3] = (vn, ve, float(gps["VZ"][k]) if "VZ" in gps else _NAN)
            rows[i, IN_VEL_AGE] = fix_age_s(int(t_us[i]), int(tg[k]) - lag_us)
            # the same fix's position, NED m from the first fix used (magnetic frame, as the velocity)
            rows[i, IN_POS : IN_POS + 3] = origin.ned(float(gps["Lat"][k]), float(gps["Lng"][k]), float(gps["Alt"][k]),
                                                      f.declination_rad if f is not None else None)
            fixes += 1
        for j, (i, d) in enumerate(steps):
            decl_at[i : steps[j + 1][0] if j + 1 < len(steps) else m] = d
        found.append(f"GPS: {int(gps_ok.sum())} 3D fixes at {_rate_hz(tg[gps_ok]):.0f} Hz, "
                     + (f"{fixes} velocities fed (Spd/GCrs/VZ; the fix taken as {lag_us / 1000:g} ms older than "
                        f"its record: {lag_why}), with their position (Lat/Lng/Alt from the first fix)"
                        if use_vel else "velocity not used (velocity_source none)"))  # fmt: skip
    else:
        found.append("GPS: no 3D fix (no declination from the magnetic model unless configured; no velocity)")
    # no position for the magnetic model and no declination configured: the autopilot's own COMPASS_DEC
    # (radians, positive east; what it used itself, learnt or set), rather than none
    mag_s = s.magnetic
    cdec = params.get("COMPASS_DEC")
    if (decl.field is None and mag_s.true_north and mag_s.declination_deg is None and cdec is not None
            and math.isfinite(cdec) and cdec != 0.0 and abs(cdec) <= math.pi):  # fmt: skip
        decl_at[:] = cdec
        found.append(f"declination: COMPASS_DEC {math.degrees(cdec):.2f}° (no GPS fix for the magnetic model)")
    # --- calibration as the pipeline applies it (the logged values are the autopilot's calibrated ones)
    cal = Calibrator(s.calibration, mag_already_calibrated=ms.mag_calibrated)
    if cal.active:
        cal.apply_rows(rows, temp)
    n_par = len(params)
    if n_par:
        shown = [f"{k} {params[k]:g}" for k in ("INS_GYRO_FILTER", "INS_ACCEL_FILTER", "SCHED_LOOP_RATE",
                                                "COMPASS_DEC", "AHRS_EKF_TYPE") if k in params]  # fmt: skip
        found.append(f"parameters: {n_par} ({', '.join(shown)})")
    refs = _references(sc, found)
    series = _series(sc, found)
    live = [i for i in np.unique(sub["I"]).tolist()
            if not np.all((sub["GyrX"][sub["I"] == i] == 0) & (sub["GyrY"][sub["I"] == i] == 0))]  # fmt: skip
    if len(live) > 1:  # every IMU's gyro, for the monitor to name the one that is off (as a tlog's IMU messages)
        keep = np.isin(sub["I"], live)
        series["imu_gyro"] = {"t_us": sub["TimeUS"][keep].astype(np.int64), "instance": sub["I"][keep].astype(np.int64),
                              "gyro_rad_s": g_all[window][keep]}  # fmt: skip
    found.append(f"read with numpy over the log's FMT records: {len(sc.offsets)} records of {len(sc.formats)} types")
    sysid = int(params.get("SYSID_THISMAV", 1)) or 1
    # the logged IMU values trail TimeUS by the group delay of the autopilot's low-pass (second order):
    # √2 / (2π · INS_GYRO_FILTER), as the ardupilot profile takes it for RAW_IMU at the default 20 Hz
    fc = params.get("INS_GYRO_FILTER", 20.0)
    delay_s = math.sqrt(2.0) / (2.0 * math.pi * fc) if fc and math.isfinite(fc) and fc > 0 else 0.0
    counts = {"imu_messages": int(t_all.shape[0]), "fed": m, "dropped_timeline": int((~keep).sum() + (~finite).sum()),
              "exact_duplicates": 0, "same_stamp_changed": 0}  # fmt: skip
    prep = PreparedInputs(
        rows=rows, t_us=t_us, frame_pos=idx.astype(np.int64), tlog_us=t_us.copy(), temperature_c=temp,
        declination_rad=decl_at, message="IMU", instance=chosen, source=(sysid, 1), profile="ardupilot",
        engine="fast", notes=notes, counts=counts, mag_reference_events=mag_events, sensor_delay_s=delay_s,
        vehicle_stream=True, multirotor=_is_multicopter(sc, params),
        velocity_source=_velocity_setting(s), velocity_fixes={"GPS": fixes} if use_vel else {},
    )  # fmt: skip
    return LogInputs(path=str(p), format="dataflash", inputs=prep, references=refs, found=found,
                     parameters=params, truncated=truncated, start_us=t0, series=series)  # fmt: skip


#: ArduCopter's FRAME_CLASS values of helicopters (single, dual, quad-heli): no rotor-drag model
_HELI_FRAME_CLASSES = frozenset((6, 11, 13))


def _is_multicopter(sc: DataflashScan, params: dict[str, float]) -> bool:
    """An ArduCopter log (its MSG firmware line) of a multirotor frame, not a helicopter."""
    msg = decode(sc, "MSG")
    if not msg or "Message" not in msg:
        return False
    copter = any(bytes(m).split(b"\0", 1)[0].startswith(b"ArduCopter") for m in msg["Message"][:50])
    return copter and int(params.get("FRAME_CLASS", 1)) not in _HELI_FRAME_CLASSES
