r"""Sensor models: gyroscope, accelerometer and magnetometer as an autopilot reports them.

Pure and seeded: every random source has its own generator spawned from the
seed, so the output does not depend on how the run is chunked.

Inertial measurement chain, per sensor sample (rate ``rate_hz``):

1. analog: ``M · truth + bias(t) + tempco · (T − T₀) + vibration + white noise``,
   where ``M = I + diag(scale) + cross-axis`` (drawn once), ``bias(t)`` = a
   constant turn-on residual plus a random walk, and ``T₀`` the temperature at
   boot (the autopilot's gyro calibration at boot removes the bias there);
2. saturation at the range (e.g. ±2000 °/s, ±16 g);
3. quantisation to the ADC step (``*_lsb_*``; 0 = none);
4. the autopilot's low-pass (2nd-order Butterworth at ``*_lowpass_hz``, as
   ArduPilot's ``INS_GYRO_FILTER`` / ``INS_ACCEL_FILTER``; 0 = none).

The stream then *snapshots* this filtered signal once per scheduler loop
(:mod:`firmware_sim.simulation`); wire units quantise again in the encoder.

Magnetometer: ``S_soft · (Cᵀ (B_earth + d_earth) ) + d_motor · (thrust/g − 1) +
d_amp · I + hard_iron + noise`` (``d_earth`` includes a ground anomaly, ``I`` the battery current), quantised, updated at ``rate_hz`` and held in between (as
an autopilot reports the latest compass sample).  White-noise densities are
one-sided: per-sample σ = density · √(fs / 2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from firmware_sim.jit import lazy_kernel
from firmware_sim.trajectory import VibrationSpec

__all__ = [
    "G",
    "ImuErrorSettings",
    "MagSettings",
    "EarthField",
    "ImuModel",
    "ImuChunk",
    "MagModel",
    "butterworth2",
    "iir2",
]

Array = NDArray[np.float64]
G = 9.80665


@dataclass(frozen=True)
class ImuErrorSettings:
    """Error model of one IMU (gyro + accelerometer).  Defaults: a calibrated
    ArduPilot IMU (ICM-42688/MPU6000 class), values per axis.

    ``*_sigma`` values are the spread from which the seed draws the actual
    error; the ``*_rad_s`` / ``*_m_s2`` tuples, when given, fix it instead.
    """

    gyro_noise_density_rad_s_rthz: float = math.radians(0.01)  # (rad/s)/√Hz
    accel_noise_density_m_s2_rthz: float = 200e-6 * G  # (m/s²)/√Hz (200 µg/√Hz)
    gyro_bias_sigma_rad_s: float = math.radians(0.1)  # residual after boot calibration
    gyro_bias_rad_s: tuple[float, float, float] | None = None
    gyro_bias_uniform_rad_s: float = 0.0  # > 0: turn-on bias uniform in ±this per axis instead (raw IMU)
    accel_bias_sigma_m_s2: float = 0.05
    accel_bias_m_s2: tuple[float, float, float] | None = None
    gyro_bias_walk_rad_s_rts: float = math.radians(0.002)  # (rad/s)/√s
    accel_bias_walk_m_s2_rts: float = 2e-4  # (m/s²)/√s
    gyro_temp_coeff_sigma_rad_s_per_c: float = math.radians(0.01)
    gyro_temp_coeff_rad_s_per_c: tuple[float, float, float] | None = None
    accel_temp_coeff_sigma_m_s2_per_c: float = 0.002
    gyro_scale_sigma: float = 0.002  # fraction
    gyro_cross_axis_sigma: float = 0.001  # fraction (misalignment, rad)
    accel_scale_sigma: float = 0.002
    accel_cross_axis_sigma: float = 0.001
    gyro_range_rad_s: float = math.radians(2000.0)
    accel_range_m_s2: float = 16.0 * G
    gyro_lsb_rad_s: float = math.radians(2000.0) / 32768.0
    accel_lsb_m_s2: float = 16.0 * G / 32768.0
    gyro_lowpass_hz: float = 20.0
    accel_lowpass_hz: float = 20.0
    vibration: bool = True  # add the scenario's motor vibration

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if isinstance(value, float) and (not math.isfinite(value) or value < 0.0):
                raise ValueError(f"ImuErrorSettings.{name} must be finite and >= 0, got {value!r}")
        if self.gyro_range_rad_s <= 0.0 or self.accel_range_m_s2 <= 0.0:
            raise ValueError("ImuErrorSettings: ranges must be > 0")

    def noiseless(self) -> ImuErrorSettings:
        """These errors without the random ones: no white noise, no bias random walk, no vibration (as
        ArduPilot's SITL with ``SIM_ACC*_RND`` and ``SIM_GYR*_RND`` at 0).  Turn-on bias, scale, cross-axis,
        quantisation and the low-pass stay, so a steady state repeats the same whole mG and mrad/s on the wire."""
        return replace(
            self,
            gyro_noise_density_rad_s_rthz=0.0,
            accel_noise_density_m_s2_rthz=0.0,
            gyro_bias_walk_rad_s_rts=0.0,
            accel_bias_walk_m_s2_rts=0.0,
            vibration=False,
        )

    @classmethod
    def raw(cls, *, max_gyro_bias_dps: float = 5.0) -> ImuErrorSettings:
        """An uncalibrated MEMS IMU as a research rig streams it: no boot gyro calibration, so the
        turn-on gyro bias is drawn from the seed uniformly in ±``max_gyro_bias_dps`` per axis (1–5 °/s
        is typical), larger accelerometer offsets (σ 0.1 m/s²) and scale/cross-axis errors (σ 0.5 %,
        0.3 %), as no factory or user calibration has removed them.  Noise, random walk,
        temperature coefficient, range, quantisation and the low-pass are the defaults."""
        return cls(
            gyro_bias_uniform_rad_s=math.radians(max_gyro_bias_dps),
            accel_bias_sigma_m_s2=0.1,
            gyro_scale_sigma=0.005,
            gyro_cross_axis_sigma=0.003,
            accel_scale_sigma=0.005,
            accel_cross_axis_sigma=0.003,
        )

    @classmethod
    def ideal(cls, *, lowpass: bool = False) -> ImuErrorSettings:
        """A perfect IMU (no noise, bias, scale, quantisation, vibration); optionally still low-passed."""
        return cls(
            gyro_noise_density_rad_s_rthz=0.0,
            accel_noise_density_m_s2_rthz=0.0,
            gyro_bias_sigma_rad_s=0.0,
            accel_bias_sigma_m_s2=0.0,
            gyro_bias_walk_rad_s_rts=0.0,
            accel_bias_walk_m_s2_rts=0.0,
            gyro_temp_coeff_sigma_rad_s_per_c=0.0,
            accel_temp_coeff_sigma_m_s2_per_c=0.0,
            gyro_scale_sigma=0.0,
            gyro_cross_axis_sigma=0.0,
            accel_scale_sigma=0.0,
            accel_cross_axis_sigma=0.0,
            gyro_range_rad_s=1e6,
            accel_range_m_s2=1e6,
            gyro_lsb_rad_s=0.0,
            accel_lsb_m_s2=0.0,
            gyro_lowpass_hz=20.0 if lowpass else 0.0,
            accel_lowpass_hz=20.0 if lowpass else 0.0,
            vibration=False,
        )


@dataclass(frozen=True)
class EarthField:
    """The local geomagnetic field.  Defaults: WMM2025 at ArduPilot SITL's default
    home (CMAC, −35.363261°, 149.165230°, 584 m) on 2025-06-01.

    Attributes:
        strength_ut: total intensity (µT).
        inclination_deg: dip, positive pointing down (northern hemisphere).
        declination_deg: magnetic north east of true north.
    """

    strength_ut: float = 58.10
    inclination_deg: float = -66.04
    declination_deg: float = 12.66

    def __post_init__(self) -> None:
        if not self.strength_ut >= 0.0:
            raise ValueError(f"EarthField.strength_ut must be >= 0, got {self.strength_ut!r}")
        if not -90.0 <= self.inclination_deg <= 90.0:
            raise ValueError(f"EarthField.inclination_deg must be in [-90, 90], got {self.inclination_deg!r}")
        if not -180.0 <= self.declination_deg <= 180.0:
            raise ValueError(f"EarthField.declination_deg must be in [-180, 180], got {self.declination_deg!r}")

    def ned_ut(self) -> Array:
        """Field vector in NED (µT)."""
        i = math.radians(self.inclination_deg)
        d = math.radians(self.declination_deg)
        b = self.strength_ut
        return np.array([b * math.cos(i) * math.cos(d), b * math.cos(i) * math.sin(d), b * math.sin(i)])


@dataclass(frozen=True)
class MagSettings:
    """Magnetometer as the autopilot reports it (ArduPilot: already calibrated, so
    hard/soft iron default to none; set them to simulate an uncalibrated compass).

    Attributes:
        noise_ut: white noise σ per sample (µT).
        rate_hz: update rate; the latest sample is held in between (Hz).
        lsb_ut: quantisation step (µT); 0 = none.
        hard_iron_ut: constant offset in body axes (µT).
        soft_iron: 3×3 matrix, row-major, applied to the body-frame field.
        range_ut: saturation (µT).
    """

    noise_ut: float = 0.3
    rate_hz: float = 100.0
    lsb_ut: float = 0.15
    hard_iron_ut: tuple[float, float, float] = (0.0, 0.0, 0.0)
    soft_iron: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    range_ut: float = 800.0

    def __post_init__(self) -> None:
        if len(self.soft_iron) != 9:
            raise ValueError("MagSettings.soft_iron needs 9 values (3×3, row-major)")
        if not self.rate_hz > 0.0:
            raise ValueError(f"MagSettings.rate_hz must be > 0, got {self.rate_hz!r}")
        if self.noise_ut < 0.0 or self.lsb_ut < 0.0 or self.range_ut <= 0.0:
            raise ValueError("MagSettings: noise_ut, lsb_ut must be >= 0 and range_ut > 0")

    @classmethod
    def ideal(cls) -> MagSettings:
        return cls(noise_ut=0.0, lsb_ut=0.0)

    def noiseless(self) -> MagSettings:
        """This compass without its white noise (quantisation and update rate kept)."""
        return replace(self, noise_ut=0.0)


@dataclass
class ImuChunk:
    """Filtered gyro/accel at the sensor rate plus the error truth (for tests and tools).

    ``gyro_bias_rad_s`` / ``accel_bias_m_s2``: the additive error (constant +
    random walk + temperature) at each sample, before scale and filtering;
    ``gyro_matrix`` / ``accel_matrix``: the scale/cross-axis matrix M.
    """

    gyro_rad_s: Array
    accel_m_s2: Array
    gyro_bias_rad_s: Array
    accel_bias_m_s2: Array


def _quantise(x: Array, lsb: float) -> Array:
    return np.round(x / lsb) * lsb if lsb > 0.0 else x


def butterworth2(cutoff_hz: float, rate_hz: float) -> Array:
    """2nd-order Butterworth low-pass ``[b0, b1, b2, a1, a2]`` (bilinear, pre-warped),
    the coefficients of ArduPilot's ``DigitalBiquadFilter::compute_params``."""
    ohm = math.tan(math.pi * cutoff_hz / rate_hz)
    c = 1.0 + 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm
    b0 = ohm * ohm / c
    return np.array([b0, 2.0 * b0, b0, 2.0 * (ohm * ohm - 1.0) / c, (1.0 - 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm) / c])


@lazy_kernel
def iir2(coef: Array, x: Array, z: Array, out: Array) -> None:
    """Biquad (direct form II transposed) along axis 0 of ``x`` (N, M); state ``z`` (2, M) carried."""
    b0, b1, b2, a1, a2 = coef[0], coef[1], coef[2], coef[3], coef[4]
    for j in range(x.shape[1]):
        z1, z2 = z[0, j], z[1, j]
        for i in range(x.shape[0]):
            xi = x[i, j]
            y = b0 * xi + z1
            z1 = b1 * xi - a1 * y + z2
            z2 = b2 * xi - a2 * y
            out[i, j] = y
        z[0, j], z[1, j] = z1, z2


class _LowPass:
    """2nd-order Butterworth per axis with carried state (ArduPilot LowPassFilter2p)."""

    def __init__(self, cutoff_hz: float, rate_hz: float, jit: bool = False) -> None:
        self.active = 0.0 < cutoff_hz < 0.5 * rate_hz
        self._z: Array | None = None
        self.coef = butterworth2(cutoff_hz, rate_hz) if self.active else np.zeros(5)
        self._iir = iir2.select(jit)

    def __call__(self, x: Array) -> Array:
        if not self.active or x.shape[0] == 0:
            return x
        x = np.ascontiguousarray(x)
        if self._z is None:  # start settled on the first sample: no start-up transient
            b0, b1, b2, a1, a2 = self.coef
            self._z = np.stack([x[0] * (b1 - a1 + b2 - a2), x[0] * (b2 - a2)])
        out = np.empty_like(x)
        self._iir(self.coef, x, self._z, out)
        return out


def _matrix(rng: np.random.Generator, scale_sigma: float, cross_sigma: float) -> Array:
    m = np.eye(3) + np.diag(rng.normal(0.0, 1.0, 3) * scale_sigma)
    off = rng.normal(0.0, 1.0, (3, 3)) * cross_sigma
    np.fill_diagonal(off, 0.0)
    return m + off


def _draw(rng: np.random.Generator, fixed: tuple[float, float, float] | None, sigma: float) -> Array:
    drawn = rng.normal(0.0, 1.0, 3) * sigma  # always draw: keeps the streams aligned
    return np.asarray(fixed, dtype=np.float64) if fixed is not None else drawn


@dataclass
class _Vibration:
    spec: VibrationSpec
    phase: Array = field(default_factory=lambda: np.zeros(0))  # per harmonic, rad
    axis_phase: Array = field(default_factory=lambda: np.zeros(0))  # per harmonic × axis × (acc, gyro)


class ImuModel:
    """One IMU instance.  ``process(t_s, gyro_true, accel_true, thrust, temperature)``
    returns the filtered measurements at the sensor rate; call it chunk after chunk.
    """

    def __init__(
        self,
        settings: ImuErrorSettings,
        *,
        rate_hz: float,
        seed: int | np.random.SeedSequence,
        vibration: VibrationSpec | None = None,
        jit: bool = False,
    ) -> None:
        self.settings = s = settings
        self.rate_hz = float(rate_hz)
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
        draw, self._rng_gn, self._rng_an, self._rng_gw, self._rng_aw = (
            np.random.default_rng(c) for c in ss.spawn(5)
        )
        self.gyro_matrix = _matrix(draw, s.gyro_scale_sigma, s.gyro_cross_axis_sigma)
        self.accel_matrix = _matrix(draw, s.accel_scale_sigma, s.accel_cross_axis_sigma)
        self.gyro_bias0_rad_s = _draw(draw, s.gyro_bias_rad_s, s.gyro_bias_sigma_rad_s)
        if s.gyro_bias_uniform_rad_s > 0.0 and s.gyro_bias_rad_s is None:
            # a generator of its own (the next child of the seed): the other draws stay as they were
            uni = np.random.default_rng(ss.spawn(1)[0])
            self.gyro_bias0_rad_s = uni.uniform(-1.0, 1.0, 3) * s.gyro_bias_uniform_rad_s
        self.accel_bias0_m_s2 = _draw(draw, s.accel_bias_m_s2, s.accel_bias_sigma_m_s2)
        self.gyro_tempco = _draw(draw, s.gyro_temp_coeff_rad_s_per_c, s.gyro_temp_coeff_sigma_rad_s_per_c)
        self.accel_tempco = _draw(draw, None, s.accel_temp_coeff_sigma_m_s2_per_c)
        self._gyro_walk = np.zeros(3)
        self._accel_walk = np.zeros(3)
        self._temp0_c: float | None = None
        self._lp_gyro = _LowPass(s.gyro_lowpass_hz, self.rate_hz, jit)
        self._lp_accel = _LowPass(s.accel_lowpass_hz, self.rate_hz, jit)
        self._vib: _Vibration | None = None
        if vibration is not None and s.vibration:
            n = len(vibration.harmonics)
            self._vib = _Vibration(vibration, np.zeros(n), draw.uniform(0.0, 2 * math.pi, (n, 2, 3)))
        sq = math.sqrt(0.5 * self.rate_hz)
        self._gyro_sigma = s.gyro_noise_density_rad_s_rthz * sq
        self._accel_sigma = s.accel_noise_density_m_s2_rthz * sq

    def _walk(self, rng: np.random.Generator, state: Array, sigma_rts: float, n: int) -> Array:
        steps = rng.normal(0.0, 1.0, (n, 3)) * (sigma_rts * math.sqrt(1.0 / self.rate_hz))
        walk = state[None, :] + np.cumsum(steps, axis=0)
        if n:
            state[:] = walk[-1]
        return walk

    def _vibration(self, thrust_m_s2: Array) -> tuple[Array, Array]:
        n = thrust_m_s2.shape[0]
        acc = np.zeros((n, 3))
        gyr = np.zeros((n, 3))
        if self._vib is None or n == 0:
            return acc, gyr
        v = self._vib
        f_motor = v.spec.motor_hz_at_hover * np.sqrt(np.maximum(thrust_m_s2, 0.0) / G)
        on = (thrust_m_s2 > 0.0).astype(np.float64)[:, None]
        for h, harm in enumerate(v.spec.harmonics):
            dphi = 2 * math.pi * harm.multiple * f_motor / self.rate_hz
            phi = v.phase[h] + np.concatenate([[0.0], np.cumsum(dphi[:-1])])
            v.phase[h] = math.fmod(phi[-1] + dphi[-1], 2 * math.pi)
            acc += on * np.asarray(harm.accel_m_s2)[None, :] * np.sin(phi[:, None] + v.axis_phase[h, 0][None, :])
            gyr += on * np.asarray(harm.gyro_rad_s)[None, :] * np.sin(phi[:, None] + v.axis_phase[h, 1][None, :])
        return acc, gyr

    def process(
        self,
        gyro_true_rad_s: Array,
        accel_true_m_s2: Array,
        thrust_m_s2: Array,
        temperature_c: Array,
    ) -> ImuChunk:
        s = self.settings
        n = gyro_true_rad_s.shape[0]
        if self._temp0_c is None and n:
            self._temp0_c = float(temperature_c[0])
        d_temp = (temperature_c - (self._temp0_c or 0.0))[:, None]
        g_bias = self.gyro_bias0_rad_s[None, :] + self._walk(self._rng_gw, self._gyro_walk, s.gyro_bias_walk_rad_s_rts, n)
        g_bias = g_bias + d_temp * self.gyro_tempco[None, :]
        a_bias = self.accel_bias0_m_s2[None, :] + self._walk(self._rng_aw, self._accel_walk, s.accel_bias_walk_m_s2_rts, n)
        a_bias = a_bias + d_temp * self.accel_tempco[None, :]
        vib_a, vib_g = self._vibration(thrust_m_s2)
        gyro = gyro_true_rad_s @ self.gyro_matrix.T + g_bias + vib_g
        gyro += self._rng_gn.normal(0.0, 1.0, (n, 3)) * self._gyro_sigma
        accel = accel_true_m_s2 @ self.accel_matrix.T + a_bias + vib_a
        accel += self._rng_an.normal(0.0, 1.0, (n, 3)) * self._accel_sigma
        gyro = _quantise(np.clip(gyro, -s.gyro_range_rad_s, s.gyro_range_rad_s), s.gyro_lsb_rad_s)
        accel = _quantise(np.clip(accel, -s.accel_range_m_s2, s.accel_range_m_s2), s.accel_lsb_m_s2)
        return ImuChunk(self._lp_gyro(gyro), self._lp_accel(accel), g_bias, a_bias)


class MagModel:
    """One magnetometer.  ``process(t_index, q_body_to_ned, disturbance_ned_ut, thrust)``
    returns the held reading at each sensor sample and a "fresh sample" flag."""

    def __init__(
        self,
        settings: MagSettings,
        field_ned_ut: Array,
        *,
        rate_hz: float,
        seed: int | np.random.SeedSequence,
        motor_ut_per_g: tuple[float, float, float] = (0.0, 0.0, 0.0),
        motor_ut_per_a: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        self.settings = settings
        self.rate_hz = float(rate_hz)
        self.field_ned_ut = np.asarray(field_ned_ut, dtype=np.float64)
        self.soft_iron = np.asarray(settings.soft_iron, dtype=np.float64).reshape(3, 3)
        self.hard_iron_ut = np.asarray(settings.hard_iron_ut, dtype=np.float64)
        self.motor_ut_per_g = np.asarray(motor_ut_per_g, dtype=np.float64)
        self.motor_ut_per_a = np.asarray(motor_ut_per_a, dtype=np.float64)
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
        self._rng = np.random.default_rng(ss)
        self._held = np.full(3, np.nan)
        self._last_period = -1

    def process(
        self,
        index: Array,
        q_body_to_ned: Array,
        disturbance_ned_ut: Array,
        thrust_m_s2: Array,
        current_a: Array | None = None,
    ) -> tuple[Array, Array]:
        """``index``: sensor sample numbers (int, since boot); ``q_body_to_ned``: the sensor's axes
        (the body's unless the board is mounted rotated); ``current_a``: battery current (A) for the
        per-amp interference (``SIM_MAG_MOT``: ``+ motor_ut_per_a · I``).
        Returns (mag_ut (N,3), fresh (N,) bool)."""
        s = self.settings
        n = index.shape[0]
        period = np.floor(index * (s.rate_hz / self.rate_hz) + 1e-9).astype(np.int64)
        fresh = np.empty(n, dtype=bool)
        if n:
            fresh[0] = period[0] != self._last_period
            fresh[1:] = period[1:] != period[:-1]
        sel = np.flatnonzero(fresh)
        out = np.empty((n, 3))
        if sel.size:
            q = q_body_to_ned[sel]
            b_ned = self.field_ned_ut[None, :] + disturbance_ned_ut[sel]
            # rotate NED → body: Cᵀ v, via the conjugate quaternion
            w = q[:, :1]
            u = -q[:, 1:]
            t = 2.0 * np.cross(u, b_ned)
            b_body = b_ned + w * t + np.cross(u, t)
            motor = ((thrust_m_s2[sel] / G) - 1.0).clip(min=-1.0)[:, None] * (thrust_m_s2[sel] > 0)[:, None]
            m = b_body @ self.soft_iron.T + self.hard_iron_ut[None, :] + motor * self.motor_ut_per_g[None, :]
            if current_a is not None and self.motor_ut_per_a.any():
                m += current_a[sel][:, None] * self.motor_ut_per_a[None, :]
            m += self._rng.normal(0.0, 1.0, m.shape) * s.noise_ut
            m = _quantise(np.clip(m, -s.range_ut, s.range_ut), s.lsb_ut)
            # hold: forward-fill the fresh samples
            last = np.maximum.accumulate(np.where(fresh, np.arange(n), -1))
            vals = np.empty((n, 3))
            vals[sel] = m
            out = np.where((last >= 0)[:, None], vals[np.maximum(last, 0)], self._held[None, :])
            self._held = out[-1].copy()
            self._last_period = int(period[-1])
        else:
            out[:] = self._held
        return out, fresh
