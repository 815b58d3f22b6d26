"""A tiny synthetic autopilot for pipeline tests: a known trajectory encoded as real MAVLink frames.

The trajectory is analytic (Euler angles as smooth functions of time, body
rates from their derivatives), so the truth is exact at every sample.  Frames
are encoded with :class:`MavCodec` exactly as an ArduPilot would send them
(RAW_IMU in mG / mrad/s / mgauss, int16, ``time_usec`` since boot) and decoded
again before reaching the pipeline, as in the daemon.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from mavahrs.geometry import rotation
from mavahrs.protocol.codec import MavCodec

G = 9.80665
MAG_NED_UT = np.array([20.0, 0.0, 45.0])  # magnetic north, dip ≈ 66°
BOOT_US = 1_000_000  # the autopilot has been up 1 s when the stream starts


@dataclass
class Trajectory:
    """Exact attitude and body rates at the sample times."""

    t_us: np.ndarray  # (N,) int
    q_body_to_ned: np.ndarray  # (N, 4)
    gyro_rad_s: np.ndarray  # (N, 3)
    accel_m_s2: np.ndarray  # (N, 3) specific force in body axes (no linear acceleration)
    mag_ut: np.ndarray  # (N, 3) field in body axes

    def index_of_ms(self, time_boot_ms: int) -> int:
        return int(np.searchsorted(self.t_us // 1000, time_boot_ms))


def make_trajectory(duration_s: float = 20.0, rate_hz: float = 400.0, rest_s: float = 2.0) -> Trajectory:
    """Level and still for ``rest_s``, then smooth roll/pitch/yaw swings (±30°, ±20°, ±40°)."""
    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    ramp = np.clip((t - rest_s) / 2.0, 0.0, 1.0)
    ramp = ramp * ramp * (3 - 2 * ramp)  # smoothstep: no rate step at the start of motion
    dramp = np.where((t > rest_s) & (t < rest_s + 2.0), 6 * ((t - rest_s) / 2.0) * (1 - (t - rest_s) / 2.0) / 2.0, 0.0)
    w1, w2, w3 = 2 * np.pi * 0.25, 2 * np.pi * 0.2, 2 * np.pi * 0.1
    a1, a2, a3 = np.radians(30.0), np.radians(20.0), np.radians(40.0)
    s1, s2, s3 = np.sin(w1 * t), np.sin(w2 * t + 0.5), np.sin(w3 * t)
    roll, pitch, yaw = a1 * ramp * s1, a2 * ramp * s2, np.radians(30.0) + a3 * ramp * s3
    droll = a1 * (dramp * s1 + ramp * w1 * np.cos(w1 * t))
    dpitch = a2 * (dramp * s2 + ramp * w2 * np.cos(w2 * t + 0.5))
    dyaw = a3 * (dramp * s3 + ramp * w3 * np.cos(w3 * t))
    # ZYX Euler rates → body rates
    p = droll - dyaw * np.sin(pitch)
    q = dpitch * np.cos(roll) + dyaw * np.cos(pitch) * np.sin(roll)
    r = -dpitch * np.sin(roll) + dyaw * np.cos(pitch) * np.cos(roll)
    quat = rotation.from_euler_rad(roll, pitch, yaw)
    t_us = BOOT_US + np.round(t * 1e6).astype(np.int64)
    c = rotation.to_matrix(quat)  # body → NED; body vectors = Cᵀ·v_ned
    accel = np.einsum("nji,j->ni", c, np.array([0.0, 0.0, -G]))
    mag = np.einsum("nji,j->ni", c, MAG_NED_UT)
    return Trajectory(t_us, quat, np.stack([p, q, r], axis=1), accel, mag)


class SyntheticAutopilot:
    """Encodes what an ArduPilot at ``system_id``/``component_id`` would send."""

    def __init__(self, system_id: int = 1, component_id: int = 1, autopilot: int = 3) -> None:
        self.codec = MavCodec(system_id, component_id)
        self.autopilot = autopilot

    def heartbeat(self) -> bytes:
        return self.codec.encode(self.codec.mav.heartbeat_encode(2, self.autopilot, 0, 0, 4))

    @staticmethod
    def body_vectors(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = rotation.to_matrix(q)
        return c.T @ np.array([0.0, 0.0, -G]), c.T @ MAG_NED_UT

    def raw_imu_k(self, traj: Trajectory, k: int, t_us: int | None = None) -> bytes:
        """RAW_IMU of trajectory sample ``k`` (stamped ``t_us``, default its own time)."""
        t = int(traj.t_us[k]) if t_us is None else t_us
        return self._raw_imu(t, traj.accel_m_s2[k], traj.gyro_rad_s[k], traj.mag_ut[k], 3500)

    def raw_imu(self, t_us: int, q: np.ndarray, gyro: np.ndarray, *, temperature_cdeg: int = 3500) -> bytes:
        f, m = self.body_vectors(q)
        return self._raw_imu(t_us, f, gyro, m, temperature_cdeg)

    def _raw_imu(self, t_us: int, f: np.ndarray, gyro: np.ndarray, m: np.ndarray, temperature_cdeg: int) -> bytes:
        acc = [int(round(x)) for x in f / G * 1000.0]
        gy = [int(round(x)) for x in gyro * 1000.0]
        mg = [int(round(x)) for x in m * 10.0]
        return self.codec.encode(self.codec.mav.raw_imu_encode(int(t_us), *acc, *gy, *mg, 0, temperature_cdeg))

    def scaled_imu2(self, t_us: int, q: np.ndarray | None, gyro: np.ndarray | None) -> bytes:
        """SCALED_IMU2; ``q=None`` sends the all-zero accel/gyro of a board without a second IMU."""
        if q is None:
            acc, gy = [0, 0, 0], [0, 0, 0]
            mg = [-289, 162, 223]
        else:
            f, m = self.body_vectors(q)
            acc = [int(round(x)) for x in f / G * 1000.0]
            gy = [int(round(x)) for x in gyro * 1000.0]
            mg = [int(round(x)) for x in m * 10.0]
        return self.codec.encode(self.codec.mav.scaled_imu2_encode(int(t_us) // 1000, *acc, *gy, *mg, 0))

    def highres_imu(self, t_us: int, accel, gyro, mag_gauss, fields_updated: int = 0x1FF) -> bytes:
        return self.codec.encode(
            self.codec.mav.highres_imu_encode(int(t_us), *accel, *gyro, *mag_gauss, 1013.0, 0.0, 10.0, 20.0, fields_updated, 0)
        )

    def global_position_int(self, t_us: int, vel_ned_m_s=(0.0, 0.0, 0.0), lat_e7: int = 473977420, lon_e7: int = 85455940) -> bytes:
        vx, vy, vz = (int(round(v * 100)) for v in vel_ned_m_s)
        return self.codec.encode(
            self.codec.mav.global_position_int_encode(int(t_us) // 1000, lat_e7, lon_e7, 500000, 10000, vx, vy, vz, 0)
        )

    def gps_raw_int(
        self, time_usec: int, vel_cm_s: int, cog_cdeg: int, fix_type: int = 3, lat_e7: int = 473977420,
        lon_e7: int = 85455940,
    ) -> bytes:  # fmt: skip
        """GPS_RAW_INT: ground speed and course over ground as the receiver gives them (UINT16_MAX = unknown)."""
        return self.codec.encode(
            self.codec.mav.gps_raw_int_encode(int(time_usec), fix_type, lat_e7, lon_e7, 500000, 80, 120,
                                              vel_cm_s, cog_cdeg, 12)  # fmt: skip
        )

    def gps2_raw(self, time_usec: int, vel_cm_s: int, cog_cdeg: int, fix_type: int = 3) -> bytes:
        return self.codec.encode(
            self.codec.mav.gps2_raw_encode(int(time_usec), fix_type, 473977420, 85455940, 500000, 80, 120,
                                           vel_cm_s, cog_cdeg, 12, 0, 0)  # fmt: skip
        )

    def command_ack(self, result: int, target_system: int = 1, target_component: int = 191) -> bytes:
        return self.codec.encode(self.codec.mav.command_ack_encode(511, result, 0, 0, target_system, target_component))

    def statustext(self, text: str) -> bytes:
        return self.codec.encode(self.codec.mav.statustext_encode(6, text.encode()))


@pytest.fixture(scope="session")
def trajectory() -> Trajectory:
    """20 s at 400 Hz (8000 samples)."""
    return make_trajectory()


@pytest.fixture
def autopilot() -> SyntheticAutopilot:
    """ArduPilot, system 1, component 1."""
    return SyntheticAutopilot()


@pytest.fixture
def make_autopilot() -> type[SyntheticAutopilot]:
    """The class, for a second source or another autopilot type: ``make_autopilot(sysid, compid, autopilot)``."""
    return SyntheticAutopilot
