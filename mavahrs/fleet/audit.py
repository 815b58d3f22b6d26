r"""``mavahrs audit``'s work: one row per flight log, a resumable table, the printed summary.

:func:`summarise_log` replays a log with :func:`mavahrs.replay.replay` — the
daemon's decoding, scaling, IMU selection, timing and filter, exactly as
``mavahrs replay`` does — then runs the daemon's second-opinion monitor
(:func:`mavahrs.service.monitor.monitor_series`, the live monitor's state
machine) over the estimates the daemon would have published and the log's own
ATTITUDE (or AHRS2), and measures clipping and vibration on the samples the
filter was fed.  It is a pure function of the path, the file and the settings;
it never raises: a log that cannot be read gives a row whose ``error`` says why.

The rows go to Parquet (pyarrow, the ``fleet`` extra) and/or CSV.  A table is
rewritten whole to a temporary file that then replaces it (``os.replace``), at
most every ``flush_every_s`` and once more when the run ends or is interrupted,
so an interruption loses nothing already summarised and never leaves a
half-written table.  A later run skips the logs whose (path, size,
modification time) are already in the table unless ``force``.
"""

from __future__ import annotations

import csv
import glob
import logging
import math
import os
import socket
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from mavahrs.logs import autopilot_reference

_log = logging.getLogger("mavahrs.fleet")

__all__ = [
    "AuditSettings",
    "FleetRow",
    "TIMING_FIELDS",
    "LOG_SUFFIXES",
    "summarise_log",
    "expand_logs",
    "select_logs",
    "LogSelection",
    "is_log_file",
    "skipped_text",
    "read_table",
    "write_table",
    "serial_map",
    "AuditRun",
    "AuditPlan",
    "plan_audit",
    "lost_row",
    "run_audit",
    "format_summary",
    "format_startup",
    "SERIAL_HINT",
    "imu_gyros",
    "onboard_imu_gyros",
    "phase_events",
    "onboard_phase_events",
    "replay_monitor",
    "monitored_filter",
]

#: What a folder is searched for (recursively), beside any file whose content is a log (mavahrs.logs.sniff).
LOG_SUFFIXES = (".tlog", ".bin", ".ulg")
#: Printed (stderr) when Dask is not installed and the logs are replayed one after the other.
SERIAL_HINT = (
    "audit: Dask is not installed: replaying the logs one after the other on one core "
    "(for all cores or a cluster: pip install 'mavahrs[fleet]')"
)
#: Fields that depend on when and where the row was computed, not on the log.
TIMING_FIELDS = ("replay_s", "worker")
_MAV_SEVERITY_WARNING = 4
_MAV_SEVERITY_NOTICE = 5


def _default_replay() -> Any:
    from mavahrs.replay import ReplaySettings
    from mavahrs.service.pipeline import PipelineSettings

    return ReplaySettings(pipeline=PipelineSettings())


@dataclass(frozen=True)
class AuditSettings:
    """How each log is replayed and judged.

    Attributes:
        replay: the replay (first filter, pipeline settings: IMU, profile,
            calibration, out-rate, monitor thresholds).  Default: filter
            ``best`` with the daemon's own defaults (ATTITUDE_QUATERNION at
            50 Hz, which is what its monitor compares).
        vibration_window_s: the vibration figure is the RMS of the
            accelerometer minus its centred moving average over this window
            (a high-pass at about 1/window Hz), m/s².
        plot_dir: also draw each flight's second-opinion chart (divergence,
            threshold, warnings and their evidence) into this folder, as
            ``LOGNAME_second_opinion.png``; "" = none (``audit --plot``).
    """

    replay: Any = field(default_factory=_default_replay)
    vibration_window_s: float = 0.2
    plot_dir: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.vibration_window_s) and self.vibration_window_s > 0):
            raise ValueError(f"vibration_window_s must be > 0, got {self.vibration_window_s!r}")


@dataclass(frozen=True)
class FleetRow:
    """One flight log's summary.  Units in the names; NaN / None / "" where the log does not tell.

    Attributes:
        path: the log, absolute.
        size_bytes: its size, bytes.
        mtime_ns: its modification time, ns since the epoch (with ``path`` and
            ``size_bytes``: what a later run compares to skip it).
        error: why the log could not be replayed ("" when it was).
        system_id: the autopilot's MAVLink system id.
        component_id: its component id.
        autopilot: MAV_AUTOPILOT of its first HEARTBEAT (``ARDUPILOTMEGA``, ``PX4`` …).
        vehicle_type: MAV_TYPE of that HEARTBEAT (``QUADROTOR``, ``FIXED_WING`` …).
        start_utc: the first record's time, ISO 8601 UTC ("" if the tlog's clock is implausible).
        duration_s: from the first to the last IMU sample fed to the filter, s (summed over the autopilot's boots
            where it rebooted during the log).
        imu_message: the IMU message fed (``RAW_IMU``, ``SCALED_IMU2``, ``HIGHRES_IMU`` …).
        imu_instance: its IMU instance.
        imu_samples: samples fed to the filter.
        imu_rate_hz: their mean rate, Hz.
        gnss: the log has a position fix (GLOBAL_POSITION_INT or a 3D GPS_RAW_INT):
            the declination is known and headings are true north.
        engine: the replay engine used (``fast`` or ``pipeline``).
        reference: the log's own attitude compared with, the autopilot's
            (:func:`mavahrs.logs.autopilot_reference`: ``autopilot ATTITUDE`` of a tlog,
            else ``autopilot AHRS2``; ``autopilot EKF3`` of a .BIN; ``EKF2`` of a .ulg; "" = none).
        compared_s: autopilot time covered by the comparison after the monitor's
            start-up grace, s.
        inclination_rms_deg, inclination_max_deg: tilt divergence between
            mavahrs and the reference (BROAD's inclination), RMS and maximum, deg.
        heading_rms_deg, heading_max_deg: heading divergence (absolute), deg.
        alarms: in-flight WARNINGs the second-opinion monitor raised (the
            divergence confirmed beyond its threshold; see ``MonitorSettings``;
            None: nothing judged — no autopilot attitude, or our IMU input slower
            than ``MonitorSettings.min_imu_rate_hz`` throughout).
        first_alarm_s: autopilot boot time of the first WARNING, s (NaN: none).
        alarm_times_s: boot times of every WARNING, s, ``;``-separated.
        ground_alarms: disagreements it raised on the ground, at take-off or
            touchdown (NOTICEs naming the phase; not counted in ``alarms``).
        ground_alarm_times_s: their boot times and phases, ``12.345 touchdown;…``.
        alarm_causes: per WARNING (``;``-separated, as ``alarm_times_s``) who is
            likely wrong, the evidence it ended with (``mag``: the magnetometer's
            field is not the expected one; ``AP?`` / ``us?``: the GNSS velocity
            change agrees with our attitude / with the autopilot's; ``IMU2?``:
            that IMU; space-separated, "" = no evidence).
        gyro_clip_fraction: fed samples with a gyro axis at ≥ the saturation
            fraction of the sensor's full scale (0–1).
        accel_clip_fraction: fed samples whose accelerometer was at its limit
            (or dropped as saturated/invalid by the scaling) (0–1).
        vibration_x_m_s2, vibration_y_m_s2, vibration_z_m_s2: accelerometer
            vibration per body axis, m/s² RMS (see ``vibration_window_s``).
        notes: replay's notes (reboots, gaps, absent IMUs, low rate …), `` | ``-separated.
        log_format: ``tlog``, ``dataflash`` or ``ulog`` ("" when not recognised).
        truncated: the log ends inside a record (cut off; read up to its last whole record).
        replay_s: wall time this row took, s (timing: differs run to run).
        worker: host:pid that computed it (timing).
    """

    path: str
    size_bytes: int
    mtime_ns: int
    error: str = ""
    system_id: int | None = None
    component_id: int | None = None
    autopilot: str = ""
    vehicle_type: str = ""
    start_utc: str = ""
    duration_s: float = math.nan
    imu_message: str = ""
    imu_instance: int | None = None
    imu_samples: int | None = None
    imu_rate_hz: float = math.nan
    gnss: bool | None = None
    engine: str = ""
    reference: str = ""
    compared_s: float = math.nan
    inclination_rms_deg: float = math.nan
    inclination_max_deg: float = math.nan
    heading_rms_deg: float = math.nan
    heading_max_deg: float = math.nan
    alarms: int | None = None
    first_alarm_s: float = math.nan
    alarm_times_s: str = ""
    ground_alarms: int | None = None
    ground_alarm_times_s: str = ""
    alarm_causes: str = ""
    gyro_clip_fraction: float = math.nan
    accel_clip_fraction: float = math.nan
    vibration_x_m_s2: float = math.nan
    vibration_y_m_s2: float = math.nan
    vibration_z_m_s2: float = math.nan
    notes: str = ""
    log_format: str = ""
    truncated: bool | None = None
    replay_s: float = math.nan
    worker: str = ""

    @property
    def ok(self) -> bool:
        return not self.error

    @property
    def flagged(self) -> bool:
        """The monitor raised at least one WARNING."""
        return bool(self.alarms)

    def key(self) -> tuple[str, int, int]:
        return (self.path, self.size_bytes, self.mtime_ns)

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: Column kinds for the tables (the dataclass's annotations, by field).
_KINDS: dict[str, str] = {
    f.name: ("bool" if "bool" in str(f.type) else "int" if "int" in str(f.type)
             else "float" if "float" in str(f.type) else "str")
    for f in fields(FleetRow)
}  # fmt: skip


# --------------------------------------------------------------------------- one log


def summarise_log(path: str | Path, settings: AuditSettings | None = None) -> FleetRow:
    """Replay one log as ``mavahrs replay`` does and summarise it (never raises)."""
    s = settings if settings is not None else AuditSettings()
    t0 = time.perf_counter()
    p = Path(path).absolute()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    try:
        st = p.stat()
    except OSError as exc:
        return FleetRow(str(p), -1, -1, error=f"cannot read: {exc.strerror or exc}", worker=worker)
    base = FleetRow(str(p), int(st.st_size), int(st.st_mtime_ns))
    try:
        row = _summarise(p, base, s)
    except Exception as exc:  # noqa: BLE001 - one bad log never stops the batch: its row says why
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        msg = msg.replace(f"{p}: ", "")
        from mavahrs.errors import MavahrsError

        if not isinstance(exc, (MavahrsError, OSError)):
            msg = f"{type(exc).__name__}: {msg}"
        row = _replace(base, error=msg)
    return _replace(row, replay_s=time.perf_counter() - t0, worker=worker)


def _replace(row: FleetRow, **changes: Any) -> FleetRow:
    from dataclasses import replace

    return replace(row, **changes)


def _enum_name(enum: str, value: int) -> str:
    from mavahrs.protocol.codec import mavlink

    entry = mavlink.enums.get(enum, {}).get(int(value))
    name = entry.name if entry is not None else str(int(value))
    return name.removeprefix(enum + "_")


def _summarise(p: Path, base: FleetRow, s: AuditSettings) -> FleetRow:
    from mavahrs.logs import sniff
    from mavahrs.replay import replay

    base = _replace(base, log_format=sniff(p) or "")
    result = replay(p, s.replay)
    if result.log is not None:
        return _summarise_onboard(result, base, s)
    td = result.tlog
    prep = result.inputs
    ps = s.replay.pipeline_settings()
    src = prep.source
    hb = td.arrays["HEARTBEAT"]
    hb = hb[(hb["sysid"] == src[0]) & (hb["compid"] == src[1])]
    autopilot = _enum_name("MAV_AUTOPILOT", hb["autopilot"][0]) if hb.shape[0] else ""
    vtype = _enum_name("MAV_TYPE", hb["type"][0]) if hb.shape[0] else ""
    start = ""
    if td.frames:
        unix_s = float(td.t_us[0]) * 1e-6
        if 946684800.0 <= unix_s <= 4102444800.0:  # 2000 … 2100, as decimal_year_of_log
            import datetime

            start = datetime.datetime.fromtimestamp(unix_s, datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    n = prep.n
    dur = prep.duration_s()
    row = _replace(
        base, system_id=int(src[0]), component_id=int(src[1]), autopilot=autopilot, vehicle_type=vtype,
        start_utc=start, duration_s=dur, imu_message=prep.message, imu_instance=int(prep.instance), imu_samples=n,
        imu_rate_hz=float(prep.rate_hz()), gnss=_has_fix(td, src), engine=result.engine,
        notes=" | ".join(result.notes),
    )  # fmt: skip
    row = _replace(row, truncated=_tlog_truncated(td), **_clipping(prep, ps), **_vibration(prep, s.vibration_window_s))
    return _second_opinion(result, row, s, autopilot_reference(result.references), phase_events(td, prep, src))


#: MAV_AUTOPILOT of each onboard log format
_AUTOPILOT_OF_FORMAT = {"dataflash": "ARDUPILOTMEGA", "ulog": "PX4"}


def _summarise_onboard(result: Any, base: FleetRow, s: AuditSettings) -> FleetRow:
    """The row of an onboard log (DataFlash, ULog): what its reader found, then the same second opinion."""
    prep = result.inputs
    li = result.log
    ps = s.replay.pipeline_settings()
    n = prep.n
    dur = prep.duration_s()
    gnss = bool(sum(prep.velocity_fixes.values())) or bool(np.any(prep.declination_rad != 0.0))
    row = _replace(
        base, system_id=int(prep.source[0]), component_id=int(prep.source[1]),
        autopilot=_AUTOPILOT_OF_FORMAT.get(li.format, ""), duration_s=dur, imu_message=prep.message,
        imu_instance=int(prep.instance), imu_samples=n, imu_rate_hz=float(prep.rate_hz()), gnss=gnss,
        engine=result.engine, notes=" | ".join(result.notes), truncated=bool(li.truncated),
    )  # fmt: skip
    row = _replace(row, **_clipping(prep, ps), **_vibration(prep, s.vibration_window_s))
    return _second_opinion(result, row, s, autopilot_reference(result.references), onboard_phase_events(li))


def _tlog_truncated(td: Any) -> bool:
    """A tlog whose last record is cut off: bytes after the last whole frame that no frame starts."""
    scan = getattr(td, "scan", None)
    if scan is None or td.data.size == 0:
        return False
    try:
        from mavahrs.protocol.fast_tlog import scan_tlog

        full = scan_tlog(td.data, None, mode="mmap")
        if len(full) == 0:
            return False
        j = len(full) - 1
        end = int(full.offset[j]) + len(full.frame(j))
        return 0 < td.data.size - end < 8 + 280  # less than one record's header and longest frame
    except Exception:  # noqa: BLE001 - only a flag: never the reason a row fails
        return False


def _second_opinion(
    result: Any, row: FleetRow, s: AuditSettings, ref: str, phase_events: list[tuple[float, str, float]]
) -> FleetRow:
    """What the daemon would have published vs the log's own attitude ``ref`` (the monitor's WARNINGs)."""
    if not ref:
        return row
    mon = s.replay.pipeline_settings().monitor
    series, t_est_ms = replay_monitor(result, mon, ref, phase_events)
    if s.plot_dir:
        row = _plot_flight(result, series, Path(s.plot_dir), ref, row)
    warns = [e for e in series.events if e.severity == _MAV_SEVERITY_WARNING and not e.update]
    ground = [e for e in series.events if e.severity == _MAV_SEVERITY_NOTICE and not e.update]
    causes = episode_causes(series.events)
    judged = np.isfinite(series.tilt_deg)
    # per boot of the autopilot (replay_monitor's NaN rows between boots): the start-up grace from its first estimate
    boot, est_boot = np.cumsum(np.isnan(series.t_ms)), np.cumsum(np.isnan(t_est_ms))
    for k in np.unique(boot).tolist():
        first = t_est_ms[(est_boot == k) & np.isfinite(t_est_ms)]
        if first.size:
            judged[boot == k] &= series.t_ms[boot == k] >= first[0] + mon.startup_grace_s * 1000.0
    tilt, hdg = series.tilt_deg[judged], np.abs(series.heading_deg[judged])
    tj = series.t_ms[judged]
    times = [e.t_ms / 1000.0 for e in warns]

    def span(t: np.ndarray, b: np.ndarray) -> float:  # s, summed over the boots
        return sum(float(np.ptp(t[b == k])) for k in np.unique(b).tolist() if (b == k).sum() > 1) / 1000.0

    if tj.size < 2:  # say why the row's divergence columns are empty
        ok = np.isfinite(series.t_ms)
        span_s = span(series.t_ms[ok], boot[ok])
        short = (f"nothing compared: the log's {span_s:.1f} s of {ref} lie within the monitor's start-up "
                 f"grace of {mon.startup_grace_s:g} s")
        row = _replace(row, notes=" | ".join(x for x in (row.notes, short) if x))
    held = series.held_note(mon)  # our IMU input too slow to judge (MonitorSettings.min_imu_rate_hz)
    if held:
        row = _replace(row, notes=" | ".join(x for x in (row.notes, "second opinion " + held) if x))
    none_judged = series.comparisons > 0 and series.held_comparisons == series.comparisons
    return _replace(
        row, reference=ref, compared_s=span(tj, boot[judged]) if tj.size > 1 else 0.0,
        inclination_rms_deg=_rms(tilt), inclination_max_deg=_max(tilt),
        heading_rms_deg=_rms(hdg), heading_max_deg=_max(hdg),
        alarms=None if none_judged else len(warns), first_alarm_s=times[0] if times else math.nan,
        alarm_times_s=";".join(f"{t:.3f}" for t in times), ground_alarms=len(ground),
        alarm_causes=";".join(causes[id(e)] for e in warns),
        ground_alarm_times_s=";".join(f"{e.t_ms / 1000.0:.3f} {e.phase}" for e in ground),
    )  # fmt: skip


def _plot_flight(result: Any, series: Any, folder: Path, ref: str, row: FleetRow) -> FleetRow:
    from mavahrs.evaluation.plots import PlotError, plot_second_opinion

    try:
        plot_second_opinion(folder / f"{Path(result.path).stem}_second_opinion.png", series,
                            title=f"{Path(result.path).name} vs {ref}")  # fmt: skip
    except PlotError as exc:  # a row is never lost to its drawing
        return _replace(row, notes=" | ".join(x for x in (row.notes, f"no plot: {exc}") if x))
    return row


def monitored_filter(tracks: Mapping[str, Any]) -> str:
    """Which of a replay's filters the second opinion judges: ``best`` where it was replayed (what the daemon
    runs by default; ``replay --filter all`` lists madgwick first, whose unaided tilt warned three times on a
    clean SITL flight), else the first."""
    return "best" if "best" in tracks else next(iter(tracks))


def replay_monitor(
    result: Any, mon: Any, ref: str, phase_events: list[tuple[float, str, float]]
) -> tuple[Any, np.ndarray]:
    """The daemon's monitor over a replay (``result``, :func:`mavahrs.replay.replay`): the published attitudes
    of the filter :func:`monitored_filter` names against the log's attitude ``ref``, with our confidence and the
    samples behind each estimate as evidence.  Returns the :class:`~mavahrs.service.monitor.MonitorSeries` and
    our estimates' times, ms.

    Where the autopilot rebooted during a tlog (:func:`~mavahrs.evaluation.tlogdata.sample_boots`), each boot is
    judged by a monitor of its own against that boot's attitudes, phase and IMUs, as the daemon resets its
    monitor at a reboot; the series (and the estimates' times) are concatenated in boot order with a NaN row between
    boots.  (Until user7 the boots were judged at once:
    a firmware_sim session with a reboot, recorded by the daemon, got a false ``IMU2 gyro off by 26.8 dps``.)"""
    from mavahrs.evaluation.tlogdata import sample_boots
    from mavahrs.replay.engine import judged_samples
    from mavahrs.service.monitor import MonitorSeries

    name = monitored_filter(result.tracks)
    sent = judged_samples(result, name)  # what the daemon publishes and judges (ReplaySettings.monitor_rate_hz)
    boot = sample_boots(result.inputs.t_us)
    td = getattr(result, "tlog", None)
    if not boot.size or boot[-1] == 0 or not hasattr(td, "arrays"):
        return _monitor_of_boot(result, mon, ref, phase_events, name, sent, None)
    from mavahrs.fleet import audit as this

    parts = [_monitor_of_boot(result, mon, ref, this.phase_events(td, result.inputs, result.inputs.source, boot=k),
                              name, sent[boot[sent] == k], k)
             for k in range(int(boot[-1]) + 1)]  # fmt: skip

    def cat(arrays: list[np.ndarray]) -> np.ndarray:  # one NaN between boots: charts break their lines there
        return np.concatenate([x for a in arrays for x in (np.full(1, np.nan), np.asarray(a, np.float64))][1:])

    series = MonitorSeries(*(cat([getattr(p[0], f) for p in parts]) for f in ("t_ms", "tilt_deg", "heading_deg")),
                           tuple(e for p in parts for e in p[0].events),
                           *(cat([getattr(p[0], f) for p in parts]) for f in ("tilt_threshold_deg", "heading_threshold_deg")),
                           sum(p[0].comparisons for p in parts), sum(p[0].held_comparisons for p in parts))  # fmt: skip
    return series, cat([p[1] for p in parts])


def _monitor_of_boot(
    result: Any, mon: Any, ref: str, phase_events: list[tuple[float, str, float]], name: str, sent: np.ndarray,
    boot: int | None,
) -> tuple[Any, np.ndarray]:  # fmt: skip
    """:func:`replay_monitor` over the estimates ``sent`` (rows) and, with ``boot``, that boot's references."""
    from mavahrs.filters.layout import FLAG_VELOCITY_AIDED, OUT_FLAGS, OUT_GAIN, OUT_HEADING_SIGMA, OUT_Q
    from mavahrs.service.monitor import input_rate_hz, monitor_series

    prep = result.inputs
    track = result.tracks[name]
    try:
        log = getattr(result, "log", None)
        imus = (onboard_imu_gyros(log) if log is not None else
                imu_gyros(getattr(result, "tlog", None), prep, result.settings.pipeline_settings(), boot=boot))  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - the IMU check is evidence, never the reason a flight fails
        _log.warning("%s: the IMUs' gyros could not be compared: %s", result.path, exc)
        imus = []
    t_est_ms = (prep.t_us[sent] // 1000).astype(np.float64)  # time_boot_ms of the frames (Pipeline)
    q_est = track.out[sent, OUT_Q : OUT_Q + 4]
    t_ref_us, q_ref = result.references[ref]
    ref_boot = getattr(result, "reference_boots", {}).get(ref)
    if boot is not None and ref_boot is not None:
        t_ref_us, q_ref = t_ref_us[ref_boot == boot], q_ref[ref_boot == boot]
    heading_valid = bool(np.any(prep.declination_rad != 0.0))  # the pipeline: declination known
    aided = (track.out[sent, OUT_FLAGS].astype(np.int64) & FLAG_VELOCITY_AIDED) != 0
    sigma = np.where(aided, track.out[sent, OUT_GAIN], np.nan)  # the ESKF's 1-σ tilt, as the pipeline passes it
    sigma_hdg = np.where(aided, track.out[sent, OUT_HEADING_SIGMA], np.nan)  # … and heading (NaN: none)
    rate = input_rate_hz(prep.t_us, sent)  # the IMU input's rate around each estimate
    series = monitor_series(t_est_ms, q_est, t_ref_us / 1000.0, q_ref, mon, heading_valid=heading_valid,
                            tilt_sigma_rad=sigma, heading_sigma_rad=sigma_hdg, phase_events=phase_events,
                            sensors=monitor_sensors(prep, sent, imus), imu_rate_hz=rate)  # fmt: skip
    return series, t_est_ms


def episode_causes(events: Any) -> dict[int, str]:
    """Per raised disagreement (``id`` of its event), the evidence it ended with: its own, or that of the
    last time it was said again with new evidence (``MonitorEvent.update``)."""
    out: dict[int, str] = {}
    current = None
    for e in events:
        if e.update and current is not None:
            out[current] = e.cause
        elif e.evidence is not None and not e.update:
            current = id(e)
            out[current] = e.cause
        else:
            current = None
    return out


def monitor_sensors(prep: Any, sent: np.ndarray, imus: Any = ()) -> Any:
    """The samples behind the estimates sent (``sent``: row indices), for the monitor's evidence: specific
    force, magnetometer, the GNSS velocity last fixed (true north), the expected field (the pipeline's)."""
    from mavahrs.filters.layout import IN_ACCEL, IN_MAG, IN_VEL, IN_VEL_AGE
    from mavahrs.service.monitor import MonitorSensors

    rows = prep.rows
    n = rows.shape[0]
    t_ms = prep.t_us.astype(np.float64) / 1000.0
    has = np.isfinite(rows[:, IN_VEL]) & np.isfinite(rows[:, IN_VEL + 1]) & np.isfinite(rows[:, IN_VEL_AGE])
    last = np.maximum.accumulate(np.where(has, np.arange(n), -1)) if n else np.zeros(0, np.int64)
    last_s = last[sent]
    ok = last_s >= 0
    idx = np.where(ok, last_s, 0)
    d = prep.declination_rad[idx]  # the rows' velocity is in the filter's (magnetic) frame: back to true north
    vn_m, ve_m = rows[idx, IN_VEL], rows[idx, IN_VEL + 1]
    vel = np.stack([vn_m * np.cos(d) - ve_m * np.sin(d), vn_m * np.sin(d) + ve_m * np.cos(d)], axis=1)
    vel[~ok] = np.nan
    vel_t = np.where(ok, t_ms[idx] - 1000.0 * rows[idx, IN_VEL_AGE], np.nan)
    refs = [(float(t_ms[min(max(i, 0), n - 1)]) if n else 0.0, float(a), float(b))
            for i, a, b in prep.mag_reference_events]  # fmt: skip
    return MonitorSensors(rows[sent, IN_ACCEL : IN_ACCEL + 3], rows[sent, IN_MAG : IN_MAG + 3], vel, vel_t, refs,
                          imus)


def imu_gyros(td: Any, prep: Any, settings: Any, boot: int | None = None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Every IMU instance's gyro in a tlog (``IMU1`` = instance 0 …; boot-clock ms, rad/s), scaled as the
    replay scales its own, for the monitor to name an IMU that is off; [] where the log has one IMU.  ``boot``:
    only the messages recorded during that boot of the autopilot (:func:`~mavahrs.evaluation.tlogdata.sample_boots`)."""
    from mavahrs.evaluation.tlogdata import IMU_TYPES, boots_of_tlog_times, scale_imu_messages
    from mavahrs.sensors.profiles import get_profile

    arrays = getattr(td, "arrays", None)
    if arrays is None:
        return []
    prof = get_profile(prep.profile)
    src = prep.source
    per: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for name in IMU_TYPES:
        a = arrays.get(name) if hasattr(arrays, "get") else arrays[name]
        ms = prof.scale_for(name)
        if a is None or not a.shape[0] or ms is None:
            continue
        a = a[(a["sysid"] == src[0]) & (a["compid"] == src[1])]
        if boot is not None and a.shape[0]:
            a = a[boots_of_tlog_times(prep, a["t_us"]) == boot]
        if not a.shape[0]:
            continue
        sc = scale_imu_messages(name, a, ms, settings.scaling)
        ok = sc["use"] & ~sc["zero"] & np.all(np.isfinite(sc["gyro"]), axis=1)
        for inst in np.unique(sc["imu"][ok]).tolist():
            sel = ok & (sc["imu"] == inst)
            per.setdefault(int(inst), []).append((sc["t_us"][sel] / 1000.0, np.array(sc["gyro"][sel])))
    if len(per) < 2:
        return []
    out = []
    for inst, parts in sorted(per.items()):
        t = np.concatenate([p[0] for p in parts])
        g = np.concatenate([p[1] for p in parts])
        order = np.argsort(t, kind="stable")
        t, g = t[order], g[order]
        keep = np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)  # re-sends once
        out.append((f"IMU{inst + 1}", t[keep], g[keep]))
    return out


def onboard_imu_gyros(li: Any) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Every IMU's gyro in an onboard log (:class:`mavahrs.logs.LogInputs` series ``imu_gyro``: a DataFlash log's
    IMU records; ``IMU1`` = instance 0 …; boot-clock ms, rad/s), as :func:`imu_gyros` gives a tlog's; [] where
    the log has one IMU (or does not say)."""
    d = (getattr(li, "series", None) or {}).get("imu_gyro")
    if d is None:
        return []
    out = []
    for inst in np.unique(d["instance"]).tolist():
        sel = d["instance"] == inst
        t = d["t_us"][sel] / 1000.0
        g = np.asarray(d["gyro_rad_s"][sel], np.float64)
        order = np.argsort(t, kind="stable")
        t, g = t[order], g[order]
        keep = (np.concatenate([[True], np.diff(t) > 0]) if t.size else np.zeros(0, bool)) & np.all(np.isfinite(g), axis=1)
        out.append((f"IMU{int(inst) + 1}", t[keep], g[keep]))
    return out if len(out) > 1 else []


def phase_events(td: Any, prep: Any, src: tuple[int, int], boot: int | None = None) -> list[tuple[float, str, float]]:
    """The flight's phase from the log's HEARTBEAT, EXTENDED_SYS_STATE and GLOBAL_POSITION_INT (boot ms); ``boot``:
    only from the messages recorded during that boot (:func:`~mavahrs.evaluation.tlogdata.sample_boots`)."""
    from mavahrs.evaluation.tlogdata import boots_of_tlog_times, tlog_to_autopilot_us
    from mavahrs.service.monitor import phase_events_of_arrays

    def of_src(name: str) -> np.ndarray:
        a = td.arrays.get(name) if hasattr(td.arrays, "get") else td.arrays[name]
        if a is None or not a.shape[0]:
            return np.zeros(0)
        a = a[(a["sysid"] == src[0]) & (a["compid"] == src[1])]
        return a[boots_of_tlog_times(prep, a["t_us"]) == boot] if boot is not None and a.shape[0] else a

    hb, ess, gpi = of_src("HEARTBEAT"), of_src("EXTENDED_SYS_STATE"), of_src("GLOBAL_POSITION_INT")
    hb_args = ess_args = pos_args = None
    if hb.shape[0]:
        hb_args = (tlog_to_autopilot_us(td, prep, hb["t_us"]) / 1000.0, hb["base_mode"])
    if ess.shape[0]:
        ess_args = (tlog_to_autopilot_us(td, prep, ess["t_us"]) / 1000.0, ess["landed_state"])
    if gpi.shape[0]:
        v = np.sqrt(gpi["vx"].astype(float) ** 2 + gpi["vy"].astype(float) ** 2 + gpi["vz"].astype(float) ** 2) * 0.01
        pos_args = (gpi["time_boot_ms"].astype(float), gpi["relative_alt"].astype(float) * 1e-3, v)
    ev = phase_events_of_arrays(hb_args, ess_args, pos_args)
    return [e for e in ev if math.isfinite(e[0])]


def onboard_phase_events(li: Any) -> list[tuple[float, str, float]]:
    """The flight's phase from an onboard log's ``armed`` and ``landed`` series (:class:`mavahrs.logs.LogInputs`;
    DataFlash ARM/EV, ULog vehicle_status / vehicle_land_detected), boot ms; [] when it logged neither (every
    disagreement is then judged as in flight, its phase ``unknown``)."""
    from mavahrs.service.monitor import phase_events_of_arrays

    series = getattr(li, "series", None) or {}
    arm, land = series.get("armed"), series.get("landed")
    hb = (arm["t_us"] / 1000.0, arm["base_mode"]) if arm is not None else None
    ess = (land["t_us"] / 1000.0, land["landed_state"]) if land is not None else None
    return phase_events_of_arrays(hb, ess) if hb is not None or ess is not None else []


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if x.size else math.nan


def _max(x: np.ndarray) -> float:
    return float(np.max(x)) if x.size else math.nan


def _has_fix(td: Any, src: tuple[int, int]) -> bool:
    gpi = td.arrays["GLOBAL_POSITION_INT"]
    gpi = gpi[(gpi["sysid"] == src[0]) & (gpi["compid"] == src[1])]
    if gpi.shape[0] and np.any((gpi["lat"] != 0) | (gpi["lon"] != 0)):
        return True
    raw = td.arrays["GPS_RAW_INT"]
    raw = raw[(raw["sysid"] == src[0]) & (raw["compid"] == src[1])]
    return bool(raw.shape[0] and np.any(raw["fix_type"] >= 3))


def _clipping(prep: Any, ps: Any) -> dict[str, float]:
    """Fractions of the fed samples at the sensor's limit, by the scaling's own saturation rule."""
    from mavahrs.filters.layout import IN_ACCEL, IN_GYRO
    from mavahrs.sensors.profiles import get_profile

    n = prep.n
    if n == 0:
        return {}
    prof = get_profile(prep.profile)
    scale = prof.scale_for(prep.message) or prof.scale_for(prof.primary_message)  # onboard logs: "IMU"
    if scale is None:
        return {}
    frac = ps.scaling.saturation_fraction
    gyro = prep.rows[:, IN_GYRO : IN_GYRO + 3]
    accel = prep.rows[:, IN_ACCEL : IN_ACCEL + 3]
    with np.errstate(invalid="ignore"):
        g = np.any(np.abs(gyro) >= frac * scale.gyro_range_rad_s, axis=1)
        a = np.any(np.abs(accel) >= frac * scale.accel_range_m_s2, axis=1) | ~np.all(np.isfinite(accel), axis=1)
    return {"gyro_clip_fraction": float(g.mean()), "accel_clip_fraction": float(a.mean())}


def _vibration(prep: Any, window_s: float) -> dict[str, float]:
    """Per axis RMS of the accelerometer minus its centred moving average (finite samples), m/s²."""
    from mavahrs.filters.layout import IN_ACCEL

    accel = prep.rows[:, IN_ACCEL : IN_ACCEL + 3]
    accel = accel[np.all(np.isfinite(accel), axis=1)]
    rate = prep.rate_hz()
    k = max(3, int(round(window_s * rate)) | 1)  # odd window, samples
    if accel.shape[0] < 2 * k or rate <= 0:
        return {}
    c = np.cumsum(np.vstack([np.zeros((1, 3)), accel]), axis=0)
    mean = (c[k:] - c[:-k]) / k  # mean of accel[i : i + k]
    hp = accel[k // 2 : k // 2 + mean.shape[0]] - mean
    v = np.sqrt(np.mean(hp * hp, axis=0))
    return {"vibration_x_m_s2": float(v[0]), "vibration_y_m_s2": float(v[1]), "vibration_z_m_s2": float(v[2])}


# --------------------------------------------------------------------------- which logs


@dataclass(frozen=True)
class LogSelection:
    """What :func:`select_logs` found: the flight logs to audit, and the files it left out (not logs)."""

    logs: list[Path]
    skipped: list[Path]


def is_log_file(path: Path) -> bool:
    """A flight log by its name (``.tlog``, ``.BIN``, ``.ulg``, any case) or by its first bytes
    (:func:`mavahrs.logs.sniff`: a renamed log still counts; a ``.tlog`` that is damaged too, so it gets
    its row with the error)."""
    from mavahrs.logs import sniff

    return path.suffix.lower() in LOG_SUFFIXES or sniff(path) is not None


def select_logs(items: Sequence[str]) -> LogSelection:
    """Files as given; folders searched recursively; globs (``**`` recursive) expanded — keeping the flight
    logs (:func:`is_log_file`) and listing the other files as skipped.

    ``mavahrs audit fleet/*`` (the shell expands the glob) or a folder also holding the audit's own
    table, plots and notes: those are not failures of the fleet, only files that are not logs.
    Sorted, duplicates removed.  Raises DataError for an item that matches nothing, and when every
    file given is skipped (none is a flight log).
    """
    from mavahrs.errors import DataError

    out: dict[str, Path] = {}
    skipped: dict[str, Path] = {}
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = [q for q in p.rglob("*") if q.is_file()]
        elif p.exists():
            found = [p]
        elif glob.has_magic(item):
            found = [Path(q) for q in glob.glob(item, recursive=True) if Path(q).is_file()]
        else:
            found = []
        if not found and not p.is_dir():
            raise DataError(f"{item}: no such log (file, folder or glob)")
        for q in found:
            key = str(q.absolute())
            if key in out or key in skipped:
                continue
            (out if is_log_file(q) else skipped)[key] = q.absolute()
    if not out and skipped:
        names = skipped_text([skipped[k] for k in sorted(skipped)])
        raise DataError(f"no flight log among the {len(skipped)} files given ({names})")
    return LogSelection([out[k] for k in sorted(out)], [skipped[k] for k in sorted(skipped)])


def skipped_text(skipped: Sequence[Path], shown: int = 3) -> str:
    """``a.csv, notes.txt, plot.png and 2 more``: the first names of the files left out."""
    names = [q.name for q in skipped[:shown]]
    more = len(skipped) - len(names)
    return ", ".join(names) + (f" and {more} more" if more > 0 else "")


def expand_logs(items: Sequence[str]) -> list[Path]:
    """The flight logs of :func:`select_logs` (files that are not logs left out)."""
    return select_logs(items).logs


# --------------------------------------------------------------------------- tables


def _table_format(path: Path) -> str:
    suf = path.suffix.lower()
    if suf in (".parquet", ".pq"):
        return "parquet"
    if suf == ".csv":
        return "csv"
    raise ValueError(f"{path}: the table must be .parquet or .csv")


def _arrow_schema() -> Any:
    try:
        import pyarrow as pa
    except ImportError as exc:
        from mavahrs.errors import ConfigError

        raise ConfigError("Parquet needs pyarrow: pip install 'mavahrs[fleet]' (or write a .csv)") from exc
    types = {"str": pa.string(), "int": pa.int64(), "float": pa.float64(), "bool": pa.bool_()}
    return pa.schema([(name, types[kind]) for name, kind in _KINDS.items()])


def write_table(path: str | Path, rows: Iterable[FleetRow]) -> None:
    """Write the rows (sorted by path) to a temporary file beside ``path``, then replace it."""
    path = Path(path)
    fmt = _table_format(path)
    rows = sorted(rows, key=lambda r: r.path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        if fmt == "parquet":
            import pyarrow as pa
            import pyarrow.parquet as pq

            schema = _arrow_schema()
            pq.write_table(pa.Table.from_pylist([r.as_dict() for r in rows], schema=schema), tmp)
        else:
            with open(tmp, "w", newline="", encoding="utf-8") as f:
                w = csv.writer(f)
                w.writerow(list(_KINDS))
                for r in rows:
                    w.writerow([_csv_cell(v) for v in r.as_dict().values()])
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _csv_cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)  # shortest text that reads back to the same float
    return str(v)


def _from_text(kind: str, text: str) -> Any:
    if kind == "str":
        return text
    if text == "":
        return math.nan if kind == "float" else None
    if kind == "int":
        return int(text)
    if kind == "float":
        return float(text)
    return text == "True"


def read_table(path: str | Path) -> list[FleetRow]:
    """The rows of a table written by :func:`write_table` ([] if it does not exist)."""
    path = Path(path)
    fmt = _table_format(path)
    if fmt == "parquet":
        _arrow_schema()  # pyarrow missing: said now, also for a table still to be written
    if not path.exists():
        return []
    if fmt == "parquet":
        import pyarrow.parquet as pq

        dicts = pq.read_table(path).to_pylist()
        for d in dicts:
            for k, kind in _KINDS.items():
                if kind == "float" and d.get(k) is None:
                    d[k] = math.nan
    else:
        with open(path, newline="", encoding="utf-8") as f:
            dicts = [{k: _from_text(_KINDS[k], v) for k, v in d.items() if k in _KINDS} for d in csv.DictReader(f)]
    names = set(_KINDS)
    return [FleetRow(**{k: v for k, v in d.items() if k in names}) for d in dicts]


# --------------------------------------------------------------------------- the run


def serial_map(fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
    """(index, fn(item)) one after the other, in this process: the engine without Dask."""
    for i, item in enumerate(items):
        yield i, fn(item)


@dataclass
class AuditRun:
    """What :func:`run_audit` did.

    Attributes:
        rows: one per log of this run, in the order given.
        replayed: logs replayed now; reused: logs whose row was already in the table.
        samples: IMU samples fed to the filter in the logs replayed now.
        wall_s: wall time of the run, s.
    """

    rows: list[FleetRow]
    replayed: int
    reused: int
    samples: int
    wall_s: float

    @property
    def samples_per_s(self) -> float:
        """IMU samples replayed per second of wall time."""
        return self.samples / self.wall_s if self.wall_s > 0 else math.nan


@dataclass
class AuditPlan:
    """Which logs a run replays.  known: the rows of the first existing table, by path; done: rows reused
    (index into the logs → row); todo: indices of the logs to replay."""

    known: dict[str, FleetRow]
    done: dict[int, FleetRow]
    todo: list[int]


def plan_audit(logs: Sequence[Path], tables: Sequence[str | Path] = (), force: bool = False) -> AuditPlan:
    """Rows already in the first existing table for the same (path, size, mtime) are reused unless ``force``."""
    known: dict[str, FleetRow] = {}
    for t in tables:
        rows = read_table(t)
        if rows:
            known = {r.path: r for r in rows}
            break
    done: dict[int, FleetRow] = {}
    todo: list[int] = []
    for i, p in enumerate(logs):
        prev = known.get(str(p))
        st = p.stat() if p.exists() else None
        if not force and prev is not None and st is not None and prev.key() == (str(p), st.st_size, st.st_mtime_ns):
            done[i] = prev
        else:
            todo.append(i)
    return AuditPlan(known, done, todo)


def lost_row(path: str | Path, exc: BaseException) -> FleetRow:
    """The row of a log whose task failed outside :func:`summarise_log` (e.g. its worker process died)."""
    p = Path(path).absolute()
    try:
        st = p.stat()
        size, mtime = int(st.st_size), int(st.st_mtime_ns)
    except OSError:
        size = mtime = -1
    return FleetRow(str(p), size, mtime, error=f"the task replaying this log failed: {type(exc).__name__}: {exc}")


def run_audit(
    logs: Sequence[Path],
    fn: Callable[[Any], FleetRow],
    mapper: Callable[[Callable[[Any], Any], Sequence[Any]], Iterator[tuple[int, Any]]] = serial_map,
    *,
    tables: Sequence[str | Path] = (),
    force: bool = False,
    flush_every_s: float = 2.0,
    on_row: Callable[[FleetRow], None] | None = None,
    plan: AuditPlan | None = None,
) -> AuditRun:
    """Summarise ``logs`` with ``fn`` (:func:`summarise_log` bound to its settings) through ``mapper``.

    What to replay is :func:`plan_audit` (or ``plan``, made by the caller):
    every table keeps the rows of other logs it held.  Tables are rewritten at
    most every ``flush_every_s`` and once more at the end, also on an
    interruption (KeyboardInterrupt).
    """
    t0 = time.perf_counter()
    plan = plan if plan is not None else plan_audit(logs, tables, force)
    known, done, todo = plan.known, dict(plan.done), plan.todo
    reused = len(done)
    samples = 0
    last = time.monotonic()

    def flush() -> None:
        if tables:
            merged = dict(known)
            merged.update({r.path: r for r in done.values()})
            for t in tables:
                write_table(t, merged.values())

    try:
        for k, row in mapper(fn, [logs[i] for i in todo]):
            done[todo[k]] = row
            samples += row.imu_samples or 0
            if on_row is not None:
                on_row(row)
            if tables and time.monotonic() - last >= flush_every_s:
                flush()
                last = time.monotonic()
    finally:
        flush()
    return AuditRun([done[i] for i in sorted(done)], len(todo), reused, samples, time.perf_counter() - t0)


# --------------------------------------------------------------------------- summary


def _severity(r: FleetRow) -> tuple[float, ...]:
    """Sort key, worst first: alarms, then the largest inclination and heading divergences."""

    def neg(x: float) -> float:
        return -x if math.isfinite(x) else math.inf

    return (-(r.alarms or 0), neg(r.inclination_max_deg), neg(r.heading_max_deg), 0.0)


def _f(x: float, fmt: str, width: int) -> str:
    return f"{x:{width}{fmt}}" if math.isfinite(x) else f"{'–':>{width}}"


def format_startup(
    startup_s: float | None, cluster_s: float | None, kernels_s: float | None, compiled_s: float | None, *,
    local: bool = True,
) -> str:  # fmt: skip
    """What the run cost before its first log (the summary's second line): the cluster's start and the filter
    kernels, compiled (a cold cache: the first run of a version) or loaded from the cache.

    ``startup_s``: start of the run to the first task (None: no cluster, the logs replayed here); ``cluster_s``:
    the cluster's start (or connection) within it; ``kernels_s``: loading or compiling the kernels in this
    process (run beside the cluster's start; None: not done here); ``compiled_s``: of that, compiling (None:
    nothing compiled, the cache was warm).
    """
    cold = compiled_s is not None and compiled_s >= 0.5
    what = "connecting to the cluster" if not local else "starting the local cluster"
    if startup_s is None:  # serial: the first log's replay compiled them (inside the replay time above)
        if not cold:
            return ""
        return (f"of which {compiled_s:.0f} s compiling the filter kernels: the first run of this version "
                "(kept in the user's cache folder: later runs load them in seconds; `mavahrs warm-up` compiles them "
                "ahead of time)")  # fmt: skip
    parts = [f"{what} {cluster_s:.1f} s" if cluster_s is not None else what]
    if kernels_s is not None:
        if cold:
            parts.append(f"meanwhile the filter kernels compiled once in this process in {compiled_s:.0f} s, "
                         "for every worker to load: the first run of this version (kept in the user's "
                         "cache folder: later runs start in seconds; `mavahrs warm-up` compiles them ahead of time)")  # fmt: skip
        else:
            parts.append(f"meanwhile the filter kernels loaded from the cache in {kernels_s:.1f} s")
    return f"start-up before the first log {startup_s:.1f} s, not in the figures above: " + "; ".join(parts)


def format_summary(run: AuditRun, *, top: int = 10, engine: str = "", startup: str = "") -> str:
    """The printed summary: counts (and ``startup``, :func:`format_startup`), then the worst flights first,
    then the unreadable logs."""
    rows = run.rows
    bad = [r for r in rows if not r.ok]
    good = [r for r in rows if r.ok]
    flagged = [r for r in good if r.flagged]
    lines = [
        f"audited {len(rows)} logs ({run.replayed} replayed, {run.reused} already in the table) in "
        f"{run.wall_s:.1f} s{(' on ' + engine) if engine else ''}: {len(flagged)} flagged, {len(bad)} unreadable"
    ]
    if run.samples:
        lines[0] += f"; {run.samples} IMU samples, {run.samples_per_s:.3g} samples/s"
    if startup:
        lines.append(startup)
    if flagged:
        from mavahrs.replay.engine import LOW_RATE_HZ

        def coarse(r: FleetRow) -> str:  # an IMU below replay's 50 Hz: too slow for attitude filtering
            return f" (IMU {r.imu_rate_hz:.0f} Hz: too slow to judge)" if 0 < r.imu_rate_hz < LOW_RATE_HZ else ""

        lines.append("flagged: the autopilot's attitude disagreed with mavahrs (second-opinion monitor WARNING) in "
                     + ", ".join(f"{Path(r.path).name} at {r.alarm_times_s.replace(';', ', ')} s{coarse(r)}"
                                 for r in flagged))  # fmt: skip
    if good:
        head = (f"{'log':<26}{'dur s':>7}{'IMU Hz':>8}{'incl rms':>9}{'max':>7}{'hdg rms':>9}{'max':>7}"
                f"{'alarms':>7}{'first s':>9}{'vib m/s²':>9}{'clip %':>7}")  # fmt: skip
        lines += ["", f"worst flights first (divergence from the log's own attitude, deg; top {min(top, len(good))} "
                  f"of {len(good)}):", head, "─" * len(head)]  # fmt: skip
        for r in sorted(good, key=_severity)[:top]:
            name = Path(r.path).name
            name = name if len(name) <= 25 else name[:24] + "…"
            vib = max((v for v in (r.vibration_x_m_s2, r.vibration_y_m_s2, r.vibration_z_m_s2) if math.isfinite(v)),
                      default=math.nan)  # fmt: skip
            clip = 100.0 * max(r.gyro_clip_fraction, r.accel_clip_fraction)
            lines.append(
                f"{name:<26}{_f(r.duration_s, '.1f', 7)}{_f(r.imu_rate_hz, '.0f', 8)}"
                f"{_f(r.inclination_rms_deg, '.2f', 9)}{_f(r.inclination_max_deg, '.1f', 7)}"
                f"{_f(r.heading_rms_deg, '.2f', 9)}{_f(r.heading_max_deg, '.1f', 7)}{r.alarms if r.alarms is not None else '–':>7}"
                f"{_f(r.first_alarm_s, '.1f', 9)}{_f(vib, '.2f', 9)}{_f(clip, '.2f', 7)}"
            )
    cut = [r for r in good if r.truncated]
    if cut:
        lines += ["", "truncated (cut off inside a record; read up to the last whole one):"] + [
            f"  {Path(r.path).name}" for r in cut]  # fmt: skip
    bare = [r for r in good if not r.reference]
    if bare:
        lines += ["", "not compared (no autopilot attitude in the log):"] + [
            f"  {Path(r.path).name}: {r.imu_samples or 0} IMU samples" + (f"; {r.notes}" if r.notes else "")
            for r in bare]  # fmt: skip
    held = sorted((r for r in good if "second opinion not judged" in r.notes), key=lambda r: r.path)
    if held:
        lines += ["", "second opinion not judged (our IMU input too slow; alarms '–' where none was):"] + [
            f"  {Path(r.path).name}: IMU {r.imu_rate_hz:.0f} Hz, "
            + next(n for n in r.notes.split(" | ") if n.startswith("second opinion not judged"))[len("second opinion "):]
            for r in held]  # fmt: skip
    short = [r for r in good if r.reference and not r.compared_s]
    if short:
        lines += ["", "not compared (too short):"] + [
            f"  {Path(r.path).name}: " + next((n for n in r.notes.split(" | ") if n.startswith("nothing compared")),
                                            f"{r.duration_s:.1f} s")
            for r in short]  # fmt: skip
    if bad:
        lines += ["", "unreadable:"] + [f"  {Path(r.path).name}: {r.error}" for r in bad]
    return "\n".join(lines)

