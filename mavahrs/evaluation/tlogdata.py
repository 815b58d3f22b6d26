r"""Telemetry logs as filter inputs, in bulk, exactly as the daemon's pipeline would feed them.

:func:`read_tlog_data` decodes a tlog once with the bulk reader
(:mod:`mavahrs.protocol.fast_tlog`: pymavlink's messages and order at
compiled speed).  :func:`prepare_inputs` then does, with numpy over whole
arrays, what :class:`mavahrs.service.pipeline.Pipeline` does per message:

* the IMU source is the first autopilot HEARTBEAT's system/component (or the
  configured one); IMU messages before it, or from elsewhere, are not used;
* scaling with the profile's units, saturation and validity checks
  (the compiled steps :class:`mavahrs.sensors.scaling.Scaler` calls per message, in a loop);
* exact re-sends (same stamp and values as the previous message of the same
  kind and instance: the pipeline's step, :mod:`mavahrs.ingest.resend`, in its
  compiled loop) dropped before anything else and counted (``counts["exact_duplicates"]``);
* the IMU instance the selector feeds: the pipeline's step
  (:func:`mavahrs.sensors.imu_select.select_step`) in its compiled loop over every
  message of every instance (``ingest/arrays.py`` ``select_over_arrays``): instances
  whose accelerometer and gyro are all zero are absent (an ArduSub SCALED_IMU2);
  all-zero samples are never fed;
* timing from the sample timestamps (the pipeline's timeline: duplicates and
  reordered samples dropped; a gap reaches the filter as a long ``dt``);
* the calibration (gyro temperature model, magnetometer calibration, axis
  remap) as :class:`~mavahrs.sensors.calibration.Calibrator` applies it;
* the GNSS velocity of the configured source (GLOBAL_POSITION_INT,
  GPS_RAW_INT, GPS2_RAW, chosen by the pipeline's own
  :class:`~mavahrs.sensors.velocity.VelocitySelector` over the messages in
  order, at their tlog times) into the next fed row, rotated into the
  magnetic frame, with its age (``IN_VEL_AGE``), and the declination applied
  to outputs, from a real :class:`~mavahrs.sensors.geomag.DeclinationSource`
  fed the position and time messages in order.

What the arrays cannot mirror in bulk — a fail-over to another instance (the pipeline
back-fills the new instance's recent samples), an autopilot reboot, a timeline
that corrects timestamps — raises :class:`FastPathUnsupported`; replay then
runs the pipeline itself, message by message (same results, slower).  A test
checks that both give identical attitudes and frames.

:func:`load_tlog_recording` turns the result into an evaluation
:class:`~mavahrs.evaluation.datasets.Recording` whose reference is the
simulator's truth (SIM_STATE quaternion, else SIMSTATE Euler angles).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import DataError, empty_window_error
from mavahrs.evaluation.datasets import Recording
from mavahrs.filters.layout import (
    IN_ACCEL,
    IN_CURRENT,
    IN_DT,
    IN_GYRO,
    IN_MAG,
    IN_POS,
    IN_VEL,
    IN_VEL_AGE,
    IN_WIDTH,
)
from mavahrs.ingest.arrays import (  # noqa: F401 - the sample chain over arrays, shared by every log reader
    _GAP_DT_S,
    FastPathUnsupported,
    PreparedInputs,
    _velocity_setting,
    select_over_arrays,
    timeline_over_arrays,
)
from mavahrs.sensors.sample import ACCEL, GYRO, MAG

__all__ = [
    "recording_from_inputs",
    "REPLAY_TYPES",
    "REFERENCE_TYPES",
    "TlogData",
    "PreparedInputs",
    "FastPathUnsupported",
    "read_tlog_data",
    "prepare_inputs",
    "references",
    "references_with_boots",
    "sample_boots",
    "boots_of_tlog_times",
    "tlog_to_autopilot_us",
    "scale_imu_messages",
    "load_tlog_recording",
    "cut_recording",
    "decimal_year_of_log",
    "true_rates",
    "interpolate_attitude",
    "run_pipelines",
    "pipeline_inputs",
]

Array = NDArray[np.float64]

IMU_TYPES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
POSITION_TYPES = ("GLOBAL_POSITION_INT", "GPS_RAW_INT", "GPS2_RAW", "HOME_POSITION", "SYSTEM_TIME")
REFERENCE_TYPES = ("ATTITUDE", "AHRS2", "SIMSTATE", "SIM_STATE", "HIL_STATE_QUATERNION")
#: What replay reads from a log.
#: battery current (the compass's motor interference, :mod:`mavahrs.sensors.current`)
CURRENT_TYPES = ("SYS_STATUS", "BATTERY_STATUS")
#: the autopilot's parameters (PX4's CAL_MAG*, for SCALED_IMU's raw field: ``mavahrs.ingest.autopilot_mag_bias``)
PARAM_TYPES = ("PARAM_VALUE",)
REPLAY_TYPES = (IMU_TYPES + ("HEARTBEAT", "EXTENDED_SYS_STATE") + POSITION_TYPES + REFERENCE_TYPES + CURRENT_TYPES
                + PARAM_TYPES)  # fmt: skip

_MAV_AUTOPILOT_INVALID = 8
_NAN = math.nan


# --------------------------------------------------------------------------- reading


@dataclass
class TlogData:
    """A tlog decoded in bulk.

    Attributes:
        path: the file.
        data: its bytes.
        msgid, t_us: per frame of :data:`REPLAY_TYPES`, in pymavlink's order.
        offset, in_side: where each frame is (to find it in a full scan).
        arrays: message type → structured array (fields of :func:`read_tlog_arrays`).
        pos: message type → positions of its frames in the frame order.
        scan: the underlying :class:`~mavahrs.protocol.fast_tlog.TlogScan`.
    """

    path: str
    data: NDArray[np.uint8]
    msgid: NDArray[np.int32]
    t_us: NDArray[np.int64]
    arrays: dict[str, np.ndarray]
    pos: dict[str, NDArray[np.int64]]
    scan: Any

    @property
    def frames(self) -> int:
        return int(self.msgid.shape[0])

    def message(self, type_name: str, k: int) -> _Msg:
        """The ``k``-th message of a type as an attribute object (``get_type()``, fields, header)."""
        return _Msg(type_name, self.arrays[type_name][k])


class _Msg:
    """A decoded row with the pymavlink attribute interface the pipeline's helpers use."""

    __slots__ = ("_type", "_row")

    def __init__(self, type_name: str, row: Any) -> None:
        self._type = type_name
        self._row = row

    def get_type(self) -> str:
        return self._type

    def get_srcSystem(self) -> int:  # noqa: N802 - pymavlink's name
        return int(self._row["sysid"])

    def get_srcComponent(self) -> int:  # noqa: N802
        return int(self._row["compid"])

    def __getattr__(self, name: str) -> Any:
        try:
            v = self._row[name]
        except (ValueError, KeyError, IndexError):
            raise AttributeError(name) from None
        return v.item() if hasattr(v, "item") else v


def read_tlog_data(path: str | Path) -> TlogData:
    """Decode the message types replay needs from a tlog (bulk, pymavlink-exact)."""
    from mavahrs.protocol.fast_tlog import decode_scan, scan_positions, scan_tlog

    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: no such tlog")
    data = np.fromfile(p, np.uint8)
    if data.size == 0:
        raise DataError(f"{p}: empty file")
    scan = scan_tlog(data, list(REPLAY_TYPES), mode="mmap")
    pos: dict[str, NDArray[np.int64]] = scan_positions(scan, list(REPLAY_TYPES))
    arrays = decode_scan(scan, list(REPLAY_TYPES), positions=pos)  # = read_tlog_arrays(data, REPLAY_TYPES)
    for name in REPLAY_TYPES:
        if pos[name].shape[0] != arrays[name].shape[0]:  # pragma: no cover - both come from the same emulation
            raise DataError(f"{p}: {name}: the bulk decoder and the frame scan disagree")
    return TlogData(
        path=str(p), data=data, msgid=scan.msgid, t_us=scan.t_us.view(np.int64), arrays=arrays, pos=pos, scan=scan
    )


def truncation_notes(td: TlogData) -> list[str]:
    """The note every command reading ``td`` puts in its header when the log ends inside a frame."""
    from mavahrs.protocol.fast_tlog import truncated_frame_at

    at = truncated_frame_at(td.scan) if td.scan is not None else None
    if at is None:
        return []
    return [f"the log ends inside a frame at byte {at} (of {int(td.data.shape[0])}): truncated? "
            "(everything before it is used)"]  # fmt: skip


def decimal_year_of_log(td: TlogData) -> float | None:
    """The date of the recording from its first record's Unix timestamp (None if implausible)."""
    if td.frames == 0:
        return None
    unix_s = float(td.t_us[0]) * 1e-6
    if not 946684800.0 <= unix_s <= 4102444800.0:  # 2000 … 2100
        return None
    from mavahrs.sensors.geomag import decimal_year_from_unix_s

    return float(decimal_year_from_unix_s(unix_s))


# --------------------------------------------------------------------------- prepared inputs


def _source_and_profile(td: TlogData, settings: Any) -> tuple[tuple[int, int], int, str]:
    """(source, position of its first heartbeat, profile name), as Pipeline._on_heartbeat decides."""
    from mavahrs.sensors.profiles import profile_for_autopilot

    hb = td.arrays["HEARTBEAT"]
    hpos = td.pos["HEARTBEAT"]
    s = settings
    ok = hb["autopilot"] != _MAV_AUTOPILOT_INVALID
    if s.source_system is not None:
        ok &= hb["sysid"] == s.source_system
    if s.source_component is not None:
        ok &= hb["compid"] == s.source_component
    if s.source_system is not None and s.source_component is not None and s.autopilot_profile != "auto":
        return (int(s.source_system), int(s.source_component)), -1, s.autopilot_profile
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        raise DataError(_no_source_message(td, s))
    k = int(idx[0])
    src = (int(hb["sysid"][k]), int(hb["compid"][k]))
    prof = profile_for_autopilot(int(hb["autopilot"][k])).name if s.autopilot_profile == "auto" else s.autopilot_profile
    return src, int(hpos[k]), prof


SOURCE_HINT = "--source SYSID[:COMPID], or source_system/source_component in the config"


def imu_senders(td: TlogData, settings: Any = None) -> list[tuple[int, int]]:
    """(system, component) of every sender of IMU messages in the log (within the settings' source), sorted."""
    found: set[tuple[int, int]] = set()
    for name in IMU_TYPES:
        a = td.arrays[name]
        if a.shape[0]:
            found.update(zip(a["sysid"].tolist(), a["compid"].tolist(), strict=True))
    if settings is not None and settings.source_system is not None:
        found = {x for x in found if x[0] == settings.source_system}
    if settings is not None and settings.source_component is not None:
        found = {x for x in found if x[1] == settings.source_component}
    return sorted(found)


def _has_autopilot_heartbeat(td: TlogData, s: Any) -> bool:
    hb = td.arrays["HEARTBEAT"]
    ok = hb["autopilot"] != _MAV_AUTOPILOT_INVALID
    if s.source_system is not None:
        ok &= hb["sysid"] == s.source_system
    if s.source_component is not None:
        ok &= hb["compid"] == s.source_component
    return bool(ok.any())


def resolve_source(td: TlogData, settings: Any) -> tuple[Any, str | None]:
    """The pipeline settings to read ``td`` with, and a note when the source was chosen automatically.

    The daemon takes its IMU data from the autopilot whose HEARTBEAT it sees
    first.  Logs exported without HEARTBEATs (``mavlogdump.py --types``, some
    ground stations' exports) have none: when the IMU messages there (within
    ``source_system``/``source_component`` when set) all come from one
    system/component, that one is the source, with the scaling profile
    ``autopilot_profile`` (``generic`` when ``auto``: nothing says which
    autopilot it is).  Otherwise the settings are returned unchanged (and
    reading the log fails with a message naming ``--source``).
    """
    import dataclasses

    s = settings
    if s.source_system is not None and s.source_component is not None and s.autopilot_profile != "auto":
        return s, None
    if _has_autopilot_heartbeat(td, s):
        return s, None
    senders = imu_senders(td, s)
    if len(senders) != 1:
        return s, None
    (sysid, compid), = senders
    profile = "generic" if s.autopilot_profile == "auto" else s.autopilot_profile
    chosen = dataclasses.replace(s, source_system=sysid, source_component=compid, autopilot_profile=profile)
    why = "as --source asks" if s.source_system is not None else "its only sender"
    note = (
        f"no autopilot HEARTBEAT in the log: using the IMU data of system {sysid}, component {compid} "
        f"({why}), with the {profile} scaling profile (--source and --profile choose otherwise)"
    )
    return chosen, note


def _no_source_message(td: TlogData, s: Any) -> str:
    """Why no source could be chosen: no MAVLink at all, no IMU data, or several senders."""
    from mavahrs.protocol.fast_tlog import scan_tlog

    senders = imu_senders(td, s)
    wanted = ""
    if s.source_system is not None:
        wanted = f" from system {s.source_system}" + (
            f", component {s.source_component}" if s.source_component is not None else ""
        )
    if len(senders) > 1:
        listed = ", ".join(f"{a}:{b}" for a, b in senders)
        return (f"{td.path}: no autopilot HEARTBEAT{wanted}, and IMU data from several senders "
                f"(SYSID:COMPID {listed}): choose one with {SOURCE_HINT}")  # fmt: skip
    if Path(td.path).suffix.lower() in (".mat", ".csv"):  # a recording with truth: BROAD, RepoIMU, the CSV format
        return (f"{td.path}: not a flight log (no MAVLink IMU messages): a recording with a reference attitude "
                "(BROAD .mat, RepoIMU or documented .csv) is scored with `mavahrs evaluate` and drawn with "
                "`mavahrs plot`")  # fmt: skip
    if td.frames == 0 and scan_tlog(td.data, None).msgid.shape[0] == 0:
        return (f"{td.path}: no MAVLink messages in this file: expected a telemetry log (.tlog, "
                "as MAVProxy, QGroundControl, Mission Planner and mavahrs write them), an ArduPilot DataFlash "
                "log (.BIN) or a PX4 ULog (.ulg)")  # fmt: skip
    others = imu_senders(td) if wanted else []
    if others:  # --source names a system that sent none: say who did (until user8: "… and no IMU messages")
        listed = ", ".join(f"{a}:{b}" for a, b in others)
        return (f"{td.path}: no autopilot HEARTBEAT and no IMU messages{wanted}; the log's IMU messages come "
                f"from SYSID:COMPID {listed} (--source)")  # fmt: skip
    return f"{td.path}: no autopilot HEARTBEAT{wanted} and no IMU messages (RAW_IMU, SCALED_IMU*, HIGHRES_IMU)"


def scale_imu_messages(name: str, a: np.ndarray, ms: Any, scaling: Any) -> dict[str, Any]:
    """The scaling step (:func:`~mavahrs.sensors.scaling.scale_int_row` / ``scale_float_row``) over one message type."""
    from mavahrs.sensors.profiles import INSTANCE_OF_MESSAGE
    from mavahrs.sensors.scaling import (
        HIGHRES_GYRO_BITS,
        INVALID_SHIFT,
        ZERO,
        scale_constants,
        scale_float_rows,
        scale_int_rows,
    )

    n = a.shape[0]
    c = scale_constants(ms, scaling)
    # the scaling step over every message (one compiled loop), written in place in an array shaped like the
    # filter's input rows, which the common case (one message type, every sample fed) then uses as they
    # are: no copy, no second 150 MB
    block = np.empty((n, IN_WIDTH))
    codes = np.empty(n, np.int64)
    cols = [a[f] for f in ("xgyro", "ygyro", "zgyro", "xacc", "yacc", "zacc", "xmag", "ymag", "zmag")]
    if ms.integer_fields:  # RAW_IMU, SCALED_IMU*
        scale_int_rows(*cols, c, block, codes)
        use = np.ones(n, bool)
    else:  # HIGHRES_IMU: only messages with a new gyro are samples (Scaler.scale: None)
        upd = a["fields_updated"].astype(np.int64)
        scale_float_rows(*(x.astype(np.float64) for x in cols), upd, c, block, codes)
        use = (upd & HIGHRES_GYRO_BITS) == HIGHRES_GYRO_BITS
    gyro = block[:, IN_GYRO : IN_GYRO + 3]
    accel = block[:, IN_ACCEL : IN_ACCEL + 3]
    mag = block[:, IN_MAG : IN_MAG + 3]
    sat = codes & 7
    inv = (codes >> INVALID_SHIFT) & 7
    zero = (codes & ZERO) != 0
    # temperature
    temp = np.full(n, _NAN)
    if ms.temperature_to_c is not None and "temperature" in a.dtype.names:
        raw_t = a["temperature"].astype(np.int64)
        temp = np.where(raw_t != 0, raw_t * ms.temperature_to_c, _NAN)
    # instance
    if name in ("RAW_IMU", "HIGHRES_IMU") and "id" in a.dtype.names:
        ids = a["id"].astype(np.int64)
        imu = np.where((ids >= 0) & (ids < 16), ids, 0)
    else:
        imu = np.full(n, INSTANCE_OF_MESSAGE[name], np.int64)
    t_us = a[ms.time_field].astype(np.int64) * ms.time_to_us
    return {
        "imu": imu, "t_us": t_us, "gyro": gyro, "accel": accel,
        "mag": mag, "temp": temp, "sat": sat, "inv": inv, "use": use, "zero": zero, "block": block,
    }  # fmt: skip


def _resends(mg: dict[str, Any], names: list[str]) -> tuple[NDArray[np.bool_], int]:
    """The re-send step (:func:`mavahrs.ingest.resend.resend_rows`, the pipeline's per-message step in a loop)
    over the merged messages: which are exact re-sends of the previous one of their stream (dropped), and how
    many repeat its stamp with new values."""
    from mavahrs.ingest.resend import RESENT, RESTAMPED, new_state, resend_rows, stream_code

    first = np.array([stream_code(name, 0) for name in names], np.int64)
    k = first[mg["kind"]] + mg["imu"].astype(np.int64)
    out = np.empty(mg["t_us"].shape[0], np.int64)
    c = np.ascontiguousarray  # one compiled signature for every log (one IMU message: views into its rows)
    resend_rows(*new_state(), c(k), c(mg["t_us"]), c(mg["gyro"]), c(mg["accel"]), c(mg["mag"]), c(mg["use"]), out)
    return out == RESENT, int(np.count_nonzero(out == RESTAMPED))


def _autopilot_bias(mg: dict[str, Any], names: list[str], profile: Any, settings: Any) -> None:
    """The autopilot-bias step (:func:`mavahrs.ingest.autopilot_bias.bias_restore_rows`, the pipeline's per-message
    steps in a loop) over the merged messages: PX4's EKF2 gyro bias, recovered from SCALED_IMU, added back to
    HIGHRES_IMU in place; a SCALED_IMU that served only that step is no sample (``use`` False)."""
    partner, primary = profile.bias_free_message, profile.primary_message
    # a log with the partner but no primary message runs the step too: the pipeline's partner serves only the
    # step for its first second (it waits for the primary stream), so the replay starts where the daemon does
    if not settings.enabled or partner is None or partner not in names:
        return
    from mavahrs.ingest.autopilot_bias import (
        ROLE_PARTNER,
        ROLE_PRIMARY,
        bias_restore_rows,
        constants,
        new_state,
    )
    from mavahrs.sensors.profiles import INSTANCE_OF_MESSAGE

    kind = mg["kind"]
    role = np.zeros(kind.shape[0], np.int64)
    if primary in names:
        role[(kind == names.index(primary)) & (mg["imu"] == INSTANCE_OF_MESSAGE[partner])] = ROLE_PRIMARY
    role[kind == names.index(partner)] = ROLE_PARTNER
    gyro = np.ascontiguousarray(mg["gyro"], np.float64)
    use = np.array(mg["use"], np.bool_)
    bad = np.ascontiguousarray((mg["sat"] | mg["inv"]) & GYRO, np.int64)
    applied = np.zeros(kind.shape[0], np.int64)
    twin = profile.scale_for(partner)
    step = twin.gyro_to_rad_s if twin.integer_fields else 0.0
    bias_restore_rows(new_state(), constants(settings, step, twin.truncated), role, np.ascontiguousarray(mg["t_us"], np.int64), gyro, bad,
                      use, applied)  # fmt: skip
    mg["gyro"], mg["use"] = gyro, use


def _autopilot_mag_bias(td: TlogData, mg: dict[str, Any], names: list[str], profile: Any, settings: Any,
                        src: tuple[int, int], hb_pos: int, use: NDArray[np.bool_]) -> None:
    """The autopilot-mag-bias step (:func:`mavahrs.ingest.autopilot_mag_bias.mag_restore_rows`, the pipeline's
    per-message steps in a loop) over the merged messages: PX4's EKF2 magnetometer bias, recovered from SCALED_IMU's
    field with the ``CAL_MAG*`` parameters as the pipeline would have them at each message, added back to
    HIGHRES_IMU's field in place.  ``use``: the messages that reach the step (before the gyro step's)."""
    partner, primary = profile.bias_free_message, profile.primary_message
    if not (settings.enabled and settings.mag_enabled) or partner is None or partner not in names or primary not in names:
        return
    from mavahrs.ingest.autopilot_mag_bias import CAL_LEN, constants, mag_restore_rows, new_state
    from mavahrs.sensors.profiles import INSTANCE_OF_MESSAGE
    from mavahrs.sensors.px4_mag_calibration import mag_calibration, param_value, relevant_name

    # the calibration in effect after each of the autopilot's PARAM_VALUE (as the pipeline's handler takes them)
    a = td.arrays["PARAM_VALUE"]
    ppos = td.pos["PARAM_VALUE"]
    ok = (a["sysid"] == src[0]) & (a["compid"] == src[1]) & (ppos > hb_pos)
    params: dict[str, float] = {}
    cals = [np.full(CAL_LEN, np.nan)]
    at_pos: list[int] = []
    at_row: list[int] = []
    for k in np.flatnonzero(ok).tolist():
        name = a["param_id"][k].decode("ascii", "replace").rstrip("\0")
        if not relevant_name(name):
            continue
        params[name] = param_value(float(a["param_value"][k]), int(a["param_type"][k]))
        cal = mag_calibration(params)[0]
        cal = np.full(CAL_LEN, np.nan) if cal is None else cal
        if not np.array_equal(cal, cals[-1], equal_nan=True):
            cals.append(cal)
            at_pos.append(int(ppos[k]))
            at_row.append(len(cals) - 1)
    if len(cals) == 1:  # never calibrated: HIGHRES_IMU as sent (the step would only count)
        return
    kind = mg["kind"]
    role = np.zeros(kind.shape[0], np.int64)
    role[(kind == names.index(primary)) & (mg["imu"] == INSTANCE_OF_MESSAGE[partner]) & use] = 1
    role[(kind == names.index(partner)) & use] = 2
    j = np.searchsorted(np.array(at_pos, np.int64), mg["pos"], side="right") - 1
    cal_index = np.where(j >= 0, np.array([0, *at_row], np.int64)[j + 1], 0).astype(np.int64)
    mag = np.array(mg["mag"], np.float64)
    mag[(role == 2) & (((mg["sat"] | mg["inv"]) & MAG) != 0), 0] = np.nan  # as the pipeline passes it
    applied = np.zeros(kind.shape[0], np.int64)
    twin = profile.scale_for(partner)
    step = twin.mag_to_ut if twin.integer_fields else 0.0
    mag_restore_rows(new_state(), constants(settings, step, twin.truncated), np.ascontiguousarray(np.array(cals)),
                     np.ascontiguousarray(cal_index), role, np.ascontiguousarray(mg["t_us"], np.int64), mag, applied)  # fmt: skip
    out = np.array(mg["mag"], np.float64)
    out[role == 1] = mag[role == 1]  # only the primary's field changes
    mg["mag"] = out


def prepare_inputs(
    td: TlogData,
    settings: Any = None,
    *,
    start_s: float | None = None,
    end_s: float | None = None,
    decimal_year: float | None = None,
) -> PreparedInputs:
    """The filter input rows of a log as :class:`~mavahrs.service.pipeline.Pipeline` builds them.

    Args:
        settings: the pipeline's settings (``PipelineSettings``; defaults if None).
        start_s, end_s: use only IMU messages whose tlog time lies in this
            window, seconds from the log's first record.
        decimal_year: date for the magnetic model until SYSTEM_TIME arrives.

    Raises:
        FastPathUnsupported: the log needs per-message decisions (see the module doc).
        DataError: no autopilot, no IMU data.
    """
    from mavahrs.sensors.calibration import Calibrator
    from mavahrs.sensors.geomag import DeclinationSource
    from mavahrs.sensors.profiles import get_profile
    from mavahrs.sensors.sample import blank_unusable_rows
    from mavahrs.sensors.velocity import VelocitySelector, fix_age_s
    from mavahrs.service.pipeline import PipelineSettings

    s = settings if settings is not None else PipelineSettings()
    src, hb_pos, prof_name = _source_and_profile(td, s)
    profile = get_profile(prof_name)
    t0 = int(td.t_us[0]) if td.frames else 0
    lo = -(2**62) if start_s is None else t0 + int(start_s * 1e6)
    hi = 2**62 if end_s is None else t0 + int(end_s * 1e6)
    # --- every IMU message of the source, scaled, in frame order
    parts = []
    notes: list[str] = truncation_notes(td)
    for name in IMU_TYPES:
        a = td.arrays[name]
        if a.shape[0] == 0 or profile.scale_for(name) is None:
            continue
        pos = td.pos[name]
        ok = (a["sysid"] == src[0]) & (a["compid"] == src[1]) & (pos > hb_pos)
        ok &= (td.t_us[pos] >= lo) & (td.t_us[pos] <= hi)
        if not ok.any():
            continue
        sc = scale_imu_messages(name, a if ok.all() else a[ok], profile.scale_for(name), s.scaling)
        sc["name"] = name
        sc["pos"] = pos[ok]
        parts.append(sc)
    if not parts:
        if start_s is not None or end_s is not None:  # there may be some outside the window: say where
            times = [td.t_us[td.pos[n][(td.arrays[n]["sysid"] == src[0]) & (td.arrays[n]["compid"] == src[1])
                                       & (td.pos[n] > hb_pos)]] for n in IMU_TYPES
                     if td.arrays[n].shape[0] and profile.scale_for(n) is not None]  # fmt: skip
            t_src = np.concatenate(times) if times else np.zeros(0, np.int64)
            if t_src.size:
                raise empty_window_error(td.path, start_s, end_s, (int(t_src.min()) - t0) * 1e-6,
                                         (int(t_src.max()) - t0) * 1e-6)  # fmt: skip
        raise DataError(f"{td.path}: no IMU messages (RAW_IMU, SCALED_IMU*, HIGHRES_IMU) from the autopilot")
    # --- all IMU messages of the source merged in frame order
    keys = ("imu", "t_us", "gyro", "accel", "mag", "temp", "sat", "inv", "use", "zero", "pos")
    if len(parts) == 1:  # one message type: already in frame order
        mg = {k: parts[0][k] for k in keys}
        mg["kind"] = np.zeros(parts[0]["pos"].shape[0], np.int64)
    else:
        mg = {k: np.concatenate([sc[k] for sc in parts]) for k in keys}
        mg["kind"] = np.concatenate([np.full(sc["pos"].shape[0], i) for i, sc in enumerate(parts)])
        order = np.argsort(mg["pos"], kind="stable")
        mg = {k: v[order] for k, v in mg.items()}
    names = [sc["name"] for sc in parts]
    resent, restamped = _resends(mg, names)
    if resent.any():
        mg["use"] = mg["use"] & ~resent
    use_before = np.array(mg["use"], np.bool_)
    _autopilot_bias(mg, names, profile, s.autopilot_bias)
    _autopilot_mag_bias(td, mg, names, profile, s.autopilot_bias, src, hb_pos, use_before)
    mg["zero"] = mg["zero"] & mg["use"]
    # --- which samples the selector feeds
    carriers: dict[int, set[int]] = {}
    live: set[int] = set()
    code = ((mg["imu"].astype(np.int64) * 64 + mg["kind"]) * 2 + mg["zero"]) * 2 + mg["use"]
    for c in np.flatnonzero(np.bincount(code)).tolist():  # (instance, message type, all-zero, new gyro)
        inst, kind, z, u = c // 256, (c // 4) % 64, (c // 2) % 2, c % 2
        carriers.setdefault(int(inst), set()).add(int(kind))
        if u and not z:
            live.add(int(inst))
    for inst in sorted(set(carriers) - live):
        notes.append(f"IMU instance {inst} sends all-zero accelerometer and gyro (no such IMU): not used")
    fixed = s.selection_settings.fixed
    if fixed is not None and fixed not in live:
        raise DataError(f"{td.path}: IMU instance {fixed} has no usable data (instances: {sorted(live) or 'none'})")
    if not live:
        raise DataError(f"{td.path}: every IMU instance sends all-zero accelerometer and gyro")
    # the pipeline's IMU selector, its compiled step over every message in the log's order
    feed, _ = select_over_arrays(s.selection_settings, mg["kind"], mg["imu"], mg["t_us"], mg["gyro"], mg["accel"],
                                 (mg["sat"] & (GYRO | ACCEL)) != 0, mg["use"])  # fmt: skip
    idx = np.flatnonzero(feed)
    if idx.size == 0:
        raise DataError(f"{td.path}: no IMU sample would reach the filter")
    inst_fed = mg["imu"][idx]
    if not np.all(inst_fed == inst_fed[0]):
        # fail-over: the pipeline also back-fills the new instance's recent samples
        raise FastPathUnsupported("the selected IMU instance changes during the log (fail-over)")
    every = idx.size == feed.size  # every message is fed: views instead of copies

    def take(k: str, sel: Any) -> Any:
        return mg[k] if sel is None else mg[k][sel]

    sel = None if every else idx
    keep, dt = timeline_over_arrays(take("t_us", sel), td.t_us[take("pos", sel)], take("gyro", sel), take("accel", sel), s.timeline)
    if not keep.all():
        idx = idx[keep]
        dt = dt[keep]
        sel = idx
    if dt.size:
        dt[0] = _NAN  # the first sample fed initialises the filter
    pos, t_us = take("pos", sel), take("t_us", sel)
    gyro, accel, mag = take("gyro", sel), take("accel", sel), take("mag", sel)
    sat, inv, temp = take("sat", sel), take("inv", sel), take("temp", sel)
    kinds = take("kind", sel)
    main_kind = int(np.bincount(kinds).argmax())
    sc = parts[main_kind]
    chosen = int(np.bincount(mg["imu"][idx]).argmax())
    m = pos.shape[0]
    in_place = sel is None and len(parts) == 1 and parts[0]["block"] is not None
    if in_place:  # gyro, accel and mag are already columns of these rows (scale_imu_messages)
        rows = parts[0]["block"]
        rows[:, IN_VEL : IN_VEL + 3] = _NAN
        rows[:, IN_VEL_AGE] = _NAN
        rows[:, IN_POS : IN_POS + 3] = _NAN
    else:
        rows = np.full((m, IN_WIDTH), _NAN)
    rows[:, IN_DT] = dt
    if not in_place:
        rows[:, IN_GYRO : IN_GYRO + 3] = gyro
        rows[:, IN_ACCEL : IN_ACCEL + 3] = accel
        rows[:, IN_MAG : IN_MAG + 3] = mag
    blank_unusable_rows(rows, np.ascontiguousarray(sat, np.int64), np.ascontiguousarray(inv, np.int64))
    # --- position/time messages in order: declination per sample, velocity into the next fed row
    decl = DeclinationSource(s.magnetic, decimal_year=decimal_year)
    events = []
    for name in POSITION_TYPES:
        a = td.arrays[name]
        if a.shape[0] == 0:
            continue
        ok = (a["sysid"] == src[0]) & (a["compid"] == src[1]) & (td.pos[name] > hb_pos)
        for k in np.flatnonzero(ok):
            events.append((int(td.pos[name][k]), name, int(k)))
    events.sort()
    decl_at = np.full(m, decl.declination_rad)
    decl_steps: list[tuple[int, float]] = []  # (first sample, declination from there on), filled in once below
    vel_rows: list[tuple[int, tuple[float, float, float], int | None, tuple[float, float, float]]] = []
    vsel = VelocitySelector(s.effective_velocity_source, s.monitor.receiver_velocity_only, profile.velocity_order)
    mag_events: list[tuple[int, float, float]] = []  # Pipeline._field_changed → filter.set_mag_reference
    ref0 = decl.mag_reference()
    if ref0 is not None:
        mag_events.append((0, float(ref0[0]), float(ref0[1])))
    for frame_pos, name, k in events:
        msg = td.message(name, k)
        changed = decl.handle(msg)
        i = int(np.searchsorted(pos, frame_pos))  # first fed sample after this message
        if changed:
            ref = decl.mag_reference()
            if ref is not None:
                mag_events.append((i, float(ref[0]), float(ref[1])))
        if decl.declination_rad != (decl_steps[-1][1] if decl_steps else decl_at[0]):
            decl_steps.append((i, decl.declination_rad))
        if name in vsel.messages:  # Pipeline._on_velocity, at the time the pipeline gets it in replay
            f = decl.field
            got = vsel.offer(msg, int(td.t_us[frame_pos]), f.declination_rad if f is not None else None)
            if got is not None and i < m:
                vel_rows.append((i, got[1:], got[0].fix_time_us, vsel.position_ned))
    for j, (i, d) in enumerate(decl_steps):  # one pass, not one fill per position message
        decl_at[i : decl_steps[j + 1][0] if j + 1 < len(decl_steps) else m] = d
    for i, v, fix_t, p_ned in vel_rows:  # later messages before the same sample overwrite earlier ones
        rows[i, IN_VEL : IN_VEL + 3] = v
        rows[i, IN_VEL_AGE] = fix_age_s(int(t_us[i]), fix_t)
        rows[i, IN_POS : IN_POS + 3] = p_ned
    _fill_current(td, src, pos, rows)
    # --- calibration (the step Calibrator.apply_row runs, in a compiled loop; one calibrator per message type)
    for kind in np.flatnonzero(np.bincount(kinds)):
        ms = profile.scale_for(names[int(kind)])
        cal = Calibrator(s.calibration, mag_already_calibrated=ms.mag_calibrated)
        if cal.active:
            sel_k = kinds == kind
            sub = rows[sel_k]
            cal.apply_rows(sub, temp[sel_k])
            rows[sel_k] = sub
    counts = {
        "imu_messages": int(mg["pos"].shape[0]),
        "fed": m,
        "dropped_timeline": int((~keep).sum()),
        "exact_duplicates": int(resent.sum()),
        "same_stamp_changed": restamped,
        # of the fed instance alone (the count above is over every instance the log carries)
        "exact_duplicates_fed": int((resent & (mg["imu"] == chosen)).sum()),
        "imu_messages_fed": int((mg["imu"] == chosen).sum()),
    }
    return PreparedInputs(
        rows=rows, t_us=t_us, frame_pos=pos, tlog_us=td.t_us[pos], temperature_c=temp,
        declination_rad=decl_at, message=sc["name"], instance=chosen, source=src, profile=prof_name,
        engine="fast", notes=notes, counts=counts, mag_reference_events=mag_events,
        sensor_delay_s=_delay_of(profile, sc["name"]), vehicle_stream=True, multirotor=_is_multirotor(td, src),
        velocity_source=_velocity_setting(s), velocity_fixes={k: vsel.used(k) for k in vsel.messages},
    )  # fmt: skip


def _is_multirotor(td: TlogData, src: tuple[int, int]) -> bool:
    """Whether the source's first HEARTBEAT names a multirotor (``Pipeline._on_heartbeat``'s test)."""
    from mavahrs.sensors.profiles import MULTIROTOR_MAV_TYPES

    hb = td.arrays["HEARTBEAT"]
    k = np.flatnonzero((hb["sysid"] == src[0]) & (hb["compid"] == src[1]))
    return bool(k.size) and int(hb["type"][k[0]]) in MULTIROTOR_MAV_TYPES


def _fill_current(td: TlogData, src: tuple[int, int], pos: NDArray[np.int64], rows: Array) -> None:
    """``IN_CURRENT``: the last battery current of the source before each sample (Pipeline._on_current)."""
    from mavahrs.sensors.current import CURRENT_STALE_S, battery_current_a

    rows[:, IN_CURRENT] = _NAN
    at: list[tuple[int, float]] = []
    for name in CURRENT_TYPES:
        a = td.arrays[name]
        if a.shape[0] == 0:
            continue
        ok = (a["sysid"] == src[0]) & (a["compid"] == src[1])
        for k in np.flatnonzero(ok):
            amps = battery_current_a(td.message(name, int(k)))
            if amps is not None:
                at.append((int(td.pos[name][k]), amps))
    if not at or pos.shape[0] == 0:
        return
    at.sort()
    mpos = np.array([p for p, _ in at], dtype=np.int64)
    amps_a = np.array([v for _, v in at])
    j = np.searchsorted(mpos, pos) - 1  # the last current message before each sample
    have = j >= 0
    jj = np.maximum(j, 0)
    age_s = (td.t_us[pos] - td.t_us[mpos[jj]]) * 1e-6
    use = have & (age_s <= CURRENT_STALE_S)
    rows[use, IN_CURRENT] = amps_a[jj[use]]


# --------------------------------------------------------------------------- the pipeline itself


def run_pipelines(
    td: TlogData,
    settings: Any,
    filters: Sequence[tuple[str, Any]],
    *,
    start_s: float | None,
    end_s: float | None,
    decimal_year: float | None,
    progress: Callable[[int], None] | None = None,
    on_block: Callable[[int, int, list[int], list[float], list[list[Array]]], None] | None = None,
    block: int = 4096,
) -> tuple[PreparedInputs, list[Array], list[list[bytes]], int]:
    """Feed every message through one Pipeline per filter (the daemon's code), message by message.

    ``on_block(start, end, times, declinations, outputs)`` is called for every
    ``block`` new samples (and the rest at the end), e.g. to write them out
    while the replay goes on.

    Returns (the inputs as the pipeline built them, per filter its output
    rows, per filter the ATTITUDE_QUATERNION/ATTITUDE frames it sent, the
    system id it used).  The rows come from the pipeline's ``sample_hook``.
    """
    from mavahrs.filters import create
    from mavahrs.protocol.codec import MavCodec
    from mavahrs.sensors.profiles import INSTANCE_OF_MESSAGE
    from mavahrs.service.pipeline import Pipeline

    pipes = []
    filts = []
    for i, (name, fs) in enumerate(filters):
        f = create(name, fs)
        ps = dataclasses.replace(settings, component_id=settings.component_id + i)
        pipes.append(Pipeline(ps, filter=f, decimal_year=decimal_year))
        filts.append(f)
    p0 = pipes[0]
    for p in pipes[1:]:  # the same field for every filter: logged once
        p.declination.announce = False
    codec = MavCodec()
    t0 = int(td.t_us[0]) if td.frames else 0
    lo = -(2**62) if start_s is None else t0 + int(start_s * 1e6)
    hi = 2**62 if end_s is None else t0 + int(end_s * 1e6)
    from mavahrs.protocol.codec import mavlink

    imu_ids = {int(getattr(mavlink, f"MAVLINK_MSG_ID_{n}")) for n in IMU_TYPES}
    rows: list[Array] = []
    t_list: list[int] = []
    pos_list: list[int] = []
    temp_list: list[float] = []
    decl_list: list[float] = []
    outs: list[list[Array]] = [[] for _ in pipes]
    frames: list[list[bytes]] = [[] for _ in pipes]
    names_fed: dict[str, int] = {}
    inst_fed: dict[int, int] = {}
    hooked: list[list[tuple[int, Array, Array]]] = [[] for _ in pipes]

    def make_hook(k: int) -> Callable[[str, int, Array, Array], None]:
        def hook(message: str, t_us: int, in_row: Array, out_row: Array) -> None:
            hooked[k].append((int(t_us), in_row.copy(), out_row.copy()))

        return hook

    for k, p in enumerate(pipes):
        p.sample_hook = make_hook(k)
    flushed = 0
    for j in range(td.frames):
        if progress is not None and j % 4096 == 0:
            progress(j)
        t_rec = int(td.t_us[j])
        if int(td.msgid[j]) in imu_ids and not lo <= t_rec <= hi:
            continue
        msg = codec.decode_frame(td.scan.frame(j))
        if msg is None:  # pragma: no cover - the scan returns decodable frames only
            continue
        for k, p in enumerate(pipes):
            for o in p.handle(msg, t_rec):
                if o.to_outputs and _msgid(o.frame) in _ATTITUDE_IDS:
                    frames[k].append(o.frame)
        if hooked[0]:
            t_s, in_row, _ = hooked[0][-1]
            rows.append(in_row)
            t_list.append(t_s)
            pos_list.append(j)
            raw_t = getattr(msg, "temperature", 0)
            temp_list.append(raw_t * 0.01 if raw_t and msg.get_type() != "HIGHRES_IMU" else math.nan)
            decl_list.append(p0.declination.declination_rad)
            names_fed[msg.get_type()] = names_fed.get(msg.get_type(), 0) + 1
            inst = INSTANCE_OF_MESSAGE.get(msg.get_type(), 0)
            if msg.get_type() in ("RAW_IMU", "HIGHRES_IMU"):
                i_id = getattr(msg, "id", 0)
                inst = i_id if isinstance(i_id, int) and 0 <= i_id < 16 else 0
            inst_fed[inst] = inst_fed.get(inst, 0) + 1
            for k in range(len(pipes)):
                outs[k].append(hooked[k][-1][2])
                hooked[k].clear()
            if on_block is not None and len(t_list) - flushed >= block:
                on_block(flushed, len(t_list), t_list, decl_list, outs)
                flushed = len(t_list)
    if on_block is not None and len(t_list) > flushed:
        on_block(flushed, len(t_list), t_list, decl_list, outs)
    m = len(t_list)
    if m == 0:
        raise DataError(f"{td.path}: no IMU sample reached the filter (no autopilot heartbeat or IMU data)")
    src = p0.source or (0, 0)
    counters = p0.status().counters
    prep = PreparedInputs(
        rows=np.vstack(rows) if rows else np.zeros((0, IN_WIDTH)),
        t_us=np.asarray(t_list, np.int64),
        frame_pos=np.asarray(pos_list, np.int64),
        tlog_us=td.t_us[np.asarray(pos_list, np.int64)],
        temperature_c=np.asarray(temp_list),
        declination_rad=np.asarray(decl_list),
        message=max(names_fed, key=names_fed.__getitem__),
        instance=max(inst_fed, key=inst_fed.__getitem__),
        source=(int(src[0]), int(src[1])),
        profile=p0.profile.name if p0.profile else "?",
        engine="pipeline",
        counts={"fed": m, **{f"fed_{k}": v for k, v in names_fed.items()},
                **{k: int(counters.get(k, 0)) for k in ("exact_duplicates", "same_stamp_changed")}},
        velocity_source=_velocity_setting(settings),
        velocity_fixes={k: p0.velocity_selector.used(k) for k in p0.velocity_selector.messages},
        notes=truncation_notes(td),
        # what the pipeline told its filters, for a filter run over these rows (`evaluate`): until user7 a log
        # that needs the pipeline (a fail-over, a reboot) was evaluated without them
        sensor_delay_s=_delay_of(p0.profile, max(names_fed, key=names_fed.__getitem__)) if p0.profile else 0.0,
        vehicle_stream=True, multirotor=_is_multirotor(td, (int(src[0]), int(src[1]))),
    )  # fmt: skip
    for kind, text in p0.drain_notices():
        if kind >= logging.WARNING:
            prep.notes.append(text)
    return prep, [np.vstack(o) for o in outs], frames, p0.codec.system_id


def _msgid(frame: bytes) -> int:
    if frame[0] == 0xFD:
        return frame[7] | (frame[8] << 8) | (frame[9] << 16)
    return frame[5]


_ATTITUDE_IDS = (31, 30)  # ATTITUDE_QUATERNION, ATTITUDE


def pipeline_inputs(td: TlogData, settings: Any, *, decimal_year: float | None = None) -> PreparedInputs:
    """The filter inputs of a log taken from the pipeline itself (any log the daemon could read)."""
    prep, _, _, _ = run_pipelines(td, settings, [("madgwick", None)], start_s=None, end_s=None,
                                   decimal_year=decimal_year)  # fmt: skip
    return prep


# --------------------------------------------------------------------------- references


def _imu_clock(td: TlogData, prep: PreparedInputs) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(tlog µs, autopilot µs) pairs of the fed samples, for mapping untimed messages."""
    return prep.tlog_us, prep.t_us


def tlog_to_autopilot_us(td: TlogData, prep: PreparedInputs, tlog_us: NDArray[np.int64]) -> Array:
    """Tlog record times (µs) mapped onto the autopilot's boot clock (µs, float; NaN outside the IMU samples).

    For messages that carry no time of their own (SIMSTATE, SIM_STATE, HEARTBEAT, EXTENDED_SYS_STATE …): the
    fed IMU samples pair each record time with their boot time, and the map interpolates between them.
    """
    x, y = _imu_clock(td, prep)
    if x.size == 0:
        return np.full(tlog_us.shape, _NAN)
    xm = np.maximum.accumulate(x.astype(np.float64))
    # np.interp needs increasing x: equal tlog stamps (several messages per record time) average out
    ux, inv = np.unique(xm, return_inverse=True)
    uy = np.bincount(inv, weights=y.astype(np.float64)) / np.bincount(inv)
    if ux.size == 1:
        return np.full(tlog_us.shape, float(uy[0]))
    return np.interp(tlog_us.astype(np.float64), ux, uy, left=_NAN, right=_NAN)


def _delay_of(profile: Any, message: str) -> float:
    """The profile's ``delay_s`` for ``message`` (0 when unknown)."""
    ms = profile.scale_for(message)
    return float(ms.delay_s) if ms is not None else 0.0


def sample_boots(t_us: NDArray[np.int64]) -> NDArray[np.int64]:
    """Per fed IMU sample, the autopilot's boot it belongs to (0, 1, …): a new one wherever the fed samples' boot
    clock goes back (the pipeline feeds no reordered sample; its clock going back is a reboot)."""
    back = np.zeros(t_us.shape[0], np.int64)
    if t_us.shape[0] > 1:
        back[1:] = t_us[1:] < t_us[:-1]
    return np.cumsum(back)


def boots_of_tlog_times(prep: PreparedInputs, tlog_us: NDArray[np.int64]) -> NDArray[np.int64]:
    """The boot (:func:`sample_boots`) of each tlog record time: the last boot whose first IMU sample was recorded
    at or before it (0 before the first)."""
    b = sample_boots(prep.t_us)
    starts = np.flatnonzero(np.diff(b, prepend=0) > 0) if b.size else np.zeros(0, np.int64)
    if starts.size == 0:
        return np.zeros(tlog_us.shape[0], np.int64)
    return np.searchsorted(prep.tlog_us[starts], tlog_us, side="right").astype(np.int64)


def references(td: TlogData, prep: PreparedInputs) -> dict[str, tuple[Array, Array]]:
    """Attitudes the log already holds, name → (autopilot time µs, (K, 4) q_body_to_ned, true north).
    Where the autopilot rebooted during the log (:func:`sample_boots`) each is in boot order, then time order
    within a boot: :func:`references_with_boots` also says which boot each sample is of.

    ``autopilot ATTITUDE`` (its ``time_boot_ms``), ``autopilot AHRS2`` and the
    simulator truth ``SIMSTATE`` (Euler), ``SIM_STATE`` (quaternion) or
    ``HIL_STATE_QUATERNION`` (PX4's simulators), the most frequent of them.  SIMSTATE and
    SIM_STATE carry no time: their tlog timestamps are mapped onto the autopilot clock
    through the IMU messages' (tlog time, sample time) pairs; HIL_STATE_QUATERNION's
    ``time_usec`` is used when every message has one (else the same mapping).
    """
    return references_with_boots(td, prep)[0]


def references_with_boots(
    td: TlogData, prep: PreparedInputs
) -> tuple[dict[str, tuple[Array, Array]], dict[str, NDArray[np.int64]]]:
    """:func:`references` and, per reference, the boot of each of its samples (by its tlog record time,
    :func:`boots_of_tlog_times`).  Until user7 a log with a reboot had its references sorted by time over all
    boots at once, so the comparison matched the first boot's attitudes with the second's (50° RMS on a
    firmware_sim session with a reboot recorded by the daemon)."""
    from mavahrs.geometry.rotation import from_euler_rad

    out: dict[str, tuple[Array, Array]] = {}
    rec: dict[str, NDArray[np.int64]] = {}  # the tlog record time of each reference sample
    src = prep.source

    def of_source(a: np.ndarray) -> np.ndarray:
        return a[(a["sysid"] == src[0]) & (a["compid"] == src[1])] if a.shape[0] else a

    att = of_source(td.arrays["ATTITUDE"])
    if att.shape[0]:
        q = from_euler_rad(att["roll"].astype(float), att["pitch"].astype(float), att["yaw"].astype(float))
        out["autopilot ATTITUDE"] = (att["time_boot_ms"].astype(np.float64) * 1000.0, q)
        rec["autopilot ATTITUDE"] = att["t_us"]
    ahrs2 = of_source(td.arrays["AHRS2"])
    if ahrs2.shape[0]:
        q = from_euler_rad(ahrs2["roll"].astype(float), ahrs2["pitch"].astype(float), ahrs2["yaw"].astype(float))
        out["autopilot AHRS2"] = (tlog_to_autopilot_us(td, prep, ahrs2["t_us"]), q)
        rec["autopilot AHRS2"] = ahrs2["t_us"]
    # the simulator's truth: SIMSTATE (ArduPilot SITL, Euler), SIM_STATE (quaternion) or
    # HIL_STATE_QUATERNION (PX4's simulators), whichever comes most often (slerping a 10 Hz truth
    # through fast manoeuvres would add its own error)
    sim = of_source(td.arrays["SIM_STATE"])
    ss = of_source(td.arrays["SIMSTATE"])
    hil = of_source(td.arrays["HIL_STATE_QUATERNION"])
    most = max(sim.shape[0], ss.shape[0], hil.shape[0])
    if hil.shape[0] and hil.shape[0] == most:
        # attitude_quaternion (w, x, y, z); time_usec is the sample's time on the autopilot's boot
        # clock (0 when the firmware leaves it unset, as upstream PX4 does: then the tlog time)
        q = hil["attitude_quaternion"].astype(float).reshape(-1, 4)
        t_hil = hil["time_usec"].astype(np.float64)
        if np.all(t_hil > 0):
            out["HIL_STATE_QUATERNION truth"] = (t_hil, q)
        else:
            out["HIL_STATE_QUATERNION truth"] = (tlog_to_autopilot_us(td, prep, hil["t_us"]), q)
        rec["HIL_STATE_QUATERNION truth"] = hil["t_us"]
    elif sim.shape[0] and sim.shape[0] == most:
        q = np.stack([sim[f"q{i}"].astype(float) for i in range(1, 5)], axis=1)
        out["SIM_STATE truth"] = (tlog_to_autopilot_us(td, prep, sim["t_us"]), q)
        rec["SIM_STATE truth"] = sim["t_us"]
    elif ss.shape[0]:
        q = from_euler_rad(ss["roll"].astype(float), ss["pitch"].astype(float), ss["yaw"].astype(float))
        out["SIMSTATE truth"] = (tlog_to_autopilot_us(td, prep, ss["t_us"]), q)
        rec["SIMSTATE truth"] = ss["t_us"]
    boots: dict[str, NDArray[np.int64]] = {}
    for k, (t, q) in list(out.items()):
        good = np.isfinite(t) & np.all(np.isfinite(q), axis=1) & (np.linalg.norm(q, axis=1) > 0.5)
        if not good.any():
            del out[k]
            continue
        t, q = t[good], q[good]
        boot = boots_of_tlog_times(prep, np.asarray(rec[k])[good])
        order = np.lexsort((t, boot))  # by boot, then by time within it (stable)
        t, q, boot = t[order], q[order], boot[order]
        # a message the autopilot sent twice in one pass (same time, same values: ArduPilot's telemetry catching
        # up at SCHED_LOOP_RATE 800) is one reference sample, not two
        again = np.zeros(t.shape[0], bool)
        again[1:] = (t[1:] == t[:-1]) & np.all(q[1:] == q[:-1], axis=1) & (boot[1:] == boot[:-1])
        if again.any():
            t, q, boot = t[~again], q[~again], boot[~again]
        out[k] = (t, q / np.linalg.norm(q, axis=1, keepdims=True))
        boots[k] = boot
    return out, boots


def true_rates(td: TlogData, prep: PreparedInputs) -> Array | None:
    """The simulator's true body rates (SIMSTATE, else SIM_STATE ``xgyro``…), rad/s, at the sample times."""
    src = prep.source
    for name in ("SIMSTATE", "SIM_STATE"):
        a = td.arrays[name]
        if a.shape[0] < 2:
            continue
        a = a[(a["sysid"] == src[0]) & (a["compid"] == src[1])]
        if a.shape[0] < 2:
            continue
        t = tlog_to_autopilot_us(td, prep, a["t_us"])
        ok = np.isfinite(t)
        if ok.sum() < 2:
            continue
        out = np.full((prep.n, 3), _NAN)
        rec_boot, boot = boots_of_tlog_times(prep, a["t_us"]), sample_boots(prep.t_us)
        for k in range(int(boot[-1]) + 1 if boot.size else 0):  # each boot's samples from that boot's truth
            sel = ok & (rec_boot == k)
            if not sel.any():
                continue
            order = np.argsort(t[sel], kind="stable")
            tt = t[sel][order]
            for i, f in enumerate(("xgyro", "ygyro", "zgyro")):
                out[boot == k, i] = np.interp(prep.t_us[boot == k].astype(np.float64), tt,
                                              a[f][sel][order].astype(np.float64), left=_NAN, right=_NAN)  # fmt: skip
        return out
    return None


def interpolate_attitude(t_ref: Array, q_ref: Array, t: Array, max_gap_s: float = 0.5) -> Array:
    """Slerp a reference attitude series onto times ``t`` (NaN outside it or across gaps)."""
    from mavahrs.geometry.quaternion import slerp

    out = np.full((t.shape[0], 4), _NAN)
    if t_ref.shape[0] < 2:
        return out
    i = np.searchsorted(t_ref, t, side="right") - 1
    ok = (i >= 0) & (i < t_ref.shape[0] - 1)
    i = np.clip(i, 0, t_ref.shape[0] - 2)
    t0, t1 = t_ref[i], t_ref[i + 1]
    span = t1 - t0
    ok &= span <= max_gap_s * 1e6
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(span > 0, (t - t0) / np.where(span > 0, span, 1.0), 0.0)
    if ok.any():
        out[ok] = slerp(q_ref[i[ok]], q_ref[i[ok] + 1], frac[ok])
    return out


# --------------------------------------------------------------------------- recordings


def _inputs_for(td: TlogData, imu: str, settings: Any, velocity_source: str = "auto") -> PreparedInputs:
    from mavahrs.service.pipeline import PipelineSettings

    s, note = resolve_source(
        td, settings if settings is not None else PipelineSettings(imu=imu, velocity_source=velocity_source)
    )
    dy = decimal_year_of_log(td)
    try:
        prep = prepare_inputs(td, s, decimal_year=dy)
    except FastPathUnsupported:
        prep = pipeline_inputs(td, s, decimal_year=dy)
    if note is not None:
        prep.notes.insert(0, note)
    return prep


def load_tlog_recording(
    path: str | Path,
    *,
    imu: str = "auto",
    reference: bool = True,
    skip_s: float = 0.0,
    settings: Any = None,
    velocity_source: str = "auto",
    source: tuple[int, int | None] | None = None,
) -> Recording:
    """A tlog as an evaluation :class:`Recording`: the pipeline's filter inputs, SIM_STATE/SIMSTATE truth.

    The truth (true north) is slerped onto the sample times and rotated by the
    declination the pipeline would apply, into the filter's own magnetic-NED
    frame, so the recording scores filters exactly as the daemon's output
    would be scored.  Samples from ``skip_s`` seconds on are scored.
    ``velocity_source`` (without ``settings``): the GNSS velocity the
    pipeline would feed (:mod:`mavahrs.sensors.velocity`); the velocity and
    its age are in ``extra["velocity_ned_m_s"]`` / ``extra["velocity_age_s"]``.
    ``source`` = (system, component or None): take the IMU data from that
    sender only (``--source``; ignored when ``settings`` are given).
    """
    if settings is None and source is not None:
        from mavahrs.service.pipeline import PipelineSettings

        settings = PipelineSettings(imu=imu, source_system=source[0], source_component=source[1],
                                    velocity_source=velocity_source)
    td = read_tlog_data(path)
    prep = _inputs_for(td, imu, settings, velocity_source)
    refs, boots = references_with_boots(td, prep) if reference else (None, None)
    return recording_from_inputs(Path(path).stem, prep, refs, skip_s=skip_s, true_rate_rad_s=true_rates(td, prep),
                                 ref_boots=boots,
                                 no_truth="no simulator truth (SIM_STATE/SIMSTATE/HIL_STATE_QUATERNION) in this "
                                 "log: nothing to score against")  # fmt: skip


def recording_from_inputs(
    name: str,
    prep: PreparedInputs,
    refs: dict[str, tuple[Array, Array]] | None,
    *,
    skip_s: float = 0.0,
    true_rate_rad_s: Array | None = None,
    groups: tuple[str, ...] = ("tlog",),
    no_truth: str = "no simulator truth in this log: nothing to score against",
    ref_boots: dict[str, NDArray[np.int64]] | None = None,
) -> Recording:
    """A log's filter inputs as an evaluation :class:`Recording`, whatever the log's format.

    ``refs`` are the log's references (name → (t_us, q_body_to_ned) on ``prep.t_us``'s clock; None:
    do not look for one); the first whose name ends in ``truth`` is slerped onto the sample times and
    rotated by the declination the pipeline would apply (true → magnetic north), so the recording
    scores filters exactly as their output would be scored.  Samples from ``skip_s`` s on are scored.
    Where the autopilot rebooted during the log (:func:`sample_boots`; ``ref_boots``: each reference sample's
    boot, :func:`references_with_boots`) each boot's samples get that boot's truth, and ``skip_s`` counts from
    each boot's first sample.
    """
    from mavahrs.geometry.quaternion import multiply

    n = prep.n
    q_ref = np.full((n, 4), _NAN)
    notes = list(prep.notes)
    boot = sample_boots(prep.t_us)
    first = np.flatnonzero(np.diff(boot, prepend=-1) > 0)  # each boot's first sample
    t_us = prep.t_us.astype(np.float64)
    if refs is not None:
        truth = [k for k in refs if k.endswith("truth")]
        if truth:
            t_ref, q = refs[truth[0]]
            rb = (ref_boots or {}).get(truth[0])
            if first.size <= 1 or rb is None:
                q_true = interpolate_attitude(np.asarray(t_ref, np.float64), q, t_us)
            else:  # a reboot: each boot's samples against that boot's truth (until user7: the boots mixed)
                q_true = np.full((n, 4), _NAN)
                for k in range(first.size):
                    mine, theirs = boot == k, rb == k
                    if theirs.any():
                        q_true[mine] = interpolate_attitude(np.asarray(t_ref, np.float64)[theirs], q[theirs], t_us[mine])
            half = -0.5 * prep.declination_rad  # true → magnetic: rotate by −D about down
            q_dec = np.stack([np.cos(half), np.zeros(n), np.zeros(n), np.sin(half)], axis=1)
            q_ref = multiply(q_dec, q_true)
            t_truth = np.asarray(t_ref, np.float64)
            if n and not np.all(np.isfinite(q_true), axis=1).any():  # e.g. SIMSTATE at 1 Hz in a `run --log` tlog
                gap = float(np.median(np.diff(t_truth))) * 1e-6 if t_truth.size > 1 else math.inf
                notes.append(f"reference: {truth[0]}, but too sparse to slerp onto the IMU samples: "
                             f"{t_truth.size} sample(s), {gap:.2g} s apart (median; truth more than 0.5 s apart "
                             "is not interpolated), so nothing is scored; `mavahrs replay` compares at the "
                             "truth's own times")  # fmt: skip
            else:
                notes.append(f"reference: {truth[0]} (true north, rotated into the filter's magnetic frame), "
                             "slerped onto the IMU samples: every sample scored (`mavahrs replay` compares at the "
                             "truth's own times instead; the two differ only where the IMU stream has gaps), "
                             + (f"from {skip_s:g} s on (--skip)" if skip_s > 0 else
                                "convergence included (--skip 10 leaves out the first 10 s, as the README's "
                                "tables)"))  # fmt: skip
        else:
            others = [k for k in refs if not k.endswith("truth")]
            notes.append(no_truth + (f" (`mavahrs replay` compares with the log's {' and '.join(others)} instead)"
                                     if others else ""))  # fmt: skip
    rate = prep.rate_hz()
    if 0 < rate < 50:
        notes.append(f"IMU samples at {rate:.1f} Hz: too slow for meaningful attitude filtering (≥ 50 Hz needed)")
    # seconds since the first sample, the time between boots left out; the boot's own for --skip
    since_boot = (t_us - t_us[first[boot]]) * 1e-6 if n else np.zeros(0)
    span = np.array([since_boot[b - 1] for b in [*first[1:].tolist(), n]]) if n else np.zeros(0)
    t_s = since_boot + np.concatenate(([0.0], np.cumsum(span)[:-1]))[boot] if n else np.zeros(0)
    rows = prep.rows
    dt = rows[:, IN_DT].copy()
    if n > 1:
        dt[0] = float(np.median(np.diff(prep.t_us))) * 1e-6
    mag = rows[:, IN_MAG : IN_MAG + 3]
    vel = rows[:, IN_VEL : IN_VEL + 3]
    return Recording(
        name=name,
        dt_s=dt,
        gyro_rad_s=np.ascontiguousarray(rows[:, IN_GYRO : IN_GYRO + 3]),
        accel_m_s2=np.ascontiguousarray(rows[:, IN_ACCEL : IN_ACCEL + 3]),
        mag_ut=np.ascontiguousarray(mag) if np.isfinite(mag).any() else None,
        q_ref_body_to_ned=q_ref,
        scored=since_boot >= skip_s,
        groups=groups,
        heading_referenced=True,
        extra={
            "time_s": t_s,
            "boot_starts": first[1:].tolist(),  # the samples where the autopilot's clock started again (a reboot)
            "temperature_c": prep.temperature_c,
            "velocity_ned_m_s": np.ascontiguousarray(vel) if np.isfinite(vel).any() else None,
            "velocity_age_s": rows[:, IN_VEL_AGE].copy() if np.isfinite(vel).any() else None,
            # the chain's other columns, as the replay feeds them (the magnetometer model's motor current, the
            # GNSS position): evaluate runs a filter on the same rows as replay
            "current_a": rows[:, IN_CURRENT].copy() if np.isfinite(rows[:, IN_CURRENT]).any() else None,
            "position_ned_m": rows[:, IN_POS : IN_POS + 3].copy() if np.isfinite(rows[:, IN_POS : IN_POS + 3]).any() else None,
            "has_reference": bool(np.isfinite(q_ref).all(axis=1).any()),
            "notes": notes,
            "imu": f"{prep.message} (instance {prep.instance}), {rate:.1f} Hz",
            "prepared": prep,
            "true_rate_rad_s": true_rate_rad_s,
            "mag_reference_events": list(prep.mag_reference_events),
            "sensor_delay_s": prep.sensor_delay_s,  # filters that use it are told, as by the pipeline
            "vehicle_stream": prep.vehicle_stream,
            "multirotor": prep.multirotor,
        },
    )


def cut_recording(rec: Recording, start_s: float | None, end_s: float | None) -> Recording:
    """The samples of a recording between ``start_s`` and ``end_s`` (seconds from its start)."""
    if start_s is None and end_s is None:
        return rec
    t = rec.extra.get("time_s")
    t = np.asarray(t, dtype=np.float64) if t is not None else np.cumsum(rec.dt_s) - rec.dt_s[0]
    t = t - t[0]
    keep = np.ones(rec.n, bool)
    if start_s is not None:
        keep &= t >= start_s
    if end_s is not None:
        keep &= t <= end_s
    if keep.sum() < 2:
        raise DataError(f"{rec.name}: fewer than two samples between {start_s} and {end_s} s")

    def cut(x: Any) -> Any:
        return np.asarray(x)[keep] if isinstance(x, np.ndarray) and x.shape[:1] == (rec.n,) else x

    extra = {k: cut(v) for k, v in rec.extra.items()}
    events = rec.extra.get("mag_reference_events")
    if events:  # sample indices move with the cut; earlier events apply at the new start
        first = int(np.flatnonzero(keep)[0])
        extra["mag_reference_events"] = [(max(0, int(i) - first), nrm, dip) for i, nrm, dip in events]
    extra.pop("prepared", None)
    return dataclasses.replace(
        rec,
        dt_s=rec.dt_s[keep],
        gyro_rad_s=rec.gyro_rad_s[keep],
        accel_m_s2=rec.accel_m_s2[keep],
        mag_ut=None if rec.mag_ut is None else rec.mag_ut[keep],
        q_ref_body_to_ned=rec.q_ref_body_to_ned[keep],
        scored=rec.scored[keep],
        extra=extra,
    )
