r"""Fault injection for logs: a copy of a tlog (or an onboard .BIN / .ulg) with a known error added.

An ArduPilot DataFlash log (.BIN) or a PX4 ULog (.ulg) — chosen by content — gets the same faults, shapes
and clock, rewritten in place in the records that carry the autopilot's attitude or the IMU's samples:
:mod:`mavahrs.evaluation.onboard_faults` says which.  What follows describes the tlog.

To test a monitor (mavahrs's second opinion, or one's own settings for it) one
needs flights where the autopilot's attitude is wrong by a known amount from a
known time.  :func:`inject_faults` copies a tlog record by record and rewrites
only the messages a fault applies to:

* :class:`AttitudeFault` — an error in the autopilot's own attitude: ATTITUDE
  (roll/pitch/yaw) and ATTITUDE_QUATERNION (the same attitude as a quaternion),
  both shifted by the same Euler-angle offsets (``roll_deg``, ``pitch_deg``,
  ``yaw_deg``: added to the aerospace Z-Y-X angles, yaw wrapped to ±180°)
  and/or an earth-frame error: ``tilt_deg`` about the horizontal axis at
  ``tilt_azimuth_deg`` from north (exactly that much inclination error,
  whatever the attitude — an Euler roll offset is a tilt of only about
  roll·cos(pitch)) and ``heading_deg`` about the vertical (a yaw offset);
* :class:`ImuFault` — a bias on one IMU message's gyro and/or accelerometer
  (``RAW_IMU``, ``SCALED_IMU``, ``SCALED_IMU2``, ``SCALED_IMU3`` in their
  mrad/s and mG, rounded to the integer field; ``HIGHRES_IMU`` in rad/s and
  m/s²), in the sensor's body axes.

Both have one time profile (:class:`FaultShape`), on the autopilot's boot clock
(the message's own ``time_boot_ms`` / ``time_usec``, the clock ``mavahrs
audit`` and the monitor report in): a ``step`` to the full offset at
``start_s``; a ``ramp`` from 0 at ``start_s`` to the full offset at
``start_s + ramp_s``, then held; ``intermittent``: the full offset for the
first ``on_s`` of every ``period_s``.  Each lasts ``duration_s`` (default: to
the end of the log).

Everything else is copied byte for byte: the other records, every record's
timestamp, the rewritten frames' MAVLink version, sequence number, system and
component id.  A rewritten frame gets a fresh checksum; a signed frame loses
its signature (it could not be valid any more; :class:`InjectionReport` counts
them).  Only messages from ``system_id``/``component_id`` (default: the
autopilot, the system of the first autopilot HEARTBEAT, component 1) change.

``mavahrs inject-fault`` is the command-line face (``docs/monitor.md``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mavahrs.geometry.rotation import euler_to_q_scalar

__all__ = [
    "FaultShape",
    "AttitudeFault",
    "ImuFault",
    "InjectionReport",
    "inject_faults",
    "IMU_FAULT_MESSAGES",
]

#: IMU messages an :class:`ImuFault` can bias.
IMU_FAULT_MESSAGES = ("RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
_SHAPES = ("step", "ramp", "intermittent")
_INT16 = (-32768, 32767)


@dataclass(frozen=True)
class FaultShape:
    """When a fault acts and how much of it (0 … 1), on the autopilot's boot clock.

    Attributes:
        shape: ``step``, ``ramp`` or ``intermittent``.
        start_s: boot time the fault begins, s.
        duration_s: how long it lasts from ``start_s``, s (inf = to the end).
        ramp_s: ``ramp``: time from 0 to the full offset, s (a 3° offset over
            15 s is a 0.2°/s drift).
        period_s, on_s: ``intermittent``: the full offset for ``on_s`` out of
            every ``period_s``, starting at ``start_s``, s.
    """

    shape: str = "step"
    start_s: float = 100.0
    duration_s: float = math.inf
    ramp_s: float = 10.0
    period_s: float = 4.0
    on_s: float = 1.0

    def __post_init__(self) -> None:
        if self.shape not in _SHAPES:
            raise ValueError(f"fault shape must be one of {', '.join(_SHAPES)}, got {self.shape!r}")
        if not (math.isfinite(self.start_s) and self.start_s >= 0):
            raise ValueError(f"fault start_s must be ≥ 0, got {self.start_s!r}")
        if not self.duration_s > 0:
            raise ValueError(f"fault duration_s must be > 0, got {self.duration_s!r}")
        for name in ("ramp_s", "period_s", "on_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"fault {name} must be > 0, got {v!r}")
        if self.on_s > self.period_s:
            raise ValueError(f"fault on_s ({self.on_s}) must be ≤ period_s ({self.period_s})")

    def factor(self, t_s: float) -> float:
        """The fraction of the full offset at boot time ``t_s`` (0 outside the fault)."""
        dt = t_s - self.start_s
        if dt < 0.0 or dt >= self.duration_s:
            return 0.0
        if self.shape == "step":
            return 1.0
        if self.shape == "ramp":
            return min(1.0, dt / self.ramp_s)
        return 1.0 if (dt % self.period_s) < self.on_s else 0.0

    def factors(self, t_s: np.ndarray) -> np.ndarray:
        """:meth:`factor` at every boot time of ``t_s`` (an array), s."""
        dt = np.asarray(t_s, np.float64) - self.start_s
        inside = (dt >= 0.0) & (dt < self.duration_s)
        if self.shape == "step":
            k = np.ones_like(dt)
        elif self.shape == "ramp":
            k = np.minimum(1.0, dt / self.ramp_s)
        else:
            k = np.where(np.mod(dt, self.period_s) < self.on_s, 1.0, 0.0)
        return np.where(inside, k, 0.0)


@dataclass(frozen=True)
class AttitudeFault:
    """An error in the autopilot's attitude (ATTITUDE and ATTITUDE_QUATERNION), Euler offsets in degrees."""

    when: FaultShape = field(default_factory=FaultShape)
    roll_deg: float = 0.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0
    tilt_deg: float = 0.0
    tilt_azimuth_deg: float = 0.0
    heading_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("roll_deg", "pitch_deg", "yaw_deg", "tilt_deg", "tilt_azimuth_deg", "heading_deg"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"attitude fault {name} must be finite")


@dataclass(frozen=True)
class ImuFault:
    """A gyro and/or accelerometer bias on one IMU, body axes (x, y, z).

    In a tlog the IMU is a message (``message``); in an onboard log (.BIN, .ulg) an instance: ``instance``
    (0 = the first IMU), else the one ``message`` carries (RAW_IMU / SCALED_IMU 0, SCALED_IMU2 1,
    SCALED_IMU3 2, HIGHRES_IMU 0; :mod:`mavahrs.evaluation.onboard_faults`). A tlog refuses ``instance``.
    """

    message: str = "RAW_IMU"
    when: FaultShape = field(default_factory=FaultShape)
    gyro_bias_deg_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    instance: int | None = None

    def __post_init__(self) -> None:
        if self.message not in IMU_FAULT_MESSAGES:
            raise ValueError(f"IMU fault message must be one of {', '.join(IMU_FAULT_MESSAGES)}, got {self.message!r}")
        if self.instance is not None and not (isinstance(self.instance, int) and 0 <= self.instance < 256):
            raise ValueError(f"IMU fault instance must be an integer 0…255, got {self.instance!r}")
        for name in ("gyro_bias_deg_s", "accel_bias_m_s2"):
            v = getattr(self, name)
            if len(v) != 3 or not all(math.isfinite(x) for x in v):
                raise ValueError(f"IMU fault {name} must be three finite numbers, got {v!r}")


@dataclass
class InjectionReport:
    """What :func:`inject_faults` did.

    Attributes:
        records: tlog records copied.
        modified: messages rewritten, by type.
        first_s, last_s: boot times of the first and last rewritten message, s (NaN: none).
        seen_first_s, seen_last_s: boot times of the first and last message that could have been
            rewritten (the fault's messages from its source), s (NaN: none in the log).
        unsigned: signed frames written without their signature (rewritten ones only).
        clipped: IMU fields that hit their integer range.
        source: the (system, component) whose messages were rewritten (a tlog's).
        format: the log's format (:data:`mavahrs.logs.FORMATS`): ``tlog``, ``dataflash``, ``ulog``; an
            onboard log's ``records`` are its DataFlash / ULog records, ``modified`` counts record types
            (DataFlash; IMU records as ``IMU[1]``: instance 1) or topics (ULog, ``name[multi_id]``).
    """

    records: int = 0
    modified: dict[str, int] = field(default_factory=dict)
    first_s: float = math.nan
    last_s: float = math.nan
    seen_first_s: float = math.nan
    seen_last_s: float = math.nan
    unsigned: int = 0
    clipped: int = 0
    source: tuple[int, int] = (0, 0)
    format: str = "tlog"

    def text(self) -> str:
        what = ", ".join(f"{n} {k}" for k, n in sorted(self.modified.items())) or "nothing"
        span = f" from {self.first_s:.3f} to {self.last_s:.3f} s boot time" if self.modified else ""
        extra = f"; {self.unsigned} signed frames written unsigned" if self.unsigned else ""
        extra += f"; {self.clipped} values clipped to their integer range" if self.clipped else ""
        if self.format != "tlog":
            return f"{self.records} records copied, rewritten in place: {what}{span}{extra}"
        return f"{self.records} records copied, rewritten: {what}{span} (system {self.source[0]} component " \
               f"{self.source[1]}){extra}"  # fmt: skip


# --------------------------------------------------------------------------- maths


def _euler_of_q(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


_q_of_euler = euler_to_q_scalar


def _wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


def _shift_euler(roll: float, pitch: float, yaw: float, f: AttitudeFault, k: float) -> tuple[float, float, float]:
    r = roll + k * math.radians(f.roll_deg)
    p = pitch + k * math.radians(f.pitch_deg)
    if p > 0.5 * math.pi or p < -0.5 * math.pi:  # past the pole: the same attitude, Euler-wise
        p = math.copysign(math.pi, p) - p
        r += math.pi
        yaw += math.pi
    return _wrap(r), p, _wrap(yaw + k * math.radians(f.yaw_deg))


# --------------------------------------------------------------------------- the copy


def _boot_s(msg: Any) -> float:
    if hasattr(msg, "time_boot_ms"):
        return float(msg.time_boot_ms) * 1e-3
    return float(msg.time_usec) * 1e-6


def _autopilot_source(path: Path) -> tuple[int, int]:
    from mavahrs.protocol.codec import mavlink
    from mavahrs.protocol.tlog import read_tlog_messages

    for _t, msg in read_tlog_messages(path, "HEARTBEAT"):
        if msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID:
            return int(msg.get_srcSystem()), 1
    return 1, 1


def _qmul(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    return (
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    )


def _earth_error(f: AttitudeFault, k: float) -> tuple[float, float, float, float] | None:
    """The earth-frame (NED) rotation of the tilt and heading parts, heading ⊗ tilt; None without them."""
    if f.tilt_deg == 0.0 and f.heading_deg == 0.0:
        return None
    a = 0.5 * k * math.radians(f.tilt_deg)
    az = math.radians(f.tilt_azimuth_deg)
    tilt = (math.cos(a), math.sin(a) * math.cos(az), math.sin(a) * math.sin(az), 0.0)
    h = 0.5 * k * math.radians(f.heading_deg)
    return _qmul((math.cos(h), 0.0, 0.0, math.sin(h)), tilt)


def _shift(q: Sequence[float], active: Sequence[tuple[AttitudeFault, float]]) -> tuple[float, float, float, float]:
    w, x, y, z = q
    for f, k in active:
        if f.roll_deg or f.pitch_deg or f.yaw_deg:
            w, x, y, z = _q_of_euler(*_shift_euler(*_euler_of_q(w, x, y, z), f, k))
        e = _earth_error(f, k)
        if e is not None:
            w, x, y, z = _qmul(e, (w, x, y, z))
    return w, x, y, z


def _apply_attitude(msg: Any, faults: Sequence[AttitudeFault], t_s: float) -> bool:
    active = [(f, f.when.factor(t_s)) for f in faults]
    active = [(f, k) for f, k in active if k != 0.0]
    if not active:
        return False
    if msg.get_type() == "ATTITUDE":
        r, p, y = float(msg.roll), float(msg.pitch), float(msg.yaw)
        if all(not (f.tilt_deg or f.heading_deg) for f, _k in active):  # Euler offsets only: exact in Euler
            for f, k in active:
                r, p, y = _shift_euler(r, p, y, f, k)
        else:
            r, p, y = _euler_of_q(*_shift(_q_of_euler(r, p, y), active))
        msg.roll, msg.pitch, msg.yaw = r, p, y
    else:
        w, x, yy, z = _shift((float(msg.q1), float(msg.q2), float(msg.q3), float(msg.q4)), active)
        if w * msg.q1 + x * msg.q2 + yy * msg.q3 + z * msg.q4 < 0.0:  # keep the sender's hemisphere
            w, x, yy, z = -w, -x, -yy, -z
        msg.q1, msg.q2, msg.q3, msg.q4 = w, x, yy, z
    return True


def _apply_imu(msg: Any, faults: Sequence[ImuFault], t_s: float, report: InjectionReport) -> bool:
    kind = msg.get_type()
    changed = False
    for f in faults:
        if f.message != kind:
            continue
        k = f.when.factor(t_s)
        if k == 0.0:
            continue
        changed = True
        highres = kind == "HIGHRES_IMU"
        g = [k * math.radians(v) * (1.0 if highres else 1000.0) for v in f.gyro_bias_deg_s]  # rad/s or mrad/s
        a = [k * v * (1.0 if highres else 1000.0 / 9.80665) for v in f.accel_bias_m_s2]  # m/s² or mG
        for name, add in zip(("xgyro", "ygyro", "zgyro", "xacc", "yacc", "zacc"), g + a, strict=True):
            if add == 0.0:
                continue
            v = getattr(msg, name) + add
            if not highres:
                v = int(round(v))
                if not _INT16[0] <= v <= _INT16[1]:
                    v = max(_INT16[0], min(_INT16[1], v))
                    report.clipped += 1
            setattr(msg, name, v)
    return changed


def inject_faults(
    src: str | os.PathLike[str],
    dst: str | os.PathLike[str],
    faults: Sequence[AttitudeFault | ImuFault],
    *,
    system_id: int | None = None,
    component_id: int = 1,
) -> InjectionReport:
    """Copy the log ``src`` to ``dst`` with ``faults`` added (see the module docstring).

    The format is chosen by content (:func:`mavahrs.logs.sniff`, as replay chooses): a DataFlash log
    (.BIN) or a ULog (.ulg) is rewritten in place by :mod:`mavahrs.evaluation.onboard_faults`
    (``system_id`` / ``component_id`` do not apply), anything else is copied as a tlog.
    ``dst`` is the original's bytes (junk and all) with the rewritten frames (records) spliced in, written
    to a temporary file beside it and renamed when complete.
    Raises DataError when ``src`` holds no MAVLink (DataFlash, ULog) records, ValueError when
    ``dst`` is ``src`` or an :class:`ImuFault` names an ``instance`` for a tlog.
    """
    from mavahrs.errors import DataError
    from mavahrs.protocol.codec import mavlink
    from mavahrs.protocol.fast_tlog import scan_tlog

    src_p, dst_p = Path(src), Path(dst)
    if dst_p.exists() and os.path.samefile(src_p, dst_p):
        raise ValueError(f"{dst_p}: the faulty copy must not replace the original")
    from mavahrs.logs import sniff

    kind = sniff(src_p)  # by content, as replay chooses (a .ulg scanned as a tlog held 24 "records")
    if kind in ("dataflash", "ulog"):
        from mavahrs.evaluation import onboard_faults

        inject = onboard_faults.inject_dataflash if kind == "dataflash" else onboard_faults.inject_ulog
        return inject(src_p, dst_p, faults)
    att = [f for f in faults if isinstance(f, AttitudeFault)]
    imu = [f for f in faults if isinstance(f, ImuFault)]
    if any(f.instance is not None for f in imu):
        raise ValueError(f"{src_p}: a telemetry log's IMU is named by its message ({', '.join(IMU_FAULT_MESSAGES)}), "
                         "not an instance number")
    types = {"ATTITUDE", "ATTITUDE_QUATERNION"} if att else set()
    types |= {f.message for f in imu}
    sysid = system_id if system_id is not None else _autopilot_source(src_p)[0]
    report = InjectionReport(source=(int(sysid), int(component_id)))
    scan = scan_tlog(src_p, None, mode="mmap")
    if len(scan) == 0:
        raise DataError(f"{src_p}: no MAVLink records to copy")
    report.records = len(scan)
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    packer = mavlink.MAVLink(None)
    ids = {cls.id: name for name, cls in ((n, getattr(mavlink, f"MAVLink_{n.lower()}_message")) for n in types)}
    data = scan.data
    picks = np.flatnonzero(np.isin(scan.msgid, list(ids)) & ~scan.in_side) if ids else np.zeros(0, np.int64)
    edits: list[tuple[int, int, bytes]] = []  # (file offset, old length, new frame)
    for j in picks:
        o, n = int(scan.offset[j]), int(scan.length[j])
        frame = bytes(data[o : o + n])
        v2 = frame[0] == 0xFD
        sys_c = (frame[5], frame[6]) if v2 else (frame[3], frame[4])
        if sys_c != (sysid, component_id):
            continue
        msg = _decode(mav, frame)
        if msg is None:
            continue
        name = ids[int(scan.msgid[j])]
        t_s = _boot_s(msg)
        report.seen_first_s = min(report.seen_first_s, t_s) if math.isfinite(report.seen_first_s) else t_s
        report.seen_last_s = max(report.seen_last_s, t_s) if math.isfinite(report.seen_last_s) else t_s
        hit = _apply_attitude(msg, att, t_s) if name.startswith("ATTITUDE") else _apply_imu(msg, imu, t_s, report)
        if not hit:
            continue
        packer.seq = frame[4] if v2 else frame[2]
        packer.srcSystem, packer.srcComponent = sys_c
        edits.append((o, n, bytes(msg.pack(packer, force_mavlink1=not v2))))
        if v2 and frame[2] & 0x01:
            report.unsigned += 1
        report.modified[name] = report.modified.get(name, 0) + 1
        if not math.isfinite(report.first_s):
            report.first_s = t_s
        report.last_s = t_s
    raw = data.tobytes() if hasattr(data, "tobytes") else bytes(data)
    tmp = dst_p.with_name(f".{dst_p.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as out:  # the original bytes, the rewritten frames spliced in
            pos = 0
            for o, n, new in edits:
                out.write(raw[pos:o])
                out.write(new)
                pos = o + n
            out.write(raw[pos:])
        os.replace(tmp, dst_p)
    finally:
        tmp.unlink(missing_ok=True)
    return report


def _decode(mav: Any, frame: bytes) -> Any | None:
    try:
        return mav.decode(bytearray(frame))
    except Exception:  # noqa: BLE001 - the scan only hands out frames that decode; be safe anyway
        return None
