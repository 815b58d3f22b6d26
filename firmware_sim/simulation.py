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
from mavahrs.geometry.rotation import from_euler_rad, to_matrix

__all__ = [
    "Home",
    "EstimateSettings",
    "AttitudeFault",
    "ImuFault",
    "MagAnomaly",
    "CurrentSettings",
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
    """A failing IMU instance (0 = RAW_IMU/SCALED_IMU, 1 = SCALED_IMU2, 2 = SCALED_IMU3).

    Attributes:
        instance: which IMU.
        freeze_at_s: from then on its reading is stuck at the last value (None = never).
        saturate_at_s: from then on it reads +full scale on every axis (None = never).
        step_at_s: from then on ``gyro_bias_step_rad_s`` and ``accel_bias_step_m_s2`` are added
            to its readings (its sensor axes; a bias step, e.g. a damaged or shifted sensor; the
            LoopBlock's ``gyro_bias_rad_s`` / ``accel_bias_m_s2`` include it).
        gyro_bias_step_rad_s: the gyro bias step per axis (rad/s).
        accel_bias_step_m_s2: the accelerometer bias step per axis (m/s²).
    """

    instance: int = 1
    freeze_at_s: float | None = None
    saturate_at_s: float | None = None
    step_at_s: float | None = None
    gyro_bias_step_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias_step_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not 0 <= self.instance <= 2:
            raise ValueError(f"ImuFault.instance must be 0, 1 or 2, got {self.instance!r}")
        for name in ("freeze_at_s", "saturate_at_s", "step_at_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"ImuFault.{name} must be >= 0 s or None, got {v!r}")
        if len(self.gyro_bias_step_rad_s) != 3 or len(self.accel_bias_step_m_s2) != 3:
            raise ValueError("ImuFault: bias steps need 3 values (x, y, z)")


@dataclass(frozen=True)
class MagAnomaly:
    """A ground-level magnetic anomaly around the take-off point, as ArduPilot SITL's
    ``SIM_MAG_ALY`` / ``SIM_MAG_ALY_HGT``: the earth-frame field ``field_ned_ut`` is added on the
    ground and decays with the height h above home as ``(H / (h + H))³`` (1/8 at H = ``height_m``;
    a dipole's 1/r³ with the source H below the ground).

    Attributes:
        field_ned_ut: the anomaly at ground level, NED (µT; SITL's parameter is in mGauss = 0.1 µT).
        height_m: height above ground where it has decayed to 1/8 (m, > 0).
    """

    field_ned_ut: tuple[float, float, float] = (0.0, 0.0, 0.0)
    height_m: float = 1.0

    def __post_init__(self) -> None:
        if len(self.field_ned_ut) != 3 or not self.height_m > 0.0:
            raise ValueError("MagAnomaly: need 3 field components and height_m > 0")


@dataclass(frozen=True)
class CurrentSettings:
    """The simulated battery current (reported in SYS_STATUS / BATTERY_STATUS; drives the
    ``SIM_MAG_MOT``-like compass interference).  Rotor power grows with thrust^1.5 (momentum
    theory), so ``I = idle_a + hover_a · (thrust / g)^1.5`` while the motors run, ``idle_a`` when
    disarmed.  Battery: a 4S pack, ``V = full_v − internal_ohm · I``.

    Attributes:
        hover_a: motor current in hover (A).
        idle_a: avionics current (A).
        full_v: open-circuit voltage (V).
        internal_ohm: internal resistance (Ω).
        capacity_mah: capacity, for the remaining percentage (mAh).
    """

    hover_a: float = 15.0
    idle_a: float = 0.4
    full_v: float = 16.4
    internal_ohm: float = 0.02
    capacity_mah: float = 5000.0

    def __post_init__(self) -> None:
        if min(self.hover_a, self.idle_a, self.internal_ohm) < 0.0 or not (self.full_v > 0 and self.capacity_mah > 0):
            raise ValueError("CurrentSettings: currents and resistance must be >= 0, voltage and capacity > 0")

    def current_a(self, thrust_m_s2: Array) -> Array:
        t = np.maximum(np.asarray(thrust_m_s2, dtype=np.float64), 0.0)
        return self.idle_a + self.hover_a * (t / G) ** 1.5


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
        imu_mount_deg: the sensor board's mounting (AHRS_ORIENTATION-like): roll, pitch, yaw (deg,
            aerospace Z-Y-X) that rotate the body axes onto the IMU's axes; IMUs and compasses
            measure in the IMU axes, ``v_imu = R(roll, pitch, yaw)ᵀ · v_body``.  (0, 90, 0) = the
            IMU's x axis up (a research rig's "x up"); SIMSTATE / SIM_STATE stay the body truth.
        start_in_motion: no rest period: flying from t = 0, rotors spinning, manoeuvres at once
            (see :func:`firmware_sim.trajectory.make_scenario`).
        gnss: False = no GNSS: GPS_RAW_INT and GLOBAL_POSITION_INT are never sent (requests are
            ACKed, nothing goes out), as a vehicle without a receiver.
        mag_anomaly: a ground anomaly (:class:`MagAnomaly`); None = the scenario's own
            (``mag_anomaly`` has one, the others none).
        mag_motor_ut_per_a: body-frame compass interference per amp of battery current (µT/A,
            ``SIM_MAG_MOT``); None = the scenario's own.
        current: the battery current model (:class:`CurrentSettings`).
        gps_velocity_noise_m_s: white noise on the reported NED velocity (m/s, σ).
        jit: run the sequential kernels compiled by numba (long batch runs; pays numba's
            start-up of about 2 s once per process); results are the same to rounding.
        imu_sample: what a tick reports of its IMUs: ``"snapshot"`` (default), the latest filtered sensor
            sample, as ArduPilot's INS front end once per loop; ``"interval_mean"``, the mean of the sensor
            samples since the previous tick (the last one at the tick's stamp), as PX4's ``vehicle_imu``:
            ``delta_angle / delta_angle_dt`` over the integration interval, which HIGHRES_IMU and SCALED_IMU
            send (``streams/HIGHRES_IMU.hpp``; PX4's IMU_GYRO_CUTOFF filters the controllers' rate, not
            ``vehicle_imu``, so the PX4 command line turns the 20 Hz low-pass off with it).
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
    imu_mount_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_in_motion: bool = False
    gnss: bool = True
    mag_anomaly: MagAnomaly | None = None
    mag_motor_ut_per_a: tuple[float, float, float] | None = None
    current: CurrentSettings = field(default_factory=CurrentSettings)
    gps_velocity_noise_m_s: float = 0.02
    jit: bool = False
    imu_sample: str = "snapshot"

    def for_autopilot(self, autopilot: str) -> SimSettings:
        """These settings with ``autopilot``'s IMU front end (one place for the command line and the fleet):
        ``"px4"``: vehicle_imu's interval mean (``imu_sample="interval_mean"``) without the INS low-pass
        (``gyro_lowpass_hz`` / ``accel_lowpass_hz`` 0), which HIGHRES_IMU and SCALED_IMU send; any other: as given."""
        if autopilot != "px4":
            return self
        imu = replace(self.imu, gyro_lowpass_hz=0.0, accel_lowpass_hz=0.0)
        return replace(self, imu_sample="interval_mean", imu=imu)

    def __post_init__(self) -> None:
        if self.imu_sample not in ("snapshot", "interval_mean"):
            raise ValueError(f"SimSettings.imu_sample must be 'snapshot' or 'interval_mean', got {self.imu_sample!r}")
        if not 1.0 <= self.loop_rate_hz <= 10000.0:
            raise ValueError(f"SimSettings.loop_rate_hz must be in [1, 10000], got {self.loop_rate_hz!r}")
        if not 1 <= self.oversample <= 32:
            raise ValueError(f"SimSettings.oversample must be in [1, 32], got {self.oversample!r}")
        if not 1 <= self.imu_count <= 3 or not 0 <= self.mag_count <= 3:
            raise ValueError("SimSettings: imu_count must be 1–3 and mag_count 0–3")
        if self.boot_offset_s < 0.0 or self.gps_velocity_noise_m_s < 0.0:
            raise ValueError("SimSettings: boot_offset_s and gps_velocity_noise_m_s must be >= 0")
        if len(self.imu_mount_deg) != 3 or not all(math.isfinite(v) for v in self.imu_mount_deg):
            raise ValueError(f"SimSettings.imu_mount_deg needs 3 finite angles, got {self.imu_mount_deg!r}")
        if self.mag_motor_ut_per_a is not None and len(self.mag_motor_ut_per_a) != 3:
            raise ValueError("SimSettings.mag_motor_ut_per_a needs 3 values")
        make_scenario(self.scenario, 0, start_in_motion=self.start_in_motion)  # validates the name

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
    velocity; ``lat_deg``/``lon_deg``/``alt_m``: reported position.  IMU and compass values
    (and their errors) are in the IMU's axes (``SimSettings.imu_mount_deg``), the truth in body
    axes.  ``current_a``: battery current (A); ``voltage_v``: battery voltage (V);
    ``consumed_mah``: charge drawn since boot (mAh).
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
    current_a: Array
    voltage_v: Array
    consumed_mah: Array
    c_imu_to_body: Array = field(default_factory=lambda: np.eye(3))

    @property
    def n(self) -> int:
        return int(self.t_us.shape[0])


class Simulation:
    """Produces :class:`LoopBlock` s in order; deterministic for given settings."""

    def __init__(self, settings: SimSettings | None = None) -> None:
        self.settings = s = settings or SimSettings()
        self.scenario = make_scenario(s.scenario, s.seed, start_in_motion=s.start_in_motion)
        # the sensor board's mounting: q_imu_to_body, and C_imu_to_body for vectors
        self.q_imu_to_body = from_euler_rad(*np.radians(s.imu_mount_deg))
        self.c_imu_to_body = to_matrix(self.q_imu_to_body)
        self._mounted = bool(any(v != 0.0 for v in s.imu_mount_deg))
        sc = self.scenario
        anomaly = s.mag_anomaly or MagAnomaly(sc.mag_anomaly_ned_ut, sc.mag_anomaly_height_m)
        self.mag_anomaly = anomaly
        self.mag_motor_ut_per_a = np.asarray(
            s.mag_motor_ut_per_a if s.mag_motor_ut_per_a is not None else sc.mag_motor_ut_per_a, dtype=np.float64
        )
        self._consumed_mah = 0.0
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
                # body-frame interference, seen in the IMU axes
                motor_ut_per_g=tuple(self.c_imu_to_body.T @ np.asarray(self.scenario.mag_motor_ut_per_g)),
                motor_ut_per_a=tuple(self.c_imu_to_body.T @ self.mag_motor_ut_per_a),
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
        #: interval_mean: each IMU's last oversample - 1 sensor samples (gyro, accel) of the previous block
        self._imu_tail: list[tuple[Array, Array] | None] = [None] * s.imu_count

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
        gyro_true, accel_true, q_sensor = fine.gyro_rad_s, fine.accel_m_s2, fine.q_body_to_ned
        if self._mounted:  # the IMU measures in its own axes: v_imu = C_imu_to_bodyᵀ v_body
            gyro_true = gyro_true @ self.c_imu_to_body
            accel_true = accel_true @ self.c_imu_to_body
            q_sensor = quat.multiply(q_sensor, self.q_imu_to_body[None, :])
        current_fine = s.current.current_a(fine.thrust_m_s2)
        for j, imu in enumerate(self.imus):
            c = imu.process(gyro_true, accel_true, fine.thrust_m_s2, temp_fine)
            if s.imu_sample == "interval_mean":
                gyro[j], accel[j] = self._interval_mean(j, c.gyro_rad_s, c.accel_m_s2, n, m)
            else:
                gyro[j], accel[j] = c.gyro_rad_s[snap], c.accel_m_s2[snap]
            gbias[j], abias[j] = c.gyro_bias_rad_s[snap], c.accel_bias_m_s2[snap]
        mag = np.empty((s.mag_count, n, 3))
        fresh = np.empty((s.mag_count, n), dtype=bool)
        if self.mags:
            dist = self.scenario.mag_disturbance_ned(fine.t_s)
            if any(self.mag_anomaly.field_ned_ut):
                dist = dist + self.mag_anomaly_ned_ut(-fine.pos_ned_m[:, 2])
            for j, mm in enumerate(self.mags):
                v, f = mm.process(idx, q_sensor, dist, fine.thrust_m_s2, current_fine)
                mag[j] = v[snap]
                # a compass sample is "fresh" at a tick if one arrived since the previous tick
                fresh[j] = np.add.reduceat(f.astype(np.int64), np.arange(0, n * m, m)) > 0
        self._apply_imu_fault(truth.t_s, gyro, accel, gbias, abias)
        current = current_fine[snap]
        # charge drawn: the current integrated at the sensor rate, reported at the ticks
        mah = self._consumed_mah + np.cumsum(current_fine) * (1000.0 / 3600.0 / s.sensor_rate_hz)
        if mah.size:
            self._consumed_mah = float(mah[-1])
        voltage = s.current.full_v - s.current.internal_ohm * current
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
            lat_deg=lat, lon_deg=lon, alt_m=alt, current_a=current, voltage_v=voltage, consumed_mah=mah[snap],
            c_imu_to_body=self.c_imu_to_body,
        )

    def _interval_mean(self, j: int, gyro_fine: Array, accel_fine: Array, n: int, m: int) -> tuple[Array, Array]:
        """IMU ``j``'s gyro and accel per tick as the mean of the ``m`` sensor samples ending at the tick's own
        sample (PX4's ``vehicle_imu``: Δθ / Δt over the interval); the first tick of the flight repeats its
        sample for the samples before the start."""
        tail = self._imu_tail[j]
        if tail is None:
            tail = (np.repeat(gyro_fine[:1], m - 1, axis=0), np.repeat(accel_fine[:1], m - 1, axis=0))
        out = []
        for prev, fine in zip(tail, (gyro_fine, accel_fine), strict=True):
            ext = np.concatenate((prev, fine))[: n * m]  # tick i: sensor samples i·m − m + 1 … i·m
            out.append(ext.reshape(n, m, 3).mean(axis=1))
        self._imu_tail[j] = (gyro_fine[n * m - (m - 1):], accel_fine[n * m - (m - 1):])
        return out[0], out[1]

    def mag_anomaly_ned_ut(self, height_agl_m: Array) -> Array:
        """The anomaly's earth-frame field (µT, NED) at heights above home (m), shape (N, 3)."""
        a = self.mag_anomaly
        h = np.maximum(np.asarray(height_agl_m, dtype=np.float64), 0.0)
        scale = (a.height_m / (h + a.height_m)) ** 3
        return scale[:, None] * np.asarray(a.field_ned_ut)[None, :]

    def _apply_imu_fault(self, t_s: Array, gyro: Array, accel: Array, gbias: Array, abias: Array) -> None:
        f = self.settings.imu_fault
        if f is None or f.instance >= self.settings.imu_count:
            return
        j = f.instance
        if f.step_at_s is not None:
            on = t_s >= f.step_at_s
            if on.any():
                g_step = np.asarray(f.gyro_bias_step_rad_s, dtype=np.float64)
                a_step = np.asarray(f.accel_bias_step_m_s2, dtype=np.float64)
                gyro[j, on] += g_step
                gbias[j, on] += g_step
                accel[j, on] += a_step
                abias[j, on] += a_step
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
