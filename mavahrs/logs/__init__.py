"""Log readers: telemetry (.tlog), ArduPilot DataFlash (.BIN) and PX4 ULog (.ulg).

Every reader ends in the same place, a :class:`LogInputs`: the filter's input rows
(:class:`~mavahrs.ingest.arrays.PreparedInputs`, the layout of
:mod:`mavahrs.filters.layout`) and the attitudes to compare against, so replay,
evaluate, tune and audit run the same code downstream whatever the log's format.

The format is chosen by content (:func:`sniff`), not by the file's extension.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from mavahrs.ingest.arrays import PreparedInputs

__all__ = [
    "FORMATS", "a_format", "LogInputs", "sniff", "read_log", "unsupported_message", "LOG_SUFFIXES", "is_truth",
    "autopilot_reference",
]

#: format name → what users call it (for messages naming the supported formats)
FORMATS: dict[str, str] = {
    "tlog": "MAVLink telemetry log (.tlog)",
    "dataflash": "ArduPilot DataFlash log (.BIN)",
    "ulog": "PX4 ULog (.ulg)",
}


def a_format(kind: str) -> str:
    """``FORMATS[kind]`` with its article, for sentences: "an ArduPilot DataFlash log (.BIN)"."""
    name = FORMATS[kind]
    return f"{'an' if name[0] in 'AEIOU' else 'a'} {name}"


#: file name endings of logs (a folder is searched for these; other files are taken when their content is a log)
LOG_SUFFIXES = (".tlog", ".bin", ".ulg")

_ULOG_MAGIC = b"ULog\x01\x12\x35"  # ULog file header, bytes 0-6 (then the version byte)
_DATAFLASH_HEAD = b"\xa3\x95"  # every DataFlash record starts with these two bytes
_DATAFLASH_FMT = 0x80  # … and the log's first record is a FMT (message type 128)
_MAVLINK_STX = (0xFE, 0xFD)  # MAVLink 1 / 2 start bytes


def sniff(path: str | Path) -> str | None:
    """The log format of ``path`` by its first bytes: ``tlog``, ``dataflash``, ``ulog`` or None.

    A tlog is a sequence of (8-byte big-endian µs timestamp, MAVLink frame); its
    first frame's start byte sits at offset 8. A DataFlash log opens with a FMT
    record (``A3 95 80``), a ULog with its magic. Empty or unreadable files give None.
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError:
        return None
    if head.startswith(_ULOG_MAGIC):
        return "ulog"
    if len(head) >= 3 and head[:2] == _DATAFLASH_HEAD and head[2] == _DATAFLASH_FMT:
        return "dataflash"
    if len(head) >= 9 and head[8] in _MAVLINK_STX:
        return "tlog"
    return None


@dataclass
class LogInputs:
    """What a log reader hands downstream.

    Attributes:
        path: the log's path.
        format: one of :data:`FORMATS`.
        inputs: the filter's input rows and their times (``t_us`` on the log's own
            clock: DataFlash TimeUS, ULog ``timestamp``, the autopilot's boot clock
            of a tlog).
        references: name → (t_us (K,), q_body_to_ned (K, 4)), the attitudes to
            compare against on the same clock as ``inputs.t_us``; names ending in
            ``" truth"`` are the simulator's true attitude, the others an
            autopilot's estimate (``"EKF3"``, ``"EKF2"``, ``"ATTITUDE"`` …).
        found: lines for the replay header: IMU instances and their rates, the
            reference and truth found, parameters used.
        parameters: the autopilot's parameters recorded in the log (name → value).
        truncated: the log ends inside a record (cut off): read up to its last whole record.
        start_us: the log's first time stamp on ``inputs.t_us``'s clock (what ``start_s``/``end_s`` count from).
        series: other time series the log holds, name → columns (each with ``t_us`` on the same clock), e.g.
            DataFlash ``battery`` (``current_a``, ``voltage_v``), ``vibration`` (``imu``, ``x_m_s2`` …,
            ``clips``), ``batch_sampler`` (ISBH headers: ``sensor``, ``instance``, ``rate_hz``, ``samples``),
            ``imu_gyro`` (every IMU's gyro when the log has two or more live ones: ``instance``, ``gyro_rad_s``
            (K, 3); for the monitor to name the IMU that is off);
            the flight's phase as logged (DataFlash ARM/EV, ULog vehicle_status / vehicle_land_detected):
            ``armed`` (``base_mode``: 128 armed, 0 not) and ``landed`` (``landed_state``: 1 on the ground, 2 in
            the air), as HEARTBEAT and EXTENDED_SYS_STATE carry them.
    """

    path: str
    format: str
    inputs: PreparedInputs
    references: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    found: list[str] = field(default_factory=list)
    parameters: dict[str, float] = field(default_factory=dict)
    truncated: bool = False
    start_us: int = 0
    series: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)


def is_truth(name: str) -> bool:
    """A reference name of :attr:`LogInputs.references` that is a simulator's true attitude (ends in ``" truth"``)."""
    return name.endswith(" truth")


def autopilot_reference(references: Mapping[str, Any]) -> str:
    """The autopilot's own attitude among a log's ``references``: the first whose name does not end in
    ``" truth"`` ("" when there is none).

    Every reader puts its autopilot's main estimate first: a tlog's ``"autopilot ATTITUDE"`` (then
    ``"autopilot AHRS2"``), a DataFlash log's ``"autopilot EKF3"`` (core 0; then ATT, DCM), a ULog's
    ``"EKF2"``. One rule for every consumer (replay's second opinion and plot, the fleet audit)."""
    return next((k for k in references if not is_truth(k)), "")


def unsupported_message(path: str | Path) -> str:
    """Why ``path`` is not read: empty, or not one of :data:`FORMATS` (named)."""
    p = Path(path)
    try:
        size = p.stat().st_size
    except OSError as exc:
        return f"{p}: cannot read: {exc.strerror or exc}"
    if size == 0:
        return f"{p}: empty file"
    return f"{p}: not a log mavahrs reads (by its content): supported are " + ", ".join(FORMATS.values())


def read_log(
    path: str | Path,
    settings: Any = None,
    *,
    start_s: float | None = None,
    end_s: float | None = None,
    format: str | None = None,  # noqa: A002 - the format's name, as LogInputs.format
) -> LogInputs:
    """A DataFlash or ULog log as :class:`LogInputs`, the format chosen by content (:func:`sniff`).

    Telemetry logs have their own reader with the daemon's per-message pipeline
    (:func:`mavahrs.evaluation.tlogdata.read_tlog_data`, used by replay directly).

    Raises:
        DataError: empty, unreadable, not a supported format, or nothing usable in it.
    """
    from mavahrs.errors import DataError

    fmt = format if format is not None else sniff(path)
    if fmt == "dataflash":
        from mavahrs.logs.dataflash import read_dataflash

        return read_dataflash(path, settings, start_s=start_s, end_s=end_s)
    if fmt == "ulog":
        try:
            from mavahrs.logs.ulog import read_ulog  # type: ignore[import-not-found,unused-ignore]
        except ImportError as exc:
            raise DataError(f"{path}: a PX4 ULog (.ulg), but its reader is not available: {exc}") from None

        return read_ulog(path, settings, start_s=start_s, end_s=end_s)  # type: ignore[no-any-return,unused-ignore]
    if fmt == "tlog":
        raise DataError(f"{path}: a telemetry log: read it with mavahrs.evaluation.tlogdata.read_tlog_data")
    raise DataError(unsupported_message(path))
