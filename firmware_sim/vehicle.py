r"""Quadcopter rigid-body model: the simulator's ground truth.

Pure and deterministic (no randomness here; the scenario carries the seed).
Frames: earth NED, body FRD; ``q_body_to_ned`` scalar-first Hamilton;
g = 9.80665 m/s² along +down.

Dynamics, integrated at the sensor sample rate ``dt_s`` (explicit, exact where
it matters):

* **Attitude** — a first-order attitude loop with feed-forward: the commanded
  body rate is the command's own rate plus ``rotvec(q⁻¹ ⊗ q_cmd) / tau_att_s``
  (correction limited to ``max_correction_rate_rad_s``), or the rate command
  itself in rate mode (flips); the body rate follows it through a first-order
  motor lag ``tau_rate_s`` (solved exactly over a step), and the quaternion is
  advanced with the exact exponential of the mean rate over the step.
* **Thrust** along body −z, per unit mass: an altitude-hold loop (altitude →
  climb rate → vertical acceleration → thrust divided by the tilt cosine) or
  the scenario's thrust override, through a first-order lag ``tau_thrust_s``.
* **Drag** in body axes: rotor drag ``−k_rotor_drag · v_xy`` on the body
  horizontal velocity (the effect that makes a multirotor's accelerometer
  measure speed), ``−k_vertical_drag · v_z``, and quadratic body drag
  ``−c_body_drag · |v| · v``.
* **Translation**: ``a_ned = C(q) · f_body + [0, 0, g]``, with the specific
  force ``f_body = thrust + drag`` being exactly what an accelerometer at the
  centre of mass measures (f = a − g).  An IMU offset from the centre of mass
  adds ``ω̇ × r + ω × (ω × r)``.
* **On the ground** (scenario flag): attitude held at the ground attitude,
  rates and velocity zero, the accelerometer reads ``C(q)ᵀ · [0, 0, −g]``.

Each output row ``k`` is the state at ``t_k`` (the specific force in it is the
one that moves the vehicle from ``t_k`` to ``t_{k+1}``, so the finite
difference of velocity reproduces it exactly).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from firmware_sim.jit import lazy_kernel
from firmware_sim.trajectory import Scenario
from mavahrs.geometry import quaternion as quat
from mavahrs.geometry.rotation import from_euler_rad

__all__ = [
    "G",
    "VehicleSettings",
    "Vehicle",
    "TruthChunk",
    "T_Q",
    "T_GYRO",
    "T_ACCEL",
    "T_VEL",
    "T_POS",
    "T_THRUST",
    "T_ACC_NED",
    "TRUTH_LEN",
]

Array = NDArray[np.float64]
G = 9.80665

# truth row layout
T_Q = 0  # q_body_to_ned (4)
T_GYRO = 4  # true body rate, rad/s (3)
T_ACCEL = 7  # true specific force at the IMU, body, m/s² (3)
T_VEL = 10  # velocity NED, m/s (3)
T_POS = 13  # position NED from home, m (3)
T_THRUST = 16  # thrust per unit mass, m/s² (1)
T_ACC_NED = 17  # kinematic acceleration NED, m/s² (3)
TRUTH_LEN = 20

# kernel state layout: q(4) w(3) v(3) p(3) thrust(1) grounded(1)
_S_LEN = 15
# kernel params layout
(
    _P_TAU_ATT,
    _P_TAU_RATE,
    _P_MAX_CORR,
    _P_MAX_RATE,
    _P_TAU_T,
    _P_K_ALT,
    _P_VUP,
    _P_VDOWN,
    _P_K_VZ,
    _P_AZ_MAX,
    _P_T_MIN,
    _P_T_MAX,
    _P_K_ROTOR,
    _P_K_VERT,
    _P_C_BODY,
    _P_RX,
    _P_RY,
    _P_RZ,
) = range(18)
_P_LEN = 18


@dataclass(frozen=True)
class VehicleSettings:
    """Quadcopter dynamics (all per unit mass).

    Attributes:
        tau_att_s: attitude-loop time constant (s).
        tau_rate_s: body-rate (motor) lag time constant (s).
        max_correction_rate_rad_s: limit of the attitude-error correction rate (rad/s).
        max_rate_rad_s: limit of the commanded body rate (rad/s); 1100 °/s allows the flips.
        tau_thrust_s: thrust lag time constant (s).
        k_alt_1_s: altitude → climb-rate gain (1/s).
        max_climb_m_s / max_descent_m_s: climb-rate limits (m/s).
        k_vz_1_s: climb-rate → vertical-acceleration gain (1/s).
        max_vertical_accel_m_s2: limit of the altitude loop's vertical acceleration (m/s²).
        thrust_min_m_s2 / thrust_max_m_s2: thrust range (m/s²).
        k_rotor_drag_1_s: rotor drag coefficient on body-horizontal velocity (1/s).
        k_vertical_drag_1_s: linear drag on body-z velocity (1/s).
        c_body_drag_1_m: quadratic body drag coefficient (1/m).
        imu_offset_m: IMU position from the centre of mass, body FRD (m).
    """

    tau_att_s: float = 0.12
    tau_rate_s: float = 0.03
    max_correction_rate_rad_s: float = math.radians(360.0)
    max_rate_rad_s: float = math.radians(1100.0)
    tau_thrust_s: float = 0.04
    k_alt_1_s: float = 1.0
    max_climb_m_s: float = 5.0
    max_descent_m_s: float = 3.0
    k_vz_1_s: float = 3.0
    max_vertical_accel_m_s2: float = 6.0
    thrust_min_m_s2: float = 0.05 * G
    thrust_max_m_s2: float = 5.0 * G
    k_rotor_drag_1_s: float = 0.4
    k_vertical_drag_1_s: float = 0.2
    c_body_drag_1_m: float = 0.01
    imu_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("tau_att_s", "tau_rate_s", "tau_thrust_s", "max_rate_rad_s", "thrust_max_m_s2"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"VehicleSettings.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.thrust_min_m_s2 < self.thrust_max_m_s2:
            raise ValueError("VehicleSettings: need 0 <= thrust_min_m_s2 < thrust_max_m_s2")
        for name in ("k_rotor_drag_1_s", "k_vertical_drag_1_s", "c_body_drag_1_m"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"VehicleSettings.{name} must be >= 0")

    def params(self) -> Array:
        p = np.zeros(_P_LEN)
        p[_P_TAU_ATT] = self.tau_att_s
        p[_P_TAU_RATE] = self.tau_rate_s
        p[_P_MAX_CORR] = self.max_correction_rate_rad_s
        p[_P_MAX_RATE] = self.max_rate_rad_s
        p[_P_TAU_T] = self.tau_thrust_s
        p[_P_K_ALT] = self.k_alt_1_s
        p[_P_VUP] = self.max_climb_m_s
        p[_P_VDOWN] = self.max_descent_m_s
        p[_P_K_VZ] = self.k_vz_1_s
        p[_P_AZ_MAX] = self.max_vertical_accel_m_s2
        p[_P_T_MIN] = self.thrust_min_m_s2
        p[_P_T_MAX] = self.thrust_max_m_s2
        p[_P_K_ROTOR] = self.k_rotor_drag_1_s
        p[_P_K_VERT] = self.k_vertical_drag_1_s
        p[_P_C_BODY] = self.c_body_drag_1_m
        p[_P_RX], p[_P_RY], p[_P_RZ] = self.imu_offset_m
        return p


@lazy_kernel
def _integrate(state: Array, params: Array, cmds: Array, q_cmd: Array, rate_ff: Array, dt: float, out: Array) -> None:
    """Advance ``state`` over ``cmds.shape[0]`` steps of ``dt``; row k of ``out`` = state at t_k.

    ``q_cmd`` (N, 4): commanded attitude; ``rate_ff`` (N, 3): the command's own body rate.
    """
    g = 9.80665
    n = cmds.shape[0]
    for k in range(n):
        c = cmds[k]
        q0, q1, q2, q3 = state[0], state[1], state[2], state[3]
        wx, wy, wz = state[4], state[5], state[6]
        vn, ve, vd = state[7], state[8], state[9]
        grounded = c[9] > 0.5
        if grounded:
            q0, q1, q2, q3 = q_cmd[k, 0], q_cmd[k, 1], q_cmd[k, 2], q_cmd[k, 3]
            wx = wy = wz = 0.0
            vn = ve = vd = 0.0
            state[12] = 0.0
        elif state[14] > 0.5:
            # just left the ground: thrust starts at hover
            r22 = 1.0 - 2.0 * (q1 * q1 + q2 * q2)
            state[13] = g / max(r22, 0.3)
        # rotation matrix C (body -> NED)
        c00 = 1.0 - 2.0 * (q2 * q2 + q3 * q3)
        c01 = 2.0 * (q1 * q2 - q0 * q3)
        c02 = 2.0 * (q1 * q3 + q0 * q2)
        c10 = 2.0 * (q1 * q2 + q0 * q3)
        c11 = 1.0 - 2.0 * (q1 * q1 + q3 * q3)
        c12 = 2.0 * (q2 * q3 - q0 * q1)
        c20 = 2.0 * (q1 * q3 - q0 * q2)
        c21 = 2.0 * (q2 * q3 + q0 * q1)
        c22 = 1.0 - 2.0 * (q1 * q1 + q2 * q2)
        # body velocity (air-relative, no wind)
        vbx = c00 * vn + c10 * ve + c20 * vd
        vby = c01 * vn + c11 * ve + c21 * vd
        vbz = c02 * vn + c12 * ve + c22 * vd
        speed = math.sqrt(vbx * vbx + vby * vby + vbz * vbz)
        dx = -params[_P_K_ROTOR] * vbx - params[_P_C_BODY] * speed * vbx
        dy = -params[_P_K_ROTOR] * vby - params[_P_C_BODY] * speed * vby
        dz = -params[_P_K_VERT] * vbz - params[_P_C_BODY] * speed * vbz
        if grounded:
            fx, fy, fz = -c20 * g, -c21 * g, -c22 * g
            an = ae = ad = 0.0
            wnx = wny = wnz = 0.0
            thrust = 0.0
        else:
            # ---- thrust: override or altitude hold
            if c[4] > 0.0:
                t_cmd = c[4]
            else:
                alt = -state[12]
                vd_des = -params[_P_K_ALT] * (c[3] - alt)
                vd_des = min(max(vd_des, -params[_P_VUP]), params[_P_VDOWN])
                ad_des = params[_P_K_VZ] * (vd_des - vd)
                ad_des = min(max(ad_des, -params[_P_AZ_MAX]), params[_P_AZ_MAX])
                drag_down = c20 * dx + c21 * dy + c22 * dz
                t_cmd = (g + drag_down - ad_des) / max(c22, 0.3)
            t_cmd = min(max(t_cmd, params[_P_T_MIN]), params[_P_T_MAX])
            thrust = state[13] + (t_cmd - state[13]) * (1.0 - math.exp(-dt / params[_P_TAU_T]))
            fx, fy, fz = dx, dy, dz - state[13]
            an = c00 * fx + c01 * fy + c02 * fz
            ae = c10 * fx + c11 * fy + c12 * fz
            ad = c20 * fx + c21 * fy + c22 * fz + g
            # ---- attitude: commanded rate then first-order lag
            if c[5] > 0.5:
                wcx, wcy, wcz = c[6], c[7], c[8]
            else:
                # attitude error: rotation vector of conj(q) ⊗ q_cmd (body frame), shortest way
                a0, a1, a2, a3 = q_cmd[k, 0], q_cmd[k, 1], q_cmd[k, 2], q_cmd[k, 3]
                ew = q0 * a0 + q1 * a1 + q2 * a2 + q3 * a3
                ex = q0 * a1 - q1 * a0 - q2 * a3 + q3 * a2
                ey = q0 * a2 + q1 * a3 - q2 * a0 - q3 * a1
                ez = q0 * a3 - q1 * a2 + q2 * a1 - q3 * a0
                if ew < 0.0:
                    ew, ex, ey, ez = -ew, -ex, -ey, -ez
                sn = math.sqrt(ex * ex + ey * ey + ez * ez)
                kk = 2.0 if sn < 1e-12 else 2.0 * math.atan2(sn, ew) / sn
                ex = kk * ex / params[_P_TAU_ATT]
                ey = kk * ey / params[_P_TAU_ATT]
                ez = kk * ez / params[_P_TAU_ATT]
                en = math.sqrt(ex * ex + ey * ey + ez * ez)
                if en > params[_P_MAX_CORR]:
                    s = params[_P_MAX_CORR] / en
                    ex, ey, ez = ex * s, ey * s, ez * s
                wcx, wcy, wcz = rate_ff[k, 0] + ex, rate_ff[k, 1] + ey, rate_ff[k, 2] + ez
            wn_ = math.sqrt(wcx * wcx + wcy * wcy + wcz * wcz)
            if wn_ > params[_P_MAX_RATE]:
                s = params[_P_MAX_RATE] / wn_
                wcx, wcy, wcz = wcx * s, wcy * s, wcz * s
            a = 1.0 - math.exp(-dt / params[_P_TAU_RATE])
            wnx = wx + (wcx - wx) * a
            wny = wy + (wcy - wy) * a
            wnz = wz + (wcz - wz) * a
        # ---- IMU lever arm: f + w' x r + w x (w x r)
        rx, ry, rz = params[_P_RX], params[_P_RY], params[_P_RZ]
        if rx != 0.0 or ry != 0.0 or rz != 0.0:
            adx, ady, adz = (wnx - wx) / dt, (wny - wy) / dt, (wnz - wz) / dt
            tx, ty, tz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
            fx += ady * rz - adz * ry + wy * tz - wz * ty
            fy += adz * rx - adx * rz + wz * tx - wx * tz
            fz += adx * ry - ady * rx + wx * ty - wy * tx
        # ---- output row k = state at t_k
        o = out[k]
        o[0], o[1], o[2], o[3] = q0, q1, q2, q3
        o[4], o[5], o[6] = wx, wy, wz
        o[7], o[8], o[9] = fx, fy, fz
        o[10], o[11], o[12] = vn, ve, vd
        o[13], o[14], o[15] = state[10], state[11], state[12]
        o[16] = state[13] if not grounded else 0.0
        o[17], o[18], o[19] = an, ae, ad
        # ---- advance to t_{k+1}: exact exponential of the mean rate over the step
        mx, my, mz = 0.5 * (wx + wnx) * dt, 0.5 * (wy + wny) * dt, 0.5 * (wz + wnz) * dt
        ang = math.sqrt(mx * mx + my * my + mz * mz)
        hw = math.cos(0.5 * ang)
        hk = 0.5 if ang < 1e-12 else math.sin(0.5 * ang) / ang
        hx, hy, hz = hk * mx, hk * my, hk * mz
        nq0 = q0 * hw - q1 * hx - q2 * hy - q3 * hz
        nq1 = q0 * hx + q1 * hw + q2 * hz - q3 * hy
        nq2 = q0 * hy - q1 * hz + q2 * hw + q3 * hx
        nq3 = q0 * hz + q1 * hy - q2 * hx + q3 * hw
        nrm = math.sqrt(nq0 * nq0 + nq1 * nq1 + nq2 * nq2 + nq3 * nq3)
        state[0], state[1], state[2], state[3] = nq0 / nrm, nq1 / nrm, nq2 / nrm, nq3 / nrm
        state[4], state[5], state[6] = wnx, wny, wnz
        state[10] += vn * dt + 0.5 * an * dt * dt
        state[11] += ve * dt + 0.5 * ae * dt * dt
        state[12] += vd * dt + 0.5 * ad * dt * dt
        state[7], state[8], state[9] = vn + an * dt, ve + ae * dt, vd + ad * dt
        state[13] = thrust
        state[14] = 1.0 if grounded else 0.0


@dataclass
class TruthChunk:
    """Truth at consecutive sample instants: ``t_s`` (N,) and rows (N, TRUTH_LEN)."""

    t_s: Array
    rows: Array

    @property
    def q_body_to_ned(self) -> Array:
        return self.rows[:, T_Q : T_Q + 4]

    @property
    def gyro_rad_s(self) -> Array:
        return self.rows[:, T_GYRO : T_GYRO + 3]

    @property
    def accel_m_s2(self) -> Array:
        return self.rows[:, T_ACCEL : T_ACCEL + 3]

    @property
    def vel_ned_m_s(self) -> Array:
        return self.rows[:, T_VEL : T_VEL + 3]

    @property
    def pos_ned_m(self) -> Array:
        return self.rows[:, T_POS : T_POS + 3]

    @property
    def thrust_m_s2(self) -> Array:
        return self.rows[:, T_THRUST]

    @property
    def accel_ned_m_s2(self) -> Array:
        return self.rows[:, T_ACC_NED : T_ACC_NED + 3]


class Vehicle:
    """Integrates a :class:`~firmware_sim.trajectory.Scenario` at ``rate_hz``, chunk by chunk.

    ``advance(n)`` returns the truth at the next ``n`` sample instants
    ``t = i / rate_hz`` (i counting from 0 at boot); chunking does not change
    the result.  ``jit=True`` runs the dynamics compiled by numba (for long
    batch runs; the interpreted kernel needs about 30 µs per step).
    """

    def __init__(
        self, scenario: Scenario, settings: VehicleSettings | None = None, *, rate_hz: float = 1200.0, jit: bool = False
    ) -> None:
        if not rate_hz > 0.0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        self.scenario = scenario
        self.settings = settings or VehicleSettings()
        self.rate_hz = float(rate_hz)
        self.dt_s = 1.0 / self.rate_hz
        self._params = self.settings.params()
        self._kernel = _integrate.select(jit)
        self._state = np.zeros(_S_LEN)
        self._state[0:4] = from_euler_rad(*scenario.ground_attitude_rad)
        self._state[14] = 1.0  # on the ground before t = 0: the first airborne step starts at hover thrust
        if scenario.start_in_motion:  # already flying: at its altitude, moving
            self._state[7:10] = scenario.initial_vel_ned_m_s
            self._state[12] = -scenario.initial_alt_m
        self._index = 0

    @property
    def index(self) -> int:
        """Number of samples produced so far (the next sample is at ``index / rate_hz``)."""
        return self._index

    def advance(self, n: int) -> TruthChunk:
        i = np.arange(self._index, self._index + n + 1, dtype=np.float64)
        t = i / self.rate_hz
        cmds = np.ascontiguousarray(self.scenario.commands(t))
        q_cmd = from_euler_rad(cmds[:, 0], cmds[:, 1], cmds[:, 2])
        # the command's own body rate: rotation from one commanded attitude to the next
        rate_ff = quat.to_rotation_vector(quat.multiply(quat.conjugate(q_cmd[:-1]), q_cmd[1:])) / self.dt_s
        out = np.empty((n, TRUTH_LEN))
        self._kernel(self._state, self._params, cmds[:-1], np.ascontiguousarray(q_cmd[:-1]),
                     np.ascontiguousarray(rate_ff), self.dt_s, out)
        self._index += n
        return TruthChunk(t_s=t[:n], rows=out)
