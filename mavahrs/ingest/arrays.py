r"""The sample chain over arrays: from decoded IMU samples to the filter's input rows.

The steps every log reader shares after decoding (telemetry logs in
:mod:`mavahrs.evaluation.tlogdata`, DataFlash and ULog in :mod:`mavahrs.logs`),
each the array form of the live pipeline's per-sample step
(:mod:`mavahrs.service.pipeline`):

* :func:`_timeline` — :class:`mavahrs.protocol.timeline.Timeline` over the samples
  (dt, gaps, drops; a reboot or a corrected time stamp raises
  :class:`FastPathUnsupported`: the per-message pipeline then replays the log);
* calibration — :meth:`mavahrs.sensors.calibration.Calibrator.apply_rows`, the compiled
  per-row step (:func:`~mavahrs.sensors.calibration.calibrate_row`) over all rows;
* :func:`si_rows` — the scaling step (:func:`~mavahrs.sensors.scaling.scale_float_row`) and the
  row step (:func:`~mavahrs.sensors.sample.blank_unusable`) over samples a log already holds in SI
  units (DataFlash IMU, ULog sensor_combined / vehicle_imu);
* :class:`PreparedInputs` — the rows in :mod:`mavahrs.filters.layout`'s layout,
  their times and what the readers found, and :meth:`PreparedInputs.run_filter`,
  the filter run over them as the pipeline runs it (reference seeding, sensor delay).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.filters.layout import IN_WIDTH, OUT_WIDTH
from mavahrs.sensors.sample import ACCEL, blank_unusable_rows
from mavahrs.sensors.scaling import (
    C_KA,
    C_KG,
    HIGHRES_ACCEL_BITS,
    HIGHRES_GYRO_BITS,
    INVALID_SHIFT,
    scale_constants,
    scale_float_rows,
)

__all__ = ["FastPathUnsupported", "PreparedInputs", "si_rows"]

Array = NDArray[np.float64]
_NAN = math.nan


class FastPathUnsupported(Exception):
    """The log needs the pipeline's per-message decisions (the reason says which)."""


@dataclass
class PreparedInputs:
    """The filter's input rows for a log, as the pipeline would build them.

    Attributes:
        rows: (M, IN_WIDTH) input rows (dt, gyro, accel, mag, velocity, its age).
        t_us: (M,) sample time, µs of the autopilot's clock.
        frame_pos: (M,) position of the IMU message in :class:`TlogData` order.
        tlog_us: (M,) the tlog timestamp of that message.
        temperature_c: (M,) IMU temperature (NaN when not sent).
        declination_rad: (M,) declination applied to the outputs at each sample.
        message: the IMU message type fed; instance: its instance number.
        source: (system, component) of the autopilot; profile: scaling profile name.
        engine: ``fast`` (this module) or ``pipeline`` (message by message).
        notes: things the user should know (absent instances, low rate …).
        counts: samples seen / fed / dropped by reason.
        velocity_source: the ``velocity_source`` setting in effect (``auto``,
            ``auto, receiver only`` with the monitor's
            ``receiver_velocity_only``, a named source, ``none``).
        velocity_fixes: GNSS velocity fixes used, per message (in the
            preference order; a fix after the last fed sample included).
    """

    rows: Array
    t_us: NDArray[np.int64]
    frame_pos: NDArray[np.int64]
    tlog_us: NDArray[np.int64]
    temperature_c: Array
    declination_rad: Array
    message: str
    instance: int
    source: tuple[int, int]
    profile: str
    engine: str = "fast"
    notes: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    velocity_source: str = "auto"
    velocity_fixes: dict[str, int] = field(default_factory=dict)
    #: (sample index, field strength µT, inclination rad): the pipeline seeds the filter's
    #: magnetometer rejection (``set_mag_reference``) before that sample
    mag_reference_events: list[tuple[int, float, float]] = field(default_factory=list)
    #: the IMU data's delay behind its stamps (the profile's ``delay_s``), given to filters that use it
    sensor_delay_s: float = 0.0
    #: the samples are an autopilot's stream (every log format): ``best`` is then the ESKF in every
    #: condition, as in the daemon (``Pipeline._set_profile`` → ``set_vehicle_stream``)
    vehicle_stream: bool = False
    #: the vehicle is a multirotor (its HEARTBEAT type, the firmware, MAV_TYPE): the ESKF's rotor-drag
    #: measurement is on, as in the daemon (``Pipeline._on_heartbeat`` → ``set_multirotor``)
    multirotor: bool = False

    def run_filter(self, f: Any, a: int = 0, b: int | None = None, out: Array | None = None) -> Array:
        """Run filter ``f`` over rows ``a:b`` as the pipeline would (reference seeding included)."""
        b = self.n if b is None else b
        if out is None:
            out = np.empty((b - a, OUT_WIDTH))
        configure_filter(f, self.sensor_delay_s, self.vehicle_stream, self.multirotor)
        cuts = [a] + sorted({i for i, _, _ in self.mag_reference_events if a < i < b}) + [b]
        for lo, hi in itertools.pairwise(cuts):
            for i, norm, dip in self.mag_reference_events:
                if i == lo or (lo == 0 and i <= 0):
                    f.set_mag_reference(norm, dip)
            if hi > lo:
                f.run(self.rows[lo:hi], out[lo - a : hi - a])
        return out

    @property
    def n(self) -> int:
        return int(self.t_us.shape[0])

    def rate_hz(self) -> float:
        """Mean sample rate reaching the filter over the log (0 if fewer than two samples)."""
        if self.n < 2:
            return 0.0
        span = float(self.t_us[-1] - self.t_us[0])
        return (self.n - 1) / span * 1e6 if span > 0 else 0.0


def configure_filter(f: Any, sensor_delay_s: float, vehicle_stream: bool, multirotor: bool) -> None:
    """Tell filter ``f`` what the daemon's pipeline tells it once it knows the autopilot.

    The IMU data's delay behind its stamps (``set_sensor_delay``, from the profile), that the input is
    an autopilot's stream (``set_vehicle_stream``) and that the vehicle is a multirotor
    (``set_multirotor``): a replay of a log then runs each filter as the daemon did on that flight.
    Filters without the method ignore it.
    """
    set_delay = getattr(f, "set_sensor_delay", None)
    if set_delay is not None:
        set_delay(float(sensor_delay_s))
    if vehicle_stream and hasattr(f, "set_vehicle_stream"):
        f.set_vehicle_stream()
    if multirotor and hasattr(f, "set_multirotor"):
        f.set_multirotor()


def _velocity_setting(s: Any) -> str:
    """The ``velocity_source`` in effect, as the replay header names it."""
    v = str(s.effective_velocity_source)
    return f"{v}, receiver only" if v == "auto" and s.monitor.receiver_velocity_only else v


#: dt given to the filters for a timeline gap: beyond every filter's max_gap_s (finite, so not "invalid")
_GAP_DT_S = 1.0e6


def _timeline(
    t_us: NDArray[np.int64], now_us: NDArray[np.int64], gyro: Array, accel: Array, settings: Any
) -> tuple[NDArray[np.bool_], Array]:
    """Which samples the pipeline's timeline passes, and their dt (s).

    Runs :class:`mavahrs.protocol.timeline.Timeline` — with the arguments the
    pipeline gives it (raw time, receive time, the gyro+accel values as the
    sample key) — sample by sample, unless the timestamps strictly increase
    by no more than the gap limit: then every event is ``ok`` with
    dt = Δt, which the timeline itself confirms on the first samples.
    """

    def key(i: int) -> tuple[float, ...]:  # Pipeline: the scaled v[2:8]
        return (*gyro[i].tolist(), *accel[i].tolist())

    from mavahrs.protocol.timeline import DROP_KINDS, GAP, OK, REBOOT, Timeline

    n = t_us.shape[0]
    keep = np.ones(n, bool)
    dt = np.full(n, _NAN)
    if n == 0:
        return keep, dt
    d = np.diff(t_us)
    max_gap_us = int(settings.timeline.max_gap_s * 1e6)
    simple = bool(np.all(d > 0)) and not bool(np.any(d > max_gap_us))
    if simple:
        tl = Timeline(settings.timeline)
        for i in range(min(n, 64)):  # the timeline's own verdict on a prefix: plain "ok"
            ev = tl.push(int(t_us[i]), int(now_us[i]), key(i))
            if i and (ev.kind != OK or ev.t_us != t_us[i] or ev.dt_s != (t_us[i] - t_us[i - 1]) * 1e-6):
                simple = False
                break
    if simple:
        dt[1:] = d * 1e-6
        return keep, dt
    tl = Timeline(settings.timeline)
    for i in range(n):
        ev = tl.push(int(t_us[i]), int(now_us[i]), key(i))
        if ev.kind == REBOOT and i:
            raise FastPathUnsupported("the autopilot rebooted during the log")
        if ev.kind in DROP_KINDS:
            keep[i] = False
            continue
        if ev.t_us != t_us[i]:
            raise FastPathUnsupported("the timeline corrects timestamps (wrap-around)")
        # As the pipeline does: a gap reaches the filter as a dt longer than any filter's
        # max_gap_s, so it re-initialises instead of integrating one gyro sample across it.
        dt[i] = max(ev.dt_s, _GAP_DT_S) if ev.kind == GAP else ev.dt_s
    return keep, dt


def si_rows(
    gyro_rad_s: Array, accel_m_s2: Array, ms: Any, scaling: Any, accel_clipped: NDArray[np.bool_] | None = None
) -> tuple[Array, NDArray[np.int64], NDArray[np.int64]]:
    """Filter input rows (dt NaN, no magnetometer) of IMU samples already in SI units: (rows, saturated, invalid).

    The scaling step of float-field messages with unit factors 1
    (:func:`~mavahrs.sensors.scaling.scale_float_row`: saturated at the profile
    ``ms``'s full scale × ``saturation_fraction``, invalid beyond × ``implausible_factor``
    or non-finite, as ``scaling`` says), an accelerometer the log marks clipped saturated
    too, then the row step's rule (:func:`~mavahrs.sensors.sample.blank_unusable`).
    """
    n = gyro_rad_s.shape[0]
    c = scale_constants(ms, scaling)
    c[C_KG] = c[C_KA] = 1.0  # already rad/s and m/s²
    rows = np.full((n, IN_WIDTH), _NAN)
    codes = np.empty(n, np.int64)
    g = np.ascontiguousarray(gyro_rad_s, np.float64)
    a = np.ascontiguousarray(accel_m_s2, np.float64)
    zeros = np.zeros(n)
    upd = np.full(n, HIGHRES_GYRO_BITS | HIGHRES_ACCEL_BITS, np.int64)
    scale_float_rows(g[:, 0], g[:, 1], g[:, 2], a[:, 0], a[:, 1], a[:, 2], zeros, zeros, zeros, upd, c, rows, codes)
    sat = codes & 7
    inv = (codes >> INVALID_SHIFT) & 7
    if accel_clipped is not None:
        sat = sat | np.where(accel_clipped, ACCEL, 0)
    blank_unusable_rows(rows, sat, inv)
    return rows, sat, inv
