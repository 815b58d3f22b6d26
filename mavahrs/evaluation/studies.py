r"""The papers' studies: gain sweep, sample-rate sweep, bias tracking, filter comparison.

* :func:`beta_study` — error vs β from 0 to 0.5 (Madgwick 2010, Fig. 10), for
  the IMU (6-axis) and MARG (9-axis) forms, at rest and in motion;
* :func:`rate_study` — error vs sample rate, 1 … 512 Hz, by decimating the
  recording (Fig. 11).  Rates above the recording's own are skipped;
* :func:`bias_study` — gyro bias tracking with an injected drift of
  +0.2 °/s per second on x and −0.2 on y, ζ = 0 for the first 10 s then
  0.015 (Fig. 12);
* :func:`compare_study` — Mahony, Madgwick and complementary side by side on
  one recording: per-angle mean and SD (Ermakov & Gogolev 2022, Table 2) and
  the per-angle evolution/error data for the plots (their Fig. 8–13).

Error figures: 9-axis runs are scored by the total error angle (BROAD's
``2·acos|e_w|``), 6-axis runs by the inclination error (their heading is not
observable); "rest" and "motion" split the scored samples at 5°/s
(:func:`~mavahrs.evaluation.metrics.motion_mask`).  Every study returns a
:class:`StudyResult` — a table (``format()``, ``to_dict()``) plus the arrays
the plot functions in :mod:`mavahrs.evaluation.plots` draw.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.evaluation.alignment import fit_alignment
from mavahrs.evaluation.datasets import Recording
from mavahrs.evaluation.metrics import (
    angle_stats,
    attitude_errors_rad,
    euler_deg,
    euler_errors_rad,
    motion_mask,
    rms_deg,
)
from mavahrs.evaluation.report import choose_alignment, run_filter
from mavahrs.filters.base import FilterSettings, make_inputs
from mavahrs.filters.layout import OUT_BIAS, OUT_Q

__all__ = [
    "StudyResult",
    "decimate",
    "gain_field",
    "beta_study",
    "rate_study",
    "bias_study",
    "compare_study",
    "STUDIES",
    "DEFAULT_RATES_HZ",
    "DEFAULT_BETAS",
]

Array = NDArray[np.float64]

#: Madgwick 2010 Fig. 11: 1 … 512 Hz in octaves.
DEFAULT_RATES_HZ: tuple[float, ...] = (1, 2, 4, 8, 16, 32, 64, 128, 256, 512)
#: Madgwick 2010 Fig. 10: β from 0 to 0.5.
DEFAULT_BETAS: tuple[float, ...] = tuple(round(0.01 * i, 2) for i in range(51))
STUDIES: tuple[str, ...] = ("beta", "rate", "bias", "compare")

#: The settings field each filter's main correction gain lives in, tried in order.
_GAIN_FIELDS: tuple[str, ...] = ("beta_rad_s", "beta", "kp_accel", "alpha", "k_g", "kg", "gain")


@dataclass
class StudyResult:
    """A study's table and the arrays behind its plot.

    Attributes:
        study: ``beta``, ``rate``, ``bias`` or ``compare``.
        title: one line saying what was measured.
        columns: table column names; ``rows`` the values (floats or text).
        notes: how it was measured (decimation method, alignment, skipped rates …).
        data: arrays for the plot functions.
    """

    study: str
    title: str
    columns: list[str]
    rows: list[list[Any]]
    notes: list[str] = field(default_factory=list)
    data: dict[str, Any] = field(default_factory=dict)

    def format(self) -> str:
        widths = [max(len(c), 8) for c in self.columns]
        for row in self.rows:
            for i, v in enumerate(row):
                widths[i] = max(widths[i], len(_cell(v)))
        lines = [self.title, "  ".join(c.rjust(w) for c, w in zip(self.columns, widths, strict=True))]
        lines.append("  ".join("─" * w for w in widths))
        for row in self.rows:
            # a row shorter than the header leaves its last columns blank
            lines.append("  ".join(_cell(v).rjust(w) for v, w in zip(row, widths, strict=False)))
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        def clean(v: Any) -> Any:
            if isinstance(v, float):
                return None if not math.isfinite(v) else round(v, 6)
            return v

        return {
            "study": self.study,
            "title": self.title,
            "columns": self.columns,
            "rows": [[clean(v) for v in row] for row in self.rows],
            "notes": self.notes,
        }


def _cell(v: Any) -> str:
    if isinstance(v, float):
        return "—" if not math.isfinite(v) else f"{v:.3f}"
    return str(v)


def gain_field(settings: FilterSettings) -> str:
    """Name of the settings field holding the filter's main correction gain (β for Madgwick)."""
    names = {f.name for f in dataclasses.fields(settings)}
    for candidate in _GAIN_FIELDS:
        if candidate in names:
            return candidate
    raise ValueError(f"{type(settings).__name__} has none of the gain fields {', '.join(_GAIN_FIELDS)}")


def _default_settings(name: str) -> FilterSettings:
    from mavahrs.filters import create

    return create(name).settings


def _run_many(rec: Recording, name: str, settings_list: Sequence[FilterSettings], use_mag: bool) -> list[Array]:
    """(N, 4) attitudes of one filter with several settings over the same recording.

    Uses the filters' many-instances sweep path (:func:`mavahrs.filters.base.run_many`,
    compiled, instances in parallel) when it exists, else one batch run per setting.
    """
    from mavahrs.filters import base, create

    mag = rec.mag_ut if use_mag else None
    vel = rec.extra.get("velocity_ned_m_s")
    inputs = make_inputs(
        rec.gyro_rad_s, rec.accel_m_s2, mag, dt_s=rec.dt_s, velocity_ned_m_s=vel,
        velocity_age_s=rec.extra.get("velocity_age_s") if vel is not None else None,
    )  # fmt: skip
    filters = [create(name, s) for s in settings_list]
    run_many = getattr(base, "run_many", None)
    if run_many is not None and len({type(f) for f in filters}) == 1:
        q = run_many(filters, inputs)
        return [q[m] for m in range(q.shape[0])]
    return [f.run(inputs)[:, OUT_Q : OUT_Q + 4] for f in filters]


def _errors(q_est: Array, rec: Recording, use_mag: bool) -> tuple[Array, NDArray[np.bool_]]:
    """The per-sample error this study scores (total for 9-axis, inclination for 6-axis), rad,
    after the dataset's alignment, and the scored mask."""
    ref = rec.q_ref_body_to_ned
    scored = np.asarray(rec.scored, dtype=bool) & np.all(np.isfinite(ref), axis=1)
    mode = choose_alignment(rec, use_mag and rec.mag_ut is not None, "auto")
    if mode != "none":
        ref = fit_alignment(q_est, ref, scored, mode=mode).apply(ref)
    total, _, incl = attitude_errors_rad(q_est, ref)
    return (total if use_mag and rec.mag_ut is not None else incl), scored


# --------------------------------------------------------------------------- β (Fig. 10)


def beta_study(
    recordings: Sequence[Recording],
    *,
    filter_name: str = "madgwick",
    values: Sequence[float] = DEFAULT_BETAS,
    axes: Sequence[int] = (6, 9),
    base_settings: FilterSettings | None = None,
    progress: bool = False,
) -> StudyResult:
    """Error vs the filter's main gain (β for Madgwick), mean over the recordings.

    For each gain value and each form (6-axis IMU, 9-axis MARG): the RMS error
    at rest and in motion over the scored samples, averaged over recordings.
    """
    base = base_settings if base_settings is not None else _default_settings(filter_name)
    fname = gain_field(base)
    settings_list = [dataclasses.replace(base, **{fname: float(v)}) for v in values]
    # results[axes][i] = list over recordings of (rest, motion, all)
    acc: dict[int, list[list[tuple[float, float, float]]]] = {a: [[] for _ in values] for a in axes}
    it: Any = recordings
    if progress:
        from tqdm import tqdm

        it = tqdm(recordings, desc=f"{fname} sweep", unit="rec", leave=False)
    for rec in it:
        moving = motion_mask(rec.gyro_rad_s, rec.dt_s)
        for a in axes:
            use_mag = a == 9
            if use_mag and rec.mag_ut is None:
                continue
            for i, q in enumerate(_run_many(rec, filter_name, settings_list, use_mag)):
                err, scored = _errors(q, rec, use_mag)
                acc[a][i].append(
                    (rms_deg(err, scored & ~moving), rms_deg(err, scored & moving), rms_deg(err, scored))
                )
    columns = [fname]
    for a in axes:
        kind = "total" if a == 9 else "incl"
        columns += [f"{a}D {kind} rest", f"{a}D {kind} motion", f"{a}D {kind} all"]
    rows: list[list[Any]] = []
    curves: dict[str, Array] = {}
    for a in axes:
        for j, part in enumerate(("rest", "motion", "all")):
            curves[f"{a}D {part}"] = np.array(
                [np.nanmean([r[j] for r in acc[a][i]]) if acc[a][i] else np.nan for i in range(len(values))]
            )
    for i, v in enumerate(values):
        row: list[Any] = [float(v)]
        for a in axes:
            row += [float(curves[f"{a}D {p}"][i]) for p in ("rest", "motion", "all")]
        rows.append(row)
    notes = [
        f"{filter_name} with its default settings except {fname}; mean over {len(recordings)} recording(s)",
        "9-axis scored by the total error angle, 6-axis by inclination (its heading is unobservable); "
        "rest/motion split at 5°/s",
    ]
    best = {}
    for a in axes:
        c = curves[f"{a}D all"]
        if np.isfinite(c).any():
            k = int(np.nanargmin(c))
            best[a] = (float(values[k]), float(c[k]))
            notes.append(f"{a}-axis: lowest error {c[k]:.3f}° at {fname} = {values[k]:g}")
    return StudyResult(
        study="beta",
        title=f"Error (deg RMS) vs {fname} — Madgwick 2010 Fig. 10",
        columns=columns,
        rows=rows,
        notes=notes,
        data={"values": np.asarray(values, dtype=float), "curves": curves, "field": fname, "best": best},
    )


# --------------------------------------------------------------------------- rate (Fig. 11)


def decimate(rec: Recording, factor: int, method: str = "average") -> Recording:
    """Keep every ``factor``-th sample, as a slower sensor stream would deliver it.

    ``method="average"``: the gyro is averaged over the ``factor`` samples of
    each block (the mean rate over the new, longer interval — what a
    delta-angle or a low-passed autopilot stream delivers — so the integrated
    angle is kept); accelerometer, magnetometer and reference are the block's
    last sample (a snapshot).  ``method="pick"``: every signal is the last
    sample of the block (a plain snapshot stream; the gyro then aliases).
    The new ``dt`` is the sum of the block's intervals.
    """
    if factor < 1:
        raise ValueError(f"decimation factor must be ≥ 1, got {factor}")
    if method not in ("average", "pick"):
        raise ValueError(f"decimation method must be 'average' or 'pick', got {method!r}")
    if factor == 1:
        return rec
    n_blocks = rec.n // factor
    if n_blocks < 2:
        raise ValueError(f"{rec.name}: too short to decimate by {factor}")
    end = n_blocks * factor
    last = np.arange(factor - 1, end, factor)

    def blocks(a: Array) -> Array:
        return a[:end].reshape(n_blocks, factor, *a.shape[1:])

    if method == "average":
        g = blocks(rec.gyro_rad_s)
        w = blocks(np.nan_to_num(rec.dt_s, nan=0.0))[..., None]
        wsum = w.sum(axis=1)
        gyro = np.where(wsum > 0, (g * w).sum(axis=1) / np.where(wsum > 0, wsum, 1.0), g.mean(axis=1))
    else:
        gyro = rec.gyro_rad_s[last]
    dt = blocks(rec.dt_s).sum(axis=1)
    extra = dict(rec.extra)
    for key in ("time_s", "temperature_c", "velocity_ned_m_s", "velocity_age_s"):
        if key in extra and extra[key] is not None:
            extra[key] = np.asarray(extra[key])[last]
    return dataclasses.replace(
        rec,
        name=f"{rec.name}@/{factor}",
        dt_s=dt,
        gyro_rad_s=np.ascontiguousarray(gyro),
        accel_m_s2=np.ascontiguousarray(rec.accel_m_s2[last]),
        mag_ut=None if rec.mag_ut is None else np.ascontiguousarray(rec.mag_ut[last]),
        q_ref_body_to_ned=rec.q_ref_body_to_ned[last],
        scored=rec.scored[last],
        extra=extra,
    )


def _native_rate_hz(rec: Recording) -> float:
    dt = rec.dt_s[np.isfinite(rec.dt_s) & (rec.dt_s > 0)]
    return float(1.0 / np.median(dt))


def rate_study(
    recordings: Sequence[Recording],
    *,
    filter_name: str = "madgwick",
    rates_hz: Sequence[float] = DEFAULT_RATES_HZ,
    axes: Sequence[int] = (6, 9),
    method: str = "average",
    settings: FilterSettings | None = None,
    progress: bool = False,
) -> StudyResult:
    """Error vs sample rate by decimation (Madgwick 2010, Fig. 11), mean over recordings.

    The decimation factor for a rate is ``round(native / rate)`` and the
    achieved rate is reported; rates above a recording's own are skipped.
    The rest/motion split is taken from the full-rate gyro at the kept samples.
    """
    rows_acc: dict[float, dict[int, list[tuple[float, float, float]]]] = {}
    achieved: dict[float, list[float]] = {}
    skipped: set[float] = set()
    it: Any = recordings
    if progress:
        from tqdm import tqdm

        it = tqdm(recordings, desc="rate sweep", unit="rec", leave=False)
    for rec in it:
        native = _native_rate_hz(rec)
        moving_full = motion_mask(rec.gyro_rad_s, rec.dt_s)
        for rate in rates_hz:
            factor = int(round(native / rate))
            if factor < 1 or rate > native * 1.05:
                skipped.add(float(rate))
                continue
            try:
                d = decimate(rec, factor, method)
            except ValueError:
                skipped.add(float(rate))
                continue
            end = (rec.n // factor) * factor
            moving = moving_full[factor - 1 : end : factor] if factor > 1 else moving_full
            achieved.setdefault(float(rate), []).append(native / factor)
            # a slow stream is not a gap: let the filter integrate across its interval
            s = settings if settings is not None else _default_settings(filter_name)
            s = dataclasses.replace(s, max_gap_s=max(s.max_gap_s, 3.0 * factor / native))
            for a in axes:
                use_mag = a == 9
                if use_mag and d.mag_ut is None:
                    continue
                out = run_filter(d, filter_name, s, use_mag=use_mag)
                err, scored = _errors(out[:, OUT_Q : OUT_Q + 4], d, use_mag)
                rows_acc.setdefault(float(rate), {}).setdefault(a, []).append(
                    (rms_deg(err, scored & ~moving), rms_deg(err, scored & moving), rms_deg(err, scored))
                )
    columns = ["rate Hz", "achieved Hz"]
    for a in axes:
        kind = "total" if a == 9 else "incl"
        columns += [f"{a}D {kind} rest", f"{a}D {kind} motion", f"{a}D {kind} all"]
    rows: list[list[Any]] = []
    used = [float(r) for r in rates_hz if float(r) in rows_acc]
    curves: dict[str, Array] = {}
    for a in axes:
        for j, part in enumerate(("rest", "motion", "all")):
            curves[f"{a}D {part}"] = np.array(
                [np.nanmean([x[j] for x in rows_acc[r].get(a, [])]) if rows_acc[r].get(a) else np.nan for r in used]
            )
    for i, r in enumerate(used):
        row: list[Any] = [r, float(np.mean(achieved[r]))]
        for a in axes:
            row += [float(curves[f"{a}D {p}"][i]) for p in ("rest", "motion", "all")]
        rows.append(row)
    notes = [
        f"{filter_name}, default settings (its gains are in physical, rate-independent units), "
        "max_gap_s raised to 3 sample intervals so a slow stream is integrated, not treated as gaps",
        f"decimation: {method} — "
        + (
            "gyro averaged over each block (keeps the integrated angle), accel/mag/reference "
            "taken at the block's last sample"
            if method == "average"
            else "every signal taken at the block's last sample (snapshot; the gyro aliases)"
        ),
        "9-axis scored by the total error angle, 6-axis by inclination; rest/motion split at 5°/s",
    ]
    if skipped - set(used):
        notes.append(
            "skipped (above the recording's own rate): "
            + ", ".join(f"{r:g} Hz" for r in sorted(skipped - set(used)))
        )
    return StudyResult(
        study="rate",
        title="Error (deg RMS) vs sample rate — Madgwick 2010 Fig. 11",
        columns=columns,
        rows=rows,
        notes=notes,
        data={"rates": np.array([row[1] for row in rows]), "curves": curves, "method": method},
    )


# --------------------------------------------------------------------------- bias (Fig. 12)


def bias_study(
    rec: Recording,
    *,
    filter_name: str = "madgwick",
    drift_deg_s2: tuple[float, float, float] = (0.2, -0.2, 0.0),
    zeta_off_s: float = 10.0,
    zeta: float = 0.015,
    duration_s: float | None = None,
    use_mag: bool = True,
    base_settings: FilterSettings | None = None,
) -> StudyResult:
    """Bias tracking with an injected gyro drift (Madgwick 2010, section 5.4, Fig. 12).

    A bias growing linearly, ``drift_deg_s2 · t`` (°/s), is added to the gyro;
    the filter runs with its bias gain (ζ for Madgwick, ``ki_accel`` for
    Mahony) at 0 for the first ``zeta_off_s`` seconds, then at ``zeta``; its
    state is carried across the switch.  Reports the bias estimate against the
    injected bias and the attitude error before and after.
    """
    from mavahrs.filters import create

    base = base_settings if base_settings is not None else _default_settings(filter_name)
    names = {f.name for f in dataclasses.fields(base)}
    limit_note = ""
    if "bias_limit_rad_s" in names and base_settings is None:
        # the injected drift grows without bound: lift the filter's bias clamp so it can be followed
        base = dataclasses.replace(base, bias_limit_rad_s=math.radians(1000.0))
        limit_note = "; the filter's bias clamp (bias_limit_rad_s) lifted to 1000 °/s"
    if base_settings is None:
        # as in the report: the bias gain alone (no rest-phase estimate, no spin freeze)
        rest = getattr(base, "rest", None)
        if rest is not None and dataclasses.is_dataclass(rest) and hasattr(rest, "bias_tau_s"):
            base = dataclasses.replace(base, rest=dataclasses.replace(rest, bias_tau_s=0.0))
            limit_note += "; rest-phase bias estimation off"
        if "zeta_spin_limit_rad_s" in names:
            base = dataclasses.replace(base, zeta_spin_limit_rad_s=0.0)
            limit_note += "; ζ applied at every rate"
    bias_field = next((n for n in ("zeta_rad_s", "zeta", "ki_accel", "bias_gain", "k_b") if n in names), None)
    if bias_field is None:
        raise ValueError(f"{filter_name} has no gyro-bias gain to switch on (zeta/ki_accel)")
    if duration_s is not None:
        t_all = np.cumsum(rec.dt_s) - rec.dt_s[0]
        keep = t_all <= duration_s
        rec = dataclasses.replace(
            rec,
            dt_s=rec.dt_s[keep],
            gyro_rad_s=rec.gyro_rad_s[keep],
            accel_m_s2=rec.accel_m_s2[keep],
            mag_ut=None if rec.mag_ut is None else rec.mag_ut[keep],
            q_ref_body_to_ned=rec.q_ref_body_to_ned[keep],
            scored=rec.scored[keep],
        )
    dt = np.nan_to_num(rec.dt_s, nan=0.0)
    t = np.cumsum(dt) - dt[0]
    injected = np.radians(np.asarray(drift_deg_s2, dtype=float))[None, :] * t[:, None]
    mag = rec.mag_ut if use_mag else None
    inputs = make_inputs(rec.gyro_rad_s + injected, rec.accel_m_s2, mag, dt_s=rec.dt_s)
    split = int(np.searchsorted(t, zeta_off_s))
    f0 = create(filter_name, dataclasses.replace(base, **{bias_field: 0.0}))
    out_a = f0.run(inputs[:split])
    f1 = create(filter_name, dataclasses.replace(base, **{bias_field: float(zeta)}))
    f1.state = f0.state
    out_b = f1.run(inputs[split:])
    out = np.vstack([out_a, out_b]) if split > 0 else out_b
    bias_est = out[:, OUT_BIAS : OUT_BIAS + 3]
    q = out[:, OUT_Q : OUT_Q + 4]
    ref = rec.q_ref_body_to_ned
    valid = np.all(np.isfinite(ref), axis=1)
    mode = choose_alignment(rec, mag is not None, "auto")
    if mode != "none":
        ref = fit_alignment(q, ref, valid & rec.scored, mode=mode).apply(ref)
    total, heading, incl = attitude_errors_rad(q, ref)
    bias_err_deg = np.degrees(bias_est - injected)
    rows: list[list[Any]] = []
    for label, sel in (
        (f"t < {zeta_off_s:g} s (bias gain 0)", t < zeta_off_s),
        (f"{zeta_off_s:g} s … {zeta_off_s + 30:g} s", (t >= zeta_off_s) & (t < zeta_off_s + 30)),
        (f"t ≥ {zeta_off_s + 30:g} s (tracking)", t >= zeta_off_s + 30),
    ):
        if not sel.any():
            continue
        s = sel & valid
        rows.append(
            [
                label,
                float(np.sqrt(np.mean(bias_err_deg[sel, 0] ** 2))),
                float(np.sqrt(np.mean(bias_err_deg[sel, 1] ** 2))),
                float(np.mean(bias_err_deg[sel, 0])),
                float(np.mean(bias_err_deg[sel, 1])),
                rms_deg(incl, s),
                rms_deg(total, s),
            ]
        )
    return StudyResult(
        study="bias",
        title=(
            f"Gyro bias tracking, {filter_name}: drift {drift_deg_s2[0]:+g}/{drift_deg_s2[1]:+g}/"
            f"{drift_deg_s2[2]:+g} °/s per s, {bias_field} = 0 then {zeta:g} after {zeta_off_s:g} s "
            "— Madgwick 2010 Fig. 12"
        ),
        columns=["interval", "bias x RMS err °/s", "bias y RMS err °/s", "bias x mean err", "bias y mean err",
                 "incl RMS °", "total RMS °"],  # fmt: skip
        rows=rows,
        notes=[
            f"recording {rec.name}, {t[-1]:.0f} s, {'9' if mag is not None else '6'}-axis",
            f"bias error = estimate − injected drift (the recording's own residual bias is not subtracted); "
            f"alignment {mode}{limit_note}",
        ],
        data={
            "t": t,
            "injected_deg_s": np.degrees(injected),
            "estimate_deg_s": np.degrees(bias_est),
            "incl_err_deg": np.degrees(incl),
            "total_err_deg": np.degrees(total),
            "zeta_on_s": zeta_off_s,
            "field": bias_field,
        },
    )


# --------------------------------------------------------------------------- 2022 comparison


def compare_study(
    rec: Recording,
    *,
    filters: Sequence[str] = ("mahony", "madgwick", "complementary"),
    use_mag: bool = True,
    settings: dict[str, FilterSettings] | None = None,
) -> StudyResult:
    """Filters side by side on one recording (Ermakov & Gogolev 2022, Table 2 and Fig. 8–13).

    The table holds the mean and SD of each angle's error; ``data`` holds the
    per-angle reference, estimates and errors for
    :func:`mavahrs.evaluation.plots.plot_comparison`.
    """
    use_mag = use_mag and rec.mag_ut is not None
    mode = choose_alignment(rec, use_mag, "auto")
    ref = rec.q_ref_body_to_ned
    scored = np.asarray(rec.scored, dtype=bool) & np.all(np.isfinite(ref), axis=1)
    t = np.cumsum(np.nan_to_num(rec.dt_s)) - np.nan_to_num(rec.dt_s[0])
    rows: list[list[Any]] = []
    est_euler: dict[str, Array] = {}
    errors: dict[str, Array] = {}
    ref_euler: dict[str, Array] = {}
    for name in filters:
        out = run_filter(rec, name, (settings or {}).get(name), use_mag=use_mag)
        q = out[:, OUT_Q : OUT_Q + 4]
        r = fit_alignment(q, ref, scored, mode=mode).apply(ref) if mode != "none" else ref
        err = euler_errors_rad(q, r)
        st = angle_stats(err, scored)
        rows.append([name, *st.mean_deg, *st.sd_deg, *st.rms_deg])
        est_euler[name] = euler_deg(q)
        errors[name] = np.degrees(err)
        ref_euler[name] = euler_deg(r)
    return StudyResult(
        study="compare",
        title=f"Per-angle error on {rec.name} ({'9' if use_mag else '6'}-axis) — Ermakov & Gogolev 2022, Table 2",
        columns=["filter", "roll mean", "pitch mean", "yaw mean", "roll SD", "pitch SD", "yaw SD",
                 "roll RMS", "pitch RMS", "yaw RMS"],  # fmt: skip
        rows=rows,
        notes=[f"alignment {mode}; degrees; errors = Euler angles of q_ref*⊗q_est over the scored samples"],
        data={"t": t, "ref_euler_deg": ref_euler, "est_euler_deg": est_euler, "err_deg": errors,
              "scored": scored, "name": rec.name},  # fmt: skip
    )
