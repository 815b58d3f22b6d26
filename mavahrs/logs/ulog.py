r"""PX4 ULog (``.ulg``) as filter inputs, through pyulog.

:func:`read_ulog` reads only the topics it needs (pyulog's
``message_name_filter_list``) and builds the filter's input rows
(:class:`~mavahrs.ingest.arrays.PreparedInputs`, layout of
:mod:`mavahrs.filters.layout`) on the log's own clock: ``t_us`` is the ULog
``timestamp`` of the IMU topic (µs since PX4 booted).

IMU, in this order of preference:

* ``vehicle_imu`` (one instance per IMU): ``delta_angle`` and ``delta_velocity``
  are the integrals over ``delta_angle_dt`` / ``delta_velocity_dt`` (µs);
  divided by them they give the *mean* angular rate and the mean specific force
  over the interval, which is what the filter integrates (a snapshot would
  alias the vibration).  Used when it is logged at the loop rate (at least
  :data:`VEHICLE_IMU_MIN_SHARE` of ``sensor_combined``'s rate): PX4's default
  logger profile keeps it at 2 Hz, useless for attitude.
* ``sensor_combined`` (the voted primary IMU): PX4's ``VotedSensorsUpdate``
  fills ``gyro_rad`` and ``accelerometer_m_s2`` from ``vehicle_imu`` as
  ``delta_angle / delta_angle_dt`` and ``delta_velocity / delta_velocity_dt`` —
  the same interval means — at the gyro sample's time (``timestamp``); the
  accelerometer's own time is ``timestamp + accelerometer_timestamp_relative``.

Both are in the board's FRD frame (the sensor rotation and ``SENS_BOARD_ROT`` /
``SENS_BOARD_*_OFF`` applied), and corrected with the *static* calibration
(``CAL_GYRO*``/``CAL_ACC*`` offsets and scales, thermal calibration when enabled).
They are **not** corrected with EKF2's in-flight bias estimates (unlike the
MAVLink ``HIGHRES_IMU`` stream, which subtracts them): the gyro bias seen here
is what the filter's own bias estimate has to find, as on the live path.
Clipped samples (``accelerometer_clipping`` / ``delta_velocity_clipping``) blank
the accelerometer of that row, as a saturated accelerometer does on the MAVLink path.

Magnetometer: ``vehicle_magnetometer.magnetometer_ga`` (calibrated, board FRD;
gauss × 100 = µT) at its ``timestamp_sample``, into the first IMU row at or
after it; in logs older than ``vehicle_magnetometer`` (PX4 ≤ 1.10) the
``magnetometer_ga`` of ``sensor_combined`` (a new sample when
``timestamp + magnetometer_timestamp_relative`` changes).  ``sensor_mag`` is not
used: it is the raw field in the chip's own axes, before calibration and before
the rotation into the board frame.

GNSS velocity, as the ``velocity_source`` setting means it on the MAVLink path (PX4 fills
GLOBAL_POSITION_INT's velocity from ``vehicle_local_position`` and GPS_RAW_INT from
``vehicle_gps_position``): ``auto`` follows the ``px4`` profile's ``velocity_order``, as the daemon's
selector does on a PX4 link: the receiver first, EKF2's velocity only in a log without one (EKF2's
velocity carries EKF2's own errors: on the shared SIH flight ``best`` measured 1.26° heading / 0.99°
inclination with it, 0.69 / 0.75 with the receiver's; docs/accuracy.md, "round five");
``global_position_int`` = EKF2's ``vehicle_local_position`` ``vx/vy/vz`` (valid and GNSS-referenced:
``v_xy_valid``, ``xy_global``), taken at ``gnss_rate_hz`` (the rate the daemon asks for; the log has
it at the estimator's 100+ Hz), else the receiver; ``gps_raw_int`` and ``gps2_raw`` = the receiver,
``vehicle_gps_position`` (else ``sensor_gps``): ``vel_n/e/d_m_s`` of fixes with ``fix_type`` ≥ 3 and
``vel_ned_valid``; ``none`` = no velocity.  Each fix goes into the first IMU
row at or after the message's ``timestamp`` (when the pipeline would have it), rotated from true
into magnetic NED, aged from its ``timestamp_sample``.

Declination (applied to the outputs, as on the tlog path): the World Magnetic
Model (:class:`~mavahrs.sensors.geomag.DeclinationSource`, the pipeline's own) at
the first GNSS fix, from that sample on, dated by the receiver's UTC time
(today's date when the log has none); without a fix the log's ``EKF2_MAG_DECL``
(PX4's own, degrees); the settings' manual values override both.

References (``LogInputs.references``): ``"EKF2"`` = ``vehicle_attitude.q``
(PX4: rotation from FRD body to NED earth, Hamilton, w first — the project's
``q_body_to_ned``), ``"SIH truth"`` = ``vehicle_attitude_groundtruth`` (the
simulator's state; named ``"groundtruth truth"`` when the log is not from SIH),
each at its ``timestamp_sample`` (the IMU sample it describes) where logged.

The other :class:`~mavahrs.ingest.arrays.PreparedInputs` fields: ``frame_pos`` is the
sample's index, ``tlog_us`` = ``t_us`` (a ULog has one clock), ``temperature_c`` the gyro's from
``vehicle_imu_status`` (about 1 Hz, held; NaN before it or without it), ``source`` the ids in
``vehicle_status`` (else PX4's 1/1), ``engine`` ``fast`` (built over arrays, filtered in blocks).

Bad input raises :class:`~mavahrs.errors.DataError` naming what is wrong: an
empty or non-ULog file, a header or definitions cut short, no IMU topic (the
topics found are listed).  A log cut short in its data section (power lost
in flight) or with corrupted records is read as far as pyulog can, and says so
in ``found``; topics and fields this reader does not know are ignored.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import io
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import DataError, empty_window_error
from mavahrs.filters.layout import IN_DT, IN_MAG, IN_POS, IN_VEL, IN_VEL_AGE
from mavahrs.ingest.arrays import select_over_arrays
from mavahrs.logs import LogInputs
from mavahrs.sensors.profiles import MULTIROTOR_MAV_TYPES, get_profile

__all__ = ["read_ulog", "TOPICS", "VEHICLE_IMU_MIN_SHARE", "GAUSS_TO_UT"]

Array = NDArray[np.float64]

#: the only topics read (pyulog skips every other data record)
TOPICS = (
    "vehicle_imu",
    "sensor_combined",
    "vehicle_imu_status",
    "vehicle_magnetometer",
    "vehicle_gps_position",
    "sensor_gps",
    "vehicle_attitude",
    "vehicle_attitude_groundtruth",
    "vehicle_local_position",
    "vehicle_status",
    "vehicle_land_detected",
)
#: vehicle_imu is used when logged at ≥ this share of sensor_combined's rate (else sensor_combined)
VEHICLE_IMU_MIN_SHARE = 0.8
GAUSS_TO_UT = 100.0
#: PX4's "relative timestamp invalid" marker (SensorCombined.msg RELATIVE_TIMESTAMP_INVALID)
_REL_INVALID = 2147483647
_GPS_FIX_3D = 3
_NAN = math.nan
_MIN_UTC_US = 1262304000 * 10**6  # 2010-01-01: earlier UTC means the receiver has no time yet


def _settings(settings: Any) -> Any:
    from mavahrs.service.pipeline import PipelineSettings

    if settings is None:
        return PipelineSettings()
    ps = getattr(settings, "pipeline_settings", None)  # a ReplaySettings
    return ps() if callable(ps) else settings


def _open(path: Path) -> tuple[Any, list[str]]:
    """The ULog read with pyulog (only :data:`TOPICS`), and pyulog's own complaints (it prints them)."""
    from pyulog import ULog
    from pyulog.core import ULogException

    try:
        size = path.stat().st_size
    except OSError as exc:
        raise DataError(f"{path}: cannot read the log ({exc.strerror or exc})") from None
    if size == 0:
        raise DataError(f"{path}: the file is empty (0 bytes), not a PX4 ULog")
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            ulog = ULog(str(path), list(TOPICS), disable_str_exceptions=True)
    except ULogException as exc:
        raise DataError(f"{path}: not a readable PX4 ULog ({exc})") from None
    except (OSError, ValueError, IndexError, KeyError, struct.error, UnicodeDecodeError, MemoryError) as exc:
        raise DataError(f"{path}: the ULog is damaged (its definitions or a record cannot be parsed: {type(exc).__name__}: {exc})") from None
    complaints = [ln.strip() for ln in printed.getvalue().splitlines() if ln.strip()]
    return ulog, complaints


def _cut_record_bytes(path: Path) -> int:
    """How many bytes of a last, incomplete record end the file (0: it ends on a record boundary).

    Walks the 3-byte record headers (``msg_size``, ``msg_type``) from the end of the 16-byte
    file header: pyulog stops silently at a record cut short (power lost while logging).
    Only meaningful for a log pyulog found undamaged (a corrupted one is re-synchronised, not walked).
    """
    import mmap

    with path.open("rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        n, pos, start = len(data), 16, 16
        header = struct.Struct("<HB").unpack_from
        while pos + 3 <= n:
            start = pos
            pos += 3 + header(data, pos)[0]
        if pos == n:
            return 0
        return n - (start if pos > n else pos)


def _all_topics(path: Path, listed: int = 40) -> str:
    """Every topic the log holds data for (a second, unfiltered read: only on the error path)."""
    from pyulog import ULog

    try:
        with contextlib.redirect_stdout(io.StringIO()):
            ulog = ULog(str(path))
    except Exception:  # the first read succeeded; this one is only for the message
        return "unknown (the log cannot be read again)"
    names = sorted({f"{d.name}" + (f"[{d.multi_id}]" if d.multi_id else "") for d in ulog.data_list
                    if len(d.data.get("timestamp", ()))})  # fmt: skip
    if not names:
        return "none (the log holds no data records: cut short after its definitions?)"
    more = f", … ({len(names)} in all)" if len(names) > listed else ""
    return ", ".join(names[:listed]) + more


def _topics(ulog: Any) -> dict[str, dict[int, dict[str, np.ndarray]]]:
    out: dict[str, dict[int, dict[str, np.ndarray]]] = {}
    for d in ulog.data_list:
        if len(d.data.get("timestamp", ())) == 0:
            continue
        out.setdefault(d.name, {})[int(d.multi_id)] = d.data
    return out


def _rate_hz(t_us: np.ndarray) -> float:
    if t_us.shape[0] < 2:
        return 0.0
    span = float(t_us[-1]) - float(t_us[0])
    return (t_us.shape[0] - 1) / span * 1e6 if span > 0 else 0.0


def _vec(d: dict[str, np.ndarray], name: str) -> Array:
    return np.column_stack([np.asarray(d[f"{name}[{k}]"], np.float64) for k in range(3)])


def _has_vec(d: dict[str, np.ndarray], name: str) -> bool:
    return all(f"{name}[{k}]" in d for k in range(3))


def _sample_time(d: dict[str, np.ndarray]) -> NDArray[np.int64]:
    """``timestamp_sample`` where logged and non-zero, else ``timestamp``."""
    t = np.asarray(d["timestamp"], np.int64)
    ts = d.get("timestamp_sample")
    if ts is None:
        return t
    ts = np.asarray(ts, np.int64)
    return np.where(ts > 0, ts, t)


def _imu(topics: dict[str, Any], s: Any, path: Path) -> tuple[str, int, dict[str, Any], list[str]]:
    """(topic, instance, columns t_us/gyro/accel/clip, header lines) of the IMU to feed."""
    lines: list[str] = []
    vimu = {i: d for i, d in topics.get("vehicle_imu", {}).items()
            if _has_vec(d, "delta_angle") and _has_vec(d, "delta_velocity")
            and "delta_angle_dt" in d and "delta_velocity_dt" in d}  # fmt: skip
    sc = topics.get("sensor_combined", {}).get(0)
    if sc is not None and not (_has_vec(sc, "gyro_rad") and _has_vec(sc, "accelerometer_m_s2")):
        sc = None
    if not vimu and sc is None:
        raise DataError(f"{path}: no IMU topic (vehicle_imu or sensor_combined with gyro and accelerometer) "
                        f"in the log; topics logged: {_all_topics(path)}")  # fmt: skip
    sc_rate = _rate_hz(np.asarray(sc["timestamp"], np.int64)) if sc is not None else 0.0
    rates = {i: _rate_hz(np.asarray(d["timestamp"], np.int64)) for i, d in vimu.items()}
    fixed = s.selection_settings.fixed
    if fixed is not None and vimu and fixed not in vimu:
        raise DataError(f"{path}: IMU instance {fixed} is not in the log (vehicle_imu instances: {sorted(vimu)})")
    usable = {i for i, r in rates.items() if r >= VEHICLE_IMU_MIN_SHARE * sc_rate and r > 0}
    if usable and (fixed is None or fixed in usable):
        # every usable instance's samples in time order through the pipeline's IMU selector (its compiled step)
        cols = {i: _vehicle_imu_columns(vimu[i]) for i in sorted(usable)}
        inst_of = np.concatenate([np.full(c["t_us"].shape[0], i, np.int64) for i, c in cols.items()])
        t = np.concatenate([c["t_us"] for c in cols.values()])
        order = np.argsort(t, kind="stable")
        merged = {k: np.concatenate([c[k] for c in cols.values()])[order] for k in ("t_us", "gyro", "accel", "clip")}
        inst_of = inst_of[order]
        feed, _ = select_over_arrays(s.selection_settings, np.zeros(t.shape[0], np.int64), inst_of, merged["t_us"],
                                     merged["gyro"], merged["accel"], merged["clip"])  # fmt: skip
        fed = sorted(set(inst_of[feed].tolist()))
        if not fed:
            raise DataError(f"{path}: no vehicle_imu sample would reach the filter (every instance all-zero)")
        inst = int(np.bincount(inst_of[feed]).argmax())
        for i in sorted(vimu):
            tag = "used" if i in fed else "not used"
            why = "" if i in usable else f" (below {VEHICLE_IMU_MIN_SHARE:.0%} of sensor_combined's {sc_rate:.1f} Hz)"
            lines.append(f"vehicle_imu[{i}]: {rates[i]:.1f} Hz, {len(vimu[i]['timestamp'])} samples — {tag}{why}")
        if len(fed) > 1:
            lines.append(f"the IMU selector switched between vehicle_imu instances {fed} during the log (fail-over)")
        if sc is not None:
            lines.append(f"sensor_combined: {sc_rate:.1f} Hz — not used (vehicle_imu at the loop rate instead)")
        lines.insert(0, f"IMU: vehicle_imu[{inst}] at {rates[inst]:.1f} Hz: delta angle / velocity over their "
                        "intervals (mean rate and specific force), board FRD, static calibration applied")  # fmt: skip
        return "vehicle_imu", inst, {k: v[feed] for k, v in merged.items()}, lines
    for i in sorted(vimu):
        why = "" if i in usable else f" (below {VEHICLE_IMU_MIN_SHARE:.0%} of sensor_combined's {sc_rate:.1f} Hz)"
        lines.append(f"vehicle_imu[{i}]: {rates[i]:.1f} Hz, {len(vimu[i]['timestamp'])} samples — not used{why}")
    if fixed is not None and fixed != 0:
        raise DataError(f"{path}: IMU instance {fixed} is not logged at the loop rate "
                        f"(vehicle_imu[{fixed}] at {rates.get(fixed, 0.0):.1f} Hz; sensor_combined is the voted IMU)")  # fmt: skip
    if sc is None:
        raise DataError(f"{path}: vehicle_imu is logged at only {max(rates.values()):.1f} Hz and there is no "
                        "sensor_combined: too slow for attitude filtering")  # fmt: skip
    t = np.asarray(sc["timestamp"], np.int64)
    clip = np.asarray(sc.get("accelerometer_clipping", np.zeros(t.shape[0])), np.int64) != 0
    rel = np.asarray(sc.get("accelerometer_timestamp_relative", np.zeros(t.shape[0])), np.int64)
    accel = _vec(sc, "accelerometer_m_s2")
    accel[rel == _REL_INVALID] = _NAN
    lines.insert(0, f"IMU: sensor_combined at {sc_rate:.1f} Hz ({t.shape[0]} samples; PX4's voted IMU: "
                    "mean rate and specific force over each interval, board FRD, static calibration "
                    "applied, not EKF2's bias estimates)")  # fmt: skip
    return "sensor_combined", 0, {"t_us": t, "gyro": _vec(sc, "gyro_rad"), "accel": accel, "clip": clip}, lines


def _vehicle_imu_columns(d: Any) -> dict[str, Any]:
    """One vehicle_imu instance's samples: time, mean rate (delta angle / its interval), specific force, clipping."""
    t = np.asarray(d["timestamp"], np.int64)
    dta = np.asarray(d["delta_angle_dt"], np.float64) * 1e-6
    dtv = np.asarray(d["delta_velocity_dt"], np.float64) * 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        gyro = _vec(d, "delta_angle") / np.where(dta > 0, dta, _NAN)[:, None]
        accel = _vec(d, "delta_velocity") / np.where(dtv > 0, dtv, _NAN)[:, None]
    clip = np.asarray(d.get("delta_velocity_clipping", np.zeros(t.shape[0])), np.int64) != 0
    return {"t_us": t, "gyro": gyro, "accel": accel, "clip": clip}


def _source(topics: dict[str, Any]) -> tuple[int, int]:
    """(system, component) of the vehicle: vehicle_status' ids (MAV_SYS_ID), else PX4's defaults (1, 1)."""
    vs = topics.get("vehicle_status", {}).get(0)
    if vs is not None and "system_id" in vs and "component_id" in vs:
        sysid, compid = int(vs["system_id"][0]), int(vs["component_id"][0])
        if 0 < sysid < 256 and 0 < compid < 256:
            return sysid, compid
    return 1, 1


def _decimal_year(gps: dict[str, np.ndarray] | None, s: Any) -> tuple[float, str]:
    from mavahrs.sensors.geomag import decimal_year_from_unix_s

    if s.magnetic.decimal_year is not None:
        return float(s.magnetic.decimal_year), "settings"
    if gps is not None and "time_utc_usec" in gps:
        utc = np.asarray(gps["time_utc_usec"], np.int64)
        ok = utc > _MIN_UTC_US
        if ok.any():
            return decimal_year_from_unix_s(float(utc[ok][0]) * 1e-6), "GNSS UTC time"
    now = _dt.datetime.now(tz=_dt.timezone.utc).timestamp()
    return decimal_year_from_unix_s(now), "today (no UTC time in the log)"


def read_ulog(path: str | Path, settings: Any = None, *, start_s: float | None = None,
              end_s: float | None = None) -> LogInputs:  # fmt: skip
    """A PX4 ULog's filter inputs, references and parameters (see the module doc).

    Args:
        settings: ``PipelineSettings`` (or ``ReplaySettings``); defaults if None.
            Used: calibration, magnetic (declination, date), scaling (limits),
            timeline (gap), ``velocity_source`` (``none`` = no GNSS velocity),
            IMU instance (``imu``).
        start_s, end_s: keep IMU samples in this window, seconds from the log's start.

    Raises:
        DataError: empty, not a ULog, damaged beyond reading, no IMU data.
    """
    from mavahrs.ingest.arrays import PreparedInputs, onboard_timeline, si_rows
    from mavahrs.sensors.calibration import Calibrator
    from mavahrs.sensors.geomag import DeclinationSource
    from mavahrs.sensors.profiles import get_profile
    from mavahrs.sensors.sample import ACCEL, GYRO

    p = Path(path)
    s = _settings(settings)
    ulog, complaints = _open(p)
    topics = _topics(ulog)
    found: list[str] = []
    notes: list[str] = []
    info = ulog.msg_info_dict
    found.append(f"PX4 ULog: {info.get('sys_name', 'PX4')} {info.get('ver_hw', '?')}, "
                 f"software {str(info.get('ver_sw', '?'))[:12]}, {len(ulog.initial_parameters)} parameters")  # fmt: skip
    if complaints:
        notes.append(f"the log has damaged records ({len(complaints)} skipped by the reader, e.g. "
                     f"'{complaints[0]}'): read as far as possible")  # fmt: skip
    if getattr(ulog, "file_corruption", False) and not complaints:
        notes.append("the log has damaged records: read as far as possible")
    truncated = False
    if not getattr(ulog, "file_corruption", False) and not complaints and (cut := _cut_record_bytes(p)):
        truncated = True
        notes.append(f"truncated: the log ends inside a record ({cut} bytes of it); read up to the last whole record")
    if ulog.dropouts:
        lost = sum(int(d.duration) for d in ulog.dropouts)
        notes.append(f"{len(ulog.dropouts)} logger dropouts ({lost} ms of data not written by PX4)")
    topic, inst, imu, imu_lines = _imu(topics, s, p)
    found.extend(imu_lines)
    t0 = int(ulog.start_timestamp)
    t_all = imu["t_us"]
    win = np.ones(t_all.shape[0], bool)
    if start_s is not None:
        win &= t_all >= t0 + int(start_s * 1e6)
    if end_s is not None:
        win &= t_all <= t0 + int(end_s * 1e6)
    # the timeline step over the samples, as for every log (a lone damaged stamp dropped, a gap a re-initialising dt)
    keep, dt = onboard_timeline(p, t_all[win], imu["gyro"][win], imu["accel"][win], s.timeline)
    sel = np.flatnonzero(win)[keep]
    dt = dt[keep]
    m = sel.shape[0]
    if m == 0:
        if (start_s is not None or end_s is not None) and t_all.size and not win.any():
            raise empty_window_error(p, start_s, end_s, (int(t_all.min()) - t0) * 1e-6,
                                     (int(t_all.max()) - t0) * 1e-6)  # fmt: skip
        raise DataError(f"{p}: {topic} has no usable samples")
    dropped = int(win.sum()) - m
    if dropped:
        notes.append(f"{dropped} IMU samples dropped by the timeline (a stamp not after the last one used, or a "
                     "lone jump ahead)")  # fmt: skip
    t_us = t_all[sel]
    gyro, accel, clip = imu["gyro"][sel], imu["accel"][sel], imu["clip"][sel]
    # --- the scaling and row steps as for HIGHRES_IMU (the px4 profile's full scales, the scaling settings)
    ms = get_profile("px4").scale_for("HIGHRES_IMU")
    rows, sat, inv = si_rows(gyro, accel, ms, s.scaling, clip)
    rows[:, IN_DT] = dt
    g_bad = (inv & GYRO) != 0
    a_bad = (inv & ACCEL) != 0
    a_sat = (sat & ACCEL) != 0
    counts = {"imu_messages": int(t_all.shape[0]), "fed": m, "dropped_timeline": dropped,
              "invalid_gyro": int(g_bad.sum()), "invalid_accel": int(a_bad.sum()),
              "saturated_accel": int((a_sat & ~a_bad).sum())}  # fmt: skip
    if counts["invalid_gyro"] or counts["invalid_accel"]:
        notes.append(f"{counts['invalid_gyro']} gyro and {counts['invalid_accel']} accelerometer samples "
                     "non-finite or beyond twice the full scale: blanked")  # fmt: skip
    if counts["saturated_accel"]:
        notes.append(f"{counts['saturated_accel']} accelerometer samples clipped or at full scale: not used")
    # --- magnetometer
    mag_line = _magnetometer(topics, t_us, rows, float(getattr(ms, "mag_plausible_max_ut", 1000.0)))
    found.append(mag_line)
    # --- temperature: vehicle_imu_status (about 1 Hz) of the gyro fed, held
    temp = np.full(m, _NAN)
    st = topics.get("vehicle_imu_status", {}).get(inst)
    if st is not None and "temperature_gyro" in st:
        ts = np.asarray(st["timestamp"], np.int64)
        tv = np.asarray(st["temperature_gyro"], np.float64)
        j = np.searchsorted(ts, t_us, side="right") - 1
        ok = j >= 0
        temp[ok] = tv[j[ok]]
        temp[~np.isfinite(temp)] = _NAN
    # --- GNSS: declination (WMM at the first fix) and velocity
    gps_name = next((n for n in ("vehicle_gps_position", "sensor_gps") if 0 in topics.get(n, {})), None)
    gps = topics[gps_name][0] if gps_name else None
    year, year_src = _decimal_year(gps, s)
    decl = DeclinationSource(s.magnetic, decimal_year=year)
    decl_at = np.full(m, decl.declination_rad)
    mag_events: list[tuple[int, float, float]] = []
    ref0 = decl.mag_reference()
    if ref0 is not None:
        mag_events.append((0, float(ref0[0]), float(ref0[1])))
    params = {str(k): float(v) for k, v in ulog.initial_parameters.items()
              if isinstance(v, (int, float)) and math.isfinite(float(v))}  # fmt: skip
    vel_used = 0
    if gps is not None:
        g_t = np.asarray(gps["timestamp"], np.int64)
        fix_type = np.asarray(gps.get("fix_type", np.zeros(g_t.shape[0])), np.int64)
        lat = np.asarray(gps.get("latitude_deg", gps.get("lat", np.zeros(g_t.shape[0]))), np.float64)
        lon = np.asarray(gps.get("longitude_deg", gps.get("lon", np.zeros(g_t.shape[0]))), np.float64)
        if "lat" in gps and "latitude_deg" not in gps:  # PX4 ≤ 1.13: degrees × 1e7
            lat, lon = lat * 1e-7, lon * 1e-7
        alt = np.asarray(gps.get("altitude_ellipsoid_m", np.zeros(g_t.shape[0])), np.float64)
        pos_ok = (fix_type >= 2) & np.isfinite(lat) & np.isfinite(lon) & ~((lat == 0) & (lon == 0))
        if pos_ok.any() and decl.settings.declination_deg is None:
            k = int(np.flatnonzero(pos_ok)[0])
            i = int(np.searchsorted(t_us, g_t[k], side="left"))
            if decl.set_position(float(lat[k]), float(lon[k]), float(alt[k]) if np.isfinite(alt[k]) else 0.0,
                                 gps_name):  # fmt: skip
                decl_at[i:] = decl.declination_rad
                ref = decl.mag_reference()
                if ref is not None and i < m:
                    mag_events.append((i, float(ref[0]), float(ref[1])))
            f = decl.field
            if f is not None:
                found.append(f"declination: {f.source} at {lat[k]:.5f}, {lon[k]:.5f} (first {gps_name} fix, "
                             f"date from {year_src}): {f.declination_deg:+.2f}°, inclination "
                             f"{f.inclination_deg:+.1f}°, {f.strength_ut:.1f} µT")  # fmt: skip
    vel = _velocity_source(topics, s)
    if vel is None:
        vel_line = ("GNSS velocity: not fed (velocity_source = none)" if s.effective_velocity_source == "none"
                    else "GNSS velocity: none in the log")  # fmt: skip
    else:
        vname, v_t, v_ts, v, fix_ok, what, p_ned = vel
        fresh = np.ones(v_t.shape[0], bool)
        fresh[1:] = v_ts[1:] != v_ts[:-1]  # a repeated fix is not fed again
        use = np.flatnonzero(fix_ok & fresh)
        if vname in _EKF_VELOCITY and s.gnss_rate_hz > 0:
            use = _decimate(v_t, use, s.gnss_rate_hz)
        at = np.searchsorted(t_us, v_t[use], side="left")
        inside = at < m
        use, at = use[inside], at[inside]
        d = decl_at[at]
        c, sn = np.cos(d), np.sin(d)  # geomag.rotate_true_to_magnetic over the rows
        rows[at, IN_VEL] = c * v[use, 0] + sn * v[use, 1]
        rows[at, IN_VEL + 1] = -sn * v[use, 0] + c * v[use, 1]
        rows[at, IN_VEL + 2] = v[use, 2]
        rows[at, IN_VEL_AGE] = (t_us[at] - v_ts[use]) * 1e-6
        if use.size:  # the same fixes' position, NED m from the first fix fed, in the velocity's frame
            pu = p_ned[use] - p_ned[use[0]]
            rows[at, IN_POS] = c * pu[:, 0] + sn * pu[:, 1]
            rows[at, IN_POS + 1] = -sn * pu[:, 0] + c * pu[:, 1]
            rows[at, IN_POS + 2] = pu[:, 2]
        vel_used = int(np.unique(at).size)
        every = "" if vname not in _EKF_VELOCITY or s.gnss_rate_hz <= 0 else f" taken at {s.gnss_rate_hz:g} Hz"
        vel_line = (f"GNSS velocity: {vname} ({what}) at {_rate_hz(v_t):.1f} Hz{every}, {vel_used} fixes fed "
                    f"({int((~fix_ok).sum())} without a valid velocity)")  # fmt: skip
    found.append(vel_line)
    if not decl.known and s.magnetic.true_north and "EKF2_MAG_DECL" in params:
        d_deg = params["EKF2_MAG_DECL"]
        decl_at[:] = math.radians(d_deg)
        found.append(f"declination: EKF2_MAG_DECL = {d_deg:+.2f}° (no GNSS position in the log)")
    elif not decl.known:
        found.append("declination: unknown (no GNSS position, no EKF2_MAG_DECL): outputs on magnetic north")
    # --- calibration (Calibrator.apply_row over all rows); the magnetometer is PX4-calibrated
    cal = Calibrator(s.calibration, mag_already_calibrated=True)
    if cal.active:
        cal.apply_rows(rows, temp)
    references = _references(topics, ulog, found)
    delay = 0.0
    if topic == "vehicle_imu":
        d = topics["vehicle_imu"][inst]
        lag = np.asarray(d["timestamp"], np.int64) - _sample_time(d)
        delay = max(0.0, float(np.median(lag)) * 1e-6) if lag.size else 0.0
    found.append(f"time: ULog timestamp (µs since boot), {t_us[0] * 1e-6:.3f}–{t_us[-1] * 1e-6:.3f} s; "
                 f"log starts at {t0 * 1e-6:.3f} s")  # fmt: skip
    prep = PreparedInputs(
        rows=rows, t_us=t_us.astype(np.int64), frame_pos=np.arange(m, dtype=np.int64),
        tlog_us=t_us.astype(np.int64), temperature_c=temp, declination_rad=decl_at, message=topic,
        instance=inst, source=_source(topics), profile="px4", engine="fast", notes=notes, counts=counts,
        velocity_source=str(s.effective_velocity_source), velocity_fixes={vel[0]: vel_used} if vel is not None else {},
        mag_reference_events=mag_events, sensor_delay_s=delay, vehicle_stream=True,
        multirotor=int(params.get("MAV_TYPE", 0)) in MULTIROTOR_MAV_TYPES,
    )  # fmt: skip
    series = _flight_state(topics)
    if series:
        found.append("flight phase: " + ", ".join(
            f"{k} from {topic}" for k, topic in (("armed", "vehicle_status"), ("landed", "vehicle_land_detected"))
            if k in series))  # fmt: skip
    return LogInputs(path=str(p), format="ulog", inputs=prep, references=references, found=found,
                     parameters=params, series=series, truncated=truncated)  # fmt: skip


_ARMING_STATE_ARMED = 2  # vehicle_status.arming_state (PX4's VehicleStatus.msg)


def _flight_state(topics: dict[str, Any]) -> dict[str, dict[str, np.ndarray]]:
    """The flight's phase as PX4 logged it, as the MAVLink fields the second-opinion monitor reads (the
    DataFlash reader's ``_flight_state``): ``armed`` (``t_us``, ``base_mode``: 128 while ``vehicle_status``'
    ``arming_state`` is ARMED, else 0) and ``landed`` (``t_us``, ``landed_state``: 1 while
    ``vehicle_land_detected``'s ``landed``, else 2), each at its own changes."""
    out: dict[str, dict[str, np.ndarray]] = {}

    def changes(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        keep = np.concatenate([[True], v[1:] != v[:-1]]) if v.size else np.zeros(0, bool)
        return np.asarray(t, np.int64)[keep], v[keep]

    vs = topics.get("vehicle_status", {}).get(0)
    if vs is not None and "arming_state" in vs and len(vs["arming_state"]):
        t, mode = changes(vs["timestamp"], np.where(np.asarray(vs["arming_state"]) == _ARMING_STATE_ARMED, 128, 0))
        out["armed"] = {"t_us": t, "base_mode": mode.astype(np.int64)}
    ld = topics.get("vehicle_land_detected", {}).get(0)
    if ld is not None and "landed" in ld and len(ld["landed"]):
        t, st = changes(ld["timestamp"], np.where(np.asarray(ld["landed"]) != 0, 1, 2))
        out["landed"] = {"t_us": t, "landed_state": st.astype(np.int64)}
    return out


#: the ``velocity_source`` setting → the ULog topics it means, in order (the MAVLink messages'
#: own origins in PX4: GLOBAL_POSITION_INT carries EKF2's velocity = vehicle_local_position
#: vx/vy/vz; GPS_RAW_INT the receiver's = vehicle_gps_position / sensor_gps)
_EKF_VELOCITY = ("vehicle_local_position",)
_RECEIVER_VELOCITY = ("vehicle_gps_position", "sensor_gps")
#: the MAVLink velocity messages → the ULog topics they are sent from (``auto`` follows the ``px4`` profile's
#: ``velocity_order``, as the daemon does on a PX4 link: the receiver's GPS_RAW_INT before EKF2's velocity)
_MESSAGE_TOPICS = {"GPS_RAW_INT": _RECEIVER_VELOCITY, "GLOBAL_POSITION_INT": _EKF_VELOCITY}


def _decimate(t_us: NDArray[np.int64], idx: NDArray[np.int64], rate_hz: float) -> NDArray[np.int64]:
    """The entries of ``idx`` a stream at ``rate_hz`` would deliver: the first, then each one at least a
    period (less 10 %, the sender's jitter) after the last kept — what the daemon gets when it asks
    for GLOBAL_POSITION_INT at ``gnss_rate_hz``."""
    period = 0.9e6 / rate_hz
    out: list[int] = []
    last = -math.inf
    for j, tj in zip(idx.tolist(), t_us[idx].tolist(), strict=True):
        if tj - last >= period:
            out.append(j)
            last = tj
    return np.asarray(out, np.int64)


def _velocity_source(topics: dict[str, Any], s: Any) -> tuple[str, Any, Any, Array, Any, str, Array] | None:
    """(topic, arrival µs, fix time µs, (N, 3) true-NED velocity, valid, what, (N, 3) true-NED position m
    from an arbitrary origin: EKF2's local x/y/z, or the receiver's lat/lon/alt from its first record;
    NaN where not valid) for the setting, or None."""
    src = str(s.effective_velocity_source)
    if src == "none":
        return None
    if src == "auto":
        if s.monitor.receiver_velocity_only:
            order = _RECEIVER_VELOCITY
        else:  # the px4 profile's order, as the daemon's velocity selector takes it on a PX4 link
            order = tuple(t for msg in get_profile("px4").velocity_order for t in _MESSAGE_TOPICS.get(msg, ()))
    elif src == "global_position_int":
        order = _EKF_VELOCITY
    else:  # gps_raw_int, gps2_raw: the receiver
        order = _RECEIVER_VELOCITY
    for name in order:
        d = topics.get(name, {}).get(0)
        if d is None:
            continue
        t = np.asarray(d["timestamp"], np.int64)
        if name in _EKF_VELOCITY:
            if not all(k in d for k in ("vx", "vy", "vz")):
                continue
            v = np.column_stack([np.asarray(d[k], np.float64) for k in ("vx", "vy", "vz")])
            ok = np.asarray(d.get("v_xy_valid", np.ones(t.shape[0])), np.int64) != 0
            ok &= np.asarray(d.get("xy_global", np.ones(t.shape[0])), np.int64) != 0  # a GNSS-referenced EKF
            vz_ok = np.asarray(d.get("v_z_valid", np.ones(t.shape[0])), np.int64) != 0
            v[~vz_ok, 2] = _NAN
            what = "EKF2's velocity, as GLOBAL_POSITION_INT sends it"
            nan = np.full(t.shape[0], _NAN)
            p = np.column_stack([np.asarray(d.get(k, nan), np.float64) for k in ("x", "y", "z")])
            p[np.asarray(d.get("xy_valid", np.ones(t.shape[0])), np.int64) == 0, :2] = _NAN
            p[np.asarray(d.get("z_valid", np.ones(t.shape[0])), np.int64) == 0, 2] = _NAN
        else:
            if not all(k in d for k in ("vel_n_m_s", "vel_e_m_s", "vel_d_m_s")):
                continue
            v = np.column_stack([np.asarray(d[k], np.float64) for k in ("vel_n_m_s", "vel_e_m_s", "vel_d_m_s")])
            ok = np.asarray(d.get("vel_ned_valid", np.ones(t.shape[0])), np.int64) != 0
            ok &= np.asarray(d.get("fix_type", np.zeros(t.shape[0])), np.int64) >= _GPS_FIX_3D
            what = "the receiver's, 3D fix"
            p = _receiver_position(d, t.shape[0])
        ok &= np.isfinite(v[:, 0]) & np.isfinite(v[:, 1])
        return name, t, _sample_time(d), v, ok, what, p
    return None


def _receiver_position(d: dict[str, Any], n: int) -> Array:
    """A vehicle_gps_position / sensor_gps record's lat/lon/alt as true-NED metres from its first record
    (:class:`~mavahrs.sensors.position.PositionOrigin`; altitude above mean sea level, NaN where absent)."""
    from mavahrs.sensors.position import PositionOrigin

    zeros = np.zeros(n)
    lat = np.asarray(d.get("latitude_deg", d.get("lat", zeros)), np.float64)
    lon = np.asarray(d.get("longitude_deg", d.get("lon", zeros)), np.float64)
    if "lat" in d and "latitude_deg" not in d:  # PX4 ≤ 1.13: degrees × 1e7, altitude mm
        lat, lon = lat * 1e-7, lon * 1e-7
        alt = np.asarray(d.get("alt", np.full(n, _NAN)), np.float64) * 1e-3
    else:
        alt = np.asarray(d.get("altitude_msl_m", np.full(n, _NAN)), np.float64)
    return PositionOrigin().ned_arrays(lat, lon, alt, None)


def _magnetometer(topics: dict[str, Any], t_us: NDArray[np.int64], rows: Array, max_ut: float) -> str:
    """Write the magnetometer samples into the first row at or after each one's time; the header line."""
    m = t_us.shape[0]
    vm = topics.get("vehicle_magnetometer", {})
    inst = min(vm) if vm else None
    if inst is not None and _has_vec(vm[inst], "magnetometer_ga"):
        d = vm[inst]
        ts = _sample_time(d)
        b = _vec(d, "magnetometer_ga") * GAUSS_TO_UT
        name = f"vehicle_magnetometer[{inst}]"
        rate = _rate_hz(np.asarray(d["timestamp"], np.int64))
    else:
        sc = topics.get("sensor_combined", {}).get(0)
        if sc is None or not _has_vec(sc, "magnetometer_ga") or "magnetometer_timestamp_relative" not in sc:
            return "magnetometer: none in the log (vehicle_magnetometer absent): heading from the gyro only"
        rel = np.asarray(sc["magnetometer_timestamp_relative"], np.int64)
        ts_all = np.asarray(sc["timestamp"], np.int64) + rel
        new = rel != _REL_INVALID
        new[1:] &= ts_all[1:] != ts_all[:-1]
        ts = ts_all[new]
        b = _vec(sc, "magnetometer_ga")[new] * GAUSS_TO_UT
        name = "sensor_combined magnetometer_ga"
        rate = _rate_hz(ts)
    n_all = ts.shape[0]
    with np.errstate(invalid="ignore"):
        norm = np.linalg.norm(b, axis=1)
        ok = np.isfinite(norm) & (norm > 1.0) & (norm < max_ut)
    at = np.searchsorted(t_us, ts[ok], side="left")
    inside = at < m
    rows[at[inside], IN_MAG : IN_MAG + 3] = b[ok][inside]
    placed = int(np.unique(at[inside]).size)
    return (f"magnetometer: {name} at {rate:.1f} Hz (calibrated by PX4, board FRD, gauss × 100 → µT), "
            f"{placed} of {n_all} samples fed" + (f", {int((~ok).sum())} implausible" if (~ok).any() else ""))


def _references(topics: dict[str, Any], ulog: Any, found: list[str]) -> dict[str, tuple[Array, Array]]:
    refs: dict[str, tuple[Array, Array]] = {}
    sih = str(ulog.msg_info_dict.get("ver_hw", "")).upper() in ("PX4_SITL", "SITL") or any(
        k.startswith("SIH_") for k in ulog.initial_parameters
    )
    for topic, name in (("vehicle_attitude", "EKF2"),
                        ("vehicle_attitude_groundtruth", "SIH truth" if sih else "groundtruth truth")):  # fmt: skip
        d = topics.get(topic, {}).get(0)
        if d is None or not all(f"q[{k}]" in d for k in range(4)):
            found.append(f"{'truth' if name.endswith('truth') else 'reference'}: no {topic} in the log")
            continue
        t = _sample_time(d)
        q = np.column_stack([np.asarray(d[f"q[{k}]"], np.float64) for k in range(4)])
        with np.errstate(invalid="ignore"):
            n = np.linalg.norm(q, axis=1)
            ok = np.isfinite(n) & (n > 0.5) & (n < 1.5)
        ok[1:] &= np.diff(t) > 0
        t, q = t[ok], q[ok] / n[ok, None]
        if t.shape[0] < 2:
            continue
        refs[name] = (t.astype(np.int64), q)
        kind = "truth" if name.endswith(" truth") else "reference"
        found.append(f"{kind}: {name} = {topic} at {_rate_hz(t):.1f} Hz ({t.shape[0]} samples)")
    return refs
