r"""What a pilot looks for on the status page, from the autopilot's own messages (``docs/status-page.md``).

The daemon hands every decoded message to :meth:`PilotInfo.observe`, which
keeps only the last one of each type it reads (a set look-up and a dict store
per message); the fields are computed from them when the page's status is
published (once a second), by :func:`pilot_fields`:

* armed state and flight mode (the autopilot's HEARTBEAT; mode names from
  pymavlink for ArduPilot and PX4);
* battery voltage, current and charge left (SYS_STATUS; BATTERY_STATUS when
  SYS_STATUS has no voltage);
* altitude above home and above sea level (GLOBAL_POSITION_INT), ground
  speed (the same message's velocity, else VFR_HUD);
* GNSS fix type and satellites (GPS_RAW_INT);
* the magnetometer's field strength as measured (the latest RAW_IMU /
  SCALED_IMU* / HIGHRES_IMU) beside the World Magnetic Model's at the
  vehicle's position;
* whether ``--log`` records, to which file and how much so far;
* the processing latency against what it must fit in: the IMU sample period
  and the attitude output period.

Every value is None while the message it comes from has not arrived.
"""

from __future__ import annotations

import math
import os
from typing import Any

__all__ = ["PilotInfo", "pilot_fields", "latency_context", "GPS_FIX_NAMES"]

#: GPS_RAW_INT.fix_type (MAVLink GPS_FIX_TYPE)
GPS_FIX_NAMES = {0: "no GPS", 1: "no fix", 2: "2D fix", 3: "3D fix", 4: "DGPS", 5: "RTK float", 6: "RTK fixed",
                 7: "static", 8: "PPP"}  # fmt: skip

_TYPES = frozenset(
    ("HEARTBEAT", "SYS_STATUS", "BATTERY_STATUS", "GLOBAL_POSITION_INT", "VFR_HUD", "GPS_RAW_INT", "RAW_IMU",
     "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "HIGHRES_IMU")
)  # fmt: skip
_MAV_MODE_FLAG_SAFETY_ARMED = 128
_MAV_AUTOPILOT_INVALID = 8
_MAV_TYPE_GCS = 6


class PilotInfo:
    """The last message of each type the pilot fields read, from the autopilot (its system id, once known)."""

    def __init__(self) -> None:
        self.last: dict[str, Any] = {}

    def observe(self, msg: Any) -> None:
        """Keep ``msg`` if it is one of the types read (cheap: called for every message)."""
        kind = msg.get_type()
        if kind not in _TYPES:
            return
        if kind == "HEARTBEAT" and (
            getattr(msg, "autopilot", _MAV_AUTOPILOT_INVALID) == _MAV_AUTOPILOT_INVALID
            or getattr(msg, "type", None) == _MAV_TYPE_GCS
        ):
            return  # a ground station's, a companion's (ours): not the vehicle's
        hb = self.last.get("HEARTBEAT")
        if hb is not None and kind != "HEARTBEAT" and msg.get_srcSystem() != hb.get_srcSystem():
            return  # another vehicle's
        self.last[kind] = msg


def _mode(hb: Any) -> str | None:
    try:
        from pymavlink import mavutil

        return str(mavutil.mode_string_v10(hb))
    except Exception:  # noqa: BLE001 - an unknown firmware or mode: the number
        return f"mode {getattr(hb, 'custom_mode', '?')}"


def _battery(last: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {"voltage_v": None, "current_a": None, "remaining_pct": None}
    ss = last.get("SYS_STATUS")
    if ss is not None:
        if 0 < ss.voltage_battery < 65535:
            out["voltage_v"] = ss.voltage_battery / 1000.0
        if ss.current_battery >= 0:
            out["current_a"] = ss.current_battery / 100.0
        if 0 <= ss.battery_remaining <= 100:
            out["remaining_pct"] = int(ss.battery_remaining)
    bs = last.get("BATTERY_STATUS")
    if bs is not None:
        if out["voltage_v"] is None:
            cells = [v for v in bs.voltages if 0 < v < 65535]
            if cells:
                out["voltage_v"] = sum(cells) / 1000.0
        if out["current_a"] is None and bs.current_battery >= 0:
            out["current_a"] = bs.current_battery / 100.0
        if out["remaining_pct"] is None and 0 <= bs.battery_remaining <= 100:
            out["remaining_pct"] = int(bs.battery_remaining)
    return out


def _position(last: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {"altitude_rel_m": None, "altitude_msl_m": None, "ground_speed_m_s": None}
    gpi = last.get("GLOBAL_POSITION_INT")
    if gpi is not None:
        out["altitude_rel_m"] = gpi.relative_alt / 1000.0
        out["altitude_msl_m"] = gpi.alt / 1000.0
        out["ground_speed_m_s"] = math.hypot(gpi.vx, gpi.vy) / 100.0
    hud = last.get("VFR_HUD")
    if hud is not None and out["ground_speed_m_s"] is None:
        out["ground_speed_m_s"] = float(hud.groundspeed)
    return out


def _gnss(last: dict[str, Any]) -> dict[str, Any]:
    gps = last.get("GPS_RAW_INT")
    if gps is None:
        return {"fix": None, "fix_type": None, "satellites": None}
    sats = int(gps.satellites_visible)
    return {"fix": GPS_FIX_NAMES.get(int(gps.fix_type), f"fix type {int(gps.fix_type)}"),
            "fix_type": int(gps.fix_type), "satellites": None if sats == 255 else sats}  # fmt: skip


def _measured_field_ut(last: dict[str, Any]) -> float | None:
    """|B| of the latest magnetometer reading, µT (SCALED_IMU* and ArduPilot's RAW_IMU: mgauss; HIGHRES_IMU: gauss)."""
    hr = last.get("HIGHRES_IMU")
    if hr is not None:
        b = math.sqrt(hr.xmag**2 + hr.ymag**2 + hr.zmag**2) * 100.0
        if b > 0 and math.isfinite(b):
            return b
    for kind in ("SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "RAW_IMU"):
        m = last.get(kind)
        if m is not None and (m.xmag or m.ymag or m.zmag):
            return math.sqrt(m.xmag**2 + m.ymag**2 + m.zmag**2) / 10.0
    return None


def latency_context(p50_us: float | None, p99_us: float | None, imu_hz: float | None,
                    out_hz: float | None) -> dict[str, Any]:  # fmt: skip
    """The latency against the two periods it must fit in: the IMU sample period (to keep up) and the attitude
    output period (to be no older than one output when sent); ``ok`` = the p99 within the sample period."""
    sample_us = 1e6 / imu_hz if imu_hz and imu_hz > 0 else None
    out_us = 1e6 / out_hz if out_hz and out_hz > 0 else None
    ok = None if p99_us is None or sample_us is None else bool(p99_us <= sample_us)
    return {"sample_period_us": sample_us, "output_period_us": out_us, "within_sample_period": ok,
            "p99_sample_periods": None if p99_us is None or sample_us is None else p99_us / sample_us,
            "p50_us": p50_us, "p99_us": p99_us}  # fmt: skip


def _recording(path: str | None) -> dict[str, Any]:
    if not path:
        return {"recording": False, "path": None, "bytes": None}
    try:
        size: int | None = os.path.getsize(path)
    except OSError:
        size = None
    return {"recording": True, "path": os.path.abspath(path), "bytes": size}


def pilot_fields(daemon: Any, status: dict[str, Any]) -> dict[str, Any]:
    """The ``pilot`` object of ``/status.json`` (``status``: the daemon's status fields, for the rates)."""
    info: PilotInfo | None = getattr(daemon, "pilot", None)
    last = info.last if info is not None else {}
    hb = last.get("HEARTBEAT")
    expected = None
    decl = getattr(getattr(daemon, "pipeline", None), "declination", None)
    fld = getattr(decl, "field", None)
    if fld is not None:
        expected = getattr(fld, "strength_ut", None)
    settings = getattr(daemon, "settings", None)
    return {
        "armed": None if hb is None else bool(hb.base_mode & _MAV_MODE_FLAG_SAFETY_ARMED),
        "mode": None if hb is None else _mode(hb),
        "battery": _battery(last),
        **_position(last),
        "gnss": _gnss(last),
        "mag_field_ut": _measured_field_ut(last),
        "mag_field_expected_ut": expected,
        "log": _recording(getattr(settings, "log_path", None)),
        "latency": latency_context(status.get("latency_p50_us"), status.get("latency_p99_us"),
                                   status.get("filter_hz") or status.get("in_hz"), status.get("out_hz")),
    }  # fmt: skip
