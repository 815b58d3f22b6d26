r"""Loop-tick state → MAVLink frames, with the wire units autopilots use.

All frames go through :class:`mavahrs.protocol.codec.MavCodec` (one encoder in
the project).  Units:

* RAW_IMU (ArduPilot): acceleration in mG (``accel · 1000 / 9.80665``), rates
  in mrad/s, field in milligauss, ``time_usec`` = the *send* time since boot;
  calibrated and low-passed values, each converted by C's implicit float →
  int16 conversion, i.e. truncated toward zero (and clipped to int16 here, as
  the ARM float→int conversion saturates: RAW_IMU cannot carry more than
  32.767 rad/s ≈ 1877 °/s);  ``temperature`` in c°C.
* SCALED_IMU / SCALED_IMU2 / SCALED_IMU3: the same units with ``time_boot_ms``.
* HIGHRES_IMU (PX4): SI floats (m/s², rad/s, gauss, hPa, °C), ``time_usec`` =
  sample time, ``fields_updated`` bit mask (mag bits only on a fresh sample).
* GLOBAL_POSITION_INT: degE7, mm, cm/s NED, heading c°.
* ATTITUDE / ATTITUDE_QUATERNION: the autopilot's estimate.
* SIMSTATE (ArduPilot SITL): true Euler angles (rad), true specific force in
  body axes (m/s²), true body rates (rad/s), degE7 position.
* SIM_STATE (common): the true quaternion (q1..q4 = w, x, y, z) and the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from firmware_sim.simulation import LoopBlock
from firmware_sim.vehicle import G
from mavahrs.geometry.rotation import to_euler_rad
from mavahrs.protocol.codec import MavCodec, mavlink

__all__ = ["FrameEncoder", "WireBlock", "Autopilot", "to_int16"]

Array = NDArray[np.float64]


def to_int16(x: Array) -> NDArray[np.int64]:
    """C float → int16 as on the autopilot: truncate toward zero, saturate."""
    return np.clip(np.trunc(np.nan_to_num(x)), -32768, 32767).astype(np.int64)


@dataclass(frozen=True)
class Autopilot:
    """HEARTBEAT identity of the simulated flight controller."""

    name: str  # "ardupilot" | "px4"

    def __post_init__(self) -> None:
        if self.name not in ("ardupilot", "px4"):
            raise ValueError(f"autopilot must be 'ardupilot' or 'px4', got {self.name!r}")

    @property
    def mav_autopilot(self) -> int:
        return mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA if self.name == "ardupilot" else mavlink.MAV_AUTOPILOT_PX4


class WireBlock:
    """A :class:`LoopBlock` converted once to wire units, as Python lists (fast per-tick access)."""

    def __init__(self, blk: LoopBlock) -> None:
        self.blk = blk
        self.k0 = blk.k0
        self.t_us = blk.t_us.tolist()
        self.acc_mg = [to_int16(a * (1000.0 / G)).tolist() for a in blk.accel_m_s2]
        self.gyro_mrad_s = [to_int16(g * 1000.0).tolist() for g in blk.gyro_rad_s]
        self.mag_mgauss = [to_int16(m * 10.0).tolist() for m in blk.mag_ut]
        self.mag_fresh = [f.tolist() for f in blk.mag_fresh]
        self.temp_cdeg = np.round(blk.temperature_c * 100.0).astype(np.int64).tolist()
        self.temperature_c = blk.temperature_c.tolist()
        self.accel = [a.tolist() for a in blk.accel_m_s2]
        self.gyro = [g.tolist() for g in blk.gyro_rad_s]
        self.mag_gauss = [(m * 0.01).tolist() for m in blk.mag_ut]
        tr = blk.truth
        self.true_q = tr.q_body_to_ned.tolist()
        self.true_euler = to_euler_rad(tr.q_body_to_ned).tolist()
        self.true_gyro = tr.gyro_rad_s.tolist()
        self.true_accel = tr.accel_m_s2.tolist()
        self.true_vel = tr.vel_ned_m_s.tolist()
        self.est_q = blk.est_q_body_to_ned.tolist()
        self.est_euler = to_euler_rad(blk.est_q_body_to_ned).tolist()
        # ATTITUDE rates: the primary gyro minus its bias (the estimator has learned it)
        # (in body axes: the IMU's axes rotated back by its mounting)
        self.est_rates = ((blk.gyro_rad_s[0] - blk.gyro_bias_rad_s[0]) @ blk.c_imu_to_body.T).tolist()
        self.lat_e7 = np.round(blk.lat_deg * 1e7).astype(np.int64).tolist()
        self.lon_e7 = np.round(blk.lon_deg * 1e7).astype(np.int64).tolist()
        self.lat = blk.lat_deg.tolist()
        self.lon = blk.lon_deg.tolist()
        self.alt_mm = np.round(blk.alt_m * 1000.0).astype(np.int64).tolist()
        self.alt_m = blk.alt_m.tolist()
        self.rel_alt_mm = np.round(-blk.truth.pos_ned_m[:, 2] * 1000.0).astype(np.int64).tolist()
        self.vel_cm_s = to_int16(np.round(blk.vel_ned_m_s * 100.0)).tolist()
        yaw = np.degrees(to_euler_rad(blk.est_q_body_to_ned)[:, 2]) % 360.0
        self.hdg_cdeg = (np.round(yaw * 100.0).astype(np.int64) % 36000).tolist()
        # battery: SYS_STATUS / BATTERY_STATUS units (mV, cA, mAh, %)
        self.voltage_mv = np.round(blk.voltage_v * 1000.0).astype(np.int64).tolist()
        self.current_ca = np.round(blk.current_a * 100.0).astype(np.int64).tolist()
        self.consumed_mah = np.round(blk.consumed_mah).astype(np.int64).tolist()
        # barometric pressure for HIGHRES_IMU (ISA troposphere)
        self.pressure_hpa = (1013.25 * (1.0 - 2.25577e-5 * blk.alt_m) ** 5.25588).tolist()


class FrameEncoder:
    """Builds frames for one link (one codec: one sequence counter)."""

    def __init__(self, codec: MavCodec, autopilot: Autopilot) -> None:
        self.codec = codec
        self.mav = codec.mav
        self.autopilot = autopilot

    def _enc(self, msg: object) -> bytes:
        return self.codec.encode(msg)

    # ------------------------------------------------------------------ sensors
    def raw_imu(self, w: WireBlock, i: int, send_us: int) -> bytes:
        a, g, m = w.acc_mg[0][i], w.gyro_mrad_s[0][i], self._mag_mgauss(w, 0, i)
        return self._enc(
            self.mav.raw_imu_encode(send_us, a[0], a[1], a[2], g[0], g[1], g[2], m[0], m[1], m[2], 0, w.temp_cdeg[i])
        )

    @staticmethod
    def _mag_mgauss(w: WireBlock, instance: int, i: int) -> list[int]:
        return w.mag_mgauss[instance][i] if instance < len(w.mag_mgauss) else [0, 0, 0]

    def scaled_imu(self, instance: int, w: WireBlock, i: int, send_us: int) -> bytes | None:
        """SCALED_IMU (instance 0), SCALED_IMU2 (1) or SCALED_IMU3 (2); None if the
        instance has neither an IMU nor a compass (ArduPilot then sends nothing)."""
        have_imu = instance < len(w.acc_mg)
        have_mag = instance < len(w.mag_mgauss)
        if not (have_imu or have_mag):
            return None
        a = w.acc_mg[instance][i] if have_imu else [0, 0, 0]
        g = w.gyro_mrad_s[instance][i] if have_imu else [0, 0, 0]
        m = self._mag_mgauss(w, instance, i)
        t_ms = send_us // 1000
        temp = w.temp_cdeg[i] if have_imu else 0
        ctor = (self.mav.scaled_imu_encode, self.mav.scaled_imu2_encode, self.mav.scaled_imu3_encode)[instance]
        return self._enc(ctor(t_ms, a[0], a[1], a[2], g[0], g[1], g[2], m[0], m[1], m[2], temp))

    def highres_imu(self, w: WireBlock, i: int, sample_us: int, instance: int = 0) -> bytes:
        a, g = w.accel[instance][i], w.gyro[instance][i]
        have_mag = instance < len(w.mag_gauss)
        m = w.mag_gauss[instance][i] if have_mag else [0.0, 0.0, 0.0]
        fields = 0x003F | 0x1E00  # accel, gyro, abs pressure, diff pressure, alt, temperature
        if have_mag and w.mag_fresh[instance][i]:
            fields |= 0x01C0
        p = w.pressure_hpa[i]
        return self._enc(
            self.mav.highres_imu_encode(
                sample_us, a[0], a[1], a[2], g[0], g[1], g[2], m[0], m[1], m[2],
                p, 0.0, w.alt_m[i], w.temperature_c[i], fields, instance,
            )
        )

    # ------------------------------------------------------------------ navigation
    def global_position_int(self, w: WireBlock, i: int, send_us: int) -> bytes:
        v = w.vel_cm_s[i]
        return self._enc(
            self.mav.global_position_int_encode(
                send_us // 1000, w.lat_e7[i], w.lon_e7[i], w.alt_mm[i], w.rel_alt_mm[i], v[0], v[1], v[2], w.hdg_cdeg[i]
            )
        )

    def gps_raw_int(self, time_usec: int, lat_e7: int, lon_e7: int, alt_mm: int, vel_cm_s: int, cog_cdeg: int) -> bytes:
        """A 3D fix from the receiver: ground speed and course over ground, HDOP 0.8, VDOP 1.2, 12 satellites."""
        return self._enc(self.mav.gps_raw_int_encode(time_usec, 3, lat_e7, lon_e7, alt_mm, 80, 120, vel_cm_s, cog_cdeg, 12))

    # ------------------------------------------------------------------ power
    def sys_status(self, w: WireBlock, i: int, remaining_pct: int, gps: bool = True) -> bytes:
        """SYS_STATUS: sensors present/healthy (3D gyro, accel, mag), battery voltage (mV),
        current (cA = 10 mA, as the current that drives the motor interference) and remaining %."""
        sensors = 0x07 | (0x20 if gps else 0)  # 3D gyro, accel, mag; GPS if there is a receiver
        return self._enc(
            self.mav.sys_status_encode(sensors, sensors, sensors, 250, w.voltage_mv[i], w.current_ca[i], remaining_pct,
                                       0, 0, 0, 0, 0, 0)
        )

    def battery_status(self, w: WireBlock, i: int, remaining_pct: int) -> bytes:
        """BATTERY_STATUS (id 0): the pack voltage in the first cell field (mV; ArduPilot does so
        without cell monitoring), current (cA), consumed charge (mAh), remaining %."""
        cells = [min(w.voltage_mv[i], 65534)] + [65535] * 9
        return self._enc(
            self.mav.battery_status_encode(0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO,
                                           w.temp_cdeg[i], cells, w.current_ca[i], w.consumed_mah[i], -1, remaining_pct)
        )

    def attitude(self, w: WireBlock, i: int, send_us: int) -> bytes:
        e, r = w.est_euler[i], w.est_rates[i]
        return self._enc(self.mav.attitude_encode(send_us // 1000, e[0], e[1], e[2], r[0], r[1], r[2]))

    def attitude_quaternion(self, w: WireBlock, i: int, send_us: int) -> bytes:
        q, r = w.est_q[i], w.est_rates[i]
        return self._enc(self.mav.attitude_quaternion_encode(send_us // 1000, q[0], q[1], q[2], q[3], r[0], r[1], r[2]))

    def system_time(self, w: WireBlock, i: int, send_us: int, epoch_unix_us: int) -> bytes:
        return self._enc(self.mav.system_time_encode(epoch_unix_us + send_us, send_us // 1000))

    # ------------------------------------------------------------------ truth
    def simstate(self, w: WireBlock, i: int) -> bytes:
        e, a, g = w.true_euler[i], w.true_accel[i], w.true_gyro[i]
        return self._enc(
            self.mav.simstate_encode(e[0], e[1], e[2], a[0], a[1], a[2], g[0], g[1], g[2], w.lat_e7[i], w.lon_e7[i])
        )

    def sim_state(self, w: WireBlock, i: int) -> bytes:
        q, e, a, g, v = w.true_q[i], w.true_euler[i], w.true_accel[i], w.true_gyro[i], w.true_vel[i]
        return self._enc(
            self.mav.sim_state_encode(
                q[0], q[1], q[2], q[3], e[0], e[1], e[2], a[0], a[1], a[2], g[0], g[1], g[2],
                w.lat[i], w.lon[i], w.alt_m[i], 0.0, 0.0, v[0], v[1], v[2], w.lat_e7[i], w.lon_e7[i],
            )
        )

    # ------------------------------------------------------------------ service
    def heartbeat(self, *, armed: bool, flying: bool) -> bytes:
        if self.autopilot.name == "ardupilot":
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
            base |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            custom = 0  # STABILIZE
        else:
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
            base |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            custom = 7 << 16  # PX4 main mode STABILIZED
        if armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        status = mavlink.MAV_STATE_ACTIVE if flying else mavlink.MAV_STATE_STANDBY
        return self._enc(
            self.mav.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, self.autopilot.mav_autopilot, base, custom, status, 3)
        )

    def autopilot_version(self, system_id: int) -> bytes:
        caps = (
            mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
        )
        if self.autopilot.name == "ardupilot":
            version = (4 << 24) | (5 << 16) | (7 << 8) | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL  # 4.5.7
        else:
            version = (1 << 24) | (15 << 16) | (0 << 8) | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL  # 1.15.0
        uid = 0x51D0000000000000 | system_id
        return self._enc(
            self.mav.autopilot_version_encode(caps, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0x1209, 0x5741, uid)
        )

    def statustext(self, severity: int, text: str) -> bytes:
        return self._enc(self.mav.statustext_encode(severity, text.encode("ascii", "replace")[:50]))

    def command_ack(self, command: int, result: int, target_system: int, target_component: int) -> bytes:
        return self._enc(self.mav.command_ack_encode(command, result, 0, 0, target_system, target_component))

    def message_interval(self, message_id: int, interval_us: int) -> bytes:
        return self._enc(self.mav.message_interval_encode(message_id, interval_us))
