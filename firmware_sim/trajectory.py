r"""Scenarios: what the simulated quadcopter is commanded to do, and its environment.

A scenario is a seeded, deterministic *plan*: piecewise-linear command
channels over time (commanded roll, pitch, yaw, altitude, thrust override,
rate-mode body rates, on-ground flag) that :mod:`firmware_sim.vehicle` follows
through its own dynamics, plus the environment the sensors see (temperature,
magnetic disturbance, motor vibration).  Plans are built lazily by a generator,
manoeuvre by manoeuvre, so a scenario runs for any duration (also "forever" in
a live run) and the same seed gives the same plan however it is chunked.

Command channels (:data:`CHANNELS`), all functions of time since boot:

========== ======= ==========================================================
roll       rad     commanded roll  (aerospace Z-Y-X Euler, NED)
pitch      rad     commanded pitch (negative = nose down = accelerate forward)
yaw        rad     commanded yaw from true north, unwrapped
alt        m       commanded altitude above home (up positive)
thrust     m/s²    thrust override per unit mass; 0 = altitude controller
rate_mode  0/1     1 = follow the body-rate command (flips), ignore attitude
p, q, r    rad/s   body-rate command in rate mode
grounded   0/1     1 = standing on the ground (held, no dynamics)
========== ======= ==========================================================

Every scenario starts on the ground (the filters see a rest phase first),
except that ``rest`` never leaves it, and unless it is made with
``start_in_motion`` (no rest period: flying from t = 0).  See ``docs/firmware_sim.md`` for what
each scenario stresses.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CHANNELS",
    "SCENARIOS",
    "SCENARIO_DESCRIPTIONS",
    "Scenario",
    "VibrationSpec",
    "Harmonic",
    "make_scenario",
    "START_IN_MOTION_ALT_M",
]

Array = NDArray[np.float64]

CHANNELS: tuple[str, ...] = ("roll", "pitch", "yaw", "alt", "thrust", "rate_mode", "p", "q", "r", "grounded")
_IDX = {name: i for i, name in enumerate(CHANNELS)}
_STEP_S = 1e-6  # width of a step change in the piecewise-linear plan
_DEG = math.pi / 180.0
G = 9.80665


@dataclass(frozen=True)
class Harmonic:
    """One motor-vibration line: ``multiple`` × the motor rotation frequency.

    Amplitudes are peaks at the IMU, per body axis: ``accel_m_s2`` (m/s²) and
    ``gyro_rad_s`` (rad/s).
    """

    multiple: float
    accel_m_s2: tuple[float, float, float]
    gyro_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class VibrationSpec:
    """Motor vibration seen by the IMU (added to the sensor, not to the rigid-body truth).

    The motor rotation frequency is ``motor_hz_at_hover`` × sqrt(thrust / g)
    (rotor thrust ∝ speed²); each harmonic is a sinusoid at a multiple of it,
    evaluated at the IMU's own sample instants, so lines above half the sample
    rate alias into the passband exactly as on a real autopilot.
    """

    motor_hz_at_hover: float
    harmonics: tuple[Harmonic, ...]


@dataclass
class _Plan:
    """Piecewise-linear command channels built manoeuvre by manoeuvre."""

    values: dict[str, float]
    t_s: float = 0.0
    in_motion: bool = False  # started airborne: no ground phase, no take-off
    points: dict[str, tuple[list[float], list[float]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for ch in CHANNELS:
            self.points[ch] = ([0.0], [float(self.values[ch])])

    def _extend_hold(self, ch: str) -> None:
        ts, vs = self.points[ch]
        if ts[-1] < self.t_s:
            ts.append(self.t_s)
            vs.append(vs[-1])

    def hold(self, dt_s: float) -> None:
        """Keep every channel where it is for ``dt_s``."""
        self.t_s += max(float(dt_s), 0.0)

    def ramp(self, dt_s: float, **targets: float) -> None:
        """Move the named channels linearly to their targets over ``dt_s``; others hold."""
        dt_s = max(float(dt_s), 2 * _STEP_S)
        for ch, value in targets.items():
            self._extend_hold(ch)
            ts, vs = self.points[ch]
            ts.append(self.t_s + dt_s)
            vs.append(float(value))
            self.values[ch] = float(value)
        self.t_s += dt_s

    def set(self, **targets: float) -> None:
        """Step the named channels to new values now."""
        for ch, value in targets.items():
            self._extend_hold(ch)
            ts, vs = self.points[ch]
            ts.append(self.t_s + _STEP_S)
            vs.append(float(value))
            self.values[ch] = float(value)
        self.t_s += _STEP_S


# --------------------------------------------------------------------------- scenarios
# Each generator receives a seeded Generator and the plan, appends one manoeuvre
# (or a few) per iteration and yields.  They never end.

PlanBuilder = Callable[[np.random.Generator, _Plan], Iterator[None]]


def _takeoff(plan: _Plan, ground_s: float = 3.0, alt_m: float = 10.0) -> Iterator[None]:
    if plan.in_motion:  # already flying at START_IN_MOTION_ALT_M: go to the scenario's altitude, manoeuvring
        if alt_m != plan.values["alt"]:
            plan.ramp(abs(alt_m - plan.values["alt"]) / 3.0, alt=alt_m)
        yield
        return
    plan.hold(ground_s)
    plan.set(grounded=0.0)
    plan.ramp(0.5, roll=0.0, pitch=0.0)
    plan.ramp(3.0, alt=alt_m)
    plan.hold(2.0)
    yield


def _rest(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    while True:
        plan.hold(10.0)
        yield


def _hover(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    yield from _takeoff(plan)
    while True:
        # small attitude wander, slow turns, gentle altitude changes
        dt = rng.uniform(2.0, 4.0)
        plan.ramp(
            dt,
            roll=rng.normal(0.0, 3.0) * _DEG,
            pitch=rng.normal(0.0, 3.0) * _DEG,
            yaw=plan.values["yaw"] + rng.uniform(-45.0, 45.0) * _DEG,
            alt=float(np.clip(plan.values["alt"] + rng.uniform(-1.5, 1.5), 5.0, 15.0)),
        )
        yield


def _aggressive(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    yield from _takeoff(plan)
    while True:
        kind = rng.choice(["dash", "turn", "spin", "brake"], p=[0.45, 0.25, 0.15, 0.15])
        if kind == "dash":
            # sustained 30–45° tilt in a random direction: accelerates for seconds
            tilt = rng.uniform(30.0, 45.0) * _DEG
            heading = rng.uniform(-math.pi, math.pi)
            plan.ramp(rng.uniform(0.2, 0.5), roll=tilt * math.sin(heading), pitch=-tilt * math.cos(heading))
            plan.hold(rng.uniform(2.0, 4.5))
        elif kind == "turn":
            # fast coordinated turn: banked while yawing at 90–180°/s
            rate = rng.uniform(90.0, 180.0) * _DEG * rng.choice([-1.0, 1.0])
            dt = rng.uniform(1.5, 3.0)
            bank = rng.uniform(25.0, 40.0) * _DEG * math.copysign(1.0, rate)
            plan.ramp(0.3, roll=bank, pitch=-rng.uniform(10.0, 30.0) * _DEG)
            plan.ramp(dt, yaw=plan.values["yaw"] + rate * dt)
        elif kind == "spin":
            # yaw spin, one or two turns at 200–400°/s, level-ish
            turns = float(rng.integers(1, 3))
            rate = rng.uniform(200.0, 400.0) * _DEG
            plan.ramp(0.3, roll=rng.normal(0.0, 5.0) * _DEG, pitch=rng.normal(0.0, 5.0) * _DEG)
            plan.ramp(turns * 2 * math.pi / rate, yaw=plan.values["yaw"] + rng.choice([-1.0, 1.0]) * turns * 2 * math.pi)
        else:
            # hard brake: tilt back against the direction of travel, then level
            plan.ramp(0.3, roll=-0.8 * plan.values["roll"], pitch=-0.8 * plan.values["pitch"])
            plan.hold(rng.uniform(1.0, 2.0))
            plan.ramp(0.4, roll=0.0, pitch=0.0)
            plan.hold(rng.uniform(0.5, 1.0))
        if rng.random() < 0.3:
            plan.ramp(rng.uniform(1.0, 2.0), alt=float(np.clip(plan.values["alt"] + rng.uniform(-5, 5), 5.0, 40.0)))
        yield


def _flips(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    yield from _takeoff(plan, alt_m=20.0)
    while True:
        plan.hold(rng.uniform(2.0, 3.5))
        rate = rng.uniform(600.0, 1000.0) * _DEG * rng.choice([-1.0, 1.0])
        axis = rng.choice(["p", "q"])
        # punch up, then a 360° flip in rate mode at reduced thrust, then recover
        plan.set(thrust=2.0 * G)
        plan.hold(0.4)
        plan.set(thrust=0.6 * G, rate_mode=1.0, **{axis: rate})
        plan.hold(2 * math.pi / abs(rate))
        plan.set(rate_mode=0.0, thrust=0.0, **{axis: 0.0})
        plan.hold(0.5)
        yield


def _highg(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    yield from _takeoff(plan, alt_m=30.0)
    while True:
        kind = rng.choice(["climb", "dive", "brake"])
        if kind == "climb":
            plan.set(thrust=rng.uniform(2.5, 4.0) * G)
            plan.hold(rng.uniform(0.5, 1.2))
            plan.set(thrust=0.0)
        elif kind == "dive":
            plan.set(thrust=rng.uniform(0.2, 0.5) * G)
            plan.hold(rng.uniform(0.6, 1.0))
            plan.set(thrust=2.5 * G)
            plan.hold(0.8)
            plan.set(thrust=0.0)
        else:
            heading = rng.uniform(-math.pi, math.pi)
            tilt = 35.0 * _DEG
            plan.ramp(0.4, roll=tilt * math.sin(heading), pitch=-tilt * math.cos(heading))
            plan.hold(2.5)
            # pitch back hard at 2–3 g total thrust: braking at 1.5–2.5 g horizontal
            brake = rng.uniform(50.0, 60.0) * _DEG
            plan.ramp(0.3, roll=-brake * math.sin(heading), pitch=brake * math.cos(heading))
            plan.set(thrust=rng.uniform(2.0, 3.0) * G)
            plan.hold(rng.uniform(0.6, 1.0))
            plan.set(thrust=0.0)
            plan.ramp(0.4, roll=0.0, pitch=0.0)
        plan.hold(rng.uniform(1.5, 3.0))
        yield


def _gentle(rng: np.random.Generator, plan: _Plan, tilt_deg: float, yaw_deg: float) -> None:
    plan.ramp(
        rng.uniform(2.0, 4.0),
        roll=rng.normal(0.0, tilt_deg) * _DEG,
        pitch=rng.normal(0.0, tilt_deg) * _DEG,
        yaw=plan.values["yaw"] + rng.uniform(-yaw_deg, yaw_deg) * _DEG,
    )
    plan.hold(rng.uniform(0.5, 2.0))


def _magnetic(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    yield from _takeoff(plan)
    while True:
        _gentle(rng, plan, tilt_deg=8.0, yaw_deg=120.0)
        yield


def _mag_anomaly(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    # 10 s on the ground in the anomaly, then hover, climbs and descents with little horizontal acceleration
    yield from _takeoff(plan, ground_s=10.0, alt_m=25.0)
    while True:
        _gentle(rng, plan, tilt_deg=3.0, yaw_deg=60.0)
        if rng.random() < 0.5:
            plan.ramp(rng.uniform(3.0, 6.0), alt=float(np.clip(plan.values["alt"] + rng.uniform(-12, 12), 8.0, 40.0)))
        yield


def _vibration(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    yield from _takeoff(plan)
    while True:
        _gentle(rng, plan, tilt_deg=12.0, yaw_deg=90.0)
        if rng.random() < 0.4:  # throttle changes sweep the aliased lines
            plan.ramp(rng.uniform(1.0, 2.0), alt=float(np.clip(plan.values["alt"] + rng.uniform(-6, 6), 5.0, 30.0)))
        yield


def _temperature(rng: np.random.Generator, plan: _Plan) -> Iterator[None]:
    yield from _takeoff(plan)
    while True:
        _gentle(rng, plan, tilt_deg=6.0, yaw_deg=60.0)
        yield


_BUILDERS: dict[str, PlanBuilder] = {
    "rest": _rest,
    "hover": _hover,
    "aggressive": _aggressive,
    "flips": _flips,
    "highg": _highg,
    "magnetic": _magnetic,
    "mag_anomaly": _mag_anomaly,
    "vibration": _vibration,
    "temperature": _temperature,
}

SCENARIO_DESCRIPTIONS: dict[str, str] = {
    "rest": "on the ground, disarmed, slightly tilted: noise, gyro-bias estimation, initial convergence",
    "hover": "take-off and hover with small attitude wander and slow turns: the baseline",
    "aggressive": (
        "sustained 30-45 deg tilts for seconds, fast banked turns at 90-180 deg/s, yaw spins at "
        "200-400 deg/s, hard braking: the accelerometer reads thrust + rotor drag, not gravity"
    ),
    "flips": "360 deg rolls/pitches at 600-1000 deg/s with thrust punches: rate range, integration, accel useless",
    "highg": "climbs at 2-4 g, dives at 0.2-0.5 g, braking at 2-3 g: accelerometer-norm gating",
    "magnetic": (
        "hover with wide turns; a ferrous structure adds a 35 uT earth-fixed disturbance from 20 s "
        "to 35 s of each minute, and motor currents add a throttle-dependent body-fixed field"
    ),
    "mag_anomaly": (
        "10 s on the ground in a ground-level field anomaly (SIM_MAG_ALY: 8,-6,12 uT NED, 1/8 at 5 m), then "
        "hover, climbs and descents to 8-40 m with little horizontal acceleration while the motor current "
        "adds a body-frame field (SIM_MAG_MOT: 0.4,-0.3,0.8 uT/A, ~15 A in hover)"
    ),
    "vibration": (
        "strong motor vibration whose 3rd harmonic (1185 Hz) aliases to ~15 Hz at the default "
        "1200 Hz sensor rate and sweeps with throttle; accelerometer peaks reach the 16 g clip"
    ),
    "temperature": "gentle flight while the IMU warms from 10 to 50 degC (tau 40 s): temperature-driven gyro-bias drift",
}

SCENARIOS: tuple[str, ...] = tuple(_BUILDERS)

_MILD_VIBRATION = VibrationSpec(
    motor_hz_at_hover=170.0,
    harmonics=(
        Harmonic(1.0, (1.5, 1.5, 3.0), (0.02, 0.02, 0.01)),
        Harmonic(2.0, (0.8, 0.8, 1.5), (0.01, 0.01, 0.005)),
    ),
)
_STRONG_VIBRATION = VibrationSpec(
    motor_hz_at_hover=395.0,
    harmonics=(
        Harmonic(1.0, (25.0, 25.0, 100.0), (0.3, 0.3, 0.15)),
        Harmonic(2.0, (10.0, 10.0, 45.0), (0.2, 0.2, 0.1)),
        Harmonic(3.0, (3.0, 3.0, 4.0), (0.4, 0.4, 0.2)),
    ),
)


@dataclass
class Scenario:
    """A named, seeded scenario: command channels plus environment.

    Build with :func:`make_scenario`.  All methods take arrays of times since
    boot (s) and are deterministic; the plan is extended as far as asked.
    """

    name: str
    seed: int
    ground_attitude_rad: tuple[float, float, float]
    temperature_start_c: float = 25.0
    temperature_end_c: float = 25.0
    temperature_tau_s: float = 40.0
    vibration: VibrationSpec | None = None
    mag_disturbance_ned_ut: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_disturbance_window_s: tuple[float, float] | None = None  # within each minute
    mag_motor_ut_per_g: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_anomaly_ned_ut: tuple[float, float, float] = (0.0, 0.0, 0.0)  # ground level (SIM_MAG_ALY)
    mag_anomaly_height_m: float = 1.0  # where it has decayed to 1/8 (SIM_MAG_ALY_HGT)
    mag_motor_ut_per_a: tuple[float, float, float] = (0.0, 0.0, 0.0)  # body field per amp (SIM_MAG_MOT)
    start_in_motion: bool = False
    initial_alt_m: float = 0.0  # above home, when starting in motion
    initial_vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _plan: _Plan | None = None
    _gen: Iterator[None] | None = None
    _arrays: tuple[tuple[Array, Array], ...] | None = None

    @property
    def description(self) -> str:
        return SCENARIO_DESCRIPTIONS[self.name]

    def _ensure(self, t_s: float) -> None:
        assert self._plan is not None and self._gen is not None
        if self._plan.t_s > t_s + 1.0 and self._arrays is not None:
            return
        while self._plan.t_s <= t_s + 1.0:
            next(self._gen)
        self._arrays = tuple(
            (np.asarray(self._plan.points[ch][0]), np.asarray(self._plan.points[ch][1])) for ch in CHANNELS
        )

    def commands(self, t_s: Array) -> Array:
        """Command channels at times ``t_s`` (s since boot), shape (N, len(CHANNELS))."""
        t = np.asarray(t_s, dtype=np.float64)
        self._ensure(float(t.max()) if t.size else 0.0)
        assert self._arrays is not None
        out = np.empty((t.size, len(CHANNELS)))
        for i in range(len(CHANNELS)):
            ts, vs = self._arrays[i]
            out[:, i] = np.interp(t, ts, vs)
        out[:, _IDX["rate_mode"]] = np.round(out[:, _IDX["rate_mode"]])
        out[:, _IDX["grounded"]] = np.round(out[:, _IDX["grounded"]])
        return out

    def temperature_c(self, t_s: Array) -> Array:
        """IMU die temperature (°C): a first-order warm-up from start to end value."""
        t = np.asarray(t_s, dtype=np.float64)
        span = self.temperature_end_c - self.temperature_start_c
        return self.temperature_start_c + span * (1.0 - np.exp(-t / self.temperature_tau_s))

    def mag_disturbance_ned(self, t_s: Array) -> Array:
        """Earth-fixed magnetic disturbance (µT, NED) at times ``t_s``, shape (N, 3).

        Smooth 2 s raised-cosine onset and release inside the window of each minute.
        """
        t = np.asarray(t_s, dtype=np.float64)
        out = np.zeros((t.size, 3))
        if self.mag_disturbance_window_s is None:
            return out
        start, end = self.mag_disturbance_window_s
        tm = np.mod(t, 60.0)
        edge = 2.0
        w = np.clip(np.minimum(tm - start, end - tm) / edge, 0.0, 1.0)
        w = 0.5 - 0.5 * np.cos(np.pi * w)
        return w[:, None] * np.asarray(self.mag_disturbance_ned_ut)[None, :]


#: the altitude above home (m) at which a scenario started in motion begins
START_IN_MOTION_ALT_M = 10.0


def make_scenario(name: str, seed: int = 0, *, start_in_motion: bool = False) -> Scenario:
    """The scenario ``name`` (one of :data:`SCENARIOS`) with its plan seeded by ``seed``.

    ``start_in_motion``: no rest period: the vehicle is already flying at t = 0 (rotors spinning,
    vibration on, at :data:`START_IN_MOTION_ALT_M` above home with a horizontal velocity of
    2–5 m/s in a random direction drawn from the seed) and the scenario's manoeuvres begin at
    once.  Not for ``rest``.
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown scenario {name!r}; choose one of {', '.join(SCENARIOS)}")
    if start_in_motion and name == "rest":
        raise ValueError("scenario 'rest' cannot start in motion")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5C3]))
    ground = (
        float(rng.normal(0.0, 1.5) * _DEG),
        float(rng.normal(0.0, 1.5) * _DEG),
        float(rng.uniform(-math.pi, math.pi)),
    )
    initial = {ch: 0.0 for ch in CHANNELS}
    initial.update(roll=ground[0], pitch=ground[1], yaw=ground[2], grounded=1.0)
    kwargs: dict[str, object] = {}
    if start_in_motion:
        # a generator of its own: the plan's draws stay those of the scenario started on the ground
        mrng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5C3, 1]))
        speed, course = mrng.uniform(2.0, 5.0), mrng.uniform(-math.pi, math.pi)
        initial.update(grounded=0.0, alt=START_IN_MOTION_ALT_M)
        kwargs.update(start_in_motion=True, initial_alt_m=START_IN_MOTION_ALT_M,
                      initial_vel_ned_m_s=(speed * math.cos(course), speed * math.sin(course), 0.0))
    plan = _Plan(values=initial, in_motion=start_in_motion)
    if name != "rest":
        kwargs["vibration"] = _MILD_VIBRATION
    if name == "vibration":
        kwargs["vibration"] = _STRONG_VIBRATION
    elif name == "temperature":
        kwargs.update(temperature_start_c=10.0, temperature_end_c=50.0, temperature_tau_s=40.0)
    elif name == "magnetic":
        kwargs.update(
            mag_disturbance_ned_ut=(25.0, -15.0, 20.0),
            mag_disturbance_window_s=(20.0, 35.0),
            mag_motor_ut_per_g=(4.0, -3.0, 10.0),
        )
    elif name == "mag_anomaly":
        kwargs.update(
            mag_anomaly_ned_ut=(8.0, -6.0, 12.0),
            mag_anomaly_height_m=5.0,
            mag_motor_ut_per_a=(0.4, -0.3, 0.8),
        )
    sc = Scenario(name=name, seed=int(seed), ground_attitude_rad=ground, **kwargs)  # type: ignore[arg-type]
    sc._plan = plan
    sc._gen = _BUILDERS[name](rng, plan)
    return sc
