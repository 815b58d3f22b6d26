r"""The simulated flight controller's state at each scheduler-loop tick (pure, seeded).

Combines the scenario, the vehicle dynamics, the IMUs and compasses, the
autopilot's own (noisy) attitude estimate and its GNSS velocity/position into
blocks of loop ticks.  The sensors run ``oversample`` times faster than the
loop (default 3 × 400 Hz = 1200 Hz); each tick *snapshots* the latest
filtered sample, as ArduPilot's INS front end does once per loop.

Tick ``k`` is at ``t_k = k / loop_rate_hz`` seconds of simulation time; the
autopilot's time since boot is ``t_k + boot_offset_s``.  Everything an
encoder needs for a tick is in :class:`LoopBlock` (row ``i`` = one tick).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from firmware_sim.imu_model import EarthField, ImuErrorSettings, ImuModel, MagModel, MagSettings, iir2
from firmware_sim.trajectory import make_scenario
from firmware_sim.vehicle import G, TruthChunk, Vehicle, VehicleSettings
from mavahrs.geometry import quaternion as quat
from mavahrs.geometry.rotation import from_euler_rad

__all__ = [
    "Home",
    "EstimateSettings",
    "AttitudeFault",
    "ImuFault",
    "SimSettings",
    "LoopBlock",
    "Simulation",
    "EARTH_RADIUS_M",
    "gravity_body",
]

Array = NDArray[np.float64]
EARTH_RADIUS_M = 6378137.0


@dataclass(frozen=True)
class Home:
    """Where the vehicle boots.  Default: ArduPilot SITL's CMAC field (Canberra)."""

    lat_deg: float = -35.363261
    lon_deg: float = 149.165230
    alt_m: float = 584.0  # AMSL

    def __post_init__(self) -> None:
        if not -90.0 <= self.lat_deg <= 90.0 or not -180.0 <= self.lon_deg <= 180.0:
            raise ValueError(f"Home: latitude/longitude out of range ({self.lat_deg}, {self.lon_deg})")


@dataclass(frozen=True)
class EstimateSettings:
    """The autopilot's own attitude estimate (what it sends in ATTITUDE): truth
    rotated by a first-order Gauss-Markov error (body frame) plus white noise."""

    tilt_sigma_deg: float = 0.3
    yaw_sigma_deg: float = 1.0
    tau_s: float = 5.0
    noise_deg: float = 0.05

    def __post_init__(self) -> None:
        if self.tau_s <= 0.0 or min(self.tilt_sigma_deg, self.yaw_sigma_deg, self.noise_deg) < 0.0:
            raise ValueError("EstimateSettings: tau_s must be > 0 and sigmas >= 0")


@dataclass(frozen=True)
class AttitudeFault:
    """An injected autopilot-estimator fault: from ``start_s`` the estimate is
    rotated (body frame, aerospace Euler offsets) by up to the given degrees,
    ramping in over ``ramp_s``, for ``duration_s`` (inf = to the end)."""

    start_s: float
    duration_s: float = math.inf
    roll_deg: float = 10.0
    pitch_deg: float = 0.0
    yaw_deg: float = 0.0
    ramp_s: float = 1.0

    def __post_init__(self) -> None:
        if self.start_s < 0.0 or self.duration_s <= 0.0 or self.ramp_s < 0.0:
            raise ValueError("AttitudeFault: need start_s >= 0, duration_s > 0, ramp_s >= 0")

    def weight(self, t_s: Array) -> Array:
        t = np.asarray(t_s, dtype=np.float64) - self.start_s
        up = np.ones_like(t) if self.ramp_s == 0.0 else np.clip(t / self.ramp_s, 0.0, 1.0)
        up = np.where(t >= 0.0, up, 0.0)
        return np.where(t <= self.duration_s, up, 0.0)


@dataclass(frozen=True)
class ImuFault:
    """A failing IMU instance: from ``freeze_at_s`` its reading is stuck at the last
    value; from ``saturate_at_s`` it reads +full scale on every axis (None = never)."""

    instance: int = 1
    freeze_at_s: float | None = None
    saturate_at_s: float | None = None


@dataclass(frozen=True)
class SimSettings:
    """Everything that defines a simulated flight (no I/O settings here).

    Attributes:
        scenario: one of :data:`firmware_sim.trajectory.SCENARIOS`.
        seed: seeds the plan and every sensor error; same seed → same flight, same bytes.
        loop_rate_hz: the autopilot scheduler loop (ArduPilot ``SCHED_LOOP_RATE``, Hz).
        oversample: sensor samples per loop tick (sensor rate = loop_rate_hz × oversample).
        boot_offset_s: time since boot at simulation start (s).
        imu_count: IMUs (1–3): RAW_IMU/SCALED_IMU carry #0, SCALED_IMU2 #1, SCALED_IMU3 #2.
        mag_count: compasses (0–3), instance numbering as the IMUs.
        gps_velocity_noise_m_s: white noise on the reported NED velocity (m/s, σ).
        jit: run the sequential kernels compiled by numba (long batch runs; pays numba's
            start-up of about 2 s once per process); results are the same to rounding.
    """

    scenario: str = "hover"
    seed: int = 0
    loop_rate_hz: float = 400.0
    oversample: int = 3
    boot_offset_s: float = 0.0
    vehicle: VehicleSettings = field(default_factory=VehicleSettings)
    imu: ImuErrorSettings = field(default_factory=ImuErrorSettings)
    imu_count: int = 2
    mag: MagSettings = field(default_factory=MagSettings)
    mag_count: int = 2
    earth_field: EarthField = field(default_factory=EarthField)
    home: Home = field(default_factory=Home)
    estimate: EstimateSettings = field(default_factory=EstimateSettings)
    attitude_fault: AttitudeFault | None = None
    imu_fault: ImuFault | None = None
    gps_velocity_noise_m_s: float = 0.02
    jit: bool = False

    def __post_init__(self) -> None:
        if not 1.0 <= self.loop_rate_hz <= 10000.0:
            raise ValueError(f"SimSettings.loop_rate_hz must be in [1, 10000], got {self.loop_rate_hz!r}")
        if not 1 <= self.oversample <= 32:
            raise ValueError(f"SimSettings.oversample must be in [1, 32], got {self.oversample!r}")
        if not 1 <= self.imu_count <= 3 or not 0 <= self.mag_count <= 3:
            raise ValueError("SimSettings: imu_count must be 1–3 and mag_count 0–3")
        if self.boot_offset_s < 0.0 or self.gps_velocity_noise_m_s < 0.0:
            raise ValueError("SimSettings: boot_offset_s and gps_velocity_noise_m_s must be >= 0")
        make_scenario(self.scenario, 0)  # validates the name

    @property
    def sensor_rate_hz(self) -> float:
        return self.loop_rate_hz * self.oversample

    def with_(self, **changes: object) -> SimSettings:
        return replace(self, **changes)  # type: ignore[arg-type]


@dataclass
class LoopBlock:
    """Consecutive loop ticks ``k0 … k0+n−1``.

    ``t_us``: sample time since boot (µs, int64).  ``truth``: the rigid-body
    truth at the ticks.  ``gyro_rad_s``/``accel_m_s2``: (imu_count, n, 3) as
    reported; ``gyro_bias_rad_s``/``accel_bias_m_s2``: their additive errors.
    ``mag_ut``: (mag_count, n, 3); ``mag_fresh``: new compass sample this tick.
    ``est_q_body_to_ned``: the autopilot's estimate; ``vel_ned_m_s``: reported
    velocity; ``lat_deg``/``lon_deg``/``alt_m``: reported position.
    """

    k0: int
    t_us: NDArray[np.int64]
    truth: TruthChunk
    gyro_rad_s: Array
    accel_m_s2: Array
    gyro_bias_rad_s: Array
    accel_bias_m_s2: Array
    mag_ut: Array
    mag_fresh: NDArray[np.bool_]
    temperature_c: Array
    est_q_body_to_ned: Array
    vel_ned_m_s: Array
    lat_deg: Array
    lon_deg: Array
    alt_m: Array

    @property
    def n(self) -> int:
        return int(self.t_us.shape[0])


class Simulation:
    """Produces :class:`LoopBlock` s in order; deterministic for given settings."""

    def __init__(self, settings: SimSettings | None = None) -> None:
        self.settings = s = settings or SimSettings()
        self.scenario = make_scenario(s.scenario, s.seed)
        self.vehicle = Vehicle(self.scenario, s.vehicle, rate_hz=s.sensor_rate_hz, jit=s.jit)
        root = np.random.SeedSequence([int(s.seed), 0xF1C])
        seeds = root.spawn(10)
        self.imus = [
            ImuModel(s.imu, rate_hz=s.sensor_rate_hz, seed=seeds[i], vibration=self.scenario.vibration, jit=s.jit)
            for i in range(s.imu_count)
        ]
        field_ned = s.earth_field.ned_ut()
        self.mags = [
            MagModel(
                s.mag, field_ned, rate_hz=s.sensor_rate_hz, seed=seeds[3 + i],
                motor_ut_per_g=self.scenario.mag_motor_ut_per_g,
            )
            for i in range(s.mag_count)
        ]
        self._rng_est = np.random.default_rng(seeds[6])
        self._rng_est_white = np.random.default_rng(seeds[8])
        self._rng_gps = np.random.default_rng(seeds[7])
        self._est_zi: Array | None = None
        self._frozen: tuple[Array, Array] | None = None
        self._last_good: tuple[Array, Array] | None = None
        self._k = 0

    @property
    def next_tick(self) -> int:
        return self._k

    @property
    def tick_period_us(self) -> float:
        return 1e6 / self.settings.loop_rate_hz

    def tick_time_us(self, k: int) -> int:
        """Sample time since boot (µs) of tick ``k``."""
        s = self.settings
        return int(round((k / s.loop_rate_hz + s.boot_offset_s) * 1e6))

    def next_block(self, n: int) -> LoopBlock:
        """The next ``n`` loop ticks."""
        s = self.settings
        m = s.oversample
        k0 = self._k
        self._k += n
        fine = self.vehicle.advance(n * m)
        idx = np.arange(k0 * m, (k0 + n) * m, dtype=np.int64)
        temp_fine = self.scenario.temperature_c(fine.t_s)
        snap = slice(0, n * m, m)
        truth = TruthChunk(t_s=fine.t_s[snap], rows=fine.rows[snap])
        gyro = np.empty((s.imu_count, n, 3))
        accel = np.empty((s.imu_count, n, 3))
        gbias = np.empty((s.imu_count, n, 3))
        abias = np.empty((s.imu_count, n, 3))
        for j, imu in enumerate(self.imus):
            c = imu.process(fine.gyro_rad_s, fine.accel_m_s2, fine.thrust_m_s2, temp_fine)
            gyro[j], accel[j] = c.gyro_rad_s[snap], c.accel_m_s2[snap]
            gbias[j], abias[j] = c.gyro_bias_rad_s[snap], c.accel_bias_m_s2[snap]
        mag = np.empty((s.mag_count, n, 3))
        fresh = np.empty((s.mag_count, n), dtype=bool)
        if self.mags:
            dist = self.scenario.mag_disturbance_ned(fine.t_s)
            for j, mm in enumerate(self.mags):
                v, f = mm.process(idx, fine.q_body_to_ned, dist, fine.thrust_m_s2)
                mag[j] = v[snap]
                # a compass sample is "fresh" at a tick if one arrived since the previous tick
                fresh[j] = np.add.reduceat(f.astype(np.int64), np.arange(0, n * m, m)) > 0
        self._apply_imu_fault(truth.t_s, gyro, accel)
        t_us = np.round((truth.t_s + s.boot_offset_s) * 1e6).astype(np.int64)
        est_q = self._estimate(truth)
        vel = truth.vel_ned_m_s + self._rng_gps.normal(0.0, 1.0, (n, 3)) * s.gps_velocity_noise_m_s
        pos = truth.pos_ned_m
        lat = s.home.lat_deg + np.degrees(pos[:, 0] / EARTH_RADIUS_M)
        lon = s.home.lon_deg + np.degrees(pos[:, 1] / (EARTH_RADIUS_M * math.cos(math.radians(s.home.lat_deg))))
        alt = s.home.alt_m - pos[:, 2]
        return LoopBlock(
            k0=k0, t_us=t_us, truth=truth, gyro_rad_s=gyro, accel_m_s2=accel,
            gyro_bias_rad_s=gbias, accel_bias_m_s2=abias, mag_ut=mag, mag_fresh=fresh,
            temperature_c=temp_fine[snap], est_q_body_to_ned=est_q, vel_ned_m_s=vel,
            lat_deg=lat, lon_deg=lon, alt_m=alt,
        )

    def _apply_imu_fault(self, t_s: Array, gyro: Array, accel: Array) -> None:
        f = self.settings.imu_fault
        if f is None or f.instance >= self.settings.imu_count:
            return
        j = f.instance
        if f.freeze_at_s is not None:
            frozen = t_s >= f.freeze_at_s
            if frozen.any():
                first = int(np.argmax(frozen))
                if self._frozen is None:
                    if first > 0 or self._last_good is None:
                        self._frozen = (gyro[j, max(first - 1, 0)].copy(), accel[j, max(first - 1, 0)].copy())
                    else:
                        self._frozen = self._last_good
                gyro[j, frozen] = self._frozen[0]
                accel[j, frozen] = self._frozen[1]
            elif gyro.shape[1]:
                self._last_good = (gyro[j, -1].copy(), accel[j, -1].copy())
        if f.saturate_at_s is not None:
            sat = t_s >= f.saturate_at_s
            gyro[j, sat] = self.settings.imu.gyro_range_rad_s
            accel[j, sat] = self.settings.imu.accel_range_m_s2

    def _estimate(self, truth: TruthChunk) -> Array:
        s = self.settings
        e = s.estimate
        n = truth.t_s.shape[0]
        a = math.exp(-1.0 / (e.tau_s * s.loop_rate_hz))
        sigma = np.radians([e.tilt_sigma_deg, e.tilt_sigma_deg, e.yaw_sigma_deg])
        if self._est_zi is None:
            # start in the stationary distribution (first-order: z1 = a·e₀, z2 = 0)
            e0 = self._rng_est.normal(0.0, 1.0, 3) * sigma
            self._est_zi = np.stack([a * e0, np.zeros(3)])
        w = self._rng_est.normal(0.0, 1.0, (n, 3)) * (sigma * math.sqrt(1.0 - a * a))[None, :]
        err = np.empty_like(w)
        iir2.select(s.jit)(np.array([1.0, 0.0, 0.0, -a, 0.0]), w, self._est_zi, err)  # e_k = a e_{k-1} + w_k
        err = err + self._rng_est_white.normal(0.0, 1.0, (n, 3)) * math.radians(e.noise_deg)
        q = quat.multiply(truth.q_body_to_ned, quat.from_rotation_vector(err))
        if s.attitude_fault is not None:
            f = s.attitude_fault
            wgt = f.weight(truth.t_s)
            if wgt.any():
                off = from_euler_rad(math.radians(f.roll_deg), math.radians(f.pitch_deg), math.radians(f.yaw_deg))
                rv = quat.to_rotation_vector(off)
                q = quat.multiply(q, quat.from_rotation_vector(wgt[:, None] * rv[None, :]))
        return quat.normalize(q)


def gravity_body(q_body_to_ned: Array) -> Array:
    """The specific force of a vehicle at rest, in body axes: ``Cᵀ [0, 0, −g]``."""
    return quat.rotate(quat.conjugate(q_body_to_ned), np.array([0.0, 0.0, -G]))
