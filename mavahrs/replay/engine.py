r"""Replay a flight log through the filters exactly as the daemon would have run them.

:func:`replay` reads a tlog, builds the filter inputs with the daemon's own
decoding, scaling, IMU selection, timing and calibration, runs one or more
filters and returns, per IMU sample, each filter's attitude and diagnostics —
plus the ATTITUDE_QUATERNION frames the daemon would have sent (vehicle
system id, component 191 (+1 per further filter), ``time_boot_ms`` of the IMU
sample, body rates = gyro − bias, at ``out_rate_hz`` of sample time, 0 = every
sample).  Writers put them into a CSV (one row per IMU sample, flushed as it
goes), a copy of the tlog with the frames inserted after the IMU message they
were computed from, and a plot; :func:`compare` scores them against what the
log already holds (the autopilot's ATTITUDE and AHRS2, the simulator's
SIM_STATE/SIMSTATE/HIL_STATE_QUATERNION truth).

Two engines, one result:

* ``pipeline`` — every message through :class:`mavahrs.service.pipeline.Pipeline`,
  the daemon's functional core (the reference; needed for fail-over between
  live IMU instances and autopilot reboots);
* ``fast`` — the log decoded in bulk (:mod:`mavahrs.evaluation.tlogdata`) and
  each filter run over all samples at once through its compiled batch path.
  It mirrors the pipeline's per-message logic with numpy and refuses logs it
  cannot mirror (``auto`` falls back to ``pipeline``); a test checks both give
  identical attitudes and identical frames.

:func:`stream` presents the replay to a ground station as a vehicle (see its
docstring): QGroundControl draws only an autopilot's attitude on its HUD.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.evaluation.tlogdata import (
    FastPathUnsupported,
    PreparedInputs,
    TlogData,
    decimal_year_of_log,
    interpolate_attitude,
    prepare_inputs,
    read_tlog_data,
    references_with_boots,
    resolve_source,
    run_pipelines,
    sample_boots,
)
from mavahrs.filters.jit import kernel
from mavahrs.filters.layout import (
    FLAG_MAG_INVALID,
    FLAG_NOT_INITIALISED,
    IN_GYRO,
    OUT_ACCEL_WEIGHT,
    OUT_BIAS,
    OUT_FLAGS,
    OUT_GAIN,
    OUT_MAG_WEIGHT,
    OUT_Q,
    OUT_WIDTH,
)
from mavahrs.logs import autopilot_reference, is_truth

__all__ = [
    "ReplaySettings",
    "FilterTrack",
    "ReplayResult",
    "ComparisonRow",
    "replay",
    "format_second_opinion",
    "judged_samples",
    "plot_second_opinion",
    "compare",
    "attitude_at_reference",
    "format_comparison",
    "format_velocity",
    "write_tlog",
    "plot_replay",
    "csv_columns",
    "LOW_RATE_HZ",
    "stream",
    "StreamSettings",
    "gap_note",
    "ReplayInterrupted",
]

log = logging.getLogger("mavahrs.replay")
Array = NDArray[np.float64]

#: Below this many samples per second, attitude filtering is not meaningful.
LOW_RATE_HZ = 50.0
# samples per fast-path block: the CSV is written and flushed per block, and Ctrl-C keeps every
# finished block.  Not slower than 131 072-sample blocks: the 400 Hz SITL log with all six filters
# and --csv filtered in 0.35–0.45 s against 0.52–0.74 s (more of the CSV overlaps the filtering).
_CHUNK = 16_384


class ReplayInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`replay`: what was computed before it is kept.

    Attributes:
        result: the replay of the samples filtered before the interrupt (every
            filter, the same samples; no references), or None when it came
            while the log was being read.
        fraction: of the fed samples, the part filtered (0…1).
        stage: ``"preparing the samples"`` or ``"filtering"``.
        csv_path, csv_rows: the CSV and the rows it holds (all flushed and synced).
    """

    def __init__(self, result: ReplayResult | None, fraction: float, stage: str) -> None:
        super().__init__(f"interrupted while {stage}")
        self.result = result
        self.fraction = fraction
        self.stage = stage
        self.csv_path: str | None = None
        self.csv_rows = 0


@dataclass(frozen=True)
class ReplaySettings:
    """What :func:`replay` does.

    Attributes:
        filters: filter names (``madgwick``, ``mahony``, ``complementary``,
            ``gyroplatform``, ``best``); the first gets component 191, the
            next 192, …
        pipeline: the daemon's pipeline settings (IMU instance, profile,
            calibration, out-rate, system id …); its ``filter_name`` is
            replaced by each of ``filters``.
        filter_settings: settings per filter name (defaults when absent).
        start_s, end_s: replay only the IMU messages in this window, seconds
            from the log's first record.
        engine: ``auto`` (fast when it can mirror the log, else pipeline),
            ``fast`` or ``pipeline``.
        monitor_rate_hz: the rate, Hz of sample time, of our attitudes the second opinion judges. The
            daemon's monitor judges each ATTITUDE_QUATERNION it publishes, at ``PipelineSettings.out_rate_hz``;
            the replay's own output rate (``pipeline``'s, every sample by default) is for its tlog and CSV.
            None (default) = the daemon's: ``pipeline.out_rate_hz`` where ``pipeline`` is given, else
            ``PipelineSettings().out_rate_hz`` (50 Hz); 0 = every sample.  ``mavahrs replay`` passes the
            daemon's rate of its ``--config`` (or the default), whatever ``--out-rate`` says.  (Until user7 the
            replay judged every sample by default: on the PX4 SIH .ulg its WARNING came 4 ms before the
            daemon's and ``mavahrs audit``'s.)
    """

    filters: tuple[str, ...] = ("best",)
    pipeline: Any = None
    filter_settings: Mapping[str, Any] = field(default_factory=dict)
    start_s: float | None = None
    end_s: float | None = None
    engine: str = "auto"
    monitor_rate_hz: float | None = None

    def __post_init__(self) -> None:
        from mavahrs.filters import ALIASES, NAMES

        if not self.filters:
            raise ValueError("replay needs at least one filter")
        for name in self.filters:
            if name not in NAMES + ALIASES:
                raise ValueError(f"unknown filter {name!r}; choose from {', '.join(NAMES + ALIASES)}")
        if len(set(self.filters)) != len(self.filters):
            raise ValueError("each filter may be replayed once")
        if self.engine not in ("auto", "fast", "pipeline"):
            raise ValueError(f"engine must be auto, fast or pipeline, got {self.engine!r}")
        if self.start_s is not None and self.end_s is not None and self.end_s <= self.start_s:
            raise ValueError(f"--end ({self.end_s}) must be after --start ({self.start_s})")
        if self.monitor_rate_hz is not None and not (math.isfinite(self.monitor_rate_hz) and self.monitor_rate_hz >= 0):
            raise ValueError(f"monitor_rate_hz must be >= 0 Hz (0: every sample), got {self.monitor_rate_hz!r}")

    def pipeline_settings(self) -> Any:
        from mavahrs.service.pipeline import PipelineSettings

        return self.pipeline if self.pipeline is not None else PipelineSettings(out_rate_hz=0.0)

    def judged_rate_hz(self) -> float:
        """The rate of the attitudes the second opinion judges, Hz of sample time (``monitor_rate_hz``
        resolved: the daemon's output rate unless set; 0 = every sample)."""
        from mavahrs.service.pipeline import PipelineSettings

        if self.monitor_rate_hz is not None:
            return float(self.monitor_rate_hz)
        return float((self.pipeline if self.pipeline is not None else PipelineSettings()).out_rate_hz)


@dataclass
class FilterTrack:
    """One filter's replay.

    Attributes:
        name: filter name; component_id: the component its frames carry.
        out: (M, OUT_WIDTH) filter output rows, with ``OUT_Q`` replaced by
            the attitude as sent (declination applied: true north when known).
        sent: (M,) an ATTITUDE_QUATERNION was sent for this sample.
        frames: the encoded frames, in sample order (one per sent sample, two
            with ``send_attitude_euler``), or None until :meth:`ReplayResult.frames` encodes them.
        magnetometer: the filter's magnetometer state at the end (``mag_status``: the learnt model or
            the trust in the last reading, the learnt declination), None for filters without one.
    """

    name: str
    component_id: int
    out: Array
    sent: NDArray[np.bool_]
    frames: list[bytes] | None = None
    magnetometer: dict[str, Any] | None = None


@dataclass
class ReplayResult:
    """Everything a replay produced.  ``inputs.rows`` are the filter inputs, one per fed sample."""

    path: str
    inputs: PreparedInputs
    tracks: dict[str, FilterTrack]
    system_id: int
    settings: ReplaySettings
    references: dict[str, tuple[Array, Array]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: per reference, the autopilot's boot of each of its samples (:func:`~mavahrs.evaluation.tlogdata.sample_boots`;
    #: absent = all of the first): a tlog in which the autopilot rebooted is compared boot by boot
    reference_boots: dict[str, NDArray[np.int64]] = field(default_factory=dict, repr=False)
    #: the decoded log (:class:`~mavahrs.evaluation.tlogdata.TlogData`): HEARTBEATs, positions … for summaries
    tlog: TlogData | None = field(default=None, repr=False)
    #: an onboard log's reading (:class:`~mavahrs.logs.LogInputs`: what was found, parameters); None for a tlog
    log: Any = field(default=None, repr=False)
    #: the second-opinion monitor over this replay once judged (:func:`_monitor_of`), for the printed second
    #: opinion and its chart alike: [] until then, else [(series, reference, filter) or None]
    second_opinion: list[Any] = field(default_factory=list, repr=False, compare=False)

    @property
    def format(self) -> str:
        """The log's format: ``tlog``, ``dataflash`` or ``ulog``."""
        return "tlog" if self.log is None else str(self.log.format)

    @property
    def engine(self) -> str:
        return self.inputs.engine

    def frames(self, name: str) -> list[bytes]:
        """The frames the daemon would have sent for filter ``name`` (encoded on first use)."""
        tr = self.tracks[name]
        if tr.frames is None:
            tr.frames = _encode_frames(self, tr)
        return tr.frames


# --------------------------------------------------------------------------- the reference path


# --------------------------------------------------------------------------- the fast path


@kernel
def _out_rate(t_us, flags, period_us, tol_us, state, sent):  # type: ignore[no-untyped-def]
    """Pipeline._filter_sample's output-rate rule; ``state[0]`` = next output time (−1 = none yet)."""
    nxt = state[0]
    for i in range(t_us.shape[0]):
        if int(flags[i]) & FLAG_NOT_INITIALISED:
            continue
        t = t_us[i]
        if period_us > 0:
            if nxt >= 0 and t < nxt - tol_us:
                continue
            nxt = (nxt if nxt >= 0 else t) + period_us
            if nxt <= t:
                nxt = t + period_us
        sent[i] = True
    state[0] = nxt


def _out_rate_by_boot(t_us: NDArray[np.int64], flags: Array, period_us: int, tol_us: int, state: NDArray[np.int64],
                      sent: NDArray[np.bool_]) -> None:  # fmt: skip
    """:func:`_out_rate` over samples that may span reboots of the autopilot: the rule starts again wherever the
    boot clock goes back, also from one call to the next (``state`` = [next output time, last sample time]), as
    the pipeline's output clock does at a reboot (``Pipeline._on_reboot``).  (Until user7 the replay carried the
    first boot's next output time on: after a reboot no sample counted as sent.)"""
    n = t_us.shape[0]
    if n == 0:
        return
    cut = [0, *(np.flatnonzero(t_us[1:] < t_us[:-1]) + 1).tolist(), n]
    for j, (a, b) in enumerate(zip(cut[:-1], cut[1:], strict=True)):
        if j > 0 or (state[1] >= 0 and t_us[0] < state[1]):
            state[0] = -1
        if b > a:
            _out_rate(t_us[a:b], flags[a:b], period_us, tol_us, state[:1], sent[a:b])
    state[1] = t_us[-1]


def judged_samples(result: ReplayResult, name: str) -> NDArray[np.int64]:
    """The rows of filter ``name``'s track that the daemon's monitor would judge: the attitudes it publishes at
    :meth:`ReplaySettings.judged_rate_hz` (Pipeline._filter_sample's output-rate rule over the track), which
    are the track's ``sent`` rows where the replay's output rate is that rate."""
    track = result.tracks[name]
    rate = result.settings.judged_rate_hz()
    if rate == float(result.settings.pipeline_settings().out_rate_hz):
        return np.flatnonzero(track.sent)
    period = int(round(1e6 / rate)) if rate > 0 else 0
    n = track.out.shape[0]
    judged = np.zeros(n, bool)
    _out_rate_by_boot(result.inputs.t_us[:n], track.out[:, OUT_FLAGS], period, min(period // 4, 1000),
                      np.full(2, -1, np.int64), judged)  # fmt: skip
    return np.flatnonzero(judged)


def _boot_spans(boot: NDArray[np.int64]) -> tuple[list[int], list[int]]:
    """Each boot's [start, end) sample indices (:func:`~mavahrs.evaluation.tlogdata.sample_boots`)."""
    starts = np.flatnonzero(np.diff(boot, prepend=-1) > 0).tolist()
    return starts, [*starts[1:], int(boot.shape[0])]


def _declinate(q: Array, decl: Array) -> Array:
    """apply_declination_wxyz over rows (cos/sin by math per distinct value: bit-identical)."""
    out = q.copy()
    for d in np.unique(decl):
        if d == 0.0:
            continue
        sel = decl == d
        c, s = math.cos(0.5 * d), math.sin(0.5 * d)
        w, x, y, z = q[sel, 0], q[sel, 1], q[sel, 2], q[sel, 3]
        out[sel, 0] = c * w - s * z
        out[sel, 1] = c * x - s * y
        out[sel, 2] = c * y + s * x
        out[sel, 3] = c * z + s * w
    return out


def _encode_frames(result: ReplayResult, tr: FilterTrack) -> list[bytes]:
    """ATTITUDE_QUATERNION (+ATTITUDE) frames as Pipeline._attitude_frames encodes them."""
    from mavahrs.protocol.codec import MavCodec

    codec = MavCodec(system_id=result.system_id, component_id=tr.component_id)
    mav = codec.mav
    rows = result.inputs.rows
    idx = np.flatnonzero(tr.sent)
    q = tr.out[idx, OUT_Q : OUT_Q + 4]
    rates = rows[idx, IN_GYRO : IN_GYRO + 3] - tr.out[idx, OUT_BIAS : OUT_BIAS + 3]
    t_ms = (result.inputs.t_us[idx] // 1000) & 0xFFFFFFFF
    euler = result.settings.pipeline_settings().send_attitude_euler
    zero = [0.0, 0.0, 0.0, 0.0]
    out: list[bytes] = []
    for k in range(idx.shape[0]):
        qw, qx, qy, qz = (float(v) for v in q[k])
        p, qq, r = (float(v) for v in rates[k])
        tm = int(t_ms[k])
        out.append(codec.encode(mav.attitude_quaternion_encode(tm, qw, qx, qy, qz, p, qq, r, zero)))
        if euler:
            roll = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
            pitch = math.asin(max(-1.0, min(1.0, 2.0 * (qw * qy - qz * qx))))
            yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            out.append(codec.encode(mav.attitude_encode(tm, roll, pitch, yaw, p, qq, r)))
    return out


# --------------------------------------------------------------------------- CSV


def csv_columns(names: Sequence[str]) -> tuple[list[str], list[int]]:
    """Replay CSV header and decimals: time, then per filter q, Euler, gain, trust, rejection, bias, flags, sent."""
    cols = ["time_s"]
    dec = [6]
    for n in names:
        cols += [f"{n}_qw", f"{n}_qx", f"{n}_qy", f"{n}_qz", f"{n}_roll_deg", f"{n}_pitch_deg", f"{n}_yaw_deg",
                 f"{n}_gain", f"{n}_accel_weight", f"{n}_mag_weight", f"{n}_accel_rejected", f"{n}_mag_rejected",
                 f"{n}_bias_x_deg_s", f"{n}_bias_y_deg_s", f"{n}_bias_z_deg_s", f"{n}_flags", f"{n}_sent"]  # fmt: skip
        dec += [7, 7, 7, 7, 3, 3, 3, 5, 3, 3, 0, 0, 4, 4, 4, 0, 0]
    return cols, dec


@kernel
def _csv_fill(t_us, out, sent, res, c, args):  # type: ignore[no-untyped-def]
    """One filter's CSV columns except the Euler angles, and the arguments of their atan2/asin.

    ``res[:, c:c+17]`` as :func:`csv_columns` lays them out (columns c+4…c+6
    left for the caller); ``args`` (n, 6) gets, per row of the normalised
    quaternion, the arguments of roll (atan2), pitch (asin, clipped) and yaw
    (atan2) exactly as :func:`mavahrs.geometry.rotation.to_euler_rad` forms
    them, and 1.0 in column 5 for rows :func:`mavahrs.evaluation.metrics.euler_deg`
    reports as NaN.  The trigonometry itself stays with numpy's ufuncs, so the
    text is the same as that of ``euler_deg`` to the last digit.
    """
    r2d = 180.0 / math.pi
    for i in range(t_us.shape[0]):
        res[i, 0] = t_us[i] * 1e-6
        flags = int(out[i, OUT_FLAGS])
        w, x, y, z = out[i, OUT_Q], out[i, OUT_Q + 1], out[i, OUT_Q + 2], out[i, OUT_Q + 3]
        if flags & FLAG_NOT_INITIALISED:
            w = x = y = z = math.nan
        res[i, c], res[i, c + 1], res[i, c + 2], res[i, c + 3] = w, x, y, z
        n = math.sqrt(w * w + x * x + y * y + z * z)  # np.linalg.norm over the row, same order
        if not (math.isfinite(w) and math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and n > 0.0):
            w, x, y, z, n = 1.0, 0.0, 0.0, 0.0, 1.0
            args[i, 5] = 1.0
        else:
            args[i, 5] = 0.0
        w, x, y, z = w / n, x / n, y / n, z / n
        args[i, 0] = 2.0 * (w * x + y * z)
        args[i, 1] = 1.0 - 2.0 * (x * x + y * y)
        p = 2.0 * (w * y - z * x)
        args[i, 2] = min(max(p, -1.0), 1.0)
        args[i, 3] = 2.0 * (w * z + x * y)
        args[i, 4] = 1.0 - 2.0 * (y * y + z * z)
        res[i, c + 7] = out[i, OUT_GAIN]
        res[i, c + 8] = out[i, OUT_ACCEL_WEIGHT]
        res[i, c + 9] = out[i, OUT_MAG_WEIGHT]
        res[i, c + 10] = 1.0 if out[i, OUT_ACCEL_WEIGHT] < 0.5 else 0.0
        res[i, c + 11] = 1.0 if (flags & FLAG_MAG_INVALID) == 0 and out[i, OUT_MAG_WEIGHT] < 0.5 else 0.0
        for k in range(3):
            res[i, c + 12 + k] = out[i, OUT_BIAS + k] * r2d  # np.degrees: x · (180/π)
        res[i, c + 15] = float(flags)
        res[i, c + 16] = 1.0 if sent[i] else 0.0


def _csv_block(t_us: NDArray[np.int64], outs: Sequence[Array], sents: Sequence[NDArray[np.bool_]]) -> Array:
    """The CSV rows of a block of samples (``csv_columns`` order), identical to the column-wise numpy
    formulation (``euler_deg`` for the angles) but in one compiled pass plus three ufuncs per filter."""
    n = t_us.shape[0]
    width = 17  # columns per filter (csv_columns)
    res = np.empty((n, 1 + width * len(outs)))
    args = np.empty((n, 6))
    t = np.ascontiguousarray(t_us, dtype=np.int64)
    for k, (out, sent) in enumerate(zip(outs, sents, strict=True)):
        c = 1 + width * k
        _csv_fill(t, np.ascontiguousarray(out), np.ascontiguousarray(sent, dtype=np.bool_), res, c, args)
        euler = np.empty((n, 3))
        np.arctan2(args[:, 0], args[:, 1], out=euler[:, 0])
        np.arcsin(args[:, 2], out=euler[:, 1])
        np.arctan2(args[:, 3], args[:, 4], out=euler[:, 2])
        lock = np.hypot(args[:, 0], args[:, 1]) < 1e-7  # gimbal lock: to_euler_rad's own special case
        if lock.any():
            from mavahrs.geometry.rotation import to_euler_rad

            q = res[lock, c : c + 4]
            ok = args[lock, 5] == 0.0
            euler[np.flatnonzero(lock)[ok]] = to_euler_rad(q[ok])
        np.degrees(euler, out=euler)
        euler[args[:, 5] != 0.0] = np.nan
        res[:, c + 4 : c + 7] = euler
    return res


# --------------------------------------------------------------------------- replay


def replay(
    path: str | Path,
    settings: ReplaySettings | None = None,
    *,
    csv_path: str | Path | None = None,
    progress: bool = False,
) -> ReplayResult:
    """Replay a tlog; optionally write the per-sample CSV as it goes.

    Raises:
        ReplayInterrupted: Ctrl-C once the samples were being filtered (with what
            was kept); while the log is read, a plain KeyboardInterrupt.
        DataError: unreadable log, no autopilot, no IMU data.
        FastPathUnsupported: ``engine="fast"`` on a log that needs the pipeline.
    """
    s = settings or ReplaySettings()
    ps = s.pipeline_settings()
    from mavahrs.logs import sniff

    fmt = sniff(path)
    if fmt in ("dataflash", "ulog"):
        return _replay_log(path, fmt, s, csv_path, progress)
    td = read_tlog_data(path)
    ps, source_note = resolve_source(td, ps)
    dy = decimal_year_of_log(td)
    filters = [(n, s.filter_settings.get(n)) for n in s.filters]
    sink = None
    notes: list[str] = [] if source_note is None else [source_note]
    try:
        prep: PreparedInputs | None = None
        if s.engine in ("auto", "fast"):
            try:
                prep = prepare_inputs(td, ps, start_s=s.start_s, end_s=s.end_s, decimal_year=dy)
            except FastPathUnsupported as exc:
                if s.engine == "fast":
                    raise
                log.info("replaying message by message through the pipeline: %s", exc)
                notes.append(f"engine: pipeline, message by message ({exc})")
        if csv_path is not None:
            from mavahrs.evaluation.csvout import CsvSink

            cols, dec = csv_columns(s.filters)
            sink = CsvSink(csv_path, cols, dec)
        if prep is not None:
            result = _replay_fast(td.path, prep, s, filters, sink, progress)
        else:
            result = _replay_pipeline(td, ps, s, filters, dy, sink, progress)
        if sink is not None:
            sink.sync_behind()  # the CSV's last block and fsync go on while the references are read
        result.references, result.reference_boots = references_with_boots(td, result.inputs)
        result.tlog = td
    except KeyboardInterrupt as exc:
        stop = exc if isinstance(exc, ReplayInterrupted) else ReplayInterrupted(None, 0.0, "preparing the samples")
        if sink is not None:
            sink.close()  # every block handed over is written, flushed and synced
            stop.csv_path, stop.csv_rows = sink.path, sink.rows
        raise stop from None
    finally:
        if sink is not None:
            sink.close()
    result.notes = notes + result.inputs.notes + result.notes + _resend_notes(result.inputs.counts)
    result.notes += _mag_notes(result)
    gaps = gap_note(result.inputs, int(td.t_us[0]) if td.frames else 0, ps.timeline.max_gap_s)
    if gaps is not None:
        result.notes.append(gaps)
    rate = result.inputs.rate_hz()
    if rate < LOW_RATE_HZ:
        result.notes.append(
            f"IMU samples reach the filter at {rate:.1f} Hz: too slow for meaningful attitude filtering "
            f"(≥ {LOW_RATE_HZ:g} Hz needed; ground stations request 2–10 Hz — ask the autopilot for more, "
            "see docs/daemon.md). The comparison below is coarse."
        )
    return result


def _replay_log(
    path: str | Path, fmt: str, s: ReplaySettings, csv_path: str | Path | None, progress: bool
) -> ReplayResult:
    """Replay an onboard log (DataFlash, ULog): its reader's :class:`~mavahrs.logs.LogInputs`, then the same
    batch filters, CSV and comparison as a tlog's fast engine (the per-message pipeline engine reads MAVLink
    only)."""
    from mavahrs.logs import a_format, read_log

    ps = s.pipeline_settings()
    li = read_log(path, ps, start_s=s.start_s, end_s=s.end_s, format=fmt)
    prep = li.inputs
    filters = [(n, s.filter_settings.get(n)) for n in s.filters]
    notes: list[str] = []
    if s.engine == "pipeline":
        notes.append(f"engine: fast (the pipeline engine reads MAVLink; this is {a_format(fmt)})")
    if ps.source_system is not None or ps.source_component is not None:  # said, not silently ignored
        notes.append(f"--source ignored: {a_format(fmt)} is written by the autopilot itself and holds its own "
                     "IMU data only (no other senders to choose from)")  # fmt: skip
    sink = None
    try:
        if csv_path is not None:
            from mavahrs.evaluation.csvout import CsvSink

            cols, dec = csv_columns(s.filters)
            sink = CsvSink(csv_path, cols, dec)
        result = _replay_fast(li.path, prep, s, filters, sink, progress)
        if sink is not None:
            sink.sync_behind()
    except KeyboardInterrupt as exc:  # as a tlog's replay: say what the CSV holds, keep the part filtered
        stop = exc if isinstance(exc, ReplayInterrupted) else ReplayInterrupted(None, 0.0, "preparing the samples")
        if stop.result is not None:  # an onboard log's part: its --output is a tlog of the frames alone
            stop.result.log = li
        if sink is not None:
            sink.close()
            stop.csv_path, stop.csv_rows = sink.path, sink.rows
        raise stop from None
    finally:
        if sink is not None:
            sink.close()
    result.references = dict(li.references)
    result.log = li
    result.notes = notes + list(prep.notes)
    result.notes += _mag_notes(result)  # (onboard logs too: the compass disturbed, the learnt declination)
    gaps = gap_note(prep, int(li.start_us), ps.timeline.max_gap_s)
    if gaps is not None:
        result.notes.append(gaps)
    rate = prep.rate_hz()
    if rate < LOW_RATE_HZ:
        result.notes.append(f"IMU samples reach the filter at {rate:.1f} Hz: too slow for meaningful attitude "
                            f"filtering (≥ {LOW_RATE_HZ:g} Hz needed)")  # fmt: skip
    return result


def _mag_notes(result: ReplayResult) -> list[str]:
    """``magnetometer disturbed: heading from GNSS`` for the velocity-aided filters, with how long;
    ``heading unknown: compass disturbed`` with how long and until when (the compass not trusted and the
    heading 1-σ at or above ``HEADING_UNKNOWN_SIGMA_DEG``: a start in a ground anomaly); the
    magnetometer's state at the end (model, offsets, learnt declination) where the filter has one."""
    from mavahrs.filters.layout import (
        FLAG_MAG_INVALID,
        FLAG_VELOCITY_AIDED,
        OUT_HEADING_SIGMA,
        OUT_MAG_WEIGHT,
    )
    from mavahrs.filters.magfield import (
        DISTURBED_TEXT,
        HEADING_UNKNOWN_SIGMA_DEG,
        HEADING_UNKNOWN_TEXT,
        mag_state_text,
    )

    notes = []
    t = result.inputs.t_us
    for name, tr in result.tracks.items():
        if name not in ("best", "eskf") or tr.out.shape[0] < 2:
            continue
        flags = tr.out[:, OUT_FLAGS].astype(np.int64)
        dt = np.diff(t, prepend=t[0]) * 1e-6
        sigma = tr.out[:, OUT_HEADING_SIGMA]
        with np.errstate(invalid="ignore"):
            unknown = (tr.out[:, OUT_MAG_WEIGHT] < 1.0) & (np.degrees(sigma) >= HEADING_UNKNOWN_SIGMA_DEG)
        if float(dt[unknown].sum()) >= 1.0:
            last = float((t[np.flatnonzero(unknown)[-1]] - t[0]) * 1e-6)
            notes.append(f"{name}: {HEADING_UNKNOWN_TEXT} for {float(dt[unknown].sum()):.0f} s (last at "
                         f"{last:.0f} s after the first sample)")  # fmt: skip
        off = ((flags & FLAG_VELOCITY_AIDED) != 0) & ((flags & FLAG_MAG_INVALID) == 0) & (tr.out[:, OUT_MAG_WEIGHT] == 0.0)
        if not off.any():
            continue
        secs = float(dt[off].sum())
        if secs >= 1.0:
            notes.append(f"{name}: {DISTURBED_TEXT} for {secs:.0f} s ({100.0 * off.mean():.0f} % of the samples)")
    for name, tr in result.tracks.items():
        text = mag_state_text(tr.magnetometer) if tr.magnetometer else ""
        if text and text != "mag trusted":  # a model, a learnt declination or a disturbance to tell
            notes.append(f"{name}: at the end {text}")
    return notes


def _resend_notes(counts: Mapping[str, int]) -> list[str]:
    """What the replay's header says about messages sent twice (ArduPilot's 400 Hz stream)."""
    out = []
    n = counts.get("exact_duplicates", 0)
    if n:
        line = (f"{n} exact duplicate IMU messages (same time stamp and values as the message before: "
                f"sent twice by the autopilot) dropped, counted over every IMU instance "
                f"({counts.get('imu_messages', 0)} IMU messages in all)")  # fmt: skip
        fed, of = counts.get("exact_duplicates_fed"), counts.get("imu_messages_fed")
        if fed is not None and of:
            line += f"; of the filtered instance's {of} messages, {fed} ({100.0 * fed / of:.0f} %)"
        out.append(line)
    n = counts.get("same_stamp_changed", 0)
    if n:
        out.append(f"{n} IMU messages repeat the previous message's time stamp with other values "
                   "(the filtered instance's are dropped as stale)")  # fmt: skip
    return out


def gap_note(inputs: PreparedInputs, log_start_us: int, max_gap_s: float, *, listed: int = 5) -> str | None:
    """A note on forward jumps of the IMU clock (holes in the log), or None when there are none.

    A hole is a step between consecutive samples longer than both the
    timeline's gap limit (``max_gap_s``: the filters start again after it)
    and ten median steps (so a slow stream, noted on its own, is not a log
    full of holes).  Positions are seconds from the log's first record, as
    ``--start``/``--end`` count them.
    """
    if inputs.n < 3:
        return None
    step = np.diff(inputs.t_us)
    limit = max(max_gap_s * 1e6, 10.0 * float(np.median(step[step > 0])) if (step > 0).any() else 0.0)
    holes = np.flatnonzero(step > limit)
    if holes.size == 0:
        return None
    at = (inputs.tlog_us.astype(np.float64) - log_start_us) * 1e-6
    where = "of the log"
    # A hole the log's own clock does not show (the samples before and after it were received
    # within less than half its length: queued data delivered in a burst) is placed on the
    # autopilot's clock instead, so its times are not all the same.
    if bool(np.any(np.diff(inputs.tlog_us)[holes] * 2 < step[holes])):
        at = inputs.t_us.astype(np.float64) * 1e-6
        where = ("of the autopilot's clock (time since boot: the log received these samples in bursts, "
                 "its own times do not show the gaps)")  # fmt: skip
    spans = [f"{at[i]:.1f}–{at[i + 1]:.1f} s" for i in holes[:listed]]
    more = ", …" if holes.size > listed else ""
    if holes.size == 1:
        i = int(holes[0])
        return (f"gap in the IMU data: no samples for {step[i] * 1e-6:.1f} s, from {at[i]:.1f} s to "
                f"{at[i + 1]:.1f} s {where}; the filters start again after it (their re-convergence "
                "is in the comparison below)")  # fmt: skip
    return (f"{holes.size} gaps in the IMU data, {float(step[holes].sum()) * 1e-6:.1f} s without samples in "
            f"all: {', '.join(spans)}{more} {where}; the filters start again after each (their "
            "re-convergence is in the comparison below)")  # fmt: skip


def _progress_bar(total: int, enabled: bool, unit: str) -> Any:
    if not enabled or total < 200_000:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, unit_scale=True, leave=False, desc="replay")


def _replay_fast(
    path: str, prep: PreparedInputs, s: ReplaySettings, filters: Sequence[tuple[str, Any]],
    sink: Any, progress: bool,
) -> ReplayResult:  # fmt: skip
    from mavahrs.filters import create

    ps = s.pipeline_settings()
    period = int(round(1e6 / ps.out_rate_hz)) if ps.out_rate_hz > 0 else 0
    tol = min(period // 4, 1000)
    m = prep.n
    filts = [create(n, fs) for n, fs in filters]
    outs = [np.empty((m, OUT_WIDTH)) for _ in filts]
    sents = [np.zeros(m, bool) for _ in filts]
    states = [np.full(1, -1, np.int64) for _ in filts]
    bar = _progress_bar(m, progress, "sample")
    done = 0  # samples every filter has finished (and the CSV sink has been handed)
    try:
        for a in range(0, m, _CHUNK):
            b = min(m, a + _CHUNK)
            for f, out, sent, st in zip(filts, outs, sents, states, strict=True):
                prep.run_filter(f, a, b, out[a:b])
                _out_rate(prep.t_us[a:b], out[a:b, OUT_FLAGS], period, tol, st, sent[a:b])
                out[a:b, OUT_Q : OUT_Q + 4] = _declinate(out[a:b, OUT_Q : OUT_Q + 4], prep.declination_rad[a:b])
            if sink is not None:
                # formatted and written by the sink's thread while the next chunk is filtered
                block = _csv_block(prep.t_us[a:b], [o[a:b] for o in outs], [x[a:b] for x in sents])
                try:
                    sink.write_behind(block)
                except KeyboardInterrupt:
                    sink.write_now(block)  # computed: kept (the interrupt came while the previous block was written)
                    done = b
                    raise
            done = b
            if bar is not None:
                bar.update(b - a)
    except KeyboardInterrupt:
        part = _first_samples(prep, done)
        tracks = {
            n: FilterTrack(n, ps.component_id + i, outs[i][:done], sents[i][:done])
            for i, (n, _) in enumerate(filters)
        }
        partial = ReplayResult(path, part, tracks, ps.system_id or prep.source[0], s)
        raise ReplayInterrupted(partial, done / m if m else 0.0, "filtering") from None
    finally:
        if bar is not None:
            bar.close()
    sysid = ps.system_id or prep.source[0]
    tracks = {
        n: FilterTrack(n, ps.component_id + i, outs[i], sents[i], magnetometer=_mag_status(filts[i]))
        for i, (n, _) in enumerate(filters)
    }
    return ReplayResult(path, prep, tracks, sysid, s)


def _mag_status(f: Any) -> dict[str, Any] | None:
    get = getattr(f, "mag_status", None)
    return get() if get is not None else None


def _first_samples(prep: PreparedInputs, n: int) -> PreparedInputs:
    """``prep`` cut to its first ``n`` samples (what an interrupted replay filtered)."""
    import dataclasses

    return dataclasses.replace(
        prep, rows=prep.rows[:n], t_us=prep.t_us[:n], frame_pos=prep.frame_pos[:n], tlog_us=prep.tlog_us[:n],
        temperature_c=prep.temperature_c[:n], declination_rad=prep.declination_rad[:n],
        mag_reference_events=[e for e in prep.mag_reference_events if e[0] < n],
        notes=list(prep.notes), counts=dict(prep.counts),
    )  # fmt: skip


def _replay_pipeline(
    td: TlogData, ps: Any, s: ReplaySettings, filters: Sequence[tuple[str, Any]], dy: float | None,
    sink: Any, progress: bool,
) -> ReplayResult:  # fmt: skip
    bar = _progress_bar(td.frames, progress, "msg")
    last = [0]
    period = int(round(1e6 / ps.out_rate_hz)) if ps.out_rate_hz > 0 else 0
    tol = min(period // 4, 1000)

    def tick(j: int) -> None:
        if bar is not None:
            bar.update(j - last[0])
            last[0] = j

    csv_states = [np.full(2, -1, np.int64) for _ in filters]

    def write_block(a: int, b: int, t_list: list[int], decl: list[float], outs: list[list[Array]]) -> None:
        """Write samples a:b to the CSV while the replay goes on (an interruption keeps them)."""
        t = np.asarray(t_list[a:b], np.int64)
        d = np.asarray(decl[a:b])
        blocks, sents = [], []
        for k in range(len(filters)):
            o = np.vstack(outs[k][a:b])
            o[:, OUT_Q : OUT_Q + 4] = _declinate(o[:, OUT_Q : OUT_Q + 4], d)
            sent = np.zeros(b - a, bool)
            _out_rate_by_boot(t, o[:, OUT_FLAGS], period, tol, csv_states[k], sent)
            blocks.append(o)
            sents.append(sent)
        sink.write(_csv_block(t, blocks, sents))

    try:
        prep, outs, frames, sysid = run_pipelines(
            td, ps, filters, start_s=s.start_s, end_s=s.end_s, decimal_year=dy, progress=tick,
            on_block=write_block if sink is not None else None,
        )  # fmt: skip
    except KeyboardInterrupt:  # the CSV holds the blocks written so far; the tlog needs the whole run
        raise ReplayInterrupted(None, last[0] / td.frames if td.frames else 0.0, "filtering") from None
    finally:
        if bar is not None:
            bar.close()
    tracks: dict[str, FilterTrack] = {}
    for i, (n, _) in enumerate(filters):
        out = outs[i]
        out[:, OUT_Q : OUT_Q + 4] = _declinate(out[:, OUT_Q : OUT_Q + 4], prep.declination_rad)
        # which samples produced a frame: the pipeline's own rule, replayed on its outputs
        sent = np.zeros(prep.n, bool)
        _out_rate_by_boot(prep.t_us, out[:, OUT_FLAGS], period, tol, np.full(2, -1, np.int64), sent)
        tracks[n] = FilterTrack(n, ps.component_id + i, out, sent, frames[i])
    return ReplayResult(td.path, prep, tracks, sysid, s)


# --------------------------------------------------------------------------- comparison


@dataclass(frozen=True)
class ComparisonRow:
    filter: str
    reference: str
    samples: int
    total_rms_deg: float
    heading_rms_deg: float
    inclination_rms_deg: float
    roll_rms_deg: float
    pitch_rms_deg: float
    yaw_rms_deg: float


def attitude_at_reference(result: ReplayResult, filter_name: str, reference_name: str) -> NDArray[np.float64]:
    """A filter's attitude (as sent) slerped onto a reference's own times: (N_ref, 4), NaN where it has none.

    NaN before the filter initialised, outside the replayed span and across
    gaps in its output longer than 0.5 s (or three sample periods).  The
    reference itself is ``result.references[reference_name]`` (times µs, q).  Where the autopilot rebooted
    during the log, each boot's reference samples get that boot's attitudes (``result.reference_boots``).
    """
    t_ref, _q_ref = result.references[reference_name]
    t = result.inputs.t_us.astype(np.float64)
    out = result.tracks[filter_name].out
    init = (out[:, OUT_FLAGS].astype(np.int64) & FLAG_NOT_INITIALISED) == 0
    if t.size < 2 or not init.any():
        return np.full((len(t_ref), 4), np.nan)
    boot = sample_boots(result.inputs.t_us[: out.shape[0]])
    one = boot[-1] == 0
    gap_s = max(0.5, 3.0 * float(np.median(np.abs(np.diff(t)))) * 1e-6)
    if one:
        return interpolate_attitude(t[init], out[init, OUT_Q : OUT_Q + 4], t_ref, max_gap_s=gap_s)
    ref_boot = result.reference_boots.get(reference_name, np.zeros(len(t_ref), np.int64))
    q = np.full((len(t_ref), 4), np.nan)
    for k in range(int(boot[-1]) + 1):
        mine, theirs = init & (boot == k), ref_boot == k
        if mine.any() and theirs.any():
            q[theirs] = interpolate_attitude(t[mine], out[mine, OUT_Q : OUT_Q + 4], t_ref[theirs], max_gap_s=gap_s)
    return q


def compare(result: ReplayResult, skip_s: float = 0.0) -> list[ComparisonRow]:
    """Each filter against each attitude the log holds, at the reference's own times.

    The filter's attitude (as sent: true north when the declination is known)
    is slerped onto the reference times within the replayed span; samples
    before the filter initialised are skipped (:func:`attitude_at_reference`),
    and so are the reference times in the first ``skip_s`` seconds after the
    first replayed sample (convergence: ``scripts/bench_sitl.py`` and the
    README's tables leave out 10 s).
    """
    from mavahrs.evaluation.metrics import euler_errors_rad, summarize

    rows: list[ComparisonRow] = []
    if result.inputs.t_us.size < 2:
        return rows
    t = result.inputs.t_us
    boot = sample_boots(t)
    first = np.flatnonzero(np.diff(boot, prepend=-1) > 0)  # each boot's first sample
    for name in result.tracks:
        for ref_name, (t_ref, q_ref) in result.references.items():
            q_est = attitude_at_reference(result, name, ref_name)
            # from skip_s after the first replayed sample of the reference sample's boot
            ref_boot = np.minimum(result.reference_boots.get(ref_name, np.zeros(len(t_ref), np.int64)), first.size - 1)
            start_us = t[first[ref_boot]].astype(np.float64) + max(0.0, skip_s) * 1e6
            ok = np.all(np.isfinite(q_est), axis=1) & (t_ref >= start_us)
            if ok.sum() < 2:
                continue
            sm = summarize(q_est[ok], q_ref[ok])
            e = np.degrees(euler_errors_rad(q_est[ok], q_ref[ok]))
            r = np.sqrt(np.mean(e**2, axis=0))
            rows.append(ComparisonRow(name, ref_name, int(ok.sum()), sm.total_rms_deg, sm.heading_rms_deg,
                                      sm.inclination_rms_deg, float(r[0]), float(r[1]), float(r[2])))  # fmt: skip
    return rows


# the attitudes each reader takes as references (LogInputs.references, read_tlog_data), by log format
_REFERENCE_RECORDS = {
    "tlog": "ATTITUDE, AHRS2, SIM_STATE, SIMSTATE or HIL_STATE_QUATERNION",
    "dataflash": "XKQ, XKF1, ATT, AHR2 or SIM",
    "ulog": "vehicle_attitude or vehicle_attitude_groundtruth",
}


def format_comparison(rows: Sequence[ComparisonRow], skip_s: float | None = None, *,
                      result: ReplayResult | None = None) -> str:  # fmt: skip
    """The comparison table; ``skip_s`` (when given) says which samples it covers in its title.

    With no row, one line saying why: the log holds no attitude (named in the records of
    ``result``'s log format), or it does but too few of its samples fall in the compared span.
    """
    if not rows:
        refs = list(result.references) if result is not None else []
        if refs:
            span = f" from {skip_s:g} s after the first replayed sample (--skip)" if skip_s else ""
            return (f"no comparison: fewer than 2 samples of {', '.join(refs)} fall within the replayed "
                    f"span{span} after the filters initialised")  # fmt: skip
        kinds = _REFERENCE_RECORDS.get(result.format if result is not None else "tlog", _REFERENCE_RECORDS["tlog"])
        return f"no attitude in the log to compare with (no {kinds})"
    head = (f"{'filter':<14}{'vs':<22}{'samples':>8}{'total':>8}{'head':>8}{'incl':>8}"
            f"{'roll':>8}{'pitch':>8}{'yaw':>8}")  # fmt: skip
    if skip_s is None:
        span = ""
    elif skip_s > 0:
        span = f"; from {skip_s:g} s after the first replayed sample (--skip)"
    else:
        span = ("; from the first replayed sample, convergence included (the README's tables leave out the "
                "first 10 s: --skip 10)")
    lines = ["RMS difference, degrees (heading/inclination as BROAD defines them; roll/pitch/yaw of q_ref*⊗q"
             f"{span}):", head, "─" * len(head)]  # fmt: skip
    for r in rows:
        lines.append(
            f"{r.filter:<14}{r.reference:<22}{r.samples:>8}{r.total_rms_deg:8.2f}{r.heading_rms_deg:8.2f}"
            f"{r.inclination_rms_deg:8.2f}{r.roll_rms_deg:8.2f}{r.pitch_rms_deg:8.2f}{r.yaw_rms_deg:8.2f}"
        )
    return "\n".join(lines)


def format_velocity(inputs: Any) -> str:
    """The replay header's velocity line: which GNSS velocity the filters got, and how many fixes.

    E.g. ``velocity: GPS_RAW_INT, 979 fixes (velocity_source gps_raw_int)``;
    ``velocity: GLOBAL_POSITION_INT, 1200 fixes + GPS_RAW_INT, 40 fixes
    (velocity_source auto)`` when ``auto`` switched; ``velocity: none
    (velocity_source auto: no usable fix in the log)``.
    """
    src = inputs.velocity_source
    used = [f"{m}, {n} fixes" for m, n in inputs.velocity_fixes.items() if n]
    if used:
        return f"velocity: {' + '.join(used)} (velocity_source {src})"
    why = "" if src == "none" else ": no usable fix in the log"
    return f"velocity: none (velocity_source {src}{why})"


# --------------------------------------------------------------------------- tlog and plot


def write_tlog(result: ReplayResult, path: str | Path, *, until_tlog_us: int | None = None) -> int:
    """The input log with every filter's frames inserted after the IMU message they came from.

    Records keep their timestamps; the inserted frames carry the IMU
    message's.  With ``start_s``/``end_s`` only records in that window are
    written; with ``until_tlog_us`` (an interrupted replay: its last
    filtered sample's record time) none after it.  Returns the number of
    frames inserted.
    """
    from mavahrs.protocol.fast_tlog import scan_tlog
    from mavahrs.protocol.tlog import tlog_record

    if result.log is not None:  # an onboard log: a tlog of the frames alone, stamped with their sample times
        return _write_frames_tlog(result, path)
    td = read_tlog_data(result.path) if not isinstance(result.inputs, PreparedInputs) else None
    data = np.fromfile(result.path, np.uint8)
    full = scan_tlog(data, None, mode="mmap")
    # locate the fed IMU frames (by byte offset) in the full scan
    sub = scan_tlog(data, list(_replay_types()), mode="mmap")
    imu_off = sub.offset[result.inputs.frame_pos]
    imu_side = sub.in_side[result.inputs.frame_pos]
    inserts: dict[int, list[bytes]] = {}
    for tr in result.tracks.values():
        frames = result.frames(tr.name)
        per = 2 if result.settings.pipeline_settings().send_attitude_euler else 1
        idx = np.flatnonzero(tr.sent)
        for k, i in enumerate(idx):
            key = int(imu_off[i]) if not imu_side[i] else -1 - int(imu_off[i])
            inserts.setdefault(key, []).extend(frames[per * k : per * k + per])
    t0 = int(full.t_us[0]) if len(full) else 0
    s = result.settings
    lo = -(2**62) if s.start_s is None else t0 + int(s.start_s * 1e6)
    hi = 2**62 if s.end_s is None else t0 + int(s.end_s * 1e6)
    if until_tlog_us is not None:
        hi = min(hi, int(until_tlog_us))
    inserted = 0
    del td
    with open(path, "wb") as f:
        buf: list[bytes] = []
        for j in range(len(full)):
            t = int(full.t_us[j])
            if not lo <= t <= hi:
                continue
            buf.append(tlog_record(t, full.frame(j)))
            key = int(full.offset[j]) if not full.in_side[j] else -1 - int(full.offset[j])
            extra = inserts.get(key)
            if extra:
                for fr in extra:
                    buf.append(tlog_record(t, fr))
                inserted += len(extra)
            if len(buf) >= 8192:
                f.write(b"".join(buf))
                buf.clear()
        f.write(b"".join(buf))
    return inserted


def _write_frames_tlog(result: ReplayResult, path: str | Path) -> int:
    from mavahrs.protocol.tlog import tlog_record

    per = 2 if result.settings.pipeline_settings().send_attitude_euler else 1
    recs: list[tuple[int, int, bytes]] = []
    for k, tr in enumerate(result.tracks.values()):
        frames = result.frames(tr.name)
        for j, i in enumerate(np.flatnonzero(tr.sent).tolist()):
            t = int(result.inputs.t_us[i])
            for fr in frames[per * j : per * j + per]:
                recs.append((t, k, fr))
    recs.sort(key=lambda r: (r[0], r[1]))
    with open(path, "wb") as f:
        for a in range(0, len(recs), 8192):
            f.write(b"".join(tlog_record(t, fr) for t, _, fr in recs[a : a + 8192]))
    return len(recs)


def _replay_types() -> tuple[str, ...]:
    from mavahrs.evaluation.tlogdata import REPLAY_TYPES

    return REPLAY_TYPES


def plot_replay(result: ReplayResult, path: str | Path) -> Path:
    """Truth (or the autopilot's attitude), the filters, errors, gain and rejection state, against the autopilot's
    boot time: the clock of the second-opinion chart, of the STATUSTEXT times replay and audit print and of
    ``inject-fault --at``.  (Until user6 this plot counted from the first sample: on the gentle SITL flight,
    first sample at boot 72.6 s, a WARNING at 82.9 s was drawn at 10.3 s.)"""
    from mavahrs.evaluation.plots import plot_attitude

    t_us = result.inputs.t_us.astype(np.float64)
    t0 = 0.0  # inputs.t_us is the autopilot's boot clock (tlog time_boot_ms / time_usec, DataFlash TimeUS, ULog)
    boot = sample_boots(result.inputs.t_us)
    if boot.size and boot[-1] > 0:
        return _plot_boots(result, path, boot)
    truth = [k for k in result.references if is_truth(k)]
    # every other reference is an autopilot's estimate (LogInputs.references): "autopilot ATTITUDE" of a tlog,
    # "autopilot EKF3" of a .BIN, "EKF2" of a .ulg
    ap = [k for k in result.references if not is_truth(k)]
    ref_name = truth[0] if truth else (ap[0] if ap else None)
    ref_q = None
    others: dict[str, tuple[Array, Array]] = {}
    if ref_name is not None:
        t_ref, q_ref = result.references[ref_name]
        gap = max(0.5, 3.0 * float(np.median(np.diff(t_ref))) * 1e-6) if t_ref.size > 1 else 0.5
        ref_q = interpolate_attitude(t_ref, q_ref, t_us, max_gap_s=gap)
    for k in ap:
        if k != ref_name:
            t_ref, q_ref = result.references[k]
            others[k] = ((t_ref - t0) * 1e-6, q_ref)
    est = {}
    for n, tr in result.tracks.items():
        o = tr.out.copy()
        bad = (o[:, OUT_FLAGS].astype(np.int64) & FLAG_NOT_INITIALISED) != 0
        o[bad, OUT_Q : OUT_Q + 4] = np.nan
        est[n] = o
    rate = result.inputs.rate_hz()
    title = (f"{Path(result.path).name}: {result.inputs.message} (IMU {result.inputs.instance}) at {rate:.1f} Hz"
             + (f" — reference: {ref_name}" if ref_name else ""))  # fmt: skip
    return plot_attitude(path, (t_us - t0) * 1e-6, est, reference_q=ref_q, reference_label=ref_name or "",
                         others=others, title=title, time_label="autopilot boot time, s")  # fmt: skip


def _plot_boots(result: ReplayResult, path: str | Path, boot: NDArray[np.int64]) -> Path:
    """:func:`plot_replay` of a log in which the autopilot rebooted: each boot on its own boot clock, drawn over
    one another with every line broken between boots, each boot's estimate against that boot's reference.
    (Until user7 lines ran from one boot's last sample to the next boot's first, and the error rows compared one
    boot's estimate with the other's reference: 17.7° roll RMS on a daemon session with a restart, 0.6° by boot.)"""
    from mavahrs.evaluation.plots import plot_attitude

    starts, ends = _boot_spans(boot)
    truth = [k for k in result.references if is_truth(k)]
    ap = [k for k in result.references if not is_truth(k)]
    ref_name = truth[0] if truth else (ap[0] if ap else None)

    def broken(parts: list[Array]) -> Array:  # the boots' rows with a NaN row between them
        gap = np.full((1, *parts[0].shape[1:]), np.nan)
        return np.concatenate([x for p in parts for x in (gap, p)][1:])

    t = broken([result.inputs.t_us[a:b].astype(np.float64) * 1e-6 for a, b in zip(starts, ends, strict=True)])
    est = {}
    for n, tr in result.tracks.items():
        o = tr.out.copy()
        o[(o[:, OUT_FLAGS].astype(np.int64) & FLAG_NOT_INITIALISED) != 0, OUT_Q : OUT_Q + 4] = np.nan
        est[n] = broken([o[a:b] for a, b in zip(starts, ends, strict=True)])
    ref_q = None
    others: dict[str, tuple[Array, Array]] = {}
    for k in ([ref_name] if ref_name else []) + [k for k in ap if k != ref_name]:
        t_ref, q_ref = result.references[k]
        rb = result.reference_boots.get(k, np.zeros(t_ref.shape[0], np.int64))
        if k == ref_name:
            parts = []
            for j, (a, b) in enumerate(zip(starts, ends, strict=True)):
                tr_j, qr_j = t_ref[rb == j], q_ref[rb == j]
                gap = max(0.5, 3.0 * float(np.median(np.diff(tr_j))) * 1e-6) if tr_j.size > 1 else 0.5
                parts.append(interpolate_attitude(tr_j, qr_j, result.inputs.t_us[a:b].astype(np.float64), max_gap_s=gap)
                             if tr_j.size else np.full((b - a, 4), np.nan))  # fmt: skip
            ref_q = broken(parts)
        else:
            ks = range(int(rb.max()) + 1) if rb.size else range(0)
            others[k] = (broken([t_ref[rb == j] * 1e-6 for j in ks]), broken([q_ref[rb == j] for j in ks]))
    title = (f"{Path(result.path).name}: {result.inputs.message} (IMU {result.inputs.instance}) at "
             f"{result.inputs.rate_hz():.1f} Hz, {len(starts)} boots of the autopilot drawn over one another"
             + (f" — reference: {ref_name}" if ref_name else ""))  # fmt: skip
    return plot_attitude(path, t, est, reference_q=ref_q, reference_label=ref_name or "", others=others,
                         title=title, time_label="autopilot boot time (each boot's own clock), s")  # fmt: skip


#: above this many autopilot attitudes the second opinion's judgement says it has started: the PX4 SIH .ulg's
#: 64 678 (EKF2 at 250 Hz) took 16.5 s after the progress bar had ended (2-core VM, load 4.5); a SITL tlog's
#: ATTITUDE at 10 Hz, or a .BIN's EKF3 at 25 Hz, a few thousand, well under a second
_SAY_JUDGING_ABOVE = 50_000


def _monitor_of(result: ReplayResult) -> tuple[Any, str, str] | None:
    """The monitor's series over the replay, the autopilot reference it judged and the filter it judged
    (:func:`~mavahrs.fleet.audit.monitored_filter`); None without an autopilot attitude.  Judged once per
    replay (kept in ``result.second_opinion``): ``replay --plot`` judged it twice, once for the printed second
    opinion and once for its chart (16 s each on the PX4 SIH .ulg's 250 Hz EKF2 attitude)."""
    if not result.second_opinion:
        result.second_opinion.append(_judge_second_opinion(result))
    return result.second_opinion[0]


def _judge_second_opinion(result: ReplayResult) -> tuple[Any, str, str] | None:
    from mavahrs.fleet.audit import monitored_filter, onboard_phase_events, phase_events, replay_monitor

    ref = autopilot_reference(result.references)  # the autopilot's (a .ulg's "EKF2"), as the fleet audit's
    if not ref or not result.tracks:
        return None
    n_ref = int(result.references[ref][0].shape[0])
    if n_ref > _SAY_JUDGING_ABOVE:  # seconds of silence after the progress bar otherwise
        log.info("second opinion: judging %d attitudes of %s against ours …", n_ref, ref)
    tlog = getattr(result, "tlog", None)
    if hasattr(tlog, "arrays"):
        phase = phase_events(tlog, result.inputs, result.inputs.source)
    else:  # a .BIN's ARM/EV, a .ulg's vehicle_status / vehicle_land_detected
        phase = onboard_phase_events(getattr(result, "log", None))
    series, _ = replay_monitor(result, result.settings.pipeline_settings().monitor, ref, phase)
    return series, ref, monitored_filter(result.tracks)


def format_second_opinion(result: ReplayResult) -> str:
    """What the daemon's monitor would have said on this flight: each STATUSTEXT (boot time, phase, text) and
    the evidence of who is likely wrong; "" where the log has no autopilot attitude."""
    got = _monitor_of(result)
    if got is None:
        return ""
    series, ref, name = got
    lines = [f"second opinion ({name}) vs {ref}: {sum(e.in_flight for e in series.events)} in-flight WARNING(s)"]
    held = series.held_note(result.settings.pipeline_settings().monitor)
    if held:
        lines[0] += f"; {held}"
    for e in series.events:
        lines.append(f"  {e.t_ms / 1000.0:9.3f} s  {e.phase or '':9s} {e.text}")
        if e.evidence is not None:
            lines.append(f"  {'':21s}({e.evidence.text()})")
    return "\n".join(lines)


def plot_second_opinion(result: ReplayResult, path: str | Path) -> Path | None:
    """The second-opinion monitor's chart beside the replay plot ``path`` (``NAME_second_opinion.png``): what
    the daemon's monitor would have said on this flight against the log's autopilot attitude (None: the log
    has none)."""
    from mavahrs.evaluation.plots import plot_second_opinion as draw

    got = _monitor_of(result)
    if got is None:
        return None
    series, ref, name = got
    p = Path(path)
    return draw(p.with_name(f"{p.stem}_second_opinion.png"), series,
                title=f"{Path(result.path).name}: {name} vs {ref}")


# --------------------------------------------------------------------------- QGC streaming


@dataclass(frozen=True)
class StreamSettings:
    """How :func:`stream` presents a replay to a ground station.

    Attributes:
        url: where to send, a connection string (``udpout:127.0.0.1:14550``).
        system_id: the system id of the pretend vehicle (distinct from the
            logged vehicle's, so the ground station shows it separately).
        speed: replay speed, 1 = real time.
        rate_hz: ATTITUDE_QUATERNION rate, Hz of log time.
        heartbeat_hz: HEARTBEAT rate (wall clock).
        max_duration_s: stop after this much wall-clock time (None = to the end).
    """

    url: str = "udpout:127.0.0.1:14550"
    system_id: int = 42
    speed: float = 1.0
    rate_hz: float = 50.0
    heartbeat_hz: float = 1.0
    max_duration_s: float | None = None

    def __post_init__(self) -> None:
        if not 1 <= self.system_id <= 255:
            raise ValueError(f"system id must be 1…255, got {self.system_id}")
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ValueError(f"speed must be positive, got {self.speed}")
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"stream rate must be positive, got {self.rate_hz}")


def stream(result: ReplayResult, name: str, settings: StreamSettings, *, clock: Any = None) -> int:
    """Stream one filter's replayed attitude to a ground station as a vehicle of its own.

    QGroundControl draws on its HUD only the attitude of a vehicle's autopilot
    component, so this presents itself as one: its own system id, component 1
    (MAV_COMP_ID_AUTOPILOT1), HEARTBEAT as a quadrotor (MAV_TYPE_QUADROTOR,
    MAV_AUTOPILOT_GENERIC) at ``heartbeat_hz``, and the filtered
    ATTITUDE_QUATERNION (+ ATTITUDE, which older ground stations draw) paced
    in real time (× ``speed``) by the log's sample times.  The live daemon
    never does this: pretending to be the autopilot would confuse the ground
    station about which vehicle is which (see docs/evaluation.md).

    Returns the number of ATTITUDE_QUATERNION messages sent.
    """
    import time

    from mavahrs.protocol.codec import MavCodec

    tr = result.tracks[name]
    clk = clock or time
    codec = MavCodec(system_id=settings.system_id, component_id=1)
    mav = codec.mav
    init = (tr.out[:, OUT_FLAGS].astype(np.int64) & FLAG_NOT_INITIALISED) == 0
    idx = np.flatnonzero(init)
    t_us = result.inputs.t_us
    # pick samples at the stream rate, on log time
    period = 1e6 / settings.rate_hz
    keep: list[int] = []
    nxt = -1.0
    for i in idx:
        if t_us[i] >= nxt:
            keep.append(int(i))
            nxt = (t_us[i] if nxt < 0 else nxt) + period
            if nxt <= t_us[i]:
                nxt = t_us[i] + period
    send = _open_udp_sender(settings.url)
    sent = 0
    try:
        start = clk.monotonic()
        t_first = float(t_us[keep[0]]) if keep else 0.0
        next_hb = start
        boot_ms0 = int(t_first // 1000)
        rows = result.inputs.rows
        for i in keep:
            due = start + (float(t_us[i]) - t_first) * 1e-6 / settings.speed
            while True:
                now = clk.monotonic()
                if now >= next_hb:
                    send(codec.encode(mav.heartbeat_encode(2, 0, 0, 0, 4)))  # QUADROTOR, GENERIC, ACTIVE
                    next_hb += 1.0 / settings.heartbeat_hz
                if settings.max_duration_s is not None and now - start >= settings.max_duration_s:
                    return sent
                if now >= due:
                    break
                clk.sleep(min(due - now, max(0.0, next_hb - now), 0.05))
            qw, qx, qy, qz = (float(v) for v in tr.out[i, OUT_Q : OUT_Q + 4])
            p, q, r = (float(v) for v in rows[i, IN_GYRO : IN_GYRO + 3] - tr.out[i, OUT_BIAS : OUT_BIAS + 3])
            tm = (int(t_us[i] // 1000) - boot_ms0) & 0xFFFFFFFF
            send(codec.encode(mav.attitude_quaternion_encode(tm, qw, qx, qy, qz, p, q, r, [0.0] * 4)))
            roll = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
            pitch = math.asin(max(-1.0, min(1.0, 2.0 * (qw * qy - qz * qx))))
            yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            send(codec.encode(mav.attitude_encode(tm, roll, pitch, yaw, p, q, r)))
            sent += 1
    finally:
        close = getattr(send, "close", None)
        if close is not None:
            close()
    return sent


def _open_udp_sender(url: str) -> Callable[[bytes], None]:
    """A sender for a connection string (``udpout:HOST:PORT``, ``tcp:…``, a serial port) through
    :func:`mavahrs.transports.open_transport`, the daemon's links."""
    from mavahrs.transports import open_transport

    link = open_transport(url)

    class _Sender:
        def __call__(self, data: bytes) -> None:
            try:
                link.write(data)
            except OSError:  # nobody listening yet: a ground station may come later
                pass

        def close(self) -> None:
            link.close()

    return _Sender()
