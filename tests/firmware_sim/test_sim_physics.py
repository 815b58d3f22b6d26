"""Physics of the simulator checked against its own known truth (vehicle, IMU, compass)."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

from firmware_sim.endpoint import Endpoint, EndpointSettings
from firmware_sim.imu_model import EarthField, ImuErrorSettings, ImuModel, MagSettings
from firmware_sim.simulation import SimSettings, Simulation, gravity_body
from firmware_sim.streamer import write_tlog
from firmware_sim.trajectory import SCENARIOS, make_scenario
from firmware_sim.vehicle import G, Vehicle
from mavahrs.geometry import quaternion as quat
from mavahrs.geometry.rotation import to_matrix

RATE_HZ = 1200.0


def _integrate(q0: np.ndarray, gyro: np.ndarray, dt: float) -> np.ndarray:
    """Integrate body rates sampled at instants (trapezoidal mean rate per step, exact exponential)."""
    steps = quat.from_rotation_vector(0.5 * (gyro[1:] + gyro[:-1]) * dt).tolist()
    out = [list(map(float, q0))]
    w, x, y, z = out[0]
    for a, b, c, d in steps:  # q ⊗ step, scalar arithmetic (fast)
        w, x, y, z = (
            w * a - x * b - y * c - z * d,
            w * b + x * a + y * d - z * c,
            w * c - x * d + y * a + z * b,
            w * d + x * c - y * b + z * a,
        )
        out.append([w, x, y, z])
    return np.asarray(out)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


@pytest.mark.parametrize("scenario", ["aggressive", "flips"])
def test_gyro_minus_known_bias_integrates_to_true_attitude(scenario: str) -> None:
    veh = Vehicle(make_scenario(scenario, 3), rate_hz=RATE_HZ, jit=True)
    truth = veh.advance(int(25 * RATE_HZ))
    # every error except the low-pass (a delay) and vibration (not rigid-body motion)
    imu = ImuModel(
        ImuErrorSettings(gyro_lowpass_hz=0.0, accel_lowpass_hz=0.0, vibration=False),
        rate_hz=RATE_HZ, seed=11, jit=True,
    )
    temp = np.full(truth.t_s.shape, 30.0)
    c = imu.process(truth.gyro_rad_s, truth.accel_m_s2, truth.thrust_m_s2, temp)
    assert np.abs(c.gyro_bias_rad_s).max() > math.radians(0.01)  # a real bias was there to remove
    corrected = (c.gyro_rad_s - c.gyro_bias_rad_s) @ np.linalg.inv(imu.gyro_matrix).T
    q = _integrate(truth.q_body_to_ned[0], corrected, 1.0 / RATE_HZ)
    err = np.degrees(quat.angle_between(q, truth.q_body_to_ned))
    assert np.abs(truth.gyro_rad_s).max() > math.radians(300.0)  # fast motion really happened
    assert err.max() < 0.5, err.max()
    # and without removing the bias, the attitude drifts measurably
    raw = _integrate(truth.q_body_to_ned[0], c.gyro_rad_s, 1.0 / RATE_HZ)
    assert np.degrees(quat.angle_between(raw[-1], truth.q_body_to_ned[-1])) > 2 * err.max()


def test_at_rest_accelerometer_reads_rotated_gravity() -> None:
    sim = Simulation(SimSettings(jit=True, scenario="rest", seed=5))
    blk = sim.next_block(4000)  # 10 s
    q = blk.truth.q_body_to_ned
    expect = gravity_body(q)
    assert np.allclose(blk.truth.accel_m_s2, expect, atol=1e-9)
    assert np.allclose(blk.truth.gyro_rad_s, 0.0)
    # the measured accelerometer (noise, bias, scale, filter): mean minus the known error model
    imu = sim.imus[0]
    mean = blk.accel_m_s2[0].mean(axis=0)
    predicted = imu.accel_matrix @ expect[0] + blk.accel_bias_m_s2[0].mean(axis=0)
    assert np.allclose(mean, predicted, atol=2e-3)
    assert abs(np.linalg.norm(blk.accel_m_s2[0], axis=1).mean() - G) < 0.2
    # the ground attitude is the scenario's, slightly tilted
    assert 0.0 < np.degrees(np.arccos(-expect[0, 2] / G)) < 8.0


def test_sustained_tilted_acceleration_departs_from_gravity_as_predicted() -> None:
    sim = Simulation(
        SimSettings(jit=True, scenario="aggressive", seed=2, imu=ImuErrorSettings.ideal(), mag=MagSettings.ideal())
    )
    blk = sim.next_block(400 * 60)
    tr = blk.truth
    # independent prediction from the truth's own kinematics: f = Cᵀ (Δv/Δt − g)
    dt = 1.0 / 400.0
    a_ned = np.diff(tr.vel_ned_m_s, axis=0) / dt
    # Δv over a loop tick averages the 3 sensor steps: compare with the mean specific force too
    f_pred = np.einsum("nji,nj->ni", to_matrix(tr.q_body_to_ned[:-1]), a_ned - np.array([0.0, 0.0, G]))
    measured = blk.accel_m_s2[0][:-1]
    g_body = gravity_body(tr.q_body_to_ned[:-1])
    dep_measured = _angle_deg(measured, g_body)
    dep_pred = _angle_deg(f_pred, g_body)
    flying = tr.thrust_m_s2[:-1] > 0
    assert np.abs(dep_measured - dep_pred)[flying].max() < 1.0
    # the effect is large: a multirotor's accelerometer does not point at gravity here
    rms = math.sqrt(np.mean(dep_measured[flying] ** 2))
    assert 12.0 < rms < 40.0, rms
    assert np.mean(dep_measured[flying] > 10.0) > 0.3
    # in a dash the reading is thrust along −z plus rotor drag on the body-horizontal speed
    v_body = np.einsum("nji,nj->ni", to_matrix(tr.q_body_to_ned), tr.vel_ned_m_s)
    k = sim.settings.vehicle.k_rotor_drag_1_s
    c = sim.settings.vehicle.c_body_drag_1_m
    speed = np.linalg.norm(v_body, axis=1)
    drag_x = -(k + c * speed) * v_body[:, 0]
    fly = tr.thrust_m_s2 > 0
    assert np.allclose(tr.accel_m_s2[fly, 0], drag_x[fly], atol=1e-9)
    assert np.max(np.abs(tr.accel_m_s2[fly, 0])) > 3.0


@pytest.mark.parametrize("declination", [0.0, 12.0])
def test_magnetometer_matches_configured_field(declination: float) -> None:
    fld = EarthField(strength_ut=50.0, inclination_deg=60.0, declination_deg=declination)
    sim = Simulation(
        SimSettings(jit=True, scenario="hover", seed=4, imu=ImuErrorSettings.ideal(), mag=MagSettings.ideal(), earth_field=fld)
    )
    blk = sim.next_block(400 * 20)
    fresh = blk.mag_fresh[0]
    m_ned = quat.rotate(blk.truth.q_body_to_ned[fresh], blk.mag_ut[0][fresh])
    assert np.allclose(np.linalg.norm(m_ned, axis=1), 50.0, atol=1e-9)
    assert np.allclose(np.degrees(np.arcsin(m_ned[:, 2] / 50.0)), 60.0, atol=1e-6)
    assert np.allclose(np.degrees(np.arctan2(m_ned[:, 1], m_ned[:, 0])), declination, atol=1e-6)
    # 100 Hz compass at a 400 Hz loop: a fresh sample every 4th tick, held in between
    assert fresh.mean() == pytest.approx(0.25, abs=0.01)


def test_hard_and_soft_iron_are_applied_as_configured() -> None:
    soft = (1.1, 0.05, 0.0, 0.05, 0.9, 0.02, 0.0, 0.02, 1.05)
    hard = (12.0, -7.0, 30.0)
    sim = Simulation(
        SimSettings(
            jit=True,
            scenario="rest", seed=9, imu=ImuErrorSettings.ideal(),
            mag=MagSettings(noise_ut=0.0, lsb_ut=0.0, hard_iron_ut=hard, soft_iron=soft),
        )
    )
    blk = sim.next_block(100)
    b_body = quat.rotate(quat.conjugate(blk.truth.q_body_to_ned), sim.settings.earth_field.ned_ut())
    expect = b_body @ np.array(soft).reshape(3, 3).T + np.array(hard)
    assert np.allclose(blk.mag_ut[0], expect, atol=1e-9)


def test_gyro_and_accel_saturate_where_configured() -> None:
    limit = math.radians(500.0)
    imu = ImuErrorSettings.ideal()
    imu = ImuErrorSettings(**{**imu.__dict__, "gyro_range_rad_s": limit, "accel_range_m_s2": 1.5 * G})
    sim = Simulation(SimSettings(jit=True, scenario="flips", seed=1, imu=imu))
    blk = sim.next_block(400 * 20)
    g = blk.gyro_rad_s[0]
    assert np.abs(blk.truth.gyro_rad_s).max() > math.radians(600.0)
    assert np.abs(g).max() == pytest.approx(limit)
    over = np.abs(blk.truth.gyro_rad_s) > limit
    assert over.any() and np.allclose(np.abs(g[over]), limit)
    assert np.abs(blk.accel_m_s2[0]).max() == pytest.approx(1.5 * G)
    # wire saturation: RAW_IMU carries int16 mrad/s, i.e. at most 32.767 rad/s
    from firmware_sim.encoder import to_int16

    assert to_int16(np.array([40.0 * 1000.0, -40.0 * 1000.0, 1.9 * 1000.0])).tolist() == [32767, -32768, 1900]


def test_quantisation_to_sensor_lsb_and_wire_units() -> None:
    lsb = math.radians(2000.0) / 32768.0
    imu = ImuErrorSettings(gyro_lowpass_hz=0.0, accel_lowpass_hz=0.0)
    sim = Simulation(SimSettings(jit=True, scenario="hover", seed=8, imu=imu))
    blk = sim.next_block(2000)
    steps = blk.gyro_rad_s[0] / lsb
    assert np.allclose(steps, np.round(steps), atol=1e-6)
    a_steps = blk.accel_m_s2[0] / imu.accel_lsb_m_s2
    assert np.allclose(a_steps, np.round(a_steps), atol=1e-6)
    # with the low-pass on, values are no longer on the grid (the filter runs after the ADC)
    blk2 = Simulation(SimSettings(jit=True, scenario="hover", seed=8)).next_block(2000)
    s2 = blk2.gyro_rad_s[0] / lsb
    assert not np.allclose(s2, np.round(s2), atol=1e-6)
    # wire units: C-style truncation toward zero
    from firmware_sim.encoder import to_int16

    assert to_int16(np.array([1.9, -1.9, 0.4, -0.4])).tolist() == [1, -1, 0, 0]


def test_lowpass_has_unit_dc_gain_and_attenuates_vibration() -> None:
    rate = 1200.0
    t = np.arange(int(2 * rate)) / rate
    truth = np.zeros((t.size, 3))
    truth[:, 0] = 0.5 + 0.5 * np.sin(2 * np.pi * 200.0 * t)
    imu = ImuModel(ImuErrorSettings(**{**ImuErrorSettings.ideal().__dict__, "gyro_lowpass_hz": 20.0}), rate_hz=rate, seed=0)
    c = imu.process(truth, truth, np.zeros(t.size), np.zeros(t.size))
    tail = c.gyro_rad_s[t.size // 2 :, 0]
    assert tail.mean() == pytest.approx(0.5, abs=1e-3)
    assert np.ptp(tail) < 0.01  # 200 Hz attenuated > 40 dB by a 2-pole 20 Hz filter


def test_vibration_scenario_aliases_into_the_passband() -> None:
    ideal = Simulation(SimSettings(jit=True, scenario="vibration", seed=1, imu=ImuErrorSettings.ideal(lowpass=True)))
    real = Simulation(SimSettings(jit=True, scenario="vibration", seed=1,
                                  imu=ImuErrorSettings(**{**ImuErrorSettings.ideal(lowpass=True).__dict__, "vibration": True})))
    a = ideal.next_block(400 * 20)
    b = real.next_block(400 * 20)
    fly = a.truth.thrust_m_s2 > 0
    resid = (b.accel_m_s2[0] - a.accel_m_s2[0])[fly]
    # 395 Hz × 3 = 1185 Hz sampled at 1200 Hz lands near 15 Hz, inside the 20 Hz filter
    assert np.sqrt(np.mean(resid**2)) > 1.0


def test_temperature_drives_gyro_bias() -> None:
    sim = Simulation(SimSettings(jit=True, scenario="temperature", seed=3))
    blks = [sim.next_block(4000) for _ in range(6)]
    temp = np.concatenate([b.temperature_c for b in blks])
    bias = np.concatenate([b.gyro_bias_rad_s[0] for b in blks])
    assert temp[0] == pytest.approx(10.0) and temp[-1] > 40.0
    tempco = sim.imus[0].gyro_tempco
    drift = bias[-1] - bias[0]
    assert np.allclose(drift, tempco * (temp[-1] - temp[0]), atol=math.radians(0.05))


def test_chunking_does_not_change_the_result() -> None:
    s = SimSettings(jit=True, scenario="aggressive", seed=6)
    a = Simulation(s)
    b = Simulation(s)
    one = a.next_block(700)
    parts = [b.next_block(n) for n in (1, 6, 93, 300, 300)]
    assert np.array_equal(one.t_us, np.concatenate([p.t_us for p in parts]))
    for name in ("gyro_rad_s", "accel_m_s2", "mag_ut"):
        assert np.allclose(getattr(one, name), np.concatenate([getattr(p, name) for p in parts], axis=1), atol=1e-12)
    assert np.allclose(one.truth.rows, np.concatenate([p.truth.rows for p in parts]), atol=1e-12)
    assert np.allclose(one.est_q_body_to_ned, np.concatenate([p.est_q_body_to_ned for p in parts]), atol=1e-12)


def test_compiled_and_interpreted_kernels_agree() -> None:
    a = Simulation(SimSettings(jit=False, scenario="flips", seed=2)).next_block(400)
    b = Simulation(SimSettings(jit=True, scenario="flips", seed=2)).next_block(400)
    assert np.allclose(a.truth.rows, b.truth.rows, rtol=0, atol=1e-9)
    assert np.allclose(a.gyro_rad_s, b.gyro_rad_s, rtol=0, atol=1e-9)
    assert np.allclose(a.est_q_body_to_ned, b.est_q_body_to_ned, rtol=0, atol=1e-9)


def _tlog_bytes(seed: int) -> bytes:
    ep = Endpoint(
        Simulation(SimSettings(jit=True, scenario="aggressive", seed=seed)), EndpointSettings(preset="bench", block_ticks=500)
    )
    buf = io.BytesIO()
    write_tlog(ep, buf, 3.0)
    return buf.getvalue()


def test_same_seed_gives_the_same_bytes() -> None:
    a, b, c = _tlog_bytes(7), _tlog_bytes(7), _tlog_bytes(8)
    assert len(a) > 50_000
    assert a == b
    assert a != c


@pytest.mark.parametrize("name", SCENARIOS)
def test_every_scenario_runs_and_stays_physical(name: str) -> None:
    sim = Simulation(SimSettings(jit=True, scenario=name, seed=1))
    blk = sim.next_block(400 * 12)
    tr = blk.truth
    assert np.all(np.isfinite(tr.rows))
    assert np.allclose(np.linalg.norm(tr.q_body_to_ned, axis=1), 1.0, atol=1e-9)
    assert np.abs(tr.gyro_rad_s).max() < math.radians(1100.0) + 1e-9
    assert np.linalg.norm(tr.accel_m_s2, axis=1).max() < 6.0 * G
    assert make_scenario(name).description
    if name != "rest":
        assert tr.thrust_m_s2[-1] > 0.0  # airborne after the take-off
