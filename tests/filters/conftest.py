"""Synthetic-truth fixtures for the filter tests.

``make_truth(...)`` builds a smooth attitude trajectory with a known
``q_body_to_ned`` and the ideal (or noisy) gyro, accelerometer and
magnetometer readings it produces; optionally a constant gyro bias and a
linear acceleration with the matching NED velocity (a GNSS stand-in).

* The gyro sample k is the *mean* rate over the interval (k−1, k]: the rotation
  vector of q_{k−1}* ⊗ q_k divided by dt, so exact integration of the ideal gyro
  reproduces the truth to rounding.
* The accelerometer reads specific force f = Cᵀ(a_NED − g_NED), g_NED = (0, 0, g):
  a level FRD sensor at rest reads (0, 0, −g).
* The field is magnetic north with a 66° dip: m_NED = (20, 0, 45) µT.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

from mavahrs.filters.base import make_inputs
from mavahrs.geometry.quaternion import conjugate, multiply, rotate, to_rotation_vector
from mavahrs.geometry.rotation import from_euler_rad

G_M_S2 = 9.80665
MAG_NED_UT = np.array([20.0, 0.0, 45.0])


@dataclass
class Truth:
    """A synthetic recording with its true attitude."""

    t_s: np.ndarray
    dt_s: np.ndarray
    q_body_to_ned: np.ndarray
    gyro_rad_s: np.ndarray
    accel_m_s2: np.ndarray
    mag_ut: np.ndarray
    velocity_ned_m_s: np.ndarray
    gyro_bias_rad_s: np.ndarray

    @property
    def n(self) -> int:
        return int(self.t_s.size)

    def inputs(self, *, mag: bool = True, velocity: bool = False) -> np.ndarray:
        """Kernel input rows (N, IN_WIDTH)."""
        return make_inputs(
            self.gyro_rad_s,
            self.accel_m_s2,
            self.mag_ut if mag else None,
            dt_s=self.dt_s,
            velocity_ned_m_s=self.velocity_ned_m_s if velocity else None,
        )


def _euler_trajectory(t: np.ndarray, amplitude: float) -> np.ndarray:
    """Smooth roll/pitch/yaw (rad) — sums of incommensurate sinusoids."""
    roll = amplitude * (0.5 * np.sin(0.7 * t) + 0.2 * np.sin(1.9 * t + 1.0))
    pitch = amplitude * (0.4 * np.sin(0.5 * t + 0.3) + 0.15 * np.sin(2.3 * t))
    yaw = amplitude * (1.2 * np.sin(0.15 * t) + 0.5 * np.sin(0.6 * t + 2.0))
    return np.stack([roll, pitch, yaw], axis=-1)


def make_truth(
    duration_s: float = 60.0,
    rate_hz: float = 200.0,
    *,
    amplitude: float = 1.0,
    gyro_bias_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
    noise: bool = False,
    linear_acceleration_m: float = 0.0,
    rest: bool = False,
    seed: int = 7,
) -> Truth:
    """Build a synthetic recording.

    Args:
        duration_s, rate_hz: length and sample rate.
        amplitude: scales the attitude excursions (0.2 = slow, ±6° roll …).
        gyro_bias_rad_s: constant bias added to the gyro.
        noise: add white noise (gyro 0.3°/s, accel 0.05 m/s², mag 0.3 µT).
        linear_acceleration_m: amplitude (m) of a sinusoidal position path in
            NED (0 = no linear motion); ≈ 1.3 m/s² peak per 2 m.
        rest: hold the attitude at level, north (amplitude ignored).
        seed: noise seed.
    """
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    t = np.arange(n) * dt
    if rest:
        q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    else:
        e = _euler_trajectory(t, amplitude)
        q = from_euler_rad(e[:, 0], e[:, 1], e[:, 2])
        q[q[:, 0] < 0] *= -1.0
    dq = multiply(conjugate(q[:-1]), q[1:])
    gyro = np.empty((n, 3))
    gyro[1:] = to_rotation_vector(dq) / dt
    gyro[0] = gyro[1] if n > 1 else 0.0
    a = linear_acceleration_m
    w = np.array([0.8, 0.6, 1.1])
    ph = np.array([0.0, 1.0, 0.5])
    amp = a * np.array([1.0, 1.0, 0.3])
    vel = amp * w * np.cos(w * t[:, None] + ph)
    acc = -amp * w * w * np.sin(w * t[:, None] + ph)
    f_ned = acc - np.array([0.0, 0.0, G_M_S2])
    q_ned_to_body = conjugate(q)
    accel = rotate(q_ned_to_body, f_ned)
    mag = rotate(q_ned_to_body, np.broadcast_to(MAG_NED_UT, (n, 3)))
    bias = np.asarray(gyro_bias_rad_s, dtype=np.float64)
    gyro = gyro + bias
    if noise:
        rng = np.random.default_rng(seed)
        gyro = gyro + rng.normal(scale=np.radians(0.3), size=gyro.shape)
        accel = accel + rng.normal(scale=0.05, size=accel.shape)
        mag = mag + rng.normal(scale=0.3, size=mag.shape)
    return Truth(
        t_s=t,
        dt_s=np.full(n, dt),
        q_body_to_ned=q,
        gyro_rad_s=gyro,
        accel_m_s2=accel,
        mag_ut=mag,
        velocity_ned_m_s=vel,
        gyro_bias_rad_s=bias,
    )


@pytest.fixture(scope="session")
def synthetic() -> Callable[..., Truth]:
    """The :func:`make_truth` factory (see its arguments)."""
    return make_truth


@pytest.fixture(scope="session")
def truth_9axis_noisy() -> Truth:
    """60 s, 200 Hz, noisy, no bias: the common accuracy case."""
    return make_truth(60.0, 200.0, noise=True)


# --------------------------------------------------------------------- real data


@pytest.fixture(scope="session")
def broad_trials(broad_dir):  # type: ignore[no-untyped-def]
    """All BROAD trials in ../shared/data/broad (skips when absent)."""
    from mavahrs.evaluation.datasets import find_broad_trials, load_broad_trial

    paths = find_broad_trials(broad_dir)
    if not paths:
        pytest.skip(f"no BROAD .mat trials in {broad_dir}")
    return [load_broad_trial(p) for p in paths]


@pytest.fixture(scope="session")
def broad_mean(broad_trials) -> Callable[..., np.ndarray]:  # type: ignore[no-untyped-def]
    """``broad_mean(name, settings=None, six_axis=False)`` → mean (total, heading, inclination) RMS, degrees.

    BROAD's scoring: per trial the RMS over ``movement == 1`` samples with a
    reference, then the plain mean over trials; one setting for all trials.
    """
    from mavahrs.evaluation.metrics import summarize
    from mavahrs.filters import create
    from mavahrs.filters.layout import OUT_Q

    def run(name: str, settings: object = None, six_axis: bool = False) -> np.ndarray:
        rows = []
        for rec in broad_trials:
            inputs = make_inputs(rec.gyro_rad_s, rec.accel_m_s2, None if six_axis else rec.mag_ut, dt_s=rec.dt_s)
            out = create(name, settings).run(inputs)
            s = summarize(out[:, OUT_Q : OUT_Q + 4], rec.q_ref_body_to_ned, rec.scored)
            rows.append((s.total_rms_deg, s.heading_rms_deg, s.inclination_rms_deg))
        return np.mean(np.array(rows), axis=0)

    return run


@pytest.fixture(scope="session")
def gnss_inclination() -> Callable[..., tuple[float, float]]:
    """``gnss_inclination(name)`` → inclination RMS (deg) with and without GNSS velocity.

    90 s, 9-axis (the NED acceleration is rotated into body axes with the
    estimated heading, so compensation needs a heading reference), a
    sinusoidal path of 4 m amplitude (≈ 2.6 m/s² peak horizontal
    acceleration), noisy sensors, velocity on every row; scored after 10 s.
    """
    from mavahrs.evaluation.metrics import attitude_errors_rad
    from mavahrs.filters import create
    from mavahrs.filters.layout import OUT_Q

    def run(name: str, settings: object = None) -> tuple[float, float]:
        tr = make_truth(90.0, 200.0, noise=True, linear_acceleration_m=4.0)
        res = []
        for velocity in (True, False):
            out = create(name, settings).run(tr.inputs(mag=True, velocity=velocity))
            _, _, incl = attitude_errors_rad(out[:, OUT_Q : OUT_Q + 4], tr.q_body_to_ned)
            res.append(float(np.degrees(np.sqrt(np.mean(incl[2000:] ** 2)))))
        return res[0], res[1]

    return run


#: raw-IMU flights: 200 Hz; body → IMU, the IMU's x axis up (rotated 90° about the body's y axis)
RAW_RATE_HZ = 200
RAW_Q_MOUNT = np.array([math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0])


def raw_imu_flight(scenario: str, seed: int, seconds: float = 90.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ``firmware_sim`` flight as a raw IMU reaches the Python API: filter rows, true attitude, gyro bias.

    The simulator's raw preset (a constant gyro bias of up to 5 °/s per axis, no calibration), the
    IMU mounted x axis up (``RAW_Q_MOUNT``), ``RAW_RATE_HZ``, no GNSS, no magnetometer, started in
    flight.  Returns the rows (:func:`make_inputs`, dt from the stamps), the true IMU → NED
    attitude per row and the gyro's bias (IMU frame, rad/s).  Skips without ``firmware_sim``.
    """
    sim_mod = pytest.importorskip("firmware_sim.simulation")
    from firmware_sim.imu_model import ImuErrorSettings

    sim = sim_mod.Simulation(sim_mod.SimSettings(
        scenario=scenario, seed=seed, start_in_motion=True, imu_mount_deg=(0.0, 90.0, 0.0),
        imu=ImuErrorSettings.raw(), gnss=False, mag_count=0, imu_count=1, loop_rate_hz=RAW_RATE_HZ,
    ))  # fmt: skip
    blk = sim.next_block(int(RAW_RATE_HZ * seconds))
    dt = np.diff(blk.t_us, prepend=blk.t_us[0] - 1e6 / RAW_RATE_HZ) / 1e6
    assert abs(float(np.median(dt)) - 1.0 / RAW_RATE_HZ) < 1e-4
    rows = make_inputs(blk.gyro_rad_s[0], blk.accel_m_s2[0], None, dt_s=dt)
    q_ref = multiply(blk.truth.q_body_to_ned, np.broadcast_to(RAW_Q_MOUNT, blk.truth.q_body_to_ned.shape).copy())
    return rows, q_ref, np.asarray(blk.gyro_bias_rad_s[0][0], dtype=float)


@pytest.fixture(scope="session")
def raw_flight() -> Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The :func:`raw_imu_flight` factory (``raw_flight(scenario, seed)``)."""
    return raw_imu_flight
