r"""The sample chain over arrays: from decoded IMU samples to the filter's input rows.

The steps every log reader shares after decoding (telemetry logs in
:mod:`mavahrs.evaluation.tlogdata`, DataFlash and ULog in :mod:`mavahrs.logs`),
each the array form of the live pipeline's per-sample step
(:mod:`mavahrs.service.pipeline`):

* :func:`timeline_over_arrays` — the timeline step (:func:`mavahrs.ingest.timeline.timeline_step`,
  the pipeline's per sample) in its compiled loop over the samples (dt, gaps, drops; a reboot
  or a corrected time stamp raises :class:`FastPathUnsupported`: the per-message pipeline then
  replays the log); :func:`onboard_timeline` — the same over an onboard log (DataFlash, ULog),
  every forward jump beyond the gap limit confirmed by the next sample;
* :func:`select_over_arrays` — the IMU selector's step (:func:`mavahrs.sensors.imu_select.select_step`,
  the pipeline's per sample) in its compiled loop over every instance's samples in order;
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

import dataclasses
import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.filters.layout import IN_WIDTH, OUT_WIDTH
from mavahrs.ingest.timeline import (
    K_DUPLICATE,
    K_GAP,
    K_HELD,
    K_REBOOT,
    K_REORDERED,
    K_STALE,
    TimelineSettings,
    new_state,
    timeline_loop,
)
from mavahrs.sensors.imu_select import G_CHANGES_TOTAL, select_loop
from mavahrs.sensors.imu_select import new_state as selector_state
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

__all__ = ["FastPathUnsupported", "PreparedInputs", "si_rows", "timeline_over_arrays", "onboard_timeline",
           "select_over_arrays"]

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

    def duration_s(self) -> float:
        """From the first to the last sample, s, summed over the autopilot's boots where it rebooted during the
        log (the boot clock goes back; until user7 a reboot's log said e.g. 5.9 s for 17 s of samples)."""
        return self._span_us()[0] * 1e-6

    def _span_us(self) -> tuple[float, int]:
        """(the samples' span summed over the boots, µs; the number of boots)."""
        if self.n < 2:
            return 0.0, 1
        t = self.t_us.astype(np.int64)
        starts = np.concatenate(([0], np.flatnonzero(t[1:] < t[:-1]) + 1))
        ends = np.concatenate((starts[1:] - 1, [t.size - 1]))
        return float(np.sum(t[ends] - t[starts])), int(starts.size)

    def rate_hz(self) -> float:
        """Mean sample rate reaching the filter over the log, within each boot (0 if fewer than two samples)."""
        if self.n < 2:
            return 0.0
        span, boots = self._span_us()
        return (self.n - boots) / span * 1e6 if span > 0 else 0.0


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


def timeline_over_arrays(
    t_us: NDArray[np.int64], now_us: NDArray[np.int64], gyro: Array, accel: Array, settings: TimelineSettings
) -> tuple[NDArray[np.bool_], Array]:
    """Which samples the pipeline's timeline passes, and their dt (s): the timeline step over the samples.

    :func:`mavahrs.ingest.timeline.timeline_loop` — the step the pipeline calls per sample, with the
    arguments the pipeline gives it (raw time, receive time, the gyro+accel values as the
    sample key) — in a compiled loop from a new stream with ``settings``.  Dropped samples
    (duplicate, stale, reordered, held) are not kept; a gap reaches the filters as a dt longer
    than any filter's ``max_gap_s`` (:data:`_GAP_DT_S`), as the pipeline gives it, so they
    re-initialise instead of integrating one gyro sample across it; the first sample's dt is NaN.

    Raises:
        FastPathUnsupported: the autopilot rebooted, or the timeline corrects time stamps
            (``time_boot_ms`` wrap-around): the per-message pipeline then replays the log.
    """
    n = t_us.shape[0]
    kind = np.empty(n, np.int64)
    t = np.empty(n, np.int64)
    dt = np.empty(n)
    # every argument C-contiguous: one compiled signature for every caller (a single-instance tlog's columns
    # are views into its rows), the one `mavahrs warm-up` compiles
    timeline_loop(*new_state(settings), np.ascontiguousarray(t_us, np.int64),
                  np.ascontiguousarray(now_us, np.int64), np.ascontiguousarray(gyro, np.float64),
                  np.ascontiguousarray(accel, np.float64), kind, t, dt)  # fmt: skip
    keep = (kind != K_DUPLICATE) & (kind != K_STALE) & (kind != K_REORDERED) & (kind != K_HELD)
    reboot = np.flatnonzero(kind[1:] == K_REBOOT)
    moved = np.flatnonzero(keep & (t != t_us))
    if reboot.size and (not moved.size or reboot[0] + 1 < moved[0]):
        raise FastPathUnsupported("the autopilot rebooted during the log")
    if moved.size:
        raise FastPathUnsupported("the timeline corrects timestamps (wrap-around)")
    gap = kind == K_GAP
    if gap.any():
        dt[gap] = np.maximum(dt[gap], _GAP_DT_S)
    dt[~keep] = _NAN
    return keep, dt


def select_over_arrays(settings: Any, source: NDArray[np.int64], imu: NDArray[np.int64], t_us: NDArray[np.int64],
                       gyro: Array, accel: Array, saturated: NDArray[np.bool_], use: NDArray[np.bool_] | None = None
                       ) -> tuple[NDArray[np.bool_], int]:  # fmt: skip
    """Which samples the pipeline's IMU selector feeds to the filter, and how many times it chose an instance.

    :func:`mavahrs.sensors.imu_select.select_loop` — the step the pipeline calls per sample — from a new
    selector with ``settings`` (:class:`~mavahrs.sensors.imu_select.ImuSelectSettings`) over every
    instance's samples in the order given (the pipeline's: as received; an onboard log's: by time).
    ``source``: a number per message type (two types carrying one instance: the later is refused while
    the first speaks); ``imu``: the instance; ``saturated``: a gyro or accelerometer axis at its limit;
    ``use``: whether the message is a sample at all (None: every one).
    """
    n = t_us.shape[0]
    feed = np.zeros(n, np.bool_)
    st, fs = selector_state(settings)
    select_loop(st, fs, np.ascontiguousarray(source, np.int64), np.ascontiguousarray(imu, np.int64),
                np.ascontiguousarray(t_us, np.int64), np.ascontiguousarray(gyro, np.float64),
                np.ascontiguousarray(accel, np.float64), np.ascontiguousarray(saturated, np.bool_),
                np.ones(n, np.bool_) if use is None else np.ascontiguousarray(use, np.bool_), feed)  # fmt: skip
    return feed, int(st[G_CHANGES_TOTAL])


def onboard_timeline(path: Any, t_us: NDArray[np.int64], gyro: Array, accel: Array, settings: TimelineSettings
                     ) -> tuple[NDArray[np.bool_], Array]:  # fmt: skip
    """:func:`timeline_over_arrays` over an onboard log's samples (DataFlash, ULog), stamps on the log's clock.

    The same step with the same settings, except that every forward jump beyond the gap limit needs
    the next sample to confirm it (``jump_confirm_s`` = ``max_gap_s``): an onboard log has no link
    whose outage would explain one, so a lone damaged stamp ahead of its neighbours is dropped
    instead of re-initialising the filters (and the samples after it, back on the clock, dropped
    as late); a real gap (a logger dropout) reaches the filters at its second sample.  The sample's
    stamp is its receive time.

    Raises:
        DataError: the clock starts again inside the log (a reboot), or wraps.
    """
    from mavahrs.errors import DataError

    s = dataclasses.replace(settings, jump_confirm_s=settings.max_gap_s)
    try:
        return timeline_over_arrays(t_us, t_us, gyro, accel, s)
    except FastPathUnsupported as exc:
        raise DataError(f"{path}: {exc}") from None


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
    # one contiguous column per axis: the signature a tlog's HIGHRES_IMU compiles (and `mavahrs warm-up`)
    g = np.ascontiguousarray(np.asarray(gyro_rad_s, np.float64).T)
    a = np.ascontiguousarray(np.asarray(accel_m_s2, np.float64).T)
    zeros = np.zeros(n)
    upd = np.full(n, HIGHRES_GYRO_BITS | HIGHRES_ACCEL_BITS, np.int64)
    scale_float_rows(g[0], g[1], g[2], a[0], a[1], a[2], zeros, zeros, zeros, upd, c, rows, codes)
    sat = codes & 7
    inv = (codes >> INVALID_SHIFT) & 7
    if accel_clipped is not None:
        sat = sat | np.where(accel_clipped, ACCEL, 0)
    blank_unusable_rows(rows, sat, inv)
    return rows, sat, inv
