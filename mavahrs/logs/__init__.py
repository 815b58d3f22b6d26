"""Log readers: telemetry (.tlog), ArduPilot DataFlash (.BIN) and PX4 ULog (.ulg).

Every reader ends in the same place, a :class:`LogInputs`: the filter's input rows
(:class:`~mavahrs.evaluation.tlogdata.PreparedInputs`, the layout of
:mod:`mavahrs.filters.layout`) and the attitudes to compare against, so replay,
evaluate, tune and audit run the same code downstream whatever the log's format.

The format is chosen by content (:func:`sniff`), not by the file's extension.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from mavahrs.evaluation.tlogdata import PreparedInputs

__all__ = ["FORMATS", "LogInputs", "sniff"]

#: format name → what users call it (for messages naming the supported formats)
FORMATS: dict[str, str] = {
    "tlog": "MAVLink telemetry log (.tlog)",
    "dataflash": "ArduPilot DataFlash log (.BIN)",
    "ulog": "PX4 ULog (.ulg)",
}

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
    """

    path: str
    format: str
    inputs: PreparedInputs
    references: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    found: list[str] = field(default_factory=list)
    parameters: dict[str, float] = field(default_factory=dict)
