r"""Plots of replays, evaluations and studies (matplotlib, the ``plot`` extra).

The only module in mavahrs that imports matplotlib, and only inside the
functions (the ``Agg`` backend: files, no window), so nothing else pays for it.

* :func:`plot_attitude` — per angle: reference, estimates (and the autopilot's
  own attitude, if given) on top, the error below; underneath, each filter's
  correction gain and its accelerometer / magnetometer trust (rejection state);
* :func:`plot_study` — the β sweep (Madgwick 2010 Fig. 10), the sample-rate
  sweep (Fig. 11), the bias-tracking study (Fig. 12) and the side-by-side
  comparison (Ermakov & Gogolev 2022, Fig. 8–13).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import MavahrsError
from mavahrs.evaluation.metrics import euler_deg, euler_errors_rad
from mavahrs.filters.layout import (
    FLAG_ACCEL_INVALID,
    FLAG_MAG_INVALID,
    OUT_ACCEL_WEIGHT,
    OUT_FLAGS,
    OUT_GAIN,
    OUT_MAG_WEIGHT,
    OUT_Q,
    OUT_WIDTH,
)

if TYPE_CHECKING:  # pragma: no cover
    from mavahrs.evaluation.studies import StudyResult

__all__ = ["plot_attitude", "plot_study", "plot_fleet", "PlotError"]

Array = NDArray[np.float64]
ANGLES = ("roll", "pitch", "yaw")
_REF_COLOR = "black"
_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:olive", "tab:cyan")
#: ``best`` stands out: its own colour (no other filter gets it), a heavier line, drawn on top
_BEST_COLOR = "tab:red"
_FLEET_NAMED = 12  # flagged flights numbered and named in the fleet plot; the rest are counted


def _style(name: str, j: int, lw: float) -> dict[str, Any]:
    """Line style of estimate ``name``, the ``j``-th of its plot."""
    if name == "best":
        return {"color": _BEST_COLOR, "lw": lw * 1.7, "zorder": 5}
    return {"color": _COLORS[j % len(_COLORS)], "lw": lw}


class PlotError(MavahrsError):
    """matplotlib is missing or the plot could not be written."""


def _pyplot() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise PlotError("plots need matplotlib: pip install 'mavahrs[plot]'") from exc
    return plt


def _save(fig: Any, path: str | Path) -> Path:
    """Write ``fig`` to ``path`` and return the file written: a name without a suffix gets ``.png``, as
    matplotlib's own default format (said, so that ``wrote OUT`` names the file that exists)."""
    path = Path(path)
    if not path.suffix:
        path = path.with_name(path.name + ".png")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise PlotError(f"cannot write the plot {path}: {exc}") from exc
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
    return path


def _fitted_legend(fig: Any, ax: Any, *, loc: str, fontsize: float) -> Any:
    """The axes' legend in as many columns as fit inside its width (one row if they can, else more).

    A legend wider than its axes would run out of the figure and over the axis label
    (``replay --filter all --plot`` drew ten entries in one row under a 12-inch-wide panel).
    """
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return None
    renderer = fig.canvas.get_renderer()
    width = ax.get_window_extent(renderer).width
    for ncol in range(len(handles), 0, -1):
        leg = ax.legend(handles, labels, loc=loc, fontsize=fontsize, ncol=ncol)
        if leg.get_window_extent(renderer).width <= width or ncol == 1:
            return leg
        leg.remove()
    return None  # pragma: no cover - the loop always returns


def _unwrap(y: Array, like: Array | None = None) -> Array:
    """Unwrap an angle in degrees (no ±180° jumps drawn as lines), NaN kept.

    Without ``like`` the result is shifted by whole turns so that the middle of
    its range lies in [−180°, 180°] (the largest |angle| drawn is then as
    small as it can be: a heading from 355° turning 320° to the right is drawn
    −5° … 315°, not −365° … −45° as a median rule put it); with ``like``, so
    that it lies on the same turn as ``like``.
    """
    y = np.asarray(y, dtype=float).copy()
    fin = np.isfinite(y)
    if fin.sum() < 2:
        return y
    y[fin] = np.unwrap(y[fin], period=360.0)
    if like is not None and np.isfinite(like).any():
        both = fin & np.isfinite(like)
        if both.any():
            y -= 360.0 * np.round(np.median(y[both] - like[both]) / 360.0)
            return y
    y -= 360.0 * np.round(0.5 * (np.min(y[fin]) + np.max(y[fin])) / 360.0)
    return y


def _angle(y: Array, k: int, like: Array | None = None) -> Array:
    """Angle ``k`` (0 roll, 1 pitch, 2 yaw) for drawing.

    Roll and yaw are unwrapped (a level BROAD sensor sits at roll ±180°) unless
    they turn more than a full circle (a vehicle flying circles): then they are
    drawn wrapped to ±180° with the wrap-arounds left undrawn.
    """
    if k == 1:
        return y
    u = _unwrap(y, like)
    fin = np.isfinite(u)
    if fin.any() and np.ptp(u[fin]) > 400.0:
        w = (np.asarray(y, dtype=float) + 180.0) % 360.0 - 180.0
        if w.size > 1:
            w[1:][np.abs(np.diff(w)) > 180.0] = np.nan
        return w
    return u


def _hidden_labels(quats: Mapping[str, Array], tol_deg: float = 0.01) -> dict[str, str]:
    """Legend labels; a filter whose attitude is within ``tol_deg`` of a later-drawn one's at every sample
    says it is hidden beneath it (a hundredth of a degree is far below a line's width on any panel).

    (Mahony and the gyro-platform filter give the same attitudes with their defaults: bit for bit without
    GNSS, within 0.002° with it — the later line covers the earlier one.)
    """
    names = list(quats)
    out = {n: n for n in names}
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            qa, qb = np.asarray(quats[a], float), np.asarray(quats[b], float)
            if qa.shape != qb.shape or not qa.size:
                continue
            dot = np.abs(np.sum(qa * qb, axis=1))  # q and −q alike
            fin = np.isfinite(dot)
            if not fin.any():
                continue
            worst = float(np.degrees(2.0 * np.arccos(np.clip(dot[fin].min(), -1.0, 1.0))))
            if worst <= tol_deg:
                same = float(np.minimum(np.abs(qa - qb), np.abs(qa + qb))[fin].max()) <= 1e-6
                out[a] = (f"{a} (identical to {b}, hidden beneath it)" if same else
                          f"{a} (within {max(worst, 0.001):.3f}° of {b}, hidden beneath it)")  # fmt: skip
                break
    return out


def _wrap_entries(entries: list[str], width: int) -> list[str]:
    """Entries joined by ``;`` into lines of at most ``width`` characters (an entry is never split)."""
    lines: list[str] = []
    for e in entries:
        if lines and len(lines[-1]) + 3 + len(e) <= width:
            lines[-1] += ("   " if lines[-1].endswith(":") else ";  ") + e
        else:
            lines.append(e)
    return lines


def _quats(x: Array) -> Array:
    x = np.asarray(x, dtype=float)
    return x[:, OUT_Q : OUT_Q + 4] if x.shape[1] == OUT_WIDTH else x


#: a sensor's trust is held over samples without its reading for at most this long (s); a longer absence is a gap
TRUST_HOLD_S = 0.5


def held_trust(t_s: Array, est: Array, column: int, invalid_flag: int, hold_s: float = TRUST_HOLD_S) -> Array:
    """A filter's trust in one sensor (``OUT_ACCEL_WEIGHT`` / ``OUT_MAG_WEIGHT``) as the filter holds it.

    A sample without that sensor's reading carries its ``FLAG_*_INVALID`` and a weight of 0: a 100 Hz
    magnetometer between 250 Hz IMU samples, drawn as it is, alternates 0 and 1 and fills the panel as if
    the compass were rejected on every other sample.  Such samples take the last weight of a sample that
    had the reading, for up to ``hold_s`` of ``t_s``; after that (the sensor gone), and before its first
    reading, they are NaN: a gap, not "rejected".  NaN rows (a reboot's line break) stay NaN.
    """
    t = np.asarray(t_s, dtype=float)
    w = np.asarray(est[:, column], dtype=float)
    flags = np.asarray(est[:, OUT_FLAGS], dtype=float)
    without = np.isfinite(flags) & ((np.where(np.isfinite(flags), flags, 0.0).astype(np.int64) & invalid_flag) != 0)
    if not without.any():
        return w.copy()
    pos = np.arange(w.size)
    last = np.maximum.accumulate(np.where(without, -1, pos))  # the last sample with the reading (or a NaN row)
    held = np.where(last >= 0, w[np.maximum(last, 0)], np.nan)
    fresh = np.abs(t - t[np.maximum(last, 0)]) <= hold_s
    return np.where(~without, w, np.where((last >= 0) & fresh, held, np.nan))


def plot_attitude(
    path: str | Path,
    t_s: Array,
    estimates: Mapping[str, Array],
    *,
    reference_q: Array | None = None,
    reference_label: str = "reference",
    others: Mapping[str, tuple[Array, Array]] | None = None,
    title: str = "",
    max_points: int = 20000,
    time_label: str = "time (s)",
) -> Path:
    """Truth / estimate / error per angle, gain and rejection state underneath.

    Args:
        path: PNG file to write.
        t_s: (N,) sample times, s (a NaN row breaks every line there: a new boot of the autopilot).
        estimates: filter name → (N, OUT_WIDTH) filter output rows (gain and
            weights are then drawn) or (N, 4) quaternions.
        reference_q: (N, 4) reference ``q_body_to_ned`` (NaN rows allowed), or None.
        reference_label: legend text for the reference (e.g. "SIMSTATE truth").
        others: extra attitudes at their own times, name → (t_s, (M, 4) q),
            e.g. the autopilot's ATTITUDE; drawn dashed, no error row.
        max_points: long series are thinned to about this many points.
        time_label: the time axis' label (what ``t_s`` counts from).
    """
    plt = _pyplot()
    t = np.asarray(t_s, dtype=float)
    step = max(1, t.size // max_points)
    idx = np.union1d(np.arange(0, t.size, step), np.flatnonzero(np.isnan(t)))  # NaN rows break lines: keep them
    has_diag = any(np.asarray(v).shape[1] == OUT_WIDTH for v in estimates.values())
    has_err = reference_q is not None and np.isfinite(reference_q).all(axis=1).any()
    rows: list[tuple[str, float]] = []
    for a in ANGLES:
        rows.append((a, 2.6))
        if has_err:
            rows.append((a + " err", 1.2))
    if has_diag:
        rows += [("gain", 1.1), ("trust", 1.1)]
    fig, axes = plt.subplots(
        len(rows), 1, sharex=True, figsize=(12, 1.15 * sum(h for _, h in rows) + 1.0),
        gridspec_kw={"height_ratios": [h for _, h in rows]},
    )  # fmt: skip
    axes = np.atleast_1d(axes)
    ax_of = {name: ax for (name, _), ax in zip(rows, axes, strict=True)}
    ref_e = euler_deg(reference_q)[idx] if has_err and reference_q is not None else None
    est_e = {name: euler_deg(_quats(est)[idx]) for name, est in estimates.items()}
    label = _hidden_labels({name: _quats(est)[idx] for name, est in estimates.items()})
    for k, a in enumerate(ANGLES):
        ax = ax_of[a]
        like = None
        if ref_e is not None:
            like = _angle(ref_e[:, k], k)
            ax.plot(t[idx], like, color=_REF_COLOR, lw=1.6, label=reference_label)
        for j, (name, e) in enumerate(est_e.items()):
            y = _angle(e[:, k], k, like)
            like = y if like is None else like
            ax.plot(t[idx], y, label=label[name], **_style(name, j, 0.9))
        for j, (name, (t_o, q_o)) in enumerate((others or {}).items()):
            e = euler_deg(q_o)
            y = _angle(e[:, k], k, np.interp(t_o, t[idx], like) if like is not None else None)
            ax.plot(t_o, y, ls="--", lw=0.9, color=_COLORS[(j + 3) % len(_COLORS)], label=name)
        ax.set_ylabel(f"{a} (°)")
        ax.grid(alpha=0.3)
        if has_err:
            axe = ax_of[a + " err"]
            for j, (name, est) in enumerate(estimates.items()):
                err = np.degrees(euler_errors_rad(_quats(est)[idx], reference_q[idx]))  # type: ignore[index]
                rms = float(np.sqrt(np.nanmean(err[:, k] ** 2))) if np.isfinite(err[:, k]).any() else np.nan
                axe.plot(t[idx], err[:, k], label=f"{label[name]} RMS {rms:.2f}°", **_style(name, j, 0.8))
            axe.axhline(0, color="grey", lw=0.6)
            axe.set_ylabel(f"{a} err (°)")
            axe.grid(alpha=0.3)
            _fitted_legend(fig, axe, loc="upper right", fontsize=7)
    _fitted_legend(fig, ax_of["roll"], loc="upper right", fontsize=8)
    if has_diag:
        axg, axw = ax_of["gain"], ax_of["trust"]
        for j, (name, est) in enumerate(estimates.items()):
            est = np.asarray(est)
            if est.shape[1] != OUT_WIDTH:
                continue
            st = _style(name, j, 0.9)
            axg.plot(t[idx], est[idx, OUT_GAIN], label=name, **st)
            axw.plot(t[idx], held_trust(t, est, OUT_ACCEL_WEIGHT, FLAG_ACCEL_INVALID)[idx], **st)
            axw.plot(t[idx], held_trust(t, est, OUT_MAG_WEIGHT, FLAG_MAG_INVALID)[idx], ls=":", **st)
        axg.set_ylabel("gain")
        axg.set_yscale("symlog", linthresh=0.01)
        axg.grid(alpha=0.3)
        _fitted_legend(fig, axg, loc="upper right", fontsize=7)
        axw.set_ylabel("trust\n(0 = rejected)")
        axw.set_ylim(-0.05, 1.1)
        axw.grid(alpha=0.3)
        # the colours are the filters' (named in the gain panel above): here only the two line styles,
        # so the legend stays two entries wide however many filters there are
        axw.plot([], [], color="grey", lw=0.9, label="accelerometer")
        axw.plot([], [], color="grey", lw=0.9, ls=":", label="magnetometer")
        _fitted_legend(fig, axw, loc="lower right", fontsize=7)
    axes[-1].set_xlabel(time_label)
    if title:
        fig.suptitle(title, fontsize=11)
        fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.985))
    else:
        fig.tight_layout()
    return _save(fig, path)


# --------------------------------------------------------------------------- studies


def plot_study(result: StudyResult, path: str | Path) -> Path:
    """Draw a :class:`~mavahrs.evaluation.studies.StudyResult` to a PNG."""
    kinds = {"beta": _plot_sweep, "rate": _plot_sweep, "bias": _plot_bias, "compare": _plot_comparison}
    try:
        fn = kinds[result.study]
    except KeyError:
        raise PlotError(f"no plot for study {result.study!r}") from None
    return fn(result, path)


def _plot_sweep(result: StudyResult, path: str | Path) -> Path:
    plt = _pyplot()
    d = result.data
    x = d["values"] if result.study == "beta" else d["rates"]
    fig, ax = plt.subplots(1, 1, figsize=(8, 5))
    styles = {"rest": "-", "motion": "--"}
    colors = {"6D": "tab:blue", "9D": "tab:red"}
    for key, y in d["curves"].items():
        axes_label, part = key.split(" ")
        if part == "all":
            continue
        kind = "total" if axes_label == "9D" else "inclination"
        label = f"{'MARG' if axes_label == '9D' else 'IMU'} ({axes_label}, {kind}) {'static' if part == 'rest' else 'dynamic'}"
        ax.plot(x, y, styles[part], color=colors.get(axes_label, "k"), marker="o", ms=3, label=label)
    if result.study == "rate":
        ax.set_xscale("log", base=2)
        ax.set_xlabel("sample rate (Hz)")
    else:
        ax.set_xlabel(d.get("field", "β"))
    ax.set_ylabel("RMS error (°)")
    finite = np.concatenate([np.asarray(v)[np.isfinite(v)] for v in d["curves"].values()] or [np.zeros(1)])
    if finite.size and finite.max() > 20 * max(np.percentile(finite, 50), 1e-3):
        ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(result.title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def _plot_bias(result: StudyResult, path: str | Path) -> Path:
    plt = _pyplot()
    d = result.data
    t = d["t"]
    step = max(1, t.size // 20000)
    s = slice(None, None, step)
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(10, 8), gridspec_kw={"height_ratios": [2, 2, 1.4]})
    for k, (ax, axis) in enumerate(zip(axes[:2], "xy", strict=True)):
        ax.plot(t[s], d["injected_deg_s"][s, k], color="black", lw=1.5, label=f"injected bias {axis}")
        ax.plot(t[s], d["estimate_deg_s"][s, k], color="tab:red", lw=1.0, label=f"estimated bias {axis}")
        ax.axvline(d["zeta_on_s"], color="grey", ls=":", lw=1)
        ax.set_ylabel(f"gyro {axis} bias (°/s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    axes[2].plot(t[s], d["incl_err_deg"][s], color="tab:blue", lw=0.8, label="inclination error")
    axes[2].plot(t[s], d["total_err_deg"][s], color="tab:orange", lw=0.8, label="total error")
    axes[2].axvline(d["zeta_on_s"], color="grey", ls=":", lw=1, label=f"{d['field']} switched on")
    axes[2].set_ylabel("error (°)")
    axes[2].set_xlabel("time (s)")
    axes[2].grid(alpha=0.3)
    axes[2].legend(fontsize=8, loc="upper left")
    fig.suptitle(result.title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def _plot_comparison(result: StudyResult, path: str | Path) -> Path:
    plt = _pyplot()
    d = result.data
    names = list(d["est_euler_deg"])
    t = d["t"]
    step = max(1, t.size // 8000)
    s = slice(None, None, step)
    fig, axes = plt.subplots(
        6, len(names), sharex=True, figsize=(4.6 * len(names) + 1, 13), squeeze=False,
        gridspec_kw={"height_ratios": [2.2, 1.2] * 3},
    )  # fmt: skip
    for j, name in enumerate(names):
        ref = d["ref_euler_deg"][name]
        est = d["est_euler_deg"][name]
        err = d["err_deg"][name]
        for k, a in enumerate(ANGLES):
            ax = axes[2 * k, j]
            r = _angle(ref[s, k], k)
            ax.plot(t[s], r, color=_REF_COLOR, lw=1.4, label="reference")
            ax.plot(t[s], _angle(est[s, k], k, r), color=_COLORS[j % len(_COLORS)], lw=0.8, label=name)
            ax.grid(alpha=0.3)
            if j == 0:
                ax.set_ylabel(f"{a} (°)")
            if k == 0:
                ax.set_title(name)
                ax.legend(fontsize=7, loc="upper right")
            axe = axes[2 * k + 1, j]
            sc = d["scored"][s]
            e = np.where(sc, err[s, k], np.nan)
            axe.plot(t[s], e, color=_COLORS[j % len(_COLORS)], lw=0.7)
            axe.axhline(0, color="grey", lw=0.5)
            axe.grid(alpha=0.3)
            m, sd = np.nanmean(err[d["scored"], k]), np.nanstd(err[d["scored"], k])
            axe.text(0.01, 0.85, f"mean {m:+.2f}°  SD {sd:.2f}°", transform=axe.transAxes, fontsize=7)
            if j == 0:
                axe.set_ylabel(f"{a} err (°)")
    for j in range(len(names)):
        axes[-1, j].set_xlabel("time (s)")
    # the same error scale across filters, so they compare at a glance
    for k in range(3):
        lims = [axes[2 * k + 1, j].get_ylim() for j in range(len(names))]
        lo, hi = min(x[0] for x in lims), max(x[1] for x in lims)
        for j in range(len(names)):
            axes[2 * k + 1, j].set_ylim(lo, hi)
    fig.suptitle(result.title, fontsize=11)
    fig.tight_layout()
    return _save(fig, path)


def fleet_threshold_lines(monitor: Any = None) -> tuple[float, float, str]:
    """(tilt deg, heading deg, legend text): where the fleet overview draws the monitor's thresholds.

    ``fixed`` mode: its fixed angles.  ``uncertainty`` mode (the default): the thresholds follow both
    estimators' σ flight by flight, so the floors they never go below (``min_tilt_threshold_deg``,
    ``min_heading_threshold_deg``: 1°, 3°) are drawn.  (Until user6 the overview drew the ``fixed``
    mode's 10° / 25° whatever the mode: a flight flagged at 2° of tilt sat far inside them.)
    """
    if monitor is None:
        from mavahrs.service.monitor import MonitorSettings

        monitor = MonitorSettings()
    if monitor.mode == "fixed":
        tilt, hdg = float(monitor.tilt_threshold_deg), float(monitor.heading_threshold_deg)
        return tilt, hdg, f"monitor thresholds ({tilt:g}° tilt, {hdg:g}° heading)"
    tilt, hdg = float(monitor.min_tilt_threshold_deg), float(monitor.min_heading_threshold_deg)
    return tilt, hdg, f"monitor thresholds' floors ({tilt:g}° tilt, {hdg:g}° heading; higher with σ)"


def plot_fleet(
    path: str | Path,
    rows: list[Mapping[str, Any]],
    *,
    monitor: Any = None,
) -> Path:
    """The fleet overview of ``mavahrs audit``: one point per flight.

    Left, each flight's largest inclination vs heading divergence from the
    autopilot's own attitude (log scales, the monitor's thresholds dashed:
    :func:`fleet_threshold_lines`), flights the monitor flagged in red and
    named; middle, the distribution of the inclination RMS; right, vibration
    vs clipping.  ``rows`` are :class:`mavahrs.fleet.audit.FleetRow` fields as
    mappings; ``monitor`` the :class:`~mavahrs.service.monitor.MonitorSettings`
    the audit judged with (None: the defaults).
    """
    plt = _pyplot()
    from matplotlib.ticker import MaxNLocator

    def col(name: str, sel: list[Mapping[str, Any]]) -> Array:
        return np.array([np.nan if r.get(name) is None else float(r[name]) for r in sel], dtype=float)

    good = [r for r in rows if not r.get("error")]
    bad = len(rows) - len(good)
    flagged = [r for r in good if r.get("alarms")]
    clean = [r for r in good if not r.get("alarms")]
    fig, axes = plt.subplots(1, 3, figsize=(15, 5), gridspec_kw={"width_ratios": [1.4, 1.0, 1.0]})
    ax = axes[0]
    floor = 0.05  # deg: divergences below this are drawn on the axis
    for sel, color, label in ((clean, "tab:blue", "agrees"), (flagged, "tab:red", "monitor WARNING")):
        if sel:
            x = np.maximum(col("inclination_max_deg", sel), floor)
            y = np.maximum(col("heading_max_deg", sel), floor)
            ax.scatter(x, y, s=18 + 2 * np.nan_to_num(col("duration_s", sel)) ** 0.5 * 4, c=color, alpha=0.7,
                       edgecolors="none", label=f"{label} ({len(sel)})")  # fmt: skip
    named: list[str] = []
    for k, r in enumerate(flagged[:_FLEET_NAMED]):  # numbered at the point, named in the list under the axes
        t = r.get("first_alarm_s")
        name = Path(str(r["path"])).name
        named.append(f"{k + 1}  {name} @ {t:.1f} s" if t is not None and t == t else f"{k + 1}  {name}")
        ax.annotate(str(k + 1), (max(float(r["inclination_max_deg"]), floor), max(float(r["heading_max_deg"]), floor)),
                    fontsize=7, xytext=(4, 4), textcoords="offset points", color="tab:red")  # fmt: skip
    if len(flagged) > _FLEET_NAMED:
        named.append(f"… and {len(flagged) - _FLEET_NAMED} more (see the table)")
    tilt_line_deg, heading_line_deg, line_label = fleet_threshold_lines(monitor)
    ax.axvline(tilt_line_deg, color="grey", ls="--", lw=0.8, label=line_label)
    if heading_line_deg > 0:  # 0: heading not judged
        ax.axhline(heading_line_deg, color="grey", ls="--", lw=0.8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("largest inclination divergence, deg")
    ax.set_ylabel("largest heading divergence, deg")
    ax.set_title("mavahrs vs the autopilot's attitude, per flight")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, which="both", alpha=0.25)
    ax = axes[1]
    incl = col("inclination_rms_deg", good)
    incl = incl[np.isfinite(incl)]
    if incl.size:
        edges = np.linspace(0.0, max(float(incl.max()) * 1.05, 1.0), 25)
        ax.hist([col("inclination_rms_deg", clean), col("inclination_rms_deg", flagged)], bins=edges, stacked=True,
                color=["tab:blue", "tab:red"], label=["agrees", "WARNING"])  # fmt: skip
    ax.set_xlabel("inclination divergence RMS, deg")
    ax.set_ylabel("flights")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # whole flights, not 1.25
    ax.set_title("inclination divergence RMS")
    ax.grid(True, alpha=0.25)
    ax = axes[2]
    vib = np.full(len(good), np.nan)
    for k, r in enumerate(good):
        v = [float(r[f"vibration_{a}_m_s2"]) for a in "xyz" if r.get(f"vibration_{a}_m_s2") is not None]
        v = [x for x in v if np.isfinite(x)]
        vib[k] = max(v) if v else np.nan
    clipped = np.fmax(col("gyro_clip_fraction", good), col("accel_clip_fraction", good)) > 0
    fin = np.isfinite(vib)
    if fin.any():
        edges = np.linspace(0.0, max(float(vib[fin].max()) * 1.05, 0.1), 25)
        ax.hist([vib[fin & ~clipped], vib[fin & clipped]], bins=edges, stacked=True, color=["tab:purple", "tab:orange"],
                label=["no clipping", "clipping"])  # fmt: skip
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("vibration, m/s² RMS (worst axis)")
    ax.set_ylabel("flights")
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_title(f"vibration ({int(clipped.sum())} flights with clipped samples)")
    ax.grid(True, alpha=0.25)
    fig.suptitle(f"fleet audit: {len(rows)} logs, {len(flagged)} flagged, {bad} unreadable")
    lines = _wrap_entries(["flagged (numbered on the left):", *named], width=170) if named else []
    bottom = 0.03 + 0.035 * len(lines)  # the list of flagged flights gets its own strip under the axes
    for k, line in enumerate(lines):
        fig.text(0.01, bottom - 0.03 - 0.035 * k, line, fontsize=7, color="tab:red", va="bottom", ha="left")
    fig.tight_layout(rect=(0.0, bottom if lines else 0.0, 1.0, 1.0))
    return _save(fig, path)


def plot_second_opinion(path: str | Path, series: Any, *, title: str = "", t0_s: float = 0.0) -> Path:
    """The second-opinion monitor over one flight (:class:`~mavahrs.service.monitor.MonitorSeries`): tilt and
    |heading| divergence from the autopilot's attitude, the threshold in force (dashed), in-flight WARNINGs
    (red lines, shaded while on, their evidence written beside), NOTICEs on the ground (grey) — the status
    page's strip chart, for the whole flight.  Times: boot time minus ``t0_s``, s."""
    from mavahrs.service.monitor import mavlink as _mav  # the severities

    plt = _pyplot()
    t = np.asarray(series.t_ms, dtype=np.float64) / 1000.0 - t0_s
    fig, axes = plt.subplots(2, 1, figsize=(11, 5.5), sharex=True, constrained_layout=True)
    thr = (series.tilt_threshold_deg, series.heading_threshold_deg)
    for ax, y, th, label in ((axes[0], series.tilt_deg, thr[0], "tilt divergence, deg"),
                             (axes[1], np.abs(series.heading_deg), thr[1], "|heading| divergence, deg")):
        ax.plot(t, y, lw=0.9, color="tab:blue", label="mavahrs − autopilot")
        if th is not None and np.isfinite(th).any():
            ok = np.isfinite(th) & (th > 0)
            keep = ok | np.isnan(t)  # a NaN time is a new boot of the autopilot (replay_monitor): the line breaks
            ax.plot(t[keep], np.where(ok, th, np.nan)[keep], lw=1.2, ls="--", color="tab:orange", label="threshold")
            fin = y[np.isfinite(y)]
            if fin.size and ok.any():  # the start-up's wide thresholds and converging estimates off the scale
                top = max(float(np.percentile(fin, 99.5)), 2.0 * float(np.median(th[ok])))
                ax.set_ylim(0.0, 1.25 * top)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    start = None
    for e in series.events:
        te = e.t_ms / 1000.0 - t0_s
        warn = e.severity == _mav.MAV_SEVERITY_WARNING
        if e.severity == _mav.MAV_SEVERITY_INFO:
            if start is not None:
                for ax in axes:
                    ax.axvspan(start, te, color="tab:red", alpha=0.12, lw=0)
            start = None
            continue
        for ax in axes:
            ax.axvline(te, color="tab:red" if warn else "0.5", lw=1.0 if e.update else 1.8,
                       ls=":" if e.update else "-")
        if not e.update and warn:
            start = te if start is None else start
        label = (e.cause or ("–" if warn else "")) + ("" if warn else f" ({e.phase})")
        axes[0].annotate(label, (te, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -24 if e.update else -12),
                         textcoords="offset points", fontsize=8, color="tab:red" if warn else "0.4")
    if start is not None and t.size:
        for ax in axes:
            ax.axvspan(start, t[-1], color="tab:red", alpha=0.12, lw=0)
    n_warn = sum(1 for e in series.events if e.in_flight)
    held = series.held_comparisons / max(series.comparisons, 1)
    # as the replay line says it (MonitorSeries.held_note): under 1 % is not worth saying
    held_text = f"; {100.0 * held:.0f} % not judged (our IMU input too slow)" if held >= 0.01 else ""
    axes[0].set_title((title + " — " if title else "") + f"second opinion: {n_warn} in-flight WARNING(s){held_text}")
    axes[0].legend(loc="upper right", fontsize=8)
    # the autopilot's boot clock, as the WARNING times replay and audit print
    axes[1].set_xlabel("autopilot boot time, s" if not t0_s else f"time from boot {t0_s:.0f} s, s")
    return _save(fig, path)
